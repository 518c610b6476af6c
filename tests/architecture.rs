//! ARCHITECTURE.md matches the tree: every path its code map names exists;
//! and the paths of a run have one home, `contract/src/run_dir.rs`.
//!
//! The code map is the first fenced block after `## Code map`. A line that
//! starts at column 0 names a path from the repository's root (`src/main.rs`,
//! `contract/`); a directory so named is the prefix of the lines indented by
//! two spaces below it (`  src/truth.rs` under `contract/` is
//! `contract/src/truth.rs`). On such a line the first word is a path, and
//! further words ending in `,` or followed by `,` (`src/metrics.rs, fit.rs,
//! bootstrap.rs`) are its siblings. Deeper-indented lines are prose.

use std::path::Path;

use crate::common::module_graph::{library_code, rust_files};

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

/// The library sources whose non-test code may not spell a run's paths:
/// every `.rs` file under the crates' `src/` and the binary's `src/`, but
/// `contract/src/run_dir.rs` (their one home) and test code (from the first
/// `#[cfg(test)]` of a file on, and files named `tests.rs`).
const LIBRARY_SOURCES: &[&str] = &[
    "contract/src",
    "numerics/src",
    "figure/src",
    "sim/src",
    "harness/src",
    "ksb/src",
    "server/src",
    "src",
];

/// The file that owns every path of a run (SPEC §5).
const RUN_PATHS_HOME: &str = "contract/src/run_dir.rs";

/// Literals naming what is not a run's but looks like it: (file, the line's
/// text it holds, why).
const NOT_A_RUN: &[(&str, &str, &str)] = &[
    (
        "sim/src/run/products.rs",
        r#"out.join("config.json")"#,
        "the output directory of `stepsim psf` and `stepsim catalog`",
    ),
    (
        "src/cmd/catalog.rs",
        r#"args.out.join("config.json")"#,
        "the output directory of `stepsim catalog`",
    ),
    (
        "sim/src/io/psf_store.rs",
        r#"c.join("stepsim").join("psf")"#,
        "the user's PSF store under ~/.cache, not a run's",
    ),
];

/// The names of a run's files and directories (SPEC §5, docs/run-layout.md).
const RUN_NAMES: &[&str] = &[
    "public",
    "private",
    "manifest.json",
    "README.md",
    "config.json",
    "datasets.json",
    "blinding.key",
    "inputs",
    "truth",
    "model",
    "done",
    "shards",
    "psf",
    "cache",
];

/// The lines of `code` (one file's text) that spell a path of a run by hand:
/// a `join` of a literal starting with one of [`RUN_NAMES`], or a literal
/// starting with `public/` or `private/`, or naming `manifest.json`,
/// `datasets.json` or `blinding.key` whole. Comments and test code are
/// skipped. Returns (line number, line).
fn hand_made_run_paths(code: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    for (i, line) in code.lines().enumerate() {
        if line.contains("#[cfg(test)]") {
            break;
        }
        let text = line.trim_start();
        if text.starts_with("//") {
            continue;
        }
        let joined = RUN_NAMES.iter().any(|name| {
            text.contains(&format!("join(\"{name}\"")) || text.contains(&format!("join(\"{name}/"))
        });
        let literal = ["\"public/", "\"private/"]
            .iter()
            .chain(&["\"manifest.json\"", "\"datasets.json\"", "\"blinding.key\""])
            .any(|l| text.contains(l));
        if joined || literal {
            out.push((i + 1, line.to_owned()));
        }
    }
    out
}

#[test]
fn the_run_path_reader_finds_hand_made_paths_outside_comments_and_tests() {
    let code = r#"//! Writes `public/manifest.json`.
fn f(run: &Path) {
    let m = run.join("public").join("manifest.json");
    let c = run.join("private/config.json");
    let t = format!("private/truth/{id}.fits");
    let d = std::fs::read("datasets.json");
    let fine = run.join("other.json"); // not public/...
    let readme = dir.join(README);
}
#[cfg(test)]
mod tests { fn g() { std::fs::read(dir.join("public/manifest.json")); } }
"#;
    let lines: Vec<usize> = hand_made_run_paths(code).iter().map(|l| l.0).collect();
    assert_eq!(lines, [3, 4, 5, 6]);
}

