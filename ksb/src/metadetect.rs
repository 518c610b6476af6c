//! Metadetection (Sheldon et al. 2020): metacalibration of the whole
//! image, detection included (`stepsim measure --method metadetect`).
//!
//! Where `metacal.rs` makes five versions of each detection's stamp, this
//! makes five versions of the whole (background-subtracted) image and runs
//! the pipeline's detection and windowed moments on each. So which objects
//! are found, merged, deblended or flagged is decided on each version, and
//! the response sees it. The version sheared by g is
//!
//! J_g = (I ⊛ h_g) ∘ A_g,  ĥ_g(q) = Γ̂(A_g q) / P̂(q),
//!
//! whose transform is Î(M k) Γ̂(k) / P̂(M k) with M = A⁻¹, the same as a
//! stamp's version in `metacal.rs`: the image is first convolved, on its
//! own grid, with a kernel whose transform is exact there (P̂ the
//! transform of the PSF stack, Γ̂ analytic), which leaves a field
//! band-limited by Γ̂; that field is then resampled at A_g x (about the
//! image's centre) by windowed-sinc interpolation in two one-dimensional
//! passes, which is accurate because the field has almost no power where
//! the interpolant is not flat. The noise correction is the stamps':
//! white noise rotated by 90°, made into the version and rotated back;
//! that equals processing unrotated noise with the PSF rotated and the
//! shear −g, which is how it is done here (no image is rotated).
//!
//! The response of a dataset is R_ij = (⟨e_i⟩ over the objects selected
//! on the +g_j version − the same on −g_j) / 0.02, each mean over its own
//! version's detections: shear and selection response in one. The rows
//! are the unsheared version's detections, each selected one with
//! R⁻¹ e(0) and weight 1.

use crate::flags;
use crate::image::Image;
#[cfg(test)]
use crate::metacal::VERSIONS;
use crate::metacal::{PsfStack, STEP, freq};
use rand::RngExt;
use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};
use std::f64::consts::PI;
use std::sync::Arc;
use stepsim_contract::seed::{SeedKey, Stream};

/// Objects whose windowed centroid, taken back to the image as given,
/// lies within this many pixels of its edge are cut (EDGE): the
/// convolution wraps round the image and the resampling reads past it.
pub const EDGE_MARGIN_PX: f64 = 64.0;

/// Objects within this many pixels of a saturated detection or of a star
/// of S/N ν ≥ [`BRIGHT_STAR_MIN_SN`] (of the image as given, taken to each
/// version's frame) are cut (SATURATED): the deconvolution of a clipped
/// core rings, and a bright star's wings beyond the stack leave arcs.
pub const SATURATED_RADIUS_PX: f64 = 32.0;

/// Stars (on the stellar locus) with S/N ν at least this are cut round
/// like saturated detections (SATURATED within [`SATURATED_RADIUS_PX`]).
/// The stack held a star's light within its 32² pixels (until
/// 2026-12-07; now within 31.5 px, [`crate::metacal::stack_psf_wide`]);
/// what lay beyond (1.4 % of STEP1's `none`) was deconvolved by nothing,
/// and every version of a bright star showed pieces of it on the star's
/// axes 19 – 21 px out, which were detected and selected. The cut is
/// kept with the wider stack, whose edge the wings still cross. On the grid runs of `none` (low
/// noise) they came from stars of I ≈ 18.8 – 19.5, whose ν is 900 – 1 200;
/// the pieces scale with the star's flux as the detection's threshold
/// with the noise, so a bound on ν holds at any noise. 500 leaves a factor
/// of two; a bound at the PSF stars' ν ≥ 50 cut round ten times as many
/// stars and lost 12 % of the lensed run's weighted rows.
pub const BRIGHT_STAR_MIN_SN: f64 = 500.0;

/// Half-width of the interpolation kernel (taps −N+1 … N).
const KERNEL_N: i64 = 12;

/// Taps of the interpolation kernel.
const TAPS: usize = 2 * KERNEL_N as usize;

/// The Kaiser window's β ([`kernel`]).
const KERNEL_BETA: f64 = 12.0;

/// Seeds the noise correction's white noise (with the image's digest).
const NOISE_SEED: u64 = 0x6d65_7461_6465_7400;

/// The shear matrix of the unsheared version, where every position of
/// the resampling is a sample.
const UNSHEARED: [[f64; 2]; 2] = [[1.0, 0.0], [0.0, 1.0]];

/// The shear matrix A of SPEC §1 for g: (1 − |g|²)^(−½) [[1 − g₁, −g₂], [−g₂, 1 + g₁]].
pub fn shear_matrix(g: [f64; 2]) -> [[f64; 2]; 2] {
    let s = 1.0 / (1.0 - g[0] * g[0] - g[1] * g[1]).sqrt();
    [[s * (1.0 - g[0]), -s * g[1]], [-s * g[1], s * (1.0 + g[0])]]
}

