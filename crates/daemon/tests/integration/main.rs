//! The crate's integration tests, one module per former test file, in one test binary
//! (each test binary links the whole dependency tree: one binary builds and links once).

#[path = "../../../../tests/speech/cover_mouth.rs"]
#[allow(dead_code, unused_imports)]
mod helper_speech_cover_mouth;
#[path = "../../../../tests/speech/festival.rs"]
#[allow(unused_imports)]
mod helper_speech_festival;

mod hardening;
mod speech_alone;
mod speech_fallback;
