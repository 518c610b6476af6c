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

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

type Graph = BTreeMap<String, BTreeSet<String>>;

/// The text of `source` without `//` comments (doc comments included) and
/// without string literals' contents, so that prose never makes an edge.
fn code_only(source: &str) -> String {
    let mut out = String::with_capacity(source.len());
    let mut chars = source.chars().peekable();
    let mut in_string = false;
    while let Some(c) = chars.next() {
        if in_string {
            match c {
                '\\' => {
                    chars.next();
                }
                '"' => {
                    in_string = false;
                    out.push('"');
                }
                '\n' => out.push('\n'),
                _ => {}
            }
            continue;
        }
        match c {
            '/' if chars.peek() == Some(&'/') => {
                for d in chars.by_ref() {
                    if d == '\n' {
                        out.push('\n');
                        break;
                    }
                }
            }
            '"' => {
                in_string = true;
                out.push('"');
            }
            // A char literal '"' must not open a string.
            '\'' => {
                out.push('\'');
                let rest: String = chars.clone().take(3).collect();
                if rest.starts_with("\"'") {
                    chars.next();
                    chars.next();
                    out.push('\'');
                }
            }
            _ => out.push(c),
        }
    }
    out
}

/// The top-level names a piece of code reaches through `crate::`.
fn crate_paths(code: &str) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    let mut rest = code;
    while let Some(i) = rest.find("crate::") {
        let before = rest[..i].chars().next_back();
        rest = &rest[i + "crate::".len()..];
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == '$') {
            continue; // e.g. `$crate::` or `mycrate::`
        }
        if let Some(group) = rest.strip_prefix('{') {
            // `crate::{a, b::{c, d}, e}`: the names at depth one.
            let mut depth = 1;
            let mut name = String::new();
            let mut at_start = true;
            for c in group.chars() {
                match c {
                    '{' => depth += 1,
                    '}' => {
                        depth -= 1;
                        if depth == 0 {
                            break;
                        }
                    }
                    ',' if depth == 1 => at_start = true,
                    c if depth == 1 && at_start && (c.is_alphanumeric() || c == '_') => {
                        name.push(c)
                    }
                    _ if depth == 1 && at_start && !name.is_empty() => {
                        found.insert(std::mem::take(&mut name));
                        at_start = false;
                    }
                    _ => {}
                }
            }
            if !name.is_empty() {
                found.insert(name);
            }
        } else {
            let name: String = rest
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            if !name.is_empty() {
                found.insert(name);
            }
        }
    }
    found
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The module graph of the crate whose sources are in `src`.
fn module_graph(src: &Path) -> Graph {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let top_of = |p: &Path| -> String {
        let rel = p.strip_prefix(src).unwrap();
        let first = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        first.trim_end_matches(".rs").to_string()
    };
    let modules: BTreeSet<String> = files
        .iter()
        .map(|p| top_of(p.as_path()))
        .filter(|m| m != "lib")
        .collect();
    let mut g: Graph = modules
        .iter()
        .map(|m| (m.clone(), BTreeSet::new()))
        .collect();
    for f in &files {
        let from = top_of(f);
        if from == "lib" {
            continue;
        }
        let code = code_only(&std::fs::read_to_string(f).unwrap());
        for to in crate_paths(&code) {
            if to != from && modules.contains(&to) {
                g.get_mut(&from).unwrap().insert(to);
            }
        }
    }
    g
}

/// A cycle of `g` (first node repeated at the end), if there is one.
fn find_cycle(g: &Graph) -> Option<Vec<String>> {
    #[derive(Clone, Copy, PartialEq)]
    enum Mark {
        New,
        Open,
        Done,
    }
    fn visit(
        n: &str,
        g: &Graph,
        marks: &mut BTreeMap<String, Mark>,
        stack: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        marks.insert(n.into(), Mark::Open);
        stack.push(n.into());
        for m in g.get(n).into_iter().flatten() {
            match marks.get(m.as_str()).copied().unwrap_or(Mark::New) {
                Mark::Open => {
                    let start = stack.iter().position(|s| s == m).unwrap();
                    let mut cycle = stack[start..].to_vec();
                    cycle.push(m.clone());
                    return Some(cycle);
                }
                Mark::New => {
                    if let Some(c) = visit(m, g, marks, stack) {
                        return Some(c);
                    }
                }
                Mark::Done => {}
            }
        }
        stack.pop();
        marks.insert(n.into(), Mark::Done);
        None
    }
    let mut marks = BTreeMap::new();
    for n in g.keys() {
        if marks.get(n.as_str()).copied().unwrap_or(Mark::New) == Mark::New {
            if let Some(c) = visit(n, g, &mut marks, &mut Vec::new()) {
                return Some(c);
            }
        }
    }
    None
}

/// The graph as ARCHITECTURE.md lists it: one `module -> a, b, c` line per
/// module that uses another.
fn listing(g: &Graph) -> String {
    g.iter()
        .filter(|(_, to)| !to.is_empty())
        .map(|(from, to)| {
            format!(
                "{from} -> {}\n",
                to.iter().cloned().collect::<Vec<_>>().join(", ")
            )
        })
        .collect()
}

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

/// The edges of `g` that [`ALLOWED`] does not allow, as `from -> to`
/// (a module it does not name at all is an offence too).
fn offences(g: &Graph) -> Vec<String> {
    let allowed: BTreeMap<&str, &[&str]> = ALLOWED.into_iter().collect();
    let mut out = Vec::new();
    for (from, to) in g {
        let Some(ok) = allowed.get(from.as_str()) else {
            out.push(format!("{from}: a module the layers do not name"));
            continue;
        };
        for t in to {
            if !ok.contains(&t.as_str()) {
                out.push(format!("{from} -> {t}"));
            }
        }
    }
    out
}

#[test]
fn server_modules_stand_in_layers() {
    let g = module_graph(&server_src());
    let names: Vec<&str> = g.keys().map(String::as_str).collect();
    assert_eq!(names, ["challenge", "http", "observe", "store", "worker"]);
    let bad = offences(&g);
    assert!(
        bad.is_empty(),
        "edges against the layers:\n{}\n\nthe graph:\n{}",
        bad.join("\n"),
        listing(&g)
    );
    if let Some(cycle) = find_cycle(&g) {
        panic!(
            "the server's modules depend on each other in a cycle: {}",
            cycle.join(" -> ")
        );
    }
}

#[test]
fn the_layer_check_sees_an_edge_upwards() {
    let mut g = module_graph(&server_src());
    g.get_mut("challenge").unwrap().insert("http".into());
    g.get_mut("store").unwrap().insert("challenge".into());
    assert_eq!(offences(&g), ["challenge -> http", "store -> challenge"]);
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
