//! Issue #23: the worker outlives a locked database, the connection layer
//! times out slow clients and caps connections, uploads are bounded before
//! their bodies are read, bearer tokens are parsed strictly, the CSV export
//! neutralises formulas, refusals do not depend on the private order of
//! datasets, and the final board says when two rows are tied.

use axum::body::Body;
use axum::http::{Request, StatusCode, header};
use http_body_util::BodyExt;
use serde_json::Value;
use std::io::{Read, Write};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};
use stepsim_server::{AppState, Challenge, Limits, WorkerPool, router};
use stepsim_testkit::synthetic::SynthRun;
use tower::ServiceExt;

use crate::common;
use common::{catalogue, write_run, write_run_of_fields};

struct Fixture {
    _tmp: tempfile::TempDir,
    state: PathBuf,
    all: SynthRun,
    tokens: Vec<String>,
}

async fn fixture(quota: u32, teams: &[&str]) -> Fixture {
    fixture_of_fields(quota, teams, 2).await
}

/// [`fixture`] on a run of `fields` base fields in each part.
async fn fixture_of_fields(quota: u32, teams: &[&str], fields: u32) -> Fixture {
    let tmp = tempfile::tempdir().unwrap();
    let (all, _) = write_run_of_fields(tmp.path(), fields);
    let state = tmp.path().join("state");
    let ch = common::init(&tmp.path().join("run"), &state, quota, false)
        .await
        .unwrap();
    let mut tokens = Vec::new();
    for t in teams {
        tokens.push(ch.add_team(t).await.unwrap());
    }
    Fixture {
        _tmp: tmp,
        state,
        all,
        tokens,
    }
}

impl Fixture {
    async fn app(&self, limits: Limits, workers: Option<Arc<AtomicUsize>>) -> axum::Router {
        router(AppState::with_limits(
            Challenge::open(&self.state).await.unwrap(),
            limits,
            workers,
        ))
    }
    /// Scores every queued job now (what a worker does).
    async fn score_queue(&self) {
        common::score_queue(&self.state).await;
    }
    /// Serves the app on a free local port (the real connection layer).
    async fn serve(&self, limits: Limits) -> std::net::SocketAddr {
        let app = self.app(limits.clone(), None).await;
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        tokio::spawn(stepsim_server::serve_with_limits(listener, app, limits));
        addr
    }
}

async fn call(app: &axum::Router, req: Request<Body>) -> (StatusCode, String) {
    let resp = app.clone().oneshot(req).await.unwrap();
    let status = resp.status();
    let body = resp.into_body().collect().await.unwrap().to_bytes();
    (status, String::from_utf8_lossy(&body).into_owned())
}

fn upload(auth: &str, body: impl Into<Body>) -> Request<Body> {
    Request::post("/api/submissions")
        .header(header::AUTHORIZATION, auth)
        .body(body.into())
        .unwrap()
}

fn json(s: &str) -> Value {
    serde_json::from_str(s).unwrap_or_else(|e| panic!("{e}: {s}"))
}

