use super::*;
use crate::linalg::Mat2;
use crate::metacal::PSF_SIDE;
use crate::psf_model::PsfCorrection;
use crate::scene::{convolve, covariance, draw_gaussian_integrated, shear_covariance};
use crate::shear::{e_cor, estimate, estimate_with, pgamma};

/// The window of the pipeline's defaults.
fn win() -> WindowSettings {
    crate::params::KsbParams::default().window_settings()
}

/// A PSF made of Gaussians (flux fraction, covariance), integrated over
/// pixels, as a normalised stack.
fn stack(parts: &[(f64, Mat2)]) -> PsfStack {
    let mut img = Image::zeros(PSF_SIDE, PSF_SIDE);
    let c = (PSF_SIDE / 2) as f64;
    for (f, cov) in parts {
        draw_gaussian_integrated(&mut img, c, c, *f, cov);
    }
    let total: f64 = img.data.iter().map(|&v| f64::from(v)).sum();
    PsfStack {
        side: PSF_SIDE,
        pix: img.data.iter().map(|&v| f64::from(v) / total).collect(),
        n_stars: 1,
    }
}

fn core() -> Mat2 {
    covariance(4.37 / 2.3548, [0.0, 0.0])
}

fn halo_psf() -> Vec<(f64, Mat2)> {
    vec![(0.8, core()), (0.2, covariance(4.0, [0.0, 0.0]))]
}

/// Draws a galaxy of covariance `gal` seen through the Gaussian mixture
/// `psf` directly in pixels (the slow, obvious twin of the Fourier
/// drawing), on a SIDE² grid centred like the models.
fn drawn_in_pixels(gal: &Mat2, psf: &[(f64, Mat2)]) -> Image {
    let mut img = Image::zeros(SIDE, SIDE);
    let c = (SIDE / 2) as f64;
    for (f, p) in psf {
        draw_gaussian_integrated(&mut img, c, c, 1e4 * f, &convolve(gal, p));
    }
    img
}

#[test]
fn a_model_drawn_in_fourier_space_is_the_same_model_drawn_in_pixels() {
    // Sheared Gaussians of σ 2.5 px through the halo PSF: the Fourier
    // drawing (the model's analytic transform times the stack's) against
    // pixel-integrated Gaussians of the convolved covariances, round and
    // with an intrinsic shape that the shear acts on (the order matters at
    // g |g_int|: with the shear drawn first the pixels differ by 3.2e-3 of
    // the peak at g_int = (0.4, 0) and this test fails). They
    // differ only by the stack's 32² truncation of the halo (σ 4 px: 1.6e-4
    // of its flux lies outside) and aliasing.
    let psf = halo_psf();
    let w = win();
    let bench = Bench::new(&stack(&psf), CalibrationProfile::Gaussian, &w);
    let g = [0.03, -0.02];
    for g_int in [[0.0, 0.0], [0.4, 0.0], [-0.1, 0.3]] {
        let fourier = bench.draw(&bench.grids[1], 2.5, g_int, g);
        let pixels = drawn_in_pixels(&shear_covariance(&covariance(2.5, g_int), g), &psf);
        let peak = pixels.data.iter().copied().fold(0.0f32, f32::max);
        let worst = fourier
            .data
            .iter()
            .zip(&pixels.data)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(
            worst < 2e-3 * peak,
            "{g_int:?}: worst {worst} of peak {peak}"
        );
        // And the same ellipticity to 1e-4.
        let (a, b) = (
            bench.shape(&fourier, 3.0, true).unwrap(),
            bench.shape(&pixels, 3.0, true).unwrap(),
        );
        assert!(
            (a.e[0] - b.e[0]).abs() < 1e-4 && (a.e[1] - b.e[1]).abs() < 1e-4,
            "{g_int:?}: {:?} {:?}",
            a.e,
            b.e
        );
        if g_int == [0.0, 0.0] {
            assert!(a.e[0] > 0.01 && a.e[1] < -0.005, "{:?}", a.e);
        }
    }
}

