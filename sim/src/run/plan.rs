//! The resolved run: the one front door between a config file and the code
//! that simulates it.
//!
//! [`Plan::new`] takes a parsed [`RawConfig`], checks every range
//! ([`RawConfig::validate`]), fixes the seed (drawn from the operating
//! system when the config gives none), enumerates the datasets and reads
//! every input file the config names, each path resolved against the
//! directory of the config file:
//!
//! * the SkyMaker lists of `population.source = skymaker_list` (one per base
//!   field, `{field}` replaced by the field number);
//! * the image of every `fits` PSF model.
//!
//! After that nothing reads the config again: consumers ask the plan for
//! ready collaborators ([`Plan::detector`], [`Plan::accuracy`],
//! [`Plan::image_wcs`], [`Plan::placement_area`], [`Plan::psf_spec`],
//! [`Plan::skymaker_list`], ...) and for the models' typed specs
//! ([`Plan::geometry`], [`Plan::instrument`], [`Plan::telescope`],
//! [`Plan::galaxies`], [`Plan::stars`], [`Plan::cosmology`], [`Plan::output`]):
//! no `config` type leaves the plan, and the models never see the config. The resolved config's JSON
//! ([`Plan::config_json`]) keeps its paths as written; what
//! `RUN/private/config.json` holds is [`Plan::run_config_json`], whose
//! input paths name the copies of the inputs the run keeps beside it
//! ([`Plan::run_inputs`]), so that it reproduces the run from anywhere.

use crate::io::image_fits::{Compression, SampleFormat};
use crate::io::psf_fits::read_psf_fits_and_bytes;
use crate::io::skymaker::{ListError, read_list_and_bytes};
use crate::model::noise::{Detector, Instrument, sky_e_per_pixel};
use crate::model::population::{
    Cosmology, GalaxySpec, ListObject, Placement, PopulationSpec, StarSpec,
};
use crate::model::psf::{Psf, PsfError, PsfFileImage, PsfModel, PsfSpec, Telescope};
use crate::model::render::{Accuracy, Renderer};
use crate::model::wcs::{Geometry, TanWcs};
use crate::run::config::{ConfigError, Invalid, RawConfig, RawPsf, RawPsfModel, Source, draw_seed};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};
use stepsim_contract::io::IoError;
use stepsim_contract::run_dir::PrivateDir;
use stepsim_contract::run_layout::Part;
use stepsim_contract::seed::{SeedKey, Stream};

/// Why a config could not become a plan.
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    /// The config itself is refused (syntax, key, range).
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A SkyMaker list named by `population.source.path` is unusable (the
    /// list error names the file and line).
    #[error("{config}: key `population.source.path`: {source}")]
    List {
        /// The config file.
        config: PathBuf,
        /// What is wrong with the list.
        source: ListError,
    },
    /// The image file of a `fits` PSF model is unusable.
    #[error("{config}: key `psfs.{index}.model.path` (psf {name}): {source}")]
    PsfFile {
        /// The config file.
        config: PathBuf,
        /// Index of the PSF in the config.
        index: usize,
        /// Its name.
        name: String,
        /// The read error (names the file).
        source: IoError,
    },
}

/// Where a plan's master seed came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SeedOrigin {
    /// Written in the config (or a `--set run.seed=N`): anyone who knows it
    /// can rebuild the run, so the release is only as blind as it is secret.
    Config,
    /// The config gave none: drawn from the operating system's entropy.
    Drawn,
}

/// One dataset: a PSF and a shear. Its index is stable: `psf * n_shears + shear`
/// for the public part; held-out datasets (a `challenge` section) follow as
/// `n_psfs * n_shears + psf * n_shears + slot`.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    /// Index in [`Plan::datasets`].
    pub index: u32,
    /// Index of the PSF in [`Plan::psf_specs`].
    pub psf: usize,
    /// Index of the shear in [`Plan::shears`] (for a held-out dataset: its
    /// slot, 0..n_shears; its shear is drawn, not configured).
    pub shear: usize,
    /// Which part of the challenge it belongs to.
    pub part: Part,
    /// Its base fields, ascending (every field unless the run holds some out).
    pub fields: Vec<u32>,
    /// Applied g1.
    pub g1: f64,
    /// Applied g2.
    pub g2: f64,
}

/// A SkyMaker list as read: its objects and its file's bytes.
type ListRead = (Arc<Vec<ListObject>>, Arc<Vec<u8>>);

/// An input file of a run (a SkyMaker list, the image of a `fits` PSF) as
/// the plan read it: the run keeps a copy in `RUN/private/` under `name`
/// ([`Plan::run_inputs`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunInput {
    /// Path of the copy relative to `RUN/private/` (see
    /// [`PrivateDir::input`]).
    pub name: String,
    /// The file read (resolved against the config's directory).
    pub source: PathBuf,
    /// The file's bytes.
    pub bytes: Arc<Vec<u8>>,
}

/// The path pattern, relative to `RUN/private/`, of the copies of a run's
/// SkyMaker lists.
fn run_list_pattern() -> String {
    PrivateDir::skymaker_list_copy_pattern()
}

/// The path, relative to `RUN/private/`, of the copy of the image of `fits`
/// PSF `index`.
fn run_psf_path(index: usize) -> String {
    PrivateDir::fits_psf_copy(index)
}

