//! Validation of the population against the STEP1/SPEC §2 claims.

use super::*;
use crate::model::population::stars::mag_cdf;
use crate::run::plan::Plan;
use std::path::Path;
use std::sync::Mutex;
use stepsim_numerics::stats::{ks_p_value, ks_statistic, median};

/// The defaults with a fixed seed (so that the tests are reproducible), then
/// `overrides`.
fn plan_with(overrides: &[&str]) -> Plan {
    let o: Vec<&str> = std::iter::once("run.seed=20060101")
        .chain(overrides.iter().copied())
        .collect();
    Plan::from_json("{}", Path::new("t.json"), &o).unwrap()
}

/// A wide field (8192² pixels of 0.206″ plus margin, ≈ 800 arcmin²) down to
/// I = 24.5: about 30 000 galaxies, the sample for the statistical tests.
fn wide_plan() -> Plan {
    plan_with(&[
        "image.width_px=8192",
        "image.height_px=8192",
        "population.galaxies.mag_faint=24.5",
    ])
}

fn galaxies_of(rows: &[TruthRow]) -> Vec<TruthRow> {
    rows.iter().filter(|r| !r.is_star()).copied().collect()
}

/// Least-squares slope of log10 counts in 0.5-mag bins over [lo, hi)
/// (galaxy counts here, star counts in `stars.rs`).
pub(crate) fn count_slope(mags: &[f64], lo: f64, hi: f64) -> f64 {
    let nb = ((hi - lo) / 0.5).round() as usize;
    let mut counts = vec![0usize; nb];
    for &m in mags {
        if m >= lo && m < hi {
            counts[((m - lo) / 0.5) as usize] += 1;
        }
    }
    let pts: Vec<(f64, f64)> = counts
        .iter()
        .enumerate()
        .map(|(i, &c)| (lo + (i as f64 + 0.5) * 0.5, (c.max(1) as f64).log10()))
        .collect();
    let n = pts.len() as f64;
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / n;
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    sxy / sxx
}

#[test]
fn galaxy_counts_match_the_deep_field_counts() {
    let plan = wide_plan();
    let area = plan.placement_area().area_arcmin2;
    let gals = galaxies_of(&base_field(&plan.population(), 0).unwrap());
    let mags: Vec<f64> = gals.iter().map(|r| r.mag).collect();
    let slope = count_slope(&mags, 20.0, 24.0);
    assert!((0.30..=0.36).contains(&slope), "slope {slope}");
    let n = mags.iter().filter(|&&m| m < 23.55).count() as f64 / area;
    assert!(
        (20.0..=40.0).contains(&n),
        "{n} galaxies/arcmin² with I < 23.55"
    );
    assert!(mags.iter().all(|&m| (17.0..=24.5).contains(&m)));
    // Every type is present and late types dominate the faint counts.
    for t in 0..6 {
        assert!(gals.iter().any(|r| r.hubble_type == t), "type {t}");
    }
    let faint_irr = gals
        .iter()
        .filter(|r| r.mag > 23.5 && r.hubble_type == 5)
        .count();
    let faint = gals.iter().filter(|r| r.mag > 23.5).count();
    assert!(faint_irr * 3 > faint, "{faint_irr} of {faint}");
}

#[test]
fn sizes_decrease_with_magnitude() {
    let gals = galaxies_of(&base_field(&wide_plan().population(), 1).unwrap());
    let mut last = (f64::INFINITY, f64::INFINITY);
    for lo in [19.0, 20.0, 21.0, 22.0, 23.0, 24.0] {
        let bin: Vec<&TruthRow> = gals
            .iter()
            .filter(|r| r.mag >= lo && r.mag < lo + 0.5)
            .collect();
        let mut disks: Vec<f64> = bin
            .iter()
            .filter(|r| r.bt < 1.0)
            .map(|r| r.disk_h_arcsec)
            .collect();
        let mut bulges: Vec<f64> = bin
            .iter()
            .filter(|r| r.bt > 0.0)
            .map(|r| r.bulge_re_arcsec)
            .collect();
        let (disk, bulge) = (median(&mut disks).unwrap(), median(&mut bulges).unwrap());
        assert!(disk < last.0 && bulge < last.1, "I = {lo}: {disk} {bulge}");
        last = (disk, bulge);
    }
    // Median disk scale length near I ≈ 24 is of order 0.2″.
    assert!(
        (0.15..=0.3).contains(&last.0),
        "median h at I≈24: {}",
        last.0
    );
}

