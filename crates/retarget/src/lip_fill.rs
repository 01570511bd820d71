//! Where the rig puts a lip dot it does not see this step (docs/rig.md, "Unseen dots from
//! the seen ones").
//!
//! The stabiliser holds a missing dot at its last position; that is what the character's
//! points are made of. The rig's curves need the dot where it is now: a corner lost in a fast
//! pucker is held wide while the other dots draw in, and `mouthPucker` reads the held width.
//! [`LipFill`] learns, from the steps where every lip dot is seen, the mean and covariance of
//! the whole mouth's displacement from neutral (one vector of three coordinates per dot), and
//! puts each unseen dot at its expected displacement given the seen ones: the Gaussian
//! conditional mean, the best linear prediction from the dots seen in the same step. Lips
//! move together (a pucker draws every dot in, a smile lifts both corners), so a few seen
//! dots say much about the others.

use nalgebra::{Cholesky, DMatrix, DVector};

use crate::Vec3;

/// Complete steps the fill learns from before it fills anything (fewer: the held dots stay).
/// Twenty steps, two thirds of a second at 30 Hz, cover a few syllables.
pub const FILL_LEARN_STEPS: usize = 20;

/// The noise of a seen dot's coordinate, metres: added to the seen dots' variances, so that
/// the prediction does not follow one dot's noise as if it were the mouth's motion.
pub const FILL_NOISE_M: f64 = 0.001;

/// The learned displacement statistics and the buffers of one fill.
#[derive(Debug, Clone)]
pub struct LipFill {
    /// Complete steps learned.
    steps: usize,
    /// Mean displacement (metres, 3 per dot, x y z).
    mean: DVector<f64>,
    /// Σ of (x − mean_before)(x − mean_after)ᵀ (Welford's running sum).
    scatter: DMatrix<f64>,
    /// Scratch: the displacement, its deviations, the system and its solution.
    x: DVector<f64>,
    before: DVector<f64>,
    after: DVector<f64>,
    system: Option<DMatrix<f64>>,
    solution: DVector<f64>,
}

impl LipFill {
    /// A fill for `dots` lip dots, with nothing learned.
    pub fn new(dots: usize) -> Self {
        let n = 3 * dots;
        Self {
            steps: 0,
            mean: DVector::zeros(n),
            scatter: DMatrix::zeros(n, n),
            x: DVector::zeros(n),
            before: DVector::zeros(n),
            after: DVector::zeros(n),
            system: Some(DMatrix::zeros(n, n)),
            solution: DVector::zeros(n),
        }
    }

    /// Complete steps learned so far.
    pub fn steps_learned(&self) -> usize {
        self.steps
    }

    fn load(&mut self, neutral: &[Vec3], lip: &[Vec3]) {
        for (k, (p, q)) in lip.iter().zip(neutral).enumerate() {
            let d = p - q;
            self.x[3 * k] = d.x;
            self.x[3 * k + 1] = d.y;
            self.x[3 * k + 2] = d.z;
        }
    }

    /// Learns from a step whose every dot was seen (`lip` and `neutral` in the same frame,
    /// dot for dot). A step with a coordinate that is not finite is not learned: it would
    /// stay in the sums for the rest of the session.
    pub fn learn(&mut self, neutral: &[Vec3], lip: &[Vec3]) {
        self.load(neutral, lip);
        if !self.x.iter().all(|v| v.is_finite()) {
            return;
        }
        self.steps += 1;
        self.before.copy_from(&self.x);
        self.before -= &self.mean;
        self.mean.axpy(1.0 / self.steps as f64, &self.before, 1.0);
        self.after.copy_from(&self.x);
        self.after -= &self.mean;
        self.scatter.ger(1.0, &self.before, &self.after, 1.0);
    }