#[test]
fn through_a_gaussian_psf_the_factor_is_one() {
    // KSB's isotropic correction is exact for round Gaussians through a
    // Gaussian PSF, so there is nothing to calibrate.
    let w = win();
    let rg_star = 1.86;
    for profile in [
        CalibrationProfile::Gaussian,
        CalibrationProfile::Exponential,
    ] {
        let cal =
            PgammaCalibration::new(&stack(&[(1.0, core())]), rg_star, 12.0, profile, &w).unwrap();
        let table = cal.table();
        // Every row reaches the top (12 px) within a step.
        assert_eq!(table.len(), INTRINSIC.len());
        // Measured: r_g 10.7–10.9 px in every row.
        for (row, e_int) in table.iter().zip(INTRINSIC) {
            let [z, e, _] = *row.last().unwrap();
            let rg = z / (1.0 - e * e).powf(0.25);
            assert!(
                rg > 12.0 / 1.2,
                "{profile:?} |g_int| {e_int}: the row ends at r_g {rg}"
            );
        }
        let round = &table[0];
        assert!(round.len() > 10, "{round:?}");
        assert!(round[0][0] < 1.15 * rg_star && round.last().unwrap()[0] > 10.0);
        // Exact for Gaussian models; an exponential through a Gaussian
        // PSF is not a Gaussian, and KSB+ is then exact to 2e-3.
        let bound = match profile {
            CalibrationProfile::Gaussian => 1e-3,
            CalibrationProfile::Exponential => 3e-3,
        };
        for [rg, _, k] in round {
            assert!((k - 1.0).abs() < bound, "{profile:?} r_g {rg}: k {k}");
        }
    }
}

/// The ring-averaged m of eight noise-free Gaussian galaxies of σ `sigma`
/// and |e_s| `es`, sheared by g = (0.02, 0), drawn in pixels through `psf`,
/// with the stellar term from the PSF measured at each galaxy's r_g and
/// P^γ multiplied by `k(r_g)`.
fn ring_m(psf: &[(f64, Mat2)], sigma: f64, es: f64, k: &dyn Fn(f64, f64) -> f64) -> f64 {
    let g = [0.02, 0.0];
    let w = win();
    let bench = Bench::new(&stack(psf), CalibrationProfile::Gaussian, &w);
    let mut star_img = Image::zeros(SIDE, SIDE);
    let c = (SIDE / 2) as f64;
    for (f, p) in psf {
        draw_gaussian_integrated(&mut star_img, c, c, 1e4 * f, p);
    }
    let n = 8;
    let mut m = 0.0;
    for i in 0..n {
        let th = PI * i as f64 / n as f64;
        let e = [es * (2.0 * th).cos(), es * (2.0 * th).sin()];
        let img = drawn_in_pixels(&shear_covariance(&covariance(sigma, e), g), psf);
        let shape = bench.shape(&img, 3.0, true).unwrap();
        let star = bench.shape(&star_img, shape.sigma_w, false).unwrap();
        let corr = PsfCorrection::of_star(&star).unwrap();
        let ec = e_cor(&shape, &corr);
        let kk = k(shape.sigma_w, ec[0].hypot(ec[1]));
        let est = estimate_with(&shape, &corr, pgamma(&shape, &corr) * kk);
        m += (est.gamma[0] / g[0] - 1.0) / n as f64;
        if kk == 1.0 {
            assert_eq!(est.gamma, estimate(&shape, &corr).gamma);
        }
    }
    m
}

/// The fractional row indices of the eight ring members of σ `sigma`,
/// |e_s| `es` (unsheared) seen through `psf`.
fn ring_shapes(cal: &PgammaCalibration, psf: &[(f64, Mat2)], sigma: f64, es: f64) -> Vec<f64> {
    let w = win();
    let bench = Bench::new(&stack(psf), CalibrationProfile::Gaussian, &w);
    (0..8)
        .map(|i| {
            let th = PI * i as f64 / 8.0;
            let e = [es * (2.0 * th).cos(), es * (2.0 * th).sin()];
            let shape = bench
                .shape(&drawn_in_pixels(&covariance(sigma, e), psf), 3.0, true)
                .unwrap();
            cal.shape_index(shape.sigma_w, shape.e[0].hypot(shape.e[1]))
        })
        .collect()
}

