//! A fixed amount of pipeline work for an instruction-count profile: renders the benchmark's
//! session (synthetic performer, seed 7, Kinect-like noise, mild head motion), runs the
//! frames up to the neutral pose and a little past it, then detect + track + retarget on
//! `FRAMES` more frames inside `profiled_frames`, OpenCV on one thread. Prints a checksum of
//! every output (tracked points, character points, confidences) so that a change meant to
//! leave the results alone can be checked bit for bit.
//!
//! ```sh
//! cargo build --release -p mouthpiece-pipeline --example profile_frames
//! valgrind --tool=callgrind --toggle-collect='*profiled_frames*' \
//!     --callgrind-out-file=callgrind.640 target/release/examples/profile_frames 640 480
//! callgrind_annotate --inclusive=yes callgrind.640 | head -60
//! ```
//!
//! Arguments: width height [frames, default 120]. See docs/performance.md.

use std::hint::black_box;

use mouthpiece_frame::Frame;
use mouthpiece_pipeline::{Pipeline, PipelineConfig};
use mouthpiece_retarget::{Character, CharacterSettings, ShapeSmoothing};
use mouthpiece_synth::{Synth, SynthConfig};

const WOLF: &str = include_str!("../../../config/characters/wolf.toml");

/// Frames processed before the profiled ones: past the neutral calibration (about 1 s).
const WARM_UP_FRAMES: usize = 60;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, default: usize| -> usize {
        args.get(i).map_or(default, |s| {
            s.parse().unwrap_or_else(|_| {
                eprintln!("usage: profile_frames WIDTH HEIGHT [FRAMES]; bad number {s:?}");
                std::process::exit(2)
            })
        })
    };
    let (width, height, count) = (arg(0, 640) as u32, arg(1, 480) as u32, arg(2, 120));
    mouthpiece_detect::set_opencv_threads(1).expect("opencv threads");
    let config = SynthConfig {
        seed: 7,
        seconds: (WARM_UP_FRAMES + count) as f64 / 30.0 + 0.1,
        camera: SynthConfig::camera_for_size(width, height),
        ..SynthConfig::default()
    };
    let mut synth = Synth::new(config).expect("synth");
    let frames: Vec<Frame> = std::iter::from_fn(|| synth.render_next().map(|(f, _)| f))
        .take(WARM_UP_FRAMES + count)
        .collect();
    assert_eq!(frames.len(), WARM_UP_FRAMES + count, "session too short");
    let character = Character::from_toml_str(WOLF).expect("wolf");
    let settings = CharacterSettings {
        smoothing: ShapeSmoothing::BSpline {
            samples_per_span: 8,
        },
        one_euro: None,
    };
    let mut p = Pipeline::new(PipelineConfig::default(), character, settings).expect("pipeline");
    let mut sum = Checksum::default();
    for f in &frames[..WARM_UP_FRAMES] {
        sum.add(&mut p, f);
    }
    profiled_frames(&mut p, &frames[WARM_UP_FRAMES..], &mut sum);
    println!(
        "{width}x{height}: {count} profiled frames after {WARM_UP_FRAMES}; output checksum {:016x}",
        sum.0
    );
}

/// The profiled work: one pipeline step per frame.
#[inline(never)]
fn profiled_frames(p: &mut Pipeline, frames: &[Frame], sum: &mut Checksum) {
    for f in frames {
        sum.add(p, black_box(f));
    }
}

/// FNV-1a over the bits of every output number.
#[derive(Default)]
struct Checksum(u64);

impl Checksum {
    fn add(&mut self, p: &mut Pipeline, frame: &Frame) {
        let (line, _) = p.process(frame).expect("process");
        if self.0 == 0 {
            self.0 = 0xcbf2_9ce4_8422_2325;
        }
        let mut hash = |x: u64| {
            for byte in x.to_le_bytes() {
                self.0 = (self.0 ^ byte as u64).wrapping_mul(0x0100_0000_01b3);
            }
        };
        for (_, v) in &line.performer.0 {
            v.iter().flatten().for_each(|x| hash(x.to_bits()));
            hash(v.is_some() as u64);
        }
        for (_, v) in &line.retarget.points.0 {
            v.iter().for_each(|x| hash(x.to_bits()));
        }
        for (_, c) in &line.retarget.confidence.0 {
            hash(c.to_bits());
        }
    }
}
