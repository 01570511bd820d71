//! The jaw on the held-out heads: the deformation error over all vertices and over the
//! chin's, without the jaw joint (the mouth's points and the root only) and with it (the
//! chin's root share on the jaw, the lower lip's joints riding on it), for each binder.
//!
//!     cargo run -p mouthpiece-bind --example jaw_eval
//!
//! Prints a Markdown table (RMS in % of the mouth width, the same 65 mouth states as
//! `bind evaluate`); docs/bind.md has it. A second table: the chin's RMS with the jaw at the
//! head's own hinge, at the hinge read from the mesh (`jaw::hinge_from_mesh`, what `bind`
//! uses when the character gives none) and at the rig's default (0.5 up, 1.6 back).

use mouthpiece_bind::jaw::{hinge_from_mesh, jaw_errors, jaw_errors_at};
use mouthpiece_bind::procedural::MouthState;
use mouthpiece_bind::training::{method_weights, random_cases, EVAL_STATES};
use nalgebra::Vector3;
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
    let mut hinges = std::collections::BTreeMap::<&str, [f64; 3]>::new();
    let mut distance = [0.0f64; 2];
    let default = Vector3::new(0.0, 0.5, -1.6);
    for case in &cases {
        let own = Vector3::from(case.head.hinge);
        let found = hinge_from_mesh(&case.head.mesh).unwrap_or(default);
        distance[0] += (found - own).norm() / cases.len() as f64;
        distance[1] = distance[1].max((found - own).norm());
        let mut all = method_weights(case, &network).to_vec();
        all.push(("reference", case.reference.clone()));
        for (name, w) in all {
            let e = jaw_errors(&case.head, &w, &states);
            let m = means.entry(name).or_default();
            for k in 0..4 {
                m[k] += e[k] / cases.len() as f64;
            }
            let h = hinges.entry(name).or_default();
            h[0] += e[3] / cases.len() as f64;
            for (k, at) in [(1, found), (2, default)] {
                h[k] += jaw_errors_at(&case.head, &w, &states, &at)[3] / cases.len() as f64;
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
    println!();
    println!(
        "hinge read from the mesh: {:.3} mouth widths from the head's own on average, {:.3} at most",
        distance[0], distance[1]
    );
    println!();
    println!(
        "| method | chin RMS, own hinge | chin RMS, hinge from the mesh | chin RMS, rig default |"
    );
    println!("|---|---:|---:|---:|");
    for name in ["network", "heat", "distance", "reference"] {
        let h = hinges[name];
        println!("| {name} | {:.2} | {:.2} | {:.2} |", h[0], h[1], h[2]);
    }
}
