//! A character's face as ARKit's 52 blend shapes plus head and eye angles: the values the
//! studio protocols that speak ARKit carry (Live Link Face's stream and CSV takes,
//! iFacialMocap), built once from a character's frame so every such output sends the same
//! numbers (docs/arkit.md).
//!
//! - The blend shapes are in Apple's ARKit order ([`ARKIT_NAMES`], the order of Unreal's
//!   `EARFaceBlendShape` and of the Live Link Face datagram): `eyeBlinkLeft` first, `jawOpen`
//!   at 17, `tongueOut` last (51).
//! - The rig's 27 curves ([`crate::CURVE_NAMES`], all of them ARKit names) map by name; the
//!   eyes' `eyeLook*` shapes come from the character's eye rotations
//!   ([`EYE_LOOK_FULL_SCALE_DEG`]); the 17 shapes nothing measures ([`UNMEASURED`]: blinks,
//!   squints, wide eyes, brows, cheeks, nose, tongue) stay 0.
//! - Head and eye angles are radians, in Live Link Face's signs: yaw positive when the head
//!   (or eye) turns to the character's **right**, pitch positive when it tips **down**, roll
//!   positive when it tilts towards the character's **left** shoulder ([`angles_of`]).
//!
//! Left and right are the character's own, as in ARKit's names (`mouthSmileLeft` is the
//! corner on the character's left).

use crate::curves::{CURVES, CURVE_NAMES};
use crate::frame::CharacterFrame;
use crate::head::CharacterHead;

/// How many ARKit blend shapes there are.
pub const BLENDSHAPES: usize = 52;

/// How many values a Live Link Face frame carries: the blend shapes, then head yaw, pitch,
/// roll, the left eye's and the right eye's.
pub const LIVELINK_VALUES: usize = BLENDSHAPES + 9;

/// ARKit's blend-shape names (`ARFaceAnchor.BlendShapeLocation`, lowerCamelCase) in Apple's
/// order, which Unreal's `EARFaceBlendShape` and the Live Link Face datagram share.
pub const ARKIT_NAMES: [&str; BLENDSHAPES] = [
    "eyeBlinkLeft",
    "eyeLookDownLeft",
    "eyeLookInLeft",
    "eyeLookOutLeft",
    "eyeLookUpLeft",
    "eyeSquintLeft",
    "eyeWideLeft",
    "eyeBlinkRight",
    "eyeLookDownRight",
    "eyeLookInRight",
    "eyeLookOutRight",
    "eyeLookUpRight",
    "eyeSquintRight",
    "eyeWideRight",
    "jawForward",
    "jawLeft",
    "jawRight",
    "jawOpen",
    "mouthClose",
    "mouthFunnel",
    "mouthPucker",
    "mouthLeft",
    "mouthRight",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthFrownLeft",
    "mouthFrownRight",
    "mouthDimpleLeft",
    "mouthDimpleRight",
    "mouthStretchLeft",
    "mouthStretchRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthPressLeft",
    "mouthPressRight",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "browDownLeft",
    "browDownRight",
    "browInnerUp",
    "browOuterUpLeft",
    "browOuterUpRight",
    "cheekPuff",
    "cheekSquintLeft",
    "cheekSquintRight",
    "noseSneerLeft",
    "noseSneerRight",
    "tongueOut",
];

