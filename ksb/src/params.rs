//! Every tunable number of the pipeline in one place, with its default and
//! where it comes from (STYLE §4). Sizes are in pixels, significances in
//! units of the noise of the quantity named.

use crate::calibration::CalibrationProfile;
use crate::error::KsbError;

/// How P^γ enters the estimator (paper appendix A4; KSB table row
/// "P^γ correction").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PgammaMode {
    /// Each galaxy's own ½Tr[P^γ] (like CH and TS: "no fit").
    PerObject,
    /// ½Tr[P^γ] fitted as a smooth function of r_g over the image's good
    /// galaxies (like MB and HH): less noise, one number per size.
    FitSize,
}

/// What KSB+'s `SMALL` cut compares with `size_min_factor` × r_g*
/// (`stepsim measure --size-cut`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SizeCut {
    /// The windowed r_g (KSB table row "Galaxy size r_g"; the default).
    /// It follows the shear to first order in g·e, so the cut selects
    /// galaxies by their alignment with the shear: on 16 fields of the
    /// STEP1 preset it adds about +0.03 to m (docs/baseline.md).
    Windowed,
    /// The r_g of the round object of the same PSF-corrected area
    /// (`psf_corrected_size` in shear.rs: the PSF taken out as a tensor,
    /// with the stars' own e* fitted across the field), which neither a
    /// shear nor the PSF's anisotropy moves for Gaussian profiles; on the
    /// preset's isolated galaxies at low noise the cut's selection is
    /// −0.014 … +0.006 in m against +0.032 … +0.043 for r_g, at STEP1's
    /// noise −0.005 … −0.036 against +0.013 … +0.023 (docs/baseline.md,
    /// "Isolated galaxies on a grid").
    PsfCorrected,
}

/// The largest |ĝ₀| a dataset is sheared back by ([`KsbParams::unshear`];
/// a dataset whose first estimate is larger keeps its first
/// measurement): far beyond the weak shears the method is for (measured
/// up to |g| = 0.113, docs/metacal.md). The reconvolution's Γ is chosen
/// for the ±0.01 versions, and a version sheared further asks more of
/// the deconvolution at high frequencies (its gain is capped at 3); how
/// far that holds has not been measured.
pub const MAX_ORIGIN_SHEAR: f64 = 0.2;

/// The shear method (`stepsim measure --method`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// KSB+ (paper appendix A; docs/ksb.md).
    Ksb,
    /// Metacalibration (`metacal.rs`): the response measured by
    /// shearing each galaxy's deconvolved image, selection included.
    Metacal,
    /// Metadetection (`metadetect.rs`): metacalibration of the whole
    /// image, detection included.
    Metadetect,
}

