//! The real binary: `stepsim challenge init`, `team add` (token on the last
//! line), `serve` killed with SIGKILL right after accepting uploads, and
//! started again: every accepted submission ends scored exactly once.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use stepsim_contract::run_dir::RunDir;
use stepsim_contract::run_layout::Part;
use stepsim_harness::{PublicFeedback, ScoreOptions, score_part};
use stepsim_testkit::synthetic::{SynthRun, SynthSpec, make_run, submission_text};

/// Runs a call of the async store to its end.
fn bo<F: std::future::Future>(f: F) -> F::Output {
    stepsim_server::block_on(f).unwrap()
}

fn stepsim(args: &[&str]) -> std::process::Output {
    let out = Command::new(env!("CARGO_BIN_EXE_stepsim"))
        .args(args)
        .output()
        .unwrap();
    eprintln!("{}", String::from_utf8_lossy(&out.stderr));
    out
}

/// The lines a server wrote to its standard error, as they come.
type Log = std::sync::Arc<std::sync::Mutex<Vec<String>>>;

/// Starts `stepsim serve` on a free port (its log as JSON with `json`);
/// returns the child, its address and its log.
fn serve(state: &Path, json: bool) -> (Child, String, Log) {
    serve_with(state, json, &[])
}

/// [`serve`] with more arguments.
fn serve_with(state: &Path, json: bool, more: &[&str]) -> (Child, String, Log) {
    let format = if json { "json" } else { "plain" };
    let mut child = Command::new(env!("CARGO_BIN_EXE_stepsim"))
        .args([
            "serve",
            "--state",
            state.to_str().unwrap(),
            "--listen",
            "127.0.0.1:0",
            "--log-format",
            format,
            // A job the kill interrupted is taken again once its lease
            // runs out.
            "--lease-s",
            "3",
        ])
        .args(more)
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let addr = loop {
        let line = lines.next().expect("serve printed its address").unwrap();
        if let Some(a) = line.strip_prefix("stepsim serve: listening on http://") {
            break a.to_string();
        }
    };
    // Keep draining stderr so the server never blocks on it.
    let log = Log::default();
    let log2 = log.clone();
    std::thread::spawn(move || {
        for l in lines.map_while(Result::ok) {
            log2.lock().unwrap().push(l);
        }
    });
    (child, addr, log)
}

/// One HTTP/1.1 request; returns (status, body).
fn http(addr: &str, method: &str, path: &str, token: &str, body: &[u8]) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    let head = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {token}\r\n\
         Content-Length: {}\r\nConnection: close\r\n\r\n",
        body.len()
    );
    s.write_all(head.as_bytes()).unwrap();
    s.write_all(body).unwrap();
    let mut out = String::new();
    s.read_to_string(&mut out).unwrap();
    let status = out[9..12].parse().unwrap();
    let body = out
        .split_once("\r\n\r\n")
        .map(|x| x.1.to_string())
        .unwrap_or_default();
    (status, body)
}

/// A challenge run of 2 PSFs × 2 shears (fields 0-1) and a held-out part
/// (fields 2-3) written to `dir/run/private`; returns it.
fn write_challenge_run(dir: &Path) -> SynthRun {
    let mut spec = SynthSpec::small(2);
    spec.psfs.truncate(2);
    spec.shears = vec![(0.0, 0.0), (0.05, 0.0)];
    let mut all = make_run(&spec);
    let mut h = spec.clone();
    h.shears = vec![(0.03, -0.04), (-0.05, 0.02)];
    h.seed = 5;
    let held = make_run(&h);
    for d in &held.datasets.datasets {
        let mut d = d.clone();
        d.dataset = format!("h{}", d.dataset);
        d.part = Part::Holdout;
        for im in &mut d.images {
            im.image = format!("h{}", im.image);
            im.field += 2;
        }
        all.datasets.datasets.push(d);
    }
    all.truth.extend(held.truth.clone());
    all.write(RunDir::new(dir.join("run")).private().path())
        .unwrap();
    all
}