/// The Live Link Face names of the 61 values, in the datagram's order: the blend shapes in
/// PascalCase (`EyeBlinkLeft`, as Unreal's `EARFaceBlendShape` names them), then the angles.
pub const LIVELINK_NAMES: [&str; LIVELINK_VALUES] = [
    "EyeBlinkLeft",
    "EyeLookDownLeft",
    "EyeLookInLeft",
    "EyeLookOutLeft",
    "EyeLookUpLeft",
    "EyeSquintLeft",
    "EyeWideLeft",
    "EyeBlinkRight",
    "EyeLookDownRight",
    "EyeLookInRight",
    "EyeLookOutRight",
    "EyeLookUpRight",
    "EyeSquintRight",
    "EyeWideRight",
    "JawForward",
    "JawLeft",
    "JawRight",
    "JawOpen",
    "MouthClose",
    "MouthFunnel",
    "MouthPucker",
    "MouthLeft",
    "MouthRight",
    "MouthSmileLeft",
    "MouthSmileRight",
    "MouthFrownLeft",
    "MouthFrownRight",
    "MouthDimpleLeft",
    "MouthDimpleRight",
    "MouthStretchLeft",
    "MouthStretchRight",
    "MouthRollLower",
    "MouthRollUpper",
    "MouthShrugLower",
    "MouthShrugUpper",
    "MouthPressLeft",
    "MouthPressRight",
    "MouthLowerDownLeft",
    "MouthLowerDownRight",
    "MouthUpperUpLeft",
    "MouthUpperUpRight",
    "BrowDownLeft",
    "BrowDownRight",
    "BrowInnerUp",
    "BrowOuterUpLeft",
    "BrowOuterUpRight",
    "CheekPuff",
    "CheekSquintLeft",
    "CheekSquintRight",
    "NoseSneerLeft",
    "NoseSneerRight",
    "TongueOut",
    "HeadYaw",
    "HeadPitch",
    "HeadRoll",
    "LeftEyeYaw",
    "LeftEyePitch",
    "LeftEyeRoll",
    "RightEyeYaw",
    "RightEyePitch",
    "RightEyeRoll",
];

/// The blend shapes nothing measures: no dot on the eyelids, brows, cheeks or nose, the
/// forehead dots being the head's rigid reference, and the tongue never painted (docs/rig.md,
/// *What the dots cannot tell*). They are always 0.
pub const UNMEASURED: [&str; 17] = [
    "eyeBlinkLeft",
    "eyeSquintLeft",
    "eyeWideLeft",
    "eyeBlinkRight",
    "eyeSquintRight",
    "eyeWideRight",
    "browDownLeft",
    "browDownRight",
    "browInnerUp",
    "browOuterUpLeft",
    "browOuterUpRight",
    "cheekPuff",
    "cheekSquintLeft",
    "cheekSquintRight",
    "noseSneerLeft",
    "noseSneerRight",
    "tongueOut",
];

/// The eye angle at which an `eyeLook*` shape reaches 1: the character's default eye limit
/// (`[head] eye_max_deg`, docs/head.md), so an eye turned as far as it goes by default reads
/// 1, halfway 0.5. Beyond it the shape stays 1.
pub const EYE_LOOK_FULL_SCALE_DEG: f64 = 30.0;

/// Index of an ARKit name in [`ARKIT_NAMES`] (exact, case-sensitive).
pub fn arkit_index(name: &str) -> Option<usize> {
    ARKIT_NAMES.iter().position(|n| *n == name)
}

/// A character's head-frame axes (docs/head.md, *Frames*) in its model frame: the unit
/// directions of its own left, up and forward. Head rotations are given in the model frame;
/// the angles are taken in these axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadAxes {
    pub left: [f64; 3],
    pub up: [f64; 3],
    pub forward: [f64; 3],
}

impl HeadAxes {
    /// Model frame = head frame (x left, y up, z forward).
    pub const IDENTITY: HeadAxes = HeadAxes {
        left: [1.0, 0.0, 0.0],
        up: [0.0, 1.0, 0.0],
        forward: [0.0, 0.0, 1.0],
    };

    /// From a matrix whose columns are left, up, forward (row-major `m[row][column]`).
    pub fn from_columns(m: [[f64; 3]; 3]) -> Self {
        HeadAxes {
            left: [m[0][0], m[1][0], m[2][0]],
            up: [m[0][1], m[1][1], m[2][1]],
            forward: [m[0][2], m[1][2], m[2][2]],
        }
    }

    /// `Aᵀ R A`: a model-frame rotation matrix written in the head frame's axes.
    fn in_head_axes(&self, r: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
        let a = [self.left, self.up, self.forward];
        let mut out = [[0.0; 3]; 3];
        for (i, ai) in a.iter().enumerate() {
            for (j, aj) in a.iter().enumerate() {
                // out[i][j] = aiᵀ R aj
                let mut s = 0.0;
                for (k, rk) in r.iter().enumerate() {
                    s += ai[k] * (rk[0] * aj[0] + rk[1] * aj[1] + rk[2] * aj[2]);
                }
                out[i][j] = s;
            }
        }
        out
    }
}

