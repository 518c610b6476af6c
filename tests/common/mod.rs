//! Helpers shared by the end-to-end tests: declared once in
//! `tests/integration.rs`, used by each test module as `crate::common`.
//!
//! Why a module included by path and not a dev-dependency crate: the
//! runner needs `env!("CARGO_BIN_EXE_stepsim")`, which Cargo sets only when
//! it compiles the root package's integration tests, so a helper crate
//! could not name the binary by itself; and the pieces are small. The FITS
//! table writer (`fits_table.rs`) is also used by the harness's tests,
//! which include that one file with `#[path]` (they run no binary).
#![allow(dead_code)]

pub mod fits_table;
pub mod module_graph;

use std::collections::BTreeMap;
use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The `stepsim` binary under test, ready for arguments. `CI=1` is set, so
/// that progress is printed as lines (as in a log), never as a bar, and
/// `STEPSIM_PSF_STORE=off`, so that no test finds a PSF another test (or
/// the user) built: tests of the user's PSF store set it to a directory.
pub fn stepsim() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_stepsim"));
    c.env("CI", "1");
    c.env("STEPSIM_PSF_STORE", "off");
    c
}

/// Runs `stepsim ARGS` in `dir` and returns its output; its stderr is
/// echoed into the test's own output (shown when the test fails).
pub fn run<S: AsRef<OsStr>>(args: &[S], dir: &Path) -> Output {
    run_with(stepsim().args(args).current_dir(dir))
}

/// [`run`] with extra environment variables.
pub fn run_env<S: AsRef<OsStr>>(args: &[S], dir: &Path, env: &[(&str, &str)]) -> Output {
    run_with(
        stepsim()
            .args(args)
            .current_dir(dir)
            .envs(env.iter().copied()),
    )
}

/// Runs a command made from [`stepsim`] (with its own environment,
/// arguments that are not strings, ...), echoing its stderr like [`run`].
pub fn run_with(c: &mut Command) -> Output {
    let out = c.output().expect("the stepsim binary runs");
    eprintln!("{}", String::from_utf8_lossy(&out.stderr));
    out
}

/// [`run`], failing the test (with the command's stderr) unless it
/// succeeded.
pub fn run_ok<S: AsRef<OsStr>>(args: &[S], dir: &Path) -> Output {
    ok(run(args, dir))
}

/// The output of a command that must have succeeded (else the test fails
/// with its stderr).
pub fn ok(o: Output) -> Output {
    assert!(o.status.success(), "stepsim failed:\n{}", stderr(&o));
    o
}

/// A command's stderr as text.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A command's stdout as text.
pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Every file under `root` (relative path -> bytes).
pub fn files(root: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<PathBuf, Vec<u8>>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                out.insert(
                    p.strip_prefix(root).unwrap().into(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(root, root, &mut out);
    out
}