/// 2-D transforms of a width × height grid: rows, a blocked transpose,
/// rows again. The forward transform leaves the spectrum transposed
/// (index kx · height + ky); the inverse takes it so.
struct Fft2 {
    w: usize,
    h: usize,
    fw: Arc<dyn Fft<f64>>,
    iw: Arc<dyn Fft<f64>>,
    fh: Arc<dyn Fft<f64>>,
    ih: Arc<dyn Fft<f64>>,
}

/// `a` (rows × cols, row-major) transposed, in blocks of 32 × 32.
fn transpose<T: Copy + Default>(a: &[T], rows: usize, cols: usize) -> Vec<T> {
    let mut out = Vec::new();
    transpose_map(a, rows, cols, &mut out, |v| v);
    out
}

/// A buffer of `len` values for a caller that writes every one: `buf` as
/// it is when it already has that length (no value is written here, no
/// page faulted in again), else a new one.
fn sized<T: Copy + Default>(buf: &mut Vec<T>, len: usize) -> &mut [T] {
    if buf.len() != len {
        *buf = vec![T::default(); len];
    }
    buf
}

/// [`transpose`] into `out` (reused when it has `a`'s length), each value
/// through `f` on its way.
fn transpose_map<T: Copy, U: Copy + Default>(
    a: &[T],
    rows: usize,
    cols: usize,
    out: &mut Vec<U>,
    f: impl Fn(T) -> U,
) {
    const B: usize = 32;
    let out = sized(out, a.len());
    for r0 in (0..rows).step_by(B) {
        for c0 in (0..cols).step_by(B) {
            for r in r0..(r0 + B).min(rows) {
                for c in c0..(c0 + B).min(cols) {
                    out[c * rows + r] = f(a[r * cols + c]);
                }
            }
        }
    }
}

/// Buffers a [`WholeImage`] reuses from one version to the next, so that
/// each version does not take about 1.2 GB of new pages from the system
/// for a 4096² image (and have the kernel clear them): the spectrum, the
/// convolved field and the resampling's passes ([`resample_t`]), rows on
/// their way back from the spectrum and the row transforms' scratch.
#[derive(Default)]
struct Scratch {
    spec: Vec<Complex64>,
    field: Vec<f64>,
    pass: Vec<f64>,
    rows: Vec<Complex64>,
    fft: Vec<Complex64>,
}

impl Fft2 {
    fn new(w: usize, h: usize) -> Self {
        let mut p = FftPlanner::new();
        Self {
            w,
            h,
            fw: p.plan_fft_forward(w),
            iw: p.plan_fft_inverse(w),
            fh: p.plan_fft_forward(h),
            ih: p.plan_fft_inverse(h),
        }
    }

    #[cfg(test)]
    fn forward(&self, mut buf: Vec<Complex64>) -> Vec<Complex64> {
        self.forward_in(&mut buf)
    }

    /// The transform of `buf` (row-major), transposed; `buf` is left
    /// holding the row transforms, a buffer its caller may reuse.
    fn forward_in(&self, buf: &mut [Complex64]) -> Vec<Complex64> {
        self.fw.process(buf);
        let mut t = transpose(buf, self.h, self.w);
        self.fh.process(&mut t);
        t
    }

    /// The real part of the inverse transform of `spec` (transposed,
    /// as [`Self::forward_in`] leaves it; transformed in place along its
    /// columns), row-major into `re`: the columns, then bands of 32 rows
    /// gathered from the transposed spectrum and transformed in `rows`
    /// (the same values and sums as a whole transpose and the rows after
    /// it, without a second spectrum-sized buffer).
    fn inverse_re(
        &self,
        spec: &mut [Complex64],
        re: &mut Vec<f64>,
        rows: &mut Vec<Complex64>,
        scratch: &mut Vec<Complex64>,
    ) {
        const B: usize = 32;
        let (w, h) = (self.w, self.h);
        let (ni, nw) = (
            self.ih.get_inplace_scratch_len(),
            self.iw.get_inplace_scratch_len(),
        );
        if scratch.len() < ni.max(nw) {
            scratch.resize(ni.max(nw), Complex64::new(0.0, 0.0));
        }
        self.ih.process_with_scratch(spec, &mut scratch[..ni]);
        let re = sized(re, w * h);
        let band = sized(rows, B.min(h) * w);
        let norm = 1.0 / (w * h) as f64;
        for y0 in (0..h).step_by(B) {
            let nr = B.min(h - y0);
            let band = &mut band[..nr * w];
            for kx in 0..w {
                for (r, &v) in spec[kx * h + y0..][..nr].iter().enumerate() {
                    band[r * w + kx] = v;
                }
            }
            self.iw.process_with_scratch(band, &mut scratch[..nw]);
            for (o, v) in re[y0 * w..][..nr * w].iter_mut().zip(band.iter()) {
                *o = v.re * norm;
            }
        }
    }
}

