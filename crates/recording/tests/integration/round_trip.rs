//! Write sessions, read them back: frames, ground truth, JSON channels, truncation, looping.

use std::sync::Arc;
use std::time::{Duration, Instant};

use mouthpiece_frame::{Calibration, ColorImage, DepthImage, Extrinsics, Frame, Intrinsics};
use mouthpiece_recording::{
    ColorEncoding, GroundTruth, HeadPose, MessageReader, SessionReader, SessionWriter,
    WriterOptions,
};

fn calibration() -> Arc<Calibration> {
    let mut color = Intrinsics::default_vga();
    color.width = 64;
    color.height = 48;
    color.cx = 31.5;
    color.cy = 23.5;
    color.distortion = [0.01, -0.02, 0.0, 0.0, 0.0];
    let mut cal = Calibration::registered(color);
    cal.depth_to_color = Extrinsics {
        translation: [0.025, 0.0, 0.0],
        ..Extrinsics::IDENTITY
    };
    Arc::new(cal)
}

/// A frame whose pixels depend on its index (smooth, so JPEG keeps them close).
fn frame(i: u64, cal: &Arc<Calibration>) -> Frame {
    let (w, h) = (64u32, 48u32);
    let mut color = ColorImage::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let o = ((y * w + x) * 3) as usize;
            color.data[o] = (x * 4) as u8;
            color.data[o + 1] = (y * 5) as u8;
            color.data[o + 2] = (i * 7 % 256) as u8;
        }
    }
    let mut depth = DepthImage::new(w, h);
    for (k, v) in depth.data.iter_mut().enumerate() {
        *v = if k.is_multiple_of(17) {
            0
        } else {
            500 + (k as u64 * 13 + i * 101) as u16 % 1000
        };
    }
    Frame {
        seq: i,
        device_ts_us: i * 33_333,
        host_rx: Instant::now(),
        wall_clock: None,
        color,
        depth,
        calibration: cal.clone(),
    }
}

fn ground_truth(i: u64) -> GroundTruth {
    GroundTruth {
        t: i as f64 / 30.0,
        points: [
            ("D1".to_string(), [0.025, 0.01 * i as f64, 0.6]),
            ("F1".to_string(), [0.0, -0.08, 0.62]),
        ]
        .into(),
        visible: [
            ("D1".to_string(), i.is_multiple_of(2)),
            ("F1".to_string(), true),
        ]
        .into(),
        head: HeadPose::IDENTITY,
        mouth: None,
    }
}

fn write_session(path: &std::path::Path, frames: u64, options: WriterOptions) {
    let cal = calibration();
    let mut w = SessionWriter::create(path, options).unwrap();
    for i in 0..frames {
        let log_time = w
            .write_frame_with_ground_truth(&frame(i, &cal), Some(&ground_truth(i)))
            .unwrap();
        w.write_json("/derived/test", log_time, &serde_json::json!({"i": i}))
            .unwrap();
    }
    let summary = w.finish().unwrap();
    assert_eq!(summary.frames, frames);
}

#[test]
fn raw_colour_round_trips_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.mcap");
    write_session(
        &path,
        10,
        WriterOptions {
            color: ColorEncoding::Raw,
            ..Default::default()
        },
    );
    let cal = calibration();
    let frames: Vec<_> = SessionReader::open(&path)
        .unwrap()
        .collect::<Result<_, _>>()
        .unwrap();
    assert_eq!(frames.len(), 10);
    for (i, f) in frames.iter().enumerate() {
        let expected = frame(i as u64, &cal);
        assert_eq!(f.frame.seq, i as u64);
        assert_eq!(f.frame.device_ts_us, expected.device_ts_us);
        assert_eq!(f.frame.color, expected.color);
        assert_eq!(f.frame.depth, expected.depth);
        assert_eq!(*f.frame.calibration, *cal);
        assert_eq!(f.ground_truth.as_ref(), Some(&ground_truth(i as u64)));
        assert_eq!(f.log_time, expected.device_ts_us * 1000);
    }
}

#[test]
fn jpeg_colour_is_close_and_depth_exact() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.mcap");
    write_session(&path, 5, WriterOptions::default());
    let cal = calibration();
    for f in SessionReader::open(&path).unwrap() {
        let f = f.unwrap();
        let expected = frame(f.frame.seq, &cal);
        assert_eq!(f.frame.depth, expected.depth);
        let max_err = f
            .frame
            .color
            .data
            .iter()
            .zip(&expected.color.data)
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap();
        assert!(max_err <= 12, "JPEG error {max_err}");
    }
}

#[test]
fn json_channels_and_metadata_are_readable() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.mcap");
    write_session(&path, 3, WriterOptions::default());
    let mut reader = MessageReader::open(&path).unwrap();
    let mut derived = Vec::new();
    while let Some(m) = reader.next_message().unwrap() {
        if &*m.topic == "/derived/test" {
            assert_eq!(&*m.message_encoding, "json");
            derived.push(
                serde_json::from_slice::<serde_json::Value>(&m.data).unwrap()["i"]
                    .as_u64()
                    .unwrap(),
            );
        }
    }
    assert_eq!(derived, vec![0, 1, 2]);
    let names: Vec<_> = reader.metadata().iter().map(|(n, _)| n.as_str()).collect();
    assert!(
        names.contains(&"mouthpiece.session") && names.contains(&"mouthpiece.calibration"),
        "{names:?}"
    );
}

