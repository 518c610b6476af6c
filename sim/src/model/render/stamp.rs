//! The Fourier-space stamp engine: fill the half-plane grid, inverse FFT.
//!
//! Layout: the grid of an `n × n` stamp has `n/2 + 1` columns (u ≥ 0) and
//! `n` rows (v, wrapped as in [`crate::model::psf::StampGrid`]). The engine stores it column by
//! column (`[u][v]`, each column contiguous) so the first inverse pass is
//! `n/2 + 1` complex FFTs of length `n` along v; then each image row y is a
//! complex-to-real FFT of length `n` along u. Both are unnormalised, so the
//! result is scaled by 1/n² (that makes the pixels sum to the k = 0 value,
//! the flux).
//!
//! The Nyquist row and column (|u| or |v| = 1/(2p)) hold the sum of the
//! transform at +ν_N and −ν_N, the two frequencies the pixel samples cannot
//! tell apart (this is what the DFT of the samples of a real, band-limited
//! image holds there). Frequencies beyond Nyquist are not folded in (no
//! aliasing of the PSF-convolved profile): the comparison with the
//! real-space reference measures what this leaves out.

use crate::model::profile::{Component, DeVaucouleurs, Exponential, ProfileKind, gram_k2};
use crate::model::psf::row_index;
use num_complex::Complex32;
use realfft::FftNum;
use realfft::num_complex::Complex;
use std::collections::HashMap;
use std::f64::consts::PI;
use std::sync::{Arc, Mutex};
use std::time::Instant;
use stepsim_numerics::fft::{BatchFft, LANES, Lanes, Real, RealFft};

use super::StageTimes;

/// What one stamp holds: geometry and the object.
#[derive(Debug, Clone)]
pub struct Fill {
    /// Stamp side (even).
    pub n: usize,
    /// Pixel scale (arcsec).
    pub pixel_scale_arcsec: f64,
    /// Object centre minus the centre of stamp pixel (0, 0), in pixels.
    pub dx_px: f64,
    /// The same along y.
    pub dy_px: f64,
    /// Flux of a point source (stars); 0 for galaxies.
    pub star_flux_e: f64,
    /// Galaxy components (empty for stars).
    pub components: Vec<Component>,
    /// Skip the galaxy transform where |T S| < cut.
    pub cut: f64,
    /// Image-array column of stamp pixel 0.
    pub x0: i64,
    /// Image-array row of stamp pixel 0.
    pub y0: i64,
}

/// The two FFT plans of one stamp side.
struct Plans<T> {
    /// Inverse complex FFTs of length n along v, eight columns at a time.
    columns: BatchFft<T>,
    /// Inverse real FFTs of length n along u, eight rows at a time.
    rows: RealFft<T>,
}

/// FFT plans and per-side tables, shared by all threads.
pub struct FftCache<T> {
    plans: Mutex<HashMap<usize, Arc<Plans<T>>>>,
    sincs: Mutex<HashMap<usize, Arc<Vec<f64>>>>,
}

impl<T: FftNum> Default for FftCache<T> {
    fn default() -> Self {
        Self {
            plans: Mutex::new(HashMap::new()),
            sincs: Mutex::new(HashMap::new()),
        }
    }
}

impl<T: FftNum> std::fmt::Debug for FftCache<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("FftCache")
    }
}

impl<T: FftNum + Real> FftCache<T> {
    fn plans(&self, n: usize) -> Arc<Plans<T>> {
        let mut map = self.plans.lock().expect("fft plan cache");
        map.entry(n)
            .or_insert_with(|| {
                Arc::new(Plans {
                    columns: BatchFft::new(n, true),
                    rows: RealFft::new(n, true),
                })
            })
            .clone()
    }

    /// sinc(m / n) for the wrapped frequency index m of row/column 0..n.
    pub(crate) fn sinc(&self, n: usize) -> Arc<Vec<f64>> {
        let mut map = self.sincs.lock().expect("sinc cache");
        map.entry(n)
            .or_insert_with(|| {
                Arc::new(
                    (0..n)
                        .map(|j| {
                            let m = row_index(j, n) as f64 / n as f64;
                            if m == 0.0 {
                                1.0
                            } else {
                                (PI * m).sin() / (PI * m)
                            }
                        })
                        .collect(),
                )
            })
            .clone()
    }
}

/// e^{−2πi m d / n} for m = 0..count, by complex recurrence from
/// e^{−2πi d / n}, re-anchored with an exact `sin_cos` every 32 steps
/// (error < 1e-14).
#[cfg(test)]
fn phases(count: usize, n: usize, d: f64) -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    phases_into(&mut out, count, n, d);
    out
}

/// [`phases`] into `out` (its old contents dropped).
fn phases_into(out: &mut Vec<(f64, f64)>, count: usize, n: usize, d: f64) {
    let exact = |m: usize| {
        let a = -2.0 * PI * ((m as f64 * d) / n as f64).rem_euclid(1.0);
        let (s, c) = a.sin_cos();
        (c, s)
    };
    let step = exact(1);
    out.clear();
    out.reserve(count);
    let mut cur = (1.0, 0.0);
    for m in 0..count {
        if m % 32 == 0 {
            cur = exact(m);
        }
        out.push(cur);
        cur = (
            cur.0 * step.0 - cur.1 * step.1,
            cur.0 * step.1 + cur.1 * step.0,
        );
    }
}

/// Renders [`Fill`]s in precision `T`.
pub struct StampEngine<T: FftNum + Real> {
    cache: FftCache<T>,
    /// Buffers of finished stamps, for the next ones (at most one per
    /// thread drawing at once is ever out of the pool).
    pool: Mutex<Vec<Scratch<T>>>,
    /// For each stamp side up to [`COLUMNS_SIDE`], the last transfer seen
    /// and its [`Columns`].
    columns: Mutex<HashMap<usize, KeptColumns>>,
}