/// The interpolation kernel's weights at `t` (in samples): the first tap's
/// index and 2N weights, sinc(x) × I₀(β √(1 − (x/N)²)) at each tap's
/// distance x (a Kaiser-windowed sinc, zero for |x| ≥ N) divided by their
/// sum. Against Lanczos (sinc windowed by sinc(x/N)) with the same 24 taps
/// it interpolates a Gaussian of σ 2.2 – 3 px 200 times better (largest
/// error 1e-6 of the peak against 2.4e-4): Lanczos's errors, largest in
/// the wings and of opposite signs on either side of a sample, made a
/// version's weighted moments 0.3 % (weight as wide as the object) to 5 %
/// (twice as wide) too sheared.
fn kernel(t: f64) -> (i64, [f64; TAPS]) {
    let fl = t.floor();
    let base = fl as i64 - KERNEL_N + 1;
    let n = KERNEL_N as f64;
    let mut w = [0.0; TAPS];
    for (k, wk) in w.iter_mut().enumerate() {
        let x = t - (base + k as i64) as f64;
        let u = x / n;
        *wk = if x.abs() >= n {
            0.0
        } else {
            let sinc = if x.abs() < 1e-12 {
                1.0
            } else {
                (PI * x).sin() / (PI * x)
            };
            sinc * bessel_i0(KERNEL_BETA * (1.0 - u * u).sqrt())
        };
    }
    let sum: f64 = w.iter().sum();
    (base, w.map(|v| v / sum))
}

/// I₀(x), the modified Bessel function of the first kind, by its power
/// series Σ ((x/2)^k / k!)², summed until a term is below 1e-17 of the
/// sum (the kernel's x ≤ β = 12: 26 terms at most).
fn bessel_i0(x: f64) -> f64 {
    let q = x * x / 4.0;
    let (mut term, mut sum) = (1.0, 1.0);
    for k in 1..200 {
        term *= q / (k * k) as f64;
        sum += term;
        if term < 1e-17 * sum {
            break;
        }
    }
    sum
}

/// Phases per sample of the tabulated kernel: a position is rounded to
/// 1/PHASES of a pixel (1.2e-4 px at most; on a field of σ 2.3 px that
/// moves a value by at most 3e-5 of its peak).
const PHASES: usize = 4096;
const _: () = assert!(PHASES.is_power_of_two());

/// [`kernel`] at the phases k / PHASES, k = 0 … PHASES.
fn kernel_table() -> &'static [[f64; TAPS]] {
    static TABLE: std::sync::OnceLock<Vec<[f64; TAPS]>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        (0..=PHASES)
            .map(|k| kernel(k as f64 / PHASES as f64).1)
            .collect()
    })
}

/// The tabulated kernel at `t`: the first tap's index and its weights.
/// `t` is rounded to the nearest phase n / PHASES (a phase rounded up to 1
/// is the next sample's phase 0); the floor is taken by truncation and a
/// shift, not by `f64::floor` and `round`, which are calls into libm on a
/// target without SSE4.1 (about 15 % of the resampling's time).
#[inline(always)]
fn weights(t: f64) -> (i64, &'static [f64; TAPS]) {
    const SHIFT: u32 = PHASES.trailing_zeros();
    let q = t * PHASES as f64 + 0.5;
    let n = q as i64;
    let n = if (n as f64) > q { n - 1 } else { n };
    (
        (n >> SHIFT) - KERNEL_N + 1,
        &kernel_table()[(n & (PHASES as i64 - 1)) as usize],
    )
}

/// Σ w_t v_t over the taps, where `base` may reach past `v`'s ends (those
/// taps count zero).
#[inline(always)]
fn dot(v: &[f64], base: i64, w: &[f64; TAPS]) -> f64 {
    if base >= 0 && base as usize + TAPS <= v.len() {
        let s = &v[base as usize..base as usize + TAPS];
        let mut acc = [0.0; 4];
        for (c, wc) in s.chunks_exact(4).zip(w.chunks_exact(4)) {
            for l in 0..4 {
                acc[l] += c[l] * wc[l];
            }
        }
        (acc[0] + acc[1]) + (acc[2] + acc[3])
    } else {
        let mut acc = 0.0;
        for (t, wt) in w.iter().enumerate() {
            let i = base + t as i64;
            if i >= 0 && (i as usize) < v.len() {
                acc += wt * v[i as usize];
            }
        }
        acc
    }
}

