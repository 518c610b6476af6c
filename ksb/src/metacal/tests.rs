use super::*;
use crate::scene::{convolve, covariance, draw_gaussian_sampled, gaussian_value, shear_covariance};

/// A point-sampled Gaussian image of `side`² with its centre at `c`.
fn gaussian_stamp(side: usize, c: [f64; 2], cov: &crate::linalg::Mat2) -> Vec<f64> {
    let mut img = Image::zeros(side, side);
    draw_gaussian_sampled(&mut img, c[0], c[1], 1.0, cov);
    img.data.iter().map(|&v| f64::from(v)).collect()
}

/// The slow twin of [`Transforms::at_sheared`]: the stamp's transform at
/// M k summed pixel by pixel.
fn transform_at(stamp: &[f64], side: usize, c: [f64; 2], k: [f64; 2]) -> Complex64 {
    let mut sum = Complex64::new(0.0, 0.0);
    for j in 0..side {
        for i in 0..side {
            let ph = -2.0 * PI * (k[0] * (i as f64 - c[0]) + k[1] * (j as f64 - c[1]));
            sum += Complex64::from_polar(stamp[j * side + i], ph);
        }
    }
    sum
}

#[test]
fn the_taylor_series_at_sheared_frequencies_equals_the_direct_sum() {
    let side = 32;
    let c = [16.3, 15.8];
    let stamp = gaussian_stamp(side, c, &covariance(2.5, [0.3, -0.2]));
    let plans = Plans::new(side);
    let t = transforms(&stamp, c, &plans);
    let mut worst: f64 = 0.0;
    for g in VERSIONS {
        let d = m_minus_one(g);
        for b in 0..side {
            for a in 0..side {
                let k = [freq(a, side), freq(b, side)];
                // Where a Γ of σ 2 px keeps more than 1e-3.
                if (-2.0 * PI * PI * 4.0 * (k[0] * k[0] + k[1] * k[1])).exp() < 1e-3 {
                    continue;
                }
                let dk = [
                    d[0][0] * k[0] + d[0][1] * k[1],
                    d[1][0] * k[0] + d[1][1] * k[1],
                ];
                let fast = t.at_sheared(b * side + a, dk);
                let slow = transform_at(&stamp, side, c, [k[0] + dk[0], k[1] + dk[1]]);
                worst = worst.max((fast - slow).norm());
            }
        }
    }
    // The flux is 1: errors relative to Î(0).
    assert!(worst < 2e-4, "largest difference {worst:e}");
}

#[test]
fn a_gaussian_deconvolved_sheared_and_reconvolved_is_the_analytic_gaussian() {
    let side = 48;
    let c = [24.2, 23.7];
    let gal = covariance(2.0, [0.25, 0.1]);
    let psf = covariance(1.9, [0.04, -0.02]);
    let observed = gaussian_stamp(side, c, &convolve(&gal, &psf));
    let stack = PsfStack {
        side: PSF_SIDE,
        pix: gaussian_stamp(
            PSF_SIDE,
            [(PSF_SIDE / 2) as f64, (PSF_SIDE / 2) as f64],
            &psf,
        ),
        n_stars: 1,
    };
    let sigma = 2.6;
    let dec = Deconvolver::new(&stack, side, sigma);
    let round = [[sigma * sigma, 0.0], [0.0, sigma * sigma]];
    for g in VERSIONS {
        let img = dec.version(&observed, c, g);
        let want = convolve(&shear_covariance(&gal, g), &round);
        let mut worst: f64 = 0.0;
        let peak = gaussian_value(1.0, &want, 0.0, 0.0);
        for j in 0..side {
            for i in 0..side {
                let w = gaussian_value(1.0, &want, i as f64 - c[0], j as f64 - c[1]);
                worst = worst.max((f64::from(img.at(i, j)) - w).abs() / peak);
            }
        }
        assert!(
            worst < 1e-4,
            "g = {g:?}: largest difference {worst:e} of the peak"
        );
    }
}

