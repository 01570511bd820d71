//! Finds PocketSphinx and SphinxBase with pkg-config (Debian ships `pocketsphinx.pc`), else
//! Debian's known include paths; generates bindings for the decoder API with bindgen and
//! links `libpocketsphinx` and `libsphinxbase`.

use std::env;
use std::path::{Path, PathBuf};
use std::process::Command;

const KNOWN_INCLUDE_DIRS: &[&str] = &[
    "/usr/include/pocketsphinx",
    "/usr/include/sphinxbase",
    "/usr/include/x86_64-linux-gnu",
    "/usr/include/x86_64-linux-gnu/sphinxbase",
    "/usr/include/aarch64-linux-gnu",
    "/usr/include/aarch64-linux-gnu/sphinxbase",
];

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=wrapper.h");

    let (includes, lib_dirs) = pkg_config().unwrap_or_else(|| {
        let inc: Vec<PathBuf> = KNOWN_INCLUDE_DIRS
            .iter()
            .map(PathBuf::from)
            .filter(|d| d.exists())
            .collect();
        (inc, Vec::new())
    });
    if !includes.iter().any(|d| d.join("pocketsphinx.h").exists()) {
        panic!(
            "PocketSphinx headers not found (tried pkg-config pocketsphinx and \
             {KNOWN_INCLUDE_DIRS:?}); install Debian's libpocketsphinx-dev"
        );
    }
    for dir in &lib_dirs {
        println!("cargo:rustc-link-search=native={}", dir.display());
    }
    println!("cargo:rustc-link-lib=dylib=pocketsphinx");
    println!("cargo:rustc-link-lib=dylib=sphinxbase");

    let bindings = bindgen::Builder::default()
        .header("wrapper.h")
        .clang_args(includes.iter().map(|d| format!("-I{}", d.display())))
        .allowlist_function("ps_.*|cmd_ln_.*|err_set_logfp|err_set_logfile|ckd_free")
        .allowlist_type("ps_.*|cmd_ln_t|arg_t")
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
        .expect("bindgen could not generate PocketSphinx bindings from pocketsphinx.h");

    let out = PathBuf::from(env::var("OUT_DIR").expect("OUT_DIR is set by cargo"));
    bindings
        .write_to_file(out.join("bindings.rs"))
        .expect("cannot write bindings.rs");
}

/// Include and library directories from `pkg-config pocketsphinx` (which pulls in sphinxbase).
fn pkg_config() -> Option<(Vec<PathBuf>, Vec<PathBuf>)> {
    let run = |flag: &str| -> Option<Vec<PathBuf>> {
        let out = Command::new("pkg-config")
            .args([flag, "pocketsphinx"])
            .output()
            .ok()?;
        if !out.status.success() {
            return None;
        }
        let prefix = if flag.ends_with('I') { "-I" } else { "-L" };
        Some(
            String::from_utf8_lossy(&out.stdout)
                .split_whitespace()
                .filter_map(|f| f.strip_prefix(prefix))
                .map(PathBuf::from)
                .filter(|d| Path::new(d).exists())
                .collect(),
        )
    };
    Some((run("--cflags-only-I")?, run("--libs-only-L")?))
}