#[test]
fn star_counts_have_the_configured_slope_and_density() {
    let plan = plan_with(&["population.stars.density_per_arcmin2=400"]);
    let area = plan.placement_area().area_arcmin2;
    let rows = base_field(&plan.population(), 0).unwrap();
    let stars: Vec<f64> = rows.iter().filter(|r| r.is_star()).map(|r| r.mag).collect();
    // Poisson mean 400 × area ≈ 80 000: within 5σ.
    let want = 400.0 * area;
    assert!((stars.len() as f64 - want).abs() < 5.0 * want.sqrt());
    let slope = count_slope(&stars, 17.0, 25.0);
    assert!((slope - 0.30).abs() < 0.02, "{slope}");
    let s = plan.stars();
    let d = ks_statistic(&stars, |m| mag_cdf(s, m));
    assert!(ks_p_value(d, stars.len()) > 1e-3, "D = {d}");
}

#[test]
fn base_field_rows_are_consistent() {
    let plan = plan_with(&["image.width_px=2048", "image.height_px=2048"]);
    let rows = base_field(&plan.population(), 3).unwrap();
    assert!(rows.len() > 1000);
    let Placement {
        x_px: xr, y_px: yr, ..
    } = plan.placement_area();
    let wcs = plan.image_wcs();
    let ins = &plan.instrument();
    for (i, r) in rows.iter().enumerate() {
        assert_eq!(r.id, i as i64 + 1);
        assert!(r.x >= xr.0 && r.x <= xr.1 && r.y >= yr.0 && r.y <= yr.1);
        let (ra, dec) = wcs.pixel_to_sky(r.x, r.y);
        assert_eq!((r.ra_deg, r.dec_deg), (ra, dec));
        assert!((r.flux_e / ins.mag_to_electrons(r.mag) - 1.0).abs() < 1e-12);
        assert_eq!((r.g1, r.g2), (0.0, 0.0));
        if r.is_star() {
            assert_eq!(r.hubble_type, -1);
            let zero = TruthRow {
                id: r.id,
                kind: r.kind,
                hubble_type: -1,
                x: r.x,
                y: r.y,
                ra_deg: r.ra_deg,
                dec_deg: r.dec_deg,
                mag: r.mag,
                flux_e: r.flux_e,
                ..TruthRow::default()
            };
            assert_eq!(*r, zero);
            continue;
        }
        assert!((0..6).contains(&r.hubble_type));
        assert!((0.0..=1.0).contains(&r.bt) && r.z > 0.0);
        assert_eq!(r.bulge_re_arcsec > 0.0, r.hubble_type != 5);
        assert_eq!(r.disk_h_arcsec > 0.0, r.hubble_type != 0);
        // Axis-ratio formulas hold exactly per object.
        let (si, ci) = r.incl_deg.to_radians().sin_cos();
        assert!((r.disk_ba - ci).abs() < 1e-12);
        let b = (r.bulge_flat_q.powi(2) * si * si + ci * ci).sqrt();
        assert!((r.bulge_ba - b).abs() < 1e-12);
        assert!((0.3..=1.0).contains(&r.bulge_flat_q) && r.incl_deg <= 85.0);
        assert!((0.0..180.0).contains(&r.pa_deg));
        // Unsheared: sheared columns equal the intrinsic ones.
        assert_eq!((r.e1, r.e2), (r.e1_int, r.e2_int));
        assert_eq!((r.bulge_e1, r.bulge_e2), (r.bulge_e1_int, r.bulge_e2_int));
        assert_eq!((r.disk_e1, r.disk_e2), (r.disk_e1_int, r.disk_e2_int));
        let ed = shear::ellipticity(r.disk_ba, r.pa_deg.to_radians());
        assert!((ed.re - r.disk_e1_int).abs() < 1e-15 && (ed.im - r.disk_e2_int).abs() < 1e-15);
        // The whole-galaxy ellipticity lies between those of its parts
        // (all share one angle, so e is real after rotating by −2θ).
        let rot = Complex64::from_polar(1.0, -2.0 * r.pa_deg.to_radians());
        let (eb, ed, e) = (
            (Complex64::new(r.bulge_e1_int, r.bulge_e2_int) * rot).re,
            (Complex64::new(r.disk_e1_int, r.disk_e2_int) * rot).re,
            (Complex64::new(r.e1_int, r.e2_int) * rot).re,
        );
        assert!(
            e >= eb.min(ed) - 1e-12 && e <= eb.max(ed) + 1e-12,
            "{eb} {ed} {e}"
        );
    }
}