// ---- a. the worker and the store ----

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_database_lock_longer_than_the_busy_timeout_does_not_end_the_worker() {
    let f = fixture(4, &["a"]).await;
    let pool = WorkerPool::start(&f.state, 1, stepsim_server::DEFAULT_TIMEOUT);
    let live = pool.live();
    // An organiser's sqlite3 holds an exclusive lock for 15 s (the store
    // waits 10 s for a lock, then fails).
    // On PostgreSQL an organiser's psql holds every table locked for 15 s.
    let db = f.state.join("challenge.db");
    let pg = std::fs::read_to_string(f.state.join(stepsim_server::STORE_FILE)).ok();
    let locker = std::thread::spawn(move || match pg {
        None => {
            let c = rusqlite::Connection::open(&db).unwrap();
            c.execute_batch("BEGIN EXCLUSIVE; UPDATE meta SET value = value WHERE key = 'name';")
                .unwrap();
            std::thread::sleep(Duration::from_secs(15));
            c.execute_batch("COMMIT").unwrap();
        }
        Some(url) => {
            let rt = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .unwrap();
            rt.block_on(async {
                let (mut c, conn) = tokio_postgres::connect(url.trim(), tokio_postgres::NoTls)
                    .await
                    .unwrap();
                tokio::spawn(conn);
                // The tables are locked one after another: when the worker
                // holds one of them and waits for one already locked here,
                // PostgreSQL ends one of the two transactions ("deadlock
                // detected"); the organiser then tries again, as psql's user
                // would.
                let tx = loop {
                    let tx = c.transaction().await.unwrap();
                    match tx
                        .batch_execute(
                            "LOCK TABLE meta, teams, submissions, scores, format_failures \
                             IN ACCESS EXCLUSIVE MODE",
                        )
                        .await
                    {
                        Ok(()) => break tx,
                        Err(e)
                            if e.code()
                                == Some(
                                    &tokio_postgres::error::SqlState::T_R_DEADLOCK_DETECTED,
                                ) => {}
                        Err(e) => panic!("{e}"),
                    }
                };
                tokio::time::sleep(Duration::from_secs(15)).await;
                tx.commit().await.unwrap();
            });
        }
    });
    locker.join().unwrap();
    assert_eq!(live.load(Ordering::SeqCst), 1, "the worker ended");
    let app = f.app(Limits::default(), Some(live.clone())).await;
    let text = catalogue(&f.all, 0.01);
    let (s, body) = call(&app, upload(&format!("Bearer {}", f.tokens[0]), text)).await;
    assert_eq!(s, StatusCode::ACCEPTED, "{body}");
    let id = json(&body)["id"].as_i64().unwrap();
    let t0 = Instant::now();
    let mut status = String::new();
    while t0.elapsed() < Duration::from_secs(60) {
        let ch = Challenge::open(&f.state).await.unwrap();
        status = ch.store.submission(id).await.unwrap().unwrap().status;
        if status == "scored" {
            break;
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    assert_eq!(status, "scored", "not scored within 60 s of the lock's end");
    pool.stop();
    assert_eq!(live.load(Ordering::SeqCst), 0);
}

#[tokio::test]
async fn uploads_are_refused_with_503_when_no_worker_runs() {
    let f = fixture(4, &["a"]).await;
    let pool = WorkerPool::start(&f.state, 2, stepsim_server::DEFAULT_TIMEOUT);
    let live = pool.live();
    assert_eq!(live.load(Ordering::SeqCst), 2);
    pool.stop();
    assert_eq!(live.load(Ordering::SeqCst), 0);
    let app = f.app(Limits::default(), Some(live)).await;
    let (s, body) = call(
        &app,
        upload(&format!("Bearer {}", f.tokens[0]), catalogue(&f.all, 0.0)),
    )
    .await;
    assert_eq!(s, StatusCode::SERVICE_UNAVAILABLE, "{body}");
    assert!(
        json(&body)["error"]
            .as_str()
            .unwrap()
            .contains("the scoring queue is not running"),
        "{body}"
    );
    let ch = Challenge::open(&f.state).await.unwrap();
    assert!(ch.store.all_submissions().await.unwrap().is_empty());
}

// ---- b. connections ----

/// Reads until the peer closes (Ok(bytes)) or `within` passes (Err).
fn read_to_close(s: &mut std::net::TcpStream, within: Duration) -> Result<Vec<u8>, Vec<u8>> {
    let end = Instant::now() + within;
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        let left = end.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(got);
        }
        s.set_read_timeout(Some(left)).unwrap();
        match s.read(&mut buf) {
            Ok(0) => return Ok(got),
            Ok(n) => got.extend_from_slice(&buf[..n]),
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                return Err(got);
            }
            Err(_) => return Ok(got),
        }
    }
}

fn connect(addr: std::net::SocketAddr) -> std::net::TcpStream {
    std::net::TcpStream::connect(addr).unwrap()
}