/// `f` (width × height, row-major) resampled at c + A (x − c), c the
/// grid's centre: out(x) = f(c + A (x − c)), zero where that lies outside.
/// Two passes: along rows to K(u, Y) = f(c + u / d + b (Y − c_y) / d, Y),
/// then along columns to out(x, y) = K(x, c_y + b (x − c_x) + d (y − c_y))
/// (A = [[a, b], [b, d]] symmetric with det 1). The kernel is tabulated
/// ([`weights`]). The second pass runs along the rows of K's transpose,
/// so that each output is a contiguous dot product as in the first (along
/// the columns it gathered 24 values a row apart for each pixel, and was
/// the slower pass). At A = 1 every position is a sample, where the
/// kernel is 1 at the sample and 0 elsewhere: `f` is returned as it is.
#[cfg(test)]
pub fn resample(f: &[f64], w: usize, h: usize, a: [[f64; 2]; 2]) -> Vec<f64> {
    if a == UNSHEARED {
        return f.to_vec();
    }
    let (mut field, mut pass) = (f.to_vec(), Vec::new());
    resample_t(&mut field, w, h, a, &mut pass);
    transpose(&pass, w, h)
}

/// [`resample`] of `field` (A not 1), left transposed in `pass` (index
/// x · height + y); `field` holds the passes between (both reused when
/// they have the grid's size).
///
/// Where the CPU runs AVX2 the same code runs built for it: the dot
/// products' four partial sums in one vector register, the same
/// multiplications and additions in the same order (Rust does not fuse
/// them), so the same bits as the plain build (the tests run both where
/// the CPU allows, `STEPSIM_SIMD=0` the plain one).
fn resample_t(field: &mut Vec<f64>, w: usize, h: usize, a: [[f64; 2]; 2], pass: &mut Vec<f64>) {
    #[cfg(target_arch = "x86_64")]
    if stepsim_numerics::simd::has_avx2() {
        // SAFETY: the CPU runs AVX2 (checked just above).
        return unsafe { resample_t_avx2(field, w, h, a, pass) };
    }
    resample_t_body(field, w, h, a, pass);
}

/// [`resample_t_body`] built for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn resample_t_avx2(
    field: &mut Vec<f64>,
    w: usize,
    h: usize,
    a: [[f64; 2]; 2],
    pass: &mut Vec<f64>,
) {
    resample_t_body(field, w, h, a, pass);
}

/// The body of [`resample_t`].
#[inline(always)]
fn resample_t_body(
    field: &mut Vec<f64>,
    w: usize,
    h: usize,
    a: [[f64; 2]; 2],
    pass: &mut Vec<f64>,
) {
    let (b, d) = (a[0][1], a[1][1]);
    let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
    let k = sized(pass, w * h);
    for (yy, (row, krow)) in field.chunks_exact(w).zip(k.chunks_exact_mut(w)).enumerate() {
        let shift = b * (yy as f64 - cy) / d;
        for (x, o) in krow.iter_mut().enumerate() {
            let (base, wt) = weights(cx + (x as f64 - cx) / d + shift);
            *o = dot(row, base, wt);
        }
    }
    // kt[x · h + y] = K(x, y): column x of K is row x of kt (in `field`),
    // whose second pass goes into `pass`.
    transpose_map(pass, h, w, field, |v| v);
    let (kt, out_t) = (&*field, sized(pass, w * h));
    for (x, (col, ocol)) in kt
        .chunks_exact(h)
        .zip(out_t.chunks_exact_mut(h))
        .enumerate()
    {
        let shift = cy + b * (x as f64 - cx);
        for (y, o) in ocol.iter_mut().enumerate() {
            let (base, wt) = weights(shift + d * (y as f64 - cy));
            *o = dot(col, base, wt);
        }
    }
}

/// The slow twin of [`resample`]: each output pixel interpolated in 2-D
/// at c + A (x − c) directly, with the same kernel in both axes.
#[cfg(test)]
pub fn resample_slow(f: &[f64], w: usize, h: usize, a: [[f64; 2]; 2]) -> Vec<f64> {
    let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let (u, v) = (x as f64 - cx, y as f64 - cy);
            let xs = cx + a[0][0] * u + a[0][1] * v;
            let ys = cy + a[1][0] * u + a[1][1] * v;
            let (bx, wx) = kernel(xs);
            let (by, wy) = kernel(ys);
            let mut s = 0.0;
            for (tj, wj) in wy.iter().enumerate() {
                let j = by + tj as i64;
                if j < 0 || j as usize >= h {
                    continue;
                }
                for (ti, wi) in wx.iter().enumerate() {
                    let i = bx + ti as i64;
                    if i >= 0 && (i as usize) < w {
                        s += wj * wi * f[j as usize * w + i as usize];
                    }
                }
            }
            out[y * w + x] = s;
        }
    }
    out
}

