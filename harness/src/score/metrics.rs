//! The metrics of SPEC §7 (paper section 4) as pure functions of tables.
//!
//! Stage 1, [`image_stats`]: one image's submitted rows, their matches and
//! its truth table are reduced to sums ([`ImageStats`]). Stage 2,
//! [`score_tables`]: the sums of every image give the per-dataset numbers,
//! the per-PSF fits, the summary and the binned residuals. The bootstrap
//! reruns stage 2 on resampled images. Every definition is written out in
//! `docs/scoring.md`.

use crate::read::submission::SubRow;
use crate::score::fit::{PolyFit, fit_poly, mean_and_error, population_std};
use crate::score::isolation::Isolation;
use crate::score::matching::match_nearest;
use crate::score::report::{
    BinReport, Binned, DatasetReport, FitChoice, FitKind, PsfReport, Summary,
};
use stepsim_contract::run_layout::Datasets;
use stepsim_contract::truth::TruthRow;

/// Edges of the true-magnitude bins (I, Vega); the outer bins are open.
pub const MAG_EDGES: [f64; 8] = [
    f64::NEG_INFINITY,
    20.0,
    21.0,
    22.0,
    23.0,
    24.0,
    25.0,
    f64::INFINITY,
];

/// Edges of the true disk scale length bins (arcsec); the last is open.
/// Pure bulges (`disk_h_arcsec` = 0) fall in the first bin.
pub const DISK_EDGES_ARCSEC: [f64; 8] = [
    f64::NEG_INFINITY,
    0.1,
    0.2,
    0.3,
    0.5,
    0.8,
    1.2,
    f64::INFINITY,
];

/// Q_c constants (GREAT3, Mandelbaum et al. 2014, eq. 15 style).
pub const QC_NORM: f64 = 2000.0 * 1.232;
/// Target additive bias σ*_c.
pub const QC_SIGMA_C: f64 = 2e-4;
/// Target multiplicative bias σ*_m.
pub const QC_SIGMA_M: f64 = 2e-3;
/// σ²_min added under the root.
pub const QC_FLOOR: f64 = 4.0;

/// Weighted sums of the shear estimates of the galaxies in one bin.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BinAcc {
    /// Rows.
    pub n: u64,
    /// Σw.
    pub sw: f64,
    /// Σw γ̂1.
    pub swe1: f64,
    /// Σw γ̂2.
    pub swe2: f64,
}

impl BinAcc {
    fn add(&mut self, w: f64, e1: f64, e2: f64) {
        self.n += 1;
        self.sw += w;
        self.swe1 += w * e1;
        self.swe2 += w * e2;
    }
}

/// The sums one image contributes to every metric.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ImageStats {
    /// Dataset index.
    pub dataset: usize,
    /// Base field.
    pub field: u32,
    /// Rows.
    pub n: u64,
    /// Rows matched to galaxies.
    pub n_gal: u64,
    /// Rows matched to stars.
    pub n_star: u64,
    /// Rows matched to nothing.
    pub n_false: u64,
    /// Σw, Σw over stars, Σw over false detections.
    pub sw: f64,
    /// Σw over rows matched to stars.
    pub sw_star: f64,
    /// Σw over unmatched rows.
    pub sw_false: f64,
    /// All rows: Σw γ̂1, Σw γ̂2.
    pub all: BinAcc,
    /// Rows matched to galaxies: Σw, Σw γ̂1, Σw γ̂2.
    pub gal: BinAcc,
    /// Matched galaxies: Σ e1 (true sheared), Σw e1.
    pub sum_e1_true: f64,
    /// Σw e1 (true sheared).
    pub sw_e1_true: f64,
    /// Matched galaxies: Σ e1_int, Σ e2_int, Σw e1_int.
    pub sum_e1_int: f64,
    /// Σ e2_int.
    pub sum_e2_int: f64,
    /// Σw e1_int.
    pub sw_e1_int: f64,
    /// Galaxy rows by true magnitude ([`MAG_EDGES`]).
    pub by_mag: Vec<BinAcc>,
    /// Galaxy rows by true disk scale length ([`DISK_EDGES_ARCSEC`]).
    pub by_disk: Vec<BinAcc>,
    /// Rows matched to isolated galaxies ([`crate::isolated`]).
    pub iso: BinAcc,
    /// Chance matches: lattice positions within the match radius of a
    /// truth object ([`chance_matches`]).
    pub chance_hits: u64,
    /// Lattice positions tried ([`CHANCE_LATTICE`]²).
    pub chance_samples: u64,
}

/// Positions per image axis of the lattice that measures the chance-match
/// rate (128² positions per image).
pub const CHANCE_LATTICE: usize = 128;

/// How often a detection at a random on-image position would count as
/// real: (hits, samples) over a regular [`CHANCE_LATTICE`]² lattice of
/// positions covering the image (FITS x = 0.5 + (i + ½) W / 128, likewise
/// y), a hit being a position with a truth object (any kind, on or off the
/// image) within `radius_px`, as the matching decides.
///
/// Each truth object marks the few lattice positions near it (the lattice
/// is regular, so they are found by index), instead of matching all 128²
/// positions against the truth: the same hits as
/// [`chance_matches_slow`] (same positions, same distance formula),
/// about 10× less work on a STEP image.
pub fn chance_matches(
    truth: &[TruthRow],
    width_px: u32,
    height_px: u32,
    radius_px: f64,
) -> (u64, u64) {
    let k = CHANCE_LATTICE;
    let (w, h) = (f64::from(width_px), f64::from(height_px));
    // The matcher treats a radius that is not > 0 (NaN included) as 0.
    let r = if radius_px > 0.0 { radius_px } else { 0.0 };
    let r2 = r * r;
    let kf = k as f64;
    // Lattice indices whose position may be within r of v along one axis,
    // widened by one on each side against rounding (the distance test
    // below decides).
    let span = |v: f64, size: f64| -> Option<(usize, usize)> {
        let lo = ((v - r - 0.5) * kf / size - 0.5).floor() - 1.0;
        let hi = ((v + r - 0.5) * kf / size - 0.5).ceil() + 1.0;
        if lo.is_nan() || hi.is_nan() || lo > hi || hi < 0.0 || lo > kf - 1.0 {
            return None;
        }
        Some((lo.max(0.0) as usize, hi.min(kf - 1.0) as usize))
    };
    let mut hit = vec![false; k * k];
    for t in truth {
        let (Some((i0, i1)), Some((j0, j1))) = (span(t.x, w), span(t.y, h)) else {
            continue;
        };
        for j in j0..=j1 {
            let qy = 0.5 + (j as f64 + 0.5) * h / kf;
            for i in i0..=i1 {
                let qx = 0.5 + (i as f64 + 0.5) * w / kf;
                if (t.x - qx).powi(2) + (t.y - qy).powi(2) <= r2 {
                    hit[j * k + i] = true;
                }
            }
        }
    }
    (hit.iter().filter(|&&b| b).count() as u64, (k * k) as u64)
}

