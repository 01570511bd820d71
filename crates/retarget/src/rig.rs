//! What engine rigs take (docs/rig.md): a jaw bone, the rigid motion of each lip, and mouth
//! curves named and ranged as Apple's ARKit blend shapes, from the stabilised performer dots.
//!
//! Everything is in the performer's neutral mouth frame (docs/method.md §2: x towards the
//! performer's left, y up, z out of the mouth; metres) and relative to the neutral pose.
//!
//! - **Unseen dots**: a dot the stabiliser holds is measured where the dots seen in the same
//!   step put it ([`crate::lip_fill`]), not where it was last seen.
//! - **Jaw**: a rigid body turning about the hinge axis (the line through the condyles) and
//!   sliding along it. The axis is the mouth frame's x axis (parallel to the corner line: the
//!   face is symmetric); its pivot is placed from the neutral mouth width with anatomical
//!   ratios ([`RigSettings::hinge_up`], [`RigSettings::hinge_back`]). Per step, the opening
//!   angle is the angle the lower-lip centroid turned about the pivot, after the forward
//!   motion the upper lip shares (lips pushed out) is taken off; the slide is the lower lip's
//!   sideways shift against the upper lip's.
//! - **Lips**: for each lip (its dots and both corners) the rigid motion that best carries the
//!   neutral dots onto the current ones (Kabsch), and the residual RMS it leaves.
//! - **Curves**: [`CURVE_NAMES`], each `clamp(measure / range, 0, 1)`; the measures are means
//!   and least-squares fits over several dots (never one distance), depth counts at
//!   [`DEPTH_WEIGHT`] and each side's stretch is fitted about the mouth's own centre; the
//!   ranges come from the defaults scaled by the performer's mouth width, widened by what the
//!   performer does in the first seconds after the neutral pose ([`RigSettings::learn_s`]),
//!   and overridable per curve ([`RigSettings::ranges`]) and per character
//!   ([`RangeOverrides`]).
//!
//! A step allocates nothing.

use nalgebra::Rotation3;
use serde::{Deserialize, Serialize};

use crate::kabsch::kabsch;
use crate::lip_fill::LipFill;
use crate::stabilised::StabilisedFrame;
use crate::{Error, MouthFrame, Named, NeutralPose, Vec3};

/// The curve names, in wire order (ARKit's blend-shape names; left and right are the
/// performer's): the output vocabulary's one list.
pub use mouthpiece_output::curves::{
    curve_index, pascal_name, visemes_from, CURVES, CURVE_NAMES, PASCAL_NAMES, VISEMES,
    VISEME_NAMES, VISEME_NAMES_VRM0,
};

mod model;
pub use model::*;

/// Default range of each curve's measure: degrees for `jawOpen`, mouth widths for the rest.
pub const DEFAULT_RANGES: [f64; CURVES] = [
    25.0, // jawOpen: degrees of jaw rotation
    25.0, // mouthClose: degrees of the jaw's opening the sealed lips hide (jawOpen's range)
    0.15, // mouthFunnel: the rounding with the lips open
    0.15, // mouthPucker: the rounding with the lips closed
    0.10, // mouthLeft
    0.10, // mouthRight
    0.12, // mouthSmileLeft: corner up
    0.12, // mouthSmileRight
    0.15, // mouthStretchLeft: corner out
    0.15, // mouthStretchRight
    0.10, // mouthRollUpper
    0.16, // mouthRollLower
    0.10, // mouthUpperUpLeft
    0.10, // mouthUpperUpRight
    0.12, // mouthLowerDownLeft
    0.12, // mouthLowerDownRight
    0.15, // mouthPressLeft
    0.15, // mouthPressRight
    0.20, // jawForward: the lower lip's distance from the hinge grows
    0.18, // jawLeft: the slide along the hinge
    0.18, // jawRight
    0.11, // mouthFrownLeft: corner down
    0.11, // mouthFrownRight
    0.14, // mouthShrugUpper: the upper lip up and out
    0.16, // mouthShrugLower: the lower lip up and out
    0.30, // mouthDimpleLeft: corner back against the upper lip (wide: depth noise)
    0.30, // mouthDimpleRight
];

/// The index of `mouthClose`, whose range is `jawOpen`'s unless it is given its own (ARKit's
/// pairing: equal `jawOpen` and `mouthClose` mean sealed lips).
const CLOSE: usize = 1;

/// The weight of depth (z) against the lateral axes (x, y) where a measure combines them:
/// inverse-variance weighting. A depth camera's depth noise on a lip dot is about twice its
/// lateral noise (standard deviation; `mouthpiece evaluate --per-dot`: Kinect-like
/// 1.2–1.6 mm against 0.3–0.75 mm, RealSense-like 0.7–1.0 mm against 0.3–0.5 mm), so its
/// variance is about four times as large and a millimetre of depth counts a quarter.
pub const DEPTH_WEIGHT: f64 = 0.25;

/// Rig settings: the `[rig]` table of a character file or of the daemon configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RigSettings {
    /// Hinge pivot height above the mouth centre, in neutral mouth widths.
    pub hinge_up: f64,
    /// Hinge pivot depth behind the mouth centre, in neutral mouth widths.
    pub hinge_back: f64,
    /// Seconds after the neutral pose during which ranges widen to what the performer does
    /// (0: the defaults as they are).
    pub learn_s: f64,
    /// A seen lip dot's depth noise along the camera's ray, metres (the camera's: docs/rig.md,
    /// "The dots the rig measures").
    pub depth_noise_m: f64,
    /// A seen lip dot's noise across the camera's ray, metres (its pixel's precision at the
    /// booth's distance).
    pub pixel_noise_m: f64,
    /// Curve name → range of its measure (degrees for `jawOpen`, mouth widths for the
    /// others). A range given here is used as it is (not widened by learning).
    pub ranges: Named<f64>,
}

impl Default for RigSettings {
    fn default() -> Self {
        Self {
            hinge_up: 0.5,
            hinge_back: 1.6,
            learn_s: 4.0,
            depth_noise_m: crate::lip_fill::RAY_NOISE_M,
            pixel_noise_m: crate::lip_fill::ACROSS_NOISE_M,
            ranges: Named::default(),
        }
    }
}

impl RigSettings {
    /// Checks the values; `prefix` names the table (`rig`, `characters.wolf.rig`).
    pub fn validate(&self, prefix: &str) -> Result<(), Error> {
        let bad = |key: &str, reason: String| Error::InvalidSetting {
            key: format!("{prefix}.{key}"),
            reason,
        };
        for (key, v, lo, hi) in [
            ("hinge_up", self.hinge_up, -5.0, 5.0),
            ("hinge_back", self.hinge_back, 0.2, 10.0),
            ("learn_s", self.learn_s, 0.0, 600.0),
            ("depth_noise_m", self.depth_noise_m, 0.0001, 0.02),
            ("pixel_noise_m", self.pixel_noise_m, 0.00005, 0.005),
        ] {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err(bad(key, format!("must be within {lo}..={hi}, got {v}")));
            }
        }
        for (name, v) in self.ranges.iter() {
            if curve_index(name).is_none() {
                return Err(bad(
                    &format!("ranges.{name}"),
                    format!("is not a curve name (one of {})", CURVE_NAMES.join(", ")),
                ));
            }
            if !range_ok(*v) {
                return Err(bad(&format!("ranges.{name}"), range_reason(*v)));
            }
        }
        let mut seen = [false; CURVES];
        for (name, _) in self.ranges.iter() {
            let i = curve_index(name).expect("checked");
            if seen[i] {
                return Err(bad(&format!("ranges.{name}"), "is given twice".into()));
            }
            seen[i] = true;
        }
        Ok(())
    }

    /// Parses a `[rig]` table given as TOML text (for tests and tools).
    pub fn from_toml_str(text: &str) -> Result<Self, Error> {
        let s: Self = toml::from_str(text).map_err(|e| Error::InvalidSetting {
            key: "rig".into(),
            reason: e.to_string(),
        })?;
        s.validate("rig")?;
        Ok(s)
    }

    /// The configured range of curve `i`, if any.
    fn configured(&self, i: usize) -> Option<f64> {
        self.ranges.get(CURVE_NAMES[i]).copied()
    }
}

