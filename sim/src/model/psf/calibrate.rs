//! Calibration of the optical PSFs: solve the seeing (λ/r0) so that the
//! pixel-convolved PSF has the requested FWHM, and, when a `target_chi` is
//! given, the aberration amplitude so that its adaptive-moment |χ| is the
//! target (at that FWHM).
//!
//! Both are measured on the finely sampled pixel-convolved PSF
//! ([`BandTransfer::image`] with the pixel, spacing λ/(n dx) ≈ pixel/9):
//! FWHM from the area above half maximum, χ from adaptive moments.
//!
//! * Seeing: regula falsi (Illinois) on FWHM(λ/r0) − target, bracketed by
//!   λ/r0 = 0 (optics, jitter and pixel alone — if that is already wider
//!   than the target, the target is refused) and the λ/r0 whose seeing
//!   alone has the target FWHM; stops at |ΔFWHM| < `fwhm_tol_arcsec`.
//! * Amplitude: |χ| grows as the square of the amplitude for both coma
//!   (an odd aberration: no first-order anisotropy) and jitter (σ² adds to
//!   one second moment), so a ← a sqrt(target/|χ(a)|) converges in a few
//!   steps; stops at ||χ| − target| < `chi_tol`.

use super::Aberration;
use super::atmosphere::Kolmogorov;
use super::jitter::Jitter;
use super::measure::fwhm_from_area;
use super::optical::{BandTransfer, Otf, SampledPupil, Wavefront};
use super::sampled::SampledPsf;
use super::{Calibration, Psf, PsfAccuracy, PsfError, StampGrid};
use crate::model::moments;
use num_complex::Complex32;
use std::sync::Arc;

/// What one evaluation found.
#[derive(Debug, Clone)]
pub struct Evaluation {
    /// The atmosphere that gives the FWHM.
    pub atmosphere: Kolmogorov,
    /// The total band-limited transfer function (not yet recentred).
    pub band: BandTransfer,
    /// Measured FWHM (arcsec).
    pub fwhm_arcsec: f64,
    /// Measured adaptive χ.
    pub chi: (f64, f64),
}

/// The inputs of a calibration.
#[derive(Debug)]
pub struct Setup<'a> {
    /// The sampled pupil.
    pub pupil: &'a SampledPupil,
    /// Pixel scale of the images (arcsec).
    pub pixel_scale_arcsec: f64,
    /// Target FWHM of the pixel-convolved PSF (arcsec).
    pub fwhm_arcsec: f64,
    /// Tolerances.
    pub accuracy: &'a PsfAccuracy,
    /// Name, for messages.
    pub name: &'a str,
}

