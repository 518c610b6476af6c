//! Recipes of README run exactly as written: each block is taken from the
//! document itself, run by `bash` in a fresh directory with `configs/` of
//! the checkout beside it and the `stepsim` under test first on the PATH.
//! The one change made to a block is its port: `127.0.0.1:8080` becomes a
//! port that is free now, so that tests running at once never collide.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The repository's root (the root package's manifest directory).
fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The first ```sh block after the line `heading` of `doc`.
fn sh_block(doc: &str, heading: &str) -> String {
    let at = doc
        .lines()
        .position(|l| l.trim() == heading)
        .unwrap_or_else(|| panic!("no line {heading:?}"));
    let mut lines = doc.lines().skip(at + 1);
    lines
        .by_ref()
        .find(|l| l.trim() == "```sh")
        .unwrap_or_else(|| panic!("no ```sh block after {heading:?}"));
    let body: Vec<&str> = lines.take_while(|l| l.trim() != "```").collect();
    body.join("\n") + "\n"
}

/// A port on 127.0.0.1 that nothing listens on now.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// What a script did: its exit status (`None`: killed at the limit), its
/// output, and whether `port` still answered once it had ended.
struct Ran {
    status: Option<i32>,
    out: String,
    err: String,
    still_listening: bool,
}

/// Runs `script` with bash in `dir` (its own process group, killed whole
/// once it has ended, or at `limit`); checks `port` before that kill.
fn run_script(script: &str, dir: &Path, limit: Duration, port: u16) -> Ran {
    use std::os::unix::process::CommandExt;
    let bin = PathBuf::from(env!("CARGO_BIN_EXE_stepsim"));
    let path = format!(
        "{}:{}",
        bin.parent().unwrap().display(),
        std::env::var("PATH").unwrap_or_default()
    );
    std::fs::write(dir.join("recipe.sh"), script).unwrap();
    // As a script: `bash recipe.sh`. The user's PSF store is off, as in
    // every test (no test reads PSFs another test or the user built).
    let mut child = Command::new("bash")
        .arg("recipe.sh")
        .current_dir(dir)
        .env("PATH", path)
        .env("CI", "1")
        .env("STEPSIM_PSF_STORE", "off")
        .stdin(Stdio::null())
        .stdout(std::fs::File::create(dir.join("recipe.out")).unwrap())
        .stderr(std::fs::File::create(dir.join("recipe.err")).unwrap())
        .process_group(0)
        .spawn()
        .unwrap();
    let pgid = child.id() as i32;
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s.code();
        }
        if start.elapsed() > limit {
            break None;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    // A server the script started must have stopped with it (given 5 s).
    let still_listening = status.is_some()
        && !(0..50).any(|_| {
            std::thread::sleep(Duration::from_millis(100));
            std::net::TcpStream::connect(("127.0.0.1", port)).is_err()
        });
    // The whole group: whatever the script left running goes with it.
    unsafe { libc::kill(-pgid, libc::SIGKILL) };
    let _ = child.wait();
    let read = |f: &str| std::fs::read_to_string(dir.join(f)).unwrap_or_default();
    Ran {
        status,
        out: read("recipe.out"),
        err: read("recipe.err"),
        still_listening,
    }
}

#[test]
fn readme_run_a_challenge_runs_as_written() {
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    let block = sh_block(&readme, "### Run a challenge");
    assert!(block.contains("127.0.0.1:8080"), "{block}");
    let port = free_port();
    let script = block.replace("127.0.0.1:8080", &format!("127.0.0.1:{port}"));
    let tmp = tempfile::tempdir().unwrap();
    std::os::unix::fs::symlink(root().join("configs"), tmp.path().join("configs")).unwrap();
    let Ran {
        status,
        out,
        err,
        still_listening,
    } = run_script(&script, tmp.path(), Duration::from_secs(900), port);
    let log = std::fs::read_to_string(tmp.path().join("runs/c1-serve.log")).unwrap_or_default();
    let context = format!("stdout:\n{out}\nstderr:\n{err}\nserver log:\n{log}");
    assert_eq!(status, Some(0), "the block failed or timed out\n{context}");
    // The block stopped its server when it ended (its `trap`).
    assert!(
        !still_listening,
        "the server still listens on {port}\n{context}"
    );
    // The upload was accepted and queued, then scored.
    assert!(out.contains("\"status\":\"queued\""), "{context}");
    // The board: the team ranked first on the held-out part.
    let board: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tmp.path().join("runs/board.json")).unwrap())
            .unwrap();
    let rows = board["rows"].as_array().expect("board.json has rows");
    assert_eq!(rows.len(), 1, "{board}");
    assert_eq!(rows[0]["team"], "Group A", "{board}");
    assert_eq!(rows[0]["rank"], 1, "{board}");
    assert_eq!(board["part"], "holdout", "{board}");
    assert!(rows[0]["holdout"]["m_mean"].as_f64().is_some(), "{board}");
    // The server's log: a line per request and per upload and scoring job.
    let line = |needles: &[&str]| log.lines().any(|l| needles.iter().all(|n| l.contains(n)));
    assert!(
        log.contains("stepsim serve: listening on http://"),
        "{context}"
    );
    assert!(
        line(&[
            "request",
            "method=POST",
            "path=/api/submissions",
            "status=202",
            "team=1"
        ]),
        "{context}"
    );
    assert!(
        line(&["upload accepted and queued", "team=1", "entry=1"]),
        "{context}"
    );
    assert!(line(&["scoring ended: scored", "entry=1"]), "{context}");
    // Everything it wrote is under runs/ (ignored by git).
    let mut top: Vec<String> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    top.sort();
    assert_eq!(
        top,
        ["configs", "recipe.err", "recipe.out", "recipe.sh", "runs"],
        "{context}"
    );
    let ignore = std::fs::read_to_string(root().join(".gitignore")).unwrap();
    assert!(ignore.lines().any(|l| l.trim() == "/runs"), "{ignore}");
}
