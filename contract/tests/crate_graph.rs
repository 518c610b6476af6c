//! The workspace's crate graph, as `cargo metadata` reports it: the rules of
//! ARCHITECTURE.md ("a scorer does not link a renderer") checked on the real
//! Cargo.tomls.
//!
//! * The scorer (`stepsim-harness`) and the reference pipeline
//!   (`stepsim-ksb`) do not depend on the simulator (`stepsim-sim`), neither
//!   directly nor through another workspace crate; a dev-dependency (tests)
//!   is allowed.
//! * `stepsim-contract` depends on no other workspace crate.
//! * The test fixtures (`stepsim-testkit`) are a dev-dependency only: no
//!   library or binary links them.
//! * The normal and build dependencies between workspace crates form no
//!   cycle.

use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Crates that must not link the simulator.
const SCORERS: &[&str] = &["stepsim-harness", "stepsim-ksb"];
/// The simulator.
const SIMULATOR: &str = "stepsim-sim";
/// The contract, which depends on no workspace crate.
const CONTRACT: &str = "stepsim-contract";
/// The test fixtures, a dev-dependency only.
const TESTKIT: &str = "stepsim-testkit";

/// Workspace crate → the workspace crates it needs to build (normal and
/// build dependencies; dev-dependencies are left out: they build only tests).
fn build_graph(metadata: &Value) -> BTreeMap<String, BTreeSet<String>> {
    let packages = metadata["packages"].as_array().expect("packages array");
    let members: BTreeSet<String> = packages
        .iter()
        .map(|p| p["name"].as_str().expect("package name").to_string())
        .collect();
    packages
        .iter()
        .map(|p| {
            let deps = p["dependencies"]
                .as_array()
                .expect("dependencies array")
                .iter()
                .filter(|d| d["kind"].as_str() != Some("dev"))
                .map(|d| d["name"].as_str().expect("dependency name").to_string())
                .filter(|n| members.contains(n))
                .collect();
            (p["name"].as_str().unwrap().to_string(), deps)
        })
        .collect()
}

/// Every workspace crate `from` needs, directly or not.
fn reachable(graph: &BTreeMap<String, BTreeSet<String>>, from: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut stack = vec![from.to_string()];
    while let Some(n) = stack.pop() {
        for d in graph.get(&n).into_iter().flatten() {
            if seen.insert(d.clone()) {
                stack.push(d.clone());
            }
        }
    }
    seen
}

/// The broken rules, as sentences (empty when the graph is as it should be).
fn violations(metadata: &Value) -> Vec<String> {
    let graph = build_graph(metadata);
    let mut out = Vec::new();
    for scorer in SCORERS {
        if !graph.contains_key(*scorer) {
            out.push(format!("{scorer} is not a workspace member"));
            continue;
        }
        let needs = reachable(&graph, scorer);
        if needs.contains(SIMULATOR) {
            let direct = graph[*scorer].contains(SIMULATOR);
            out.push(format!(
                "{scorer} depends on {SIMULATOR} ({}); only a dev-dependency is allowed",
                if direct {
                    "directly"
                } else {
                    "through another crate"
                }
            ));
        }
    }
    if let Some(deps) = graph.get(CONTRACT)
        && !deps.is_empty()
    {
        out.push(format!("{CONTRACT} depends on workspace crates {deps:?}"));
    }
    for (name, deps) in &graph {
        if deps.contains(TESTKIT) {
            out.push(format!(
                "{name} depends on {TESTKIT}; only a dev-dependency is allowed"
            ));
        }
    }
    for name in graph.keys() {
        if reachable(&graph, name).contains(name) {
            out.push(format!("{name} is on a dependency cycle"));
        }
    }
    out
}