impl Setup<'_> {
    fn fine_fwhm(&self, band: &BandTransfer) -> f64 {
        let k = self.pupil.n;
        let img = band.image(k, Some(self.pixel_scale_arcsec));
        fwhm_from_area(&img, k) / (k as f64 * band.du)
    }

    /// Measures |χ| of the pixel-convolved PSF of `band`.
    pub fn fine_chi(&self, band: &BandTransfer) -> Result<(f64, f64), PsfError> {
        let k = self.pupil.n;
        let h = 1.0 / (k as f64 * band.du);
        let img = band.image(k, Some(self.pixel_scale_arcsec));
        let m = moments::adaptive(&img, k, k, 0.4 / h).map_err(|source| PsfError::Moments {
            name: self.name.into(),
            source,
        })?;
        Ok(m.chi())
    }

    /// Solves λ/r0 for the target FWHM given the optics and jitter.
    pub fn solve_seeing(&self, otf: &Otf, jitter: Option<&Jitter>) -> Result<Evaluation, PsfError> {
        let floor = self.accuracy.band_floor;
        let target = self.fwhm_arcsec;
        let eval = |x: f64| {
            let atm = Kolmogorov {
                lambda_over_r0_arcsec: x,
            };
            let band = BandTransfer::new(otf, Some(&atm), jitter, floor);
            let f = self.fine_fwhm(&band);
            (atm, band, f)
        };
        let period = 1.0 / otf.du;
        if target > period / 8.0 {
            return Err(PsfError::Unreachable {
                name: self.name.into(),
                message: format!(
                    "fwhm_arcsec {target}″ is too wide for the optical grid (period {period:.1}″; at most {:.1}″)",
                    period / 8.0
                ),
            });
        }
        let no_atm = BandTransfer::new(otf, None, jitter, floor);
        let f0 = self.fine_fwhm(&no_atm);
        if f0 >= target {
            return Err(PsfError::Unreachable {
                name: self.name.into(),
                message: format!(
                    "without any seeing the PSF already has FWHM {f0:.4}″ ≥ fwhm_arcsec {target}″"
                ),
            });
        }
        let (mut lo, mut flo) = (0.0, f0 - target);
        let mut hi = target / super::atmosphere::FWHM_OVER_LAMBDA_R0;
        let mut best = eval(hi);
        let mut fhi = best.2 - target;
        let mut widen = 0;
        while fhi <= 0.0 {
            widen += 1;
            if widen > 20 {
                return Err(PsfError::NoConvergence {
                    name: self.name.into(),
                    what: "seeing for the target FWHM (no seeing is wide enough)".into(),
                });
            }
            hi *= 1.5;
            best = eval(hi);
            fhi = best.2 - target;
        }
        // First guess from FWHMs adding in quadrature.
        let mut x = (target * target - f0 * f0).sqrt() / super::atmosphere::FWHM_OVER_LAMBDA_R0;
        let mut side = 0i32;
        for _ in 0..60 {
            if !(x > lo && x < hi) {
                x = 0.5 * (lo + hi);
            }
            let e = eval(x);
            let d = e.2 - target;
            if d.abs() < self.accuracy.fwhm_tol_arcsec {
                let chi = self.fine_chi(&e.1)?;
                return Ok(Evaluation {
                    atmosphere: e.0,
                    band: e.1,
                    fwhm_arcsec: e.2,
                    chi,
                });
            }
            if d > 0.0 {
                hi = x;
                fhi = d;
                if side == 1 {
                    flo *= 0.5;
                }
                side = 1;
            } else {
                lo = x;
                flo = d;
                if side == -1 {
                    fhi *= 0.5;
                }
                side = -1;
            }
            x = (lo * fhi - hi * flo) / (fhi - flo);
        }
        Err(PsfError::NoConvergence {
            name: self.name.into(),
            what: "seeing for the target FWHM".into(),
        })
    }
}

/// Noll index of the Zernike term of an aberration (None for jitter / none).
pub fn zernike_of(a: Aberration) -> Option<u32> {
    match a {
        Aberration::None | Aberration::Jitter => None,
        Aberration::Defocus => Some(4),
        Aberration::Astigmatism => Some(6),
        Aberration::Coma => Some(8),
        Aberration::Trefoil => Some(10),
        Aberration::Spherical => Some(11),
    }
}

/// The documented default amplitude of an aberration when the config gives
/// neither `amplitude` nor `target_chi` (waves; arcsec σ for jitter).
pub fn default_amplitude(a: Aberration) -> f64 {
    match a {
        Aberration::None => 0.0,
        Aberration::Coma => 0.35,
        Aberration::Jitter => 0.15,
        Aberration::Defocus => 0.7,
        Aberration::Astigmatism => 0.95,
        Aberration::Trefoil => 0.7,
        Aberration::Spherical => 0.3,
    }
}

/// Evaluates one amplitude: OTF, then the seeing for the target FWHM.
pub fn evaluate(
    setup: &Setup<'_>,
    aberration: Aberration,
    amplitude: f64,
    angle_rad: f64,
    flat_otf: &Otf,
) -> Result<Evaluation, PsfError> {
    match (aberration, zernike_of(aberration)) {
        (Aberration::Jitter, _) => {
            let j = Jitter {
                sigma_arcsec: amplitude,
                angle_rad,
            };
            setup.solve_seeing(flat_otf, Some(&j))
        }
        (_, Some(noll)) if amplitude != 0.0 => {
            let otf = setup.pupil.otf(&Wavefront {
                noll,
                amplitude_waves: amplitude,
                angle_rad,
            });
            setup.solve_seeing(&otf, None)
        }
        _ => setup.solve_seeing(flat_otf, None),
    }
}

