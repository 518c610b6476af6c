//! The participants' pages in-process (tower's `oneshot`), as a browser
//! would use them: sign-in and sessions, CSRF, escaping of a hostile team
//! name, the upload form's refusals, and reports and figures that open
//! only at reveal (docs/server.md, "Pages").

use axum::body::Body;
use axum::http::{HeaderMap, Request, StatusCode, header};
use http_body_util::BodyExt;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use stepsim_server::Challenge;
use stepsim_server::{AppState, router};
use stepsim_testkit::synthetic::SynthRun;
use tower::ServiceExt;

const HOST: &str = "challenge.test";
const ORIGIN: &str = "http://challenge.test";
const HOSTILE: &str = "<script>alert(1)</script>";
/// The `Accept` header Chromium sends for a page.
const BROWSER_ACCEPT: &str = "text/html,application/xhtml+xml,application/xml;q=0.9,\
                              image/avif,image/webp,image/apng,*/*;q=0.8";

use crate::common;
use common::catalogue;

/// The shared challenge run with a participants' README.
fn write_run(dir: &Path) -> (SynthRun, SynthRun) {
    common::write_run_with_readme(
        dir,
        "# Simulated images\n\nMeasure the **shear**; columns `image x y e1 e2`.\n\n\
         - one <b>bold</b> claim\n",
    )
}

struct Fixture {
    _tmp: tempfile::TempDir,
    state: PathBuf,
    all: SynthRun,
    held: SynthRun,
    tokens: Vec<String>,
}

async fn fixture(teams: &[&str]) -> Fixture {
    let tmp = tempfile::tempdir().unwrap();
    let (all, held) = write_run(tmp.path());
    let state = tmp.path().join("state");
    let ch = common::init(&tmp.path().join("run"), &state, 4, false)
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
        held,
        tokens,
    }
}

impl Fixture {
    async fn app(&self) -> axum::Router {
        router(AppState::new(Challenge::open(&self.state).await.unwrap()))
    }
    /// Scores every queued job now (what a worker does).
    async fn score_queue(&self) {
        common::score_queue(&self.state).await;
    }
    async fn reveal(&self) {
        Challenge::open(&self.state)
            .await
            .unwrap()
            .reveal()
            .await
            .unwrap();
    }
}

/// An answer: status, headers, body text.
struct Answer {
    status: StatusCode,
    headers: HeaderMap,
    body: String,
    bytes: Vec<u8>,
}

impl Answer {
    fn location(&self) -> &str {
        self.headers
            .get(header::LOCATION)
            .map_or("", |v| v.to_str().unwrap())
    }
    /// The value of the first hidden `csrf` field of the page.
    fn csrf(&self) -> String {
        let at = self
            .body
            .find("name=\"csrf\" value=\"")
            .unwrap_or_else(|| panic!("no csrf field: {}", self.body));
        let rest = &self.body[at + 19..];
        rest[..rest.find('"').unwrap()].to_string()
    }
}

/// A browser in miniature: keeps cookies, sends Host and Origin.
struct Agent {
    app: axum::Router,
    cookies: HashMap<String, String>,
    origin: Option<String>,
}

impl Agent {
    fn new(app: axum::Router) -> Self {
        Self {
            app,
            cookies: HashMap::new(),
            origin: Some(ORIGIN.into()),
        }
    }

    async fn send(&mut self, mut req: Request<Body>) -> Answer {
        req.headers_mut()
            .insert(header::HOST, HOST.parse().unwrap());
        if !self.cookies.is_empty() {
            let c: Vec<String> = self
                .cookies
                .iter()
                .map(|(k, v)| format!("{k}={v}"))
                .collect();
            req.headers_mut()
                .insert(header::COOKIE, c.join("; ").parse().unwrap());
        }
        if req.method() == "POST" {
            if let Some(o) = &self.origin {
                req.headers_mut().insert(header::ORIGIN, o.parse().unwrap());
            }
        }
        let resp = self.app.clone().oneshot(req).await.unwrap();
        for v in resp.headers().get_all(header::SET_COOKIE) {
            let v = v.to_str().unwrap();
            let (kv, _) = v.split_once(';').unwrap();
            let (k, val) = kv.split_once('=').unwrap();
            if val.is_empty() {
                self.cookies.remove(k);
            } else {
                self.cookies.insert(k.into(), val.into());
            }
        }
        let status = resp.status();
        let headers = resp.headers().clone();
        let body = resp.into_body().collect().await.unwrap().to_bytes();
        Answer {
            status,
            headers,
            body: String::from_utf8_lossy(&body).into_owned(),
            bytes: body.to_vec(),
        }
    }

    async fn get(&mut self, path: &str) -> Answer {
        self.send(Request::get(path).body(Body::empty()).unwrap())
            .await
    }

    /// A GET with this `Accept` header.
    async fn get_accepting(&mut self, path: &str, accept: &str) -> Answer {
        self.send(
            Request::get(path)
                .header(header::ACCEPT, accept)
                .body(Body::empty())
                .unwrap(),
        )
        .await
    }

    /// A GET as a browser sends it (Chromium's `Accept` for a page).
    async fn browse(&mut self, path: &str) -> Answer {
        self.get_accepting(path, BROWSER_ACCEPT).await
    }

    async fn post_form(&mut self, path: &str, fields: &[(&str, &str)]) -> Answer {
        let body = serde_urlencoded::to_string(fields).unwrap();
        self.send(
            Request::post(path)
                .header(header::CONTENT_TYPE, "application/x-www-form-urlencoded")
                .body(Body::from(body))
                .unwrap(),
        )
        .await
    }

    /// The upload form: `csrf` (when given) then `file`.
    async fn upload(&mut self, csrf: Option<&str>, file: &[u8]) -> Answer {
        let mut b = Vec::new();
        if let Some(c) = csrf {
            b.extend_from_slice(
                format!("--XyZ\r\nContent-Disposition: form-data; name=\"csrf\"\r\n\r\n{c}\r\n")
                    .as_bytes(),
            );
        }
        b.extend_from_slice(
            b"--XyZ\r\nContent-Disposition: form-data; name=\"file\"; filename=\"c.txt\"\r\n\
              Content-Type: text/plain\r\n\r\n",
        );
        b.extend_from_slice(file);
        b.extend_from_slice(b"\r\n--XyZ--\r\n");
        self.send(
            Request::post("/entries")
                .header(header::CONTENT_TYPE, "multipart/form-data; boundary=XyZ")
                .body(Body::from(b))
                .unwrap(),
        )
        .await
    }

    /// Signs in with `token` through the form; returns the answer.
    async fn sign_in(&mut self, token: &str) -> Answer {
        let page = self.get("/signin").await;
        assert_eq!(page.status, StatusCode::OK);
        let csrf = page.csrf();
        self.post_form("/signin", &[("csrf", &csrf), ("token", token)])
            .await
    }
}

fn uploads(state: &Path) -> usize {
    std::fs::read_dir(state.join("uploads")).unwrap().count()
}

