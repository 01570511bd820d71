//! The `rig` of a character entry (docs/rig.md, docs/protocol.md): jaw, lip motions and the
//! ARKit-named mouth curves, as the daemon publishes them. Fixed-size and `Copy`, so that
//! publishing does not allocate; the curves serialise as a name → value object.

use serde::ser::SerializeMap;
use serde::{Serialize, Serializer};
use serde_json::{json, Value};

/// Curve names in the order of [`RigState::curves`] (the retarget core's order; the daemon's
/// tests check that both lists agree).
pub const RIG_CURVE_NAMES: [&str; 18] = [
    "jawOpen",
    "mouthClose",
    "mouthFunnel",
    "mouthPucker",
    "mouthLeft",
    "mouthRight",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthStretchLeft",
    "mouthStretchRight",
    "mouthRollUpper",
    "mouthRollLower",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "mouthPressLeft",
    "mouthPressRight",
];

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

/// The curves, in [`RIG_CURVE_NAMES`] order, 0..1.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RigCurves(pub [f32; 18]);

impl Serialize for RigCurves {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(Some(self.0.len()))?;
        for (name, v) in RIG_CURVE_NAMES.iter().zip(&self.0) {
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
}

impl RigState {
    /// The value of a curve by name.
    pub fn curve(&self, name: &str) -> Option<f32> {
        RIG_CURVE_NAMES
            .iter()
            .position(|n| *n == name)
            .map(|i| self.curves.0[i])
    }
}

/// The properties of a Foxglove `/rig/<name>` message (its JSON Schema's `properties`; the
/// channel adds `seq`, `t`, `capture_us`). Quaternions are `{w, x, y, z}` objects and the
/// curves an object with one number per name, so that each is a plottable message path
/// (`/rig/wolf.curves.jawOpen`, `/rig/wolf.jaw.angle_deg`).
pub fn foxglove_properties() -> Value {
    let number = |what: &str| json!({"type": "number", "description": what});
    let lip = |what: &str| {
        json!({
            "type": "object",
            "description": what,
            "properties": {
                "rotation": {
                    "type": "object",
                    "description": "unit quaternion carrying the neutral lip onto the current one",
                    "properties": {"w": {"type": "number"}, "x": {"type": "number"},
                                   "y": {"type": "number"}, "z": {"type": "number"}},
                    "required": ["w", "x", "y", "z"]
                },
                "translation": {
                    "type": "object",
                    "description": "metres, performer mouth frame",
                    "properties": {"x": {"type": "number"}, "y": {"type": "number"},
                                   "z": {"type": "number"}},
                    "required": ["x", "y", "z"]
                },
                "residual": number("RMS distance the rigid motion leaves, metres")
            },
            "required": ["rotation", "translation", "residual"]
        })
    };
    let curves: serde_json::Map<String, Value> = RIG_CURVE_NAMES
        .iter()
        .map(|n| {
            (
                (*n).to_owned(),
                json!({"type": "number", "minimum": 0, "maximum": 1}),
            )
        })
        .collect();
    json!({
        "name": {"type": "string", "description": "the character"},
        "jaw": {
            "type": "object",
            "properties": {
                "angle_deg": number("opening angle about the hinge axis, degrees, > 0 open"),
                "slide_m": number("slide along the hinge axis, metres, > 0 towards the performer's left")
            },
            "required": ["angle_deg", "slide_m"]
        },
        "lips": {
            "type": "object",
            "properties": {"upper": lip("upper lip"), "lower": lip("lower lip")},
            "required": ["upper", "lower"]
        },
        "curves": {
            "type": "object",
            "description": "ARKit-named mouth curves, 0..1",
            "properties": curves,
            "required": RIG_CURVE_NAMES,
            "additionalProperties": false
        }
    })
}

/// The body of a Foxglove `/rig/<name>` message (before the channel's stamp).
pub fn foxglove_payload(name: &str, rig: &RigState) -> Value {
    let lip = |l: &RigLip| {
        let [w, x, y, z] = l.rotation;
        let [tx, ty, tz] = l.translation;
        json!({
            "rotation": {"w": w, "x": x, "y": y, "z": z},
            "translation": {"x": tx, "y": ty, "z": tz},
            "residual": l.residual,
        })
    };
    json!({
        "name": name,
        "jaw": rig.jaw,
        "lips": {"upper": lip(&rig.lips.upper), "lower": lip(&rig.lips.lower)},
        "curves": rig.curves,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

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
    }
}
