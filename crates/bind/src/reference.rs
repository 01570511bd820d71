//! Reference weights: for each vertex of a procedural head, the skin weights that best
//! reproduce its analytic motion with linear blend skinning over the mouth joints.
//!
//! For vertex v and mouth states s = 1…S, the joints translate by `d_j(s)` (the motion of
//! point j) and the vertex by `u_v(s)`. Skinning moves it by `Σ_j w_j d_j(s)` (the root does
//! not move), so the weights solve
//!
//! ```text
//!   minimise  Σ_s |A(s) w − u_v(s)|²   over  w ≥ 0,  Σ_j w_j = 1   (j over P1…P12 and the root)
//! ```
//!
//! a least-squares problem over the probability simplex. `A` (the joints' motions) is the
//! same for every vertex, so its Gram matrix `G = AᵀA` is formed once and each vertex needs
//! only `h = Aᵀu_v`. We solve it by accelerated projected gradient (FISTA, Beck & Teboulle
//! 2009) with step `1/λ_max(G)` and the exact Euclidean projection onto the simplex
//! (sort-based, Duchi et al. 2008). Then the four largest weights are kept and the problem
//! is solved again over those four alone, so the reference is the best fit a glTF skin can
//! carry. The objective is convex, so the solution's quality is checked by its optimality
//! conditions in the tests (KKT: the gradient is constant on the support and not smaller
//! off it).

use nalgebra::{DMatrix, DVector, Vector3};
use rand::SeedableRng;

use crate::procedural::{Head, MouthState, POINTS};
use crate::weights::{Weights, JOINTS, MAX_INFLUENCES, ROOT};

/// FISTA iterations per solve (the problem has 13 unknowns; this is far past convergence
/// for the conditioning of the mouth heads, see the KKT test).
pub const ITERATIONS: usize = 3000;
/// Random mouth states the references are fitted over (after the pure ones).
pub const FIT_STATES: usize = 40;

/// Euclidean projection of `y` onto the probability simplex.
pub fn project_simplex(y: &mut [f64]) {
    let mut sorted: Vec<f64> = y.to_vec();
    sorted.sort_by(|a, b| b.total_cmp(a));
    let mut cumulative = 0.0;
    let mut theta = 0.0;
    for (i, &v) in sorted.iter().enumerate() {
        cumulative += v;
        let t = (cumulative - 1.0) / (i + 1) as f64;
        if v - t > 0.0 {
            theta = t;
        }
    }
    for v in y.iter_mut() {
        *v = (*v - theta).max(0.0);
    }
}

/// minimise ½wᵀGw − hᵀw over the simplex restricted to `support` (others stay 0).
pub fn simplex_least_squares(
    g: &DMatrix<f64>,
    h: &DVector<f64>,
    support: &[usize],
) -> DVector<f64> {
    let k = support.len();
    let gs = DMatrix::from_fn(k, k, |a, b| g[(support[a], support[b])]);
    let hs = DVector::from_fn(k, |a, _| h[support[a]]);
    let lipschitz = gs.clone().symmetric_eigenvalues().max().max(1e-300);
    let step = 1.0 / lipschitz;
    let mut w = DVector::from_element(k, 1.0 / k as f64);
    let mut y = w.clone();
    let mut t = 1.0f64;
    for _ in 0..ITERATIONS {
        let grad = &gs * &y - &hs;
        let mut next = &y - step * grad;
        project_simplex(next.as_mut_slice());
        let t_next = 0.5 * (1.0 + (1.0 + 4.0 * t * t).sqrt());
        y = &next + ((t - 1.0) / t_next) * (&next - &w);
        w = next;
        t = t_next;
    }
    let mut full = DVector::zeros(g.nrows());
    for (a, &j) in support.iter().enumerate() {
        full[j] = w[a];
    }
    full
}

/// The mouth states the references are fitted over: the pure states and
/// [`FIT_STATES`] random ones from a fixed seed.
pub fn fit_states() -> Vec<MouthState> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x005e_ed0f_5717);
    MouthState::set(FIT_STATES, &mut rng)
}

