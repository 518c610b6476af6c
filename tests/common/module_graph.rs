//! Reading a crate's module graph from its sources, shared by the
//! module-graph tests of sim (`sim/tests/module_graph.rs`), the harness
//! (`harness/tests/module_graph.rs`) and the server
//! (`server/tests/module_graph.rs`), which include this file by path.
//!
//! Every `crate::name` path (including `use crate::{a, b::c}` groups) in a
//! file under `src/<module>` is an edge `<module> -> name`; comments and
//! string literals are left out, so that prose never makes an edge.

#![allow(dead_code)]

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

pub type Graph = BTreeMap<String, BTreeSet<String>>;

/// The text of `source` without `//` comments (doc comments included) and
/// without string literals' contents, so that prose never makes an edge.
pub fn code_only(source: &str) -> String {
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
pub fn crate_paths(code: &str) -> BTreeSet<String> {
    crate_paths_to(code, 1)
}

/// The paths a piece of code reaches through `crate::`, each cut to its
/// first `depth` segments and joined by `::` (`crate::model::{psf::Psf,
/// wcs}` gives `model::psf` and `model::wcs` at depth 2).
pub fn crate_paths_to(code: &str, depth: usize) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    let mut rest = code;
    while let Some(i) = rest.find("crate::") {
        let before = rest[..i].chars().next_back();
        rest = &rest[i + "crate::".len()..];
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == '$') {
            continue;
        }
        use_tree(rest, &mut Vec::new(), depth, &mut found);
    }
    found
}

/// Reads the use tree at the start of `text` (after a `::`), adding to
/// `out` every path it names, cut to `depth` segments, below `prefix`;
/// returns the length of text read.
fn use_tree(
    text: &str,
    prefix: &mut Vec<String>,
    depth: usize,
    out: &mut BTreeSet<String>,
) -> usize {
    let ident_len = |t: &str| {
        t.find(|c: char| !(c.is_alphanumeric() || c == '_'))
            .unwrap_or(t.len())
    };
    let mut at = 0;
    let pushed = prefix.len();
    let mut grouped = false;
    loop {
        let t = &text[at..];
        if let Some(group) = t.strip_prefix('{') {
            // `{a, b::c, ...}`: each member is a tree below the prefix.
            let mut used = 1;
            let mut g = group;
            loop {
                let skip = g.len() - g.trim_start().len();
                used += skip;
                g = &g[skip..];
                if g.starts_with('}') {
                    used += 1;
                    break;
                }
                if let Some(r) = g.strip_prefix(',') {
                    used += 1;
                    g = r;
                    continue;
                }
                let n = use_tree(g, prefix, depth, out);
                if n == 0 {
                    break; // not a use tree: stop reading
                }
                used += n;
                g = &g[n..];
            }
            at += used;
            grouped = true;
            break;
        }
        let n = ident_len(t);
        if n == 0 {
            break;
        }
        prefix.push(t[..n].to_string());
        at += n;
        if text[at..].starts_with("::") {
            at += 2;
            continue;
        }
        break;
    }
    let names: Vec<&String> = prefix
        .iter()
        .take(depth)
        .filter(|s| s.as_str() != "self" && s.as_str() != "super")
        .collect();
    if !grouped && !names.is_empty() && prefix.len() > pushed {
        out.insert(
            names
                .iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join("::"),
        );
    }
    prefix.truncate(pushed);
    at
}

pub fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
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
pub fn module_graph(src: &Path) -> Graph {
    graph_of(src, false)
}

/// The non-test code of `source`: empty for a file named `tests.rs`, else
/// everything before the file's inline test module (`#[cfg(test)]` followed
/// by `mod name {`; unit tests sit at a file's end).
pub fn library_code<'a>(path: &Path, source: &'a str) -> &'a str {
    if path.file_name().is_some_and(|n| n == "tests.rs") {
        return "";
    }
    let mut from = 0;
    while let Some(i) = source[from..].find("#[cfg(test)]") {
        let at = from + i;
        let rest = source[at + "#[cfg(test)]".len()..].trim_start();
        let line = rest.lines().next().unwrap_or("");
        if line.starts_with("mod ") && line.contains('{') {
            return &source[..at];
        }
        from = at + 1;
    }
    source
}