#[test]
fn scorers_do_not_link_the_simulator_and_the_graph_is_acyclic() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = std::process::Command::new(cargo)
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .arg("--manifest-path")
        .arg(root.join("Cargo.toml"))
        .output()
        .expect("cargo metadata runs");
    assert!(
        out.status.success(),
        "cargo metadata failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let metadata: Value = serde_json::from_slice(&out.stdout).expect("cargo metadata JSON");
    let graph = build_graph(&metadata);
    // The check sees the workspace as it is.
    for name in [
        SIMULATOR,
        CONTRACT,
        TESTKIT,
        "stepsim-harness",
        "stepsim-ksb",
    ] {
        assert!(graph.contains_key(name), "{name} missing from {graph:?}");
    }
    assert!(graph["stepsim-harness"].contains(CONTRACT), "{graph:?}");
    // The challenge server scores with the harness and links no simulator.
    assert!(
        !reachable(&graph, "stepsim-server").contains(SIMULATOR),
        "stepsim-server reaches {SIMULATOR}: {graph:?}"
    );
    let broken = violations(&metadata);
    assert!(broken.is_empty(), "{}", broken.join("\n"));
}

/// Dependencies of a crate: (name, kind), kind `None` for a normal one.
type Deps<'a> = &'a [(&'a str, Option<&'a str>)];

/// A metadata document of `(crate, dependencies)`.
fn fake(packages: &[(&str, Deps<'_>)]) -> Value {
    let packages: Vec<Value> = packages
        .iter()
        .map(|(name, deps)| {
            let deps: Vec<Value> = deps
                .iter()
                .map(|(d, kind)| serde_json::json!({"name": d, "kind": kind}))
                .collect();
            serde_json::json!({"name": name, "dependencies": deps})
        })
        .collect();
    serde_json::json!({ "packages": packages })
}

#[test]
fn the_check_refuses_a_simulator_dependency_and_a_cycle() {
    let sim: Deps = &[(CONTRACT, None), ("rustfft", None)];
    let good = fake(&[
        (CONTRACT, &[("serde", None)]),
        (SIMULATOR, sim),
        (
            "stepsim-harness",
            &[
                (CONTRACT, None),
                (SIMULATOR, Some("dev")),
                (TESTKIT, Some("dev")),
            ],
        ),
        ("stepsim-ksb", &[(CONTRACT, None)]),
        (TESTKIT, &[("stepsim-harness", None)]),
    ]);
    assert_eq!(violations(&good), Vec::<String>::new());

    let fixtures = fake(&[
        (CONTRACT, &[]),
        ("stepsim-harness", &[(CONTRACT, None)]),
        ("stepsim-ksb", &[]),
        ("stepsim-server", &[(TESTKIT, None)]),
        (TESTKIT, &[("stepsim-harness", None)]),
    ]);
    assert_eq!(
        violations(&fixtures),
        ["stepsim-server depends on stepsim-testkit; only a dev-dependency is allowed"]
    );

    let direct = fake(&[
        (CONTRACT, &[]),
        (SIMULATOR, sim),
        ("stepsim-harness", &[(SIMULATOR, None)]),
        ("stepsim-ksb", &[(SIMULATOR, Some("build"))]),
    ]);
    assert_eq!(
        violations(&direct),
        [
            "stepsim-harness depends on stepsim-sim (directly); only a dev-dependency is allowed",
            "stepsim-ksb depends on stepsim-sim (directly); only a dev-dependency is allowed",
        ]
    );

    let through = fake(&[
        (CONTRACT, &[]),
        (SIMULATOR, sim),
        ("stepsim-figure", &[(SIMULATOR, None)]),
        ("stepsim-harness", &[("stepsim-figure", None)]),
        ("stepsim-ksb", &[]),
    ]);
    assert_eq!(
        violations(&through),
        [
            "stepsim-harness depends on stepsim-sim (through another crate); only a dev-dependency is allowed"
        ]
    );

    let cycle = fake(&[
        (CONTRACT, &[(SIMULATOR, None)]),
        (SIMULATOR, sim),
        ("stepsim-harness", &[]),
        ("stepsim-ksb", &[]),
    ]);
    assert_eq!(
        violations(&cycle),
        [
            "stepsim-contract depends on workspace crates {\"stepsim-sim\"}",
            "stepsim-contract is on a dependency cycle",
            "stepsim-sim is on a dependency cycle",
        ]
    );
}
