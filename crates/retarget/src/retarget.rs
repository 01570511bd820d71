//! The streaming retarget (docs/method.md §4–§6, §8): per time step, remove the head's motion from
//! the performer's dots ([`Stabiliser`]), then move each character's points
//! ([`CharacterRetarget`]). [`Retargeter`] chains the two for one character.
//!
//! A daemon driving several characters from one performer runs one `Stabiliser` and one
//! `CharacterRetarget` per character. Steps reuse their buffers: after the first step they do
//! not allocate.

use crate::character::Character;
use crate::deform::deformation;
use crate::kabsch::{kabsch, RigidTransform};
use crate::layout::{PerformerDots, PerformerLayout};
use crate::neutral::NeutralPose;
use crate::one_euro::{OneEuro, OneEuroParams};
use crate::smooth::{smooth_closed, ShapeSmoothing};
use crate::{Error, Vec3};

/// What happens to a lip dot that is not seen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MissingDots {
    /// Seconds a missing dot keeps its last value.
    pub hold: f64,
    /// Seconds over which it then moves linearly back to neutral (0: at once).
    pub decay: f64,
}

impl Default for MissingDots {
    fn default() -> Self {
        Self {
            hold: 0.5,
            decay: 0.5,
        }
    }
}

impl MissingDots {
    /// Longest hold or decay, seconds: a day, past any take.
    pub const MAX_SECONDS: f64 = 86_400.0;

    /// Whether `v` is a hold or decay time: 0 to [`Self::MAX_SECONDS`].
    pub fn valid_seconds(v: f64) -> bool {
        v.is_finite() && (0.0..=Self::MAX_SECONDS).contains(&v)
    }

    fn validate(&self) -> Result<(), Error> {
        for (key, v) in [("missing.hold", self.hold), ("missing.decay", self.decay)] {
            if !Self::valid_seconds(v) {
                return Err(Error::InvalidConfig {
                    key,
                    reason: format!(
                        "must be a number of seconds within 0 to {}, got {v}",
                        Self::MAX_SECONDS
                    ),
                });
            }
        }
        Ok(())
    }
}

pub use crate::stabilised::StabilisedFrame;

/// Removes head motion from the performer's dots, step by step.
#[derive(Debug, Clone)]
pub struct Stabiliser {
    neutral: NeutralPose,
    missing: MissingDots,
    last_t: Option<f64>,
    /// Last good alignment current → neutral (the inverse of the head pose).
    align: RigidTransform,
    /// Per lip dot: last stabilised value and when it was seen.
    last_seen: Vec<Option<(Vec3, f64)>>,
    from: Vec<Vec3>,
    to: Vec<Vec3>,
    out: StabilisedFrame,
}

impl Stabiliser {
    /// A stabiliser for a performer's neutral pose.
    pub fn new(neutral: NeutralPose, missing: MissingDots) -> Result<Self, Error> {
        missing.validate()?;
        let n = neutral.layout.lip_dots;
        let k = neutral.layout.forehead_dots;
        Ok(Self {
            missing,
            last_t: None,
            align: RigidTransform::IDENTITY,
            last_seen: vec![None; n],
            from: Vec::with_capacity(k),
            to: Vec::with_capacity(k),
            out: StabilisedFrame {
                t: 0.0,
                lip: neutral.lip.clone(),
                confidence: vec![0.0; n],
                head: RigidTransform::IDENTITY,
                head_lost: false,
            },
            neutral,
        })
    }

    /// The neutral pose.
    pub fn neutral(&self) -> &NeutralPose {
        &self.neutral
    }

    /// The dot layout.
    pub fn layout(&self) -> PerformerLayout {
        self.neutral.layout
    }

