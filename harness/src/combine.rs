//! One report from the reports of runs that each hold some of the PSFs
//! (`stepsim score --combine`): the full STEP1 preset generated as six
//! one-PSF runs, or a challenge scored run by run.
//!
//! What is combined, and how (docs/scoring.md, "Combining reports"):
//!
//! * `datasets` and `psfs`: the rows of every report, in the order given.
//!   A PSF may appear in one report only.
//! * `summary`: recomputed from the combined `psfs` rows by the same
//!   [`crate::score::metrics::summarize`] a single score uses (⟨m⟩, σ_c, Q_c, …),
//!   so a combined report of one-PSF runs has the summary a single run of
//!   all the PSFs would have, given the same per-PSF rows. `pct_chance_match`
//!   is the mean over the combined datasets.
//! * No bootstrap intervals: they resample base fields across all PSFs at
//!   once and need the images' sums, which a report does not hold. The
//!   per-PSF rows keep their errors; a warning says so.
//! * `by_magnitude`, `by_disk_size`: per bin, the mean over reports of the
//!   bin's residual weighted by each report's number of datasets (its value
//!   is already a mean over them), its error √(Σ w² err²)/Σ w, and the
//!   summed object count. The bins must have the same edges in every
//!   report.
//! * `run`: `combined:sha256:` + SHA-256 of the reports' sorted `run`
//!   values, one per line, so that two combinations of the same runs rank
//!   together on a leaderboard.
//!
//! Refused, naming the file: fewer than two reports, a report that cannot
//! be read, a report without PSF rows or with a PSF twice, the same file or
//! the same run twice, the same PSF or dataset in two reports, different
//! match radii, different submission names unless `name` is given,
//! different bins, counts that overflow, sums that are not finite.

use crate::error::HarnessError;
use crate::report::leaderboard::read_report;
use crate::score::report::{BinReport, Binned, Report};
use std::path::{Path, PathBuf};

/// A report directory (its `report.json`) or a report file.
pub fn report_file(path: &Path) -> PathBuf {
    if path.is_dir() {
        path.join(crate::pipeline::REPORT_JSON)
    } else {
        path.to_path_buf()
    }
}

/// Reads the reports at `paths` (directories or `report.json` files) and
/// combines them (`combine`).
pub fn combine_files(paths: &[PathBuf], name: Option<&str>) -> Result<Report, HarnessError> {
    let mut reports = Vec::with_capacity(paths.len());
    for p in paths {
        let file = report_file(p);
        let r = read_report(&file)?;
        reports.push((file, r));
    }
    combine(&reports, name)
}