#[test]
fn same_seed_same_field_other_seed_or_field_differs() {
    let plan = plan_with(&["image.width_px=1024", "image.height_px=1024"]);
    let a = base_field(&plan.population(), 0).unwrap();
    assert_eq!(a, base_field(&plan.population(), 0).unwrap());
    assert_ne!(a, base_field(&plan.population(), 1).unwrap());
    let other = plan_with(&["image.width_px=1024", "image.height_px=1024", "run.seed=7"]);
    assert_ne!(a, base_field(&other.population(), 0).unwrap());
    // The shear, the PSFs and the noise do not enter the base field.
    let psf = plan_with(&[
        "image.width_px=1024",
        "image.height_px=1024",
        "shears.0.g1=0.03",
        "render.folding_threshold=0.01",
    ]);
    assert_eq!(a, base_field(&psf.population(), 0).unwrap());
}

#[test]
fn sheared_view_obeys_eq8_and_recovers_the_shear() {
    let plan = plan_with(&[
        "image.width_px=8192",
        "image.height_px=8192",
        "population.galaxies.mag_faint=23.5",
    ]);
    let base = base_field(&plan.population(), 2).unwrap();
    let (g1, g2) = (0.05, -0.02);
    let g = Complex64::new(g1, g2);
    let view = sheared(&base, g1, g2);
    assert_eq!(view.len(), base.len());
    let mut sum = (Complex64::default(), Complex64::default());
    let mut var = 0.0;
    let mut n = 0.0;
    for (b, s) in base.iter().zip(&view) {
        assert_eq!((s.g1, s.g2), (g1, g2));
        assert_eq!(
            (s.x, s.y, s.flux_e, s.mag, s.pa_deg),
            (b.x, b.y, b.flux_e, b.mag, b.pa_deg)
        );
        if b.is_star() {
            assert_eq!(
                TruthRow {
                    g1: 0.0,
                    g2: 0.0,
                    ..*s
                },
                *b
            );
            continue;
        }
        assert_eq!((s.e1_int, s.e2_int), (b.e1_int, b.e2_int));
        let e_int = Complex64::new(b.e1_int, b.e2_int);
        let e = Complex64::new(s.e1, s.e2);
        assert!((e - shear::apply_shear(e_int, g)).norm() < 1e-12);
        for (ei, es) in [
            ((b.bulge_e1_int, b.bulge_e2_int), (s.bulge_e1, s.bulge_e2)),
            ((b.disk_e1_int, b.disk_e2_int), (s.disk_e1, s.disk_e2)),
        ] {
            let want = shear::apply_shear(Complex64::new(ei.0, ei.1), g);
            assert!((Complex64::new(es.0, es.1) - want).norm() < 1e-14);
        }
        sum.0 += e_int;
        sum.1 += e;
        var += e_int.norm_sqr() / 2.0;
        n += 1.0;
    }
    // ⟨e⟩ = g for an isotropic population (Seitz & Schneider 1997), and the
    // intrinsic mean is zero, each within 4σ of shape noise.
    let sigma = (var / n).sqrt() / n.sqrt();
    let (m_int, m) = (sum.0 / n, sum.1 / n);
    assert!(
        m_int.re.abs() < 4.0 * sigma && m_int.im.abs() < 4.0 * sigma,
        "{m_int} σ={sigma}"
    );
    assert!(
        (m - g).re.abs() < 4.0 * sigma && (m - g).im.abs() < 4.0 * sigma,
        "{m} σ={sigma}"
    );
}