/// A validated, resolved run (see the module docs). Cheap to clone: the
/// files it read are shared.
#[derive(Debug, Clone)]
pub struct Plan {
    config: RawConfig,
    source: PathBuf,
    datasets: Vec<Dataset>,
    seed_origin: SeedOrigin,
    /// One list per base field (`skymaker_list` sources only).
    lists: Option<Arc<Vec<Arc<Vec<ListObject>>>>>,
    /// What each PSF is built from, in config order (with the file's image
    /// for `fits` models).
    specs: Arc<Vec<PsfSpec>>,
    /// One slot per PSF, filled the first time [`Plan::psf`] builds it;
    /// shared by the plan's clones.
    psfs: Arc<Vec<OnceLock<Arc<dyn Psf>>>>,
    /// The input files read, as a run keeps them.
    inputs: Arc<Vec<RunInput>>,
}

impl Plan {
    /// Validates and resolves a parsed config; `source` is the config file
    /// (relative input paths are relative to its directory; it names the
    /// config in messages). A config without `run.seed` gets one drawn from
    /// the operating system ([`draw_seed`]; [`SeedOrigin::Drawn`]).
    pub fn new(mut config: RawConfig, source: &Path) -> Result<Self, PlanError> {
        config.validate(source)?;
        check_sky_below_saturation(&config).map_err(|e| e.in_file(source))?;
        let seed_origin = match config.run.seed {
            Some(_) => SeedOrigin::Config,
            None => {
                config.run.seed = Some(draw_seed().map_err(ConfigError::from)?);
                SeedOrigin::Drawn
            }
        };
        let datasets = challenge_datasets(&config);
        let mut inputs = Vec::new();
        let lists = match &config.population.source {
            Source::Stuff => None,
            Source::SkymakerList { path } => {
                // A file named by several fields (a path without `{field}`)
                // is read and parsed once, its objects and bytes shared.
                let mut seen: HashMap<PathBuf, ListRead> = HashMap::new();
                let mut read = Vec::new();
                for field in 0..config.image.n_images {
                    let file = list_path(source, path, field);
                    let (objects, bytes) = match seen.get(&file) {
                        Some(done) => done.clone(),
                        None => {
                            let (objects, bytes) =
                                read_list_and_bytes(&file).map_err(|e| PlanError::List {
                                    config: source.into(),
                                    source: e,
                                })?;
                            let done = (Arc::new(objects), Arc::new(bytes));
                            seen.insert(file.clone(), done.clone());
                            done
                        }
                    };
                    read.push(objects);
                    inputs.push(RunInput {
                        name: run_list_pattern().replace("{field}", &field.to_string()),
                        source: file,
                        bytes,
                    });
                }
                Some(Arc::new(read))
            }
        };
        let psf_images = config
            .psfs
            .iter()
            .enumerate()
            .map(|(index, p)| match &p.model {
                RawPsfModel::Fits { path, .. } => {
                    let path = resolve(source, Path::new(path));
                    let err = |e| PlanError::PsfFile {
                        config: source.into(),
                        index,
                        name: p.name.clone(),
                        source: e,
                    };
                    let ((values, nx, ny), bytes) = read_psf_fits_and_bytes(&path).map_err(err)?;
                    inputs.push(RunInput {
                        name: run_psf_path(index),
                        source: path.clone(),
                        bytes: Arc::new(bytes),
                    });
                    Ok(Some(Arc::new(PsfFileImage {
                        path,
                        values,
                        nx,
                        ny,
                    })))
                }
                _ => Ok(None),
            })
            .collect::<Result<Vec<_>, PlanError>>()?;
        let specs: Vec<PsfSpec> = config
            .psfs
            .iter()
            .zip(psf_images)
            .map(|(entry, image)| PsfSpec {
                image,
                ..psf_spec_of(entry, &config)
            })
            .collect();
        Ok(Self {
            config,
            source: source.into(),
            datasets,
            seed_origin,
            lists,
            psfs: Arc::new(specs.iter().map(|_| OnceLock::new()).collect()),
            specs: Arc::new(specs),
            inputs: Arc::new(inputs),
        })
    }

    /// Loads, overrides, validates and resolves a config file in one go.
    pub fn load(path: &Path, overrides: &[String]) -> Result<Self, PlanError> {
        Self::new(RawConfig::load(path, overrides)?, path)
    }

    /// A plan from JSON text and `--set` overrides, as if the text were the
    /// file `source` (relative input paths resolve against its directory):
    /// for tests, examples and benchmarks that make a config in code.
    pub fn from_json(json: &str, source: &Path, overrides: &[&str]) -> Result<Self, PlanError> {
        let overrides: Vec<String> = overrides.iter().map(|s| (*s).to_owned()).collect();
        Self::new(RawConfig::parse(json, source, &overrides)?, source)
    }

    /// The same plan with master seed `seed` (the origin is kept: adopting
    /// the seed of an existing run does not make it public).
    pub fn with_seed(&self, seed: u64) -> Self {
        let mut p = self.clone();
        p.config.run.seed = Some(seed);
        p.datasets = challenge_datasets(&p.config);
        p
    }

