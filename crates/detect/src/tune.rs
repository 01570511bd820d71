//! Proposing colour classes from frames (`mouthpiece tune-colours`).
//!
//! [`ColourSampler::add_frame`] finds saturated, compact colour blobs in one frame: OpenCV
//! converts to HSV; the performer's distance (a depth histogram: the nearest surface covering
//! 1.5 % of the image) masks out what is more than 35 cm behind it; the face's saturation is
//! measured (99.5th percentile of the foreground, with the blobs of a first, lower-threshold
//! pass left out so a close-up's paint does not lift it) and pixels 20 above it form connected
//! components; a component is kept when it is dot-sized and shaped, at least 60 more
//! saturated than the ring around it (paint stands out, a fold of the lips does not) and of
//! one hue (pixels more than 15 hue units off its trimmed mean are dropped; a blob losing a
//! third is dropped). Everything else in the foreground goes into a hue x saturation
//! histogram of "face".
//!
//! [`ColourSampler::propose`] clusters the blobs of every frame by hue (a circular histogram,
//! smoothed, split at its valleys), keeps the clusters seen in two frames out of three, picks
//! the lip cluster (about `lip_dots` blobs per frame) and the forehead cluster (about
//! `forehead_dots`, above the lips), and turns each into a [`crate::ColorClass`]: hue from the 2nd to
//! the 98th percentile of its pixels plus a margin (a red across hue 0 written as two ranges,
//! hue shared with another class split between them), saturation from the lowest level at
//! which the face shows (almost) no pixel of that hue, value from the paint's low tail.
//! [`Proposal::to_toml`] prints it as a `[detect]` snippet.
//!
//! [`ColourSampler::propose_checked`] runs the detector with the ranges in use and with the
//! proposed ones on the sampled frames (at most [`MAX_CHECK_FRAMES`], spread evenly) and
//! counts the dots each finds; a proposal that finds fewer is not to be offered
//! ([`CheckedProposal::offered`]).

mod check;
mod hue;
mod proposal;
mod sampling;

use crate::DetectConfig;

pub use check::{CheckedProposal, ClassFound, DotsFound, MAX_CHECK_FRAMES};
pub use hue::hue_ranges;
pub use proposal::{ClusterSummary, Proposal, ProposedClass};
pub use sampling::{performer_distance, ColourSampler, FrameSample, SampledBlob};

/// How the sampler looks for blobs and how much room the proposed ranges get.
#[derive(Debug, Clone, PartialEq)]
pub struct TuneOptions {
    /// Dots expected on the lips and on the forehead (the tracker's `lip_dots`,
    /// `forehead_dots`).
    pub lip_dots: usize,
    pub forehead_dots: usize,
    /// Paint colours to propose: `Some(1)` one class (role `any`) for every dot, `Some(2)`
    /// lips and forehead, `None` as many as found (at most two).
    pub classes: Option<usize>,
    /// Lowest saturation (0–255) a blob pixel may have, whatever the face's saturation is.
    pub min_saturation: u8,
    /// How far above the face's 99.5th-percentile saturation the blob threshold sits.
    pub saturation_above_face: u8,
    /// How much more saturated (median) a blob must be than the skin around it (the ring
    /// 2–3 px outside its box): paint stands out, a saturated fold of the lips does not.
    pub min_contrast: u8,
    /// Largest circular standard deviation of hue inside one blob (hue units): a paint dot
    /// is one colour.
    pub max_hue_spread: f64,
    /// Darkest pixel (value, 0–255) considered: hue is noise in the dark.
    pub min_value: u8,
    /// Margins added outside the paint's percentiles, hue and value units (the saturation
    /// floor comes from the face: as low as it allows in the class's hues).
    pub hue_margin: u8,
    pub value_margin: u8,
    /// Smallest blob (pixels); larger blobs are bounded by a 15 mm disc at their distance.
    pub min_area_px: u32,
    pub min_fill_ratio: f64,
    pub max_aspect: f64,
    /// Plausible performer distance (metres).
    pub depth_range_m: [f64; 2],
    /// Background cut: pixels farther than the performer's nearest surface plus this are
    /// ignored (metres).
    pub depth_window_m: f64,
}

impl TuneOptions {
    /// Blob filters from a detector configuration (the user's `[detect]`), dot counts from
    /// the tracker's layout.
    pub fn from_config(detect: &DetectConfig, lip_dots: usize, forehead_dots: usize) -> Self {
        Self {
            lip_dots,
            forehead_dots,
            classes: None,
            min_saturation: 60,
            saturation_above_face: 20,
            min_contrast: 60,
            max_hue_spread: 6.0,
            min_value: 60,
            hue_margin: 12,
            value_margin: 25,
            min_area_px: detect.min_area_px.max(2),
            min_fill_ratio: detect.min_fill_ratio,
            max_aspect: detect.max_aspect,
            depth_range_m: detect.depth_range_m,
            depth_window_m: 0.35,
        }
    }
}

impl Default for TuneOptions {
    fn default() -> Self {
        Self::from_config(&DetectConfig::default(), 12, 3)
    }
}

#[cfg(test)]
mod tests;
