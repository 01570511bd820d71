use super::*;
use crate::read::TOPIC_POINTS;
use mouthpiece_recording::{SessionWriter, WriterOptions};
use mouthpiece_synth::{Synth, SynthConfig};
use std::path::PathBuf;

/// A foxglove.RawAudio message in CDR, as `foxglove_msgs/msg/RawAudio` lays it out.
fn raw_audio_cdr(samples: &[i16], rate: u32, channels: u32) -> Vec<u8> {
    let mut b = vec![0u8, 1, 0, 0];
    let mut body: Vec<u8> = Vec::new();
    let align = |body: &mut Vec<u8>| body.resize(body.len().div_ceil(4) * 4, 0);
    body.extend_from_slice(&12i32.to_le_bytes());
    body.extend_from_slice(&5u32.to_le_bytes());
    let pcm: Vec<u8> = samples.iter().flat_map(|s| s.to_le_bytes()).collect();
    body.extend_from_slice(&(pcm.len() as u32).to_le_bytes());
    body.extend_from_slice(&pcm);
    align(&mut body);
    body.extend_from_slice(&8u32.to_le_bytes());
    body.extend_from_slice(b"pcm-s16\0");
    align(&mut body);
    body.extend_from_slice(&rate.to_le_bytes());
    body.extend_from_slice(&channels.to_le_bytes());
    b.extend_from_slice(&body);
    b
}

fn raw_audio_json(samples: &[i16], rate: u32) -> serde_json::Value {
    use base64::Engine as _;
    let pcm: Vec<u8> = samples.iter().flat_map(|s| s.to_le_bytes()).collect();
    serde_json::json!({
        "timestamp": {"sec": 0, "nsec": 0},
        "data": base64::engine::general_purpose::STANDARD.encode(pcm),
        "format": "pcm-s16",
        "sample_rate": rate,
        "number_of_channels": 1,
    })
}

#[test]
fn raw_audio_decodes_from_cdr_and_json() {
    let samples = [1i16, -2, 300, -32768, 32767];
    let a = decode_raw_audio("cdr", &raw_audio_cdr(&samples, 48000, 1)).unwrap();
    assert_eq!(
        (a.format.as_str(), a.sample_rate, a.channels),
        ("pcm-s16", 48000, 1)
    );
    assert_eq!(a.data.len(), 10);
    assert_eq!(i16::from_le_bytes([a.data[6], a.data[7]]), -32768);
    let j = serde_json::to_vec(&raw_audio_json(&samples, 44100)).unwrap();
    let b = decode_raw_audio("json", &j).unwrap();
    assert_eq!((b.sample_rate, b.data), (44100, a.data));
    let mut cut = raw_audio_cdr(&samples, 48000, 1);
    cut.truncate(20);
    assert!(decode_raw_audio("cdr", &cut).is_err());
    assert!(decode_raw_audio("protobuf", &j).is_err());
}

/// A 2-second take: synthetic frames (JPEG colour), a dot on the optical axis, and 20 ms
/// blocks of sound (`foxglove.RawAudio` in CDR, as takes write it) whose samples say which
/// block they are, from 0.1 s on.
fn write_take(dir: &Path, name: &str) -> (PathBuf, Intrinsics) {
    let path = dir.join(name);
    let mut writer = SessionWriter::create(&path, WriterOptions::default()).unwrap();
    let synth = Synth::new(SynthConfig {
        seed: 2,
        seconds: 2.0,
        camera: SynthConfig::camera_for_size(160, 120),
        ..SynthConfig::default()
    })
    .unwrap();
    let mut k = None;
    let mut first = None;
    let mut block = 0i16;
    for (frame, _) in synth {
        k.get_or_insert(frame.calibration.color);
        let log_time = writer.write_frame(&frame).unwrap();
        let first = *first.get_or_insert(log_time);
        writer
            .write_json(
                TOPIC_POINTS,
                log_time,
                &serde_json::json!({"seq": frame.seq, "points": {"D1": [0.0, 0.0, 0.6], "D2": null}}),
            )
            .unwrap();
        // Sound blocks up to this frame's time.
        while 100_000_000 + u64::from(block as u16) * 20_000_000 <= log_time - first {
            let at = first + 100_000_000 + u64::from(block as u16) * 20_000_000;
            let format = mouthpiece_frame::AudioFormat {
                sample_rate: 48000,
                channels: 1,
            };
            writer.write_audio(at, format, &[block; 960]).unwrap();
            block += 1;
        }
    }
    writer.finish().unwrap();
    (path, k.unwrap())
}

