//! Reads back a recording made from the booth (tests/alsa/booth.rs) with Python's own MCAP
//! reader (`tests/python/check_take_audio.py`): its sound against the booth's raw samples and,
//! when given, the WAV exported beside it. Included by the tests that need it with `#[path]`.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

/// The Python with numpy and mcap (`MOUTHPIECE_PYTHON`, else `python3`).
pub fn python() -> String {
    std::env::var("MOUTHPIECE_PYTHON").unwrap_or_else(|_| "python3".into())
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// What `check_take_audio.py` found in `recording` (`blocks`, `exact`, `events`,
/// `first_audio`, `last_frame`, …); panics with its stderr when it fails.
pub fn check_take_audio(recording: &Path, s16: &Path, wav: Option<&Path>) -> serde_json::Value {
    let mut command = Command::new(python());
    command
        .arg(repo().join("tests/python/check_take_audio.py"))
        .arg(recording)
        .arg(s16);
    if let Some(wav) = wav {
        command.arg(wav);
    }
    let checked = command
        .output()
        .expect("running Python (set MOUTHPIECE_PYTHON)");
    assert!(
        checked.status.success(),
        "{}",
        String::from_utf8_lossy(&checked.stderr)
    );
    serde_json::from_slice(&checked.stdout).unwrap()
}
