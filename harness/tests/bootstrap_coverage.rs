//! Do the bootstrap intervals from few base fields cover the truth as
//! often as they claim (issue #24)? Synthetic per-image statistics with a
//! known m (`synth_stats`), 8 base fields, three shears (so the fit is
//! linear in every realisation and only the interval is tested), 200
//! resamples each: the 68 % and 95 % intervals of ⟨m⟩ must hold the truth
//! in 68 ± 5 % and 95 ± 2.5 % of the realisations. The plain percentile
//! intervals, which the report gave before, cover about 59 % and 90 %
//! (asserted below 64 % and 92 %): the bootstrap's spread is the plug-in
//! one and its percentiles are normal ones, while 8 fields call for
//! Student's t with 7 degrees of freedom. Measured numbers:
//! docs/scoring.md. `STEPSIM_SLOW=1` also runs 16 and 32 fields.

use crate::synth_stats;

use stepsim_harness::{intervals, percentile_interval, resample_summaries, score_tables};
use synth_stats::{Case, stats};

/// Realisations per design.
const N_REAL: u64 = 600;
/// Resamples per realisation (the default of `stepsim score`).
const N_RESAMPLES: usize = 200;

/// Coverage of ⟨m⟩'s intervals over `N_REAL` realisations with
/// `n_fields` base fields: ((new 68 %, new 95 %), (plain 68 %, plain 95 %)).
fn coverage(n_fields: u32) -> ((f64, f64), (f64, f64)) {
    let (mut new, mut plain) = ((0u64, 0u64), (0u64, 0u64));
    let m0 = 0.01;
    let inside = |ci: Option<[f64; 2]>| {
        let [lo, hi] = ci.expect("an interval");
        u64::from(lo <= m0 && m0 <= hi)
    };
    for r in 0..N_REAL {
        let case = Case {
            shears: vec![0.0, 0.05, 0.1],
            n_fields,
            m: m0,
            q: 0.0,
            c: 1e-3,
            sigma_shape: 0.02,
            sigma_meas: 2e-3,
            seed: 7_000 + r + (u64::from(n_fields) << 32),
        };
        let (meta, st) = stats(&case);
        assert!(score_tables(&meta, &st, 1.0).psfs[0].linear);
        let sums = resample_summaries(&meta, &st, 1.0, N_RESAMPLES, 20_060_101 + r);
        let f = n_fields as usize;
        new.0 += inside(intervals(&sums, f, 0.6827, N_RESAMPLES, 0).m_mean);
        new.1 += inside(intervals(&sums, f, 0.95, N_RESAMPLES, 0).m_mean);
        let mut v: Vec<f64> = sums.iter().filter_map(|s| s.m_mean).collect();
        plain.0 += inside(percentile_interval(&mut v.clone(), 0.6827));
        plain.1 += inside(percentile_interval(&mut v, 0.95));
    }
    let n = N_REAL as f64;
    let frac = |(a, b): (u64, u64)| (a as f64 / n, b as f64 / n);
    let (new, plain) = (frac(new), frac(plain));
    eprintln!(
        "{n_fields} base fields, {N_REAL} realisations: t-widened intervals cover {:.1} % (68 %), \
         {:.1} % (95 %); plain percentiles {:.1} %, {:.1} %",
        100.0 * new.0,
        100.0 * new.1,
        100.0 * plain.0,
        100.0 * plain.1
    );
    (new, plain)
}

#[test]
fn intervals_from_eight_base_fields_hold_their_coverage() {
    let (new, plain) = coverage(8);
    assert!(
        (0.63..=0.73).contains(&new.0),
        "68 % interval covers {}",
        new.0
    );
    assert!(
        (0.925..=0.975).contains(&new.1),
        "95 % interval covers {}",
        new.1
    );
    // The defect: the plain percentile intervals are too short.
    assert!(plain.0 < 0.64 && plain.1 < 0.92, "plain: {plain:?}");
    if std::env::var_os("STEPSIM_SLOW").is_some() {
        for f in [4, 16, 32] {
            coverage(f);
        }
    }
}
