//! Finds OpenNI2 (pkg-config `libopenni2`, else Debian's known paths), generates bindings for
//! `OniCAPI.h` with bindgen and links `libOpenNI2`.

use std::env;
use std::path::{Path, PathBuf};
use std::process::Command;

const KNOWN_INCLUDE_DIRS: &[&str] = &["/usr/include/openni2", "/usr/local/include/openni2"];
const KNOWN_LIB_DIRS: &[&str] = &[
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib",
    "/usr/local/lib",
];

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=wrapper.h");
    println!("cargo:rerun-if-env-changed=OPENNI2_INCLUDE");
    println!("cargo:rerun-if-env-changed=OPENNI2_REDIST");

    let (include_dir, lib_dir) = locate();
    if let Some(lib_dir) = &lib_dir {
        println!("cargo:rustc-link-search=native={}", lib_dir.display());
    }
    println!("cargo:rustc-link-lib=dylib=OpenNI2");
    println!("cargo:include={}", include_dir.display());

    let bindings = bindgen::Builder::default()
        .header("wrapper.h")
        // The headers are C++ (`typedef _OniDevice* OniDeviceHandle;` is not valid C).
        .clang_args(["-x", "c++", "-std=c++11"])
        .clang_arg(format!("-I{}", include_dir.display()))
        .allowlist_function("oni.*")
        .allowlist_type("Oni.*|_Oni.*")
        .allowlist_var("ONI_.*|XN_.*")
        // Values the library hands back may be ones this header does not know: newtypes,
        // never Rust enums (an unknown discriminant in a Rust enum is undefined behaviour).
        .default_enum_style(bindgen::EnumVariation::NewType {
            is_bitfield: false,
            is_global: false,
        })
        .prepend_enum_name(false)
        .derive_default(true)
        .derive_debug(true)
        .layout_tests(true)
        .generate_comments(false)
        .parse_callbacks(Box::new(bindgen::CargoCallbacks::new()))
        .generate()
        .expect("bindgen could not generate OpenNI2 bindings from OniCAPI.h");

    let out = PathBuf::from(env::var("OUT_DIR").expect("OUT_DIR is set by cargo"));
    bindings
        .write_to_file(out.join("bindings.rs"))
        .expect("cannot write bindings.rs");
}

/// Include directory and (when not on the default linker path) library directory.
fn locate() -> (PathBuf, Option<PathBuf>) {
    if let (Ok(inc), Ok(lib)) = (env::var("OPENNI2_INCLUDE"), env::var("OPENNI2_REDIST")) {
        return (PathBuf::from(inc), Some(PathBuf::from(lib)));
    }
    if let Some(found) = pkg_config() {
        return found;
    }
    let include = KNOWN_INCLUDE_DIRS
        .iter()
        .map(Path::new)
        .find(|d| d.join("OniCAPI.h").exists())
        .unwrap_or_else(|| {
            panic!(
                "OpenNI2 headers not found (tried pkg-config libopenni2 and {KNOWN_INCLUDE_DIRS:?}); \
                 install Debian's libopenni2-dev or set OPENNI2_INCLUDE and OPENNI2_REDIST"
            )
        });
    let lib = KNOWN_LIB_DIRS
        .iter()
        .map(Path::new)
        .find(|d| d.join("libOpenNI2.so").exists());
    (include.to_path_buf(), lib.map(Path::to_path_buf))
}

/// Asks `pkg-config` for `libopenni2` (Debian ships `libopenni2.pc`).
fn pkg_config() -> Option<(PathBuf, Option<PathBuf>)> {
    let cflags = Command::new("pkg-config")
        .args(["--cflags-only-I", "libopenni2"])
        .output()
        .ok()?;
    if !cflags.status.success() {
        return None;
    }
    let include = String::from_utf8_lossy(&cflags.stdout)
        .split_whitespace()
        .filter_map(|f| f.strip_prefix("-I"))
        .map(PathBuf::from)
        .find(|d| d.join("OniCAPI.h").exists())?;
    let libs = Command::new("pkg-config")
        .args(["--libs-only-L", "libopenni2"])
        .output()
        .ok()?;
    let lib = String::from_utf8_lossy(&libs.stdout)
        .split_whitespace()
        .filter_map(|f| f.strip_prefix("-L"))
        .map(PathBuf::from)
        .next();
    Some((include, lib))
}
