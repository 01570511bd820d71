//! What the tracker reports per frame: named dots, their pixels and confidences, the
//! stabilised frame once calibrated, status flags, and the naming steps that fired.

use mouthpiece_retarget::{PerformerDots, PerformerLayout, StabilisedFrame};
use serde::{Deserialize, Serialize};

use crate::labels::Small;

/// A dot's name, `D1..DN` or `F1..FK`, without a heap string (per-frame status is built
/// without allocating).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DotName {
    pub forehead: bool,
    /// 1-based.
    pub number: u16,
}

impl DotName {
    pub(crate) fn of(layout: PerformerLayout, i: usize) -> Self {
        let (forehead, index) = if i < layout.lip_dots {
            (false, i)
        } else {
            (true, i - layout.lip_dots)
        };
        DotName {
            forehead,
            number: index as u16 + 1,
        }
    }
}

impl std::fmt::Display for DotName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let letter = if self.forehead { 'F' } else { 'D' };
        write!(f, "{letter}{}", self.number)
    }
}

impl Serialize for DotName {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for DotName {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let text = <std::borrow::Cow<'de, str>>::deserialize(deserializer)?;
        let bad = || serde::de::Error::custom(format!("not a dot name: {text:?}"));
        let (forehead, number) = match text.split_at_checked(1) {
            Some(("D", n)) => (false, n),
            Some(("F", n)) => (true, n),
            _ => return Err(bad()),
        };
        let number = number.parse::<u16>().map_err(|_| bad())?;
        Ok(DotName { forehead, number })
    }
}

/// Per-frame status flags.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// No neutral pose yet (or a requested recalibration is collecting frames).
    pub calibrating: bool,
    /// Fewer than 3 forehead dots: the head pose is the last good one.
    pub head_lost: bool,
    /// Dots not seen in this frame (serialized by name: `"D3"`, `"F1"`).
    pub dots_missing: Small<DotName>,
    /// No dot candidate of any colour class was found (no paint, wrong colours, no face).
    pub no_dots: bool,
    /// Fewer candidates than the layout needs (and no names from earlier frames to go on).
    pub too_few_dots: bool,
    /// Candidates found that no dot took (stray paint, other objects of a paint colour).
    pub unassigned_blobs: usize,
    /// The neutral pose was (re)taken on this frame.
    pub neutral_taken: bool,
}

/// One frame's result.
#[derive(Debug, Clone)]
pub struct TrackedFrame {
    pub seq: u64,
    pub device_ts_us: u64,
    /// Seconds since the first frame.
    pub t: f64,
    /// Named dots in the camera frame (metres), `None` when not seen.
    pub dots: PerformerDots,
    /// Per dot (lip dots, then forehead): pixel centre in the colour image.
    pub pixels: Vec<Option<[f64; 2]>>,
    /// Per dot (lip dots, then forehead): 1 seen, 0 missing.
    pub confidence: Vec<f64>,
    /// Head pose and lip dots in the neutral mouth frame, once calibrated.
    pub stabilised: Option<StabilisedFrame>,
    pub status: Status,
    /// The naming steps that changed names on this frame, in the order they ran: one entry
    /// per dot a step named, re-named or left missing (the steps:
    /// `crate::naming::recovery::STEPS`). A later step or check may change the name again.
    pub steps: Vec<StepEvent>,
    /// The rectangles the detector searched on this frame, cut to the image: the box round
    /// the forehead's predicted dots and the one round the lips' (one box round all when
    /// they meet), the whole image when nothing was predicted or on the periodic full search
    /// while dots are missing; empty when the frame was not searched. The booth console
    /// draws these, so it never shows a region the tracker did not use.
    pub searched: Vec<mouthpiece_detect::PixelRect>,
}

/// One name a naming step changed on a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepEvent {
    /// The step's name (`crate::naming::recovery::Step::name`).
    pub step: &'static str,
    /// Numbers the step runs on the frame: the changes of one run share it.
    pub run: u16,
    /// The dot: lip dots `0..N`, then forehead dots.
    pub dot: u16,
    /// Pixel of the candidate the dot had before the step and has after it (`None`: missing).
    pub before: Option<[f64; 2]>,
    pub after: Option<[f64; 2]>,
}

impl TrackedFrame {
    /// The dot names in output order: `D1..DN`, then `F1..FK`.
    pub fn names(layout: PerformerLayout) -> Vec<String> {
        (0..layout.lip_dots)
            .map(PerformerLayout::lip_name)
            .chain((0..layout.forehead_dots).map(PerformerLayout::forehead_name))
            .collect()
    }
}