/// The five versions of one image.
pub struct WholeImage {
    fft: Fft2,
    w: usize,
    h: usize,
    /// σ of Γ (pixels).
    pub sigma: f64,
    /// Transforms of the image (`Î`) and of the noise (`N̂`), transposed.
    img_hat: Vec<Complex64>,
    noise_hat: Option<Vec<Complex64>>,
    /// P̂, transposed.
    psf_hat: Vec<Complex64>,
    /// |P̂_rot|², the power of the PSF rotated by 90°, transposed: the
    /// noise correction's filter at any frequency, by bilinear
    /// interpolation.
    psf_rot_pow: Vec<f64>,
    /// Buffers kept from one version to the next.
    scratch: std::cell::Cell<Scratch>,
}

/// The PSF stack on a w × h grid, its centre at index (0, 0) (wrapped),
/// as the real part, and rotated by 90° as the imaginary part.
fn psf_on_grid(psf: &PsfStack, w: usize, h: usize) -> Vec<Complex64> {
    let mut g = vec![Complex64::new(0.0, 0.0); w * h];
    let c = (psf.side / 2) as i64;
    for (j, row) in psf.pix.chunks_exact(psf.side).enumerate() {
        for (i, &p) in row.iter().enumerate() {
            let (dx, dy) = (i as i64 - c, j as i64 - c);
            for (rotated, (dx, dy)) in [(false, (dx, dy)), (true, (-dy, dx))] {
                let x = dx.rem_euclid(w as i64) as usize;
                let y = dy.rem_euclid(h as i64) as usize;
                let v = &mut g[y * w + x];
                if rotated {
                    v.im += p;
                } else {
                    v.re += p;
                }
            }
        }
    }
    g
}

/// The transforms of two real fields packed as one complex field, a + i b
/// (transposed layout, w × h), from the conjugate symmetry of real
/// fields' transforms: `z` becomes â, and `b` is given b̂ at each index
/// (each index once; a frequency and its mirror are done together, so
/// that nothing is read after it is overwritten).
fn unpack(z: &mut [Complex64], w: usize, h: usize, mut b: impl FnMut(usize, Complex64)) {
    let half = |p: Complex64, q: Complex64| {
        (
            (p + q.conj()) * 0.5,
            (p - q.conj()) * Complex64::new(0.0, -0.5),
        )
    };
    for kx in 0..w {
        let mx = (w - kx) % w;
        for ky in 0..h {
            let my = (h - ky) % h;
            let (i, m) = (kx * h + ky, mx * h + my);
            if m < i {
                continue;
            }
            let (p, q) = (z[i], z[m]);
            let (ai, bi) = half(p, q);
            let (am, bm) = half(q, p);
            z[i] = ai;
            b(i, bi);
            if m != i {
                z[m] = am;
                b(m, bm);
            }
        }
    }
}

/// The slow twin of [`unpack`]: â and b̂ into new fields, each frequency
/// from the packed field as given.
#[cfg(test)]
fn unpack_slow(z: &[Complex64], w: usize, h: usize) -> (Vec<Complex64>, Vec<Complex64>) {
    let mut a = vec![Complex64::new(0.0, 0.0); z.len()];
    let mut b = vec![Complex64::new(0.0, 0.0); z.len()];
    for kx in 0..w {
        let mx = (w - kx) % w;
        for ky in 0..h {
            let my = (h - ky) % h;
            let (p, q) = (z[kx * h + ky], z[mx * h + my].conj());
            a[kx * h + ky] = (p + q) * 0.5;
            b[kx * h + ky] = (p - q) * Complex64::new(0.0, -0.5);
        }
    }
    (a, b)
}

