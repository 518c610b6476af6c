//! The score report, `report.json` (SPEC §7 keys), as plain serde types.
//!
//! Missing values (an error from a single image, a signal-to-noise when
//! γ1_true = 0, a fit with too few datasets) are JSON `null`. Keys beyond
//! SPEC §7: the `*_err` of every fitted parameter (SPEC asks for errors on
//! every parameter), `m2`/`q2` only when component 2 is fitted, `q_c` and
//! `bootstrap` in `summary`, the `q_*` and `fit*` model of every fitted
//! family in `psfs`, and `warnings` at the top level (ignored
//! columns, images skipped), and `run`, the run's identity. See
//! `docs/scoring.md`.

use serde::{Deserialize, Serialize};

/// The whole report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    /// Submission name (`--name`, default the submission's file name).
    pub submission: String,
    /// The run scored against: `sha256:` + SHA-256 of its `datasets.json`
    /// ([`crate::read::truth_set::run_identity`]). The leaderboard ranks only
    /// reports of one run.
    pub run: String,
    /// Match radius used.
    pub match_radius_arcsec: f64,
    /// Where the isolated galaxies' separations were taken: `"image"`, or
    /// `"source"` for a run whose galaxy positions are lensed (each
    /// dataset's shear undone; [`crate::score::isolation::Plane`]). Reports
    /// written before the key read as `"image"`.
    #[serde(default)]
    pub isolation_plane: crate::score::isolation::IsolationPlane,
    /// One entry per dataset with at least one submitted image.
    pub datasets: Vec<DatasetReport>,
    /// One entry per PSF.
    pub psfs: Vec<PsfReport>,
    /// Averages over PSFs.
    pub summary: Summary,
    /// Residual γ − γ_true in bins of true magnitude.
    pub by_magnitude: Binned,
    /// Residual γ − γ_true in bins of true disk scale length.
    pub by_disk_size: Binned,
    /// Things the participant should know (ignored columns, skipped images).
    #[serde(default)]
    pub warnings: Vec<String>,
}

/// Per-dataset numbers (one PSF, one shear).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DatasetReport {
    /// Opaque dataset id.
    pub dataset: String,
    /// PSF name.
    pub psf: String,
    /// Applied g1.
    pub g1_true: f64,
    /// Applied g2.
    pub g2_true: f64,
    /// Images with rows.
    pub n_images: usize,
    /// Submitted rows.
    pub n_objects: u64,
    /// Mean over base fields (twins averaged first) of the per-image
    /// weighted mean γ̂1.
    pub g1: Option<f64>,
    /// Its error (std over base fields / √F).
    pub g1_err: Option<f64>,
    /// Same for γ̂2.
    pub g2: Option<f64>,
    /// Its error.
    pub g2_err: Option<f64>,
    /// Submitted objects per arcmin².
    pub ngal_per_arcmin2: f64,
    /// Percentage of rows matched to stars.
    pub pct_stars: f64,
    /// Percentage of rows matched to nothing.
    pub pct_false: f64,
    /// 100 Σw(stars) / Σw.
    pub pct_stars_weighted: Option<f64>,
    /// 100 Σw(false) / Σw.
    pub pct_false_weighted: Option<f64>,
    /// Percentage of on-image positions (a regular 128² lattice per image)
    /// within the match radius of a truth object: how often a detection at a
    /// random position would count as real (read `pct_false` against it).
    #[serde(default)]
    pub pct_chance_match: Option<f64>,
    /// γ1_true / σ_γ1.
    pub snr: Option<f64>,
    /// γ1_true / σ(true e1 of the matched galaxies).
    pub sn_shot: Option<f64>,
    /// The same with the submitted weights.
    pub sn_shot_weighted: Option<f64>,
}

/// The model of a fitted family.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FitKind {
    /// y = m γ_true + c (q = 0).
    #[default]
    Linear,
    /// y = q γ_true² + m γ_true + c.
    Quadratic,
}

/// Which model a family was fitted with, and why (the rule of
/// `docs/scoring.md`: the quadratic only with at least 4 distinct shears,
/// kept when |q| ≥ 2σ_q).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FitChoice {
    /// `"linear"` or `"quadratic"`.
    pub model: FitKind,
    /// Why, one lower-case sentence (`"linear: 3 distinct shears, …"`).
    pub reason: String,
}

