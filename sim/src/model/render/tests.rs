//! Tests of the renderer: flux, moments (shear exactness), the real-space
//! twin, stamp sizing and reproducibility. Tolerances are stated in each
//! test; measured values are in docs/rendering.md.

use super::*;
use crate::model::profile::{ellipticity_of_moments, shear_ellipticity};
use crate::model::psf::GaussianPsf;

const P: f64 = 0.206;
/// Sky σ per pixel of the STEP1 preset (≈ sqrt(8.0e4 e⁻ + 25)).
const SKY_SIGMA: f64 = 283.0;

fn psf() -> Arc<GaussianPsf> {
    Arc::new(GaussianPsf::round(0.9))
}

fn renderer(acc: Accuracy) -> Renderer {
    Renderer::new(psf(), P, acc, SKY_SIGMA)
}

#[allow(clippy::too_many_arguments)]
fn galaxy(
    x: f64,
    y: f64,
    flux: f64,
    bt: f64,
    re: f64,
    bulge_ba: f64,
    h: f64,
    disk_ba: f64,
    pa_deg: f64,
    g: (f64, f64),
) -> TruthRow {
    TruthRow {
        id: 1,
        kind: stepsim_contract::truth::KIND_GALAXY,
        x,
        y,
        flux_e: flux,
        bt,
        bulge_re_arcsec: re,
        bulge_ba,
        disk_h_arcsec: h,
        disk_ba,
        pa_deg,
        g1: g.0,
        g2: g.1,
        ..TruthRow::default()
    }
}

fn star(x: f64, y: f64, flux: f64) -> TruthRow {
    TruthRow {
        id: 2,
        kind: stepsim_contract::truth::KIND_STAR,
        hubble_type: -1,
        x,
        y,
        flux_e: flux,
        ..TruthRow::default()
    }
}

#[test]
fn stamps_hold_the_catalogue_flux() {
    // Tolerance 1e-3 relative (measured: < 1e-6, f32 rounding): the FFT
    // stamp holds the whole flux (light beyond the stamp is folded in).
    let r = renderer(Accuracy::default());
    for row in [
        galaxy(
            50.3,
            40.7,
            2.0e4,
            0.3,
            0.3,
            0.7,
            0.4,
            0.4,
            20.0,
            (0.05, 0.0),
        ),
        galaxy(
            10.0,
            10.5,
            5.0e5,
            1.0,
            0.8,
            0.6,
            0.0,
            1.0,
            120.0,
            (0.0, 0.1),
        ),
        star(7.25, 3.5, 1.0e5),
    ] {
        let s = r.draw(&row);
        assert!(s.nx >= 16 && s.nx == s.ny && s.data.len() == s.nx * s.ny);
        let rel = (s.sum() / row.flux_e - 1.0).abs();
        assert!(rel < 1e-3, "{row:?}: {rel}");
    }
}

/// Flux of the big stamp outside the footprint of the automatic one.
fn flux_outside(r: &Renderer, row: &TruthRow) -> (f64, usize) {
    let small = r.draw(row);
    let (bx0, by0, big) = r.draw_f64_with_side(row, small.nx * 4).unwrap();
    let nb = small.nx * 4;
    let mut outside = 0.0;
    for j in 0..nb {
        for i in 0..nb {
            let (x, y) = (bx0 + i as i64, by0 + j as i64);
            let inside = x >= small.x0
                && x < small.x0 + small.nx as i64
                && y >= small.y0
                && y < small.y0 + small.ny as i64;
            if !inside {
                outside += big[j * nb + i];
            }
        }
    }
    (outside / row.flux_e, small.nx)
}

#[test]
fn stamp_size_keeps_the_folded_flux_below_the_threshold() {
    // At most folding_threshold (5e-3) of the flux falls outside the stamp
    // (measured on a 4× larger stamp).
    let r = renderer(Accuracy::default());
    for row in [
        galaxy(20.0, 20.0, 1.0e3, 1.0, 0.3, 0.9, 0.0, 1.0, 0.0, (0.0, 0.0)),
        galaxy(20.0, 20.0, 1.0e3, 0.0, 0.0, 1.0, 0.5, 0.2, 45.0, (0.1, 0.0)),
        galaxy(20.4, 20.2, 1.0e3, 0.5, 0.2, 0.6, 0.3, 0.5, 10.0, (0.0, 0.0)),
        star(20.0, 20.0, 1.0e3),
    ] {
        let (out, n) = flux_outside(&r, &row);
        assert!(out < 5e-3, "{out} outside a {n}-pixel stamp");
        assert!(out > -1e-6);
    }
}

