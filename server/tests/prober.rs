//! The prober (issue #10: "a test plays the prober"): a participant spends
//! its whole quota on crafted submissions — zero shears, per-dataset
//! constants, scaled and partly scaled copies of a good catalogue, plus a
//! duplicate, a refused file and one past the quota — and reads every answer
//! the API gives it, trying to estimate the held-out shears.
//!
//! Three challenges are built from runs identical in their public part and
//! different only in the held-out shears. The prober plays the same game
//! against each; everything it sees (status and body of every answer, with
//! the times removed) is byte-identical across the three. Any estimate it
//! makes is a function of what it sees, so it is the same whatever the
//! held-out shears are: it cannot do better than a guess made without
//! playing.

use axum::body::Body;
use axum::http::{Request, header};
use http_body_util::BodyExt;
use serde_json::Value;
use std::path::Path;
use stepsim_server::Challenge;
use stepsim_server::{AppState, router};
use stepsim_testkit::synthetic::{SynthRun, SynthSpec, challenge_run, submission_text};
use tower::ServiceExt;

use crate::common;

/// Held-out shears of the three runs (within |g| ≤ 0.1).
const DRAWS: [[(f64, f64); 2]; 3] = [
    [(0.0371, -0.0523), (-0.0617, 0.0289)],
    [(-0.0800, 0.0100), (0.0200, 0.0700)],
    [(0.0000, 0.0000), (0.0900, -0.0300)],
];

fn spec() -> SynthSpec {
    let mut spec = SynthSpec::small(2);
    spec.psfs.truncate(2);
    spec.shears = vec![(0.0, 0.0), (0.05, 0.0)];
    spec
}

/// Removes what changes with the clock from an answer: the keys `created`
/// and `reset`, and times written in messages.
fn without_times(v: &mut Value) {
    match v {
        Value::String(s) => {
            let mut out = String::new();
            let mut rest = s.as_str();
            while !rest.is_empty() {
                if rest
                    .get(..20)
                    .is_some_and(|t| stepsim_server::parse_rfc3339(t).is_some())
                {
                    out.push_str("<time>");
                    rest = &rest[20..];
                } else {
                    let c = rest.chars().next().unwrap();
                    out.push(c);
                    rest = &rest[c.len_utf8()..];
                }
            }
            *s = out;
        }
        Value::Object(m) => {
            m.remove("created");
            m.remove("reset");
            for x in m.values_mut() {
                without_times(x);
            }
        }
        Value::Array(a) => a.iter_mut().for_each(without_times),
        _ => {}
    }
}

/// The prober's catalogues (the same bytes for every challenge: made from
/// its own measurement, here the first run's truth).
fn crafted(all: &SynthRun) -> Vec<Vec<u8>> {
    let index = all.index();
    let text = |rule: &stepsim_testkit::synthetic::Rule| {
        submission_text(&index, &all.submission(rule)).into_bytes()
    };
    vec![
        // A good catalogue.
        text(&|t, _| (!t.is_star()).then_some((t.e1, t.e2, 1.0))),
        // Zero shear everywhere.
        text(&|t, _| (!t.is_star()).then_some((0.0, 0.0, 1.0))),
        // A constant per dataset.
        text(&|t, d| (!t.is_star()).then_some((0.02 * (d % 3) as f64 - 0.02, 0.01, 1.0))),
        // The good catalogue scaled by 1.5 on every other dataset.
        text(&|t, d| {
            let k = if d % 2 == 1 { 1.5 } else { 1.0 };
            (!t.is_star()).then_some((k * t.e1, k * t.e2, 1.0))
        }),
        // One more, past the quota.
        text(&|t, _| (!t.is_star()).then_some((1.1 * t.e1, 1.1 * t.e2, 1.0))),
    ]
}

