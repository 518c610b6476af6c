//! Synthetic runs with an exactly known answer, for the harness's tests, the
//! command-line tests and the benchmark (not used when scoring).
//!
//! Each base field holds galaxies on a jittered grid (so that matching is
//! unambiguous) and stars between them. Intrinsic shapes come in *rings*:
//! `ring_size` galaxies with one |e| and position angles spread evenly over
//! [0, π), so that the mean sheared ellipticity of a ring is the shear itself
//! (eq. 8 is holomorphic in e_s) up to terms of order (|g||e|)^ring_size.
//! With `shape_noise` the shapes are drawn independently instead.

use rand::{RngExt, SeedableRng};
use std::path::Path;
use stepsim_contract::run_dir::PrivateDir;
use stepsim_contract::run_layout::{DATASETS_FORMAT, DatasetEntry, DatasetImage, Datasets, Part};
use stepsim_contract::seed::{SimRng, splitmix64};
use stepsim_contract::truth::{KIND_GALAXY, KIND_STAR, TruthRow};
use stepsim_harness::{DatasetMeta, HarnessError, ImageIndex, ImageStats, SubRow, match_image};

/// What to build.
#[derive(Debug, Clone)]
pub struct SynthSpec {
    /// PSF (id, name) pairs.
    pub psfs: Vec<(u32, String)>,
    /// Shears (g1, g2), the same for every PSF.
    pub shears: Vec<(f64, f64)>,
    /// Base fields (= images per dataset).
    pub n_fields: u32,
    /// Image size.
    pub width_px: u32,
    /// Image size.
    pub height_px: u32,
    /// Pixel scale.
    pub pixel_scale_arcsec: f64,
    /// Grid spacing of the galaxies in pixels (≥ 4 × the match radius).
    pub spacing_px: f64,
    /// Galaxies per ring.
    pub ring_size: usize,
    /// Fraction of grid cells holding a star instead of a galaxy.
    pub star_fraction: f64,
    /// Independent random shapes instead of rings.
    pub shape_noise: bool,
    /// Every base field also appears as its 90°-rotated twin (each galaxy's
    /// intrinsic ellipticity negated, positions unchanged), as with
    /// `population.rotated_pairs`.
    pub rotated_pairs: bool,
    /// Seed.
    pub seed: u64,
}

impl SynthSpec {
    /// A small run: 6 PSFs × 5 STEP1 shears × `n_fields` images of 300².
    pub fn small(n_fields: u32) -> Self {
        Self {
            psfs: ["none", "coma", "jitter", "defocus", "astig", "trefoil"]
                .iter()
                .enumerate()
                .map(|(i, n)| (i as u32, (*n).to_owned()))
                .collect(),
            shears: vec![
                (0.0, 0.0),
                (0.005, 0.0),
                (0.01, 0.0),
                (0.05, 0.0),
                (0.1, 0.0),
            ],
            n_fields,
            width_px: 300,
            height_px: 300,
            pixel_scale_arcsec: 0.2,
            spacing_px: 20.0,
            ring_size: 8,
            star_fraction: 0.1,
            shape_noise: false,
            rotated_pairs: false,
            seed: 1,
        }
    }
}

/// A submission rule: (truth row, dataset index) -> (e1, e2, weight), or
/// `None` to leave the object out.
pub type Rule<'a> = dyn Fn(&TruthRow, usize) -> Option<(f64, f64, f64)> + 'a;

/// A run in memory.
#[derive(Debug, Clone)]
pub struct SynthRun {
    /// `datasets.json`.
    pub datasets: Datasets,
    /// The truth table of every image, in [`ImageIndex`] order.
    pub truth: Vec<Vec<TruthRow>>,
}

