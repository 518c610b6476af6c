//! The harness's modules stand in layers, and ARCHITECTURE.md lists their
//! graph as it is.
//!
//! ```text
//! pipeline, part, combine   the stages end to end: may use everything below
//!                           (part and combine build on pipeline)
//! report                    the outputs: the report types of score, the
//!                           bounded reads of read
//! score                     pure functions of tables: the rows read made
//! read                      the readers: nothing but error
//! error                     nothing of the crate
//! ```
//!
//! Every `crate::name` path (including `use crate::{a, b::c}` groups) in a
//! file under `harness/src/<module>` is an edge `<module> -> name`;
//! comments and strings are left out (the reading of sim's and the
//! server's `tests/module_graph.rs`). What `lib.rs` re-exports makes no
//! edge.

use std::path::{Path, PathBuf};

#[path = "../../tests/common/module_graph.rs"]
mod graph;
use graph::*;

fn harness_src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// What each top-level module may use of the others.
const ALLOWED: [(&str, &[&str]); 7] = [
    ("error", &[]),
    ("read", &["error"]),
    ("score", &["error", "read"]),
    ("report", &["error", "read", "score"]),
    ("pipeline", &["error", "read", "report", "score"]),
    ("part", &["error", "pipeline", "read", "report", "score"]),
    ("combine", &["error", "pipeline", "read", "report", "score"]),
];

#[test]
fn harness_modules_stand_in_layers() {
    let g = module_graph(&harness_src());
    assert_layered(
        &g,
        &[
            "combine", "error", "part", "pipeline", "read", "report", "score",
        ],
        &ALLOWED,
        "the harness",
    );
}

#[test]
fn the_layer_check_sees_an_edge_upwards() {
    let mut g = module_graph(&harness_src());
    g.get_mut("read").unwrap().insert("score".into());
    g.get_mut("score").unwrap().insert("report".into());
    g.get_mut("report").unwrap().insert("pipeline".into());
    assert_eq!(
        offences(&g, &ALLOWED),
        ["read -> score", "report -> pipeline", "score -> report"]
    );
    assert!(find_cycle(&g).is_some());
}

/// Layers are reached by `crate::` paths only: a `super::super::` path
/// from one folder into another would make an edge the reader cannot see.
#[test]
fn other_layers_are_named_from_the_crate_root() {
    let mut files = Vec::new();
    rust_files(&harness_src(), &mut files);
    assert!(files.len() > 15, "{} files", files.len());
    let offenders: Vec<String> = files
        .iter()
        .filter(|f| code_only(&std::fs::read_to_string(f).unwrap()).contains("super::super"))
        .map(|f| f.display().to_string())
        .collect();
    assert!(offenders.is_empty(), "super::super in {offenders:?}");
}

#[test]
fn architecture_lists_the_harness_module_graph_as_it_is() {
    let g = module_graph(&harness_src());
    let doc_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../ARCHITECTURE.md");
    let doc = std::fs::read_to_string(&doc_path).unwrap();
    let start = "<!-- harness module graph: begin -->\n```\n";
    let end = "```\n<!-- harness module graph: end -->";
    let (Some(a), Some(b)) = (doc.find(start), doc.find(end)) else {
        panic!("ARCHITECTURE.md has no block between {start:?} and {end:?}");
    };
    assert_eq!(
        &doc[a + start.len()..b],
        listing(&g),
        "ARCHITECTURE.md's harness module graph differs from the code; the graph now is:\n{}",
        listing(&g)
    );
}