/// Yaw, pitch and roll (radians) of a rotation written in head-frame axes (left, up,
/// forward; row-major matrix), in Live Link Face's signs.
///
/// The rotation is decomposed as ARKit decomposes a face's (`R = R_up(a) · R_left(b) ·
/// R_forward(c)`, each a right-handed turn about the head's own axis: `a` turns the face to
/// its left, `b` tips it down, `c` lifts its left side); Live Link Face sends the mirror image
/// (its Unreal source negates yaw and roll together): yaw `−a`, pitch `b`, roll `−c`. So a
/// turn to the character's right is a positive yaw, a nod down a positive pitch, a tilt
/// towards the left shoulder a positive roll. The pitch is clamped to ±90°.
pub fn angles_of(h: &[[f64; 3]; 3]) -> [f64; 3] {
    let a = h[0][2].atan2(h[2][2]);
    let b = (-h[1][2]).clamp(-1.0, 1.0).asin();
    let c = h[1][0].atan2(h[1][1]);
    [-a, b, -c]
}

/// Row-major rotation matrix of a quaternion `[w, x, y, z]` (normalised first; identity for
/// a zero or non-finite one).
fn matrix_of(q: [f32; 4]) -> [[f64; 3]; 3] {
    let [w, x, y, z] = q.map(f64::from);
    let n = (w * w + x * x + y * y + z * z).sqrt();
    if !(n.is_finite() && n > 0.0) {
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    }
    let (w, x, y, z) = (w / n, x / n, y / n, z / n);
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// One character's face in one frame, as ARKit-speaking receivers take it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArkitFace {
    /// The blend shapes in [`ARKIT_NAMES`] order, each 0..=1.
    pub blendshapes: [f32; BLENDSHAPES],
    /// The head's yaw, pitch, roll, radians ([`angles_of`]).
    pub head: [f32; 3],
    /// The left eye's yaw, pitch, roll relative to the head, radians.
    pub eye_left: [f32; 3],
    /// The right eye's yaw, pitch, roll relative to the head, radians.
    pub eye_right: [f32; 3],
}

impl Default for ArkitFace {
    fn default() -> Self {
        ArkitFace {
            blendshapes: [0.0; BLENDSHAPES],
            head: [0.0; 3],
            eye_left: [0.0; 3],
            eye_right: [0.0; 3],
        }
    }
}

/// Where each rig curve goes in [`ARKIT_NAMES`] (every rig curve is an ARKit name).
const fn rig_slots() -> [usize; CURVES] {
    let mut out = [0; CURVES];
    let mut i = 0;
    while i < CURVES {
        let mut j = 0;
        loop {
            assert!(j < BLENDSHAPES, "a rig curve that is not an ARKit name");
            if str_eq(CURVE_NAMES[i], ARKIT_NAMES[j]) {
                break;
            }
            j += 1;
        }
        out[i] = j;
        i += 1;
    }
    out
}

const fn str_eq(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len() != b.len() {
        return false;
    }
    let mut i = 0;
    while i < a.len() {
        if a[i] != b[i] {
            return false;
        }
        i += 1;
    }
    true
}

/// [`rig_slots`], computed at compile time (a rig curve missing from ARKit's names fails the
/// build).
const RIG_SLOTS: [usize; CURVES] = rig_slots();

/// Index in [`ARKIT_NAMES`] by name, at compile time.
const fn slot(name: &str) -> usize {
    let mut j = 0;
    while j < BLENDSHAPES {
        if str_eq(name, ARKIT_NAMES[j]) {
            return j;
        }
        j += 1;
    }
    panic!("not an ARKit name")
}

