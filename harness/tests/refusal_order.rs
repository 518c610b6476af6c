//! No refusal depends on the private order of `datasets.json` (issue #23):
//! the battery of `common/permuted.rs`, scored through the library against
//! the same run listed in two orders, gives byte-identical messages (and
//! identical public feedback when it is accepted).

use crate::common;
#[path = "common/permuted.rs"]
mod permuted;

use common::{doubles, fits_table, text};
use permuted::{Row, normalise, pair};
use std::path::Path;
use stepsim_contract::run_layout::Part;
use stepsim_harness::{PublicFeedback, ScoreOptions, prepare, score_part};

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

/// What a participant (or the organiser) is told for `sub` scored against
/// `truth`: the whole run, each part, each with and without
/// `--allow-missing-images`. A refusal is its message; an accepted entry
/// its warnings and, for the public part, its public feedback.
fn outcomes(truth: &Path, sub: &Path) -> Vec<String> {
    let mut out = Vec::new();
    for allow in [false, true] {
        let mut opts = ScoreOptions::new(truth, sub);
        opts.allow_missing_images = allow;
        opts.bootstrap_resamples = 0;
        out.push(match prepare(&opts) {
            Ok(p) => format!("prepared; warnings {:?}", p.warnings),
            Err(e) => format!("refused: {e}"),
        });
        for part in [Part::Public, Part::Holdout] {
            out.push(match score_part(&opts, part) {
                Ok(r) => {
                    let feedback = (part == Part::Public)
                        .then(|| serde_json::to_string(&PublicFeedback::of_report(&r)).unwrap());
                    format!("{part:?} scored; warnings {:?}; {feedback:?}", r.warnings)
                }
                Err(e) => format!("{part:?} refused: {e}"),
            });
        }
    }
    out.iter().map(|m| normalise(m, truth)).collect()
}

#[test]
fn every_refusal_reads_the_same_whatever_the_order_of_datasets_json() {
    let p = pair(&fits);
    let mut refused = 0;
    for (name, sub) in &p.subs {
        let a = outcomes(&p.a, sub);
        let b = outcomes(&p.b, sub);
        assert_eq!(a, b, "{name}: the outcome depends on the private order");
        refused += usize::from(a[0].starts_with("refused"));
    }
    // Everything but the two complete submissions is refused.
    assert_eq!(refused, p.subs.len() - 2);
}

#[test]
fn the_battery_is_refused_for_the_reasons_it_was_built_for() {
    let p = pair(&fits);
    let want = [
        ("complete.txt", "prepared; warnings []"),
        (
            "missing_one.txt",
            "1 of 20 images have no rows (missing, smallest ids first: i003f001);",
        ),
        (
            "missing_several.txt",
            "5 of 20 images have no rows (missing, smallest ids first: hi001f000, \
             hi003f001, i000f001, i004f000, i005f001);",
        ),
        (
            "public_only.txt",
            "8 of 20 images have no rows (missing, smallest ids first: hi000f000, \
             hi000f001, hi001f000, hi001f001, hi002f000, …);",
        ),
        (
            "holdout_only.txt",
            "12 of 20 images have no rows (missing, smallest ids first: i000f000, \
             i000f001, i001f000, i001f001, i002f000, …);",
        ),
        ("one_image.txt", "19 of 20 images have no rows"),
        (
            "unknown_id.txt",
            "column `image`: unknown image id `i999f000`",
        ),
        ("unknown_id_and_missing.txt", "unknown image id `zz`"),
        ("bad_values.txt", "column `x`: x = -7 is off the image"),
        (
            "bad_values_swapped.txt",
            "column `e1`: value `NaN` is not finite",
        ),
        ("duplicate.txt", "duplicate row: image `i004f001`"),
        (
            "weight_overflow.txt",
            "weight 1e308 makes the weighted sums of image `i002f001` overflow",
        ),
        ("no_e2.txt", "column `e2`: required column missing"),
        ("x_twice.txt", "column `x`: column named twice"),
        (
            "too_many_columns.txt",
            "line 1: the header names 2006 columns, more than the 1024",
        ),
        ("missing_several.csv", "5 of 20 images have no rows"),
        ("missing_several.fits", "5 of 20 images have no rows"),
        (
            "unknown_id.fits",
            "row 18, column `image`: unknown image id `i003f009`",
        ),
        ("empty.txt", "no rows (empty table)"),
        ("dir_complete", "prepared; warnings []"),
        ("dir_missing_several", "5 of 20 images have no rows"),
        ("dir_second_file", "a second file for image `i003f000`"),
        ("dir_unknown", "unknown image id `i009f000`"),
        ("dir_bad_values", "hi002f001.txt: line 2, column `e1`"),
    ];
    assert_eq!(p.subs.len(), want.len());
    for ((name, sub), (want_name, want)) in p.subs.iter().zip(want) {
        assert_eq!(name, want_name);
        let got = &outcomes(&p.a, sub)[0];
        assert!(got.contains(want), "{name}: {got}");
    }
    // With --allow-missing-images, a submission of the public part only is
    // scored on it and refused nothing on the held-out part either way.
    let public_only = &p.subs.iter().find(|s| s.0 == "public_only.txt").unwrap().1;
    let o = outcomes(&p.a, public_only);
    assert!(o[4].starts_with("Public scored"), "{}", o[4]);
}
