//! Science tests of the PSF models (SPEC §3): analytic optics, the
//! Kolmogorov FWHM, normalisation, the six calibrated STEP1 PSFs, and the
//! agreement between the renderer's path (`transfer` × pixel) and the
//! PSF's own pixel image.

use super::atmosphere::Kolmogorov;
use super::contour_radius;
use super::measure::fwhm_from_area;
use super::optical::{BandTransfer, Otf, SampledPupil, Wavefront};
use super::pupil::Pupil;
use super::*;
use num_complex::Complex64;
use std::f64::consts::PI;

/// Bessel J_n(x) = (1/π) ∫₀^π cos(nτ − x sin τ) dτ by the trapezoid rule,
/// which converges exponentially for this periodic integrand (|x| < 60).
fn bessel_j(n: u32, x: f64) -> f64 {
    let m = 400;
    let mut s = 0.0;
    for k in 0..=m {
        let t = PI * k as f64 / m as f64;
        let w = if k == 0 || k == m { 0.5 } else { 1.0 };
        s += w * (f64::from(n) * t - x * t.sin()).cos();
    }
    s / m as f64
}

#[test]
fn bessel_reference_values() {
    // Abramowitz & Stegun table 9.1.
    assert!((bessel_j(0, 1.0) - 0.765_197_686_6).abs() < 1e-9);
    assert!((bessel_j(1, 1.0) - 0.440_050_585_7).abs() < 1e-9);
    assert!((bessel_j(1, 3.831_705_970_2)).abs() < 1e-9);
}

fn airy_pupil() -> SampledPupil {
    let t = Telescope {
        spider_arms: 0,
        ..Telescope::default()
    };
    SampledPupil::new(Pupil::from_telescope(&t), 0.8e-6, 1024, 8)
}

#[test]
fn obstructed_airy_dark_ring_and_encircled_energy_within_1_percent() {
    let pupil = airy_pupil();
    let otf = pupil.otf(&Wavefront::NONE);
    let eps = 1.0 / 3.6;
    // λ/D in arcsec; v = π D θ / λ.
    let lam_d = 0.8e-6 / 3.6 / optical::ARCSEC;
    // Analytic first dark ring: first root of J1(v) − ε J1(εv) beyond 2.
    let f = |v: f64| bessel_j(1, v) - eps * bessel_j(1, eps * v);
    let (a, b) = (2.5, 4.5);
    assert!(f(a) * f(b) < 0.0);
    let (a, b) = stepsim_numerics::roots::Bisection::halvings(60).run(a, b, |m| f(a) * f(m) <= 0.0);
    let v_dark = 0.5 * (a + b);
    // Numerical: I(x, 0) from the OTF, column sums then a 1-D sum.
    let n = otf.n;
    let mut col = vec![Complex64::new(0.0, 0.0); n];
    for row in otf.data.chunks_exact(n) {
        for (c, v) in col.iter_mut().zip(row) {
            *c += v;
        }
    }
    let profile = |x: f64| -> f64 {
        col.iter()
            .enumerate()
            .map(|(m, c)| {
                let u = fft2::signed(m, n) as f64 * otf.du;
                (c * Complex64::from_polar(1.0, 2.0 * PI * u * x)).re
            })
            .sum()
    };
    // Scan for the minimum between 0.8 and 1.6 λ/D, then refine.
    let mut best = (f64::INFINITY, 0.0);
    for k in 0..=160 {
        let x = (0.8 + 0.8 * k as f64 / 160.0) * lam_d;
        let p = profile(x);
        if p < best.0 {
            best = (p, x);
        }
    }
    let (mut lo, mut hi) = (best.1 - 0.01 * lam_d, best.1 + 0.01 * lam_d);
    for _ in 0..40 {
        let (m1, m2) = (lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0);
        if profile(m1) < profile(m2) {
            hi = m2;
        } else {
            lo = m1;
        }
    }
    let v_num = PI * 0.5 * (lo + hi) / lam_d;
    eprintln!("dark ring: v = {v_num:.5} (analytic {v_dark:.5})");
    assert!(
        (v_num / v_dark - 1.0).abs() < 0.01,
        "dark ring at v = {v_num}, analytic {v_dark}"
    );
    assert!(
        best.0 < 1e-3 * profile(0.0),
        "the dark ring is dark: {}",
        best.0 / profile(0.0)
    );
    // Encircled energy: EE(r) = 2π r ∫ OTF(k) J1(2π k r) dk along the u axis
    // (the OTF of a pupil without arms is round), against Mahajan's formula.
    let radial: Vec<f64> = (0..n / 2).map(|m| otf.data[m].re).collect();
    let ee_num = |r: f64| {
        let steps = 8 * radial.len();
        let dk = otf.du * (radial.len() - 1) as f64 / steps as f64;
        let mut s = 0.0;
        for k in 0..=steps {
            let kk = k as f64 * dk;
            let pos = kk / otf.du;
            let i = (pos.floor() as usize).min(radial.len() - 2);
            let t = radial[i] + (pos - i as f64) * (radial[i + 1] - radial[i]);
            let w = if k == 0 || k == steps { 0.5 } else { 1.0 };
            s += w * t * bessel_j(1, 2.0 * PI * kk * r);
        }
        2.0 * PI * r * s * dk
    };
    let ee_exact = |r: f64| {
        let v0 = PI * r / lam_d;
        let m = 4000;
        let mut integral = 0.0;
        for k in 0..m {
            let v = (k as f64 + 0.5) / m as f64 * v0;
            integral += bessel_j(1, v) * bessel_j(1, eps * v) / v;
        }
        integral *= v0 / m as f64;
        let j = |x: f64| 1.0 - bessel_j(0, x).powi(2) - bessel_j(1, x).powi(2);
        (j(v0) + eps * eps * j(eps * v0) - 4.0 * eps * integral) / (1.0 - eps * eps)
    };
    for r in [1.0, 2.0, 3.0] {
        let (num, exact) = (ee_num(r * lam_d), ee_exact(r * lam_d));
        eprintln!("EE({r} λ/D) = {num:.5} (analytic {exact:.5})");
        assert!(
            (num / exact - 1.0).abs() < 0.01,
            "EE({r} λ/D) = {num}, analytic {exact}"
        );
    }
}