fn short(limits: Limits) -> Limits {
    Limits {
        max_connections: 2000,
        max_connections_per_addr: 2000,
        ..limits
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_hundred_half_sent_headers_are_all_closed_after_the_header_timeout() {
    let f = fixture(4, &["a"]).await;
    let addr = f
        .serve(short(Limits {
            header_timeout: Duration::from_secs(1),
            ..Limits::default()
        }))
        .await;
    let t0 = Instant::now();
    let socks: Vec<std::net::TcpStream> = (0..300)
        .map(|_| {
            let mut s = connect(addr);
            s.write_all(b"POST /api/submissions HTTP/1.1\r\nHost: x\r\nAuthor")
                .unwrap();
            s
        })
        .collect();
    let closed = tokio::task::spawn_blocking(move || {
        socks
            .into_iter()
            .map(|mut s| read_to_close(&mut s, Duration::from_secs(5)).is_ok())
            .filter(|&c| c)
            .count()
    })
    .await
    .unwrap();
    let took = t0.elapsed();
    eprintln!("300 half-sent requests: {closed} closed after {took:?}");
    assert_eq!(closed, 300, "{closed} of 300 closed");
    assert!(took < Duration::from_secs(4), "{took:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_idle_kept_alive_connection_is_closed_after_the_idle_timeout() {
    let f = fixture(4, &["a"]).await;
    let addr = f
        .serve(short(Limits {
            idle_timeout: Duration::from_millis(1500),
            ..Limits::default()
        }))
        .await;
    let r = tokio::task::spawn_blocking(move || {
        let mut s = connect(addr);
        s.write_all(b"GET /api/challenge HTTP/1.1\r\nHost: x\r\n\r\n")
            .unwrap();
        let t0 = Instant::now();
        let r = read_to_close(&mut s, Duration::from_secs(6));
        (r, t0.elapsed())
    })
    .await
    .unwrap();
    let (r, took) = r;
    let got = r.expect("the idle connection was not closed within 6 s");
    assert!(
        got.starts_with(b"HTTP/1.1 200"),
        "{}",
        String::from_utf8_lossy(&got)
    );
    assert!(took >= Duration::from_millis(1400), "{took:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_past_the_per_address_cap_are_refused_at_once() {
    let f = fixture(4, &["a"]).await;
    let addr = f
        .serve(Limits {
            max_connections_per_addr: 3,
            ..Limits::default()
        })
        .await;
    tokio::task::spawn_blocking(move || {
        let held: Vec<_> = (0..3).map(|_| connect(addr)).collect();
        std::thread::sleep(Duration::from_millis(200));
        let mut fourth = connect(addr);
        let got = read_to_close(&mut fourth, Duration::from_secs(2)).expect("not closed");
        let text = String::from_utf8_lossy(&got);
        assert!(text.starts_with("HTTP/1.1 503"), "{text}");
        assert!(
            text.contains("too many connections from your address"),
            "{text}"
        );
        // One closed, a new one is served.
        drop(held);
        std::thread::sleep(Duration::from_millis(300));
        let mut s = connect(addr);
        s.write_all(b"GET /api/challenge HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
            .unwrap();
        let got = read_to_close(&mut s, Duration::from_secs(5)).expect("not answered");
        assert!(
            got.starts_with(b"HTTP/1.1 200"),
            "{}",
            String::from_utf8_lossy(&got)
        );
    })
    .await
    .unwrap();
}

/// Sends an upload's headers (and `first` bytes of a body of `len`) and
/// leaves the rest unsent.
fn start_upload(
    addr: std::net::SocketAddr,
    token: &str,
    len: usize,
    first: &[u8],
) -> std::net::TcpStream {
    let mut s = connect(addr);
    let head = format!(
        "POST /api/submissions HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {token}\r\n\
         Content-Length: {len}\r\n\r\n"
    );
    s.write_all(head.as_bytes()).unwrap();
    s.write_all(first).unwrap();
    s
}

fn status_of(got: &[u8]) -> u16 {
    let t = String::from_utf8_lossy(got);
    t.get(9..12).and_then(|c| c.parse().ok()).unwrap_or(0)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_body_that_stalls_is_cut_off_with_408() {
    let f = fixture(4, &["a"]).await;
    let addr = f
        .serve(short(Limits {
            body_stall_timeout: Duration::from_secs(1),
            ..Limits::default()
        }))
        .await;
    let token = f.tokens[0].clone();
    let (got, took) = tokio::task::spawn_blocking(move || {
        let mut s = start_upload(addr, &token, 100_000, b"# image x y e1 e2 weight\n");
        let t0 = Instant::now();
        let got = read_to_close(&mut s, Duration::from_secs(6)).expect("not cut off");
        (got, t0.elapsed())
    })
    .await
    .unwrap();
    assert_eq!(status_of(&got), 408, "{}", String::from_utf8_lossy(&got));
    assert!(String::from_utf8_lossy(&got).contains("arrived too slowly"));
    assert!(took < Duration::from_secs(4), "{took:?}");
    assert!(
        std::fs::read_dir(f.state.join("uploads"))
            .unwrap()
            .next()
            .is_none(),
        "the cut upload was kept"
    );
}

// ---- c. uploads at once, the quota, the format check's budget ----

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_upload_of_a_team_is_refused_before_its_body_is_sent() {
    let f = fixture(4, &["a", "b"]).await;
    let addr = f.serve(short(Limits::default())).await;
    let (ta, tb) = (f.tokens[0].clone(), f.tokens[1].clone());
    tokio::task::spawn_blocking(move || {
        // Team a's first upload arrives slowly.
        let _first = start_upload(addr, &ta, 110 << 20, b"# image");
        std::thread::sleep(Duration::from_millis(300));
        // Its second is refused before a byte of its body is sent.
        let mut second = start_upload(addr, &ta, 110 << 20, b"");
        let got = read_to_close(&mut second, Duration::from_secs(3))
            .expect("no answer before the body was sent");
        let text = String::from_utf8_lossy(&got);
        assert_eq!(status_of(&got), 429, "{text}");
        assert!(text.contains("still arriving or being checked"), "{text}");
        // Team b's upload is not refused: the server waits for its body.
        let mut other = start_upload(addr, &tb, 1000, b"");
        assert!(read_to_close(&mut other, Duration::from_millis(800)).is_err());
    })
    .await
    .unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn uploads_in_flight_count_against_the_quota_before_a_body_is_read() {
    let f = fixture(2, &["a"]).await;
    let app = f.app(Limits::default(), None).await;
    let (s, body) = call(
        &app,
        upload(&format!("Bearer {}", f.tokens[0]), catalogue(&f.all, 0.0)),
    )
    .await;
    assert_eq!(s, StatusCode::ACCEPTED, "{body}");
    let addr = f
        .serve(short(Limits {
            uploads_per_team: 2,
            ..Limits::default()
        }))
        .await;
    let t = f.tokens[0].clone();
    tokio::task::spawn_blocking(move || {
        // One accepted + one arriving = the quota of 2.
        let _arriving = start_upload(addr, &t, 110 << 20, b"# image");
        std::thread::sleep(Duration::from_millis(300));
        let mut next = start_upload(addr, &t, 110 << 20, b"");
        let got = read_to_close(&mut next, Duration::from_secs(3))
            .expect("no answer before the body was sent");
        let text = String::from_utf8_lossy(&got);
        assert_eq!(status_of(&got), 429, "{text}");
        assert!(text.contains("quota of 2"), "{text}");
        assert!(
            text.contains("1 upload(s) of your team still arriving"),
            "{text}"
        );
    })
    .await
    .unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn uploads_past_the_cap_of_all_teams_are_refused_with_503_before_their_body() {
    let f = fixture(4, &["a", "b"]).await;
    let addr = f
        .serve(short(Limits {
            uploads_at_once: 1,
            ..Limits::default()
        }))
        .await;
    let (ta, tb) = (f.tokens[0].clone(), f.tokens[1].clone());
    tokio::task::spawn_blocking(move || {
        let _first = start_upload(addr, &ta, 110 << 20, b"# image");
        std::thread::sleep(Duration::from_millis(300));
        let mut other = start_upload(addr, &tb, 110 << 20, b"");
        let got = read_to_close(&mut other, Duration::from_secs(3))
            .expect("no answer before the body was sent");
        let text = String::from_utf8_lossy(&got);
        assert_eq!(status_of(&got), 503, "{text}");
        assert!(text.contains("nothing was counted"), "{text}");
    })
    .await
    .unwrap();
}

#[tokio::test]
async fn a_format_check_past_its_budget_is_refused_and_not_counted() {
    let f = fixture(4, &["a"]).await;
    let app = f
        .app(
            Limits {
                check_budget: Duration::ZERO,
                ..Limits::default()
            },
            None,
        )
        .await;
    // A good catalogue padded with 40 MB of comment lines: its check takes
    // longer than the (zero) budget.
    let mut text = catalogue(&f.all, 0.0);
    text.push_str(&"# padding padding padding padding padding padding padding\n".repeat(700_000));
    let (s, body) = call(&app, upload(&format!("Bearer {}", f.tokens[0]), text)).await;
    assert_eq!(s, StatusCode::SERVICE_UNAVAILABLE, "{body}");
    assert!(body.contains("not counted against your team"), "{body}");
    let ch = Challenge::open(&f.state).await.unwrap();
    assert!(ch.store.all_submissions().await.unwrap().is_empty());
    assert!(
        ch.store
            .format_failures_since(1, 0)
            .await
            .unwrap()
            .is_empty()
    );
    // The harness may still be reading it; its file is gone from uploads/.
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert!(
        std::fs::read_dir(f.state.join("uploads"))
            .unwrap()
            .next()
            .is_none()
    );
}

// ---- d. bearer tokens ----

#[tokio::test]
async fn bearer_tokens_are_parsed_strictly_and_rate_limited_by_the_token() {
    let f = fixture(4, &["a"]).await;
    {
        let ch = Challenge::open(&f.state).await.unwrap();
        ch.store.set_meta("requests_per_minute", "4").await.unwrap();
    }
    let app = f.app(Limits::default(), None).await;
    let t = &f.tokens[0];
    let get = |auth: String| {
        Request::get("/api/submissions")
            .header(header::AUTHORIZATION, auth)
            .body(Body::empty())
            .unwrap()
    };
    assert_eq!(
        stepsim_server::bearer_token(b"Bearer abc-._~+/9=="),
        Some("abc-._~+/9==")
    );
    for bad in [
        format!("Bearer  {t}"),
        format!("Bearer {t} "),
        format!("Bearer {t} x"),
        format!("Bearer\t{t}"),
        format!("Bearer {t}=x"),
        format!("Basic {t}"),
        "Bearer ".to_string(),
        "Bearer ==".to_string(),
    ] {
        let (s, body) = call(&app, get(bad.clone())).await;
        assert_eq!(s, StatusCode::UNAUTHORIZED, "{bad:?}: {body}");
    }
    // Four of those carry the token (two spaces, a trailing space, a tab,
    // `Basic`): its key has spent the limit of 4, also for the well-formed
    // header and for new spellings.
    for auth in [
        format!("Bearer {t}"),
        format!("Bearer   {t}"),
        format!("bearer {t}"),
    ] {
        let (s, body) = call(&app, get(auth.clone())).await;
        assert_eq!(s, StatusCode::TOO_MANY_REQUESTS, "{auth:?}: {body}");
    }
    // Another team's key is its own; the scheme's case does not matter.
    let f2 = fixture(4, &["b"]).await;
    let app2 = f2.app(Limits::default(), None).await;
    let (s, body) = call(&app2, get(format!("bearer {}", f2.tokens[0]))).await;
    assert_eq!(s, StatusCode::OK, "{body}");
}

// ---- e. the CSV export ----

#[tokio::test]
async fn the_csv_export_neutralises_team_names_a_spreadsheet_would_run() {
    let evil = "=HYPERLINK(\"http://example.org/\",\"click\")";
    let f = fixture(4, &[evil, "+plus", "@at", "plain"]).await;
    let app = f.app(Limits::default(), None).await;
    for (i, m) in [0.0, 0.01, 0.02, 0.03].into_iter().enumerate() {
        let (s, body) = call(
            &app,
            upload(&format!("Bearer {}", f.tokens[i]), catalogue(&f.all, m)),
        )
        .await;
        assert_eq!(s, StatusCode::ACCEPTED, "{body}");
    }
    f.score_queue().await;
    let ch = Challenge::open(&f.state).await.unwrap();
    let e = ch.export(&f.state.join("board.json")).await.unwrap();
    let csv = std::fs::read_to_string(&e.csv).unwrap();
    let teams: Vec<&str> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(1).unwrap())
        .collect();
    assert_eq!(teams[0], "\"'=HYPERLINK(\"\"http://example.org/\"\"");
    assert_eq!(&teams[1..], ["'+plus", "'@at", "plain"]);
    // Numbers stay numbers (a negative ⟨m⟩ is not prefixed).
    for l in csv.lines().skip(1) {
        assert!(!l.contains(",'-"), "{l}");
    }
    // The JSON export keeps the names as they are.
    let j: Value = json(&std::fs::read_to_string(&e.json).unwrap());
    assert_eq!(j["rows"][0]["team"], evil);
}

// ---- f. refusals do not depend on the private order of datasets ----

/// Two challenges on the same run whose `datasets.json` list the datasets
/// in two orders (same ids, same truth files).
async fn permuted_pair() -> (Fixture, Fixture) {
    let a = fixture(4, &["a"]).await;
    let tmp = tempfile::tempdir().unwrap();
    let (all, _) = write_run(tmp.path());
    let p = tmp.path().join("run/private/datasets.json");
    let mut v: Value = json(&std::fs::read_to_string(&p).unwrap());
    let list = v["datasets"].as_array_mut().unwrap();
    assert!(list.len() >= 4);
    list.reverse();
    list.swap(0, 1);
    std::fs::write(&p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    let state = tmp.path().join("state");
    let ch = common::init(&tmp.path().join("run"), &state, 4, false)
        .await
        .unwrap();
    let tokens = vec![ch.add_team("a").await.unwrap()];
    let b = Fixture {
        _tmp: tmp,
        state,
        all,
        tokens,
    };
    (a, b)
}

#[tokio::test]
async fn refusals_are_byte_identical_whatever_the_private_order_of_datasets() {
    let (a, b) = permuted_pair().await;
    let good = catalogue(&a.all, 0.0);
    let lines: Vec<&str> = good.lines().collect();
    let images: Vec<&str> = {
        let mut v: Vec<&str> = lines[1..]
            .iter()
            .map(|l| l.split_whitespace().next().unwrap())
            .collect();
        v.dedup();
        v
    };
    let without = |drop: &[&str]| -> String {
        let mut t: String = lines
            .iter()
            .filter(|l| !drop.contains(&l.split_whitespace().next().unwrap()))
            .map(|l| format!("{l}\n"))
            .collect();
        t.truncate(t.len());
        t
    };
    let n = images.len();
    let mut bad_row: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
    let mut f: Vec<String> = bad_row[3].split_whitespace().map(String::from).collect();
    f[3] = "abc".into();
    bad_row[3] = f.join(" ");
    let uploads = [
        ("one image missing", without(&[images[n - 1]])),
        (
            "images missing here and there",
            without(&[images[1], images[n / 2], images[n - 2]]),
        ),
        ("every image but one missing", without(&images[1..])),
        (
            "an unknown image id",
            format!("{good}no_such_image 1 1 0.1 0.1 1\n"),
        ),
        ("a bad value on line 4", bad_row.join("\n") + "\n"),
        ("an empty file", String::new()),
    ];
    let (app_a, app_b) = (
        a.app(Limits::default(), None).await,
        b.app(Limits::default(), None).await,
    );
    let mut differ = Vec::new();
    for (what, text) in uploads {
        let ra = call(
            &app_a,
            upload(&format!("Bearer {}", a.tokens[0]), text.clone()),
        )
        .await;
        let rb = call(&app_b, upload(&format!("Bearer {}", b.tokens[0]), text)).await;
        assert_eq!(ra.0, StatusCode::UNPROCESSABLE_ENTITY, "{what}: {}", ra.1);
        if ra != rb {
            differ.push(format!("{what}:\n  {:?}\n  {:?}", ra, rb));
        }
    }
    assert!(
        differ.is_empty(),
        "answers differ with the order of datasets:\n{}",
        differ.join("\n")
    );
}

// ---- h. the final board says when rows are tied within the intervals ----

#[tokio::test]
async fn the_final_board_marks_rows_whose_held_out_intervals_overlap() {
    // Eight base fields in the held-out part: with two, the intervals are
    // widened for Student's t with one degree of freedom (k = 9.2) and do
    // not tell m = 0.5 from m = 0 (measured: [6.94, 6.97] inside [-963, 1811]).
    let f = fixture_of_fields(4, &["exact", "close", "far"], 8).await;
    let app = f.app(Limits::default(), None).await;
    // Catalogues with measurement noise (a fixed pseudo-random number per
    // object; the same for the first two teams), so that the bootstrap
    // intervals have a width.
    let noisy = |m: f64, seed: u64| {
        let rows = f.all.submission(&|t, _| {
            let mut h = (t.id as u64 ^ seed.wrapping_mul(0x9e37_79b9_7f4a_7c15))
                .wrapping_mul(0xbf58_476d_1ce4_e5b9);
            let mut u = || {
                h ^= h >> 31;
                h = h.wrapping_mul(0x94d0_49bb_1331_11eb);
                (h >> 11) as f64 / (1u64 << 53) as f64 - 0.5
            };
            (!t.is_star()).then(|| {
                (
                    (1.0 + m) * t.e1 + 0.2 * u(),
                    (1.0 + m) * t.e2 + 0.2 * u(),
                    1.0,
                )
            })
        });
        stepsim_testkit::synthetic::submission_text(&f.all.index(), &rows)
    };
    for (i, m) in [0.0, 0.0005, 0.5].into_iter().enumerate() {
        let (s, body) = call(
            &app,
            upload(&format!("Bearer {}", f.tokens[i]), noisy(m, [1, 1, 3][i])),
        )
        .await;
        assert_eq!(s, StatusCode::ACCEPTED, "{body}");
    }
    f.score_queue().await;
    // Each row as (team, held-out Q_c interval, tied above), `None` for
    // what the row does not have (before reveal: no interval, no tie).
    type BoardSummary = Vec<(String, Option<[f64; 2]>, Option<bool>)>;
    let rows = async |revealed: bool| -> BoardSummary {
        let ch = Challenge::open(&f.state).await.unwrap();
        let teams = ch.store.teams().await.unwrap();
        let subs = ch.store.all_submissions().await.unwrap();
        stepsim_server::leaderboard_rows(&teams, &subs, revealed)
            .iter()
            .map(|r| {
                (
                    r.team.name.clone(),
                    stepsim_server::q_c_interval(r),
                    r.revealed.as_ref().map(|v| v.tied_above),
                )
            })
            .collect()
    };
    // Before reveal no interval and no tie is shown.
    assert!(
        rows(false)
            .await
            .iter()
            .all(|r| r.1.is_none() && r.2.is_none())
    );
    Challenge::open(&f.state)
        .await
        .unwrap()
        .reveal()
        .await
        .unwrap();
    let summary: Vec<(String, Option<[f64; 2]>, bool)> = rows(true)
        .await
        .into_iter()
        .map(|(team, ci, tied)| (team, ci, tied.unwrap()))
        .collect();
    eprintln!("{summary:?}");
    let teams: Vec<&str> = summary.iter().map(|s| s.0.as_str()).collect();
    assert_eq!(teams, ["exact", "close", "far"], "{summary:?}");
    let [a, b, c] = [
        summary[0].1.unwrap(),
        summary[1].1.unwrap(),
        summary[2].1.unwrap(),
    ];
    assert!(!summary[0].2);
    assert_eq!(summary[1].2, a[0] <= b[1] && b[0] <= a[1], "{summary:?}");
    assert!(
        summary[1].2,
        "m = 0 and m = 0.0005 are not ranked apart: {summary:?}"
    );
    assert!(!summary[2].2, "m = 0.5 is ranked below: {summary:?}");
    assert!(c[1] < b[0], "{summary:?}");
    // The page says so.
    let resp = app
        .clone()
        .oneshot(Request::get("/leaderboard").body(Body::empty()).unwrap())
        .await
        .unwrap();
    let html =
        String::from_utf8_lossy(&resp.into_body().collect().await.unwrap().to_bytes()).into_owned();
    assert_eq!(
        html.matches("<span class=\"tag tied\">tied within the intervals</span>")
            .count(),
        1,
        "{html}"
    );
    assert!(html.contains("this board does not rank them apart"));
}
