//! The rig's accuracy (docs/rig.md), measured inside `mouthpiece evaluate`: the jaw against the
//! synthetic performer's own mouth state, and every named curve against its definition
//! applied to the ground-truth dots.
//!
//! Per session, over the frames after calibration from the evaluation's `--skip` on:
//! - *jaw RMS*: the rig's jaw angle against the synthetic jaw's rotation about its own hinge
//!   (wherever the session put it: `SynthConfig::jaw`), in degrees;
//! - *slide RMS*: the rig's jaw slide against the synthetic jaw's sideways slide (0 unless the
//!   session slides it), in mm;
//! - *curve RMS*: each curve against the same curve computed from the ground-truth dots
//!   (stabilised by the retarget core from the true dots, the same neutral frames), with the
//!   ranges the character's output uses (its own `[rig.ranges]`, else the tracked rig's); the
//!   worst curve is reported with its name;
//! - *correlations*: `jawOpen` with the synthetic jaw angle, the rig's rounding
//!   (`mouthFunnel + mouthPucker`, which split it by the lips' opening) with its rounding,
//!   and the same from the true dots with the rounding beside the rounding's standard
//!   deviation (a performer who hardly rounds leaves the correlation to the noise).
//!
//! Every curve of [`CURVE_NAMES`] is compared with its definition ([`RigModel::measure`]
//! applied to the true dots), the ones added after the first 18 included.

use mouthpiece_retarget::rig::{curves_from, RigModel, RigSettings, CURVES, CURVE_NAMES};
use mouthpiece_retarget::{Character, PerformerLayout, Retargeter};
use mouthpiece_synth::{GroundTruth, MouthTruth};

use crate::measures::{reference_retargeter, true_dots, true_neutral};
use crate::{EvaluateError, FrameView, Measure};

/// Pearson correlation accumulator.
#[derive(Debug, Clone, Copy, Default)]
pub struct Correlation {
    n: f64,
    sx: f64,
    sy: f64,
    sxx: f64,
    syy: f64,
    sxy: f64,
}

impl Correlation {
    pub fn push(&mut self, x: f64, y: f64) {
        self.n += 1.0;
        self.sx += x;
        self.sy += y;
        self.sxx += x * x;
        self.syy += y * y;
        self.sxy += x * y;
    }

    pub fn value(&self) -> f64 {
        let n = self.n.max(1.0);
        let cov = self.sxy / n - self.sx * self.sy / (n * n);
        let vx = self.sxx / n - self.sx * self.sx / (n * n);
        let vy = self.syy / n - self.sy * self.sy / (n * n);
        if vx <= 0.0 || vy <= 0.0 {
            return f64::NAN;
        }
        cov / (vx * vy).sqrt()
    }

    /// The standard deviation of the second variable (population, over what was pushed).
    pub fn y_sd(&self) -> f64 {
        let n = self.n.max(1.0);
        (self.syy / n - self.sy * self.sy / (n * n)).max(0.0).sqrt()
    }
}

/// One session's rig figures.
#[derive(Debug, Clone, Default)]
pub struct RigMetrics {
    pub frames: usize,
    pub jaw_sq: f64,
    pub slide_sq: f64,
    pub curve_sq: [f64; CURVES],
    pub jaw_open: Correlation,
    /// The rounding, `mouthFunnel + mouthPucker`, against the synthetic rounding.
    pub funnel: Correlation,
    /// The same from the true dots against the rounding: what the definition itself
    /// reaches on the session, without the tracker's error.
    pub funnel_true: Correlation,
}

impl RigMetrics {
    pub fn jaw_rms_deg(&self) -> f64 {
        (self.jaw_sq / self.frames.max(1) as f64).sqrt()
    }
    pub fn slide_rms_mm(&self) -> f64 {
        1e3 * (self.slide_sq / self.frames.max(1) as f64).sqrt()
    }
    pub fn curve_rms(&self, i: usize) -> f64 {
        (self.curve_sq[i] / self.frames.max(1) as f64).sqrt()
    }
    /// The figures the targets ([`RigTargets`]) are on, in a line.
    pub fn summary(&self) -> String {
        let (worst, rms) = self.worst_curve();
        format!(
            "{} frames: jaw RMS {:.2}°, slide RMS {:.2} mm, worst curve {worst} {rms:.3}, jawOpen r {:.3}",
            self.frames,
            self.jaw_rms_deg(),
            self.slide_rms_mm(),
            self.jaw_open.value()
        )
    }

