//! Characters' heads on the wire (docs/head.md): the per-character `head` entry of `frame`,
//! the `look_at` request's checks, and the Foxglove form.

use mouthpiece_output::CharacterHead;
use serde_json::{json, Value};

use crate::hub::StreamInfo;

/// Largest coordinate a `look_at` point may have (as the dot coordinates of the retarget core).
pub const MAX_LOOK_AT_COORDINATE: f64 = 1e6;

/// Checks a `look_at` point: three finite numbers within ±[`MAX_LOOK_AT_COORDINATE`].
pub fn check_point(p: &[f64; 3]) -> Result<(), String> {
    if p.iter()
        .all(|c| c.is_finite() && c.abs() <= MAX_LOOK_AT_COORDINATE)
    {
        Ok(())
    } else {
        Err(format!(
            "look_at: point must be three finite numbers within ±{MAX_LOOK_AT_COORDINATE:e}, got {p:?}"
        ))
    }
}

/// The error text when `name` is not one of the stream's characters.
pub fn unknown_character(info: &StreamInfo, name: &str) -> Option<String> {
    if info.characters.iter().any(|c| c.name == name) {
        return None;
    }
    let known: Vec<&str> = info.characters.iter().map(|c| c.name.as_str()).collect();
    Some(format!(
        "look_at: unknown character {name:?} (available: {})",
        known.join(", ")
    ))
}

fn quaternion(q: &[f32; 4]) -> Value {
    json!({"w": q[0], "x": q[1], "y": q[2], "z": q[3]})
}

/// The `head` object of a Foxglove `/character/<name>` message.
pub fn foxglove_payload(h: &CharacterHead) -> Value {
    json!({
        "rotation": quaternion(&h.rotation),
        "eye_left": quaternion(&h.eye_left),
        "eye_right": quaternion(&h.eye_right),
        "mode": h.mode,
        "in_reach": h.in_reach,
        "progress": h.progress,
    })
}

/// JSON Schema of [`foxglove_payload`].
pub fn foxglove_schema() -> Value {
    let q = |what: &str| {
        json!({
            "type": "object",
            "description": what,
            "properties": {"w": {"type": "number"}, "x": {"type": "number"},
                           "y": {"type": "number"}, "z": {"type": "number"}}
        })
    };
    json!({
        "type": "object",
        "description": "the character's head and eyes",
        "properties": {
            "rotation": q("head rotation about its pivot, character model frame"),
            "eye_left": q("left eye rotation relative to the head"),
            "eye_right": q("right eye rotation relative to the head"),
            "mode": {"type": "string", "enum": ["follow", "look_at"]},
            "in_reach": {"type": ["boolean", "null"]},
            "progress": {"type": "number", "minimum": 0, "maximum": 1}
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::{parse_client_message, ClientMessage, ErrorCode};

    #[test]
    fn look_at_requests_are_checked() {
        let m = parse_client_message(
            r#"{"type":"look_at","id":5,"character":"wolf","point":[0.1,0.2,3]}"#,
        )
        .unwrap();
        assert!(matches!(
            m,
            ClientMessage::LookAt {
                point: Some([_, _, _]),
                ..
            }
        ));
        let m =
            parse_client_message(r#"{"type":"look_at","character":"wolf","point":null}"#).unwrap();
        assert!(matches!(m, ClientMessage::LookAt { point: None, .. }));
        for bad in [
            r#"{"type":"look_at","character":"wolf","point":[1e7,0,0]}"#,
            r#"{"type":"look_at","character":"wolf","point":[0,0]}"#,
            r#"{"type":"look_at","character":"wolf","point":["a",0,0]}"#,
            r#"{"type":"look_at","point":[0,0,1]}"#,
        ] {
            let e = parse_client_message(bad).unwrap_err();
            assert_eq!(e.code, ErrorCode::BadRequest, "{bad}: {}", e.message);
        }
        // JSON has no infinity: a number it cannot hold is not JSON the server reads.
        let e =
            parse_client_message(r#"{"type":"look_at","character":"wolf","point":[1e999,0,0]}"#)
                .unwrap_err();
        assert!(
            matches!(e.code, ErrorCode::BadJson | ErrorCode::BadRequest),
            "{e:?}"
        );
        assert!(check_point(&[f64::NAN, 0.0, 0.0]).is_err());
        assert!(check_point(&[f64::INFINITY, 0.0, 0.0]).is_err());
    }
}
