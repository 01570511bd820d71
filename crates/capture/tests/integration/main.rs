//! The crate's integration tests, one module per former test file, in one test binary
//! (each test binary links the whole dependency tree: one binary builds and links once).

mod oni_writer_vs_recorder;
mod openni2_round_trip;
