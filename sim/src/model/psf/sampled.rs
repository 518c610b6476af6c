//! A PSF given by samples of its surface brightness on a square grid.
//!
//! The optical, Moffat and FITS-file PSFs all end up here. Sample (i, j) of
//! an `n × n` grid of spacing s sits at x = (i − n/2) s − cx,
//! y = (j − n/2) s − cy, so the offset (cx, cy) moves the grid's light
//! centroid onto the origin. Values are fractions of the flux (they sum
//! to 1).
//!
//! The transfer function is the discrete-time Fourier transform of the
//! samples, T(u, v) = Σ w_ij e^{−2πi(u x_i + v y_j)}, set to zero beyond the
//! grid's Nyquist frequency 1/(2s) on either axis (the samples say nothing
//! about higher frequencies). [`SampledPsf::transfer_at`] is the obvious
//! direct sum; [`Psf::transfer`] evaluates the same sum separably (rows,
//! then columns) for every cell of a stamp grid and caches the result.

use super::{Psf, StampGrid};
use num_complex::{Complex32, Complex64};
use std::collections::HashMap;
use std::f64::consts::TAU;
use std::sync::{Arc, Mutex, OnceLock};

/// The transfer on one stamp grid, computed by the first thread to ask.
type TransferCell = OnceLock<Arc<Vec<Complex32>>>;

/// A sampled PSF.
#[derive(Debug)]
pub struct SampledPsf {
    n: usize,
    spacing_arcsec: f64,
    values: Vec<f64>,
    offset: (f64, f64),
    /// (radius, value) of every sample, by increasing radius.
    by_radius: Vec<(f64, f64)>,
    peak: f64,
    /// The transfer on each stamp grid met so far, computed once: a thread
    /// that asks while another computes it waits for that result.
    cache: Mutex<HashMap<StampGrid, Arc<TransferCell>>>,
}

impl SampledPsf {
    /// A PSF from `n × n` samples (row-major, y by rows) of spacing
    /// `spacing_arcsec`, normalised to unit sum. `offset` is subtracted from
    /// the sample positions (pass the grid centroid to recentre).
    /// Returns `None` if the sum is not positive and finite.
    pub fn new(
        values: Vec<f64>,
        n: usize,
        spacing_arcsec: f64,
        offset: (f64, f64),
    ) -> Option<Self> {
        let sum: f64 = values.iter().sum();
        if values.len() != n * n
            || !(sum.is_finite() && sum > 0.0)
            || spacing_arcsec.is_nan()
            || spacing_arcsec <= 0.0
        {
            return None;
        }
        let values: Vec<f64> = values.iter().map(|v| v / sum).collect();
        let c = (n / 2) as f64;
        let mut by_radius: Vec<(f64, f64)> = values
            .iter()
            .enumerate()
            .map(|(k, &v)| {
                let x = ((k % n) as f64 - c) * spacing_arcsec - offset.0;
                let y = ((k / n) as f64 - c) * spacing_arcsec - offset.1;
                (x.hypot(y), v)
            })
            .collect();
        by_radius.sort_by(|a, b| a.0.total_cmp(&b.0));
        let peak = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Some(Self {
            n,
            spacing_arcsec,
            values,
            offset,
            by_radius,
            peak,
            cache: Mutex::new(HashMap::new()),
        })
    }

    /// The unweighted centroid (x, y) in arcsec of samples laid out with
    /// the centre at index n/2 (no offset).
    pub fn grid_centroid(values: &[f64], n: usize, spacing_arcsec: f64) -> (f64, f64) {
        let c = (n / 2) as f64;
        let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
        for (k, &v) in values.iter().enumerate() {
            s += v;
            sx += v * ((k % n) as f64 - c);
            sy += v * ((k / n) as f64 - c);
        }
        (sx / s * spacing_arcsec, sy / s * spacing_arcsec)
    }

    /// Grid side.
    pub fn n(&self) -> usize {
        self.n
    }

    /// Sample spacing (arcsec).
    pub fn spacing_arcsec(&self) -> f64 {
        self.spacing_arcsec
    }

