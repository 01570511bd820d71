//! How good a set of weights is against a procedural head's reference: the KL divergence
//! of the weights from the reference rows, and what a user sees, the skinned deformation's
//! error against the analytic motion.

use nalgebra::Vector3;

use crate::procedural::{Head, MouthState};
use crate::weights::Weights;

/// Added to every predicted weight before the KL divergence (then renormalised), so a
/// weight a 4-influence row leaves at zero costs a finite amount.
pub const KL_FLOOR: f64 = 1e-6;

/// `KL(p ‖ q) = Σ p_i ln(p_i / q_i)` in nats, terms with `p_i = 0` contributing 0 (what
/// `scipy.stats.entropy(p, q)` computes after normalising both).
pub fn kl_divergence(p: &[f64], q: &[f64]) -> f64 {
    let sp: f64 = p.iter().sum();
    let sq: f64 = q.iter().sum();
    p.iter()
        .zip(q)
        .filter(|(&pi, _)| pi > 0.0)
        .map(|(&pi, &qi)| {
            let (pi, qi) = (pi / sp, qi / sq);
            pi * (pi / qi).ln()
        })
        .sum()
}

/// Mean over vertices of `KL(reference ‖ predicted)`, the prediction floored by
/// [`KL_FLOOR`].
pub fn mean_kl(reference: &Weights, predicted: &Weights) -> f64 {
    let n = reference.len().max(1);
    reference
        .rows
        .iter()
        .zip(&predicted.rows)
        .map(|(p, q)| {
            let q: Vec<f64> = q.iter().map(|v| v + KL_FLOOR).collect();
            kl_divergence(p, &q)
        })
        .sum::<f64>()
        / n as f64
}

/// The skinned deformation's vertex error against the analytic motion, over states.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DeformationError {
    /// Root mean square over vertices and states, % of the mouth width.
    pub rms: f64,
    /// Largest over vertices and states, % of the mouth width.
    pub max: f64,
}

/// Deformation error of `weights` on `head` (mouth-width units, so % is ×100).
pub fn deformation_error(
    head: &Head,
    weights: &Weights,
    states: &[MouthState],
) -> DeformationError {
    let rest: Vec<Vector3<f64>> = (0..head.mesh.len()).map(|v| head.mesh.vertex(v)).collect();
    let mut sum = 0.0;
    let mut max = 0.0f64;
    let mut count = 0usize;
    for s in states {
        let skinned = weights.skin(&rest, &head.joint_motion(s));
        for (v, p) in skinned.iter().enumerate() {
            let truth = rest[v] + head.displacement(v, s);
            let e = (p - truth).norm();
            sum += e * e;
            max = max.max(e);
            count += 1;
        }
    }
    DeformationError {
        rms: 100.0 * (sum / count.max(1) as f64).sqrt(),
        max: 100.0 * max,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kl_is_zero_for_equal_rows_and_positive_otherwise() {
        assert_eq!(kl_divergence(&[0.5, 0.5], &[0.5, 0.5]), 0.0);
        assert!(kl_divergence(&[1.0, 0.0], &[0.5, 0.5]) > 0.69);
    }
}
