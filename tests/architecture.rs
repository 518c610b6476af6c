//! ARCHITECTURE.md matches the tree: every path its code map names exists.
//!
//! The code map is the first fenced block after `## Code map`. A line that
//! starts at column 0 names a path from the repository's root (`src/main.rs`,
//! `contract/`); a directory so named is the prefix of the lines indented by
//! two spaces below it (`  src/truth.rs` under `contract/` is
//! `contract/src/truth.rs`). On such a line the first word is a path, and
//! further words ending in `,` or followed by `,` (`src/metrics.rs, fit.rs,
//! bootstrap.rs`) are its siblings. Deeper-indented lines are prose.

use std::path::Path;

/// The paths the code map of `text` names, from the repository's root.
fn code_map_paths(text: &str) -> Vec<String> {
    let after = text
        .split_once("## Code map")
        .expect("ARCHITECTURE.md has a '## Code map' section")
        .1;
    let block = after
        .split("```")
        .nth(1)
        .expect("the code map is a fenced block");
    let mut paths = Vec::new();
    let mut prefix = String::new();
    for line in block.lines() {
        let (indent, rest) = match line.strip_prefix("  ") {
            Some(r) if !r.starts_with(' ') => (2, r),
            Some(_) => continue,
            None => (0, line),
        };
        let Some(first) = rest.split_whitespace().next() else {
            continue;
        };
        let first = first.trim_end_matches(',');
        let full = if indent == 0 {
            prefix = if first.ends_with('/') {
                first.to_owned()
            } else {
                String::new()
            };
            first.to_owned()
        } else {
            format!("{prefix}{first}")
        };
        paths.push(full.clone());
        // Siblings: `a.rs, b.rs, c.rs` after the first word.
        if rest
            .split_whitespace()
            .next()
            .is_some_and(|w| w.ends_with(','))
        {
            let dir = full.rsplit_once('/').map_or("", |(d, _)| d).to_owned();
            for w in rest.split_whitespace().skip(1) {
                let name = w.trim_end_matches(',');
                paths.push(format!("{dir}/{name}"));
                if !w.ends_with(',') {
                    break;
                }
            }
        }
    }
    paths
}

#[test]
fn the_code_map_reader_finds_prefixed_paths_and_siblings() {
    let text = "## Code map\n\n```\nsrc/main.rs       the CLI\nharness/          the scorer\n  src/metrics.rs, fit.rs, bootstrap.rs   metrics\n                  src/not_a_path.rs in prose\n  tests/          its tests\n```\n";
    assert_eq!(
        code_map_paths(text),
        [
            "src/main.rs",
            "harness/",
            "harness/src/metrics.rs",
            "harness/src/fit.rs",
            "harness/src/bootstrap.rs",
            "harness/tests/",
        ]
    );
}

#[test]
fn every_path_the_code_map_names_exists() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap();
    let paths = code_map_paths(&text);
    assert!(
        paths.len() > 60,
        "only {} paths read: {paths:?}",
        paths.len()
    );
    let missing: Vec<&String> = paths.iter().filter(|p| !root.join(p).exists()).collect();
    assert!(
        missing.is_empty(),
        "ARCHITECTURE.md names paths that do not exist: {missing:?}"
    );
}
