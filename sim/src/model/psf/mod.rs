//! PSF models (SPEC §3).
//!
//! A PSF is an immutable value implementing [`Psf`]. The renderer works in
//! Fourier space per stamp, so the central operation is
//! [`Psf::transfer`]: the PSF's transfer function sampled on the frequency
//! grid of an `n × n` stamp. Implementations cache it per `(n, pixel scale)`.
//!
//! Units: arcsec on the sky, frequencies in cycles per arcsec.
//!
//! The STEP1 optical PSFs (SPEC §3) are built as physics, one concept per
//! file: [`pupil`] (obstructed aperture with spider arms), [`zernike`]
//! (the wavefront error), [`optical`] (Fourier optics to the OTF),
//! [`atmosphere`] (Kolmogorov long-exposure MTF), [`jitter`] (tracking
//! error), `calibrate.rs` (seeing and amplitude solved for the targets:
//! [`OpticalPsf`]). [`build`] turns a [`PsfSpec`] into a ready [`Psf`];
//! `measure.rs` makes PSF images ([`image`]) and the `psf_report.json`
//! numbers ([`report`]). See `docs/psf.md`.

pub mod atmosphere;
mod calibrate;
mod czt;
mod fft2;
pub mod fits_psf;
mod gaussian;
pub mod jitter;
mod measure;
pub mod moffat;
pub mod optical;
pub mod panel;
pub mod pupil;
mod sampled;
mod spec;
pub mod zernike;

#[cfg(test)]
mod tests;

pub use calibrate::{OpticalPsf, default_amplitude};
pub use gaussian::GaussianPsf;
pub use measure::{
    DrawnPsf, FINE_OVERSAMPLE, PsfReport, contour_radius, draw_for_file, image, report,
};
pub use sampled::SampledPsf;
pub use spec::{Aberration, PsfModel, PsfSpec, STEP1_PSFS, Telescope};

use num_complex::Complex32;
use std::sync::Arc;

/// Frequency grid of an `n × n` stamp with pixel scale `pixel_scale_arcsec`,
/// in the half-plane layout of a real 2-D FFT: `n` rows (v index) of
/// `n / 2 + 1` columns (u index), row-major. Column `i` is
/// u = i / (n·p); row `j` is v = j / (n·p) for j ≤ n/2 and (j − n) / (n·p)
/// above. `n` is even.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct StampGrid {
    /// Stamp side in pixels (even).
    pub n: usize,
    /// Pixel scale in micro-arcsec (an integer so that the grid can key a cache).
    pub pixel_scale_uas: u64,
}

impl StampGrid {
    /// A grid for an `n`-pixel stamp of the given pixel scale.
    pub fn new(n: usize, pixel_scale_arcsec: f64) -> Self {
        assert!(n >= 2 && n % 2 == 0, "stamp side must be even, got {n}");
        Self {
            n,
            pixel_scale_uas: (pixel_scale_arcsec * 1e6).round() as u64,
        }
    }
    /// Pixel scale in arcsec.
    pub fn pixel_scale_arcsec(&self) -> f64 {
        self.pixel_scale_uas as f64 * 1e-6
    }
    /// Number of columns of the half plane.
    pub fn n_cols(&self) -> usize {
        self.n / 2 + 1
    }
    /// Frequency spacing in cycles per arcsec.
    pub fn dk(&self) -> f64 {
        1.0 / (self.n as f64 * self.pixel_scale_arcsec())
    }
    /// (u, v) in cycles per arcsec of half-plane cell (`row`, `col`).
    pub fn frequency(&self, row: usize, col: usize) -> (f64, f64) {
        let dk = self.dk();
        (col as f64 * dk, self.row_index(row) as f64 * dk)
    }
    /// The signed frequency index of `row` (v = index × dk): `row` for rows
    /// up to n/2, `row − n` above.
    pub fn row_index(&self, row: usize) -> i64 {
        row_index(row, self.n)
    }
}

/// The signed frequency index of row `row` of an `n`-point grid: `row` up
/// to n/2, `row − n` above (the Nyquist row is +n/2; [`fft2::signed`]
/// makes it −n/2).
pub(crate) fn row_index(row: usize, n: usize) -> i64 {
    if row <= n / 2 {
        row as i64
    } else {
        row as i64 - n as i64
    }
}

