//! Scoring one part of a challenge run gives exactly the numbers of
//! `stepsim score` on a run that holds only that part's datasets, and the
//! public feedback is those numbers rounded.

use stepsim_contract::run_layout::Part;
use stepsim_contract::truth::TruthRow;
use stepsim_harness::{
    FEEDBACK_DECIMALS, PublicFeedback, ScoreOptions, has_holdout, round_to, score, score_part,
};
use stepsim_testkit::synthetic::{self, SynthRun, SynthSpec, submission_text};

/// A public part (2 PSFs × 3 STEP1 shears on 2 fields) and a held-out part
/// (the same PSFs, other shears, other fields, ids of its own).
fn challenge_run() -> (SynthRun, SynthRun) {
    let mut spec = SynthSpec::small(2);
    spec.psfs.truncate(2);
    spec.shears = vec![(0.0, 0.0), (0.01, 0.0), (0.05, 0.0)];
    let (public, held, _) =
        synthetic::challenge_run(&spec, &[(0.031, -0.044), (-0.02, 0.07), (0.066, 0.012)], 99);
    (public, held)
}

fn join(a: &SynthRun, b: &SynthRun) -> SynthRun {
    let mut all = a.clone();
    all.datasets
        .datasets
        .extend(b.datasets.datasets.iter().cloned());
    all.truth.extend(b.truth.iter().cloned());
    all
}

/// A biased catalogue: m = 0.02, c1 = 1e-3, with a third of the stars kept
/// at weight 0 (they count as contamination, not in the shear means).
fn catalogue(run: &SynthRun) -> String {
    let rows = run.submission(&|t: &TruthRow, _| {
        if t.is_star() {
            return (t.id % 3 == 0).then_some((0.0, 0.0, 0.0));
        }
        Some((1.02 * t.e1 + 1e-3, 1.02 * t.e2, 1.0))
    });
    submission_text(&run.index(), &rows)
}

fn numbers(r: &stepsim_harness::Report) -> serde_json::Value {
    let mut v = serde_json::to_value(r).unwrap();
    let o = v.as_object_mut().unwrap();
    o.remove("run");
    o.remove("submission");
    o.remove("warnings");
    v
}

#[test]
fn a_part_scores_as_a_run_of_that_part_alone() {
    let dir = tempfile::tempdir().unwrap();
    let (public, held) = challenge_run();
    let whole = join(&public, &held);
    whole.write(&dir.path().join("whole")).unwrap();
    public.write(&dir.path().join("pub")).unwrap();
    held.write(&dir.path().join("held")).unwrap();
    assert!(has_holdout(&whole.datasets) && !has_holdout(&public.datasets));
    let sub = dir.path().join("sub.txt");
    std::fs::write(&sub, catalogue(&whole)).unwrap();
    // The same catalogue restricted to each part's images.
    for (part, alone) in [(Part::Public, &public), (Part::Holdout, &held)] {
        let name = part.name();
        let only = dir.path().join(format!("sub-{name}.txt"));
        let text = catalogue(&whole);
        let ids: std::collections::HashSet<String> = alone
            .index()
            .images
            .iter()
            .map(|i| i.image.clone())
            .collect();
        let kept: String = text
            .lines()
            .filter(|l| l.starts_with('#') || ids.contains(l.split(' ').next().unwrap()))
            .map(|l| format!("{l}\n"))
            .collect();
        std::fs::write(&only, kept).unwrap();
        let want = score(&ScoreOptions::new(
            dir.path().join(match part {
                Part::Public => "pub",
                Part::Holdout => "held",
            }),
            &only,
        ))
        .unwrap();
        let got = score_part(&ScoreOptions::new(dir.path().join("whole"), &sub), part).unwrap();
        assert_eq!(numbers(&got), numbers(&want), "{name}");
        assert_eq!(got.datasets.len(), 6);
        assert!(got.run.ends_with(&format!("#{name}")), "{}", got.run);
    }
    // The whole run scores otherwise: the restriction matters.
    let all = score(&ScoreOptions::new(dir.path().join("whole"), &sub)).unwrap();
    assert_eq!(all.datasets.len(), 12);
    let public_only = score_part(
        &ScoreOptions::new(dir.path().join("whole"), &sub),
        Part::Public,
    )
    .unwrap();
    assert_ne!(numbers(&all)["summary"], numbers(&public_only)["summary"]);
    // A run without held-out datasets has no held-out part to score.
    let err = score_part(
        &ScoreOptions::new(dir.path().join("pub"), dir.path().join("sub-public.txt")),
        Part::Holdout,
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("no dataset of the holdout part"), "{err}");
    assert!(err.contains("datasets.json"), "{err}");
}

#[test]
fn a_submission_is_checked_against_the_whole_run() {
    // An error in a held-out image's row is reported when scoring the
    // public part too, with the harness's message (the participant cannot
    // tell the parts apart, and must not learn which images are held out
    // from which errors are reported).
    let dir = tempfile::tempdir().unwrap();
    let (public, held) = challenge_run();
    let whole = join(&public, &held);
    whole.write(&dir.path().join("whole")).unwrap();
    let held_image = held.index().images[0].image.clone();
    let mut text = catalogue(&whole);
    text.push_str(&format!("{held_image} 1e9 5 0 0 1\n"));
    let sub = dir.path().join("bad.txt");
    std::fs::write(&sub, &text).unwrap();
    let want = score(&ScoreOptions::new(dir.path().join("whole"), &sub))
        .unwrap_err()
        .to_string();
    let got = score_part(
        &ScoreOptions::new(dir.path().join("whole"), &sub),
        Part::Public,
    )
    .unwrap_err()
    .to_string();
    assert_eq!(got, want);
    assert!(got.contains("line"), "{got}");
}

#[test]
fn public_feedback_is_the_summary_rounded() {
    let dir = tempfile::tempdir().unwrap();
    let (public, held) = challenge_run();
    let whole = join(&public, &held);
    whole.write(&dir.path().join("whole")).unwrap();
    let sub = dir.path().join("sub.txt");
    std::fs::write(&sub, catalogue(&whole)).unwrap();
    let r = score_part(
        &ScoreOptions::new(dir.path().join("whole"), &sub),
        Part::Public,
    )
    .unwrap();
    let f = PublicFeedback::of_report(&r);
    let dec = |k: &str| FEEDBACK_DECIMALS.iter().find(|d| d.0 == k).unwrap().1;
    assert_eq!(f.m_mean, round_to(r.summary.m_mean, dec("m_mean")));
    assert_eq!(f.sigma_c, round_to(r.summary.sigma_c, dec("sigma_c")));
    assert_eq!(f.q_c, round_to(r.summary.q_c, dec("q_c")));
    let stars = r.datasets.iter().map(|d| d.pct_stars).sum::<f64>() / 6.0;
    assert_eq!(f.pct_stars, round_to(Some(stars), 1));
    assert!(f.pct_stars.unwrap() > 0.0, "stars were kept");
    // m = 0.02 is recovered to the stated precision.
    assert!((f.m_mean.unwrap() - 0.02).abs() <= 0.002, "{:?}", f.m_mean);
    // The JSON names are the summary's.
    let v = serde_json::to_value(&f).unwrap();
    let keys: Vec<&str> = v.as_object().unwrap().keys().map(String::as_str).collect();
    assert_eq!(keys, ["m_mean", "pct_false", "pct_stars", "q_c", "sigma_c"]);
}
