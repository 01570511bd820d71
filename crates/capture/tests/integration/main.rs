//! The crate's integration tests, one module per former test file, in one test binary
//! (each test binary links the whole dependency tree: one binary builds and links once).

#[path = "../../../../tests/alsa/booth.rs"]
#[allow(dead_code, unused_imports)]
mod helper_alsa_booth;

mod alsa_booth;
mod oni_writer_vs_recorder;
mod openni2_round_trip;