#[test]
fn the_calibration_removes_a_halos_bias() {
    // Rings of galaxies drawn in pixels (not by the calibration's own
    // drawing) through the 20 % halo PSF, each ring its own population.
    // Without the calibration m = −0.077 … +0.015 (round: −0.043 at σ 1.5
    // to −0.025 at σ 4; |e_s| = 0.4: −0.076 at σ 1.5 to +0.015 at σ 4).
    // With Gaussian models (the rings' own profile) |m| < 3e-3 for every
    // ring (measured ≤ 1.0e-3). With exponential models (the default) the
    // round rings too (measured ≤ 9e-4), but the profile's mismatch leaves
    // the elliptical ones at −0.010 … +0.036 (bound 0.045).
    let w = win();
    let psf = halo_psf();
    let cal =
        PgammaCalibration::new(&stack(&psf), 1.96, 12.0, CalibrationProfile::Gaussian, &w).unwrap();
    let exp = PgammaCalibration::new(
        &stack(&psf),
        1.96,
        12.0,
        CalibrationProfile::Exponential,
        &w,
    )
    .unwrap();
    for sigma in [1.5, 2.0, 3.0, 4.0] {
        for es in [0.0, 0.2, 0.4] {
            let sizes = cal.for_shapes(&ring_shapes(&cal, &psf, sigma, es));
            let before = ring_m(&psf, sigma, es, &|_, _| 1.0);
            let after = ring_m(&psf, sigma, es, &|rg, e| sizes.factor(rg, e));
            let exp_sizes = exp.for_shapes(&ring_shapes(&exp, &psf, sigma, es));
            let after_exp = ring_m(&psf, sigma, es, &|rg, e| exp_sizes.factor(rg, e));
            eprintln!(
                "σ {sigma} |e_s| {es}: m {before:+.5} → {after:+.5} (exponential models {after_exp:+.5})"
            );
            if es == 0.0 {
                assert!(before < -0.02, "σ {sigma}: m without {before}");
                assert!(
                    after_exp.abs() < 2e-3,
                    "σ {sigma}: exponential models {after_exp}"
                );
            }
            assert!(after_exp.abs() < 0.045, "σ {sigma} |e_s| {es}: {after_exp}");
            assert!(
                after.abs() < 3e-3,
                "σ {sigma} |e_s| {es}: m with {after} (without {before})"
            );
        }
    }
}

/// A model whose response is `k` at size `rg`, its sheared versions of
/// the same size (so k's dependence on size does not enter).
fn member(rg: f64, k: f64) -> Member {
    // |e_cor| ≤ 1e-5: sizes stay rg to 3e-11.
    let at = |e_cor: [f64; 2]| ModelShape {
        rg,
        e_cor,
        pgamma: 1e-3,
    };
    let d = 1e-3 * k * STEP;
    Member {
        base: at([0.0, 0.0]),
        sheared: [at([d, 0.0]), at([-d, 0.0]), at([0.0, d]), at([0.0, -d])],
    }
}