/// A point-spread function: optics, atmosphere and anything else except the
/// pixel response, which the renderer applies.
pub trait Psf: Send + Sync + std::fmt::Debug {
    /// Transfer function T(u, v) = ∫ PSF(x) e^{−2πi(ux+vy)} dx, with T(0) = 1,
    /// on the half-plane grid of `grid`. Cached by the implementation.
    fn transfer(&self, grid: StampGrid) -> Arc<Vec<Complex32>>;

    /// Radius (arcsec) of the circle about the centroid that holds `fraction`
    /// of the flux; used to size stamps.
    fn radius_enclosing(&self, fraction: f64) -> f64;

    /// Fraction of the flux beyond radius `r_arcsec` at which the surface
    /// brightness relative to the peak drops below `level` (for the edge
    /// criterion of bright stars): the radius beyond which the PSF is fainter
    /// than `level` × peak everywhere.
    fn radius_below(&self, level: f64) -> f64;

    /// How an optical PSF was calibrated (seeing, aberration amplitude);
    /// `None` for the other models.
    fn calibration(&self) -> Option<Calibration> {
        None
    }

    /// Hands the PSF its transfer on `grid`, computed earlier by
    /// [`Psf::transfer`] (a PSF store's copy), so that the first call for
    /// that grid does not compute it; ignored when the PSF computes its
    /// transfers cheaply or already holds that grid's. The caller answers
    /// for `t` being exactly what `transfer(grid)` gives.
    fn provide_transfer(&self, grid: StampGrid, t: Arc<Vec<Complex32>>) {
        let _ = (grid, t);
    }
}

/// The result of calibrating an optical PSF (SPEC §3).
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// Seeing FWHM of the atmosphere alone, 0.976 λ/r0 (arcsec).
    pub seeing_fwhm_arcsec: f64,
    /// λ/r0 (arcsec).
    pub lambda_over_r0_arcsec: f64,
    /// The aberration's config name.
    pub aberration: String,
    /// Amplitude: waves rms, or σ in arcsec for jitter.
    pub amplitude: f64,
    /// `waves` or `arcsec`.
    pub amplitude_unit: &'static str,
    /// FWHM measured during calibration (arcsec).
    pub fwhm_arcsec: f64,
    /// |χ| measured during calibration.
    pub chi_abs: f64,
    /// How far the light centroid sat from the origin before recentring
    /// (arcsec); coma moves the light.
    pub centroid_shift_arcsec: (f64, f64),
}

/// Accuracy settings of the PSF models (one place, documented defaults).
#[derive(Debug, Clone, PartialEq)]
pub struct PsfAccuracy {
    /// Side of the pupil / OTF grid of the final PSF. The PSF is
    /// represented with period λ/dx: 46.8″ at 2048 for the default
    /// telescope, enough for the diffraction spikes to fall below 1e-5 of
    /// the peak (at 14″) inside the 23.4″ half-box (see docs/psf.md).
    pub pupil_grid: usize,
    /// Side of the pupil grid used while solving seeing and amplitude
    /// (period 23.3″ at 1024: the core, FWHM and χ agree with the final grid
    /// to better than 1e-4″ and 1e-4).
    pub calibration_grid: usize,
    /// Sub-samples per side of pupil cells cut by an edge (anti-aliasing).
    pub pupil_supersample: usize,
    /// Frequencies where the atmospheric MTF is below this are dropped.
    pub band_floor: f64,
    /// Tolerance of the seeing solution on the FWHM (arcsec).
    pub fwhm_tol_arcsec: f64,
    /// Tolerance of the amplitude solution on |χ|.
    pub chi_tol: f64,
}

impl Default for PsfAccuracy {
    fn default() -> Self {
        Self {
            pupil_grid: 2048,
            calibration_grid: 1024,
            pupil_supersample: 8,
            band_floor: 1e-12,
            fwhm_tol_arcsec: 2e-4,
            chi_tol: 2e-4,
        }
    }
}