    /// The seed written in a resolved config's JSON (`RUN/private/config.json`
    /// of a run; `path` names it in nothing but parse errors), or `None`
    /// when the text is not a config or gives no seed.
    pub fn seed_written_in(json: &str, path: &Path) -> Option<u64> {
        RawConfig::parse(json, path, &[]).ok()?.run.seed
    }

    /// The config file the plan came from.
    pub fn source(&self) -> &Path {
        &self.source
    }

    /// Every PSF × shear pair, PSF-major.
    pub fn datasets(&self) -> &[Dataset] {
        &self.datasets
    }

    /// Whether the seed was given or drawn by [`Plan::new`].
    pub fn seed_origin(&self) -> SeedOrigin {
        self.seed_origin
    }

    /// Master seed ([`Plan::new`] always sets one).
    pub fn seed(&self) -> u64 {
        self.config.run.seed.unwrap_or_default()
    }

    /// Number of base fields (images per dataset).
    pub fn n_fields(&self) -> u32 {
        self.config.image.n_images
    }

    /// Number of images in the run (every dataset's fields, twins included).
    pub fn n_images_in_run(&self) -> u64 {
        let twins = 1 + u64::from(self.config.population.rotated_pairs);
        self.datasets
            .iter()
            .map(|d| d.fields.len() as u64)
            .sum::<u64>()
            * twins
    }

    /// The run's name (`run.name`).
    pub fn run_name(&self) -> &str {
        &self.config.run.name
    }

    /// The resolved config as pretty JSON (defaults, overrides and the seed
    /// filled in; paths as written): `RUN/private/config.json` holds it.
    pub fn config_json(&self) -> String {
        self.config.to_json()
    }

    /// The resolved config of a run, `RUN/private/config.json`:
    /// [`Plan::config_json`] with every input path naming the run's copy of
    /// that input ([`Plan::run_inputs`], relative to `RUN/private/`, where
    /// the config lives). It therefore reproduces the run from any working
    /// directory and on any machine, reads the very bytes the run was made
    /// with, and does not depend on where the inputs were: the same config
    /// and inputs give the same `private/config.json` (and so the same
    /// blinding key) wherever they lie. A config without input files is
    /// [`Plan::config_json`] itself.
    pub fn run_config_json(&self) -> String {
        let mut c = self.config.clone();
        if let Source::SkymakerList { path } = &mut c.population.source {
            *path = run_list_pattern();
        }
        for (index, p) in c.psfs.iter_mut().enumerate() {
            if let RawPsfModel::Fits { path, .. } = &mut p.model {
                *path = run_psf_path(index);
            }
        }
        c.to_json()
    }

    /// The input files the plan read (SkyMaker lists in field order, then
    /// the images of `fits` PSFs in config order), each with the name of
    /// the copy a run keeps under `RUN/private/` ([`Plan::run_config_json`]
    /// names them).
    pub fn run_inputs(&self) -> &[RunInput] {
        &self.inputs
    }

    /// [`Plan::config_json`] as the user gave it: with the seed when the
    /// config (or a `--set`) gave one, without it when [`Plan::new`] drew it.
    pub fn config_json_as_given(&self) -> String {
        let mut c = self.config.clone();
        if self.seed_origin == SeedOrigin::Drawn {
            c.run.seed = None;
        }
        c.to_json()
    }

    /// The geometry of every image (size, pixel scale, sky position).
    pub fn geometry(&self) -> Geometry {
        let im = &self.config.image;
        Geometry {
            width_px: im.width_px,
            height_px: im.height_px,
            pixel_scale_arcsec: im.pixel_scale_arcsec,
            ra_deg: im.field_ra_deg,
            dec_deg: im.field_dec_deg,
        }
    }

    /// Image pixel scale (arcsec).
    pub fn pixel_scale_arcsec(&self) -> f64 {
        self.config.image.pixel_scale_arcsec
    }

    /// Detector, sky and exposure.
    pub fn instrument(&self) -> &Instrument {
        &self.config.instrument
    }

    /// The telescope the optical PSFs are computed for.
    pub fn telescope(&self) -> &Telescope {
        &self.config.telescope
    }

    /// The galaxy model of a drawn population (`source = stuff`).
    pub fn galaxies(&self) -> &GalaxySpec {
        &self.config.population.galaxies
    }

    /// The stars of a drawn population.
    pub fn stars(&self) -> &StarSpec {
        &self.config.population.stars
    }

    /// Everything the base fields are drawn from (or, for
    /// `source = skymaker_list`, the lists they are made of), for
    /// [`crate::model::population::base_field`] and the other population functions.
    pub fn population(&self) -> PopulationSpec {
        PopulationSpec {
            seed: self.seed(),
            n_fields: self.n_fields(),
            galaxies: self.galaxies().clone(),
            stars: self.stars().clone(),
            cosmology: self.cosmology().clone(),
            instrument: self.instrument().clone(),
            wcs: self.image_wcs(),
            placement: self.placement_area(),
            lensing_centre: self.lensing_centre(),
            lens_positions: self.lens_positions(),
            rotate_positions: self.config.population.rotate_positions,
            pixel_scale_arcsec: self.pixel_scale_arcsec(),
            shears: self.datasets.iter().map(|d| (d.g1, d.g2)).collect(),
            lists: self.lists.clone(),
        }
    }

