//! The binders on held-out heads re-meshed at other densities (the same shapes and motion,
//! 612 to 62 k vertices): does the network trained on 36–60 vertices a ring hold up?
//!
//!     cargo run -p mouthpiece-bind --example density_eval
//!
//! Prints a Markdown table: deformation RMS (% of the mouth width) per density and method,
//! the mean over the first three held-out heads; docs/bind.md has it.

use mouthpiece_bind::eval::deformation_error;
use mouthpiece_bind::procedural::{HeadParams, MouthState};
use mouthpiece_bind::training::{method_weights, Case, EVAL_STATES};
use rand::SeedableRng;

/// `bind evaluate`'s held-out seed.
const HELD_OUT_SEED: u64 = 1_319_952;

fn main() {
    let network = mouthpiece_bind::shipped_network().unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(HELD_OUT_SEED);
    let heads: Vec<HeadParams> = (0..3).map(|_| HeadParams::random(&mut rng)).collect();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0xe7a1);
    let states = MouthState::set(EVAL_STATES, &mut rng);
    println!("| ring vertices | vertices | network | heat | distance | reference |");
    println!("|---:|---:|---:|---:|---:|---:|");
    for r in [3usize, 8, 16, 32] {
        let mut sums = [0.0; 4];
        let mut vertices = 0;
        for params in &heads {
            let mut p = params.clone();
            p.around = 12 * r;
            p.face_rings = 3 * r;
            p.tube_rings = 2 * r;
            let case = Case::new(format!("r{r}"), &p);
            vertices += case.head.mesh.len();
            let mut all = method_weights(&case, &network).to_vec();
            all.push(("reference", case.reference.clone()));
            for (k, (_, w)) in all.iter().enumerate() {
                sums[k] += deformation_error(&case.head, w, &states).rms / heads.len() as f64;
            }
        }
        println!(
            "| {} | {} | {:.2} | {:.2} | {:.2} | {:.2} |",
            12 * r,
            vertices / heads.len(),
            sums[0],
            sums[1],
            sums[2],
            sums[3]
        );
    }
}
