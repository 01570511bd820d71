//! The built-in measures: naming and 3D error, head rotation error, character error.

use mouthpiece_retarget::{
    Character, NeutralAccumulator, NeutralPose, PerformerDots, PerformerLayout, RetargetConfig,
    Retargeter,
};
use mouthpiece_synth::GroundTruth;
use nalgebra::{Matrix3, Vector3};

use crate::{measured_settings, EvaluateError, FrameView, Measure};

/// A correctly named dot farther than this from its true centre is logged (debug).
const FAR_FROM_TRUTH_M: f64 = 0.006;

fn v3(a: [f64; 3]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}

pub(crate) fn rotation(gt: &GroundTruth) -> Matrix3<f64> {
    let m = gt.head.rotation_matrix();
    Matrix3::new(
        m[0][0], m[0][1], m[0][2], m[1][0], m[1][1], m[1][2], m[2][0], m[2][1], m[2][2],
    )
}

/// The true dots of a frame, as the tracker reports its own.
pub fn true_dots(gt: &GroundTruth, layout: PerformerLayout) -> PerformerDots {
    let mut d = PerformerDots::new(layout);
    for (i, slot) in d.lip.iter_mut().enumerate() {
        *slot = gt.point(&PerformerLayout::lip_name(i)).map(v3);
    }
    for (i, slot) in d.forehead.iter_mut().enumerate() {
        *slot = gt.point(&PerformerLayout::forehead_name(i)).map(v3);
    }
    d
}

/// Found, wrong and hidden names, and the 3D error of the found ones.
#[derive(Debug, Clone, Default)]
pub struct Naming {
    pub visible: usize,
    pub found_named: usize,
    pub wrong: usize,
    pub named_hidden: usize,
    pub err_sq_sum: f64,
    /// Per dot (`D1..`, then `F1..`).
    pub per_dot: Vec<DotStats>,
}

/// One dot's figures over a session.
#[derive(Debug, Clone, Default)]
pub struct DotStats {
    pub visible: usize,
    pub found_named: usize,
    pub wrong: usize,
    /// Sum of (tracked − true), camera frame, metres: the bias.
    pub err_sum: Vector3<f64>,
    /// Sum of squared error components.
    pub err_sq: Vector3<f64>,
}

impl Naming {
    pub fn new(dots: usize) -> Self {
        Naming {
            per_dot: vec![DotStats::default(); dots],
            ..Naming::default()
        }
    }

    pub fn found_pct(&self) -> f64 {
        100.0 * self.found_named as f64 / self.visible.max(1) as f64
    }

    pub fn rms_mm(&self) -> f64 {
        1e3 * (self.err_sq_sum / self.found_named.max(1) as f64).sqrt()
    }
}

impl Measure for Naming {
    fn frame(&mut self, f: &FrameView) -> Result<(), EvaluateError> {
        if !f.counted {
            return Ok(());
        }
        let tracked = f.tracked;
        let points = tracked.dots.lip.iter().chain(&tracked.dots.forehead);
        for (i, (name, p)) in f.names.iter().zip(points).enumerate() {
            let visible = f.truth.is_visible(name);
            if visible {
                self.visible += 1;
                self.per_dot[i].visible += 1;
            }
            let Some(p) = p else {
                if visible {
                    tracing::debug!(t = f.t, dot = %name, "visible dot not found");
                }
                continue;
            };
            // Naming is judged in the image (which blob got the name); how far the 3D point
            // is from the truth is the 3D error, reported apart.
            let px = tracked.pixels[i].expect("a named dot has a pixel");
            if !f.names_right(i, px) {
                self.wrong += 1;
                self.per_dot[i].wrong += 1;
                tracing::debug!(t = f.t, dot = %name, nearest = ?f.nearest_dot(px), "wrongly named");
            } else if visible {
                let e = p - f.true_points[i];
                let dist = e.norm();
                self.found_named += 1;
                self.err_sq_sum += dist * dist;
                let d = &mut self.per_dot[i];
                d.found_named += 1;
                d.err_sum += e;
                d.err_sq += e.component_mul(&e);
                if dist > FAR_FROM_TRUTH_M {
                    tracing::debug!(t = f.t, dot = %name, dist_mm = dist * 1e3, "far from its true position");
                }
            } else {
                self.named_hidden += 1;
            }
        }
        Ok(())
    }
}

/// The tracked head rotation against the true one, both relative to the pose at
/// calibration (the mean rotation over the calibration window: the neutral pose averages
/// it).
#[derive(Debug, Clone)]
pub struct HeadError {
    pub sq_sum: f64,
    pub frames: usize,
    calibration_s: f64,
    at_calibration: Matrix3<f64>,
}

impl HeadError {
    pub fn new(calibration_s: f64) -> Self {
        HeadError {
            sq_sum: 0.0,
            frames: 0,
            calibration_s,
            at_calibration: Matrix3::identity(),
        }
    }

    pub fn rms_deg(&self) -> f64 {
        (self.sq_sum / self.frames.max(1) as f64)
            .sqrt()
            .to_degrees()
    }
}

impl Default for HeadError {
    fn default() -> Self {
        HeadError::new(1.0)
    }
}

