use super::*;
use crate::metacal::PSF_SIDE;

/// An elliptical Gaussian of covariance `c` and flux `flux` centred at
/// `p`, sampled at pixel centres of a w × h grid.
fn gaussian(w: usize, h: usize, p: [f64; 2], c: [[f64; 2]; 2], flux: f64) -> Vec<f64> {
    let det = c[0][0] * c[1][1] - c[0][1] * c[1][0];
    let inv = [
        [c[1][1] / det, -c[0][1] / det],
        [-c[1][0] / det, c[0][0] / det],
    ];
    let norm = flux / (2.0 * PI * det.sqrt());
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let (u, v) = (x as f64 - p[0], y as f64 - p[1]);
            let q = inv[0][0] * u * u + 2.0 * inv[0][1] * u * v + inv[1][1] * v * v;
            out[y * w + x] = norm * (-0.5 * q).exp();
        }
    }
    out
}

/// A C Aᵀ for symmetric A.
fn sandwich(a: [[f64; 2]; 2], c: [[f64; 2]; 2]) -> [[f64; 2]; 2] {
    let mut ac = [[0.0; 2]; 2];
    for i in 0..2 {
        for j in 0..2 {
            ac[i][j] = a[i][0] * c[0][j] + a[i][1] * c[1][j];
        }
    }
    let mut out = [[0.0; 2]; 2];
    for i in 0..2 {
        for j in 0..2 {
            out[i][j] = ac[i][0] * a[j][0] + ac[i][1] * a[j][1];
        }
    }
    out
}

fn inverse(a: [[f64; 2]; 2]) -> [[f64; 2]; 2] {
    let det = a[0][0] * a[1][1] - a[0][1] * a[1][0];
    [
        [a[1][1] / det, -a[0][1] / det],
        [-a[1][0] / det, a[0][0] / det],
    ]
}

/// The slow twin of [`bessel_i0`]: (1/π) ∫₀^π e^{x cos θ} dθ by the
/// trapezoid rule on 4000 intervals (exact to rounding for a periodic
/// integrand this smooth).
fn bessel_i0_slow(x: f64) -> f64 {
    let n = 4000;
    let h = PI / n as f64;
    let mut s = 0.5 * (x.exp() + (-x).exp());
    for k in 1..n {
        s += (x * (k as f64 * h).cos()).exp();
    }
    s * h / PI
}

#[test]
fn the_kernel_s_bessel_function_equals_its_slow_twin_and_tabulated_values() {
    // Values from a table (scipy.special.i0).
    for (x, want) in [
        (0.0, 1.0),
        (1.0, 1.266_065_877_752_008_2),
        (5.0, 27.239_871_823_604_442),
        (12.0, 18_948.925_349_296_31),
        (20.0, 43_558_282.559_553_534),
    ] {
        let got = bessel_i0(x);
        assert!((got / want - 1.0).abs() < 1e-14, "{x}: {got} {want}");
        let slow = bessel_i0_slow(x);
        assert!((slow / want - 1.0).abs() < 1e-12, "{x}: {slow} {want}");
    }
}

#[test]
fn the_kernel_s_table_holds_the_kernel_at_each_phase() {
    // At a table phase the lookup is the kernel itself; between phases it
    // is the kernel at the nearest phase (1/4096 of a pixel), and a phase
    // rounded up to 1 is the next sample's phase 0.
    for t in [
        0.0,
        0.25,
        0.5,
        3.75,
        -2.25,
        4095.5,
        1.0 - 1.0 / PHASES as f64,
    ] {
        let (b1, w1) = weights(t);
        let (b2, w2) = kernel(t);
        assert_eq!(b1, b2, "{t}");
        for (a, b) in w1.iter().zip(&w2) {
            assert!((a - b).abs() < 1e-15, "{t}: {w1:?} {w2:?}");
        }
    }
    let t = 7.0 + 0.3 / PHASES as f64;
    assert_eq!(weights(t), weights(7.0));
    let t = 7.0 - 0.3 / PHASES as f64;
    assert_eq!(weights(t), weights(7.0));
    // The weights sum to 1, and the kernel is 1 at a sample, 0 at the
    // others.
    let (_, w) = kernel(3.0);
    for (k, v) in w.iter().enumerate() {
        let want = if k == KERNEL_N as usize - 1 { 1.0 } else { 0.0 };
        assert!((v - want).abs() < 1e-15, "{k}: {v}");
    }
    let (_, w) = kernel(3.37);
    assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-14);
}