impl WholeImage {
    /// Prepares the versions of `sub` (background-subtracted) with the PSF
    /// stack `psf`, reconvolved with a round Gaussian of σ `sigma`, and,
    /// when `noise_sigma > 0`, the noise correction (white noise of that
    /// σ, seeded by a digest of the image's pixels). `None` if the image
    /// is smaller than 4 × the PSF stack.
    pub fn new(sub: &Image, psf: &PsfStack, sigma: f64, noise_sigma: f64) -> Option<Self> {
        let (w, h) = (sub.width, sub.height);
        if w < 4 * psf.side || h < 4 * psf.side {
            return None;
        }
        let fft = Fft2::new(w, h);
        // The image and the noise in one transform: I + i N.
        let noise: Option<Vec<f64>> = (noise_sigma > 0.0).then(|| {
            let digest = sub.data.iter().fold((w * h) as u64, |d, v| {
                stepsim_contract::seed::splitmix64(d ^ u64::from(v.to_bits()))
            });
            let mut rng = SeedKey::base(NOISE_SEED, 0, Stream::Noise)
                .with_index(digest)
                .rng();
            (0..w * h)
                .map(|_| noise_sigma * rng.sample::<f64, _>(rand_distr::StandardNormal))
                .collect()
        });
        let mut z: Vec<Complex64> = sub
            .data
            .iter()
            .enumerate()
            .map(|(i, &v)| Complex64::new(f64::from(v), noise.as_ref().map_or(0.0, |n| n[i])))
            .collect();
        drop(noise);
        let mut img_hat = fft.forward_in(&mut z);
        let mut noise_hat = (noise_sigma > 0.0).then(|| vec![Complex64::new(0.0, 0.0); w * h]);
        unpack(&mut img_hat, w, h, |i, b| {
            if let Some(n) = &mut noise_hat {
                n[i] = b;
            }
        });
        let mut p = psf_on_grid(psf, w, h);
        let mut psf_hat = fft.forward_in(&mut p);
        drop(p);
        let mut psf_rot_pow = vec![0.0; w * h];
        unpack(&mut psf_hat, w, h, |i, b| psf_rot_pow[i] = b.norm_sqr());
        // z's buffer is the first version's spectrum.
        let scratch = Scratch {
            spec: z,
            ..Scratch::default()
        };
        Some(Self {
            fft,
            w,
            h,
            sigma,
            img_hat,
            noise_hat,
            psf_hat,
            psf_rot_pow,
            scratch: std::cell::Cell::new(scratch),
        })
    }

    /// |P̂_rot|² at the frequency (kx, ky) (cycles per pixel, anywhere),
    /// bilinear between the grid's frequencies, periodic as the grid's
    /// transform is. The PSF stack is 32² pixels, so its power varies
    /// over about 1/63 cycle per pixel, 65 grid steps at 4096 px: the
    /// interpolation's relative error is about (π · 63 / side)² / 8.
    fn rot_power(&self, kx: f64, ky: f64) -> f64 {
        let (w, h) = (self.w as f64, self.h as f64);
        let (u, v) = (wrap(kx * w, w), wrap(ky * h, h));
        // u, v ≥ 0: the floor by truncation (`f64::floor` is a call into
        // libm on a target without SSE4.1).
        let (i0, j0) = ((u as u64) as f64, (v as u64) as f64);
        let (fx, fy) = (u - i0, v - j0);
        let (i0, j0) = (i0 as usize % self.w, j0 as usize % self.h);
        let (i1, j1) = ((i0 + 1) % self.w, (j0 + 1) % self.h);
        let p = |i: usize, j: usize| self.psf_rot_pow[i * self.h + j];
        (1.0 - fx) * ((1.0 - fy) * p(i0, j0) + fy * p(i0, j1))
            + fx * ((1.0 - fy) * p(i1, j0) + fy * p(i1, j1))
    }

    /// The noise correction's filter at the grid frequency k for the
    /// version whose shear matrix is A (`a2` = A², `gam` = Γ̂(A k) from
    /// [`Self::gamma`]): Γ̂(A k) / |P̂_rot(A² k)|, no
    /// frequency amplified more than 3 × (as [`Self::kernel`]). Resampled
    /// at A x as the image is, white noise so filtered has the power
    /// σ² |Γ̂(k′)|² / |P̂_rot(A k′)|² at k′ = A q, which is the power of
    /// the image's noise in the version, σ² |Γ̂(k′)|² / |P̂(A⁻¹ k′)|²,
    /// rotated by 90° (R⁻¹ A⁻¹ R = A_−g⁻¹ = A_g for SPEC's A): what the
    /// correction must add for the sum to have no direction. Real and
    /// even, so the noise stays real.
    #[inline]
    fn noise_gain(&self, a2: &[[f64; 2]; 2], kx: f64, ky: f64, gam: f64) -> f64 {
        let mag = self
            .rot_power(a2[0][0] * kx + a2[0][1] * ky, a2[1][0] * kx + a2[1][1] * ky)
            .sqrt();
        if mag > 0.0 {
            if gam > 3.0 * mag { 3.0 } else { gam / mag }
        } else {
            0.0
        }
    }

    /// Γ̂(A k) at the frequency k = (kx, ky): what [`Self::kernel`] and
    /// [`Self::noise_gain`] take, computed once for both.
    #[inline]
    fn gamma(&self, a: &[[f64; 2]; 2], kx: f64, ky: f64) -> f64 {
        let s2 = 2.0 * PI * PI * self.sigma * self.sigma;
        let q = [a[0][0] * kx + a[0][1] * ky, a[1][0] * kx + a[1][1] * ky];
        (-s2 * (q[0] * q[0] + q[1] * q[1])).exp()
    }