/// The largest stamp side whose [`Columns`] the engine keeps (133 kB for
/// a side of 128; up to 256 px the galaxy stage ran no faster, and the
/// larger sides are few and each costs 4× as much).
const COLUMNS_SIDE: usize = 128;

/// A transfer and its [`Columns`].
type KeptColumns = (Arc<Vec<Complex32>>, Arc<Columns>);

/// A stamp grid's PSF transfer times the pixel response, in f64, column by
/// column (entry i · n + j: column u = i, row j), as [`fill_kspace`]
/// computes it for each column: kept by the engine for each side, so that
/// a stamp reads its columns instead of gathering them from the row-major
/// transfer (a strided loop that was a fifth of the fill's time).
#[derive(Debug)]
pub(crate) struct Columns {
    re: Vec<f64>,
    im: Vec<f64>,
}

impl Columns {
    /// The columns of `transfer` (row-major `[v][u]`, n/2 + 1 columns of
    /// `n`), times `sinc[u] · sinc[v]`.
    pub(crate) fn new(transfer: &[Complex32], sinc: &[f64], n: usize) -> Self {
        let nc = n / 2 + 1;
        let (mut re, mut im) = (vec![0.0; n * nc], vec![0.0; n * nc]);
        for (i, (re, im)) in re
            .chunks_exact_mut(n)
            .zip(im.chunks_exact_mut(n))
            .enumerate()
        {
            transfer_column(transfer, sinc, n, i, re, im);
        }
        Self { re, im }
    }
}

/// Column `i` of `transfer` (row-major `[v][u]`, n/2 + 1 columns of `n`)
/// times `sinc[i] · sinc[j]`, row j into `re[j]`, `im[j]`.
#[inline(always)]
fn transfer_column(
    transfer: &[Complex32],
    sinc: &[f64],
    n: usize,
    i: usize,
    re: &mut [f64],
    im: &mut [f64],
) {
    let nc = n / 2 + 1;
    let su = sinc[i];
    for j in 0..n {
        let tr = transfer[j * nc + i];
        let ts = su * sinc[j];
        (re[j], im[j]) = (f64::from(tr.re) * ts, f64::from(tr.im) * ts);
    }
}

impl<T: FftNum + Real> std::fmt::Debug for StampEngine<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StampEngine").finish_non_exhaustive()
    }
}

/// The largest stamp side whose buffers the engine keeps for the next
/// stamp: nearly all of a STEP1 image's stamps are smaller; the few larger
/// ones allocate theirs, as every stamp did before.
const KEPT_SIDE: usize = 256;

/// The working buffers of one stamp's rendering, kept between stamps so
/// that an image's tens of thousands of stamps do not each allocate (and
/// zero) them anew. Their contents never carry over: the fill writes every
/// cell of the grid, the FFTs' columns are written before they are
/// transformed and the scratch is written before it is read, and the row
/// pass's lanes past the stamp's last row are zeroed (or never written,
/// when the side is a multiple of eight).
struct Scratch<T> {
    grid: Vec<Complex<T>>,
    fill: FillScratch,
    col: Vec<Lanes<T>>,
    fft: Vec<Lanes<T>>,
    rows: Vec<Lanes<T>>,
}

impl<T: FftNum> Default for Scratch<T> {
    fn default() -> Self {
        Self {
            grid: Vec::new(),
            fill: FillScratch::default(),
            col: Vec::new(),
            fft: Vec::new(),
            rows: Vec::new(),
        }
    }
}

/// The per-column arrays of [`fill_kspace`] (each as long as a column)
/// and the Nyquist row's (`amp_high`, `amp_low`: n/2 + 1 of their values
/// used).
#[derive(Debug, Default)]
pub(crate) struct FillScratch {
    tre: Vec<f64>,
    tim: Vec<f64>,
    amp: Vec<f64>,
    ts: Vec<f64>,
    /// The Nyquist column's second terms, at u = −ν_N: transfer and
    /// amplitude of each row.
    tre_mirror: Vec<f64>,
    tim_mirror: Vec<f64>,
    amp_mirror: Vec<f64>,
    /// The Nyquist row's amplitudes at v = +ν_N and −ν_N, column by column.
    amp_high: Vec<f64>,
    amp_low: Vec<f64>,
    setup: SetupArrays,
}

impl<T: FftNum + Real> StampEngine<T> {
    /// An engine with the given cache.
    pub fn new(cache: FftCache<T>) -> Self {
        Self {
            cache,
            pool: Mutex::new(Vec::new()),
            columns: Mutex::new(HashMap::new()),
        }
    }

    /// The [`Columns`] of `transfer` on a grid of side `n` (`None` past
    /// [`COLUMNS_SIDE`]): the kept ones while the same transfer comes back
    /// (a PSF hands out one transfer per grid), else made and kept.
    fn columns(
        &self,
        n: usize,
        transfer: &Arc<Vec<Complex32>>,
        sinc: &[f64],
    ) -> Option<Arc<Columns>> {
        // A transfer of another grid is left to the fill, which refuses it.
        if n > COLUMNS_SIDE || transfer.len() != n * (n / 2 + 1) || sinc.len() != n {
            return None;
        }
        {
            let map = self.columns.lock().expect("stamp columns");
            if let Some((t, c)) = map.get(&n) {
                if Arc::ptr_eq(t, transfer) {
                    return Some(c.clone());
                }
            }
        }
        // Made outside the lock (a PSF that hands out a new transfer for
        // every stamp makes them every time, but holds up no other thread).
        let c = Arc::new(Columns::new(transfer, sinc, n));
        let mut map = self.columns.lock().expect("stamp columns");
        map.insert(n, (transfer.clone(), c.clone()));
        Some(c)
    }

