//! The server's integration tests, linked as one binary (`cargo test -p
//! stepsim-server --test integration`): each file of `server/tests/` is a
//! module of it (`pages.rs` is `pages`, its tests are `pages::...`);
//! `common/` is the shared helpers, used as `crate::common`. With
//! `autotests = false` a new file must be named below (the root package's
//! `every_test_file_is_a_module` checks it).

mod common;

mod api;
mod browser;
mod hardening;
mod module_graph;
mod pages;
mod prober;
