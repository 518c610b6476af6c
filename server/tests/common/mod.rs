//! The challenge run the server's tests share: each test file includes this
//! module with `mod common;`.
#![allow(dead_code)]

use std::path::Path;
use stepsim_harness::synthetic::{SynthRun, SynthSpec, challenge_run, submission_text};

/// A challenge run written to `dir/run/private`: the public part (2 PSFs ×
/// 2 shears on fields 0-1) and the held-out part (other shears on fields
/// 2-3). Returns the whole run and its held-out part.
pub fn write_run(dir: &Path) -> (SynthRun, SynthRun) {
    write_run_of_fields(dir, 2)
}

/// [`write_run`] with `fields` base fields in each part.
pub fn write_run_of_fields(dir: &Path, fields: u32) -> (SynthRun, SynthRun) {
    let mut spec = SynthSpec::small(fields);
    spec.psfs.truncate(2);
    spec.shears = vec![(0.0, 0.0), (0.05, 0.0)];
    let (_, held, all) = challenge_run(&spec, &[(0.0371, -0.0523), (-0.0617, 0.0289)], 7);
    all.write(&dir.join("run/private")).unwrap();
    (all, held)
}

/// [`write_run`] with `readme` as the participants' README in `dir/run/public`.
pub fn write_run_with_readme(dir: &Path, readme: &str) -> (SynthRun, SynthRun) {
    let run = write_run(dir);
    std::fs::create_dir_all(dir.join("run/public")).unwrap();
    std::fs::write(dir.join("run/public/README.md"), readme).unwrap();
    run
}

/// A catalogue of the whole run: galaxies with multiplicative bias `m` and
/// additive `c` on e1, no stars.
pub fn catalogue_mc(all: &SynthRun, m: f64, c: f64) -> String {
    let rows = all.submission(&|t, _| {
        (!t.is_star()).then_some(((1.0 + m) * t.e1 + c, (1.0 + m) * t.e2, 1.0))
    });
    submission_text(&all.index(), &rows)
}

/// A catalogue of the whole run: galaxies with multiplicative bias `m`,
/// no stars.
pub fn catalogue(all: &SynthRun, m: f64) -> String {
    let rows =
        all.submission(&|t, _| (!t.is_star()).then_some(((1.0 + m) * t.e1, (1.0 + m) * t.e2, 1.0)));
    submission_text(&all.index(), &rows)
}