    /// The worst curve: (name, RMS).
    pub fn worst_curve(&self) -> (&'static str, f64) {
        (0..CURVES)
            .map(|i| (CURVE_NAMES[i], self.curve_rms(i)))
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .expect("curves")
    }
}

/// The rig's accuracy targets (docs/rig.md): the jaw within 1.5° RMS of the synthetic jaw's
/// rotation about its own hinge, its slide within 1 mm RMS of the synthetic slide, every curve
/// within 0.05 RMS of its definition applied to the true dots, and `jawOpen` correlated with
/// the synthetic jaw at r ≥ 0.95.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigTargets {
    pub jaw_deg: f64,
    pub slide_mm: f64,
    pub curve_rms: f64,
    pub jaw_open_r: f64,
}

impl RigTargets {
    pub const TARGETS: RigTargets = RigTargets {
        jaw_deg: 1.5,
        slide_mm: 1.0,
        curve_rms: 0.05,
        jaw_open_r: 0.95,
    };

    /// Every figure of `m` against these targets; the error lists the session's figures.
    pub fn check(&self, m: &RigMetrics) -> Result<(), crate::Missed> {
        let (_, rms) = m.worst_curve();
        // NaN figures fail (every comparison with NaN is false).
        let ok = m.frames > 0
            && m.jaw_rms_deg() <= self.jaw_deg
            && m.slide_rms_mm() <= self.slide_mm
            && rms <= self.curve_rms
            && m.jaw_open.value() >= self.jaw_open_r;
        if ok {
            Ok(())
        } else {
            Err(crate::Missed {
                figures: m.summary(),
                limits: format!("targets {self:?}"),
            })
        }
    }
}

/// One counted frame, kept when [`RigAccuracy::keep_frames`] asks (`mouthpiece evaluate
/// --rig-frames`): what an outside analysis needs to recompute the figures and split the
/// error by its source.
#[derive(Debug, Clone)]
pub struct RigFrameRecord {
    pub t: f64,
    /// The synthetic mouth's own state (jaw angle in radians, spread, rounding, raise,
    /// roll-in).
    pub mouth: MouthTruth,
    /// Every curve from the tracked dots and from the true dots, [`CURVE_NAMES`] order.
    pub tracked: [f64; CURVES],
    pub reference: [f64; CURVES],
    /// The lip dots (neutral mouth frame, metres) the two rigs measured (the tracked ones as the
    /// rig estimated them: the unseen dots from the seen, the seen with their ray noise), and each rig's neutral dots.
    pub tracked_lip: Vec<[f64; 3]>,
    /// The tracked lip dots as the stabiliser gave them to the rig (before its estimate).
    pub stabilised_lip: Vec<[f64; 3]>,
    pub reference_lip: Vec<[f64; 3]>,
    pub tracked_neutral: Vec<[f64; 3]>,
    pub reference_neutral: Vec<[f64; 3]>,
    /// The ranges both curves were computed with.
    pub ranges: [f64; CURVES],
    /// Per tracked lip dot: whether it was seen this frame (not held).
    pub tracked_seen: Vec<bool>,
    /// The camera's centre in the tracked neutral mouth frame (metres): a tracked dot's depth
    /// error lies along the line to it.
    pub camera: [f64; 3],
}

/// The measurement in progress: the pipeline's rig against the one the ground truth gives.
#[derive(Debug)]
pub struct RigAccuracy {
    settings: RigSettings,
    character: Character,
    layout: PerformerLayout,
    calibration_s: f64,
    /// The retarget core fed with the true dots (their stabilised frames) and the rig model
    /// of its neutral pose.
    reference: Option<(Retargeter, RigModel)>,
    pub metrics: RigMetrics,
    /// Every counted frame, when kept.
    pub frames: Option<Vec<RigFrameRecord>>,
}