#[test]
fn rotated_twin_cancels_intrinsic_shapes() {
    let plan = plan_with(&["image.width_px=1024", "image.height_px=1024"]);
    let base = base_field(&plan.population(), 0).unwrap();
    let rot = rotated(&base);
    let g = Complex64::new(0.1, 0.0);
    let (sa, sb) = (sheared(&base, 0.1, 0.0), sheared(&rot, 0.1, 0.0));
    for ((b, r), (x, y)) in base.iter().zip(&rot).zip(sa.iter().zip(&sb)) {
        assert_eq!((b.id, b.x, b.y, b.flux_e), (r.id, r.x, r.y, r.flux_e));
        if b.is_star() {
            assert_eq!(b, r);
            continue;
        }
        let d = (r.pa_deg - b.pa_deg).rem_euclid(180.0);
        assert!((d - 90.0).abs() < 1e-9);
        for (u, v) in [
            ((b.e1_int, b.e2_int), (r.e1_int, r.e2_int)),
            (
                (b.bulge_e1_int, b.bulge_e2_int),
                (r.bulge_e1_int, r.bulge_e2_int),
            ),
            (
                (b.disk_e1_int, b.disk_e2_int),
                (r.disk_e1_int, r.disk_e2_int),
            ),
        ] {
            assert!((u.0 + v.0).abs() < 1e-12 && (u.1 + v.1).abs() < 1e-12);
        }
        // Sheared twins: each obeys eq. 8 from its own intrinsic shape.
        let want = shear::apply_shear(Complex64::new(r.e1_int, r.e2_int), g);
        assert!((Complex64::new(y.e1, y.e2) - want).norm() < 1e-12);
        assert_eq!((x.g1, y.g1), (0.1, 0.1));
    }
    // Rotating twice is the identity (up to rounding of the angle).
    let back = rotated(&rot);
    for (a, b) in base.iter().zip(&back) {
        assert!((a.pa_deg - b.pa_deg).abs() < 1e-9 && (a.e1 - b.e1).abs() < 1e-12);
    }
}

/// Σ over the galaxies within 20 px of each galaxy of flux × e^{2iφ}, φ
/// the direction from the galaxy to the neighbour: a spin-2 quantity of
/// the scene that turns with the positions, not with the shapes.
fn neighbour_directions(rows: &[TruthRow]) -> Vec<Complex64> {
    let g = galaxies_of(rows);
    g.iter()
        .map(|a| {
            g.iter()
                .filter(|b| b.id != a.id && (b.x - a.x).hypot(b.y - a.y) < 20.0)
                .map(|b| {
                    let phi = (b.y - a.y).atan2(b.x - a.x);
                    b.flux_e * Complex64::from_polar(1.0, 2.0 * phi)
                })
                .sum()
        })
        .collect()
}

#[test]
fn the_turned_twin_changes_the_sign_of_shapes_and_of_neighbour_directions() {
    let common = [
        "image.width_px=600",
        "image.height_px=600",
        "population.rotated_pairs=true",
        "population.lens_positions=true",
        "shears=[{\"g1\":0.04,\"g2\":-0.02}]",
    ];
    let turned = plan_with(&[&common[..], &["population.rotate_positions=true"]].concat());
    let spec = turned.population();
    let base = base_field(&spec, 0).unwrap();
    let tw = twin(&spec, &base);
    let (cx, cy) = spec.lensing_centre;
    assert_eq!((cx, cy), (300.5, 300.5));
    for (b, t) in base.iter().zip(&tw) {
        assert_eq!((b.id, b.flux_e, b.kind), (t.id, t.flux_e, t.kind));
        // (x, y) → (c − (y − c), c + (x − c)), stars too.
        assert_eq!((t.x, t.y), (cx - (b.y - cy), cy + (b.x - cx)));
        assert_eq!((t.ra_deg, t.dec_deg), spec.wcs.pixel_to_sky(t.x, t.y));
        if !b.is_star() {
            assert!((b.e1_int + t.e1_int).abs() < 1e-12 && (b.e2_int + t.e2_int).abs() < 1e-12);
        }
    }
    // The directions to the neighbours change sign with the shapes (a 180°
    // turn, or none, would keep them).
    let (nb, nt) = (neighbour_directions(&base), neighbour_directions(&tw));
    let scale: f64 = nb.iter().map(|z| z.norm()).sum();
    assert!(scale > 0.0 && nb.iter().filter(|z| z.norm() > 0.0).count() > 100);
    for (a, b) in nb.iter().zip(&nt) {
        assert!((a + b).norm() < 1e-9 * scale, "{a} {b}");
    }
    // Four turns are the identity.
    let back = (0..3).fold(tw.clone(), |r, _| turned_positions(&spec, &r));
    for (a, b) in base.iter().zip(&back) {
        assert!((a.x - b.x).abs() < 1e-9 && (a.y - b.y).abs() < 1e-9);
    }
    // The source area is square, so that the turned twin covers the image
    // for the run's shears as the field does.
    let area = galaxy_placement_area(&spec);
    assert_eq!(
        area.x_px.1 - area.x_px.0,
        area.y_px.1 - area.y_px.0,
        "{area:?}"
    );
    // Without the option the twin is `rotated`, positions kept.
    let kept = plan_with(&common).population();
    assert_eq!(twin(&kept, &base), rotated(&base));
    let plain = galaxy_placement_area(&kept);
    assert!(plain.x_px.1 - plain.x_px.0 != plain.y_px.1 - plain.y_px.0);
}

