//! One published frame: what the daemon hands to every output per processed camera (or
//! speech) frame. Hand-written `clone_from`s reuse the destination's buffers, so copying a
//! frame into a recycled slot does not allocate once the slot has seen a frame of its shape.

use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::head::{CharacterHead, HeadPose};
use crate::rig::RigState;

/// One character's mouth in one frame.
#[derive(Debug, PartialEq, Default, Serialize, Deserialize)]
pub struct CharacterFrame {
    /// The character's name, as in the stream's `hello`.
    pub name: String,
    /// Points in the character's mouth frame, in the order of the character's point names.
    pub points: Vec<[f32; 3]>,
    /// Per point, 0 (missing, last value held) ..= 1.
    pub confidence: Vec<f32>,
    /// The smoothed closed curve through the points (docs/method.md §8), if the daemon computes it.
    pub curve: Option<Vec<[f32; 3]>>,
    /// The rig (docs/rig.md) once the performer is calibrated.
    #[serde(skip)]
    pub rig: Option<RigState>,
    /// The character's head and eyes (docs/head.md), if the daemon drives them.
    pub head: Option<CharacterHead>,
    /// What drove the mouth in this frame (docs/daemon.md, "Speech").
    #[serde(default)]
    pub source: MouthSource,
}

/// What drove a character's mouth in a frame: the camera's lip dots, the microphone's speech,
/// or a blend of both during a handover.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MouthSource {
    #[default]
    Camera,
    Speech,
    Blend,
}

impl MouthSource {
    /// The name in JSON frames and takes.
    pub fn as_str(self) -> &'static str {
        match self {
            MouthSource::Camera => "camera",
            MouthSource::Speech => "speech",
            MouthSource::Blend => "blend",
        }
    }

    /// The code in binary frames (docs/protocol.md): 0 camera, 1 speech, 2 blend.
    pub fn code(self) -> u8 {
        match self {
            MouthSource::Camera => 0,
            MouthSource::Speech => 1,
            MouthSource::Blend => 2,
        }
    }
}

/// The performer's lip dots in one frame: head motion removed, performer mouth frame, metres.
#[derive(Debug, PartialEq, Default, Serialize, Deserialize)]
pub struct PerformerFrame {
    /// Points `D1..Dn`.
    pub points: Vec<[f32; 3]>,
    /// Per point, 0 ..= 1.
    pub confidence: Vec<f32>,
}

/// What the daemon publishes per processed frame. `seq` and the timecode are added by the hub.
///
/// Keep one value and refill it each frame: the server's hub copies it with `clone_from`,
/// which reuses the slot's buffers.
#[derive(Debug, PartialEq, Default)]
pub struct StreamFrame {
    /// Seconds since the start of the stream.
    pub t: f64,
    /// Capture clock of the source, microseconds.
    pub capture_us: u64,
    /// Host wall-clock time of capture, Unix microseconds (live sources).
    pub wall_us: Option<i64>,
    /// Head pose.
    pub head: HeadPose,
    /// One entry per character being driven.
    pub characters: Vec<CharacterFrame>,
    /// The performer's dots (sent to clients that ask for `performer`).
    pub performer: Option<PerformerFrame>,
    /// Time the pipeline spent on this frame (feeds the `/metrics` histogram).
    pub processing: Option<Duration>,
}

// Hand-written `clone_from`s reuse the destination's buffers, so that publishing into a
// recycled slot does not allocate once the slot has seen a frame of the same shape.
impl Clone for CharacterFrame {
    fn clone(&self) -> Self {
        Self {
            name: self.name.clone(),
            points: self.points.clone(),
            confidence: self.confidence.clone(),
            curve: self.curve.clone(),
            rig: self.rig,
            head: self.head,
            source: self.source,
        }
    }
    fn clone_from(&mut self, other: &Self) {
        self.source = other.source;
        self.name.clone_from(&other.name);
        self.points.clone_from(&other.points);
        self.confidence.clone_from(&other.confidence);
        clone_option_from(&mut self.curve, &other.curve);
        self.rig = other.rig;
        self.head = other.head;
    }
}

impl Clone for PerformerFrame {
    fn clone(&self) -> Self {
        Self {
            points: self.points.clone(),
            confidence: self.confidence.clone(),
        }
    }
    fn clone_from(&mut self, other: &Self) {
        self.points.clone_from(&other.points);
        self.confidence.clone_from(&other.confidence);
    }
}

impl Clone for StreamFrame {
    fn clone(&self) -> Self {
        Self {
            t: self.t,
            capture_us: self.capture_us,
            wall_us: self.wall_us,
            head: self.head,
            characters: self.characters.clone(),
            performer: self.performer.clone(),
            processing: self.processing,
        }
    }
    fn clone_from(&mut self, other: &Self) {
        self.t = other.t;
        self.capture_us = other.capture_us;
        self.wall_us = other.wall_us;
        self.head = other.head;
        // Vec::clone_from calls the elements' clone_from for the common prefix.
        self.characters.clone_from(&other.characters);
        clone_option_from(&mut self.performer, &other.performer);
        self.processing = other.processing;
    }
}

fn clone_option_from<T: Clone>(dst: &mut Option<T>, src: &Option<T>) {
    match (dst.as_mut(), src) {
        (Some(d), Some(s)) => d.clone_from(s),
        _ => dst.clone_from(src),
    }
}