#[test]
fn stamp_edges_are_fainter_than_a_tenth_of_the_sky_noise() {
    let r = renderer(Accuracy::default());
    for row in [
        galaxy(30.0, 30.0, 3.0e6, 0.5, 0.6, 0.8, 0.8, 0.5, 30.0, (0.0, 0.0)),
        galaxy(30.0, 30.0, 3.0e6, 1.0, 0.6, 0.8, 0.0, 1.0, 30.0, (0.0, 0.0)),
        star(30.0, 30.0, 3.0e7),
    ] {
        let s = r.draw(&row);
        let n = s.nx;
        let mut edge: f64 = 0.0;
        for k in 0..n {
            for v in [
                s.data[k],
                s.data[(n - 1) * n + k],
                s.data[k * n],
                s.data[k * n + n - 1],
            ] {
                edge = edge.max(f64::from(v).abs());
            }
        }
        assert!(edge < 0.1 * SKY_SIGMA, "edge {edge} on a {n}-pixel stamp");
        assert!(n <= 1024);
    }
}

/// Unweighted centred moments (xx, xy, yy) of an n × n stamp, arcsec².
fn pixel_moments(data: &[f64], n: usize) -> [f64; 3] {
    let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for j in 0..n {
        for i in 0..n {
            let v = data[j * n + i];
            s += v;
            sx += v * i as f64;
            sy += v * j as f64;
        }
    }
    let (cx, cy) = (sx / s, sy / s);
    let mut q = [0.0; 3];
    for j in 0..n {
        for i in 0..n {
            let v = data[j * n + i] / s;
            let (dx, dy) = (i as f64 - cx, j as f64 - cy);
            q[0] += v * dx * dx;
            q[1] += v * dx * dy;
            q[2] += v * dy * dy;
        }
    }
    q.map(|x| x * P * P)
}

#[test]
fn sheared_moments_are_galaxy_plus_psf_plus_pixel_and_obey_eq8() {
    // Large stamps (512², double precision) so that the untruncated
    // profiles' second moments are captured; k-space cut off (its effect is
    // measured by the reference comparison). Tolerances: moments 1e-4
    // relative to the trace, galaxy e within 1e-4 of eq. 8 (measured:
    // ≤ 5e-6 of the trace, |Δe| ≤ 3e-6).
    let acc = Accuracy {
        kvalue_threshold: 0.0,
        ..Accuracy::default()
    };
    let r = renderer(acc);
    let sigma = psf().sigma_arcsec();
    let g = (0.1, -0.05);
    // 512² holds all but ~2.5e-5 of a 0.1″ bulge's r² weight; larger
    // stamps are limited by the f32 PSF transfer near k = 0 (1024²: e off by
    // ~1e-4), smaller ones by the bulge's wings (256²: moments off 1.2e-4).
    let n = 512;
    for (bt, re, h) in [(1.0, 0.1, 0.0), (0.0, 0.0, 0.4), (0.4, 0.1, 0.35)] {
        let row = galaxy(500.3, 500.6, 1.0e4, bt, re, 0.7, h, 0.35, 25.0, g);
        let (_, _, data) = r.draw_f64_with_side(&row, n).unwrap();
        let q = pixel_moments(&data, n);
        let gal = Galaxy::from_row(&row).unwrap();
        let qg = gal.moments();
        let add = sigma * sigma + P * P / 12.0;
        let want = [qg[0] + add, qg[1], qg[2] + add];
        let tr = want[0] + want[2];
        for k in 0..3 {
            assert!(
                (q[k] - want[k]).abs() < 1e-4 * tr,
                "bt={bt} k={k}: {} vs {}",
                q[k],
                want[k]
            );
        }
        // Recovered galaxy ellipticity vs eq. 8 applied to the intrinsic one.
        let e = ellipticity_of_moments([q[0] - add, q[1], q[2] - add]);
        let mut unsheared = row;
        unsheared.g1 = 0.0;
        unsheared.g2 = 0.0;
        let e_int = Galaxy::from_row(&unsheared).unwrap().ellipticity();
        let want_e = shear_ellipticity(e_int, g);
        assert!(
            (e.0 - want_e.0).abs() < 1e-4 && (e.1 - want_e.1).abs() < 1e-4,
            "bt={bt}: e {e:?} vs eq. 8 {want_e:?}"
        );
    }
}

/// Max |fast − reference| / peak on the fast stamp's footprint.
fn compare_with_reference(r: &Renderer, row: &TruthRow, side: Option<usize>) -> f64 {
    let s = match side {
        Some(n) => r.draw_with_side(row, n).unwrap(),
        None => r.draw(row),
    };
    let reference = ReferenceRenderer {
        pixel_scale_arcsec: P,
        psf_sigma_arcsec: Some(psf().sigma_arcsec()),
        supersample: 9,
    };
    let want = reference.draw(row, s.x0, s.y0, s.nx, s.ny).unwrap();
    let peak = want.iter().copied().fold(0.0, f64::max);
    s.data
        .iter()
        .zip(&want)
        .map(|(&a, &b)| (f64::from(a) - b).abs())
        .fold(0.0, f64::max)
        / peak
}