    /// Processes one time step. `t` must not decrease.
    pub fn step(&mut self, t: f64, dots: &PerformerDots) -> Result<&StabilisedFrame, Error> {
        if !t.is_finite() {
            return Err(Error::NonFiniteTime { t });
        }
        if let Some(previous) = self.last_t {
            if t < previous {
                return Err(Error::TimeBackwards { previous, t });
            }
        }
        dots.check(self.neutral.layout)?;
        self.last_t = Some(t);

        self.from.clear();
        self.to.clear();
        for (cur, reference) in dots.forehead.iter().zip(&self.neutral.forehead_camera) {
            if let (Some(c), Some(r)) = (cur, reference) {
                self.from.push(*c);
                self.to.push(*r);
            }
        }
        let head_lost = match kabsch(&self.from, &self.to) {
            Some(align) => {
                self.align = align;
                false
            }
            None => true,
        };

        let out = &mut self.out;
        out.t = t;
        out.head = self.align.inverse();
        out.head_lost = head_lost;
        let frame = &self.neutral.frame;
        for (i, dot) in dots.lip.iter().enumerate() {
            match dot {
                Some(p) => {
                    let d = frame.to_mouth(&self.align.apply(p));
                    self.last_seen[i] = Some((d, t));
                    out.lip[i] = d;
                    out.confidence[i] = 1.0;
                }
                None => {
                    let neutral = self.neutral.lip[i];
                    out.lip[i] = match self.last_seen[i] {
                        None => neutral,
                        Some((last, seen_at)) => {
                            let age = t - seen_at;
                            if age <= self.missing.hold {
                                last
                            } else if self.missing.decay > 0.0
                                && age < self.missing.hold + self.missing.decay
                            {
                                let lambda = (age - self.missing.hold) / self.missing.decay;
                                last + (neutral - last) * lambda
                            } else {
                                neutral
                            }
                        }
                    };
                    out.confidence[i] = 0.0;
                }
            }
        }
        tracing::trace!(t, head_lost, "stabilised");
        Ok(&self.out)
    }
}

/// Per-character settings of the retarget.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CharacterSettings {
    /// Shape smoothing that makes the `curve`.
    pub smoothing: ShapeSmoothing,
    /// Temporal One Euro filter on the output points; `None` (the default) for off.
    pub one_euro: Option<OneEuroParams>,
}

/// One time step of a character as the retarget core computes it (double precision, its own
/// head frame); published as `mouthpiece_output::CharacterFrame`.
#[derive(Debug, Clone, PartialEq)]
pub struct CharacterStep {
    /// Timestamp, seconds.
    pub t: f64,
    /// `Pᵐ` in the character's mouth frame and units, in point order (One Euro filtered when
    /// configured, otherwise exactly the closed form).
    pub points: Vec<Vec3>,
    /// Per point: the confidence of the dot driving it.
    pub confidence: Vec<f64>,
    /// The smoothed closed curve (empty with `ShapeSmoothing::None`).
    pub curve: Vec<Vec3>,
    /// The character's head and eyes (docs/head.md).
    pub head: crate::head::HeadFrame,
}

/// Moves one character's points from stabilised performer dots (docs/method.md §6).
#[derive(Debug, Clone)]
pub struct CharacterRetarget {
    character: Character,
    settings: CharacterSettings,
    m: Vec<Vec3>,
    /// `D⁰` of the dot driving each point.
    d0: Vec<Vec3>,
    filters: Vec<OneEuro>,
    /// The head and eyes, driven by the performer's head or a viewpoint.
    head: crate::head::HeadDriver,
    /// The performer's neutral mouth frame axes (camera frame): the head rotation is carried
    /// into them, where it means the same to the character.
    performer_axes: nalgebra::Matrix3<f64>,
    out: CharacterStep,
}

impl CharacterRetarget {
    /// Binds a character to a performer's neutral pose: computes `M` (docs/method.md §5).
    pub fn new(
        character: Character,
        neutral: &NeutralPose,
        settings: CharacterSettings,
    ) -> Result<Self, Error> {
        settings.smoothing.validate()?;
        let n = character.len();
        if neutral.layout.lip_dots != n {
            return Err(Error::LayoutMismatch {
                character: character.name.clone(),
                points: n,
                lip_dots: neutral.layout.lip_dots,
            });
        }
        let m = deformation(
            character.m_mode,
            &neutral.lip,
            &character.neutral,
            &character.driver,
            neutral.mouth_width(),
            character.manual_m.as_deref(),
        );
        let d0 = character.driver.iter().map(|&d| neutral.lip[d]).collect();
        let filters = match settings.one_euro {
            Some(p) => vec![OneEuro::new(p); 3 * n],
            None => Vec::new(),
        };
        tracing::info!(character = %character.name, points = n, "character bound to neutral pose");
        Ok(Self {
            out: CharacterStep {
                t: 0.0,
                points: character.neutral.clone(),
                confidence: vec![0.0; n],
                curve: Vec::with_capacity(settings.smoothing.curve_len(n)),
                head: Default::default(),
            },
            head: character.head_driver(),
            performer_axes: neutral.frame.axes,
            character,
            settings,
            m,
            d0,
            filters,
        })
    }

    /// The character.
    pub fn character(&self) -> &Character {
        &self.character
    }