#[test]
fn whole_galaxy_moments_are_flux_weighted_sums() {
    // A pure disk of h = 1″ at β = 0.5, θ = 0: σ² = 3, Q = diag(3, 0.75).
    let r = TruthRow {
        kind: KIND_GALAXY,
        bt: 0.0,
        disk_h_arcsec: 1.0,
        disk_ba: 0.5,
        bulge_ba: 0.9,
        bulge_re_arcsec: 0.0,
        ..TruthRow::default()
    };
    let q = galaxy_moments(&r);
    assert!((q.xx - 3.0).abs() < 1e-12 && (q.yy - 0.75).abs() < 1e-12 && q.xy.abs() < 1e-15);
    // Half bulge (r_e = 1, round), half disk: 0.5·10.8397·I + 0.5·Q_disk.
    let r = TruthRow {
        bt: 0.5,
        bulge_re_arcsec: 1.0,
        bulge_ba: 1.0,
        ..r
    };
    let q = galaxy_moments(&r);
    let sb = 0.5 * crate::model::profile::sersic::devaucouleurs_r2_over_re2();
    assert!((q.xx - (0.5 * sb + 1.5)).abs() < 1e-12);
    assert!((q.yy - (0.5 * sb + 0.375)).abs() < 1e-12);
    let mut row = r;
    fill_ellipticities(&mut row);
    let want = (q.xx.sqrt() - q.yy.sqrt()) / (q.xx.sqrt() + q.yy.sqrt());
    assert!((row.e1_int - want).abs() < 1e-12 && row.e2_int.abs() < 1e-15);
}

#[test]
fn skymaker_round_trip_through_the_config_source() {
    let dir = tempfile::tempdir().unwrap();
    let plan = plan_with(&["image.width_px=1024", "image.height_px=1024"]);
    let t_types = crate::model::population::t_types(&plan.population());
    let mut fields = Vec::new();
    for f in 0..2 {
        let rows = base_field(&plan.population(), f).unwrap();
        crate::io::skymaker::write_list(&dir.path().join(format!("f{f}.list")), &rows, &t_types)
            .unwrap();
        fields.push(rows);
    }
    let pattern = dir.path().join("f{field}.list");
    let src = format!(
        "population.source={{\"skymaker_list\": {{\"path\": {:?}}}}}",
        pattern.to_str().unwrap()
    );
    let list_plan = plan_with(&[
        "image.width_px=1024",
        "image.height_px=1024",
        "image.n_images=2",
        &src,
    ]);
    for (f, want) in fields.iter().enumerate() {
        let got = base_field(&list_plan.population(), f as u32).unwrap();
        assert_eq!(got.len(), want.len());
        for (a, b) in got.iter().zip(want) {
            assert_eq!((a.id, a.kind, a.hubble_type), (b.id, b.kind, b.hubble_type));
            assert_eq!(
                (a.x, a.y, a.mag, a.flux_e, a.z, a.bt),
                (b.x, b.y, b.mag, b.flux_e, b.z, b.bt)
            );
            assert_eq!(
                (a.bulge_re_arcsec, a.disk_h_arcsec),
                (b.bulge_re_arcsec, b.disk_h_arcsec)
            );
            assert_eq!(
                (a.bulge_ba, a.disk_ba, a.pa_deg),
                (b.bulge_ba, b.disk_ba, b.pa_deg)
            );
            assert!(
                (a.incl_deg - b.incl_deg).abs() < 1e-6,
                "{} {}",
                a.incl_deg,
                b.incl_deg
            );
            if !a.is_star() && b.incl_deg > 5.0 {
                assert!((a.bulge_flat_q - b.bulge_flat_q).abs() < 1e-6);
            }
            assert!((a.e1 - b.e1).abs() < 1e-12 && (a.e2 - b.e2).abs() < 1e-12);
        }
    }
    // A field beyond the plan's has no list.
    let err = base_field(&list_plan.population(), 5)
        .unwrap_err()
        .to_string();
    assert_eq!(
        err,
        "no SkyMaker list for base field 5: the plan has 2 base fields"
    );
}