/// The slow twin of [`chance_matches`]: every lattice position goes
/// through the matcher ([`match_nearest`]) as a submitted row would.
pub fn chance_matches_slow(
    truth: &[TruthRow],
    width_px: u32,
    height_px: u32,
    radius_px: f64,
) -> (u64, u64) {
    let k = CHANCE_LATTICE;
    let (w, h) = (f64::from(width_px), f64::from(height_px));
    let lattice: Vec<(f64, f64)> = (0..k * k)
        .map(|n| {
            let (i, j) = ((n % k) as f64, (n / k) as f64);
            (
                0.5 + (i + 0.5) * w / k as f64,
                0.5 + (j + 0.5) * h / k as f64,
            )
        })
        .collect();
    let txy: Vec<(f64, f64)> = truth.iter().map(|t| (t.x, t.y)).collect();
    let hits = match_nearest(&txy, &lattice, radius_px)
        .iter()
        .filter(|m| m.is_some())
        .count();
    (hits as u64, (k * k) as u64)
}

/// Index of the bin of `v` among `edges` (lower edge inclusive).
pub fn bin_of(edges: &[f64], v: f64) -> usize {
    let k = edges.partition_point(|e| *e <= v);
    k.saturating_sub(1).min(edges.len() - 2)
}

/// Reduces one image: `rows` submitted, `matches[i]` the truth index of row
/// i (or `None`), `truth` the image's truth table.
pub fn image_stats(
    dataset: usize,
    field: u32,
    rows: &[SubRow],
    matches: &[Option<usize>],
    truth: &[TruthRow],
) -> ImageStats {
    let mut s = ImageStats {
        dataset,
        field,
        by_mag: vec![BinAcc::default(); MAG_EDGES.len() - 1],
        by_disk: vec![BinAcc::default(); DISK_EDGES_ARCSEC.len() - 1],
        ..Default::default()
    };
    for (r, m) in rows.iter().zip(matches) {
        let w = r.weight;
        s.n += 1;
        s.sw += w;
        s.all.add(w, r.e1, r.e2);
        match m.map(|j| &truth[j]) {
            None => {
                s.n_false += 1;
                s.sw_false += w;
            }
            Some(t) if t.is_star() => {
                s.n_star += 1;
                s.sw_star += w;
            }
            Some(t) => {
                s.n_gal += 1;
                s.gal.add(w, r.e1, r.e2);
                s.sum_e1_true += t.e1;
                s.sw_e1_true += w * t.e1;
                s.sum_e1_int += t.e1_int;
                s.sum_e2_int += t.e2_int;
                s.sw_e1_int += w * t.e1_int;
                s.by_mag[bin_of(&MAG_EDGES, t.mag)].add(w, r.e1, r.e2);
                s.by_disk[bin_of(&DISK_EDGES_ARCSEC, t.disk_h_arcsec)].add(w, r.e1, r.e2);
            }
        }
    }
    s
}

/// Matches one image's submitted `rows` to its `truth` table (nearest
/// truth object within `radius_px`, [`match_nearest`]), reduces them
/// ([`image_stats`]), sums the rows matched to isolated galaxies (no
/// neighbour above the class's fraction of the flux within its radius,
/// separations taken in its plane: [`crate::score::isolation::isolated`])
/// and measures the chance-match rate of the image (`size_px` = (width,
/// height), [`chance_matches`]).
pub fn match_image(
    dataset: usize,
    field: u32,
    rows: &[SubRow],
    truth: &[TruthRow],
    radius_px: f64,
    size_px: (u32, u32),
    isolation: Isolation,
) -> ImageStats {
    let txy: Vec<(f64, f64)> = truth.iter().map(|t| (t.x, t.y)).collect();
    let qxy: Vec<(f64, f64)> = rows.iter().map(|r| (r.x, r.y)).collect();
    let m = match_nearest(&txy, &qxy, radius_px);
    let mut s = image_stats(dataset, field, rows, &m, truth);
    let iso = crate::score::isolation::isolated(truth, isolation);
    for (r, j) in rows.iter().zip(&m) {
        if let Some(j) = *j
            && iso[j]
        {
            s.iso.add(r.weight, r.e1, r.e2);
        }
    }
    (s.chance_hits, s.chance_samples) = chance_matches(truth, size_px.0, size_px.1, radius_px);
    s
}

/// A dataset as the metrics need it.
#[derive(Debug, Clone, PartialEq)]
pub struct DatasetMeta {
    /// Opaque id.
    pub dataset: String,
    /// PSF index (groups datasets into PSFs).
    pub psf_id: u32,
    /// PSF name.
    pub psf: String,
    /// Applied g1.
    pub g1: f64,
    /// Applied g2.
    pub g2: f64,
}

impl DatasetMeta {
    /// The metrics' table of every dataset of a run (`datasets.json`), in
    /// dataset order.
    pub fn of_run(datasets: &Datasets) -> Vec<Self> {
        datasets
            .datasets
            .iter()
            .map(|d| Self {
                dataset: d.dataset.clone(),
                psf_id: d.psf_id,
                psf: d.psf.clone(),
                g1: d.g1,
                g2: d.g2,
            })
            .collect()
    }
}

/// A per-dataset quantity measured on every image and reduced per base
/// field: the images of one field (the field and its rotated twin) are
/// averaged first, then the mean and its error are taken over fields. Base
/// fields are the independent units: rotated twins share their galaxies,
/// and every dataset shows the same fields.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FieldSeries {
    /// (base field, mean over the field's images), sorted by field.
    pub fields: Vec<(u32, f64)>,
    /// Mean over fields.
    pub mean: Option<f64>,
    /// Standard deviation over fields (n − 1) / √n_fields.
    pub err: Option<f64>,
}

