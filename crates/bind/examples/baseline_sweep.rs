//! The baselines' constants against others, on the network's training heads (never the
//! held-out ones): is the distance and heat binding the network is compared with a fair one?
//!
//!     cargo run --release -p mouthpiece-bind --example baseline_sweep
//!
//! Prints the mean deformation RMS (% of the mouth width) over the heads for each setting.

use mouthpiece_bind::eval::deformation_error;
use mouthpiece_bind::procedural::MouthState;
use mouthpiece_bind::training::random_cases;
use mouthpiece_bind::weights::{distance_weights_with, heat_weights_with, joint_distances};
use rand::SeedableRng;

fn main() {
    let cases = random_cases("train", 8, 1);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0xe7a1);
    let states = MouthState::set(60, &mut rng);
    let prepared: Vec<_> = cases
        .iter()
        .map(|c| {
            let points = c.head.params.points.map(nalgebra::Vector3::from);
            (c, joint_distances(&c.head.mesh, &points))
        })
        .collect();
    let score =
        |f: &dyn Fn(&mouthpiece_bind::training::Case, &[[f64; 12]]) -> mouthpiece_bind::Weights| {
            prepared
                .iter()
                .map(|(c, d)| {
                    let mut w = f(c, d);
                    w.limit_influences();
                    deformation_error(&c.head, &w, &states).rms
                })
                .sum::<f64>()
                / prepared.len() as f64
        };
    println!("| baseline | falloff | root distance | RMS (% mouth width) |");
    println!("|---|---:|---:|---:|");
    for root in [0.3, 0.6, 1.0] {
        for falloff in [0.025, 0.05, 0.1, 0.2] {
            let rms = score(&|_, d| distance_weights_with(d, 1.0, falloff, root));
            println!("| distance | {falloff} | {root} | {rms:.2} |");
        }
    }
    for root in [0.3, 0.6, 1.0] {
        let rms = score(&|c, d| heat_weights_with(&c.head.mesh, d, 1.0, root));
        println!("| heat | — | {root} | {rms:.2} |");
    }
}