/// A catalogue of `all` with multiplicative bias `m`.
fn catalogue(all: &SynthRun, m: f64) -> String {
    let rows =
        all.submission(&|t, _| (!t.is_star()).then_some(((1.0 + m) * t.e1, (1.0 + m) * t.e2, 1.0)));
    submission_text(&all.index(), &rows)
}

#[test]
fn a_killed_server_scores_every_accepted_upload_once_after_a_restart() {
    let tmp = tempfile::tempdir().unwrap();
    let all = write_challenge_run(tmp.path());
    let run = tmp.path().join("run");
    let state = tmp.path().join("state");
    let (r, s) = (run.to_str().unwrap(), state.to_str().unwrap());
    // A run without held-out datasets would be refused; this one is taken.
    assert!(
        stepsim(&[
            "challenge",
            "init",
            "--run",
            r,
            "--state",
            s,
            "--quota",
            "5"
        ])
        .status
        .success()
    );
    let out = stepsim(&["challenge", "team", "add", "Team <A>", "--state", s]);
    assert!(out.status.success());
    let stdout = String::from_utf8(out.stdout).unwrap();
    let token = stdout.lines().last().unwrap().to_string();
    assert!(token.starts_with("stp_") && token.len() == 68, "{stdout}");

    let (mut server, addr, _) = serve(&state, false);
    let mut ids = Vec::new();
    let mut files = Vec::new();
    for m in [0.0, 0.01, 0.02] {
        let text = catalogue(&all, m);
        let file = tmp.path().join(format!("cat{}.txt", files.len()));
        std::fs::write(&file, &text).unwrap();
        files.push(file);
        let (status, body) = http(&addr, "POST", "/api/submissions", &token, text.as_bytes());
        assert_eq!(status, 202, "{body}");
        let v: serde_json::Value = serde_json::from_str(&body).unwrap();
        ids.push(v["id"].as_i64().unwrap());
    }
    server.kill().unwrap(); // SIGKILL
    server.wait().unwrap();

    let (mut server, addr, log) = serve(&state, true);
    let mut done = false;
    for _ in 0..1200 {
        let statuses: Vec<String> = ids
            .iter()
            .map(|id| {
                let (_, body) = http(&addr, "GET", &format!("/api/submissions/{id}"), &token, b"");
                let v: serde_json::Value = serde_json::from_str(&body).unwrap();
                v["status"].as_str().unwrap().to_string()
            })
            .collect();
        if statuses.iter().all(|s| s == "scored") {
            done = true;
            break;
        }
        assert!(!statuses.iter().any(|s| s == "refused"), "{statuses:?}");
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    // A job is recorded as scored before its "scoring ended" line is
    // written: give the last line a moment before the kill.
    for _ in 0..100 {
        let text = log.lock().unwrap().join("\n");
        if text.matches("scoring started").count() == text.matches("scoring ended").count() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    server.kill().unwrap();
    server.wait().unwrap();
    assert!(done, "every accepted upload is scored");
    // The JSON log: a line per request (method, path, status, ms, team)
    // and per scoring job, each one JSON object.
    let log: Vec<serde_json::Value> = log
        .lock()
        .unwrap()
        .iter()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{l}: {e}")))
        .collect();
    let first = &ids[0].to_string();
    let request = log
        .iter()
        .find(|v| v["message"] == "request" && v["path"] == format!("/api/submissions/{first}"))
        .unwrap_or_else(|| panic!("no request line: {log:?}"));
    assert_eq!(request["method"], "GET", "{request}");
    assert_eq!(request["status"], 200, "{request}");
    assert_eq!(request["team"], "1", "{request}");
    assert!(request["ms"].as_str().unwrap().parse::<f64>().unwrap() >= 0.0);
    // Every job this server started (those the killed one had not
    // finished) ended scored, each with its line.
    let count = |m: &str| log.iter().filter(|v| v["message"] == m).count();
    let started = count("scoring started");
    assert!(started <= ids.len(), "{log:?}");
    assert_eq!(count("scoring ended: scored"), started, "{log:?}");
    let ch = bo(stepsim_server::Challenge::open(&state)).unwrap();
    let truth = RunDir::new(&run).private().path().to_path_buf();
    for (id, file) in ids.iter().zip(&files) {
        let sub = bo(ch.store.submission(*id)).unwrap().unwrap();
        assert_eq!(
            (sub.status.as_str(), sub.n_scorings),
            ("scored", 1),
            "entry {id}"
        );
        // The numbers of the library code of `stepsim score` on the same
        // file restricted to the public part.
        let report = score_part(&ScoreOptions::new(&truth, file), Part::Public).unwrap();
        let want = serde_json::to_value(PublicFeedback::of_report(&report)).unwrap();
        let got: serde_json::Value =
            serde_json::from_str(sub.public_json.as_deref().unwrap()).unwrap();
        assert_eq!(got, want, "entry {id}");
    }
    drop(ch);

    // Rotate: the old token stops, the new one works; revoke stops it.
    let out = stepsim(&["challenge", "team", "rotate", "Team <A>", "--state", s]);
    assert!(out.status.success());
    let new_token = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .last()
        .unwrap()
        .to_string();
    assert_ne!(new_token, token);
    let (mut server, addr, _) = serve(&state, false);
    assert_eq!(http(&addr, "GET", "/api/submissions", &token, b"").0, 401);
    assert_eq!(
        http(&addr, "GET", "/api/submissions", &new_token, b"").0,
        200
    );
    let out = stepsim(&["challenge", "team", "revoke", "Team <A>", "--state", s]);
    assert!(out.status.success());
    assert_eq!(
        http(&addr, "GET", "/api/submissions", &new_token, b"").0,
        401
    );
    server.kill().unwrap();
    server.wait().unwrap();

    // Reveal and export: JSON, CSV and reports `stepsim leaderboard` reads.
    assert!(
        stepsim(&["challenge", "reveal", "--state", s])
            .status
            .success()
    );
    let board = tmp.path().join("board.json");
    let b = board.to_str().unwrap();
    assert!(
        stepsim(&["challenge", "export", "--state", s, "--out", b])
            .status
            .success()
    );
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&board).unwrap()).unwrap();
    assert_eq!(doc["part"], "holdout");
    assert_eq!(doc["rows"][0]["team"], "Team <A>");
    let csv = std::fs::read_to_string(tmp.path().join("board.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next().unwrap(),
        "rank,team,entry,part,m_mean,sigma_c,q_c,report,role"
    );
    assert!(lines.next().unwrap().starts_with("1,Team <A>,"), "{csv}");
    let report = tmp
        .path()
        .join("board.reports")
        .join(doc["rows"][0]["report"].as_str().unwrap());
    let out = stepsim(&["leaderboard", report.to_str().unwrap()]);
    assert!(out.status.success());
    let table = String::from_utf8(out.stdout).unwrap();
    let entry = format!("entry {}", doc["rows"][0]["entry"]);
    assert!(table.contains(&entry), "{table}");
}

/// `stepsim challenge` with stdin.
fn stepsim_stdin(args: &[&str], input: &str) -> std::process::Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_stepsim"))
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(input.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    eprintln!("{}", String::from_utf8_lossy(&out.stderr));
    out
}

#[test]
fn the_organiser_commands_set_roles_deadline_freeze_close_rescore_and_password() {
    let tmp = tempfile::tempdir().unwrap();
    let mut spec = SynthSpec::small(2);
    spec.psfs.truncate(1);
    spec.shears = vec![(0.0, 0.0)];
    let (_, _, all) = stepsim_testkit::synthetic::challenge_run(&spec, &[(0.03, -0.04)], 5);
    let run = tmp.path().join("run");
    all.write(RunDir::new(&run).private().path()).unwrap();
    let state = tmp.path().join("state");
    let (r, s) = (run.to_str().unwrap(), state.to_str().unwrap());
    // Bad times and roles are usage errors (exit 2) and change nothing.
    let out = stepsim(&[
        "challenge",
        "init",
        "--run",
        r,
        "--state",
        s,
        "--deadline",
        "soon",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("RFC 3339"));
    assert!(!state.join("challenge.db").exists());
    let init = [
        "challenge",
        "init",
        "--run",
        r,
        "--state",
        s,
        "--deadline",
        "2099-01-02T03:04:05+01:00",
        "--name",
        "STEP-mini <test>",
    ];
    assert!(stepsim(&init).status.success());
    assert!(
        stepsim(&["challenge", "team", "add", "KSB", "--state", s])
            .status
            .success()
    );
    let out = stepsim(&[
        "challenge",
        "team",
        "mark",
        "KSB",
        "--role",
        "boss",
        "--state",
        s,
    ]);
    assert_eq!(out.status.code(), Some(2));
    let out = stepsim(&[
        "challenge",
        "team",
        "mark",
        "nobody",
        "--role",
        "baseline",
        "--state",
        s,
    ]);
    assert_eq!(out.status.code(), Some(1));
    let mark = [
        "challenge",
        "team",
        "mark",
        "KSB",
        "--role",
        "baseline",
        "--state",
        s,
    ];
    assert!(stepsim(&mark).status.success());
    let ch = bo(stepsim_server::Challenge::open(&state)).unwrap();
    let team = bo(ch.store.team_by_name("KSB")).unwrap().unwrap();
    assert_eq!(team.role, stepsim_server::Role::Baseline);
    let phase = bo(stepsim_server::Phase::read(ch.store.as_ref())).unwrap();
    assert_eq!(
        phase.deadline_s,
        Some(4_071_002_645),
        "2099-01-02T02:04:05Z"
    );
    assert_eq!(
        bo(ch.store.meta("name")).unwrap().as_deref(),
        Some("STEP-mini <test>")
    );
    drop(ch);
    let at = [
        "challenge",
        "deadline",
        "--state",
        s,
        "--at",
        "2030-06-01T00:00:00Z",
    ];
    assert!(stepsim(&at).status.success());
    assert!(
        stepsim(&["challenge", "freeze", "--state", s])
            .status
            .success()
    );
    let ch = bo(stepsim_server::Challenge::open(&state)).unwrap();
    let phase = bo(stepsim_server::Phase::read(ch.store.as_ref())).unwrap();
    assert_eq!(
        (phase.deadline_s, phase.frozen, phase.closed),
        (Some(1_906_502_400), true, false)
    );
    drop(ch);
    assert!(
        stepsim(&["challenge", "close", "--state", s])
            .status
            .success()
    );
    let out = stepsim(&["challenge", "rescore", "--state", s]);
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("0 scored entries queued again"));
    // The password: the first line of stdin; too short is refused (exit 1).
    let pw = ["challenge", "organiser-password", "--state", s];
    assert_eq!(stepsim_stdin(&pw, "short\n").status.code(), Some(1));
    assert!(
        stepsim_stdin(&pw, "a long enough secret\nsecond line\n")
            .status
            .success()
    );
    let ch = bo(stepsim_server::Challenge::open(&state)).unwrap();
    let phase = bo(stepsim_server::Phase::read(ch.store.as_ref())).unwrap();
    assert!(phase.closed && phase.frozen);
    assert!(bo(ch.verify_organiser_password("a long enough secret")));
    assert!(!bo(
        ch.verify_organiser_password("a long enough secret\nsecond line")
    ));
}

/// A fresh, empty database on the PostgreSQL server of `admin` (a URL
/// whose user may create databases); returns its URL.
fn fresh_database(admin: &str) -> String {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let (client, conn) = tokio_postgres::connect(admin, tokio_postgres::NoTls)
            .await
            .unwrap_or_else(|e| panic!("STEPSIM_TEST_POSTGRES={admin}: {e}"));
        tokio::spawn(conn);
        let name = format!(
            "stepsim_p_{}_{}",
            std::process::id(),
            stepsim_server::now_s()
        );
        client
            .batch_execute(&format!("CREATE DATABASE {name}"))
            .await
            .unwrap();
        let (base, _) = admin.rsplit_once('/').unwrap();
        format!("{base}/{name}")
    })
}

