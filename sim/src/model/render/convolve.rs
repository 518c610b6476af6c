//! Convolution of a whole image with a kernel given by its transfer
//! function, by overlap-save FFTs on square tiles.
//!
//! The input is a *canvas*: the output image plus a margin of `m` pixels on
//! every side (light from just outside the image is convolved in). Output
//! block (bx, by) of side `b = n − 2m` reads the canvas window of side `n`
//! that starts at the same indices (canvas pixel = image pixel + m), takes a
//! real 2-D FFT of side `n`, multiplies by the kernel's transfer function on
//! that grid, transforms back and keeps the central `b × b` pixels. Every
//! kept pixel receives each kernel offset |d| ≤ m from its true source
//! pixel, so the result is the linear convolution whenever the kernel's
//! support lies within ±m pixels; kernel light beyond that is wrapped within
//! the tile window (misplaced, never lost).
//!
//! Blocks write disjoint parts of the output, so the result does not depend
//! on the thread count. Precision: f32 transforms (error ~1e-6 of the
//! brightest pixel of a tile, measured in the tests).
//!
//! The slow twin is [`convolve_slow`], the obvious double sum over pixels.

use num_complex::Complex32;
use rayon::prelude::*;
use std::cell::RefCell;
use stepsim_numerics::fft::{BatchFft, LANES, Lanes, RealFft, transpose};

/// Overlap-save convolver for one kernel and one tile size.
pub struct Convolver {
    n: usize,
    margin: usize,
    /// The kernel's transfer on the n-grid's half plane, scaled by 1/n²,
    /// eight columns to a [`Lanes`] value: entry `g * n + v`, lane l holds
    /// column u = 8g + l at row v (zero past u = n/2).
    transfer: Vec<Lanes<f32>>,
    row_fwd: RealFft<f32>,
    row_inv: RealFft<f32>,
    col_fwd: BatchFft<f32>,
    col_inv: BatchFft<f32>,
}

impl std::fmt::Debug for Convolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Convolver")
            .field("n", &self.n)
            .field("margin", &self.margin)
            .finish_non_exhaustive()
    }
}

impl Convolver {
    /// A convolver with tiles of side `n` (even) and margin `margin`
    /// (2 · margin < n); `transfer` is the kernel's transfer function on the
    /// half-plane grid of an `n`-pixel stamp, row-major `[v][u]` as
    /// [`crate::model::psf::Psf::transfer`] gives it (T(0) = 1 keeps the flux).
    pub fn new(n: usize, margin: usize, transfer: &[Complex32]) -> Self {
        assert!(
            n % 2 == 0 && 2 * margin < n,
            "tile {n} too small for margin {margin}"
        );
        let nc = n / 2 + 1;
        assert_eq!(transfer.len(), n * nc, "transfer of the wrong grid");
        let scale = 1.0 / (n as f32 * n as f32);
        let mut lanes = vec![Lanes::zero(); nc.div_ceil(LANES) * n];
        for v in 0..n {
            for u in 0..nc {
                let t = transfer[v * nc + u] * scale;
                let e = &mut lanes[(u / LANES) * n + v];
                (e.re[u % LANES], e.im[u % LANES]) = (t.re, t.im);
            }
        }
        Self {
            n,
            margin,
            transfer: lanes,
            row_fwd: RealFft::new(n, false),
            row_inv: RealFft::new(n, true),
            col_fwd: BatchFft::new(n, false),
            col_inv: BatchFft::new(n, true),
        }
    }

    /// Tile side.
    pub fn tile(&self) -> usize {
        self.n
    }

    /// Margin (pixels) the canvas carries on every side.
    pub fn margin(&self) -> usize {
        self.margin
    }

    /// Side of the output block each tile produces.
    pub fn block(&self) -> usize {
        self.n - 2 * self.margin
    }