/// The reference weights of a procedural head over the given states.
pub fn reference_weights(head: &Head, states: &[MouthState]) -> Weights {
    let motions: Vec<[Vector3<f64>; POINTS]> =
        states.iter().map(|s| head.joint_motion(s)).collect();
    fit_weights(&motions, head.mesh.len(), |v, s| {
        head.displacement(v, &states[s])
    })
}

/// The best four-influence skin of `vertices` vertices whose motion in state `s` is
/// `displacement(v, s)`, the joints moving by `motions[s]` (any mesh, any reference motion).
pub fn fit_weights(
    motions: &[[Vector3<f64>; POINTS]],
    vertices: usize,
    displacement: impl Fn(usize, usize) -> Vector3<f64>,
) -> Weights {
    // A: rows (state, axis), columns joints; the root's column is zero.
    let rows = 3 * motions.len();
    let a = DMatrix::from_fn(rows, JOINTS, |r, j| {
        if j == ROOT {
            0.0
        } else {
            motions[r / 3][j][r % 3]
        }
    });
    let g = a.transpose() * &a;
    let all: Vec<usize> = (0..JOINTS).collect();
    let rows = (0..vertices)
        .map(|v| {
            let moves: Vec<Vector3<f64>> = (0..motions.len()).map(|s| displacement(v, s)).collect();
            let u = DVector::from_fn(rows, |r, _| moves[r / 3][r % 3]);
            let h = a.transpose() * u;
            let w = simplex_least_squares(&g, &h, &all);
            let mut order = all.clone();
            order.sort_by(|&x, &y| w[y].total_cmp(&w[x]).then(x.cmp(&y)));
            order.truncate(MAX_INFLUENCES);
            order.sort_unstable();
            let w = simplex_least_squares(&g, &h, &order);
            std::array::from_fn(|j| w[j])
        })
        .collect();
    Weights { rows }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projection_lands_on_the_simplex_and_keeps_points_already_there() {
        let mut y = [0.2, 0.3, 0.5];
        project_simplex(&mut y);
        assert_eq!(y, [0.2, 0.3, 0.5]);
        let mut y = [2.0, -1.0, 0.5];
        project_simplex(&mut y);
        assert!((y.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(y.iter().all(|&v| v >= 0.0));
        assert_eq!(y, [1.0, 0.0, 0.0]);
    }

    #[test]
    fn the_solution_meets_the_optimality_conditions() {
        // A random convex problem: at the optimum the gradient is equal (= −λ) on the
        // support and at least −λ off it (KKT for the simplex).
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        use rand::Rng;
        let a = DMatrix::from_fn(30, JOINTS, |_, _| rng.random_range(-1.0..1.0));
        let b = DVector::from_fn(30, |_, _| rng.random_range(-1.0..1.0));
        let g = a.transpose() * &a;
        let h = a.transpose() * b;
        let all: Vec<usize> = (0..JOINTS).collect();
        let w = simplex_least_squares(&g, &h, &all);
        assert!((w.sum() - 1.0).abs() < 1e-9 && w.iter().all(|&v| v >= 0.0));
        let grad = &g * &w - &h;
        let support: Vec<usize> = (0..JOINTS).filter(|&j| w[j] > 1e-9).collect();
        let lambda = grad[support[0]];
        for j in 0..JOINTS {
            if support.contains(&j) {
                assert!(
                    (grad[j] - lambda).abs() < 1e-6,
                    "{j}: {} vs {lambda}",
                    grad[j]
                );
            } else {
                assert!(grad[j] >= lambda - 1e-6);
            }
        }
    }

    #[test]
    fn a_vertex_on_a_point_is_bound_to_that_point() {
        let head = crate::procedural::HeadParams::around_points(
            crate::procedural::HeadParams::mouth_points(0.2, 0.2, 0.3),
            0.0,
            1,
        )
        .build();
        let w = reference_weights(&head, &fit_states());
        for (k, &v) in head.point_vertices.iter().enumerate() {
            assert!(w.rows[v][k] > 0.999, "point {k}: {:?}", w.rows[v]);
        }
    }
}
