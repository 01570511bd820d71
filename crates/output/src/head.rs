//! Heads: the performer's head pose (the forehead's rigid motion, which the retarget removes)
//! and each character's head and eyes (docs/head.md).

use serde::{Deserialize, Serialize};

/// A rigid motion: `current = R · neutral + t`, camera frame (docs/method.md §10). The
/// performer's head pose in every output, file and ground truth is this.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RigidPose {
    /// Unit quaternion `[w, x, y, z]`.
    pub rotation: [f64; 4],
    /// Translation, metres.
    pub translation: [f64; 3],
}

impl Default for RigidPose {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl RigidPose {
    pub const IDENTITY: RigidPose = RigidPose {
        rotation: [1.0, 0.0, 0.0, 0.0],
        translation: [0.0; 3],
    };

    /// Applies the pose to a point of the neutral head.
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        let m = self.rotation_matrix();
        let t = self.translation;
        [
            m[0][0] * p[0] + m[0][1] * p[1] + m[0][2] * p[2] + t[0],
            m[1][0] * p[0] + m[1][1] * p[1] + m[1][2] * p[2] + t[1],
            m[2][0] * p[0] + m[2][1] * p[1] + m[2][2] * p[2] + t[2],
        ]
    }

    /// Row-major rotation matrix of the (normalised) quaternion.
    pub fn rotation_matrix(&self) -> [[f64; 3]; 3] {
        let [w, x, y, z] = self.rotation;
        let n = (w * w + x * x + y * y + z * z).sqrt();
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
}

/// The performer's head pose in one published frame: the rigid motion, and whether it is a
/// held one. Serialises flat: `{"rotation", "translation", "lost"}`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct HeadPose {
    #[serde(flatten)]
    pub pose: RigidPose,
    /// Fewer than three forehead dots were seen: the pose is the last good one.
    pub lost: bool,
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