impl RigAccuracy {
    pub fn new(
        settings: RigSettings,
        character: Character,
        layout: PerformerLayout,
        calibration_s: f64,
    ) -> Self {
        Self {
            settings,
            character,
            layout,
            calibration_s,
            reference: None,
            metrics: RigMetrics::default(),
            frames: None,
        }
    }

    /// Keeps every counted frame in [`Self::frames`].
    pub fn keep_frames(mut self) -> Self {
        self.frames = Some(Vec::new());
        self
    }
}

impl Measure for RigAccuracy {
    fn neutral_taken(
        &mut self,
        f: &FrameView,
        history: &[(f64, GroundTruth)],
    ) -> Result<(), EvaluateError> {
        let neutral = true_neutral(history, f.t, self.calibration_s, self.layout)?;
        let r = reference_retargeter(&self.character, neutral)?;
        let model = RigModel::new(r.stabiliser().neutral(), &self.settings)?;
        self.reference = Some((r, model));
        Ok(())
    }

    fn frame(&mut self, f: &FrameView) -> Result<(), EvaluateError> {
        let Some((r, model)) = &mut self.reference else {
            return Ok(());
        };
        let out = r.step(f.t, &true_dots(f.truth, self.layout))?;
        let (true, Some(rig), Some(mouth)) = (f.counted, f.line.rig, f.truth.mouth.as_ref()) else {
            return Ok(());
        };
        let ours = *rig.measures();
        let theirs = model.measure(&out.performer.lip);
        let (mut a, mut b) = ([0.0; CURVES], [0.0; CURVES]);
        // The ranges the character's output uses: its own, else the performer's.
        let ranges = rig.ranges_for(&self.character.rig_ranges);
        curves_from(&ours, &ranges, &mut a);
        curves_from(&theirs, &ranges, &mut b);
        let m = &mut self.metrics;
        m.frames += 1;
        m.jaw_sq += (ours.jaw_angle - mouth.jaw).to_degrees().powi(2);
        m.slide_sq += (ours.jaw_slide - mouth.slide).powi(2);
        for ((sq, x), y) in m.curve_sq.iter_mut().zip(a).zip(b) {
            *sq += (x - y).powi(2);
        }
        m.jaw_open.push(a[0], mouth.jaw);
        // The rounding: mouthFunnel and mouthPucker split it by the lips' opening.
        m.funnel.push(a[2] + a[3], mouth.round);
        m.funnel_true.push(b[2] + b[3], mouth.round);
        if let (Some(frames), Some(tracked)) = (&mut self.frames, &f.tracked.stabilised) {
            let xyz = |v: &[nalgebra::Vector3<f64>]| v.iter().map(|p| [p.x, p.y, p.z]).collect();
            frames.push(RigFrameRecord {
                t: f.t,
                mouth: *mouth,
                tracked: a,
                reference: b,
                tracked_lip: xyz(rig.measured_lip()),
                stabilised_lip: xyz(&tracked.lip),
                reference_lip: xyz(&out.performer.lip),
                tracked_neutral: xyz(rig.model().neutral()),
                reference_neutral: xyz(model.neutral()),
                ranges,
                tracked_seen: tracked.confidence.iter().map(|&c| c > 0.0).collect(),
                camera: {
                    let c = rig.model().camera_in_mouth(&tracked.head);
                    [c.x, c.y, c.z]
                },
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::Correlation;

    #[test]
    fn correlation_and_spread_agree_with_their_definitions() {
        let mut c = Correlation::default();
        // y = 2x + 1 with x = 0..4: r = 1, and y's population SD is 2 · sqrt(2).
        for x in 0..5 {
            c.push(x as f64, 2.0 * x as f64 + 1.0);
        }
        assert!((c.value() - 1.0).abs() < 1e-12);
        assert!((c.y_sd() - 2.0 * 2f64.sqrt()).abs() < 1e-12);
        // Anti-correlated, and a constant second variable has no correlation (NaN), SD 0.
        let mut a = Correlation::default();
        let mut k = Correlation::default();
        for x in 0..5 {
            a.push(x as f64, -(x as f64));
            k.push(x as f64, 0.3);
        }
        assert!((a.value() + 1.0).abs() < 1e-12);
        assert!(k.value().is_nan());
        assert!(k.y_sd() < 1e-9);
    }
}