#[test]
fn absurd_depth_is_refused_not_attempted() {
    // 65536² pixels: ≈ 9e6 galaxies expected, over the 2e6 limit.
    let plan = plan_with(&["image.width_px=65536", "image.height_px=65536"]);
    let err = base_field(&plan.population(), 0).unwrap_err().to_string();
    assert!(err.contains("population.galaxies.mag_faint"), "{err}");
}

#[test]
fn inclinations_follow_the_law_unless_extinction_selects_face_on_disks() {
    let flat = |i: f64| (i / 85.0).clamp(0.0, 1.0);
    // Without disk extinction the magnitude window does not depend on i:
    // the field's inclinations follow the drawn law.
    let mut o = vec![
        "image.width_px=4096",
        "image.height_px=4096",
        "population.galaxies.mag_faint=24.5",
    ];
    let keys: Vec<String> = (0..6)
        .map(|t| format!("population.galaxies.types.{t}.disk_extinction=0"))
        .collect();
    o.extend(keys.iter().map(String::as_str));
    let gals = galaxies_of(&base_field(&plan_with(&o).population(), 0).unwrap());
    let i: Vec<f64> = gals.iter().map(|r| r.incl_deg).collect();
    let d = ks_statistic(&i, flat);
    assert!(ks_p_value(d, i.len()) > 1e-3, "D = {d} (n = {})", i.len());
    // With it (the default), inclined disks are dimmer and fewer of them
    // pass the window: the selected disks lean face-on (mean ≈ 37° instead
    // of 42.5°), as in any magnitude-limited sample of dusty disks.
    let gals = galaxies_of(&base_field(&plan_with(&o[..3]).population(), 0).unwrap());
    let i: Vec<f64> = gals
        .iter()
        .filter(|r| r.hubble_type >= 2)
        .map(|r| r.incl_deg)
        .collect();
    let mean = i.iter().sum::<f64>() / i.len() as f64;
    assert!((34.0..40.0).contains(&mean), "mean inclination {mean}");
}

