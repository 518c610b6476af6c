//! Known-answer tests of the metrics: synthetic submissions with a chosen
//! m, c, q, weights, contamination and selection, scored in memory.

use stepsim_contract::truth::TruthRow;
use stepsim_harness::{
    DISK_EDGES_ARCSEC, MAG_EDGES, PsfReport, binned_residuals, fit_line_closed_form, score_tables,
};
use stepsim_testkit::synthetic::{SynthRun, SynthSpec, make_run};

const AREA: f64 = 1.0;

fn psf<'a>(psfs: &'a [PsfReport], name: &str) -> &'a PsfReport {
    psfs.iter().find(|p| p.psf == name).unwrap()
}

/// m0, c0 (component 1), c0 (component 2), q0 of PSF p.
fn truth_bias(p: usize) -> (f64, f64, f64, f64) {
    let m0 = -0.03 + 0.012 * p as f64;
    let c1 = 1e-3 * (p as f64 - 2.5);
    let c2 = -4e-4 * p as f64;
    let q0 = if p % 2 == 1 { 0.8 * p as f64 } else { 0.0 };
    (m0, c1, c2, q0)
}

fn biased(run: &SynthRun, with_q: bool) -> Vec<Vec<stepsim_harness::SubRow>> {
    let ds = &run.datasets.datasets;
    run.submission(&|t: &TruthRow, d| {
        if t.is_star() {
            return None;
        }
        let (m0, c1, c2, q0) = truth_bias(ds[d].psf_id as usize);
        let q0 = if with_q { q0 } else { 0.0 };
        let g1 = ds[d].g1;
        // A weight that depends on magnitude only (constant within a ring).
        let w = 1.0 / (1.0 + (t.mag - 20.0).powi(2) / 10.0);
        Some((
            (1.0 + m0) * t.e1 + c1 + q0 * g1 * g1,
            (1.0 + m0) * t.e2 + c2,
            w,
        ))
    })
}

#[test]
fn m_c_q_are_recovered_to_1e_3_without_shape_noise() {
    let run = make_run(&SynthSpec::small(3));
    let rows = biased(&run, true);
    let stats = run.stats(&rows, 1.0);
    let s = score_tables(&run.meta(), &stats, AREA);
    assert_eq!(s.psfs.len(), 6);
    assert_eq!(s.datasets.len(), 30);
    for (p, (_, name)) in SynthSpec::small(1).psfs.iter().enumerate() {
        let r = psf(&s.psfs, name);
        let (m0, c1, c2, q0) = truth_bias(p);
        let m = r.m.unwrap();
        let q = r.q.unwrap();
        assert!((m - m0).abs() < 1e-3, "{name}: m {m} vs {m0}");
        assert!((r.c1.unwrap() - c1).abs() < 1e-3, "{name}: c1");
        assert!((r.c2.unwrap() - c2).abs() < 1e-3, "{name}: c2");
        assert!((q - q0).abs() < 1e-3, "{name}: q {q} vs {q0}");
        if q0 != 0.0 {
            assert!(!r.linear, "{name}: a real q is kept");
        }
        // Much tighter in fact: the ring average is exact to ~1e-9.
        assert!((m - m0).abs() < 1e-6 && (r.c1.unwrap() - c1).abs() < 1e-8);
        // Nothing was contaminated, selected or weighted by shape.
        assert!((r.m_uncontaminated.unwrap() - m0).abs() < 1e-6);
        assert!(r.m_selc.unwrap().abs() < 1e-6, "{name}: m_selc");
        assert!(r.m_weight.unwrap().abs() < 1e-6, "{name}: m_weight");
        assert!(
            r.m2.is_none(),
            "g2_true is constant: component 2 is not fitted"
        );
    }
    let m_mean: f64 = (0..6).map(|p| truth_bias(p).0).sum::<f64>() / 6.0;
    assert!((s.summary.m_mean.unwrap() - m_mean).abs() < 1e-6);
    let q_mean: f64 = (0..6).map(|p| truth_bias(p).3).sum::<f64>() / 6.0;
    assert!((s.summary.q_mean.unwrap() - q_mean).abs() < 1e-3);
    // sigma_c: population std of the 12 pooled c values.
    let cs: Vec<f64> = (0..6)
        .flat_map(|p| [truth_bias(p).1, truth_bias(p).2])
        .collect();
    let mean = cs.iter().sum::<f64>() / 12.0;
    let sd = (cs.iter().map(|c| (c - mean).powi(2)).sum::<f64>() / 12.0).sqrt();
    assert!((s.summary.sigma_c.unwrap() - sd).abs() < 1e-8);
    // No stars, no false detections, SNR undefined at g1 = 0.
    for d in &s.datasets {
        assert_eq!(d.pct_stars, 0.0);
        assert_eq!(d.pct_false, 0.0);
        assert_eq!(d.n_images, 3);
        assert_eq!(d.snr.is_none(), d.g1_true == 0.0);
    }
}