    /// The normalised samples.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// Highest frequency represented (cycles per arcsec): 1/(2s).
    pub fn band_limit(&self) -> f64 {
        0.5 / self.spacing_arcsec
    }

    fn sample_positions(&self, offset: f64) -> Vec<f64> {
        let c = (self.n / 2) as f64;
        (0..self.n)
            .map(|i| (i as f64 - c) * self.spacing_arcsec - offset)
            .collect()
    }

    /// Reference: T(u, v) by the direct double sum (slow; for tests).
    pub fn transfer_at(&self, u: f64, v: f64) -> Complex64 {
        let band = self.band_limit() * (1.0 + 1e-12);
        if u.abs() > band || v.abs() > band {
            return Complex64::new(0.0, 0.0);
        }
        let xs = self.sample_positions(self.offset.0);
        let ys = self.sample_positions(self.offset.1);
        let mut t = Complex64::new(0.0, 0.0);
        for (j, y) in ys.iter().enumerate() {
            for (i, x) in xs.iter().enumerate() {
                t += self.values[j * self.n + i]
                    * Complex64::from_polar(1.0, -TAU * (u * x + v * y));
            }
        }
        t
    }

    /// The columns (u) and rows (v) of `grid` inside the band.
    fn band_cells(&self, grid: StampGrid) -> (Vec<usize>, Vec<usize>) {
        let band = self.band_limit() * (1.0 + 1e-12);
        let cols = (0..grid.n_cols())
            .filter(|&c| grid.frequency(0, c).0.abs() <= band)
            .collect();
        let rows = (0..grid.n)
            .filter(|&r| grid.frequency(r, 0).1.abs() <= band)
            .collect();
        (cols, rows)
    }

    /// T on a stamp grid by the separable sum; zero beyond the band.
    ///
    /// Step 1, A[j][c] = Σ_i w_ij e^{−2πi u_c x_i}, and step 2,
    /// T[r][c] = Σ_j e^{−2πi v_r y_j} A[j][c], each summed over i (or j) in
    /// order, with the products of `Complex64`, exactly as
    /// [`Self::compute_transfer_slow`] does cell by cell. Here the
    /// loops are turned inside out: all columns c are summed together, one
    /// term at a time, over plain arrays of real and imaginary parts, so
    /// each sum is an independent lane the compiler vectorises instead of
    /// one long chain of dependent additions. Same bits (tested). Where the
    /// CPU runs AVX2 the same code runs built for it (same bits,
    /// `stepsim_numerics::simd`).
    fn compute_transfer(&self, grid: StampGrid) -> Vec<Complex32> {
        #[cfg(target_arch = "x86_64")]
        if stepsim_numerics::simd::has_avx2() {
            // SAFETY: the CPU runs AVX2 (checked just above).
            return unsafe { self.compute_transfer_avx2(grid) };
        }
        self.compute_transfer_body(grid)
    }