    /// Renders one stamp: row-major n × n pixels in electrons.
    /// `transfer` is the PSF transfer on the stamp's grid (row-major `[v][u]`).
    pub fn render(
        &self,
        fill: &Fill,
        transfer: &Arc<Vec<Complex32>>,
        times: Option<&mut StageTimes>,
    ) -> Vec<T> {
        let t0 = times.as_ref().map(|_| Instant::now());
        let n = fill.n;
        let nc = n / 2 + 1;
        let sinc = self.cache.sinc(n);
        let columns = self.columns(n, transfer, &sinc);
        let mut s = self
            .pool
            .lock()
            .expect("stamp scratch pool")
            .pop()
            .unwrap_or_default();
        // Every cell is written by the fill: old values need no clearing.
        s.grid.resize(nc * n, Complex::new(T::zero(), T::zero()));
        let cols = columns.as_deref();
        fill_kspace_in(fill, transfer, cols, &sinc, &mut s.grid, &mut s.fill);
        let t1 = t0.map(|_| Instant::now());

        let out = inverse_2d(&self.cache.plans(n), &mut s, n);
        // Only small stamps' buffers are kept: a pooled set never grows
        // past [`KEPT_SIDE`], so the pool holds at most ~0.6 MB a thread (a
        // bright star's stamp of 2048 px would keep 34 MB).
        if n <= KEPT_SIDE {
            self.pool.lock().expect("stamp scratch pool").push(s);
        }
        if let (Some(times), Some(t0), Some(t1)) = (times, t0, t1) {
            times.kspace_ns += (t1 - t0).as_nanos() as u64;
            times.fft_ns += t1.elapsed().as_nanos() as u64;
        }
        out
    }
}

/// The n × n image (row-major, scaled by 1/n²) of the half-plane grid
/// `s.grid` (`[u][v]`, n/2 + 1 columns of n), with `s`'s other buffers
/// as working space.
///
/// Eight columns at a time go through the inverse FFT along v, and are
/// written, an 8 × 8 block at a time, into the layout of the row pass,
/// where eight image rows at a time go through the inverse real FFT along
/// u. Lanes past the last column or row hold zeros and are not read out.
/// The imaginary parts of the columns u = 0 and n/2 of each row are not
/// used (Hermitian symmetry makes them 0 up to rounding).
fn inverse_2d<T: FftNum + Real>(plans: &Plans<T>, s: &mut Scratch<T>, n: usize) -> Vec<T> {
    let nc = n / 2 + 1;
    let groups = n.div_ceil(LANES);
    let buf = &s.grid[..nc * n];
    let (col, scratch, rows) = (&mut s.col, &mut s.fft, &mut s.rows);
    col.resize(n, Lanes::zero());
    scratch.resize(n, Lanes::zero());
    // rows[h * nc + u], lane l: row 8h + l's value at column u. Every lane
    // of a row below n is written by the column pass; the lanes past the
    // last row must hold zeros.
    if n % LANES != 0 {
        rows.clear();
    }
    rows.resize(groups * nc, Lanes::zero());
    let (col, scratch, rows) = (&mut col[..n], &mut scratch[..n], &mut rows[..groups * nc]);
    for g in 0..nc.div_ceil(LANES) {
        let width = LANES.min(nc - g * LANES);
        let done = if width == LANES {
            layout::gather(buf, g, n, col)
        } else {
            0
        };
        for (v, c) in col.iter_mut().enumerate().skip(done) {
            for l in 0..LANES {
                (c.re[l], c.im[l]) = if l < width {
                    let z = buf[(g * LANES + l) * n + v];
                    (z.re, z.im)
                } else {
                    (T::zero(), T::zero())
                };
            }
        }
        plans.columns.process(col, scratch);
        let done = if width == LANES {
            layout::scatter(col, g, nc, rows)
        } else {
            0
        };
        for (v, c) in col.iter().enumerate().skip(done) {
            let (h, lane) = (v / LANES, v % LANES);
            for l in 0..width {
                let r = &mut rows[h * nc + g * LANES + l];
                r.re[lane] = c.re[l];
                r.im[lane] = c.im[l];
            }
        }
    }
    let scale = <T as Real>::from_f64_rounded(1.0 / (n as f64 * n as f64));
    let mut out = vec![T::zero(); n * n];
    let half = &mut col[..n / 2];
    for h in 0..groups {
        plans
            .rows
            .inverse(&rows[h * nc..(h + 1) * nc], half, scratch);
        let rows_here = LANES.min(n - h * LANES);
        let done = if rows_here == LANES {
            layout::write_rows(half, scale, &mut out[h * LANES * n..(h + 1) * LANES * n])
        } else {
            0
        };
        for l in 0..rows_here {
            let out_row = &mut out[(h * LANES + l) * n..(h * LANES + l + 1) * n];
            for (pair, z) in out_row.chunks_exact_mut(2).zip(half.iter()).skip(done) {
                pair[0] = z.re[l] * scale;
                pair[1] = z.im[l] * scale;
            }
        }
    }
    out
}