    /// Convolves a canvas of `(width + 2m) × (height + 2m)` pixels
    /// (row-major) and returns the `width × height` output, in the canvas's
    /// own buffer.
    ///
    /// One band of output rows per row of blocks, band after band; the
    /// blocks of a band are computed in parallel into a band buffer, each
    /// thread with its own FFT buffers (kept from one call to the next, so a
    /// long run allocates them once per thread). A finished band is copied
    /// into the canvas's buffer at its place in the `width × height` output
    /// (rows of `width`, not of the canvas's `width + 2m`): output row y
    /// ends before canvas row y + 1 begins, and every band after it reads
    /// canvas rows from its own first output row on, so nothing a later
    /// band reads is overwritten. The output needs no image-sized buffer of
    /// its own: about 50 MB of fresh pages fewer for a 4096² image.
    pub fn apply(&self, mut canvas: Vec<f32>, width: usize, height: usize) -> Vec<f32> {
        let m = self.margin;
        let cw = width + 2 * m;
        assert_eq!(
            canvas.len(),
            cw * (height + 2 * m),
            "canvas of the wrong size"
        );
        if width == 0 || height == 0 {
            return Vec::new();
        }
        let b = self.block();
        let mut band = vec![0.0f32; b.min(height) * width];
        for y0 in (0..height).step_by(b) {
            let rows_here = b.min(height - y0);
            let band = &mut band[..rows_here * width];
            let mut blocks: Vec<Vec<&mut [f32]>> =
                (0..width.div_ceil(b)).map(|_| Vec::new()).collect();
            for row in band.chunks_mut(width) {
                let mut rest = row;
                for block in &mut blocks {
                    let (part, tail) = rest.split_at_mut(b.min(rest.len()));
                    block.push(part);
                    rest = tail;
                }
            }
            let input = &canvas[..];
            blocks.into_par_iter().enumerate().for_each(|(bx, rows)| {
                SCRATCH.with(|cell| {
                    let mut kept = cell.borrow_mut();
                    let scratch = match &mut *kept {
                        Some(s) if s.fits(self) => s,
                        other => other.insert(Scratch::new(self)),
                    };
                    let at = BlockAt {
                        canvas: input,
                        width,
                        x0: bx * b,
                        y0,
                    };
                    self.block_into(at, rows, scratch);
                });
            });
            canvas[y0 * width..(y0 + rows_here) * width].copy_from_slice(band);
        }
        canvas.truncate(width * height);
        canvas
    }

    /// Writes the output block whose first pixel is image pixel (x0, y0)
    /// into `rows`: its `min(b, height − y0)` rows, each of
    /// `min(b, width − x0)` pixels.
    ///
    /// Where the CPU runs AVX2 the same code runs built for it, with the
    /// 8 × 8 transposes by AVX shuffles (moves only: the same bits,
    /// `stepsim_numerics::simd`).
    fn block_into(&self, at: BlockAt<'_>, rows: Vec<&mut [f32]>, s: &mut Scratch) {
        #[cfg(target_arch = "x86_64")]
        if stepsim_numerics::simd::has_avx2() {
            // SAFETY: the CPU runs AVX2 (checked just above).
            return unsafe { self.block_avx2(at, rows, s) };
        }
        self.block_body::<false>(at, rows, s);
    }

