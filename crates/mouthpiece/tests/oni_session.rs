//! Synthetic sessions as OpenNI2 `.oni` files: written by our plain-Rust writer, read back by
//! OpenNI2's own file player (Debian's libopenni2-0, through `replay:FILE?speed=0`), and
//! processed by `mouthpiece process` like the same session in MCAP.
//!
//! Sessions are rendered at test time, 320x240 at 35 cm, 2.5 s (the neutral lead-in is 1.5 s
//! and calibration needs 1 s of it).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use mouthpiece_capture::oni_write::OniFrameWriter;
use mouthpiece_capture::{open_source, CaptureConfig};
use mouthpiece_synth::{Synth, SynthConfig};
use serde_json::Value;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn mouthpiece(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mouthpiece"))
        .args(args)
        .env("RUST_LOG", "info")
        .output()
        .expect("run mouthpiece")
}

fn ok(args: &[&str]) -> String {
    let out = mouthpiece(args);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "mouthpiece {args:?} failed: {stderr}");
    stderr
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `mouthpiece synth` of one session, as `.oni` and as `.mcap` with lossless colour (so that
/// both hold the same pixels).
fn synth_both(dir: &Path, seconds: &str, seed: &str) -> (PathBuf, PathBuf) {
    let oni = dir.join("session.oni");
    let mcap = dir.join("session.mcap");
    for (out, extra) in [(&oni, None), (&mcap, Some("--raw-color"))] {
        let mut args = vec![
            "synth",
            "--out",
            s(out),
            "--seconds",
            seconds,
            "--seed",
            seed,
            "--size",
            "320x240",
            // Close enough that the dots are big enough for the default detector at 320x240.
            "--distance",
            "0.35",
        ];
        args.extend(extra);
        ok(&args);
    }
    (oni, mcap)
}

#[test]
fn synth_oni_replays_frame_for_frame_through_openni2() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.oni");
    let config = SynthConfig {
        seed: 7,
        seconds: 1.0,
        camera: SynthConfig::camera_for_size(320, 240),
        ..SynthConfig::default()
    };
    let calibration = config.calibration();
    let mut writer = OniFrameWriter::create(&path, &calibration, config.fps).unwrap();
    let mut written = Vec::new();
    for (frame, _) in Synth::new(config).unwrap() {
        writer.write_frame(&frame).unwrap();
        written.push(frame);
    }
    let summary = writer.finish().unwrap();
    assert_eq!(summary.depth_frames as usize, written.len());
    assert_eq!(written.len(), 30);
    // Uncompressed: 2 + 3 bytes a pixel a frame, and the records around them.
    let payload = 30 * 320 * 240 * 5;
    assert!(
        summary.bytes > payload && summary.bytes < payload + 10_000,
        "{} bytes",
        summary.bytes
    );

    let spec = format!("replay:{}?speed=0", path.display());
    let mut replay = open_source(&spec, &CaptureConfig::default()).unwrap();
    assert_eq!(
        (replay.info().color_width, replay.info().color_height),
        (320, 240)
    );
    assert_eq!(replay.info().fps, 30.0);
    let mut read = Vec::new();
    while let Some(frame) = replay.next_frame().unwrap() {
        read.push(frame);
        assert!(read.len() <= written.len(), "the replay does not end");
    }
    assert_eq!(read.len(), written.len(), "every frame, none dropped");
    for (i, (w, r)) in written.iter().zip(&read).enumerate() {
        assert_eq!(r.seq, i as u64);
        assert_eq!(r.device_ts_us, w.device_ts_us, "frame {i}: timestamp");
        assert!(
            r.color.data == w.color.data,
            "frame {i}: colour bytes differ"
        );
        assert!(
            r.depth.data == w.depth.data,
            "frame {i}: depth values differ"
        );
    }
    // What the player reports: intrinsics from the field of view (stored as f64, handed out by
    // OpenNI2 as f32 radians), centred principal point, no distortion, registered depth.
    let (k, c) = (&read[0].calibration.color, &calibration.color);
    assert!(read[0].calibration.depth_registered);
    assert!(!k.has_distortion());
    assert_eq!((k.cx, k.cy), (c.cx, c.cy));
    assert!((k.fx - c.fx).abs() < 1e-3, "fx {} vs {}", k.fx, c.fx);
    assert!((k.fy - c.fy).abs() < 1e-3, "fy {} vs {}", k.fy, c.fy);
    assert_eq!(read[0].calibration.depth, read[0].calibration.color);
}

