//! Heads: the performer's head pose (the forehead's rigid motion, which the retarget removes)
//! and each character's head and eyes (docs/head.md).

use serde::{Deserialize, Serialize};

/// Head pose of one frame (docs/method.md §10): current = R · neutral + t, camera frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HeadPose {
    /// Unit quaternion `[w, x, y, z]`.
    pub rotation: [f64; 4],
    /// Translation, metres.
    pub translation: [f64; 3],
    /// Fewer than three forehead dots were seen: the pose is the last good one.
    pub lost: bool,
}

impl Default for HeadPose {
    fn default() -> Self {
        Self {
            rotation: [1.0, 0.0, 0.0, 0.0],
            translation: [0.0; 3],
            lost: false,
        }
    }
}

/// What drives a character's head.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LookMode {
    /// The performer's head rotation, scaled and limited to the character's reach.
    #[default]
    Follow,
    /// Turning to, or facing, a viewpoint set with `look_at`.
    LookAt,
}

/// One character's head and eyes in one frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CharacterHead {
    /// The head's rotation about its pivot, the character's model frame, `[w, x, y, z]`.
    pub rotation: [f32; 4],
    /// The left eye's rotation relative to the head, `[w, x, y, z]`.
    pub eye_left: [f32; 4],
    /// The right eye's rotation relative to the head, `[w, x, y, z]`.
    pub eye_right: [f32; 4],
    /// What drives the head.
    pub mode: LookMode,
    /// With a viewpoint: whether the head can face it; `null` while following.
    pub in_reach: Option<bool>,
    /// How far the current turn has come, 0..=1 (1 when none is under way).
    pub progress: f32,
}

impl Default for CharacterHead {
    fn default() -> Self {
        Self {
            rotation: [1.0, 0.0, 0.0, 0.0],
            eye_left: [1.0, 0.0, 0.0, 0.0],
            eye_right: [1.0, 0.0, 0.0, 0.0],
            mode: LookMode::Follow,
            in_reach: None,
            progress: 1.0,
        }
    }
}
