//! `mouthpiece synth` end to end: the file it writes is read by Python's `mcap` package (an
//! independent reader, `tests/read_session.py`) and by our own reader; bad input exits 2.

use std::path::{Path, PathBuf};
use std::process::Command;

use mouthpiece_recording::SessionReader;
use mouthpiece_synth::{Synth, SynthConfig};

fn mouthpiece() -> Command {
    Command::new(env!("CARGO_BIN_EXE_mouthpiece"))
}

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn python() -> String {
    std::env::var("MOUTHPIECE_PYTHON").unwrap_or_else(|_| "python3".into())
}

#[test]
fn python_mcap_reads_what_synth_writes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s.mcap");
    let status = mouthpiece()
        .args(["synth", "--out"])
        .arg(&out)
        .args(["--seconds", "2", "--seed", "42", "--size", "160x120"])
        .status()
        .unwrap();
    assert!(status.success());

    // What was written: the same config rendered in memory.
    let config = SynthConfig {
        seed: 42,
        seconds: 2.0,
        camera: SynthConfig::camera_for_size(160, 120),
        ..SynthConfig::default()
    };
    let depth_frame = 47;
    let (frame, _) = Synth::new(config).unwrap().nth(depth_frame).unwrap();
    let depth_file = dir.path().join("depth.raw");
    let bytes: Vec<u8> = frame
        .depth
        .data
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    std::fs::write(&depth_file, bytes).unwrap();
    let expected = serde_json::json!({
        "frames": 60, "depth_frame": depth_frame, "depth_file": depth_file,
        "width": 160, "height": 120, "color_format": "jpeg",
    });
    let expected_file = dir.path().join("expected.json");
    std::fs::write(&expected_file, expected.to_string()).unwrap();

    let output = Command::new(python())
        .arg(repo_root().join("tests/read_session.py"))
        .arg(&out)
        .arg(&expected_file)
        .output()
        .expect("run Python (set MOUTHPIECE_PYTHON)");
    assert!(
        output.status.success(),
        "read_session.py failed:\n{}\n{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );

    // And our reader gives back the same depth and the ground truth.
    let f = SessionReader::open(&out)
        .unwrap()
        .nth(depth_frame)
        .unwrap()
        .unwrap();
    assert_eq!(f.frame.depth, frame.depth);
    assert!(f.ground_truth.is_some());
}

#[test]
fn bad_input_exits_2_and_names_it() {
    let dir = tempfile::tempdir().unwrap();
    let layout = dir.path().join("layout.toml");
    std::fs::write(&layout, "lip_dots = 5\n").unwrap();
    let output = mouthpiece()
        .args(["synth", "--seconds", "1", "--seed", "1", "--out"])
        .arg(dir.path().join("x.mcap"))
        .arg("--layout")
        .arg(&layout)
        .output()
        .unwrap();
    assert_eq!(output.status.code(), Some(2));
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(
        err.contains("layout.toml") && err.contains("lip_dots"),
        "{err}"
    );

    let output = mouthpiece()
        .args([
            "synth",
            "--seconds",
            "1",
            "--seed",
            "1",
            "--distance",
            "9",
            "--out",
        ])
        .arg(dir.path().join("x.mcap"))
        .output()
        .unwrap();
    assert_eq!(output.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&output.stderr).contains("distance"));
}

/// Runs `synth` with `args` (one second unless they say): it must exit 2 naming `named` and
/// leave no file.
fn synth_refuses(out: &str, args: &[&str], named: &str) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(out);
    let mut cmd = mouthpiece();
    cmd.args(["synth", "--seed", "1", "--size", "64x48", "--out"])
        .arg(&path);
    if !args.contains(&"--seconds") {
        cmd.args(["--seconds", "1"]);
    }
    let output = cmd.args(args).output().unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{args:?}: {err}");
    assert!(err.contains(named), "{args:?}: {err}");
    assert!(!path.exists(), "{args:?} left {out}");
}

/// A frame rate near zero wrote an empty session that looked like success.
#[test]
fn a_frame_rate_near_zero_exits_2() {
    synth_refuses("a.mcap", &["--fps", "1e-300"], "fps");
    synth_refuses("b.oni", &["--fps", "1e-300"], "fps");
    synth_refuses("c.mcap", &["--fps", "0.5"], "fps");
}

/// A length of 10^300 s planned speech without end.
#[test]
fn a_length_past_a_day_exits_2() {
    synth_refuses("d.mcap", &["--seconds", "1e300"], "seconds");
    synth_refuses("e.mcap", &["--seconds", "1e9"], "seconds");
}

/// Non-finite lens distortion.
#[test]
fn non_finite_distortion_exits_2() {
    synth_refuses("f.mcap", &["--distortion", "NaN,0,0,0,0"], "distortion");
}

/// A hinge moved past ±50 % or a jaw slide out of 0–5 mm is refused at the door, naming the
/// flag.
#[test]
fn a_hinge_or_a_jaw_slide_out_of_range_exits_2() {
    synth_refuses("g.mcap", &["--hinge", "back=+80%"], "--hinge");
    synth_refuses("h.mcap", &["--hinge", "sideways=5%"], "--hinge");
    synth_refuses("i.mcap", &["--jaw-slide", "NaN"], "--jaw-slide");
    synth_refuses("j.mcap", &["--jaw-slide", "12"], "--jaw-slide");
    let output = mouthpiece()
        .args(["evaluate", "--seeds", "1", "--hinge", "down=-70%"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{err}");
    assert!(err.contains("--hinge"), "{err}");
}
