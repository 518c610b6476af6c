//! What the population is drawn from ([`PopulationSpec`]): the galaxy model
//! ([`GalaxySpec`]: magnitudes, shapes, the six Hubble types, sizes,
//! redshifts), the stars ([`StarSpec`]), the cosmology ([`Cosmology`]),
//! where objects go ([`Placement`]) or the SkyMaker lists ([`ListObject`]).
//!
//! These are the model's own types, with its STEP1 defaults (sources in
//! `docs/population.md`). The config spells them exactly so
//! (`population.galaxies`, `population.stars`, `population.cosmology`): they
//! carry their serde derives here and the config imports them; the range
//! checks are the config's (ARCHITECTURE.md, "Configs in two layers").

use crate::model::noise::Instrument;
use crate::model::wcs::TanWcs;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Everything the base fields of a run are drawn from: the seed, the
/// models, where objects go on the images and, for a run made of SkyMaker
/// lists, the lists (made by the plan: `crate::run::plan::Plan::population`).
#[derive(Debug, Clone)]
pub struct PopulationSpec {
    /// The run's master seed.
    pub seed: u64,
    /// Number of base fields.
    pub n_fields: u32,
    /// The galaxy model.
    pub galaxies: GalaxySpec,
    /// The stars.
    pub stars: StarSpec,
    /// The cosmology of the galaxy model.
    pub cosmology: Cosmology,
    /// Magnitudes to electrons.
    pub instrument: Instrument,
    /// The images' WCS (the same for every base field).
    pub wcs: TanWcs,
    /// Where objects are placed: the image and its margin.
    pub placement: Placement,
    /// The point about which positions are lensed (the image centre, FITS
    /// pixels).
    pub lensing_centre: (f64, f64),
    /// Whether galaxy positions are lensed by the dataset's shear.
    pub lens_positions: bool,
    /// Whether the rotated twin turns the positions too, about
    /// `lensing_centre` ([`crate::model::population::twin`]).
    pub rotate_positions: bool,
    /// Image pixel scale (arcsec).
    pub pixel_scale_arcsec: f64,
    /// Every dataset's shear (g1, g2): lensed positions must cover the image
    /// for each.
    pub shears: Vec<(f64, f64)>,
    /// One list per base field when the objects come from SkyMaker lists
    /// (`None`: drawn from the models); fields that name the same file
    /// share its one copy.
    pub lists: Option<Arc<Vec<Arc<Vec<ListObject>>>>>,
}

impl PopulationSpec {
    /// Whether the base fields come from SkyMaker lists.
    pub fn reads_skymaker_lists(&self) -> bool {
        self.lists.is_some()
    }

    /// The objects of base field `field`'s list (`None`: no lists, or no
    /// such field).
    pub fn skymaker_list(&self, field: u32) -> Option<&[ListObject]> {
        list_of(self.lists.as_deref().map(Vec::as_slice), field)
    }
}

/// Base field `field`'s list among `lists` (one per base field), `None`
/// without lists or past the last field.
pub(crate) fn list_of(lists: Option<&[Arc<Vec<ListObject>>]>, field: u32) -> Option<&[ListObject]> {
    lists?.get(field as usize).map(|l| l.as_slice())
}

/// Where objects are placed: the image plus its margin.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    /// Area in arcmin².
    pub area_arcmin2: f64,
    /// x range in FITS pixels.
    pub x_px: (f64, f64),
    /// y range in FITS pixels.
    pub y_px: (f64, f64),
}

/// One object of a SkyMaker list, as written in the file (`crate::io::skymaker`
/// reads and writes the format).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ListObject {
    /// `100 x y mag`.
    Star {
        /// FITS x.
        x: f64,
        /// FITS y.
        y: f64,
        /// Magnitude.
        mag: f64,
    },
    /// `200 x y mag B/T bulge_re bulge_q bulge_pa disk_h disk_q disk_pa [z] [type]`.
    Galaxy {
        /// FITS x.
        x: f64,
        /// FITS y.
        y: f64,
        /// Magnitude.
        mag: f64,
        /// Bulge-to-total ratio.
        bt: f64,
        /// Bulge effective radius along the major axis (arcsec).
        bulge_re_arcsec: f64,
        /// Apparent bulge axis ratio.
        bulge_ba: f64,
        /// Bulge position angle (degrees).
        bulge_pa_deg: f64,
        /// Disk scale length along the major axis (arcsec).
        disk_h_arcsec: f64,
        /// Apparent disk axis ratio.
        disk_ba: f64,
        /// Disk position angle (degrees).
        disk_pa_deg: f64,
        /// Redshift, if given.
        z: Option<f64>,
        /// de Vaucouleurs T, if given.
        t_type: Option<f64>,
    },
}