/// Plays the prober against the challenge of a run whose held-out shears
/// are `draw`; returns its transcript and its estimate.
async fn play(dir: &Path, draw: &[(f64, f64)], catalogues: &[Vec<u8>]) -> (String, Vec<f64>) {
    let (_, held, all) = challenge_run(&spec(), draw, 7);
    let truth_g: Vec<(f64, f64)> = held
        .datasets
        .datasets
        .iter()
        .map(|d| (d.g1, d.g2))
        .collect();
    // Two PSFs, each with the draw's shears.
    assert_eq!(truth_g, [draw, draw].concat());
    all.write(&dir.join("run/private")).unwrap();
    let ch = common::init(&dir.join("run"), &dir.join("state"), 4, false)
        .await
        .unwrap();
    let token = ch.add_team("prober").await.unwrap();
    drop(ch);
    let app = router(AppState::new(
        Challenge::open(&dir.join("state")).await.unwrap(),
    ));
    let mut transcript = String::new();
    let mut see = async |req: Request<Body>| -> Value {
        let what = format!("{} {}", req.method(), req.uri());
        let resp = app.clone().oneshot(req).await.unwrap();
        let status = resp.status();
        let body = resp.into_body().collect().await.unwrap().to_bytes();
        let mut v: Value = serde_json::from_slice(&body).unwrap();
        without_times(&mut v);
        transcript.push_str(&format!("{what} -> {status} {v}\n"));
        v
    };
    let get = |path: &str| {
        Request::get(path)
            .header(header::AUTHORIZATION, format!("Bearer {token}"))
            .body(Body::empty())
            .unwrap()
    };
    let post = |bytes: Vec<u8>| {
        Request::post("/api/submissions")
            .header(header::AUTHORIZATION, format!("Bearer {token}"))
            .body(Body::from(bytes))
            .unwrap()
    };
    see(get("/api/challenge")).await;
    let mut ids = Vec::new();
    for (k, c) in catalogues.iter().enumerate() {
        let v = see(post(c.clone())).await;
        if let Some(id) = v["id"].as_i64() {
            ids.push(id);
        }
        if k == 0 {
            see(post(c.clone())).await; // a duplicate
            see(post(b"i0 1 2 3 4 5\n".to_vec())).await; // refused, with its message
        }
    }
    assert_eq!(ids.len(), 4, "the whole quota is spent: {transcript}");
    // Score the queue as a worker does.
    let ch = Challenge::open(&dir.join("state")).await.unwrap();
    while let Some(job) = ch.store.claim_job(&common::lease(), 0).await.unwrap() {
        let r = stepsim_server::score_entry(&ch, &job);
        ch.store
            .finish_job(job.id, "test", r, stepsim_server::SCORER_VERSION, 0)
            .await
            .unwrap();
    }
    let mut m = Vec::new();
    for id in &ids {
        let v = see(get(&format!("/api/submissions/{id}"))).await;
        assert_eq!(v["status"], "scored", "{v}");
        m.push(v["public"]["m_mean"].as_f64().unwrap());
    }
    see(get("/api/submissions")).await;
    see(get("/api/leaderboard")).await;
    see(Request::put("/api/final")
        .header(header::AUTHORIZATION, format!("Bearer {token}"))
        .body(Body::from(format!("{{\"entries\": [{}]}}", ids[3])))
        .unwrap())
    .await;
    see(get("/api/submissions")).await;
    see(get("/api/leaderboard")).await;
    // The estimate: each held-out dataset's g1 and g2 from the feedback's
    // response to the crafted catalogues (any rule would do: it can only
    // use what it saw).
    let estimate = vec![m[3] - m[0], m[2] - m[1], m[1] * 0.5, m[2] + m[3]];
    (transcript, estimate)
}

#[tokio::test]
async fn a_prober_spending_its_quota_learns_nothing_about_the_held_out_shears() {
    let tmp = tempfile::tempdir().unwrap();
    let (_, _, first) = challenge_run(&spec(), &DRAWS[0], 7);
    let catalogues = crafted(&first);
    let mut seen = Vec::new();
    for (k, draw) in DRAWS.iter().enumerate() {
        let dir = tmp.path().join(format!("c{k}"));
        seen.push(play(&dir, draw, &catalogues).await);
    }
    let (transcript, estimate) = &seen[0];
    // The feedback is real: scored entries with numbers that differ.
    assert!(transcript.contains("\"status\":\"scored\""), "{transcript}");
    assert!(transcript.contains("unknown image id") || transcript.contains("line 1"));
    assert!(
        transcript.contains("429"),
        "the quota was reached: {transcript}"
    );
    assert!(estimate.iter().any(|e| *e != 0.0), "{estimate:?}");
    for (k, (t, e)) in seen.iter().enumerate().skip(1) {
        assert_eq!(t, transcript, "draw {k}: the prober saw something else");
        assert_eq!(e, estimate, "draw {k}");
    }
    // The same estimate for three different truths: its error is the
    // truth's own spread, as for a guess made without playing.
    let errors: Vec<f64> = DRAWS.iter().map(|d| (estimate[0] - d[0].0).abs()).collect();
    assert!(errors.windows(2).all(|w| w[0] != w[1]), "{errors:?}");
}