#[test]
fn looping_keeps_timestamps_increasing() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.mcap");
    write_session(&path, 4, WriterOptions::default());
    let mut reader = SessionReader::open(&path).unwrap();
    reader.set_looping(true);
    let mut last = None;
    for k in 0..10u64 {
        let f = reader.next_frame().unwrap().unwrap();
        assert_eq!(f.frame.seq, k);
        if let Some(prev) = last {
            assert!(
                f.frame.device_ts_us > prev,
                "{} after {prev}",
                f.frame.device_ts_us
            );
        }
        last = Some(f.frame.device_ts_us);
    }
    // 4 frames 33.333 ms apart: frame 4 (the first of pass 2) is 133.332 ms in.
    assert_eq!(last, Some(9 * 33_333));
}

#[test]
fn seek_reads_forward_to_a_time_and_back() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.mcap");
    write_session(&path, 30, WriterOptions::default());
    let mut reader = SessionReader::open(&path).unwrap();
    reader.seek(Duration::from_millis(490)).unwrap();
    let f = reader.next_frame().unwrap().unwrap();
    assert_eq!(f.frame.device_ts_us, 15 * 33_333);
    reader.seek(Duration::from_micros(3 * 33_333)).unwrap();
    let f = reader.next_frame().unwrap().unwrap();
    assert_eq!(f.frame.device_ts_us, 3 * 33_333);
    assert_eq!(f.ground_truth.unwrap().t, 3.0 / 30.0);
}

#[test]
fn truncated_files_replay_up_to_the_last_complete_chunk() {
    let dir = tempfile::tempdir().unwrap();
    let full = dir.path().join("full.mcap");
    // Small chunks so that a cut lands between many of them.
    let options = WriterOptions {
        chunk_size: 20_000,
        ..Default::default()
    };
    write_session(&full, 40, options);
    let bytes = std::fs::read(&full).unwrap();
    let all: Vec<_> = SessionReader::open(&full)
        .unwrap()
        .collect::<Result<_, _>>()
        .unwrap();
    assert_eq!(all.len(), 40);

    let cut_path = dir.path().join("cut.mcap");
    let mut previous = 0;
    let mut offsets: Vec<usize> = (0..bytes.len()).step_by(997).collect();
    offsets.extend([
        0,
        1,
        7,
        8,
        9,
        100,
        bytes.len() - 1,
        bytes.len() - 9,
        bytes.len() - 30,
    ]);
    offsets.sort_unstable();
    for cut in offsets {
        std::fs::write(&cut_path, &bytes[..cut]).unwrap();
        let mut reader = SessionReader::open(&cut_path).unwrap();
        let mut got = 0;
        while let Some(f) = reader
            .next_frame()
            .unwrap_or_else(|e| panic!("cut at {cut}: {e}"))
        {
            assert_eq!(f.frame.depth, all[got].frame.depth, "cut at {cut}");
            got += 1;
        }
        assert!(
            got >= previous,
            "cut at {cut}: {got} frames, fewer than a shorter cut ({previous})"
        );
        previous = got;
        if cut < bytes.len() {
            // Near the end only the summary is lost; every frame is still there.
            assert!(reader.is_truncated(), "cut at {cut} not reported");
        }
    }
    assert_eq!(
        previous, 40,
        "a file missing only its last byte still has every frame"
    );
}

#[test]
fn garbage_is_an_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("g.mcap");
    std::fs::write(
        &path,
        b"this is not an mcap file at all, but it is long enough",
    )
    .unwrap();
    let mut reader = SessionReader::open(&path).unwrap();
    assert!(reader.next_frame().is_err());
    assert!(SessionReader::open(dir.path().join("missing.mcap")).is_err());
}

#[test]
fn the_committed_demo_session_replays() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../recordings/demo.mcap");
    let mut depth_messages = 0;
    for m in MessageReader::open(&path).unwrap() {
        if &*m.unwrap().topic == mouthpiece_recording::TOPIC_DEPTH {
            depth_messages += 1;
        }
    }
    assert_eq!(depth_messages, 600, "20 s at 30 fps");
    let mut reader = SessionReader::open(&path).unwrap();
    for k in 0..5 {
        let f = reader.next_frame().unwrap().unwrap();
        assert_eq!((f.frame.color.width, f.frame.depth.height), (640, 480));
        assert_eq!(f.frame.calibration.color.fx, 525.0);
        let gt = f.ground_truth.expect("synthetic session with ground truth");
        assert_eq!(gt.points.len(), 15);
        assert!((gt.t - k as f64 / 30.0).abs() < 1e-9);
    }
    assert!(!reader.is_truncated());
}
