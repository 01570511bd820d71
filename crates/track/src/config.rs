//! The tracker's settings: the `[track]` table of a configuration file.

use mouthpiece_retarget::PerformerLayout;
use serde::{Deserialize, Serialize};

use crate::TrackError;

/// Default [`TrackConfig::min_gate_spacings`] (*gate floor*): a third of a dot spacing, 3.0 px
/// at 640x480 and 0.6 m, 2.3 px at 0.8 m. Chosen on every saved accuracy set (0.30, 0.33 and
/// 0.36 run on all of them: at 0.33 no set has more wrong names than at the others, and
/// held-out sessions agree; 0.27 had lost names before; the table is in the lab notes). It
/// binds only where predictions
/// crowd (a gate is otherwise half the distance to the nearest other prediction, about half a
/// spacing).
pub const MIN_GATE_SPACINGS: f64 = 0.33;

/// Default [`TrackConfig::roi_margin_spacings`] (*search margin*): 2.2 dot spacings, 20 px at
/// 640x480 and 0.6 m (the margin the search region had in pixels there): a lip dot moves up
/// to 1.4 spacings in a frame, plus its paint's radius and the prediction's own error.
pub const ROI_MARGIN_SPACINGS: f64 = 2.2;

/// The dot spacing of the synthetic performer's mouth at rest at 640x480 (fx 525) and 0.6 m,
/// pixels: for the error that names the replaced pixel keys.
pub const PX_PER_SPACING_VGA_0_6M: f64 = 9.2;

/// The tracker's settings (`[track]` in a configuration file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackConfig {
    /// Lip dots `D1..DN` (even, at least 4).
    pub lip_dots: usize,
    /// Forehead dots `F1..FK` (at least 3).
    pub forehead_dots: usize,
    /// How long the mouth must be still and closed before the neutral pose is taken, seconds.
    pub calibration_s: f64,
    /// Largest RMS wobble (75th percentile over the lip dots) of the head-stabilised lip dots
    /// over the calibration window, metres, for the mouth to count as still. Depth noise
    /// alone gives about 4 mm on the synthetic performer with Kinect-like noise; speech moves
    /// the lips by 5–20 mm.
    pub still_tolerance_m: f64,
    /// Largest mouth opening (middle of upper to middle of lower lip) as a fraction of the
    /// mouth width for the mouth to count as closed.
    pub max_opening_ratio: f64,
    /// Radius of the skin patch around a forehead dot whose depth readings a plane is fitted
    /// to, metres (the sensor's depth noise is spatially correlated over a few pixels, so the
    /// readings under the paint alone keep most of it).
    pub forehead_depth_patch_m: f64,
    /// Radius of the patch around a lip dot whose depth readings a plane is fitted to,
    /// robustly, metres; 0: the median of the paint's inner disc (the fallback when the
    /// patch has too few readings). The paint's own few pixels share one sensor error.
    pub lip_depth_patch_m: f64,
    /// Once named, a lip dot (not a corner) takes its depth again from a patch stretched
    /// along the lip: this far each way along the line through its neighbours (at most
    /// [`crate::LIP_PATCH_NEIGHBOUR_FRACTION`] of the way to the nearer one), metres; 0: no second
    /// look. A lip is curved across and nearly straight along its line, so the long patch
    /// averages more of the sensor's correlated noise for the same curvature.
    pub lip_depth_along_m: f64,
    /// ... and this far each way across the lip, metres.
    pub lip_depth_across_m: f64,
    /// How far the forehead's skin reaches beyond its dots (to the sides and above; a third
    /// of it below, towards the brows), metres: the surface the head motion is refined on
    /// once calibrated (`forehead`). 0: the head motion from the three dots alone.
    pub forehead_surface_margin_m: f64,
    /// Temporal filter on the forehead dots' depths (One Euro: cut-off frequency at rest in Hz,
    /// and how fast it opens with the depth's speed, Hz per m/s; one cutoff for all the dots,
    /// the fastest one's). The forehead's depth noise is what tilts the head pose; pixels are
    /// precise and stay unfiltered. On frames where the head filter runs (a surface fit once
    /// calibrated, `head_filter_accel` not zero) that filter takes this one's place. 0 Hz: no
    /// filter.
    pub forehead_depth_min_cutoff_hz: f64,
    pub forehead_depth_beta: f64,
    /// How far down the face the head's rigid surface reaches below the forehead: the share
    /// of the way from the lowest forehead dot to the mouth's centre, along the line between
    /// them, 10 mm either side of it (the nose bridge, skull like the forehead; it sets the
    /// head's pitch over a longer lever). 0: the forehead alone.
    pub nose_bridge_reach: f64,
    /// The head motion's constant-velocity filter (`head_filter`): the head's angular
    /// acceleration (rad²/s³) and linear acceleration (m²/s³) as the spectral density of
    /// white noise, against the fitted motion's noise of 0.2° and 0.2 mm per axis. Smaller:
    /// smoother, slower to follow a change of speed. `[0, 0]`: no filter on the motion, the
    /// forehead dots' depth filter above instead.
    pub head_filter_accel: [f64; 2],
    /// Margin around the predicted dots for the search region, in dot spacings (the neutral
    /// mouth's mean distance between neighbouring lip dots, projected at the lips' depth):
    /// the same share of the face at any resolution and distance.
    pub roi_margin_spacings: f64,
    /// While dots are missing, search the full frame every this many frames.
    pub full_search_every: u32,
    /// Smallest gate around a prediction, in dot spacings at the dot's depth.
    pub min_gate_spacings: f64,
    /// Gate as a fraction of the distance to the nearest other predicted dot.
    pub gate_fraction: f64,
    /// Largest difference between a lip candidate's depth and the dot's depth, metres: its
    /// depth when last seen, or its last place carried by this frame's head motion (motion
    /// blur leaves a ghost of a lip dot over the open mouth, deeper by a centimetre or more;
    /// the lips move a few millimetres in depth between frames). Widened by a fifth per
    /// frame the dot has been missing, up to 10 frames.
    pub lip_depth_gate_m: f64,
    /// Replaced by `min_gate_spacings` (a pixel floor meant other things at other
    /// resolutions and distances): a file that still sets it is refused with an error that
    /// names the new key.
    #[doc(hidden)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min_gate_px: Option<f64>,
    /// Replaced by `roi_margin_spacings`, as `min_gate_px`.
    #[doc(hidden)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub roi_margin_px: Option<f64>,
    /// After this many frames with no dot named, forget the names and re-acquire from geometry.
    pub lost_after_frames: u32,
    /// How long a missing lip dot keeps its last value, then decays to neutral (seconds);
    /// passed to the retarget core.
    pub missing_hold_s: f64,
    pub missing_decay_s: f64,
}