#[test]
fn a_chunk_holds_the_images_the_dots_and_the_sound_in_its_window() {
    let dir = tempfile::tempdir().unwrap();
    let (path, k) = write_take(dir.path(), "scene_T001_20260101T000000Z.mcap");
    let chunk = read_chunk(&path, 0.5, 1.0, MAX_CHUNK_BYTES).unwrap();
    assert!(!chunk.end);
    assert_eq!((chunk.width, chunk.height), (160, 120));
    assert_eq!(chunk.next_s, 1.5);
    let n = chunk.frames.len();
    assert!((29..=31).contains(&n), "{n} frames in one second");
    assert!(chunk.frames.iter().all(|f| (0.5..1.5).contains(&f.t)));
    assert!(chunk
        .frames
        .iter()
        .all(|f| f.jpeg.starts_with(&[0xff, 0xd8])));
    // The seen dot, projected; the unseen one left out.
    let dots = &chunk.frames[0].dots;
    assert_eq!(dots.len(), 1, "{dots:?}");
    let [cx, cy] = k.project([0.0, 0.0, 0.6]).unwrap();
    assert!((f64::from(dots[0].x) - cx).abs() < 1e-3 && (f64::from(dots[0].y) - cy).abs() < 1e-3);
    // Sound: blocks 20..=69 (0.5 s to 1.48 s), back to back, first at 0.5 s.
    let a = chunk.audio.as_ref().unwrap();
    assert_eq!((a.sample_rate, a.channels), (48000, 1));
    assert!((a.start_s - 0.5).abs() < 1e-6, "{}", a.start_s);
    assert_eq!(a.pcm_s16le.len(), 50 * 960 * 2);
    let sample = |i: usize| i16::from_le_bytes([a.pcm_s16le[2 * i], a.pcm_s16le[2 * i + 1]]);
    assert_eq!((sample(0), sample(960), sample(49 * 960)), (20, 21, 69));
    // The last chunk ends the take.
    let last = read_chunk(&path, 1.5, 4.0, MAX_CHUNK_BYTES).unwrap();
    assert!(last.end && !last.frames.is_empty());
}

#[test]
fn a_chunk_stops_at_its_byte_cap_and_says_where_to_go_on() {
    let dir = tempfile::tempdir().unwrap();
    let (path, _) = write_take(dir.path(), "cap_T001.mcap");
    let whole = read_chunk(&path, 0.0, 2.0, MAX_CHUNK_BYTES).unwrap();
    let one = whole.frames[0].jpeg.len();
    let capped = read_chunk(&path, 0.0, 2.0, one * 5 + one / 2).unwrap();
    assert!(capped.frames.len() < whole.frames.len() && !capped.end);
    assert!(capped.next_s > capped.frames.last().unwrap().t);
    assert!(capped.next_s < 2.0);
}

/// A take from a booth without a camera: no pictures, its steps keep the time and its sound
/// plays.
#[test]
fn a_take_without_a_camera_plays_its_sound_on_its_steps_clock() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nocam_T001_20260101T000000Z.mcap");
    let mut writer = SessionWriter::create(&path, WriterOptions::default()).unwrap();
    let first = 1_795_316_645_000_000_000u64;
    let format = mouthpiece_frame::AudioFormat {
        sample_rate: 48000,
        channels: 1,
    };
    // Two seconds: a step every 20 ms, a block of 20 ms of sound with each.
    for i in 0..100u64 {
        let at = first + i * 20_000_000;
        writer
            .write_json(
                "/character/human",
                at,
                &serde_json::json!({"seq": i, "points": {"P1": [0.0, 0.0, 0.0]}, "source": "speech"}),
            )
            .unwrap();
        writer.write_audio(at, format, &[i as i16; 960]).unwrap();
    }
    writer.finish().unwrap();
    let chunk = read_chunk(&path, 0.5, 1.0, MAX_CHUNK_BYTES).unwrap();
    assert!(chunk.frames.is_empty());
    assert!(!chunk.end, "the take goes on past the chunk");
    assert!(
        chunk.notes.iter().any(|n| n.contains("no camera")),
        "{:?}",
        chunk.notes
    );
    let a = chunk.audio.as_ref().expect("the sound plays");
    assert!((a.start_s - 0.5).abs() < 1e-6, "{}", a.start_s);
    assert_eq!(a.pcm_s16le.len(), 50 * 960 * 2);
    assert_eq!(i16::from_le_bytes([a.pcm_s16le[0], a.pcm_s16le[1]]), 25);
    let last = read_chunk(&path, 1.5, 4.0, MAX_CHUNK_BYTES).unwrap();
    assert!(last.end);
}
