//! A scored entry's full report (report.json of one part) as the tables of
//! the report page: the summary with its bootstrap intervals, m, q and c per
//! PSF with their errors, and the per-dataset shears. Shown only after
//! reveal (docs/server.md, "Pages").

use super::{fixed, interval_ends, signed};
use serde::Serialize;
use stepsim_harness::{FEW_BASE_FIELDS, Report, distinct_resamples};

/// One summary figure: value and bootstrap interval.
#[derive(Debug, Serialize)]
pub(crate) struct SummaryRow {
    /// The figure's symbol (`m`, `σ`, ...).
    label: &'static str,
    /// Its subscript, if any.
    sub: &'static str,
    /// What it is.
    what: &'static str,
    value: String,
    lo: String,
    hi: String,
}

/// One PSF's fit.
#[derive(Debug, Serialize)]
pub(crate) struct PsfRow {
    psf: String,
    m: String,
    q: String,
    c1: String,
    c2: String,
    m_uncontaminated: String,
    linear: bool,
}

/// One dataset.
#[derive(Debug, Serialize)]
pub(crate) struct DatasetRow {
    dataset: String,
    psf: String,
    g1_true: String,
    g2_true: String,
    g1: String,
    g2: String,
    n_images: usize,
    n_objects: u64,
    pct_stars: String,
    pct_false: String,
}

/// The tables of one part's report.
#[derive(Debug, Serialize)]
pub(crate) struct ReportTables {
    pub(crate) summary: Vec<SummaryRow>,
    pub(crate) confidence: String,
    pub(crate) n_resamples: usize,
    pub(crate) psfs: Vec<PsfRow>,
    pub(crate) datasets: Vec<DatasetRow>,
    pub(crate) warnings: Vec<String>,
    /// report.md's caveat when the bootstrap resamples few base fields.
    pub(crate) caveat: Option<String>,
    /// Some interval is shown as "—" (no width at the precision shown).
    pub(crate) no_width: bool,
}

/// How a summary figure's interval is picked from the bootstrap.
type Pick = fn(&stepsim_harness::BootstrapCi) -> Option<[f64; 2]>;
/// A summary row to build: (symbol, subscript, meaning, value, interval, decimals).
type SummaryLine = (
    &'static str,
    &'static str,
    &'static str,
    Option<f64>,
    Pick,
    usize,
);

/// `value ± error` with `dp` decimals; an error that reads 0 at that
/// precision is shown as `± —` (it would claim an exact value).
fn pm(v: Option<f64>, e: Option<f64>, dp: usize) -> String {
    match (v, e) {
        (Some(_), Some(e)) => {
            let e = fixed(Some(e), dp);
            if e.chars().all(|c| c == '0' || c == '.') {
                format!("{} ± —", signed(v, dp))
            } else {
                format!("{} ± {e}", signed(v, dp))
            }
        }
        _ => signed(v, dp),
    }
}

/// The tables of a report.
pub(crate) fn tables(r: &Report) -> ReportTables {
    let s = &r.summary;
    let b = s.bootstrap.as_ref();
    let rows: [SummaryLine; 8] = [
        (
            "Q",
            "c",
            "quality factor (larger is better)",
            s.q_c,
            |b| b.q_c,
            1,
        ),
        (
            "⟨m⟩",
            "",
            "mean multiplicative bias over PSFs",
            s.m_mean,
            |b| b.m_mean,
            4,
        ),
        (
            "σ",
            "c",
            "scatter of c₁, c₂ over PSFs",
            s.sigma_c,
            |b| b.sigma_c,
            5,
        ),
        ("⟨q⟩", "", "mean non-linearity", s.q_mean, |b| b.q_mean, 3),
        (
            "⟨m⟩",
            "galaxies",
            "galaxies only (uncontaminated)",
            s.m_uncontaminated_mean,
            |b| b.m_uncontaminated_mean,
            4,
        ),
        (
            "⟨m⟩",
            "selection",
            "selection bias",
            s.m_selc_mean,
            |b| b.m_selc_mean,
            4,
        ),
        (
            "⟨m⟩",
            "weight",
            "weight bias",
            s.m_weight_mean,
            |b| b.m_weight_mean,
            4,
        ),
        (
            "⟨m⟩",
            "isolated",
            "isolated galaxies (no blending)",
            s.m_isolated_mean,
            |b| b.m_isolated_mean,
            4,
        ),
    ];
    let mut no_width = false;
    let summary: Vec<SummaryRow> = rows
        .into_iter()
        .map(|(label, sub, what, v, pick, dp)| {
            let ci = b.and_then(pick);
            let ends = ci.and_then(|ci| interval_ends(ci, dp, signed));
            no_width |= ci.is_some() && ends.is_none();
            let (lo, hi) = ends.unwrap_or_else(|| ("—".into(), "—".into()));
            SummaryRow {
                label,
                sub,
                what,
                value: signed(v, dp),
                lo,
                hi,
            }
        })
        .collect();
    // report.md's caveat, in its words: the base fields are the images per
    // dataset.
    let fields = r.datasets.iter().map(|d| d.n_images).max().unwrap_or(0);
    let caveat = b.filter(|_| fields < FEW_BASE_FIELDS).map(|b| {
        format!(
            "the interval resamples only {fields} base field{} (images per dataset), so it can \
             take at most {} distinct values and is no reliable {:.0} % interval; trust it from \
             about {FEW_BASE_FIELDS} base fields on.",
            if fields == 1 { "" } else { "s" },
            distinct_resamples(fields),
            100.0 * b.confidence
        )
    });
    let psfs = r
        .psfs
        .iter()
        .map(|p| PsfRow {
            psf: p.psf.clone(),
            m: pm(p.m, p.m_err, 4),
            q: pm(p.q, p.q_err, 3),
            c1: pm(p.c1, p.c1_err, 5),
            c2: pm(p.c2, p.c2_err, 5),
            m_uncontaminated: pm(p.m_uncontaminated, p.m_uncontaminated_err, 4),
            linear: p.linear,
        })
        .collect();
    let datasets = r
        .datasets
        .iter()
        .map(|d| DatasetRow {
            dataset: d.dataset.clone(),
            psf: d.psf.clone(),
            g1_true: signed(Some(d.g1_true), 4),
            g2_true: signed(Some(d.g2_true), 4),
            g1: pm(d.g1, d.g1_err, 4),
            g2: pm(d.g2, d.g2_err, 4),
            n_images: d.n_images,
            n_objects: d.n_objects,
            pct_stars: fixed(Some(d.pct_stars), 1),
            pct_false: fixed(Some(d.pct_false), 1),
        })
        .collect();
    ReportTables {
        summary,
        confidence: b
            .map(|b| format!("{:.0} %", 100.0 * b.confidence))
            .unwrap_or_default(),
        n_resamples: b.map_or(0, |b| b.n_resamples),
        psfs,
        datasets,
        warnings: r.warnings.clone(),
        caveat,
        no_width,
    }
}