impl FieldSeries {
    /// Reduces `value` of each image (images where it is `None` are left
    /// out).
    pub fn of(imgs: &[&ImageStats], value: impl Fn(&ImageStats) -> Option<f64>) -> Self {
        let mut acc: std::collections::BTreeMap<u32, (f64, usize)> = Default::default();
        for s in imgs {
            if let Some(v) = value(s) {
                let e = acc.entry(s.field).or_default();
                e.0 += v;
                e.1 += 1;
            }
        }
        let fields: Vec<(u32, f64)> = acc
            .into_iter()
            .map(|(f, (sum, n))| (f, sum / n as f64))
            .collect();
        let v: Vec<f64> = fields.iter().map(|p| p.1).collect();
        let (mean, err) = mean_and_error(&v);
        Self { fields, mean, err }
    }
}

/// Error of a linear combination Σ_d l_d ȳ_d of per-dataset means ȳ_d =
/// mean over the fields of `series[d]`, with base fields as the independent
/// units (a field's contribution to every dataset moves together):
/// σ² = F/(F − 1) Σ_f u_f², u_f = Σ_d l_d (y_{d,f} − ȳ_d) / F_d, over the F
/// fields that appear anywhere (F_d those of dataset d). For one dataset this
/// is the standard deviation over fields / √F. `None` with fewer than two
/// fields or a series without a mean.
pub fn paired_error(l: &[f64], series: &[&FieldSeries]) -> Option<f64> {
    let mut u: std::collections::BTreeMap<u32, f64> = Default::default();
    for (ld, s) in l.iter().zip(series) {
        let mean = s.mean?;
        let nf = s.fields.len() as f64;
        for &(f, v) in &s.fields {
            *u.entry(f).or_default() += ld * (v - mean) / nf;
        }
    }
    let nf = u.len();
    if nf < 2 {
        return None;
    }
    let ss: f64 = u.values().map(|x| x * x).sum();
    Some((ss * nf as f64 / (nf - 1) as f64).sqrt())
}

/// Per-dataset values that feed the fits.
#[derive(Debug, Clone, Default)]
struct Core {
    g1: FieldSeries,
    g2: FieldSeries,
    g1u: FieldSeries,
    g1iso: FieldSeries,
    g2iso: FieldSeries,
    e1s: FieldSeries,
    e2s: FieldSeries,
    dw: FieldSeries,
}

fn ratio(a: f64, b: f64) -> Option<f64> {
    (b != 0.0).then(|| a / b)
}

fn sn(g_true: f64, err: Option<f64>) -> Option<f64> {
    match err {
        Some(e) if g_true != 0.0 && e > 0.0 => Some(g_true / e),
        _ => None,
    }
}

fn dataset_numbers(
    meta: &DatasetMeta,
    imgs: &[&ImageStats],
    area_arcmin2: f64,
) -> (DatasetReport, Core) {
    let core = Core {
        g1: FieldSeries::of(imgs, |s| ratio(s.all.swe1, s.all.sw)),
        g2: FieldSeries::of(imgs, |s| ratio(s.all.swe2, s.all.sw)),
        g1u: FieldSeries::of(imgs, |s| ratio(s.gal.swe1, s.gal.sw)),
        g1iso: FieldSeries::of(imgs, |s| ratio(s.iso.swe1, s.iso.sw)),
        g2iso: FieldSeries::of(imgs, |s| ratio(s.iso.swe2, s.iso.sw)),
        e1s: FieldSeries::of(imgs, |s| ratio(s.sum_e1_int, s.n_gal as f64)),
        e2s: FieldSeries::of(imgs, |s| ratio(s.sum_e2_int, s.n_gal as f64)),
        dw: FieldSeries::of(imgs, |s| {
            Some(ratio(s.sum_e1_int, s.n_gal as f64)? - ratio(s.sw_e1_int, s.gal.sw)?)
        }),
    };
    let n: u64 = imgs.iter().map(|s| s.n).sum();
    let sw: f64 = imgs.iter().map(|s| s.sw).sum();
    let sw_star: f64 = imgs.iter().map(|s| s.sw_star).sum();
    let sw_false: f64 = imgs.iter().map(|s| s.sw_false).sum();
    let n_star: u64 = imgs.iter().map(|s| s.n_star).sum();
    let n_false: u64 = imgs.iter().map(|s| s.n_false).sum();
    let chance_hits: u64 = imgs.iter().map(|s| s.chance_hits).sum();
    let chance_samples: u64 = imgs.iter().map(|s| s.chance_samples).sum();
    let pct = |a: f64, b: f64| if b > 0.0 { 100.0 * a / b } else { 0.0 };
    let shot = FieldSeries::of(imgs, |s| ratio(s.sum_e1_true, s.n_gal as f64)).err;
    let shot_w = FieldSeries::of(imgs, |s| ratio(s.sw_e1_true, s.gal.sw)).err;
    let rep = DatasetReport {
        dataset: meta.dataset.clone(),
        psf: meta.psf.clone(),
        g1_true: meta.g1,
        g2_true: meta.g2,
        n_images: imgs.len(),
        n_objects: n,
        g1: core.g1.mean,
        g1_err: core.g1.err,
        g2: core.g2.mean,
        g2_err: core.g2.err,
        ngal_per_arcmin2: if imgs.is_empty() {
            0.0
        } else {
            n as f64 / (imgs.len() as f64 * area_arcmin2)
        },
        pct_stars: pct(n_star as f64, n as f64),
        pct_false: pct(n_false as f64, n as f64),
        pct_stars_weighted: (sw > 0.0).then(|| pct(sw_star, sw)),
        pct_false_weighted: (sw > 0.0).then(|| pct(sw_false, sw)),
        pct_chance_match: (chance_samples > 0)
            .then(|| pct(chance_hits as f64, chance_samples as f64)),
        snr: sn(meta.g1, core.g1.err),
        sn_shot: sn(meta.g1, shot),
        sn_shot_weighted: sn(meta.g1, shot_w),
    };
    (rep, core)
}

/// The least number of distinct shears at which the quadratic is fitted:
/// with three, q γ² + m γ + c passes through every point, so the data
/// cannot test it (no residual degree of freedom).
pub const MIN_SHEARS_QUADRATIC: usize = 4;

/// The quadratic is kept when |q| ≥ `Q_SIGNIFICANCE` σ_q.
pub const Q_SIGNIFICANCE: f64 = 2.0;

