//! Skin weights, and the two geometric binders the learned one is measured against.
//!
//! A row per vertex, a column per joint: the mouth points P1…P12, then the root (the head,
//! which stays still). Rows are non-negative and sum to 1; a bound mesh keeps at most
//! [`MAX_INFLUENCES`] non-zero weights per row (what glTF's `JOINTS_0`/`WEIGHTS_0` carry).

use nalgebra::Vector3;

use crate::mesh::{Mesh, SparseSym};
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
///
/// The matrix `L + M H` is the same for every joint, so it is factorised once (a sparse
/// Cholesky with a fill-reducing ordering, `faer`) and the thirteen right-hand sides are
/// solved with that one factor.
pub fn heat_weights_with(
    mesh: &Mesh,
    distances: &[[f64; POINTS]],
    mouth_width: f64,
    root_distance: f64,
) -> Weights {
    let (laplacian, heat, nearest) = heat_system(mesh, distances, mouth_width, root_distance);
    match heat_solve_cholesky(&laplacian, &heat, &nearest) {
        Some(rows) => normalise_heat(rows),
        // not expected (the matrix is symmetric positive definite): the iterative solve
        None => heat_solve_cg(&laplacian, &heat, &nearest),
    }
}

/// The heat system: the cotangent Laplacian, each vertex's heat `M H` (unit-free), and the
/// joint each vertex is nearest to (the root when no point is nearer than `root_distance`).
fn heat_system(
    mesh: &Mesh,
    distances: &[[f64; POINTS]],
    mouth_width: f64,
    root_distance: f64,
) -> (SparseSym, Vec<f64>, Vec<usize>) {
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
    (laplacian, heat, nearest)
}

/// Solves `(L + M H) w_j = M H p_j` for every joint with one sparse Cholesky factor. A
/// vertex in no triangle (an empty row) keeps its nearest joint, as the iterative solve's
/// first guess leaves it. None when the factorisation fails.
fn heat_solve_cholesky(
    laplacian: &SparseSym,
    heat: &[f64],
    nearest: &[usize],
) -> Option<Vec<[f64; JOINTS]>> {
    use faer::linalg::solvers::Solve;
    use faer::sparse::{SparseColMat, Triplet};

    let n = heat.len();
    let mut entries = Vec::with_capacity(n + laplacian.off.iter().map(Vec::len).sum::<usize>());
    let mut rhs = faer::Mat::<f64>::zeros(n, JOINTS);
    for v in 0..n {
        let d = laplacian.diag[v] + heat[v];
        if d > 0.0 {
            entries.push(Triplet::new(v, v, d));
            rhs[(v, nearest[v])] = heat[v];
        } else {
            entries.push(Triplet::new(v, v, 1.0));
            rhs[(v, nearest[v])] = 1.0;
        }
        entries.extend(
            laplacian.off[v]
                .iter()
                .filter(|&&(u, _)| (u as usize) > v)
                .map(|&(u, w)| Triplet::new(u as usize, v, w)),
        );
    }
    let matrix = SparseColMat::<usize, f64>::try_new_from_triplets(n, n, &entries).ok()?;
    drop(entries);
    let llt = matrix.sp_cholesky(faer::Side::Lower).ok()?;
    drop(matrix);
    llt.solve_in_place(rhs.as_mut());
    let rows = (0..n)
        .map(|v| std::array::from_fn(|j| rhs[(v, j)]))
        .collect::<Vec<[f64; JOINTS]>>();
    rows.iter()
        .all(|r| r.iter().all(|w| w.is_finite()))
        .then_some(rows)
}

/// [`heat_weights`] solved as before the shared factorisation: conjugate gradients, one joint at
/// a time (`examples/heat_speed.rs` times both; the unit tests compare them).
pub fn heat_weights_iterative(
    mesh: &Mesh,
    distances: &[[f64; POINTS]],
    mouth_width: f64,
) -> Weights {
    let (laplacian, heat, nearest) = heat_system(mesh, distances, mouth_width, ROOT_DISTANCE);
    heat_solve_cg(&laplacian, &heat, &nearest)
}

/// The heat solve by conjugate gradients (Jacobi preconditioner, relative residual 1e-6), one
/// joint at a time: the reference the factorised solve is checked against.
fn heat_solve_cg(laplacian: &SparseSym, heat: &[f64], nearest: &[usize]) -> Weights {
    let n = heat.len();
    let mut rows = vec![[0.0; JOINTS]; n];
    let mut x = vec![0.0; n];
    for j in 0..JOINTS {
        let b: Vec<f64> = (0..n)
            .map(|v| if nearest[v] == j { heat[v] } else { 0.0 })
            .collect();
        for v in 0..n {
            x[v] = if nearest[v] == j { 1.0 } else { 0.0 };
        }
        laplacian.solve_cg(heat, &b, &mut x, 1e-6, 4 * n.max(100));
        for v in 0..n {
            rows[v][j] = x[v];
        }
    }
    normalise_heat(rows)
}

/// Negative weights (round-off) to zero, rows to sum 1 (a row of zeros to the root).
fn normalise_heat(mut rows: Vec<[f64; JOINTS]>) -> Weights {
    for row in &mut rows {
        for w in row.iter_mut() {
            *w = w.max(0.0);
        }
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

    #[test]
    fn the_factorised_heat_solve_matches_the_iterative_one() {
        // a procedural head with a separate shell and a vertex in no triangle
        let head = crate::procedural::HeadParams::around_points(
            crate::procedural::HeadParams::mouth_points(0.3, 0.2, 0.4),
            0.5,
            3,
        )
        .build();
        let mut mesh = head.mesh.clone();
        let base = mesh.positions.len() as u32;
        mesh.positions.extend([
            [0.0, 0.0, -0.5],
            [0.1, 0.0, -0.5],
            [0.0, 0.1, -0.5],
            [9.0; 3],
        ]);
        mesh.triangles.push([base, base + 1, base + 2]);
        let points = std::array::from_fn(|k| mesh.vertex(head.point_vertices[k]));
        let d = joint_distances(&mesh, &points);
        let nearest = heat_system(&mesh, &d, 1.0, ROOT_DISTANCE).2;
        let fast = heat_weights(&mesh, &d, 1.0);
        let reference = heat_weights_iterative(&mesh, &d, 1.0);
        let mut worst: f64 = 0.0;
        for (a, b) in fast.rows.iter().zip(&reference.rows) {
            for j in 0..JOINTS {
                worst = worst.max((a[j] - b[j]).abs());
            }
        }
        assert!(worst < 1e-4, "largest difference {worst}");
        assert!(fast
            .rows
            .iter()
            .all(|r| (r.iter().sum::<f64>() - 1.0).abs() < 1e-12));
        assert_eq!(
            fast.rows[base as usize + 3][nearest[base as usize + 3]],
            1.0
        );
        // heat reaches the lips: some vertex follows each point most
        for j in 0..POINTS {
            assert!(fast.rows.iter().any(|r| r[j] > 0.5), "point {j}");
        }
    }
}