    /// [`Self::compute_transfer_body`] built for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn compute_transfer_avx2(&self, grid: StampGrid) -> Vec<Complex32> {
        self.compute_transfer_body(grid)
    }

    /// The body of [`Self::compute_transfer`], in whichever build its
    /// caller has.
    #[inline(always)]
    fn compute_transfer_body(&self, grid: StampGrid) -> Vec<Complex32> {
        let (n, nc) = (grid.n, grid.n_cols());
        let (cols, rows) = self.band_cells(grid);
        let xs = self.sample_positions(self.offset.0);
        let ys = self.sample_positions(self.offset.1);
        let (m, k) = (self.n, cols.len());
        // e^{−2πi u_c x_i} as [i][c].
        let (mut tw_re, mut tw_im) = (vec![0.0; m * k], vec![0.0; m * k]);
        for (ci, &c) in cols.iter().enumerate() {
            let u = grid.frequency(0, c).0;
            for (i, x) in xs.iter().enumerate() {
                let t = Complex64::from_polar(1.0, -TAU * u * x);
                (tw_re[i * k + ci], tw_im[i * k + ci]) = (t.re, t.im);
            }
        }
        // Step 1: A as [j][c].
        let (mut a_re, mut a_im) = (vec![0.0; m * k], vec![0.0; m * k]);
        for j in 0..m {
            let row = &self.values[j * m..(j + 1) * m];
            let (sr, si) = (&mut a_re[j * k..(j + 1) * k], &mut a_im[j * k..(j + 1) * k]);
            for (i, &w) in row.iter().enumerate() {
                let (tr, ti) = (&tw_re[i * k..(i + 1) * k], &tw_im[i * k..(i + 1) * k]);
                for c in 0..k {
                    sr[c] += tr[c] * w;
                    si[c] += ti[c] * w;
                }
            }
        }
        // Step 2.
        let mut out = vec![Complex32::new(0.0, 0.0); n * nc];
        let (mut sr, mut si) = (vec![0.0; k], vec![0.0; k]);
        for &r in &rows {
            let v = grid.frequency(r, 0).1;
            sr.fill(0.0);
            si.fill(0.0);
            for (j, y) in ys.iter().enumerate() {
                let t = Complex64::from_polar(1.0, -TAU * v * y);
                let (ar, ai) = (&a_re[j * k..(j + 1) * k], &a_im[j * k..(j + 1) * k]);
                for c in 0..k {
                    sr[c] += t.re * ar[c] - t.im * ai[c];
                    si[c] += t.re * ai[c] + t.im * ar[c];
                }
            }
            for (ci, &c) in cols.iter().enumerate() {
                out[r * nc + c] = Complex32::new(sr[ci] as f32, si[ci] as f32);
            }
        }
        out
    }

    /// [`Self::compute_transfer`]'s slow, obvious twin: each cell's sums
    /// one after the other. The two agree bit for bit (tested).
    #[cfg_attr(not(test), allow(dead_code))]
    fn compute_transfer_slow(&self, grid: StampGrid) -> Vec<Complex32> {
        let (n, nc) = (grid.n, grid.n_cols());
        let (cols, rows) = self.band_cells(grid);
        let xs = self.sample_positions(self.offset.0);
        let ys = self.sample_positions(self.offset.1);
        let m = self.n;
        // Step 1: A[j][c] = Σ_i w_ij e^{−2πi u_c x_i}.
        let mut a = vec![Complex64::new(0.0, 0.0); m * cols.len()];
        let mut tw = vec![Complex64::new(0.0, 0.0); m];
        for (ci, &c) in cols.iter().enumerate() {
            let u = grid.frequency(0, c).0;
            for (i, x) in xs.iter().enumerate() {
                tw[i] = Complex64::from_polar(1.0, -TAU * u * x);
            }
            for j in 0..m {
                let row = &self.values[j * m..(j + 1) * m];
                let mut s = Complex64::new(0.0, 0.0);
                for (w, t) in row.iter().zip(&tw) {
                    s += t * *w;
                }
                a[j * cols.len() + ci] = s;
            }
        }
        // Step 2: T[r][c] = Σ_j e^{−2πi v_r y_j} A[j][c].
        let mut out = vec![Complex32::new(0.0, 0.0); n * nc];
        for &r in &rows {
            let v = grid.frequency(r, 0).1;
            let twy: Vec<Complex64> = ys
                .iter()
                .map(|y| Complex64::from_polar(1.0, -TAU * v * y))
                .collect();
            for (ci, &c) in cols.iter().enumerate() {
                let mut s = Complex64::new(0.0, 0.0);
                for (j, t) in twy.iter().enumerate() {
                    s += t * a[j * cols.len() + ci];
                }
                out[r * nc + c] = Complex32::new(s.re as f32, s.im as f32);
            }
        }
        out
    }
}

impl Psf for SampledPsf {
    fn transfer(&self, grid: StampGrid) -> Arc<Vec<Complex32>> {
        let cell = self
            .cache
            .lock()
            .expect("psf cache lock")
            .entry(grid)
            .or_default()
            .clone();
        cell.get_or_init(|| Arc::new(self.compute_transfer(grid)))
            .clone()
    }

    fn radius_enclosing(&self, fraction: f64) -> f64 {
        let mut s = 0.0;
        for &(r, v) in &self.by_radius {
            s += v;
            if s >= fraction {
                return r;
            }
        }
        self.by_radius.last().map_or(0.0, |p| p.0)
    }

