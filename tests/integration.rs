//! The `stepsim` package's integration tests, linked as one binary
//! (`cargo test --test integration`): each file of `tests/` is a module of
//! it, so the workspace is linked once for all of them instead of once per
//! file. The files stay where they are (`tests/generate.rs` is the module
//! `generate`, its tests are `generate::...`); `tests/common/` holds the
//! shared helpers, used as `crate::common`. `autotests = false` in
//! Cargo.toml keeps Cargo from building each file as a binary of its own,
//! so a new file must be named below: [`every_test_file_is_a_module`]
//! fails otherwise. harness, server and sim do the same in their own
//! `tests/integration.rs`.

mod common;

mod architecture;
mod binary_restart;
mod blindness;
mod catalog;
mod challenge_generate;
mod cli_config;
mod cli_measure;
mod generate;
mod golden;
mod hostile_input;
mod presets;
mod psf_cli;
mod recipes;
mod refusal_order;
mod run_integrity;
mod science;
mod score_cli;
mod score_outputs;

use std::collections::BTreeSet;
use std::path::Path;

/// Every `.rs` file and every directory with a `mod.rs` beside the
/// `integration.rs` of the packages whose tests are one binary is declared
/// there with `mod name;`: with `autotests = false` a file named nowhere
/// is not compiled, and its tests would silently never run.
#[test]
fn every_test_file_is_a_module() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for dir in ["tests", "harness/tests", "server/tests", "sim/tests"] {
        let dir = root.join(dir);
        let main = std::fs::read_to_string(dir.join("integration.rs")).unwrap();
        let declared: BTreeSet<&str> = main
            .lines()
            .filter_map(|l| l.strip_prefix("mod ")?.strip_suffix(';'))
            .collect();
        let mut files = BTreeSet::new();
        for entry in std::fs::read_dir(&dir).unwrap() {
            let p = entry.unwrap().path();
            let stem = p.file_stem().unwrap().to_str().unwrap().to_owned();
            let is_module = if p.is_dir() {
                p.join("mod.rs").is_file()
            } else {
                p.extension().is_some_and(|e| e == "rs") && stem != "integration"
            };
            if is_module {
                files.insert(stem);
            }
        }
        assert!(files.len() >= 2, "{}: {files:?}", dir.display());
        let missing: Vec<&String> = files
            .iter()
            .filter(|f| !declared.contains(f.as_str()))
            .collect();
        assert!(
            missing.is_empty(),
            "{}: no `mod` line in integration.rs names {missing:?}, so their tests never run",
            dir.display()
        );
    }
}