/// Rows of the accuracy tests, about (c, c) = (w/2, w/2): shapes and sizes
/// down to 0.1″ at sub-pixel offsets, shear, one galaxy centred 1.7 px left
/// of the image (its light must come in through the margin), and a star.
fn accuracy_rows(w: f64) -> Vec<TruthRow> {
    let c = w / 2.0;
    vec![
        galaxy(
            c + 0.3,
            c - 0.2,
            1.0e4,
            0.0,
            0.0,
            1.0,
            0.3,
            0.5,
            30.0,
            (0.05, 0.02),
        ),
        galaxy(
            c + 0.5,
            c + 0.5,
            1.0e4,
            1.0,
            0.1,
            0.7,
            0.0,
            1.0,
            100.0,
            (0.1, 0.0),
        ),
        galaxy(
            c + 0.1,
            c + 0.45,
            1.0e4,
            0.4,
            0.2,
            0.8,
            0.5,
            0.25,
            170.0,
            (-0.03, 0.07),
        ),
        galaxy(c - 0.23, c, 1.0e4, 0.0, 0.0, 1.0, 0.1, 0.9, 0.0, (0.0, 0.0)),
        galaxy(
            -1.7,
            c + 3.2,
            1.0e4,
            0.3,
            0.4,
            0.6,
            0.8,
            0.4,
            60.0,
            (0.0, 0.05),
        ),
        star(c + 0.25, c + 0.75, 1.0e4),
    ]
}

#[test]
fn fast_renderer_matches_the_real_space_reference() {
    // Shapes, sizes down to 0.1″, sub-pixel offsets, shear; tolerance 1e-3
    // of the peak with the default accuracy and automatic stamps.
    let r = renderer(Accuracy::default());
    let rows = accuracy_rows(60.0);
    for row in &rows {
        let d = compare_with_reference(&r, row, None);
        assert!(d < 1e-3, "{row:?}: max diff {d} of peak");
    }
}

#[test]
fn reference_renderer_conserves_flux() {
    // The slow twin itself: a galaxy well inside its region keeps its flux
    // to 1e-4 (the part beyond the region is the exponential's tail).
    let reference = ReferenceRenderer {
        pixel_scale_arcsec: P,
        psf_sigma_arcsec: Some(0.38),
        supersample: 5,
    };
    let row = galaxy(40.0, 40.0, 1.0, 0.0, 0.0, 1.0, 0.2, 0.5, 10.0, (0.0, 0.0));
    let img = reference.draw(&row, 0, 0, 80, 80).unwrap();
    let sum: f64 = img.iter().sum();
    assert!((sum - 1.0).abs() < 1e-4, "{sum}");
    let s = reference
        .draw(&star(40.5, 40.5, 1.0), 0, 0, 80, 80)
        .unwrap();
    assert!((s.iter().sum::<f64>() - 1.0).abs() < 1e-9);
}

#[test]
fn bad_rows_are_refused_not_drawn() {
    let r = renderer(Accuracy::default());
    let mut row = galaxy(10.0, 10.0, 1.0e3, 0.5, 0.2, 0.0, 0.3, 0.5, 0.0, (0.0, 0.0));
    assert_eq!(r.try_draw(&row).unwrap_err().column, "bulge_ba");
    assert_eq!(r.draw(&row).nx, 0);
    assert!(try_draw_image(&r, &[row], 32, 32).is_err());
    assert!(draw_image(&r, &[row], 32, 32).iter().all(|&v| v == 0.0));
    assert!(draw_image(&r, &[], 0, 7).is_empty());
    row.bulge_ba = 0.5;
    row.x = f64::INFINITY;
    assert_eq!(r.try_draw(&row).unwrap_err().column, "x");
}

fn field(n: usize, w: f64) -> Vec<TruthRow> {
    // A deterministic spread of galaxies and stars, some off the edges.
    (0..n)
        .map(|k| {
            let f = k as f64;
            let x = (f * 37.77).rem_euclid(w + 40.0) - 20.0;
            let y = (f * 71.31).rem_euclid(w + 40.0) - 20.0;
            if k % 7 == 0 {
                star(x, y, 1.0e3 * (1.0 + (f * 0.3).sin().abs() * 100.0))
            } else {
                galaxy(
                    x,
                    y,
                    2.0e3 + 5.0e4 * (f * 0.77).sin().abs(),
                    (f * 0.13).sin().abs(),
                    0.05 + 0.5 * (f * 0.21).cos().abs(),
                    0.3 + 0.7 * (f * 0.5).sin().abs(),
                    0.1 + 0.6 * (f * 0.17).sin().abs(),
                    0.1 + 0.9 * (f * 0.31).cos().abs(),
                    (f * 13.0) % 180.0,
                    (0.05, 0.0),
                )
            }
        })
        .collect()
}