#[test]
fn the_response_of_a_gaussian_is_the_finite_difference_of_its_analytic_ellipticity() {
    // e of the reconvolved version measured on the analytic image equals
    // e measured on the version made by deconvolution: the response the
    // method computes is the analytic one.
    let side = 48;
    let c = [24.0, 24.0];
    let gal = covariance(2.2, [0.2, -0.1]);
    let psf = covariance(1.8, [0.0, 0.0]);
    let observed = gaussian_stamp(side, c, &convolve(&gal, &psf));
    let stack = PsfStack {
        side: PSF_SIDE,
        pix: gaussian_stamp(PSF_SIDE, [16.0, 16.0], &psf),
        n_stars: 1,
    };
    let sigma = 2.4;
    let dec = Deconvolver::new(&stack, side, sigma);
    let win = test_window();
    let img = Image {
        width: side,
        height: side,
        data: observed.iter().map(|&v| v as f32).collect(),
    };
    let m = dec
        .measure(&img, c, c, 2.8, &win, &NOISELESS)
        .expect("inside");
    assert!(m.ok.iter().all(|&b| b));
    let round = [[sigma * sigma, 0.0], [0.0, sigma * sigma]];
    for (v, g) in VERSIONS.iter().enumerate() {
        let want_img = Image {
            width: side,
            height: side,
            data: gaussian_stamp(side, c, &convolve(&shear_covariance(&gal, *g), &round))
                .iter()
                .map(|&v| v as f32)
                .collect(),
        };
        let w = windowed(&want_img, c[0], c[1], 3.0, true, &win).expect("found");
        let ints = ksb_integrals(&want_img, w.x, w.y, w.rg, 4.0 * w.rg, None);
        let e = [ints.q[0] / ints.trace, ints.q[1] / ints.trace];
        for i in 0..2 {
            assert!(
                (m.e[v][i] - e[i]).abs() < 2e-5,
                "version {v}: {:?} vs {e:?}",
                m.e[v]
            );
        }
    }
}

#[test]
fn the_response_of_an_ensemble_recovers_its_shear() {
    // Ring of sheared Gaussians (no noise): ⟨R⁻¹ e⟩ = g to 1e-3 of g.
    let side = 48;
    let c = [24.0, 24.0];
    let psf = covariance(1.9, [0.05, -0.03]);
    let stack = PsfStack {
        side: PSF_SIDE,
        pix: gaussian_stamp(PSF_SIDE, [16.0, 16.0], &psf),
        n_stars: 1,
    };
    let sigma = 2.6;
    let dec = Deconvolver::new(&stack, side, sigma);
    let win = test_window();
    let g = [0.03, -0.02];
    let mean = ring_mean(&dec, side, c, g, &win, |gal| {
        gaussian_stamp(side, c, &convolve(gal, &psf))
    });
    for i in 0..2 {
        assert!(
            (mean[i] - g[i]).abs() < 1e-3 * g[i].abs() + 2e-5,
            "⟨R⁻¹e⟩ = {mean:?}, g = {g:?}"
        );
    }
}

#[test]
fn the_signal_to_noise_a_version_is_cut_on_is_the_versions_own() {
    // One galaxy seen through two PSFs has the same versions (the galaxy
    // sheared and convolved with Γ), so the S/N each version is cut on
    // must be the same through both: the version's weighted flux over σ
    // √(Σ W²), here from the slow twin of the KSB sums on the analytic
    // version. The image's KSB ν, which the cut was scaled from before
    // 2026-12-06, differs between the two PSFs by more than 10 %.
    let side = 48;
    let c = [24.0, 24.0];
    let flux = 1e6;
    let noise_sigma = 1.0;
    let gal = covariance(2.2, [0.3, -0.1]);
    let sigma = 2.8;
    let win = test_window();
    let tests = VersionTests {
        noise_sigma,
        ..NOISELESS
    };
    let noise = Some(crate::moments::PixelNoise {
        background_var: noise_sigma * noise_sigma,
        poisson: false,
    });
    let round = [[sigma * sigma, 0.0], [0.0, sigma * sigma]];
    let as_image = |pix: Vec<f64>| Image {
        width: side,
        height: side,
        data: pix.iter().map(|&v| (flux * v) as f32).collect(),
    };
    let mut nu = Vec::new();
    for psf_sigma in [1.4, 2.0] {
        let psf = covariance(psf_sigma, [0.0, 0.0]);
        let img = as_image(gaussian_stamp(side, c, &convolve(&gal, &psf)));
        let stack = PsfStack {
            side: PSF_SIDE,
            pix: gaussian_stamp(PSF_SIDE, [16.0, 16.0], &psf),
            n_stars: 1,
        };
        let m = Deconvolver::new(&stack, side, sigma)
            .measure(&img, c, c, 2.8, &win, &tests)
            .expect("inside");
        for (v, g) in VERSIONS.iter().enumerate() {
            let want_img = as_image(gaussian_stamp(
                side,
                c,
                &convolve(&shear_covariance(&gal, *g), &round),
            ));
            let w = windowed(&want_img, c[0], c[1], 3.0, true, &win).expect("found");
            let ints =
                crate::moments::ksb_integrals_slow(&want_img, w.x, w.y, w.rg, 4.0 * w.rg, noise);
            let want = ints.s0 / ints.var_s0.sqrt();
            assert!(
                (m.sn[v] / want - 1.0).abs() < 1e-4,
                "PSF σ {psf_sigma}, version {v}: S/N {} against {want}",
                m.sn[v]
            );
        }
        // The shear moves the S/N far more than the tolerance.
        assert!((m.sn[1] / m.sn[2] - 1.0).abs() > 1e-3, "{:?}", m.sn);
        let w = windowed(&img, c[0], c[1], 3.0, true, &win).expect("found");
        let ints = ksb_integrals(&img, w.x, w.y, w.rg, 4.0 * w.rg, noise);
        nu.push(ints.s0 / ints.var_s0.sqrt());
    }
    assert!(nu[0] / nu[1] - 1.0 > 0.1, "the images' ν {nu:?}");
}