/// A character's own ranges (`[rig.ranges]` of its file): per curve in [`CURVE_NAMES`] order,
/// the range that character uses instead of the performer's (`None`: the performer's).
///
/// Precedence, for each curve: the character's range, else the `[rig.ranges]` of the daemon
/// (or `--config`) configuration, else the performer's range learned from the default.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RangeOverrides(pub [Option<f64>; CURVES]);

impl RangeOverrides {
    /// No range of its own.
    pub fn is_empty(&self) -> bool {
        self.0.iter().all(Option::is_none)
    }

    /// From curve name → range pairs, checked as [`RigSettings::validate`] checks
    /// `[rig.ranges]`; the error is the offending name and the reason.
    pub fn from_named<'a>(
        pairs: impl IntoIterator<Item = (&'a str, f64)>,
    ) -> Result<Self, (String, String)> {
        let mut out = Self::default();
        for (name, v) in pairs {
            let Some(i) = curve_index(name) else {
                return Err((
                    name.to_string(),
                    format!("is not a curve name (one of {})", CURVE_NAMES.join(", ")),
                ));
            };
            if !range_ok(v) {
                return Err((name.to_string(), range_reason(v)));
            }
            if out.0[i].replace(v).is_some() {
                return Err((name.to_string(), "is given twice".into()));
            }
        }
        Ok(out)
    }
}

/// Smallest range of a curve's measure: a range near 0 turns the measure's noise into a
/// curve jumping between 0 and 1.
pub const MIN_RANGE: f64 = 0.001;
/// Largest range of a curve's measure.
pub const MAX_RANGE: f64 = 1000.0;

fn range_ok(v: f64) -> bool {
    (MIN_RANGE..=MAX_RANGE).contains(&v)
}

fn range_reason(v: f64) -> String {
    format!("must be a positive number, at least {MIN_RANGE} and at most {MAX_RANGE}, got {v:?}")
}

/// One lip's rigid motion from neutral (mouth frame).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LipMotion {
    /// Unit quaternion `[w, x, y, z]`, `w >= 0`.
    pub rotation: [f64; 4],
    /// Metres.
    pub translation: [f64; 3],
    /// RMS distance (metres) between the current dots and the rigidly moved neutral ones:
    /// what the rigid motion cannot explain (stretch, rounding).
    pub residual: f64,
}

impl Default for LipMotion {
    fn default() -> Self {
        Self {
            rotation: [1.0, 0.0, 0.0, 0.0],
            translation: [0.0; 3],
            residual: 0.0,
        }
    }
}

/// The jaw of one step.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct JawState {
    /// Opening angle about the hinge axis, degrees (> 0 open).
    pub angle_deg: f64,
    /// Slide along the hinge axis, metres (> 0 towards the performer's left).
    pub slide_m: f64,
}

/// Both lips of one step.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct LipsState {
    pub upper: LipMotion,
    pub lower: LipMotion,
}

/// The rig of one step, as it goes on the wire and into files.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RigFrame {
    pub jaw: JawState,
    pub lips: LipsState,
    /// Curve name → value in 0..1, in [`CURVE_NAMES`] order.
    pub curves: Named<f64>,
    /// VRM 1.0 mouth expression → value in 0..1, in [`VISEME_NAMES`] order, from the curves
    /// ([`visemes_from`]).
    #[serde(default = "default_visemes")]
    pub visemes: Named<f64>,
    /// The performer's neutral mouth width (corner to corner), metres: what the export scales
    /// the slide and the lip translations by to the character's size (docs/export.md).
    /// Absent in takes made before it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub performer_width_m: Option<f64>,
}

fn default_visemes() -> Named<f64> {
    Named(VISEME_NAMES.iter().map(|n| (n.to_string(), 0.0)).collect())
}

impl Default for RigFrame {
    fn default() -> Self {
        Self {
            jaw: JawState::default(),
            lips: LipsState::default(),
            curves: Named(CURVE_NAMES.iter().map(|n| (n.to_string(), 0.0)).collect()),
            visemes: default_visemes(),
            performer_width_m: None,
        }
    }
}

/// Sets `out`'s visemes from the curves `values` (no allocation once it has them).
fn set_visemes(values: &[f64; CURVES], out: &mut Named<f64>) {
    if out.0.len() != VISEMES {
        *out = default_visemes();
    }
    for ((name, dst), (v, want)) in out
        .0
        .iter_mut()
        .zip(visemes_from(values).into_iter().zip(VISEME_NAMES))
    {
        if name != want {
            name.clear();
            name.push_str(want);
        }
        *dst = v;
    }
}

impl RigFrame {
    /// The value of curve `name` (0 when absent).
    pub fn curve(&self, name: &str) -> f64 {
        self.curves.get(name).copied().unwrap_or(0.0)
    }
}

/// The raw measures of one step, before ranges (degrees for the jaw, mouth widths for the
/// rest), and the jaw in natural units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measures {
    pub values: [f64; CURVES],
    /// Jaw angle, radians.
    pub jaw_angle: f64,
    /// Jaw slide, metres.
    pub jaw_slide: f64,
}

/// The streaming rig estimator of one performer: [`RigModel`], the range learning and the
/// lip fits. One per performer neutral pose; [`Rig::step`] per stabilised frame.
#[derive(Debug, Clone)]
pub struct Rig {
    model: RigModel,
    settings: RigSettings,
    ranges: [f64; CURVES],
    learn_until: Option<f64>,
    start: Option<f64>,
    /// Scratch for the lip fits.
    from: Vec<Vec3>,
    to: Vec<Vec3>,
    /// The dots the rig measures (the unseen ones from the seen ones, the seen ones with
    /// their depth error along the camera's ray), and those the last step measured.
    fill: LipFill,
    lip: Vec<Vec3>,
    seen: Vec<bool>,
    /// The last step's stabilised dots, as given: a dot unseen whose value has not changed
    /// since is one the stabiliser holds.
    given: Vec<Vec3>,
    fill_wanted: Vec<bool>,
    measures: Measures,
    values: [f64; CURVES],
    out: RigFrame,
}

impl Rig {
    /// A rig for a performer's neutral pose.
    pub fn new(neutral: &NeutralPose, settings: RigSettings) -> Result<Self, Error> {
        let model = RigModel::new(neutral, &settings)?;
        let mut ranges = DEFAULT_RANGES;
        for (i, r) in ranges.iter_mut().enumerate() {
            if let Some(v) = settings.configured(i) {
                *r = v;
            }
        }
        if settings.configured(CLOSE).is_none() {
            ranges[CLOSE] = ranges[0];
        }
        let n = neutral.lip.len();
        Ok(Self {
            model,
            ranges,
            learn_until: None,
            start: None,
            from: Vec::with_capacity(n),
            to: Vec::with_capacity(n),
            fill: LipFill::new(n).with_noise(settings.depth_noise_m, settings.pixel_noise_m),
            lip: Vec::with_capacity(n),
            seen: Vec::with_capacity(n),
            given: Vec::with_capacity(n),
            fill_wanted: Vec::with_capacity(n),
            measures: Measures {
                values: [0.0; CURVES],
                jaw_angle: 0.0,
                jaw_slide: 0.0,
            },
            values: [0.0; CURVES],
            out: RigFrame {
                performer_width_m: Some(neutral.mouth_width()),
                ..RigFrame::default()
            },
            settings,
        })
    }

