//! The crate's integration tests, one module per former test file, in one test binary
//! (each test binary links the whole dependency tree: one binary builds and links once).

mod hostile;
mod kl;
mod shipped_network;
mod skinning;