    /// Moves every dot that is not `seen` and is `wanted` to its expected place given the
    /// seen ones (the others stay as they are). Returns whether it did: not before
    /// [`FILL_LEARN_STEPS`] complete steps, not when no dot is seen or none is to be moved;
    /// then `lip` is left as it was.
    pub fn fill(
        &mut self,
        neutral: &[Vec3],
        lip: &mut [Vec3],
        seen: &[bool],
        wanted: &[bool],
    ) -> bool {
        let moved = |k: usize| !seen[k] && wanted[k];
        if self.steps < FILL_LEARN_STEPS || !seen.contains(&true) || !(0..seen.len()).any(moved) {
            return false;
        }
        self.load(neutral, lip);
        let n = self.x.len();
        let scale = 1.0 / (self.steps - 1) as f64;
        let noise = FILL_NOISE_M * FILL_NOISE_M;
        let seen_at = |i: usize| seen[i / 3];
        // The seen coordinates' covariance plus noise; an unseen coordinate's row and column
        // are the identity's, so that one fixed-size system serves every mask (its solution
        // is 0 there).
        let mut system = self.system.take().unwrap_or_else(|| DMatrix::zeros(n, n));
        for j in 0..n {
            for i in 0..n {
                system[(i, j)] = match (seen_at(i), seen_at(j)) {
                    (true, true) => self.scatter[(i, j)] * scale + if i == j { noise } else { 0.0 },
                    _ => f64::from(u8::from(i == j)),
                };
            }
            self.solution[j] = if seen_at(j) {
                self.x[j] - self.mean[j]
            } else {
                0.0
            };
        }
        let Some(cholesky) = Cholesky::new(system) else {
            return false;
        };
        cholesky.solve_mut(&mut self.solution);
        self.system = Some(cholesky.unpack_dirty());
        if !self.solution.iter().all(|v| v.is_finite()) {
            return false;
        }
        for (k, (p, q)) in lip.iter_mut().zip(neutral).enumerate() {
            if !moved(k) {
                continue;
            }
            // The solution is 0 at the unseen coordinates, so the whole row serves.
            let d = Vec3::from_fn(|axis, _| {
                let u = 3 * k + axis;
                self.mean[u] + self.scatter.row(u).tr_dot(&self.solution) * scale
            });
            *p = q + d;
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn neutral() -> Vec<Vec3> {
        (0..6)
            .map(|i| Vec3::new(0.01 * i as f64 - 0.025, 0.0, 0.0))
            .collect()
    }

    /// A fill that has learned one complete step per scale in `scales`.
    fn learned(n: &[Vec3], scales: impl IntoIterator<Item = f64>) -> LipFill {
        let mut fill = LipFill::new(n.len());
        for s in scales {
            fill.learn(n, &scaled(n, s));
        }
        fill
    }

    /// Speech: the mouth drawn in by up to 30 % and let go, step `k`.
    fn speech(k: usize) -> f64 {
        1.0 - 0.3 * (0.5 + 0.5 * (k as f64 * 0.4).sin())
    }

    /// A mouth that only scales horizontally about its centre (a pucker and its release).
    fn scaled(neutral: &[Vec3], s: f64) -> Vec<Vec3> {
        neutral
            .iter()
            .map(|p| Vec3::new(p.x * s, p.y, p.z))
            .collect()
    }

    #[test]
    fn nothing_is_filled_before_enough_complete_steps() {
        let n = neutral();
        let mut fill = learned(&n, (0..FILL_LEARN_STEPS - 1).map(|k| 1.0 - 0.01 * k as f64));
        let mut lip = scaled(&n, 0.7);
        let held = n[0];
        lip[0] = held;
        let seen = [false, true, true, true, true, true];
        assert!(!fill.fill(&n, &mut lip, &seen, &[true; 6]));
        assert_eq!(lip[0], held);
    }

    #[test]
    fn a_lost_corner_follows_the_seen_dots_pucker() {
        let n = neutral();
        let mut fill = learned(&n, (0..60).map(speech));
        assert_eq!(fill.steps_learned(), 60);
        // Drawn in to 0.75 of the width, the left corner unseen and held where it was at rest.
        let truth = scaled(&n, 0.75);
        let mut lip = truth.clone();
        lip[0] = n[0];
        let seen = [false, true, true, true, true, true];
        assert!(fill.fill(&n, &mut lip, &seen, &[true; 6]));
        // The held corner was 6.25 mm out; filled, it is within a fraction of a millimetre.
        assert!(
            (lip[0] - truth[0]).norm() < 2e-4,
            "{:?} vs {:?}",
            lip[0],
            truth[0]
        );
        for k in 1..n.len() {
            assert_eq!(lip[k], truth[k], "a seen dot is never moved");
        }
    }

    #[test]
    fn an_unwanted_dot_stays_held_and_is_not_used() {
        let n = neutral();
        let mut fill = learned(&n, (0..60).map(speech));
        let truth = scaled(&n, 0.75);
        let mut lip = truth.clone();
        // Both ends unseen and held at rest; only the left one is to be moved.
        lip[0] = n[0];
        lip[5] = n[5];
        let seen = [false, true, true, true, true, false];
        let wanted = [true, true, true, true, true, false];
        assert!(fill.fill(&n, &mut lip, &seen, &wanted));
        // Held, 6.25 mm out; from the four inner dots, within half a millimetre.
        assert!((lip[0] - truth[0]).norm() < 5e-4, "{:?}", lip[0]);
        assert_eq!(lip[5], n[5]);
        // Nothing wanted: nothing done.
        let mut lip = truth.clone();
        lip[0] = n[0];
        assert!(!fill.fill(&n, &mut lip, &seen, &[false; 6]));
        assert_eq!(lip[0], n[0]);
    }

    #[test]
    fn a_step_that_is_not_finite_is_not_learned_nor_used() {
        let n = neutral();
        let mut fill = learned(&n, (0..30).map(|k| 1.0 - 0.01 * k as f64));
        let mut bad = scaled(&n, 0.9);
        bad[3].y = f64::NAN;
        fill.learn(&n, &bad);
        assert_eq!(fill.steps_learned(), 30);
        // A seen coordinate that is not finite: the held dot stays.
        let mut lip = bad.clone();
        lip[0] = n[0];
        let seen = [false, true, true, true, true, true];
        assert!(!fill.fill(&n, &mut lip, &seen, &[true; 6]));
        assert_eq!(lip[0], n[0]);
        // And the fill still works on the next good step.
        let mut lip = scaled(&n, 0.8);
        lip[0] = n[0];
        assert!(fill.fill(&n, &mut lip, &seen, &[true; 6]));
        assert!(lip[0].x.is_finite());
    }

    #[test]
    fn no_seen_dot_leaves_the_held_ones() {
        let n = neutral();
        let mut fill = learned(&n, (0..30).map(|k| 1.0 - 0.01 * k as f64));
        let mut lip = scaled(&n, 0.8);
        let before = lip.clone();
        assert!(!fill.fill(&n, &mut lip, &[false; 6], &[true; 6]));
        assert_eq!(lip, before);
    }
}