fn lines(path: &Path) -> Vec<Value> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

#[test]
fn process_on_oni_tracks_like_process_on_mcap() {
    let dir = tempfile::tempdir().unwrap();
    let (oni, mcap) = synth_both(dir.path(), "2.5", "11");
    let wolf = repo().join("config/characters/wolf.toml");
    let mut takes = Vec::new();
    for input in [&mcap, &oni] {
        let out = input.with_extension("jsonl");
        let stderr = ok(&[
            "process",
            s(input),
            "--character",
            s(&wolf),
            "--out",
            s(&out),
        ]);
        assert!(stderr.contains("process done"), "{stderr}");
        takes.push(lines(&out));
    }
    let (from_mcap, from_oni) = (&takes[0], &takes[1]);
    assert_eq!(from_oni.len(), 75, "one line per frame");
    assert_eq!(from_mcap.len(), from_oni.len());
    let calibrated = |take: &[Value]| {
        take.iter()
            .position(|l| l["status"]["neutral_taken"] == true)
    };
    let first = calibrated(from_oni).expect("the .oni session calibrates");
    assert_eq!(
        calibrated(from_mcap),
        Some(first),
        "calibrated at the same frame"
    );

    // The same pixels and depths: detection is identical, and 3D points differ only by the
    // focal length the replay derives from the field of view OpenNI2 hands out as f32 (relative
    // error ≤ 6e-8, so ≤ 3e-8 m on coordinates within ±0.5 m; measured 1.6e-9 m). 1e-6 m
    // leaves a wide margin and is still a thousand times below a real sensor's depth noise.
    let mut max_diff = 0.0f64;
    let mut compared = 0;
    for (i, (a, b)) in from_mcap.iter().zip(from_oni).enumerate() {
        assert_eq!(
            a["frame"]["device_ts_us"], b["frame"]["device_ts_us"],
            "line {i}"
        );
        assert_eq!(a["status"], b["status"], "line {i}");
        let (pa, pb) = (&a["performer"], &b["performer"]);
        let dots = pa.as_object().expect("performer dots by name");
        for (name, p) in dots {
            let q = &pb[name];
            assert_eq!(p.is_null(), q.is_null(), "line {i} dot {name}");
            if let (Some(p), Some(q)) = (p.as_array(), q.as_array()) {
                for (x, y) in p.iter().zip(q) {
                    max_diff = max_diff.max((x.as_f64().unwrap() - y.as_f64().unwrap()).abs());
                }
                compared += 1;
            }
        }
    }
    assert!(compared >= 1000, "only {compared} dots compared");
    assert!(max_diff < 1e-6, "tracked dots differ by up to {max_diff} m");
    eprintln!("{compared} dots compared, largest difference {max_diff:e} m");
}

#[test]
fn synth_refuses_what_an_oni_cannot_hold() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.oni");
    for (flag, value, needle) in [
        ("--distortion", "0.1,0,0,0,0", "lens distortion"),
        ("--depth-baseline-mm", "25", "not registered"),
    ] {
        let output = mouthpiece(&[
            "synth",
            "--out",
            s(&out),
            "--seconds",
            "0.1",
            "--seed",
            "1",
            flag,
            value,
        ]);
        assert_eq!(output.status.code(), Some(2), "{flag}");
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(
            stderr.contains(needle) && stderr.contains(".mcap"),
            "{stderr}"
        );
    }
}