#[tokio::test]
async fn pages_need_a_session_and_signing_in_sets_a_strict_cookie() {
    let f = fixture(&["alpha", "beta"]).await;
    let mut a = Agent::new(f.app().await);
    // Without a session: the entries page sends to the sign-in page.
    let r = a.get("/entries").await;
    assert_eq!((r.status, r.location()), (StatusCode::SEE_OTHER, "/signin"));
    // The challenge page: the README (its HTML escaped), the rules.
    let r = a.get("/").await;
    assert_eq!(r.status, StatusCode::OK);
    assert!(r.body.contains("<h2>Simulated images</h2>"), "{}", r.body);
    assert!(r.body.contains("<strong>shear</strong>"));
    assert!(r.body.contains("one &lt;b&gt;bold&lt;/b&gt; claim"));
    assert!(
        r.body
            .contains("<strong>4</strong> scored uploads per team")
    );
    assert_eq!(
        r.headers[header::CONTENT_SECURITY_POLICY],
        stepsim_server::PAGE_CSP
    );
    assert!(
        !stepsim_server::PAGE_CSP.contains("script-src")
            && stepsim_server::PAGE_CSP.contains("default-src 'none'")
    );
    assert_eq!(r.headers[header::X_FRAME_OPTIONS], "DENY");
    assert_eq!(r.headers[header::X_CONTENT_TYPE_OPTIONS], "nosniff");
    assert_eq!(r.headers[header::REFERRER_POLICY], "same-origin");
    // The API keeps its own policy.
    let r = a.get("/api/leaderboard").await;
    assert_eq!(
        r.headers[header::CONTENT_SECURITY_POLICY],
        "default-src 'none'; frame-ancestors 'none'"
    );
    assert_eq!(r.headers[header::REFERRER_POLICY], "no-referrer");
    // The stylesheet is served from the binary.
    let r = a.get("/static/style.css").await;
    assert_eq!(r.status, StatusCode::OK);
    assert!(
        r.headers[header::CONTENT_TYPE]
            .to_str()
            .unwrap()
            .starts_with("text/css")
    );
    assert!(r.body.contains("table.data"));
    // A wrong token: 401, the form again, no session.
    let r = a.sign_in("stp_0000").await;
    assert_eq!(r.status, StatusCode::UNAUTHORIZED);
    assert!(r.body.contains("this token is not valid"));
    assert!(!a.cookies.contains_key(stepsim_server::SESSION_COOKIE));
    // The right one: a session cookie, HttpOnly, SameSite=Strict, Path=/.
    let r = a.sign_in(&f.tokens[0]).await;
    assert_eq!(
        (r.status, r.location()),
        (StatusCode::SEE_OTHER, "/entries")
    );
    let set: Vec<&str> = r
        .headers
        .get_all(header::SET_COOKIE)
        .iter()
        .map(|v| v.to_str().unwrap())
        .collect();
    let session = set
        .iter()
        .find(|c| c.starts_with("stepsim_session="))
        .unwrap();
    for attr in ["HttpOnly", "SameSite=Strict", "Path=/;"] {
        assert!(session.contains(attr), "{session}");
    }
    let id = a.cookies[stepsim_server::SESSION_COOKIE].clone();
    assert_eq!(id.len(), 64, "256 random bits");
    let r = a.get("/entries").await;
    assert_eq!(r.status, StatusCode::OK);
    assert!(r.body.contains("Entries of alpha"));
    assert!(r.body.contains("<strong>0</strong> of 4"));
    // Sign out (a form with the session's token): the session ends.
    let csrf = r.csrf();
    let r = a.post_form("/signout", &[("csrf", &csrf)]).await;
    assert_eq!((r.status, r.location()), (StatusCode::SEE_OTHER, "/"));
    let r = a.get("/entries").await;
    assert_eq!(r.status, StatusCode::SEE_OTHER);
    // A session of a token that is then revoked ends too; a stolen cookie
    // value of an ended session does not come back.
    a.sign_in(&f.tokens[1]).await;
    assert_eq!(a.get("/entries").await.status, StatusCode::OK);
    Challenge::open(&f.state)
        .await
        .unwrap()
        .revoke("beta")
        .await
        .unwrap();
    assert_eq!(a.get("/entries").await.status, StatusCode::SEE_OTHER);
    a.cookies
        .insert(stepsim_server::SESSION_COOKIE.into(), id.clone());
    assert_eq!(a.get("/entries").await.status, StatusCode::SEE_OTHER);
}

#[tokio::test]
async fn forms_without_the_right_token_or_from_another_origin_are_refused() {
    let f = fixture(&["alpha"]).await;
    let app = f.app().await;
    let mut a = Agent::new(app.clone());
    // Sign-in: the double-submit token is needed, and the right origin.
    let page = a.get("/signin").await;
    let good = page.csrf();
    for fields in [
        vec![("token", f.tokens[0].as_str())],
        vec![("csrf", "0f0f"), ("token", f.tokens[0].as_str())],
    ] {
        let r = a.post_form("/signin", &fields).await;
        assert_eq!(r.status, StatusCode::FORBIDDEN, "{fields:?}");
        assert!(
            r.body.contains("security token is missing or wrong"),
            "{}",
            r.body
        );
    }
    a.origin = Some("http://evil.example".into());
    let r = a
        .post_form("/signin", &[("csrf", &good), ("token", &f.tokens[0])])
        .await;
    assert_eq!(r.status, StatusCode::FORBIDDEN);
    assert!(r.body.contains("sent from another site"));
    a.origin = Some("null".into());
    let r = a
        .post_form("/signin", &[("csrf", &good), ("token", &f.tokens[0])])
        .await;
    assert_eq!(r.status, StatusCode::FORBIDDEN);
    assert!(!a.cookies.contains_key(stepsim_server::SESSION_COOKIE));
    a.origin = Some(ORIGIN.into());
    a.sign_in(&f.tokens[0]).await;
    let csrf = a.get("/entries").await.csrf();
    let good_file = catalogue(&f.all, 0.0);
    // Upload: without the token, with a wrong one, from another origin.
    let r = a.upload(None, good_file.as_bytes()).await;
    assert_eq!(r.status, StatusCode::FORBIDDEN, "{}", r.body);
    let r = a.upload(Some("deadbeef"), good_file.as_bytes()).await;
    assert_eq!(r.status, StatusCode::FORBIDDEN);
    a.origin = Some("https://evil.example".into());
    let r = a.upload(Some(&csrf), good_file.as_bytes()).await;
    assert_eq!(r.status, StatusCode::FORBIDDEN);
    let r = a.post_form("/signout", &[("csrf", &csrf)]).await;
    assert_eq!(r.status, StatusCode::FORBIDDEN);
    a.origin = Some(ORIGIN.into());
    let r = a.post_form("/signout", &[("csrf", "nope")]).await;
    assert_eq!(r.status, StatusCode::FORBIDDEN);
    // A field before the file larger than 1 KiB is refused unread (400).
    let r = a
        .upload(Some(&"x".repeat(5000)), good_file.as_bytes())
        .await;
    assert_eq!(r.status, StatusCode::BAD_REQUEST, "{}", r.body);
    assert!(r.body.contains("too many or too large fields"));
    assert_eq!(uploads(&f.state), 0, "nothing kept");
    // A post without a session (as a cross-site form arrives under
    // SameSite=Strict) is refused too.
    let mut stranger = Agent::new(app);
    let r = stranger.upload(Some(&csrf), good_file.as_bytes()).await;
    assert_eq!(r.status, StatusCode::FORBIDDEN);
    assert!(r.body.contains("Sign in first"));
    // Still signed in; the right token and origin go through.
    let r = a.upload(Some(&csrf), good_file.as_bytes()).await;
    assert_eq!(
        (r.status, r.location()),
        (StatusCode::SEE_OTHER, "/entries?uploaded=1")
    );
    assert_eq!(uploads(&f.state), 1);
}