/// The pipeline's parameters. `KsbParams::default()` is the setting used by
/// `stepsim measure`; every default is justified next to its field.
#[derive(Debug, Clone, PartialEq)]
pub struct KsbParams {
    /// Side of a background mesh (SExtractor's BACK_SIZE default, 64).
    pub background_mesh_px: usize,
    /// κ of the κσ clipping of each mesh (3, SExtractor).
    pub background_clip_sigma: f64,
    /// σ of the Gaussian detection filter (1.5 px ≈ 0.8 × the σ of a 0.9″
    /// PSF at 0.206″/px: close to matched for the faint, PSF-sized sources).
    pub detect_filter_sigma_px: f64,
    /// Pixels of the filtered image above this many filtered-noise σ belong
    /// to a source (2; the isophote that defines footprints).
    pub detect_thresh: f64,
    /// Smallest footprint in pixels (5, SExtractor's DETECT_MINAREA).
    pub detect_min_area: usize,
    /// A source's filtered peak must reach this many filtered-noise σ (5).
    pub detect_peak_sn: f64,
    /// Two peaks of one footprint are split when the filtered image dips by
    /// at least this fraction of the lower peak on the line between them (0.3).
    pub deblend_min_dip: f64,
    /// ... and when they are at least this far apart (3 px).
    pub deblend_min_sep_px: f64,
    /// A split source is flagged BLENDED when another peak of its footprint
    /// is closer than this (20 px = 5 r_g of a PSF-sized object).
    pub deblend_flag_px: f64,
    /// Largest number of peaks kept per footprint (32).
    pub deblend_max_peaks: usize,
    /// Largest number of windowed-centroid iterations (60).
    pub centroid_max_iter: usize,
    /// Convergence of the windowed centroid (1e-3 px, and 1e-3 relative in r_g).
    pub centroid_tol_px: f64,
    /// Largest distance the windowed centroid may move from the detection
    /// peak (3 px; the |d| < 3 pix cut of MH and TS).
    pub centroid_max_shift_px: f64,
    /// Smallest weight scale r_g (0.5 px).
    pub rg_min_px: f64,
    /// Largest weight scale r_g (15 px ≈ 3″); larger objects are flagged LARGE.
    pub rg_max_px: f64,
    /// Moments are summed over |θ| ≤ this × r_g (4, the θ_max = 4 r_g of MB, CH, LV).
    pub window_radius_rg: f64,
    /// Objects used to find the stellar locus and model the PSF need this
    /// Gaussian-weighted S/N (50).
    pub star_min_sn: f64,
    /// Objects fainter than this S/N are never called stars (20).
    pub star_class_min_sn: f64,
    /// Kernel width, in ln r_g, of the density estimate that finds the locus (0.03).
    pub locus_bandwidth: f64,
    /// Half-width of the locus in robust σ of ln r_g (3).
    pub locus_nsigma: f64,
    /// Largest robust width (1.4826 MAD, in ln r_g) of a stellar locus
    /// (0.04). Stars scatter in size by noise only: ≈ 0.01 at ν ≈ 100,
    /// ≈ 0.02 at ν ≈ 20 on the STEP images; a flat clump of galaxies or the
    /// lower edge of their size distribution widens past it when the
    /// locus is refined (`refine_locus`, `stars.rs`).
    pub locus_max_width: f64,
    /// Smallest robust width of the locus used while refining it (0.002;
    /// keeps noise-free stars of identical sizes from collapsing the window).
    pub locus_width_floor: f64,
    /// Smallest half-width of the locus in ln r_g (0.03, i.e. ±3 %).
    pub locus_min_halfwidth: f64,
    /// Polynomial order of the PSF model across the field (2, like MB, CH, HH, LV).
    pub psf_order: usize,
    /// κ of the κσ clipping of the PSF fit (3).
    pub psf_clip_sigma: f64,
    /// The order drops until there are at least this many stars per
    /// polynomial coefficient (3).
    pub psf_stars_per_term: f64,
    /// Fewest stars that give a PSF model at all (order 0) (3).
    pub psf_min_stars: usize,
    /// Ratio of neighbouring weight scales of the stellar ladder (1.06).
    pub scale_step: f64,
    /// Galaxies need r_g > this × r_g* (1.25; CH and TS 1.2, MB and MH 1.0).
    /// KSB's bias is worst for the smallest galaxies: on synthetic scenes
    /// with a PSF halo m went from −0.083 (1.1) to −0.056 (1.3) and −0.022
    /// (1.6, with a third of the galaxies); see docs/ksb.md.
    pub size_min_factor: f64,
    /// Which size the `SMALL` cut uses ([`SizeCut::Windowed`]).
    pub size_cut: SizeCut,
    /// Metacal's galaxies need Gaussian-weighted S/N ν ≥ this on each
    /// version (10, like CH and C1/C2; `metacal::McMeasure::sn`).
    pub min_sn: f64,
    /// KSB+'s galaxies need ν ≥ this (20). Faint galaxies are the ones
    /// with a neighbour of ≥ 10 % of their flux within 3″ that the
    /// detection does not split, and such blends respond less than the
    /// shear in the unlensed STEP1 scene: on 16 fields of the preset
    /// (PSF `none`) m went from −0.115 (ν ≥ 10) to −0.050 (ν ≥ 20), and
    /// to −0.015 with the centroid-shift flag; see docs/baseline.md.
    pub ksb_min_sn: f64,
    /// KSB+'s galaxies need their windowed centroid within this of the
    /// smoothed image's sub-pixel peak (0.4 px; `flags::SHIFTED`): a
    /// neighbour merged into the footprint pulls the light's mean away
    /// from its mode.
    pub ksb_max_peak_shift_px: f64,
    /// Galaxies need ½Tr[P^γ] ≥ this (0.1).
    pub min_pgamma: f64,
    /// Galaxies need |γ̂| < this (1).
    pub max_shear: f64,
    /// Intrinsic shear-estimate dispersion per component in the weights
    /// w = 1 / (σ_int² + σ_γ²) (0.3; Hoekstra et al. 2000).
    pub sigma_int: f64,
    /// Two detections closer than this are a close pair, both flagged
    /// BLENDED (10 px ≈ 2″, CH's close-pair cut).
    pub close_pair_px: f64,
    /// How P^γ is used (per object: on synthetic scenes the fit against
    /// size loses the per-object ellipticity dependence of P^sh and gives a
    /// 2–4 % more negative m; see docs/ksb.md).
    pub pgamma_mode: PgammaMode,
    /// Include the objects' own photon noise in the pixel variance (true).
    pub poisson_variance: bool,
    /// The shear method (KSB+).
    pub method: Method,
    /// KSB+'s P^γ calibrated on the image's own PSF with model galaxies of
    /// this profile (docs/ksb.md, step 8); `None` keeps P^γ as KSB+
    /// gives it.
    pub calibration: Option<CalibrationProfile>,
    /// Metacalibration keeps galaxies whose reconvolved size r_g exceeds
    /// this × the reconvolution's σ (1.2, i.e. (r_g² − σ²)/σ² > 0.44, about
    /// KSB's r_g > 1.25 r_g*).
    pub metacal_size_min_factor: f64,
    /// Metadetection measures each dataset a second time on its images
    /// sheared back by its first estimate ĝ₀ (`stepsim measure --unshear`;
    /// false): the response R is a derivative at the shear the image has,
    /// so ⟨e⟩/R is off by a term in |g|² (for metadetection +0.003 ±
    /// 0.003 at g = ±(0.08, 0.08) on isolated galaxies, for per-object
    /// metacal +0.0165; docs/metacal.md, "The response at a finite
    /// shear"); the rows are then ĝ₀ + R⁻¹ e of the version sheared by
    /// −ĝ₀, whose own shear is near zero, where a galaxy and its turned
    /// twin cancel whatever their shapes. Assumes one shear per dataset.
    pub unshear: bool,
    /// The shear of the one version metadetection makes when it is not
    /// zero: −ĝ₀ of the image's dataset, set by the run for the second
    /// measurement of [`Self::unshear`]; zero (the five versions about
    /// the image as given) otherwise.
    pub metadetect_origin: [f64; 2],
}