    /// [`Self::block_body`] built for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn block_avx2(&self, at: BlockAt<'_>, rows: Vec<&mut [f32]>, s: &mut Scratch) {
        self.block_body::<true>(at, rows, s);
    }

    /// The body of [`Self::block_into`]; `AVX`: built for AVX2 (its
    /// caller checked the CPU).
    #[inline(always)]
    fn block_body<const AVX: bool>(
        &self,
        at: BlockAt<'_>,
        mut rows: Vec<&mut [f32]>,
        s: &mut Scratch,
    ) {
        let transpose = tr::<AVX>;
        let BlockAt {
            canvas,
            width,
            x0,
            y0,
        } = at;
        let (n, m) = (self.n, self.margin);
        let (h, nc) = (n / 2, n / 2 + 1);
        let cw = width + 2 * m;
        let ch = canvas.len() / cw;
        let (np, colp) = (s.np, s.colp);
        // Forward: eight rows of the window at a time (zero beyond the
        // canvas) into lanes, by 8 × 8 blocks of samples; their frequencies
        // go into s.uv by 8 × 8 blocks (eight columns to an entry); then the
        // columns, eight at a time.
        let xs = cw.min(x0 + n) - x0;
        for r0 in (0..n).step_by(LANES) {
            for (l, line) in s.lines.chunks_exact_mut(np).enumerate() {
                let cy = y0 + r0 + l;
                let len = if r0 + l < n && cy < ch { xs } else { 0 };
                if len > 0 {
                    line[..len].copy_from_slice(&canvas[cy * cw + x0..][..len]);
                }
                line[len..].fill(0.0);
            }
            // Samples c0..c0 + 8 of the eight rows, transposed: entry i is
            // sample c0 + i of every row, the real (even sample) or the
            // imaginary part (odd) of entry (c0 + i)/2.
            for c0 in (0..np).step_by(LANES) {
                let t = transpose(&std::array::from_fn(|l| {
                    s.lines[l * np + c0..][..LANES]
                        .try_into()
                        .expect("8 samples")
                }));
                for (i, v) in t.into_iter().enumerate() {
                    let e = &mut s.half[(c0 + i) / 2];
                    if i % 2 == 0 {
                        e.re = v;
                    } else {
                        e.im = v;
                    }
                }
            }
            self.row_fwd
                .forward(&mut s.half[..h], &mut s.freq[..nc], &mut s.scratch);
            for (g, freq) in s.freq.chunks_exact(LANES).enumerate() {
                let re = transpose(&std::array::from_fn(|u| freq[u].re));
                let im = transpose(&std::array::from_fn(|u| freq[u].im));
                let col = &mut s.uv[g * colp + r0..][..LANES];
                for (l, e) in col.iter_mut().enumerate() {
                    (e.re, e.im) = (re[l], im[l]);
                }
            }
        }
        for (col, t) in
            s.uv.chunks_exact_mut(colp)
                .zip(self.transfer.chunks_exact(n))
        {
            let col = &mut col[..n];
            self.col_fwd.process(col, &mut s.scratch);
            for (a, t) in col.iter_mut().zip(t) {
                for l in 0..LANES {
                    let (ar, ai) = (a.re[l], a.im[l]);
                    a.re[l] = ar * t.re[l] - ai * t.im[l];
                    a.im[l] = ar * t.im[l] + ai * t.re[l];
                }
            }
            self.col_inv.process(col, &mut s.scratch);
        }
        // Inverse along rows, eight of the rows kept at a time.
        for (j0, dsts) in rows.chunks_mut(LANES).enumerate() {
            let r0 = m + j0 * LANES;
            for (g, freq) in s.freq.chunks_exact_mut(LANES).enumerate() {
                let col = &s.uv[g * colp + r0..][..LANES];
                let re = transpose(&std::array::from_fn(|l| col[l].re));
                let im = transpose(&std::array::from_fn(|l| col[l].im));
                for (u, f) in freq.iter_mut().enumerate() {
                    (f.re, f.im) = (re[u], im[u]);
                }
            }
            self.row_inv
                .inverse(&s.freq[..nc], &mut s.half[..h], &mut s.scratch);
            for c0 in (0..np).step_by(LANES) {
                let t = transpose(&std::array::from_fn(|i| {
                    let e = &s.half[(c0 + i) / 2];
                    if i % 2 == 0 { e.re } else { e.im }
                }));
                for (l, v) in t.iter().enumerate() {
                    s.lines[l * np + c0..][..LANES].copy_from_slice(v);
                }
            }
            for (l, dst) in dsts.iter_mut().enumerate() {
                let bw = dst.len();
                dst.copy_from_slice(&s.lines[l * np + m..][..bw]);
            }
        }
    }
}

