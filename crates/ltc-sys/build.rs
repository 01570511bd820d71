//! Finds libltc with pkg-config (Debian ships `ltc.pc`), else the system include path;
//! generates bindings for its decoder, encoder and frame conversions with bindgen and links
//! `libltc`.

use std::env;
use std::path::PathBuf;
use std::process::Command;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=wrapper.h");

    let includes = pkg_config_includes().unwrap_or_default();
    let found = includes
        .iter()
        .chain(std::iter::once(&PathBuf::from("/usr/include")))
        .any(|d| d.join("ltc.h").exists());
    if !found {
        panic!("libltc's header ltc.h not found (tried pkg-config ltc and /usr/include); install Debian's libltc-dev");
    }
    println!("cargo:rustc-link-lib=dylib=ltc");

    let bindings = bindgen::Builder::default()
        .header("wrapper.h")
        .clang_args(includes.iter().map(|d| format!("-I{}", d.display())))
        .allowlist_function("ltc_.*")
        .allowlist_type("LTC.*|SMPTETimecode|ltc_off_t|ltcsnd_sample_t")
        .allowlist_var("LTC_.*")
        .default_enum_style(bindgen::EnumVariation::NewType {
            is_bitfield: false,
            is_global: false,
        })
        .derive_default(true)
        .derive_debug(true)
        .layout_tests(true)
        .generate_comments(false)
        .parse_callbacks(Box::new(bindgen::CargoCallbacks::new()))
        .generate()
        .expect("bindgen could not generate libltc bindings from ltc.h");

    let out = PathBuf::from(env::var("OUT_DIR").expect("OUT_DIR is set by cargo"));
    bindings
        .write_to_file(out.join("bindings.rs"))
        .expect("cannot write bindings.rs");
}

/// Include directories from `pkg-config ltc` (none on Debian: the header is in /usr/include).
fn pkg_config_includes() -> Option<Vec<PathBuf>> {
    let out = Command::new("pkg-config")
        .args(["--cflags-only-I", "ltc"])
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    Some(
        String::from_utf8_lossy(&out.stdout)
            .split_whitespace()
            .filter_map(|f| f.strip_prefix("-I"))
            .map(PathBuf::from)
            .collect(),
    )
}