#[tokio::test]
async fn the_upload_form_shows_the_harness_message_with_its_line_and_queues_good_files() {
    let f = fixture(&["alpha"]).await;
    let mut a = Agent::new(f.app().await);
    a.sign_in(&f.tokens[0]).await;
    let csrf = a.get("/entries").await.csrf();
    // Line 4 of the file carries a value that is not a number.
    let good = catalogue(&f.all, 0.0);
    let mut lines: Vec<String> = good.lines().map(String::from).collect();
    let mut fields: Vec<&str> = lines[3].split(' ').collect();
    fields[3] = "abc";
    lines[3] = fields.join(" ");
    let bad = lines.join("\n") + "\n";
    let r = a.upload(Some(&csrf), bad.as_bytes()).await;
    assert_eq!(r.status, StatusCode::UNPROCESSABLE_ENTITY, "{}", r.body);
    assert!(r.body.contains("The upload was refused."));
    // The harness's message, as the API gives it for the same bytes.
    let api = f
        .app()
        .await
        .oneshot(
            Request::post("/api/submissions")
                .header(header::AUTHORIZATION, format!("Bearer {}", f.tokens[0]))
                .body(Body::from(bad.clone()))
                .unwrap(),
        )
        .await
        .unwrap();
    let api: serde_json::Value =
        serde_json::from_slice(&api.into_body().collect().await.unwrap().to_bytes()).unwrap();
    let message = api["error"].as_str().unwrap();
    assert!(message.contains("line 4"), "{message}");
    assert!(
        r.body.contains(&stepsim_server::escape_html(message)),
        "{message} not in {}",
        r.body
    );
    assert!(!r.body.contains(f.state.to_str().unwrap()));
    // A good file: queued, then scored with the rounded public feedback.
    let r = a
        .upload(Some(&csrf), catalogue(&f.all, 0.02).as_bytes())
        .await;
    assert_eq!(r.status, StatusCode::SEE_OTHER);
    let r = a.get(r.location().to_string().as_str()).await;
    assert!(
        r.body.contains("Entry 1 passed the format check"),
        "{}",
        r.body
    );
    assert!(
        r.body
            .contains("<span class=\"badge queued\">queued</span>")
    );
    assert!(r.body.contains("<strong>1</strong> of 4"));
    assert!(r.body.contains("leaves the window at"));
    // While an entry waits the page reloads itself (no script needed).
    assert!(
        r.body
            .contains("<meta http-equiv=\"refresh\" content=\"10; url=/entries\">")
    );
    f.score_queue().await;
    let r = a.get("/entries").await;
    assert!(
        r.body
            .contains("<span class=\"badge scored\">scored</span>")
    );
    assert!(!r.body.contains("http-equiv"), "no reload once scored");
    let ch = Challenge::open(&f.state).await.unwrap();
    let public: serde_json::Value = serde_json::from_str(
        &ch.store
            .submission(1)
            .await
            .unwrap()
            .unwrap()
            .public_json
            .unwrap(),
    )
    .unwrap();
    let m = public["m_mean"].as_f64().unwrap();
    assert!((m - 0.02).abs() < 0.002, "{m}");
    assert!(r.body.contains(&format!("+{m:.3}")), "{}", r.body);
    // The same bytes again: recognised, nothing counted.
    let r = a
        .upload(Some(&csrf), catalogue(&f.all, 0.02).as_bytes())
        .await;
    assert_eq!(r.location(), "/entries?uploaded=1&duplicate=1");
}

/// Every dataset id of the run and every held-out shear: none may show
/// on a page before reveal (per-dataset tables and true shears are hidden).
/// True when `body` shows the secret `s`: for a secret that starts and
/// ends with a letter or digit (a dataset id, a shear), only where it
/// stands alone, not inside a longer run of letters and digits (the
/// dataset ids are a few hex digits, which a random CSRF token or checksum
/// holds now and then); other secrets (paths) anywhere.
fn shows(body: &str, s: &str) -> bool {
    let word = |c: char| c.is_ascii_alphanumeric();
    let alone = s.starts_with(|c: char| c.is_ascii_alphanumeric())
        && s.ends_with(|c: char| c.is_ascii_alphanumeric());
    if !alone {
        return body.contains(s);
    }
    body.match_indices(s).any(|(i, _)| {
        let before = body[..i].chars().next_back();
        let after = body[i + s.len()..].chars().next();
        !before.is_some_and(word) && !after.is_some_and(word)
    })
}

#[test]
fn a_secret_inside_a_longer_token_is_not_shown() {
    assert!(shows("dataset d00a here", "d00a"));
    assert!(shows("<td>d00a</td>", "d00a"));
    assert!(!shows("token 3fd00a91 here", "d00a"));
    assert!(!shows("g 10.0400 here", "0.0400"));
    assert!(shows("g = 0.0400.", "0.0400"));
    assert!(shows("g (0.0400)", "0.0400"));
    assert!(shows("/entries/1/figures/x.png", "/figures/"));
}

fn secrets(f: &Fixture) -> Vec<String> {
    let mut v: Vec<String> = f
        .all
        .datasets
        .datasets
        .iter()
        .map(|d| d.dataset.clone())
        .collect();
    for d in &f.held.datasets.datasets {
        v.push(format!("{:.4}", d.g1.abs()));
        v.push(format!("{:.4}", d.g2.abs()));
    }
    v.push("/figures/".into());
    v.push(f.state.display().to_string());
    v
}

#[tokio::test]
async fn a_hostile_team_name_stays_text_on_every_page() {
    let f = fixture(&[HOSTILE, "beta"]).await;
    let mut a = Agent::new(f.app().await);
    a.sign_in(&f.tokens[0]).await;
    let csrf = a.get("/entries").await.csrf();
    let r = a
        .upload(Some(&csrf), catalogue(&f.all, 0.01).as_bytes())
        .await;
    assert_eq!(r.status, StatusCode::SEE_OTHER);
    f.score_queue().await;
    // minijinja writes `/` as `&#x2f;` too.
    let escaped = "&lt;script&gt;alert(1)&lt;&#x2f;script&gt;";
    let secrets = secrets(&f);
    for revealed in [false, true] {
        if revealed {
            f.reveal().await;
        }
        let mut pages = vec!["/", "/signin", "/entries", "/leaderboard"];
        if revealed {
            pages.push("/entries/1/report");
        }
        for page in pages {
            let r = a.get(page).await;
            assert_eq!(r.status, StatusCode::OK, "{page}");
            assert!(!r.body.contains(HOSTILE), "{page}: {}", r.body);
            assert!(!r.body.contains("<script"), "{page}");
            assert!(r.body.contains(escaped), "{page} shows the name escaped");
            if !revealed {
                for s in &secrets {
                    assert!(!shows(&r.body, s), "{page} shows {s:?} before reveal");
                }
            }
        }
    }
}

