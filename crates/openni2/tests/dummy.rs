//! Through the real OpenNI2 library: the Dummy device, OpenNI2's recorder, the cropping fix
//! and OpenNI2's file player. One test function: OpenNI2 is process-global and these steps
//! share it; running them in sequence keeps the teardown order the notes require.

use std::time::Duration;

use openni2::{oni_file, Device, FrameReader, Overflow, ReaderEvent, Recorder, SensorType};

fn next_frame(reader: &FrameReader) -> openni2::OwnedFrame {
    match reader.recv_timeout(Duration::from_secs(5)).unwrap() {
        Some(ReaderEvent::Frame(f)) => f,
        other => panic!("expected a frame, got {other:?}"),
    }
}

#[test]
fn dummy_device_records_and_plays_back_through_openni2() {
    let dir = tempfile::tempdir().unwrap();
    let oni = dir.path().join("dummy.oni");

    // Live: the Dummy device streams 320x240 depth and RGB888.
    let device = Device::open("Dummy").unwrap();
    assert!(!device.is_file());
    let depth = device.create_stream(SensorType::Depth).unwrap();
    let color = device.create_stream(SensorType::Color).unwrap();
    let mode = depth.video_mode().unwrap();
    assert_eq!(
        (mode.width, mode.height, mode.pixel_format),
        (320, 240, openni2::PixelFormat::DEPTH_1_MM)
    );
    assert!(
        !depth.supports_cropping().unwrap(),
        "the Dummy driver gained cropping: the fix is moot"
    );
    let mut recorder = Recorder::create(&oni).unwrap();
    recorder.attach(&depth, false).unwrap();
    recorder.attach(&color, false).unwrap();
    recorder.start().unwrap();
    depth.start().unwrap();
    color.start().unwrap();
    let reader = FrameReader::start(&[&depth, &color], 64, Overflow::DropOldest).unwrap();
    let mut live = Vec::new();
    while live.len() < 40 {
        live.push(next_frame(&reader));
    }
    recorder.finish().unwrap();
    drop(reader);
    drop((depth, color));
    drop(device);
    let depth_ts: Vec<u64> = live
        .iter()
        .filter(|f| f.sensor == SensorType::Depth)
        .map(|f| f.timestamp_us)
        .collect();
    assert!(depth_ts.windows(2).all(|w| w[1] > w[0]), "{depth_ts:?}");
    for f in &live {
        assert_eq!(
            f.data.len(),
            320 * 240 * if f.sensor == SensorType::Depth { 2 } else { 3 }
        );
    }

    // As recorded, OpenNI2's player would deliver nothing; fix it.
    let fix = oni_file::add_missing_cropping(&oni, |_| (1.0, 0.75)).unwrap();
    assert_eq!(fix.cropping_added.len(), 2);

    let player = Device::open_file(&oni).unwrap();
    assert!(player.is_file());
    player.set_playback_speed(-1.0).unwrap();
    player.set_playback_repeat(false).unwrap();
    let depth = player.create_stream(SensorType::Depth).unwrap();
    let color = player.create_stream(SensorType::Color).unwrap();
    let n_depth = depth.number_of_frames().unwrap().unwrap();
    let n_color = color.number_of_frames().unwrap().unwrap();
    assert!(n_depth >= 15 && n_color >= 15, "{n_depth} {n_color}");
    depth.start().unwrap();
    color.start().unwrap();
    let reader = FrameReader::start(&[&depth, &color], 8, Overflow::Backpressure).unwrap();
    let mut played = Vec::new();
    while played.len() < (n_depth + n_color) as usize {
        played.push(next_frame(&reader));
    }
    drop(reader);
    drop((depth, color));
    drop(player);
    // Every live frame was recorded: its bytes come back, in order.
    for sensor in [SensorType::Depth, SensorType::Color] {
        let rec: Vec<&Vec<u8>> = played
            .iter()
            .filter(|f| f.sensor == sensor)
            .map(|f| &f.data)
            .collect();
        let got: Vec<&Vec<u8>> = live
            .iter()
            .filter(|f| f.sensor == sensor)
            .map(|f| &f.data)
            .collect();
        let distinct: std::collections::HashSet<_> = rec.iter().collect();
        eprintln!(
            "{sensor}: {} recorded, {} distinct, {} live",
            rec.len(),
            distinct.len(),
            got.len()
        );
        // `Recorder::start` returns once the recorder records, and the streams start after
        // it: every live frame is in the recording, the first included, in order.
        let first = got
            .iter()
            .position(|g| rec.contains(g))
            .expect("no live frame was recorded");
        assert_eq!(first, 0, "the recorder missed the first {first} frames");
        let mut it = rec.iter();
        for g in &got[first..] {
            assert!(
                it.any(|r| r == g),
                "a live {sensor} frame is missing from the recording"
            );
        }
    }
}