#[test]
fn only_the_contract_spells_the_paths_of_a_run() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for dir in LIBRARY_SOURCES {
        rust_files(&root.join(dir), &mut files);
    }
    files.sort();
    assert!(files.len() > 100, "only {} files read", files.len());
    let mut found = Vec::new();
    for file in &files {
        let rel = file
            .strip_prefix(root)
            .unwrap()
            .to_string_lossy()
            .into_owned();
        if rel == RUN_PATHS_HOME || file.file_name().is_some_and(|n| n == "tests.rs") {
            continue;
        }
        let code = std::fs::read_to_string(file).unwrap();
        for (n, line) in hand_made_run_paths(&code) {
            let allowed = NOT_A_RUN
                .iter()
                .any(|(f, text, _)| rel == *f && line.contains(text));
            if !allowed {
                found.push(format!("{rel}:{n}: {}", line.trim()));
            }
        }
    }
    assert!(
        found.is_empty(),
        "paths of a run spelled outside {RUN_PATHS_HOME} (use stepsim_contract::run_dir::RunDir, \
         PublicDir or PrivateDir):\n{}",
        found.join("\n")
    );
}

/// `read(code)`'s findings in each of `files`, as `path:line: text` with
/// the path relative to `root`.
fn findings(
    root: &Path,
    files: &[std::path::PathBuf],
    read: impl Fn(&str) -> Vec<(usize, String)>,
) -> Vec<String> {
    let mut found = Vec::new();
    for file in files {
        let code = std::fs::read_to_string(file).unwrap();
        let rel = file.strip_prefix(root).unwrap().display().to_string();
        for (n, text) in read(&code) {
            found.push(format!("{rel}:{n}: {text}"));
        }
    }
    found
}

/// Names of FFT planners that choose their code by CPU (rustfft's AVX and
/// SSE code round differently from its scalar code).
const PLANNERS_BY_CPU: &[&str] = &[
    "FftPlanner::",
    "FftPlanner<",
    "RealFftPlanner",
    "FftPlannerAvx",
    "FftPlannerSse",
];

/// Lines of `code` (up to its first `#[cfg(test)]`, comments left out)
/// that name a planner of [`PLANNERS_BY_CPU`]: (line number, line).
fn planners_by_cpu(code: &str) -> Vec<(usize, String)> {
    let library = code.split("#[cfg(test)]").next().unwrap_or("");
    library
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim_start().starts_with("//"))
        .filter(|(_, l)| PLANNERS_BY_CPU.iter().any(|p| l.contains(p)))
        .map(|(i, l)| (i + 1, l.trim().to_string()))
        .collect()
}

#[test]
fn the_planner_reader_finds_planners_by_cpu_only() {
    let code = "use rustfft::{FftPlanner, FftPlannerScalar};\nlet p = FftPlannerScalar::new();\n\
                let q = FftPlanner::new();\n// FftPlanner::new() in a comment\n\
                let r = RealFftPlanner::<f32>::new();\n#[cfg(test)]\nmod t { fn f() { FftPlanner::<f64>::new(); } }\n";
    let lines: Vec<usize> = planners_by_cpu(code).iter().map(|l| l.0).collect();
    assert_eq!(lines, [3, 5]);
}

#[test]
fn the_simulator_plans_no_fft_by_cpu() {
    // Issue #25's rule: the same config and seed give the same bytes with
    // and without vector instructions. `STEPSIM_SIMD=0` cannot switch
    // rustfft's planner by CPU, so the golden test comparing the two
    // builds would not see one: this test does (docs/config.md, "Vector
    // instructions").
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    rust_files(&root.join("sim/src"), &mut files);
    rust_files(&root.join("numerics/src"), &mut files);
    files.sort();
    assert!(files.len() > 40, "only {} files read", files.len());
    let found = findings(root, &files, planners_by_cpu);
    assert!(
        found.is_empty(),
        "the simulator plans FFTs by CPU (use stepsim_numerics::fft, or rustfft's FftPlannerScalar):\n{}",
        found.join("\n")
    );
}

/// Suffixes the slow twins had before they took one name, `f_slow`
/// (ARCHITECTURE.md, "Every fast routine has a slow twin").
const OLD_TWIN_SUFFIXES: &[&str] = &[
    "_reference",
    "_direct",
    "_brute",
    "_brute_force",
    "_plainly",
    "_whole",
    "_naive",
    "_by_counting",
    "_by_scan",
    "_by_series",
    "_by_integration",
    "_by_bisection",
    "_by_trapezoids",
    "_by_cramer",
    "_by_column",
    "_by_matching",
];