/// Why a PSF could not be built.
#[derive(Debug, thiserror::Error)]
pub enum PsfError {
    /// The requested targets cannot be met.
    #[error("psf {name}: {message}")]
    Unreachable {
        /// PSF name.
        name: String,
        /// What cannot be met.
        message: String,
    },
    /// An iterative solution failed.
    #[error("psf {name}: no convergence solving the {what}")]
    NoConvergence {
        /// PSF name.
        name: String,
        /// What was being solved.
        what: String,
    },
    /// The PSF could not be measured.
    #[error("psf {name}: {source}")]
    Moments {
        /// PSF name.
        name: String,
        /// The moments error.
        source: crate::model::moments::MomentsError,
    },
    /// A PSF image read from a file is unusable.
    #[error("psf {name}: {path}: {message}")]
    BadImage {
        /// PSF name.
        name: String,
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
}

/// A PSF image read from a FITS file by the plan (primary HDU, row-major):
/// the PSF module never reads files itself.
#[derive(Clone, PartialEq)]
pub struct PsfFileImage {
    /// The file it was read from (resolved against the config's directory).
    pub path: std::path::PathBuf,
    /// Row-major values.
    pub values: Vec<f64>,
    /// Columns (NAXIS1).
    pub nx: usize,
    /// Rows (NAXIS2).
    pub ny: usize,
}

impl std::fmt::Debug for PsfFileImage {
    /// The path, the shape and a digest of the values (not every value).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // FNV-1a over the bits: two different images never share a cache key.
        let digest = self.values.iter().fold(0xcbf2_9ce4_8422_2325_u64, |h, v| {
            (h ^ v.to_bits()).wrapping_mul(0x0000_0100_0000_01b3)
        });
        f.debug_struct("PsfFileImage")
            .field("path", &self.path)
            .field("nx", &self.nx)
            .field("ny", &self.ny)
            .field("digest", &format_args!("{digest:016x}"))
            .finish()
    }
}

/// Builds the PSF of `spec` (default accuracy). Nothing is cached here: a
/// run's PSFs are owned, built once, by its plan (`Plan::psf`).
pub fn build(spec: &PsfSpec) -> Result<Arc<dyn Psf>, PsfError> {
    build_with(spec, &PsfAccuracy::default())
}

/// [`build`] with explicit accuracy settings.
pub fn build_with(spec: &PsfSpec, accuracy: &PsfAccuracy) -> Result<Arc<dyn Psf>, PsfError> {
    let (psf, telescope, pixel_scale_arcsec) = (spec, &spec.telescope, spec.pixel_scale_arcsec);
    match &psf.model {
        PsfModel::Gaussian { e1, e2 } => {
            Ok(Arc::new(GaussianPsf::elliptical(psf.fwhm_arcsec, *e1, *e2)))
        }
        PsfModel::Moffat { beta, trunc_fwhm } => Ok(Arc::new(moffat::moffat(
            psf.fwhm_arcsec,
            *beta,
            *trunc_fwhm,
            pixel_scale_arcsec,
        ))),
        PsfModel::Fits {
            path,
            pixel_scale_arcsec: scale,
        } => {
            let Some(image) = &spec.image else {
                return Err(PsfError::BadImage {
                    name: psf.name.clone(),
                    path: path.clone(),
                    message: "the file's image was not read (build FITS PSFs from the plan's spec)"
                        .into(),
                });
            };
            let shown = image.path.display().to_string();
            fits_psf::from_image(&psf.name, &shown, &image.values, image.nx, image.ny, *scale)
                .map(|p| Arc::new(p) as _)
        }
        PsfModel::Optical {
            aberration,
            amplitude,
            target_chi,
            angle_deg,
        } => {
            let request = OpticalRequest {
                name: &psf.name,
                fwhm_arcsec: psf.fwhm_arcsec,
                aberration: *aberration,
                amplitude: *amplitude,
                target_chi: *target_chi,
                angle_rad: angle_deg.to_radians(),
                telescope,
                pixel_scale_arcsec,
            };
            Ok(Arc::new(build_optical(&request, accuracy)?))
        }
    }
}

/// What an optical PSF is built from: the spec's model and
/// targets, the telescope and the pixel scale.
#[derive(Debug, Clone, Copy)]
pub struct OpticalRequest<'a> {
    /// The PSF's name (in errors).
    pub name: &'a str,
    /// Target FWHM.
    pub fwhm_arcsec: f64,
    /// The aberration.
    pub aberration: Aberration,
    /// Its amplitude in waves (`None`: solved for `target_chi`).
    pub amplitude: Option<f64>,
    /// Target ellipticity χ.
    pub target_chi: Option<f64>,
    /// Orientation of the aberration.
    pub angle_rad: f64,
    /// Pupil and wavelength.
    pub telescope: &'a Telescope,
    /// Pixel scale of the images.
    pub pixel_scale_arcsec: f64,
}

