//! The load benchmark of `stepsim serve` (BENCHMARKS.md, "Server load
//! (#10)"); not a test. It makes a challenge of a generated run, starts the
//! real binary, has `--teams` teams upload `--per-team` catalogues each
//! concurrently (good ones, perturbed ones, duplicates, refused ones),
//! kills the server with SIGKILL once half of the uploads are answered,
//! restarts it, waits for the queue to drain (a job the kill interrupted
//! is taken again once its lease, `--lease-s`, runs out), and checks that every
//! accepted upload (answered 2xx) is scored exactly once. It prints upload
//! latencies (median, p95), scoring throughput and the server's peak RSS.
//!
//! ```sh
//! stepsim generate --config configs/step1-mini.json --out /tmp/load/run \
//!     --set challenge.holdout_fields=1
//! cargo run -p stepsim-server --example load -- \
//!     --stepsim target/debug/stepsim --run /tmp/load/run --work /tmp/load/w
//! ```
//!
//! `--store postgres://USER@HOST:PORT/DATABASE` (an empty database) runs it
//! on PostgreSQL instead of the state directory's SQLite file.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use stepsim_testkit::synthetic::{SynthRun, submission_text};

struct Args {
    stepsim: PathBuf,
    run: PathBuf,
    work: PathBuf,
    teams: usize,
    per_team: usize,
    workers: usize,
    store: Option<String>,
    lease_s: usize,
}

/// The runtime the benchmark's own reads of the store run on (one for the
/// process: a PostgreSQL connection lives on the runtime that opened it).
fn rt() -> &'static tokio::runtime::Runtime {
    static RT: std::sync::OnceLock<tokio::runtime::Runtime> = std::sync::OnceLock::new();
    RT.get_or_init(|| tokio::runtime::Runtime::new().expect("a runtime"))
}

/// The challenge in `state`, opened on [`rt`].
fn open(state: &Path) -> stepsim_server::Challenge {
    rt().block_on(stepsim_server::Challenge::open(state))
        .expect("the challenge")
}

fn args() -> Result<Args, String> {
    let mut a = Args {
        stepsim: PathBuf::from("target/debug/stepsim"),
        run: PathBuf::new(),
        work: PathBuf::new(),
        teams: 50,
        per_team: 4,
        workers: 2,
        store: None,
        lease_s: 10,
    };
    let mut it = std::env::args().skip(1);
    while let Some(k) = it.next() {
        let v = it.next().ok_or(format!("{k} needs a value"))?;
        let n = || {
            v.parse::<usize>()
                .map_err(|_| format!("{k}: {v:?} is not a count"))
        };
        match k.as_str() {
            "--stepsim" => a.stepsim = v.clone().into(),
            "--run" => a.run = v.clone().into(),
            "--work" => a.work = v.clone().into(),
            "--teams" => a.teams = n()?,
            "--per-team" => a.per_team = n()?,
            "--workers" => a.workers = n()?,
            "--store" => a.store = Some(v.clone()),
            "--lease-s" => a.lease_s = n()?,
            _ => return Err(format!("unknown option {k}")),
        }
    }
    if a.run.as_os_str().is_empty() || a.work.as_os_str().is_empty() {
        return Err(
            "usage: load --run RUN --work DIR [--stepsim BIN] [--teams 50] \
                    [--per-team 4] [--workers 2]"
                .into(),
        );
    }
    Ok(a)
}

/// The run's truth, read as the scorer reads it.
fn load_run(run: &Path) -> SynthRun {
    let private = run.join("private");
    let ts = stepsim_harness::load_truth_set(&private).expect("the run's truth");
    let truth = ts
        .index
        .images
        .iter()
        .map(|im| {
            stepsim_contract::io::truth::read_truth_fits(
                &private.join("truth").join(format!("{}.fits", im.image)),
            )
            .expect("a truth table")
        })
        .collect();
    SynthRun {
        datasets: ts.datasets,
        truth,
    }
}