#[tokio::test]
async fn reports_and_figures_open_at_reveal_only_and_only_named_files() {
    let f = fixture(&["alpha", "beta"]).await;
    let app = f.app().await;
    let mut alpha = Agent::new(app.clone());
    alpha.sign_in(&f.tokens[0]).await;
    let csrf = alpha.get("/entries").await.csrf();
    for m in [0.01, 0.2] {
        let r = alpha
            .upload(Some(&csrf), catalogue(&f.all, m).as_bytes())
            .await;
        assert_eq!(r.status, StatusCode::SEE_OTHER);
    }
    f.score_queue().await;
    let mut anyone = Agent::new(app.clone());
    let mut beta = Agent::new(app);
    beta.sign_in(&f.tokens[1]).await;
    let fig = "/entries/1/figures/public/fig2_shear_response.png";
    let held_fig = "/entries/1/figures/holdout/fig3_m_sigma_c.png";
    // Before reveal: nothing, not even for the entry's own team.
    for agent in [&mut alpha, &mut anyone] {
        for path in ["/entries/1/report", fig, held_fig] {
            let r = agent.get(path).await;
            assert_eq!(r.status, StatusCode::NOT_FOUND, "{path}");
        }
    }
    let r = alpha.get("/entries").await;
    assert!(!r.body.contains("/report"), "no report link before reveal");
    f.reveal().await;
    // After: the ranked entry's report for everyone, with its tables and
    // figures; the other entry for its own team only.
    let r = anyone.get("/leaderboard").await;
    assert!(r.body.contains("Final leaderboard"));
    // The noise-free catalogue's bootstrap has no spread: its interval is
    // shown as "—", not as "Q–Q".
    assert!(
        r.body.contains("<td class=\"num muted\">—</td>"),
        "{}",
        r.body
    );
    assert!(r.body.contains("href=\"/entries/1/report\""), "{}", r.body);
    let r = anyone.get("/entries/1/report").await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.body);
    for part in ["part-holdout", "part-public"] {
        assert!(r.body.contains(part), "{part}");
    }
    for d in f.all.datasets.datasets.iter() {
        assert!(
            r.body.contains(&d.dataset),
            "dataset {} in the tables",
            d.dataset
        );
    }
    let held = &f.held.datasets.datasets[0];
    let g1 = stepsim_harness::round_to(Some(held.g1), 4).unwrap();
    assert!(
        r.body.contains(&format!("{:.4}", g1.abs())),
        "true held-out shear {g1} shown after reveal"
    );
    assert!(
        r.body
            .contains("95 % bootstrap intervals from 200 resamples"),
        "bootstrap intervals"
    );
    assert!(r.body.contains(&format!("src=\"{fig}\"")));
    assert!(r.body.contains(&format!("src=\"{held_fig}\"")));
    for path in [fig, held_fig] {
        let r = anyone.get(path).await;
        assert_eq!(r.status, StatusCode::OK, "{path}");
        assert_eq!(r.headers[header::CONTENT_TYPE], "image/png");
        assert!(r.body.starts_with("\u{FFFD}PNG"), "a PNG file");
    }
    assert_eq!(
        anyone.get("/entries/2/report").await.status,
        StatusCode::NOT_FOUND
    );
    assert_eq!(
        beta.get("/entries/2/report").await.status,
        StatusCode::NOT_FOUND
    );
    assert_eq!(alpha.get("/entries/2/report").await.status, StatusCode::OK);
    // Only the named PNG plots, never another file or a path.
    for path in [
        "/entries/1/figures/public/report.json",
        "/entries/1/figures/public/report.md",
        "/entries/1/figures/public/fig2_shear_response.svg",
        "/entries/1/figures/public/..%2Freport.json",
        "/entries/1/figures/public/..%2F..%2F..%2Fchallenge.db",
        "/entries/1/figures/..%2F..%2Fuploads/fig2_shear_response.png",
        "/entries/1/figures/../../challenge.db",
        "/entries/1/figures/private/fig2_shear_response.png",
        "/entries/..%2F1/figures/public/fig2_shear_response.png",
        "/entries/3/figures/public/fig2_shear_response.png",
        "/entries/x/report",
        "/entries/-1/report",
    ] {
        let r = anyone.get(path).await;
        assert_eq!(r.status, StatusCode::NOT_FOUND, "{path}");
        assert!(!r.body.contains("\"run\""), "{path}");
    }
    // A named plot that does not exist: 404 too.
    std::fs::remove_file(f.state.join("entries/1/public/fig5_residual_magnitude.png")).unwrap();
    let r = anyone
        .get("/entries/1/figures/public/fig5_residual_magnitude.png")
        .await;
    assert_eq!(r.status, StatusCode::NOT_FOUND);
}

#[tokio::test]
async fn the_rate_limit_counts_page_requests() {
    let f = fixture(&["alpha"]).await;
    let ch = Challenge::open(&f.state).await.unwrap();
    ch.store.set_meta("requests_per_minute", "3").await.unwrap();
    let mut a = Agent::new(f.app().await);
    let from = |path: &str| {
        let mut r = Request::get(path).body(Body::empty()).unwrap();
        r.extensions_mut().insert(axum::extract::ConnectInfo(
            "10.1.1.1:5".parse::<std::net::SocketAddr>().unwrap(),
        ));
        r
    };
    for path in ["/", "/leaderboard", "/signin"] {
        assert_eq!(a.send(from(path)).await.status, StatusCode::OK, "{path}");
    }
    let r = a.send(from("/")).await;
    assert_eq!(r.status, StatusCode::TOO_MANY_REQUESTS);
    assert!(r.headers.contains_key(header::RETRY_AFTER));
}

#[tokio::test]
async fn final_entries_are_chosen_on_the_entries_page() {
    let f = fixture(&["alpha", "beta"]).await;
    let app = f.app().await;
    let mut a = Agent::new(app.clone());
    a.sign_in(&f.tokens[0]).await;
    let csrf = a.get("/entries").await.csrf();
    for m in [0.01, 0.2] {
        let r = a.upload(Some(&csrf), catalogue(&f.all, m).as_bytes()).await;
        assert_eq!(r.status, StatusCode::SEE_OTHER);
    }
    f.score_queue().await;
    let r = a.get("/entries").await;
    assert!(
        r.body.contains("final (default)"),
        "the best public entry counts"
    );
    assert!(r.body.contains("name=\"final\" value=\"2\""));
    // Entry 2 chosen through the form.
    let r = a
        .post_form("/entries/final", &[("csrf", &csrf), ("final", "2")])
        .await;
    assert_eq!(
        (r.status, r.location()),
        (StatusCode::SEE_OTHER, "/entries?final=2")
    );
    let ch = Challenge::open(&f.state).await.unwrap();
    assert_eq!(ch.store.final_entries(1).await.unwrap(), vec![2]);
    let r = a.get(r.location().to_string().as_str()).await;
    assert!(r.body.contains("Final entries saved: 2."), "{}", r.body);
    assert!(r.body.contains("id=\"final-2\" checked"));
    // Refused: a wrong token, three entries, an entry of another team.
    let r = a
        .post_form("/entries/final", &[("csrf", "bad"), ("final", "1")])
        .await;
    assert_eq!(r.status, StatusCode::FORBIDDEN);
    let r = a
        .post_form(
            "/entries/final",
            &[
                ("csrf", &csrf),
                ("final", "1"),
                ("final", "2"),
                ("final", "3"),
            ],
        )
        .await;
    assert_eq!(r.status, StatusCode::UNPROCESSABLE_ENTITY);
    assert!(r.body.contains("at most 2 final entries"), "{}", r.body);
    let mut b = Agent::new(app);
    b.sign_in(&f.tokens[1]).await;
    let bcsrf = b.get("/entries").await.csrf();
    let r = b
        .post_form("/entries/final", &[("csrf", &bcsrf), ("final", "1")])
        .await;
    assert_eq!(r.status, StatusCode::NOT_FOUND);
    assert_eq!(
        ch.store.final_entries(1).await.unwrap(),
        vec![2],
        "unchanged"
    );
    // Once closed: no more choices, no form button.
    Challenge::open(&f.state)
        .await
        .unwrap()
        .close()
        .await
        .unwrap();
    let r = a
        .post_form("/entries/final", &[("csrf", &csrf), ("final", "1")])
        .await;
    assert_eq!(r.status, StatusCode::FORBIDDEN);
    assert!(r.body.contains("closed"));
    assert!(!a.get("/entries").await.body.contains("save-final"));
}

