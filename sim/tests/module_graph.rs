//! The dependency graph between sim's top-level modules has no cycle, and
//! ARCHITECTURE.md lists it as it is.
//!
//! Every `crate::name` path (including `use crate::{a, b::c}` groups) in a
//! file under `sim/src/<module>` is an edge `<module> -> name`; comments are
//! left out. A cycle makes the test fail with the cycle spelled out.

use std::path::{Path, PathBuf};

#[path = "../../tests/common/module_graph.rs"]
mod graph;
use graph::*;

fn sim_src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

#[test]
fn sim_modules_form_no_cycle() {
    let g = library_module_graph(&sim_src());
    assert!(g.contains_key("plan") && g.contains_key("config"), "{g:?}");
    if let Some(cycle) = find_cycle(&g) {
        panic!(
            "sim's modules depend on each other in a cycle: {}\n\nthe graph:\n{}",
            cycle.join(" -> "),
            listing(&g)
        );
    }
}

#[test]
fn architecture_lists_the_module_graph_as_it_is() {
    let g = library_module_graph(&sim_src());
    let doc_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../ARCHITECTURE.md");
    let doc = std::fs::read_to_string(&doc_path).unwrap();
    let start = "<!-- sim module graph: begin -->\n```\n";
    let end = "```\n<!-- sim module graph: end -->";
    let (Some(a), Some(b)) = (doc.find(start), doc.find(end)) else {
        panic!("ARCHITECTURE.md has no block between {start:?} and {end:?}");
    };
    let written = &doc[a + start.len()..b];
    assert_eq!(
        written,
        listing(&g),
        "ARCHITECTURE.md's sim module graph differs from the code; the graph now is:\n{}",
        listing(&g)
    );
}

/// The model layer: what a run simulates, knowing no file and no config.
const MODELS: [&str; 7] = [
    "psf",
    "population",
    "profile",
    "render",
    "noise",
    "wcs",
    "moments",
];

/// The run layer the models must not reach: the config (its schema), the
/// plan that reads it, file formats and the run's bookkeeping.
const RUN_LAYER: [&str; 7] = [
    "config", "plan", "io", "generate", "products", "memory", "disk",
];

/// "model -> module" for every edge of `g` from one of `models` to one of
/// `forbidden`.
fn edges_between(g: &Graph, models: &[&str], forbidden: &[&str]) -> Vec<String> {
    models
        .iter()
        .flat_map(|m| g.get(*m).into_iter().flatten().map(move |to| (m, to)))
        .filter(|(_, to)| forbidden.contains(&to.as_str()))
        .map(|(m, to)| format!("{m} -> {to}"))
        .collect()
}

#[test]
fn the_models_know_no_config_plan_or_files() {
    let src = sim_src();
    let library = library_module_graph(&src);
    assert!(
        MODELS.iter().all(|m| library.contains_key(*m)),
        "{library:?}"
    );
    let wrong = edges_between(&library, &MODELS, &RUN_LAYER);
    assert!(
        wrong.is_empty(),
        "the models (sim/src/{{{}}}) must take typed specs from the plan, not \
         reach the run layer {RUN_LAYER:?}:\n{}",
        MODELS.join(","),
        wrong.join("\n")
    );
    // Not even a model's tests name the config: only the plan reads it.
    let everything = module_graph(&src);
    let wrong = edges_between(&everything, &MODELS, &["config"]);
    assert!(
        wrong.is_empty(),
        "a model's code or tests use `crate::config`:\n{}",
        wrong.join("\n")
    );
    // The check sees an edge when there is one.
    let mut planted = library.clone();
    planted.get_mut("wcs").unwrap().insert("config".into());
    assert_eq!(
        edges_between(&planted, &MODELS, &RUN_LAYER),
        ["wcs -> config"]
    );
}

#[test]
fn library_code_leaves_out_test_modules_and_test_files() {
    let lib = "use crate::a;\nfn f() {\n    #[cfg(test)]\n    crate::b::g();\n}\n\
               #[cfg(test)]\nmod tests;\n#[cfg(test)]\nmod tests {\n    use crate::c;\n}\n";
    let code = library_code(Path::new("src/x/mod.rs"), lib);
    let found: Vec<String> = crate_paths(code).into_iter().collect();
    assert_eq!(found, ["a", "b"]);
    assert_eq!(library_code(Path::new("src/x/tests.rs"), lib), "");
}

