//! The JSON API in-process (tower's `oneshot`): tokens, escaping and
//! headers, the size cap, the quota, refused uploads, scoring through the
//! queue with the harness's numbers, and a participant's walk over routes.

use axum::body::Body;
use axum::http::{Request, StatusCode, header};
use http_body_util::BodyExt;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use stepsim_contract::run_layout::Part;
use stepsim_harness::{PublicFeedback, ScoreOptions, score_part};
use stepsim_server::Challenge;
use stepsim_server::{AppState, router};
use stepsim_testkit::synthetic::SynthRun;
use tower::ServiceExt;

use crate::common;
use common::{catalogue, write_run};

struct Fixture {
    _tmp: tempfile::TempDir,
    state: PathBuf,
    truth: PathBuf,
    all: SynthRun,
    held: SynthRun,
    tokens: Vec<String>,
}

async fn fixture(quota: u32, teams: &[&str]) -> Fixture {
    let tmp = tempfile::tempdir().unwrap();
    let (all, held) = write_run(tmp.path());
    let state = tmp.path().join("state");
    let ch = common::init(&tmp.path().join("run"), &state, quota, false)
        .await
        .unwrap();
    let mut tokens = Vec::new();
    for t in teams {
        tokens.push(ch.add_team(t).await.unwrap());
    }
    Fixture {
        truth: ch.settings.truth_dir.clone(),
        _tmp: tmp,
        state,
        all,
        held,
        tokens,
    }
}

impl Fixture {
    async fn app(&self) -> axum::Router {
        router(AppState::new(Challenge::open(&self.state).await.unwrap()))
    }
    async fn set(&self, key: &str, value: &str) {
        let ch = Challenge::open(&self.state).await.unwrap();
        ch.store.set_meta(key, value).await.unwrap();
    }
    /// Scores every queued job now (what a worker does).
    async fn score_queue(&self) {
        common::score_queue(&self.state).await;
    }
}

async fn call(
    app: &axum::Router,
    req: Request<Body>,
) -> (StatusCode, axum::http::HeaderMap, String) {
    let resp = app.clone().oneshot(req).await.unwrap();
    let status = resp.status();
    let headers = resp.headers().clone();
    let body = resp.into_body().collect().await.unwrap().to_bytes();
    (status, headers, String::from_utf8_lossy(&body).into_owned())
}

fn get(path: &str, token: Option<&str>) -> Request<Body> {
    let mut r = Request::get(path);
    if let Some(t) = token {
        r = r.header(header::AUTHORIZATION, format!("Bearer {t}"));
    }
    r.body(Body::empty()).unwrap()
}

fn upload(token: &str, body: impl Into<Body>) -> Request<Body> {
    Request::post("/api/submissions")
        .header(header::AUTHORIZATION, format!("Bearer {token}"))
        .body(body.into())
        .unwrap()
}

/// Equal JSON trees, numbers to 1e-9 relative (1e-20 absolute): the
/// harness's bootstrap of a σ_c at rounding level (1e-13) is not
/// bit-reproducible between two scorings of one file (reported, harness).
fn assert_close(got: &Value, want: &Value, at: &str) {
    match (got, want) {
        (Value::Number(a), Value::Number(b)) => {
            let (a, b) = (a.as_f64().unwrap(), b.as_f64().unwrap());
            assert!(
                (a - b).abs() <= 1e-9 * a.abs().max(b.abs()) + 1e-20,
                "{at}: {a} != {b}"
            );
        }
        (Value::Object(a), Value::Object(b)) => {
            assert_eq!(a.len(), b.len(), "{at}: keys differ");
            for (k, v) in b {
                assert_close(&a[k], v, &format!("{at}.{k}"));
            }
        }
        (Value::Array(a), Value::Array(b)) => {
            assert_eq!(a.len(), b.len(), "{at}: lengths differ");
            for (i, (x, y)) in a.iter().zip(b).enumerate() {
                assert_close(x, y, &format!("{at}[{i}]"));
            }
        }
        _ => assert_eq!(got, want, "{at}"),
    }
}