/// The moves of [`inverse_2d`] between its three layouts as 8 × 8 block
/// transposes by AVX shuffles, for f32 where the CPU runs AVX2 (moves and,
/// in [`write_rows`], the same product by the scale: the same bits). Each
/// returns how many leading elements it handled (0 for another `T`, or
/// without AVX2); [`inverse_2d`]'s own loops do the rest. The slices are
/// seen as f32 ones only where `T` is f32 ([`same`], by type id).
mod layout {
    use super::{Complex, LANES, Lanes, Real};
    use std::any::TypeId;

    /// Whether the f32 moves run: the CPU runs AVX2 (x86-64 only).
    fn vector() -> bool {
        cfg!(target_arch = "x86_64") && stepsim_numerics::simd::has_avx2()
    }

    /// `x` as a slice of `B` when `A` is `B` (`S<T>` and `S<f32>` with T =
    /// f32), else `None`.
    fn same<A: 'static, B: 'static>(x: &[A]) -> Option<&[B]> {
        // SAFETY: A and B are the same type (checked), so the slice is one
        // of B.
        (TypeId::of::<A>() == TypeId::of::<B>())
            .then(|| unsafe { std::slice::from_raw_parts(x.as_ptr().cast::<B>(), x.len()) })
    }

    /// [`same`] for a slice to be written.
    fn same_mut<A: 'static, B: 'static>(x: &mut [A]) -> Option<&mut [B]> {
        // SAFETY: as in `same`.
        (TypeId::of::<A>() == TypeId::of::<B>())
            .then(|| unsafe { std::slice::from_raw_parts_mut(x.as_mut_ptr().cast::<B>(), x.len()) })
    }

