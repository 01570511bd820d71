//! The ground-truth message of synthetic sessions (`/groundtruth/points`).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// The rigid motion carrying the neutral head onto the current one:
/// `current = R · neutral + t`, camera frame, metres: the one rigid pose of every output.
pub type HeadPose = mouthpiece_output::RigidPose;

/// One frame's exact truth: every dot's centre (hidden dots too), whether it is visible, and
/// the head pose. JSON exactly as `/groundtruth/points` carries it:
/// `{"t": s, "points": {"D1": [x, y, z], …}, "visible": {"D1": true, …}, "head": {…}}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroundTruth {
    /// Seconds since the start of the session.
    pub t: f64,
    /// Dot centres, camera frame, metres, keyed by dot name (`D1`…, `F1`…).
    pub points: BTreeMap<String, [f64; 3]>,
    /// Whether the dot's centre is seen by the colour camera (not occluded, facing it).
    pub visible: BTreeMap<String, bool>,
    pub head: HeadPose,
    /// The synthetic performer's mouth state (absent in sessions written before it existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mouth: Option<MouthTruth>,
}

/// The mouth state a synthetic frame was rendered with (the synthetic performer's own
/// articulation parameters; all zero is the neutral pose).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct MouthTruth {
    /// Jaw rotation about the hinge axis (the synthetic head's, wherever the session put it),
    /// radians (opening > 0).
    pub jaw: f64,
    /// Lip spreading (corners outward), 0..1.
    pub spread: f64,
    /// Rounding and pucker (corners inward, lips forward), 0..1.
    pub round: f64,
    /// Upper-lip raise, 0..1.
    pub raise: f64,
    /// Lower lip rolled in under the upper lip, 0..1.
    pub roll_in: f64,
    /// The jaw's slide along the hinge axis, metres (> 0 towards the performer's left);
    /// absent, 0: a jaw that does not slide (the default synthetic jaw).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub slide: f64,
    /// The jaw's forward glide, metres (> 0 out of the face); absent, 0.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub glide: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

impl GroundTruth {
    pub fn point(&self, name: &str) -> Option<[f64; 3]> {
        self.points.get(name).copied()
    }

    pub fn is_visible(&self, name: &str) -> bool {
        self.visible.get(name).copied().unwrap_or(false)
    }

    /// JSON Schema of the message (stored as the channel's `jsonschema` schema).
    pub fn json_schema() -> &'static str {
        r#"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "mouthpiece.GroundTruth",
  "description": "Exact dot centres (camera frame, metres), visibility and head pose of a synthetic frame",
  "type": "object",
  "required": ["t", "points", "visible", "head"],
  "properties": {
    "t": {"type": "number", "description": "seconds since the start of the session"},
    "points": {"type": "object", "additionalProperties": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}},
    "visible": {"type": "object", "additionalProperties": {"type": "boolean"}},
    "head": {
      "type": "object",
      "required": ["rotation", "translation"],
      "properties": {
        "rotation": {"type": "array", "items": {"type": "number"}, "minItems": 4, "maxItems": 4, "description": "unit quaternion [w, x, y, z], neutral head to current"},
        "translation": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3, "description": "metres, camera frame"}
      }
    },
    "mouth": {
      "type": "object",
      "description": "the synthetic mouth state: jaw (radians, about the hinge), spread, round, raise, roll_in (0..1); slide (metres along the hinge axis, > 0 the performer's left) and glide (metres forward), absent when 0",
      "required": ["jaw", "spread", "round", "raise", "roll_in"],
      "properties": {
        "jaw": {"type": "number"}, "spread": {"type": "number"}, "round": {"type": "number"},
        "raise": {"type": "number"}, "roll_in": {"type": "number"},
        "slide": {"type": "number"}, "glide": {"type": "number"}
      }
    }
  }
}"#
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quaternion_rotates_like_its_matrix() {
        // 90° about z: x → y.
        let h = 0.5f64.sqrt();
        let pose = HeadPose {
            rotation: [h, 0.0, 0.0, h],
            translation: [0.0, 0.0, 1.0],
        };
        let p = pose.apply([1.0, 0.0, 0.0]);
        assert!((p[0]).abs() < 1e-12 && (p[1] - 1.0).abs() < 1e-12 && (p[2] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn json_has_the_documented_shape() {
        let gt = GroundTruth {
            t: 0.5,
            points: [("D1".to_string(), [0.1, 0.2, 0.6])].into(),
            visible: [("D1".to_string(), true)].into(),
            head: HeadPose::IDENTITY,
            mouth: Some(MouthTruth {
                jaw: 0.1,
                ..MouthTruth::default()
            }),
        };
        let v: serde_json::Value = serde_json::to_value(&gt).unwrap();
        assert_eq!(v["points"]["D1"][2], 0.6);
        assert_eq!(v["visible"]["D1"], true);
        assert_eq!(v["head"]["rotation"][0], 1.0);
        assert_eq!(v["mouth"]["jaw"], 0.1);
        let back: GroundTruth = serde_json::from_value(v).unwrap();
        assert_eq!(back, gt);
        let _: serde_json::Value = serde_json::from_str(GroundTruth::json_schema()).unwrap();
    }
}