/// One report from `reports` (file, report) as described in the module
/// documentation; `name` is the combined submission's name (default: the
/// reports' common name).
pub fn combine(reports: &[(PathBuf, Report)], name: Option<&str>) -> Result<Report, HarnessError> {
    let refuse = |path: &Path, message: String| HarnessError::Report {
        path: path.to_path_buf(),
        message,
    };
    let Some((first_path, first)) = reports.first() else {
        return Err(HarnessError::BadOption {
            name: "--combine".into(),
            message: "give at least two reports".into(),
        });
    };
    if reports.len() < 2 {
        return Err(refuse(
            first_path,
            "only one report given; --combine needs at least two".into(),
        ));
    }
    let canonical: Vec<PathBuf> = reports
        .iter()
        .map(|(p, _)| std::fs::canonicalize(p).unwrap_or_else(|_| p.clone()))
        .collect();
    for (j, (path, r)) in reports.iter().enumerate() {
        if r.psfs.is_empty() {
            return Err(refuse(path, "the report has no PSF rows".into()));
        }
        // Names are compared as sets and the smallest is named, so that no
        // message follows the order of a report's rows (that of the run's
        // private `datasets.json`).
        if let Some(psf) = smallest_repeated(r.psfs.iter().map(|p| p.psf.as_str())) {
            return Err(refuse(
                path,
                format!("PSF `{psf}` appears twice in the report"),
            ));
        }
        for (i, (pi, ri)) in reports[..j].iter().enumerate() {
            if canonical[i] == canonical[j] {
                return Err(refuse(path, "the same report is given twice".into()));
            }
            if ri.run == r.run {
                return Err(refuse(
                    path,
                    format!(
                        "it scores the same run as {} (`{}`); combine reports of different runs",
                        pi.display(),
                        r.run
                    ),
                ));
            }
            if let Some(d) = smallest_shared(
                r.datasets.iter().map(|d| d.dataset.as_str()),
                ri.datasets.iter().map(|d| d.dataset.as_str()),
            ) {
                return Err(refuse(
                    path,
                    format!("dataset `{d}` is also in {}", pi.display()),
                ));
            }
        }
        if r.match_radius_arcsec != first.match_radius_arcsec {
            return Err(refuse(
                path,
                format!(
                    "match radius {} arcsec, but {} used {} arcsec; score both with the same radius",
                    r.match_radius_arcsec,
                    first_path.display(),
                    first.match_radius_arcsec
                ),
            ));
        }
        if r.isolation_plane != first.isolation_plane {
            return Err(refuse(
                path,
                format!(
                    "its isolated galaxies are classed in the {} plane, but {}'s in the {} plane \
                     (one run lensed its galaxies' positions, the other did not); combine reports \
                     of runs that place galaxies alike",
                    r.isolation_plane.name(),
                    first_path.display(),
                    first.isolation_plane.name()
                ),
            ));
        }
        if name.is_none() && r.submission != first.submission {
            return Err(refuse(
                path,
                format!(
                    "submission `{}`, but {} is `{}`; pass --name to name the combination",
                    r.submission,
                    first_path.display(),
                    first.submission
                ),
            ));
        }
        for (pi, ri) in &reports[..j] {
            if let Some(psf) = smallest_shared(
                r.psfs.iter().map(|p| p.psf.as_str()),
                ri.psfs.iter().map(|p| p.psf.as_str()),
            ) {
                return Err(refuse(
                    path,
                    format!(
                        "PSF `{psf}` is also in {}; each PSF may come from one report only",
                        pi.display()
                    ),
                ));
            }
        }
    }
    let psfs: Vec<_> = reports.iter().flat_map(|(_, r)| r.psfs.clone()).collect();
    let datasets: Vec<_> = reports
        .iter()
        .flat_map(|(_, r)| r.datasets.clone())
        .collect();
    let mut summary = crate::score::metrics::summarize(&psfs);
    let chance: Vec<f64> = datasets.iter().filter_map(|d| d.pct_chance_match).collect();
    summary.pct_chance_match =
        (!chance.is_empty()).then(|| chance.iter().sum::<f64>() / chance.len() as f64);
    let mut runs: Vec<&str> = reports.iter().map(|(_, r)| r.run.as_str()).collect();
    runs.sort_unstable();
    let run = format!(
        "combined:sha256:{}",
        stepsim_contract::digest::sha256_hex(runs.join("\n").as_bytes())
    );
    let binned = |get: fn(&Report) -> &Binned| -> Result<Binned, HarnessError> {
        let all: Vec<(&PathBuf, &Binned, f64)> = reports
            .iter()
            .map(|(p, r)| (p, get(r), r.datasets.len().max(1) as f64))
            .collect();
        combine_binned(&all)
    };
    let mut warnings = vec![format!(
        "combined from {} reports ({}); the summary is recomputed from their per-PSF rows; \
         no bootstrap intervals (they need the images: score one run of all PSFs for them)",
        reports.len(),
        reports
            .iter()
            .map(|(p, _)| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    )];
    for (p, r) in reports {
        warnings.extend(r.warnings.iter().map(|w| format!("{}: {w}", p.display())));
    }
    let s = &summary;
    let figures = [
        s.m_mean,
        s.q_mean,
        s.sigma_c,
        s.m_uncontaminated_mean,
        s.m_selc_mean,
        s.sigma_c_selc,
        s.m_weight_mean,
        s.m_isolated_mean,
        s.sigma_c_isolated,
        s.q_c,
        s.pct_chance_match,
    ];
    if figures.iter().flatten().any(|v| !v.is_finite()) {
        return Err(refuse(
            first_path,
            "the combined summary is not finite (values near the limit of a double in the reports)"
                .into(),
        ));
    }
    Ok(Report {
        submission: name.map_or_else(|| first.submission.clone(), str::to_owned),
        run,
        match_radius_arcsec: first.match_radius_arcsec,
        isolation_plane: first.isolation_plane,
        datasets,
        psfs,
        summary,
        by_magnitude: binned(|r| &r.by_magnitude)?,
        by_disk_size: binned(|r| &r.by_disk_size)?,
        warnings,
    })
}

/// The smallest name (in byte order) that `names` holds more than once.
fn smallest_repeated<'a>(names: impl Iterator<Item = &'a str>) -> Option<&'a str> {
    let mut v: Vec<&str> = names.collect();
    v.sort_unstable();
    v.windows(2).find(|w| w[0] == w[1]).map(|w| w[0])
}