impl ArkitFace {
    /// The face of `character` in one frame: its rig's curves by name (all 0 without a rig),
    /// its head and eye angles and the eyes' `eyeLook*` shapes (at rest without a head);
    /// `axes` are the character's head-frame axes in its model frame.
    pub fn from_character(character: &CharacterFrame, axes: &HeadAxes) -> Self {
        let mut face = ArkitFace::default();
        if let Some(rig) = &character.rig {
            for (value, &j) in rig.curves.0.iter().zip(&RIG_SLOTS) {
                face.blendshapes[j] = if value.is_finite() {
                    value.clamp(0.0, 1.0)
                } else {
                    0.0
                };
            }
        }
        if let Some(head) = &character.head {
            face.set_head(head, axes);
        }
        face
    }

    /// The head and eye angles and the eyes' `eyeLook*` shapes from a character's head.
    pub fn set_head(&mut self, head: &CharacterHead, axes: &HeadAxes) {
        self.head = angles_of(&axes.in_head_axes(&matrix_of(head.rotation))).map(|v| v as f32);
        // The eyes' rotations are relative to the head, in its axes (the model's axes turned
        // with the head): the same change of axes applies.
        let left = axes.in_head_axes(&matrix_of(head.eye_left));
        let right = axes.in_head_axes(&matrix_of(head.eye_right));
        self.eye_left = angles_of(&left).map(|v| v as f32);
        self.eye_right = angles_of(&right).map(|v| v as f32);
        let full = EYE_LOOK_FULL_SCALE_DEG.to_radians();
        let shape = |angle: f64| ((angle / full).clamp(0.0, 1.0)) as f32;
        // Each eye's gaze (its forward axis) in the head's axes: towards the character's left
        // (positive `side`) is out for the left eye and in for the right one.
        for (m, down, inward, outward, up, is_left) in [
            (
                &left,
                slot("eyeLookDownLeft"),
                slot("eyeLookInLeft"),
                slot("eyeLookOutLeft"),
                slot("eyeLookUpLeft"),
                true,
            ),
            (
                &right,
                slot("eyeLookDownRight"),
                slot("eyeLookInRight"),
                slot("eyeLookOutRight"),
                slot("eyeLookUpRight"),
                false,
            ),
        ] {
            let [gl, gu, gf] = [m[0][2], m[1][2], m[2][2]];
            let side = gl.atan2(gf);
            let rise = gu.atan2((gl * gl + gf * gf).sqrt());
            let towards_left = if is_left { outward } else { inward };
            let towards_right = if is_left { inward } else { outward };
            self.blendshapes[towards_left] = shape(side);
            self.blendshapes[towards_right] = shape(-side);
            self.blendshapes[up] = shape(rise);
            self.blendshapes[down] = shape(-rise);
        }
    }

    /// The 61 values in Live Link Face's order ([`LIVELINK_NAMES`]).
    pub fn livelink_values(&self) -> [f32; LIVELINK_VALUES] {
        let mut out = [0.0; LIVELINK_VALUES];
        out[..BLENDSHAPES].copy_from_slice(&self.blendshapes);
        out[BLENDSHAPES..BLENDSHAPES + 3].copy_from_slice(&self.head);
        out[BLENDSHAPES + 3..BLENDSHAPES + 6].copy_from_slice(&self.eye_left);
        out[BLENDSHAPES + 6..].copy_from_slice(&self.eye_right);
        out
    }

    /// A blend shape's value by its ARKit name.
    pub fn blendshape(&self, name: &str) -> Option<f32> {
        arkit_index(name).map(|i| self.blendshapes[i])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::RigState;
    use std::collections::HashSet;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-5
    }

    /// A turn by `deg` about a model-frame axis, `[w, x, y, z]`.
    fn turn(axis: [f64; 3], deg: f64) -> [f32; 4] {
        let h = deg.to_radians() / 2.0;
        let s = h.sin();
        [h.cos(), axis[0] * s, axis[1] * s, axis[2] * s].map(|v| v as f32)
    }

    fn character(head: CharacterHead) -> CharacterFrame {
        CharacterFrame {
            name: "wolf".into(),
            head: Some(head),
            ..Default::default()
        }
    }