#[tokio::test]
async fn the_challenge_page_shows_the_deadline_and_uploads_stop_after_it() {
    let f = fixture(&["alpha", "beta"]).await;
    let ch = Challenge::open(&f.state).await.unwrap();
    ch.set_name("STEP mini 2026").await.unwrap();
    ch.set_deadline(Some(stepsim_server::now_s() + 3600))
        .await
        .unwrap();
    let mut a = Agent::new(f.app().await);
    let r = a.get("/").await;
    assert!(r.body.contains("STEP mini 2026"), "the name in the header");
    assert!(r.body.contains("id=\"deadline\""));
    assert!(r.body.contains("badge queued\">open"));
    ch.set_deadline(Some(stepsim_server::now_s() - 60))
        .await
        .unwrap();
    let r = a.get("/").await;
    assert!(r.body.contains("deadline passed"), "{}", r.body);
    a.sign_in(&f.tokens[0]).await;
    let r = a.get("/entries").await;
    assert!(r.body.contains("id=\"uploads-closed\""));
    assert!(!r.body.contains("enctype=\"multipart/form-data\""));
    let csrf = r.csrf();
    let r = a
        .upload(Some(&csrf), catalogue(&f.all, 0.0).as_bytes())
        .await;
    assert_eq!(r.status, StatusCode::FORBIDDEN);
    assert!(r.body.contains("has passed: no more uploads"), "{}", r.body);
    assert_eq!(uploads(&f.state), 0);
    ch.set_deadline(None).await.unwrap();
    ch.freeze().await.unwrap();
    assert!(a.get("/").await.body.contains("badge refused\">frozen"));
}

#[tokio::test]
async fn roles_are_tagged_and_the_organisers_page_needs_the_password() {
    let f = fixture(&[HOSTILE, "KSB+ reference"]).await;
    let ch = Challenge::open(&f.state).await.unwrap();
    ch.set_role("KSB+ reference", stepsim_server::Role::Baseline)
        .await
        .unwrap();
    ch.set_organiser_password("correct horse").await.unwrap();
    let app = f.app().await;
    for t in &f.tokens {
        let resp = app
            .clone()
            .oneshot(
                Request::post("/api/submissions")
                    .header(header::AUTHORIZATION, format!("Bearer {t}"))
                    .body(Body::from(catalogue(&f.all, 0.01)))
                    .unwrap(),
            )
            .await
            .unwrap();
        assert_eq!(resp.status(), StatusCode::ACCEPTED);
    }
    f.score_queue().await;
    let mut o = Agent::new(app.clone());
    let r = o.get("/leaderboard").await;
    assert!(
        r.body
            .contains("KSB+ reference <span class=\"tag role\">baseline</span>"),
        "{}",
        r.body
    );
    assert!(
        r.body.contains("<td class=\"num rank\">—</td>"),
        "the baseline is not ranked"
    );
    assert!(r.body.contains("<td class=\"num rank\">1</td>"));
    // The organisers' page: the form, a wrong password, the right one.
    let r = o.get("/organisers").await;
    assert!(r.body.contains("Organiser password"));
    assert!(!r.body.contains("id=\"teams\""));
    let csrf = r.csrf();
    let r = o
        .post_form("/organisers/signin", &[("password", "correct horse")])
        .await;
    assert_eq!(r.status, StatusCode::FORBIDDEN, "no CSRF token");
    let r = o
        .post_form(
            "/organisers/signin",
            &[("csrf", &csrf), ("password", "wrong")],
        )
        .await;
    assert_eq!(r.status, StatusCode::UNAUTHORIZED);
    let csrf = r.csrf();
    let r = o
        .post_form(
            "/organisers/signin",
            &[("csrf", &csrf), ("password", "correct horse")],
        )
        .await;
    assert_eq!(
        (r.status, r.location()),
        (StatusCode::SEE_OTHER, "/organisers")
    );
    let r = o.get("/organisers").await;
    assert!(r.body.contains("id=\"teams\"") && r.body.contains("id=\"all-entries\""));
    assert!(
        r.body
            .contains("&lt;script&gt;alert(1)&lt;&#x2f;script&gt;")
    );
    assert!(!r.body.contains(HOSTILE));
    assert!(r.body.contains("<span class=\"tag\">baseline</span>"));
    for s in secrets(&f) {
        assert!(!shows(&r.body, &s), "the organisers' page shows {s:?}");
    }
    // An organiser session is not a team's; a team's is not an organiser's.
    assert_eq!(o.get("/entries").await.status, StatusCode::SEE_OTHER);
    let mut t = Agent::new(app);
    t.sign_in(&f.tokens[0]).await;
    assert!(!t.get("/organisers").await.body.contains("id=\"teams\""));
}

#[tokio::test]
async fn the_organisers_see_refused_uploads_the_queue_and_the_metrics() {
    let f = fixture(&["alpha", "Organisers"]).await;
    let ch = Challenge::open(&f.state).await.unwrap();
    ch.set_role("Organisers", stepsim_server::Role::Organisers)
        .await
        .unwrap();
    ch.set_organiser_password("correct horse").await.unwrap();
    let app = f.app().await;
    let post = |body: String| {
        Request::post("/api/submissions")
            .header(header::AUTHORIZATION, format!("Bearer {}", f.tokens[0]))
            .body(Body::from(body))
            .unwrap()
    };
    // Four refused uploads (never entries), then one accepted.
    for k in 0..4 {
        let resp = app
            .clone()
            .oneshot(post(format!("not a catalogue {k}\n")))
            .await
            .unwrap();
        assert_eq!(resp.status(), StatusCode::UNPROCESSABLE_ENTITY);
    }
    let resp = app
        .clone()
        .oneshot(post(catalogue(&f.all, 0.01)))
        .await
        .unwrap();
    assert_eq!(resp.status(), StatusCode::ACCEPTED);
    // /metrics: not for a participant; for the organisers' token.
    let metrics = |token: &str| {
        Request::get("/metrics")
            .header(header::AUTHORIZATION, format!("Bearer {token}"))
            .body(Body::empty())
            .unwrap()
    };
    let mut o = Agent::new(app.clone());
    let r = o.send(metrics(&f.tokens[0])).await;
    assert_eq!(r.status, StatusCode::UNAUTHORIZED, "{}", r.body);
    assert_eq!(o.get("/metrics").await.status, StatusCode::UNAUTHORIZED);
    let r = o.send(metrics(&f.tokens[1])).await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.body);
    assert!(
        r.headers[header::CONTENT_TYPE]
            .to_str()
            .unwrap()
            .starts_with("text/plain; version=0.0.4")
    );
    for line in [
        "stepsim_uploads_total{status=\"422\"} 4",
        "stepsim_uploads_total{status=\"202\"} 1",
        "stepsim_entries{status=\"queued\"} 1",
        "stepsim_entries{status=\"scored\"} 0",
        "stepsim_format_refusals 4",
        "stepsim_http_requests_total{status=\"401\"} 2",
    ] {
        assert!(r.body.lines().any(|l| l == line), "{line}\n{}", r.body);
    }
    // The organisers' page: the refusals with their messages, counted in
    // the team's row, and the queue.
    let csrf = o.get("/organisers").await.csrf();
    o.post_form(
        "/organisers/signin",
        &[("csrf", &csrf), ("password", "correct horse")],
    )
    .await;
    let r = o.get("/organisers").await;
    assert!(r.body.contains("id=\"refusals\""), "{}", r.body);
    assert_eq!(
        r.body.matches("<td class=\"team\">alpha</td>").count(),
        1 + 1 + 4
    );
    // alpha: 1 entry, 0 scored, 4 refused.
    assert!(
        r.body
            .contains("<td class=\"num\">1</td><td class=\"num\">0</td><td class=\"num\">4</td>"),
        "{}",
        r.body
    );
    assert!(
        r.body.contains(
            "<tbody><tr><td class=\"num\">1</td><td class=\"num\">0</td><td class=\"num\">0</td>\
             <td class=\"num\">0</td><td class=\"num\">4</td>"
        ),
        "{}",
        r.body
    );
    // The signed-in organisers' session reads /metrics too.
    assert_eq!(o.get("/metrics").await.status, StatusCode::OK);
    f.score_queue().await;
    let r = o.get("/organisers").await;
    assert!(
        r.body.contains(
            "<tbody><tr><td class=\"num\">0</td><td class=\"num\">0</td><td class=\"num\">1</td>"
        ),
        "{}",
        r.body
    );
}