#[test]
fn image_is_bit_identical_at_any_thread_count_and_holds_the_flux() {
    // 5 000 objects: more than two batches of stamps (2 048 each), and a
    // 420 × 380 image is 2 × 2 convolution tiles.
    let r = renderer(Accuracy::default());
    const { assert!(5000 > 2 * image::BATCH) };
    let (w, h) = (420, 380);
    let rows = field(5000, 420.0);
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| draw_image(&r, &rows, w, h))
    };
    let one = run(1);
    let four = run(4);
    assert_eq!(one.len(), (w * h) as usize);
    assert!(
        one.iter()
            .zip(&four)
            .all(|(a, b)| a.to_bits() == b.to_bits())
    );
    // Flux: the image holds each stamp's on-image part (clipping), summed
    // independently here in f64 from whole-PSF stamps, to 1e-5 relative
    // (a dropped batch would cost ~40%).
    let mut want = 0.0;
    for row in &rows {
        let s = r.draw(row);
        for j in 0..s.ny {
            for i in 0..s.nx {
                let (x, y) = (s.x0 + i as i64, s.y0 + j as i64);
                if (0..i64::from(w)).contains(&x) && (0..i64::from(h)).contains(&y) {
                    want += f64::from(s.data[j * s.nx + i]);
                }
            }
        }
    }
    let got: f64 = one.iter().map(|&v| f64::from(v)).sum();
    assert!((got / want - 1.0).abs() < 1e-5, "{got} vs {want}");
}

#[test]
fn rows_are_drawn_galaxies_first_down_the_image_and_in_one_order_whatever_the_calls() {
    // `field` interleaves stars (every 7th row) with galaxies in no order of
    // position; row 599 is put where row 11 is, so two galaxies tie.
    let mut rows = field(600, 300.0);
    rows[599].x = rows[11].x;
    rows[599].y = rows[11].y;
    let order = drawing_order(rows.iter());
    assert_eq!(order.len(), rows.len());
    let index = |r: &TruthRow| rows.iter().position(|q| std::ptr::eq(q, r)).unwrap();
    let key = |r: &TruthRow| (r.is_star(), -r.y, r.x);
    for pair in order.windows(2) {
        let (a, b) = (key(pair[0]), key(pair[1]));
        assert!(
            (!a.0 && b.0) || (a.0 == b.0 && (a.1, a.2) <= (b.1, b.2)),
            "{a:?} before {b:?}"
        );
        if a == b {
            assert!(index(pair[0]) < index(pair[1]), "ties keep the rows' order");
        }
    }
    assert!(order.iter().take_while(|r| !r.is_star()).count() == 600 - 86);
    // Galaxies then stars in two calls: the same bits as all rows at once.
    let r = renderer(Accuracy::default());
    let draw = |calls: &[Option<bool>]| {
        let mut c = Canvas::new(&r, 300, 300);
        for &stars in calls {
            match stars {
                None => c.try_add(&rows).unwrap(),
                Some(stars) => c.try_add_only(&rows, stars).unwrap(),
            }
        }
        c.finish()
    };
    let same = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
    let whole = draw(&[None]);
    assert!(same(&whole, &draw(&[Some(false), Some(true)])));
    // Stars first would be another sum (a check that the order matters
    // here, so the comparison above could fail).
    assert!(!same(&whole, &draw(&[Some(true), Some(false)])));
}

#[test]
fn an_object_is_placed_at_its_fits_position() {
    // A star at FITS (12.0, 7.0) peaks at array index (6, 11); its centroid
    // is the catalogue position to 1e-4 pixel.
    let r = renderer(Accuracy::default());
    let img = draw_image(&r, &[star(12.0, 7.0, 1.0e4)], 40, 30);
    let (imax, _) = img
        .iter()
        .enumerate()
        .fold((0, f32::MIN), |a, (i, &v)| if v > a.1 { (i, v) } else { a });
    assert_eq!((imax % 40, imax / 40), (11, 6));
    let row = galaxy(
        20.3,
        14.8,
        1.0e4,
        0.5,
        0.2,
        0.7,
        0.3,
        0.5,
        40.0,
        (0.05, 0.05),
    );
    let s = r.draw(&row);
    let (mut sx, mut sy, mut st) = (0.0, 0.0, 0.0);
    for j in 0..s.ny {
        for i in 0..s.nx {
            let v = f64::from(s.data[j * s.nx + i]);
            sx += v * (s.x0 + 1 + i as i64) as f64;
            sy += v * (s.y0 + 1 + j as i64) as f64;
            st += v;
        }
    }
    assert!((sx / st - 20.3).abs() < 1e-3 && (sy / st - 14.8).abs() < 1e-3);
}

/// A Gaussian PSF displaced by (dx, dy) arcsec: a complex transfer function
/// T(k) e^{−2πi k·d}, to check the sign conventions of asymmetric PSFs.
#[derive(Debug)]
struct ShiftedPsf {
    inner: GaussianPsf,
    dx: f64,
    dy: f64,
}

impl Psf for ShiftedPsf {
    fn transfer(&self, grid: StampGrid) -> Arc<Vec<num_complex::Complex32>> {
        let t = self.inner.transfer(grid);
        let mut out = Vec::with_capacity(t.len());
        for row in 0..grid.n {
            for col in 0..grid.n_cols() {
                let (u, v) = grid.frequency(row, col);
                let a = -2.0 * std::f64::consts::PI * (u * self.dx + v * self.dy);
                let c = num_complex::Complex32::new(a.cos() as f32, a.sin() as f32);
                out.push(t[row * grid.n_cols() + col] * c);
            }
        }
        Arc::new(out)
    }
    fn radius_enclosing(&self, fraction: f64) -> f64 {
        self.inner.radius_enclosing(fraction) + self.dx.hypot(self.dy)
    }
    fn radius_below(&self, level: f64) -> f64 {
        self.inner.radius_below(level) + self.dx.hypot(self.dy)
    }
}

