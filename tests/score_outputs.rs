//! `stepsim score` never overwrites a report without `--force`: not
//! report.json, and not report.md (or a plot) found alone in `--out`.

use std::path::Path;
use std::process::Output;
use stepsim_contract::run_dir::RunDir;
use stepsim_contract::truth::TruthRow;
use stepsim_testkit::synthetic::{SynthSpec, make_run, submission_text};

use crate::common;
use common::{run_with, stepsim};

fn score(dir: &Path, out: &str, force: bool) -> Output {
    let mut c = stepsim();
    c.args([
        "score",
        "--truth",
        "private",
        "--submission",
        "sub.txt",
        "--out",
        out,
    ])
    .current_dir(dir);
    if force {
        c.arg("--force");
    }
    run_with(&mut c)
}

#[test]
fn a_report_md_alone_is_not_overwritten_without_force() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut spec = SynthSpec::small(2);
    spec.psfs.truncate(2);
    spec.shears.truncate(4);
    let run = make_run(&spec);
    run.write(RunDir::new(d).private().path()).unwrap();
    let rows = run.submission(&|t: &TruthRow, _| {
        Some(if t.is_star() {
            (0.0, 0.0, 1.0)
        } else {
            (t.e1, t.e2, 1.0)
        })
    });
    std::fs::write(d.join("sub.txt"), submission_text(&run.index(), &rows)).unwrap();
    let o = score(d, "full", false);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let names: Vec<String> = std::fs::read_dir(d.join("full"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n != "report.json")
        .collect();
    assert!(names.iter().any(|n| n == "report.md"), "{names:?}");
    // Each output alone in --out (someone's earlier report.md, a plot) is
    // refused by name, untouched; --force overwrites it.
    for name in names {
        let out = d.join("alone");
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join(&name), "mine").unwrap();
        let o = score(d, "alone", false);
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{name}: {e}");
        assert!(e.contains(&name) && e.contains("--force"), "{name}: {e}");
        assert_eq!(std::fs::read(out.join(&name)).unwrap(), b"mine");
        assert!(!out.join("report.json").exists(), "{name}");
        let o = score(d, "alone", true);
        assert!(o.status.success());
        assert_ne!(std::fs::read(out.join(&name)).unwrap(), b"mine");
        std::fs::remove_dir_all(&out).unwrap();
    }
}