#[test]
fn the_cycle_finder_finds_cycles_and_only_cycles() {
    let graph = |edges: &[(&str, &str)]| -> Graph {
        let mut g = Graph::new();
        for (a, b) in edges {
            g.entry(a.to_string()).or_default().insert(b.to_string());
            g.entry(b.to_string()).or_default();
        }
        g
    };
    let dag = graph(&[("a", "b"), ("b", "c"), ("a", "c"), ("d", "a")]);
    assert_eq!(find_cycle(&dag), None);
    let cyclic = graph(&[("a", "b"), ("b", "c"), ("c", "a"), ("d", "a")]);
    assert_eq!(
        find_cycle(&cyclic).unwrap(),
        ["a", "b", "c", "a"].map(String::from)
    );
    assert!(find_cycle(&graph(&[("x", "x")])).is_some());
}

#[test]
fn paths_are_read_from_code_not_from_prose() {
    let code = code_only(
        "use crate::{config::{A, B}, io::x, plan};\n\
         // crate::generate in a comment\n\
         let s = \"crate::render in a string\";\n\
         let c = '\"'; crate::wcs::TanWcs::new();\n\
         $crate::noise::f(); fn f() -> crate::seed::SeedKey {}\n",
    );
    let found: Vec<String> = crate_paths(&code).into_iter().collect();
    assert_eq!(found, ["config", "io", "plan", "seed", "wcs"]);
}

/// The modules of sim that may touch files: the edges of ARCHITECTURE.md's
/// invariant ("sim does no file I/O in its numerical core").
const FILE_EDGES: [&str; 5] = ["io", "generate", "config", "products", "disk"];

/// What in code reads or writes files (or the file system's tree).
const FILE_IO: [&str; 6] = [
    "std::fs",
    "fs::",
    "File::",
    "fitsio",
    "OpenOptions",
    "read_dir",
];

/// The file-I/O words in the non-test code of `source` (everything from the
/// first `#[cfg(test)]` on is test code, as is a file named `tests.rs`).
fn file_io_in(source: &str) -> Vec<&'static str> {
    let code = code_only(source);
    let code = code.split("#[cfg(test)]").next().unwrap_or("");
    FILE_IO.into_iter().filter(|w| code.contains(w)).collect()
}

/// "file: words" for each file of sim's sources outside `edges` whose
/// non-test code touches files.
fn file_io_outside(edges: &[&str]) -> (usize, Vec<String>) {
    let src = sim_src();
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut offenders = Vec::new();
    let mut checked = 0;
    for f in &files {
        let rel = f.strip_prefix(&src).unwrap();
        let top = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        let top = top.trim_end_matches(".rs");
        if edges.contains(&top) || f.file_name().is_some_and(|n| n == "tests.rs") {
            continue;
        }
        checked += 1;
        let found = file_io_in(&std::fs::read_to_string(f).unwrap());
        if !found.is_empty() {
            offenders.push(format!("{} uses {found:?}", rel.display()));
        }
    }
    (checked, offenders)
}

#[test]
fn only_the_edge_modules_touch_files() {
    let (checked, offenders) = file_io_outside(&FILE_EDGES);
    assert!(checked > 20, "{checked} files checked");
    assert!(
        offenders.is_empty(),
        "file I/O outside sim's edge modules {FILE_EDGES:?}:\n{}",
        offenders.join("\n")
    );
    // The check sees the edges' own I/O when they are not excused.
    let (_, io) = file_io_outside(&["generate", "config", "products", "disk"]);
    assert!(io.iter().any(|o| o.starts_with("io")), "{io:?}");
}

#[test]
fn the_file_io_check_sees_code_and_not_prose_or_tests() {
    assert_eq!(
        file_io_in("fn f() { let t = std::fs::read(p); }"),
        ["std::fs", "fs::"]
    );
    assert_eq!(
        file_io_in("fn f() { fitsio::FitsFile::open(p); }"),
        ["File::", "fitsio"]
    );
    assert!(file_io_in("//! reads no file: std::fs is for io/\nfn f() {}").is_empty());
    assert!(file_io_in("fn f() { let s = \"std::fs\"; }").is_empty());
    assert!(
        file_io_in("fn f() {}\n#[cfg(test)]\nmod tests { fn g() { std::fs::write(p, b); } }")
            .is_empty()
    );
}