#[test]
fn a_displaced_psf_moves_the_light_the_right_way() {
    // T e^{−2πi k·d} is the PSF moved by +d: a star's centroid must move by
    // +d / p pixels (to 1e-4 pixel), which fixes the sign conventions of the
    // transfer function, the phase of the position and the FFT.
    let psf = Arc::new(ShiftedPsf {
        inner: GaussianPsf::round(0.9),
        dx: 0.3,
        dy: -0.1,
    });
    let r = Renderer::new(psf, P, Accuracy::default(), SKY_SIGMA);
    let s = r.draw_with_side(&star(40.2, 30.7, 1.0e4), 64).unwrap();
    let (mut sx, mut sy, mut st) = (0.0, 0.0, 0.0);
    for j in 0..s.ny {
        for i in 0..s.nx {
            let v = f64::from(s.data[j * s.nx + i]);
            sx += v * (s.x0 + 1 + i as i64) as f64;
            sy += v * (s.y0 + 1 + j as i64) as f64;
            st += v;
        }
    }
    assert!((sx / st - (40.2 + 0.3 / P)).abs() < 1e-4, "{}", sx / st);
    assert!((sy / st - (30.7 - 0.1 / P)).abs() < 1e-4, "{}", sy / st);
}

#[test]
fn an_elliptical_psf_gives_a_star_its_moments() {
    // Star moments = σ² A⁻² + p²/12 for the elliptical Gaussian
    // exp(−|A x|²/2σ²), within 1e-5 of the trace.
    let (e1, e2) = (0.06, -0.04);
    let g = GaussianPsf::elliptical(0.9, e1, e2);
    let sigma = g.sigma_arcsec();
    let r = Renderer::new(Arc::new(g), P, Accuracy::default(), SKY_SIGMA);
    let (_, _, data) = r.draw_f64_with_side(&star(50.4, 50.1, 1.0), 96).unwrap();
    let q = pixel_moments(&data, 96);
    let a = crate::model::profile::shear_matrix(e1, e2).inverse();
    let c = a.then_after(a).m;
    let want = [
        sigma * sigma * c[0][0] + P * P / 12.0,
        sigma * sigma * c[0][1],
        sigma * sigma * c[1][1] + P * P / 12.0,
    ];
    let tr = want[0] + want[2];
    for k in 0..3 {
        assert!(
            (q[k] - want[k]).abs() < 1e-5 * tr,
            "{k}: {} vs {}",
            q[k],
            want[k]
        );
    }
    // Its ellipticity is the PSF's e.
    let e = ellipticity_of_moments([q[0] - P * P / 12.0, q[1], q[2] - P * P / 12.0]);
    assert!((e.0 - e1).abs() < 1e-5 && (e.1 - e2).abs() < 1e-5, "{e:?}");
}

#[test]
fn accuracy_sets_the_stamps_and_timing_does_not_change_pixels() {
    // (The plan makes an Accuracy from the `render` section: plan.rs's
    // tests check the mapping.)
    let acc = Accuracy {
        folding_threshold: 1e-3,
        kvalue_threshold: 2e-3,
        edge_sky_sigma: 0.5,
        max_stamp_px: 256,
        min_stamp_px: 16,
        method: Method::Stamp,
    };
    assert_eq!(Accuracy::default().method, Method::Split);
    assert_eq!(Accuracy::default().kvalue_threshold, 1e-4);
    // A tighter folding threshold gives a larger stamp; the cap holds.
    let loose = renderer(Accuracy::default());
    let tight = renderer(acc);
    let row = galaxy(20.0, 20.0, 1.0e4, 0.5, 0.3, 0.7, 0.4, 0.5, 0.0, (0.0, 0.0));
    assert!(tight.stamp_side(&row).unwrap() > loose.stamp_side(&row).unwrap());
    let huge = galaxy(20.0, 20.0, 1.0e4, 1.0, 50.0, 0.7, 0.0, 1.0, 0.0, (0.0, 0.0));
    assert_eq!(tight.stamp_side(&huge).unwrap(), 256);
    let (s, t) = loose.draw_timed(&row).unwrap();
    assert_eq!(s, loose.draw(&row));
    assert!(t.kspace_ns > 0 && t.fft_ns > 0);
}

// ---- The split method (PSF factored as L · T/L; see split.rs) ----

fn with_method(psf: Arc<dyn Psf>, method: Method) -> Renderer {
    let acc = Accuracy {
        method,
        ..Accuracy::default()
    };
    Renderer::new(psf, P, acc, SKY_SIGMA)
}

fn step1_psf(name: &str) -> Arc<dyn Psf> {
    let index = crate::model::psf::STEP1_PSFS
        .iter()
        .position(|p| p.0 == name)
        .unwrap();
    crate::model::psf::build(&crate::model::psf::PsfSpec::step1(index, P)).unwrap()
}

