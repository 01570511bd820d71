//! Skin weights, and the two geometric binders the learned one is measured against.
//!
//! A row per vertex, a column per joint: the mouth points P1…P12, then the root (the head,
//! which stays still). Rows are non-negative and sum to 1; a bound mesh keeps at most
//! [`MAX_INFLUENCES`] non-zero weights per row (what glTF's `JOINTS_0`/`WEIGHTS_0` carry).

use nalgebra::Vector3;

use crate::mesh::Mesh;
use crate::procedural::POINTS;

/// Columns: the twelve mouth points, then the root.
pub const JOINTS: usize = POINTS + 1;
/// Index of the root column.
pub const ROOT: usize = POINTS;
/// Influences a bound vertex may have.
pub const MAX_INFLUENCES: usize = 4;

/// Distance baseline: how fast a joint's weight falls off, in mouth widths: about 0.4 of the
/// spacing between neighbouring points (0.25 mouth widths), so a vertex between two points
/// blends them and one on a point follows it. Chosen as the best of 0.025…0.2 on the
/// network's training heads (`examples/baseline_sweep.rs`, docs/bind.md), never the held-out.
pub const DISTANCE_FALLOFF: f64 = 0.1;
/// Distance and heat baselines: the root acts as a joint at this distance from every vertex
/// (mouth widths), so vertices farther than this from all points stay with the head. The best
/// of 0.3, 0.6, 1.0 for both baselines on the training heads (same sweep).
pub const ROOT_DISTANCE: f64 = 0.6;
/// Heat baseline: the heat a joint puts into the vertices it is nearest to,
/// `c / d²` (Baran & Popović 2007 use 1).
pub const HEAT_CONSTANT: f64 = 1.0;

/// Dense skin weights, `n × JOINTS`, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Weights {
    pub rows: Vec<[f64; JOINTS]>,
}

impl Weights {
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// Keeps the [`MAX_INFLUENCES`] largest weights of every row and rescales them to sum
    /// to 1 (a row of zeros goes to the root).
    pub fn limit_influences(&mut self) {
        for row in &mut self.rows {
            limit_row(row, MAX_INFLUENCES);
        }
    }

    /// The skinned position of each vertex (mouth frame) when the joints translate by
    /// `motion` (the root stays): `v + Σ_j w_j d_j`.
    pub fn skin(
        &self,
        rest: &[Vector3<f64>],
        motion: &[Vector3<f64>; POINTS],
    ) -> Vec<Vector3<f64>> {
        rest.iter()
            .zip(&self.rows)
            .map(|(v, row)| {
                let mut p = *v;
                for j in 0..POINTS {
                    if row[j] != 0.0 {
                        p += row[j] * motion[j];
                    }
                }
                p
            })
            .collect()
    }
}

/// Keeps the `k` largest entries of a row, zeroes the rest, rescales to sum 1.
pub fn limit_row(row: &mut [f64; JOINTS], k: usize) {
    let mut order: Vec<usize> = (0..JOINTS).collect();
    order.sort_by(|&a, &b| row[b].total_cmp(&row[a]).then(a.cmp(&b)));
    for &j in &order[k..] {
        row[j] = 0.0;
    }
    for v in row.iter_mut() {
        if v.is_nan() || *v <= 0.0 {
            *v = 0.0;
        }
    }
    let sum: f64 = row.iter().sum();
    if sum > 0.0 {
        for v in row.iter_mut() {
            *v /= sum;
        }
    } else {
        *row = [0.0; JOINTS];
        row[ROOT] = 1.0;
    }
}

/// Euclidean distance of every vertex to every mouth point, in the mesh's units.
pub fn joint_distances(mesh: &Mesh, points: &[Vector3<f64>; POINTS]) -> Vec<[f64; POINTS]> {
    (0..mesh.len())
        .map(|v| {
            let p = mesh.vertex(v);
            std::array::from_fn(|j| (p - points[j]).norm())
        })
        .collect()
}

/// The distance baseline: `softmax(−d_j / σ)` over the joints, the root at a fixed
/// distance, with d in mouth widths and σ = [`DISTANCE_FALLOFF`].
pub fn distance_weights(distances: &[[f64; POINTS]], mouth_width: f64) -> Weights {
    distance_weights_with(distances, mouth_width, DISTANCE_FALLOFF, ROOT_DISTANCE)
}

