//! Frames per second of the renderer alone: `cargo run --release -p mouthpiece-synth --example speed -- [kinect|none] [effects|plain]`.
use mouthpiece_synth::{NoiseModel, Synth, SynthConfig};
fn main() {
    let mut args = std::env::args().skip(1);
    let noise = if args.next().as_deref() == Some("none") {
        NoiseModel::None
    } else {
        NoiseModel::Kinect
    };
    let effects = args.next().as_deref() != Some("plain");
    let mut s = Synth::new(SynthConfig {
        seconds: 1e6,
        noise,
        colour_effects: effects,
        ..Default::default()
    })
    .expect("valid");
    for _ in 0..60 {
        s.next();
    }
    let n = 150;
    let t = std::time::Instant::now();
    for _ in 0..n {
        std::hint::black_box(s.next());
    }
    let dt = t.elapsed().as_secs_f64() / n as f64;
    println!("{:.2} ms/frame, {:.1} frames/s", dt * 1e3, 1.0 / dt);
}