/// [`module_graph`] of the library code alone ([`library_code`]): the edges
/// a test makes (a model's test building its inputs from a plan) left out.
pub fn library_module_graph(src: &Path) -> Graph {
    graph_of(src, true)
}

fn graph_of(src: &Path, library_only: bool) -> Graph {
    layered_module_graph(src, &[], library_only)
}

/// A cycle of `g` (first node repeated at the end), if there is one.
pub fn find_cycle(g: &Graph) -> Option<Vec<String>> {
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
pub fn listing(g: &Graph) -> String {
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

/// The edges of `g` that `allowed` (each module with the modules it may
/// use) does not allow, as `from -> to`; a module `allowed` does not name
/// at all is an offence too.
pub fn offences(g: &Graph, allowed: &[(&str, &[&str])]) -> Vec<String> {
    let allowed: BTreeMap<&str, &[&str]> = allowed.iter().copied().collect();
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

/// Asserts that `g` has exactly the modules `names`, that every edge is
/// one `allowed` allows, and that there is no cycle; `who` names the crate
/// in the messages.
pub fn assert_layered(g: &Graph, names: &[&str], allowed: &[(&str, &[&str])], who: &str) {
    let have: Vec<&str> = g.keys().map(String::as_str).collect();
    assert_eq!(have, names, "{who}'s top-level modules");
    let bad = offences(g, allowed);
    assert!(
        bad.is_empty(),
        "edges against the layers:\n{}\n\nthe graph:\n{}",
        bad.join("\n"),
        listing(g)
    );
    if let Some(cycle) = find_cycle(g) {
        panic!(
            "{who}'s modules depend on each other in a cycle: {}",
            cycle.join(" -> ")
        );
    }
}

/// The module graph of the crate whose sources are in `src`, with the
/// modules of each folder named in `layers` as nodes of their own
/// (`model::psf` for `src/model/psf/`, `src/model/psf.rs`); a layer's own
/// `mod.rs` is the node `model`. With `library_only`, test code is left out
/// ([`library_code`]).
pub fn layered_module_graph(src: &Path, layers: &[&str], library_only: bool) -> Graph {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let node_of = |p: &Path| -> String { layered_node(p.strip_prefix(src).unwrap(), layers) };
    let modules: BTreeSet<String> = files
        .iter()
        .map(|p| node_of(p))
        .filter(|m| m != "lib")
        .collect();
    let mut g: Graph = modules
        .iter()
        .map(|m| (m.clone(), BTreeSet::new()))
        .collect();
    for f in &files {
        let from = node_of(f);
        if from == "lib" {
            continue;
        }
        let text = std::fs::read_to_string(f).unwrap();
        let code = code_only(&text);
        let code = if library_only {
            library_code(f, &code)
        } else {
            &code
        };
        for path in crate_paths_to(code, 2) {
            let mut parts = path.split("::");
            let first = parts.next().unwrap_or("");
            let to = match parts.next() {
                Some(second) if layers.contains(&first) => format!("{first}::{second}"),
                _ => first.to_string(),
            };
            if to != from && modules.contains(&to) {
                g.get_mut(&from).unwrap().insert(to);
            }
        }
    }
    g
}

/// The node of the file at `rel` (relative to `src/`) in a
/// [`layered_module_graph`]: `model::psf` for `model/psf/mod.rs` or
/// `model/psf.rs`, `model` for `model/mod.rs`, `io` for `io/skymaker.rs`.
pub fn layered_node(rel: &Path, layers: &[&str]) -> String {
    let parts: Vec<String> = rel
        .components()
        .map(|c| {
            c.as_os_str()
                .to_string_lossy()
                .trim_end_matches(".rs")
                .to_string()
        })
        .collect();
    match &parts[..] {
        [first, second, ..] if layers.contains(&first.as_str()) && second != "mod" => {
            format!("{first}::{second}")
        }
        [first, ..] => first.clone(),
        [] => String::new(),
    }
}

/// `g` with each node replaced by its layer (the part before `::`), the
/// edges inside a layer left out.
pub fn layers_of(g: &Graph) -> Graph {
    let layer = |n: &str| n.split("::").next().unwrap_or(n).to_string();
    let mut out = Graph::new();
    for (from, to) in g {
        let f = layer(from);
        let entry = out.entry(f.clone()).or_default();
        for t in to {
            let t = layer(t);
            if t != f {
                entry.insert(t);
            }
        }
    }
    out
}
