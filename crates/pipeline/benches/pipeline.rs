//! Detect + track + retarget per frame, on the synthetic performer's frames (kinect noise,
//! mild head motion), at 640x480 and 1280x720, OpenCV on one thread.
//!
//! `cargo bench -p mouthpiece-pipeline --bench pipeline`. Besides criterion's report, prints the
//! median and 99th percentile of single-frame times over the rendered session. Each size is
//! measured twice: with the frame just written by a source thread, as the daemon hands it
//! over, and with a frame long out of every cache (see [`Delivery`]).

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion};
use mouthpiece_frame::Frame;
use mouthpiece_pipeline::{Pipeline, PipelineConfig};
use mouthpiece_retarget::{Character, CharacterSettings, ShapeSmoothing};
use mouthpiece_synth::{Synth, SynthConfig};

const WOLF: &str = include_str!("../../../config/characters/wolf.toml");

fn frames(width: u32, height: u32, seconds: f64) -> Vec<Frame> {
    let config = SynthConfig {
        seed: 7,
        seconds,
        camera: SynthConfig::camera_for_size(width, height),
        ..SynthConfig::default()
    };
    let mut synth = Synth::new(config).expect("synth");
    std::iter::from_fn(|| synth.render_next().map(|(f, _)| f)).collect()
}

fn pipeline() -> Pipeline {
    let character = Character::from_toml_str(WOLF).expect("wolf");
    let settings = CharacterSettings {
        smoothing: ShapeSmoothing::BSpline {
            samples_per_span: 8,
        },
        one_euro: None,
    };
    Pipeline::new(PipelineConfig::default(), character, settings).expect("pipeline")
}

/// Cycles through the frames forever, shifting timestamps so that time keeps increasing.
struct Cycle {
    frames: Vec<Frame>,
    next: usize,
    offset_us: u64,
    span_us: u64,
}

impl Cycle {
    fn new(frames: Vec<Frame>) -> Self {
        let span_us = frames.last().unwrap().device_ts_us + 33_333;
        Self {
            frames,
            next: 0,
            offset_us: 0,
            span_us,
        }
    }
    fn next(&mut self) -> &Frame {
        if self.next == self.frames.len() {
            self.next = 0;
            self.offset_us += self.span_us;
            for f in &mut self.frames {
                f.device_ts_us += self.span_us;
            }
        }
        self.next += 1;
        &self.frames[self.next - 1]
    }
}

/// Where the frame's bytes are when processing starts.
#[derive(Clone, Copy, PartialEq)]
enum Delivery {
    /// Just written by the source thread (decoded, converted or copied out of the driver's
    /// buffer into the frame, then handed over through the latest-frame slot), so in the
    /// shared cache: the daemon's case. The copy is outside the timed part.
    JustWritten,
    /// Read back from a session longer than every cache (180 frames cycled): no capture path
    /// hands over a frame like this; the worst case, and what this bench measured first.
    NotInCache,
}

fn bench_size(c: &mut Criterion, width: u32, height: u32, delivery: Delivery) {
    let mut cycle = Cycle::new(frames(width, height, 6.0));
    let mut p = pipeline();
    // Warm up past the neutral calibration.
    for _ in 0..60 {
        let f = cycle.next().clone();
        p.process(&f).expect("process");
    }
    // The frame a source thread writes into (one buffer, reused, as a source reuses its own).
    let mut written = cycle.frames[0].clone();
    let mut one_frame = |cycle: &mut Cycle, p: &mut Pipeline| -> Duration {
        let frame = cycle.next();
        let frame = match delivery {
            Delivery::JustWritten => {
                written.color.data.copy_from_slice(&frame.color.data);
                written.depth.data.copy_from_slice(&frame.depth.data);
                written.seq = frame.seq;
                written.device_ts_us = frame.device_ts_us;
                &written
            }
            Delivery::NotInCache => frame,
        };
        let start = Instant::now();
        black_box(p.process(frame).expect("process").0.frame);
        start.elapsed()
    };
    let label = match delivery {
        Delivery::JustWritten => "",
        Delivery::NotInCache => ", frame not in cache",
    };
    c.bench_function(
        &format!("detect+track+retarget {width}x{height}{label}"),
        |b| {
            b.iter_custom(|iters| {
                (0..iters)
                    .map(|_| one_frame(&mut cycle, &mut p))
                    .sum::<Duration>()
            })
        },
    );
    // Percentiles over two passes of the session.
    let mut times: Vec<f64> = (0..2 * cycle.frames.len())
        .map(|_| one_frame(&mut cycle, &mut p).as_secs_f64() * 1e3)
        .collect();
    times.sort_by(f64::total_cmp);
    let pct = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize];
    println!(
        "{width}x{height}{label}: per frame median {:.3} ms, p99 {:.3} ms, max {:.3} ms over {} frames",
        pct(0.5),
        pct(0.99),
        pct(1.0),
        times.len()
    );
}

fn benches(c: &mut Criterion) {
    mouthpiece_detect::set_opencv_threads(1).expect("opencv threads");
    for delivery in [Delivery::JustWritten, Delivery::NotInCache] {
        bench_size(c, 640, 480, delivery);
        bench_size(c, 1280, 720, delivery);
    }
}

criterion_group!(pipeline_benches, benches);
criterion_main!(pipeline_benches);