impl<'a> OpticalRequest<'a> {
    /// The request of an optical `spec` (`None` for other models).
    pub fn of(spec: &'a PsfSpec) -> Option<Self> {
        let PsfModel::Optical {
            aberration,
            amplitude,
            target_chi,
            angle_deg,
        } = &spec.model
        else {
            return None;
        };
        Some(Self {
            name: &spec.name,
            fwhm_arcsec: spec.fwhm_arcsec,
            aberration: *aberration,
            amplitude: *amplitude,
            target_chi: *target_chi,
            angle_rad: angle_deg.to_radians(),
            telescope: &spec.telescope,
            pixel_scale_arcsec: spec.pixel_scale_arcsec,
        })
    }
}

/// Builds and calibrates one optical PSF (see `calibrate.rs`).
pub fn build_optical(
    request: &OpticalRequest,
    accuracy: &PsfAccuracy,
) -> Result<OpticalPsf, PsfError> {
    let (band, cal) = solve_optical(request, accuracy)?;
    Ok(OpticalPsf::new(band, cal))
}

/// The expensive part of [`build_optical`]: the solved calibration and the
/// band-limited transfer function on the final grid, before
/// [`OpticalPsf::new`] recentres and samples it (what
/// [`crate::io::psf_store`] keeps).
pub fn solve_optical(
    request: &OpticalRequest,
    accuracy: &PsfAccuracy,
) -> Result<(optical::BandTransfer, Calibration), PsfError> {
    let &OpticalRequest {
        name,
        fwhm_arcsec,
        aberration,
        amplitude,
        target_chi,
        angle_rad,
        telescope,
        pixel_scale_arcsec,
    } = request;
    let geometry = pupil::Pupil::from_telescope(telescope);
    let lambda_m = telescope.wavelength_um * 1e-6;
    let pupil = optical::SampledPupil::new(
        geometry,
        lambda_m,
        accuracy.calibration_grid,
        accuracy.pupil_supersample,
    );
    let setup = calibrate::Setup {
        pupil: &pupil,
        pixel_scale_arcsec,
        fwhm_arcsec,
        accuracy,
        name,
    };
    if target_chi.is_some() && amplitude.is_none() && aberration == Aberration::None {
        return Err(PsfError::Unreachable {
            name: name.into(),
            message: "target_chi needs an aberration to solve for (aberration is none)".into(),
        });
    }
    let flat = pupil.otf(&optical::Wavefront::NONE);
    let (amp, eval) = match (amplitude, target_chi) {
        (Some(a), _) => (
            a,
            calibrate::evaluate(&setup, aberration, a, angle_rad, &flat)?,
        ),
        (None, Some(t)) if aberration != Aberration::None => {
            calibrate::solve_amplitude(&setup, aberration, t, angle_rad, &flat)?
        }
        (None, _) => {
            let a = calibrate::default_amplitude(aberration);
            (
                a,
                calibrate::evaluate(&setup, aberration, a, angle_rad, &flat)?,
            )
        }
    };
    let name_of = serde_json::to_value(aberration)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default();
    let cal = Calibration {
        seeing_fwhm_arcsec: eval.atmosphere.fwhm_arcsec(),
        lambda_over_r0_arcsec: eval.atmosphere.lambda_over_r0_arcsec,
        aberration: name_of,
        amplitude: amp,
        amplitude_unit: if aberration == Aberration::Jitter {
            "arcsec"
        } else {
            "waves"
        },
        fwhm_arcsec: eval.fwhm_arcsec,
        chi_abs: eval.chi.0.hypot(eval.chi.1),
        centroid_shift_arcsec: (0.0, 0.0),
    };
    let band = if accuracy.pupil_grid == accuracy.calibration_grid {
        eval.band
    } else {
        let big = optical::SampledPupil::new(
            geometry,
            lambda_m,
            accuracy.pupil_grid,
            accuracy.pupil_supersample,
        );
        calibrate::band_for(
            &big,
            aberration,
            amp,
            angle_rad,
            &eval.atmosphere,
            accuracy.band_floor,
        )
    };
    Ok((band, cal))
}