/// The smallest name (in byte order) in both `a` and `b`.
fn smallest_shared<'a>(
    a: impl Iterator<Item = &'a str>,
    b: impl Iterator<Item = &'a str>,
) -> Option<&'a str> {
    let b: std::collections::BTreeSet<&str> = b.collect();
    a.filter(|n| b.contains(n)).min()
}

/// A value and its error, either possibly missing.
type ValueAndError = (Option<f64>, Option<f64>);

/// Per bin: the mean over reports of the residuals, each report weighted
/// by its number of datasets (its value is a mean over them), error
/// √(Σ w² σ²)/Σ w over the reports with a value; counts summed. The bins
/// must agree.
fn combine_binned(all: &[(&PathBuf, &Binned, f64)]) -> Result<Binned, HarnessError> {
    let (_, first, _) = all[0];
    let refuse = |path: &Path, message: String| HarnessError::Report {
        path: path.to_path_buf(),
        message,
    };
    for (path, b, _) in &all[1..] {
        let edges = |b: &Binned| -> Vec<(Option<f64>, Option<f64>)> {
            b.bins.iter().map(|x| (x.lo, x.hi)).collect()
        };
        if b.variable != first.variable || edges(b) != edges(first) {
            return Err(refuse(
                path,
                format!(
                    "its `{}` bins differ from the first report's; combine reports of one stepsim version",
                    b.variable
                ),
            ));
        }
    }
    let one = |pick: &dyn Fn(&Binned) -> &BinReport| -> Result<BinReport, HarnessError> {
        let bins: Vec<(&PathBuf, &BinReport, f64)> =
            all.iter().map(|(p, b, w)| (*p, pick(b), *w)).collect();
        let mut n_objects = 0u64;
        for (path, b, _) in &bins {
            n_objects = n_objects
                .checked_add(b.n_objects)
                .ok_or_else(|| refuse(path, "the objects counted in a bin overflow".into()))?;
        }
        let mean =
            |v: &dyn Fn(&BinReport) -> ValueAndError| -> Result<ValueAndError, HarnessError> {
                let parts: Vec<(f64, Option<f64>, f64)> = bins
                    .iter()
                    .filter_map(|(_, b, w)| {
                        let (x, e) = v(b);
                        x.map(|x| (x, e, *w))
                    })
                    .collect();
                if parts.is_empty() {
                    return Ok((None, None));
                }
                let total: f64 = parts.iter().map(|p| p.2).sum();
                let x = parts.iter().map(|p| p.0 * p.2).sum::<f64>() / total;
                let err = parts
                    .iter()
                    .map(|p| p.1.map(|e| (e * p.2).powi(2)))
                    .sum::<Option<f64>>()
                    .map(|s| s.sqrt() / total);
                if !x.is_finite() || err.is_some_and(|e| !e.is_finite()) {
                    return Err(refuse(
                        bins[0].0,
                        "a combined residual is not finite (values near the limit of a double)"
                            .into(),
                    ));
                }
                Ok((Some(x), err))
            };
        let (g1, g1_err) = mean(&|b| (b.g1_residual, b.g1_residual_err))?;
        let (g2, g2_err) = mean(&|b| (b.g2_residual, b.g2_residual_err))?;
        Ok(BinReport {
            lo: bins[0].1.lo,
            hi: bins[0].1.hi,
            n_objects,
            g1_residual: g1,
            g1_residual_err: g1_err,
            g2_residual: g2,
            g2_residual_err: g2_err,
        })
    };
    Ok(Binned {
        variable: first.variable.clone(),
        all: one(&|b| &b.all)?,
        bins: (0..first.bins.len())
            .map(|i| one(&move |b: &Binned| &b.bins[i]))
            .collect::<Result<_, _>>()?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::score::report::{DatasetReport, PsfReport};

    fn psf(name: &str, m: f64, c1: f64, c2: f64) -> PsfReport {
        let mut p: PsfReport = serde_json::from_value(serde_json::json!({
            "psf": name, "m": m, "m_err": 0.01, "q": 0.0, "q_err": null,
            "c1": c1, "c1_err": 0.001, "c2": c2, "c2_err": 0.001, "linear": true,
            "m_uncontaminated": null, "m_uncontaminated_err": null,
            "m_selc": null, "m_selc_err": null, "c1_selc": null, "c1_selc_err": null,
            "c2_selc": null, "c2_selc_err": null, "m_weight": null, "m_weight_err": null,
            "c1_weight": null, "c1_weight_err": null
        }))
        .unwrap();
        p.m = Some(m);
        p
    }

    fn binned(values: [f64; 2], n: u64) -> Binned {
        let bin = |lo: Option<f64>, hi: Option<f64>, v: f64| BinReport {
            lo,
            hi,
            n_objects: n,
            g1_residual: Some(v),
            g1_residual_err: Some(0.003),
            g2_residual: Some(-v),
            g2_residual_err: None,
        };
        Binned {
            variable: "mag".into(),
            all: bin(None, None, values[0] + values[1]),
            bins: vec![
                bin(None, Some(24.0), values[0]),
                bin(Some(24.0), None, values[1]),
            ],
        }
    }

    fn report(run: &str, psfs: Vec<PsfReport>, bins: [f64; 2]) -> Report {
        let summary = crate::score::metrics::summarize(&psfs);
        Report {
            submission: "ksb".into(),
            run: run.into(),
            match_radius_arcsec: 1.0,
            isolation_plane: crate::score::isolation::IsolationPlane::Image,
            datasets: vec![],
            psfs,
            summary,
            by_magnitude: binned(bins, 10),
            by_disk_size: binned(bins, 10),
            warnings: vec!["w".into()],
        }
    }

    #[test]
    fn the_summary_is_that_of_the_combined_rows() {
        let a = report(
            "sha256:aa",
            vec![psf("none", -0.10, 0.001, -0.002)],
            [0.01, 0.03],
        );
        let b = report(
            "sha256:bb",
            vec![
                psf("coma", -0.20, -0.003, 0.0),
                psf("jitter", -0.30, 0.002, 0.004),
            ],
            [0.02, 0.05],
        );
        let c = combine(
            &[("a.json".into(), a.clone()), ("b.json".into(), b.clone())],
            None,
        )
        .unwrap();
        assert_eq!(c.psfs.len(), 3);
        // ⟨m⟩ over the three PSFs, not the mean of the two reports' means.
        assert!((c.summary.m_mean.unwrap() - (-0.20)).abs() < 1e-15);
        // σ_c: population standard deviation of the six c values.
        let cs = [0.001, -0.002, -0.003, 0.0, 0.002, 0.004];
        let mean = cs.iter().sum::<f64>() / 6.0;
        let sd = (cs.iter().map(|c| (c - mean).powi(2)).sum::<f64>() / 6.0).sqrt();
        assert!((c.summary.sigma_c.unwrap() - sd).abs() < 1e-15);
        assert_eq!(c.summary.q_c, crate::score::metrics::q_c(&c.psfs));
        assert!(c.summary.bootstrap.is_none());
        // Bins: mean of the reports' values, counts summed, errors combined.
        let b0 = &c.by_magnitude.bins[0];
        assert!((b0.g1_residual.unwrap() - 0.015).abs() < 1e-15);
        assert!(
            (b0.g1_residual_err.unwrap() - (2.0f64 * 0.003 * 0.003).sqrt() / 2.0).abs() < 1e-15
        );
        assert_eq!(b0.g2_residual_err, None);
        assert_eq!(b0.n_objects, 20);
        // The identity does not depend on the order of the reports.
        let d = combine(&[("b.json".into(), b), ("a.json".into(), a)], None).unwrap();
        assert_eq!(c.run, d.run);
        assert!(c.run.starts_with("combined:sha256:"));
        assert_eq!(c.warnings.len(), 3);
    }

    #[test]
    fn bins_are_weighted_by_datasets_and_counts_may_not_overflow() {
        let ds = |id: &str| -> DatasetReport {
            serde_json::from_value(serde_json::json!({
                "dataset": id, "psf": "x", "g1_true": 0.0, "g2_true": 0.0, "n_images": 1,
                "n_objects": 1, "g1": null, "g1_err": null, "g2": null, "g2_err": null,
                "ngal_per_arcmin2": 1.0, "pct_stars": 0.0, "pct_false": 0.0,
                "pct_stars_weighted": null, "pct_false_weighted": null,
                "snr": null, "sn_shot": null, "sn_shot_weighted": null
            }))
            .unwrap()
        };
        let mut a = report("sha256:aa", vec![psf("none", -0.1, 0.0, 0.0)], [0.01, 0.0]);
        let mut b = report("sha256:bb", vec![psf("coma", -0.2, 0.0, 0.0)], [0.04, 0.0]);
        a.datasets = vec![ds("d1")];
        b.datasets = vec![ds("d2"), ds("d3"), ds("d4")];
        let c = combine(
            &[("a.json".into(), a.clone()), ("b.json".into(), b.clone())],
            None,
        )
        .unwrap();
        // (1 × 0.01 + 3 × 0.04) / 4
        assert!((c.by_magnitude.bins[0].g1_residual.unwrap() - 0.0325).abs() < 1e-15);
        let e = (0.003f64.powi(2) + (3.0 * 0.003f64).powi(2)).sqrt() / 4.0;
        assert!((c.by_magnitude.bins[0].g1_residual_err.unwrap() - e).abs() < 1e-15);
        // A dataset in both reports, and counts that overflow, are refused.
        let mut dup = b.clone();
        dup.datasets[0] = ds("d1");
        let e = combine(
            &[("a.json".into(), a.clone()), ("b.json".into(), dup)],
            None,
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("dataset `d1` is also in a.json"),
            "{e}"
        );
        a.by_magnitude.bins[0].n_objects = u64::MAX;
        let e = combine(&[("a.json".into(), a), ("b.json".into(), b)], None).unwrap_err();
        assert!(
            e.to_string().starts_with("b.json:") && e.to_string().contains("overflow"),
            "{e}"
        );
    }

    #[test]
    fn refusals_name_the_smallest_name_whatever_the_order_of_the_rows() {
        assert_eq!(
            smallest_repeated(["c", "b", "a", "c", "b"].into_iter()),
            Some("b")
        );
        assert_eq!(smallest_repeated(["c", "b", "a"].into_iter()), None);
        assert_eq!(
            smallest_shared(["z", "m", "b"].into_iter(), ["b", "z"].into_iter()),
            Some("b")
        );
        let a = report(
            "sha256:aa",
            vec![psf("p2", -0.1, 0.0, 0.0), psf("p1", -0.1, 0.0, 0.0)],
            [0.0, 0.0],
        );
        let mut b = report(
            "sha256:bb",
            vec![psf("p2", -0.2, 0.0, 0.0), psf("p1", -0.2, 0.0, 0.0)],
            [0.0, 0.0],
        );
        let msg = |a: &Report, b: &Report| {
            combine(
                &[("a.json".into(), a.clone()), ("b.json".into(), b.clone())],
                None,
            )
            .unwrap_err()
            .to_string()
        };
        let first = msg(&a, &b);
        assert!(first.contains("PSF `p1` is also in a.json"), "{first}");
        b.psfs.reverse();
        assert_eq!(msg(&a, &b), first);
    }

    #[test]
    fn refusals_name_the_file() {
        let a = report("sha256:aa", vec![psf("none", -0.1, 0.0, 0.0)], [0.0, 0.0]);
        let mut b = report("sha256:bb", vec![psf("none", -0.2, 0.0, 0.0)], [0.0, 0.0]);
        let msg = |r: Result<Report, HarnessError>| r.unwrap_err().to_string();
        let e = msg(combine(
            &[("a.json".into(), a.clone()), ("b.json".into(), b.clone())],
            None,
        ));
        assert!(
            e.starts_with("b.json:") && e.contains("PSF `none` is also in a.json"),
            "{e}"
        );
        b.psfs[0].psf = "coma".into();
        b.match_radius_arcsec = 2.0;
        let e = msg(combine(
            &[("a.json".into(), a.clone()), ("b.json".into(), b.clone())],
            None,
        ));
        assert!(
            e.starts_with("b.json:") && e.contains("match radius"),
            "{e}"
        );
        b.match_radius_arcsec = 1.0;
        b.isolation_plane = crate::score::isolation::IsolationPlane::Source;
        let e = msg(combine(
            &[("a.json".into(), a.clone()), ("b.json".into(), b.clone())],
            None,
        ));
        assert!(
            e.starts_with("b.json:")
                && e.contains("classed in the source plane, but a.json's in the image plane"),
            "{e}"
        );
        b.isolation_plane = crate::score::isolation::IsolationPlane::Image;
        b.submission = "other".into();
        let e = msg(combine(
            &[("a.json".into(), a.clone()), ("b.json".into(), b.clone())],
            None,
        ));
        assert!(e.contains("--name"), "{e}");
        let named = combine(
            &[("a.json".into(), a.clone()), ("b.json".into(), b.clone())],
            Some("x"),
        );
        assert_eq!(named.unwrap().submission, "x");
        b.submission = "ksb".into();
        b.by_magnitude.bins[1].lo = Some(23.0);
        let e = msg(combine(
            &[("a.json".into(), a.clone()), ("b.json".into(), b)],
            None,
        ));
        assert!(
            e.starts_with("b.json:") && e.contains("`mag` bins differ"),
            "{e}"
        );
        let e = msg(combine(&[("a.json".into(), a.clone())], None));
        assert!(e.contains("at least two"), "{e}");
        // The same file, the same run, no PSF, a PSF twice in one report.
        let e = msg(combine(
            &[("a.json".into(), a.clone()), ("a.json".into(), a.clone())],
            None,
        ));
        assert!(e.contains("given twice"), "{e}");
        let mut c = report("sha256:aa", vec![psf("other", -0.1, 0.0, 0.0)], [0.0, 0.0]);
        let e = msg(combine(
            &[("a.json".into(), a.clone()), ("c.json".into(), c.clone())],
            None,
        ));
        assert!(e.starts_with("c.json:") && e.contains("same run"), "{e}");
        c.run = "sha256:cc".into();
        c.psfs.clear();
        let e = msg(combine(
            &[("a.json".into(), a.clone()), ("c.json".into(), c.clone())],
            None,
        ));
        assert!(e.starts_with("c.json:") && e.contains("no PSF rows"), "{e}");
        c.psfs = vec![psf("p", 0.0, 0.0, 0.0), psf("p", 0.0, 0.0, 0.0)];
        let e = msg(combine(
            &[("a.json".into(), a.clone()), ("c.json".into(), c)],
            None,
        ));
        assert!(e.contains("PSF `p` appears twice"), "{e}");
        // Sums beyond the range of a double.
        let mut big = report("sha256:dd", vec![psf("big", 1e308, 0.0, 0.0)], [0.0, 0.0]);
        big.psfs.push(psf("big2", 1e308, 0.0, 0.0));
        let e = msg(combine(
            &[("a.json".into(), a), ("big.json".into(), big)],
            None,
        ));
        assert!(e.contains("not finite"), "{e}");
    }
}