/// Why a fit is linear or quadratic ([`Response::why`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub enum ModelWhy {
    /// Fewer than [`MIN_SHEARS_QUADRATIC`] distinct shears (the count):
    /// linear.
    FewShears(usize),
    /// |q| / σ_q of the quadratic fit, at least [`Q_SIGNIFICANCE`]: kept.
    Significant(f64),
    /// |q| / σ_q below [`Q_SIGNIFICANCE`]: refitted with q = 0.
    NotSignificant(f64),
    /// σ_q could not be determined: refitted with q = 0.
    NoQError,
    /// The caller fixed the model (the bootstrap keeps the full data's).
    #[default]
    Fixed,
}

impl ModelWhy {
    /// One lower-case sentence for the report.
    pub fn sentence(&self) -> String {
        match *self {
            Self::FewShears(n) => format!(
                "linear: {n} distinct shear{}, and the quadratic is fitted only from {MIN_SHEARS_QUADRATIC} on (with 3 it passes through every point and cannot be tested)",
                if n == 1 { "" } else { "s" }
            ),
            Self::Significant(z) => {
                format!("quadratic: |q| = {z:.1} σ_q ≥ {Q_SIGNIFICANCE} σ_q")
            }
            Self::NotSignificant(z) => {
                format!("linear: |q| = {z:.1} σ_q < {Q_SIGNIFICANCE} σ_q, refitted with q = 0")
            }
            Self::NoQError => "linear: σ_q undetermined, refitted with q = 0".to_owned(),
            Self::Fixed => "fixed by the caller".to_owned(),
        }
    }
}

/// The fitted response of one component: γ − γ_true = q γ_true² + m γ_true + c.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Response {
    /// m and its error.
    pub m: ValErr,
    /// q and its error (q = 0, error `None` when linear).
    pub q: ValErr,
    /// c and its error.
    pub c: ValErr,
    /// True when the linear model was kept.
    pub linear: bool,
    /// Why that model.
    pub why: ModelWhy,
}

impl Response {
    /// The model and its reason as the report states them.
    pub fn choice(&self) -> FitChoice {
        FitChoice {
            model: if self.linear {
                FitKind::Linear
            } else {
                FitKind::Quadratic
            },
            reason: self.why.sentence(),
        }
    }
}

fn coef(f: &PolyFit, k: usize) -> ValErr {
    ValErr {
        value: Some(f.coef[k]),
        err: f.err[k],
    }
}

/// Fits γ − γ_true = q γ_true² + m γ_true + c over points (γ_true, γ, σ),
/// by the one rule of every fitted family: the quadratic is fitted only
/// with at least [`MIN_SHEARS_QUADRATIC`] distinct shears, and kept when
/// |q| ≥ [`Q_SIGNIFICANCE`] σ_q; otherwise (or when σ_q is unknown) the fit
/// is linear, q = 0. With one point only c = γ − γ_true. The errors are
/// those of the weighted fit (`fit_poly`), the points taken as
/// independent; the scoring uses `fit_response_fields`.
pub fn fit_response(points: &[(f64, f64, Option<f64>)]) -> Response {
    let x: Vec<f64> = points.iter().map(|p| p.0).collect();
    let y: Vec<f64> = points.iter().map(|p| p.1 - p.0).collect();
    let s: Vec<Option<f64>> = points.iter().map(|p| p.2).collect();
    response(&x, &y, &s, None, None)
}

/// [`fit_response`] for per-dataset [`FieldSeries`] of γ at applied shears
/// `x`, with the errors of m, q and c from the base fields
/// ([`paired_error`]: datasets that show the same fields are not
/// independent). `linear` fixes the model (`Some(true)` linear,
/// `Some(false)` quadratic) instead of choosing it from the data: the
/// bootstrap keeps the model of the full data in every resample.
pub fn fit_response_fields(x: &[f64], series: &[&FieldSeries], linear: Option<bool>) -> Response {
    let (x, y, s, kept) = fit_inputs(x, series, |x| x);
    response(&x, &y, &s, Some(&kept), linear)
}

/// The same rule for a quantity that is not a shear estimate (the
/// selection and weight biases): y = q γ_true² + m γ_true + c fitted to
/// the series' means themselves.
fn fit_bias_fields(x: &[f64], series: &[&FieldSeries], linear: Option<bool>) -> Response {
    let (x, y, s, kept) = fit_inputs(x, series, |_| 0.0);
    response(&x, &y, &s, Some(&kept), linear)
}

/// Points with a mean: (x, y − offset(x), σ, series).
#[allow(clippy::type_complexity)]
fn fit_inputs<'a>(
    x: &[f64],
    series: &[&'a FieldSeries],
    offset: impl Fn(f64) -> f64,
) -> (Vec<f64>, Vec<f64>, Vec<Option<f64>>, Vec<&'a FieldSeries>) {
    let mut out = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (&xi, s) in x.iter().zip(series) {
        if let Some(m) = s.mean {
            out.0.push(xi);
            out.1.push(m - offset(xi));
            out.2.push(s.err);
            out.3.push(*s);
        }
    }
    out
}

/// The weighted polynomial fit of degree p − 1, with the coefficient errors
/// from the fields when `series` is given and they are defined (else the
/// fit's own).
fn fit_fields(
    x: &[f64],
    y: &[f64],
    s: &[Option<f64>],
    series: Option<&[&FieldSeries]>,
    p: usize,
) -> Option<PolyFit> {
    let mut f = fit_poly(x, y, s, p)?;
    if let Some(series) = series {
        // The coefficients are linear in y: row k of the hat matrix is the
        // fit of the unit vectors.
        let n = x.len();
        let mut rows = vec![vec![0.0; n]; p];
        for d in 0..n {
            let mut e = vec![0.0; n];
            e[d] = 1.0;
            let fd = fit_poly(x, &e, s, p)?;
            for (k, row) in rows.iter_mut().enumerate() {
                row[d] = fd.coef[k];
            }
        }
        for (k, row) in rows.iter().enumerate() {
            if let Some(e) = paired_error(row, series) {
                f.err[k] = Some(e);
            }
        }
    }
    Some(f)
}

/// The number of distinct values of `x`.
fn distinct(x: &[f64]) -> usize {
    let mut v = x.to_vec();
    v.sort_by(f64::total_cmp);
    v.dedup();
    v.len()
}

