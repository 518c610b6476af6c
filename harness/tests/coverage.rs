//! Are the errors calibrated? Many synthetic realisations with a known m
//! and c, shape noise and measurement noise, in the STEP1 design (every
//! dataset shows the same base fields) without and with 90°-rotated twins:
//! the ±1σ and ±1.96σ intervals of m, c1 and c2 must cover the truth in
//! 68 ± 5 % and 95 ± 3 % of the realisations (docs/scoring.md).

use rand::{RngExt, SeedableRng};
use stepsim_contract::seed::{SimRng, splitmix64};
use stepsim_contract::truth::TruthRow;
use stepsim_harness::{
    FitModel, ImageStats, PsfReport, image_stats, score_tables, score_tables_with,
};
use stepsim_testkit::synthetic::{SynthRun, SynthSpec, make_run};

/// Realisations per design.
const N_REAL: u64 = 1000;
/// Measurement noise per shape component.
const SIGMA_MEAS: f64 = 0.1;

fn spec(seed: u64, paired: bool) -> SynthSpec {
    SynthSpec {
        psfs: vec![(0, "none".into())],
        // 64 base fields of 16 galaxies (100² px, 20 px grid).
        n_fields: 64,
        width_px: 100,
        height_px: 100,
        star_fraction: 0.0,
        shape_noise: true,
        rotated_pairs: paired,
        seed,
        ..SynthSpec::small(1)
    }
}

/// Standard normal deviate keyed by (key, index) (Box–Muller).
fn normal(key: u64, i: u64) -> f64 {
    let mut rng = SimRng::seed_from_u64(splitmix64(key ^ splitmix64(i)));
    let u1: f64 = rng.random_range(f64::EPSILON..1.0);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// The image sums of a submission γ̂ = (1 + m0) e + c + noise, every galaxy
/// measured at its true position (so the matches are the identity).
fn stats(run: &SynthRun, m0: f64, c: (f64, f64), key: u64) -> Vec<ImageStats> {
    let index = run.index();
    index
        .images
        .iter()
        .zip(&run.truth)
        .enumerate()
        .map(|(i, (info, truth))| {
            let rows: Vec<_> = truth
                .iter()
                .enumerate()
                .map(|(j, t): (usize, &TruthRow)| {
                    let k = splitmix64(key ^ splitmix64((i as u64) << 20 | j as u64));
                    stepsim_harness::SubRow {
                        x: t.x,
                        y: t.y,
                        e1: (1.0 + m0) * t.e1 + c.0 + SIGMA_MEAS * normal(k, 1),
                        e2: (1.0 + m0) * t.e2 + c.1 + SIGMA_MEAS * normal(k, 2),
                        weight: 1.0,
                        line: 0,
                    }
                })
                .collect();
            let matches: Vec<Option<usize>> = (0..truth.len()).map(Some).collect();
            image_stats(info.dataset, info.field, &rows, &matches, truth)
        })
        .collect()
}

/// The model of the truth (q = 0).
const LINEAR: FitModel = FitModel::LINEAR;

/// Fractions of realisations whose ±1σ and ±1.96σ intervals cover the truth,
/// for m, c1 and c2, and the fraction where the quadratic was chosen. With
/// `chosen` the fit model is chosen from the data (|q| ≥ 2σ_q keeps the
/// quadratic), else it is the truth's (linear).
fn coverage(paired: bool, chosen: bool) -> ([(f64, f64); 3], f64) {
    let mut hits = [(0u64, 0u64); 3];
    let mut n = 0u64;
    let mut quadratic = 0u64;
    for r in 0..N_REAL {
        let seed = 1000 + r + if paired { 1 << 32 } else { 0 };
        let mut rng = SimRng::seed_from_u64(splitmix64(seed));
        let m0 = rng.random_range(-0.05..0.05);
        let c = (rng.random_range(-2e-3..2e-3), rng.random_range(-2e-3..2e-3));
        let run = make_run(&spec(seed, paired));
        let st = stats(&run, m0, c, seed);
        let s = if chosen {
            score_tables(&run.meta(), &st, 1.0)
        } else {
            score_tables_with(&run.meta(), &st, 1.0, &[(0, LINEAR)])
        };
        let p: &PsfReport = &s.psfs[0];
        let checks = [
            (p.m.unwrap(), p.m_err.unwrap(), m0),
            (p.c1.unwrap(), p.c1_err.unwrap(), c.0),
            (p.c2.unwrap(), p.c2_err.unwrap(), c.1),
        ];
        quadratic += u64::from(!p.linear);
        for (h, (v, e, t)) in hits.iter_mut().zip(checks) {
            let z = (v - t).abs() / e;
            h.0 += u64::from(z <= 1.0);
            h.1 += u64::from(z <= 1.96);
        }
        n += 1;
    }
    (
        hits.map(|(a, b)| (a as f64 / n as f64, b as f64 / n as f64)),
        quadratic as f64 / n as f64,
    )
}

fn print(paired: bool, chosen: bool, cov: &[(f64, f64); 3], quadratic: f64) {
    for (name, (c68, c95)) in ["m", "c1", "c2"].iter().zip(cov) {
        eprintln!(
            "{} design, model {}: {name}: 68% interval covers {:.1}%, 95% interval {:.1}% \
             ({N_REAL} realisations, quadratic chosen in {:.1}%)",
            if paired { "paired" } else { "unpaired" },
            if chosen {
                "chosen from the data"
            } else {
                "fixed"
            },
            100.0 * c68,
            100.0 * c95,
            100.0 * quadratic
        );
    }
}

fn check(paired: bool) {
    // With STEPSIM_SLOW=1, also the figures with the model chosen from the
    // data, for docs/scoring.md (m loses coverage: when |q̂| ≥ 2σ_q by chance, m̂ — strongly
    // anti-correlated with q̂ on the STEP1 shears — is off by as much).
    if std::env::var_os("STEPSIM_SLOW").is_some() {
        let (cov, quadratic) = coverage(paired, true);
        print(paired, true, &cov, quadratic);
    }
    let (cov, quadratic) = coverage(paired, false);
    print(paired, false, &cov, quadratic);
    assert_eq!(quadratic, 0.0);
    for (name, (c68, c95)) in ["m", "c1", "c2"].iter().zip(cov) {
        assert!(
            (c68 - 0.68).abs() <= 0.05,
            "{name}: 68% interval covers {c68}"
        );
        assert!(
            (c95 - 0.95).abs() <= 0.03,
            "{name}: 95% interval covers {c95}"
        );
    }
}

#[test]
fn errors_cover_the_truth_without_rotated_twins() {
    check(false);
}

#[test]
fn errors_cover_the_truth_with_rotated_twins() {
    check(true);
}