    /// ĥ(k) = Γ̂(A k) / P̂(k), given P̂(k) = `p` and `gam` = Γ̂(A k)
    /// ([`Self::gamma`]); no frequency amplified more than 3 × (Γ ≤ 1.5
    /// |P̂| is how Γ was chosen, on a coarser grid).
    #[inline]
    fn kernel(p: Complex64, gam: f64) -> Complex64 {
        // |P̂| by a square root (an instruction), not `hypot` (a call into
        // libm); P̂ is far from overflow.
        let mag = p.norm_sqr().sqrt();
        if mag > 0.0 {
            let gain = if gam > 3.0 * mag { 3.0 } else { gam / mag };
            (p.conj() / mag) * gain
        } else {
            Complex64::new(0.0, 0.0)
        }
    }

    /// The version sheared by `g`, noise correction included: ((I ⊛ h_g) +
    /// (N ⊛ h′_g)) ∘ A_g, ĥ′ the noise filter of [`Self::noise_gain`].
    /// The noise is resampled with the image, so every version holds the
    /// same noise at the same place relative to the objects; only its
    /// filter follows the shear. (Resampled at A_−g x instead, as the
    /// first versions did, it moved against the objects by 2g (x − c):
    /// 40 px between the ±0.01 versions 1 000 px from the centre, and
    /// each version's objects met independent noise.)
    pub fn version(&self, g: [f64; 2]) -> Image {
        let a = shear_matrix(g);
        let a2 = [
            [
                a[0][0] * a[0][0] + a[0][1] * a[1][0],
                a[0][0] * a[0][1] + a[0][1] * a[1][1],
            ],
            [
                a[1][0] * a[0][0] + a[1][1] * a[1][0],
                a[1][0] * a[0][1] + a[1][1] * a[1][1],
            ],
        ];
        let mut s = self.scratch.take();
        let prod = sized(&mut s.spec, self.img_hat.len());
        for kxi in 0..self.w {
            let kx = freq(kxi, self.w);
            for kyi in 0..self.h {
                let ky = freq(kyi, self.h);
                let i = kxi * self.h + kyi;
                let gam = self.gamma(&a, kx, ky);
                let mut v = self.img_hat[i] * Self::kernel(self.psf_hat[i], gam);
                if let Some(n) = &self.noise_hat {
                    v += n[i] * self.noise_gain(&a2, kx, ky, gam);
                }
                prod[i] = v;
            }
        }
        self.fft
            .inverse_re(&mut s.spec, &mut s.field, &mut s.rows, &mut s.fft);
        let data = if a == UNSHEARED {
            s.field.iter().map(|&v| v as f32).collect()
        } else {
            resample_t(&mut s.field, self.w, self.h, a, &mut s.pass);
            let mut data = Vec::new();
            transpose_map(&s.pass, self.w, self.h, &mut data, |v| v as f32);
            data
        };
        self.scratch.set(s);
        Image {
            width: self.w,
            height: self.h,
            data,
        }
    }
}

/// `x.rem_euclid(n)` for n > 0, the same bits, without a call to `fmod`
/// where −n < x < 2n (x itself, x + n as `rem_euclid` adds it, or x − n,
/// exact there by Sterbenz's lemma as `fmod` is).
#[inline]
fn wrap(x: f64, n: f64) -> f64 {
    if (0.0..n).contains(&x) {
        x
    } else if x > -n && x < 0.0 {
        x + n
    } else if x >= n && x < 2.0 * n {
        x - n
    } else {
        x.rem_euclid(n)
    }
}

/// Where a point x of the image as given lies in the version sheared by
/// g: c + M (x − c), M = A⁻¹.
pub fn to_version(p: [f64; 2], w: usize, h: usize, g: [f64; 2]) -> [f64; 2] {
    let a = shear_matrix(g);
    // A is symmetric with det 1: A⁻¹ = [[d, −b], [−b, a]].
    let m = [[a[1][1], -a[0][1]], [-a[1][0], a[0][0]]];
    let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
    let (u, v) = (p[0] - cx, p[1] - cy);
    [
        cx + m[0][0] * u + m[0][1] * v,
        cy + m[1][0] * u + m[1][1] * v,
    ]
}

/// Σ e₁, Σ e₂ and the count of the selected objects of each version.
pub type VersionSums = [[f64; 3]; 5];

/// A dataset's response from its images' version sums: R_ij =
/// (⟨e_i⟩ on +g_j − ⟨e_i⟩ on −g_j) / 0.02; `None` if a sheared version
/// selected nothing or R is singular.
pub fn response(sums: &[VersionSums]) -> Option<[[f64; 2]; 2]> {
    response_of_total(&add(sums.iter(), 1.0, [[0.0; 3]; 5]))
}