/// A deterministic number in [-1, 1) from two keys.
fn noise(a: u64, b: u64) -> f64 {
    let mut x = a
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(b.wrapping_mul(0xBF58_476D_1CE4_E5B9));
    x ^= x >> 31;
    x = x.wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 29;
    (x >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

/// Upload `k` of team `t`: what it is and its bytes.
fn catalogue(run: &SynthRun, t: usize, k: usize) -> (&'static str, Vec<u8>) {
    let index = run.index();
    // Objects off the image (the truth's margin) are not submitted.
    let (w, h) = (run.datasets.width_px as f64, run.datasets.height_px as f64);
    let text = |rule: &stepsim_testkit::synthetic::Rule| {
        let on = |r: &stepsim_contract::truth::TruthRow| {
            r.x > 0.5 && r.x < w + 0.5 && r.y > 0.5 && r.y < h + 0.5
        };
        submission_text(
            &index,
            &run.submission(&|r, d| if on(r) { rule(r, d) } else { None }),
        )
        .into_bytes()
    };
    let m = 0.002 * t as f64;
    match k % 4 {
        0 => (
            "good",
            text(&|r, _| (!r.is_star()).then_some(((1.0 + m) * r.e1, (1.0 + m) * r.e2, 1.0))),
        ),
        1 => (
            "perturbed",
            text(&|r, _| {
                (!r.is_star()).then_some((
                    (1.0 - m) * r.e1 + 0.05 * noise(r.id as u64, t as u64),
                    r.e2 + 0.05 * noise(r.id as u64, 1000 + t as u64),
                    1.0,
                ))
            }),
        ),
        2 if t % 5 == 0 => ("duplicate", catalogue(run, t, 0).1),
        2 => (
            "offset",
            text(&|r, _| (!r.is_star()).then_some((r.e1 + 0.001 * (t % 7) as f64, r.e2, 0.5))),
        ),
        _ if t % 10 == 0 => {
            let good = catalogue(run, t, 0).1;
            ("bad", good[..good.len() / 2 + 3].to_vec())
        }
        _ => (
            "sparse",
            text(&|r, _| (!r.is_star() && r.id % 3 != 0).then_some((r.e1, r.e2, 1.0))),
        ),
    }
}

fn stepsim(bin: &Path, args: &[&str]) -> String {
    let out = Command::new(bin).args(args).output().expect("stepsim runs");
    assert!(
        out.status.success(),
        "stepsim {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn serve(bin: &Path, state: &Path, addr: &str, workers: usize, lease_s: usize) -> Child {
    let log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(state.with_extension("serve.log"))
        .expect("a log file");
    let mut child = Command::new(bin)
        .args([
            "serve",
            "--state",
            state.to_str().unwrap(),
            "--listen",
            addr,
        ])
        .args(["--workers", &workers.to_string()])
        .args(["--lease-s", &lease_s.to_string()])
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .expect("serve starts");
    for _ in 0..600 {
        if TcpStream::connect(addr).is_ok() {
            return child;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let _ = child.kill();
    let _ = child.wait();
    panic!("the server did not listen on {addr}");
}

/// One request; (status, body), or an error when the connection failed.
fn http(
    addr: &str,
    method: &str,
    path: &str,
    token: &str,
    body: &[u8],
) -> std::io::Result<(u16, String)> {
    let mut s = TcpStream::connect(addr)?;
    s.set_read_timeout(Some(Duration::from_secs(600)))?;
    let head = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {token}\r\n\
         Content-Length: {}\r\nConnection: close\r\n\r\n",
        body.len()
    );
    s.write_all(head.as_bytes())?;
    s.write_all(body)?;
    let mut out = Vec::new();
    s.read_to_end(&mut out)?;
    let out = String::from_utf8_lossy(&out).into_owned();
    let status = out
        .get(9..12)
        .and_then(|c| c.parse().ok())
        .ok_or_else(|| std::io::Error::other(format!("no HTTP answer: {out:?}")))?;
    let body = out
        .split_once("\r\n\r\n")
        .map(|x| x.1.to_string())
        .unwrap_or_default();
    Ok((status, body))
}

fn peak_rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1).and_then(|v| v.parse().ok()))
        })
        .unwrap_or(0)
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[i]
}