#[test]
fn m_and_c_are_recovered_within_errors_with_shape_noise() {
    let mut spec = SynthSpec::small(12);
    spec.shape_noise = true;
    spec.seed = 99;
    let run = make_run(&spec);
    // No quadratic term here: with noise, a q that the fit cannot detect
    // would (correctly, as in the paper) be absorbed into m.
    let rows = biased(&run, false);
    let stats = run.stats(&rows, 1.0);
    let s = score_tables(&run.meta(), &stats, AREA);
    for (p, (_, name)) in spec.psfs.iter().enumerate() {
        let r = psf(&s.psfs, name);
        let (m0, c1, _, _) = truth_bias(p);
        let q0 = 0.0;
        let (m, me) = (r.m.unwrap(), r.m_err.unwrap());
        assert!(me > 0.0 && me < 0.5, "{name}: m_err {me}");
        assert!((m - m0).abs() < 3.0 * me, "{name}: m {m} ± {me} vs {m0}");
        let (c, ce) = (r.c1.unwrap(), r.c1_err.unwrap());
        assert!((c - c1).abs() < 3.0 * ce, "{name}: c1 {c} ± {ce} vs {c1}");
        if !r.linear {
            let (q, qe) = (r.q.unwrap(), r.q_err.unwrap());
            assert!((q - q0).abs() < 3.0 * qe, "{name}: q {q} ± {qe} vs {q0}");
        }
    }
    // The shot-noise signal-to-noise is finite where g1 ≠ 0.
    for d in &s.datasets {
        assert_eq!(d.sn_shot.is_some(), d.g1_true != 0.0);
    }
}

#[test]
fn contamination_is_counted_exactly_and_m_uncontaminated_removes_it() {
    let spec = SynthSpec::small(2);
    let run = make_run(&spec);
    // Every galaxy perfectly measured, every star submitted with a fixed
    // shape and weight 0.5, and false detections at the grid corners
    // (≥ 8 px from any object, the radius is 5 px) with weight 2.
    let mut rows = run.submission(&|t: &TruthRow, _| {
        Some(if t.is_star() {
            (0.3, -0.2, 0.5)
        } else {
            (t.e1, t.e2, 1.0)
        })
    });
    let n_false_per_image = 7;
    for r in rows.iter_mut() {
        for k in 0..n_false_per_image {
            let x = 3.0 + (k + 1) as f64 * spec.spacing_px;
            r.push(stepsim_harness::SubRow {
                x,
                y: x,
                e1: -0.4,
                e2: 0.1,
                weight: 2.0,
                line: 0,
            });
        }
    }
    let stats = run.stats(&rows, 1.0);
    let s = score_tables(&run.meta(), &stats, AREA);
    // Both base fields (images 0 and 1 of dataset 0) together.
    let n_star = run.truth[..2]
        .iter()
        .flatten()
        .filter(|t| t.is_star())
        .count() as f64;
    let n_gal = (run.truth[0].len() + run.truth[1].len()) as f64 - n_star;
    let n_false = 2.0 * n_false_per_image as f64;
    let n = n_star + n_gal + n_false;
    let sw = n_gal + 0.5 * n_star + 2.0 * n_false;
    for d in &s.datasets {
        assert_eq!(d.n_objects as f64, n);
        assert_eq!(d.pct_stars, 100.0 * n_star / n);
        assert_eq!(d.pct_false, 100.0 * n_false / n);
        assert!((d.pct_stars_weighted.unwrap() - 100.0 * 0.5 * n_star / sw).abs() < 1e-12);
        assert!((d.pct_false_weighted.unwrap() - 100.0 * 2.0 * n_false / sw).abs() < 1e-12);
        assert!((d.ngal_per_arcmin2 - n / (2.0 * AREA)).abs() < 1e-9);
    }
    for r in &s.psfs {
        assert!(
            r.m.unwrap() < -0.05,
            "stars and false detections dilute m: {:?}",
            r.m
        );
        assert!(
            r.m_uncontaminated.unwrap().abs() < 1e-6,
            "{:?}",
            r.m_uncontaminated
        );
    }
    assert!(s.summary.m_uncontaminated_mean.unwrap().abs() < 1e-6);
}

