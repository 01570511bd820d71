//! Allocations on the processing thread's per-frame path (detect + track + retarget into the
//! reused `Output`), counted with a counting global allocator after a warm-up. Only Rust-side
//! heap allocations are seen: OpenCV's own (C++) allocations are not counted here.
//!
//! The path is not allocation-free yet: the tracker builds small per-frame vectors (candidates,
//! assignment matrices, missing-dot names), measured at about 90 allocations a frame. What this
//! test holds is that the count stays flat over a session (nothing accumulates).

use mouthpiece_daemon::live::LiveProcessor;
use mouthpiece_daemon::pipeline::{Output, Processor};
use mouthpiece_synth::{Synth, SynthConfig};

#[path = "../../retarget/tests/counting_alloc/mod.rs"]
mod counting_alloc;

#[global_allocator]
static GLOBAL: counting_alloc::Counting = counting_alloc::Counting;

#[test]
fn allocations_per_frame_stay_flat_over_a_session() {
    let config = mouthpiece_config::Config::embedded();
    let mut processor =
        LiveProcessor::new(mouthpiece_daemon::live::setup(&config).unwrap()).unwrap();
    let frames: Vec<_> = Synth::new(SynthConfig {
        seed: 2,
        seconds: 4.0,
        ..SynthConfig::default()
    })
    .unwrap()
    .map(|(f, _)| f)
    .collect();
    let mut out = Output::default();
    let (warm, measured) = frames.split_at(60);
    for f in warm {
        processor.process(f, &mut out);
    }
    let (first, second) = measured.split_at(measured.len() / 2);
    let mut count = |frames: &[mouthpiece_frame::Frame]| {
        let before = counting_alloc::allocations();
        for f in frames {
            processor.process(f, &mut out);
        }
        (counting_alloc::allocations() - before) as f64 / frames.len() as f64
    };
    let (a, b) = (count(first), count(second));
    println!("allocations per frame: {a:.1} in the first half, {b:.1} in the second");
    assert!(
        b <= a * 1.5 + 5.0,
        "allocations grow: {a:.1} then {b:.1} per frame"
    );
}