#[test]
fn lensed_positions_follow_the_shear_and_keep_the_density() {
    // Default shears reach g1 = 0.1: galaxies are placed over a rectangle
    // about 10% wider along y, so that after lensing they still cover the
    // image and its margin with the density of an unlensed field.
    let flags = [
        "image.width_px=2048",
        "image.height_px=2048",
        "population.galaxies.mag_faint=24.5",
    ];
    let lens = plan_with(&[flags.as_slice(), &["population.lens_positions=true"]].concat());
    let flat = plan_with(&flags);
    assert!(!flat.lens_positions());
    let whole = lens.placement_area();
    let (a0, xr0, yr0) = (whole.area_arcmin2, whole.x_px, whole.y_px);
    let wide = galaxy_placement_area(&lens.population());
    let (a1, xr1, yr1) = (wide.area_arcmin2, wide.x_px, wide.y_px);
    assert_eq!(
        galaxy_placement_area(&flat.population()),
        flat.placement_area()
    );
    assert!(
        a1 > 1.09 * a0 && (xr1.0 - xr0.0).abs() < 1e-9 && yr1.0 < yr0.0,
        "{a1} {a0}"
    );
    let (cx, cy) = lens.lensing_centre();
    assert_eq!((cx, cy), (1024.5, 1024.5));
    let base = base_field(&lens.population(), 0).unwrap();
    let (g1, g2) = (0.1, 0.0);
    let twin = rotated(&base);
    let view = lensed(&lens.population(), 0, &sheared(&base, g1, g2), g1, g2);
    let view_twin = lensed(&lens.population(), 0, &sheared(&twin, g1, g2), g1, g2);
    assert_eq!(view.len(), view_twin.len());
    let by_id: std::collections::HashMap<i64, &TruthRow> = base.iter().map(|r| (r.id, r)).collect();
    for (v, t) in view.iter().zip(&view_twin) {
        // Twins land on the same spots.
        assert_eq!((v.id, v.x, v.y), (t.id, t.x, t.y));
        let b = by_id[&v.id];
        if b.is_star() {
            assert_eq!(
                (v.x, v.y, v.ra_deg, v.dec_deg),
                (b.x, b.y, b.ra_deg, b.dec_deg)
            );
            continue;
        }
        let s = 1.0 / (1.0 - g1 * g1).sqrt();
        assert!((v.x - (cx + s * (1.0 + g1) * (b.x - cx))).abs() < 1e-9);
        assert!((v.y - (cy + s * (1.0 - g1) * (b.y - cy))).abs() < 1e-9);
        assert!((xr0.0..=xr0.1).contains(&v.x) && (yr0.0..=yr0.1).contains(&v.y));
        assert_eq!(
            (v.e1, v.e2, v.flux_e),
            (
                sheared(&[*b], g1, g2)[0].e1,
                sheared(&[*b], g1, g2)[0].e2,
                b.flux_e
            )
        );
    }
    // Stars are all kept; galaxies on the image: as many as without lensing
    // (Poisson, 5σ).
    let on = |rows: &[TruthRow]| {
        rows.iter()
            .filter(|r| {
                !r.is_star() && (0.5..=2048.5).contains(&r.x) && (0.5..=2048.5).contains(&r.y)
            })
            .count() as f64
    };
    assert_eq!(
        view.iter().filter(|r| r.is_star()).count(),
        base.iter().filter(|r| r.is_star()).count()
    );
    let unlensed = on(&base_field(&flat.population(), 0).unwrap());
    let got = on(&view);
    eprintln!("galaxies on the image: lensed {got}, unlensed {unlensed}");
    assert!(
        (got - unlensed).abs() < 5.0 * (2.0 * unlensed).sqrt(),
        "{got} vs {unlensed}"
    );
    // With g = 0 nothing moves.
    let still = lensed(&lens.population(), 0, &sheared(&base, 0.0, 0.0), 0.0, 0.0);
    let inside = base.iter().filter(|r| {
        r.is_star() || ((xr0.0..=xr0.1).contains(&r.x) && (yr0.0..=yr0.1).contains(&r.y))
    });
    assert!(
        still
            .iter()
            .zip(inside)
            .all(|(a, b)| a.id == b.id && (a.x - b.x).abs() < 1e-9 && (a.y - b.y).abs() < 1e-9)
    );
}

/// A config file in `dir` with the given JSON body.
fn config_in(dir: &Path, body: &str) -> std::path::PathBuf {
    let path = dir.join("config.json");
    std::fs::write(&path, body).unwrap();
    path
}