#[test]
fn otf_vanishes_beyond_the_diffraction_cutoff_so_nothing_aliases() {
    // The alias check of docs/psf.md: the sampled OTF (autocorrelation of
    // the sampled pupil) is zero beyond D/λ + one cell diagonal, so the
    // circular autocorrelation computed by the FFT equals the linear one;
    // and the cut-off lies inside the grid.
    let pupil = SampledPupil::new(Pupil::from_telescope(&Telescope::default()), 0.8e-6, 512, 4);
    let otf = pupil.otf(&Wavefront {
        noll: 8,
        amplitude_waves: 0.3,
        angle_rad: 0.0,
    });
    let n = otf.n;
    assert!(otf.cutoff < (n / 2) as f64 * otf.du);
    let mut beyond: f64 = 0.0;
    let mut inside: f64 = 0.0;
    for l in 0..n {
        for m in 0..n {
            let u = fft2::signed(m, n) as f64 * otf.du;
            let v = fft2::signed(l, n) as f64 * otf.du;
            let f = u.hypot(v);
            let a = otf.data[l * n + m].norm();
            if f > otf.cutoff + 1.5 * otf.du {
                beyond = beyond.max(a);
            } else if f < 0.9 * otf.cutoff {
                inside = inside.max(a);
            }
        }
    }
    eprintln!("max |OTF| beyond the cut-off: {beyond:.1e}");
    assert!(beyond < 1e-12, "{beyond}");
    assert!(inside > 0.99);
}

