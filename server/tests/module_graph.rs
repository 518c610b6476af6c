//! The server's modules stand in layers, and ARCHITECTURE.md lists their
//! graph as it is.
//!
//! ```text
//! http                 the handlers (axum): may use everything below
//! worker, observe      beside the handlers: the challenge and the store,
//!                      and no HTTP
//! challenge            the challenge core: the store only, and no HTTP
//! store                nothing of the crate
//! ```
//!
//! Every `crate::name` path (including `use crate::{a, b::c}` groups) in a
//! file under `server/src/<module>` is an edge `<module> -> name`;
//! comments and strings are left out (the same reading as sim's
//! `tests/module_graph.rs`). Items of `lib.rs` itself (`now_s`, `hex`, ...)
//! are no module and make no edge.

use std::path::{Path, PathBuf};

#[path = "../../tests/common/module_graph.rs"]
mod graph;
use graph::*;

fn server_src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// What each top-level module may use of the others.
const ALLOWED: [(&str, &[&str]); 5] = [
    ("store", &[]),
    ("challenge", &["store"]),
    ("observe", &["store"]),
    ("worker", &["challenge", "observe", "store"]),
    ("http", &["challenge", "observe", "store", "worker"]),
];

#[test]
fn server_modules_stand_in_layers() {
    let g = module_graph(&server_src());
    assert_layered(
        &g,
        &["challenge", "http", "observe", "store", "worker"],
        &ALLOWED,
        "the server",
    );
}

#[test]
fn the_layer_check_sees_an_edge_upwards() {
    let mut g = module_graph(&server_src());
    g.get_mut("challenge").unwrap().insert("http".into());
    g.get_mut("store").unwrap().insert("challenge".into());
    assert_eq!(
        offences(&g, &ALLOWED),
        ["challenge -> http", "store -> challenge"]
    );
}

/// What in code speaks HTTP: the web framework and the server's error
/// answer.
const HTTP_WORDS: [&str; 7] = [
    "axum",
    "hyper",
    "tower",
    "http_body",
    "StatusCode",
    "ApiError",
    "IntoResponse",
];

/// The HTTP words in the code (not comments, not strings) of every file
/// under `dir`, as "file: words".
fn http_words_under(dir: &Path) -> (usize, Vec<String>) {
    let mut files = Vec::new();
    rust_files(dir, &mut files);
    let mut found = Vec::new();
    for f in &files {
        let code = code_only(&std::fs::read_to_string(f).unwrap());
        let words: Vec<&str> = HTTP_WORDS
            .into_iter()
            .filter(|w| code.contains(w))
            .collect();
        if !words.is_empty() {
            found.push(format!("{}: {words:?}", f.display()));
        }
    }
    (files.len(), found)
}

#[test]
fn the_core_the_store_and_the_workers_know_no_http() {
    let src = server_src();
    for dir in ["challenge", "store"] {
        let (n, found) = http_words_under(&src.join(dir));
        assert!(n >= 3, "{dir}: {n} files");
        assert!(found.is_empty(), "HTTP in {dir}/:\n{}", found.join("\n"));
    }
    for file in ["worker.rs", "observe.rs"] {
        let code = code_only(&std::fs::read_to_string(src.join(file)).unwrap());
        let words: Vec<&str> = HTTP_WORDS
            .into_iter()
            .filter(|w| code.contains(w))
            .collect();
        assert!(words.is_empty(), "HTTP in {file}: {words:?}");
    }
    // The check sees the handlers' own HTTP.
    let (_, http) = http_words_under(&src.join("http"));
    assert!(http.iter().any(|f| f.contains("axum")), "{http:?}");
}

#[test]
fn architecture_lists_the_server_module_graph_as_it_is() {
    let g = module_graph(&server_src());
    let doc_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../ARCHITECTURE.md");
    let doc = std::fs::read_to_string(&doc_path).unwrap();
    let start = "<!-- server module graph: begin -->\n```\n";
    let end = "```\n<!-- server module graph: end -->";
    let (Some(a), Some(b)) = (doc.find(start), doc.find(end)) else {
        panic!("ARCHITECTURE.md has no block between {start:?} and {end:?}");
    };
    assert_eq!(
        &doc[a + start.len()..b],
        listing(&g),
        "ARCHITECTURE.md's server module graph differs from the code; the graph now is:\n{}",
        listing(&g)
    );
}

#[test]
fn paths_are_read_from_code_not_from_prose() {
    let code = code_only(
        "use crate::{challenge::{Phase, leaderboard}, store::Team, worker};\n\
         // crate::http in a comment\n\
         let s = \"crate::observe in a string\";\n\
         $crate::x::f(); fn f() -> crate::store::Role {}\n",
    );
    let found: Vec<String> = crate_paths(&code).into_iter().collect();
    assert_eq!(found, ["challenge", "store", "worker"]);
}
