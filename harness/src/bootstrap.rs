//! Bootstrap confidence intervals of the summary figures, resampling images.
//!
//! Image k of every dataset shows base field k, so the resampling draws
//! *base fields* with replacement (as many as there are) and every dataset
//! takes its images of the drawn fields, the rotated twin with its field:
//! the correlation between datasets that makes σ_c small, and the
//! cancellation of shape noise within a pair, are kept. A field drawn twice
//! counts as two fields. The fit model of each PSF (linear or quadratic) is
//! the one chosen on the full data, in every resample. Each resample has
//! its own generator keyed by (seed, resample index), so the intervals do
//! not depend on the thread count. Intervals are the 2.5 and 97.5
//! percentiles (nearest rank on the sorted finite values).

use crate::metrics::{DatasetMeta, ImageStats, score_tables, score_tables_with};
use crate::report::{BootstrapCi, Summary};
use rand::{RngExt, SeedableRng};
use rayon::prelude::*;
use stepsim_contract::seed::{SimRng, splitmix64};

/// Default number of resamples.
pub const DEFAULT_RESAMPLES: usize = 200;
/// Default seed of the resampling.
pub const DEFAULT_SEED: u64 = 20_060_101;

/// Central probability of the intervals.
pub const CONFIDENCE: f64 = 0.95;

/// Percentile interval of `v` (non-finite values dropped); `None` when empty.
pub fn percentile_interval(v: &mut Vec<f64>, confidence: f64) -> Option<[f64; 2]> {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let a = (1.0 - confidence) / 2.0;
    let at = |p: f64| v[((p * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
    Some([at(a), at(1.0 - a)])
}

/// The summaries of `n` resamples (in resample order).
pub fn resample_summaries(
    meta: &[DatasetMeta],
    stats: &[ImageStats],
    area_arcmin2: f64,
    n: usize,
    seed: u64,
) -> Vec<Summary> {
    let mut fields: Vec<u32> = stats.iter().map(|s| s.field).collect();
    fields.sort_unstable();
    fields.dedup();
    // Images of each field.
    let mut by_field: Vec<Vec<&ImageStats>> = vec![Vec::new(); fields.len()];
    for s in stats {
        let k = fields.binary_search(&s.field).unwrap_or(0);
        by_field[k].push(s);
    }
    let models = score_tables(meta, stats, area_arcmin2).models;
    (0..n)
        .into_par_iter()
        .map(|b| {
            let mut rng = SimRng::seed_from_u64(splitmix64(seed ^ splitmix64(b as u64)));
            let mut sample = Vec::with_capacity(stats.len());
            for draw in 0..fields.len() {
                let k = rng.random_range(0..fields.len());
                sample.extend(by_field[k].iter().map(|s| ImageStats {
                    field: draw as u32,
                    ..(*s).clone()
                }));
            }
            score_tables_with(meta, &sample, area_arcmin2, &models).summary
        })
        .collect()
}

/// Bootstrap intervals of every summary figure.
pub fn bootstrap(
    meta: &[DatasetMeta],
    stats: &[ImageStats],
    area_arcmin2: f64,
    n: usize,
    seed: u64,
) -> BootstrapCi {
    let sums = resample_summaries(meta, stats, area_arcmin2, n, seed);
    let ci = |f: fn(&Summary) -> Option<f64>| {
        let mut v: Vec<f64> = sums.iter().filter_map(f).collect();
        percentile_interval(&mut v, CONFIDENCE)
    };
    BootstrapCi {
        n_resamples: n,
        seed,
        confidence: CONFIDENCE,
        m_mean: ci(|s| s.m_mean),
        q_mean: ci(|s| s.q_mean),
        sigma_c: ci(|s| s.sigma_c),
        m_uncontaminated_mean: ci(|s| s.m_uncontaminated_mean),
        m_selc_mean: ci(|s| s.m_selc_mean),
        sigma_c_selc: ci(|s| s.sigma_c_selc),
        m_weight_mean: ci(|s| s.m_weight_mean),
        q_c: ci(|s| s.q_c),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentile_interval_uses_nearest_rank() {
        let mut v: Vec<f64> = (0..=100).rev().map(f64::from).collect();
        v.push(f64::NAN);
        assert_eq!(percentile_interval(&mut v, 0.95), Some([3.0, 98.0]));
        assert_eq!(percentile_interval(&mut vec![], 0.95), None);
    }
}
