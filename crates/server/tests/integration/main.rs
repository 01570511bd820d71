//! The crate's integration tests, one module per former test file, in one test binary
//! (each test binary links the whole dependency tree: one binary builds and links once).

#[path = "../common/mod.rs"]
#[allow(unused_imports)]
mod helper_common;
#[path = "../webdriver/mod.rs"]
#[allow(dead_code, unused_imports)]
mod helper_webdriver;

mod console_page;
mod foxglove;
mod foxglove_panels;
mod http_security;
mod protocol;
mod schemas;
mod viewer;
