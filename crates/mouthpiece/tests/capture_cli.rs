//! `mouthpiece record` and `mouthpiece devices` as a user runs them: the real binary, the
//! real OpenNI2 Dummy device, Ctrl-C as SIGINT.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use mouthpiece_capture::{open_source, CaptureConfig};

fn mouthpiece() -> Command {
    Command::new(env!("CARGO_BIN_EXE_mouthpiece"))
}

fn count_frames(spec: &str) -> u64 {
    let mut src =
        open_source(spec, &CaptureConfig::default()).unwrap_or_else(|e| panic!("{spec}: {e}"));
    let mut n = 0;
    while src.next_frame().unwrap().is_some() {
        n += 1;
    }
    n
}

#[test]
fn ctrl_c_stops_recording_with_a_readable_file() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["take.mcap", "take.oni"] {
        let out = dir.path().join(name);
        let mut child = mouthpiece()
            .args(["record", "--source", "openni2:Dummy", "--out"])
            .arg(&out)
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(2500));
        let status = Command::new("kill")
            .args(["-INT", &child.id().to_string()])
            .status()
            .unwrap();
        assert!(status.success());
        let start = Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            assert!(
                start.elapsed() < Duration::from_secs(20),
                "record did not stop after Ctrl-C"
            );
            std::thread::sleep(Duration::from_millis(50));
        };
        let mut err = String::new();
        std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
        assert!(status.success(), "{name}: {status}\n{err}");
        assert!(err.contains("recorded"), "{err}");
        let n = count_frames(&format!("replay:{}?speed=0", out.display()));
        assert!(n >= 20, "{name}: only {n} frames after about 2 s");
    }
}

#[test]
fn seconds_limit_and_bad_input_exit_codes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("two.mcap");
    let o = mouthpiece()
        .args([
            "record",
            "--source",
            "openni2:Dummy",
            "--seconds",
            "2",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let n = count_frames(&format!("replay:{}?speed=0", out.display()));
    assert!((50..=62).contains(&n), "2 s at 30 fps gave {n} frames");

    // A session whose camera has lens distortion, which an .oni cannot hold.
    let synth = mouthpiece()
        .current_dir(dir.path())
        .args([
            "synth",
            "--seed",
            "1",
            "--seconds",
            "0.5",
            "--size",
            "160x120",
        ])
        .args(["--distortion", "0.1,0,0,0,0", "--out", "distorted.mcap"])
        .output()
        .unwrap();
    assert!(synth.status.success(), "{synth:?}");
    for (args, needle) in [
        (
            vec!["record", "--source", "kinect:0", "--out", "x.mcap"],
            "unknown source kind",
        ),
        (
            vec!["record", "--source", "openni2:Dummy", "--out", "x.avi"],
            "unknown output format",
        ),
        (
            vec![
                "record",
                "--source",
                "replay:distorted.mcap",
                "--out",
                "x.oni",
            ],
            "lens distortion",
        ),
        (
            vec![
                "record",
                "--source",
                "replay:/nonexistent/take.mcap",
                "--out",
                "x.mcap",
            ],
            "no such file",
        ),
        (
            vec![
                "record",
                "--source",
                "openni2:Dummy",
                "--out",
                "x.mcap",
                "--seconds",
                "0",
            ],
            "--seconds 0",
        ),
    ] {
        let o = mouthpiece()
            .current_dir(dir.path())
            .args(&args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
    }
}

#[test]
fn devices_lists_or_says_there_are_none() {
    let o = mouthpiece().arg("devices").output().unwrap();
    assert!(o.status.success());
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("OpenNI2 devices:"), "{text}");
    assert!(text.contains("V4L2 nodes:"), "{text}");
    if !std::path::Path::new("/dev/video0").exists() {
        assert!(text.contains("none found (no /dev/video*)"), "{text}");
    }
}

/// Any source records to `.oni` (here an MCAP replay, through mouthpiece's writer); OpenNI2's
/// player gives back the same frames.
#[test]
fn an_mcap_session_records_to_oni_and_replays_the_same_frames() {
    let dir = tempfile::tempdir().unwrap();
    let mcap = dir.path().join("s.mcap");
    let oni = dir.path().join("s.oni");
    let synth = mouthpiece()
        .args([
            "synth",
            "--seed",
            "1",
            "--seconds",
            "1",
            "--size",
            "160x120",
        ])
        .args(["--raw-color", "--out"])
        .arg(&mcap)
        .output()
        .unwrap();
    assert!(synth.status.success(), "{synth:?}");
    let record = mouthpiece()
        .args(["record", "--source"])
        .arg(format!("replay:{}?speed=0", mcap.display()))
        .arg("--out")
        .arg(&oni)
        .output()
        .unwrap();
    assert!(record.status.success(), "{record:?}");
    let frames = |spec: String| {
        let mut src = open_source(&spec, &CaptureConfig::default()).unwrap();
        std::iter::from_fn(|| src.next_frame().unwrap()).collect::<Vec<_>>()
    };
    let from_mcap = frames(format!("replay:{}?speed=0", mcap.display()));
    let from_oni = frames(format!("replay:{}?speed=0", oni.display()));
    assert_eq!(from_mcap.len(), 30);
    assert_eq!(from_oni.len(), from_mcap.len());
    for (a, b) in from_mcap.iter().zip(&from_oni) {
        assert_eq!(a.device_ts_us, b.device_ts_us);
        assert!(a.color.data == b.color.data, "colour of frame {}", a.seq);
        assert!(a.depth.data == b.depth.data, "depth of frame {}", a.seq);
    }
}