/// `GET path` on the API with team `token`: status and JSON body.
async fn api_get(app: &axum::Router, path: &str, token: &str) -> (StatusCode, serde_json::Value) {
    let resp = app
        .clone()
        .oneshot(
            Request::get(path)
                .header(header::AUTHORIZATION, format!("Bearer {token}"))
                .body(Body::empty())
                .unwrap(),
        )
        .await
        .unwrap();
    let status = resp.status();
    let body = resp.into_body().collect().await.unwrap().to_bytes();
    (status, serde_json::from_slice(&body).unwrap())
}

/// Text as the templates write it (minijinja's escaping: `/` and `'` too).
fn esc(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
        .replace('\'', "&#x27;")
        .replace('/', "&#x2f;")
}

/// The part of a page from `from` to the next `to` after it.
fn section<'a>(body: &'a str, from: &str, to: &str) -> &'a str {
    let at = body
        .find(from)
        .unwrap_or_else(|| panic!("no {from:?} in {body}"));
    let rest = &body[at..];
    &rest[..rest.find(to).map_or(rest.len(), |e| e + to.len())]
}

#[tokio::test]
async fn the_data_page_lists_the_files_and_the_archive_extracts_and_verifies() {
    let f = fixture(&["alpha"]).await;
    let files = common::write_public(f.state.parent().unwrap(), &f.all);
    let mut a = Agent::new(f.app().await);
    // The challenge page links to the data page.
    let r = a.browse("/").await;
    assert!(r.body.contains("href=\"/data/\""), "{}", r.body);
    // A browser gets a page: every file with its size and checksum, the
    // archive and the command that downloads and verifies it.
    let r = a.browse("/data/").await;
    assert_eq!(r.status, StatusCode::OK);
    assert!(
        r.headers[header::CONTENT_TYPE]
            .to_str()
            .unwrap()
            .starts_with("text/html"),
        "{:?}",
        r.headers
    );
    assert_eq!(
        r.headers[header::CONTENT_SECURITY_POLICY],
        stepsim_server::PAGE_CSP
    );
    for (path, bytes) in &files {
        use sha2::Digest;
        let sha = stepsim_contract::digest::hex(&sha2::Sha256::digest(bytes));
        assert!(
            r.body.contains(&format!("href=\"/data/{}\"", esc(path))),
            "{path}"
        );
        assert!(r.body.contains(&sha), "{path}: {sha}");
        assert!(
            r.body.contains(&format!("title=\"{} bytes\"", bytes.len())),
            "{path}"
        );
    }
    assert!(r.body.contains("href=\"/data.tar\""));
    let command = "curl -fsS http://challenge.test/data.tar | tar -xf - && \
                   (cd public && sha256sum -c SHA256SUMS)";
    assert!(r.body.contains(&esc(command)), "{}", r.body);
    // A script gets the JSON listing, as before.
    let r = a.get("/data/").await;
    assert_eq!(r.headers[header::CONTENT_TYPE], "application/json");
    let listed: serde_json::Value = serde_json::from_str(&r.body).unwrap();
    assert_eq!(listed["files"].as_array().unwrap().len(), files.len());
    // The archive: its length announced, every file under public/ with
    // SHA256SUMS, no file time; the page's command extracts and verifies it.
    let r = a.get("/data.tar").await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.body);
    assert_eq!(r.headers[header::CONTENT_TYPE], "application/x-tar");
    assert_eq!(
        r.headers[header::CONTENT_LENGTH].to_str().unwrap(),
        r.bytes.len().to_string()
    );
    assert_eq!(&r.bytes[257..262], b"ustar");
    assert_eq!(&r.bytes[136..147], b"00000000000", "mtime 0");
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("data.tar"), &r.bytes).unwrap();
    let run = |dir: &Path, cmd: &str| {
        let out = std::process::Command::new("sh")
            .arg("-c")
            .arg(cmd)
            .current_dir(dir)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{cmd}: {}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    run(
        tmp.path(),
        "tar -xf - < data.tar && (cd public && sha256sum -c SHA256SUMS)",
    );
    for (path, bytes) in &files {
        assert_eq!(
            &std::fs::read(tmp.path().join("public").join(path)).unwrap(),
            bytes
        );
    }
    let sums = std::fs::read_to_string(tmp.path().join("public/SHA256SUMS")).unwrap();
    assert_eq!(sums.lines().count(), files.len());
    // A damaged file fails the check.
    let (first_image, _) = &files[files.len() - 1];
    std::fs::write(tmp.path().join("public").join(first_image), b"changed").unwrap();
    let out = std::process::Command::new("sha256sum")
        .args(["-c", "SHA256SUMS"])
        .current_dir(tmp.path().join("public"))
        .output()
        .unwrap();
    assert!(!out.status.success());
}

#[tokio::test]
async fn refused_uploads_show_on_the_entries_page_with_the_cap() {
    let f = fixture(&["alpha"]).await;
    let app = f.app().await;
    let mut a = Agent::new(app.clone());
    a.sign_in(&f.tokens[0]).await;
    let csrf = a.get("/entries").await.csrf();
    for bad in [
        "not a catalogue\n",
        "# image x y e1 e2 weight\nnope 1 2 3 4 5\n",
    ] {
        let r = a.upload(Some(&csrf), bad.as_bytes()).await;
        assert_eq!(r.status, StatusCode::UNPROCESSABLE_ENTITY, "{}", r.body);
    }
    let r = a
        .upload(Some(&csrf), catalogue(&f.all, 0.01).as_bytes())
        .await;
    assert_eq!(r.status, StatusCode::SEE_OTHER);
    let r = a.get("/entries").await;
    assert!(
        r.body.contains(
            "<strong>2</strong> of 20 <span class=\"muted\">refused uploads in the last 24 hours"
        ),
        "{}",
        r.body
    );
    assert!(r.body.contains("<strong>1</strong> of 4"));
    let refusals = section(&r.body, "id=\"refusals\"", "</table>");
    let failures = Challenge::open(&f.state)
        .await
        .unwrap()
        .store
        .format_failures(Some(1), 10)
        .await
        .unwrap();
    assert_eq!(failures.len(), 2);
    for fl in &failures {
        assert!(
            refusals.contains(&esc(&fl.error)),
            "{} not in {refusals}",
            fl.error
        );
    }
    assert_eq!(refusals.matches("<tr class=\"refused-upload\">").count(), 2);
    // The API: the entries keep their shape; the refusals beside them.
    let (s, v) = api_get(&app, "/api/submissions", &f.tokens[0]).await;
    assert_eq!(s, StatusCode::OK);
    assert_eq!(v["submissions"].as_array().unwrap().len(), 1);
    assert_eq!(v["quota"]["used"], 1);
    let ru = &v["refused_uploads"];
    assert_eq!(
        (ru["used"].as_u64(), ru["limit"].as_u64()),
        (Some(2), Some(20)),
        "{v}"
    );
    assert_eq!(ru["window_hours"], 24);
    assert!(ru["reset"].is_string());
    let recent = ru["recent"].as_array().unwrap();
    assert_eq!(recent.len(), 2);
    assert_eq!(recent[0]["error"], failures[0].error.as_str());
    assert!(recent[0]["created"].is_string());
}

