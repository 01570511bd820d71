//! The processing thread's per-frame path (detect + track + retarget into the reused
//! `Output`, then the publish into the server hub's ring) makes no heap allocation in steady
//! state: counted with a counting global
//! allocator over a synthetic session after a warm-up in which the tracker's buffers grow to
//! their working size. Only Rust-side allocations are seen; OpenCV allocates on its C++ side
//! (a `Mat` header for each region-of-interest view it is asked for, and its scratch images
//! when the search region grows), which this allocator cannot count.

use mouthpiece_daemon::live::LiveProcessor;
use mouthpiece_daemon::pipeline::{Output, Processor};
use mouthpiece_synth::{Synth, SynthConfig};

#[path = "../../retarget/tests/counting_alloc/mod.rs"]
mod counting_alloc;

#[global_allocator]
static GLOBAL: counting_alloc::Counting = counting_alloc::Counting;

#[test]
fn the_per_frame_path_does_not_allocate_in_steady_state() {
    let config = mouthpiece_config::Config::embedded();
    let mut processor =
        LiveProcessor::new(mouthpiece_daemon::live::setup(&config).unwrap()).unwrap();
    let frames: Vec<_> = Synth::new(SynthConfig {
        seed: 2,
        seconds: 8.0,
        ..SynthConfig::default()
    })
    .unwrap()
    .map(|(f, _)| f)
    .collect();
    let mut out = Output::default();
    let (hub, _control) = mouthpiece_server::Hub::new(&mouthpiece_server::HubConfig::default());
    // What the processing thread does with each frame (`pipeline::run`).
    let mut step = |f: &mouthpiece_frame::Frame, out: &mut Output| {
        processor.process(f, out);
        out.stream.capture_us = f.device_ts_us;
        hub.publish(&out.stream);
    };
    // The neutral second, then tracking until every buffer has met its largest frame.
    let (warm, measured) = frames.split_at(90);
    for f in warm {
        step(f, &mut out);
    }
    assert!(
        out.stream.performer.is_some(),
        "calibrated during the warm-up"
    );
    let before = counting_alloc::allocations();
    for f in measured {
        step(f, &mut out);
    }
    let allocations = counting_alloc::allocations() - before;
    println!(
        "{allocations} allocations over {} frames in steady state",
        measured.len()
    );
    assert_eq!(allocations, 0, "the per-frame path allocated");
}
