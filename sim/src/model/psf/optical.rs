//! Fourier optics: pupil + wavefront → optical transfer function (OTF), and
//! the band-limited total transfer function of an optical PSF.
//!
//! The complex pupil field is E(r) = P(r) e^{2πi W(r)}, W the wavefront in
//! waves (a Noll Zernike times its amplitude, see [`super::zernike`]; ρ = 1
//! at the rim). The PSF is I(θ) = |∫ E(r) e^{−2πi r·θ/λ} d²r|² (image axes
//! = pupil axes), and the OTF is its Fourier transform, i.e. the
//! autocorrelation of E, which vanishes beyond the cut-off D/λ.
//!
//! **Sampling (no aliasing).** The pupil is sampled on an `n × n` grid of
//! spacing dx with D ≤ (n/2 − 4) dx, so E fills less than half the grid.
//! |FFT(E)|² are then exact samples of I at spacing λ/(n dx), and the FFT
//! of those is the circular autocorrelation of the sampled E, which equals
//! the linear one because the autocorrelation's support (2D) fits inside
//! the grid: the OTF samples at frequency spacing du = dx/λ are exact
//! (up to the anti-aliased representation of the pupil's edges). The PSF
//! itself is then represented with period 1/du (23.3″ at the defaults) —
//! the only approximation, the wrap of the far wings, is measured in
//! `docs/psf.md`.
//!
//! [`BandTransfer`] multiplies the OTF by the other transfer functions
//! (atmosphere, jitter) and keeps only the central band where the
//! atmosphere leaves more than a floor (1e-12 by default): the discarded
//! frequencies carry nothing measurable.

use super::atmosphere::Kolmogorov;
use super::fft2::{fft2, signed};
use super::jitter::Jitter;
use super::pupil::Pupil;
use super::zernike;
use num_complex::Complex64;
use rustfft::FftDirection;
use std::f64::consts::{PI, TAU};

/// Radians per arcsec.
pub const ARCSEC: f64 = PI / 648_000.0;

/// A wavefront error: one Noll Zernike term.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wavefront {
    /// Noll index (0: no aberration).
    pub noll: u32,
    /// Amplitude in waves (rms over the unobstructed disk).
    pub amplitude_waves: f64,
    /// The pattern is rotated counter-clockwise by this angle (radians).
    pub angle_rad: f64,
}

impl Wavefront {
    /// No aberration.
    pub const NONE: Self = Self {
        noll: 0,
        amplitude_waves: 0.0,
        angle_rad: 0.0,
    };

    /// W (waves) at pupil position (x, y) for a pupil of radius `r_m`.
    pub fn waves(&self, x: f64, y: f64, r_m: f64) -> f64 {
        if self.noll == 0 || self.amplitude_waves == 0.0 {
            return 0.0;
        }
        let rho = x.hypot(y) / r_m;
        let th = y.atan2(x) - self.angle_rad;
        self.amplitude_waves * zernike::noll(self.noll, rho, th)
    }
}

/// The pupil sampled once, reused for every wavefront.
#[derive(Debug, Clone)]
pub struct SampledPupil {
    /// The geometry.
    pub pupil: Pupil,
    /// Grid side.
    pub n: usize,
    /// Cell size (m).
    pub dx_m: f64,
    /// Wavelength (m).
    pub lambda_m: f64,
    /// Open fraction per cell (pupil centre at cell (n/2, n/2)).
    pub transmission: Vec<f64>,
}

impl SampledPupil {
    /// Samples `pupil` on an `n × n` grid (n even, ≥ 64) so that the OTF is
    /// alias-free: D = (n/2 − 4) dx.
    pub fn new(pupil: Pupil, lambda_m: f64, n: usize, supersample: usize) -> Self {
        let dx_m = pupil.diameter_m / (n / 2 - 4) as f64;
        Self {
            transmission: pupil.sample(n, dx_m, supersample),
            pupil,
            n,
            dx_m,
            lambda_m,
        }
    }

    /// Frequency spacing of the OTF in cycles per arcsec (dx/λ per radian).
    pub fn du(&self) -> f64 {
        self.dx_m / self.lambda_m * ARCSEC
    }

    /// The OTF for a wavefront.
    pub fn otf(&self, wf: &Wavefront) -> Otf {
        let n = self.n;
        let c = (n / 2) as f64;
        let r_m = 0.5 * self.pupil.diameter_m;
        let mut e: Vec<Complex64> = self
            .transmission
            .iter()
            .enumerate()
            .map(|(k, &a)| {
                if a == 0.0 {
                    return Complex64::new(0.0, 0.0);
                }
                let x = ((k % n) as f64 - c) * self.dx_m;
                let y = ((k / n) as f64 - c) * self.dx_m;
                Complex64::from_polar(a, TAU * wf.waves(x, y, r_m))
            })
            .collect();
        fft2(&mut e, n, FftDirection::Forward);
        for v in e.iter_mut() {
            *v = Complex64::new(v.norm_sqr(), 0.0);
        }
        fft2(&mut e, n, FftDirection::Forward);
        let norm = e[0].re;
        for v in e.iter_mut() {
            *v /= norm;
        }
        Otf {
            n,
            du: self.du(),
            cutoff: self.pupil.diameter_m / self.lambda_m * ARCSEC,
            data: e,
        }
    }

    /// The optical PSF itself (no atmosphere) as `n × n` samples of spacing
    /// 1/(n du) arcsec, FFT order (index 0 at θ = 0), unit sum.
    pub fn psf(&self, wf: &Wavefront) -> Vec<f64> {
        let mut o = self.otf(wf).data;
        fft2(&mut o, self.n, FftDirection::Inverse);
        let s: f64 = o.iter().map(|v| v.re).sum();
        o.iter().map(|v| v.re / s).collect()
    }
}

