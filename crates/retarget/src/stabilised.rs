//! The performer after head-motion removal: what the stabiliser hands the retarget and the
//! rig each step.

use crate::kabsch::RigidTransform;
use crate::Vec3;

/// One time step of the performer after head-motion removal.
#[derive(Debug, PartialEq)]
pub struct StabilisedFrame {
    /// Timestamp, seconds.
    pub t: f64,
    /// `Dᵐ`: lip dots in the performer's neutral mouth frame (metres); missing dots held or
    /// decaying towards neutral.
    pub lip: Vec<Vec3>,
    /// Per lip dot: 1 when seen this step, 0 when held or decaying.
    pub confidence: Vec<f64>,
    /// Head pose: the rigid motion carrying the neutral head onto the current one in the
    /// camera frame (`current = R · neutral + t`).
    pub head: RigidTransform,
    /// Fewer than 3 usable forehead dots: `head` is the last good pose.
    pub head_lost: bool,
}

// By hand for `clone_from`: copying a step into a kept frame reuses its vectors (the
// per-frame path must not allocate).
impl Clone for StabilisedFrame {
    fn clone(&self) -> Self {
        Self {
            t: self.t,
            lip: self.lip.clone(),
            confidence: self.confidence.clone(),
            head: self.head,
            head_lost: self.head_lost,
        }
    }

    fn clone_from(&mut self, source: &Self) {
        self.t = source.t;
        self.lip.clone_from(&source.lip);
        self.confidence.clone_from(&source.confidence);
        self.head = source.head;
        self.head_lost = source.head_lost;
    }
}