/// Where an output block lies: the canvas of an image `width` wide and the
/// block's first pixel (x0, y0) in the image.
#[derive(Clone, Copy)]
struct BlockAt<'a> {
    canvas: &'a [f32],
    width: usize,
    x0: usize,
    y0: usize,
}

/// An 8 × 8 block transposed, by AVX shuffles when `AVX` (the caller is
/// built for AVX2 and the CPU runs it).
#[inline(always)]
fn tr<const AVX: bool>(a: &[[f32; LANES]; LANES]) -> [[f32; LANES]; LANES] {
    #[cfg(target_arch = "x86_64")]
    if AVX {
        // SAFETY: AVX is only set in code built for AVX2 and run after
        // `has_avx2` (Convolver::block_into).
        return unsafe { stepsim_numerics::fft::transpose_avx2(a) };
    }
    transpose(a)
}

thread_local! {
    /// Each thread's buffers for [`Convolver::block_into`], kept between
    /// calls (rebuilt when a convolver of another tile side comes).
    static SCRATCH: RefCell<Option<Scratch>> = const { RefCell::new(None) };
}

/// Per-thread buffers of [`Convolver::block_into`], padded to whole
/// 8 × 8 blocks (the padding's lanes are never read out).
struct Scratch {
    n: usize,
    /// Samples of a padded row: 2 · (entries of `half`).
    np: usize,
    /// Entries of one column group of `uv`: n rounded up to eight.
    colp: usize,
    /// Eight rows of samples, `np` each.
    lines: Vec<f32>,
    /// Eight real rows (samples 2k and 2k + 1 in entry k).
    half: Vec<Lanes<f32>>,
    /// Eight rows' frequencies u = 0..=n/2.
    freq: Vec<Lanes<f32>>,
    /// The tile's half plane, eight columns to an entry: group g's rows at
    /// `g * colp ..`.
    uv: Vec<Lanes<f32>>,
    scratch: Vec<Lanes<f32>>,
}

impl Scratch {
    fn new(c: &Convolver) -> Self {
        let n = c.n;
        let nc = n / 2 + 1;
        let half = (n / 2).div_ceil(LANES) * LANES;
        let colp = n.div_ceil(LANES) * LANES;
        Self {
            n,
            np: 2 * half,
            colp,
            lines: vec![0.0; LANES * 2 * half],
            half: vec![Lanes::zero(); half],
            freq: vec![Lanes::zero(); nc.div_ceil(LANES) * LANES],
            uv: vec![Lanes::zero(); nc.div_ceil(LANES) * colp],
            scratch: vec![Lanes::zero(); n],
        }
    }

    /// Whether these buffers serve `c` (same tile side).
    fn fits(&self, c: &Convolver) -> bool {
        self.n == c.n
    }
}

