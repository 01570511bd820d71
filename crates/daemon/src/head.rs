//! The retarget core's head frame in the stream's form (docs/head.md).

use mouthpiece_retarget::head::{wxyz, HeadFrame, HeadMode};
use mouthpiece_server::{CharacterHead, LookMode};

/// The stream's `head` entry for a character's head frame.
pub fn wire(h: &HeadFrame) -> CharacterHead {
    let q = |q| wxyz(q).map(|c| c as f32);
    CharacterHead {
        rotation: q(&h.rotation),
        eye_left: q(&h.eye_left),
        eye_right: q(&h.eye_right),
        mode: match h.mode {
            HeadMode::Follow => LookMode::Follow,
            HeadMode::LookAt => LookMode::LookAt,
        },
        in_reach: h.in_reach,
        progress: h.progress as f32,
    }
}