#[test]
fn skymaker_lists_are_found_beside_the_config_and_read_once() {
    let dir = tempfile::tempdir().unwrap();
    let small = [
        "image.width_px=256",
        "image.height_px=256",
        "image.n_images=2",
    ];
    let drawn = Plan::from_json("{\"run\": {\"seed\": 5}}", Path::new("t.json"), &small).unwrap();
    std::fs::create_dir(dir.path().join("lists")).unwrap();
    let t_types = crate::model::population::t_types(&drawn.population());
    let mut counts = Vec::new();
    for field in 0..2 {
        let rows = base_field(&drawn.population(), field).unwrap();
        let list = dir.path().join(format!("lists/f{field}.list"));
        crate::io::skymaker::write_list(&list, &rows, &t_types).unwrap();
        counts.push(rows.len());
    }
    // A relative pattern: relative to the config's directory, whatever
    // the working directory is.
    let config = config_in(
        dir.path(),
        r#"{"run": {"seed": 5}, "image": {"width_px": 256, "height_px": 256, "n_images": 2},
           "population": {"source": {"skymaker_list": {"path": "lists/f{field}.list"}}}}"#,
    );
    let plan = Plan::load(&config, &[]).unwrap();
    assert_eq!(plan.skymaker_list(0).unwrap().len(), counts[0]);
    assert_eq!(plan.skymaker_list(1).unwrap().len(), counts[1]);
    assert!(plan.skymaker_list(2).is_none());
    // Read once, at plan time: the files are no longer needed.
    std::fs::remove_dir_all(dir.path().join("lists")).unwrap();
    let rows = base_field(&plan.population(), 1).unwrap();
    assert_eq!(rows.len(), counts[1]);
    // A missing list is refused when the plan is made, naming the key
    // and the resolved file.
    let err = Plan::load(&config, &[]).unwrap_err().to_string();
    assert!(
        err.contains("key `population.source.path`")
            && err.contains(&dir.path().join("lists/f0.list").display().to_string()),
        "{err}"
    );
}

#[test]
fn the_galaxies_kept_per_field_are_the_expected_count_less_those_out_of_range() {
    // What the disk estimate counts per truth table: the galaxies drawn
    // (Poisson, density × area) times the fraction kept in the magnitude
    // range: within 4σ of the mean of 4 fields.
    let plan = plan_with(&["image.width_px=2048", "image.height_px=2048"]);
    let drawn =
        model(&plan.population()).density_per_arcmin2() * plan.placement_area().area_arcmin2;
    let kept = kept_fraction(&plan.population());
    assert!((0.5..0.95).contains(&kept), "{kept}");
    let fields = 4;
    let mean = (0..fields)
        .map(|f| galaxies_of(&base_field(&plan.population(), f).unwrap()).len() as f64)
        .sum::<f64>()
        / f64::from(fields);
    let want = drawn * kept;
    let sigma = (want / f64::from(fields)).sqrt() + want * 0.006;
    assert!(
        (mean - want).abs() < 4.0 * sigma,
        "{mean} kept per field, {want} expected ({drawn} drawn × {kept})"
    );
}

#[test]
fn the_model_is_made_once_per_spec_and_is_the_model_of_that_spec() {
    // A store of the test's own: the process's is shared with other tests.
    let store = Mutex::new(Vec::new());
    let made = |spec: &PopulationSpec| tabulated_in(&store, spec).model.clone();
    let spec = plan_with(&[]).population();
    let first = made(&spec);
    assert!(Arc::ptr_eq(&first, &made(&spec)), "made twice");
    let g = &spec.galaxies;
    let fresh = StuffModel::new(g, Lcdm::new(&spec.cosmology), g.mag_bright, g.mag_faint);
    assert_eq!(
        first.density_per_arcmin2().to_bits(),
        fresh.density_per_arcmin2().to_bits()
    );
    assert_eq!(
        model(&spec).density_per_arcmin2().to_bits(),
        fresh.density_per_arcmin2().to_bits()
    );
    // Another faint limit is another model, with more galaxies, and the
    // first is still the first spec's.
    let fainter = plan_with(&["population.galaxies.mag_faint=26.5"]).population();
    let other = made(&fainter);
    assert!(!Arc::ptr_eq(&first, &other));
    assert!(other.density_per_arcmin2() > first.density_per_arcmin2());
    assert!(Arc::ptr_eq(&first, &made(&spec)));
    // The store keeps the last MODELS_KEPT specs: one more than that evicts
    // the least recently asked for.
    for k in 0..MODELS_KEPT {
        made(
            &plan_with(&[&format!(
                "population.galaxies.mag_faint={}",
                24.1 + 0.1 * k as f64
            )])
            .population(),
        );
    }
    assert_eq!(store.lock().unwrap().len(), MODELS_KEPT);
    assert!(
        !Arc::ptr_eq(&first, &made(&spec)),
        "kept more than {MODELS_KEPT}"
    );
    // The kept fraction is measured once per model too, and is the
    // fraction of the spec asked about.
    assert_eq!(kept_fraction(&spec), kept_fraction(&spec));
    assert_ne!(kept_fraction(&spec), kept_fraction(&fainter));
}