/// Reference: the weight-bias and selection-bias slopes computed directly
/// from the truth tables with plain loops and the closed-form line fit.
fn reference_slopes(
    run: &SynthRun,
    psf_id: u32,
    keep: &dyn Fn(&TruthRow) -> bool,
    weight: &dyn Fn(&TruthRow) -> f64,
) -> (f64, f64) {
    let index = run.index();
    let (mut xs, mut sel, mut wb, mut sel_err, mut wb_err) =
        (vec![], vec![], vec![], vec![], vec![]);
    for (d, ds) in run.datasets.datasets.iter().enumerate() {
        if ds.psf_id != psf_id {
            continue;
        }
        let (mut a, mut b) = (vec![], vec![]);
        for (info, truth) in index.images.iter().zip(&run.truth) {
            if info.dataset != d {
                continue;
            }
            let g: Vec<&TruthRow> = truth.iter().filter(|t| !t.is_star() && keep(t)).collect();
            let un = g.iter().map(|t| t.e1_int).sum::<f64>() / g.len() as f64;
            let sw: f64 = g.iter().map(|t| weight(t)).sum();
            let wm = g.iter().map(|t| weight(t) * t.e1_int).sum::<f64>() / sw;
            a.push(un);
            b.push(un - wm);
        }
        let err = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64;
            (m, (var / v.len() as f64).sqrt())
        };
        xs.push(ds.g1);
        let (m, e) = err(&a);
        sel.push(m);
        sel_err.push(e);
        let (m, e) = err(&b);
        wb.push(m);
        wb_err.push(e);
    }
    let (_, m_selc, _, _) = fit_line_closed_form(&xs, &sel, &sel_err);
    let (_, m_weight, _, _) = fit_line_closed_form(&xs, &wb, &wb_err);
    (m_selc, m_weight)
}

#[test]
fn a_shape_dependent_weight_shows_as_weight_bias() {
    let mut spec = SynthSpec::small(4);
    spec.psfs.truncate(2);
    let run = make_run(&spec);
    // BJ02-like weight on the observed (sheared) ellipticity: rounder
    // galaxies weigh more, and shear changes which ones are round.
    let weight = |t: &TruthRow| 1.0 / (0.05 + t.e1 * t.e1 + t.e2 * t.e2);
    let rows = run.submission(&|t: &TruthRow, _| (!t.is_star()).then(|| (t.e1, t.e2, weight(t))));
    let stats = run.stats(&rows, 1.0);
    let s = score_tables(&run.meta(), &stats, AREA);
    for p in &s.psfs {
        let mw = p.m_weight.unwrap();
        assert!(
            mw > 0.1 && mw > 10.0 * p.m_weight_err.unwrap_or(0.0),
            "m_weight {mw}"
        );
        let (_, reference) = reference_slopes(
            &run,
            if p.psf == "none" { 0 } else { 1 },
            &|_| true,
            &weight,
        );
        assert!(
            (mw - reference).abs() < 1e-9,
            "{mw} vs reference {reference}"
        );
        assert!(p.m_selc.unwrap().abs() < 1e-6, "no selection");
    }
    assert!(s.summary.m_weight_mean.unwrap() > 0.1);
}