/// Intrinsic bulge flattening law: normal, truncated by resampling.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Flattening {
    /// Mean (paper: 0.65).
    pub mean: f64,
    /// Standard deviation (paper: 0.18).
    pub sigma: f64,
    /// Lower truncation (paper: 0.3).
    pub min: f64,
    /// Upper truncation (paper: 1).
    pub max: f64,
}

impl Default for Flattening {
    fn default() -> Self {
        Self {
            mean: 0.65,
            sigma: 0.18,
            min: 0.3,
            max: 1.0,
        }
    }
}

/// Inclination law of the disks.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum InclinationLaw {
    /// Uniform in angle on [0, max_inclination_deg] (Stuff; STEP1 default).
    Flat,
    /// Isotropic orientations: cos i uniform on [cos max, 1].
    Isotropic,
}

/// The galaxy model (the config's `population.galaxies`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct GalaxySpec {
    /// Bright limit of the apparent I (Vega) magnitude.
    pub mag_bright: f64,
    /// Faint limit of the apparent I (Vega) magnitude.
    pub mag_faint: f64,
    /// Bulge intrinsic flattening.
    pub flattening: Flattening,
    /// Inclination law.
    pub inclination: InclinationLaw,
    /// Largest inclination (Stuff: 85°).
    pub max_inclination_deg: f64,
    /// The Hubble types E, S0, Sab, Sbc, Scd, Irr (exactly six, in this
    /// order): luminosity functions, B/T and colours.
    pub types: Vec<GalaxyType>,
    /// Every type's φ* is multiplied by this: the calibration of the model's
    /// I-band counts to the CFDF/Hawaii deep-field counts (see
    /// `docs/population.md`; Stuff's own defaults give ≈ 0.6× the observed
    /// counts at I ≈ 20 with this project's K-corrections).
    pub phi_star_scale: f64,
    /// Luminosity–size relations.
    pub sizes: Sizes,
    /// Bounds of every luminosity function, absolute B_J magnitude − 5 log10 h
    /// (Stuff `LF_MAGLIMITS`: −27, −13).
    pub abs_mag_limits: [f64; 2],
    /// Galaxies are placed at redshifts in (0, z_max] (the model has no
    /// Lyman break: keep z_max ≤ 5 so that I stays redward of Lyman α).
    pub z_max: f64,
}

/// One Hubble type of the Stuff-style model. Absolute magnitudes are in the
/// reference band B_J (Vega) and written as M − 5 log10 h; densities in
/// h³ Mpc⁻³ (Stuff's conventions). Sources in `docs/population.md`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct GalaxyType {
    /// Name (E, S0, Sab, Sbc, Scd, Irr).
    pub name: String,
    /// de Vaucouleurs T, written in SkyMaker lists (Stuff `HUBBLE_TYPE`).
    pub t_type: f64,
    /// Bulge-to-total flux ratio (Stuff `BULGE_FRACTION`).
    pub bt: f64,
    /// Schechter φ* at z = 0, h³ Mpc⁻³ (Stuff `LF_PHISTAR`).
    pub phi_star_h3_mpc3: f64,
    /// Schechter M* − 5 log10 h at z = 0, B_J Vega (Stuff `LF_MSTAR`).
    pub m_star: f64,
    /// Schechter faint-end slope α (Stuff `LF_ALPHA`).
    pub alpha: f64,
    /// d ln φ* / d ln(1+z) (Stuff `LF_PHISTAREVOL`).
    pub phi_star_evol: f64,
    /// d M* / d ln(1+z) (Stuff `LF_MSTAREVOL`).
    pub m_star_evol: f64,
    /// Rest-frame colour B − I (Vega) of the type; sets the optical slope of
    /// the power-law SED used for the K-correction.
    pub b_minus_i: f64,
    /// Slope s of the SED f_ν ∝ λ^s blueward of 4000 Å (the break).
    pub uv_slope: f64,
    /// Internal extinction of the disk, de Vaucouleurs' α: A_B(i) =
    /// α log10(sec i) (Stuff `DISK_EXTINCT`).
    pub disk_extinction: f64,
}

impl GalaxyType {
    #[allow(clippy::too_many_arguments)]
    fn new(
        name: &str,
        t_type: f64,
        bt: f64,
        phi_star_h3_mpc3: f64,
        m_star: f64,
        alpha: f64,
        phi_star_evol: f64,
        m_star_evol: f64,
        b_minus_i: f64,
        uv_slope: f64,
        disk_extinction: f64,
    ) -> Self {
        Self {
            name: name.into(),
            t_type,
            bt,
            phi_star_h3_mpc3,
            m_star,
            alpha,
            phi_star_evol,
            m_star_evol,
            b_minus_i,
            uv_slope,
            disk_extinction,
        }
    }

