//! Direct synthetic per-image statistics for the fit-rule and interval
//! tests: one PSF, a few shears, `n_fields` base fields shown by every
//! dataset, one image per field and dataset. Every family (all rows,
//! uncontaminated, isolated, selection and weight bias) measures
//! y = q g² + (1 + m) g + c (the biases without the 1: q g² + m g + c) plus
//! a shape noise shared by the datasets of a field and a measurement noise
//! of each image, so that every family sees the same numbers.
#![allow(dead_code)]

use rand::{RngExt, SeedableRng};
use stepsim_contract::seed::{SimRng, splitmix64};
use stepsim_harness::{BinAcc, DatasetMeta, ImageStats};

/// A synthetic design and its truth.
#[derive(Debug, Clone)]
pub struct Case {
    /// Applied γ1 of each dataset (γ2 = 0).
    pub shears: Vec<f64>,
    /// Base fields.
    pub n_fields: u32,
    /// True m, q and c1.
    pub m: f64,
    /// See `m`.
    pub q: f64,
    /// See `m`.
    pub c: f64,
    /// Shape noise per field (common to the datasets).
    pub sigma_shape: f64,
    /// Measurement noise per image.
    pub sigma_meas: f64,
    /// Seed of the noise.
    pub seed: u64,
}

/// Standard normal deviate keyed by (key, index) (Box–Muller).
pub fn normal(key: u64, i: u64) -> f64 {
    let mut rng = SimRng::seed_from_u64(splitmix64(key ^ splitmix64(i)));
    let u1: f64 = rng.random_range(f64::EPSILON..1.0);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// The metrics' table of datasets and the image sums of `case`.
pub fn stats(case: &Case) -> (Vec<DatasetMeta>, Vec<ImageStats>) {
    let meta: Vec<DatasetMeta> = case
        .shears
        .iter()
        .enumerate()
        .map(|(d, &g)| DatasetMeta {
            dataset: format!("d{d}"),
            psf_id: 0,
            psf: "none".into(),
            g1: g,
            g2: 0.0,
        })
        .collect();
    let mut stats = Vec::new();
    for f in 0..case.n_fields {
        let fk = splitmix64(case.seed ^ splitmix64(u64::from(f)));
        let shape = (
            case.sigma_shape * normal(fk, 1),
            case.sigma_shape * normal(fk, 2),
        );
        for (d, &g) in case.shears.iter().enumerate() {
            let k = splitmix64(fk ^ splitmix64(1000 + d as u64));
            let bias = case.q * g * g + case.m * g + case.c;
            let y1 = g + bias + shape.0 + case.sigma_meas * normal(k, 1);
            let y2 = shape.1 + case.sigma_meas * normal(k, 2);
            let acc = BinAcc {
                n: 1,
                sw: 1.0,
                swe1: y1,
                swe2: y2,
            };
            // Selection bias ⟨e1_int⟩ = bias + noise; weight bias
            // ⟨e1_int⟩ − ⟨e1_int⟩_w the same numbers.
            let sel = y1 - g;
            stats.push(ImageStats {
                dataset: d,
                field: f,
                n: 1,
                n_gal: 1,
                sw: 1.0,
                all: acc,
                gal: acc,
                iso: acc,
                sum_e1_int: sel,
                sum_e2_int: y2,
                sw_e1_int: 0.0,
                ..Default::default()
            });
        }
    }
    (meta, stats)
}