fn shear(es: (f64, f64), g: (f64, f64)) -> (f64, f64) {
    // e = (e_s + g) / (1 + g* e_s), complex.
    let (num_r, num_i) = (es.0 + g.0, es.1 + g.1);
    let (den_r, den_i) = (1.0 + g.0 * es.0 + g.1 * es.1, g.0 * es.1 - g.1 * es.0);
    let d = den_r * den_r + den_i * den_i;
    (
        (num_r * den_r + num_i * den_i) / d,
        (num_i * den_r - num_r * den_i) / d,
    )
}

/// The unsheared objects of base field `field`.
pub fn base_field(spec: &SynthSpec, field: u32) -> Vec<TruthRow> {
    let mut rng = SimRng::seed_from_u64(splitmix64(spec.seed ^ splitmix64(u64::from(field) + 1)));
    let mut rows = Vec::new();
    let nx = ((f64::from(spec.width_px) - 4.0) / spec.spacing_px).floor() as usize;
    let ny = ((f64::from(spec.height_px) - 4.0) / spec.spacing_px).floor() as usize;
    let (mut ring_e, mut ring_phase, mut ring_mag, mut ring_h) = (0.0, 0.0, 0.0, 0.0);
    let mut k_gal = 0usize;
    for iy in 0..ny {
        for ix in 0..nx {
            let jitter = 0.2 * spec.spacing_px;
            let x = 3.0 + (ix as f64 + 0.5) * spec.spacing_px + rng.random_range(-jitter..jitter);
            let y = 3.0 + (iy as f64 + 0.5) * spec.spacing_px + rng.random_range(-jitter..jitter);
            let mag = rng.random_range(19.5..26.0);
            let id = rows.len() as i64 + 1;
            if rng.random::<f64>() < spec.star_fraction {
                rows.push(TruthRow {
                    id,
                    kind: KIND_STAR,
                    hubble_type: -1,
                    x,
                    y,
                    mag,
                    ..Default::default()
                });
                continue;
            }
            let (emod, theta) = if spec.shape_noise {
                (
                    rng.random_range(0.0..0.7),
                    rng.random_range(0.0..std::f64::consts::PI),
                )
            } else {
                if k_gal % spec.ring_size == 0 {
                    ring_e = rng.random_range(0.02..0.6);
                    ring_phase = rng.random_range(0.0..std::f64::consts::PI);
                    ring_mag = rng.random_range(19.5..26.0);
                    ring_h = rng.random_range(0.05..1.0);
                }
                let k = (k_gal % spec.ring_size) as f64;
                (
                    ring_e,
                    ring_phase + std::f64::consts::PI * k / spec.ring_size as f64,
                )
            };
            k_gal += 1;
            let (mag, disk_h) = if spec.shape_noise {
                (mag, rng.random_range(0.05..1.0))
            } else {
                (ring_mag, ring_h)
            };
            let e = (emod * (2.0 * theta).cos(), emod * (2.0 * theta).sin());
            rows.push(TruthRow {
                id,
                kind: KIND_GALAXY,
                hubble_type: 3,
                x,
                y,
                mag,
                disk_h_arcsec: disk_h,
                pa_deg: theta.to_degrees(),
                e1_int: e.0,
                e2_int: e.1,
                e1: e.0,
                e2: e.1,
                ..Default::default()
            });
        }
    }
    if !spec.shape_noise {
        // An incomplete last ring would break the exact ring average: its
        // galaxies become stars.
        let mut extra = k_gal % spec.ring_size;
        for r in rows.iter_mut().rev() {
            if extra == 0 {
                break;
            }
            if !r.is_star() {
                *r = TruthRow {
                    id: r.id,
                    kind: KIND_STAR,
                    hubble_type: -1,
                    x: r.x,
                    y: r.y,
                    mag: r.mag,
                    ..Default::default()
                };
                extra -= 1;
            }
        }
    }
    rows
}