#[tokio::test]
async fn a_catalogue_missing_images_is_refused_in_words_for_the_web() {
    let f = fixture(&["alpha"]).await;
    let app = f.app().await;
    let mut a = Agent::new(app.clone());
    a.sign_in(&f.tokens[0]).await;
    let csrf = a.get("/entries").await.csrf();
    // The catalogue without the rows of its first image.
    let good = catalogue(&f.all, 0.0);
    let first = good.lines().nth(1).unwrap().split(' ').next().unwrap();
    let partial: String = good
        .lines()
        .filter(|l| !l.starts_with(&format!("{first} ")))
        .map(|l| format!("{l}\n"))
        .collect();
    let r = a.upload(Some(&csrf), partial.as_bytes()).await;
    assert_eq!(r.status, StatusCode::UNPROCESSABLE_ENTITY, "{}", r.body);
    let notice = section(&r.body, "id=\"notice\"", "</div>");
    assert!(
        notice.contains(&format!("smallest ids first: {first})")),
        "{notice}"
    );
    assert!(!r.body.contains("--allow-missing-images"), "{notice}");
    assert!(
        notice.contains("the server scores only catalogues with rows for every image"),
        "{notice}"
    );
    // The API and the stored refusal say the same.
    let resp = app
        .clone()
        .oneshot(
            Request::post("/api/submissions")
                .header(header::AUTHORIZATION, format!("Bearer {}", f.tokens[0]))
                .body(Body::from(partial.clone()))
                .unwrap(),
        )
        .await
        .unwrap();
    assert_eq!(resp.status(), StatusCode::UNPROCESSABLE_ENTITY);
    let v: serde_json::Value =
        serde_json::from_slice(&resp.into_body().collect().await.unwrap().to_bytes()).unwrap();
    let message = v["error"].as_str().unwrap();
    assert!(notice.contains(&esc(message)), "{message}");
    let stored = Challenge::open(&f.state)
        .await
        .unwrap()
        .store
        .format_failures(Some(1), 10)
        .await
        .unwrap();
    assert!(stored.iter().all(|s| s.error == message));
}

#[tokio::test]
async fn a_teams_own_report_before_reveal_says_when_it_opens() {
    let f = fixture(&["alpha", "beta"]).await;
    let app = f.app().await;
    let mut alpha = Agent::new(app.clone());
    alpha.sign_in(&f.tokens[0]).await;
    let csrf = alpha.get("/entries").await.csrf();
    let r = alpha
        .upload(Some(&csrf), catalogue(&f.all, 0.01).as_bytes())
        .await;
    assert_eq!(r.status, StatusCode::SEE_OTHER);
    f.score_queue().await;
    let r = alpha.browse("/entries/1/report").await;
    assert_eq!(r.status, StatusCode::NOT_FOUND);
    assert!(r.body.contains("opens at reveal"), "{}", r.body);
    // Another team learns nothing: the answer for an entry that exists is
    // the one for an entry that does not.
    let mut beta = Agent::new(app);
    beta.sign_in(&f.tokens[1]).await;
    let theirs = beta.browse("/entries/1/report").await;
    let none = beta.browse("/entries/99/report").await;
    assert_eq!(theirs.status, StatusCode::NOT_FOUND);
    assert_eq!(theirs.body, none.body);
    assert!(!theirs.body.contains("opens at reveal"));
    f.reveal().await;
    assert_eq!(
        alpha.browse("/entries/1/report").await.status,
        StatusCode::OK
    );
}

#[tokio::test]
async fn unknown_routes_answer_a_page_to_browsers_and_json_to_api_clients() {
    let f = fixture(&["alpha"]).await;
    common::write_public(f.state.parent().unwrap(), &f.all);
    let mut a = Agent::new(f.app().await);
    let r = a.browse("/no/such/page").await;
    assert_eq!(r.status, StatusCode::NOT_FOUND);
    assert!(
        r.headers[header::CONTENT_TYPE]
            .to_str()
            .unwrap()
            .starts_with("text/html"),
        "{}",
        r.body
    );
    assert_eq!(
        r.headers[header::CONTENT_SECURITY_POLICY],
        stepsim_server::PAGE_CSP
    );
    assert!(r.body.contains("href=\"/static/style.css\""));
    assert!(r.body.contains("<h1>Not found</h1>"), "{}", r.body);
    assert!(
        r.body.contains("There is no page at this address"),
        "{}",
        r.body
    );
    assert!(!r.body.contains("such"), "the path is not repeated");
    // A hostile path stays text.
    let r = a.browse("/%3Cscript%3Ealert(1)%3C%2Fscript%3E").await;
    assert_eq!(r.status, StatusCode::NOT_FOUND);
    assert!(!r.body.contains("<script"), "{}", r.body);
    // A file of the data that does not exist: a page too.
    let r = a.browse("/data/nothing.fits").await;
    assert_eq!(r.status, StatusCode::NOT_FOUND);
    assert!(r.body.contains("<h1>Not found</h1>"));
    // API clients, and clients that do not ask for HTML, get JSON.
    for (path, accept) in [
        ("/api/nothing", BROWSER_ACCEPT),
        ("/no/such/page", "*/*"),
        ("/no/such/page", "application/json"),
        ("/data/nothing.fits", "*/*"),
    ] {
        let r = a.get_accepting(path, accept).await;
        assert_eq!(r.status, StatusCode::NOT_FOUND, "{path}");
        assert_eq!(
            r.headers[header::CONTENT_TYPE],
            "application/json",
            "{path} {accept}"
        );
        assert_eq!(r.body, "{\"error\":\"not found\"}");
    }
}

#[tokio::test]
async fn the_default_final_entry_is_one_entry_everywhere_when_public_scores_tie() {
    let f = fixture(&["alpha"]).await;
    let app = f.app().await;
    let mut a = Agent::new(app.clone());
    a.sign_in(&f.tokens[0]).await;
    let csrf = a.get("/entries").await.csrf();
    // The same rows twice (the second with a comment: other bytes, the
    // same scores).
    let rows = catalogue(&f.all, 0.01);
    for text in [rows.clone(), format!("{rows}# the same rows again\n")] {
        let r = a.upload(Some(&csrf), text.as_bytes()).await;
        assert_eq!(r.status, StatusCode::SEE_OTHER, "{}", r.body);
    }
    f.score_queue().await;
    let (_, mine) = api_get(&app, "/api/submissions", &f.tokens[0]).await;
    let subs = mine["submissions"].as_array().unwrap();
    assert_eq!(subs.len(), 2);
    assert_eq!(subs[0]["public"], subs[1]["public"], "a tie");
    assert_eq!(mine["final"], serde_json::json!([1]), "{mine}");
    assert_eq!(mine["final_chosen"], false);
    let (_, board) = api_get(&app, "/api/leaderboard", &f.tokens[0]).await;
    assert_eq!(board["rows"][0]["entry"], 1, "{board}");
    let page = a.get("/entries").await;
    assert!(
        section(&page.body, "<tr id=\"entry-1\">", "</tr>").contains("final (default)"),
        "{}",
        page.body
    );
    assert!(!section(&page.body, "<tr id=\"entry-2\">", "</tr>").contains("tag final"));
    let r = a.get("/leaderboard").await;
    assert!(r.body.contains("<td class=\"num\">1</td>\n"), "{}", r.body);
    // At reveal the same entry counts.
    f.reveal().await;
    let (_, board) = api_get(&app, "/api/leaderboard", &f.tokens[0]).await;
    assert_eq!(board["rows"][0]["entry"], 1, "{board}");
    assert_eq!(board["rows"][0]["finals"], serde_json::json!([1]));
    let (_, mine) = api_get(&app, "/api/submissions", &f.tokens[0]).await;
    assert_eq!(mine["final"], serde_json::json!([1]));
}

