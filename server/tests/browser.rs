//! The pages in a real browser: Debian's `chromium`, headless, driven
//! through WebDriver (`chromedriver`, started here on a free port) by
//! fantoccini. A team signs in with its token, uploads a bad catalogue
//! (sees the harness's message with the line number) and a good one
//! through the file input, waits until it is scored and on the
//! leaderboard; after reveal it opens the report with its tables and
//! figures. On the way it opens the data page, an address that is no page,
//! uploads a catalogue missing an image and opens its entry's report
//! before reveal. Screenshots of every page go to `target/screenshots/`.
//!
//! Without `chromium` and `chromedriver` the test fails, naming the
//! packages, unless `STEPSIM_SKIP_BROWSER=1`.

use axum::body::Body;
use axum::http::{Request, StatusCode, header};
use fantoccini::{Client, ClientBuilder, Locator};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use stepsim_server::Challenge;
use stepsim_server::{AppState, router};
use stepsim_testkit::synthetic::SynthRun;
use tower::ServiceExt;

const TEAM: &str = "Lensing Group A";

/// An executable on PATH (or one of `also`), if any.
fn find_program(names: &[&str], also: &[&str]) -> Option<PathBuf> {
    let path = std::env::var_os("PATH").unwrap_or_default();
    for name in names {
        for dir in std::env::split_paths(&path) {
            let p = dir.join(name);
            if p.is_file() {
                return Some(p);
            }
        }
    }
    also.iter().map(PathBuf::from).find(|p| p.is_file())
}

/// chromedriver, killed when dropped.
struct Driver(Child);

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

use crate::common;
use common::catalogue_mc as catalogue;

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn write_run(dir: &Path) -> SynthRun {
    common::write_run_with_readme(
        dir,
        &format!(
            "# Simulated weak-lensing images\n\n\
             This directory holds simulated ground-based images in the style of the Shear \
             TEsting Programme (STEP1). Every image shows galaxies and stars seen through a \
             point-spread function and sheared by a constant reduced shear.\n\n\
             ## What is here\n\n\
             - `manifest.json`: every image with its id, dataset and SHA-256.\n\
             - `<dataset-id>/<image-id>.fits`: the images.\n\n{}",
            stepsim_contract::SUBMISSION_FORMAT_MD
        ),
    )
    .0
}