    /// Columns g·8 … g·8 + 7 of `buf` (`[u][v]`, n per column) into
    /// `col` (element v: the eight columns' values at v), four v at a time.
    pub(super) fn gather<T: Real>(
        buf: &[Complex<T>],
        g: usize,
        n: usize,
        col: &mut [Lanes<T>],
    ) -> usize {
        match (vector(), same(buf), same_mut(col)) {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: the CPU runs AVX2 (checked).
            (true, Some(buf), Some(col)) => unsafe { gather_avx2(buf, g, n, col) },
            _ => 0,
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn gather_avx2(buf: &[Complex<f32>], g: usize, n: usize, col: &mut [Lanes<f32>]) -> usize {
        let whole = n / 4 * 4;
        for v0 in (0..whole).step_by(4) {
            let block: [[f32; LANES]; LANES] = std::array::from_fn(|l| {
                let z = &buf[(g * LANES + l) * n + v0..][..4];
                [
                    z[0].re, z[0].im, z[1].re, z[1].im, z[2].re, z[2].im, z[3].re, z[3].im,
                ]
            });
            let t = stepsim_numerics::fft::transpose_avx2(&block);
            for k in 0..4 {
                col[v0 + k].re = t[2 * k];
                col[v0 + k].im = t[2 * k + 1];
            }
        }
        whole
    }

    /// The column pass's `col` (group g) into the row pass's `rows`
    /// (`rows[h·nc + u]`, lane l: row 8h + l at column u), eight v at a time.
    pub(super) fn scatter<T: Real>(
        col: &[Lanes<T>],
        g: usize,
        nc: usize,
        rows: &mut [Lanes<T>],
    ) -> usize {
        match (vector(), same(col), same_mut(rows)) {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: the CPU runs AVX2 (checked).
            (true, Some(col), Some(rows)) => unsafe { scatter_avx2(col, g, nc, rows) },
            _ => 0,
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn scatter_avx2(col: &[Lanes<f32>], g: usize, nc: usize, rows: &mut [Lanes<f32>]) -> usize {
        let whole = col.len() / LANES * LANES;
        for h in 0..whole / LANES {
            let re: [[f32; LANES]; LANES] = std::array::from_fn(|lane| col[h * LANES + lane].re);
            let im: [[f32; LANES]; LANES] = std::array::from_fn(|lane| col[h * LANES + lane].im);
            let (re, im) = (
                stepsim_numerics::fft::transpose_avx2(&re),
                stepsim_numerics::fft::transpose_avx2(&im),
            );
            for l in 0..LANES {
                let r = &mut rows[h * nc + g * LANES + l];
                r.re = re[l];
                r.im = im[l];
            }
        }
        whole
    }

    /// Eight image rows from the row pass's `half` (element k: the rows'
    /// pixels 2k and 2k + 1 as re and im), times `scale`, into `out` (the
    /// eight rows, n each), four k at a time.
    pub(super) fn write_rows<T: Real>(half: &[Lanes<T>], scale: T, out: &mut [T]) -> usize {
        let scale = same::<T, f32>(std::slice::from_ref(&scale));
        match (vector(), same(half), scale, same_mut(out)) {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: the CPU runs AVX2 (checked).
            (true, Some(half), Some(&[scale]), Some(out)) => unsafe {
                write_rows_avx2(half, scale, out)
            },
            _ => 0,
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn write_rows_avx2(half: &[Lanes<f32>], scale: f32, out: &mut [f32]) -> usize {
        let n = out.len() / LANES;
        let whole = half.len() / 4 * 4;
        for k0 in (0..whole).step_by(4) {
            let block: [[f32; LANES]; LANES] = std::array::from_fn(|j| {
                let z = &half[k0 + j / 2];
                if j % 2 == 0 { z.re } else { z.im }
            });
            let t = stepsim_numerics::fft::transpose_avx2(&block);
            for (l, row) in t.iter().enumerate() {
                for (o, &x) in out[l * n + 2 * k0..][..LANES].iter_mut().zip(row) {
                    *o = x * scale;
                }
            }
        }
        whole
    }
}

/// What both fills of one stamp derive from its [`Fill`] before their loops
/// (its arrays held in a [`SetupArrays`]).
struct Setup<'a> {
    n: usize,
    nc: usize,
    /// Frequency step, cycles per arcsec.
    dk: f64,
    /// Shift phases e^{−2πi m d / n} along x for m = 0..=n/2.
    px: &'a [(f64, f64)],
    /// The same along y.
    pos_y: &'a [(f64, f64)],
    /// The phase of each row j: rows 0..=n/2 are m = j; rows above are
    /// m = j − n, the conjugates of rows n − j.
    py: &'a [(f64, f64)],
    /// Frequency v of each row j.
    vs: &'a [f64],
    /// Frequency u of each column i.
    us: &'a [f64],
    /// (law, flux, Gram matrix of the map) of each galaxy component.
    comps: &'a [(ProfileKind, f64, [f64; 3])],
}

/// The arrays of a [`Setup`], kept from stamp to stamp (each rewritten
/// whole by [`Setup::new`]).
#[derive(Debug, Default)]
pub(crate) struct SetupArrays {
    px: Vec<(f64, f64)>,
    pos_y: Vec<(f64, f64)>,
    py: Vec<(f64, f64)>,
    vs: Vec<f64>,
    us: Vec<f64>,
    comps: Vec<(ProfileKind, f64, [f64; 3])>,
}

impl<'a> Setup<'a> {
    fn new(fill: &Fill, transfer: &[Complex32], a: &'a mut SetupArrays) -> Self {
        let n = fill.n;
        let nc = n / 2 + 1;
        assert_eq!(transfer.len(), n * nc, "PSF transfer of the wrong grid");
        let dk = 1.0 / (n as f64 * fill.pixel_scale_arcsec);
        phases_into(&mut a.pos_y, n / 2 + 1, n, fill.dy_px);
        a.py.clear();
        a.py.extend((0..n).map(|j| {
            if j <= n / 2 {
                a.pos_y[j]
            } else {
                let (c, s) = a.pos_y[n - j];
                (c, -s)
            }
        }));
        phases_into(&mut a.px, nc, n, fill.dx_px);
        a.vs.clear();
        a.vs.extend((0..n).map(|j| row_index(j, n) as f64 * dk));
        a.us.clear();
        a.us.extend((0..nc).map(|i| i as f64 * dk));
        a.comps.clear();
        a.comps.extend(
            fill.components
                .iter()
                .map(|c| (c.kind, c.flux_e, c.map.gram())),
        );
        let a: &'a SetupArrays = a;
        Self {
            n,
            nc,
            dk,
            px: &a.px,
            pos_y: &a.pos_y,
            py: &a.py,
            vs: &a.vs,
            us: &a.us,
            comps: &a.comps,
        }
    }

    fn spectrum<'b>(
        &self,
        fill: &'b Fill,
        transfer: &'b [Complex32],
        sinc: &'b [f64],
    ) -> Spectrum<'b>
    where
        'a: 'b,
    {
        Spectrum {
            fill,
            transfer,
            sinc,
            px: self.px,
            py: self.pos_y,
            comps: self.comps,
            dk: self.dk,
        }
    }
}

/// amp · (tre + i tim) · (pxr + i pxi) · (pyr + i pyi) as (re, im): the
/// galaxy transform times PSF ⊗ pixel times the shift phases.
#[inline]
fn shifted(
    amp: f64,
    (tre, tim): (f64, f64),
    (pxr, pxi): (f64, f64),
    (pyr, pyi): (f64, f64),
) -> (f64, f64) {
    let (ph_r, ph_i) = (pxr * pyr - pxi * pyi, pxr * pyi + pxi * pyr);
    (
        amp * (tre * ph_r - tim * ph_i),
        amp * (tre * ph_i + tim * ph_r),
    )
}

/// One grid cell in the FFT's precision.
#[inline]
fn cell<T: FftNum>((re, im): (f64, f64)) -> Complex<T> {
    Complex::new(
        T::from_f64(re).expect("float"),
        T::from_f64(im).expect("float"),
    )
}

/// Fills the `[u][v]` buffer with object × PSF × pixel × shift.
///
/// The Nyquist row and column hold what the samples of a real image hold
/// there: both frequencies ±ν_N fall on the same cell, so the cell is the sum
/// of the continuous transform at +ν_N and −ν_N (at the corner, of all four
/// sign combinations); see [`nyquist_cell`].
///
/// A column at a time, in passes over plain arrays: the PSF ⊗ pixel
/// transfer, then each galaxy component's transform (the exponential's
/// loop without branches, which the compiler turns into vector square
/// roots and divisions; the de Vaucouleurs table read four values at a
/// time, [`DeVaucouleurs::add_transforms_k2`]), then the product with the
/// shift phases, computed for every cell and then zeroed where the cut
/// applies (no branch in that loop either). The Nyquist column takes two
/// such passes, at u = +ν_N and −ν_N ([`nyquist_column`]); the Nyquist row
/// one pass along it, after the amplitudes at v = −ν_N ([`nyquist_row`]);
/// only the corner goes through [`nyquist_cell`] (the three were 4.6 % of
/// a user's first image's CPU when every Nyquist cell did). Each cell gets
/// the same operations in the same order as in [`fill_kspace_slow`], so
/// the same bits; the transform is also evaluated where the cut then
/// zeroes the cell (at the STEP1 settings 0.85 % of a preset image's
/// galaxy cells are cut, near the grids' corners).
///
/// Where the CPU runs AVX2 the same code runs built for it (four f64 lanes
/// instead of two; same bits, `stepsim_numerics::simd`).
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn fill_kspace<T: FftNum>(
    fill: &Fill,
    transfer: &[Complex32],
    sinc: &[f64],
    buf: &mut [Complex<T>],
) {
    fill_kspace_in(fill, transfer, None, sinc, buf, &mut FillScratch::default());
}

/// [`fill_kspace`] with its per-column arrays in `s` (any length and
/// contents: each is sized and written before it is read), and the
/// transfer's columns times the pixel response from `cols` when given
/// ([`Columns::new`] of `transfer` and `sinc`; computed column by column
/// otherwise).
pub(crate) fn fill_kspace_in<T: FftNum>(
    fill: &Fill,
    transfer: &[Complex32],
    cols: Option<&Columns>,
    sinc: &[f64],
    buf: &mut [Complex<T>],
    s: &mut FillScratch,
) {
    #[cfg(target_arch = "x86_64")]
    if stepsim_numerics::simd::has_avx2() {
        // SAFETY: the CPU runs AVX2 (checked just above).
        return unsafe { fill_kspace_avx2(fill, transfer, cols, sinc, buf, s) };
    }
    fill_kspace_body(fill, transfer, cols, sinc, buf, s);
}

/// [`fill_kspace_body`] built for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn fill_kspace_avx2<T: FftNum>(
    fill: &Fill,
    transfer: &[Complex32],
    cols: Option<&Columns>,
    sinc: &[f64],
    buf: &mut [Complex<T>],
    s: &mut FillScratch,
) {
    fill_kspace_body(fill, transfer, cols, sinc, buf, s);
}

/// The body of [`fill_kspace`], in whichever build its caller has.
#[inline(always)]
pub(crate) fn fill_kspace_body<T: FftNum>(
    fill: &Fill,
    transfer: &[Complex32],
    cols: Option<&Columns>,
    sinc: &[f64],
    buf: &mut [Complex<T>],
    s: &mut FillScratch,
) {
    let g = Setup::new(fill, transfer, &mut s.setup);
    let (n, nc) = (g.n, g.nc);
    let at = g.spectrum(fill, transfer, sinc);
    let is_star = fill.components.is_empty();
    for v in [
        &mut s.tre,
        &mut s.tim,
        &mut s.amp,
        &mut s.ts,
        &mut s.tre_mirror,
        &mut s.tim_mirror,
        &mut s.amp_mirror,
        &mut s.amp_high,
        &mut s.amp_low,
    ] {
        v.resize(n, 0.0);
    }
    let (amp, ts) = (&mut s.amp[..n], &mut s.ts[..n]);
    // Every cell computed, then the cut ones set to zero (no branch in the
    // loops, so that they run in vector registers; the same values).
    let cut = if is_star { f64::NEG_INFINITY } else { fill.cut };
    let (amp_high, amp_low) = (&mut s.amp_high[..nc], &mut s.amp_low[..nc]);
    for i in 0..nc {
        let col = &mut buf[i * n..(i + 1) * n];
        let u = g.us[i];
        amplitudes_along(&g, fill, g.vs, |gram, v| gram_k2(gram, u, v), amp, ts);
        amp_high[i] = amp[n / 2];
        let su = sinc[i];
        let (tre, tim): (&[f64], &[f64]) = match cols {
            Some(c) => (&c.re[i * n..(i + 1) * n], &c.im[i * n..(i + 1) * n]),
            None => {
                let (tre, tim) = (&mut s.tre[..n], &mut s.tim[..n]);
                transfer_column(transfer, sinc, n, i, tre, tim);
                (tre, tim)
            }
        };
        if i == n / 2 {
            let mirror = (
                &mut s.tre_mirror[..n],
                &mut s.tim_mirror[..n],
                &mut s.amp_mirror[..n],
            );
            nyquist_column(&g, transfer, su, (tre, tim, amp), mirror, cut, sinc, col);
            col[n / 2] = cell(nyquist_cell(&at, i, n / 2, Some(amp)));
            continue;
        }
        for (j, c) in col.iter_mut().enumerate() {
            let value = cell(shifted(amp[j], (tre[j], tim[j]), g.px[i], g.py[j]));
            let dropped = tre[j].abs() + tim[j].abs() < cut;
            *c = if dropped {
                Complex::new(T::zero(), T::zero())
            } else {
                value
            };
        }
    }
    // The Nyquist row but its corner, in one pass along the row (the
    // amplitudes at v = −ν_N, which no column holds, by a pass as a
    // column's).
    let v_low = (-((n / 2) as i64)) as f64 * g.dk;
    let k2 = |gram, u| gram_k2(gram, u, v_low);
    amplitudes_along(&g, fill, g.us, k2, amp_low, &mut ts[..nc]);
    nyquist_row(&g, transfer, sinc, (amp_high, amp_low), cut, buf);
}

/// The Nyquist row v = n/2 of [`fill_kspace_body`] but its corner (column
/// n/2): each cell is the sum of [`Spectrum::at`] at v = +ν_N and −ν_N, as
/// [`nyquist_cell`] adds them. Both take the transfer of the grid's one
/// Nyquist row (see [`Spectrum::at`]); `amp_high` and `amp_low` hold the
/// object's amplitudes there, column by column.
#[inline(always)]
fn nyquist_row<T: FftNum>(
    g: &Setup<'_>,
    transfer: &[Complex32],
    sinc: &[f64],
    (amp_high, amp_low): (&[f64], &[f64]),
    cut: f64,
    buf: &mut [Complex<T>],
) {
    let (n, nc) = (g.n, g.nc);
    let h = n / 2;
    let (qr, qi) = g.pos_y[h];
    let sv = sinc[h];
    for i in (0..nc).filter(|&i| i != h) {
        let tr = transfer[h * nc + i];
        let ts = sinc[i] * sv;
        let (tre, tim) = (f64::from(tr.re) * ts, f64::from(tr.im) * ts);
        let plus = shifted(amp_high[i], (tre, tim), g.px[i], (qr, qi));
        let minus = shifted(amp_low[i], (tre, tim), g.px[i], (qr, -qi));
        let (plus, minus) = if tre.abs() + tim.abs() < cut {
            ((0.0, 0.0), (0.0, 0.0))
        } else {
            (plus, minus)
        };
        buf[i * n + h] = cell(((0.0 + plus.0) + minus.0, (0.0 + plus.1) + minus.1));
    }
}

/// The Nyquist column u = n/2 of [`fill_kspace_body`] but its corner (row
/// n/2): each cell is the sum of [`Spectrum::at`] at u = +ν_N and −ν_N, as
/// [`nyquist_cell`] adds them, in two passes over the rows. `tre`, `tim`
/// and `amp` hold the transfer × pixel and the amplitudes of the column at
/// u = +ν_N (as the other columns have them); the terms at −ν_N take the
/// transfer's conjugate and the amplitude of the mirrored row −v (written
/// into `tre_m`, `tim_m`, `amp_m` first), and the phase's conjugate
/// along x.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn nyquist_column<T: FftNum>(
    g: &Setup<'_>,
    transfer: &[Complex32],
    su: f64,
    (tre, tim, amp): (&[f64], &[f64], &[f64]),
    (tre_m, tim_m, amp_m): (&mut [f64], &mut [f64], &mut [f64]),
    cut: f64,
    sinc: &[f64],
    col: &mut [Complex<T>],
) {
    let (n, nc) = (g.n, g.nc);
    let i = n / 2;
    for j in 0..n {
        let m = (n - j) % n;
        let tr = transfer[m * nc + i];
        let ts = su * sinc[j];
        (tre_m[j], tim_m[j]) = (f64::from(tr.re) * ts, -f64::from(tr.im) * ts);
        amp_m[j] = amp[m];
    }
    let (pr, pi) = g.px[i];
    for (j, c) in col.iter_mut().enumerate() {
        let plus = shifted(amp[j], (tre[j], tim[j]), (pr, pi), g.py[j]);
        let minus = shifted(amp_m[j], (tre_m[j], tim_m[j]), (pr, -pi), g.py[j]);
        let plus = if tre[j].abs() + tim[j].abs() < cut {
            (0.0, 0.0)
        } else {
            plus
        };
        let minus = if tre_m[j].abs() + tim_m[j].abs() < cut {
            (0.0, 0.0)
        } else {
            minus
        };
        *c = cell(((0.0 + plus.0) + minus.0, (0.0 + plus.1) + minus.1));
    }
}

/// The object's amplitude (the sum of its components' transforms times
/// their fluxes; a star's flux) at the cells of one line of the grid, in
/// the order [`Spectrum::at`] sums them: cell j lies at the frequency
/// coordinate `xs[j]` along the line, and `k2(gram, xs[j])` is a
/// component's k² there (a column: u fixed, `xs` the rows' v; a row: v
/// fixed, `xs` the columns' u). `ts` is scratch of `amp`'s length.
#[inline(always)]
fn amplitudes_along(
    g: &Setup<'_>,
    fill: &Fill,
    xs: &[f64],
    k2: impl Fn([f64; 3], f64) -> f64,
    amp: &mut [f64],
    ts: &mut [f64],
) {
    if fill.components.is_empty() {
        amp.fill(fill.star_flux_e);
        return;
    }
    amp.fill(0.0);
    for &(kind, flux, gram) in g.comps {
        match kind {
            ProfileKind::Exponential => {
                for (f, &x) in amp.iter_mut().zip(xs) {
                    *f += flux * Exponential::transform_k2(k2(gram, x));
                }
            }
            ProfileKind::DeVaucouleurs => {
                for (tk, &x) in ts.iter_mut().zip(xs) {
                    *tk = k2(gram, x);
                }
                DeVaucouleurs::add_transforms_k2(flux, ts, amp);
            }
        }
    }
}

/// [`fill_kspace`]'s slow, obvious twin: every cell on its own, in order,
/// with the same arithmetic; the two must agree bit for bit (tested).
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn fill_kspace_slow<T: FftNum>(
    fill: &Fill,
    transfer: &[Complex32],
    sinc: &[f64],
    buf: &mut [Complex<T>],
) {
    let mut arrays = SetupArrays::default();
    let g = Setup::new(fill, transfer, &mut arrays);
    let (n, nc) = (g.n, g.nc);
    let at = g.spectrum(fill, transfer, sinc);
    for i in 0..nc {
        for j in 0..n {
            buf[i * n + j] = if i == n / 2 || j == n / 2 {
                cell(nyquist_cell(&at, i, j, None))
            } else {
                let (u, v) = (i as f64 * g.dk, g.vs[j]);
                let tr = transfer[j * nc + i];
                let ts = sinc[i] * sinc[j];
                let (tre, tim) = (f64::from(tr.re) * ts, f64::from(tr.im) * ts);
                if fill.components.is_empty() {
                    cell(shifted(fill.star_flux_e, (tre, tim), g.px[i], g.py[j]))
                } else if tre.abs() + tim.abs() < fill.cut {
                    Complex::new(T::zero(), T::zero())
                } else {
                    let mut amp = 0.0;
                    for &(kind, flux, [a, b, c]) in g.comps {
                        let t = a * u * u + 2.0 * b * u * v + c * v * v;
                        amp += flux * kind.transform_k2(t);
                    }
                    cell(shifted(amp, (tre, tim), g.px[i], g.py[j]))
                }
            };
        }
    }
}

/// What [`fill_kspace`] needs to evaluate the stamp's continuous transform at
/// any signed frequency index.
struct Spectrum<'a> {
    fill: &'a Fill,
    transfer: &'a [Complex32],
    sinc: &'a [f64],
    /// Shift phases along x for m = 0..=n/2.
    px: &'a [(f64, f64)],
    /// Shift phases along y for m = 0..=n/2.
    py: &'a [(f64, f64)],
    comps: &'a [(ProfileKind, f64, [f64; 3])],
    dk: f64,
}

impl Spectrum<'_> {
    /// object × PSF × pixel × shift at the signed frequency index (mu, mv),
    /// |mu|, |mv| ≤ n/2.
    ///
    /// The PSF transfer is known on the half plane u ≥ 0; at u < 0 it is the
    /// conjugate of the transfer at (−u, −v) (a real PSF). The grid holds one
    /// Nyquist row, v = +ν_N; the transfer at v = −ν_N, u ≠ 0, ±ν_N is taken
    /// from it. That is exact for PSFs symmetric about the x axis (the round
    /// Gaussian L of the split method) and otherwise an error bounded by
    /// |T| at Nyquist (≲ 1e-6 for the PSFs the renderer is meant for).
    fn at(&self, mu: i64, mv: i64) -> (f64, f64) {
        self.at_with(mu, mv, || self.amplitude(mu, mv))
    }

