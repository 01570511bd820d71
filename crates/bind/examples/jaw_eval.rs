//! The jaw on the held-out heads: the deformation error over all vertices and over the
//! chin's, without the jaw joint (the mouth's points and the root only) and with it (the
//! chin's root share on the jaw, the lower lip's joints riding on it), for each binder.
//!
//!     cargo run -p mouthpiece-bind --example jaw_eval
//!
//! Prints a Markdown table (RMS in % of the mouth width, the same 65 mouth states as
//! `bind evaluate`); docs/bind.md has it.

use mouthpiece_bind::jaw::jaw_errors;
use mouthpiece_bind::procedural::MouthState;
use mouthpiece_bind::training::{method_weights, random_cases, EVAL_STATES};
use rand::SeedableRng;

/// `bind evaluate`'s held-out seed.
const HELD_OUT_SEED: u64 = 1_319_952;

fn main() {
    let network = mouthpiece_bind::shipped_network().unwrap();
    let cases = random_cases("held-out ", 8, HELD_OUT_SEED);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0xe7a1);
    let states = MouthState::set(EVAL_STATES, &mut rng);
    println!("| method | RMS, no jaw | RMS, jaw | chin RMS, no jaw | chin RMS, jaw |");
    println!("|---|---:|---:|---:|---:|");
    let mut means = std::collections::BTreeMap::<&str, [f64; 4]>::new();
    for case in &cases {
        let mut all = method_weights(case, &network).to_vec();
        all.push(("reference", case.reference.clone()));
        for (name, w) in all {
            let e = jaw_errors(&case.head, &w, &states);
            let m = means.entry(name).or_default();
            for k in 0..4 {
                m[k] += e[k] / cases.len() as f64;
            }
        }
    }
    for name in ["network", "heat", "distance", "reference"] {
        let m = means[name];
        println!(
            "| {name} | {:.2} | {:.2} | {:.2} | {:.2} |",
            m[0], m[1], m[2], m[3]
        );
    }
}
