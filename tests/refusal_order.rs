//! `stepsim score` refuses every submission of the battery of
//! `harness/tests/common/permuted.rs` with the same bytes on stderr, the
//! same exit code and nothing written, whether the run's `datasets.json`
//! lists its datasets in the order made or in another (issue #23).

use crate::common;
#[path = "../harness/tests/common/permuted.rs"]
mod permuted;

use common::fits_table::{doubles, fits_table, text};
use common::{run_with, stderr, stepsim};
use permuted::{Row, normalise, pair};
use std::path::Path;

fn fits(rows: &[Row]) -> Vec<u8> {
    let ids: Vec<&str> = rows.iter().map(|r| r.0.as_str()).collect();
    let col = |f: fn(&Row) -> f64| rows.iter().map(f).collect::<Vec<f64>>();
    fits_table(&[
        text("IMAGE", &ids),
        doubles("X", &col(|r| r.1)),
        doubles("Y", &col(|r| r.2)),
        doubles("E1", &col(|r| r.3)),
        doubles("E2", &col(|r| r.4)),
        doubles("WEIGHT", &col(|r| r.5)),
    ])
}

/// (exit code, stderr with the truth and output paths replaced, files
/// written) of `stepsim score`.
fn score(truth: &Path, sub: &Path, out: &Path) -> (Option<i32>, String, usize) {
    let o = run_with(
        stepsim()
            .args(["score", "--bootstrap-resamples", "0", "--truth"])
            .arg(truth)
            .arg("--submission")
            .arg(sub)
            .arg("--out")
            .arg(out),
    );
    let written = std::fs::read_dir(out).map_or(0, |d| d.count());
    let message = normalise(&stderr(&o), truth).replace(&out.display().to_string(), "<out>");
    (o.status.code(), message, written)
}

#[test]
fn score_refuses_the_same_way_whatever_the_order_of_datasets_json() {
    let p = pair(&fits);
    let mut refused = 0;
    for (k, (name, sub)) in p.subs.iter().enumerate() {
        let a = score(&p.a, sub, &p.dir.path().join(format!("out-a-{k}")));
        let b = score(&p.b, sub, &p.dir.path().join(format!("out-b-{k}")));
        assert_eq!(a, b, "{name}: `stepsim score` depends on the private order");
        if a.0 == Some(1) {
            refused += 1;
            assert_eq!(a.2, 0, "{name}: a refusal wrote files");
            assert!(a.1.contains(name.as_str()), "{name}: {}", a.1);
        } else {
            assert_eq!(a.0, Some(0), "{name}: {}", a.1);
        }
    }
    assert_eq!(refused, p.subs.len() - 2);
    let missing = &p
        .subs
        .iter()
        .find(|s| s.0 == "missing_several.txt")
        .unwrap()
        .1;
    let (_, msg, _) = score(&p.b, missing, &p.dir.path().join("out-m"));
    assert!(
        msg.contains(
            "5 of 20 images have no rows (missing, smallest ids first: hi001f000, hi003f001, \
             i000f001, i004f000, i005f001); pass --allow-missing-images"
        ),
        "{msg}"
    );
}
