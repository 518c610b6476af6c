//! Scoring one part of a challenge run (`challenge` section of the config,
//! `part` of each dataset in `datasets.json`): the public part, whose
//! aggregate feedback participants see before reveal, or the held-out part,
//! ranked at reveal.
//!
//! A submission covers the whole run (participants cannot tell the parts
//! apart), so it is read and checked against every image exactly as
//! `stepsim score` does ([`crate::pipeline::prepare`]); then the truth set
//! and the rows are restricted to the datasets of one part, and the same
//! stages ([`match_images`], [`build_report`]) score them. The numbers are
//! those of `stepsim score` on a run whose `datasets.json` lists only that
//! part's datasets (tested).

use crate::error::HarnessError;
use crate::pipeline::{Prepared, ScoreOptions, build_report, match_images, prepare};
use crate::read::truth_set::{ImageIndex, TruthSet};
use crate::score::report::{Report, Summary};
use serde::{Deserialize, Serialize};
use stepsim_contract::run_layout::Datasets;
use stepsim_contract::run_layout::Part;

/// The datasets of `part` in a run's `datasets.json` (in file order).
pub fn part_datasets(datasets: &Datasets, part: Part) -> Datasets {
    Datasets {
        datasets: datasets
            .datasets
            .iter()
            .filter(|d| d.part == part)
            .cloned()
            .collect(),
        ..datasets.clone()
    }
}

/// True when the run has datasets of the held-out part.
pub fn has_holdout(datasets: &Datasets) -> bool {
    datasets.datasets.iter().any(|d| d.part == Part::Holdout)
}

/// Restricts a prepared truth set and submission to the datasets of `part`.
/// Refuses a run without datasets of that part. The run identity becomes
/// `<identity>#<part>`, so that a leaderboard never ranks a part's report
/// with a whole run's.
pub fn restrict(p: &Prepared, part: Part) -> Result<Prepared, HarnessError> {
    let datasets = part_datasets(&p.truth.datasets, part);
    let path = stepsim_contract::run_dir::PrivateDir::new(&p.truth.dir).datasets();
    if datasets.datasets.is_empty() {
        return Err(HarnessError::truth(
            &path,
            format!("the run has no dataset of the {} part", part.name()),
        ));
    }
    let index = ImageIndex::new(&datasets, &path)?;
    let old = &p.truth.index;
    let which: Vec<usize> = index.images.iter().map(|im| old.by_id[&im.image]).collect();
    let submission = p.submission.select(&which);
    let truth = TruthSet {
        datasets,
        index,
        dir: p.truth.dir.clone(),
        run: format!("{}#{}", p.truth.run, part.name()),
        lensed_positions: p.truth.lensed_positions,
    };
    Ok(Prepared {
        truth,
        submission,
        warnings: p.warnings.clone(),
    })
}

/// Scores the datasets of `part` only (the same stages as
/// [`crate::pipeline::score`]).
pub fn score_part(opts: &ScoreOptions, part: Part) -> Result<Report, HarnessError> {
    score_prepared_part(&prepare(opts)?, part, opts)
}

/// [`score_part`] of a submission already read ([`prepare`]): a caller
/// that scores both parts reads and checks the file once.
pub fn score_prepared_part(
    p: &Prepared,
    part: Part,
    opts: &ScoreOptions,
) -> Result<Report, HarnessError> {
    let p = restrict(p, part)?;
    let stats = match_images(&p, opts.match_radius_arcsec)?;
    Ok(build_report(&p, &stats, opts))
}

/// Decimal places of each figure of [`PublicFeedback`]: ⟨m⟩ to 0.001, σ_c
/// to 0.0001, Q_c to 1, the percentages to 0.1.
pub const FEEDBACK_DECIMALS: [(&str, i32); 5] = [
    ("m_mean", 3),
    ("sigma_c", 4),
    ("q_c", 0),
    ("pct_stars", 1),
    ("pct_false", 1),
];