/// Max |a − b| over the image, divided by the peak of `b`.
fn max_diff_of_peak(a: &[f32], b: &[f64]) -> f64 {
    let peak = b.iter().copied().fold(0.0, f64::max);
    a.iter()
        .zip(b)
        .map(|(&x, &y)| (f64::from(x) - y).abs())
        .fold(0.0, f64::max)
        / peak
}

#[test]
fn split_images_match_the_real_space_reference() {
    // Gaussian PSF: the split method's image of each object against the slow
    // twin integrated over the whole image; tolerance 1e-4 of the peak
    // (measured ≤ 7.1e-5, docs/rendering.md).
    let r = renderer(Accuracy::default());
    assert_eq!(r.accuracy().method, Method::Split);
    let split = r.split().expect("the default method splits");
    // L is the widest allowed Gaussian (a 0.9″ Gaussian PSF never limits it).
    assert!((split.sigma_l_arcsec() - split::MAX_SIGMA_PX * P).abs() < 1e-12);
    let reference = ReferenceRenderer {
        pixel_scale_arcsec: P,
        psf_sigma_arcsec: Some(psf().sigma_arcsec()),
        supersample: 9,
    };
    let n = 48;
    for row in accuracy_rows(n as f64) {
        let img = draw_image(&r, std::slice::from_ref(&row), n as u32, n as u32);
        let want = reference.draw(&row, 0, 0, n, n).unwrap();
        let d = max_diff_of_peak(&img, &want);
        eprintln!("split vs reference, x = {:.1}: {d:.2e} of the peak", row.x);
        assert!(d < 1e-4, "{row:?}: max diff {d} of peak");
        let (got, exp): (f64, f64) = (img.iter().map(|&v| f64::from(v)).sum(), want.iter().sum());
        assert!((got - exp).abs() < 1e-3 * row.flux_e, "flux {got} vs {exp}");
    }
}

#[test]
fn split_and_stamp_methods_agree_for_the_coma_psf() {
    // STEP1 PSF 1 (optics with spiders, Kolmogorov seeing, coma): each
    // object drawn by the split method against the same object drawn with
    // the whole PSF on one 320-pixel stamp (66″: the PSF's whole support, so
    // nothing is folded); tolerance 1e-4 of the peak (measured ≤ 5.7e-5),
    // flux to 1e-3.
    let psf = step1_psf("coma");
    let split_r = with_method(psf.clone(), Method::Split);
    let whole = with_method(psf, Method::Stamp);
    let n = 64;
    for row in accuracy_rows(n as f64) {
        let img = draw_image(&split_r, std::slice::from_ref(&row), n as u32, n as u32);
        let s = whole.draw_f64_with_side(&row, 320).unwrap();
        let mut want = vec![0.0; n * n];
        for j in 0..320 {
            for i in 0..320 {
                let (x, y) = (s.0 + i as i64, s.1 + j as i64);
                if (0..n as i64).contains(&x) && (0..n as i64).contains(&y) {
                    want[y as usize * n + x as usize] += s.2[j * 320 + i];
                }
            }
        }
        let d = max_diff_of_peak(&img, &want);
        eprintln!(
            "coma split vs whole-PSF stamp, x = {:.1}: {d:.2e} of the peak",
            row.x
        );
        assert!(d < 1e-4, "{row:?}: max diff {d} of peak");
        let (got, exp): (f64, f64) = (img.iter().map(|&v| f64::from(v)).sum(), want.iter().sum());
        assert!((got - exp).abs() < 1e-3 * row.flux_e, "flux {got} vs {exp}");
    }
}

#[test]
fn the_image_kernel_never_amplifies_and_reaches_the_psf_wings() {
    // |T / L| ≤ 1 on the whole tile grid, for a physical and a Gaussian
    // PSF; the margin covers the optical PSF's diffraction spikes (1e-5 of
    // the peak at 13–14″, docs/psf.md).
    for psf in [step1_psf("coma"), step1_psf("none"), psf() as Arc<dyn Psf>] {
        let r = with_method(psf.clone(), Method::Split);
        let s = r.split().unwrap();
        let sig = s.sigma_l_arcsec();
        assert!(sig > 0.5 * P, "σ_L {sig}″");
        // The tile of a full STEP1 image and that of a small one.
        for side in [4096, 64] {
            let n = s.convolver(side, side).tile();
            let grid = StampGrid::new(n, P);
            let t = psf.transfer(grid);
            let mut worst: f64 = 0.0;
            for row in 0..n {
                for col in 0..grid.n_cols() {
                    let (u, v) = grid.frequency(row, col);
                    let l = (-2.0 * (std::f64::consts::PI * sig).powi(2) * (u * u + v * v)).exp();
                    worst = worst.max(f64::from(t[row * grid.n_cols() + col].norm()) / l);
                }
            }
            eprintln!(
                "σ_L {sig:.3}″, margin {} px, image {side}: tile {n}, max |T/L| {worst:.6}",
                s.margin_px()
            );
            assert!(worst <= 1.0 + 1e-6, "max |T/L| {worst}");
        }
        if psf.calibration().is_some() {
            assert!(s.margin_px() as f64 * P > 14.0, "margin {}", s.margin_px());
        }
    }
}