impl Default for TrackConfig {
    fn default() -> Self {
        Self {
            lip_dots: 12,
            forehead_dots: 3,
            calibration_s: 1.0,
            still_tolerance_m: 0.006,
            max_opening_ratio: 0.6,
            forehead_depth_patch_m: 0.014,
            lip_depth_patch_m: 0.0035,
            lip_depth_along_m: 0.009,
            lip_depth_across_m: 0.0018,
            forehead_surface_margin_m: 0.025,
            forehead_depth_min_cutoff_hz: 2.0,
            forehead_depth_beta: 400.0,
            nose_bridge_reach: 0.5,
            head_filter_accel: [0.05, 0.003],
            roi_margin_spacings: ROI_MARGIN_SPACINGS,
            full_search_every: 8,
            min_gate_spacings: MIN_GATE_SPACINGS,
            gate_fraction: 0.5,
            lip_depth_gate_m: 0.008,
            min_gate_px: None,
            roi_margin_px: None,
            lost_after_frames: 15,
            missing_hold_s: 0.5,
            missing_decay_s: 0.5,
        }
    }
}

impl TrackConfig {
    pub fn validate(&self) -> Result<(), TrackError> {
        let bad = |key: &str, message: &str| {
            Err(TrackError::Config {
                key: format!("track.{key}"),
                message: message.into(),
            })
        };
        // The keys in pixels of older files: refused, naming the key that replaced each.
        for (old, set, new, default) in [
            (
                "min_gate_px",
                self.min_gate_px,
                "min_gate_spacings",
                MIN_GATE_SPACINGS,
            ),
            (
                "roi_margin_px",
                self.roi_margin_px,
                "roi_margin_spacings",
                ROI_MARGIN_SPACINGS,
            ),
        ] {
            if set.is_some() {
                return bad(
                    old,
                    &format!(
                        "was replaced by track.{new}, in dot spacings (the neutral mouth's \
                         distance between neighbouring lip dots, about {PX_PER_SPACING_VGA_0_6M} px at \
                         640x480 and 0.6 m) instead of pixels; the default is {default}"
                    ),
                );
            }
        }
        if self.lip_dots < 4 || !self.lip_dots.is_multiple_of(2) {
            return bad("lip_dots", "must be even and at least 4");
        }
        if self.forehead_dots < crate::MIN_POSE_DOTS {
            return bad(
                "forehead_dots",
                &format!(
                    "at least {} forehead dots are needed for the head pose",
                    crate::MIN_POSE_DOTS
                ),
            );
        }
        for (key, v) in [
            ("calibration_s", self.calibration_s),
            ("still_tolerance_m", self.still_tolerance_m),
            ("max_opening_ratio", self.max_opening_ratio),
            ("forehead_depth_patch_m", self.forehead_depth_patch_m),
            ("roi_margin_spacings", self.roi_margin_spacings),
            ("min_gate_spacings", self.min_gate_spacings),
            ("gate_fraction", self.gate_fraction),
            ("lip_depth_gate_m", self.lip_depth_gate_m),
            ("lip_depth_across_m", self.lip_depth_across_m),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(key, "must be a positive number");
            }
        }
        for (key, v) in [
            (
                "forehead_depth_min_cutoff_hz",
                self.forehead_depth_min_cutoff_hz,
            ),
            ("forehead_depth_beta", self.forehead_depth_beta),
            ("lip_depth_patch_m", self.lip_depth_patch_m),
            ("lip_depth_along_m", self.lip_depth_along_m),
            ("forehead_surface_margin_m", self.forehead_surface_margin_m),
            ("missing_hold_s", self.missing_hold_s),
            ("missing_decay_s", self.missing_decay_s),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(key, "must be zero or positive");
            }
        }
        if !(self.nose_bridge_reach.is_finite() && (0.0..=1.0).contains(&self.nose_bridge_reach)) {
            return bad("nose_bridge_reach", "must be within 0..1");
        }
        let [turn, shift] = self.head_filter_accel;
        let off = turn == 0.0 && shift == 0.0;
        let on = turn.is_finite() && shift.is_finite() && turn > 0.0 && shift > 0.0;
        if !(off || on) {
            return bad(
                "head_filter_accel",
                "must be two positive numbers [rad²/s³, m²/s³], or [0, 0] for no filter",
            );
        }
        if self.full_search_every == 0 {
            return bad("full_search_every", "must be at least 1");
        }
        Ok(())
    }

    pub fn layout(&self) -> PerformerLayout {
        PerformerLayout {
            lip_dots: self.lip_dots,
            forehead_dots: self.forehead_dots,
        }
    }
}