impl Default for KsbParams {
    fn default() -> Self {
        Self {
            background_mesh_px: 64,
            background_clip_sigma: 3.0,
            detect_filter_sigma_px: 1.5,
            detect_thresh: 2.0,
            detect_min_area: 5,
            detect_peak_sn: 5.0,
            deblend_min_dip: 0.3,
            deblend_min_sep_px: 3.0,
            deblend_max_peaks: 32,
            deblend_flag_px: 20.0,
            centroid_max_iter: 60,
            centroid_tol_px: 1e-3,
            centroid_max_shift_px: 3.0,
            rg_min_px: 0.5,
            rg_max_px: 15.0,
            window_radius_rg: 4.0,
            star_min_sn: 50.0,
            star_class_min_sn: 20.0,
            locus_bandwidth: 0.03,
            locus_nsigma: 3.0,
            locus_min_halfwidth: 0.03,
            locus_max_width: 0.04,
            locus_width_floor: 0.002,
            psf_order: 2,
            psf_clip_sigma: 3.0,
            psf_stars_per_term: 3.0,
            psf_min_stars: 3,
            scale_step: 1.06,
            size_min_factor: 1.25,
            size_cut: SizeCut::Windowed,
            min_sn: 10.0,
            ksb_min_sn: 20.0,
            ksb_max_peak_shift_px: 0.4,
            min_pgamma: 0.1,
            max_shear: 1.0,
            sigma_int: 0.3,
            close_pair_px: 10.0,
            pgamma_mode: PgammaMode::PerObject,
            poisson_variance: true,
            method: Method::Ksb,
            calibration: Some(CalibrationProfile::Exponential),
            metacal_size_min_factor: 1.2,
            unshear: false,
            metadetect_origin: [0.0; 2],
        }
    }
}

impl KsbParams {
    /// The windowed-centroid settings these parameters define.
    pub fn window_settings(&self) -> crate::centroid::WindowSettings {
        crate::centroid::WindowSettings {
            radius_rg: self.window_radius_rg,
            rg_min: self.rg_min_px,
            rg_max: self.rg_max_px,
            tol: self.centroid_tol_px,
            max_iter: self.centroid_max_iter,
        }
    }