fn json(s: &str) -> Value {
    serde_json::from_str(s).unwrap_or_else(|e| panic!("not JSON ({e}): {s}"))
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[tokio::test]
async fn tokens_gate_every_route_and_entries_stay_with_their_team() {
    let f = fixture(4, &["alpha", "beta", "gamma"]).await;
    let app = f.app().await;
    let (s, _, body) = call(&app, upload(&f.tokens[0], catalogue(&f.all, 0.0))).await;
    assert_eq!(s, StatusCode::ACCEPTED, "{body}");
    let id = json(&body)["id"].as_i64().unwrap();
    assert_eq!(json(&body)["status"], "queued");
    let own = format!("/api/submissions/{id}");
    // No token, a forged one, a malformed header: 401 with a JSON error.
    for token in [None, Some("stp_0000"), Some("")] {
        for path in ["/api/submissions", own.as_str()] {
            let (s, h, body) = call(&app, get(path, token)).await;
            assert_eq!(s, StatusCode::UNAUTHORIZED, "{path} {token:?}");
            assert!(json(&body)["error"].as_str().unwrap().contains("token"));
            assert_eq!(h[header::WWW_AUTHENTICATE], "Bearer");
        }
        let (s, _, _) = call(&app, upload(token.unwrap_or(""), "x")).await;
        assert_eq!(s, StatusCode::UNAUTHORIZED);
    }
    // Another team's entry: 404, the same answer as a missing one.
    let (s, _, other) = call(&app, get(&own, Some(&f.tokens[1]))).await;
    let (s2, _, missing) = call(&app, get("/api/submissions/999", Some(&f.tokens[1]))).await;
    assert_eq!((s, s2), (StatusCode::NOT_FOUND, StatusCode::NOT_FOUND));
    assert_eq!(other, missing);
    let (_, _, list) = call(&app, get("/api/submissions", Some(&f.tokens[1]))).await;
    assert_eq!(json(&list)["submissions"], serde_json::json!([]));
    // The owner sees it.
    let (s, _, mine) = call(&app, get(&own, Some(&f.tokens[0]))).await;
    assert_eq!(s, StatusCode::OK);
    assert_eq!(json(&mine)["status"], "queued");
    // Revoked and rotated tokens stop working; the new one works.
    let ch = Challenge::open(&f.state).await.unwrap();
    ch.revoke("gamma").await.unwrap();
    let (s, _, _) = call(&app, get("/api/submissions", Some(&f.tokens[2]))).await;
    assert_eq!(s, StatusCode::UNAUTHORIZED);
    let new = ch.rotate_token("alpha").await.unwrap();
    let (s, _, _) = call(&app, get(&own, Some(&f.tokens[0]))).await;
    assert_eq!(s, StatusCode::UNAUTHORIZED);
    let (s, _, _) = call(&app, get(&own, Some(&new))).await;
    assert_eq!(s, StatusCode::OK);
    // Only the hash of a token is stored.
    let db = common::store_text(&f.state).await;
    assert!(db.contains("alpha") && !db.contains(&new) && !db.contains(&f.tokens[1]));
}

#[tokio::test]
async fn names_stay_text_and_answers_carry_security_headers() {
    let f = fixture(4, &["<script>alert(1)</script>"]).await;
    let app = f.app().await;
    let (s, _, _) = call(&app, upload(&f.tokens[0], catalogue(&f.all, 0.01))).await;
    assert_eq!(s, StatusCode::ACCEPTED);
    f.score_queue().await;
    let (s, h, body) = call(&app, get("/api/leaderboard", None)).await;
    assert_eq!(s, StatusCode::OK);
    assert_eq!(h[header::CONTENT_TYPE], "application/json");
    assert_eq!(h[header::X_CONTENT_TYPE_OPTIONS], "nosniff");
    assert_eq!(h[header::X_FRAME_OPTIONS], "DENY");
    assert!(
        h[header::CONTENT_SECURITY_POLICY]
            .to_str()
            .unwrap()
            .contains("default-src 'none'")
    );
    assert_eq!(json(&body)["rows"][0]["team"], "<script>alert(1)</script>");
    // Names with control characters are refused at `team add`.
    let ch = Challenge::open(&f.state).await.unwrap();
    assert!(ch.add_team("a\u{7}b").await.is_err());
    assert!(
        ch.add_team("<script>alert(1)</script>").await.is_err(),
        "names are unique"
    );
}

#[tokio::test]
async fn uploads_past_the_cap_get_413_and_leave_nothing() {
    let f = fixture(4, &["alpha"]).await;
    f.set("max_upload_bytes", "1000").await;
    let app = f.app().await;
    let big = catalogue(&f.all, 0.0);
    assert!(big.len() > 5_000, "{}", big.len());
    // Announced by Content-Length, and streamed without one.
    let mut announced = upload(&f.tokens[0], big.clone());
    announced.headers_mut().insert(
        header::CONTENT_LENGTH,
        big.len().to_string().parse().unwrap(),
    );
    let (s, _, body) = call(&app, announced).await;
    assert_eq!(s, StatusCode::PAYLOAD_TOO_LARGE, "{body}");
    assert!(
        json(&body)["error"]
            .as_str()
            .unwrap()
            .contains("limit of 1000 bytes")
    );
    let stream = Body::new(Chunked(
        big.as_bytes().chunks(500).map(<[u8]>::to_vec).collect(),
    ));
    let (s, _, body) = call(&app, upload(&f.tokens[0], stream)).await;
    assert_eq!(s, StatusCode::PAYLOAD_TOO_LARGE);
    assert!(
        json(&body)["error"]
            .as_str()
            .unwrap()
            .contains("limit of 1000 bytes")
    );
    assert!(files_in(&f.state.join("uploads")).is_empty());
    let (_, _, list) = call(&app, get("/api/submissions", Some(&f.tokens[0]))).await;
    assert_eq!(json(&list)["submissions"], serde_json::json!([]));
}

/// A body of chunks without a known length (no Content-Length).
struct Chunked(std::collections::VecDeque<Vec<u8>>);

impl http_body::Body for Chunked {
    type Data = axum::body::Bytes;
    type Error = std::io::Error;
    fn poll_frame(
        self: std::pin::Pin<&mut Self>,
        _: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Option<Result<http_body::Frame<Self::Data>, Self::Error>>> {
        let next = self.get_mut().0.pop_front();
        std::task::Poll::Ready(next.map(|c| Ok(http_body::Frame::data(c.into()))))
    }
}

#[tokio::test]
async fn the_quota_counts_accepted_uploads_and_says_when_it_resets() {
    let f = fixture(2, &["alpha", "beta"]).await;
    let app = f.app().await;
    for m in [0.0, 0.01] {
        let (s, _, body) = call(&app, upload(&f.tokens[0], catalogue(&f.all, m))).await;
        assert_eq!(s, StatusCode::ACCEPTED, "{body}");
    }
    // The same bytes again are recognised, not counted.
    let (s, _, body) = call(&app, upload(&f.tokens[0], catalogue(&f.all, 0.0))).await;
    assert_eq!(s, StatusCode::TOO_MANY_REQUESTS, "quota first: {body}");
    let (s, h, body) = call(&app, upload(&f.tokens[0], catalogue(&f.all, 0.02))).await;
    assert_eq!(s, StatusCode::TOO_MANY_REQUESTS);
    let v = json(&body);
    assert!(
        v["error"].as_str().unwrap().contains("quota of 2"),
        "{body}"
    );
    let reset = v["reset"].as_str().unwrap();
    assert!(reset.ends_with('Z') && reset.len() == 20, "{reset}");
    let wait: i64 = h[header::RETRY_AFTER].to_str().unwrap().parse().unwrap();
    assert!((23 * 3600..=24 * 3600).contains(&wait), "{wait}");
    // Another team is not affected; the list shows the quota.
    let (s, _, _) = call(&app, upload(&f.tokens[1], catalogue(&f.all, 0.0))).await;
    assert_eq!(s, StatusCode::ACCEPTED);
    let (_, _, list) = call(&app, get("/api/submissions", Some(&f.tokens[0]))).await;
    let q = &json(&list)["quota"];
    assert_eq!(
        (q["used"].as_u64(), q["limit"].as_u64()),
        (Some(2), Some(2))
    );
    assert_eq!(q["reset"].as_str(), Some(reset));
}

#[tokio::test]
async fn duplicates_are_recognised() {
    let f = fixture(4, &["alpha"]).await;
    let app = f.app().await;
    let (_, _, a) = call(&app, upload(&f.tokens[0], catalogue(&f.all, 0.0))).await;
    let (s, _, b) = call(&app, upload(&f.tokens[0], catalogue(&f.all, 0.0))).await;
    assert_eq!(s, StatusCode::OK);
    assert_eq!(json(&b)["id"], json(&a)["id"]);
    assert_eq!(json(&b)["duplicate"], true);
    assert_eq!(files_in(&f.state.join("uploads")).len(), 1);
}

#[tokio::test]
async fn a_run_that_cannot_be_read_is_not_the_uploads_fault() {
    // The run's config.json broken after init (the organisers' side): an
    // upload is answered 503, not counted as a refusal, shown nothing of
    // the private file; mended, the same upload is taken.
    let f = fixture(4, &["alpha"]).await;
    f.set("format_failure_cap", "1").await;
    let app = f.app().await;
    let good = catalogue(&f.all, 0.0);
    let config = f.truth.join("config.json");
    let kept = std::fs::read(&config).unwrap();
    std::fs::write(
        &config,
        r#"{"population": {"lens_positions": "private words"}}"#,
    )
    .unwrap();
    for _ in 0..3 {
        let (s, _, body) = call(&app, upload(&f.tokens[0], good.clone())).await;
        assert_eq!(s, StatusCode::SERVICE_UNAVAILABLE, "{body}");
        let msg = json(&body)["error"].as_str().unwrap().to_owned();
        assert!(msg.contains("not counted"), "{msg}");
        assert!(
            !msg.contains("private words") && !msg.contains("config.json"),
            "{msg}"
        );
    }
    assert!(files_in(&f.state.join("uploads")).is_empty());
    std::fs::write(&config, kept).unwrap();
    let (s, _, body) = call(&app, upload(&f.tokens[0], good)).await;
    assert_eq!(s, StatusCode::ACCEPTED, "past a cap of 1 refusal: {body}");
}

#[tokio::test]
async fn bad_uploads_get_the_harness_message_and_change_nothing() {
    let f = fixture(4, &["alpha", "beta"]).await;
    f.set("format_failure_cap", "5").await;
    let app = f.app().await;
    let good = catalogue(&f.all, 0.0);
    let first_line = good.lines().nth(1).unwrap();
    let id = first_line.split(' ').next().unwrap();
    let truncated = &good[..good.len() / 2 + 7];
    let wrong_id = good.replacen(id, "i0000000000000000", 1);
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("empty", vec![], "no rows"),
        (
            "binary",
            vec![0u8, 159, 146, 150, 0, 1, 2, 3, 10, 0],
            "binary",
        ),
        ("truncated", truncated.as_bytes().to_vec(), "line"),
        ("wrong id", wrong_id.into_bytes(), "unknown image id"),
    ];
    for (what, bytes, says) in cases {
        let (s, _, body) = call(&app, upload(&f.tokens[0], bytes)).await;
        assert_eq!(s, StatusCode::UNPROCESSABLE_ENTITY, "{what}: {body}");
        let msg = json(&body)["error"].as_str().unwrap().to_owned();
        assert!(msg.to_lowercase().contains(says), "{what}: {msg}");
        assert!(
            !msg.contains(f.state.to_str().unwrap()),
            "{what}: a server path: {msg}"
        );
        assert!(
            !msg.contains(f.truth.to_str().unwrap()),
            "{what}: a server path: {msg}"
        );
    }
    assert!(files_in(&f.state.join("uploads")).is_empty());
    let (_, _, list) = call(&app, get("/api/submissions", Some(&f.tokens[0]))).await;
    assert_eq!(json(&list)["submissions"], serde_json::json!([]));
    assert_eq!(json(&list)["quota"]["used"], 0, "refusals use no quota");
    // The cap on refusals: the fifth is the last.
    let (s, _, _) = call(&app, upload(&f.tokens[0], "x")).await;
    assert_eq!(s, StatusCode::UNPROCESSABLE_ENTITY);
    let (s, _, body) = call(&app, upload(&f.tokens[0], good.clone())).await;
    assert_eq!(s, StatusCode::TOO_MANY_REQUESTS, "{body}");
    assert!(
        json(&body)["error"]
            .as_str()
            .unwrap()
            .contains("5 refused uploads")
    );
    // Multipart without a `file` field is a 400 with a JSON error (another
    // team: alpha is past its cap).
    let b = "--XyZ\r\nContent-Disposition: form-data; name=\"other\"\r\n\r\nabc\r\n--XyZ--\r\n";
    let req = Request::post("/api/submissions")
        .header(header::AUTHORIZATION, format!("Bearer {}", f.tokens[1]))
        .header(header::CONTENT_TYPE, "multipart/form-data; boundary=XyZ")
        .body(Body::from(b))
        .unwrap();
    let (s, _, body) = call(&app, req).await;
    assert_eq!(s, StatusCode::BAD_REQUEST, "{body}");
    assert!(json(&body)["error"].as_str().unwrap().contains("`file`"));
}

#[tokio::test]
async fn an_entry_is_scored_as_stepsim_score_scores_its_part() {
    let f = fixture(4, &["alpha", "beta"]).await;
    let app = f.app().await;
    let text = catalogue(&f.all, 0.02);
    let b = format!(
        "--XyZ\r\nContent-Disposition: form-data; name=\"file\"; filename=\"c.txt\"\r\n\
         Content-Type: text/plain\r\n\r\n{text}\r\n--XyZ--\r\n"
    );
    let req = Request::post("/api/submissions")
        .header(header::AUTHORIZATION, format!("Bearer {}", f.tokens[0]))
        .header(header::CONTENT_TYPE, "multipart/form-data; boundary=XyZ")
        .body(Body::from(b))
        .unwrap();
    let (s, _, body) = call(&app, req).await;
    assert_eq!(s, StatusCode::ACCEPTED, "{body}");
    let id = json(&body)["id"].as_i64().unwrap();
    // The stored file is the upload, byte for byte.
    let stored = files_in(&f.state.join("uploads"));
    assert_eq!(
        std::fs::read(f.state.join("uploads").join(&stored[0])).unwrap(),
        text.as_bytes()
    );
    // A worker scores it.
    let stop = Arc::new(AtomicBool::new(false));
    let (dir, stop2) = (f.state.clone(), stop.clone());
    let w = std::thread::spawn(move || {
        stepsim_server::run_worker(&dir, stop2, stepsim_server::DEFAULT_TIMEOUT)
    });
    let mut entry = Value::Null;
    for _ in 0..600 {
        let (_, _, e) = call(
            &app,
            get(&format!("/api/submissions/{id}"), Some(&f.tokens[0])),
        )
        .await;
        entry = json(&e);
        if entry["status"] == "scored" || entry["status"] == "refused" {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    w.join().unwrap().unwrap();
    assert_eq!(entry["status"], "scored", "{entry}");
    // The feedback is the harness's public-part report, rounded.
    let copy = f.state.join("copy.txt");
    std::fs::write(&copy, &text).unwrap();
    let want = score_part(&ScoreOptions::new(&f.truth, &copy), Part::Public).unwrap();
    let want = serde_json::to_value(PublicFeedback::of_report(&want)).unwrap();
    assert_eq!(entry["public"], want);
    assert!((entry["public"]["m_mean"].as_f64().unwrap() - 0.02).abs() < 0.002);
    assert!(
        entry.get("holdout").is_none(),
        "held out until reveal: {entry}"
    );
    // Reports kept per entry, both parts.
    for part in ["public", "holdout"] {
        let d = f.state.join(format!("entries/{id}/{part}"));
        for file in ["report.json", "report.md", "fig2_shear_response.png"] {
            assert!(d.join(file).is_file(), "{part}/{file}");
        }
    }
    let ch = Challenge::open(&f.state).await.unwrap();
    assert_eq!(
        ch.store.submission(id).await.unwrap().unwrap().n_scorings,
        1
    );
    // The leaderboard: one row (beta has no entry), public figures only.
    let (_, _, lb) = call(&app, get("/api/leaderboard", None)).await;
    let lb = json(&lb);
    assert_eq!(lb["revealed"], false);
    assert_eq!(lb["rows"].as_array().unwrap().len(), 1);
    assert_eq!(lb["rows"][0]["team"], "alpha");
    assert_eq!(lb["rows"][0]["public"], want);
    assert!(lb["rows"][0].get("holdout").is_none());
    // After reveal: the held-out summary, as the harness scores that part.
    let ch = Challenge::open(&f.state).await.unwrap();
    ch.reveal().await.unwrap();
    let held = score_part(&ScoreOptions::new(&f.truth, &copy), Part::Holdout).unwrap();
    let (_, _, lb) = call(&app, get("/api/leaderboard", None)).await;
    let lb = json(&lb);
    assert_eq!(lb["revealed"], true);
    // The summary as report.json carries it (stored as JSON text, read back).
    let held_json: Value =
        serde_json::from_str(&serde_json::to_string(&held.summary).unwrap()).unwrap();
    assert_close(&lb["rows"][0]["holdout"], &held_json, "holdout");
    let (_, _, e) = call(
        &app,
        get(&format!("/api/submissions/{id}"), Some(&f.tokens[0])),
    )
    .await;
    assert_eq!(
        json(&e)["holdout"]["m_mean"],
        serde_json::json!(held.summary.m_mean)
    );
}

#[tokio::test]
async fn a_participant_walking_every_route_sees_no_truth_and_no_server_path() {
    let f = fixture(4, &["alpha", "beta"]).await;
    let app = f.app().await;
    let (_, _, body) = call(&app, upload(&f.tokens[0], catalogue(&f.all, 0.01))).await;
    let id = json(&body)["id"].as_i64().unwrap();
    f.score_queue().await;
    let sha = files_in(&f.state.join("uploads"))[0].clone();
    let paths = [
        "/".to_string(),
        "/api".into(),
        "/api/leaderboard".into(),
        "/api/submissions".into(),
        format!("/api/submissions/{id}"),
        format!("/api/submissions/{}", id + 1),
        "/api/submissions/1/../../../run/private/datasets.json".into(),
        "/../run/private/datasets.json".into(),
        "/%2e%2e/%2e%2e/run/private/datasets.json".into(),
        "/challenge.db".into(),
        format!("/uploads/{sha}"),
        format!("/entries/{id}/holdout/report.json"),
        format!("/entries/{id}/public/report.json"),
        "/private/truth".into(),
        "/api/submissions/-1".into(),
        "/api/submissions/1e3".into(),
        "/api/challenge".into(),
        "/api/final".into(),
        "/data".into(),
        "/data/".into(),
        "/data/manifest.json".into(),
        "/data/../private/datasets.json".into(),
        "/data/..%2Fprivate%2Fdatasets.json".into(),
        "/data/%2e%2e/%2e%2e/state/challenge.db".into(),
    ];
    // Values a leak would show: held-out shears and dataset ids, image ids
    // of the held-out part, paths of the server.
    let mut secrets: Vec<String> = Vec::new();
    for d in &f.held.datasets.datasets {
        secrets.push(d.dataset.clone());
        secrets.push(format!("{}", d.g1));
        secrets.push(format!("{}", d.g2));
        secrets.extend(d.images.iter().map(|i| i.image.clone()));
    }
    secrets.push(f.truth.display().to_string());
    secrets.push(f.state.display().to_string());
    secrets.push("holdout".into());
    secrets.push("truth".into());
    for token in [Some(f.tokens[0].as_str()), Some(f.tokens[1].as_str()), None] {
        for path in &paths {
            let (s, _, body) = call(&app, get(path, token)).await;
            assert!(s == StatusCode::OK || s.is_client_error(), "{path}: {s}");
            for secret in &secrets {
                assert!(
                    !body.contains(secret.as_str()),
                    "{path} shows {secret:?}: {body}"
                );
            }
        }
    }
}

#[tokio::test]
async fn a_job_interrupted_while_scoring_is_scored_once_after_a_restart() {
    let f = fixture(4, &["alpha"]).await;
    let app = f.app().await;
    let (_, _, body) = call(&app, upload(&f.tokens[0], catalogue(&f.all, 0.0))).await;
    let id = json(&body)["id"].as_i64().unwrap();
    {
        // A worker claims it and the server dies before it records a result.
        let ch = Challenge::open(&f.state).await.unwrap();
        let job = ch
            .store
            .claim_job(&common::lease(), 0)
            .await
            .unwrap()
            .unwrap();
        assert_eq!(job.id, id);
        assert!(
            ch.store
                .claim_job(&common::lease(), 0)
                .await
                .unwrap()
                .is_none(),
            "one running job per team"
        );
    }
    let ch = Challenge::open(&f.state).await.unwrap();
    assert_eq!(ch.store.requeue_interrupted().await.unwrap(), 1);
    f.score_queue().await;
    let s = ch.store.submission(id).await.unwrap().unwrap();
    assert_eq!((s.status.as_str(), s.n_scorings), ("scored", 1));
    // A late result of the dead worker changes nothing.
    ch.store
        .finish_job(id, "test", Err("late".into()), "x", 0)
        .await
        .unwrap();
    let s = ch.store.submission(id).await.unwrap().unwrap();
    assert_eq!((s.status.as_str(), s.n_scorings), ("scored", 1));
}

#[tokio::test]
async fn init_refuses_a_run_without_held_out_fields_unless_told() {
    let tmp = tempfile::tempdir().unwrap();
    let (all, _) = write_run(tmp.path());
    let mut public = all.clone();
    public.datasets.datasets.retain(|d| d.part == Part::Public);
    public.truth.truncate(public.index().images.len());
    public.write(&tmp.path().join("plain/private")).unwrap();
    let err = common::init(&tmp.path().join("plain"), &tmp.path().join("s1"), 4, false)
        .await
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("no held-out datasets") && err.contains("--no-holdout"),
        "{err}"
    );
    assert!(!tmp.path().join("s1").exists());
    let ch = common::init(&tmp.path().join("plain"), &tmp.path().join("s2"), 4, true)
        .await
        .unwrap();
    assert!(!ch.settings.holdout);
    // A directory that holds a challenge is not taken again.
    let err = common::init(&tmp.path().join("run"), &tmp.path().join("s2"), 4, false)
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("already holds a challenge"), "{err}");
    // A run whose twins turn the whole field is a benchmark, not a
    // challenge: turned, its images pair the datasets of opposite shear.
    let config = tmp.path().join("run/private/config.json");
    std::fs::write(&config, r#"{"population": {"rotate_positions": true}}"#).unwrap();
    let err = common::init(&tmp.path().join("run"), &tmp.path().join("s3"), 4, false)
        .await
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("config.json")
            && err.contains("rotate_positions")
            && err.contains("opposite shear"),
        "{err}"
    );
    assert!(!tmp.path().join("s3").exists());
    std::fs::write(&config, r#"{"population": {"rotate_positions": false}}"#).unwrap();
    common::init(&tmp.path().join("run"), &tmp.path().join("s3"), 4, false)
        .await
        .unwrap();
}

#[tokio::test]
async fn requests_past_the_rate_limit_per_token_and_per_address_get_429() {
    let f = fixture(4, &["alpha", "beta"]).await;
    f.set("requests_per_minute", "3").await;
    let app = f.app().await;
    let from = |addr: &str, token: Option<&str>| {
        let mut r = get("/api/submissions", token);
        r.extensions_mut().insert(axum::extract::ConnectInfo(
            addr.parse::<std::net::SocketAddr>().unwrap(),
        ));
        r
    };
    // alpha from two addresses: the token's limit counts both.
    for addr in ["10.0.0.1:1", "10.0.0.2:1", "10.0.0.1:2"] {
        let (s, _, body) = call(&app, from(addr, Some(&f.tokens[0]))).await;
        assert_eq!(s, StatusCode::OK, "{body}");
    }
    let (s, h, body) = call(&app, from("10.0.0.3:1", Some(&f.tokens[0]))).await;
    assert_eq!(s, StatusCode::TOO_MANY_REQUESTS, "{body}");
    assert!(json(&body)["reset"].is_string(), "{body}");
    assert!(h.contains_key(header::RETRY_AFTER));
    // beta is not held back by alpha's requests...
    let (s, _, _) = call(&app, from("10.0.0.3:1", Some(&f.tokens[1]))).await;
    assert_eq!(s, StatusCode::OK);
    // ...but an address that made 3 requests is, whatever the token; a
    // forged token from a fresh address counts towards the address too.
    let (s, _, _) = call(&app, from("10.0.0.1:3", Some(&f.tokens[1]))).await;
    assert_eq!(s, StatusCode::OK, "10.0.0.1 made 2 counted requests");
    let (s, _, _) = call(&app, from("10.0.0.1:4", None)).await;
    assert_eq!(s, StatusCode::TOO_MANY_REQUESTS);
    for _ in 0..3 {
        let (s, _, _) = call(&app, from("10.0.0.9:1", Some("stp_forged"))).await;
        assert_eq!(s, StatusCode::UNAUTHORIZED);
    }
    let (s, _, _) = call(&app, from("10.0.0.9:1", Some("stp_forged2"))).await;
    assert_eq!(s, StatusCode::TOO_MANY_REQUESTS);
}

/// A request with a JSON body.
fn put_json(path: &str, token: &str, body: &str) -> Request<Body> {
    Request::put(path)
        .header(header::AUTHORIZATION, format!("Bearer {token}"))
        .header(header::CONTENT_TYPE, "application/json")
        .body(Body::from(body.to_string()))
        .unwrap()
}

async fn upload_id(app: &axum::Router, token: &str, text: String) -> i64 {
    let (s, _, body) = call(app, upload(token, text)).await;
    assert_eq!(s, StatusCode::ACCEPTED, "{body}");
    json(&body)["id"].as_i64().unwrap()
}

#[tokio::test]
async fn final_entries_are_chosen_checked_and_ranked_on_the_held_out_part() {
    let f = fixture(4, &["alpha", "beta"]).await;
    let app = f.app().await;
    let a_best = upload_id(&app, &f.tokens[0], catalogue(&f.all, 0.0)).await;
    let a_worse = upload_id(&app, &f.tokens[0], catalogue(&f.all, 0.08)).await;
    let b_only = upload_id(&app, &f.tokens[1], catalogue(&f.all, 0.03)).await;
    // Not scored yet: refused with 422.
    let (s, _, body) = call(
        &app,
        put_json(
            "/api/final",
            &f.tokens[0],
            &format!("{{\"entries\": [{a_best}]}}"),
        ),
    )
    .await;
    assert_eq!(s, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert!(
        json(&body)["error"]
            .as_str()
            .unwrap()
            .contains("not scored")
    );
    f.score_queue().await;
    let a_third = upload_id(&app, &f.tokens[0], catalogue(&f.all, 0.01)).await;
    // The default: the best public entry, no choice made.
    let (_, _, list) = call(&app, get("/api/submissions", Some(&f.tokens[0]))).await;
    let list = json(&list);
    assert_eq!(list["final"], serde_json::json!([a_best]));
    assert_eq!(list["final_chosen"], false);
    let flags: Vec<(i64, bool)> = list["submissions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| (e["id"].as_i64().unwrap(), e["final"].as_bool().unwrap()))
        .collect();
    assert_eq!(
        flags,
        vec![
            (a_third, false),
            (b_only, false),
            (a_worse, false),
            (a_best, true)
        ]
        .into_iter()
        .filter(|(id, _)| *id != b_only)
        .collect::<Vec<_>>()
    );
    // Refusals change nothing: three ids, another team's id (404 as for a
    // missing one), an unscored one, malformed bodies.
    let refusals = [
        (
            format!("{{\"entries\": [{a_best}, {a_worse}, {a_third}]}}"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "at most 2",
        ),
        (
            format!("{{\"entries\": [{a_best}, {a_third}]}}"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "not scored",
        ),
        (
            "{\"entries\": [\"x\"]}".into(),
            StatusCode::UNPROCESSABLE_ENTITY,
            "not an entry id",
        ),
        (
            "{\"entries\": 3}".into(),
            StatusCode::UNPROCESSABLE_ENTITY,
            "entries",
        ),
        ("[1, 2".into(), StatusCode::UNPROCESSABLE_ENTITY, "not JSON"),
    ];
    for (body, status, says) in refusals {
        let (s, _, answer) = call(&app, put_json("/api/final", &f.tokens[0], &body)).await;
        assert_eq!(s, status, "{body}: {answer}");
        assert!(
            json(&answer)["error"].as_str().unwrap().contains(says),
            "{answer}"
        );
    }
    let (s, _, other) = call(
        &app,
        put_json(
            "/api/final",
            &f.tokens[0],
            &format!("{{\"entries\": [{b_only}]}}"),
        ),
    )
    .await;
    let (s2, _, missing) = call(
        &app,
        put_json("/api/final", &f.tokens[0], "{\"entries\": [999]}"),
    )
    .await;
    assert_eq!((s, s2), (StatusCode::NOT_FOUND, StatusCode::NOT_FOUND));
    assert_eq!(other, missing);
    let (s, _, _) = call(
        &app,
        put_json("/api/final", "stp_forged", "{\"entries\": []}"),
    )
    .await;
    assert_eq!(s, StatusCode::UNAUTHORIZED);
    let ch = Challenge::open(&f.state).await.unwrap();
    assert!(
        ch.store.final_entries(1).await.unwrap().is_empty(),
        "nothing chosen yet"
    );
    drop(ch);
    // alpha chooses its worse entry (twice named: counted once).
    let (s, _, body) = call(
        &app,
        put_json(
            "/api/final",
            &f.tokens[0],
            &format!("{{\"entries\": [{a_worse}, {a_worse}]}}"),
        ),
    )
    .await;
    assert_eq!(s, StatusCode::OK, "{body}");
    assert_eq!(json(&body)["final"], serde_json::json!([a_worse]));
    let (_, _, list) = call(&app, get("/api/submissions", Some(&f.tokens[0]))).await;
    assert_eq!(json(&list)["final"], serde_json::json!([a_worse]));
    assert_eq!(json(&list)["final_chosen"], true);
    // Before reveal: ranked by the best public entry, choices not shown.
    let (_, _, lb) = call(&app, get("/api/leaderboard", None)).await;
    let lb = json(&lb);
    let order = |lb: &Value| -> Vec<(String, i64, Value)> {
        lb["rows"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| {
                (
                    r["team"].as_str().unwrap().to_string(),
                    r["entry"].as_i64().unwrap(),
                    r["rank"].clone(),
                )
            })
            .collect()
    };
    assert_eq!(
        order(&lb),
        vec![
            ("alpha".into(), a_best, 1.into()),
            ("beta".into(), b_only, 2.into())
        ]
    );
    assert!(lb["rows"][0].get("finals").is_none(), "{lb}");
    // After reveal: each team's final entries on the held-out part; alpha's
    // choice (m = 0.08) ranks it below beta (m = 0.03).
    let ch = Challenge::open(&f.state).await.unwrap();
    ch.reveal().await.unwrap();
    let (_, _, lb) = call(&app, get("/api/leaderboard", None)).await;
    let lb = json(&lb);
    assert_eq!(
        order(&lb),
        vec![
            ("beta".into(), b_only, 1.into()),
            ("alpha".into(), a_worse, 2.into())
        ]
    );
    assert_eq!(lb["rows"][1]["finals"], serde_json::json!([a_worse]));
    assert_eq!(
        lb["rows"][0]["finals"],
        serde_json::json!([b_only]),
        "the default"
    );
    let held_m = lb["rows"][1]["holdout"]["m_mean"].as_f64().unwrap();
    assert!((held_m - 0.08).abs() < 0.005, "{held_m}");
    // Reveal closes the challenge: no more choices.
    let (s, _, body) = call(
        &app,
        put_json(
            "/api/final",
            &f.tokens[0],
            &format!("{{\"entries\": [{a_best}]}}"),
        ),
    )
    .await;
    assert_eq!(s, StatusCode::FORBIDDEN, "{body}");
    assert!(json(&body)["error"].as_str().unwrap().contains("closed"));
    assert_eq!(ch.store.final_entries(1).await.unwrap(), vec![a_worse]);
}

#[tokio::test]
async fn organisers_and_the_baseline_are_shown_tagged_and_never_ranked() {
    let f = fixture(4, &["org", "ksb", "p1", "p2"]).await;
    let app = f.app().await;
    for (i, m) in [0.0, 0.01, 0.02, 0.04].into_iter().enumerate() {
        upload_id(&app, &f.tokens[i], catalogue(&f.all, m)).await;
    }
    f.score_queue().await;
    let ch = Challenge::open(&f.state).await.unwrap();
    ch.set_role("org", stepsim_server::Role::Organisers)
        .await
        .unwrap();
    ch.set_role("ksb", stepsim_server::Role::Baseline)
        .await
        .unwrap();
    assert!(
        ch.set_role("nobody", stepsim_server::Role::Baseline)
            .await
            .is_err()
    );
    for revealed in [false, true] {
        if revealed {
            ch.reveal().await.unwrap();
        }
        let (_, _, lb) = call(&app, get("/api/leaderboard", None)).await;
        let rows: Vec<(String, String, Value)> = json(&lb)["rows"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| {
                (
                    r["team"].as_str().unwrap().into(),
                    r["role"].as_str().unwrap().into(),
                    r["rank"].clone(),
                )
            })
            .collect();
        assert_eq!(
            rows,
            vec![
                ("org".into(), "organisers".into(), Value::Null),
                ("ksb".into(), "baseline".into(), Value::Null),
                ("p1".into(), "participant".into(), 1.into()),
                ("p2".into(), "participant".into(), 2.into()),
            ],
            "revealed {revealed}"
        );
    }
    // The export: unranked rows have an empty rank and their role in the
    // report's name; `stepsim leaderboard` can still read every report.
    let out = f.state.join("board.json");
    let e = ch.export(&out).await.unwrap();
    let csv = std::fs::read_to_string(&e.csv).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(
        lines[0],
        "rank,team,entry,part,m_mean,sigma_c,q_c,report,role"
    );
    assert!(lines[1].starts_with(",org,1,holdout,"), "{csv}");
    assert!(
        lines[1].ends_with(",board.reports/organisers-entry1.json,organisers"),
        "{csv}"
    );
    assert!(lines[2].starts_with(",ksb,2,holdout,"), "{csv}");
    assert!(lines[2].ends_with(",baseline"), "{csv}");
    assert!(lines[3].starts_with("1,p1,3,holdout,"), "{csv}");
    assert!(
        lines[4].ends_with(",board.reports/2-entry4.json,participant"),
        "{csv}"
    );
    let names: Vec<String> = e
        .reports
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        names,
        [
            "organisers-entry1.json",
            "baseline-entry2.json",
            "1-entry3.json",
            "2-entry4.json"
        ]
    );
    // Marked back as participants, they are ranked.
    ch.set_role("org", stepsim_server::Role::Participant)
        .await
        .unwrap();
    let (_, _, lb) = call(&app, get("/api/leaderboard", None)).await;
    assert_eq!(json(&lb)["rows"][0]["rank"], 1);
    assert_eq!(json(&lb)["rows"][2]["rank"], 2);
}

#[tokio::test]
async fn deadline_freeze_and_close_stop_uploads_with_a_clear_403() {
    let f = fixture(4, &["alpha"]).await;
    let app = f.app().await;
    let (_, _, c) = call(&app, get("/api/challenge", None)).await;
    let c = json(&c);
    assert_eq!(c["name"], "run");
    assert_eq!(c["deadline"], Value::Null);
    assert_eq!(
        (
            &c["frozen"],
            &c["closed"],
            &c["revealed"],
            &c["uploads_open"]
        ),
        (&false.into(), &false.into(), &false.into(), &true.into())
    );
    assert_eq!(c["rules"]["quota"], 4);
    assert_eq!(c["rules"]["quota_window_hours"], 24);
    assert_eq!(c["rules"]["max_final_entries"], 2);
    assert_eq!(c["rules"]["feedback_decimals"]["m_mean"], 3);
    let id = upload_id(&app, &f.tokens[0], catalogue(&f.all, 0.0)).await;
    f.score_queue().await;
    let ch = Challenge::open(&f.state).await.unwrap();
    // A deadline in the future changes nothing; one passed refuses uploads.
    ch.set_deadline(Some(stepsim_server::now_s() + 3600))
        .await
        .unwrap();
    upload_id(&app, &f.tokens[0], catalogue(&f.all, 0.01)).await;
    ch.set_deadline(stepsim_server::parse_rfc3339("2020-01-01T00:00:00Z"))
        .await
        .unwrap();
    let (s, _, body) = call(&app, upload(&f.tokens[0], catalogue(&f.all, 0.02))).await;
    assert_eq!(s, StatusCode::FORBIDDEN, "{body}");
    assert!(
        json(&body)["error"]
            .as_str()
            .unwrap()
            .contains("deadline (2020-01-01T00:00:00Z) has passed"),
        "{body}"
    );
    let (_, _, c) = call(&app, get("/api/challenge", None)).await;
    assert_eq!(json(&c)["deadline"], "2020-01-01T00:00:00Z");
    assert_eq!(json(&c)["uploads_open"], false);
    ch.set_deadline(None).await.unwrap();
    // Frozen: uploads refused, final choices allowed.
    ch.freeze().await.unwrap();
    let (s, _, body) = call(&app, upload(&f.tokens[0], catalogue(&f.all, 0.02))).await;
    assert_eq!(s, StatusCode::FORBIDDEN);
    assert!(
        json(&body)["error"]
            .as_str()
            .unwrap()
            .starts_with("the challenge is frozen")
    );
    let (s, _, _) = call(
        &app,
        put_json(
            "/api/final",
            &f.tokens[0],
            &format!("{{\"entries\": [{id}]}}"),
        ),
    )
    .await;
    assert_eq!(s, StatusCode::OK);
    // Closed: nothing changes.
    ch.close().await.unwrap();
    let (s, _, body) = call(&app, upload(&f.tokens[0], catalogue(&f.all, 0.03))).await;
    assert_eq!(s, StatusCode::FORBIDDEN);
    assert!(
        json(&body)["error"]
            .as_str()
            .unwrap()
            .starts_with("the challenge is closed")
    );
    let (s, _, _) = call(
        &app,
        put_json("/api/final", &f.tokens[0], "{\"entries\": []}"),
    )
    .await;
    assert_eq!(s, StatusCode::FORBIDDEN);
    assert_eq!(ch.store.final_entries(1).await.unwrap(), vec![id]);
    let (_, _, c) = call(&app, get("/api/challenge", None)).await;
    let c = json(&c);
    assert_eq!((&c["frozen"], &c["closed"]), (&true.into(), &true.into()));
    // Nothing was stored by the refused uploads.
    assert_eq!(files_in(&f.state.join("uploads")).len(), 2);
}

#[tokio::test]
async fn the_organiser_password_is_kept_as_an_argon2_hash() {
    let f = fixture(4, &[]).await;
    let ch = Challenge::open(&f.state).await.unwrap();
    assert!(!ch.verify_organiser_password("").await, "none set");
    assert!(ch.set_organiser_password("short").await.is_err());
    ch.set_organiser_password("correct horse battery")
        .await
        .unwrap();
    assert!(ch.verify_organiser_password("correct horse battery").await);
    assert!(!ch.verify_organiser_password("correct horse batterY").await);
    assert!(!ch.verify_organiser_password("").await);
    let ch = Challenge::open(&f.state).await.unwrap();
    assert!(
        stepsim_server::verify_organiser_password(ch.store.as_ref(), "correct horse battery").await
    );
    let phc = ch
        .store
        .meta(stepsim_server::ORGANISER_PASSWORD_KEY)
        .await
        .unwrap()
        .unwrap();
    assert!(phc.starts_with("$argon2id$"), "{phc}");
    let db = common::store_text(&f.state).await;
    assert!(db.contains("$argon2id$") && !db.contains("correct horse"));
    // A damaged hash is a wrong password, not a panic.
    let ch = ch;
    ch.store
        .set_meta(stepsim_server::ORGANISER_PASSWORD_KEY, "$argon2id$garbage")
        .await
        .unwrap();
    assert!(!ch.verify_organiser_password("correct horse battery").await);
}

#[tokio::test]
async fn a_rescore_keeps_old_scores_and_scores_each_entry_once_per_scorer_version() {
    let f = fixture(4, &["alpha"]).await;
    let app = f.app().await;
    let id = upload_id(&app, &f.tokens[0], catalogue(&f.all, 0.01)).await;
    // Scored by an older scorer.
    {
        let ch = Challenge::open(&f.state).await.unwrap();
        let job = ch
            .store
            .claim_job(&common::lease(), 0)
            .await
            .unwrap()
            .unwrap();
        let mut r = stepsim_server::score_entry(&ch, &job);
        if let Ok((p, _)) = &mut r {
            *p = p.replace("\"m_mean\":0.01", "\"m_mean\":0.5");
        }
        ch.store
            .finish_job(job.id, "test", r, "stepsim-harness 0.0.1", 10)
            .await
            .unwrap();
    }
    let (_, _, e) = call(
        &app,
        get(&format!("/api/submissions/{id}"), Some(&f.tokens[0])),
    )
    .await;
    assert_eq!(json(&e)["scorer_version"], "stepsim-harness 0.0.1");
    assert_eq!(json(&e)["public"]["m_mean"], 0.5);
    let ch = Challenge::open(&f.state).await.unwrap();
    assert_eq!(ch.rescore().await.unwrap(), 1);
    // Queued again, still showing its old score (and on the leaderboard).
    let (_, _, e) = call(
        &app,
        get(&format!("/api/submissions/{id}"), Some(&f.tokens[0])),
    )
    .await;
    assert_eq!(json(&e)["status"], "queued");
    assert_eq!(json(&e)["public"]["m_mean"], 0.5);
    let (_, _, lb) = call(&app, get("/api/leaderboard", None)).await;
    assert_eq!(json(&lb)["rows"][0]["entry"], id);
    // A worker claims it and dies; after the restart it is scored once.
    let job = ch
        .store
        .claim_job(&common::lease(), 20)
        .await
        .unwrap()
        .unwrap();
    assert_eq!(job.id, id);
    drop(ch);
    let ch = Challenge::open(&f.state).await.unwrap();
    assert_eq!(ch.store.requeue_interrupted().await.unwrap(), 1);
    f.score_queue().await;
    // The dead worker's late result is ignored; a second rescore by the same
    // scorer queues nothing.
    ch.store
        .finish_job(
            id,
            "test",
            Err("late".into()),
            stepsim_server::SCORER_VERSION,
            30,
        )
        .await
        .unwrap();
    assert_eq!(ch.rescore().await.unwrap(), 0);
    let scores = ch.store.scores_of(id).await.unwrap();
    let got: Vec<(&str, &str, i64)> = scores
        .iter()
        .map(|s| (s.scorer_version.as_str(), s.status.as_str(), s.n_scorings))
        .collect();
    assert_eq!(
        got,
        vec![
            (stepsim_server::SCORER_VERSION, "scored", 1),
            ("stepsim-harness 0.0.1", "scored", 1)
        ]
    );
    assert!(
        scores[1]
            .public_json
            .as_deref()
            .unwrap()
            .contains("\"m_mean\":0.5")
    );
    let sub = ch.store.submission(id).await.unwrap().unwrap();
    assert_eq!((sub.status.as_str(), sub.n_scorings), ("scored", 2));
    let (_, _, e) = call(
        &app,
        get(&format!("/api/submissions/{id}"), Some(&f.tokens[0])),
    )
    .await;
    let e = json(&e);
    assert_eq!(e["scorer_version"], stepsim_server::SCORER_VERSION);
    assert_eq!(e["public"]["m_mean"], 0.01, "the newest score is shown");
}

/// Writes a `public/` beside the fixture's `private/`: a manifest naming
/// one file per image (made-up bytes), a README, and a stray file the
/// manifest does not name.
async fn write_public(f: &Fixture) -> (PathBuf, Vec<(String, Vec<u8>)>) {
    use sha2::Digest;
    let public = f.truth.parent().unwrap().join("public");
    let mut images = Vec::new();
    let mut files = Vec::new();
    for (k, d) in f.all.datasets.datasets.iter().enumerate() {
        for im in &d.images {
            let file = format!("{}/{}.fits", d.dataset, im.image);
            let bytes: Vec<u8> = (0..1000 + 37 * k).map(|i| (i * 7 + k) as u8).collect();
            std::fs::create_dir_all(public.join(&d.dataset)).unwrap();
            std::fs::write(public.join(&file), &bytes).unwrap();
            images.push(serde_json::json!({
                "image": im.image, "dataset": d.dataset, "file": file,
                "sha256": stepsim_contract::digest::hex(&sha2::Sha256::digest(&bytes)),
            }));
            files.push((file, bytes));
        }
    }
    let manifest = serde_json::json!({
        "format": "stepsim-manifest-1",
        "instrument": {"width_px": 64, "height_px": 64, "pixel_scale_arcsec": 0.2,
            "gain_e_per_adu": 4.0, "read_noise_e": 5.0, "saturation_adu": 65535.0,
            "exposure_s": 3600.0, "zeropoint_mag": 26.0},
        "images": images,
    });
    let text = serde_json::to_string_pretty(&manifest).unwrap();
    std::fs::write(public.join("manifest.json"), &text).unwrap();
    std::fs::write(public.join("README.md"), "# the data\n").unwrap();
    std::fs::write(public.join("notes.txt"), "not listed\n").unwrap();
    let mut all = vec![
        ("manifest.json".to_string(), text.into_bytes()),
        ("README.md".to_string(), b"# the data\n".to_vec()),
    ];
    all.extend(files);
    (public, all)
}

#[tokio::test]
async fn the_public_data_downloads_as_listed_and_nothing_else() {
    use sha2::Digest;
    let f = fixture(4, &["alpha"]).await;
    let (_, files) = write_public(&f).await;
    let app = f.app().await;
    let (s, h, body) = call(&app, get("/data/", None)).await;
    assert_eq!(s, StatusCode::OK, "{body}");
    assert!(h.get(header::LAST_MODIFIED).is_none());
    let listed: Vec<(String, u64, String)> = json(&body)["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| {
            (
                x["path"].as_str().unwrap().to_string(),
                x["bytes"].as_u64().unwrap(),
                x["sha256"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    let want: Vec<(String, u64, String)> = files
        .iter()
        .map(|(p, b)| {
            (
                p.clone(),
                b.len() as u64,
                stepsim_contract::digest::hex(&sha2::Sha256::digest(b)),
            )
        })
        .collect();
    assert_eq!(listed, want, "the manifest's order, sizes and checksums");
    for (path, bytes) in &files {
        let resp = app
            .clone()
            .oneshot(get(&format!("/data/{path}"), None))
            .await
            .unwrap();
        assert_eq!(resp.status(), StatusCode::OK, "{path}");
        assert!(
            resp.headers().get(header::LAST_MODIFIED).is_none(),
            "{path}"
        );
        if path.ends_with(".fits") {
            let sha = stepsim_contract::digest::hex(&sha2::Sha256::digest(bytes));
            assert_eq!(resp.headers()[header::ETAG], format!("\"{sha}\""));
        }
        let got = resp.into_body().collect().await.unwrap().to_bytes();
        assert_eq!(got.as_ref(), bytes.as_slice(), "{path}");
    }
    let sha = {
        let (_, _, _) = call(&app, upload(&f.tokens[0], catalogue(&f.all, 0.0))).await;
        files_in(&f.state.join("uploads"))[0].clone()
    };
    let truth_file = format!("{}.fits", f.held.datasets.datasets[0].images[0].image);
    for bad in [
        "/data/notes.txt".to_string(),
        "/data/../private/datasets.json".into(),
        "/data/..%2Fprivate%2Fdatasets.json".into(),
        "/data/%2e%2e/private/datasets.json".into(),
        "/data/%2E%2E%2Fprivate%2Fdatasets.json".into(),
        "/data/./manifest.json".into(),
        "/data//manifest.json".into(),
        "/data/manifest.json/../../private/datasets.json".into(),
        format!("/data/../private/truth/{truth_file}"),
        format!("/data/..%2Fprivate%2Ftruth%2F{truth_file}"),
        "/data/../../state/challenge.db".into(),
        "/data/..%2F..%2Fstate%2Fchallenge.db".into(),
        format!("/data/../../state/uploads/{sha}"),
        "/data/%2Fetc%2Fpasswd".into(),
    ] {
        let (s, h, body) = call(&app, get(&bad, Some(&f.tokens[0]))).await;
        assert_eq!(s, StatusCode::NOT_FOUND, "{bad}: {body}");
        assert_eq!(json(&body)["error"], "not found", "{bad}");
        assert!(h.get(header::LAST_MODIFIED).is_none());
    }
    // A manifest naming a file outside public/ is refused whole.
    let public = f.truth.parent().unwrap().join("public");
    let text = std::fs::read_to_string(public.join("manifest.json")).unwrap();
    let first = &files[2].0;
    let text = text.replacen(first.as_str(), "../private/datasets.json", 1);
    std::fs::write(public.join("manifest.json"), text).unwrap();
    for path in [
        "/data/",
        "/data/../private/datasets.json",
        "/data/manifest.json",
    ] {
        let (s, _, body) = call(&app, get(path, None)).await;
        assert_eq!(s, StatusCode::NOT_FOUND, "{path}: {body}");
        assert!(!body.contains("stepsim-datasets"), "{body}");
    }
}

#[tokio::test]
async fn a_database_of_the_first_schema_is_migrated_with_its_scores_kept() {
    use stepsim_server::{MIGRATIONS, SqliteStore, Store};
    let tmp = tempfile::tempdir().unwrap();
    let db = tmp.path().join("challenge.db");
    {
        let conn = rusqlite::Connection::open(&db).unwrap();
        conn.execute_batch(MIGRATIONS[0]).unwrap();
        conn.pragma_update(None, "user_version", 1).unwrap();
        conn.execute_batch(
            "INSERT INTO teams (name, token_sha256, created_s) VALUES ('a', 'h', 0);
             INSERT INTO submissions (team_id, sha256, bytes, created_s, status, public_json,
                 scorer_version, n_scorings) VALUES (1, 's', 3, 0, 'scored', '{\"q_c\":7}',
                 'stepsim-harness 0.0.9', 1);
             INSERT INTO submissions (team_id, sha256, bytes, created_s, status)
                 VALUES (1, 't', 3, 0, 'queued');",
        )
        .unwrap();
    }
    let store = SqliteStore::open(&db, false).await.unwrap();
    let team = store.team_by_name("a").await.unwrap().unwrap();
    assert_eq!(team.role, stepsim_server::Role::Participant);
    let scores = store.scores_of(1).await.unwrap();
    assert_eq!(scores.len(), 1);
    assert_eq!(
        (scores[0].scorer_version.as_str(), scores[0].n_scorings),
        ("stepsim-harness 0.0.9", 1)
    );
    assert_eq!(scores[0].public_json.as_deref(), Some("{\"q_c\":7}"));
    assert!(store.scores_of(2).await.unwrap().is_empty());
    let s = store.submission(1).await.unwrap().unwrap();
    assert!(!s.final_choice && s.has_score());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn parallel_uploads_of_one_team_cannot_pass_the_quota_together() {
    let f = fixture(2, &["alpha"]).await;
    // Six at once allowed per team (the default is one: the rest would be
    // refused before their bodies, hardening.rs), so that all six reach
    // the quota's check in the store.
    let app = router(AppState::with_limits(
        Challenge::open(&f.state).await.unwrap(),
        stepsim_server::Limits {
            uploads_per_team: 6,
            uploads_at_once: 6,
            ..Default::default()
        },
        None,
    ));
    let handles: Vec<_> = (0..6)
        .map(|k| {
            let (app, token) = (app.clone(), f.tokens[0].clone());
            let text = catalogue(&f.all, 0.01 * f64::from(k));
            tokio::spawn(async move { call(&app, upload(&token, text)).await.0 })
        })
        .collect();
    let mut statuses = Vec::new();
    for h in handles {
        statuses.push(h.await.unwrap());
    }
    let n = |s: StatusCode| statuses.iter().filter(|&&x| x == s).count();
    assert_eq!(
        (n(StatusCode::ACCEPTED), n(StatusCode::TOO_MANY_REQUESTS)),
        (2, 4),
        "{statuses:?}"
    );
    let ch = Challenge::open(&f.state).await.unwrap();
    let team = ch.store.team_by_name("alpha").await.unwrap().unwrap();
    assert_eq!(ch.store.submissions_of(team.id).await.unwrap().len(), 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_upload_still_arriving_at_the_freeze_is_refused() {
    let f = fixture(4, &["alpha"]).await;
    let app = f.app().await;
    let text = catalogue(&f.all, 0.0).into_bytes();
    let (tx, rx) = tokio::sync::mpsc::channel::<Result<axum::body::Bytes, std::io::Error>>(4);
    let stream = futures_util::stream::unfold(rx, |mut rx| async move {
        rx.recv().await.map(|chunk| (chunk, rx))
    });
    let (app2, token) = (app.clone(), f.tokens[0].clone());
    let pending =
        tokio::spawn(async move { call(&app2, upload(&token, Body::from_stream(stream))).await });
    let half = text.len() / 2;
    tx.send(Ok(text[..half].to_vec().into())).await.unwrap();
    // The upload started while uploads were open; the challenge freezes
    // before its body ends.
    tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    Challenge::open(&f.state)
        .await
        .unwrap()
        .freeze()
        .await
        .unwrap();
    tx.send(Ok(text[half..].to_vec().into())).await.unwrap();
    drop(tx);
    let (s, _, body) = pending.await.unwrap();
    assert_eq!(s, StatusCode::FORBIDDEN, "{body}");
    assert!(
        json(&body)["error"]
            .as_str()
            .unwrap()
            .starts_with("the challenge is frozen")
    );
    let ch = Challenge::open(&f.state).await.unwrap();
    let team = ch.store.team_by_name("alpha").await.unwrap().unwrap();
    assert!(ch.store.submissions_of(team.id).await.unwrap().is_empty());
}

#[tokio::test]
async fn a_failure_on_the_held_out_part_does_not_show_before_reveal() {
    let f = fixture(4, &["alpha"]).await;
    let app = f.app().await;
    let id = upload_id(&app, &f.tokens[0], catalogue(&f.all, 0.0)).await;
    // The held-out truth becomes unreadable after the format check.
    for im in &f.held.index().images {
        std::fs::write(
            f.truth.join("truth").join(format!("{}.fits", im.image)),
            b"broken",
        )
        .unwrap();
    }
    f.score_queue().await;
    let (s, _, body) = call(
        &app,
        get(&format!("/api/submissions/{id}"), Some(&f.tokens[0])),
    )
    .await;
    assert_eq!(s, StatusCode::OK);
    let v = json(&body);
    assert_eq!(v["status"], "scored", "{body}");
    assert!(v["public"]["m_mean"].is_number(), "{body}");
    assert!(
        v.get("holdout").is_none() && v.get("error").is_none_or(Value::is_null),
        "{body}"
    );
    // Kept for after reveal.
    let ch = Challenge::open(&f.state).await.unwrap();
    let sub = ch.store.submission(id).await.unwrap().unwrap();
    assert!(sub.holdout_json.unwrap().contains("\"error\""));
}