fn main() {
    let a = match args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("load: {e}");
            std::process::exit(2);
        }
    };
    let run = Arc::new(load_run(&a.run));
    std::fs::create_dir_all(&a.work).expect("the work directory");
    let state = a.work.join("state");
    let (r, s) = (a.run.to_str().unwrap(), state.to_str().unwrap());
    let mut init = vec![
        "challenge",
        "init",
        "--run",
        r,
        "--state",
        s,
        "--quota",
        "10",
    ];
    if let Some(url) = &a.store {
        init.extend(["--store", url.as_str()]);
    }
    stepsim(&a.stepsim, &init);
    // All teams upload from 127.0.0.1: lift the per-address rate limit.
    {
        let ch = open(&state);
        rt().block_on(ch.store.set_meta("requests_per_minute", "1000000"))
            .expect("a setting");
    }
    let tokens: Vec<String> = (0..a.teams)
        .map(|t| {
            let out = stepsim(
                &a.stepsim,
                &[
                    "challenge",
                    "team",
                    "add",
                    &format!("team {t:02}"),
                    "--state",
                    s,
                ],
            );
            out.lines().last().unwrap().to_string()
        })
        .collect();
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let addr = format!("127.0.0.1:{port}");
    let total = a.teams * a.per_team;
    let mut server = serve(&a.stepsim, &state, &addr, a.workers, a.lease_s);
    let up = Arc::new(AtomicBool::new(true));
    let answered = Arc::new(AtomicUsize::new(0));
    // (team, upload, kind, status, id, latency ms)
    let results = Arc::new(Mutex::new(Vec::new()));
    let failed_connections = Arc::new(AtomicUsize::new(0));
    let t0 = Instant::now();
    let mut handles = Vec::new();
    for (t, token) in tokens.iter().enumerate() {
        let (run, token, addr, up, answered, results, failed) = (
            run.clone(),
            token.clone(),
            addr.clone(),
            up.clone(),
            answered.clone(),
            results.clone(),
            failed_connections.clone(),
        );
        let per_team = a.per_team;
        handles.push(std::thread::spawn(move || {
            for k in 0..per_team {
                let (kind, bytes) = catalogue(&run, t, k);
                loop {
                    while !up.load(Ordering::SeqCst) {
                        std::thread::sleep(Duration::from_millis(50));
                    }
                    let start = Instant::now();
                    match http(&addr, "POST", "/api/submissions", &token, &bytes) {
                        Ok((status, body)) => {
                            let ms = start.elapsed().as_secs_f64() * 1e3;
                            let v: serde_json::Value =
                                serde_json::from_str(&body).unwrap_or_default();
                            if status == 422 && kind != "bad" {
                                eprintln!("load: team {t} upload {k} ({kind}) refused: {body}");
                            }
                            results.lock().unwrap().push((
                                t,
                                k,
                                kind,
                                status,
                                v["id"].as_i64(),
                                ms,
                            ));
                            answered.fetch_add(1, Ordering::SeqCst);
                            break;
                        }
                        // The server was killed under this upload: not
                        // accepted; upload again once it is back.
                        Err(_) => {
                            failed.fetch_add(1, Ordering::SeqCst);
                            std::thread::sleep(Duration::from_millis(200));
                        }
                    }
                }
            }
        }));
    }
    while answered.load(Ordering::SeqCst) < total / 2 {
        std::thread::sleep(Duration::from_millis(20));
    }
    let rss1 = peak_rss_kib(server.id());
    up.store(false, Ordering::SeqCst);
    server.kill().expect("SIGKILL");
    server.wait().unwrap();
    let killed_at = t0.elapsed().as_secs_f64();
    let answered_at_kill = answered.load(Ordering::SeqCst);
    let scored_at_kill = scored_count(&state);
    let mut server = serve(&a.stepsim, &state, &addr, a.workers, a.lease_s);
    let t_restart = Instant::now();
    let scored_at_restart = scored_count(&state);
    up.store(true, Ordering::SeqCst);
    for h in handles {
        h.join().expect("an upload thread");
    }
    let uploads_done = t0.elapsed().as_secs_f64();
    // Wait for the queue to drain.
    loop {
        let ch = open(&state);
        let subs = rt()
            .block_on(ch.store.all_submissions())
            .expect("the entries");
        if subs
            .iter()
            .all(|s| s.status == "scored" || s.status == "refused")
        {
            break;
        }
        drop(ch);
        std::thread::sleep(Duration::from_millis(500));
    }
    let drain_s = t_restart.elapsed().as_secs_f64();
    let rss2 = peak_rss_kib(server.id());
    server.kill().unwrap();
    server.wait().unwrap();

    // None lost, none scored twice.
    let results = results.lock().unwrap().clone();
    let ch = open(&state);
    let subs = rt()
        .block_on(ch.store.all_submissions())
        .expect("the entries");
    let mut accepted: Vec<i64> = results
        .iter()
        .filter(|r| r.3 == 202 || r.3 == 200)
        .filter_map(|r| r.4)
        .collect();
    accepted.sort_unstable();
    accepted.dedup();
    let mut lost = 0;
    for id in &accepted {
        match subs.iter().find(|s| s.id == *id) {
            Some(s) if s.status == "scored" && s.n_scorings == 1 => {
                let scores = rt().block_on(ch.store.scores_of(*id)).expect("scores");
                assert_eq!(scores.len(), 1, "entry {id}: {scores:?}");
                assert_eq!(scores[0].n_scorings, 1, "entry {id} scored twice");
            }
            Some(s) => panic!("entry {id}: {} after {} scorings", s.status, s.n_scorings),
            None => lost += 1,
        }
    }
    assert_eq!(lost, 0, "accepted uploads lost");
    for s in &subs {
        assert!(
            s.n_scorings <= 1,
            "entry {} scored {} times",
            s.id,
            s.n_scorings
        );
    }
    let count = |st: u16| results.iter().filter(|r| r.3 == st).count();
    let mut lat: Vec<f64> = results.iter().filter(|r| r.3 == 202).map(|r| r.5).collect();
    lat.sort_by(f64::total_cmp);
    let scored_after = subs.iter().filter(|s| s.status == "scored").count() - scored_at_restart;
    println!(
        "store {}, teams {}, uploads {} ({} per team), workers {}, lease {} s",
        ch.store.describe(),
        a.teams,
        total,
        a.per_team,
        a.workers,
        a.lease_s
    );
    println!(
        "answers: 202 {}, 200 duplicate {}, 422 refused {}, other {}; connections broken by the kill {}",
        count(202),
        count(200),
        count(422),
        results.len() - count(202) - count(200) - count(422),
        failed_connections.load(Ordering::SeqCst)
    );
    println!(
        "killed at {killed_at:.1} s after {answered_at_kill} answers ({scored_at_kill} scored); uploads done at {uploads_done:.1} s"
    );
    println!(
        "entries in the store {}, accepted (answered) {}, lost 0, scored twice 0",
        subs.len(),
        accepted.len()
    );
    println!(
        "upload latency (202): median {:.0} ms, p95 {:.0} ms, max {:.0} ms (n = {})",
        percentile(&lat, 0.5),
        percentile(&lat, 0.95),
        lat.last().copied().unwrap_or(f64::NAN),
        lat.len()
    );
    println!(
        "scoring after the restart: {scored_after} entries in {drain_s:.1} s = {:.1} entries/min",
        scored_after as f64 / drain_s * 60.0
    );
    println!(
        "server peak RSS (VmHWM): {:.0} MiB before the kill, {:.0} MiB after the restart",
        rss1 as f64 / 1024.0,
        rss2 as f64 / 1024.0
    );
}

fn scored_count(state: &Path) -> usize {
    let ch = open(state);
    rt().block_on(ch.store.all_submissions())
        .expect("the entries")
        .iter()
        .filter(|s| s.status == "scored")
        .count()
}