#[test]
fn kolmogorov_fwhm_is_0976_lambda_over_r0_within_1_percent() {
    // The atmosphere alone: an OTF of ones.
    let n = 1024;
    let du = 1.0 / 30.0;
    let otf = Otf {
        n,
        du,
        cutoff: f64::INFINITY,
        data: vec![Complex64::new(1.0, 0.0); n * n],
    };
    for lam_r0 in [0.6, 0.9] {
        let atm = Kolmogorov {
            lambda_over_r0_arcsec: lam_r0,
        };
        let band = BandTransfer::new(&otf, Some(&atm), None, 1e-12);
        let img = band.image(n, None);
        let fwhm = fwhm_from_area(&img, n) / (n as f64 * du);
        eprintln!(
            "Kolmogorov λ/r0 = {lam_r0}: FWHM = {:.5} λ/r0",
            fwhm / lam_r0
        );
        assert!(
            (fwhm / (0.976 * lam_r0) - 1.0).abs() < 0.01,
            "FWHM {fwhm} for λ/r0 {lam_r0}"
        );
        let s: f64 = img.iter().sum();
        assert!((s - 1.0).abs() < 1e-9, "{s}");
    }
}

fn step1(name: &str) -> Arc<dyn Psf> {
    let index = STEP1_PSFS.iter().position(|p| p.0 == name).unwrap();
    build(&PsfSpec::step1(index, 0.206)).unwrap()
}

/// Checks normalisation and returns the report.
fn checked_report(name: &str) -> PsfReport {
    let psf = step1(name);
    // Unit sum on the full grid of every representation.
    let t = psf.transfer(StampGrid::new(64, 0.206));
    assert!(
        (f64::from(t[0].re) - 1.0).abs() < 1e-6,
        "{name}: T(0) = {}",
        t[0]
    );
    for (n, os) in [(128, 1), (256, 4)] {
        let img = image(psf.as_ref(), n, 0.206, os);
        let s: f64 = img.iter().sum();
        assert!((s - 1.0).abs() < 1e-6, "{name}: image {n}/{os} sums to {s}");
    }
    let r = report(name, psf.as_ref(), 0.206).unwrap();
    assert!(
        (r.fwhm_arcsec - 0.9).abs() < 0.02,
        "{name}: FWHM {}",
        r.fwhm_arcsec
    );
    // Centroid at the nominal position (recentred), to 0.01 pixel.
    assert!(
        r.centroid_x.abs() < 0.01 && r.centroid_y.abs() < 0.01,
        "{name}: centroid {} {}",
        r.centroid_x,
        r.centroid_y
    );
    // The spikes reach 1e-5 of the peak inside the represented box.
    assert!(r.radius_1e5_arcsec > 10.0 && r.radius_1e5_arcsec < 20.0);
    r
}

#[test]
fn step1_psf0_none() {
    let r = checked_report("none");
    assert!(r.chi_abs < 0.002, "{}", r.chi_abs);
    // Diffraction spikes: along the arms' perpendiculars (x and y for arms
    // at 0° and 90°) the wings at 10–12″ are several times brighter than
    // on the diagonal at the same radius (measured: 2.0e-5 vs 7.0e-6 of
    // the peak at 10″).
    let psf = step1("none");
    let (n, h) = (512, 0.103);
    let img = image(psf.as_ref(), n, 0.206, 2);
    let peak = img.iter().copied().fold(0.0, f64::max);
    let c = n / 2;
    for r in [10.0, 12.0] {
        let k = (r / h) as usize;
        let kd = (r / h / std::f64::consts::SQRT_2) as usize;
        let axis = img[c * n + c + k].min(img[(c + k) * n + c]) / peak;
        let diag = img[(c + kd) * n + c + kd] / peak;
        assert!(
            axis > 2.5 * diag && axis > 1e-5,
            "{r}″: axis {axis:e}, diagonal {diag:e}"
        );
    }
}

#[test]
fn step1_psf1_coma() {
    let r = checked_report("coma");
    assert!((r.chi_abs - 0.040).abs() < 0.004, "{}", r.chi_abs);
    assert!((r.chi1_pixel.hypot(r.chi2_pixel) - 0.040).abs() < 0.004);
    // Coma moved the light; the PSF was recentred on it.
    let c = step1("coma").calibration().unwrap();
    eprintln!("coma centroid shift {:?}", c.centroid_shift_arcsec);
    assert!(c.centroid_shift_arcsec.0.abs() > 0.01, "{c:?}");
}

#[test]
fn step1_psf2_jitter() {
    let r = checked_report("jitter");
    assert!((r.chi_abs - 0.080).abs() < 0.005, "{}", r.chi_abs);
    // Reference point: a 1-D Gaussian of σ ≈ 0.15″.
    assert!((r.amplitude.unwrap() - 0.15).abs() < 0.03);
}

