//! The crate's integration tests, one module per former test file, in one test binary
//! (each test binary links the whole dependency tree: one binary builds and links once).

#[path = "../festival/mod.rs"]
#[allow(unused_imports)]
mod helper_festival;

mod continuity;
mod live;
mod reference;
mod shipped;