/// Builds the run: datasets PSF-major then shear; ids `d<k>` and `i<k>f<j>`.
pub fn make_run(spec: &SynthSpec) -> SynthRun {
    let fields: Vec<Vec<TruthRow>> = (0..spec.n_fields).map(|f| base_field(spec, f)).collect();
    let mut datasets = Vec::new();
    let mut truth = Vec::new();
    for (p, (psf_id, psf)) in spec.psfs.iter().enumerate() {
        for (s, &(g1, g2)) in spec.shears.iter().enumerate() {
            let d = p * spec.shears.len() + s;
            let mut images = Vec::new();
            let rotations: &[bool] = if spec.rotated_pairs {
                &[false, true]
            } else {
                &[false]
            };
            for f in 0..spec.n_fields {
                for &rotated in rotations {
                    images.push(DatasetImage {
                        image: format!("i{d:03}f{f:03}{}", if rotated { "r" } else { "" }),
                        field: f,
                        rotated,
                    });
                    truth.push(
                        fields[f as usize]
                            .iter()
                            .map(|r| {
                                let mut r = *r;
                                if !r.is_star() {
                                    if rotated {
                                        (r.e1_int, r.e2_int) = (-r.e1_int, -r.e2_int);
                                        r.pa_deg = (r.pa_deg + 90.0) % 180.0;
                                    }
                                    (r.e1, r.e2) = shear((r.e1_int, r.e2_int), (g1, g2));
                                    r.g1 = g1;
                                    r.g2 = g2;
                                }
                                r
                            })
                            .collect(),
                    );
                }
            }
            datasets.push(DatasetEntry {
                part: Default::default(),
                dataset: format!("d{d:03}"),
                psf_id: *psf_id,
                psf: psf.clone(),
                g1,
                g2,
                images,
            });
        }
    }
    SynthRun {
        datasets: Datasets {
            format: DATASETS_FORMAT.into(),
            width_px: spec.width_px,
            height_px: spec.height_px,
            pixel_scale_arcsec: spec.pixel_scale_arcsec,
            datasets,
        },
        truth,
    }
}

/// A challenge run's two parts: the public part of `spec`, and a held-out
/// part with the same PSFs, `holdout_shears` and base fields of its own
/// (numbered after the public ones, drawn with `holdout_seed`), its
/// datasets and images renamed `h…` and marked [`Part::Holdout`]. Returns
/// (public, held-out, the whole run).
pub fn challenge_run(
    spec: &SynthSpec,
    holdout_shears: &[(f64, f64)],
    holdout_seed: u64,
) -> (SynthRun, SynthRun, SynthRun) {
    let public = make_run(spec);
    let mut h = spec.clone();
    h.shears = holdout_shears.to_vec();
    h.seed = holdout_seed;
    let mut held = make_run(&h);
    for d in &mut held.datasets.datasets {
        d.dataset = format!("h{}", d.dataset);
        d.part = Part::Holdout;
        for im in &mut d.images {
            im.image = format!("h{}", im.image);
            im.field += spec.n_fields;
        }
    }
    let mut all = public.clone();
    all.datasets
        .datasets
        .extend(held.datasets.datasets.iter().cloned());
    all.truth.extend(held.truth.iter().cloned());
    (public, held, all)
}

impl SynthRun {
    /// The image index of the run.
    pub fn index(&self) -> ImageIndex {
        ImageIndex::new(&self.datasets, Path::new(PrivateDir::DATASETS))
            .expect("unique synthetic ids")
    }

    /// Writes `dir/datasets.json`, a `dir/config.json` of unlensed positions
    /// and `dir/truth/<image>.fits` (dir = `RUN/private`).
    pub fn write(&self, dir: &Path) -> Result<(), HarnessError> {
        let json = serde_json::to_string_pretty(&self.datasets).unwrap_or_default();
        let private = PrivateDir::new(dir);
        stepsim_contract::io::write_bytes_atomically(&private.datasets(), json.as_bytes())?;
        // The run's config as the harness reads it: positions not lensed.
        stepsim_contract::io::write_bytes_atomically(
            &private.config(),
            b"{\"population\": {\"lens_positions\": false}}\n",
        )?;
        let index = self.index();
        for (info, rows) in index.images.iter().zip(&self.truth) {
            let path = private.truth(&info.image);
            stepsim_contract::io::truth::write_truth_fits(&path, rows, &[])?;
        }
        Ok(())
    }