    /// The cosmology of the galaxy model.
    pub fn cosmology(&self) -> &Cosmology {
        &self.config.population.cosmology
    }

    /// Whether the base fields come from SkyMaker lists
    /// ([`Plan::skymaker_list`]) rather than from the galaxy and star models.
    pub fn reads_skymaker_lists(&self) -> bool {
        matches!(self.config.population.source, Source::SkymakerList { .. })
    }

    /// Whether every base field also exists with its galaxies turned by 90°
    /// (`population.rotated_pairs`).
    pub fn rotated_pairs(&self) -> bool {
        self.config.population.rotated_pairs
    }

    /// Whether the galaxies' positions are lensed by the dataset's shear
    /// (`population.lens_positions`).
    pub fn lens_positions(&self) -> bool {
        self.config.population.lens_positions
    }

    /// What gets written.
    pub fn output(&self) -> Output {
        let o = &self.config.output;
        Output {
            noise: o.noise,
            write_model: o.write_model,
            write_psf: o.write_psf,
            format: o.format,
            compression: o.compression,
        }
    }

    /// Number of PSFs (dataset `psf` indices are below it).
    pub fn n_psfs(&self) -> usize {
        self.specs.len()
    }

    /// The name of PSF `index`.
    ///
    /// # Panics
    /// When `index` is not a PSF of the plan (a dataset's `psf` always is).
    pub fn psf_name(&self, index: usize) -> &str {
        &self.specs[index].name
    }

    /// The PSF names, in config order.
    pub fn psf_names(&self) -> Vec<&str> {
        self.specs.iter().map(|p| p.name.as_str()).collect()
    }

    /// The applied shears, in config order (dataset `shear` indices point
    /// here).
    pub fn shears(&self) -> Vec<Shear> {
        self.config
            .shears
            .iter()
            .map(|s| Shear { g1: s.g1, g2: s.g2 })
            .collect()
    }

    /// The detector of every image: the instrument at the image pixel scale.
    pub fn detector(&self) -> Detector {
        Detector::new(&self.config.instrument, self.pixel_scale_arcsec())
    }

    /// The renderer's tolerances (the `render` section).
    pub fn accuracy(&self) -> Accuracy {
        let r = &self.config.render;
        Accuracy {
            folding_threshold: r.folding_threshold,
            kvalue_threshold: r.maxk_threshold,
            edge_sky_sigma: r.edge_sky_sigma,
            max_stamp_px: r.max_stamp_px as usize,
            method: r.method,
            ..Accuracy::default()
        }
    }

    /// The TAN WCS of every image (one for all base fields: see
    /// [`crate::model::wcs`]).
    pub fn image_wcs(&self) -> TanWcs {
        TanWcs::of_images(&self.geometry())
    }

    /// Where objects are placed: the image plus `image.margin_arcsec` on
    /// every side.
    pub fn placement_area(&self) -> Placement {
        let im = &self.config.image;
        let m_px = im.margin_arcsec / im.pixel_scale_arcsec;
        let x_px = (0.5 - m_px, f64::from(im.width_px) + 0.5 + m_px);
        let y_px = (0.5 - m_px, f64::from(im.height_px) + 0.5 + m_px);
        let s = im.pixel_scale_arcsec / 60.0;
        Placement {
            area_arcmin2: (x_px.1 - x_px.0) * (y_px.1 - y_px.0) * s * s,
            x_px,
            y_px,
        }
    }

    /// The centre of the image in FITS pixels, ((W + 1)/2, (H + 1)/2): the
    /// point about which `population.lens_positions` lenses positions.
    pub fn lensing_centre(&self) -> (f64, f64) {
        let im = &self.config.image;
        (
            (f64::from(im.width_px) + 1.0) / 2.0,
            (f64::from(im.height_px) + 1.0) / 2.0,
        )
    }

    /// Everything PSF `index` is built from ([`crate::model::psf::build`]), with
    /// the image a `fits` model names, read once by [`Plan::new`].
    ///
    /// # Panics
    /// When `index` is not a PSF of the plan (a dataset's `psf` always is).
    pub fn psf_spec(&self, index: usize) -> PsfSpec {
        self.specs[index].clone()
    }

    /// PSF `index`, built from [`Plan::psf_spec`] the first time it is asked
    /// for and then handed out again: the plan owns its PSFs, so a process
    /// builds each once (two threads asking at once may both build it; the
    /// first kept is handed out, and both are the same PSF).
    pub fn psf(&self, index: usize) -> Result<Arc<dyn Psf>, PsfError> {
        let slot = &self.psfs[index];
        if let Some(p) = slot.get() {
            return Ok(p.clone());
        }
        let built = crate::model::psf::build(&self.psf_spec(index))?;
        Ok(slot.get_or_init(|| built).clone())
    }