    /// The six types with Stuff's default parameters (B/T, LFs and their
    /// evolution) and this project's colours (see `docs/population.md`).
    pub fn stuff_defaults() -> Vec<Self> {
        vec![
            Self::new(
                "E", -6.0, 1.0, 4.95e-3, -19.58, -0.54, -1.7, -1.0, 2.27, 4.0, 0.0,
            ),
            Self::new(
                "S0", -2.0, 0.57, 4.95e-3, -19.58, -0.54, -1.7, -1.0, 2.15, 3.5, 0.75,
            ),
            Self::new(
                "Sab", 2.0, 0.32, 7.2e-3, -19.53, -0.99, -1.2, -1.0, 2.0, 2.5, 1.23,
            ),
            Self::new(
                "Sbc", 4.0, 0.16, 5.0e-3, -19.17, -1.24, -1.2, -1.0, 1.75, 1.5, 1.47,
            ),
            Self::new(
                "Scd", 6.0, 0.049, 1.2e-3, -19.15, -1.50, -1.2, -1.0, 1.45, 2.0, 1.47,
            ),
            Self::new(
                "Irr", 10.0, 0.0, 1.2e-3, -19.15, -1.50, 1.9, -1.5, 1.05, 2.5, 1.23,
            ),
        ]
    }
}

/// Luminosity–size relations (Stuff defaults; sources in `docs/population.md`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Sizes {
    /// Disk effective radius at L*, h⁻¹ kpc (de Jong & Lacey 2000; Stuff
    /// `DISK_RSTAR` 3.85). The scale length is this / 1.67835.
    pub disk_re_star_kpc_h: f64,
    /// Disk size–luminosity exponent β: h ∝ (L/L*)^(−β) (Stuff `DISK_BETA`).
    pub disk_beta: f64,
    /// Log-normal scatter σ of ln h (Stuff `DISK_SIGMAL`).
    pub disk_sigma_ln: f64,
    /// d ln h / d ln(1+z) (Stuff `DISK_REVOL`).
    pub disk_evol: f64,
    /// Absolute magnitude of the knee, M − 5 log10 h (Stuff `SPHEROID_MKNEE`).
    pub bulge_m_knee: f64,
    /// Bulge effective radius at the knee, h⁻¹ kpc (Stuff `SPHEROID_RKNEE`).
    pub bulge_re_knee_kpc_h: f64,
    /// d ln r_e / d ln(1+z) (Stuff `SPHEROID_REVOL`).
    pub bulge_evol: f64,
}

impl Default for Sizes {
    fn default() -> Self {
        Self {
            disk_re_star_kpc_h: 3.85,
            disk_beta: -0.214,
            disk_sigma_ln: 0.36,
            disk_evol: -0.4,
            bulge_m_knee: -20.0,
            bulge_re_knee_kpc_h: 1.58,
            bulge_evol: -0.5,
        }
    }
}

impl Default for GalaxySpec {
    fn default() -> Self {
        Self {
            mag_bright: 17.0,
            mag_faint: 26.0,
            flattening: Flattening::default(),
            inclination: InclinationLaw::Flat,
            max_inclination_deg: 85.0,
            types: GalaxyType::stuff_defaults(),
            phi_star_scale: 1.5,
            sizes: Sizes::default(),
            abs_mag_limits: [-27.0, -13.0],
            z_max: 5.0,
        }
    }
}

/// The stars (the config's `population.stars`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct StarSpec {
    /// Stars per arcmin² between the bright and the faint limit.
    pub density_per_arcmin2: f64,
    /// d log10 N / dm of the differential counts (paper: 0.3).
    pub slope: f64,
    /// Bright limit (I, Vega).
    pub mag_bright: f64,
    /// Faint limit (paper: 25).
    pub mag_faint: f64,
}

impl Default for StarSpec {
    fn default() -> Self {
        Self {
            density_per_arcmin2: 10.0,
            slope: 0.3,
            mag_bright: 17.0,
            mag_faint: 25.0,
        }
    }
}

/// Flat or curved ΛCDM (the config's `population.cosmology`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Cosmology {
    /// Hubble constant, km s⁻¹ Mpc⁻¹.
    pub h0: f64,
    /// Matter density.
    pub omega_m: f64,
    /// Dark energy density.
    pub omega_lambda: f64,
}

impl Default for Cosmology {
    fn default() -> Self {
        Self {
            h0: 70.0,
            omega_m: 0.3,
            omega_lambda: 0.7,
        }
    }
}