    /// A synthetic submission: `rule(truth row, dataset index)` gives the
    /// row's (e1, e2, weight), or `None` to leave the object out. Stars are
    /// offered to the rule too. Positions are the truth positions.
    pub fn submission(&self, rule: &Rule) -> Vec<Vec<SubRow>> {
        let index = self.index();
        index
            .images
            .iter()
            .zip(&self.truth)
            .map(|(info, rows)| {
                rows.iter()
                    .filter_map(|t| {
                        let (e1, e2, weight) = rule(t, info.dataset)?;
                        Some(SubRow {
                            x: t.x,
                            y: t.y,
                            e1,
                            e2,
                            weight,
                            line: 0,
                        })
                    })
                    .collect()
            })
            .collect()
    }

    /// Matches `rows` (per image) and reduces them, in memory.
    pub fn stats(&self, rows: &[Vec<SubRow>], radius_arcsec: f64) -> Vec<ImageStats> {
        let index = self.index();
        let r = radius_arcsec / self.datasets.pixel_scale_arcsec;
        index
            .images
            .iter()
            .enumerate()
            .filter(|(i, _)| !rows[*i].is_empty())
            .map(|(i, info)| {
                match_image(
                    info.dataset,
                    info.field,
                    &rows[i],
                    &self.truth[i],
                    r,
                    (self.datasets.width_px, self.datasets.height_px),
                    stepsim_harness::Isolation::standard(
                        self.datasets.pixel_scale_arcsec,
                        stepsim_harness::Plane::Image,
                    ),
                )
            })
            .collect()
    }

    /// The dataset table of the metrics.
    pub fn meta(&self) -> Vec<DatasetMeta> {
        DatasetMeta::of_run(&self.datasets)
    }
}

/// Writes per-image rows as one whitespace table (`# image x y e1 e2
/// weight`), with full precision.
pub fn submission_text(index: &ImageIndex, rows: &[Vec<SubRow>]) -> String {
    use std::fmt::Write as _;
    let mut s = String::from("# image x y e1 e2 weight\n");
    for (info, rows) in index.images.iter().zip(rows) {
        for r in rows {
            let _ = writeln!(
                s,
                "{} {:?} {:?} {:?} {:?} {:?}",
                info.image, r.x, r.y, r.e1, r.e2, r.weight
            );
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shear_formula_composes_like_eq_8() {
        // A round source takes the shear's ellipticity.
        assert_eq!(shear((0.0, 0.0), (0.03, -0.02)), (0.03, -0.02));
        // Shearing by g then by -g (same axis, reduced shear) is not identity
        // in general, but a source with e_s = -g becomes round.
        let e = shear((-0.05, 0.02), (0.05, -0.02));
        assert!(e.0.abs() < 1e-15 && e.1.abs() < 1e-15);
    }

    #[test]
    fn ring_mean_is_the_shear() {
        let spec = SynthSpec::small(1);
        let run = make_run(&spec);
        let idx = run.index();
        for (info, rows) in idx.images.iter().zip(&run.truth) {
            let g = &run.datasets.datasets[info.dataset];
            let gal: Vec<&TruthRow> = rows.iter().filter(|r| !r.is_star()).collect();
            assert_eq!(gal.len() % spec.ring_size, 0);
            let m1 = gal.iter().map(|r| r.e1).sum::<f64>() / gal.len() as f64;
            assert!((m1 - g.g1).abs() < 1e-9, "{m1} {}", g.g1);
        }
    }
}