/// Functions of `code` (up to its first `#[cfg(test)]`: test names may
/// say what they compare) whose name ends in one of
/// [`OLD_TWIN_SUFFIXES`]: (line number, name).
fn twins_named_otherwise(code: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let library = code.split("#[cfg(test)]").next().unwrap_or("");
    for (i, line) in library.lines().enumerate() {
        let Some(at) = line.find("fn ") else { continue };
        if line.trim_start().starts_with("//") {
            continue;
        }
        let name: String = line[at + 3..]
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        if OLD_TWIN_SUFFIXES.iter().any(|s| name.ends_with(s)) {
            out.push((i + 1, name));
        }
    }
    out
}

#[test]
fn the_twin_reader_finds_old_suffixes_only_in_function_names() {
    let code = "pub fn convolve_direct(a: f64) {}\n// fn smooth_reference()\n\
                fn convolve_slow() { let x_reference = 1; }\n    pub(crate) fn fill_by_column<T>() {}\n\
                #[cfg(test)]\nmod tests { fn matches_the_reference() {} }\n";
    let names: Vec<String> = twins_named_otherwise(code)
        .into_iter()
        .map(|(_, n)| n)
        .collect();
    assert_eq!(names, ["convolve_direct", "fill_by_column"]);
}

#[test]
fn slow_twins_have_one_name() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for dir in LIBRARY_SOURCES {
        rust_files(&root.join(dir), &mut files);
    }
    files.sort();
    files.retain(|f| f.file_name().is_none_or(|n| n != "tests.rs"));
    let found = findings(root, &files, |code| {
        twins_named_otherwise(code)
            .into_iter()
            .map(|(n, name)| (n, format!("fn {name}")))
            .collect()
    });
    assert!(
        found.is_empty(),
        "a slow twin is named `<fast>_slow` (ARCHITECTURE.md); these functions end as the old \
         names did:\n{}",
        found.join("\n")
    );
}

/// The libraries whose surface is curated (ARCHITECTURE.md, "Public
/// surfaces"): their modules are private and lib.rs re-exports what users
/// call, each item under one name, but for the modules of
/// [`PUBLIC_MODULES`].
const CURATED_LIBRARIES: &[&str] = &[
    "contract", "numerics", "figure", "sim", "harness", "ksb", "server", "testkit",
];

/// The public modules a curated library's lib.rs may declare: (crate,
/// module, why the module is the name its users call by).
const PUBLIC_MODULES: &[(&str, &str, &str)] = &[
    ("contract", "digest", "SHA-256 as hex: `digest::sha256_hex`"),
    (
        "contract",
        "io",
        "the run's files: `io::write_atomically`, `io::truth`, `io::fits`",
    ),
    ("contract", "run_dir", "the paths of a run (SPEC §5)"),
    ("contract", "run_layout", "manifest.json and datasets.json"),
    ("contract", "seed", "the keyed random streams"),
    ("contract", "shear", "the conventions of SPEC §1"),
    ("contract", "truth", "the truth table's row and columns"),
    ("figure", "chart", "line and scatter charts: `chart::Chart`"),
    ("figure", "picture", "image panels: `picture::Picture`"),
    (
        "figure",
        "png",
        "PNG bytes: `png::svg_to_png`, `png::decode`",
    ),
    ("sim", "io", "the simulator's file formats (a layer)"),
    (
        "sim",
        "model",
        "the models, knowing no files or config (a layer)",
    ),
    ("sim", "run", "plan, generate and the estimates (a layer)"),
    ("numerics", "fft", "`fft::BatchFft`"),
    ("numerics", "fft_size", "`fft_size::fft_friendly`"),
    ("numerics", "fit", "`fit::fit_clipped`"),
    ("numerics", "linalg", "`linalg::solve_spd`"),
    ("numerics", "quad", "`quad::simpson`"),
    ("numerics", "robust", "`robust::mad_sigma`"),
    ("numerics", "roots", "`roots::Bisection`"),
    ("numerics", "simd", "`simd::has_avx2`"),
    ("numerics", "stats", "`stats::median`, `stats::normal_cdf`"),
    ("numerics", "student_t", "`student_t::t_quantile`"),
    (
        "testkit",
        "scene",
        "ksb's synthetic scenes (also compiled into ksb's tests)",
    ),
    (
        "testkit",
        "synthetic",
        "the harness's synthetic runs (also compiled into its tests)",
    ),
];

