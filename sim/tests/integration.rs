//! sim's integration tests, linked as one binary (`cargo test -p
//! stepsim-sim --test integration`): each file of `sim/tests/` is a module
//! of it. With `autotests = false` a new file must be named below (the
//! root package's `every_test_file_is_a_module` checks it).

mod module_graph;
mod truth_matches_drawing;
