//! The truth table and the renderer agree (issue #4, shear exactness): real
//! galaxies of the Stuff-style population, sheared by `population::sheared`,
//! drawn noise-free through a Gaussian PSF on a large stamp, have unweighted
//! second moments whose eq.-1 ellipticity, after removing the PSF's and the
//! pixel's moments, equals the truth table's sheared `e1`, `e2` within 1e-4.
//!
//! This ties two independent pieces together: the population's analytic
//! moments (sizes along the major axis, ⟨r²⟩ of the de Vaucouleurs and
//! exponential profiles) and the renderer's Fourier-space drawing.

use std::path::Path;
use std::sync::Arc;
use stepsim_sim::Plan;
use stepsim_sim::model::psf::GaussianPsf;
use stepsim_sim::model::render::{Accuracy, Renderer};

/// Centroid-subtracted second moments (xx, xy, yy) of a stamp, in pixels².
fn pixel_moments(data: &[f64], n: usize) -> [f64; 3] {
    let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for (i, v) in data.iter().enumerate() {
        let (x, y) = ((i % n) as f64, (i / n) as f64);
        s += v;
        sx += v * x;
        sy += v * y;
    }
    let (cx, cy) = (sx / s, sy / s);
    let mut q = [0.0; 3];
    for (i, v) in data.iter().enumerate() {
        let (dx, dy) = ((i % n) as f64 - cx, (i / n) as f64 - cy);
        q[0] += v * dx * dx;
        q[1] += v * dx * dy;
        q[2] += v * dy * dy;
    }
    q.map(|m| m / s)
}

#[test]
fn drawn_population_galaxies_have_their_truth_ellipticity() {
    let plan = Plan::from_json(
        "{}",
        Path::new("t.json"),
        &[
            "run.seed=20060101",
            "image.width_px=1024",
            "image.height_px=1024",
        ],
    )
    .unwrap();
    let base = stepsim_sim::model::population::base_field(&plan.population(), 0).unwrap();
    let (g1, g2) = (0.05, -0.03);
    let rows = stepsim_sim::model::population::sheared(&base, g1, g2);
    // Compact galaxies (the 512² stamp holds their second moments) of three
    // kinds: bulge-dominated, disk-dominated and mixed.
    let compact = |r: &&stepsim_contract::truth::TruthRow| {
        !r.is_star() && r.bulge_re_arcsec < 0.15 && r.disk_h_arcsec < 0.4
    };
    let pick = |lo: f64, hi: f64| {
        rows.iter()
            .filter(compact)
            .filter(|r| r.bt >= lo && r.bt <= hi && r.e1.hypot(r.e2) > 0.1)
            .take(2)
            .copied()
            .collect::<Vec<_>>()
    };
    let chosen: Vec<_> = [pick(0.8, 1.0), pick(0.0, 0.1), pick(0.3, 0.7)].concat();
    assert!(
        chosen.len() >= 5,
        "population has too few compact galaxies: {}",
        chosen.len()
    );

    let p = plan.geometry().pixel_scale_arcsec;
    let psf = Arc::new(GaussianPsf::round(0.9));
    let sigma_px = psf.sigma_arcsec() / p;
    // No k-space cut: the comparison is with untruncated analytic moments.
    let acc = Accuracy {
        kvalue_threshold: 0.0,
        ..Accuracy::default()
    };
    let renderer = Renderer::new(psf, p, acc, 0.0);
    let n = 512;
    for mut row in chosen {
        row.x = 256.3;
        row.y = 256.6;
        let (_, _, data) = renderer.draw_f64_with_side(&row, n).unwrap();
        let q = pixel_moments(&data, n);
        let add = sigma_px * sigma_px + 1.0 / 12.0;
        let m = stepsim_contract::shear::Moments {
            xx: q[0] - add,
            xy: q[1],
            yy: q[2] - add,
        };
        let e = m.ellipticity();
        let (de1, de2) = (e.re - row.e1, e.im - row.e2);
        eprintln!(
            "id {} bt {:.2} re {:.3}″ h {:.3}″: truth e ({:+.5}, {:+.5}), drawn Δe ({de1:+.1e}, {de2:+.1e})",
            row.id, row.bt, row.bulge_re_arcsec, row.disk_h_arcsec, row.e1, row.e2
        );
        assert!(
            de1.abs() < 1e-4 && de2.abs() < 1e-4,
            "id {}: Δe = ({de1}, {de2})",
            row.id
        );
    }
}