/// Per-PSF fits. Every fitted family (γ1 and, when fitted, γ2; the
/// uncontaminated, isolated, selection and weight families) has its m, q
/// and c with errors and a `fit*` [`FitChoice`] saying which model was
/// used and why; the `q*` and `fit*` keys are absent from (and `null` when
/// reading) reports written before they existed.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PsfReport {
    /// PSF name.
    pub psf: String,
    /// Multiplicative bias.
    pub m: Option<f64>,
    /// Its error.
    pub m_err: Option<f64>,
    /// Quadratic term (0 when `linear`).
    pub q: Option<f64>,
    /// Its error (`null` when `linear`).
    pub q_err: Option<f64>,
    /// Additive bias, component 1.
    pub c1: Option<f64>,
    /// Its error.
    pub c1_err: Option<f64>,
    /// Additive bias, component 2.
    pub c2: Option<f64>,
    /// Its error.
    pub c2_err: Option<f64>,
    /// True when the γ1 fit is linear (`fit` says why).
    pub linear: bool,
    /// The γ1 fit's model and why.
    #[serde(default)]
    pub fit: Option<FitChoice>,
    /// The γ2 fit's model and why (only when component 2 is fitted).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fit2: Option<FitChoice>,
    /// m2 (only when g2_true varies over the PSF's shears).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub m2: Option<f64>,
    /// Its error.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub m2_err: Option<f64>,
    /// q2 (only when component 2 is fitted).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub q2: Option<f64>,
    /// Its error.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub q2_err: Option<f64>,
    /// m from objects matched to galaxies only.
    pub m_uncontaminated: Option<f64>,
    /// Its error.
    pub m_uncontaminated_err: Option<f64>,
    /// Quadratic term of the uncontaminated fit (0 when linear).
    #[serde(default)]
    pub q_uncontaminated: Option<f64>,
    /// Its error (`null` when linear).
    #[serde(default)]
    pub q_uncontaminated_err: Option<f64>,
    /// The uncontaminated fit's model and why.
    #[serde(default)]
    pub fit_uncontaminated: Option<FitChoice>,
    /// Selection bias slope.
    pub m_selc: Option<f64>,
    /// Its error.
    pub m_selc_err: Option<f64>,
    /// Quadratic term of the selection-bias fit (0 when linear).
    #[serde(default)]
    pub q_selc: Option<f64>,
    /// Its error (`null` when linear).
    #[serde(default)]
    pub q_selc_err: Option<f64>,
    /// The selection-bias fit's model and why.
    #[serde(default)]
    pub fit_selc: Option<FitChoice>,
    /// Selection bias offset, component 1.
    pub c1_selc: Option<f64>,
    /// Its error.
    pub c1_selc_err: Option<f64>,
    /// Mean intrinsic e2 of the selected galaxies.
    pub c2_selc: Option<f64>,
    /// Its error.
    pub c2_selc_err: Option<f64>,
    /// Weight bias slope.
    pub m_weight: Option<f64>,
    /// Its error.
    pub m_weight_err: Option<f64>,
    /// Quadratic term of the weight-bias fit (0 when linear).
    #[serde(default)]
    pub q_weight: Option<f64>,
    /// Its error (`null` when linear).
    #[serde(default)]
    pub q_weight_err: Option<f64>,
    /// The weight-bias fit's model and why.
    #[serde(default)]
    pub fit_weight: Option<FitChoice>,
    /// Weight bias offset.
    pub c1_weight: Option<f64>,
    /// Its error.
    pub c1_weight_err: Option<f64>,
    /// m from rows matched to isolated galaxies (no neighbour above 10 % of
    /// the flux within 3″; `isolation.rs`): the method without the scene's
    /// blending.
    #[serde(default)]
    pub m_isolated: Option<f64>,
    /// Its error.
    #[serde(default)]
    pub m_isolated_err: Option<f64>,
    /// Quadratic term of the isolated-galaxy fit (0 when linear).
    #[serde(default)]
    pub q_isolated: Option<f64>,
    /// Its error (`null` when linear).
    #[serde(default)]
    pub q_isolated_err: Option<f64>,
    /// The isolated-galaxy fit's model and why.
    #[serde(default)]
    pub fit_isolated: Option<FitChoice>,
    /// c1 from the same rows.
    #[serde(default)]
    pub c1_isolated: Option<f64>,
    /// Its error.
    #[serde(default)]
    pub c1_isolated_err: Option<f64>,
    /// c2 from the same rows (mean of γ2 − γ2_true, as `c2`).
    #[serde(default)]
    pub c2_isolated: Option<f64>,
    /// Its error.
    #[serde(default)]
    pub c2_isolated_err: Option<f64>,
}