    /// [`Plan::psf`], taken from (or, when built, put into) the store
    /// `dir` of a run (`RUN/private/psf/cache`, see [`crate::io::psf_store`]),
    /// or copied there from the user's store ([`crate::io::psf_store::user_store_dir`]):
    /// the second value says how it came (`None`: the plan already held it).
    pub fn psf_in_store(
        &self,
        index: usize,
        dir: &Path,
    ) -> Result<
        (Arc<dyn Psf>, Option<crate::io::psf_store::Origin>),
        crate::io::psf_store::StoreError,
    > {
        let slot = &self.psfs[index];
        if let Some(p) = slot.get() {
            return Ok((p.clone(), None));
        }
        let accuracy = crate::model::psf::PsfAccuracy::default();
        let user = crate::io::psf_store::user_store_dir();
        let spec = self.psf_spec(index);
        let (built, origin) =
            crate::io::psf_store::load_or_build_shared(&spec, &accuracy, dir, user.as_deref())?;
        // The transfers the first image's renderer will ask for, from the
        // user's store when it has them.
        let geometry = self.geometry();
        let grids = crate::model::render::split::transfer_grids(
            built.as_ref(),
            self.pixel_scale_arcsec(),
            &self.accuracy(),
            geometry.width_px.max(geometry.height_px) as usize,
        );
        crate::io::psf_store::provide_transfers(
            built.as_ref(),
            &spec,
            &accuracy,
            &grids,
            user.as_deref(),
        );
        Ok((slot.get_or_init(|| built).clone(), Some(origin)))
    }

    /// The renderer of PSF `index` for this plan's images: its PSF
    /// ([`Plan::psf`]), pixel scale, accuracy and the detector's sky noise.
    pub fn renderer(&self, index: usize) -> Result<Renderer, PsfError> {
        Ok(Renderer::new(
            self.psf(index)?,
            self.pixel_scale_arcsec(),
            self.accuracy(),
            self.detector().sky_sigma_e(),
        ))
    }

    /// [`Plan::psf_spec`] of every PSF, in config order.
    pub fn psf_specs(&self) -> &[PsfSpec] {
        &self.specs
    }

    /// The objects of base field `field`'s SkyMaker list, read once by
    /// [`Plan::new`]; `None` when the population is drawn (`source = stuff`)
    /// or `field` is not a base field of the plan.
    pub fn skymaker_list(&self, field: u32) -> Option<&[ListObject]> {
        crate::model::population::list_of(self.lists.as_deref().map(Vec::as_slice), field)
    }
}

/// What the plan's writers are asked to write (the `output` section).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Output {
    /// Add photon and read noise (false: noise-free images with sky).
    pub noise: bool,
    /// Also write the noise-free model beside each noisy image (private).
    pub write_model: bool,
    /// Write the PSF images into the private half.
    pub write_psf: bool,
    /// Pixel type of the images.
    pub format: SampleFormat,
    /// Compression of the images.
    pub compression: Compression,
}

/// One applied shear of the configured design.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shear {
    /// g1.
    pub g1: f64,
    /// g2.
    pub g2: f64,
}

/// The model's spec of PSF entry `entry` of a validated `config` (no
/// image: [`Plan::new`] adds the file's for a `fits` model).
fn psf_spec_of(entry: &RawPsf, config: &RawConfig) -> PsfSpec {
    let model = match &entry.model {
        RawPsfModel::Optical {
            aberration,
            amplitude,
            target_chi,
            angle_deg,
        } => PsfModel::Optical {
            aberration: *aberration,
            amplitude: *amplitude,
            target_chi: *target_chi,
            angle_deg: *angle_deg,
        },
        RawPsfModel::Gaussian { e1, e2 } => PsfModel::Gaussian { e1: *e1, e2: *e2 },
        RawPsfModel::Moffat { beta, trunc_fwhm } => PsfModel::Moffat {
            beta: *beta,
            trunc_fwhm: *trunc_fwhm,
        },
        RawPsfModel::Fits {
            path,
            pixel_scale_arcsec,
        } => PsfModel::Fits {
            path: path.clone(),
            pixel_scale_arcsec: *pixel_scale_arcsec,
        },
    };
    PsfSpec::new(
        &entry.name,
        entry.fwhm_arcsec,
        model,
        config.telescope.clone(),
        config.image.pixel_scale_arcsec,
    )
}

/// `path` resolved against the directory of the config file `config`
/// (absolute paths stay).
fn resolve(config: &Path, path: &Path) -> PathBuf {
    if path.is_relative() {
        config
            .parent()
            .map(|d| d.join(path))
            .unwrap_or_else(|| path.into())
    } else {
        path.into()
    }
}

/// The list file of field `field` for the path pattern `pattern`
/// (`{field}` replaced by the field number), resolved against the config's
/// directory.
pub fn list_path(config: &Path, pattern: &str, field: u32) -> PathBuf {
    resolve(
        config,
        Path::new(&pattern.replace("{field}", &field.to_string())),
    )
}

/// The sky alone must stay below the clip level, or every pixel of every
/// image is the saturation value (a blank image).
fn check_sky_below_saturation(raw: &RawConfig) -> Result<(), Invalid> {
    let ins = &raw.instrument;
    let sky_adu = sky_e_per_pixel(ins, raw.image.pixel_scale_arcsec) / ins.gain_e_per_adu;
    if sky_adu.is_finite() && sky_adu < ins.saturation_adu {
        return Ok(());
    }
    Err(Invalid::new(
        "instrument".into(),
        format!(
            "the sky alone gives {sky_adu:.4e} ADU per pixel, at or above instrument.saturation_adu = {}: every pixel would be clipped (a blank image); lower instrument.exposure_s or image.pixel_scale_arcsec, or raise instrument.sky_mag_arcsec2 or instrument.gain_e_per_adu",
            ins.saturation_adu
        ),
    ))
}