/// Starts `stepsim worker` on `state` with a short lease; its log goes to
/// a file beside the state.
fn worker(state: &Path, name: &str) -> Child {
    let log = std::fs::File::create(state.with_extension(format!("{name}.log"))).unwrap();
    Command::new(env!("CARGO_BIN_EXE_stepsim"))
        .args([
            "worker",
            "--state",
            state.to_str().unwrap(),
            "--lease-s",
            "3",
        ])
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .unwrap()
}

/// Two `serve` (with no workers of their own) and two `worker` processes
/// share one challenge: on the state directory's SQLite file, and on a
/// PostgreSQL database when `STEPSIM_TEST_POSTGRES` names a server
/// (`tests/all.sh` starts one). Uploads go to both servers; one worker is
/// killed with SIGKILL while it scores; its job is taken again by the
/// other once the lease runs out, and every accepted upload ends scored
/// exactly once.
#[test]
fn two_servers_and_two_workers_score_every_upload_once_though_a_worker_is_killed() {
    let mut stores = vec![None];
    if let Ok(admin) = std::env::var("STEPSIM_TEST_POSTGRES") {
        stores.push(Some(fresh_database(&admin)));
    }
    for store in stores {
        several_processes_on_one_store(store.as_deref());
    }
}

fn several_processes_on_one_store(store: Option<&str>) {
    let tmp = tempfile::tempdir().unwrap();
    let all = write_challenge_run(tmp.path());
    let run = tmp.path().join("run");
    let state = tmp.path().join("state");
    let (r, s) = (run.to_str().unwrap(), state.to_str().unwrap());
    let mut init = vec![
        "challenge",
        "init",
        "--run",
        r,
        "--state",
        s,
        "--quota",
        "3",
    ];
    if let Some(url) = store {
        init.extend(["--store", url]);
    }
    assert!(stepsim(&init).status.success());
    assert_eq!(state.join("store.url").exists(), store.is_some());
    let tokens: Vec<String> = ["A", "B", "C"]
        .iter()
        .map(|t| {
            let out = stepsim(&["challenge", "team", "add", t, "--state", s]);
            assert!(out.status.success());
            let text = String::from_utf8(out.stdout).unwrap();
            text.lines().last().unwrap().to_string()
        })
        .collect();
    let servers = [
        serve_with(&state, false, &["--workers", "0"]),
        serve_with(&state, false, &["--workers", "0"]),
    ];
    let addrs: Vec<String> = servers.iter().map(|(_, a, _)| a.clone()).collect();
    let mut logs = vec!["w1".to_string()];
    let mut w1 = worker(&state, "w1");
    // Teams A and B: three uploads each (their quota), each team through
    // both servers.
    let mut ids = Vec::new();
    for k in 0..6 {
        let text = catalogue(&all, 0.01 * k as f64);
        let (addr, token) = (&addrs[(k / 2) % 2], &tokens[k % 2]);
        let (status, body) = http(addr, "POST", "/api/submissions", token, text.as_bytes());
        assert_eq!(status, 202, "{body}");
        let v: serde_json::Value = serde_json::from_str(&body).unwrap();
        ids.push(v["id"].as_i64().unwrap());
    }
    // Team C: six uploads at once, three to each server; the quota of 3
    // holds across the two.
    let burst: Vec<_> = (0..6)
        .map(|k| {
            let (addr, token) = (addrs[k % 2].clone(), tokens[2].clone());
            let text = catalogue(&all, 0.1 + 0.01 * k as f64);
            std::thread::spawn(move || {
                http(&addr, "POST", "/api/submissions", &token, text.as_bytes())
            })
        })
        .collect();
    let mut c_accepted = 0;
    for h in burst {
        let (status, body) = h.join().unwrap();
        assert!(status == 202 || status == 429, "{status} {body}");
        if status == 202 {
            c_accepted += 1;
            let v: serde_json::Value = serde_json::from_str(&body).unwrap();
            ids.push(v["id"].as_i64().unwrap());
        }
    }
    assert!(
        (1..=3).contains(&c_accepted),
        "team C: {c_accepted} accepted"
    );
    let w2 = worker(&state, "w2");
    logs.insert(0, "w2".into());
    // Kill the first worker while it scores (its name holds its pid): a
    // job still `scoring` under its name after the kill was cut off
    // mid-scoring. Should it have finished in the instant between, a new
    // first worker is started and killed in turn.
    let mut killed = None;
    let t0 = std::time::Instant::now();
    while killed.is_none() && t0.elapsed() < std::time::Duration::from_secs(90) {
        let victim = format!(":{}:", w1.id());
        let held: Option<i64> = bo(async {
            let ch = stepsim_server::Challenge::open(&state).await.unwrap();
            leased_by(&ch, &victim).await
        });
        if held.is_none() {
            std::thread::sleep(std::time::Duration::from_millis(10));
            continue;
        }
        w1.kill().unwrap(); // SIGKILL
        w1.wait().unwrap();
        // Any job still `scoring` under the dead worker's name was cut off
        // (it may have finished the one seen and taken another since).
        killed = bo(async {
            let ch = stepsim_server::Challenge::open(&state).await.unwrap();
            leased_by(&ch, &victim).await
        });
        if killed.is_none() {
            let name = format!("w1-{}", logs.len());
            w1 = worker(&state, &name);
            logs.push(name);
        }
    }
    let killed = killed.expect("the first worker was killed while it scored");
    // The killed worker's own log: it may have been killed between taking
    // the job and logging that it started, so its start is not counted.
    let victim_log = logs.last().unwrap().clone();
    let t0 = std::time::Instant::now();
    let mut subs = Vec::new();
    while t0.elapsed() < std::time::Duration::from_secs(120) {
        let ch = bo(stepsim_server::Challenge::open(&state)).unwrap();
        subs = bo(ch.store.all_submissions()).unwrap();
        if subs.len() == ids.len() && subs.iter().all(|s| s.status == "scored") {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    for (mut child, _, _) in servers {
        child.kill().unwrap();
        child.wait().unwrap();
    }
    for mut w in [w1, w2] {
        let _ = w.kill();
        w.wait().unwrap();
    }
    let ch = bo(stepsim_server::Challenge::open(&state)).unwrap();
    assert_eq!(subs.len(), ids.len(), "{subs:?}");
    for sub in &subs {
        assert!(ids.contains(&sub.id), "entry {} was not accepted", sub.id);
        assert_eq!(
            (sub.status.as_str(), sub.n_scorings),
            ("scored", 1),
            "entry {} (the killed worker's job: {killed})",
            sub.id
        );
        let scores = bo(ch.store.scores_of(sub.id)).unwrap();
        assert_eq!(scores.len(), 1, "{scores:?}");
        assert_eq!(scores[0].n_scorings, 1, "{scores:?}");
    }
    // Every job was started once, and the killed one once more by a worker
    // left alive: no worker took a job under a live lease, and the killed
    // job was taken again after its lease ran out. The killed worker's own
    // start of it may be missing from its log (SIGKILL can fall between
    // taking the job and writing the line).
    let read = |n: &String| std::fs::read_to_string(state.with_extension(format!("{n}.log")));
    let starts = |text: &str, id: i64| {
        text.lines()
            .filter(|l| l.contains("scoring started") && l.contains(&format!("entry={id} ")))
            .count()
    };
    let alive: String = logs
        .iter()
        .filter(|n| **n != victim_log)
        .map(|n| read(n).unwrap())
        .collect();
    let dead = read(&victim_log).unwrap();
    for id in &ids {
        let (a, d) = (starts(&alive, *id), starts(&dead, *id));
        if *id == killed {
            assert!(a == 1 && d <= 1, "entry {id}: {alive}{dead}");
        } else {
            assert_eq!(a + d, 1, "entry {id}: {alive}{dead}");
        }
    }
}

/// The job held now under a lease by a worker whose name contains `who`.
async fn leased_by(ch: &stepsim_server::Challenge, who: &str) -> Option<i64> {
    let subs = ch.store.all_submissions().await.ok()?;
    subs.iter()
        .find(|s| s.status == "scoring" && s.worker.as_deref().is_some_and(|w| w.contains(who)))
        .map(|s| s.id)
}
