//! Writes a few frames as PPM (colour) and PGM (depth) images for a quick look:
//! `cargo run -p mouthpiece-synth --example preview -- OUT_DIR [head-motion] [t1 t2 …]`.

use mouthpiece_synth::{HeadMotion, NoiseModel, Synth, SynthConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let out = std::path::PathBuf::from(args.next().unwrap_or_else(|| "preview".into()));
    let motion = match args.next().as_deref() {
        Some("none") => HeadMotion::None,
        Some("strong") => HeadMotion::Strong,
        _ => HeadMotion::Mild,
    };
    let times: Vec<f64> = args.map(|a| a.parse()).collect::<Result<_, _>>()?;
    let times = if times.is_empty() {
        vec![0.0, 2.5, 4.0]
    } else {
        times
    };
    std::fs::create_dir_all(&out)?;
    let config = SynthConfig {
        seconds: times.iter().cloned().fold(0.0, f64::max) + 0.1,
        head_motion: motion,
        seed: std::env::var("SEED")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(1),
        noise: NoiseModel::Kinect,
        ..SynthConfig::default()
    };
    let fps = config.fps;
    for (frame, gt) in Synth::new(config)? {
        let t = frame.seq as f64 / fps;
        if !times.iter().any(|&x| (x - t).abs() < 0.5 / fps) {
            continue;
        }
        let (w, h) = (frame.color.width, frame.color.height);
        let mut ppm = format!("P6\n{w} {h}\n255\n").into_bytes();
        ppm.extend(
            frame
                .color
                .data
                .chunks_exact(3)
                .flat_map(|p| [p[2], p[1], p[0]]),
        );
        std::fs::write(out.join(format!("color_{t:.2}.ppm")), ppm)?;
        let mut pgm = format!("P5\n{w} {h}\n255\n").into_bytes();
        pgm.extend(frame.depth.data.iter().map(|&d| {
            if d == 0 {
                0
            } else {
                (255.0 - (d as f64 - 450.0) * 0.8).clamp(0.0, 255.0) as u8
            }
        }));
        std::fs::write(out.join(format!("depth_{t:.2}.pgm")), pgm)?;
        println!(
            "t={t:.2} visible: {:?}",
            gt.visible
                .iter()
                .filter(|(_, v)| **v)
                .map(|(k, _)| k.as_str())
                .collect::<Vec<_>>()
        );
    }
    Ok(())
}
