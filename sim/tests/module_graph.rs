//! sim's modules stand in three layers, their dependency graph has no
//! cycle, and ARCHITECTURE.md lists it as it is.
//!
//! The layers are folders of `sim/src`: `model/` (what a run simulates),
//! `io/` (the simulator's file formats) and `run/` (config, plan and the
//! run). The models use neither `run` nor `io`; `io` uses the models, not
//! `run`. Every `crate::a::b` path (including `use crate::{a, b::c}` groups)
//! in a file is an edge from the file's module to `a::b` when `a` is a layer
//! folder (`model::psf`), else to `a` (`io`); comments are left out. A cycle
//! makes the test fail with the cycle spelled out.

use std::path::{Path, PathBuf};

#[path = "../../tests/common/module_graph.rs"]
mod graph;
use graph::*;

fn sim_src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// The folders of `sim/src` whose modules are nodes of their own.
const LAYERS: [&str; 2] = ["model", "run"];

/// The graph of sim's modules (library code only, or with the tests).
fn sim_graph(library_only: bool) -> Graph {
    layered_module_graph(&sim_src(), &LAYERS, library_only)
}

/// Which layer may use which: the models nothing, io the models, the run
/// both.
const LAYER_RULES: [(&str, &[&str]); 3] = [
    ("io", &["model"]),
    ("model", &[]),
    ("run", &["io", "model"]),
];

#[test]
fn sim_modules_form_no_cycle() {
    let g = sim_graph(true);
    assert!(
        g.contains_key("run::plan") && g.contains_key("run::config"),
        "{g:?}"
    );
    if let Some(cycle) = find_cycle(&g) {
        panic!(
            "sim's modules depend on each other in a cycle: {}\n\nthe graph:\n{}",
            cycle.join(" -> "),
            listing(&g)
        );
    }
}

#[test]
fn the_layers_depend_downward_only() {
    let g = sim_graph(true);
    assert_layered(&layers_of(&g), &["io", "model", "run"], &LAYER_RULES, "sim");
}

#[test]
fn the_layer_rules_see_a_planted_edge() {
    let g = sim_graph(true);
    let plant = |from: &str, to: &str| {
        let mut planted = g.clone();
        planted.get_mut(from).unwrap().insert(to.into());
        offences(&layers_of(&planted), &LAYER_RULES)
    };
    assert!(offences(&layers_of(&g), &LAYER_RULES).is_empty());
    assert_eq!(plant("model::wcs", "run::config"), ["model -> run"]);
    assert_eq!(plant("model::psf", "io"), ["model -> io"]);
    assert_eq!(plant("io", "run::plan"), ["io -> run"]);
    assert!(plant("run::plan", "io").is_empty());
}

#[test]
fn the_graph_reads_layered_paths_and_groups() {
    let code = "use crate::model::{psf::Psf, wcs};\nuse crate::{io, run::plan::Plan};\n\
                fn f() { crate::model::render::draw(); crate::run::{self}; }\n";
    let found: Vec<String> = crate_paths_to(&code_only(code), 2).into_iter().collect();
    assert_eq!(
        found,
        [
            "io",
            "model::psf",
            "model::render",
            "model::wcs",
            "run",
            "run::plan"
        ]
    );
    let node = |p: &str| layered_node(Path::new(p), &LAYERS);
    assert_eq!(node("model/psf/zernike.rs"), "model::psf");
    assert_eq!(node("model/wcs.rs"), "model::wcs");
    assert_eq!(node("model/mod.rs"), "model");
    assert_eq!(node("io/skymaker.rs"), "io");
    assert_eq!(node("lib.rs"), "lib");
}

#[test]
fn architecture_lists_the_module_graph_as_it_is() {
    let g = sim_graph(true);
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
    "model::psf",
    "model::population",
    "model::profile",
    "model::render",
    "model::noise",
    "model::wcs",
    "model::moments",
];

/// "model -> module" for every edge of `g` from one of `models` to a module
/// of a layer in `forbidden` (`run` is every `run::…`).
fn edges_between(g: &Graph, models: &[&str], forbidden: &[&str]) -> Vec<String> {
    let hits = |to: &str| {
        forbidden
            .iter()
            .any(|f| to == *f || to.starts_with(&format!("{f}::")))
    };
    models
        .iter()
        .flat_map(|m| g.get(*m).into_iter().flatten().map(move |to| (m, to)))
        .filter(|(_, to)| hits(to))
        .map(|(m, to)| format!("{m} -> {to}"))
        .collect()
}

#[test]
fn the_models_know_no_config_plan_or_files() {
    let library = sim_graph(true);
    assert!(
        MODELS.iter().all(|m| library.contains_key(*m)),
        "{library:?}"
    );
    let models: Vec<&str> = library
        .keys()
        .map(String::as_str)
        .filter(|m| m.starts_with("model::"))
        .collect();
    assert_eq!(models.len(), MODELS.len(), "{models:?}");
    let wrong = edges_between(&library, &models, &["run", "io"]);
    assert!(
        wrong.is_empty(),
        "the models (sim/src/model/) must take typed specs from the plan, not \
         reach the run layer or the files (sim/src/run/, sim/src/io/):\n{}",
        wrong.join("\n")
    );
    // Not even a model's tests name the config: only the plan reads it.
    let everything = sim_graph(false);
    let wrong = edges_between(&everything, &models, &["run::config"]);
    assert!(
        wrong.is_empty(),
        "a model's code or tests use `crate::run::config`:\n{}",
        wrong.join("\n")
    );
    // The check sees an edge when there is one.
    let mut planted = library.clone();
    planted
        .get_mut("model::wcs")
        .unwrap()
        .insert("run::config".into());
    planted.get_mut("model::psf").unwrap().insert("io".into());
    assert_eq!(
        edges_between(&planted, &models, &["run", "io"]),
        ["model::psf -> io", "model::wcs -> run::config"]
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
    let deep: Vec<String> = crate_paths_to(&code, 2).into_iter().collect();
    assert_eq!(
        deep,
        [
            "config::A",
            "config::B",
            "io::x",
            "plan",
            "seed::SeedKey",
            "wcs::TanWcs"
        ]
    );
}

/// The modules of sim that may touch files: the edges of ARCHITECTURE.md's
/// invariant ("sim does no file I/O in its numerical core").
const FILE_EDGES: [&str; 5] = [
    "io",
    "run::generate",
    "run::config",
    "run::products",
    "run::disk",
];

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
        let node = layered_node(rel, &LAYERS);
        if edges.contains(&node.as_str()) || f.file_name().is_some_and(|n| n == "tests.rs") {
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
    let (_, io) = file_io_outside(&["run::generate", "run::config", "run::products", "run::disk"]);
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