/// What breaks the curated surface in `lib` (a lib.rs's text) of crate
/// `krate`: a `pub mod` not on [`PUBLIC_MODULES`], and a `pub use` of
/// another crate's item (a second name for it; users name the other crate).
/// Comments and test code are skipped. Returns (line number, line).
fn surface_breaches(krate: &str, lib: &str) -> Vec<(usize, String)> {
    let code = lib.split("#[cfg(test)]\nmod tests").next().unwrap_or("");
    let own_modules: Vec<&str> = code
        .lines()
        .filter_map(|l| {
            let l = l.trim_start();
            let rest = l
                .strip_prefix("pub mod ")
                .or_else(|| l.strip_prefix("mod "))
                .or_else(|| l.strip_prefix("pub(crate) mod "))?;
            Some(rest.trim_end_matches([';', '{', ' ']))
        })
        .collect();
    let mut out = Vec::new();
    for (i, line) in code.lines().enumerate() {
        let l = line.trim_start();
        if let Some(name) = l.strip_prefix("pub mod ") {
            let name = name.trim_end_matches([';', '{', ' ']);
            if !PUBLIC_MODULES
                .iter()
                .any(|(c, m, _)| *c == krate && *m == name)
            {
                out.push((i + 1, line.to_string()));
            }
        } else if let Some(path) = l.strip_prefix("pub use ") {
            let first = path
                .trim_start_matches("::")
                .split(|c: char| !(c.is_alphanumeric() || c == '_'))
                .next()
                .unwrap_or("");
            let local = ["crate", "self", "super"].contains(&first) || own_modules.contains(&first);
            if !local {
                out.push((i + 1, line.to_string()));
            }
        }
    }
    out
}

#[test]
fn the_surface_reader_finds_unlisted_modules_and_second_names() {
    let lib = "//! pub mod docs;\nmod error;\npub mod stats;\npub mod flags;\n\
               pub use error::KsbError;\npub use crate::error::Location;\n\
               pub use stepsim_contract::digest::hex;\npub use ::serde_json::Value;\n\
               pub(crate) mod inner;\npub use inner::{\n    A, B,\n};\n\
               #[cfg(test)]\nmod tests { pub use std::fs; }\n";
    let lines: Vec<usize> = surface_breaches("numerics", lib)
        .iter()
        .map(|l| l.0)
        .collect();
    assert_eq!(lines, [4, 7, 8]);
}

#[test]
fn curated_libraries_have_one_name_per_item() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut found = Vec::new();
    for krate in CURATED_LIBRARIES {
        let path = root.join(krate).join("src/lib.rs");
        let lib = std::fs::read_to_string(&path).unwrap();
        for (n, line) in surface_breaches(krate, &lib) {
            found.push(format!("{krate}/src/lib.rs:{n}: {}", line.trim()));
        }
    }
    assert!(
        found.is_empty(),
        "a curated library's lib.rs declares a public module not on PUBLIC_MODULES \
         (tests/architecture.rs; make it private and re-export what users call), or re-exports \
         another crate's item (users name that crate):\n{}",
        found.join("\n")
    );
}

#[test]
fn no_library_module_reexports_another_crates_item() {
    // The lib.rs rule above, for every file of the libraries: a
    // `pub use num_complex::Complex64` inside a module is a second name too.
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut found = Vec::new();
    for krate in CURATED_LIBRARIES {
        let mut files = Vec::new();
        rust_files(&root.join(krate).join("src"), &mut files);
        for file in files {
            let text = std::fs::read_to_string(&file).unwrap();
            for (n, line) in surface_breaches(krate, &text) {
                if line.trim_start().starts_with("pub use ") {
                    let rel = file.strip_prefix(root).unwrap().display().to_string();
                    found.push(format!("{rel}:{n}: {}", line.trim()));
                }
            }
        }
    }
    assert!(
        found.is_empty(),
        "a library module re-exports another crate's item (users name that crate):\n{}",
        found.join("\n")
    );
}