/// The datasets of a validated config with its seed set: PSF × shear on
/// the public fields, then (with `challenge.holdout_fields`) PSF × slot on
/// the held-out fields with drawn shears.
fn challenge_datasets(config: &RawConfig) -> Vec<Dataset> {
    let seed = config.run.seed.unwrap_or_default();
    let n_fields = config.image.n_images;
    let n_shears = config.shears.len();
    let n_psfs = config.psfs.len();
    let held = holdout_fields(seed, n_fields, config.challenge.holdout_fields);
    let public: Vec<u32> = (0..n_fields).filter(|f| !held.contains(f)).collect();
    let pairs = || (0..n_psfs).flat_map(move |p| (0..n_shears).map(move |s| (p, s)));
    let mut out: Vec<Dataset> = pairs()
        .map(|(psf, shear)| Dataset {
            index: (psf * n_shears + shear) as u32,
            psf,
            shear,
            part: Part::Public,
            fields: public.clone(),
            g1: config.shears[shear].g1,
            g2: config.shears[shear].g2,
        })
        .collect();
    if !held.is_empty() {
        let g_max = config.challenge.holdout_g_max;
        out.extend(pairs().map(|(psf, slot)| {
            let index = (n_psfs * n_shears + psf * n_shears + slot) as u32;
            let (g1, g2) = holdout_shear(seed, index, g_max);
            Dataset {
                index,
                psf,
                shear: slot,
                part: Part::Holdout,
                fields: held.clone(),
                g1,
                g2,
            }
        }));
    }
    out
}

/// The base fields held out: `n_held` of `0..n_fields`, chosen by a keyed
/// order (stream [`Stream::Holdout`] per field), not by position, so that
/// nothing about a field's index tells its part. Ascending.
pub fn holdout_fields(seed: u64, n_fields: u32, n_held: u32) -> Vec<u32> {
    let mut order: Vec<(u64, u32)> = (0..n_fields)
        .map(|f| (SeedKey::base(seed, f, Stream::Holdout).seed(), f))
        .collect();
    order.sort_unstable();
    let mut held: Vec<u32> = order
        .into_iter()
        .take(n_held as usize)
        .map(|(_, f)| f)
        .collect();
    held.sort_unstable();
    held
}