/// What a participant is told about a scored entry before reveal: aggregate
/// figures of the public part only, rounded ([`FEEDBACK_DECIMALS`]). Keys
/// as in report.json (`summary` for the first three; the percentages are
/// the means over the part's datasets of the per-dataset keys).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PublicFeedback {
    /// ⟨m⟩ over PSFs.
    pub m_mean: Option<f64>,
    /// σ_c.
    pub sigma_c: Option<f64>,
    /// Q_c.
    pub q_c: Option<f64>,
    /// Stellar contamination: mean over datasets of `pct_stars`.
    pub pct_stars: Option<f64>,
    /// False detections: mean over datasets of `pct_false`.
    pub pct_false: Option<f64>,
}

/// Rounds `v` to `decimals` decimal places (half away from zero); NaN and
/// infinities become `None`.
pub fn round_to(v: Option<f64>, decimals: i32) -> Option<f64> {
    let v = v.filter(|v| v.is_finite())?;
    let scale = 10f64.powi(decimals);
    let r = (v * scale).round() / scale;
    // -0.0 reads as 0 in JSON either way; keep it plain.
    Some(if r == 0.0 { 0.0 } else { r })
}

/// The mean of `v`, summed in ascending order: the same bits whatever the
/// order of `v` (which follows the private order of the datasets), so that
/// not even the last bit of a figure, nor its rounding, depends on it.
/// `None` when `v` is empty.
fn order_free_mean(mut v: Vec<f64>) -> Option<f64> {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    (n > 0).then(|| v.iter().sum::<f64>() / n as f64)
}

impl PublicFeedback {
    /// The rounded aggregate of a report (of the public part).
    pub fn of_report(report: &Report) -> Self {
        let Summary {
            m_mean,
            sigma_c,
            q_c,
            ..
        } = report.summary;
        let mean = |f: fn(&crate::score::report::DatasetReport) -> f64| {
            order_free_mean(report.datasets.iter().map(f).collect())
        };
        let d = |k: &str| {
            FEEDBACK_DECIMALS
                .iter()
                .find(|(n, _)| *n == k)
                .map(|x| x.1)
                .unwrap_or(0)
        };
        Self {
            m_mean: round_to(m_mean, d("m_mean")),
            sigma_c: round_to(sigma_c, d("sigma_c")),
            q_c: round_to(q_c, d("q_c")),
            pct_stars: round_to(mean(|r| r.pct_stars), d("pct_stars")),
            pct_false: round_to(mean(|r| r.pct_false), d("pct_false")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounding_states_its_precision() {
        assert_eq!(round_to(Some(0.012_345), 3), Some(0.012));
        assert_eq!(round_to(Some(-0.0125), 3), Some(-0.013));
        assert_eq!(round_to(Some(0.000_04), 3), Some(0.0));
        assert_eq!(round_to(Some(812.6), 0), Some(813.0));
        assert_eq!(round_to(Some(f64::NAN), 3), None);
        assert_eq!(round_to(None, 3), None);
    }

    #[test]
    fn the_mean_over_datasets_does_not_depend_on_their_order() {
        use rand::{RngExt, SeedableRng};
        let mut rng = stepsim_contract::seed::SimRng::seed_from_u64(23);
        let v: Vec<f64> = (0..30).map(|_| rng.random_range(0.0..100.0)).collect();
        let mut w = v.clone();
        w.reverse();
        w.rotate_left(7);
        // A plain sum in the two orders differs in its last bits here …
        assert_ne!(
            v.iter().sum::<f64>().to_bits(),
            w.iter().sum::<f64>().to_bits()
        );
        // … the mean does not.
        let m = order_free_mean(v.clone()).unwrap();
        assert_eq!(m.to_bits(), order_free_mean(w).unwrap().to_bits());
        assert!((m - v.iter().sum::<f64>() / 30.0).abs() < 1e-12);
        assert_eq!(order_free_mean(vec![1.0, 2.0, 4.5]), Some(2.5));
        assert_eq!(order_free_mean(Vec::new()), None);
    }
}
