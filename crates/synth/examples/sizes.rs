//! Measures session size per minute (640x480, 30 fps, kinect noise, mild motion) for chunk
//! compressions and colour encodings, and what the RVL depth codec would give:
//! `cargo run --release -p mouthpiece-synth --example sizes -- SECONDS`.

use mouthpiece_recording::{ColorEncoding, SessionWriter, WriterOptions};
use mouthpiece_synth::{Synth, SynthConfig};

/// RVL (Wilson 2017): run lengths of zeros and non-zeros, then zig-zag deltas, in 4-bit
/// variable-length nibbles. Returns the encoded size in bytes.
fn rvl_size(depth: &[u16]) -> usize {
    let mut nibbles = 0usize;
    let mut vle = |mut v: u32| loop {
        nibbles += 1;
        v >>= 3;
        if v == 0 {
            break;
        }
    };
    let (mut i, mut prev) = (0usize, 0i32);
    while i < depth.len() {
        let zeros = depth[i..].iter().take_while(|&&d| d == 0).count();
        i += zeros;
        let nonzeros = depth[i..].iter().take_while(|&&d| d != 0).count();
        vle(zeros as u32);
        vle(nonzeros as u32);
        for &d in &depth[i..i + nonzeros] {
            let delta = d as i32 - prev;
            vle(((delta << 1) ^ (delta >> 31)) as u32);
            prev = d as i32;
        }
        i += nonzeros;
    }
    nibbles.div_ceil(2)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let seconds: f64 = std::env::args()
        .nth(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(10.0);
    let config = SynthConfig {
        seed: 1,
        seconds,
        ..SynthConfig::default()
    };
    let frames: Vec<_> = Synth::new(config)?.collect();
    let dir = tempfile::tempdir()?;
    let per_minute = |bytes: u64| bytes as f64 * 60.0 / seconds / 1e6;
    let variants: Vec<(&str, WriterOptions)> = vec![
        ("zstd-3, jpeg q90", WriterOptions::default()),
        (
            "zstd-3, jpeg q75",
            WriterOptions {
                color: ColorEncoding::Jpeg { quality: 75 },
                ..Default::default()
            },
        ),
        (
            "zstd-9, jpeg q90",
            WriterOptions {
                zstd_level: 9,
                ..Default::default()
            },
        ),
        (
            "lz4, jpeg q90",
            WriterOptions {
                compression: Some(mcap::Compression::Lz4),
                ..Default::default()
            },
        ),
        (
            "none, jpeg q90",
            WriterOptions {
                compression: None,
                ..Default::default()
            },
        ),
        (
            "zstd-3, raw bgr8",
            WriterOptions {
                color: ColorEncoding::Raw,
                ..Default::default()
            },
        ),
    ];
    println!(
        "{} frames, {seconds} s, 640x480 @ 30 fps, kinect noise, mild head motion",
        frames.len()
    );
    for (name, options) in variants {
        let path = dir.path().join("s.mcap");
        let started = std::time::Instant::now();
        let mut w = SessionWriter::create(&path, options)?;
        for (f, gt) in &frames {
            w.write_frame_with_ground_truth(f, Some(gt))?;
        }
        w.finish()?;
        let bytes = std::fs::metadata(&path)?.len();
        println!(
            "{name:20} {:8.1} MB/min  ({:.1} KB/frame, write {:.1} ms/frame)",
            per_minute(bytes),
            bytes as f64 / frames.len() as f64 / 1e3,
            started.elapsed().as_secs_f64() * 1e3 / frames.len() as f64
        );
    }
    let rvl: usize = frames.iter().map(|(f, _)| rvl_size(&f.depth.data)).sum();
    println!(
        "depth alone, RVL:    {:8.1} MB/min  ({:.1} KB/frame)",
        per_minute(rvl as u64),
        rvl as f64 / frames.len() as f64 / 1e3
    );
    Ok(())
}