    /// Checks every range; the first offending parameter is named.
    pub fn validate(&self) -> Result<(), KsbError> {
        let pos = |name: &'static str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(KsbError::Param {
                    name,
                    value: v,
                    reason: "must be finite and > 0",
                })
            }
        };
        if self.method == Method::Ksb
            && self.pgamma_mode == PgammaMode::FitSize
            && self.calibration.is_some()
        {
            return Err(KsbError::Combination {
                message: "the P^γ calibration is the response of each galaxy's own P^γ, \
                          not of a P^γ fitted against size: with pgamma_mode FitSize set \
                          calibration None (`--pgamma fit-size --calibration none`)",
            });
        }
        if self.unshear && self.method != Method::Metadetect {
            return Err(KsbError::Combination {
                message: "unshear is metadetection's second measurement: \
                          use it with `--method metadetect`",
            });
        }
        let o = self.metadetect_origin;
        if !(o[0].is_finite() && o[1].is_finite() && o[0].hypot(o[1]) < MAX_ORIGIN_SHEAR) {
            return Err(KsbError::Param {
                name: "metadetect_origin",
                value: o[0].hypot(o[1]),
                reason: "its modulus must be finite and below 0.2",
            });
        }
        if self.background_mesh_px < 8 {
            return Err(KsbError::Param {
                name: "background_mesh_px",
                value: self.background_mesh_px as f64,
                reason: "must be at least 8",
            });
        }
        pos("background_clip_sigma", self.background_clip_sigma)?;
        pos("detect_filter_sigma_px", self.detect_filter_sigma_px)?;
        pos("detect_thresh", self.detect_thresh)?;
        pos("detect_peak_sn", self.detect_peak_sn)?;
        pos("deblend_min_dip", self.deblend_min_dip)?;
        pos("centroid_tol_px", self.centroid_tol_px)?;
        pos("centroid_max_shift_px", self.centroid_max_shift_px)?;
        pos("rg_min_px", self.rg_min_px)?;
        pos("rg_max_px", self.rg_max_px - self.rg_min_px)?;
        pos("window_radius_rg", self.window_radius_rg - 1.0)?;
        pos("metacal_size_min_factor", self.metacal_size_min_factor)?;
        pos("star_min_sn", self.star_min_sn)?;
        pos("locus_bandwidth", self.locus_bandwidth)?;
        pos("locus_nsigma", self.locus_nsigma)?;
        pos("locus_width_floor", self.locus_width_floor)?;
        pos(
            "locus_max_width",
            self.locus_max_width - self.locus_width_floor,
        )?;
        pos("psf_clip_sigma", self.psf_clip_sigma)?;
        pos("psf_stars_per_term", self.psf_stars_per_term)?;
        pos("scale_step", self.scale_step - 1.0)?;
        pos("min_pgamma", self.min_pgamma)?;
        pos("ksb_max_peak_shift_px", self.ksb_max_peak_shift_px)?;
        if !(self.ksb_min_sn.is_finite() && self.ksb_min_sn >= 0.0) {
            return Err(KsbError::Param {
                name: "ksb_min_sn",
                value: self.ksb_min_sn,
                reason: "must be finite and at least 0",
            });
        }
        pos("max_shear", self.max_shear)?;
        pos("sigma_int", self.sigma_int)?;
        if self.psf_order > 4 {
            return Err(KsbError::Param {
                name: "psf_order",
                value: self.psf_order as f64,
                reason: "must be at most 4",
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate_and_bad_values_are_named() {
        KsbParams::default().validate().unwrap();
        let p = KsbParams {
            scale_step: 0.9,
            ..KsbParams::default()
        };
        let e = p.validate().unwrap_err().to_string();
        assert!(e.contains("scale_step"), "{e}");
        let p = KsbParams {
            psf_order: 7,
            ..KsbParams::default()
        };
        assert!(p.validate().unwrap_err().to_string().contains("psf_order"));
        let fit = KsbParams {
            pgamma_mode: PgammaMode::FitSize,
            ..KsbParams::default()
        };
        let e = fit.validate().unwrap_err().to_string();
        assert!(e.contains("--calibration none"), "{e}");
        KsbParams {
            calibration: None,
            ..fit
        }
        .validate()
        .unwrap();
        // unshear is metadetection's; the origin's modulus below 0.2.
        let e = KsbParams {
            unshear: true,
            ..KsbParams::default()
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(e.contains("--method metadetect"), "{e}");
        let md = KsbParams {
            method: Method::Metadetect,
            unshear: true,
            metadetect_origin: [0.1, -0.17],
            ..KsbParams::default()
        };
        md.validate().unwrap();
        for o in [[0.0, 0.2], [f64::NAN, 0.0], [0.15, -0.15]] {
            let e = KsbParams {
                metadetect_origin: o,
                ..md.clone()
            }
            .validate()
            .unwrap_err()
            .to_string();
            assert!(e.contains("metadetect_origin"), "{o:?}: {e}");
        }
    }
}
