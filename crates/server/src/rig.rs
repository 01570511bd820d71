//! The rig's Foxglove form (docs/rig.md, docs/protocol.md): the `/rig/<name>` channel's
//! schema and payload. The rig itself is [`mouthpiece_output::RigState`].

use mouthpiece_output::{RigLip, RigState, CURVE_NAMES, VISEME_NAMES};
use serde_json::{json, Value};

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
    let curves: serde_json::Map<String, Value> = CURVE_NAMES
        .iter()
        .map(|n| {
            (
                (*n).to_owned(),
                json!({"type": "number", "minimum": 0, "maximum": 1}),
            )
        })
        .collect();
    let visemes: serde_json::Map<String, Value> = VISEME_NAMES
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
            "required": CURVE_NAMES,
            "additionalProperties": false
        },
        "visemes": {
            "type": "object",
            "description": "VRM 1.0 mouth expressions from the curves, 0..1",
            "properties": visemes,
            "required": VISEME_NAMES,
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
        "visemes": rig.visemes,
    })
}