    #[test]
    fn names_are_in_apples_order() {
        assert_eq!(ARKIT_NAMES.len(), 52);
        assert_eq!(ARKIT_NAMES[0], "eyeBlinkLeft");
        assert_eq!(ARKIT_NAMES[7], "eyeBlinkRight");
        assert_eq!(ARKIT_NAMES[14], "jawForward");
        assert_eq!(ARKIT_NAMES[17], "jawOpen");
        assert_eq!(ARKIT_NAMES[18], "mouthClose");
        assert_eq!(ARKIT_NAMES[41], "browDownLeft");
        assert_eq!(ARKIT_NAMES[51], "tongueOut");
        let unique: HashSet<_> = ARKIT_NAMES.iter().collect();
        assert_eq!(unique.len(), 52);
        // The Live Link names are the same names capitalised, then the nine angles.
        for (a, l) in ARKIT_NAMES.iter().zip(&LIVELINK_NAMES) {
            assert_eq!(l[..1], a[..1].to_uppercase());
            assert_eq!(l[1..], a[1..]);
        }
        assert_eq!(LIVELINK_NAMES[52], "HeadYaw");
        assert_eq!(LIVELINK_NAMES[55], "LeftEyeYaw");
        assert_eq!(LIVELINK_NAMES[60], "RightEyeRoll");
        // Measured and unmeasured shapes split the 52: 27 rig curves, 8 eyeLook, 17 zeros.
        let unmeasured: HashSet<_> = UNMEASURED.iter().collect();
        assert_eq!(unmeasured.len(), 17);
        for name in CURVE_NAMES {
            assert!(arkit_index(name).is_some(), "{name}");
            assert!(!unmeasured.contains(&name), "{name}");
        }
        let looks = ARKIT_NAMES
            .iter()
            .filter(|n| n.starts_with("eyeLook"))
            .count();
        assert_eq!(looks, 8);
        assert_eq!(CURVES + looks + UNMEASURED.len(), BLENDSHAPES);
    }

    #[test]
    fn rig_curves_map_by_name() {
        let mut rig = RigState::default();
        for (i, v) in rig.curves.0.iter_mut().enumerate() {
            *v = 0.01 * (i + 1) as f32;
        }
        rig.curves.0[crate::curve_index("jawOpen").unwrap()] = 0.75;
        rig.curves.0[crate::curve_index("mouthSmileLeft").unwrap()] = 0.25;
        rig.curves.0[crate::curve_index("mouthDimpleRight").unwrap()] = f32::NAN;
        let c = CharacterFrame {
            rig: Some(rig),
            ..Default::default()
        };
        let face = ArkitFace::from_character(&c, &HeadAxes::IDENTITY);
        assert_eq!(face.blendshapes[17], 0.75);
        assert_eq!(face.blendshape("mouthSmileLeft"), Some(0.25));
        assert_eq!(face.blendshape("mouthDimpleRight"), Some(0.0));
        for (i, name) in CURVE_NAMES.iter().enumerate() {
            if !["jawOpen", "mouthSmileLeft", "mouthDimpleRight"].contains(name) {
                assert_eq!(face.blendshape(name), Some(rig.curves.0[i]), "{name}");
            }
        }
        for name in UNMEASURED {
            assert_eq!(face.blendshape(name), Some(0.0), "{name}");
        }
        assert_eq!(face.livelink_values()[17], 0.75);
        // No rig: every shape at rest.
        let none = ArkitFace::from_character(&CharacterFrame::default(), &HeadAxes::IDENTITY);
        assert_eq!(none, ArkitFace::default());
    }