fn response(
    x: &[f64],
    y: &[f64],
    s: &[Option<f64>],
    series: Option<&[&FieldSeries]>,
    linear: Option<bool>,
) -> Response {
    let n_shears = distinct(x);
    let try_quadratic = match linear {
        Some(l) => !l && x.len() >= 3,
        None => n_shears >= MIN_SHEARS_QUADRATIC,
    };
    let mut why = match linear {
        Some(_) => ModelWhy::Fixed,
        None => ModelWhy::FewShears(n_shears),
    };
    if let Some(f) = try_quadratic
        .then(|| fit_fields(x, y, s, series, 3))
        .flatten()
    {
        let z = f.err[2].map(|qe| f.coef[2].abs() / qe);
        let keep = match linear {
            Some(l) => !l,
            None => z.is_some_and(|z| z >= Q_SIGNIFICANCE),
        };
        if linear.is_none() {
            why = match z {
                Some(z) if keep => ModelWhy::Significant(z),
                Some(z) => ModelWhy::NotSignificant(z),
                None => ModelWhy::NoQError,
            };
        }
        if keep {
            return Response {
                m: coef(&f, 1),
                q: coef(&f, 2),
                c: coef(&f, 0),
                linear: false,
                why,
            };
        }
    }
    if let Some(f) = fit_fields(x, y, s, series, 2) {
        return Response {
            m: coef(&f, 1),
            q: ValErr {
                value: Some(0.0),
                err: None,
            },
            c: coef(&f, 0),
            linear: true,
            why,
        };
    }
    Response {
        m: ValErr::default(),
        q: ValErr::default(),
        c: plain_mean(y, s, series),
        linear: true,
        why,
    }
}

/// A value and its error, either possibly missing.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ValErr {
    /// The value.
    pub value: Option<f64>,
    /// Its error (one σ).
    pub err: Option<f64>,
}

/// Plain mean of `y`; its error from the fields when `series` is given and
/// it is defined, else sqrt(Σσ²)/n when every σ is known.
fn plain_mean(y: &[f64], s: &[Option<f64>], series: Option<&[&FieldSeries]>) -> ValErr {
    if y.is_empty() {
        return ValErr::default();
    }
    let n = y.len() as f64;
    let mean = y.iter().sum::<f64>() / n;
    let paired = series.and_then(|series| paired_error(&vec![1.0 / n; y.len()], series));
    let err = paired.or_else(|| {
        s.iter()
            .map(|e| e.map(|e| e * e))
            .sum::<Option<f64>>()
            .map(|v| v.sqrt() / n)
    });
    ValErr {
        value: Some(mean),
        err,
    }
}

/// The fit model of each PSF (`true` = linear), chosen on the full data
/// and kept in every bootstrap resample.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FitModel {
    /// γ1 response.
    pub g1_linear: bool,
    /// γ2 response (when fitted).
    pub g2_linear: Option<bool>,
    /// γ1 response of the rows matched to galaxies.
    pub g1u_linear: bool,
    /// γ1 response of the rows matched to isolated galaxies.
    pub g1iso_linear: bool,
    /// Selection bias, ⟨e1_int⟩ against γ1_true.
    pub selc_linear: bool,
    /// Weight bias against γ1_true.
    pub weight_linear: bool,
}

impl FitModel {
    /// Every family linear.
    pub const LINEAR: Self = Self {
        g1_linear: true,
        g2_linear: None,
        g1u_linear: true,
        g1iso_linear: true,
        selc_linear: true,
        weight_linear: true,
    };
}

fn psf_numbers(
    name: &str,
    cores: &[(&DatasetMeta, &Core)],
    model: Option<FitModel>,
) -> (PsfReport, FitModel) {
    let g1: Vec<f64> = cores.iter().map(|(m, _)| m.g1).collect();
    let pick = |f: fn(&Core) -> &FieldSeries| -> Vec<&FieldSeries> {
        cores.iter().map(|(_, c)| f(c)).collect()
    };
    let r1 = fit_response_fields(&g1, &pick(|c| &c.g1), model.map(|m| m.g1_linear));
    let g2_const = cores.windows(2).all(|w| w[0].0.g2 == w[1].0.g2);
    let g2: Vec<f64> = cores.iter().map(|(m, _)| m.g2).collect();
    let (c2, r2) = if g2_const {
        let (_, y, s, kept) = fit_inputs(&g2, &pick(|c| &c.g2), |x| x);
        (plain_mean(&y, &s, Some(&kept)), None)
    } else {
        let r = fit_response_fields(&g2, &pick(|c| &c.g2), model.and_then(|m| m.g2_linear));
        (r.c, Some(r))
    };
    let ru = fit_response_fields(&g1, &pick(|c| &c.g1u), model.map(|m| m.g1u_linear));
    let ri = fit_response_fields(&g1, &pick(|c| &c.g1iso), model.map(|m| m.g1iso_linear));
    let c2_iso = {
        let (_, y, s, kept) = fit_inputs(&g2, &pick(|c| &c.g2iso), |x| x);
        plain_mean(&y, &s, Some(&kept))
    };
    let rs = fit_bias_fields(&g1, &pick(|c| &c.e1s), model.map(|m| m.selc_linear));
    let c2_selc = {
        let (_, y, s, kept) = fit_inputs(&g1, &pick(|c| &c.e2s), |_| 0.0);
        plain_mean(&y, &s, Some(&kept))
    };
    let rw = fit_bias_fields(&g1, &pick(|c| &c.dw), model.map(|m| m.weight_linear));
    let used = FitModel {
        g1_linear: r1.linear,
        g2_linear: r2.as_ref().map(|r| r.linear),
        g1u_linear: ru.linear,
        g1iso_linear: ri.linear,
        selc_linear: rs.linear,
        weight_linear: rw.linear,
    };
    let rep = PsfReport {
        psf: name.to_owned(),
        m: r1.m.value,
        m_err: r1.m.err,
        q: r1.q.value,
        q_err: r1.q.err,
        c1: r1.c.value,
        c1_err: r1.c.err,
        c2: c2.value,
        c2_err: c2.err,
        linear: r1.linear,
        fit: Some(r1.choice()),
        fit2: r2.as_ref().map(Response::choice),
        m2: r2.as_ref().and_then(|r| r.m.value),
        m2_err: r2.as_ref().and_then(|r| r.m.err),
        q2: r2.as_ref().and_then(|r| r.q.value),
        q2_err: r2.as_ref().and_then(|r| r.q.err),
        m_uncontaminated: ru.m.value,
        m_uncontaminated_err: ru.m.err,
        q_uncontaminated: ru.q.value,
        q_uncontaminated_err: ru.q.err,
        fit_uncontaminated: Some(ru.choice()),
        m_selc: rs.m.value,
        m_selc_err: rs.m.err,
        q_selc: rs.q.value,
        q_selc_err: rs.q.err,
        fit_selc: Some(rs.choice()),
        c1_selc: rs.c.value,
        c1_selc_err: rs.c.err,
        c2_selc: c2_selc.value,
        c2_selc_err: c2_selc.err,
        m_weight: rw.m.value,
        m_weight_err: rw.m.err,
        q_weight: rw.q.value,
        q_weight_err: rw.q.err,
        fit_weight: Some(rw.choice()),
        c1_weight: rw.c.value,
        c1_weight_err: rw.c.err,
        m_isolated: ri.m.value,
        m_isolated_err: ri.m.err,
        q_isolated: ri.q.value,
        q_isolated_err: ri.q.err,
        fit_isolated: Some(ri.choice()),
        c1_isolated: ri.c.value,
        c1_isolated_err: ri.c.err,
        c2_isolated: c2_iso.value,
        c2_isolated_err: c2_iso.err,
    };
    (rep, used)
}

