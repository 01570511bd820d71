//! Crafted files: absurd record lengths, images whose header claims gigapixels, images
//! that disagree with the calibration. Each is an error naming what was wrong, never an
//! abort or an allocation of the claimed size.

use std::collections::BTreeMap;
use std::io::Write;

use mouthpiece_recording::cdr::{self, CameraCalibration, CompressedImage, RawImage, Time};
use mouthpiece_recording::{
    MessageReader, SessionReader, TOPIC_CALIBRATION, TOPIC_COLOR, TOPIC_DEPTH,
};

const MAGIC: &[u8] = b"\x89MCAP0\r\n";

#[test]
fn a_record_claiming_a_terabyte_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    for opcode in [0x01u8, 0x06, 0x05] {
        let path = dir.path().join(format!("huge-{opcode}.mcap"));
        let mut bytes = MAGIC.to_vec();
        bytes.push(opcode);
        bytes.extend_from_slice(&(1u64 << 40).to_le_bytes());
        bytes.extend_from_slice(&[0u8; 64]);
        std::fs::write(&path, &bytes).unwrap();
        let mut reader = MessageReader::open(&path).unwrap();
        let result: Result<Vec<_>, _> = (&mut reader).collect();
        assert!(
            result.is_err() || reader.is_truncated(),
            "opcode {opcode}: {result:?}"
        );
    }
    // A chunk whose own length is honest (the file holds it) but whose header says it
    // decompresses to a terabyte: refused by the record limit, not allocated.
    let path = dir.path().join("huge-chunk.mcap");
    let mut body = Vec::new();
    body.extend_from_slice(&0u64.to_le_bytes()); // message start time
    body.extend_from_slice(&0u64.to_le_bytes()); // message end time
    body.extend_from_slice(&(1u64 << 40).to_le_bytes()); // uncompressed size
    body.extend_from_slice(&1u32.to_le_bytes()); // uncompressed CRC
    body.extend_from_slice(&4u32.to_le_bytes());
    body.extend_from_slice(b"zstd");
    body.extend_from_slice(&16u64.to_le_bytes());
    body.extend_from_slice(&[0x28, 0xb5, 0x2f, 0xfd, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
    let mut bytes = MAGIC.to_vec();
    bytes.push(0x06);
    bytes.extend_from_slice(&(body.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&body);
    std::fs::write(&path, &bytes).unwrap();
    let mut reader = MessageReader::open(&path).unwrap();
    let result: Result<Vec<_>, _> = (&mut reader).collect();
    let err = result.expect_err("a chunk claiming a terabyte is an error");
    let mut text = err.to_string();
    let mut source = std::error::Error::source(&err);
    while let Some(s) = source {
        text.push_str(&format!(": {s}"));
        source = s.source();
    }
    assert!(text.contains("exceeds limit"), "{text}");
}

/// A session with one calibration (64x48) and one colour + depth pair.
fn session(path: &std::path::Path, color: (&str, Vec<u8>), depth: RawImage) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = mcap::WriteOptions::new().profile("").create(file).unwrap();
    let channel = |w: &mut mcap::Writer<_>, topic: &str, schema: &str| {
        let s = w.add_schema(schema, "ros2msg", b"").unwrap();
        w.add_channel(s, topic, "cdr", &BTreeMap::new()).unwrap()
    };
    let cal = channel(
        &mut w,
        TOPIC_CALIBRATION,
        "foxglove_msgs/msg/CameraCalibration",
    );
    let col = channel(&mut w, TOPIC_COLOR, color.0);
    let dep = channel(&mut w, TOPIC_DEPTH, "foxglove_msgs/msg/RawImage");
    let calibration = CameraCalibration {
        timestamp: Time::from_micros(0),
        frame_id: "camera".into(),
        width: 64,
        height: 48,
        distortion_model: "plumb_bob".into(),
        d: vec![0.0; 5],
        k: [60.0, 0.0, 32.0, 0.0, 60.0, 24.0, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [0.0; 12],
    };
    let header = |channel_id, sequence| mcap::records::MessageHeader {
        channel_id,
        sequence,
        log_time: 1000,
        publish_time: 1000,
    };
    w.write_to_known_channel(&header(cal, 0), &calibration.encode())
        .unwrap();
    w.write_to_known_channel(&header(col, 1), &color.1).unwrap();
    w.write_to_known_channel(&header(dep, 2), &depth.encode())
        .unwrap();
    w.finish().unwrap();
    std::io::stdout().flush().unwrap();
}

fn depth(width: u32, height: u32) -> RawImage {
    RawImage {
        timestamp: Time::from_micros(0),
        frame_id: "depth".into(),
        width,
        height,
        encoding: "16UC1".into(),
        step: width * 2,
        data: vec![0; (width * height * 2) as usize],
    }
}

fn raw_colour(width: u32, height: u32) -> Vec<u8> {
    RawImage {
        timestamp: Time::from_micros(0),
        frame_id: "color".into(),
        width,
        height,
        encoding: "bgr8".into(),
        step: width * 3,
        data: vec![0; (width * height * 3) as usize],
    }
    .encode()
}

fn first_error(path: &std::path::Path) -> String {
    let mut reader = SessionReader::open(path).unwrap();
    match reader.next_frame() {
        Ok(f) => panic!(
            "{} read a frame: {:?}",
            path.display(),
            f.map(|f| f.log_time)
        ),
        Err(e) => {
            let mut text = e.to_string();
            let mut source = std::error::Error::source(&e);
            while let Some(s) = source {
                text.push_str(&format!(": {s}"));
                source = s.source();
            }
            text
        }
    }
}

/// A baseline JPEG whose SOF0 header claims `width` x `height`, with no scan data.
fn jpeg_header(width: u16, height: u16) -> Vec<u8> {
    let mut j = vec![0xFF, 0xD8];
    // Quantisation table 0, all ones.
    j.extend_from_slice(&[0xFF, 0xDB, 0x00, 0x43, 0x00]);
    j.extend(std::iter::repeat_n(1u8, 64));
    // SOF0: 8 bits, height, width, 3 components 1x1 sampled, table 0.
    j.extend_from_slice(&[0xFF, 0xC0, 0x00, 0x11, 0x08]);
    j.extend_from_slice(&height.to_be_bytes());
    j.extend_from_slice(&width.to_be_bytes());
    j.extend_from_slice(&[0x03, 0x01, 0x11, 0x00, 0x02, 0x11, 0x00, 0x03, 0x11, 0x00]);
    j.extend_from_slice(&[0xFF, 0xD9]);
    j
}

#[test]
fn a_jpeg_claiming_gigapixels_is_refused_before_decoding() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("giga.mcap");
    let jpeg = CompressedImage {
        timestamp: Time::from_micros(0),
        frame_id: "color".into(),
        data: jpeg_header(65535, 65535),
        format: "jpeg".into(),
    };
    session(
        &path,
        ("foxglove_msgs/msg/CompressedImage", jpeg.encode()),
        depth(64, 48),
    );
    let err = first_error(&path);
    assert!(err.contains("65535x65535"), "{err}");
}

#[test]
fn a_raw_image_claiming_gigapixels_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("raw.mcap");
    let mut big = depth(64, 48);
    big.width = 100_000;
    big.height = 100_000;
    big.step = 200_000;
    session(
        &path,
        ("foxglove_msgs/msg/RawImage", raw_colour(64, 48)),
        big,
    );
    let err = first_error(&path);
    assert!(err.contains("100000x100000"), "{err}");
    // An image just over the cap whose pixels are all there (the claim above is also caught
    // by its missing bytes): refused for its size before it is decoded.
    let path = dir.path().join("raw-over-cap.mcap");
    session(
        &path,
        ("foxglove_msgs/msg/RawImage", raw_colour(64, 48)),
        depth(4100, 4100),
    );
    let err = first_error(&path);
    assert!(
        err.contains("4100x4100") && err.contains("larger than"),
        "{err}"
    );
}

#[test]
fn images_that_disagree_with_the_calibration_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("size.mcap");
    session(
        &path,
        ("foxglove_msgs/msg/RawImage", raw_colour(32, 24)),
        depth(64, 48),
    );
    let err = first_error(&path);
    assert!(err.contains("32x24") && err.contains("64x48"), "{err}");
    let path = dir.path().join("depth.mcap");
    session(
        &path,
        ("foxglove_msgs/msg/RawImage", raw_colour(64, 48)),
        depth(64, 40),
    );
    let err = first_error(&path);
    assert!(err.contains("depth image is 64x40"), "{err}");
    let _ = cdr::raw_image_schema();
}
