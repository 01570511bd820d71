//! The character's head following the performer (docs/head.md), measured against the same
//! rule applied to the performer's true head rotation.

use mouthpiece_retarget::head::{HeadDriver, FORWARD};
use mouthpiece_retarget::{Character, PerformerLayout};
use mouthpiece_synth::GroundTruth;
use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion};

use crate::measures::{mean_rotation, rotation, true_neutral};
use crate::{EvaluateError, FrameView, Measure};

/// Angles between the character head the pipeline gave and the one the head rule gives for
/// the true head rotation (relative to the calibration window's mean), over the frames where
/// the scaled true rotation is within the character's reach.
#[derive(Debug, Clone)]
pub struct CharacterHeadFollow {
    character: Character,
    layout: PerformerLayout,
    calibration_s: f64,
    /// The true head rotation at calibration and the true neutral mouth frame's axes.
    neutral: Option<(Matrix3<f64>, Matrix3<f64>)>,
    /// The rule on the true rotation; started on the frame after calibration, as the
    /// pipeline's own driver is.
    reference: Option<HeadDriver>,
    pub sq_sum: f64,
    pub frames: usize,
    /// Frames where the rule had to limit the (true) rotation.
    pub limited: usize,
    /// Frames where the character's head faced a direction out of its reach (must be 0).
    pub outside: usize,
}

impl CharacterHeadFollow {
    pub fn new(character: Character, layout: PerformerLayout, calibration_s: f64) -> Self {
        CharacterHeadFollow {
            character,
            layout,
            calibration_s,
            neutral: None,
            reference: None,
            sq_sum: 0.0,
            frames: 0,
            limited: 0,
            outside: 0,
        }
    }

    /// RMS angle within reach, degrees.
    pub fn rms_deg(&self) -> f64 {
        (self.sq_sum / self.frames.max(1) as f64)
            .sqrt()
            .to_degrees()
    }
}

impl Measure for CharacterHeadFollow {
    fn neutral_taken(
        &mut self,
        f: &FrameView,
        history: &[(f64, GroundTruth)],
    ) -> Result<(), EvaluateError> {
        let at_calibration = mean_rotation(history, f.t, self.calibration_s);
        let neutral = true_neutral(history, f.t, self.calibration_s, self.layout)?;
        self.neutral = Some((at_calibration, neutral.frame.axes));
        self.reference = None;
        Ok(())
    }

    fn frame(&mut self, f: &FrameView) -> Result<(), EvaluateError> {
        let Some((at_calibration, axes)) = self.neutral else {
            return Ok(());
        };
        let Some(driver) = &mut self.reference else {
            self.reference = Some(self.character.head_driver());
            return Ok(());
        };
        let truth_rel = rotation(f.truth) * at_calibration.transpose();
        let relative = axes.transpose() * truth_rel * axes;
        let relative =
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(relative));
        let limited = driver.follow_target(&relative).1;
        let expected = driver.step(f.t, &relative).rotation;
        let (Some(ours), true) = (&f.line.retarget.character_head, f.counted) else {
            return Ok(());
        };
        let [w, x, y, z] = ours.rotation;
        let ours = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
        let a = &self.character.frame.axes;
        let forward = a.transpose() * (ours * (a * FORWARD));
        if !self.character.head.reach.contains_within(&forward, 1e-9) {
            self.outside += 1;
        }
        if limited {
            self.limited += 1;
        } else {
            let angle = ours.angle_to(&expected);
            self.sq_sum += angle * angle;
            self.frames += 1;
        }
        Ok(())
    }
}