#[test]
fn the_kernel_interpolates_a_gaussian_to_1e_6_of_its_peak() {
    // A Gaussian of σ 2.2 px (a star reconvolved: the narrowest a version
    // holds) and 3 px sampled at the integers, interpolated at 801 points
    // 0 – 20 px from its centre. Measured: largest error 1.0e-6 (σ 2.2)
    // and 9.9e-7 (σ 3) of the peak; Lanczos with the same taps: 2.4e-4.
    for sigma in [2.2f64, 3.0] {
        let f = |x: f64| (-x * x / (2.0 * sigma * sigma)).exp();
        let mut worst = 0.0f64;
        for i in 0..=800 {
            let t = i as f64 / 40.0;
            let (base, w) = kernel(t);
            let got: f64 = w
                .iter()
                .enumerate()
                .map(|(k, wk)| wk * f((base + k as i64) as f64))
                .sum();
            worst = worst.max((got - f(t)).abs());
        }
        assert!(worst < 2e-6, "σ {sigma}: {worst:e}");
    }
}

#[test]
fn the_two_pass_resampling_equals_its_slow_twin_and_the_sheared_gaussian() {
    // f(c + A(x − c)) of an elliptical Gaussian at c is the Gaussian of
    // covariance A⁻¹ C A⁻¹. The slow twin (the kernel at each exact
    // position) gives it to 2e-6 of the peak (measured ≤ 6.4e-7; the
    // Lanczos kernel of 049bf34: 2e-4), the two-pass form to 5e-5
    // (measured ≤ 3.4e-5: its table rounds a position to 1/4096 px).
    let (w, h) = (96, 80);
    let c = [(w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0];
    let cov = [[7.0, 1.5], [1.5, 5.0]];
    let f = gaussian(w, h, c, cov, 1000.0);
    let peak = f.iter().cloned().fold(0.0, f64::max);
    for g in [
        [0.01, 0.0],
        [-0.01, 0.0],
        [0.0, 0.01],
        [0.0, -0.01],
        [0.05, -0.03],
    ] {
        let a = shear_matrix(g);
        let m = inverse(a);
        let want = gaussian(w, h, c, sandwich(m, cov), 1000.0);
        let fast = resample(&f, w, h, a);
        let slow = resample_slow(&f, w, h, a);
        let worst = |x: &[f64], y: &[f64]| {
            x.iter()
                .zip(y)
                .map(|(p, q)| (p - q).abs())
                .fold(0.0, f64::max)
                / peak
        };
        assert!(
            worst(&fast, &want) < 5e-5,
            "{g:?}: fast {}",
            worst(&fast, &want)
        );
        assert!(
            worst(&slow, &want) < 2e-6,
            "{g:?}: slow {}",
            worst(&slow, &want)
        );
        assert!(worst(&fast, &slow) < 5e-5, "{g:?}");
    }
    // At A = 1 (the unsheared version) the field comes back as it was:
    // exactly from the fast form, to rounding from the slow twin.
    let one = shear_matrix([0.0, 0.0]);
    assert_eq!(resample(&f, w, h, one), f);
    let slow = resample_slow(&f, w, h, one);
    assert!(
        f.iter()
            .zip(&slow)
            .all(|(p, q)| (p - q).abs() < 1e-12 * peak)
    );
    // A wrong sign of the shear is seen: the error is then 100 times larger.
    let a = shear_matrix([0.01, 0.0]);
    let want = gaussian(w, h, c, sandwich(a, cov), 1000.0);
    let fast = resample(&f, w, h, a);
    let err = fast
        .iter()
        .zip(&want)
        .map(|(p, q)| (p - q).abs())
        .fold(0.0, f64::max)
        / peak;
    assert!(err > 2e-3, "{err}");
}

#[test]
fn a_version_of_the_whole_image_is_the_sheared_galaxy_reconvolved() {
    // A Gaussian galaxy (covariance C) seen through a Gaussian PSF (σ_p):
    // the version sheared by g is the Gaussian of covariance
    // A⁻¹ C A⁻¹ + σ_Γ² 1, of the same flux, at the image's centre.
    let (w, h) = (160, 144);
    let c = [(w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0];
    let cov = [[4.0, 0.8], [0.8, 2.5]];
    let sp = 1.5;
    let seen = [
        [cov[0][0] + sp * sp, cov[0][1]],
        [cov[1][0], cov[1][1] + sp * sp],
    ];
    let data = gaussian(w, h, c, seen, 5000.0);
    let sub = Image {
        width: w,
        height: h,
        data: data.iter().map(|&v| v as f32).collect(),
    };
    let half = (PSF_SIDE / 2) as f64;
    let pix = gaussian(
        PSF_SIDE,
        PSF_SIDE,
        [half, half],
        [[sp * sp, 0.0], [0.0, sp * sp]],
        1.0,
    );
    let sum: f64 = pix.iter().sum();
    let psf = PsfStack {
        side: PSF_SIDE,
        pix: pix.iter().map(|v| v / sum).collect(),
        n_stars: 1,
    };
    let sigma = 2.2;
    let whole = WholeImage::new(&sub, &psf, sigma, 0.0).expect("large enough");
    for g in VERSIONS {
        let m = inverse(shear_matrix(g));
        let sc = sandwich(m, cov);
        let want_cov = [
            [sc[0][0] + sigma * sigma, sc[0][1]],
            [sc[1][0], sc[1][1] + sigma * sigma],
        ];
        let want = gaussian(w, h, c, want_cov, 5000.0);
        let peak = want.iter().cloned().fold(0.0, f64::max);
        let got = whole.version(g);
        let err = got
            .data
            .iter()
            .zip(&want)
            .map(|(p, q)| (f64::from(*p) - q).abs())
            .fold(0.0, f64::max)
            / peak;
        assert!(err < 1e-4, "{g:?}: {err}");
        // The shear itself, by moments weighted by a Gaussian twice the
        // galaxy's size (where the wings count): a 1 % error in the
        // applied shear moves e by 6e-5. Measured: at most 5.7e-6 (the
        // table's phases); 8e-4 with the Lanczos kernel of 049bf34, a
        // shear 13 % too strong at this weight.
        let (e_got, e_want) = (moments_e(&got.data, w, c), moments_e(&want, w, c));
        for i in 0..2 {
            assert!(
                (e_got[i] - e_want[i]).abs() < 1e-5,
                "{g:?}: {e_got:?} {e_want:?}"
            );
        }
    }
}

/// (Q₁₁ − Q₂₂, 2Q₁₂) / (Q₁₁ + Q₂₂) of the second moments of a `w`-wide
/// image about `c`, weighted by a round Gaussian of σ 6 px.
fn moments_e<T: Copy + Into<f64>>(data: &[T], w: usize, c: [f64; 2]) -> [f64; 2] {
    let (mut qxx, mut qyy, mut qxy) = (0.0, 0.0, 0.0);
    for (k, &v) in data.iter().enumerate() {
        let (x, y) = ((k % w) as f64 - c[0], (k / w) as f64 - c[1]);
        let v = v.into() * (-(x * x + y * y) / 72.0).exp();
        qxx += v * x * x;
        qyy += v * y * y;
        qxy += v * x * y;
    }
    [(qxx - qyy) / (qxx + qyy), 2.0 * qxy / (qxx + qyy)]
}

#[test]
fn a_dataset_s_response_is_the_difference_of_its_versions_means() {
    // Two images: ⟨e₁⟩ on +g₁ is (0.03 + 0.05) / 4, on −g₁ (−0.02 − 0.04) / 4,
    // so R₁₁ = (0.02 + 0.015) / 0.02 = 1.75; ⟨e₂⟩ on ±g₂ is ±0.03 / 2, so
    // R₂₂ = 1.5.
    let a = [
        [0.0; 3],
        [0.03, 0.0, 2.0],
        [-0.02, 0.0, 2.0],
        [0.0, 0.01, 1.0],
        [0.0, -0.01, 1.0],
    ];
    let b = [
        [0.0; 3],
        [0.05, 0.0, 2.0],
        [-0.04, 0.0, 2.0],
        [0.0, 0.02, 1.0],
        [0.0, -0.02, 1.0],
    ];
    let r = response(&[a, b]).expect("a response");
    assert!((r[0][0] - 1.75).abs() < 1e-12, "{r:?}");
    assert!((r[1][1] - 1.5).abs() < 1e-12, "{r:?}");
    assert!(r[0][1].abs() < 1e-12 && r[1][0].abs() < 1e-12, "{r:?}");
    // No object on a sheared version: no response.
    let mut c = a;
    c[3][2] = 0.0;
    c[3][1] = 0.0;
    assert!(response(&[c]).is_none());
}

#[test]
fn the_response_s_jackknife_error_is_that_of_the_responses_without_each_image() {
    // Four images of differing sums. The slow twin: each response without
    // one image computed from the other three's sums, and the jackknife's
    // √((n − 1)/n Σ (R₍ᵢ₎ − R̄)²) written out.
    let image = |k: f64| -> VersionSums {
        [
            [0.01 * k, -0.02, 10.0],
            [0.06 + 0.01 * k * k, 0.002 * k, 10.0 + k],
            [-0.05 - 0.02 * k, 0.001, 9.0 + k],
            [0.003 * k, 0.07 - 0.01 * k, 11.0],
            [-0.001, -0.06 + 0.005 * k * k, 10.0 + 2.0 * k],
        ]
    };
    let sums: Vec<VersionSums> = (0..4).map(|k| image(k as f64)).collect();
    let err = response_error(&sums).expect("an error");
    let without: Vec<[[f64; 2]; 2]> = (0..4)
        .map(|i| {
            let others: Vec<VersionSums> = (0..4).filter(|&j| j != i).map(|j| sums[j]).collect();
            response(&others).expect("a response")
        })
        .collect();
    for i in 0..2 {
        for j in 0..2 {
            let mean: f64 = without.iter().map(|r| r[i][j]).sum::<f64>() / 4.0;
            let var: f64 = 0.75
                * without
                    .iter()
                    .map(|r| (r[i][j] - mean).powi(2))
                    .sum::<f64>();
            assert!((err[i][j] - var.sqrt()).abs() < 1e-12, "{i}{j}: {err:?}");
            assert!(err[i][j] > 1e-3, "{i}{j}: {err:?}");
        }
    }
    // Identical images: no scatter. One image: no error.
    let same = vec![image(1.0); 3];
    let zero = response_error(&same).expect("an error");
    assert!(zero.iter().flatten().all(|e| e.abs() < 1e-12), "{zero:?}");
    assert!(response_error(&sums[..1]).is_none());
}

#[test]
fn the_edge_is_cut_in_the_image_as_given_and_saturation_where_the_light_went() {
    let (w, h) = (4096, 4096);
    for g in crate::metacal::VERSIONS {
        // The two maps invert each other.
        let p = [123.4, 3900.2];
        let back = to_version(to_version(p, w, h, g), w, h, [-g[0], -g[1]]);
        assert!((back[0] - p[0]).abs() < 1e-9 && (back[1] - p[1]).abs() < 1e-9);
        // 70 px from the left edge as given: kept on every version, though
        // the ±g₁ versions put it 50 and 90 px from their edge.
        let q = to_version([70.0, 2047.5], w, h, g);
        assert_eq!(position_flags(q, w, h, g, &[]), 0, "{g:?} at {q:?}");
        // 60 px from it: cut on every version (40 and 80 px in the ±g₁
        // versions' frames).
        let q = to_version([60.0, 2047.5], w, h, g);
        assert_eq!(position_flags(q, w, h, g, &[]), flags::EDGE, "{g:?}");
        // A saturated detection of the image as given cuts what lies within
        // SATURATED_RADIUS_PX of where the version put it.
        let s = [1000.0, 3000.0];
        let at = to_version(s, w, h, g);
        let near = [at[0] + 0.9 * SATURATED_RADIUS_PX, at[1]];
        let far = [at[0] + 1.1 * SATURATED_RADIUS_PX, at[1]];
        assert_eq!(position_flags(near, w, h, g, &[s]), flags::SATURATED);
        assert_eq!(position_flags(far, w, h, g, &[s]), 0);
    }
    let q = to_version([70.0, 2047.5], w, h, [0.01, 0.0]);
    assert!(q[0] < 55.0, "{q:?}");
}

#[test]
fn the_rows_use_the_response_s_diagonal() {
    let r = [[0.31, 0.02], [-0.015, 0.29]];
    assert_eq!(applied_response(r), Some([[0.31, 0.0], [0.0, 0.29]]));
    assert_eq!(applied_response([[0.31, 0.0], [0.0, -0.01]]), None);
    assert_eq!(applied_response([[0.0, 0.3], [0.3, 0.3]]), None);
    assert_eq!(applied_response([[f64::NAN, 0.0], [0.0, 0.3]]), None);
}

/// White noise of σ 1, `n` values, from `seed` (Box–Muller on splitmix64).
fn white(n: usize, seed: u64) -> Vec<f64> {
    let u = |k: u64| {
        let x = stepsim_contract::seed::splitmix64(seed.wrapping_mul(0x1_0000_0001) ^ k);
        ((x >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    (0..n as u64)
        .map(|i| (-2.0 * u(2 * i).ln()).sqrt() * (2.0 * PI * u(2 * i + 1)).cos())
        .collect()
}

/// A Gaussian PSF stack of covariance `cov`, normalised.
fn gaussian_stack(cov: [[f64; 2]; 2]) -> PsfStack {
    let half = (PSF_SIDE / 2) as f64;
    let pix = gaussian(PSF_SIDE, PSF_SIDE, [half, half], cov, 1.0);
    let sum: f64 = pix.iter().sum();
    PsfStack {
        side: PSF_SIDE,
        pix: pix.iter().map(|v| v / sum).collect(),
        n_stars: 1,
    }
}

/// The ellipticity of a field's power spectrum over the central `side`²
/// pixels: Σ P(k) (k_x² − k_y², 2 k_x k_y) / Σ P(k) |k|².
fn power_e(img: &Image, side: usize) -> [f64; 2] {
    let (x0, y0) = ((img.width - side) / 2, (img.height - side) / 2);
    let z: Vec<Complex64> = (0..side * side)
        .map(|i| {
            let v = img.data[(y0 + i / side) * img.width + x0 + i % side];
            Complex64::new(f64::from(v), 0.0)
        })
        .collect();
    let s = Fft2::new(side, side).forward(z);
    let (mut q1, mut q2, mut t) = (0.0, 0.0, 0.0);
    for kxi in 0..side {
        let kx = freq(kxi, side);
        for kyi in 0..side {
            let ky = freq(kyi, side);
            let p = s[kxi * side + kyi].norm_sqr();
            q1 += p * (kx * kx - ky * ky);
            q2 += p * 2.0 * kx * ky;
            t += p * (kx * kx + ky * ky);
        }
    }
    [q1 / t, q2 / t]
}

#[test]
fn the_noise_correction_leaves_the_version_s_noise_without_direction() {
    // White noise through an elliptical PSF, deconvolved and sheared: the
    // version's noise has a direction (the PSF's, and the shear's). The
    // correction adds the same noise rotated by 90°, so the sum has none.
    let (w, h) = (512, 512);
    let sub = Image {
        width: w,
        height: h,
        data: white(w * h, 1).iter().map(|&v| v as f32).collect(),
    };
    let psf = gaussian_stack([[2.6, 0.5], [0.5, 1.7]]);
    let bare = WholeImage::new(&sub, &psf, 2.6, 0.0).expect("large enough");
    let fixed = WholeImage::new(&sub, &psf, 2.6, 1.0).expect("large enough");
    for g in VERSIONS {
        let e_bare = power_e(&bare.version(g), 448);
        let e_fixed = power_e(&fixed.version(g), 448);
        assert!(e_bare[0].hypot(e_bare[1]) > 0.1, "{g:?}: {e_bare:?}");
        for i in 0..2 {
            assert!(
                e_fixed[i].abs() < 0.01,
                "{g:?}: {e_fixed:?} ({e_bare:?} without)"
            );
        }
    }
}

#[test]
fn every_version_holds_the_noise_correction_where_the_objects_are() {
    // A blank image: each version is the correction's noise alone. Taken
    // back to the image's frame (resampled at A_−g x, as a version's
    // objects are by `to_version`), the ±0.01 versions hold the same noise
    // but for the 1 % shear of its filter, even far from the centre.
    // Resampled against the image, as the first versions did, it moved by
    // 0.04 r between them, 6 px or more beyond r = 150 px, where σ_Γ is
    // 2.2 px.
    let (w, h) = (512, 512);
    let sub = Image {
        width: w,
        height: h,
        data: vec![0.0; w * h],
    };
    let psf = gaussian_stack([[2.0, 0.3], [0.3, 1.6]]);
    let whole = WholeImage::new(&sub, &psf, 2.2, 1.0).expect("large enough");
    let c = (w as f64 - 1.0) / 2.0;
    for (p, m) in [(1, 2), (3, 4)] {
        let back = |g: [f64; 2]| {
            let v: Vec<f64> = whole
                .version(g)
                .data
                .iter()
                .map(|&x| f64::from(x))
                .collect();
            resample(&v, w, h, shear_matrix([-g[0], -g[1]]))
        };
        let (a, b) = (back(VERSIONS[p]), back(VERSIONS[m]));
        let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
        for y in 0..h {
            for x in 0..w {
                let r = (x as f64 - c).hypot(y as f64 - c);
                if !(150.0..=230.0).contains(&r) {
                    continue;
                }
                let (u, v) = (a[y * w + x], b[y * w + x]);
                ab += u * v;
                aa += u * u;
                bb += v * v;
            }
        }
        let corr = ab / (aa * bb).sqrt();
        assert!(corr > 0.98, "versions {p} and {m}: correlation {corr}");
    }
}

#[test]
fn the_noise_filter_s_psf_power_equals_its_direct_transform_between_the_grid_s_frequencies() {
    // The slow twin of `rot_power`: |Σ P(R⁻¹x) e^(−2πi k·x)|² over the
    // stack's pixels, at frequencies between the grid's (and past its
    // Nyquist, where it wraps), against the bilinear interpolation of the
    // grid's |P̂_rot|².
    let (w, h) = (512, 384);
    let sub = Image {
        width: w,
        height: h,
        data: vec![0.0; w * h],
    };
    let psf = gaussian_stack([[2.4, 0.6], [0.6, 1.5]]);
    let whole = WholeImage::new(&sub, &psf, 2.2, 1.0).expect("large enough");
    let c = (PSF_SIDE / 2) as f64;
    let direct = |kx: f64, ky: f64| {
        let mut z = Complex64::new(0.0, 0.0);
        for (j, row) in psf.pix.chunks_exact(PSF_SIDE).enumerate() {
            for (i, &p) in row.iter().enumerate() {
                let (dx, dy) = (i as f64 - c, j as f64 - c);
                let (x, y) = (-dy, dx);
                z += Complex64::from_polar(p, -2.0 * PI * (kx * x + ky * y));
            }
        }
        z.norm_sqr()
    };
    let mut worst: f64 = 0.0;
    for k in 0..400 {
        let t = k as f64;
        let (kx, ky) = (
            (t * 0.618_034).fract() - 0.5,
            (t * 0.414_214).fract() * 1.2 - 0.6,
        );
        worst = worst.max((whole.rot_power(kx, ky) - direct(kx, ky)).abs());
    }
    // Bilinear interpolation errs by about h² max|f″| / 8, h = 1/384 and
    // f″ ≈ 8π² · 2.4 here: 1.6e-4 of the peak (measured 1.63e-4); at
    // 4096 px, 1.4e-6.
    assert!(worst < 3e-4, "{worst}");
}

#[test]
fn unpacking_in_place_equals_its_slow_twin() {
    // Grids of even and odd sides (an odd side has no Nyquist frequency,
    // so only (0, 0) is its own mirror; an even one has four such
    // frequencies): â in place and b̂ given index by index, bit for bit
    // as the slow twin computes them from the packed field as given.
    for (w, h) in [(8, 6), (7, 5), (6, 9), (1, 4)] {
        let re = white(w * h, 3);
        let im = white(w * h, 4);
        let z: Vec<Complex64> = re
            .iter()
            .zip(&im)
            .map(|(&a, &b)| Complex64::new(a, b))
            .collect();
        let (a_slow, b_slow) = unpack_slow(&z, w, h);
        let mut a = z.clone();
        let mut b = vec![Complex64::new(f64::NAN, f64::NAN); w * h];
        let mut seen = vec![0u32; w * h];
        unpack(&mut a, w, h, |i, v| {
            b[i] = v;
            seen[i] += 1;
        });
        assert!(seen.iter().all(|&n| n == 1), "{w}×{h}: {seen:?}");
        let bits = |v: &[Complex64]| -> Vec<(u64, u64)> {
            v.iter().map(|c| (c.re.to_bits(), c.im.to_bits())).collect()
        };
        assert_eq!(bits(&a), bits(&a_slow), "{w}×{h}: â");
        assert_eq!(bits(&b), bits(&b_slow), "{w}×{h}: b̂");
    }
    // The two fields are told apart: with the real field zero and the
    // imaginary one v, â is zero (to rounding) and b̂ the transform of v.
    let (w, h) = (8, 6);
    let v = white(w * h, 5);
    let fft = Fft2::new(w, h);
    let mut a = fft.forward(v.iter().map(|&x| Complex64::new(0.0, x)).collect());
    let want = fft.forward(v.iter().map(|&x| Complex64::new(x, 0.0)).collect());
    let mut b = vec![Complex64::new(0.0, 0.0); w * h];
    unpack(&mut a, w, h, |i, x| b[i] = x);
    assert!(a.iter().all(|c| c.norm() < 1e-12), "{a:?}");
    assert!(b.iter().zip(&want).all(|(p, q)| (p - q).norm() < 1e-12));
    assert!(want.iter().map(|c| c.norm()).sum::<f64>() > 1.0);
}

#[test]
fn a_version_does_not_depend_on_the_versions_made_before_it() {
    // The versions reuse their buffers: each must be the same bits made
    // first, made again, or made after the others in any order, with and
    // without the noise correction, on a grid whose sides differ.
    let (w, h) = (160, 136);
    let c = [70.3, 61.8];
    let field = gaussian(w, h, c, [[6.0, 1.2], [1.2, 4.0]], 4000.0);
    let noise = white(w * h, 9);
    let sub = Image {
        width: w,
        height: h,
        data: field
            .iter()
            .zip(&noise)
            .map(|(f, n)| (f + n) as f32)
            .collect(),
    };
    let psf = gaussian_stack([[2.2, 0.4], [0.4, 1.8]]);
    for noise_sigma in [0.0, 1.0] {
        let first: Vec<Vec<u32>> = VERSIONS
            .iter()
            .map(|&g| {
                let whole = WholeImage::new(&sub, &psf, 2.4, noise_sigma).expect("large enough");
                whole.version(g).data.iter().map(|v| v.to_bits()).collect()
            })
            .collect();
        let whole = WholeImage::new(&sub, &psf, 2.4, noise_sigma).expect("large enough");
        for order in [[0, 1, 2, 3, 4], [4, 3, 2, 1, 0], [2, 0, 4, 1, 3]] {
            for v in order {
                let got: Vec<u32> = whole
                    .version(VERSIONS[v])
                    .data
                    .iter()
                    .map(|x| x.to_bits())
                    .collect();
                assert!(
                    got == first[v],
                    "σ {noise_sigma}, version {v} after {order:?}"
                );
            }
        }
        // The versions differ from one another (the test could fail).
        assert!(first[1] != first[2] && first[0] != first[1]);
    }
}

#[test]
fn wrapping_a_frequency_equals_rem_euclid_bit_for_bit() {
    // Every branch of `wrap` and its edges: 0, ±n, 2n, values a rounding
    // away from them, signed zeros, and a sweep across (−3n, 3n).
    for n in [4096.0f64, 384.0, 7.0] {
        let mut xs = vec![0.0, -0.0, n, -n, 2.0 * n, -2.0 * n, 3.5 * n, -3.5 * n];
        for e in [n, -n, 0.0, 2.0 * n] {
            xs.push(f64::from_bits(e.to_bits() + 1));
            xs.push(f64::from_bits(e.to_bits().saturating_sub(1)));
            xs.push(e - 1e-12);
            xs.push(e + 1e-12);
        }
        for k in 0..6000 {
            xs.push((k as f64 / 1000.0 - 3.0) * n + 0.000_123 * k as f64);
        }
        for x in xs {
            assert_eq!(
                wrap(x, n).to_bits(),
                x.rem_euclid(n).to_bits(),
                "x = {x:e}, n = {n}"
            );
        }
    }
}

#[test]
fn the_resampling_built_for_avx2_gives_the_plain_build_s_bits() {
    let (w, h) = (96, 80);
    let f = white(w * h, 11);
    for g in [[0.01, 0.0], [0.0, -0.01], [0.05, -0.03]] {
        let a = shear_matrix(g);
        let (mut field, mut pass) = (f.clone(), Vec::new());
        resample_t_body(&mut field, w, h, a, &mut pass);
        let plain: Vec<u64> = pass.iter().map(|v| v.to_bits()).collect();
        // The dispatching entry gives the same (AVX2 where the CPU runs it).
        let (mut field, mut pass) = (f.clone(), Vec::new());
        resample_t(&mut field, w, h, a, &mut pass);
        assert!(
            pass.iter().map(|v| v.to_bits()).eq(plain.iter().copied()),
            "{g:?}"
        );
        #[cfg(target_arch = "x86_64")]
        if stepsim_numerics::simd::has_avx2() {
            let (mut field, mut pass) = (f.clone(), Vec::new());
            // SAFETY: the CPU runs AVX2 (checked just above).
            unsafe { resample_t_avx2(&mut field, w, h, a, &mut pass) };
            assert!(
                pass.iter().map(|v| v.to_bits()).eq(plain.iter().copied()),
                "{g:?}"
            );
        }
        assert!(plain.iter().any(|&b| b != 0));
    }
}
