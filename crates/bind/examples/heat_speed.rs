//! Heat diffusion's two solves on a procedural head around the human's mouth (`bind head
//! --resolution R`'s mesh, mouth-width units): the shared sparse Cholesky factorisation
//! `bind` uses and the per-joint conjugate gradients it replaced; seconds of each and the
//! largest difference between their weights.
//!
//!     cargo run -p mouthpiece-bind --example heat_speed -- 58     # 203 232 vertices

use std::time::Instant;

use mouthpiece_bind::procedural::{HeadParams, POINTS};
use mouthpiece_bind::weights::{heat_weights, heat_weights_iterative, joint_distances, JOINTS};
use nalgebra::Vector3;

fn main() {
    let resolution: usize = std::env::args()
        .nth(1)
        .map_or(29, |r| r.parse().expect("a resolution"));
    let head =
        HeadParams::around_points(HeadParams::mouth_points(0.2, 0.2, 0.3), 0.0, resolution).build();
    let points: [Vector3<f64>; POINTS] = head.params.points.map(Vector3::from);
    let d = joint_distances(&head.mesh, &points);
    println!("{} vertices", head.mesh.len());
    let start = Instant::now();
    let fast = heat_weights(&head.mesh, &d, 1.0);
    println!("factorised: {:.2} s", start.elapsed().as_secs_f64());
    if std::env::args().nth(2).as_deref() == Some("--fast-only") {
        return;
    }
    let start = Instant::now();
    let slow = heat_weights_iterative(&head.mesh, &d, 1.0);
    println!(
        "conjugate gradients: {:.2} s",
        start.elapsed().as_secs_f64()
    );
    let worst = fast
        .rows
        .iter()
        .zip(&slow.rows)
        .flat_map(|(a, b)| (0..JOINTS).map(move |j| (a[j] - b[j]).abs()))
        .fold(0.0, f64::max);
    println!("largest weight difference: {worst:.2e}");
}