    /// [`Self::at`] with the object's amplitude at (mu, mv) from `amplitude`
    /// (called only for a galaxy cell the cut keeps).
    fn at_with(&self, mu: i64, mv: i64, amplitude: impl FnOnce() -> f64) -> (f64, f64) {
        let n = self.fill.n as i64;
        let nc = (n / 2 + 1) as usize;
        // |m| ≤ n/2 here, so the wrapped row is m or m + n (no division).
        let row = |m: i64| -> usize {
            if m == -n / 2 {
                (n / 2) as usize
            } else if m < 0 {
                (m + n) as usize
            } else {
                m as usize
            }
        };
        let (t_re, t_im) = if mu >= 0 {
            let t = self.transfer[row(mv) * nc + mu as usize];
            (f64::from(t.re), f64::from(t.im))
        } else {
            let t = self.transfer[row(-mv) * nc + (-mu) as usize];
            (f64::from(t.re), -f64::from(t.im))
        };
        let ts = self.sinc[row(mu)] * self.sinc[row(mv)];
        let (tre, tim) = (t_re * ts, t_im * ts);
        let amp = if self.fill.components.is_empty() {
            self.fill.star_flux_e
        } else {
            if tre.abs() + tim.abs() < self.fill.cut {
                return (0.0, 0.0);
            }
            amplitude()
        };
        let signed = |table: &[(f64, f64)], m: i64| {
            let (c, s) = table[m.unsigned_abs() as usize];
            if m >= 0 { (c, s) } else { (c, -s) }
        };
        shifted(amp, (tre, tim), signed(self.px, mu), signed(self.py, mv))
    }