#[test]
fn a_row_is_cut_on_its_versions_s_n_not_on_the_images_nu() {
    // `measure_object` decides LOW_SN and each version's selection on the
    // versions' own S/N, whatever the image's ν (`o.sn`, KSB+'s) says: a
    // faint galaxy given a high ν is cut, a bright one given a low ν is
    // kept, and the row's ν becomes its unsheared version's.
    let side = 96;
    let c = [48.0, 48.0];
    let psf = covariance(1.8, [0.0, 0.0]);
    let gal = covariance(2.5, [0.2, 0.1]);
    let stack = PsfStack {
        side: PSF_SIDE,
        pix: gaussian_stamp(PSF_SIDE, [16.0, 16.0], &psf),
        n_stars: 1,
    };
    let sigma = 2.6;
    let mc = ImageMetacal {
        decs: STAMP_SIDES
            .iter()
            .map(|&s| Deconvolver::new(&stack, s, sigma))
            .collect(),
        sigma,
    };
    let params = KsbParams::default();
    let shape = gaussian_stamp(side, c, &convolve(&gal, &psf));
    // flux (e⁻, noise σ 1 e⁻), the image's ν handed in, kept
    for (flux, image_nu, kept) in [(90.0, 1000.0, false), (3000.0, 5.0, true)] {
        let sub = Image {
            width: side,
            height: side,
            data: shape.iter().map(|&v| (flux * v) as f32).collect(),
        };
        let o = MeasuredObject {
            x: c[0] + 1.0,
            y: c[1] + 1.0,
            e1: 0.0,
            e2: 0.0,
            weight: 0.0,
            flags: 0,
            rg_px: 3.1,
            sn: image_nu,
            mag: f64::NAN,
            pgamma: f64::NAN,
            metacal: None,
            ksb: None,
        };
        let o = measure_object(o, 0, c, &sub, Some(&mc), &params, 1.0);
        let (m, selected) = o.metacal.expect("measured");
        assert_eq!(o.sn, m.sn[0], "the row's ν is its unsheared version's");
        assert_eq!(
            selected[0], kept,
            "flux {flux}: S/N {:?}, flags {}",
            m.sn, o.flags
        );
        assert_eq!(
            o.flags & flags::LOW_SN != 0,
            !kept,
            "flux {flux}: flags {}",
            o.flags
        );
        if kept {
            assert_eq!(o.flags, 0, "flux {flux}: flags {}", o.flags);
            assert!(selected.iter().all(|&b| b), "{selected:?}");
        } else {
            assert!(m.sn[0] < params.min_sn, "flux {flux}: S/N {:?}", m.sn);
        }
    }
}