/// The (value, low, high) cells of each row of a report's summary tables.
fn summary_cells(body: &str) -> Vec<(String, String, String)> {
    let mut out = Vec::new();
    let mut rest = body;
    while let Some(at) = rest.find("<table class=\"data summary\">") {
        let table = section(&rest[at..], "<tbody>", "</tbody>");
        for row in table.split("<tr>").skip(1) {
            let cells: Vec<String> = row
                .split("<td class=\"num")
                .skip(1)
                .map(|c| {
                    let c = &c[c.find('>').unwrap() + 1..];
                    c[..c.find("</td>").unwrap()].to_string()
                })
                .collect();
            if let [v, lo, hi] = &cells[..] {
                out.push((v.clone(), lo.clone(), hi.clone()));
            }
        }
        rest = &rest[at + 10..];
    }
    out
}

#[tokio::test]
async fn the_report_page_shows_no_interval_of_no_width_and_says_why() {
    let f = fixture(&["alpha"]).await;
    let mut a = Agent::new(f.app().await);
    a.sign_in(&f.tokens[0]).await;
    let csrf = a.get("/entries").await.csrf();
    let r = a
        .upload(Some(&csrf), catalogue(&f.all, 0.01).as_bytes())
        .await;
    assert_eq!(r.status, StatusCode::SEE_OTHER);
    f.score_queue().await;
    f.reveal().await;
    let r = a.get("/entries/1/report").await;
    assert_eq!(r.status, StatusCode::OK);
    let cells = summary_cells(&r.body);
    assert_eq!(cells.len(), 16, "8 figures, 2 parts: {cells:?}");
    // This noise-free catalogue's resamples agree: its intervals have no
    // width at the precision shown, and none may read low = high.
    for (v, lo, hi) in &cells {
        assert!(lo != hi || lo == "—", "{v}: {lo}–{hi}");
    }
    assert!(cells.iter().any(|(_, lo, hi)| lo == "—" && hi == "—"));
    // report.md's caveat on 2 base fields.
    assert!(
        r.body.contains(
            "the interval resamples only 2 base fields (images per dataset), so it can take at \
             most 3 distinct values"
        ),
        "{}",
        r.body
    );
    // Errors of no width at the precision shown read "—", not "± 0.0000".
    for zero in ["± 0.000<", "± 0.0000<", "± 0.00000<"] {
        assert!(!r.body.contains(zero), "{zero}: {}", r.body);
    }
}

/// The text of each `<td>` cell of the row of `body` whose text holds
/// `marker`, tags inside a cell dropped.
fn row_cells(body: &str, marker: &str) -> Vec<String> {
    let at = body
        .find(marker)
        .unwrap_or_else(|| panic!("no {marker:?} in {body}"));
    let start = body[..at].rfind("<tr").unwrap();
    let end = at + body[at..].find("</tr>").unwrap();
    let mut cells = Vec::new();
    let mut rest = &body[start..end];
    while let Some(i) = rest.find("<td") {
        rest = &rest[i..];
        let open = rest.find('>').unwrap() + 1;
        let close = rest.find("</td>").unwrap();
        let mut text = String::new();
        let mut in_tag = false;
        for c in rest[open..close].chars() {
            match c {
                '<' => in_tag = true,
                '>' => in_tag = false,
                c if !in_tag => text.push(c),
                _ => {}
            }
        }
        cells.push(text.trim().to_string());
        rest = &rest[close + 5..];
    }
    cells
}

/// The figure `key` of `figures` as a page cell shows it with `dp`
/// decimals: `—` when the harness gave none, else its digits (the page's
/// sign aside).
fn shown(figures: &serde_json::Value, key: &str, dp: usize) -> String {
    match figures[key].as_f64() {
        Some(v) => format!("{:.dp$}", v.abs()),
        None => "—".to_string(),
    }
}

/// Every figure the harness stored for an entry is on its team's entries
/// page and on the board: the pages read the harness's fields, so a
/// figure renamed on one side is a compile error, not a cell of "—".
#[tokio::test]
async fn every_figure_the_harness_gave_is_on_the_pages() {
    let f = fixture(&["alpha"]).await;
    let app = f.app().await;
    let mut alpha = Agent::new(app.clone());
    alpha.sign_in(&f.tokens[0]).await;
    let csrf = alpha.get("/entries").await.csrf();
    let r = alpha
        .upload(Some(&csrf), catalogue(&f.all, 0.02).as_bytes())
        .await;
    assert_eq!(r.status, StatusCode::SEE_OTHER);
    f.score_queue().await;
    let (s, v) = api_get(&app, "/api/submissions/1", &f.tokens[0]).await;
    assert_eq!(s, StatusCode::OK, "{v}");
    let public = &v["public"];
    let keys = ["m_mean", "sigma_c", "q_c", "pct_stars", "pct_false"];
    for k in keys {
        assert!(public[k].is_number(), "the harness gave {k}: {public}");
    }
    // Entries page: ⟨m⟩, σ_c, Q_c, stars %, false % after five fixed cells.
    let r = alpha.get("/entries").await;
    let cells = row_cells(&r.body, "id=\"entry-1\"");
    for (cell, (k, dp)) in cells[5..10]
        .iter()
        .zip(keys.into_iter().zip([3, 4, 0, 1, 1]))
    {
        let want = shown(public, k, dp);
        assert!(cell.contains(&want), "{k}: {cell:?} shows {want:?}");
        assert_ne!(cell, "—", "{k}");
    }
    f.reveal().await;
    let (_, v) = api_get(&app, "/api/submissions/1", &f.tokens[0]).await;
    let holdout = &v["holdout"];
    for k in ["m_mean", "sigma_c", "q_c"] {
        assert!(holdout[k].is_number(), "the harness gave {k}: {holdout}");
    }
    // Board after reveal: rank, team, entries, entry, then held-out Q_c,
    // its interval, ⟨m⟩, σ_c, then public Q_c, ⟨m⟩, σ_c.
    let r = alpha.get("/leaderboard").await;
    let cells = row_cells(&r.body, "href=\"/entries/1/report\"");
    let figures = [
        (4, holdout, "q_c", 1),
        (6, holdout, "m_mean", 4),
        (7, holdout, "sigma_c", 5),
        (8, public, "q_c", 0),
        (9, public, "m_mean", 3),
        (10, public, "sigma_c", 4),
    ];
    for (i, part, k, dp) in figures {
        let want = shown(part, k, dp);
        assert!(
            cells[i].contains(&want),
            "{k}: cell {i} {:?} shows {want:?} ({cells:?})",
            cells[i]
        );
        assert_ne!(cells[i], "—", "{k}");
    }
    assert_eq!(cells[0], "1", "{cells:?}");
}
