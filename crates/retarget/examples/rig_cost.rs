//! The rig's per-frame cost in instructions, for a machine too busy for wall-clock timing:
//! the criterion bench's frames (`benches/support`), `Rig::step` on each of them `ROUNDS`
//! times. Run under callgrind, collecting only inside `Rig::step`:
//!
//!     cargo build --release -p mouthpiece-retarget --example rig_cost
//!     valgrind --tool=callgrind --callgrind-out-file=rig.callgrind \
//!         --toggle-collect='*Rig*step*' target/release/examples/rig_cost
//!     callgrind_annotate rig.callgrind | head -30
//!
//! Instructions per step = the `Ir` total ÷ the step count this program prints.

use std::hint::black_box;

use mouthpiece_retarget::{Rig, RigSettings};

#[path = "../benches/support/mod.rs"]
mod support;

const ROUNDS: usize = 10;

fn main() {
    let (rt, stabilised) = support::stabilised_frames();
    let mut rig = Rig::new(rt.stabiliser().neutral(), RigSettings::default()).unwrap();
    let mut steps = 0usize;
    let mut sum = 0.0;
    for _ in 0..ROUNDS {
        for frame in &stabilised {
            sum += rig.step(black_box(frame)).jaw.angle_deg;
            steps += 1;
        }
    }
    println!("{steps} steps (checksum {sum:.6})");
}
