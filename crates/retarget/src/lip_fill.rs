//! Where the rig measures the lip dots (docs/rig.md, "The dots the rig measures").
//!
//! The stabiliser holds a missing dot at its last position; that is what the character's
//! points are made of. The rig's curves need the dot where it is now: a corner lost in a fast
//! pucker is held wide while the other dots draw in, and `mouthPucker` reads the held width.
//! And a seen dot's depth is the noisiest number the camera gives, its error lying along the
//! camera's ray: with the head turned, that ray is no longer the mouth's depth axis and the
//! error leaks into the sideways motion the curves read.
//! [`LipFill`] learns, from the steps where every lip dot is seen, the mean and covariance of
//! the whole mouth's displacement from neutral (one vector of three coordinates per dot). Each
//! step it takes the mouth's expected displacement given what was seen (the Gaussian
//! conditional mean): every seen dot measured with its noise (small across the camera's ray,
//! large along it), every unseen one not measured at all. Lips move together (a pucker draws
//! every dot in, a smile lifts both corners), so the dots' precise sideways motion says much
//! about their noisy depth and about the dots not seen.

use nalgebra::{Cholesky, DMatrix, DVector};

use crate::Vec3;

/// Complete steps learned before the estimate is used (fewer: the dots as the stabiliser gives
/// them). Twenty steps, two thirds of a second at 30 Hz, cover a few syllables.
pub const FILL_LEARN_STEPS: usize = 20;

/// A seen dot's noise along the camera's ray by default, metres (`[rig] depth_noise_m`): a
/// depth camera's error on a lip dot's depth (Kinect-like 1.2–1.6 mm, RealSense-like
/// 0.7–1.0 mm on the synthetic sessions).
pub const RAY_NOISE_M: f64 = 0.0012;

/// A seen dot's noise across the camera's ray by default, metres (`[rig] pixel_noise_m`): its
/// pixel's precision (a quarter of a pixel at 0.6 m is 0.3 mm).
pub const ACROSS_NOISE_M: f64 = 0.0003;

/// *The prior steers depth, not shape*: the learned covariance is widened by this factor.
/// It is learned from complete steps only, which rarely show the shapes that hide dots (lips
/// rolled in, a wide opening); widened, it still ties a dot's depth to the mouth's precise
/// sideways motion, but no longer pulls an unusual shape towards the usual ones.
pub const PRIOR_WIDTH: f64 = 2.0;

/// *An unlearned shape is taken as measured*: a step whose seen displacement lies farther than
/// this from what was learned (its squared Mahalanobis distance under the prior and the noise,
/// per seen coordinate; 0.2 is typical, 2.5 the 99th percentile on the synthetic sessions)
/// keeps its seen dots as measured (its unseen ones are still estimated). Early in a session
/// the covariance knows few shapes, and a new expression is not noise.
pub const SHAPE_GATE: f64 = 3.0;

/// *A dot the others disown is not measured*: when a step lies beyond [`SHAPE_GATE`], the seen
/// dot with the largest share of that distance is left out, and if the other seen dots then
/// lie within the gate and put it farther than this from where it was read (metres), it was
/// misread (a fast lip's blurred trail, another blob) and is estimated like an unseen dot.
/// Lips are one tissue: a dot 6 mm from where its neighbours put it would have torn from
/// them. On the synthetic sessions such misreads are 6–15 mm off; a genuine shape the
/// complete steps never showed leaves no single dot that far out.
pub const DISOWN_M: f64 = 0.006;

/// ... and only when at least this many other dots are seen to say where it should be.
pub const DISOWN_WITNESSES: usize = 3;