/// The second names in one module file's `code`: a `pub use x::…` (or
/// `pub use self::x::…`) whose path runs through a `pub mod x` declared in
/// the same file, so that the item is reachable both here and as
/// `x::Item`. `public(path)` says whether the deeper modules of a path
/// (`["run", "plan"]` for `pub use run::plan::Plan`) are public below the
/// first; a re-export through a private module is one name. Returns (line
/// number, line).
fn second_names(code: &str, public: &dyn Fn(&[&str]) -> bool) -> Vec<(usize, String)> {
    let public_modules: Vec<&str> = code
        .lines()
        .filter_map(|l| {
            let name = l.trim_start().strip_prefix("pub mod ")?;
            Some(name.trim_end_matches([';', '{', ' ']))
        })
        .collect();
    let mut out = Vec::new();
    for (i, line) in code.lines().enumerate() {
        let Some(path) = line.trim_start().strip_prefix("pub use ") else {
            continue;
        };
        let path = path.strip_prefix("self::").unwrap_or(path);
        let path = path.split(['{', ';', ' ', ',']).next().unwrap_or("");
        let mut segments: Vec<&str> = path.split("::").collect();
        segments.pop(); // the item, or "" before a `{…}` list
        let first_public = segments.first().is_some_and(|m| public_modules.contains(m));
        if first_public && public(&segments) {
            out.push((i + 1, line.to_string()));
        }
    }
    out
}

#[test]
fn the_second_name_reader_finds_reexports_from_public_submodules() {
    let code = "//! pub mod docs;\npub mod galaxy;\nmod spec;\npub mod run;\n\
                pub use galaxy::Galaxy;\npub use spec::PsfSpec;\npub use self::galaxy::{\n    A,\n};\n\
                pub use run::plan::Plan;\npub use run::Shard;\npub use stepsim_contract::Part;\n\
                pub(crate) use galaxy::GL8;\n";
    // `run::plan` is private, `run::open` would be public.
    let public = |path: &[&str]| !path.contains(&"plan");
    let lines: Vec<usize> = second_names(code, &public).iter().map(|l| l.0).collect();
    assert_eq!(lines, [5, 7, 11]);
}

/// The file of module `name` declared in `file`: beside a `lib.rs` or
/// `mod.rs`, else in the directory named after `file`.
fn module_file(file: &Path, name: &str) -> std::path::PathBuf {
    let stem = file.file_stem().unwrap_or_default();
    let dir = if stem == "lib" || stem == "mod" {
        file.parent().unwrap().to_path_buf()
    } else {
        file.with_extension("")
    };
    let flat = dir.join(format!("{name}.rs"));
    if flat.exists() {
        flat
    } else {
        dir.join(name).join("mod.rs")
    }
}

/// Whether every module of `path` after the first is declared `pub mod` in
/// its parent, starting from module `path[0]` declared in `file`.
fn public_below(file: &Path, path: &[&str]) -> bool {
    let mut at = module_file(file, path[0]);
    for name in &path[1..] {
        let Ok(text) = std::fs::read_to_string(&at) else {
            return false;
        };
        let declared = text.lines().any(|l| {
            l.trim() == format!("pub mod {name};") || l.trim() == format!("pub mod {name} {{")
        });
        if !declared {
            return false;
        }
        at = module_file(&at, name);
    }
    true
}

#[test]
fn submodules_have_one_name_per_item() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for krate in CURATED_LIBRARIES {
        rust_files(&root.join(krate).join("src"), &mut files);
    }
    files.sort();
    let mut read = 0;
    let mut found = Vec::new();
    for file in &files {
        let name = file.file_name().unwrap_or_default();
        if name != "mod.rs" && name != "lib.rs" {
            continue;
        }
        read += 1;
        let text = std::fs::read_to_string(file).unwrap();
        let code = library_code(file, &text);
        for (n, line) in second_names(code, &|path| public_below(file, path)) {
            let rel = file.strip_prefix(root).unwrap().display();
            found.push(format!("{rel}:{n}: {}", line.trim()));
        }
    }
    assert!(read > 20, "only {read} mod.rs and lib.rs files read");
    assert!(
        found.is_empty(),
        "a module both declares `pub mod x` and re-exports from it, giving an item two public \
         names (make x private and keep the re-export, or drop the re-export and name the path \
         `x::Item`):\n{}",
        found.join("\n")
    );
}
