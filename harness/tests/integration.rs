//! The harness's integration tests, linked as one binary (`cargo test -p
//! stepsim-harness --test integration`): each file of `harness/tests/` is
//! a module of it (`coverage.rs` is `coverage`, its tests are
//! `coverage::...`); `common/` and `synth_stats/` are shared helpers, used
//! as `crate::common` and `crate::synth_stats`. With `autotests = false` a
//! new file must be named below (the root package's
//! `every_test_file_is_a_module` checks it).

mod common;
mod synth_stats;

mod blends;
mod bootstrap_coverage;
mod coverage;
mod fit_models;
mod fits_plain_names;
mod fuzz_readers;
mod hostile_input;
mod known_answer;
mod module_graph;
mod part;
mod refusal_order;
mod streaming;
mod submission_parse;
mod wide_headers;
