//! The crate's integration tests, one module per former test file, in one test binary
//! (each test binary links the whole dependency tree: one binary builds and links once).

#[path = "../harness/mod.rs"]
#[allow(unused_imports)]
mod helper_harness;
#[path = "../harness/take.rs"]
#[allow(dead_code, unused_imports)]
mod helper_harness_take;

mod cluster;
mod fetch_trust;
mod link;
mod takes;