#[test]
fn both_methods_draw_the_same_field() {
    // A field of 900 objects, some off the edges, with the Gaussian PSF, on
    // 2 × 2 convolution tiles: the split and stamp methods agree to 1e-4 of
    // the brightest pixel (measured 6.9e-5).
    let rows = field(900, 420.0);
    let a = draw_image(&with_method(psf(), Method::Split), &rows, 420, 380);
    let b = draw_image(&with_method(psf(), Method::Stamp), &rows, 420, 380);
    let b64: Vec<f64> = b.iter().map(|&v| f64::from(v)).collect();
    let d = max_diff_of_peak(&a, &b64);
    eprintln!("split vs stamp field: {d:.2e} of the peak");
    assert!(d < 1e-4, "{d}");
}

#[test]
fn a_bright_star_shows_its_diffraction_spikes_in_the_image() {
    // STEP1 PSF 0 (spider arms at 0° and 90°): in a split-method image, a
    // bright star's light at 10″ along x and y is several times brighter
    // than on the diagonal at the same radius (the PSF alone: 2.0e-5 vs
    // 7.0e-6 of the peak, docs/psf.md), so the spikes are drawn.
    let r = with_method(step1_psf("none"), Method::Split);
    let n = 160;
    let c = 80.0;
    let img = draw_image(&r, &[star(c + 1.0, c + 1.0, 1.0e9)], n, n);
    let at = |dx: i64, dy: i64| f64::from(img[((80 + dy) * 160 + 80 + dx) as usize]);
    let peak = at(0, 0);
    let k = (10.0 / P).round() as i64; // 49 px
    let kd = (10.0 / P / std::f64::consts::SQRT_2).round() as i64;
    let axis = at(k, 0).min(at(0, k)).min(at(-k, 0)).min(at(0, -k)) / peak;
    let diag = at(kd, kd).max(at(-kd, kd)) / peak;
    eprintln!("star at 10″: axis {axis:.2e}, diagonal {diag:.2e} of the peak");
    assert!(
        axis > 2.5 * diag && axis > 5e-6,
        "axis {axis:e}, diagonal {diag:e}"
    );
}

/// The split and whole-PSF images of one star at (`x`, `y`) on an `n`²
/// image, STEP1 coma PSF, and the difference divided by the peak.
fn star_split_minus_stamp(x: f64, y: f64, n: usize) -> Vec<f64> {
    let psf = step1_psf("coma");
    let split_r = with_method(psf.clone(), Method::Split);
    let whole = with_method(psf, Method::Stamp);
    let row = star(x, y, 1.0e4);
    let img = draw_image(&split_r, std::slice::from_ref(&row), n as u32, n as u32);
    let s = whole.draw_f64_with_side(&row, 320).unwrap();
    let mut want = vec![0.0; n * n];
    for j in 0..320 {
        for i in 0..320 {
            let (px, py) = (s.0 + i as i64, s.1 + j as i64);
            if (0..n as i64).contains(&px) && (0..n as i64).contains(&py) {
                want[py as usize * n + px as usize] += s.2[j * 320 + i];
            }
        }
    }
    let peak = want.iter().copied().fold(0.0, f64::max);
    img.iter()
        .zip(&want)
        .map(|(&a, &b)| (f64::from(a) - b) / peak)
        .collect()
}

#[test]
fn split_stars_have_no_nyquist_lobes() {
    // The stamps of the split method are drawn with the narrow Gaussian L
    // (σ = 1 px), whose transfer is still 4.6e-3 at Nyquist. Zeroing the
    // Nyquist row and column of the stamps left lobes of alternating sign
    // along the stamp's edges, ±2.8e-4 of the peak about 8 px either side of
    // every star. Measured here: the largest difference to the whole-PSF
    // stamp between 4 and 16 px from the star (sub-pixel offsets), and
    // anywhere on the image: ≤ 7.2e-5 of the peak (2.2e-4 before the fix).
    // What is left is smooth, not alternating: the stamp holds the
    // band-limited image of star ⊗ L ⊗ pixel, whose tails the stamp's edge
    // cuts off (docs/rendering.md).
    let n = 64;
    for (dx, dy) in [(0.25, 0.75), (0.0, 0.0), (0.5, 0.5), (0.37, -0.12)] {
        let (x, y) = (33.0 + dx, 33.0 + dy);
        let d = star_split_minus_stamp(x, y, n);
        let mut ring: f64 = 0.0;
        for (k, v) in d.iter().enumerate() {
            let (px, py) = ((k % n) as f64 + 1.0, (k / n) as f64 + 1.0);
            let r = (px - x).abs().max((py - y).abs());
            if (4.0..=16.0).contains(&r) {
                ring = ring.max(v.abs());
            }
        }
        let all = d.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
        eprintln!("star at ({x}, {y}): lobes {ring:.2e}, anywhere {all:.2e} of the peak");
        assert!(ring < 1e-4, "lobes {ring:e} of the peak");
        assert!(all < 1e-4, "max difference {all:e} of the peak");
    }
}