/// What one [`LipFill::estimate`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Estimated {
    /// Unseen dots moved to their expected place.
    pub filled: bool,
    /// Seen dots moved to their expected place given every seen dot's noise.
    pub seen: bool,
    /// The seen dot taken as misread ([`DISOWN_M`]) and moved to where the others put it.
    pub disowned: Option<usize>,
}

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
    /// Scratch: the step's own solution while a dot's disowning is tried.
    step_solution: DVector<f64>,
    /// Scratch: per dot, the unit direction from it to the camera.
    rays: Vec<Vec3>,
    /// Scratch: the seen dots without the one a disowning leaves out.
    kept: Vec<bool>,
    /// A seen dot's noise along and across its ray, metres.
    along_m: f64,
    across_m: f64,
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
            step_solution: DVector::zeros(n),
            rays: vec![Vec3::zeros(); dots],
            kept: vec![false; dots],
            along_m: RAY_NOISE_M,
            across_m: ACROSS_NOISE_M,
        }
    }

    /// The seen dots' noise along and across the camera's ray, metres (the camera's; the
    /// defaults are [`RAY_NOISE_M`] and [`ACROSS_NOISE_M`]).
    pub fn with_noise(mut self, along_m: f64, across_m: f64) -> Self {
        self.along_m = along_m;
        self.across_m = across_m;
        self
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
    /// seen ones, and the seen ones to theirs given every seen dot's noise (`camera`: the
    /// camera's centre in the same frame; each dot's depth error lies along the line to it),
    /// unless the step's shape is one not learned ([`SHAPE_GATE`]); a seen dot the others
    /// disown ([`DISOWN_M`]) is moved like an unseen one. Nothing before
    /// [`FILL_LEARN_STEPS`] complete steps, nor when no dot is seen; then `lip` is left as
    /// it was.
    pub fn estimate(
        &mut self,
        neutral: &[Vec3],
        lip: &mut [Vec3],
        seen: &[bool],
        wanted: &[bool],
        camera: &Vec3,
    ) -> Estimated {
        let moved = |k: usize| !seen[k] && wanted[k];
        if self.steps < FILL_LEARN_STEPS || !seen.contains(&true) {
            return Estimated::default();
        }
        self.load(neutral, lip);
        for (k, p) in lip.iter().enumerate() {
            self.rays[k] = (camera - p).normalize();
        }
        let usable = (0..self.x.len())
            .filter(|&i| seen[i / 3])
            .all(|i| self.x[i].is_finite())
            && self
                .rays
                .iter()
                .enumerate()
                .all(|(k, r)| !seen[k] || r.iter().all(|v| v.is_finite()));
        if !usable {
            return Estimated::default();
        }
        let Some(mut distance) = self.solve(seen) else {
            return Estimated::default();
        };
        let mut disowned = None;
        if distance > SHAPE_GATE {
            if let Some((k, d)) = self.disown(seen) {
                (disowned, distance) = (Some(k), d);
            }
        }
        let out = Estimated {
            filled: (0..seen.len()).any(moved),
            seen: distance <= SHAPE_GATE,
            disowned,
        };
        // A disowned dot is seen, and the step then within the gate: it moves with the rest.
        for (k, (p, q)) in lip.iter_mut().zip(neutral).enumerate() {
            if moved(k) || (seen[k] && out.seen) {
                *p = q + self.expected(k);
            }
        }
        out
    }

    /// The learned covariance's factor: the scatter's sample covariance, widened by
    /// [`PRIOR_WIDTH`].
    fn prior_scale(&self) -> f64 {
        PRIOR_WIDTH / (self.steps - 1) as f64
    }

    /// Dot `k`'s expected displacement from neutral under the solution in place (it is 0 at
    /// the coordinates not used, so the whole row serves).
    fn expected(&self, k: usize) -> Vec3 {
        let scale = self.prior_scale();
        Vec3::from_fn(|axis, _| {
            let u = 3 * k + axis;
            self.mean[u] + self.scatter.row(u).tr_dot(&self.solution) * scale
        })
    }

    /// Solves for the weights of the `used` dots' deviations from the learned mean
    /// (`self.solution`, 0 at the other coordinates; their right-hand side kept in
    /// `self.before`) and returns the step's squared Mahalanobis distance per used coordinate.
    /// `None` when the system cannot be solved.
    fn solve(&mut self, used: &[bool]) -> Option<f64> {
        let n = self.x.len();
        let scale = self.prior_scale();
        let (across, along) = (self.across_m * self.across_m, self.along_m * self.along_m);
        let used_at = |i: usize| used[i / 3];
        // The used coordinates' covariance plus their noise (a dot's own 3×3 block:
        // `across·I + (along − across)·r rᵀ`, r its ray); another coordinate's row and column
        // are the identity's, so that one fixed-size system serves every mask (its solution
        // is 0 there).
        let mut system = self.system.take().unwrap_or_else(|| DMatrix::zeros(n, n));
        let mut coordinates_used = 0usize;
        for j in 0..n {
            for i in 0..n {
                system[(i, j)] = match (used_at(i), used_at(j)) {
                    (true, true) => {
                        let noise = if i / 3 == j / 3 {
                            let r = &self.rays[i / 3];
                            (along - across) * r[i % 3] * r[j % 3]
                                + if i == j { across } else { 0.0 }
                        } else {
                            0.0
                        };
                        self.scatter[(i, j)] * scale + noise
                    }
                    _ => f64::from(u8::from(i == j)),
                };
            }
            self.solution[j] = if used_at(j) {
                coordinates_used += 1;
                self.x[j] - self.mean[j]
            } else {
                0.0
            };
        }
        self.before.copy_from(&self.solution);
        let cholesky = Cholesky::new(system)?;
        cholesky.solve_mut(&mut self.solution);
        self.system = Some(cholesky.unpack_dirty());
        if !self.solution.iter().all(|v| v.is_finite()) {
            return None;
        }
        Some(self.before.dot(&self.solution) / coordinates_used as f64)
    }

    /// *A dot the others disown is not measured* ([`DISOWN_M`]), tried on a step beyond the
    /// gate whose solution is in place: the seen dot with the largest share of the distance
    /// (the first of equal ones), if at least [`DISOWN_WITNESSES`] other dots are seen, the
    /// others then lie within the gate and put it farther than [`DISOWN_M`] from where it was
    /// read. Returns it and the others' distance, their solution in place; else `None`, the
    /// step's own solution put back.
    fn disown(&mut self, seen: &[bool]) -> Option<(usize, f64)> {
        if seen.iter().filter(|&&s| s).count() <= DISOWN_WITNESSES {
            return None;
        }
        let share = |k: usize| {
            (3 * k..3 * k + 3)
                .map(|u| self.before[u] * self.solution[u])
                .sum::<f64>()
        };
        let mut worst: Option<(usize, f64)> = None;
        for k in (0..seen.len()).filter(|&k| seen[k]) {
            let s = share(k);
            if worst.is_none_or(|(_, w)| s > w) {
                worst = Some((k, s));
            }
        }
        let (k, _) = worst?;
        self.step_solution.copy_from(&self.solution);
        self.kept.copy_from_slice(seen);
        self.kept[k] = false;
        let kept = std::mem::take(&mut self.kept);
        let distance = self.solve(&kept);
        self.kept = kept;
        let read = Vec3::new(self.x[3 * k], self.x[3 * k + 1], self.x[3 * k + 2]);
        match distance {
            Some(d) if d <= SHAPE_GATE && (self.expected(k) - read).norm() > DISOWN_M => {
                Some((k, d))
            }
            _ => {
                self.solution.copy_from(&self.step_solution);
                None
            }
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
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

    /// The camera 0.6 m straight in front of the mouth.
    fn camera() -> Vec3 {
        Vec3::new(0.0, 0.0, 0.6)
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
        assert!(
            !fill
                .estimate(&n, &mut lip, &seen, &[true; 6], &camera())
                .filled
        );
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
        assert!(
            fill.estimate(&n, &mut lip, &seen, &[true; 6], &camera())
                .filled
        );
        // The held corner was 6.25 mm out; filled, it is within a fraction of a millimetre.
        assert!(
            (lip[0] - truth[0]).norm() < 2e-4,
            "{:?} vs {:?}",
            lip[0],
            truth[0]
        );
        for k in 1..n.len() {
            assert!(
                (lip[k] - truth[k]).norm() < 1e-4,
                "a seen dot on the learned shape stays where it is: {:?} vs {:?}",
                lip[k],
                truth[k]
            );
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
        assert!(
            fill.estimate(&n, &mut lip, &seen, &wanted, &camera())
                .filled
        );
        // Held, 6.25 mm out; from the four inner dots, within half a millimetre.
        assert!((lip[0] - truth[0]).norm() < 5e-4, "{:?}", lip[0]);
        assert_eq!(lip[5], n[5]);
        // Nothing wanted: nothing done.
        let mut lip = truth.clone();
        lip[0] = n[0];
        assert!(
            !fill
                .estimate(&n, &mut lip, &seen, &[false; 6], &camera())
                .filled
        );
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
        assert!(
            !fill
                .estimate(&n, &mut lip, &seen, &[true; 6], &camera())
                .filled
        );
        assert_eq!(lip[0], n[0]);
        // And the fill still works on the next good step.
        let mut lip = scaled(&n, 0.8);
        lip[0] = n[0];
        assert!(
            fill.estimate(&n, &mut lip, &seen, &[true; 6], &camera())
                .filled
        );
        assert!(lip[0].x.is_finite());
    }

    #[test]
    fn no_seen_dot_leaves_the_held_ones() {
        let n = neutral();
        let mut fill = learned(&n, (0..30).map(|k| 1.0 - 0.01 * k as f64));
        let mut lip = scaled(&n, 0.8);
        let before = lip.clone();
        assert!(
            !fill
                .estimate(&n, &mut lip, &[false; 6], &[true; 6], &camera())
                .filled
        );
        assert_eq!(lip, before);
    }

    /// Rounding as the tests' performer does it: drawn in by `1 − s` and pushed forward,
    /// 8 mm at a third drawn in (also the rig's tests').
    pub(crate) fn rounded(neutral: &[Vec3], s: f64) -> Vec<Vec3> {
        neutral
            .iter()
            .map(|p| Vec3::new(p.x * s, p.y, p.z + 0.024 * (1.0 - s)))
            .collect()
    }

    /// A fill that has learned 60 steps of [`rounded`] speech, every dot seen and exact.
    fn rounding_learned(n: &[Vec3]) -> LipFill {
        let mut fill = LipFill::new(n.len());
        for k in 0..60 {
            fill.learn(n, &rounded(n, speech(k)));
        }
        fill
    }

    /// Standard normal deviates, repeatable from `seed` (a sum of twelve xorshift uniforms:
    /// close enough to a normal for the tests' noise; also the rig's tests').
    pub(crate) fn gauss_stream(seed: u64) -> impl FnMut() -> f64 {
        let mut state = seed;
        move || {
            (0..12)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    (state >> 11) as f64 / (1u64 << 53) as f64
                })
                .sum::<f64>()
                - 6.0
        }
    }

    #[test]
    fn a_depth_error_along_the_ray_is_taken_off_a_seen_dot() {
        let n = neutral();
        let mut fill = rounding_learned(&n);
        // The head turned: the camera off to the side, so a depth error moves a dot sideways
        // as well. One dot reads 3 mm too far along its ray.
        let camera = Vec3::new(0.35, 0.0, 0.5);
        let truth = rounded(&n, 0.8);
        let mut lip = truth.clone();
        let ray = (camera - truth[1]).normalize();
        lip[1] = truth[1] - ray * 0.003;
        let measured_error = (lip[1] - truth[1]).norm();
        let out = fill.estimate(&n, &mut lip, &[true; 6], &[true; 6], &camera);
        assert_eq!(
            out,
            Estimated {
                filled: false,
                seen: true,
                disowned: None
            }
        );
        let error = (lip[1] - truth[1]).norm();
        assert!(
            error < 0.3 * measured_error,
            "{error} m left of {measured_error} m"
        );
        // Sideways too: the leak of the depth error into x is taken off with it.
        assert!((lip[1].x - truth[1].x).abs() < 0.3 * (truth[1] - ray * 0.003 - truth[1]).x.abs());
        for k in [0, 2, 3, 4, 5] {
            assert!(
                (lip[k] - truth[k]).norm() < 5e-4,
                "dot {k} moved by the other's error"
            );
        }
    }

    #[test]
    fn an_unlearned_shape_is_taken_as_measured() {
        let n = neutral();
        let mut fill = rounding_learned(&n);
        // A smile never made before: both ends 6 mm up. Far from every learned step, so the
        // seen dots stay as measured instead of being pulled towards a rounding.
        let mut smile = rounded(&n, 0.9);
        smile[0].y += 0.006;
        smile[5].y += 0.006;
        let mut lip = smile.clone();
        let out = fill.estimate(&n, &mut lip, &[true; 6], &[true; 6], &camera());
        assert_eq!(
            out,
            Estimated {
                filled: false,
                seen: false,
                disowned: None
            }
        );
        assert_eq!(lip, smile);
    }

    /// *A dot the others disown is not measured*: one dot read 10 mm off (a fast lip's
    /// blurred trail over the open mouth) is put where the others say, and they are estimated
    /// as usual; read 4.5 mm off, closer than [`DISOWN_M`], it may be a shape not learned and
    /// the step is taken as measured.
    #[test]
    fn a_dot_the_others_disown_is_not_measured() {
        let n = neutral();
        let mut fill = rounding_learned(&n);
        let truth = rounded(&n, 0.85);
        let misread = |by: Vec3| {
            let mut lip = truth.clone();
            lip[2] += by;
            lip
        };
        let mut lip = misread(Vec3::new(0.0, -0.004, -0.009));
        let out = fill.estimate(&n, &mut lip, &[true; 6], &[true; 6], &camera());
        assert_eq!(
            out,
            Estimated {
                filled: false,
                seen: true,
                disowned: Some(2)
            }
        );
        for (k, (p, q)) in lip.iter().zip(&truth).enumerate() {
            assert!((p - q).norm() < 5e-4, "dot {k}: {p:?} vs {q:?}");
        }
        let read = misread(Vec3::new(0.0, -0.0045, 0.0));
        let mut lip = read.clone();
        let out = fill.estimate(&n, &mut lip, &[true; 6], &[true; 6], &camera());
        assert_eq!(
            out,
            Estimated {
                filled: false,
                seen: false,
                disowned: None
            }
        );
        assert_eq!(lip, read);
        // Too few other dots seen to say where it should be: taken as measured.
        let seen = [false, false, true, true, true, false];
        let mut lip = misread(Vec3::new(0.0, -0.004, -0.009));
        let out = fill.estimate(&n, &mut lip, &seen, &[false; 6], &camera());
        assert_eq!(out.disowned, None);
        assert_eq!(lip[2], truth[2] + Vec3::new(0.0, -0.004, -0.009));
    }

    /// *The prior steers depth, not shape*: a shape the complete steps did not show (three
    /// dots 1.5 mm further back, as a lip rolling in) is shrunk towards the learned ones by
    /// the share the doubled prior gives the noise, a third, not by the half an undoubled one
    /// would take.
    #[test]
    fn the_prior_steers_depth_not_shape() {
        let n = neutral();
        let camera = camera();
        let mut fill = LipFill::new(n.len());
        // Learned from noisy steps: the depth noise along each dot's ray, as measured.
        let mut gauss = gauss_stream(0x2545_f491_4f6c_dd1d);
        for k in 0..2000 {
            let lip: Vec<Vec3> = rounded(&n, speech(k))
                .iter()
                .map(|p| p + (camera - p).normalize() * (RAY_NOISE_M * gauss()))
                .collect();
            fill.learn(&n, &lip);
        }
        let shape = |back: f64| {
            let mut lip = rounded(&n, 0.85);
            for p in &mut lip[3..] {
                p.z -= back;
            }
            lip
        };
        let mut lip = shape(0.0015);
        let out = fill.estimate(&n, &mut lip, &[true; 6], &[true; 6], &camera);
        assert_eq!(
            out,
            Estimated {
                filled: false,
                seen: true,
                disowned: None
            }
        );
        let kept: f64 = (3..6)
            .map(|k| (shape(0.0)[k].z - lip[k].z) / 0.0015)
            .sum::<f64>()
            / 3.0;
        assert!(
            (0.58..0.75).contains(&kept),
            "kept {kept} of the unlearned shape"
        );
    }
}