    /// The galaxy's amplitude at (mu, mv): each component's transform
    /// times its flux, summed.
    fn amplitude(&self, mu: i64, mv: i64) -> f64 {
        let (u, v) = (mu as f64 * self.dk, mv as f64 * self.dk);
        self.comps
            .iter()
            .map(|&(kind, flux, gram)| flux * kind.transform_k2(gram_k2(gram, u, v)))
            .sum()
    }
}

/// The cell (column `i`, row `j`) of the half-plane grid when it lies on the
/// Nyquist row or column: the sum of the transform over the frequencies that
/// the pixel samples cannot tell apart, ±ν_N on each Nyquist axis. This is
/// what the DFT of the samples of the (band-limited) image holds there;
/// leaving the cell zero instead removes a pattern of alternating sign over
/// the whole stamp, which the image convolution of the split method turns
/// into lobes at the stamp's edges.
///
/// `column`, when given, holds the object's amplitudes of column `i` (at
/// u = i, rows −n/2 < v ≤ n/2, as [`amplitudes_along`] computes them);
/// they are used where they apply, the amplitude at (−u, v) being the one
/// at (u, −v) (the quadratic form is even: the same bits). Without it every
/// amplitude is evaluated here, as the slow twin does.
fn nyquist_cell(at: &Spectrum<'_>, i: usize, j: usize, column: Option<&[f64]>) -> (f64, f64) {
    let n = at.fill.n;
    let half = (n / 2) as i64;
    let mu = i as i64; // columns are u ≥ 0
    let mv = row_index(j, n);
    let us: &[i64] = if i == n / 2 { &[half, -half] } else { &[mu] };
    let vs: &[i64] = if j == n / 2 { &[half, -half] } else { &[mv] };
    let mut sum = (0.0, 0.0);
    for &u in us {
        for &v in vs {
            let v_in_column = if u == mu { v } else { -v };
            let known = column
                .filter(|_| v_in_column > -half)
                .map(|amp| amp[v_in_column.rem_euclid(n as i64) as usize]);
            let (re, im) = match known {
                Some(a) => at.at_with(u, v, || a),
                None => at.at(u, v),
            };
            sum.0 += re;
            sum.1 += im;
        }
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn phase_recurrence_matches_sin_cos() {
        let n = 1000;
        let d = 500.37;
        for (m, &(c, s)) in phases(n / 2 + 1, n, d).iter().enumerate() {
            let a = -2.0 * PI * m as f64 * d / n as f64;
            assert!(
                (c - a.cos()).abs() < 1e-12 && (s - a.sin()).abs() < 1e-12,
                "{m}"
            );
        }
    }
}