/// Reference: the direct convolution of a canvas of
/// `(width + 2m) × (height + 2m)` pixels with a real-space kernel of
/// `(2m + 1)²` pixels (row-major, centre at index (m, m)):
/// out(x, y) = Σ_{|dx|,|dy| ≤ m} kernel(dx, dy) · canvas(x + m − dx, y + m − dy).
/// O(width · height · m²); for tests.
pub fn convolve_slow(
    canvas: &[f32],
    width: usize,
    height: usize,
    kernel: &[f64],
    m: usize,
) -> Vec<f64> {
    let cw = width + 2 * m;
    let k = 2 * m + 1;
    assert_eq!(kernel.len(), k * k, "kernel of the wrong size");
    let mut out = vec![0.0; width * height];
    for y in 0..height {
        for x in 0..width {
            let mut s = 0.0;
            for dy in 0..k {
                for dx in 0..k {
                    let cx = x + 2 * m - dx;
                    let cy = y + 2 * m - dy;
                    s += kernel[dy * k + dx] * f64::from(canvas[cy * cw + cx]);
                }
            }
            out[y * width + x] = s;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::TAU;

    /// The transfer function of a real-space kernel of (2m+1)² pixels on
    /// the half plane of an n-grid, by the direct DFT (row-major [v][u]).
    fn transfer_of(kernel: &[f64], m: usize, n: usize) -> Vec<Complex32> {
        let k = 2 * m + 1;
        let nc = n / 2 + 1;
        let mut t = vec![Complex32::new(0.0, 0.0); n * nc];
        for v in 0..n {
            for u in 0..nc {
                let (mut re, mut im) = (0.0, 0.0);
                for dy in 0..k {
                    for dx in 0..k {
                        let (ox, oy) = (dx as f64 - m as f64, dy as f64 - m as f64);
                        let a = -TAU * (u as f64 * ox + v as f64 * oy) / n as f64;
                        re += kernel[dy * k + dx] * a.cos();
                        im += kernel[dy * k + dx] * a.sin();
                    }
                }
                t[v * nc + u] = Complex32::new(re as f32, im as f32);
            }
        }
        t
    }

    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (*state >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn overlap_save_equals_the_direct_sum() {
        // A lopsided kernel filling its whole ±m support, a random canvas
        // whose margins hold light too, blocks that do not divide the image:
        // the FFT path must equal the double sum to 2e-6 of the largest pixel.
        let m = 5;
        let k = 2 * m + 1;
        let mut st = 7u64;
        let kernel: Vec<f64> = (0..k * k).map(|_| lcg(&mut st) + 0.1).collect();
        let (w, h) = (53, 41);
        let canvas: Vec<f32> = (0..(w + 2 * m) * (h + 2 * m))
            .map(|_| (lcg(&mut st) * 100.0) as f32)
            .collect();
        let n = 24; // block 14: 4 × 3 blocks, the last ones partial
        let conv = Convolver::new(n, m, &transfer_of(&kernel, m, n));
        let fast = conv.apply(canvas.clone(), w, h);
        let slow = convolve_slow(&canvas, w, h, &kernel, m);
        let peak = slow.iter().copied().fold(0.0, f64::max);
        let worst = fast
            .iter()
            .zip(&slow)
            .map(|(&a, &b)| (f64::from(a) - b).abs())
            .fold(0.0, f64::max);
        assert!(worst < 2e-6 * peak, "max diff {worst} of peak {peak}");
        // Thread count does not change a bit.
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| conv.apply(canvas.clone(), w, h))
        };
        assert_eq!(run(1), fast);
        assert_eq!(run(4), fast);
        // An empty image is empty, not a panic.
        assert!(conv.apply(vec![0.0; (2 * m) * (2 * m)], 0, 0).is_empty());
    }

    #[test]
    fn a_point_in_the_margin_spreads_into_the_image() {
        // Light placed m pixels outside the image reaches its first column
        // through the kernel's far edge, exactly once.
        let m = 3;
        let k = 2 * m + 1;
        let mut kernel = vec![0.0; k * k];
        kernel[m * k + 2 * m] = 0.25; // offset (+m, 0)
        kernel[m * k + m] = 0.75; // centre
        let (w, h) = (10, 8);
        let cw = w + 2 * m;
        let mut canvas = vec![0.0f32; cw * (h + 2 * m)];
        // Canvas (0, m + 4): image pixel (−m, 4).
        canvas[(m + 4) * cw] = 8.0;
        let conv = Convolver::new(16, m, &transfer_of(&kernel, m, 16));
        let out = conv.apply(canvas, w, h);
        // out(x) = Σ_d kernel(d) in(x − d): offset d = +m carries the light
        // at x = −m to image pixel (0, 4), which receives 0.25 · 8; the
        // centre's 0.75 stays outside the image.
        assert!((out[4 * w] - 2.0).abs() < 1e-5, "{}", out[4 * w]);
        let total: f32 = out.iter().sum();
        assert!((total - 2.0).abs() < 1e-4, "{total}");
    }
}