    fn radius_below(&self, level: f64) -> f64 {
        let cut = level * self.peak;
        self.by_radius
            .iter()
            .rev()
            .find(|p| p.1 > cut)
            .map_or(0.0, |p| p.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn blob() -> SampledPsf {
        // A lopsided blob, off-centre, so the test sees phases too.
        let n = 24;
        let mut v = vec![0.0; n * n];
        for j in 0..n {
            for i in 0..n {
                let (x, y) = (i as f64 - 13.3, j as f64 - 11.1);
                v[j * n + i] =
                    (-(x * x / 8.0 + y * y / 5.0 + 0.1 * x * y)).exp() * (1.0 + 0.02 * x);
            }
        }
        SampledPsf::new(v, n, 0.1, (0.05, -0.02)).unwrap()
    }

    #[test]
    fn separable_transfer_matches_the_direct_sum() {
        let p = blob();
        for grid in [StampGrid::new(16, 0.2), StampGrid::new(20, 0.07)] {
            let t = p.transfer(grid);
            assert!((f64::from(t[0].re) - 1.0).abs() < 1e-6);
            for row in 0..grid.n {
                for col in 0..grid.n_cols() {
                    let (u, v) = grid.frequency(row, col);
                    let want = p.transfer_at(u, v);
                    let got = t[row * grid.n_cols() + col];
                    assert!(
                        (f64::from(got.re) - want.re).abs() < 1e-6
                            && (f64::from(got.im) - want.im).abs() < 1e-6,
                        "({row},{col}) {got} vs {want}"
                    );
                }
            }
            assert!(Arc::ptr_eq(&t, &p.transfer(grid)));
        }
        // Beyond the band (1/(2·0.1) = 5 cycles/arcsec) it is zero.
        assert_eq!(p.transfer_at(5.5, 0.0), Complex64::new(0.0, 0.0));
    }

    #[test]
    fn transfer_in_lanes_equals_the_cell_by_cell_sums_bit_for_bit() {
        let p = blob();
        // Grids inside the band and grids the band cuts (|u| > 5 beyond
        // 1/(2·0.1)), of even sides from 2 up.
        for (n, scale) in [
            (2, 0.2),
            (16, 0.2),
            (20, 0.07),
            (36, 0.4),
            (64, 0.206),
            (90, 0.03),
        ] {
            let grid = StampGrid::new(n, scale);
            // As dispatched (the AVX2 build where the CPU has it), the
            // plain build, and the twin.
            let fast = p.compute_transfer(grid);
            let plain = p.compute_transfer_body(grid);
            let slow = p.compute_transfer_slow(grid);
            assert_eq!((fast.len(), plain.len()), (slow.len(), slow.len()));
            for (k, ((a, q), b)) in fast.iter().zip(&plain).zip(&slow).enumerate() {
                let same = |x: &Complex32| {
                    x.re.to_bits() == b.re.to_bits() && x.im.to_bits() == b.im.to_bits()
                };
                assert!(same(a) && same(q), "n {n}, cell {k}: {a} and {q} vs {b}");
            }
            let cut = fast.iter().filter(|t| t.re == 0.0 && t.im == 0.0).count();
            eprintln!("n {n}, scale {scale}: {} cells, {cut} zero", fast.len());
        }
    }

    #[test]
    fn radii_and_bad_input() {
        let p = blob();
        let r50 = p.radius_enclosing(0.5);
        let r90 = p.radius_enclosing(0.9);
        assert!(r50 > 0.1 && r50 < r90, "{r50} {r90}");
        assert!(p.radius_below(1e-3) > p.radius_below(1e-1));
        assert!(SampledPsf::new(vec![0.0; 4], 2, 0.1, (0.0, 0.0)).is_none());
        assert!(SampledPsf::new(vec![1.0; 3], 2, 0.1, (0.0, 0.0)).is_none());
        assert!(SampledPsf::new(vec![f64::NAN; 4], 2, 0.1, (0.0, 0.0)).is_none());
    }
}