fn shots_dir() -> PathBuf {
    // CARGO_TARGET_TMPDIR is TARGET/tmp: the shots go beside it.
    let d = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .parent()
        .unwrap()
        .join("screenshots");
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A screenshot of the whole page (the window stretched to its height).
async fn shot(c: &Client, name: &str) {
    let height = c
        .execute("return document.documentElement.scrollHeight;", vec![])
        .await
        .ok()
        .and_then(|v| v.as_u64())
        .unwrap_or(1000)
        .clamp(600, 6000) as u32;
    c.set_window_size(1280, height + 140).await.unwrap();
    let png = c.screenshot().await.unwrap();
    std::fs::write(shots_dir().join(format!("server-{name}.png")), png).unwrap();
    c.set_window_size(1280, 1000).await.unwrap();
}

async fn text_of(c: &Client, css: &str) -> String {
    match c.find(Locator::Css(css)).await {
        Ok(e) => e.text().await.unwrap_or_default(),
        Err(e) => panic!(
            "{css} not on the page ({e}); the page at {:?}:\n{}",
            c.current_url().await.map(|u| u.to_string()),
            c.source().await.unwrap_or_default()
        ),
    }
}

/// Waits (at most 20 s) until the element `css` holds `needle`: a click
/// on a form's button may return before the next page is there.
async fn wait_text(c: &Client, css: &str, needle: &str) -> String {
    let t0 = Instant::now();
    loop {
        if let Ok(e) = c.find(Locator::Css(css)).await {
            if let Ok(t) = e.text().await {
                if t.contains(needle) {
                    return t;
                }
            }
        }
        if t0.elapsed() > Duration::from_secs(20) {
            return text_of(c, css).await;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_team_uses_the_pages_in_a_real_browser() {
    let driver = find_program(&["chromedriver"], &["/usr/lib/chromium/chromedriver"]);
    let chromium = find_program(&["chromium", "chromium-browser"], &[]);
    let (Some(driver), Some(chromium)) = (driver, chromium) else {
        if std::env::var("STEPSIM_SKIP_BROWSER").as_deref() == Ok("1") {
            eprintln!(
                "browser test skipped (STEPSIM_SKIP_BROWSER=1): chromium/chromedriver not found"
            );
            return;
        }
        panic!(
            "the browser test needs Debian's `chromium` and `chromium-driver` packages \
             (chromium and chromedriver on PATH): install them with \
             `apt-get install -y chromium chromium-driver`, or set STEPSIM_SKIP_BROWSER=1 to skip it"
        );
    };

    // The challenge: three teams; the browser is the first.
    let tmp = tempfile::tempdir().unwrap();
    let all = write_run(tmp.path());
    common::write_public(tmp.path(), &all);
    let state = tmp.path().join("state");
    let ch = common::init(&tmp.path().join("run"), &state, 4, false)
        .await
        .unwrap();
    ch.store
        .set_meta("requests_per_minute", "100000")
        .await
        .unwrap();
    let token = ch.add_team(TEAM).await.unwrap();
    let others = [
        ("Durham KSB", -0.021, 0.0004),
        ("KSB+ reference", 0.034, -0.0009),
    ];
    let mut other_tokens: Vec<String> = Vec::new();
    for o in &others {
        other_tokens.push(ch.add_team(o.0).await.unwrap());
    }
    // The reference pipeline's row: shown, tagged, never ranked.
    ch.set_role("KSB+ reference", stepsim_server::Role::Baseline)
        .await
        .unwrap();
    ch.set_name("STEP1-mini challenge").await.unwrap();
    ch.set_deadline(Some(stepsim_server::now_s() + 14 * 86_400))
        .await
        .unwrap();
    drop(ch);
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let base = format!("http://{}", listener.local_addr().unwrap());
    let app = router(AppState::new(Challenge::open(&state).await.unwrap()));
    tokio::spawn(async move {
        axum::serve(
            listener,
            app.into_make_service_with_connect_info::<SocketAddr>(),
        )
        .await
    });
    let stop = Arc::new(AtomicBool::new(false));
    let (dir, stop2) = (state.clone(), stop.clone());
    let worker = std::thread::spawn(move || {
        stepsim_server::run_worker(&dir, stop2, stepsim_server::DEFAULT_TIMEOUT).unwrap();
    });
    // The other teams upload through the API.
    let api = router(AppState::new(Challenge::open(&state).await.unwrap()));
    for ((_, m, c), t) in others.iter().zip(&other_tokens) {
        let resp = api
            .clone()
            .oneshot(
                Request::post("/api/submissions")
                    .header(header::AUTHORIZATION, format!("Bearer {t}"))
                    .body(Body::from(catalogue(&all, *m, *c)))
                    .unwrap(),
            )
            .await
            .unwrap();
        assert_eq!(resp.status(), StatusCode::ACCEPTED);
    }
    // The files the browser uploads: a bad one (line 4 not a number) and a
    // good one.
    let good = catalogue(&all, 0.008, 0.0002);
    let mut lines: Vec<String> = good.lines().map(String::from).collect();
    let mut fields: Vec<&str> = lines[3].split(' ').collect();
    fields[3] = "abc";
    lines[3] = fields.join(" ");
    let bad_path = tmp.path().join("bad-catalogue.txt");
    std::fs::write(&bad_path, lines.join("\n") + "\n").unwrap();
    let good_path = tmp.path().join("good-catalogue.txt");
    std::fs::write(&good_path, &good).unwrap();
    // And one without the rows of its first image.
    let first = good.lines().nth(1).unwrap().split(' ').next().unwrap();
    let partial: String = good
        .lines()
        .filter(|l| !l.starts_with(&format!("{first} ")))
        .map(|l| format!("{l}\n"))
        .collect();
    let partial_path = tmp.path().join("partial-catalogue.txt");
    std::fs::write(&partial_path, partial).unwrap();

    // chromedriver on a free port, headless chromium.
    let port = free_port();
    let log = std::fs::File::create(tmp.path().join("chromedriver.log")).unwrap();
    let _driver = Driver(
        Command::new(&driver)
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", driver.display())),
    );
    let t0 = Instant::now();
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "chromedriver did not listen"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let mut caps = serde_json::Map::new();
    caps.insert(
        "goog:chromeOptions".into(),
        serde_json::json!({
            "binary": chromium,
            "args": ["--headless=new", "--no-sandbox", "--disable-gpu",
                     "--window-size=1280,1000", "--disable-dev-shm-usage",
                     "--force-device-scale-factor=1"],
        }),
    );
    let c = ClientBuilder::new(hyper_util::client::legacy::connect::HttpConnector::new())
        .capabilities(caps)
        .connect(&format!("http://127.0.0.1:{port}"))
        .await
        .expect("chromedriver session");
    let files = Files {
        bad: &bad_path,
        partial: &partial_path,
        good: &good_path,
    };
    let result = browse(&c, &base, &token, &files, &state).await;
    let _ = c.close().await;
    stop.store(true, Ordering::Relaxed);
    worker.join().unwrap();
    result.unwrap();
}

/// The catalogues the browser uploads.
struct Files<'a> {
    /// Line 4 not a number.
    bad: &'a Path,
    /// Without the rows of one image.
    partial: &'a Path,
    /// Scored.
    good: &'a Path,
}

async fn browse(
    c: &Client,
    base: &str,
    token: &str,
    files: &Files<'_>,
    state: &Path,
) -> Result<(), String> {
    let (bad, good) = (files.bad, files.good);
    let err = |e: fantoccini::error::CmdError| e.to_string();
    // The challenge page.
    c.goto(&format!("{base}/")).await.map_err(err)?;
    assert!(text_of(c, "main h1").await.contains("The challenge"));
    assert!(
        text_of(c, "article.readme")
            .await
            .contains("Simulated weak-lensing images")
    );
    shot(c, "challenge").await;
    // The data page: the files, the archive and the command.
    c.find(Locator::LinkText("Data"))
        .await
        .map_err(err)?
        .click()
        .await
        .map_err(err)?;
    let command = wait_text(c, "#command", "sha256sum").await;
    assert!(
        command.ends_with("/data.tar | tar -xf - && (cd public && sha256sum -c SHA256SUMS)"),
        "{command}"
    );
    assert!(text_of(c, "#files").await.contains("manifest.json"));
    shot(c, "data").await;
    // An address that is no page: a page saying so, not JSON.
    c.goto(&format!("{base}/no/such/page")).await.map_err(err)?;
    assert_eq!(text_of(c, "main h1").await, "Not found");
    shot(c, "not-found").await;
    c.goto(&format!("{base}/")).await.map_err(err)?;
    // Sign in with the token.
    c.find(Locator::LinkText("Sign in"))
        .await
        .map_err(err)?
        .click()
        .await
        .map_err(err)?;
    c.find(Locator::Id("token"))
        .await
        .map_err(err)?
        .send_keys(token)
        .await
        .map_err(err)?;
    shot(c, "signin").await;
    c.find(Locator::Css("form.panel button[type=submit]"))
        .await
        .map_err(err)?
        .click()
        .await
        .map_err(err)?;
    let who = wait_text(c, "header .who", TEAM).await;
    assert!(who.contains(TEAM), "signed in: {who}");
    assert_eq!(c.current_url().await.map_err(err)?.path(), "/entries");
    // The bad catalogue: refused, the harness's message with its line.
    let upload = |path: &Path| {
        let p = path.display().to_string();
        async move {
            c.find(Locator::Id("file")).await?.send_keys(&p).await?;
            c.find(Locator::Css("form.upload button"))
                .await?
                .click()
                .await
        }
    };
    upload(bad).await.map_err(err)?;
    let notice = wait_text(c, "#notice", "refused").await;
    assert!(notice.contains("The upload was refused."), "{notice}");
    assert!(notice.contains("line 4"), "the line number: {notice}");
    assert!(notice.contains("the upload"), "{notice}");
    shot(c, "upload-refused").await;
    // A catalogue missing an image: told what to do on the web.
    upload(files.partial).await.map_err(err)?;
    let notice = wait_text(c, "#notice", "rows for every image").await;
    assert!(!notice.contains("--allow-missing-images"), "{notice}");
    shot(c, "upload-refused-missing").await;
    // The good one: queued, then scored (poll, bounded).
    upload(good).await.map_err(err)?;
    let notice = wait_text(c, "#notice", "passed the format check").await;
    assert!(notice.contains("passed the format check"), "{notice}");
    let t0 = Instant::now();
    let id = loop {
        let rows = c
            .find_all(Locator::Css("#entries tbody tr"))
            .await
            .map_err(err)?;
        let first = rows.first().ok_or("no entry row")?;
        let status = first
            .find(Locator::Css(".badge"))
            .await
            .map_err(err)?
            .text()
            .await
            .map_err(err)?;
        if status.eq_ignore_ascii_case("scored") {
            break first
                .find(Locator::Css("td"))
                .await
                .map_err(err)?
                .text()
                .await
                .map_err(err)?;
        }
        assert!(
            !status.eq_ignore_ascii_case("refused"),
            "the good file was refused"
        );
        assert!(t0.elapsed() < Duration::from_secs(60), "not scored in 60 s");
        tokio::time::sleep(Duration::from_millis(300)).await;
        c.refresh().await.map_err(err)?;
    };
    let refused = text_of(c, "#refused-count").await;
    assert!(
        refused.contains("2 of 20 refused uploads in the last 24 hours"),
        "{refused}"
    );
    assert_eq!(
        c.find_all(Locator::Css("#refusals tbody tr"))
            .await
            .map_err(err)?
            .len(),
        2
    );
    shot(c, "entries").await;
    // The entry's report before reveal: when it opens.
    c.goto(&format!("{base}/entries/{id}/report"))
        .await
        .map_err(err)?;
    assert!(text_of(c, "#message").await.contains("opens at reveal"));
    shot(c, "report-not-open").await;
    c.goto(&format!("{base}/entries")).await.map_err(err)?;
    // On the leaderboard.
    c.find(Locator::LinkText("Leaderboard"))
        .await
        .map_err(err)?
        .click()
        .await
        .map_err(err)?;
    let board = wait_text(c, "#board", TEAM).await;
    assert!(board.contains(TEAM), "{board}");
    // Wait for the other teams' entries so the board shows three rows.
    let t0 = Instant::now();
    while c
        .find_all(Locator::Css("#board tbody tr"))
        .await
        .map_err(err)?
        .len()
        < 3
    {
        assert!(t0.elapsed() < Duration::from_secs(60), "board incomplete");
        tokio::time::sleep(Duration::from_millis(300)).await;
        c.refresh().await.map_err(err)?;
    }
    shot(c, "leaderboard").await;
    // Reveal (the organiser's command, through the library); the final
    // board links to the reports; the report has tables and figures.
    Challenge::open(state)
        .await
        .unwrap()
        .reveal()
        .await
        .unwrap();
    c.refresh().await.map_err(err)?;
    let h1 = wait_text(c, "main h1", "Final leaderboard").await;
    assert!(h1.contains("Final leaderboard"), "{h1}");
    shot(c, "leaderboard-final").await;
    c.goto(&format!("{base}/entries/{id}/report"))
        .await
        .map_err(err)?;
    for part in ["holdout", "public"] {
        let tables = c
            .find_all(Locator::Css(&format!("#part-{part} table.data")))
            .await
            .map_err(err)?;
        assert_eq!(tables.len(), 3, "summary, per PSF, per dataset ({part})");
        let imgs = c
            .find_all(Locator::Css(&format!("#part-{part} figure img")))
            .await
            .map_err(err)?;
        assert_eq!(imgs.len(), 4, "{part} figures");
        for img in imgs {
            let w = c
                .execute(
                    "return arguments[0].naturalWidth;",
                    vec![serde_json::to_value(&img).unwrap()],
                )
                .await
                .map_err(err)?
                .as_u64()
                .unwrap_or(0);
            assert!(w > 100, "a figure did not load ({w} px)");
        }
    }
    // Two base fields: report.md's caveat is on the page.
    assert!(
        text_of(c, "#caveat-holdout")
            .await
            .contains("resamples only 2 base fields")
    );
    // The per-dataset tables are folded (a full run lists 30 datasets a
    // part): hidden until their summary line is clicked.
    let shown = |c: &Client| {
        let c = c.clone();
        async move {
            c.execute(
                "return document.querySelector('#part-public table.datasets').checkVisibility() ? 1 : 0;",
                vec![],
            )
            .await
            .map_err(err)
            .map(|v| v.as_u64().unwrap_or(0))
        }
    };
    let height = |c: &Client| {
        let c = c.clone();
        async move {
            c.execute("return document.documentElement.scrollHeight;", vec![])
                .await
                .map_err(err)
                .map(|v| v.as_u64().unwrap_or(0))
        }
    };
    assert_eq!(shown(c).await?, 0, "folded at first");
    let folded = height(c).await?;
    c.find(Locator::Css("#part-public details.datasets > summary"))
        .await
        .map_err(err)?
        .click()
        .await
        .map_err(err)?;
    assert!(shown(c).await? > 0, "shown once clicked");
    let unfolded = height(c).await?;
    eprintln!("report page: {folded} px tall folded, {unfolded} px with one part's datasets shown");
    assert!(unfolded > folded, "{unfolded} > {folded}");
    c.refresh().await.map_err(err)?;
    c.execute("window.scrollTo(0, 0);", vec![])
        .await
        .map_err(err)?;
    shot(c, "report").await;
    // The top of the report (the held-out summary, its caveat, the fits).
    c.set_window_size(1280, 1250).await.map_err(err)?;
    let png = c.screenshot().await.map_err(err)?;
    std::fs::write(shots_dir().join("server-report-top.png"), png).unwrap();
    Ok(())
}
