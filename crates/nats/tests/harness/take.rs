//! A real take file, written by the takes crate, for the upload tests.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant, UNIX_EPOCH};

use mouthpiece_frame::{Calibration, ColorImage, DepthImage, Frame, Intrinsics};
use mouthpiece_takes::{CharacterRecord, Derived, TakeSettings, Takes};

const WAIT: Duration = Duration::from_secs(30);

pub fn frame(seq: u64) -> Arc<Frame> {
    let mut color = ColorImage::new(32, 24);
    color
        .data
        .iter_mut()
        .enumerate()
        .for_each(|(i, b)| *b = (i as u64 * 7 + seq) as u8);
    Arc::new(Frame {
        seq,
        device_ts_us: seq * 33_333,
        host_rx: Instant::now(),
        wall_clock: Some(UNIX_EPOCH + Duration::from_micros(1_795_316_645_000_000 + seq * 33_333)),
        color,
        depth: DepthImage::new(32, 24),
        calibration: Arc::new(Calibration::registered(Intrinsics::ideal(
            32, 24, 26.0, 26.0, 15.5, 11.5,
        ))),
    })
}

pub fn derived(seq: u64) -> Box<Derived> {
    Box::new(Derived {
        seq,
        t: seq as f64 / 30.0,
        wall_us: 1_795_316_645_000_000 + seq as i64 * 33_333,
        timecode: format!("03:04:05:{:02}", seq % 30),
        characters: vec![CharacterRecord {
            name: "wolf".into(),
            points: vec![("P1".into(), [0.07, 0.0, 0.0])],
            confidence: vec![1.0],
            ..CharacterRecord::default()
        }],
        ..Derived::default()
    })
}

/// Records a real take of `frames` frames into `folder` and waits until it is closed.
pub fn record_take(folder: &Path, slate: &str, frames: u64) -> PathBuf {
    let mut takes = Takes::new(TakeSettings {
        folder: folder.to_owned(),
        flush: Duration::from_millis(100),
        min_free_mb: 0,
        queue_frames: 256,
        timecode_rate: "30".into(),
        max_write_bytes_s: None,
    });
    let (tx, rx) = crossbeam_channel::bounded(1);
    takes.start(
        slate,
        None,
        "replay:test.mcap",
        Box::new(move |r| {
            let _ = tx.send(r);
        }),
        Box::new(|_| {}),
    );
    let info = rx.recv_timeout(WAIT).unwrap().unwrap();
    for seq in 0..frames {
        takes.push(frame(seq), derived(seq));
    }
    let (tx, rx) = crossbeam_channel::bounded(1);
    takes.stop(Box::new(move |r| {
        let _ = tx.send(r);
    }));
    let ended = rx.recv_timeout(WAIT).unwrap().unwrap();
    assert_eq!(ended.frames, frames);
    info.path
}