/// [`distance_weights`] with other constants (`bench`'s sweep of them).
pub fn distance_weights_with(
    distances: &[[f64; POINTS]],
    mouth_width: f64,
    falloff: f64,
    root_distance: f64,
) -> Weights {
    let rows = distances
        .iter()
        .map(|d| {
            let mut scores = [0.0; JOINTS];
            for j in 0..POINTS {
                scores[j] = -d[j] / mouth_width / falloff;
            }
            scores[ROOT] = -root_distance / falloff;
            softmax(&scores)
        })
        .collect();
    Weights { rows }
}

/// Numerically stable softmax.
pub fn softmax(scores: &[f64; JOINTS]) -> [f64; JOINTS] {
    let max = scores.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let mut out = scores.map(|s| (s - max).exp());
    let sum: f64 = out.iter().sum();
    for v in &mut out {
        *v /= sum;
    }
    out
}

/// The heat-diffusion baseline (Baran & Popović 2007, Blender's "automatic weights"): for
/// each joint j, solve `(L + M H) w_j = M H p_j` over the mesh, with L the cotangent
/// Laplacian, M the vertex areas, `H_v = c / d_v²` the heat from the vertex's nearest joint
/// at distance d_v, and `p_j(v) = 1` where joint j is that nearest joint. The root counts as
/// a joint at [`ROOT_DISTANCE`] mouth widths from every vertex, so the head is its
/// region. Joints are points, not bones, so "nearest" is the nearest point.
pub fn heat_weights(mesh: &Mesh, distances: &[[f64; POINTS]], mouth_width: f64) -> Weights {
    heat_weights_with(mesh, distances, mouth_width, ROOT_DISTANCE)
}

/// [`heat_weights`] with another root distance (`bench`'s sweep of it).
pub fn heat_weights_with(
    mesh: &Mesh,
    distances: &[[f64; POINTS]],
    mouth_width: f64,
    root_distance: f64,
) -> Weights {
    let n = mesh.len();
    let (laplacian, area) = mesh.cotangent_laplacian();
    let mut nearest = vec![ROOT; n];
    let mut heat = vec![0.0; n];
    for v in 0..n {
        let mut best = root_distance * mouth_width;
        for j in 0..POINTS {
            if distances[v][j] < best {
                best = distances[v][j];
                nearest[v] = j;
            }
        }
        // a vertex on a point would get infinite heat: floor at 1 % of the mouth width
        let d = best.max(0.01 * mouth_width) / mouth_width;
        heat[v] = area[v] / (mouth_width * mouth_width) * HEAT_CONSTANT / (d * d);
    }
    // The Laplacian's cotangent weights are scale-free; the areas carry units², removed
    // above so the balance between diffusion and heat does not depend on the units.
    let mut rows = vec![[0.0; JOINTS]; n];
    let mut x = vec![0.0; n];
    for j in 0..JOINTS {
        let b: Vec<f64> = (0..n)
            .map(|v| if nearest[v] == j { heat[v] } else { 0.0 })
            .collect();
        for v in 0..n {
            x[v] = if nearest[v] == j { 1.0 } else { 0.0 };
        }
        laplacian.solve_cg(&heat, &b, &mut x, 1e-6, 4 * n.max(100));
        for v in 0..n {
            rows[v][j] = x[v].max(0.0);
        }
    }
    for row in &mut rows {
        let sum: f64 = row.iter().sum();
        if sum > 0.0 {
            for w in row.iter_mut() {
                *w /= sum;
            }
        } else {
            row[ROOT] = 1.0;
        }
    }
    Weights { rows }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn limiting_keeps_the_four_largest_and_sums_to_one() {
        let mut row = [0.0; JOINTS];
        for (j, w) in row.iter_mut().enumerate() {
            *w = j as f64;
        }
        limit_row(&mut row, 4);
        assert_eq!(row.iter().filter(|&&w| w > 0.0).count(), 4);
        assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(row[12] > row[9] && row[8] == 0.0);
        let mut zero = [0.0; JOINTS];
        limit_row(&mut zero, 4);
        assert_eq!(zero[ROOT], 1.0);
    }

    #[test]
    fn distance_weights_follow_the_nearest_point_and_far_vertices_the_root() {
        let mut near = [1.0; POINTS];
        near[4] = 0.0;
        let far = [3.0; POINTS];
        let w = distance_weights(&[near, far], 1.0);
        assert!(w.rows[0][4] > 0.99);
        assert!(w.rows[1][ROOT] > 0.99);
    }
}