#[test]
fn the_factor_is_linear_in_ln_rg_and_in_the_shape_index_and_held_at_the_ends() {
    let sizes = [1.0, 2.0, 4.0];
    let row = |e: [f64; 3], k: [f64; 3]| Row {
        ln_rg: sizes.iter().map(|r: &f64| r.ln()).collect(),
        e: e.to_vec(),
        rings: sizes
            .iter()
            .zip(k)
            .map(|(&r, k)| vec![member(r, k)])
            .collect(),
    };
    let cal = PgammaCalibration {
        rows: vec![
            row([0.0, 0.0, 0.0], [1.1, 1.05, 1.01]),
            row([0.2, 0.3, 0.4], [1.2, 1.15, 1.11]),
        ],
    };
    // No shapes: the round row, linear in ln r_g, held beyond the sizes.
    let round = cal.for_shapes(&[]);
    assert_eq!(cal.row_weights(&[]), vec![1.0, 0.0]);
    assert!((round.factor(0.5, 0.0) - 1.1).abs() < 1e-9);
    assert!((round.factor(8.0, 0.0) - 1.01).abs() < 1e-9);
    // A NaN size or |e| has no k (its P^γ becomes NaN and is flagged).
    assert!(round.factor(f64::NAN, 0.0).is_nan() && round.factor(2.0, f64::NAN).is_nan());
    assert!((round.factor(2.0, 0.0) - 1.05).abs() < 1e-9);
    assert!((round.factor(2.0f64.sqrt(), 0.0) - 1.075).abs() < 1e-9);
    assert!((round.factor(2.0 * 2.0f64.sqrt(), 0.0) - 1.03).abs() < 1e-9);
    // Shape indices: at size 2 the rows' |e| are 0 and 0.3 (r_g is the
    // size over (1 − |e|²)^¼).
    let rg = |size: f64, e: f64| size / (1.0 - e * e).powf(0.25);
    assert_eq!(cal.shape_index(2.0, 0.0), 0.0);
    assert!((cal.shape_index(rg(2.0, 0.15), 0.15) - 0.5).abs() < 1e-12);
    assert!((cal.shape_index(rg(2.0f64.sqrt(), 0.125), 0.125) - 0.5).abs() < 1e-12);
    assert_eq!(cal.shape_index(2.0, 0.9), 1.0);
    assert!((size(rg(3.0, 0.4), 0.4) - 3.0).abs() < 1e-12);
    assert_eq!(cal.shape_index(2.0, f64::NAN), 0.0);
    // Row weights: clamped, NaN counts as round.
    assert_eq!(
        cal.row_weights(&[0.25, 7.0, f64::NAN, -1.0]),
        vec![0.6875, 0.3125]
    );
    // A population half round, half of the second row: the mean of both.
    let half = cal.for_shapes(&[0.0, 1.0]);
    assert!((half.factor(2.0, 0.0) - 1.10).abs() < 1e-9);
    assert!((half.factor(4.0, 0.0) - 1.06).abs() < 1e-9);
}

#[test]
fn a_size_that_follows_the_shear_is_taken_into_k() {
    // One round row, k rising with size (1.0, 1.1, 1.2 at sizes 1, 1.5,
    // 2), whose middle model grows along the shear: its +g₁ version is
    // larger, so with k rising its γ̂ is divided by more and the plain k
    // leaves the response below 1. The iterations must bring it most of
    // the way back.
    let mut m = member(1.5, 1.1);
    m.sheared[0].rg = 1.8;
    m.sheared[1].rg = 1.25;
    let row = Row {
        ln_rg: vec![1.0f64.ln(), 1.5f64.ln(), 2.0f64.ln()],
        e: vec![0.0; 3],
        rings: vec![vec![member(1.0, 1.0)], vec![m], vec![member(2.0, 1.2)]],
    };
    let cal = PgammaCalibration { rows: vec![row] };
    let t = 1.5f64.ln();
    // The members' responses with k = 1.
    let plain = SizeFactor {
        ln_rg: cal.rows[0].ln_rg.clone(),
        k: vec![1.0, 1.1, 1.2],
    };
    assert_eq!(cal.for_shapes(&[]).ln_rg, plain.ln_rg);
    let before = cal.rows[0].response_at(t, &|z| plain.at_size(z));
    assert!(before < 1.0 - 1e-3, "plain k: response {before}");
    let f = cal.for_shapes(&[]);
    let after = cal.rows[0].response_at(t, &|z| f.at_size(z));
    // Measured: 0.99704 with the plain k, 0.99979 after the two
    // iterations (k 1.1 → 1.096).
    assert!(
        (after - 1.0).abs() < 0.1 * (1.0 - before),
        "response {after} (plain k: {before})"
    );
    assert!(f.factor(1.5, 0.0) < 1.1, "{}", f.factor(1.5, 0.0));
}