#[test]
fn a_stack_of_shifted_stars_is_the_star_centred() {
    let mut img = Image::zeros(200, 100);
    let psf = covariance(1.8, [0.05, 0.02]);
    let spots = [(40.3, 50.7), (100.6, 49.2), (160.45, 51.9)];
    for (k, &(x, y)) in spots.iter().enumerate() {
        draw_gaussian_sampled(&mut img, x, y, 1000.0 * (k + 1) as f64, &psf);
    }
    let stack = stack_psf(&img, &spots).expect("stars inside");
    assert_eq!(stack.n_stars, 3);
    let h = (PSF_SIDE / 2) as f64;
    let want = gaussian_stamp(PSF_SIDE, [h, h], &psf);
    let total: f64 = want.iter().sum();
    for (a, b) in stack.pix.iter().zip(&want) {
        assert!((a - b / total).abs() < 1e-5, "{a} vs {}", b / total);
    }
}

#[test]
fn the_wide_stack_leaves_out_neighbours_and_is_cut_round() {
    // Five stars, each with a galaxy 20 px from it at the same offset
    // (inside a 64² stamp, outside a 32² one): where every star has a
    // neighbour the median keeps it; left out by the detections' discs,
    // the stack is the star, cut round. Measured: largest difference
    // 3.3e-6 with the discs (the galaxy's light beyond its disc), 9.7e-3
    // without (the peak is 0.049).
    let mut img = Image::zeros(600, 300);
    let psf = covariance(1.8, [0.05, 0.02]);
    let gal = covariance(2.5, [0.2, -0.1]);
    let spots = [
        (60.3, 150.7),
        (180.6, 149.2),
        (300.45, 151.9),
        (420.1, 150.3),
        (540.8, 148.6),
    ];
    let mut others = Vec::new();
    for (k, &(x, y)) in spots.iter().enumerate() {
        draw_gaussian_sampled(&mut img, x, y, 1000.0 * (k + 1) as f64, &psf);
        draw_gaussian_sampled(&mut img, x + 20.0, y + 3.0, 1000.0, &gal);
        others.push([x, y, 8.0]);
        others.push([x + 20.0, y + 3.0, 12.0]);
    }
    let h = (WIDE_PSF_SIDE / 2) as f64;
    let mut want = gaussian_stamp(WIDE_PSF_SIDE, [h, h], &psf);
    for (p, v) in want.iter_mut().enumerate() {
        let (x, y) = (
            (p % WIDE_PSF_SIDE) as f64 - h,
            (p / WIDE_PSF_SIDE) as f64 - h,
        );
        *v *= round_taper(x.hypot(y), WIDE_PSF_SIDE);
    }
    let total: f64 = want.iter().sum();
    let worst = |stack: &PsfStack| {
        stack
            .pix
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b / total).abs())
            .fold(0.0, f64::max)
    };
    let stack = stack_psf_wide(&img, &spots, &others).expect("stars inside");
    assert_eq!((stack.side, stack.n_stars), (WIDE_PSF_SIDE, 5));
    assert!((stack.pix.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    for (p, v) in stack.pix.iter().enumerate() {
        let (x, y) = (
            (p % WIDE_PSF_SIDE) as f64 - h,
            (p / WIDE_PSF_SIDE) as f64 - h,
        );
        if x.hypot(y) >= h - 0.5 {
            assert_eq!(*v, 0.0, "({x}, {y})");
        }
    }
    let (with, without) = (
        worst(&stack),
        worst(&stack_psf_wide(&img, &spots, &[]).unwrap()),
    );
    eprintln!("wide stack: largest difference {with:e} with the discs, {without:e} without");
    assert!(with < 2e-5, "{with}");
    assert!(without > 1e-3, "{without}");
    // The taper: 1 within 24 px, ½ half-way, 0 from 31.5 px.
    assert_eq!(round_taper(24.0, WIDE_PSF_SIDE), 1.0);
    assert!((round_taper(27.75, WIDE_PSF_SIDE) - 0.5).abs() < 1e-12);
    assert_eq!(round_taper(31.5, WIDE_PSF_SIDE), 0.0);
}

#[test]
fn the_wide_stack_weighs_each_star_by_its_flux_squared() {
    // Stars of fluxes 10³ … 1.4·10⁵ on light the background left (a
    // constant 0.05 a pixel, as a deep scene's faint galaxies leave above
    // the sky's mode). Divided by its flux, each star's stamp carries
    // 0.05 / F a pixel: the plain median of the stars is the median
    // star's, 0.05 / 2·10⁴ = 2.5e-6 a pixel, about 1 % of the stack over
    // its 3 100 pixels; weighted by F², the three brightest make the
    // stack. Measured: 4.2e-7 a pixel 12–24 px from the centre.
    let fluxes = [1e3, 2e3, 5e3, 1e4, 2e4, 5e4, 1e5, 1.2e5, 1.4e5];
    let level = 0.05;
    let mut img = Image::zeros(100 * fluxes.len() + 20, 200);
    let psf = covariance(1.8, [0.05, 0.02]);
    let spots: Vec<(f64, f64)> = (0..fluxes.len())
        .map(|k| (60.3 + 100.0 * k as f64, 100.6 - 0.1 * k as f64))
        .collect();
    for (&(x, y), &f) in spots.iter().zip(&fluxes) {
        draw_gaussian_sampled(&mut img, x, y, f, &psf);
    }
    img.data.iter_mut().for_each(|v| *v += level as f32);
    let others: Vec<[f64; 3]> = spots.iter().map(|&(x, y)| [x, y, 8.0]).collect();
    let stack = stack_psf_wide(&img, &spots, &others).expect("stars inside");
    assert_eq!(stack.n_stars, fluxes.len());
    let h = (WIDE_PSF_SIDE / 2) as f64;
    let (mut sum, mut n) = (0.0, 0);
    for (p, v) in stack.pix.iter().enumerate() {
        let r = ((p % WIDE_PSF_SIDE) as f64 - h).hypot((p / WIDE_PSF_SIDE) as f64 - h);
        // The PSF is below 1e-10 of its peak there; the taper starts at 24 px.
        if (12.0..24.0).contains(&r) {
            sum += v;
            n += 1;
        }
    }
    let pedestal = sum / f64::from(n);
    let plain = stepsim_numerics::stats::median(&mut fluxes.map(|f| level / f)).unwrap();
    eprintln!("wide stack's level 12–24 px: {pedestal:e} (the plain median's: {plain:e})");
    assert!(pedestal > 0.0 && pedestal < 5e-7, "{pedestal}");
    assert!(plain > 4.0 * 5e-7, "{plain}");
}

#[test]
fn the_selection_response_counts_galaxies_that_cross_a_cut() {
    // Two galaxies of fixed e; the first is selected only on +g₁: R_S,11 =
    // (⟨e₁⟩ on +g₁ − ⟨e₁⟩ on −g₁) / 0.02 = (mean(e_a, e_b) − e_b) / 0.02.
    let mk = |e1: f64| McMeasure {
        e: [
            [e1, 0.0],
            [e1 + 0.02, 0.0],
            [e1 - 0.02, 0.0],
            [e1, 0.02],
            [e1, -0.02],
        ],
        rg: [2.0; 5],
        sn: [20.0; 5],
        ok: [true; 5],
        blended: [false; 5],
    };
    let objs = vec![
        (mk(0.3), [false, true, false, true, true]),
        (mk(-0.1), [true; 5]),
    ];
    let r = response(&objs).expect("response");
    let rs11 = (0.5 * (0.3 - 0.1) - (-0.1)) / 0.02;
    assert!((r[0][0] - (2.0 + rs11)).abs() < 1e-12, "{r:?}");
    assert!((r[1][1] - 2.0).abs() < 1e-12, "{r:?}");
}

#[test]
fn an_ensemble_seen_through_a_psf_with_a_halo_recovers_its_shear() {
    // KSB+'s P^γ assumes a Gaussian-like PSF; metacalibration deconvolves
    // the PSF itself. Core σ 1.9 px plus 20 % of the flux in a σ 4 px halo,
    // both with e = (0.05, −0.03), the exact PSF image given: ring of eight
    // e = 0.3 Gaussians of σ 2 px sheared by g = (0.05, 0). Measured
    // ⟨R⁻¹ e⟩₁ = 0.050052 on 32, 48 and 64 px stamps (1.0e-3 of g).
    let core = covariance(1.9, [0.05, -0.03]);
    let halo = covariance(4.0, [0.05, -0.03]);
    let two = |s: usize, c: [f64; 2], gal: Option<&crate::linalg::Mat2>| -> Vec<f64> {
        let mut img = Image::zeros(s, s);
        let (a, b) = match gal {
            Some(g) => (convolve(&core, g), convolve(&halo, g)),
            None => (core, halo),
        };
        draw_gaussian_sampled(&mut img, c[0], c[1], 0.8, &a);
        draw_gaussian_sampled(&mut img, c[0], c[1], 0.2, &b);
        img.data.iter().map(|&v| f64::from(v)).collect()
    };
    let h = (PSF_SIDE / 2) as f64;
    let stack = PsfStack {
        side: PSF_SIDE,
        pix: two(PSF_SIDE, [h, h], None),
        n_stars: 1,
    };
    let sigma = reconvolution_sigma(&stack, 1.96);
    let win = test_window();
    let g = [0.05, 0.0];
    for side in STAMP_SIDES {
        let dec = Deconvolver::new(&stack, side, sigma);
        let c = [(side / 2) as f64, (side / 2) as f64];
        let mean = ring_mean(&dec, side, c, g, &win, |gal| two(side, c, Some(gal)));
        assert!(
            (mean[0] / g[0] - 1.0).abs() < 2e-3 && mean[1].abs() < 1e-5,
            "side {side}: ⟨R⁻¹e⟩ = {mean:?}"
        );
    }
}

#[test]
fn rotating_by_90_degrees_and_back_is_the_identity_and_moves_the_centre_with_the_pixels() {
    let side = 6;
    let a: Vec<f32> = (0..side * side).map(|v| v as f32).collect();
    let r = rot90(&a, side);
    assert_eq!(rot270(&r, side), a);
    assert_ne!(r, a);
    // The pixel at (4, 1) lands where rot90_point takes (4, 1).
    let p = rot90_point([4.0, 1.0], side);
    assert_eq!(r[p[1] as usize * side + p[0] as usize], a[side + 4]);
}

/// The version tests without noise, and KSB+'s blend radius and largest
/// centroid shift.
const NOISELESS: VersionTests = VersionTests {
    noise_sigma: 0.0,
    blend_radius: 10.0,
    max_shift: 3.0,
};

/// The window settings of the deconvolution tests: tight tolerance, many
/// iterations.
fn test_window() -> WindowSettings {
    WindowSettings {
        radius_rg: 4.0,
        rg_min: 0.5,
        rg_max: 15.0,
        tol: 1e-6,
        max_iter: 200,
    }
}

/// ⟨R⁻¹ e⟩ of a ring of eight e = 0.3 Gaussians of σ 2 px sheared by `g`,
/// each drawn by `draw` (its sheared covariance → the observed side² stamp
/// centred on `c`) and measured by `dec`, R from the ring itself.
fn ring_mean(
    dec: &Deconvolver,
    side: usize,
    c: [f64; 2],
    g: [f64; 2],
    win: &WindowSettings,
    draw: impl Fn(&crate::linalg::Mat2) -> Vec<f64>,
) -> [f64; 2] {
    let objs: Vec<(McMeasure, [bool; 5])> = (0..8)
        .map(|k| {
            let ang = PI * k as f64 / 8.0;
            let es = [0.3 * (2.0 * ang).cos(), 0.3 * (2.0 * ang).sin()];
            let gal = shear_covariance(&covariance(2.0, es), g);
            let img = Image {
                width: side,
                height: side,
                data: draw(&gal).iter().map(|&v| v as f32).collect(),
            };
            let m = dec
                .measure(&img, c, c, 2.8, win, &NOISELESS)
                .expect("inside");
            (m, [true; 5])
        })
        .collect();
    let r = response(&objs).expect("response");
    objs.iter()
        .map(|(m, _)| apply_inverse(&r, m.e[0]))
        .fold([0.0, 0.0], |a, e| [a[0] + e[0] / 8.0, a[1] + e[1] / 8.0])
}

/// Two round Gaussians of σ `s` through a Gaussian PSF of σ 1.8 px, the
/// second `d` px to the right of the first (flux `f2`), on a 96² image,
/// symmetric about its centre (48, 48): the image and the first one's
/// centre.
fn pair_stamp(s: f64, d: f64, f2: f64) -> (Image, [f64; 2]) {
    let side = 96;
    let c = [48.0 - d / 2.0, 48.0];
    let cov = convolve(&covariance(s, [0.0, 0.0]), &covariance(1.8, [0.0, 0.0]));
    let a = gaussian_stamp(side, c, &cov);
    let b = gaussian_stamp(side, [c[0] + d, c[1]], &cov);
    let img = Image {
        width: side,
        height: side,
        data: a.iter().zip(&b).map(|(x, y)| (x + f2 * y) as f32).collect(),
    };
    (img, c)
}

#[test]
fn a_resolved_neighbour_is_a_second_peak_and_a_merged_one_is_not() {
    // Well apart: two peaks with a deep dip between them.
    let (img, c) = pair_stamp(1.5, 9.0, 0.5);
    assert!(neighbour_peak(&img, c[0], c[1], 10.0, 0.0));
    // Beyond the radius it does not count.
    assert!(!neighbour_peak(&img, c[0], c[1], 8.0, 0.0));
    // Closer than the blend's resolution: one peak.
    let (img, c) = pair_stamp(1.5, 3.0, 0.5);
    assert!(!neighbour_peak(&img, c[0], c[1], 10.0, 0.0));
    // Alone: one peak.
    let (img, c) = pair_stamp(1.5, 9.0, 0.0);
    assert!(!neighbour_peak(&img, c[0], c[1], 10.0, 0.0));
    // A dip shallower than 4 σ does not count: the resolved pair with a
    // noise σ of a tenth of its second peak's height.
    let (img, c) = pair_stamp(1.5, 9.0, 0.5);
    let second = f64::from(img.data[48 * 96 + 53]);
    assert!(neighbour_peak(&img, c[0], c[1], 10.0, 0.1 * second));
    assert!(!neighbour_peak(&img, c[0], c[1], 10.0, 0.3 * second));
}

/// The versions of pairs along x ([`pair_stamp`] of galaxy σ `s` and
/// second flux `f2`) at `n` separations from `d0` in steps of 0.1 px,
/// through a PSF of σ 1.8 px reconvolved to 2.4 px, each measured about
/// the pair's centre with its centroid started at the image centre or,
/// with `from_first`, at the first galaxy: (separation, versions).
fn pairs_measured(s: f64, f2: f64, d0: f64, n: u32, from_first: bool) -> Vec<(f64, McMeasure)> {
    let stack = PsfStack {
        side: PSF_SIDE,
        pix: gaussian_stamp(PSF_SIDE, [16.0, 16.0], &covariance(1.8, [0.0, 0.0])),
        n_stars: 1,
    };
    let dec = Deconvolver::new(&stack, 64, 2.4);
    let win = test_window();
    (0..n)
        .map(|step| {
            let d = d0 + 0.1 * f64::from(step);
            let (img, c) = pair_stamp(s, d, f2);
            let start = if from_first { c } else { [48.0; 2] };
            let m = dec
                .measure(&img, [48.0; 2], start, 2.5, &win, &NOISELESS)
                .expect("inside");
            (d, m)
        })
        .collect()
}

#[test]
fn stretching_a_pair_along_its_axis_resolves_it_and_squeezing_merges_it() {
    // A pair along x: the +g₁ version stretches x (SPEC §1), so it can
    // only resolve more than the −g₁ one. At some separation the two
    // versions disagree: that is the selection the response must see.
    // Measured about the pair's centre: one blended object, as a detector
    // that does not split it would measure it.
    let mut disagree = 0;
    for (d, m) in pairs_measured(1.0, 1.0, 4.0, 60, false) {
        assert!(
            m.blended[1] >= m.blended[2],
            "d = {d}: +g₁ merged where −g₁ resolved"
        );
        assert_eq!(
            m.blended[3], m.blended[4],
            "d = {d}: g₂ is symmetric for a pair along x"
        );
        disagree += usize::from(m.blended[1] != m.blended[2]);
    }
    assert!(
        disagree > 0,
        "no separation where the sheared versions disagree"
    );
}

#[test]
fn a_centroid_pulled_onto_a_brighter_neighbour_is_tested_on_every_version() {
    // A faint galaxy with a neighbour three times brighter to its right,
    // its centroid started at the faint one (the detection's position).
    // The window runs onto the pair's light-weighted centre, so the shift
    // grows with the separation: beyond about 3.8 px it exceeds 3 px.
    // The version stretched along the pair (+g₁) crosses that first, and
    // at some separation only it fails: the shift test responds to the
    // shear, and R_S sees it because it is made on every version.
    let (mut disagree, mut failed) = (0, 0);
    for (d, m) in pairs_measured(1.2, 3.0, 2.5, 30, true) {
        assert_eq!(
            m.ok[3], m.ok[4],
            "d = {d}: g₂ is symmetric for a pair along x"
        );
        if m.ok[1] != m.ok[2] {
            disagree += 1;
            assert!(m.ok[2] && !m.ok[1], "d = {d}: {:?}", m.ok);
        }
        failed += usize::from(!m.ok[0]);
    }
    assert!(
        failed > 0 && failed < 30,
        "{failed} of 30 separations fail unsheared"
    );
    assert!(
        disagree > 0,
        "no separation where the sheared versions disagree"
    );
}

#[test]
fn the_noise_correction_stamp_is_seeded_by_the_stamp_and_differs_between_images() {
    let stamp: Vec<f64> = (0..32 * 32).map(|v| (v % 7) as f64).collect();
    let a = fixnoise(&stamp, 2.0);
    assert_eq!(a, fixnoise(&stamp, 2.0), "the same stamp, the same noise");
    let sd = (a.iter().map(|v| v * v).sum::<f64>() / a.len() as f64).sqrt();
    assert!((sd / 2.0 - 1.0).abs() < 0.1, "σ {sd}");
    // One pixel one unit in the last place away: another, uncorrelated
    // stamp (1 024 pixels: |r| ~ 0.03).
    let mut other = stamp.clone();
    other[100] = f64::from_bits(other[100].to_bits() + 1);
    let b = fixnoise(&other, 2.0);
    let r =
        a.iter().zip(&b).map(|(x, y)| x * y).sum::<f64>() / a.iter().map(|x| x * x).sum::<f64>();
    assert!(r.abs() < 0.15, "correlation {r}");
}

#[test]
fn galaxies_at_one_pixel_of_many_images_do_not_share_a_noise_correction() {
    // The same round galaxy at the same pixel of 200 images, each with its
    // own white noise (ν ≈ 40), as on a grid of fixed positions or a base
    // field seen at five shears. d = e(0) with the noise correction minus
    // e(0) without it is the correction's part of each measurement. Seeded
    // by the position alone, d was nearly the same in every image (spread
    // 9e-4) and its mean an offset (0.018 in e₁) that no number of images
    // removes; seeded by the stamp, the d are independent (spread 0.015)
    // and their mean is 0 within 4 standard errors.
    let side = 32;
    let sigma_n = 0.002;
    let cov = convolve(&covariance(2.0, [0.0, 0.0]), &covariance(1.8, [0.0, 0.0]));
    let c = [16.2, 15.7];
    let clean = gaussian_stamp(side, c, &cov);
    let psf = gaussian_stamp(PSF_SIDE, [16.0, 16.0], &covariance(1.8, [0.0, 0.0]));
    let total: f64 = psf.iter().sum();
    let stack = PsfStack {
        side: PSF_SIDE,
        pix: psf.iter().map(|v| v / total).collect(),
        n_stars: 1,
    };
    let dec = Deconvolver::new(&stack, side, reconvolution_sigma(&stack, 1.8 * 2f64.sqrt()));
    let win = test_window();
    let with = VersionTests {
        noise_sigma: sigma_n,
        ..NOISELESS
    };
    let n = 200;
    let d: Vec<[f64; 2]> = (0..n)
        .map(|k| {
            let mut rng = SeedKey::base(5, 0, Stream::Test).with_index(k).rng();
            let img = Image {
                width: side,
                height: side,
                data: clean
                    .iter()
                    .map(|&v| {
                        (v + sigma_n * rng.sample::<f64, _>(rand_distr::StandardNormal)) as f32
                    })
                    .collect(),
            };
            let a = dec.measure(&img, c, c, 2.8, &win, &with).expect("inside");
            let b = dec
                .measure(&img, c, c, 2.8, &win, &NOISELESS)
                .expect("inside");
            [a.e[0][0] - b.e[0][0], a.e[0][1] - b.e[0][1]]
        })
        .collect();
    for i in 0..2 {
        let mean = d.iter().map(|v| v[i]).sum::<f64>() / n as f64;
        let sd = (d.iter().map(|v| (v[i] - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
        assert!(
            sd > 5e-3,
            "e{}: d has a spread of {sd:e} only: one correction shared by all images?",
            i + 1
        );
        assert!(
            mean.abs() < 4.0 * sd / (n as f64).sqrt(),
            "e{}: mean {mean:e}, standard error {:e}",
            i + 1,
            sd / (n as f64).sqrt()
        );
    }
}