    pub fn model(&self) -> &RigModel {
        &self.model
    }

    pub fn settings(&self) -> &RigSettings {
        &self.settings
    }

    /// The ranges in use (degrees for `jawOpen`, mouth widths for the rest).
    pub fn ranges(&self) -> &[f64; CURVES] {
        &self.ranges
    }

    /// The last step's measures.
    pub fn measures(&self) -> &Measures {
        &self.measures
    }

    /// The last step's output.
    pub fn output(&self) -> &RigFrame {
        &self.out
    }

    /// The lip dots the last step measured (mouth frame): the stabilised ones, with the
    /// unseen ones put where the seen ones say they are ([`LipFill`]).
    pub fn measured_lip(&self) -> &[Vec3] {
        &self.lip
    }

    /// Whether the ranges are still being learned (the learning window has not ended).
    pub fn learning(&self) -> bool {
        self.learn_until.is_none()
    }

    /// The ranges a character uses: its own where it sets them ([`RangeOverrides`]), the
    /// performer's ([`Rig::ranges`]) otherwise.
    pub fn ranges_for(&self, character: &RangeOverrides) -> [f64; CURVES] {
        let mut out = self.ranges;
        for (dst, own) in out.iter_mut().zip(character.0) {
            if let Some(r) = own {
                *dst = r;
            }
        }
        if character.0[CLOSE].is_none() && self.settings.configured(CLOSE).is_none() {
            out[CLOSE] = out[0];
        }
        out
    }

    /// The last step's output with a character's ranges (the jaw and the lips are the
    /// performer's; only the curves depend on ranges). No allocation once `out` has its
    /// curves.
    pub fn output_for(&self, character: &RangeOverrides, out: &mut RigFrame) {
        out.jaw = self.out.jaw;
        out.lips = self.out.lips;
        out.performer_width_m = self.out.performer_width_m;
        if character.is_empty() {
            out.curves.clone_from(&self.out.curves);
            out.visemes.clone_from(&self.out.visemes);
            return;
        }
        let mut values = [0.0; CURVES];
        curves_from(&self.measures, &self.ranges_for(character), &mut values);
        set_visemes(&values, &mut out.visemes);
        if out.curves.0.len() != CURVES {
            out.curves = RigFrame::default().curves;
        }
        for (((name, dst), v), want) in out.curves.0.iter_mut().zip(values).zip(CURVE_NAMES) {
            if name != want {
                name.clear();
                name.push_str(want);
            }
            *dst = v;
        }
    }

    /// One step.
    pub fn step(&mut self, frame: &StabilisedFrame) -> &RigFrame {
        self.seen.clear();
        self.seen.extend(frame.confidence.iter().map(|&c| c > 0.0));
        // *A held dot keeps the rig's measure*: a dot the stabiliser holds (unseen, its
        // value the same as last step's) stays where the rig last measured it, not where it
        // was last seen; the estimate below may still move it. (`lip` and `given` have the
        // last step's length, or none before the first step.)
        if self.given.len() == frame.lip.len() {
            for (k, p) in frame.lip.iter().enumerate() {
                if self.seen[k] || self.given[k] != *p {
                    self.lip[k] = *p;
                }
            }
        } else {
            self.lip.clone_from(&frame.lip);
        }
        self.given.clone_from(&frame.lip);
        if self.seen.iter().all(|&s| s) {
            self.fill.learn(&self.model.neutral, &self.lip);
        }
        self.model
            .roles
            .fill_wanted(&self.seen, &mut self.fill_wanted);
        let camera = self.model.camera_in_mouth(&frame.head);
        self.fill.estimate(
            &self.model.neutral,
            &mut self.lip,
            &self.seen,
            &self.fill_wanted,
            &camera,
        );
        let m = self.model.measure(&self.lip);
        self.measures = m;
        // Learning: the first `learn_s` seconds widen the ranges of curves not configured.
        let start = *self.start.get_or_insert(frame.t);
        if frame.t - start <= self.settings.learn_s {
            for (i, (range, v)) in self.ranges.iter_mut().zip(m.values).enumerate() {
                if self.settings.configured(i).is_none() && v.is_finite() {
                    *range = range.max(v);
                }
            }
            if self.settings.configured(CLOSE).is_none() {
                self.ranges[CLOSE] = self.ranges[0];
            }
        } else {
            self.learn_until.get_or_insert(frame.t);
        }
        curves_from(&m, &self.ranges, &mut self.values);
        for ((_, dst), v) in self.out.curves.0.iter_mut().zip(&self.values) {
            *dst = *v;
        }
        set_visemes(&self.values, &mut self.out.visemes);
        self.out.jaw = JawState {
            angle_deg: m.jaw_angle.to_degrees(),
            slide_m: m.jaw_slide,
        };
        let m = &self.model;
        let r = &m.roles;
        self.out.lips.upper = lip_motion(
            &m.neutral,
            &self.lip,
            r.upper.iter().chain([r.left, r.right].iter()),
            &mut self.from,
            &mut self.to,
        );
        self.out.lips.lower = lip_motion(
            &m.neutral,
            &self.lip,
            r.lower.iter().chain([r.left, r.right].iter()),
            &mut self.from,
            &mut self.to,
        );
        &self.out
    }
}