/// The shear of held-out dataset `index`: uniform in the disc |g| ≤ `g_max`
/// (radius g_max·√u, angle 2πv), from the keyed stream
/// `SeedKey::image(seed, 0, index, Stream::Holdout)`.
pub fn holdout_shear(seed: u64, index: u32, g_max: f64) -> (f64, f64) {
    use rand::RngExt;
    let mut rng = SeedKey::image(seed, 0, index, Stream::Holdout).rng();
    let u: f64 = rng.random();
    let v: f64 = rng.random();
    let r = g_max * u.sqrt();
    let phi = std::f64::consts::TAU * v;
    (r * phi.cos(), r * phi.sin())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<RawConfig, ConfigError> {
        RawConfig::parse(text, Path::new("test.json"), &[])
    }

    #[test]
    fn empty_object_gives_step1_defaults() {
        let raw = parse("{}").unwrap();
        assert_eq!(raw, RawConfig::default());
        let plan = Plan::new(raw, Path::new("test.json")).unwrap();
        assert_eq!(plan.datasets().len(), 30);
        assert_eq!(plan.datasets()[7].psf, 1);
        assert_eq!(plan.datasets()[7].shear, 2);
        assert_eq!(plan.datasets()[7].g1, 0.01);
    }

    #[test]
    fn a_list_named_by_every_field_is_read_once_and_shared() {
        let tmp = tempfile::tempdir().unwrap();
        let one = "100 10.0 20.0 21.5\n200 30.0 40.0 23.0 0.2 0.5 0.8 10 1.0 0.6 10\n";
        std::fs::write(tmp.path().join("all.list"), one).unwrap();
        std::fs::write(tmp.path().join("f0.list"), one).unwrap();
        std::fs::write(tmp.path().join("f1.list"), "100 5.0 6.0 22.0\n").unwrap();
        let config = tmp.path().join("c.json");
        let plan_of = |pattern: &str| {
            let source = format!(r#"population.source={{"skymaker_list":{{"path":"{pattern}"}}}}"#);
            Plan::from_json("{}", &config, &[&source, "image.n_images=3"]).unwrap()
        };
        // One file for every field: parsed once, the same objects and bytes.
        let plan = plan_of("all.list");
        let lists = plan.lists.as_ref().unwrap();
        assert_eq!(lists.len(), 3);
        assert!(Arc::ptr_eq(&lists[0], &lists[1]) && Arc::ptr_eq(&lists[0], &lists[2]));
        assert_eq!(plan.skymaker_list(2).unwrap().len(), 2);
        let inputs = plan.run_inputs();
        assert_eq!(inputs.len(), 3);
        assert!(
            inputs
                .iter()
                .all(|i| Arc::ptr_eq(&i.bytes, &inputs[0].bytes))
        );
        assert_ne!(inputs[0].name, inputs[1].name);
        // A file per field: each its own.
        std::fs::write(tmp.path().join("f2.list"), "100 7.0 8.0 22.0\n").unwrap();
        let plan = plan_of("f{field}.list");
        let lists = plan.lists.as_ref().unwrap();
        assert!(!Arc::ptr_eq(&lists[0], &lists[1]));
        assert_eq!(
            (0..3)
                .map(|f| plan.skymaker_list(f).unwrap().len())
                .collect::<Vec<_>>(),
            [2, 1, 1]
        );
    }

    #[test]
    fn the_plan_owns_its_psfs_and_nothing_else_caches_them() {
        let plan = Plan::from_json(
            "{}",
            Path::new("t.json"),
            &[r#"psfs=[{"name":"g","model":"gaussian","fwhm_arcsec":0.9},{"name":"m","model":"moffat","fwhm_arcsec":0.8,"beta":3.0}]"#],
        )
        .unwrap();
        let a = plan.psf(1).unwrap();
        // Asked again, or by a clone of the plan: the same PSF, not a rebuild.
        assert!(Arc::ptr_eq(&a, &plan.psf(1).unwrap()));
        assert!(Arc::ptr_eq(&a, &plan.with_seed(7).psf(1).unwrap()));
        assert!(!Arc::ptr_eq(&a, &plan.psf(0).unwrap()));
        // No hidden process-wide cache: building from the spec makes a new
        // PSF each time (equal in value).
        let (b, c) = (
            crate::model::psf::build(&plan.psf_spec(1)).unwrap(),
            crate::model::psf::build(&plan.psf_spec(1)).unwrap(),
        );
        assert!(!Arc::ptr_eq(&b, &c) && !Arc::ptr_eq(&a, &b));
        assert_eq!(format!("{b:?}"), format!("{c:?}"));
        // Another plan of the same config owns its own.
        let other = Plan::from_json("{}", Path::new("t.json"), &[r#"psfs=[{"name":"g","model":"gaussian","fwhm_arcsec":0.9},{"name":"m","model":"moffat","fwhm_arcsec":0.8,"beta":3.0}]"#]).unwrap();
        assert!(!Arc::ptr_eq(&a, &other.psf(1).unwrap()));
    }

    #[test]
    fn psf_specs_spell_their_entry_as_the_config_does() {
        // The PSF store's key hashes the entry's JSON (io::psf_store::spec_digest):
        // the spec's must be the config entry's, byte for byte, or every
        // stored PSF would be orphaned.
        let plan = Plan::from_json(
            "{}",
            Path::new("t.json"),
            &[r#"psfs=[{"name":"o","model":"optical","aberration":"trefoil","amplitude":0.2,"angle_deg":12.5},{"name":"c","model":"optical","aberration":"coma","target_chi":0.03,"fwhm_arcsec":1.1},{"name":"g","model":"gaussian","e1":0.1},{"name":"m","model":"moffat","beta":3.0,"trunc_fwhm":4.0}]"#],
        )
        .unwrap();
        let step1 = Plan::from_json("{}", Path::new("t.json"), &[]).unwrap();
        for p in [&plan, &step1] {
            assert_eq!(p.n_psfs(), p.config.psfs.len());
            for (spec, entry) in p.psf_specs().iter().zip(&p.config.psfs) {
                assert_eq!(spec.entry_json(), serde_json::to_string(entry).unwrap());
                assert_eq!(
                    serde_json::to_string(&spec.telescope).unwrap(),
                    serde_json::to_string(&p.config.telescope).unwrap()
                );
                assert_eq!(spec.pixel_scale_arcsec, 0.206);
            }
        }
        assert_eq!(step1.psf_spec(1), PsfSpec::step1(1, 0.206));
        assert_eq!(plan.psf_name(3), "m");
        assert!(plan.psf_spec(1).is_optical() && !plan.psf_spec(2).is_optical());
    }

    #[test]
    fn the_models_get_the_sections_values() {
        let plan = Plan::from_json(
            "{}",
            Path::new("t.json"),
            &[
                r#"render={"folding_threshold":1e-3,"maxk_threshold":2e-3,"edge_sky_sigma":0.5,"max_stamp_px":256,"method":"stamp"}"#,
                "image.width_px=300",
                "image.height_px=200",
                "image.field_ra_deg=10",
                "image.field_dec_deg=-5",
                "population.rotated_pairs=true",
            ],
        )
        .unwrap();
        let acc = plan.accuracy();
        assert_eq!(
            acc,
            Accuracy {
                folding_threshold: 1e-3,
                kvalue_threshold: 2e-3,
                edge_sky_sigma: 0.5,
                max_stamp_px: 256,
                min_stamp_px: 16,
                method: crate::model::render::Method::Stamp,
            }
        );
        // The defaults are the renderer's own.
        let step1 = Plan::from_json("{}", Path::new("t.json"), &[]).unwrap();
        assert_eq!(step1.accuracy(), Accuracy::default());
        let g = plan.geometry();
        assert_eq!(
            (
                g.width_px,
                g.height_px,
                g.pixel_scale_arcsec,
                g.ra_deg,
                g.dec_deg
            ),
            (300, 200, 0.206, 10.0, -5.0)
        );
        assert_eq!(step1.geometry(), Geometry::step1());
        let pop = plan.population();
        assert_eq!(pop.seed, plan.seed());
        assert_eq!(pop.placement, plan.placement_area());
        assert_eq!(pop.shears.len(), plan.datasets().len());
        assert!(!pop.reads_skymaker_lists() && plan.rotated_pairs());
    }

    #[test]
    fn out_of_range_values_name_the_key() {
        let raw = RawConfig::parse("{}", Path::new("t.json"), &["shears.0.g1=1.5".into()]).unwrap();
        let err = Plan::new(raw, Path::new("t.json")).unwrap_err().to_string();
        assert!(err.contains("shears.0"), "{err}");
        let raw = RawConfig::parse(
            "{}",
            Path::new("t.json"),
            &["image.pixel_scale_arcsec=-1".into()],
        )
        .unwrap();
        let err = Plan::new(raw, Path::new("t.json")).unwrap_err().to_string();
        assert!(err.contains("image.pixel_scale_arcsec"), "{err}");
    }

    #[test]
    fn a_config_without_seed_gets_a_fresh_one_and_records_it() {
        let raw = parse("{}").unwrap();
        assert_eq!(raw.run.seed, None);
        assert!(!raw.to_json().contains("seed"), "no seed key when absent");
        let a = Plan::new(raw.clone(), Path::new("t.json")).unwrap();
        let b = Plan::new(raw, Path::new("t.json")).unwrap();
        assert_eq!(
            (a.seed_origin(), b.seed_origin()),
            (SeedOrigin::Drawn, SeedOrigin::Drawn)
        );
        assert_eq!(a.config.run.seed, Some(a.seed()));
        // 64 bits from the OS: two draws agreeing would be a broken source.
        assert_ne!(a.seed(), b.seed());
        assert!(a.config_json().contains(&format!("\"seed\": {}", a.seed())));
        // The resolved JSON gives the same seed back, now as given.
        let again = Plan::new(parse(&a.config_json()).unwrap(), Path::new("c.json")).unwrap();
        assert_eq!(
            (again.seed(), again.seed_origin()),
            (a.seed(), SeedOrigin::Config)
        );
        let given = parse("{\"run\": {\"seed\": 7}}").unwrap();
        let p = Plan::new(given, Path::new("t.json")).unwrap();
        assert_eq!((p.seed(), p.seed_origin()), (7, SeedOrigin::Config));
        assert_eq!(p.with_seed(9).seed(), 9);
    }

    /// A config file in `dir` with the given JSON body.
    fn config_in(dir: &Path, body: &str) -> PathBuf {
        let path = dir.join("config.json");
        std::fs::write(&path, body).unwrap();
        path
    }

    #[test]
    fn a_fits_psf_is_found_beside_the_config_and_read_once() {
        use crate::io::psf_fits::{PsfImage, write_psf_fits};
        let dir = tempfile::tempdir().unwrap();
        // A round Gaussian, σ = 4 samples of 0.05″, on 41².
        let n = 41;
        let values: Vec<f64> = (0..n * n)
            .map(|k| {
                let (x, y) = ((k % n) as f64 - 20.0, (k / n) as f64 - 20.0);
                (-(x * x + y * y) / 32.0).exp()
            })
            .collect();
        let image = PsfImage {
            data: &values,
            n,
            scale_arcsec: 0.05,
        };
        std::fs::create_dir(dir.path().join("psfs")).unwrap();
        write_psf_fits(&dir.path().join("psfs/g.fits"), "g", image, image, 1, &[]).unwrap();
        let config = config_in(
            dir.path(),
            r#"{"psfs": [{"name": "g", "fwhm_arcsec": 0.47, "model": "fits",
                          "path": "psfs/g.fits", "pixel_scale_arcsec": 0.05}]}"#,
        );
        let plan = Plan::load(&config, &[]).unwrap();
        let spec = plan.psf_spec(0);
        let read = spec.image.as_ref().unwrap();
        assert_eq!((read.nx, read.ny), (n, n));
        assert_eq!(read.path, dir.path().join("psfs/g.fits"));
        let with_file = crate::model::psf::build(&spec).unwrap();
        let r_with_file = crate::model::psf::Psf::radius_enclosing(with_file.as_ref(), 0.5);
        // Read once: the PSF builds from the plan's copy without the file,
        // and is the same PSF.
        std::fs::remove_dir_all(dir.path().join("psfs")).unwrap();
        let psf = crate::model::psf::build(&spec).unwrap();
        let r_half = crate::model::psf::Psf::radius_enclosing(psf.as_ref(), 0.5);
        assert_eq!(r_half, r_with_file);
        // σ = 0.2″: half the light within σ √(2 ln 2) = 0.2355″ before the
        // detector's pixel widens it (0.25″ measured).
        assert!((0.2355..0.27).contains(&r_half), "{r_half}");
        let err = Plan::load(&config, &[]).unwrap_err().to_string();
        assert!(
            err.contains("key `psfs.0.model.path` (psf g)") && err.contains("g.fits"),
            "{err}"
        );
    }
}