    /// A turn to the character's left is a negative yaw, a nod down a positive pitch, a tilt
    /// towards the left shoulder a positive roll, whatever the model frame's axes.
    #[test]
    fn head_turns_have_live_link_signs() {
        // Model frame = head frame: left x, up y, forward z.
        let id = HeadAxes::IDENTITY;
        let face = |q| ArkitFace::from_character(&character(head_with(q)), &id);
        // 30° to the character's left: forward (z) turns towards left (x), about up (+y).
        let left = face(turn([0.0, 1.0, 0.0], 30.0));
        assert!(close(left.head[0].into(), -30f64.to_radians()), "{left:?}");
        assert!(close(left.head[1].into(), 0.0) && close(left.head[2].into(), 0.0));
        // 20° down: forward (z) towards down (−y), about left (+x).
        let down = face(turn([1.0, 0.0, 0.0], 20.0));
        assert!(close(down.head[1].into(), 20f64.to_radians()), "{down:?}");
        assert!(close(down.head[0].into(), 0.0) && close(down.head[2].into(), 0.0));
        // 10° tilt to the left shoulder: up (y) towards left (x), about forward: −z.
        let tilt = face(turn([0.0, 0.0, 1.0], -10.0));
        assert!(close(tilt.head[2].into(), 10f64.to_radians()), "{tilt:?}");
        // A combined turn comes back as the angles it was built from: yaw a, then pitch b,
        // then roll c, each about the turned head's own axes.
        let (a, b, c) = (25f64, -15f64, 8f64);
        let q = mul(
            mul(turn([0.0, 1.0, 0.0], -a), turn([1.0, 0.0, 0.0], b)),
            turn([0.0, 0.0, 1.0], -c),
        );
        let got = face(q).head;
        for (g, want) in got.iter().zip([a, b, c]) {
            assert!(close((*g).into(), want.to_radians()), "{got:?}");
        }
        // Another model frame (x right, y forward, z up, like a Z-up file): the same turn
        // to the character's left reads the same yaw.
        let zup = HeadAxes {
            left: [-1.0, 0.0, 0.0],
            up: [0.0, 0.0, 1.0],
            forward: [0.0, 1.0, 0.0],
        };
        // Forward (+y) towards left (−x): a right-handed turn about up (+z).
        let f = ArkitFace::from_character(&character(head_with(turn([0.0, 0.0, 1.0], 30.0))), &zup);
        assert!(close(f.head[0].into(), -30f64.to_radians()), "{f:?}");
    }

    #[test]
    fn eyes_give_their_angles_and_look_shapes() {
        // Both eyes 15° to the character's left and 6° up (relative to the head).
        let q = mul(turn([0.0, 1.0, 0.0], 15.0), turn([1.0, 0.0, 0.0], -6.0));
        let head = CharacterHead {
            eye_left: q,
            eye_right: q,
            ..Default::default()
        };
        let face = ArkitFace::from_character(&character(head), &HeadAxes::IDENTITY);
        assert!(close(face.eye_left[0].into(), -15f64.to_radians()));
        assert!(close(face.eye_left[1].into(), -6f64.to_radians()));
        assert_eq!(face.head, [0.0; 3]);
        let s = |n| f64::from(face.blendshape(n).unwrap());
        assert!(close(s("eyeLookOutLeft"), 0.5), "{face:?}");
        assert!(close(s("eyeLookInRight"), 0.5));
        assert_eq!(s("eyeLookInLeft"), 0.0);
        assert_eq!(s("eyeLookOutRight"), 0.0);
        // The gaze's elevation (6°: the nod is about the eye's own turned axis).
        let rise = (q_forward(q)[1]).asin().to_degrees();
        assert!(
            close(s("eyeLookUpLeft"), rise / 30.0),
            "{}",
            s("eyeLookUpLeft")
        );
        assert_eq!(s("eyeLookDownLeft"), 0.0);
        // Beyond the full scale the shape stays 1.
        let far = CharacterHead {
            eye_right: turn([0.0, 1.0, 0.0], -50.0),
            ..Default::default()
        };
        let face = ArkitFace::from_character(&character(far), &HeadAxes::IDENTITY);
        assert_eq!(face.blendshape("eyeLookOutRight"), Some(1.0));
        assert_eq!(face.blendshape("eyeLookInLeft"), Some(0.0));
        let v = face.livelink_values();
        assert!(close(v[58].into(), 50f64.to_radians()));
    }

    fn head_with(rotation: [f32; 4]) -> CharacterHead {
        CharacterHead {
            rotation,
            ..Default::default()
        }
    }

    fn mul(a: [f32; 4], b: [f32; 4]) -> [f32; 4] {
        let [aw, ax, ay, az] = a;
        let [bw, bx, by, bz] = b;
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    }

    fn q_forward(q: [f32; 4]) -> [f64; 3] {
        let m = matrix_of(q);
        [m[0][2], m[1][2], m[2][2]]
    }
}
