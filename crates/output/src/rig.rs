//! A character's rig in one frame (docs/rig.md): jaw, lip motions and the ARKit-named mouth
//! curves. Fixed-size and `Copy`, so that publishing does not allocate; the curves serialise
//! as a name → value object in [`CURVE_NAMES`] order.

use serde::ser::SerializeMap;
use serde::{Serialize, Serializer};

use crate::curves::{curve_index, visemes_from, CURVES, CURVE_NAMES, VISEMES, VISEME_NAMES};

/// The jaw: opening angle about the hinge (degrees) and slide along it (metres).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct RigJaw {
    pub angle_deg: f32,
    pub slide_m: f32,
}

/// One lip's rigid motion from neutral (performer mouth frame) and its residual RMS (metres).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RigLip {
    pub rotation: [f32; 4],
    pub translation: [f32; 3],
    pub residual: f32,
}

impl Default for RigLip {
    fn default() -> Self {
        Self {
            rotation: [1.0, 0.0, 0.0, 0.0],
            translation: [0.0; 3],
            residual: 0.0,
        }
    }
}

/// Both lips.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct RigLips {
    pub upper: RigLip,
    pub lower: RigLip,
}

/// The curves, in [`CURVE_NAMES`] order, 0..1.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RigCurves(pub [f32; CURVES]);

impl Serialize for RigCurves {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(Some(self.0.len()))?;
        for (name, v) in CURVE_NAMES.iter().zip(&self.0) {
            map.serialize_entry(name, v)?;
        }
        map.end()
    }
}

/// The VRM 1.0 mouth expressions, in [`VISEME_NAMES`] order, 0..1
/// ([`crate::curves::visemes_from`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RigVisemes(pub [f32; VISEMES]);

impl Serialize for RigVisemes {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(Some(self.0.len()))?;
        for (name, v) in VISEME_NAMES.iter().zip(&self.0) {
            map.serialize_entry(name, v)?;
        }
        map.end()
    }
}

/// A character's rig in one frame.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct RigState {
    pub jaw: RigJaw,
    pub lips: RigLips,
    pub curves: RigCurves,
    /// From the curves ([`RigState::set_visemes`]).
    pub visemes: RigVisemes,
}

impl RigState {
    /// The value of a curve by name.
    pub fn curve(&self, name: &str) -> Option<f32> {
        curve_index(name).map(|i| self.curves.0[i])
    }

    /// Sets the visemes from the curves.
    pub fn set_visemes(&mut self) {
        let curves = self.curves.0.map(f64::from);
        self.visemes = RigVisemes(visemes_from(&curves).map(|v| v as f32));
    }

    /// This rig moved towards `other` by `share` (0: this one, 1: `other`), as a handover
    /// mixes two sources' points: jaw and curves linearly, the lips' motions taken from the
    /// source with the larger share, the visemes made again from the mixed curves.
    pub fn blend(&self, other: &RigState, share: f32) -> RigState {
        let share = share.clamp(0.0, 1.0);
        let mix = |a: f32, b: f32| a + (b - a) * share;
        let mut out = RigState {
            jaw: RigJaw {
                angle_deg: mix(self.jaw.angle_deg, other.jaw.angle_deg),
                slide_m: mix(self.jaw.slide_m, other.jaw.slide_m),
            },
            lips: if share > 0.5 { other.lips } else { self.lips },
            curves: RigCurves(std::array::from_fn(|i| {
                mix(self.curves.0[i], other.curves.0[i])
            })),
            visemes: RigVisemes::default(),
        };
        out.set_visemes();
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_blend_moves_jaw_and_curves_by_the_share_and_remakes_the_visemes() {
        let mut camera = RigState::default();
        camera.curves.0[0] = 0.2;
        camera.jaw.angle_deg = 4.0;
        let mut speech = RigState::default();
        speech.curves.0[0] = 0.6;
        speech.jaw.angle_deg = 12.0;
        speech.lips.lower.translation = [0.0, -0.004, 0.0];
        speech.set_visemes();
        let half = camera.blend(&speech, 0.5);
        assert!((half.curves.0[0] - 0.4).abs() < 1e-6);
        assert!((half.jaw.angle_deg - 8.0).abs() < 1e-6);
        assert_eq!(
            half.lips, camera.lips,
            "at half, the lips stay the camera's"
        );
        let mut expected = half;
        expected.set_visemes();
        assert_eq!(half.visemes, expected.visemes);
        assert_eq!(camera.blend(&speech, 0.0), {
            let mut c = camera;
            c.set_visemes();
            c
        });
        assert_eq!(camera.blend(&speech, 1.0), speech);
        assert_eq!(camera.blend(&speech, 7.0), speech, "the share is clamped");
    }

    #[test]
    fn curves_serialise_by_name_in_order() {
        let mut rig = RigState::default();
        rig.curves.0[2] = 0.5;
        rig.jaw.angle_deg = 12.0;
        let text = serde_json::to_string(&rig).unwrap();
        assert!(
            text.contains(r#""curves":{"jawOpen":0.0,"mouthClose":0.0,"mouthFunnel":0.5"#),
            "{text}"
        );
        assert!(
            text.contains(r#""jaw":{"angle_deg":12.0,"slide_m":0.0}"#),
            "{text}"
        );
        assert_eq!(rig.curve("mouthFunnel"), Some(0.5));
        rig.set_visemes();
        let text = serde_json::to_string(&rig).unwrap();
        assert!(
            text.contains(r#""visemes":{"aa":0.0,"ih":0.0,"ou":0.5,"ee":0.0,"oh":0.0}"#),
            "{text}"
        );
    }
}
