//! Allocations on the processing thread's per-frame path (detect + track + retarget into the
//! reused `Output`), counted with a counting global allocator after a warm-up. Only Rust-side
//! heap allocations are seen: OpenCV's own (C++) allocations are not counted here.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use mouthpiece_daemon::live::LiveProcessor;
use mouthpiece_daemon::pipeline::{Output, Processor};
use mouthpiece_synth::{Synth, SynthConfig};

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator unchanged; only counts calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn allocations_per_frame_in_steady_state() {
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
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    for f in measured {
        processor.process(f, &mut out);
    }
    let per_frame = (ALLOCATIONS.load(Ordering::Relaxed) - before) as f64 / measured.len() as f64;
    println!("allocations per frame: {per_frame:.1}");
}