/// The total band-limited transfer function for a known amplitude and
/// atmosphere (no solving): used to build the final PSF on the larger grid
/// once the calibration grid has fixed λ/r0 and the amplitude.
pub fn band_for(
    pupil: &SampledPupil,
    aberration: Aberration,
    amplitude: f64,
    angle_rad: f64,
    atmosphere: &Kolmogorov,
    floor: f64,
) -> BandTransfer {
    match (aberration, zernike_of(aberration)) {
        (Aberration::Jitter, _) => {
            let j = Jitter {
                sigma_arcsec: amplitude,
                angle_rad,
            };
            BandTransfer::new(
                &pupil.otf(&Wavefront::NONE),
                Some(atmosphere),
                Some(&j),
                floor,
            )
        }
        (_, Some(noll)) => {
            let otf = pupil.otf(&Wavefront {
                noll,
                amplitude_waves: amplitude,
                angle_rad,
            });
            BandTransfer::new(&otf, Some(atmosphere), None, floor)
        }
        _ => BandTransfer::new(&pupil.otf(&Wavefront::NONE), Some(atmosphere), None, floor),
    }
}

/// Solves the amplitude that gives |χ| = `target`; returns it with its evaluation.
pub fn solve_amplitude(
    setup: &Setup<'_>,
    aberration: Aberration,
    target: f64,
    angle_rad: f64,
    flat_otf: &Otf,
) -> Result<(f64, Evaluation), PsfError> {
    let (mut a, max) = match aberration {
        Aberration::Jitter => (default_amplitude(aberration), 3.0),
        _ => (default_amplitude(aberration).max(0.1), 5.0),
    };
    for _ in 0..25 {
        let e = evaluate(setup, aberration, a, angle_rad, flat_otf)?;
        let chi = e.chi.0.hypot(e.chi.1);
        if (chi - target).abs() < setup.accuracy.chi_tol {
            return Ok((a, e));
        }
        if chi < 1e-6 {
            break;
        }
        a *= (target / chi).sqrt().clamp(0.3, 3.0);
        if a > max {
            break;
        }
    }
    Err(PsfError::Unreachable {
        name: setup.name.into(),
        message: format!("target_chi {target} cannot be reached with {aberration:?}"),
    })
}

/// A calibrated optical PSF: the real-space samples (recentred on the light
/// centroid) behind the [`Psf`] interface, plus the band-limited transfer
/// function they came from (the reference for tests) and the calibration.
#[derive(Debug)]
pub struct OpticalPsf {
    sampled: SampledPsf,
    band: BandTransfer,
    calibration: Calibration,
}

impl OpticalPsf {
    /// Recentres `band` on its light centroid and samples it in real space.
    pub fn new(mut band: BandTransfer, calibration: Calibration) -> Self {
        let nc = band.nc;
        let s = 1.0 / (nc as f64 * band.du);
        let mut total = (0.0, 0.0);
        for _ in 0..3 {
            let img = band.image(nc, None);
            let (cx, cy) = SampledPsf::grid_centroid(&img, nc, s);
            band.shift(cx, cy);
            total = (total.0 + cx, total.1 + cy);
        }
        let mut calibration = calibration;
        calibration.centroid_shift_arcsec = total;
        Self::recentred(band, calibration)
    }

    /// The PSF of a band that [`OpticalPsf::new`] has recentred already
    /// (its [`OpticalPsf::band`], with the calibration that records the
    /// shift): only sampled, so the very same PSF as the one `new` made
    /// (what the PSF store keeps, [`crate::io::psf_store`]).
    pub fn recentred(band: BandTransfer, calibration: Calibration) -> Self {
        let nc = band.nc;
        let s = 1.0 / (nc as f64 * band.du);
        let img = band.image(nc, None);
        let sampled = SampledPsf::new(img, nc, s, (0.0, 0.0)).expect("optical PSF has flux");
        Self {
            sampled,
            band,
            calibration,
        }
    }

    /// The calibration, with the recentring's shift.
    pub fn calibration_ref(&self) -> &Calibration {
        &self.calibration
    }

    /// The band-limited transfer function (recentred).
    pub fn band(&self) -> &BandTransfer {
        &self.band
    }

    /// The real-space samples.
    pub fn sampled(&self) -> &SampledPsf {
        &self.sampled
    }
}

impl Psf for OpticalPsf {
    fn transfer(&self, grid: StampGrid) -> Arc<Vec<Complex32>> {
        self.sampled.transfer(grid)
    }
    fn radius_enclosing(&self, fraction: f64) -> f64 {
        self.sampled.radius_enclosing(fraction)
    }
    fn radius_below(&self, level: f64) -> f64 {
        self.sampled.radius_below(level)
    }
    fn calibration(&self) -> Option<Calibration> {
        Some(self.calibration.clone())
    }
    fn provide_transfer(&self, grid: StampGrid, t: Arc<Vec<Complex32>>) {
        self.sampled.provide_transfer(grid, t);
    }
}