/// Fourier coefficients |c_m| / c_0 of the radius of the contour at
/// `level` of the finely sampled pixel-convolved PSF, m = 0..=4.
fn contour_harmonics(name: &str, level: f64) -> [f64; 5] {
    let psf = step1(name);
    let n = 256;
    let img = image(psf.as_ref(), n, 0.206, 8);
    let k = 72;
    let r: Vec<f64> = (0..k)
        .map(|i| contour_radius(&img, n, level, 2.0 * PI * i as f64 / k as f64))
        .collect();
    let c0 = r.iter().sum::<f64>() / k as f64;
    let mut out = [1.0; 5];
    for (m, o) in out.iter_mut().enumerate().skip(1) {
        let c: Complex64 = r
            .iter()
            .enumerate()
            .map(|(i, &v)| v * Complex64::from_polar(1.0, -2.0 * PI * (m * i) as f64 / k as f64))
            .sum();
        *o = c.norm() / k as f64 / c0;
    }
    out
}

#[test]
fn step1_psf3_defocus_has_a_broader_core() {
    let r = checked_report("defocus");
    assert!(r.chi_abs < 0.005, "{}", r.chi_abs);
    let none = checked_report("none");
    assert!(
        r.core_diameter_arcsec > 1.15 * none.core_diameter_arcsec,
        "core {} vs {}",
        r.core_diameter_arcsec,
        none.core_diameter_arcsec
    );
}

#[test]
fn step1_psf4_astigmatism_is_plus_shaped() {
    let r = checked_report("astigmatism");
    assert!(r.chi_abs < 0.005, "{}", r.chi_abs);
    let (a, o) = (
        contour_harmonics("astigmatism", 0.25),
        contour_harmonics("none", 0.25),
    );
    eprintln!("astigmatism harmonics {a:?}, none {o:?}");
    assert!(a[4] > 20.0 * o[4] && a[4] > 0.003, "{a:?} vs {o:?}");
}

#[test]
fn step1_psf5_trefoil_is_three_fold() {
    let r = checked_report("trefoil");
    assert!(r.chi_abs < 0.01, "{}", r.chi_abs);
    let (h, o) = (
        contour_harmonics("trefoil", 0.25),
        contour_harmonics("none", 0.25),
    );
    eprintln!("trefoil harmonics {h:?}, none {o:?}");
    // The three-fold harmonic dominates the contour's shape (the m = 2 one
    // is the small |χ| the spiders and the square pixel leave).
    assert!(h[3] > 1.3 * h[1].max(h[2]).max(h[4]), "{h:?}");
    assert!(h[3] > 100.0 * o[3] && h[3] > 2e-3, "{h:?} vs {o:?}");
}

#[test]
fn transfer_times_pixel_agrees_with_the_psf_pixel_image() {
    // The renderer's path: transfer × pixel sinc on a 128² stamp grid,
    // inverse FFT. The reference: the pixel-convolved PSF evaluated
    // directly from the band-limited transfer function at pixel centres.
    let psf = step1("coma");
    let p = 0.206;
    let n = 128;
    let img = image(psf.as_ref(), n, p, 1);
    let raw = PsfSpec::step1(1, p);
    let PsfModel::Optical {
        aberration,
        target_chi,
        ..
    } = raw.model
    else {
        unreachable!()
    };
    // Same calibration (amplitude from the cached PSF), its band transfer.
    let cal = psf.calibration().unwrap();
    let telescope = Telescope::default();
    let request = OpticalRequest {
        name: "coma",
        fwhm_arcsec: 0.9,
        aberration,
        amplitude: Some(cal.amplitude),
        target_chi,
        angle_rad: 0.0,
        telescope: &telescope,
        pixel_scale_arcsec: p,
    };
    let opt = build_optical(&request, &PsfAccuracy::default()).unwrap();
    let peak = img.iter().copied().fold(0.0, f64::max);
    let mut worst: f64 = 0.0;
    let c = n / 2;
    let mut points: Vec<(usize, usize)> = Vec::new();
    for j in c - 7..=c + 7 {
        for i in c - 7..=c + 7 {
            points.push((i, j));
        }
    }
    for k in [12, 20, 30, 45, 60] {
        points.extend([(c + k, c), (c, c - k), (c + k, c + k), (c - k, c + 3)]);
    }
    for (i, j) in points {
        let x = (i as f64 - c as f64) * p;
        let y = (j as f64 - c as f64) * p;
        let want = opt.band().pixel_value_at(x, y, p);
        worst = worst.max((img[j * n + i] - want).abs());
    }
    assert!(
        worst < 1e-4 * peak,
        "max difference {} of the peak",
        worst / peak
    );
    eprintln!(
        "transfer vs image: max difference {:.2e} of the peak",
        worst / peak
    );
}