/// The rigid motion carrying the neutral dots `idx` onto the current ones, and its residual.
fn lip_motion<'a>(
    neutral: &[Vec3],
    lip: &[Vec3],
    idx: impl Iterator<Item = &'a usize>,
    from: &mut Vec<Vec3>,
    to: &mut Vec<Vec3>,
) -> LipMotion {
    from.clear();
    to.clear();
    for &i in idx {
        from.push(neutral[i]);
        to.push(lip[i]);
    }
    let Some(t) = kabsch(from, to) else {
        return LipMotion::default();
    };
    let sq: f64 = from
        .iter()
        .zip(to.iter())
        .map(|(a, b)| (t.apply(a) - b).norm_squared())
        .sum();
    LipMotion {
        rotation: t.quaternion_wxyz(),
        translation: [t.translation.x, t.translation.y, t.translation.z],
        residual: (sq / from.len().max(1) as f64).sqrt(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lip_fill::tests::{gauss_stream, rounded};
    use crate::{PerformerLayout, RigidTransform};

    /// A 12-dot mouth given directly in its mouth frame (x left, y up, z out): the forehead
    /// straight above, so the camera frame is the mouth frame.
    fn neutral() -> NeutralPose {
        let mut lip = vec![Vec3::new(0.025, 0.0, -0.004)];
        for k in 0..5 {
            let x = 0.016 - 0.008 * k as f64;
            lip.push(Vec3::new(x, 0.006 - 40.0 * x * x, -2.0 * x * x));
        }
        lip.push(Vec3::new(-0.025, 0.0, -0.004));
        for k in 0..5 {
            let x = -0.016 + 0.008 * k as f64;
            lip.push(Vec3::new(x, -0.008 + 40.0 * x * x, -2.0 * x * x));
        }
        let forehead = vec![
            Some(Vec3::new(-0.03, 0.1, -0.01)),
            Some(Vec3::new(0.03, 0.1, -0.01)),
            Some(Vec3::new(0.0, 0.12, -0.02)),
        ];
        NeutralPose::from_positions(
            PerformerLayout::default(),
            lip.into_iter().map(Some).collect(),
            forehead,
            30,
        )
        .unwrap()
    }

    /// [`neutral`] 0.6 m in front of a camera (OpenCV axes: x right, y down, z forward; the
    /// performer's left on the camera's right), as a real session has it: the camera's rays
    /// run along the mouth frame's z.
    fn neutral_before_camera() -> NeutralPose {
        let m = neutral();
        let to_camera = |p: &Vec3| Vec3::new(p.x, -p.y, 0.6 - p.z);
        NeutralPose::from_positions(
            PerformerLayout::default(),
            m.lip.iter().map(|p| Some(to_camera(p))).collect(),
            m.forehead_camera
                .iter()
                .map(|p| p.map(|p| to_camera(&p)))
                .collect(),
            30,
        )
        .unwrap()
    }

    fn frame(lip: Vec<Vec3>) -> StabilisedFrame {
        StabilisedFrame {
            t: 0.0,
            confidence: vec![1.0; lip.len()],
            lip,
            head: RigidTransform::IDENTITY,
            head_lost: false,
        }
    }

    fn rig() -> Rig {
        Rig::new(
            &neutral(),
            RigSettings {
                learn_s: 0.0,
                ..RigSettings::default()
            },
        )
        .unwrap()
    }

    /// The neutral lips drawn in horizontally to `s` of their width.
    fn drawn_in(n: &NeutralPose, s: f64) -> Vec<Vec3> {
        n.lip.iter().map(|p| Vec3::new(s * p.x, p.y, p.z)).collect()
    }

    /// A rig that has seen 40 steps of speech, every dot seen: the mouth drawing in by up to
    /// 30 % and letting go (what the fill of unseen dots learns from).
    fn rig_after_speech(n: &NeutralPose) -> Rig {
        let mut rig = rig();
        for k in 0..40 {
            rig.step(&frame(drawn_in(
                n,
                1.0 - 0.3 * (0.5 + 0.5 * (0.3 * k as f64).sin()),
            )));
        }
        rig
    }

    #[test]
    fn neutral_is_all_zero() {
        let n = neutral();
        let mut rig = rig();
        let out = rig.step(&frame(n.lip.clone())).clone();
        assert!(out.jaw.angle_deg.abs() < 1e-9 && out.jaw.slide_m.abs() < 1e-12);
        assert!(out.curves.iter().all(|(_, v)| v.abs() < 1e-12), "{out:?}");
        assert!(out.lips.upper.residual < 1e-12 && out.lips.lower.residual < 1e-12);
    }

    #[test]
    fn a_turned_jaw_gives_its_angle_and_nothing_else_moves() {
        let n = neutral();
        let mut rig = rig();
        let jaw = rig.model().jaw_transform(10f64.to_radians(), 0.0);
        let mut lip = n.lip.clone();
        for p in &mut lip[7..] {
            *p = jaw.apply(p);
        }
        let out = rig.step(&frame(lip.clone())).clone();
        assert!((out.jaw.angle_deg - 10.0).abs() < 1e-9, "{:?}", out.jaw);
        assert!(out.jaw.slide_m.abs() < 1e-12);
        assert!((out.curve("jawOpen") - 10.0 / 25.0).abs() < 1e-9);
        // The lips followed the jaw: no lower-down, no roll, no press; the lips parted, so
        // no mouthClose either.
        for name in [
            "mouthLowerDownLeft",
            "mouthRollLower",
            "mouthPressLeft",
            "mouthClose",
        ] {
            assert!(out.curve(name) < 1e-9, "{name}: {}", out.curve(name));
        }
        // The lower lip's rigid motion is the jaw's rotation: 10° about x.
        let q = out.lips.lower.rotation;
        let angle = 2.0 * q[1].atan2(q[0]);
        assert!(angle.to_degrees() > 5.0, "{q:?}");
        // A slide along the hinge.
        let jaw = rig.model().jaw_transform(0.0, 0.002);
        let mut lip = n.lip.clone();
        for p in &mut lip[7..] {
            *p = jaw.apply(p);
        }
        let out = rig.step(&frame(lip)).clone();
        assert!((out.jaw.slide_m - 0.002).abs() < 1e-12 && out.jaw.angle_deg.abs() < 1e-9);
        // The mouth as a whole moved by the lower lip's share.
        let w = n.mouth_width();
        assert!((out.curve("mouthLeft") - 0.002 * 5.0 / 12.0 / w / 0.10).abs() < 1e-9);
        assert!(
            out.curve("mouthPucker").abs() < 1e-12,
            "the slide is not a narrowing"
        );
    }

    /// The lips drawn in to 0.8, the left corner lost and held where it was at rest.
    fn corner_held(n: &NeutralPose) -> StabilisedFrame {
        let mut lip = drawn_in(n, 0.8);
        lip[0] = n.lip[0];
        let mut held = frame(lip);
        held.confidence[0] = 0.0;
        held
    }

    #[test]
    fn a_held_corner_does_not_hold_the_puckers_width() {
        let n = neutral();
        let drawn = |s: f64| drawn_in(&n, s);
        let mut rig = rig_after_speech(&n);
        let held = corner_held(&n);
        let out = rig.step(&held).clone();
        // What the whole mouth shows (the range was learned: these frames all have t = 0).
        assert!(
            (out.curve("mouthPucker") - 0.1 / rig.ranges()[3]).abs() < 0.005,
            "{}",
            out.curve("mouthPucker")
        );
        let measured = rig.measured_lip()[0];
        assert!((measured - drawn(0.8)[0]).norm() < 2e-4, "{measured:?}");
        // Measured as held, the pucker reads a quarter less: the corner 5 mm out.
        let as_held = rig.model().measure(&held.lip);
        assert!(as_held.values[3] < 0.08, "{:?}", as_held.values[3]);
    }

    /// A turned head's depth noise, which lies along the camera's ray and so partly sideways
    /// in the mouth frame, does not read as a pucker: the rig measures the seen dots with
    /// their noise along the ray (docs/rig.md, "The dots the rig measures").
    #[test]
    fn depth_noise_of_a_turned_head_does_not_read_as_a_pucker() {
        let n = neutral_before_camera();
        let mut rig = Rig::new(
            &n,
            RigSettings {
                learn_s: 0.0,
                ..RigSettings::default()
            },
        )
        .unwrap();
        // The head turned by `yaw` about a vertical axis 10 cm behind the mouth.
        let head = |yaw: f64| {
            let rotation = Rotation3::from_axis_angle(&Vec3::y_axis(), yaw).into_inner();
            let pivot = Vec3::new(0.0, 0.0, 0.7);
            RigidTransform {
                rotation,
                translation: pivot - rotation * pivot,
            }
        };
        let mut gauss = gauss_stream(0x9e37_79b9_7f4a_7c15);
        let mut noisy = |lip: &[Vec3], camera: &Vec3| -> Vec<Vec3> {
            lip.iter()
                .map(|p| p + (camera - p).normalize() * (0.0012 * gauss()))
                .collect()
        };
        let (mut raw_sq, mut rig_sq, mut count) = (0.0, 0.0, 0.0);
        for k in 0..160 {
            let s = 1.0 - 0.3 * (0.5 + 0.5 * (0.35 * k as f64).sin());
            let truth = rounded(&n.lip, s);
            // Facing the camera while it learns, then turned 35° away.
            let pose = head(if k < 60 { 0.0 } else { 35f64.to_radians() });
            let camera = rig.model().camera_in_mouth(&pose);
            let lip = noisy(&truth, &camera);
            let mut f = frame(lip.clone());
            f.head = pose;
            let pucker = rig.step(&f).curve("mouthPucker") * rig.ranges()[3];
            if k >= 60 {
                let want = rig.model().measure(&truth).values[3];
                let raw = rig.model().measure(&lip).values[3];
                raw_sq += (raw - want).powi(2);
                rig_sq += (pucker - want).powi(2);
                count += 1.0;
            }
        }
        let (raw, estimated) = ((raw_sq / count).sqrt(), (rig_sq / count).sqrt());
        assert!(
            estimated < 0.65 * raw,
            "pucker RMS {estimated} measured by the rig, {raw} on the dots as given"
        );
    }

    /// `[rig] depth_noise_m` reaches the estimate: told that the depth is as precise as the
    /// pixel, the rig leaves a seen dot's depth error where it is.
    #[test]
    fn the_configured_depth_noise_is_the_estimates() {
        let n = neutral_before_camera();
        let settings = |depth_noise_m: f64| RigSettings {
            learn_s: 0.0,
            depth_noise_m,
            pixel_noise_m: 0.0003,
            ..RigSettings::default()
        };
        let mut moved = Vec::new();
        for depth_noise_m in [0.0012, 0.0003] {
            let mut rig = Rig::new(&n, settings(depth_noise_m)).unwrap();
            for k in 0..40 {
                rig.step(&frame(drawn_in(
                    &n,
                    1.0 - 0.3 * (0.5 + 0.5 * (0.3 * k as f64).sin()),
                )));
            }
            // One dot 3 mm off in depth (the camera is straight in front in these frames).
            let mut lip = drawn_in(&n, 0.85);
            lip[3].z += 0.003;
            rig.step(&frame(lip.clone()));
            moved.push((rig.measured_lip()[3] - lip[3]).norm());
        }
        assert!(moved[0] > 0.0015, "{moved:?}");
        assert!(moved[1] < 0.6 * moved[0], "{moved:?}");
    }

    #[test]
    fn a_held_dot_keeps_the_rigs_measure() {
        let n = neutral();
        let drawn = |s: f64| drawn_in(&n, s);
        let mut rig = rig_after_speech(&n);
        // The rig puts the held corner drawn in.
        let held = corner_held(&n);
        rig.step(&held);
        let measured = rig.measured_lip().to_vec();
        assert!((measured[0] - drawn(0.8)[0]).norm() < 2e-4);
        // Next step no dot is seen and the stabiliser holds every one: nothing to estimate
        // from, so the rig keeps what it measured (the corner drawn in, not at rest).
        let mut none = held.clone();
        none.confidence.iter_mut().for_each(|c| *c = 0.0);
        rig.step(&none);
        assert_eq!(rig.measured_lip(), &measured[..]);
        // Once the stabiliser moves a held dot (decaying towards neutral), the rig takes it.
        none.lip[0] = (n.lip[0] + drawn(0.8)[0]) / 2.0;
        rig.step(&none);
        assert_eq!(rig.measured_lip()[0], none.lip[0]);
        assert_eq!(rig.measured_lip()[1..], measured[1..]);
    }

    #[test]
    fn a_lip_with_no_dot_seen_stays_held() {
        let n = neutral();
        let drawn = |s: f64| drawn_in(&n, s);
        let mut rig = rig_after_speech(&n);
        // The corners and the whole lower lip unseen, held at rest.
        let mut lip = drawn(0.8);
        let unseen = [0, 6, 7, 8, 9, 10, 11];
        for &i in &unseen {
            lip[i] = n.lip[i];
        }
        let mut held = frame(lip.clone());
        for &i in &unseen {
            held.confidence[i] = 0.0;
        }
        rig.step(&held);
        // The corners follow the upper lip; the lower lip stays where it was held.
        for i in [0, 6] {
            assert!((rig.measured_lip()[i] - drawn(0.8)[i]).norm() < 2e-4);
        }
        assert_eq!(&rig.measured_lip()[7..], &lip[7..]);
        // One lower-lip dot seen: the rest of that lip is moved too.
        held.confidence[9] = 1.0;
        held.lip[9] = drawn(0.8)[9];
        rig.step(&held);
        assert!((rig.measured_lip()[7] - drawn(0.8)[7]).norm() < 2e-4);
    }

    #[test]
    fn lips_drawn_in_pucker_and_pushed_out_funnel() {
        let n = neutral();
        let w = n.mouth_width();
        let mut rig = rig();
        let drawn: Vec<Vec3> = n
            .lip
            .iter()
            .map(|p| Vec3::new(0.9 * p.x, p.y, p.z))
            .collect();
        let out = rig.step(&frame(drawn)).clone();
        // Drawn in with the lips closed: a pucker, no funnel.
        assert!(
            (out.curve("mouthPucker") - 0.05 / 0.15).abs() < 1e-9,
            "{out:?}"
        );
        assert_eq!(out.curve("mouthFunnel"), 0.0);
        let pushed: Vec<Vec3> = n
            .lip
            .iter()
            .map(|p| p + Vec3::new(0.0, 0.0, 0.003))
            .collect();
        let out = rig.step(&frame(pushed)).clone();
        // Pushed out with the lips closed: the rounding is a pucker too.
        assert!((out.curve("mouthPucker") - DEPTH_WEIGHT * 0.003 / w / 0.15).abs() < 1e-9);
        assert_eq!(out.curve("mouthFunnel"), 0.0);
        assert!(
            out.jaw.angle_deg.abs() < 1e-9,
            "a push is not a jaw: {:?}",
            out.jaw
        );
    }

    #[test]
    fn left_and_right_are_the_performers_and_mirror() {
        let n = neutral();
        let mut rig = rig();
        // The left corner (D1, +x) up and out.
        let mut lip = n.lip.clone();
        lip[0] += Vec3::new(0.003, 0.004, 0.0);
        let left = rig.step(&frame(lip)).clone();
        let (sl, sr) = (left.curve("mouthSmileLeft"), left.curve("mouthSmileRight"));
        assert!(sl > 0.1 && sr < 1e-12, "{sl} {sr}");
        let (tl, tr) = (
            left.curve("mouthStretchLeft"),
            left.curve("mouthStretchRight"),
        );
        assert!(tl > 0.1 && tr < 1e-12, "{tl} {tr}");
        let mut lip = n.lip.clone();
        lip[6] += Vec3::new(-0.003, 0.004, 0.0);
        let right = rig.step(&frame(lip)).clone();
        for (a, b) in [
            ("mouthSmileLeft", "mouthSmileRight"),
            ("mouthStretchLeft", "mouthStretchRight"),
        ] {
            assert!((left.curve(a) - right.curve(b)).abs() < 1e-9, "{a}");
        }
        // The whole mouth shifted to the performer's left.
        let shifted: Vec<Vec3> = n
            .lip
            .iter()
            .map(|p| p + Vec3::new(0.002, 0.0, 0.0))
            .collect();
        let out = rig.step(&frame(shifted)).clone();
        assert!(out.curve("mouthLeft") > 0.3 && out.curve("mouthRight") == 0.0);
        assert!(out.jaw.slide_m.abs() < 1e-12, "the jaw moved with the lips");
    }

    /// Centred stretch: a shift of the whole mouth (or a common error of every dot) is no
    /// stretch; a widening of both sides is the same stretch on both; one corner pulled out
    /// leaves the other side unstretched.
    #[test]
    fn centred_stretch_ignores_a_whole_mouth_shift() {
        let n = neutral();
        let mut rig = rig();
        let shifted: Vec<Vec3> = n
            .lip
            .iter()
            .map(|p| p + Vec3::new(0.003, 0.0, 0.0))
            .collect();
        let v = rig.model().measure(&shifted).values;
        assert!(v[8].abs() < 1e-12 && v[9].abs() < 1e-12, "{:?}", &v[8..10]);
        // (Fitted about the neutral centre instead, the left side would read 0.09 here.)
        let wide: Vec<Vec3> = n
            .lip
            .iter()
            .map(|p| Vec3::new(1.1 * p.x, p.y, p.z))
            .collect();
        let v = rig.model().measure(&wide).values;
        assert!(
            (v[8] - 0.05).abs() < 1e-12 && (v[9] - 0.05).abs() < 1e-12,
            "{:?}",
            &v[8..10]
        );
        let out = rig.step(&frame(wide)).clone();
        assert!((out.curve("mouthStretchLeft") - 0.05 / 0.15).abs() < 1e-9);
    }

    #[test]
    fn midline_weights_are_one_on_the_midline_and_zero_at_the_corners() {
        let n = neutral();
        let w = n.mouth_width();
        let m = midline_weights(&n.lip, w);
        assert_eq!((m[0], m[6]), (0.0, 0.0), "corners");
        assert_eq!((m[3], m[9]), (1.0, 1.0), "midline");
        assert!((m[1] - (1.0 - 0.016 / (0.5 * w))).abs() < 1e-12);
        assert!(m.iter().all(|x| (0.0..=1.0).contains(x)));
        // A shift of the centre dots only moves the centre by their weighted share.
        let dx = |i: usize| if i == 3 || i == 9 { 0.001 } else { 0.0 };
        let want = 0.002 / m.iter().sum::<f64>();
        assert!((centre_shift(&m, dx) - want).abs() < 1e-15);
    }

    /// Depth weight: a millimetre of depth counts DEPTH_WEIGHT of a lateral one in the rolls
    /// and the funnel.
    #[test]
    fn depth_counts_at_depth_weight_in_rolls_and_funnel() {
        let n = neutral();
        let w = n.mouth_width();
        let mut rig = rig();
        // The upper lip pushed back 2 mm, nothing else: a roll of the upper lip by depth only.
        let mut lip = n.lip.clone();
        for p in &mut lip[1..6] {
            p.z -= 0.002;
        }
        let v = rig.model().measure(&lip).values;
        assert!(
            (v[10] - DEPTH_WEIGHT * 0.002 / w).abs() < 1e-12,
            "{}",
            v[10]
        );
        // The upper lip down 2 mm counts in full.
        let mut lip = n.lip.clone();
        for p in &mut lip[1..6] {
            p.y -= 0.002;
        }
        let v = rig.model().measure(&lip).values;
        assert!((v[10] - 0.002 / w).abs() < 1e-12, "{}", v[10]);
        // Both lips pushed forward 4 mm: funnel by depth only.
        let pushed: Vec<Vec3> = n
            .lip
            .iter()
            .map(|p| p + Vec3::new(0.0, 0.0, 0.004))
            .collect();
        let out = rig.step(&frame(pushed)).clone();
        // (The lips closed: the rounding is mouthPucker.)
        assert!((out.curve("mouthPucker") - DEPTH_WEIGHT * 0.004 / w / 0.15).abs() < 1e-9);
    }

    /// One weight per axis: in the funnel a corner's inward motion counts millimetre for
    /// millimetre (a lateral motion, weight 1), the lips' forward motion at DEPTH_WEIGHT.
    #[test]
    fn the_funnel_counts_the_corners_inward_motion_in_full() {
        let n = neutral();
        let w = n.mouth_width();
        let model = rig().model().clone();
        // Every dot 10 % nearer the midline: each corner came in by 10 % of half the width.
        let drawn: Vec<Vec3> = n
            .lip
            .iter()
            .map(|p| Vec3::new(0.9 * p.x, p.y, p.z))
            .collect();
        let corner_in = (n.lip[0].x - drawn[0].x) / w;
        assert!((corner_in - 0.05).abs() < 1e-12, "{corner_in}");
        // (The lips closed: the rounding, funnel + pucker, is all pucker.)
        let v = model.measure(&drawn).values;
        assert!(
            (v[2] + v[3] - corner_in).abs() < 1e-12,
            "the corners' inward motion in mouth widths: {}",
            v[3]
        );
        // (Counted at half weight, as before the rule, it would read 0.025.)
        // A motion forward counts a quarter: every dot 2 mm out reads a quarter of 2 mm.
        let mut both = n.lip.clone();
        for p in &mut both {
            p.z += 0.002;
        }
        let v = model.measure(&both).values;
        let v_fwd = v[2] + v[3];
        assert!((v_fwd - DEPTH_WEIGHT * 0.002 / w).abs() < 1e-12, "{v_fwd}");
        assert!((funnel_measure(0.0, 0.9) - 0.05).abs() < 1e-15);
        assert!((funnel_measure(0.04, 1.0) - DEPTH_WEIGHT * 0.04).abs() < 1e-15);
    }

    /// Drawn in only: corners pushed out (spreading) do not take away from the lips' push;
    /// a spread mouth alone reads no funnel (and a stretch on both sides).
    #[test]
    fn spreading_does_not_cancel_the_funnel() {
        let n = neutral();
        let w = n.mouth_width();
        let model = rig().model().clone();
        // Lips pushed 4 mm forward while the mouth is 10 % wider.
        let spread_pushed: Vec<Vec3> = n
            .lip
            .iter()
            .map(|p| Vec3::new(1.1 * p.x, p.y, p.z + 0.004))
            .collect();
        let v = model.measure(&spread_pushed).values;
        assert!(
            (v[2] + v[3] - DEPTH_WEIGHT * 0.004 / w).abs() < 1e-12,
            "the push alone: {} (subtracting the spread it would be {})",
            v[2] + v[3],
            DEPTH_WEIGHT * 0.004 / w - 0.05
        );
        assert!(v[8] > 0.04 && v[9] > 0.04, "a stretch: {:?}", &v[8..10]);
        // Spread alone: no funnel (the measure is 0, not negative).
        let spread: Vec<Vec3> = n
            .lip
            .iter()
            .map(|p| Vec3::new(1.1 * p.x, p.y, p.z))
            .collect();
        assert_eq!(model.measure(&spread).values[2], 0.0);
        assert_eq!(funnel_measure(0.0, 1.2), 0.0);
    }

    #[test]
    fn ranges_are_learned_then_kept_and_configured_ones_are_not_learned() {
        let n = neutral();
        let settings = RigSettings {
            learn_s: 1.0,
            ranges: Named(vec![("mouthPucker".into(), 0.5)]),
            ..RigSettings::default()
        };
        let mut rig = Rig::new(&n, settings).unwrap();
        let jaw = rig.model().jaw_transform(40f64.to_radians(), 0.0);
        let mut lip: Vec<Vec3> = n
            .lip
            .iter()
            .map(|p| Vec3::new(0.5 * p.x, p.y, p.z))
            .collect();
        for p in &mut lip[7..] {
            *p = jaw.apply(p);
        }
        let mut f = frame(lip);
        f.t = 0.5;
        rig.step(&f);
        assert!(
            (rig.ranges()[0] - 40.0).abs() < 1e-9,
            "jawOpen widened to 40°"
        );
        assert_eq!(rig.ranges()[3], 0.5, "configured: kept");
        assert!(rig.learning());
        let mut g = frame(n.lip.clone());
        g.t = 2.0;
        rig.step(&g);
        assert!(!rig.learning());
        assert!((rig.ranges()[0] - 40.0).abs() < 1e-9);
    }

    /// Precedence of ranges: the character's own, else the configured one, else the
    /// performer's learned from the default.
    #[test]
    fn a_characters_ranges_override_the_configured_and_the_learned_ones() {
        let n = neutral();
        let settings = RigSettings {
            learn_s: 1.0,
            ranges: Named(vec![("mouthPucker".into(), 0.5), ("jawOpen".into(), 20.0)]),
            ..RigSettings::default()
        };
        let mut rig = Rig::new(&n, settings).unwrap();
        let jaw = rig.model().jaw_transform(10f64.to_radians(), 0.0);
        let mut lip: Vec<Vec3> = n
            .lip
            .iter()
            .map(|p| Vec3::new(0.9 * p.x, p.y, p.z))
            .collect();
        for p in &mut lip[7..] {
            *p = jaw.apply(p);
        }
        rig.step(&frame(lip));
        let own =
            RangeOverrides::from_named([("jawOpen", 40.0), ("mouthStretchLeft", 0.3)]).unwrap();
        let r = rig.ranges_for(&own);
        let i = |name: &str| curve_index(name).unwrap();
        assert_eq!(r[i("jawOpen")], 40.0, "the character's over the configured");
        assert_eq!(r[i("mouthPucker")], 0.5, "the configured");
        assert_eq!(
            r[i("mouthStretchLeft")],
            0.3,
            "the character's over the default"
        );
        assert_eq!(r[i("mouthClose")], 40.0, "jawOpen's");
        let mut out = RigFrame::default();
        rig.output_for(&own, &mut out);
        assert!((out.curve("jawOpen") - 10.0 / 40.0).abs() < 1e-9, "{out:?}");
        // (The jaw is open, so the lips' rounding is a funnel.)
        assert!((out.curve("mouthFunnel") - 0.05 / 0.15).abs() < 1e-9);
        assert_eq!(out.jaw, rig.output().jaw);
        assert_eq!(out.lips, rig.output().lips);
        // Without ranges of its own, the character gets the performer's output.
        rig.output_for(&RangeOverrides::default(), &mut out);
        assert_eq!(&out, rig.output());
        assert!((out.curve("jawOpen") - 10.0 / 20.0).abs() < 1e-9);
        // Names are checked like [rig.ranges].
        for (name, v, words) in [
            ("mouthSmile", 0.1, "not a curve name"),
            ("jawOpen", 0.0, "positive"),
            ("jawOpen", f64::NAN, "positive"),
        ] {
            let (n, reason) = RangeOverrides::from_named([(name, v)]).unwrap_err();
            assert!(n == name && reason.contains(words), "{n}: {reason}");
        }
        let (n, reason) =
            RangeOverrides::from_named([("jawOpen", 1.0), ("jawOpen", 2.0)]).unwrap_err();
        assert!(n == "jawOpen" && reason.contains("twice"), "{reason}");
    }

    #[test]
    fn settings_errors_name_the_key() {
        let e = RigSettings::from_toml_str("hinge_back = -1")
            .unwrap_err()
            .to_string();
        assert!(e.contains("rig.hinge_back"), "{e}");
        let e = RigSettings::from_toml_str("[ranges]\nmouthSmile = 0.1")
            .unwrap_err()
            .to_string();
        assert!(e.contains("rig.ranges.mouthSmile"), "{e}");
        let e = RigSettings::from_toml_str("[ranges]\njawOpen = 0")
            .unwrap_err()
            .to_string();
        assert!(e.contains("rig.ranges.jawOpen"), "{e}");
        let e = RigSettings::from_toml_str("hinge = 1")
            .unwrap_err()
            .to_string();
        assert!(e.contains("hinge"), "{e}");
        let s = RigSettings::from_toml_str("learn_s = 0\n[ranges]\njawOpen = 30").unwrap();
        assert_eq!(s.ranges.get("jawOpen"), Some(&30.0));
        for bad in [
            "depth_noise_m = 0",
            "depth_noise_m = 0.5",
            "pixel_noise_m = -1e-4",
        ] {
            let e = RigSettings::from_toml_str(bad).unwrap_err().to_string();
            let key = bad.split(' ').next().unwrap();
            assert!(e.contains(&format!("rig.{key}")), "{bad}: {e}");
        }
        let s = RigSettings::from_toml_str("depth_noise_m = 0.0007").unwrap();
        assert_eq!((s.depth_noise_m, s.pixel_noise_m), (0.0007, 0.0003));
    }

    /// The neutral mouth with the lower lip carried by the jaw (`deg` open) and the upper lip
    /// moved by `upper`.
    fn jaw_and_upper(rig: &Rig, n: &NeutralPose, deg: f64, upper: Vec3) -> Vec<Vec3> {
        let jaw = rig.model().jaw_transform(deg.to_radians(), 0.0);
        let mut lip = n.lip.clone();
        for p in &mut lip[1..6] {
            *p += upper;
        }
        for p in &mut lip[7..] {
            *p = jaw.apply(p);
        }
        lip
    }

    /// ARKit's mouthClose: lips sealed while the jaw is open. A jaw dropped with the lips kept
    /// together (the upper lip following the lower down) reads jawOpen and mouthClose alike;
    /// lips pressed with the jaw shut read no mouthClose.
    #[test]
    fn mouth_close_is_a_sealed_jaw_drop_and_not_a_press() {
        let n = neutral();
        let mut rig = rig();
        // The drop 15° of jaw gives the lower-lip centroid.
        let open = jaw_and_upper(&rig, &n, 15.0, Vec3::zeros());
        let drop = (7..12).map(|i| n.lip[i].y - open[i].y).sum::<f64>() / 5.0;
        let sealed = jaw_and_upper(&rig, &n, 15.0, Vec3::new(0.0, -drop, 0.0));
        let out = rig.step(&frame(sealed)).clone();
        assert!((out.jaw.angle_deg - 15.0).abs() < 1e-9, "{:?}", out.jaw);
        let (jaw, close) = (out.curve("jawOpen"), out.curve("mouthClose"));
        assert!((jaw - 0.6).abs() < 1e-9, "{jaw}");
        assert!(
            (close - jaw).abs() < 1e-9,
            "sealed: mouthClose {close}, jawOpen {jaw}"
        );
        // Half the drop shown as parting: half the opening is sealed.
        let half = jaw_and_upper(&rig, &n, 15.0, Vec3::new(0.0, -0.5 * drop, 0.0));
        let out = rig.step(&frame(half)).clone();
        assert!((out.curve("mouthClose") - 0.3).abs() < 1e-9, "{out:?}");
        // Pressed, the jaw shut: the upper lip down 2 mm, the lower up 2 mm.
        let mut pressed = n.lip.clone();
        for p in &mut pressed[1..6] {
            p.y -= 0.002;
        }
        for p in &mut pressed[7..] {
            p.y += 0.002;
        }
        let out = rig.step(&frame(pressed)).clone();
        assert_eq!(out.curve("mouthClose"), 0.0, "{out:?}");
        assert!(out.curve("mouthPressLeft") > 0.1, "{out:?}");
        assert_eq!(close_measure(-3.0, 0.001, 0.0), 0.0);
        assert_eq!(close_measure(10.0, 0.004, 0.006), 0.0);
    }

    /// mouthClose's range is jawOpen's unless it has its own.
    #[test]
    fn mouth_close_takes_jaw_opens_range() {
        let n = neutral();
        let settings = RigSettings {
            ranges: Named(vec![("jawOpen".into(), 40.0)]),
            ..RigSettings::default()
        };
        let rig = Rig::new(&n, settings).unwrap();
        assert_eq!(rig.ranges()[1], 40.0);
        let own = RangeOverrides::from_named([("jawOpen", 20.0)]).unwrap();
        assert_eq!(rig.ranges_for(&own)[1], 20.0);
        let own = RangeOverrides::from_named([("jawOpen", 20.0), ("mouthClose", 9.0)]).unwrap();
        assert_eq!(rig.ranges_for(&own)[1], 9.0);
    }

    /// The same rounding (lips pushed 3 mm forward, drawn in to 0.8 of their width) reads
    /// mouthFunnel with the lips apart and mouthPucker with them closed.
    #[test]
    fn funnel_and_pucker_are_told_apart_by_the_lips_opening() {
        let n = neutral();
        let w = n.mouth_width();
        let mut rig = rig();
        let round: Vec<Vec3> = n
            .lip
            .iter()
            .map(|p| Vec3::new(0.8 * p.x, p.y, p.z + 0.003))
            .collect();
        let rounding = DEPTH_WEIGHT * 0.003 / w + 0.1;
        let out = rig.step(&frame(round.clone())).clone();
        assert_eq!(out.curve("mouthFunnel"), 0.0, "closed: {out:?}");
        assert!((out.curve("mouthPucker") - rounding / 0.15).abs() < 1e-9);
        // The jaw open 12° under the same lips: the lips parted (by more than OPEN_WIDTHS).
        let jaw = rig.model().jaw_transform(12f64.to_radians(), 0.0);
        let mut open = round.clone();
        for p in &mut open[7..] {
            *p = jaw.apply(p);
        }
        let out = rig.step(&frame(open)).clone();
        assert!(
            (out.curve("mouthFunnel") - rounding / 0.15).abs() < 1e-9,
            "{out:?}"
        );
        assert_eq!(out.curve("mouthPucker"), 0.0, "open: {out:?}");
        // Half open: the rounding shared half and half.
        assert_eq!(open_fraction(0.5 * OPEN_WIDTHS), 0.5);
        assert_eq!(open_fraction(-0.01), 0.0);
        assert_eq!(open_fraction(f64::NAN), 0.0);
    }

    /// The curves added from the same dots: the jaw's slide and thrust, the corners down and
    /// back, the lips turned out; and the visemes of an open mouth.
    #[test]
    fn the_jaw_slide_thrust_frown_shrug_and_dimple_read_their_motions() {
        let n = neutral();
        let w = n.mouth_width();
        let mut rig = rig();
        let range = |name: &str| DEFAULT_RANGES[curve_index(name).unwrap()];
        let moved = |f: &dyn Fn(usize, &mut Vec3)| -> Vec<Vec3> {
            let mut lip = n.lip.clone();
            for (i, p) in lip.iter_mut().enumerate() {
                f(i, p);
            }
            lip
        };
        // The jaw slid 3 mm to the performer's left.
        let jaw = rig.model().jaw_transform(0.0, 0.003);
        let slid = moved(&|i, p| {
            if i > 6 {
                *p = jaw.apply(p)
            }
        });
        let out = rig.step(&frame(slid)).clone();
        assert!(
            (out.curve("jawLeft") - 0.003 / w / range("jawLeft")).abs() < 1e-9,
            "{out:?}"
        );
        assert!(out.curve("jawRight") < 1e-9, "{out:?}");
        // The lower lip 2 mm forward: a thrust, not an opening.
        let thrust = moved(&|i, p| {
            if i > 6 {
                p.z += 0.002
            }
        });
        let out = rig.step(&frame(thrust)).clone();
        assert!(out.curve("jawForward") > 0.15, "{out:?}");
        assert!(out.curve("jawOpen") < 1e-9, "{out:?}");
        // The left corner and its neighbours 2 mm down: a frown on the left only.
        let down = moved(&|i, p| {
            if [0, 1, 11].contains(&i) {
                p.y -= 0.002
            }
        });
        let out = rig.step(&frame(down)).clone();
        // (The lower neighbour's drop turns the jaw a little, which takes a little off it.)
        let frown = out.curve("mouthFrownLeft");
        assert!(
            frown > 0.9 * 0.002 / w / range("mouthFrownLeft")
                && frown < 0.002 / w / range("mouthFrownLeft"),
            "{out:?}"
        );
        assert!(out.curve("mouthFrownRight") < 1e-9, "{out:?}");
        assert!(out.curve("mouthSmileLeft") < 1e-9, "{out:?}");
        // The right corner and its neighbours 2 mm back: a dimple on the right only.
        let back = moved(&|i, p| {
            if [5, 6, 7].contains(&i) {
                p.z -= 0.002
            }
        });
        let out = rig.step(&frame(back)).clone();
        // (Against the upper lip's mean depth, which its neighbour took 0.4 mm back.)
        let want = (0.002 - 0.002 / 5.0) / w / 0.30;
        assert!(
            (out.curve("mouthDimpleRight") - want).abs() < 1e-9,
            "{out:?}"
        );
        assert!(out.curve("mouthDimpleLeft") < 1e-9, "{out:?}");
        // The upper lip 1 mm up and 2 mm out: a shrug of the upper lip, not a roll.
        let out_up = moved(&|i, p| {
            if (1..6).contains(&i) {
                *p += Vec3::new(0.0, 0.001, 0.002)
            }
        });
        let out = rig.step(&frame(out_up)).clone();
        let want = (0.001 + DEPTH_WEIGHT * 0.002) / w / range("mouthShrugUpper");
        assert!(
            (out.curve("mouthShrugUpper") - want).abs() < 1e-9,
            "{out:?}"
        );
        assert!(out.curve("mouthRollUpper") < 1e-9, "{out:?}");
        // The lower lip 1 mm up and 2 mm out against the jaw.
        let pout = moved(&|i, p| {
            if i > 6 {
                *p += Vec3::new(0.0, 0.001, 0.002)
            }
        });
        let out = rig.step(&frame(pout)).clone();
        let want = (0.001 + DEPTH_WEIGHT * 0.002) / w / 0.16;
        assert!(
            (out.curve("mouthShrugLower") - want).abs() < 1e-9,
            "{out:?}"
        );
        assert!(
            out.curve("jawForward") > 0.075,
            "(a pout reads as a thrust too)"
        );
        assert!(out.curve("jawOpen") < 1e-9, "{out:?}");
        // An open unrounded mouth is the viseme aa, which the frame carries.
        let open = jaw_and_upper(&rig, &n, 20.0, Vec3::zeros());
        let out = rig.step(&frame(open)).clone();
        let aa = out.visemes.get("aa").copied().unwrap();
        assert!((aa - 0.8).abs() < 1e-9, "{out:?}");
        let names: Vec<&str> = out.visemes.0.iter().map(|(k, _)| &k[..]).collect();
        assert_eq!(names, VISEME_NAMES);
    }
}