/// An OTF on a full frequency grid, FFT order: cell (row l, col m) is
/// (u, v) = (signed(m), signed(l)) × du.
#[derive(Debug, Clone)]
pub struct Otf {
    /// Grid side.
    pub n: usize,
    /// Frequency spacing (cycles per arcsec).
    pub du: f64,
    /// Diffraction cut-off D/λ (cycles per arcsec).
    pub cutoff: f64,
    /// Values, T(0) = 1.
    pub data: Vec<Complex64>,
}

/// The band-limited total transfer function of an optical PSF: OTF ×
/// atmosphere × jitter on the central `nc × nc` cells of the OTF grid (FFT
/// order), with a recentring phase.
#[derive(Debug, Clone)]
pub struct BandTransfer {
    /// Grid side.
    pub nc: usize,
    /// Frequency spacing (cycles per arcsec).
    pub du: f64,
    /// Values, FFT order, T(0) = 1.
    pub t: Vec<Complex64>,
}

impl BandTransfer {
    /// Combines an OTF with optional atmosphere and jitter, keeping the band
    /// where the atmosphere is above `floor`.
    pub fn new(otf: &Otf, atm: Option<&Kolmogorov>, jitter: Option<&Jitter>, floor: f64) -> Self {
        let mut fcut = otf.cutoff;
        if let Some(a) = atm {
            fcut = fcut.min(a.cutoff(floor));
        }
        let half = ((fcut / otf.du).ceil() as usize + 2).min(otf.n / 2);
        let nc = (2 * half).div_ceil(32) * 32;
        let nc = nc.min(otf.n);
        let mut t = vec![Complex64::new(0.0, 0.0); nc * nc];
        for l in 0..nc {
            let ls = signed(l, nc);
            let lo = ls.rem_euclid(otf.n as i64) as usize;
            let v = ls as f64 * otf.du;
            for m in 0..nc {
                let ms = signed(m, nc);
                let mo = ms.rem_euclid(otf.n as i64) as usize;
                let u = ms as f64 * otf.du;
                let mut g = 1.0;
                if let Some(a) = atm {
                    g *= a.mtf(u.hypot(v));
                }
                if let Some(j) = jitter {
                    g *= j.transfer(u, v);
                }
                t[l * nc + m] = otf.data[lo * otf.n + mo] * g;
            }
        }
        Self { nc, du: otf.du, t }
    }

    /// Moves the PSF by (−cx, −cy) arcsec (multiplies T by e^{2πi(u cx + v cy)}).
    pub fn shift(&mut self, cx: f64, cy: f64) {
        let nc = self.nc;
        for l in 0..nc {
            let v = signed(l, nc) as f64 * self.du;
            for m in 0..nc {
                let u = signed(m, nc) as f64 * self.du;
                self.t[l * nc + m] *= Complex64::from_polar(1.0, TAU * (u * cx + v * cy));
            }
        }
    }

    /// The PSF (optionally convolved with a square pixel of side
    /// `pixel_arcsec`) on a `k × k` grid of spacing 1/(k du) with the origin
    /// at index (k/2, k/2), as fractions of the flux (unit sum). `k ≥ nc`.
    pub fn image(&self, k: usize, pixel_arcsec: Option<f64>) -> Vec<f64> {
        assert!(
            k >= self.nc && k % 2 == 0,
            "image grid {k} smaller than band {}",
            self.nc
        );
        let nc = self.nc;
        let mut buf = vec![Complex64::new(0.0, 0.0); k * k];
        for l in 0..nc {
            let ls = signed(l, nc);
            let lk = ls.rem_euclid(k as i64) as usize;
            for m in 0..nc {
                let ms = signed(m, nc);
                let mk = ms.rem_euclid(k as i64) as usize;
                let mut g = self.t[l * nc + m];
                if let Some(p) = pixel_arcsec {
                    g *= sinc(ms as f64 * self.du * p) * sinc(ls as f64 * self.du * p);
                }
                // Put the origin at index k/2: multiply by (−1)^(l+m).
                if (ls + ms).rem_euclid(2) == 1 {
                    g = -g;
                }
                buf[lk * k + mk] = g;
            }
        }
        fft2(&mut buf, k, FftDirection::Inverse);
        let norm = (k * k) as f64;
        buf.iter().map(|v| v.re / norm).collect()
    }

    /// Reference twin of [`Self::image`] with a pixel: the pixel-convolved PSF
    /// at arbitrary points (x, y) in arcsec, as flux per pixel of side
    /// `pixel_arcsec`, by the direct Fourier sum (slow).
    pub fn pixel_value_at(&self, x: f64, y: f64, pixel_arcsec: f64) -> f64 {
        let nc = self.nc;
        let mut s = 0.0;
        for l in 0..nc {
            let v = signed(l, nc) as f64 * self.du;
            let sv = sinc(v * pixel_arcsec);
            for m in 0..nc {
                let u = signed(m, nc) as f64 * self.du;
                let ph = Complex64::from_polar(1.0, TAU * (u * x + v * y));
                s += (self.t[l * nc + m] * ph).re * sinc(u * pixel_arcsec) * sv;
            }
        }
        s * self.du * self.du * pixel_arcsec * pixel_arcsec
    }
}

/// sin(πx)/(πx).
pub fn sinc(x: f64) -> f64 {
    if x.abs() < 1e-8 {
        1.0 - (PI * x).powi(2) / 6.0
    } else {
        (PI * x).sin() / (PI * x)
    }
}