/// The true head rotation averaged over the calibration window that ends at `t`.
pub(crate) fn mean_rotation(history: &[(f64, GroundTruth)], t: f64, seconds: f64) -> Matrix3<f64> {
    let rotations: Vec<Matrix3<f64>> = window(history, t, seconds).map(rotation).collect();
    let mean = rotations.iter().sum::<Matrix3<f64>>() / rotations.len().max(1) as f64;
    nalgebra::Rotation3::from_matrix(&mean).into_inner()
}

/// The neutral pose taken from the true dots of the calibration window that ends at `t`:
/// what the tracker would have taken with perfect dots.
pub(crate) fn true_neutral(
    history: &[(f64, GroundTruth)],
    t: f64,
    seconds: f64,
    layout: PerformerLayout,
) -> Result<NeutralPose, EvaluateError> {
    let mut acc = NeutralAccumulator::new(layout);
    for g in window(history, t, seconds) {
        acc.push(&true_dots(g, layout))?;
    }
    Ok(acc.finish()?)
}

/// The retarget core bound to `neutral` with the measured settings: the reference a measure
/// feeds the true dots.
pub(crate) fn reference_retargeter(
    character: &Character,
    neutral: NeutralPose,
) -> Result<Retargeter, EvaluateError> {
    let cfg = RetargetConfig {
        missing: Default::default(),
        character: measured_settings(),
    };
    Ok(Retargeter::new(character.clone(), neutral, cfg)?)
}

/// The ground truth of the calibration window that ends at `t`.
pub(crate) fn window(
    history: &[(f64, GroundTruth)],
    t: f64,
    seconds: f64,
) -> impl Iterator<Item = &GroundTruth> {
    // 1 µs: frame times are sums of intervals.
    history
        .iter()
        .filter(move |(ht, _)| *ht >= t - seconds - 1e-6)
        .map(|(_, g)| g)
}

impl Measure for HeadError {
    fn neutral_taken(
        &mut self,
        f: &FrameView,
        history: &[(f64, GroundTruth)],
    ) -> Result<(), EvaluateError> {
        self.at_calibration = mean_rotation(history, f.t, self.calibration_s);
        Ok(())
    }

    fn frame(&mut self, f: &FrameView) -> Result<(), EvaluateError> {
        if !f.counted {
            return Ok(());
        }
        if let Some(s) = &f.tracked.stabilised {
            let truth_rel = rotation(f.truth) * self.at_calibration.transpose();
            let diff = s.head.rotation.transpose() * truth_rel;
            let angle = ((diff.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos();
            self.sq_sum += angle * angle;
            self.frames += 1;
        }
        Ok(())
    }
}

/// The character points against those the retarget core gives from the true dots with the
/// same neutral window, as a share of the character's mouth width.
#[derive(Debug, Clone, Default)]
pub struct CharacterError {
    pub sq_sum: f64,
    pub count: usize,
    /// Over the points whose driving lip dot is visible.
    pub visible_sq_sum: f64,
    pub visible_count: usize,
    /// The character's mouth width.
    pub width: f64,
}

impl CharacterError {
    /// Over every character point (% of the width).
    pub fn rms_pct(&self) -> f64 {
        100.0 * (self.sq_sum / self.count.max(1) as f64).sqrt() / self.width
    }

    /// Over the character points whose driving lip dot is visible.
    pub fn visible_rms_pct(&self) -> f64 {
        100.0 * (self.visible_sq_sum / self.visible_count.max(1) as f64).sqrt() / self.width
    }
}

/// Measures [`CharacterError`]: the retarget core fed the true dots, bound to the neutral
/// pose of the tracker's calibration window.
pub(crate) struct CharacterMeasure {
    character: Character,
    layout: PerformerLayout,
    calibration_s: f64,
    reference: Option<Retargeter>,
    pub(crate) error: CharacterError,
}

impl CharacterMeasure {
    pub(crate) fn new(character: Character, layout: PerformerLayout, calibration_s: f64) -> Self {
        CharacterMeasure {
            error: CharacterError {
                width: character.mouth_width(),
                ..CharacterError::default()
            },
            character,
            layout,
            calibration_s,
            reference: None,
        }
    }
}

impl Measure for CharacterMeasure {
    fn neutral_taken(
        &mut self,
        f: &FrameView,
        history: &[(f64, GroundTruth)],
    ) -> Result<(), EvaluateError> {
        let neutral = true_neutral(history, f.t, self.calibration_s, self.layout)?;
        let mut r = reference_retargeter(&self.character, neutral)?;
        // Bring the reference's clock to now.
        r.step(f.t, &true_dots(f.truth, self.layout))?;
        self.reference = Some(r);
        Ok(())
    }

    fn frame(&mut self, f: &FrameView) -> Result<(), EvaluateError> {
        if !f.counted {
            return Ok(());
        }
        let Some(r) = &mut self.reference else {
            return Ok(());
        };
        let out = r.step(f.t, &true_dots(f.truth, self.layout))?;
        let e = &mut self.error;
        for (k, ((_, a), b)) in f
            .line
            .retarget
            .points
            .0
            .iter()
            .zip(&out.character.points)
            .enumerate()
        {
            let d2 = (v3(*a) - b).norm_squared();
            e.sq_sum += d2;
            e.count += 1;
            if f.truth.is_visible(&f.names[self.character.driver[k]]) {
                e.visible_sq_sum += d2;
                e.visible_count += 1;
            }
        }
        Ok(())
    }
}