/// The part of a dataset's response `r` that its rows use: the diagonal,
/// R₁₂ = R₂₁ = 0. For a population with no preferred direction the
/// off-diagonal elements vanish to first order in the shear (e₁ answers
/// g₂ only through terms in g₁g₂), but measured they carry as much noise
/// as the diagonal: on the lensed low-noise run (32 images per dataset,
/// g₁ = −2g₂) R₂₁'s noise carried g₁ into the g₂ estimate, and m's error
/// from R was ±0.033 with the whole matrix against ±0.014 with its
/// diagonal (docs/metacal.md, "The whole run, and the response's
/// noise"). `None` unless both diagonal elements are positive.
pub fn applied_response(r: [[f64; 2]; 2]) -> Option<[[f64; 2]; 2]> {
    (r[0][0] > 0.0 && r[1][1] > 0.0).then_some([[r[0][0], 0.0], [0.0, r[1][1]]])
}

/// `tot` plus `sign` × each of `sums`.
fn add<'a>(
    sums: impl Iterator<Item = &'a VersionSums>,
    sign: f64,
    mut tot: VersionSums,
) -> VersionSums {
    for s in sums {
        for (t, v) in tot.iter_mut().zip(s) {
            for k in 0..3 {
                t[k] += sign * v[k];
            }
        }
    }
    tot
}

/// The error of [`response`] by the delete-one jackknife over the images:
/// √((n − 1)/n Σᵢ (R₍ᵢ₎ − R̄)²), R₍ᵢ₎ the response without image i and R̄
/// their mean, element by element. `None` with fewer than two images, or
/// when a response without one image is undefined. It measures what the
/// per-field errors of m leave out: R is one per dataset, shared by its
/// fields.
pub fn response_error(sums: &[VersionSums]) -> Option<[[f64; 2]; 2]> {
    let n = sums.len();
    if n < 2 {
        return None;
    }
    let tot = add(sums.iter(), 1.0, [[0.0; 3]; 5]);
    let parts: Vec<[[f64; 2]; 2]> = sums
        .iter()
        .map(|s| response_of_total(&add(std::iter::once(s), -1.0, tot)))
        .collect::<Option<_>>()?;
    let mut err = [[0.0; 2]; 2];
    for (i, row) in err.iter_mut().enumerate() {
        for (j, e) in row.iter_mut().enumerate() {
            let mean = parts.iter().map(|r| r[i][j]).sum::<f64>() / n as f64;
            let ss: f64 = parts.iter().map(|r| (r[i][j] - mean).powi(2)).sum();
            *e = ((n - 1) as f64 / n as f64 * ss).sqrt();
        }
    }
    Some(err)
}

/// [`response`] from the version sums of all the images together.
fn response_of_total(tot: &VersionSums) -> Option<[[f64; 2]; 2]> {
    let mean = |v: usize, i: usize| (tot[v][2] > 0.0).then(|| tot[v][i] / tot[v][2]);
    let mut r = [[0.0; 2]; 2];
    for j in 0..2 {
        for (i, row) in r.iter_mut().enumerate() {
            row[j] = (mean(1 + 2 * j, i)? - mean(2 + 2 * j, i)?) / (2.0 * STEP);
        }
    }
    let det = r[0][0] * r[1][1] - r[0][1] * r[1][0];
    (det.is_finite() && det.abs() > 1e-6).then_some(r)
}

/// The flags a version's detection at `p` (in the version sheared by `g`)
/// is cut by, besides its detection's. EDGE is decided where `p` lies in
/// the image as given (the versions are sheared about the image's centre,
/// so near an edge a version moves its objects by up to 0.01 × 2048 ≈ 20
/// px): which objects lie near an edge does not depend on their shape,
/// and a margin that moved with the shear only changed, at random, which
/// objects each version's mean took, adding noise to the response and
/// nothing else. SATURATED is decided in the version's frame, about the
/// positions `cut_round` (saturated detections and bright stars of the
/// image as given) taken there, as it follows the light.
pub fn position_flags(p: [f64; 2], w: usize, h: usize, g: [f64; 2], cut_round: &[[f64; 2]]) -> u32 {
    let mut f = 0;
    // Back to the image as given: the map by −g inverts the map by g.
    let o = to_version(p, w, h, [-g[0], -g[1]]);
    if o[0] < EDGE_MARGIN_PX
        || o[1] < EDGE_MARGIN_PX
        || o[0] > w as f64 - 1.0 - EDGE_MARGIN_PX
        || o[1] > h as f64 - 1.0 - EDGE_MARGIN_PX
    {
        f |= flags::EDGE;
    }
    if cut_round.iter().any(|&s| {
        let q = to_version(s, w, h, g);
        (q[0] - p[0]).hypot(q[1] - p[1]) < SATURATED_RADIUS_PX
    }) {
        f |= flags::SATURATED;
    }
    f
}

#[cfg(test)]
mod tests;