/// Averages over PSFs (paper Table 5) and the extra figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// ⟨m⟩.
    pub m_mean: Option<f64>,
    /// ⟨q⟩ (0 for linear PSFs).
    pub q_mean: Option<f64>,
    /// Population std of the pooled {c1(p), c2(p)}.
    pub sigma_c: Option<f64>,
    /// ⟨m_uncontaminated⟩.
    pub m_uncontaminated_mean: Option<f64>,
    /// ⟨m_selc⟩.
    pub m_selc_mean: Option<f64>,
    /// Population std of the pooled {c1_selc(p), c2_selc(p)}.
    pub sigma_c_selc: Option<f64>,
    /// ⟨m_weight⟩.
    pub m_weight_mean: Option<f64>,
    /// ⟨m_isolated⟩.
    #[serde(default)]
    pub m_isolated_mean: Option<f64>,
    /// Population std of the pooled {c1_isolated(p), c2_isolated(p)}.
    #[serde(default)]
    pub sigma_c_isolated: Option<f64>,
    /// GREAT3-style quality factor Q_c.
    pub q_c: Option<f64>,
    /// Mean over datasets of `pct_chance_match`.
    #[serde(default)]
    pub pct_chance_match: Option<f64>,
    /// Bootstrap confidence intervals (over base fields).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bootstrap: Option<BootstrapCi>,
}

/// Bootstrap confidence intervals of the summary figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BootstrapCi {
    /// Number of resamples.
    pub n_resamples: usize,
    /// Seed of the resampling.
    pub seed: u64,
    /// Central probability of the intervals (0.95).
    pub confidence: f64,
    /// Base fields resampled (F; absent from reports written before the
    /// key existed).
    #[serde(default)]
    pub base_fields: Option<usize>,
    /// Factor by which the percentile intervals were widened about the
    /// resamples' median, t_{(1+C)/2, F−1} / z_{(1+C)/2} · √(F/(F − 1))
    /// (`null` below 2 base fields, and in older reports: plain
    /// percentiles).
    #[serde(default)]
    pub widening: Option<f64>,
    /// Interval [low, high] of each summary figure (`null` when undefined).
    pub m_mean: Option<[f64; 2]>,
    /// See `m_mean`.
    pub q_mean: Option<[f64; 2]>,
    /// See `m_mean`.
    pub sigma_c: Option<[f64; 2]>,
    /// See `m_mean`.
    pub m_uncontaminated_mean: Option<[f64; 2]>,
    /// See `m_mean`.
    pub m_selc_mean: Option<[f64; 2]>,
    /// See `m_mean`.
    pub sigma_c_selc: Option<[f64; 2]>,
    /// See `m_mean`.
    pub m_weight_mean: Option<[f64; 2]>,
    /// See `m_mean`.
    pub q_c: Option<[f64; 2]>,
    /// See `m_mean` (isolated galaxies; absent from reports written before
    /// the key existed).
    #[serde(default)]
    pub m_isolated_mean: Option<[f64; 2]>,
    /// See `m_isolated_mean`.
    #[serde(default)]
    pub sigma_c_isolated: Option<[f64; 2]>,
}

/// Residuals in bins of a true galaxy property.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Binned {
    /// Truth column binned (`mag` or `disk_h_arcsec`).
    pub variable: String,
    /// The residuals over all matched galaxies (one bin holding everything).
    pub all: BinReport,
    /// The bins, in increasing order.
    pub bins: Vec<BinReport>,
}

/// One bin.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BinReport {
    /// Lower edge (`null` = −∞).
    pub lo: Option<f64>,
    /// Upper edge (`null` = +∞).
    pub hi: Option<f64>,
    /// Matched galaxies in the bin, over all datasets.
    pub n_objects: u64,
    /// Mean over datasets of (γ1 − γ1_true) from the bin's galaxies.
    pub g1_residual: Option<f64>,
    /// Its error.
    pub g1_residual_err: Option<f64>,
    /// Same for component 2.
    pub g2_residual: Option<f64>,
    /// Its error.
    pub g2_residual_err: Option<f64>,
}