#[test]
fn column_passes_fill_kspace_exactly_as_the_cell_by_cell_twin() {
    use realfft::num_complex::Complex;
    // Bulge + disk, pure bulge, pure disk, sheared, off-centre, tiny and
    // large, and a star; odd sizes are made even by fill_for.
    let r = renderer(Accuracy::default());
    let rows = [
        galaxy(
            40.3,
            41.7,
            2e5,
            0.4,
            0.5,
            0.7,
            0.8,
            0.4,
            30.0,
            (0.05, -0.03),
        ),
        galaxy(10.0, 12.9, 1e4, 1.0, 0.2, 0.9, 0.0, 1.0, 0.0, (0.0, 0.0)),
        galaxy(
            7.77,
            3.21,
            5e5,
            0.0,
            0.0,
            1.0,
            2.5,
            0.2,
            123.0,
            (-0.02, 0.04),
        ),
        galaxy(
            100.5,
            99.5,
            3e3,
            0.2,
            0.05,
            0.5,
            0.1,
            0.6,
            77.0,
            (0.01, 0.01),
        ),
        star(20.2, 30.9, 1e6),
    ];
    let cut_renderer = renderer(Accuracy {
        kvalue_threshold: 0.05, // cuts many cells of these stamps
        ..Accuracy::default()
    });
    // No cut: the Nyquist cells' amplitudes (taken from the column's where
    // they apply) are used even where the PSF's transfer is tiny.
    let uncut_renderer = renderer(Accuracy {
        kvalue_threshold: 0.0,
        ..Accuracy::default()
    });
    // A narrow, elliptical and displaced PSF: a complex transfer whose
    // size differs between rows v and −v, large enough at Nyquist for
    // thresholds to cut one term of a Nyquist cell and keep the other.
    let asymmetric = |threshold| {
        let psf = ShiftedPsf {
            inner: GaussianPsf::elliptical(0.35, 0.2, -0.15),
            dx: 0.05,
            dy: -0.08,
        };
        let acc = Accuracy {
            kvalue_threshold: threshold,
            ..Accuracy::default()
        };
        Renderer::new(Arc::new(psf), P, acc, SKY_SIGMA)
    };
    let asymmetric: Vec<Renderer> = [0.0, 1e-3, 1e-2, 0.05].map(asymmetric).into();
    let mut compared = 0;
    // Working arrays kept from stamp to stamp, as the engine keeps them
    // (stale values of other sides; the grids start as NaN, so a cell the
    // fill did not write would show).
    let (mut kept_fast, mut kept_plain) =
        (stamp::FillScratch::default(), stamp::FillScratch::default());
    let renderers = [&r, &cut_renderer, &uncut_renderer]
        .into_iter()
        .chain(&asymmetric);
    for rr in renderers {
        for row in &rows {
            for n in [64, 16, 34, 4, 2] {
                let fill = rr.fill_for(row, n).unwrap();
                let grid = StampGrid::new(fill.n, P);
                let t = rr.psf.transfer(grid);
                let sinc = FftCache::<f32>::default().sinc(fill.n);
                let len = (fill.n / 2 + 1) * fill.n;
                let junk = Complex::<f32>::new(f32::NAN, f32::NAN);
                let (mut fast, mut fresh, mut slow) =
                    (vec![junk; len], vec![junk; len], vec![junk; len]);
                let cols = stamp::Columns::new(&t, &sinc, fill.n);
                // As dispatched (the AVX2 build where the CPU has it) and
                // in the plain build, each with the transfer's columns
                // computed in the fill and given ready; with fresh arrays;
                // and the twin.
                let mut builds = Vec::new();
                for c in [None, Some(&cols)] {
                    let mut a = vec![junk; len];
                    stamp::fill_kspace_in(&fill, &t, c, &sinc, &mut a, &mut kept_fast);
                    let mut p = vec![junk; len];
                    stamp::fill_kspace_body(&fill, &t, c, &sinc, &mut p, &mut kept_plain);
                    builds.extend([a, p]);
                }
                stamp::fill_kspace_in(&fill, &t, None, &sinc, &mut fast, &mut kept_fast);
                stamp::fill_kspace(&fill, &t, &sinc, &mut fresh);
                stamp::fill_kspace_slow(&fill, &t, &sinc, &mut slow);
                assert!(fresh.iter().zip(&fast).all(|(x, y)| x == y));
                for (v, build) in builds.iter().enumerate() {
                    for (k, (a, b)) in build.iter().zip(&slow).enumerate() {
                        assert!(
                            a.re.to_bits() == b.re.to_bits() && a.im.to_bits() == b.im.to_bits(),
                            "row {} n {n} build {v} cell {k}: {a} vs {b}",
                            row.x
                        );
                    }
                }
                compared += len;
            }
        }
    }
    assert!(compared > 20_000, "{compared}");
}