#[test]
fn other_targets_can_be_asked_for() {
    let model = PsfModel::Optical {
        aberration: Aberration::Coma,
        amplitude: None,
        target_chi: Some(0.03),
        angle_deg: 30.0,
    };
    let psf = build(&PsfSpec::new("c", 1.1, model, Telescope::default(), 0.206)).unwrap();
    let r = report("c", psf.as_ref(), 0.206).unwrap();
    assert!((r.fwhm_arcsec - 1.1).abs() < 0.02, "{}", r.fwhm_arcsec);
    assert!((r.chi_abs - 0.03).abs() < 0.004, "{}", r.chi_abs);
    // Rotated by 30°: χ turns by 60° (spin 2).
    let angle = r.chi2.atan2(r.chi1).to_degrees();
    assert!((angle - 60.0).abs() < 2.0, "χ angle {angle}");
}

#[test]
fn unreachable_targets_are_errors_not_panics() {
    let t = Telescope::default();
    let acc = PsfAccuracy {
        pupil_grid: 512,
        calibration_grid: 512,
        ..PsfAccuracy::default()
    };
    // Builds PSF `name` (no rotation, 0.206″ pixels) and returns its error.
    let refuse = |name: &str, fwhm: f64, ab: Aberration, amplitude, target_chi| {
        let request = OpticalRequest {
            name,
            fwhm_arcsec: fwhm,
            aberration: ab,
            amplitude,
            target_chi,
            angle_rad: 0.0,
            telescope: &t,
            pixel_scale_arcsec: 0.206,
        };
        build_optical(&request, &acc).unwrap_err()
    };
    let err = refuse("d", 0.9, Aberration::Defocus, Some(2.0), None);
    assert!(matches!(err, PsfError::Unreachable { .. }), "{err}");
    assert!(err.to_string().contains("psf d"), "{err}");
    // Astigmatism at best focus is round: no amplitude gives |χ| = 0.05.
    let err = refuse("a", 0.9, Aberration::Astigmatism, None, Some(0.05));
    assert!(err.to_string().contains("target_chi"), "{err}");
    // Wider than the optical grid can hold (period 11.6″ at 512): refused.
    let err = refuse("w", 3.0, Aberration::None, None, None);
    assert!(err.to_string().contains("too wide"), "{err}");
    let err = refuse("n", 0.9, Aberration::None, None, Some(0.05));
    assert!(err.to_string().contains("target_chi"), "{err}");
}

#[test]
fn builds_are_bit_reproducible() {
    // No randomness and no order dependence: two uncached builds give the
    // same bits (small grids to keep the test quick).
    let acc = PsfAccuracy {
        pupil_grid: 512,
        calibration_grid: 512,
        ..PsfAccuracy::default()
    };
    let t = Telescope::default();
    let make = || {
        let request = OpticalRequest {
            name: "c",
            fwhm_arcsec: 0.9,
            aberration: Aberration::Coma,
            amplitude: Some(0.3),
            target_chi: None,
            angle_rad: 0.2,
            telescope: &t,
            pixel_scale_arcsec: 0.206,
        };
        build_optical(&request, &acc)
            .unwrap()
            .transfer(StampGrid::new(32, 0.206))
    };
    let (a, b) = (make(), make());
    assert!(
        a.iter()
            .zip(b.iter())
            .all(|(x, y)| x.re.to_bits() == y.re.to_bits() && x.im.to_bits() == y.im.to_bits())
    );
}