#[test]
fn a_shape_dependent_cut_shows_as_selection_bias_and_a_magnitude_cut_does_not() {
    let mut spec = SynthSpec::small(4);
    spec.psfs.truncate(2);
    let run = make_run(&spec);
    let keep_round = |t: &TruthRow| t.e1.hypot(t.e2) < 0.3;
    let rows = run.submission(&|t: &TruthRow, _| {
        (!t.is_star() && keep_round(t)).then_some((t.e1, t.e2, 1.0))
    });
    let s = score_tables(&run.meta(), &run.stats(&rows, 1.0), AREA);
    for p in &s.psfs {
        let ms = p.m_selc.unwrap();
        assert!(
            ms < -0.1,
            "dropping elongated sheared galaxies biases ⟨e_int⟩: {ms}"
        );
        let (reference, _) = reference_slopes(
            &run,
            if p.psf == "none" { 0 } else { 1 },
            &keep_round,
            &|_| 1.0,
        );
        assert!(
            (ms - reference).abs() < 1e-9,
            "{ms} vs reference {reference}"
        );
    }
    let rows = run
        .submission(&|t: &TruthRow, _| (!t.is_star() && t.mag < 24.0).then_some((t.e1, t.e2, 1.0)));
    let s = score_tables(&run.meta(), &run.stats(&rows, 1.0), AREA);
    for p in &s.psfs {
        assert!(p.m_selc.unwrap().abs() < 1e-6, "{:?}", p.m_selc);
        assert!(p.m.unwrap().abs() < 1e-6);
    }
}

#[test]
fn residuals_by_magnitude_and_disk_size_follow_the_injected_bias() {
    let spec = SynthSpec::small(2);
    let run = make_run(&spec);
    let meta = run.meta();
    let rows = run.submission(&|t: &TruthRow, _| {
        (!t.is_star()).then(|| {
            let m0 = if t.mag < 23.0 { 0.02 } else { -0.02 };
            ((1.0 + m0) * t.e1, (1.0 + m0) * t.e2, 1.0)
        })
    });
    let stats = run.stats(&rows, 1.0);
    let b = binned_residuals(&meta, &stats, "mag", &MAG_EDGES, |s| &s.by_mag);
    let mean_g1 = meta.iter().map(|m| m.g1).sum::<f64>() / meta.len() as f64;
    assert_eq!(b.bins.len(), 7);
    for bin in &b.bins {
        if bin.n_objects == 0 {
            assert!(bin.g1_residual.is_none());
            continue;
        }
        let m0 = if bin.hi.is_some_and(|h| h <= 23.0) {
            0.02
        } else {
            -0.02
        };
        assert!(
            (bin.g1_residual.unwrap() - m0 * mean_g1).abs() < 1e-9,
            "{bin:?}"
        );
    }
    let total: u64 = b.bins.iter().map(|b| b.n_objects).sum();
    assert_eq!(total, b.all.n_objects);
    let d = binned_residuals(&meta, &stats, "disk_h_arcsec", &DISK_EDGES_ARCSEC, |s| {
        &s.by_disk
    });
    assert_eq!(d.all, b.all);
    assert_eq!(d.bins.iter().map(|b| b.n_objects).sum::<u64>(), total);
}

#[test]
fn bootstrap_is_reproducible_and_brackets_the_estimate() {
    let mut spec = SynthSpec::small(10);
    spec.shape_noise = true;
    spec.psfs.truncate(3);
    let run = make_run(&spec);
    let rows = biased(&run, false);
    let stats = run.stats(&rows, 1.0);
    let meta = run.meta();
    let a = stepsim_harness::bootstrap(&meta, &stats, AREA, 60, 5);
    let b = stepsim_harness::bootstrap(&meta, &stats, AREA, 60, 5);
    assert_eq!(a, b);
    let c = stepsim_harness::bootstrap(&meta, &stats, AREA, 60, 6);
    assert_ne!(a.m_mean, c.m_mean, "the seed matters");
    let s = score_tables(&meta, &stats, AREA).summary;
    let [lo, hi] = a.m_mean.unwrap();
    let m = s.m_mean.unwrap();
    assert!(
        lo < hi && lo <= m + 0.05 && m - 0.05 <= hi,
        "[{lo}, {hi}] vs {m}"
    );
}