    /// The deformation parameters `M`, per point (reported in `hello`).
    pub fn m(&self) -> &[Vec3] {
        &self.m
    }

    /// The head and eyes.
    pub fn head(&self) -> &crate::head::HeadDriver {
        &self.head
    }

    /// Turns the head to `point` (character model frame), or back to following the
    /// performer (`None`); see [`crate::head::HeadDriver::look_at`].
    pub fn look_at(&mut self, point: Option<Vec3>) -> Result<Option<bool>, Error> {
        self.head.look_at(point)
    }

    /// The settings.
    pub fn settings(&self) -> &CharacterSettings {
        &self.settings
    }

    /// The last [`CharacterRetarget::apply`]'s result (the neutral pose, confidence 0,
    /// before the first).
    pub fn output(&self) -> &CharacterStep {
        &self.out
    }

    /// `Pᵐ = P⁰ + (Dᵐ − D⁰) ⊙ M` for every point, then the optional One Euro filter and the
    /// curve.
    pub fn apply(&mut self, performer: &StabilisedFrame) -> &CharacterStep {
        let out = &mut self.out;
        out.t = performer.t;
        for (n, &d) in self.character.driver.iter().enumerate() {
            let delta = performer.lip[d] - self.d0[n];
            let mut p = self.character.neutral[n] + delta.component_mul(&self.m[n]);
            if !self.filters.is_empty() {
                for k in 0..3 {
                    p[k] = self.filters[3 * n + k].filter(performer.t, p[k]);
                }
            }
            out.points[n] = p;
            out.confidence[n] = performer.confidence[d];
        }
        smooth_closed(&out.points, &self.settings.smoothing, &mut out.curve);
        let p = &self.performer_axes;
        let relative = p.transpose() * performer.head.rotation * p;
        let relative = nalgebra::UnitQuaternion::from_rotation_matrix(
            &nalgebra::Rotation3::from_matrix_unchecked(relative),
        );
        out.head = *self.head.step(performer.t, &relative);
        &self.out
    }
}

/// One performer, one character: [`Stabiliser`] then [`CharacterRetarget`].
#[derive(Debug, Clone)]
pub struct Retargeter {
    stabiliser: Stabiliser,
    character: CharacterRetarget,
}

/// Settings of a [`Retargeter`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RetargetConfig {
    /// Missing lip dots.
    pub missing: MissingDots,
    /// Character output settings.
    pub character: CharacterSettings,
}

/// What a [`Retargeter`] step produces.
#[derive(Debug, Clone, Copy)]
pub struct RetargetOutput<'a> {
    /// The performer after head-motion removal (with head pose).
    pub performer: &'a StabilisedFrame,
    /// The character's points.
    pub character: &'a CharacterStep,
}

impl Retargeter {
    /// A retargeter for a character and a performer's neutral pose.
    pub fn new(
        character: Character,
        neutral: NeutralPose,
        config: RetargetConfig,
    ) -> Result<Self, Error> {
        let character = CharacterRetarget::new(character, &neutral, config.character)?;
        Ok(Self {
            stabiliser: Stabiliser::new(neutral, config.missing)?,
            character,
        })
    }

    /// Processes one time step of raw camera-frame dots.
    pub fn step(&mut self, t: f64, dots: &PerformerDots) -> Result<RetargetOutput<'_>, Error> {
        let performer = self.stabiliser.step(t, dots)?;
        let character = self.character.apply(performer);
        Ok(RetargetOutput {
            performer,
            character,
        })
    }

    /// The performer side.
    pub fn stabiliser(&self) -> &Stabiliser {
        &self.stabiliser
    }

    /// The character side.
    pub fn character(&self) -> &CharacterRetarget {
        &self.character
    }

    /// The character side, to change (e.g. [`CharacterRetarget::look_at`]).
    pub fn character_mut(&mut self) -> &mut CharacterRetarget {
        &mut self.character
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hold_and_decay_are_within_a_day() {
        let ok = MissingDots {
            hold: MissingDots::MAX_SECONDS,
            decay: 0.0,
        };
        assert!(ok.validate().is_ok());
        for (hold, decay) in [
            (1e300, 0.5),
            (0.5, 1e300),
            (-1.0, 0.5),
            (0.5, f64::INFINITY),
        ] {
            let err = MissingDots { hold, decay }
                .validate()
                .unwrap_err()
                .to_string();
            assert!(err.contains("missing."), "{err}");
        }
    }
}