fn mean_of(v: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    let v: Vec<f64> = v.flatten().collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// Q_c = 2000·1.232 / sqrt(⟨(c1/σ*_c)² + (c2/σ*_c)² + (m/σ*_m)² [+ (m2/σ*_m)²]⟩_PSF + 4),
/// the average over PSFs of the squared scaled biases (see docs/scoring.md).
pub fn q_c(psfs: &[PsfReport]) -> Option<f64> {
    let terms: Vec<f64> = psfs
        .iter()
        .filter_map(|p| {
            let mut t = (p.c1? / QC_SIGMA_C).powi(2) + (p.c2? / QC_SIGMA_C).powi(2);
            t += (p.m? / QC_SIGMA_M).powi(2);
            if let Some(m2) = p.m2 {
                t += (m2 / QC_SIGMA_M).powi(2);
            }
            Some(t)
        })
        .collect();
    if terms.is_empty() {
        return None;
    }
    let mean = terms.iter().sum::<f64>() / terms.len() as f64;
    Some(QC_NORM / (mean + QC_FLOOR).sqrt())
}

/// The summary over PSFs.
pub fn summarize(psfs: &[PsfReport]) -> Summary {
    let pooled = |a: fn(&PsfReport) -> Option<f64>, b: fn(&PsfReport) -> Option<f64>| {
        let v: Vec<f64> = psfs.iter().flat_map(|p| [a(p), b(p)]).flatten().collect();
        population_std(&v)
    };
    Summary {
        m_mean: mean_of(psfs.iter().map(|p| p.m)),
        q_mean: mean_of(psfs.iter().map(|p| p.q)),
        sigma_c: pooled(|p| p.c1, |p| p.c2),
        m_uncontaminated_mean: mean_of(psfs.iter().map(|p| p.m_uncontaminated)),
        m_selc_mean: mean_of(psfs.iter().map(|p| p.m_selc)),
        sigma_c_selc: pooled(|p| p.c1_selc, |p| p.c2_selc),
        m_weight_mean: mean_of(psfs.iter().map(|p| p.m_weight)),
        m_isolated_mean: mean_of(psfs.iter().map(|p| p.m_isolated)),
        sigma_c_isolated: pooled(|p| p.c1_isolated, |p| p.c2_isolated),
        q_c: q_c(psfs),
        pct_chance_match: None,
        bootstrap: None,
    }
}

/// Everything computed from image sums.
#[derive(Debug, Clone, PartialEq)]
pub struct Scores {
    /// Per dataset (datasets with at least one image).
    pub datasets: Vec<DatasetReport>,
    /// Per PSF, ordered by PSF id.
    pub psfs: Vec<PsfReport>,
    /// Averages over PSFs.
    pub summary: Summary,
    /// The fit model of each PSF, (psf id, model), ordered by PSF id.
    pub models: Vec<(u32, FitModel)>,
}

/// Per-dataset numbers, per-PSF fits and the summary from the image sums.
/// `stats` may hold several images of one dataset in any order; datasets
/// without images are left out. Images of the same `field` (a base field
/// and its rotated twin) are averaged before the statistics over fields.
pub fn score_tables(meta: &[DatasetMeta], stats: &[ImageStats], area_arcmin2: f64) -> Scores {
    score_tables_with(meta, stats, area_arcmin2, &[])
}

/// [`score_tables`] with the fit model of the PSFs listed in `models`
/// fixed (the others choose theirs from the data).
pub fn score_tables_with(
    meta: &[DatasetMeta],
    stats: &[ImageStats],
    area_arcmin2: f64,
    models: &[(u32, FitModel)],
) -> Scores {
    let mut by_ds: Vec<Vec<&ImageStats>> = vec![Vec::new(); meta.len()];
    for s in stats {
        by_ds[s.dataset].push(s);
    }
    let mut datasets = Vec::new();
    let mut cores = Vec::new();
    for (d, m) in meta.iter().enumerate() {
        if by_ds[d].is_empty() {
            continue;
        }
        let (rep, core) = dataset_numbers(m, &by_ds[d], area_arcmin2);
        datasets.push(rep);
        cores.push((m, core));
    }
    let mut psf_ids: Vec<u32> = cores.iter().map(|(m, _)| m.psf_id).collect();
    psf_ids.sort_unstable();
    psf_ids.dedup();
    let (psfs, used): (Vec<PsfReport>, Vec<(u32, FitModel)>) = psf_ids
        .iter()
        .map(|&p| {
            let mut group: Vec<(&DatasetMeta, &Core)> = cores
                .iter()
                .filter(|(m, _)| m.psf_id == p)
                .map(|(m, c)| (*m, c))
                .collect();
            group.sort_by(|a, b| a.0.g1.total_cmp(&b.0.g1));
            let fixed = models.iter().find(|m| m.0 == p).map(|m| m.1);
            let (rep, model) = psf_numbers(&group[0].0.psf, &group, fixed);
            (rep, (p, model))
        })
        .unzip();
    let mut summary = summarize(&psfs);
    summary.pct_chance_match = mean_of(datasets.iter().map(|d| d.pct_chance_match));
    Scores {
        datasets,
        psfs,
        summary,
        models: used,
    }
}

fn bin_report(
    meta: &[DatasetMeta],
    stats: &[ImageStats],
    lo: f64,
    hi: f64,
    pick: impl Fn(&ImageStats) -> BinAcc,
) -> BinReport {
    let mut by_ds: Vec<Vec<&ImageStats>> = vec![Vec::new(); meta.len()];
    let mut n = 0;
    for s in stats {
        n += pick(s).n;
        by_ds[s.dataset].push(s);
    }
    let comp = |k: usize| {
        let series: Vec<FieldSeries> = by_ds
            .iter()
            .enumerate()
            .map(|(d, imgs)| {
                FieldSeries::of(imgs, |s| {
                    let b = pick(s);
                    let (g, sum) = if k == 0 {
                        (meta[d].g1, b.swe1)
                    } else {
                        (meta[d].g2, b.swe2)
                    };
                    (b.sw > 0.0).then(|| sum / b.sw - g)
                })
            })
            .collect();
        let refs: Vec<&FieldSeries> = series.iter().collect();
        let (_, y, s, kept) = fit_inputs(&vec![0.0; refs.len()], &refs, |_| 0.0);
        plain_mean(&y, &s, Some(&kept))
    };
    let g1 = comp(0);
    let g2 = comp(1);
    let edge = |e: f64| e.is_finite().then_some(e);
    BinReport {
        lo: edge(lo),
        hi: edge(hi),
        n_objects: n,
        g1_residual: g1.value,
        g1_residual_err: g1.err,
        g2_residual: g2.value,
        g2_residual_err: g2.err,
    }
}

/// Residuals γ − γ_true of the matched galaxies binned in a true property:
/// for each bin and dataset, per-image weighted mean of the bin's galaxies
/// minus the applied shear, reduced over fields (`FieldSeries`), then the
/// plain mean over datasets (error from the fields, `paired_error`).
pub fn binned_residuals(
    meta: &[DatasetMeta],
    stats: &[ImageStats],
    variable: &str,
    edges: &[f64],
    pick: fn(&ImageStats) -> &[BinAcc],
) -> Binned {
    let all = bin_report(meta, stats, edges[0], edges[edges.len() - 1], |s| s.gal);
    let bins = (0..edges.len() - 1)
        .map(|k| bin_report(meta, stats, edges[k], edges[k + 1], |s| pick(s)[k]))
        .collect();
    Binned {
        variable: variable.to_owned(),
        all,
        bins,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chance_matches_equal_their_slow_twin() {
        use rand::{RngExt, SeedableRng};
        let mut rng = stepsim_contract::seed::SimRng::seed_from_u64(11);
        for case in 0..200 {
            let (w, h) = (rng.random_range(1..700u32), rng.random_range(1..700u32));
            let radius = match case % 10 {
                0 => 0.0,
                1 => f64::NAN,
                2 => -3.0,
                3 => 1e4,
                _ => rng.random_range(0.01..40.0),
            };
            let n = rng.random_range(0..300usize);
            let mut truth: Vec<TruthRow> = (0..n)
                .map(|_| TruthRow {
                    x: rng.random_range(-50.0..f64::from(w) + 50.0),
                    y: rng.random_range(-50.0..f64::from(h) + 50.0),
                    ..TruthRow::default()
                })
                .collect();
            // Objects exactly on lattice positions (ties at distance 0 and r).
            let k = CHANCE_LATTICE as f64;
            truth.push(TruthRow {
                x: 0.5 + 3.5 * f64::from(w) / k,
                y: 0.5 + 7.5 * f64::from(h) / k,
                ..TruthRow::default()
            });
            let fast = chance_matches(&truth, w, h, radius);
            let slow = chance_matches_slow(&truth, w, h, radius);
            assert_eq!(fast, slow, "case {case}: {w}x{h}, r {radius}, {n} objects");
        }
    }

    #[test]
    fn chance_matches_measure_the_area_within_the_radius() {
        let at = |x: f64, y: f64| TruthRow {
            x,
            y,
            ..TruthRow::default()
        };
        // A disc of radius 10 px in the middle of a 100² image: π 100 / 1e4.
        let (h, n) = chance_matches(&[at(50.5, 50.5)], 100, 100, 10.0);
        assert_eq!(n, 128 * 128);
        let f = h as f64 / n as f64;
        assert!((f - std::f64::consts::PI * 1e-2).abs() < 1e-3, "{f}");
        // An object off the image still catches positions on it: the disc's
        // segment beyond the edge x = 0.5 (centre 5.5 px outside).
        let (h, _) = chance_matches(&[at(-5.0, 50.5)], 100, 100, 10.0);
        let d: f64 = 5.5;
        let seg = 100.0 * (d / 10.0).acos() - d * (100.0 - d * d).sqrt();
        let f = h as f64 / n as f64;
        assert!((f - seg / 1e4).abs() < 5e-4, "{f} vs {}", seg / 1e4);
        assert_eq!(chance_matches(&[], 100, 100, 10.0), (0, n));
        // Per dataset and in the summary: the synthetic run's 196 objects
        // per field, all discs (r = 1″ = 5 px) on the image and disjoint.
        let spec = crate::synthetic::SynthSpec::small(2);
        let run = crate::synthetic::make_run(&spec);
        let rows = run.submission(&|t, _| Some((t.e1, t.e2, 1.0)));
        let scores = score_tables(&run.meta(), &run.stats(&rows, 1.0), 1.0);
        let want = 100.0 * 196.0 * std::f64::consts::PI * 25.0 / 9e4;
        for d in &scores.datasets {
            let got = d.pct_chance_match.unwrap();
            assert!((got - want).abs() < 0.2, "{got} vs {want}");
            assert_eq!(d.pct_false, 0.0);
        }
        let got = scores.summary.pct_chance_match.unwrap();
        assert!((got - want).abs() < 0.2, "{got} vs {want}");
    }

    #[test]
    fn paired_errors_follow_the_shared_fields() {
        let img = |dataset, field, g: f64| ImageStats {
            dataset,
            field,
            all: BinAcc {
                n: 1,
                sw: 1.0,
                swe1: g,
                swe2: 0.0,
            },
            ..Default::default()
        };
        let v = [0.01, -0.02, 0.03, 0.005];
        // One dataset: the error over fields, twins averaged first.
        let mut one = Vec::new();
        for (f, &x) in v.iter().enumerate() {
            one.push(img(0, f as u32, x + 0.1));
            one.push(img(0, f as u32, x - 0.1));
        }
        let refs: Vec<&ImageStats> = one.iter().collect();
        let s = FieldSeries::of(&refs, |s| Some(s.all.swe1));
        assert_eq!(s.fields.len(), 4);
        let (m, e) = mean_and_error(&v);
        assert!((s.mean.unwrap() - m.unwrap()).abs() < 1e-15);
        assert!((s.err.unwrap() - e.unwrap()).abs() < 1e-15);
        assert!((paired_error(&[1.0], &[&s]).unwrap() - e.unwrap()).abs() < 1e-15);
        // Two datasets showing the same fields, one offset by a constant:
        // their difference has no field noise at all, their sum twice it.
        let other: Vec<ImageStats> = one
            .iter()
            .map(|s| ImageStats {
                dataset: 1,
                all: BinAcc {
                    swe1: s.all.swe1 + 0.05,
                    ..s.all
                },
                ..s.clone()
            })
            .collect();
        let refs2: Vec<&ImageStats> = other.iter().collect();
        let s2 = FieldSeries::of(&refs2, |s| Some(s.all.swe1));
        assert!(paired_error(&[1.0, -1.0], &[&s, &s2]).unwrap() < 1e-15);
        let sum = paired_error(&[1.0, 1.0], &[&s, &s2]).unwrap();
        assert!((sum - 2.0 * e.unwrap()).abs() < 1e-15, "{sum}");
        // A single field gives no error.
        let single = FieldSeries::of(&refs[..2], |s| Some(s.all.swe1));
        assert_eq!(paired_error(&[1.0], &[&single]), None);
    }

    #[test]
    fn isolated_galaxies_give_their_own_m_and_c() {
        // Isolated galaxies measured with m = 0, c1 = 1e-3; galaxies with a
        // bright neighbour within 3″ with m = −0.2: the isolated figures see
        // only the former, the paper's m a mixture.
        let spec = crate::synthetic::SynthSpec::small(2);
        let run = crate::synthetic::make_run(&spec);
        let class = Isolation::standard(
            spec.pixel_scale_arcsec,
            crate::score::isolation::Plane::Image,
        );
        let mut iso = std::collections::HashSet::new();
        let mut counts = (0, 0);
        for t in &run.truth {
            for (row, ok) in t.iter().zip(crate::score::isolation::isolated(t, class)) {
                if ok {
                    iso.insert((row.x.to_bits(), row.y.to_bits()));
                    counts.0 += 1;
                } else if !row.is_star() {
                    counts.1 += 1;
                }
            }
        }
        assert!(counts.0 > 0 && counts.1 > 0, "{counts:?}");
        let ds = run.datasets.datasets.clone();
        let rows = run.submission(&|t, d| {
            let g = (ds[d].g1, ds[d].g2);
            if t.is_star() {
                None
            } else if iso.contains(&(t.x.to_bits(), t.y.to_bits())) {
                Some((g.0 + 1e-3, g.1 - 2e-3, 1.0))
            } else {
                Some((0.8 * g.0, g.1, 1.0))
            }
        });
        let scores = score_tables(&run.meta(), &run.stats(&rows, 1.0), 1.0);
        for p in &scores.psfs {
            assert!(p.m_isolated.unwrap().abs() < 1e-12, "{p:?}");
            assert!((p.c1_isolated.unwrap() - 1e-3).abs() < 1e-12);
            assert!((p.c2_isolated.unwrap() + 2e-3).abs() < 1e-12);
            assert!(p.m.unwrap() < -0.01 && p.m.unwrap() > -0.2, "{:?}", p.m);
        }
        assert!(scores.summary.m_isolated_mean.unwrap().abs() < 1e-12);
    }

    #[test]
    fn bins_include_their_lower_edge() {
        assert_eq!(bin_of(&MAG_EDGES, 10.0), 0);
        assert_eq!(bin_of(&MAG_EDGES, 20.0), 1);
        assert_eq!(bin_of(&MAG_EDGES, 24.999), 5);
        assert_eq!(bin_of(&MAG_EDGES, 30.0), 6);
        assert_eq!(bin_of(&DISK_EDGES_ARCSEC, 0.0), 0);
    }

    #[test]
    fn response_keeps_a_significant_quadratic_and_drops_a_null_one() {
        let xs = [0.0, 0.005, 0.01, 0.05, 0.1];
        let quad: Vec<_> = xs
            .iter()
            .map(|&x| (x, x + 0.001 - 0.02 * x + 1.5 * x * x, Some(1e-4)))
            .collect();
        let r = fit_response(&quad);
        assert!(!r.linear);
        assert!((r.q.value.unwrap() - 1.5).abs() < 1e-9);
        assert!((r.m.value.unwrap() + 0.02).abs() < 1e-10);
        assert!((r.c.value.unwrap() - 0.001).abs() < 1e-12);
        let lin: Vec<_> = xs
            .iter()
            .enumerate()
            .map(|(i, &x)| {
                (
                    x,
                    x + 0.03 * x + if i % 2 == 0 { 1e-4 } else { -1e-4 },
                    Some(1e-4),
                )
            })
            .collect();
        let r = fit_response(&lin);
        assert!(r.linear);
        assert_eq!(
            r.q,
            ValErr {
                value: Some(0.0),
                err: None
            }
        );
        assert!((r.m.value.unwrap() - 0.03).abs() < 5e-3);
    }

    #[test]
    fn q_c_of_a_perfect_method_is_the_normalisation_over_two() {
        let p = PsfReport {
            psf: "a".into(),
            m: Some(0.0),
            q: Some(0.0),
            c1: Some(0.0),
            c2: Some(0.0),
            linear: true,
            ..PsfReport::default()
        };
        assert!((q_c(std::slice::from_ref(&p)).unwrap() - 1232.0).abs() < 1e-9);
        let p2 = PsfReport {
            m: Some(2e-3),
            c1: Some(2e-4),
            c2: Some(-2e-4),
            ..p
        };
        // terms 1 + 1 + 1 + 4 = 7
        assert!((q_c(&[p2]).unwrap() - 2464.0 / 7f64.sqrt()).abs() < 1e-9);
    }
}
