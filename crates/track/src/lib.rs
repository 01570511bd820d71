//! From frames to named 3D dots: the tracker.
//!
//! Per frame ([`Tracker::process`]):
//! 1. depth onto the colour grid when the source did not register it ([`camera::register_depth`]);
//! 2. the detector (`mouthpiece-detect`) searches the region around the predicted dots, or
//!    the full frame when dots were lost;
//! 3. each blob's depth ([`depth::depth_at_dot`]: median of an inner disc, plane fit when
//!    the centre has no reading), undistorted and deprojected into the camera frame;
//! 4. names: from 3D geometry when every dot is seen ([`labels::label_by_geometry`]),
//!    otherwise by optimal assignment (Hungarian, [`labels::assign`]) to predictions: the
//!    forehead by constant pixel velocity, then the head motion from the forehead (Kabsch),
//!    then each lip dot's last head-stabilised position plus its velocity, carried by that
//!    head motion and projected. Gated: a dot with nothing near its prediction is missing
//!    (confidence 0), never given a neighbour's blob;
//! 5. once named, lip dots take their depth again from a patch stretched along the lip
//!    ([`depth::depth_by_plane_along`]), and, once calibrated, the head motion is refined on
//!    the whole forehead surface ([`forehead`]) and the forehead dots placed by it;
//! 6. neutral calibration (docs/method.md §3) once the mouth has been still for
//!    [`TrackConfig::calibration_s`] (again on [`Tracker::calibrate`]), then head pose and
//!    stabilised lip dots every frame through the retarget core's [`Stabiliser`] (§4).
//!
//! Everything is on the caller's thread; no queues. `process` allocates little once warm.

pub mod camera;
pub mod clock;
pub mod depth;
pub mod forehead;
pub mod labels;
pub mod pipeline;

use std::collections::VecDeque;
use std::sync::Arc;

use mouthpiece_detect::{DetectConfig, DetectError, Detections, Detector, DotRole, PixelRect};
use mouthpiece_frame::{Calibration, DepthImage, Frame, Intrinsics};
use mouthpiece_retarget::kabsch::kabsch;
use mouthpiece_retarget::{
    MissingDots, NeutralAccumulator, NeutralPose, OneEuro, OneEuroParams, PerformerDots,
    PerformerLayout, RigidTransform, StabilisedFrame, Stabiliser,
};
use serde::{Deserialize, Serialize};

use labels::{Candidate, Slot, Small};

/// The retarget core's vector type (metres, camera frame unless said otherwise).
pub type Vec3 = nalgebra::Vector3<f64>;

/// What can go wrong in the tracker.
#[derive(Debug, thiserror::Error)]
pub enum TrackError {
    #[error("invalid configuration {key}: {message}")]
    Config { key: String, message: String },
    #[error("dot detection failed")]
    Detect(#[source] DetectError),
    #[error("neutral calibration failed")]
    Neutral(#[source] mouthpiece_retarget::Error),
    #[error("head stabilisation failed")]
    Stabilise(#[source] mouthpiece_retarget::Error),
    #[error("frame {seq}: {message}")]
    Frame { seq: u64, message: String },
}

impl From<DetectError> for TrackError {
    /// A bad detector setting is a configuration error like any other (the key says where).
    fn from(e: DetectError) -> Self {
        match e {
            DetectError::Config { key, message } => TrackError::Config { key, message },
            other => TrackError::Detect(other),
        }
    }
}

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
    /// [`LIP_PATCH_NEIGHBOUR_FRACTION`] of the way to the nearer one), metres; 0: no second
    /// look. A lip is curved across and nearly straight along its line, so the long patch
    /// averages more of the sensor's correlated noise for the same curvature.
    pub lip_depth_along_m: f64,
    /// ... and this far each way across the lip, metres.
    pub lip_depth_across_m: f64,
    /// How far the forehead's skin reaches beyond its dots (to the sides and above; a third
    /// of it below, towards the brows), metres: the surface the head motion is refined on
    /// once calibrated ([`forehead`]). 0: the head motion from the three dots alone.
    pub forehead_surface_margin_m: f64,
    /// Temporal filter on each forehead dot's depth (One Euro: cut-off frequency at rest in Hz,
    /// and how fast it opens with the depth's speed, Hz per m/s). The forehead's depth noise
    /// is what tilts the head pose; pixels are precise and stay unfiltered. 0 Hz: no filter.
    pub forehead_depth_min_cutoff_hz: f64,
    pub forehead_depth_beta: f64,
    /// Margin around the predicted dots for the search region, pixels.
    pub roi_margin_px: f64,
    /// While dots are missing, search the full frame every this many frames.
    pub full_search_every: u32,
    /// Smallest gate (pixels) around a prediction.
    pub min_gate_px: f64,
    /// Gate as a fraction of the distance to the nearest other predicted dot.
    pub gate_fraction: f64,
    /// Largest difference between a lip candidate's depth and the dot's depth, metres: its
    /// depth when last seen, or its last place carried by this frame's head motion (motion
    /// blur leaves a ghost of a lip dot over the open mouth, deeper by a centimetre or more;
    /// the lips move a few millimetres in depth between frames). Widened by a fifth per
    /// frame the dot has been missing, up to 10 frames.
    pub lip_depth_gate_m: f64,
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
            forehead_depth_beta: 200.0,
            roi_margin_px: 20.0,
            full_search_every: 8,
            min_gate_px: 2.5,
            gate_fraction: 0.5,
            lip_depth_gate_m: 0.008,
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
        if self.lip_dots < 4 || !self.lip_dots.is_multiple_of(2) {
            return bad("lip_dots", "must be even and at least 4");
        }
        if self.forehead_dots < 3 {
            return bad(
                "forehead_dots",
                "at least 3 forehead dots are needed for the head pose",
            );
        }
        for (key, v) in [
            ("calibration_s", self.calibration_s),
            ("still_tolerance_m", self.still_tolerance_m),
            ("max_opening_ratio", self.max_opening_ratio),
            ("forehead_depth_patch_m", self.forehead_depth_patch_m),
            ("roi_margin_px", self.roi_margin_px),
            ("min_gate_px", self.min_gate_px),
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

/// A dot's name, `D1..DN` or `F1..FK`, without a heap string (per-frame status is built
/// without allocating).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DotName {
    pub forehead: bool,
    /// 1-based.
    pub number: u16,
}

impl DotName {
    fn of(layout: PerformerLayout, i: usize) -> Self {
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

#[derive(Debug, Clone)]
struct DotTrack {
    pixel: [f64; 2],
    pixel_vel: [f64; 2],
    /// Last position carried back into the reference head pose (`H⁻¹ p`).
    stab: Vec3,
    stab_vel: Vec3,
    /// Depth when last seen (camera frame, metres): one end of the depth gate's window (the
    /// other, the stabilised position carried by the head motion, carries the head pose's
    /// noise about the lever from the forehead).
    depth: f64,
    /// Frames since last seen (0 = seen in the last frame).
    missing: u32,
}

impl DotTrack {
    /// Where constant pixel velocity puts the dot `ratio` frame intervals on.
    fn predicted_pixel(&self, ratio: f64) -> [f64; 2] {
        [
            self.pixel[0] + self.pixel_vel[0] * ratio,
            self.pixel[1] + self.pixel_vel[1] * ratio,
        ]
    }
}

/// This frame's depth image (on the colour grid, `scale` metres per unit) and colour
/// intrinsics, for the last-chance naming steps that measure new candidates.
struct DepthView<'a> {
    depth: &'a DepthImage,
    scale: f64,
    k: &'a mouthpiece_frame::Intrinsics,
}

/// The depths (metres, low and high) a lip candidate may have to be this dot: within `gate`
/// of its last depth or of its last place carried by this frame's head motion (`head`).
fn depth_window(track: &DotTrack, head: &RigidTransform, gate: f64) -> [f64; 2] {
    let (last, carried) = (track.depth, head.apply(&track.stab).z);
    [last.min(carried) - gate, last.max(carried) + gate]
}

/// Area (pixels) of a disc of radius `r` pixels: what a dot's paint covers.
fn disc_area(r: f64) -> f64 {
    std::f64::consts::PI * r * r
}

/// A lip dot unseen for longer than this many frames is not looked for in a merged blob.
const SPLIT_MISSING_FRAMES: u32 = 10;

/// How the lip dots are predicted to have moved since the last frame.
#[derive(Debug, Clone, Copy, PartialEq)]
enum LipMotion {
    /// On at the velocity they had (in the head's frame).
    Steady,
    /// Not at all: where they were last (in the head's frame).
    Stopped,
    /// As `Steady`, the lower lip between the corners shifted by these pixels besides (the
    /// jaw dropping or snapping shut within one frame).
    JawJumped([f64; 2]),
}

/// Largest RMS misfit (metres) of the upper lip and forehead dots to their rest shape for
/// the head motion fitted to them to be used while a forehead dot is hidden.
const HEAD_FALLBACK_RMS_M: f64 = 0.003;

/// Largest change the forehead surface fit may make to the dots' head motion: rotation
/// (radians, 5°) and the forehead dots' places (metres).
const SURFACE_FIT_MAX_TURN_RAD: f64 = 0.087;
const SURFACE_FIT_MAX_SHIFT_M: f64 = 0.01;

/// Farthest a lower-lip dot is looked for beyond its prediction when the jaw jumps, pixels.
const JAW_JUMP_PX: f64 = 12.0;

/// How far towards its nearer neighbour a lip dot's stretched depth patch may reach.
pub const LIP_PATCH_NEIGHBOUR_FRACTION: f64 = 0.8;

/// The forehead surface is sampled this far apart, metres (2 px at 0.6 m in VGA; the
/// sensor's noise is correlated over about four pixels, and the samples' count is what the
/// fit costs).
const FOREHEAD_SAMPLE_SPACING_M: f64 = 0.002;

/// The most frames the calibration window holds (each with a crop of the forehead's depth,
/// about 12 kB at 640x480): beyond it every second frame is dropped, so a long calibration
/// at a high frame rate (or a clock creeping forward by microseconds) stays within a few
/// megabytes. 512 frames are 8.5 s at 60 frames/s.
const CALIBRATION_WINDOW_MAX_FRAMES: usize = 512;

/// Drops every second entry (the first and the last stay): the span is kept, the number of
/// entries halved.
fn thin_out<T>(window: &mut VecDeque<T>) {
    let last = window.len().saturating_sub(1);
    let mut i = 0;
    window.retain(|_| {
        let keep = i % 2 == 0 || i == last;
        i += 1;
        keep
    });
}

/// Largest change of any side of the forehead triangle (all pairwise distances between
/// forehead dots; rigid, so the head's pose does not change them) for the performer to
/// count as the calibrated one after a source restart, metres. The sides measured frame to
/// frame vary by 1–2 mm with Kinect-like depth noise on the synthetic performer; dots painted
/// again by hand, or another performer, land several millimetres to centimetres apart.
pub const SAME_PERFORMER_TOLERANCE_M: f64 = 0.005;

/// Whether the forehead dots `now` (camera frame, all seen) are the neutral pose's
/// (`neutral`, camera frame; a dot unseen at calibration is not compared): every side of
/// the triangle within [`SAME_PERFORMER_TOLERANCE_M`].
pub fn same_performer(neutral: &[Option<Vec3>], now: &[Vec3]) -> bool {
    let n = neutral.len().min(now.len());
    (0..n).all(|a| {
        (a + 1..n).all(|b| match (neutral[a], neutral[b]) {
            (Some(p), Some(q)) => {
                let then = (p - q).norm();
                let here = (now[a] - now[b]).norm();
                (then - here).abs() <= SAME_PERFORMER_TOLERANCE_M
            }
            _ => true,
        })
    })
}

/// Candidates from index `real` on (made by a step: split halves, faint corners) that no
/// name refers to are removed, and the names re-pointed: the frame's unassigned candidates
/// are then blobs the detector found, never a step's leftovers.
fn drop_unnamed_extras(
    names: &mut [Option<usize>],
    cands: &mut Vec<Candidate>,
    cand_blob: &mut Vec<usize>,
    real: usize,
) {
    let mut next = real;
    for c in real..cands.len() {
        if !names.contains(&Some(c)) {
            continue;
        }
        if c != next {
            cands.swap(next, c);
            if c < cand_blob.len() {
                cand_blob.swap(next, c);
            }
            for name in names.iter_mut().filter(|n| **n == Some(c)) {
                *name = Some(next);
            }
        }
        next += 1;
    }
    cands.truncate(next);
    cand_blob.truncate(next.min(cand_blob.len()));
}

/// The tracker: owns the detector, the names, and the calibration.
pub struct Tracker {
    config: TrackConfig,
    layout: PerformerLayout,
    detector: Detector,
    dot_radius_m: f64,
    depth_range: [f64; 2],
    roles: Vec<DotRole>,
    /// Session time from the frames' device timestamps, running on across source restarts.
    clock: clock::SessionClock,
    /// The source restarted while calibrated: on the first full naming, check that the
    /// performer in view is the calibrated one ([`same_performer`]).
    check_performer: bool,
    /// The previous frame's time (seconds) and the interval the tracks' velocities were
    /// measured over: a live source may skip frames, so predictions scale the velocities by
    /// this frame's interval over that one.
    prev_t: Option<f64>,
    velocity_dt: f64,
    /// This frame's interval over `velocity_dt` (1 at a steady frame rate).
    step_ratio: f64,
    tracks: Option<Vec<DotTrack>>,
    /// Forehead positions the head motion is measured against (camera frame).
    reference_forehead: Vec<Vec3>,
    head: RigidTransform,
    /// Lip dots at rest in the reference head pose (first naming, then the neutral pose): the
    /// shape the neighbour-based prediction keeps offsets from.
    rest: Vec<Vec3>,
    frames_without_names: u32,
    frames_with_missing: u32,
    calibrating: bool,
    /// How long the running calibration wants the mouth still, seconds
    /// ([`TrackConfig::calibration_s`] unless [`Tracker::calibrate_for`] said otherwise).
    calibration_s: f64,
    window: VecDeque<(f64, PerformerDots)>,
    /// The forehead's depth in each frame of `window` (when the surface fit is on).
    window_crops: VecDeque<forehead::DepthCrop>,
    /// The neutral forehead surface the head motion is refined on, once calibrated.
    forehead_surface: Option<forehead::ForeheadSurface>,
    stabiliser: Option<Stabiliser>,
    registered: DepthImage,
    depth_buf: depth::DepthScratch,
    /// Per-frame buffers kept between frames (a frame allocates nothing once they have grown).
    found: Detections,
    cands: Vec<Candidate>,
    /// Per candidate: its blob in `found.blobs` (split halves: the blob split).
    cand_blob: Vec<usize>,
    assignment: labels::Assignment,
    /// Per forehead dot: its depth filter (`None` when switched off).
    forehead_depth: Option<Vec<OneEuro>>,
    pub(crate) out: TrackedFrame,
}

impl std::fmt::Debug for Tracker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tracker")
            .field("config", &self.config)
            .finish_non_exhaustive()
    }
}

impl Tracker {
    /// Validates both configurations.
    pub fn new(detect: DetectConfig, config: TrackConfig) -> Result<Self, TrackError> {
        config.validate()?;
        let layout = config.layout();
        let dot_radius_m = detect.dot_radius_m;
        let depth_range = detect.depth_range_m;
        let roles = detect.classes.iter().map(|c| c.role).collect();
        let detector = Detector::new(detect)?;
        let n = layout.lip_dots + layout.forehead_dots;
        let forehead_depth = (config.forehead_depth_min_cutoff_hz > 0.0).then(|| {
            let params = OneEuroParams {
                min_cutoff: config.forehead_depth_min_cutoff_hz,
                beta: config.forehead_depth_beta,
                d_cutoff: 1.0,
            };
            vec![OneEuro::new(params); layout.forehead_dots]
        });
        Ok(Self {
            forehead_depth,
            layout,
            detector,
            dot_radius_m,
            depth_range,
            roles,
            clock: clock::SessionClock::default(),
            check_performer: false,
            prev_t: None,
            velocity_dt: 0.0,
            step_ratio: 1.0,
            tracks: None,
            reference_forehead: Vec::new(),
            head: RigidTransform::IDENTITY,
            rest: Vec::new(),
            frames_without_names: 0,
            frames_with_missing: 0,
            calibrating: true,
            calibration_s: config.calibration_s,
            window: VecDeque::new(),
            window_crops: VecDeque::new(),
            forehead_surface: None,
            stabiliser: None,
            registered: DepthImage::new(0, 0),
            depth_buf: depth::DepthScratch::default(),
            found: Detections::default(),
            cands: Vec::new(),
            cand_blob: Vec::new(),
            assignment: labels::Assignment::default(),
            out: TrackedFrame {
                seq: 0,
                device_ts_us: 0,
                t: 0.0,
                dots: PerformerDots::new(layout),
                pixels: vec![None; n],
                confidence: vec![0.0; n],
                stabilised: None,
                status: Status::default(),
            },
            config,
        })
    }

    pub fn layout(&self) -> PerformerLayout {
        self.layout
    }

    pub fn config(&self) -> &TrackConfig {
        &self.config
    }

    /// The neutral pose, once calibrated.
    pub fn neutral(&self) -> Option<&NeutralPose> {
        self.stabiliser.as_ref().map(|s| s.neutral())
    }

    /// Asks for a new neutral calibration: the next [`TrackConfig::calibration_s`] of still,
    /// closed mouth become the neutral pose. The old one stays in use until then.
    pub fn calibrate(&mut self) {
        self.calibrate_for(None);
    }

    /// [`Tracker::calibrate`] over `seconds` of still, closed mouth instead of
    /// [`TrackConfig::calibration_s`] (`None`: that). The frame that takes the pose says
    /// so in [`Status::neutral_taken`].
    pub fn calibrate_for(&mut self, seconds: Option<f64>) {
        let seconds = seconds
            .filter(|s| s.is_finite() && *s > 0.0)
            .unwrap_or(self.config.calibration_s);
        tracing::info!(seconds, "neutral calibration requested");
        self.calibrating = true;
        self.calibration_s = seconds;
        self.window.clear();
        self.window_crops.clear();
    }

    /// The source was reopened (a replay from its beginning, a camera plugged back in): the
    /// next frame starts a new segment of the session clock, whatever its timestamp. A clock
    /// that goes backwards is taken as a restart without being told.
    pub fn source_restarted(&mut self) {
        self.clock.restart();
    }

    /// After a restart: the names are found again from geometry, the calibration window
    /// starts afresh, and the first full naming checks the performer ([`same_performer`]):
    /// the neutral pose is kept for the same performer, a new one is taken otherwise.
    fn restart_tracks(&mut self) {
        tracing::info!("source restarted; re-acquiring the dots");
        self.tracks = None;
        self.window.clear();
        self.window_crops.clear();
        self.frames_without_names = 0;
        self.frames_with_missing = 0;
        self.velocity_dt = 0.0;
        if let Some(filters) = &mut self.forehead_depth {
            filters.iter_mut().for_each(OneEuro::reset);
        }
        self.check_performer = self.stabiliser.is_some();
    }

    /// Tracks one frame.
    pub fn process(&mut self, frame: &Frame) -> Result<&TrackedFrame, TrackError> {
        let tick = self.clock.tick(frame.device_ts_us);
        if tick.restarted {
            self.restart_tracks();
        }
        let t = tick.t;
        let dt = self.prev_t.map_or(0.0, |p| t - p);
        self.step_ratio = if self.velocity_dt > 0.0 && dt > 0.0 {
            // Past a few skipped frames constant velocity says little: cap the extrapolation.
            (dt / self.velocity_dt).min(4.0)
        } else {
            1.0
        };
        let calib: &Arc<Calibration> = &frame.calibration;
        let k = calib.color;
        if frame.color.width != k.width || frame.color.height != k.height {
            return Err(TrackError::Frame {
                seq: frame.seq,
                message: format!(
                    "colour image is {}x{} but its calibration says {}x{}",
                    frame.color.width, frame.color.height, k.width, k.height
                ),
            });
        }
        let mut registered = std::mem::replace(&mut self.registered, DepthImage::new(0, 0));
        let depth = if calib.depth_registered {
            &frame.depth
        } else {
            camera::register_depth(&frame.depth, calib, &mut registered);
            &registered
        };
        let mut found = std::mem::take(&mut self.found);
        let mut cands = std::mem::take(&mut self.cands);
        let result = self.detect_and_name(frame, depth, t, &mut found, &mut cands);
        self.found = found;
        self.cands = cands;
        let result = result.and_then(|()| {
            if dt > 0.0 {
                self.velocity_dt = dt;
            }
            self.prev_t = Some(t);
            self.update_calibration(t, depth, calib.depth_scale_m, k)
        });
        self.registered = registered;
        result?;
        let out = &mut self.out;
        match (&mut self.stabiliser, &mut out.stabilised) {
            (Some(stab), stabilised) => {
                let s = stab.step(t, &out.dots).map_err(TrackError::Stabilise)?;
                out.status.head_lost = s.head_lost;
                // Into the kept frame, reusing its vectors.
                match stabilised {
                    Some(mine) => mine.clone_from(s),
                    none => *none = Some(s.clone()),
                }
            }
            (None, stabilised) => {
                *stabilised = None;
                out.status.head_lost = out.dots.forehead.iter().flatten().count() < 3;
            }
        }
        out.status.calibrating = self.calibrating;
        tracing::trace!(seq = frame.seq, candidates = self.cands.len(), "tracked");
        Ok(&self.out)
    }

    /// The body of [`Self::process`], on buffers taken out of the tracker for the frame.
    fn detect_and_name(
        &mut self,
        frame: &Frame,
        depth: &DepthImage,
        t: f64,
        found: &mut Detections,
        cands: &mut Vec<Candidate>,
    ) -> Result<(), TrackError> {
        let k = frame.calibration.color;
        let scale = frame.calibration.depth_scale_m;
        let search = self.search_region(frame);
        self.detector
            .detect_into(&frame.color, Some((depth, scale)), k.fx, search, found)?;
        cands.clear();
        self.cand_blob.clear();
        for (blob_index, blob) in found.blobs.iter().enumerate() {
            let z_hint = blob.depth_m.unwrap_or(0.6);
            let radius_px = self.dot_radius_px(k.fx, z_hint);
            let role = self.roles[blob.class];
            let z = if role == DotRole::Forehead {
                // The forehead is smooth: a plane over a wide patch of skin around the dot
                // averages the sensor's (spatially correlated) noise down; the head pose
                // needs it.
                // Rounded to 1/64 px: calibrations that differ only in their last digits (an
                // .oni's field of view is a 32-bit float) must pick the same pixels.
                let patch_px =
                    (self.config.forehead_depth_patch_m * k.fx / z_hint * 64.0).round() / 64.0;
                depth::depth_by_plane(
                    depth,
                    scale,
                    blob.center,
                    patch_px.max(2.0 * radius_px).max(3.0),
                    self.depth_range,
                    &mut self.depth_buf,
                )
            } else {
                self.lip_depth(depth, scale, blob.center, z_hint, k.fx)
            };
            if let Some((z, _)) = z {
                cands.push(Candidate {
                    pixel: blob.center,
                    point: camera::deproject(&k, blob.center, z),
                    role,
                });
                self.cand_blob.push(blob_index);
            }
        }

        let n = self.layout.lip_dots;
        let mut names = self.name_candidates(cands, &k, &found.blobs);
        // After a restart, on the first full naming and before the forehead surface fit
        // (which places the forehead dots on the neutral triangle): the same performer?
        if self.check_performer && self.tracks.is_none() && names.iter().all(Option::is_some) {
            self.check_performer = false;
            let now: Small<Vec3> = names[n..]
                .iter()
                .map(|c| cands[c.expect("all named")].point)
                .collect();
            let same = self
                .neutral()
                .is_none_or(|neutral| same_performer(&neutral.forehead_camera, &now));
            if !same {
                tracing::info!(
                    "the forehead dots are not where the neutral pose had them: another performer; recalibrating"
                );
                self.calibrate();
            }
        }
        let view = DepthView {
            depth,
            scale,
            k: &k,
        };
        self.split_merged_blobs(&mut names, cands, &found.blobs, &view);
        self.name_faint_corners(&mut names, cands, &found.faint, &view);
        self.fit_forehead_surface(&names[n..], cands, &view);
        self.lip_depths_along_the_lips(&names[..n], cands, &view);
        if let Some(filters) = &mut self.forehead_depth {
            for (filter, name) in filters.iter_mut().zip(&names[n..]) {
                match name {
                    Some(c) => {
                        let c = &mut cands[*c];
                        let z = filter.filter(t, c.point.z);
                        c.point = camera::deproject(&k, c.pixel, z);
                    }
                    // Unseen: start afresh when it returns, rather than from a stale depth.
                    None => filter.reset(),
                }
            }
        }
        // Fill the output.
        let out = &mut self.out;
        out.seq = frame.seq;
        out.device_ts_us = frame.device_ts_us;
        out.t = t;
        out.dots.clear();
        let mut used: Small<bool> = smallvec::smallvec![false; cands.len()];
        for (dot, name) in names.iter().enumerate() {
            let p = name.map(|c| {
                used[c] = true;
                &cands[c]
            });
            out.pixels[dot] = p.map(|c| c.pixel);
            out.confidence[dot] = if p.is_some() { 1.0 } else { 0.0 };
            let slot = if dot < n {
                &mut out.dots.lip[dot]
            } else {
                &mut out.dots.forehead[dot - n]
            };
            *slot = p.map(|c| c.point);
        }
        let seen = names.iter().filter(|c| c.is_some()).count();
        out.status.calibrating = false;
        out.status.head_lost = false;
        out.status.dots_missing.clear();
        out.status.dots_missing.extend(
            (0..names.len())
                .filter(|&i| names[i].is_none())
                .map(|i| DotName::of(self.layout, i)),
        );
        out.status.no_dots = found.blobs.is_empty();
        out.status.too_few_dots = self.tracks.is_none() && cands.len() < names.len();
        out.status.unassigned_blobs = used.iter().filter(|u| !**u).count();
        out.status.neutral_taken = false;
        if seen == 0 {
            self.frames_without_names += 1;
        } else {
            self.frames_without_names = 0;
        }
        if seen < names.len() {
            self.frames_with_missing += 1;
        } else {
            self.frames_with_missing = 0;
        }

        self.update_tracks(&names, cands);
        Ok(())
    }

    /// A dot's paint radius in pixels at depth `z` (metres).
    fn dot_radius_px(&self, fx: f64, z: f64) -> f64 {
        self.dot_radius_m * fx / z
    }

    /// Depth at a lip dot: a robust plane over a few millimetres of lip around it (the
    /// sensor's noise is correlated over a few pixels, so the paint's own pixels share one
    /// error; the plane's outlier rejection drops the open mouth behind the lip), else the
    /// median of the paint's readings.
    fn lip_depth(
        &mut self,
        depth: &DepthImage,
        scale: f64,
        center: [f64; 2],
        z_hint: f64,
        fx: f64,
    ) -> Option<(f64, depth::DepthMethod)> {
        let radius_px = self.dot_radius_px(fx, z_hint);
        // Rounded to 1/64 px, like the forehead's patch.
        let patch_px = (self.config.lip_depth_patch_m * fx / z_hint * 64.0).round() / 64.0;
        (self.config.lip_depth_patch_m > 0.0)
            .then(|| {
                depth::depth_by_plane(
                    depth,
                    scale,
                    center,
                    patch_px.max(radius_px),
                    self.depth_range,
                    &mut self.depth_buf,
                )
            })
            .flatten()
            .or_else(|| {
                depth::depth_at_dot(
                    depth,
                    scale,
                    center,
                    radius_px,
                    self.depth_range,
                    &mut self.depth_buf,
                )
            })
    }

    /// Two lip dots close together (lips pressed shut, a corner and its neighbour in a
    /// pursed mouth) merge into one blob: one of them is missing, or both, or the blob went to
    /// the wrong one. A missing lip dot (seen within the last [`SPLIT_MISSING_FRAMES`])
    /// whose prediction lies within a dot's diameter plus its gate of a blob at least 1.2
    /// times a dot's area (a corner half folded away adds less than a dot) splits that blob
    /// with the dot holding it (or another missing dot predicted there): the blob's colour
    /// weight spreads along its long axis by the dots' own spread plus a quarter of their
    /// separation squared, which gives the two centres. The split names are kept only if the
    /// mouth's order and corner checks hold.
    fn split_merged_blobs(
        &mut self,
        names: &mut [Option<usize>],
        cands: &mut Vec<Candidate>,
        blobs: &[mouthpiece_detect::Blob],
        view: &DepthView,
    ) {
        let (depth, scale, k) = (view.depth, view.scale, view.k);
        let n = self.layout.lip_dots;
        let (Some(tracks), Some(_)) = (&self.tracks, &self.stabiliser) else {
            return;
        };
        if names[..n].iter().all(Option::is_some) {
            return;
        }
        let head = self.head_now(names, cands);
        let preds = self.lip_predictions(&head, k, LipMotion::Steady);
        let missing: Small<u32> = tracks[..n].iter().map(|t| t.missing).collect();
        let last_seen: Small<[f64; 2]> = tracks[..n].iter().map(|t| t.pixel).collect();
        // Depth windows as the assignment's (see `gated`): last depth to carried depth.
        let depth_window: Small<[f64; 2]> = tracks[..n]
            .iter()
            .map(|t| depth_window(t, &head, self.config.lip_depth_gate_m))
            .collect();
        let before: Small<Option<usize>> = names.iter().copied().collect();
        let real = cands.len();
        let mut split_any = false;
        for i in 0..n {
            if names[i].is_some() || missing[i] > SPLIT_MISSING_FRAMES {
                continue;
            }
            let p = preds[i];
            // From its prediction or, if that overshot (a velocity measured on merged blobs
            // is poor), from where it was last seen.
            let last = last_seen[i];
            let dist = |q: [f64; 2]| {
                ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2))
                    .sqrt()
                    .min(((q[0] - last[0]).powi(2) + (q[1] - last[1]).powi(2)).sqrt())
            };
            // The merged blob: the nearest big lip blob within reach.
            let merged = (0..real)
                .filter(|&c| cands[c].role != DotRole::Forehead)
                .filter_map(|c| {
                    let blob = &blobs[self.cand_blob[c]];
                    let r = self.dot_radius_px(k.fx, cands[c].point.z);
                    let big = blob.area as f64 >= 1.2 * disc_area(r);
                    let d = dist(cands[c].pixel);
                    (big && d <= 2.0 * r + self.config.min_gate_px).then_some((d, c, r))
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let Some((_, c, r)) = merged else { continue };
            // Its other dot: the lip dot named on it, else another missing one predicted
            // nearest to it.
            let holder = (0..n).find(|&j| names[j] == Some(c));
            let partner = holder.or_else(|| {
                (0..n)
                    .filter(|&j| j != i && names[j].is_none() && missing[j] <= SPLIT_MISSING_FRAMES)
                    .map(|j| {
                        let q = preds[j];
                        let e = cands[c].pixel;
                        (((q[0] - e[0]).powi(2) + (q[1] - e[1]).powi(2)).sqrt(), j)
                    })
                    .filter(|&(d, _)| d <= 2.0 * r + self.config.min_gate_px)
                    .min_by(|a, b| a.0.total_cmp(&b.0))
                    .map(|(_, j)| j)
            });
            let Some(j) = partner else { continue };
            let d = [preds[i][0] - preds[j][0], preds[i][1] - preds[j][1]];
            let [xx, xy, yy] = blobs[self.cand_blob[c]].spread;
            // The blob's long axis, pointing from dot j's side to dot i's: the two dots lie
            // along it (their predictions give only the side; a mouth narrowing fast turns
            // the line between a corner and its neighbour within a frame). Two equal dots
            // 2h apart spread h² more along that line than across it.
            let mean = 0.5 * (xx + yy);
            let root = (0.25 * (xx - yy).powi(2) + xy * xy).sqrt();
            let (long, short) = (mean + root, mean - root);
            let axis = if xy.abs() > 1e-12 {
                [xy, long - xx]
            } else if xx >= yy {
                [1.0, 0.0]
            } else {
                [0.0, 1.0]
            };
            let norm = axis[0].hypot(axis[1]);
            if !(norm.is_finite() && norm > 0.0) {
                continue;
            }
            let sign = if axis[0] * d[0] + axis[1] * d[1] >= 0.0 {
                1.0
            } else {
                -1.0
            };
            let u = [sign * axis[0] / norm, sign * axis[1] / norm];
            let half = (long - short).max(0.0).sqrt();
            // Less than half a dot apart: one dot, not two.
            if half < 0.5 * r {
                continue;
            }
            let centre = cands[c].pixel;
            let at = |sign: f64| {
                [
                    centre[0] + sign * half * u[0],
                    centre[1] + sign * half * u[1],
                ]
            };
            let mut halves = [(i, at(1.0)), (j, at(-1.0))].into_iter().map(|(dot, px)| {
                let z_hint = cands[c].point.z;
                self.lip_depth(depth, scale, px, z_hint, k.fx)
                    .filter(|(z, _)| (depth_window[dot][0]..=depth_window[dot][1]).contains(z))
                    .map(|(z, _)| (dot, px, z))
            });
            let (Some(a), Some(b)) = (halves.next().flatten(), halves.next().flatten()) else {
                continue;
            };
            for (dot, px, z) in [a, b] {
                cands.push(Candidate {
                    pixel: px,
                    point: camera::deproject(k, px, z),
                    role: cands[c].role,
                });
                self.cand_blob.push(self.cand_blob[c]);
                names[dot] = Some(cands.len() - 1);
            }
            split_any = true;
        }
        if !split_any {
            return;
        }
        self.enforce_lip_order(names, cands);
        self.keep_corner_neighbours_in_place(names, cands);
        if !self.corners_are_extremes(names, cands) {
            names.copy_from_slice(&before);
        }
        // Halves no name kept (the split rolled back, or a half out of order) are not blobs.
        drop_unnamed_extras(names, cands, &mut self.cand_blob, real);
        tracing::debug!(dots = cands.len() - real, "merged lip blobs split");
    }

    /// A mouth corner the names left missing may show only a speck of paint (the corner of
    /// the mouth folds in over it): a faint blob (smaller than a dot, see
    /// [`Detections::faint`]) within `min_gate_px` of where the corner is predicted (moving on
    /// or stopped), at the corner's depth (`lip_depth_gate_m`), names it, if the corner checks
    /// still hold with it. Only corners: elsewhere on the lips a speck is as likely a motion-
    /// blur ghost, and taking ghosts slipped whole lips.
    fn name_faint_corners(
        &mut self,
        names: &mut [Option<usize>],
        cands: &mut Vec<Candidate>,
        faint: &[mouthpiece_detect::Blob],
        view: &DepthView,
    ) {
        let (depth, scale, k) = (view.depth, view.scale, view.k);
        if faint.is_empty() || self.tracks.is_none() || self.stabiliser.is_none() {
            return;
        }
        let head = self.head_now(names, cands);
        let real = cands.len();
        for corner in [self.layout.left_corner(), self.layout.right_corner()] {
            let track = &self.tracks.as_ref().expect("checked")[corner];
            if names[corner].is_some() || track.missing > 2 {
                continue;
            }
            let (stab, moving, window) = (
                track.stab,
                track.stab + track.stab_vel * self.step_ratio,
                depth_window(track, &head, self.config.lip_depth_gate_m),
            );
            let preds: Small<[f64; 2]> = [stab, moving]
                .iter()
                .filter_map(|q| camera::project(k, &head.apply(q)))
                .collect();
            let gate = self.config.min_gate_px;
            let nearest = faint
                .iter()
                .filter(|b| matches!(self.roles[b.class], DotRole::Lip | DotRole::Any))
                .filter_map(|b| {
                    let d = preds
                        .iter()
                        .map(|p| {
                            ((b.center[0] - p[0]).powi(2) + (b.center[1] - p[1]).powi(2)).sqrt()
                        })
                        .fold(f64::INFINITY, f64::min);
                    (d < gate).then_some((d, b))
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let Some((_, blob)) = nearest else { continue };
            let z_hint = blob.depth_m.unwrap_or(0.5 * (window[0] + window[1]));
            let Some((z, _)) = self.lip_depth(depth, scale, blob.center, z_hint, k.fx) else {
                continue;
            };
            if !(window[0]..=window[1]).contains(&z) {
                continue;
            }
            cands.push(Candidate {
                pixel: blob.center,
                point: camera::deproject(k, blob.center, z),
                role: DotRole::Lip,
            });
            names[corner] = Some(cands.len() - 1);
        }
        if cands.len() == real {
            return;
        }
        self.keep_corner_neighbours_in_place(names, cands);
        if !self.corners_are_extremes(names, cands) {
            for name in names.iter_mut() {
                if name.is_some_and(|c| c >= real) {
                    *name = None;
                }
            }
        }
        // Faint candidates no name kept are not blobs the frame left unassigned.
        while cands.len() > real && !names.contains(&Some(cands.len() - 1)) {
            cands.pop();
        }
        tracing::debug!(
            named = cands.len() - real,
            "mouth corners named on faint paint"
        );
    }

    /// Names for this frame's candidates, per dot (lip dots, then forehead).
    ///
    /// Without names from earlier frames: from geometry alone (start-up, re-acquisition).
    /// With them: by prediction and assignment; when that leaves dots missing although there
    /// are as many candidates as dots, geometry may fill them in, but only if it agrees with
    /// every name the prediction gave (geometry alone can be fooled by extreme mouth shapes,
    /// prediction alone by fast motion; agreement of both is trusted).
    fn name_candidates(
        &mut self,
        cands: &[Candidate],
        k: &mouthpiece_frame::Intrinsics,
        blobs: &[mouthpiece_detect::Blob],
    ) -> Small<Option<usize>> {
        let layout = self.layout;
        let total = layout.lip_dots + layout.forehead_dots;
        let geometry = || match labels::label_by_geometry(cands, layout) {
            Ok(names) => Some(names),
            Err(why) => {
                tracing::trace!(?why, candidates = cands.len(), "no names from geometry");
                None
            }
        };
        if self.tracks.is_none() {
            return match geometry() {
                Some(names) => names.into_iter().map(Some).collect(),
                None => smallvec::smallvec![None; total],
            };
        }
        let mut solver = std::mem::take(&mut self.assignment);
        // The forehead is named once; the lips under each motion hypothesis below.
        let (forehead, head) = self.assign_forehead(cands, k, &mut solver);
        let named_forehead = (&forehead[..], &head);
        let mut predicted =
            self.checked_names(cands, k, &mut solver, named_forehead, LipMotion::Steady);
        // Lips that stop dead (closing against each other, a corner at the end of a smile)
        // overshoot a constant-velocity prediction: with lip dots missing and candidates
        // left, the names from "the lips stayed where they were" are taken when they name more.
        let lips_named = |names: &[Option<usize>]| {
            names[..layout.lip_dots]
                .iter()
                .filter(|c| c.is_some())
                .count()
        };
        let named = predicted.iter().filter(|c| c.is_some()).count();
        if lips_named(&predicted) < layout.lip_dots && named < cands.len() {
            let stopped =
                self.checked_names(cands, k, &mut solver, named_forehead, LipMotion::Stopped);
            if lips_named(&stopped) > lips_named(&predicted)
                && self.corners_are_extremes(&stopped, cands)
            {
                tracing::debug!(
                    steady = lips_named(&predicted),
                    stopped = lips_named(&stopped),
                    "lips stopped: named from their last places"
                );
                predicted = stopped;
            }
        }
        // The jaw drops or snaps shut within a frame: the lower lip lands beyond its
        // prediction together, leaving ghosts where it was (faint: part of the exposure).
        let ghosts = self.lower_lip_on_ghosts(&predicted, cands, k, blobs);
        let on_ghosts = ghosts.iter().filter(|g| **g).count();
        let free_lips = (0..cands.len())
            .filter(|c| cands[*c].role != DotRole::Forehead && !predicted.contains(&Some(*c)))
            .count();
        let lower_area = |names: &[Option<usize>]| -> f64 {
            names[layout.right_corner() + 1..layout.lip_dots]
                .iter()
                .flatten()
                .map(|&c| blobs[self.cand_blob[c]].area as f64)
                .sum()
        };
        if (lips_named(&predicted) < layout.lip_dots && named < cands.len())
            || (on_ghosts >= 2 && free_lips >= 2)
        {
            if let Some(shift) = self.jaw_jump(&predicted, &ghosts, cands, k, &head) {
                let jumped = self.checked_names(
                    cands,
                    k,
                    &mut solver,
                    named_forehead,
                    LipMotion::JawJumped(shift),
                );
                // With the lower lip on its ghosts, a corner merged with its neighbour may
                // fail the checks under the new names: one name fewer, missing rather than
                // five on ghosts.
                let slack = usize::from(on_ghosts >= 2);
                let better = lips_named(&jumped) > lips_named(&predicted)
                    || (lips_named(&jumped) + slack >= lips_named(&predicted)
                        && lower_area(&jumped) > 1.3 * lower_area(&predicted));
                if better && self.corners_are_extremes(&jumped, cands) {
                    tracing::debug!(
                        before = lips_named(&predicted),
                        jumped = lips_named(&jumped),
                        ?shift,
                        "the jaw jumped: lower lip named from its shifted places"
                    );
                    predicted = jumped;
                }
            }
        }
        self.assignment = solver;
        if !self.corners_are_extremes(&predicted, cands) {
            // Names slipped by one or more places around the mouth (a slip keeps the order):
            // geometry names a full set afresh; without one the lips go missing for now
            // (missing beats wrong).
            tracing::debug!("lip names slipped around the mouth; renaming");
            if let Some(geo) = geometry() {
                return geo.into_iter().map(Some).collect();
            }
            predicted[..layout.lip_dots].fill(None);
            return predicted;
        }
        if predicted.iter().all(Option::is_some) || cands.len() != total {
            return predicted;
        }
        match geometry() {
            Some(geo)
                if predicted
                    .iter()
                    .zip(&geo)
                    .all(|(p, g)| p.is_none_or(|p| p == *g)) =>
            {
                geo.into_iter().map(Some).collect()
            }
            _ => predicted,
        }
    }

    /// How far the lower lip jumped beyond its prediction, in pixels: the median offset from
    /// the prediction of each lower-lip dot that is missing or on a ghost (`ghosts`) to the
    /// nearest free lip candidate within [`JAW_JUMP_PX`] and its depth window. `None` when no
    /// such candidate lies near one.
    fn jaw_jump(
        &self,
        names: &[Option<usize>],
        ghosts: &[bool],
        cands: &[Candidate],
        k: &mouthpiece_frame::Intrinsics,
        head: &RigidTransform,
    ) -> Option<[f64; 2]> {
        let n = self.layout.lip_dots;
        let tracks = self.tracks.as_ref()?;
        let preds = self.lip_predictions(head, k, LipMotion::Steady);
        let mut taken: Small<bool> = smallvec::smallvec![false; cands.len()];
        for c in names.iter().flatten() {
            taken[*c] = true;
        }
        let (mut dx, mut dy): (Small<f64>, Small<f64>) = (Small::new(), Small::new());
        for i in self.layout.right_corner() + 1..n {
            if names[i].is_some() && !ghosts[i] {
                continue;
            }
            let window = depth_window(&tracks[i], head, self.config.lip_depth_gate_m);
            let nearest = cands
                .iter()
                .enumerate()
                .filter(|&(j, c)| !taken[j] && c.role != DotRole::Forehead)
                .filter(|(_, c)| (window[0]..=window[1]).contains(&c.point.z))
                .map(|(_, c)| [c.pixel[0] - preds[i][0], c.pixel[1] - preds[i][1]])
                .filter(|d| d[0].hypot(d[1]) <= JAW_JUMP_PX)
                .min_by(|a, b| a[0].hypot(a[1]).total_cmp(&b[0].hypot(b[1])));
            if let Some(d) = nearest {
                dx.push(d[0]);
                dy.push(d[1]);
            }
        }
        let median = |v: &mut Small<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        (!dx.is_empty()).then(|| [median(&mut dx), median(&mut dy)])
    }

    /// Per lip dot: whether it is on the lower lip between the corners and named on a blob
    /// of less than half a dot's area (what a motion-blur ghost of the jaw's lip looks like).
    fn lower_lip_on_ghosts(
        &self,
        names: &[Option<usize>],
        cands: &[Candidate],
        k: &mouthpiece_frame::Intrinsics,
        blobs: &[mouthpiece_detect::Blob],
    ) -> Small<bool> {
        let n = self.layout.lip_dots;
        (0..n)
            .map(|i| {
                i > self.layout.right_corner()
                    && names[i].is_some_and(|c| {
                        let r = self.dot_radius_px(k.fx, cands[c].point.z);
                        (blobs[self.cand_blob[c]].area as f64) < 0.5 * disc_area(r)
                    })
            })
            .collect()
    }

    /// Lip names by prediction, then the checks that drop names breaking the mouth's shape.
    fn checked_names(
        &self,
        cands: &[Candidate],
        k: &mouthpiece_frame::Intrinsics,
        solver: &mut labels::Assignment,
        (forehead, head): (&[Option<usize>], &RigidTransform),
        lip_motion: LipMotion,
    ) -> Small<Option<usize>> {
        let mut names = self.assign_lips(cands, k, solver, forehead, head, lip_motion);
        self.enforce_lip_order(&mut names, cands);
        self.keep_corner_neighbours_in_place(&mut names, cands);
        names
    }

    /// With one of two neighbouring dots unseen, names can slip by one place without breaking
    /// the order around the mouth: the dot next to a corner named on the corner's blob, the
    /// corner on its neighbour's, a lower-lip dot on the upper-lip blob above it. In the
    /// neutral mouth frame (head motion removed) a corner stays out beyond its two
    /// neighbours, and each upper-lip dot above the lower-lip dot opposite it, by at least
    /// 40 % of their gap at rest; with one of the two unseen, the seen one is held to that
    /// against where the unseen one is taken to be. A name that breaks it is dropped (missing
    /// beats wrong).
    fn keep_corner_neighbours_in_place(&self, names: &mut [Option<usize>], cands: &[Candidate]) {
        let (Some(stab), Some(tracks)) = (&self.stabiliser, &self.tracks) else {
            return;
        };
        let neutral = stab.neutral();
        let frame = &neutral.frame;
        let n = self.layout.lip_dots;
        let inverse = self.head_now(names, cands).inverse();
        let now = |names: &[Option<usize>], i: usize| {
            names[i].map(|c| frame.to_mouth(&inverse.apply(&cands[c].point)))
        };
        let (left, right) = (self.layout.left_corner(), self.layout.right_corner());
        let is_corner = |i: usize| i == left || i == right;
        // Where an unseen dot is taken to be: where it was, if lately; a lip dot unseen for
        // longer, from a seen lip neighbour (not a corner) plus their offset at rest (the
        // mouth moves on while a dot is unseen); else where it was, up to 30 frames back.
        let last = |names: &[Option<usize>], i: usize| {
            let track = &tracks[i];
            if track.missing > 2 && !is_corner(i) {
                let seen = [(i + n - 1) % n, (i + 1) % n]
                    .into_iter()
                    .filter(|&k| !is_corner(k))
                    .find_map(|k| now(names, k).map(|q| (k, q)));
                if let Some((k, q)) = seen {
                    return Some(q + (neutral.lip[i] - neutral.lip[k]));
                }
            }
            (track.missing <= 30).then(|| frame.to_mouth(&track.stab))
        };
        // (outer or upper dot, inner or lower dot, axis): `outer` stays beyond `inner` along
        // the axis (x for the left corner, -x for the right one, y for upper over lower).
        let x = Vec3::x();
        let y = Vec3::y();
        let corners = [
            (left, (left + 1) % n, x),
            (left, (left + n - 1) % n, x),
            (right, right - 1, -x),
            (right, right + 1, -x),
        ];
        // Each upper-lip dot over the lower-lip dot opposite it (D2 over D12, … D6 over D8).
        let lips = (1..right).map(|u| (u, n - u, y));
        // Along each lip, each dot beyond its neighbour towards the right corner (D2 beyond
        // D3, …; D12 beyond D11, …): a name slipped one place along a lip with the dot it
        // slipped onto unseen keeps every other order, and held on for 1.5 s in one session.
        let upper = (1..right - 1).map(|i| (i, i + 1, x));
        let lower = (right + 1..n - 1).map(|i| (i + 1, i, x));
        let pairs = corners.into_iter().chain(lips).chain(upper).chain(lower);
        // A corner unseen for a while, checked against one neighbour, from its other
        // neighbour as seen now plus their rest offset (a mouth pursing moves the corners in).
        let corner_ref = |names: &[Option<usize>], corner: usize, against: usize| {
            let other = [(corner + n - 1) % n, (corner + 1) % n]
                .into_iter()
                .find(|&k| k != against)
                .expect("a corner has two neighbours");
            match now(names, other) {
                Some(q) if tracks[corner].missing > 2 => {
                    Some(q + (neutral.lip[corner] - neutral.lip[other]))
                }
                _ => last(names, corner),
            }
        };
        for (outer, inner, axis) in pairs {
            let gap = (neutral.lip[outer] - neutral.lip[inner]).dot(&axis);
            if gap <= 0.0 {
                continue;
            }
            let margin = 0.4 * gap;
            let outer_ref = |names: &[Option<usize>]| {
                if is_corner(outer) {
                    corner_ref(names, outer, inner)
                } else {
                    last(names, outer)
                }
            };
            match (now(names, outer), now(names, inner)) {
                (None, Some(q))
                    if outer_ref(names).is_some_and(|o| (o - q).dot(&axis) < margin) =>
                {
                    tracing::debug!(dot = %PerformerLayout::lip_name(inner), "where an unseen neighbour was; name dropped");
                    names[inner] = None;
                }
                (Some(q), None)
                    if last(names, inner).is_some_and(|i| (q - i).dot(&axis) < margin) =>
                {
                    tracing::debug!(dot = %PerformerLayout::lip_name(outer), "where an unseen neighbour was; name dropped");
                    names[outer] = None;
                }
                _ => {}
            }
        }
    }

    /// Whether the named mouth corners are the lip dots furthest out along the mouth's x axis
    /// (neutral mouth frame, head motion removed), within 3 % of the mouth width: names that
    /// slipped around the mouth still meet in order, but put a corner name on a lip dot.
    fn corners_are_extremes(&self, names: &[Option<usize>], cands: &[Candidate]) -> bool {
        let Some(stab) = &self.stabiliser else {
            return true;
        };
        let frame = &stab.neutral().frame;
        let tolerance = 0.03 * frame.width;
        let (n, left, right) = (
            self.layout.lip_dots,
            self.layout.left_corner(),
            self.layout.right_corner(),
        );
        let inverse = self.head_now(names, cands).inverse();
        let x = |i: usize| names[i].map(|c| frame.to_mouth(&inverse.apply(&cands[c].point)).x);
        let others = || (0..n).filter(|&i| i != left && i != right).filter_map(x);
        let left_ok = x(left).is_none_or(|l| others().all(|o| o <= l + tolerance));
        let right_ok = x(right).is_none_or(|r| others().all(|o| o >= r - tolerance));
        left_ok && right_ok
    }

    /// Names that break the walk around the mouth are dropped (missing beats wrong): in the
    /// neutral mouth frame (head motion removed), the named lip dots must meet in label order
    /// going round the mouth's origin from the left corner over the upper lip. The longest
    /// run of names in order is kept, the others become missing.
    fn enforce_lip_order(&self, names: &mut [Option<usize>], cands: &[Candidate]) {
        let Some(stab) = &self.stabiliser else { return };
        let frame = &stab.neutral().frame;
        let n = self.layout.lip_dots;
        let inverse = self.head_now(names, cands).inverse();
        // Angle about the mouth origin, the walk starting at the left corner (or, when it is
        // not seen, half-way between it and the last lower-lip dot at rest).
        let tau = std::f64::consts::TAU;
        let raw = |c: usize| {
            let q = frame.to_mouth(&inverse.apply(&cands[c].point));
            q.y.atan2(q.x)
        };
        let start = match names[0] {
            Some(c) => raw(c) - 1e-9,
            None => {
                let rest = |i: usize| stab.neutral().lip[i].y.atan2(stab.neutral().lip[i].x);
                let (last, first) = (rest(n - 1), rest(0));
                let last = if last > first { last - tau } else { last };
                (last + first) / 2.0
            }
        };
        let angle = |c: usize| (raw(c) - start).rem_euclid(tau);
        let found: Small<(usize, f64)> = (0..n)
            .filter_map(|i| names[i].map(|c| (i, angle(c))))
            .collect();
        if found.len() < 2 {
            return;
        }
        // Longest increasing subsequence of the angles in label order (n is small: O(n²)).
        let mut best_len: Small<usize> = smallvec::smallvec![1; found.len()];
        let mut prev: Small<usize> = smallvec::smallvec![usize::MAX; found.len()];
        for a in 0..found.len() {
            for b in 0..a {
                if found[b].1 < found[a].1 && best_len[b] + 1 > best_len[a] {
                    best_len[a] = best_len[b] + 1;
                    prev[a] = b;
                }
            }
        }
        let mut end = (0..found.len())
            .max_by_key(|&a| best_len[a])
            .expect("non-empty");
        let mut keep: Small<bool> = smallvec::smallvec![false; found.len()];
        loop {
            keep[end] = true;
            if prev[end] == usize::MAX {
                break;
            }
            end = prev[end];
        }
        for (a, &(i, _)) in found.iter().enumerate() {
            if !keep[a] {
                tracing::debug!(dot = %PerformerLayout::lip_name(i), "name breaks the order around the mouth; dropped");
                names[i] = None;
            }
        }
    }

    /// This frame's head motion (reference → now) from the named forehead dots, or the last one.
    ///
    /// For naming only (the reported head pose follows docs/method.md §4): with fewer than 3 forehead
    /// dots the motion is fitted to the two forehead dots seen plus the upper lip and corners
    /// at rest. The upper lip moves little with speech; a head turning fast while a forehead dot
    /// is hidden moves far more, and a stale head pose would bend every lip prediction.
    fn head_now(&self, names: &[Option<usize>], cands: &[Candidate]) -> RigidTransform {
        let n = self.layout.lip_dots;
        let (mut from, mut to): (Small<Vec3>, Small<Vec3>) = names[n..]
            .iter()
            .enumerate()
            .filter_map(|(j, c)| c.map(|c| (self.reference_forehead[j], cands[c].point)))
            .unzip();
        if let Some(head) = kabsch(&from, &to) {
            return head;
        }
        if self.rest.len() == n && from.len() == 2 {
            let upper = 0..=self.layout.right_corner();
            for (rest, c) in self.rest[upper.clone()].iter().zip(&names[upper]) {
                if let Some(c) = c {
                    from.push(*rest);
                    to.push(cands[*c].point);
                }
            }
        }
        // Only a fit the upper lip follows rigidly (wrong or deformed lip names fit badly).
        match kabsch(&from, &to) {
            Some(head)
                if from
                    .iter()
                    .zip(&to)
                    .map(|(f, t)| (head.apply(f) - t).norm_squared())
                    .sum::<f64>()
                    <= from.len() as f64 * HEAD_FALLBACK_RMS_M.powi(2) =>
            {
                head
            }
            _ => self.head,
        }
    }

    /// Where to look: around the predicted dots, growing while some are missing; the full
    /// frame when nothing is named or every few frames while dots are missing.
    fn search_region(&self, frame: &Frame) -> Option<PixelRect> {
        let tracks = self.tracks.as_ref()?;
        if self.frames_with_missing > 0
            && self
                .frames_with_missing
                .is_multiple_of(self.config.full_search_every)
        {
            return None;
        }
        let grow = (1u32 << self.frames_with_missing.min(4)) as f64;
        let margin = self.config.roi_margin_px * grow;
        let rect = PixelRect::around(
            tracks.iter().map(|t| t.predicted_pixel(self.step_ratio)),
            margin,
        )?;
        // A region covering most of the image costs as much as the full frame.
        let full = frame.color.width as i64 * frame.color.height as i64;
        (rect.area() < full / 2).then_some(rect)
    }

    /// Forehead names by prediction (constant pixel velocity), and the head motion
    /// (reference → now) fitted to the named forehead dots (the last one without any).
    fn assign_forehead(
        &self,
        cands: &[Candidate],
        k: &mouthpiece_frame::Intrinsics,
        solver: &mut labels::Assignment,
    ) -> (Small<Option<usize>>, RigidTransform) {
        let n = self.layout.lip_dots;
        let tracks = self.tracks.as_ref().expect("called with tracks");
        let forehead_preds: Small<[f64; 2]> = tracks[n..]
            .iter()
            .map(|t| {
                if t.missing == 0 {
                    t.predicted_pixel(self.step_ratio)
                } else {
                    camera::project(k, &self.head.apply(&t.stab)).unwrap_or(t.pixel)
                }
            })
            .collect();
        let taken: Small<bool> = smallvec::smallvec![false; cands.len()];
        let forehead = labels::assign(
            &self.gated(&forehead_preds, &tracks[n..], Slot::Forehead, &self.head),
            cands,
            &taken,
            solver,
        );
        let (from, to): (Small<Vec3>, Small<Vec3>) = forehead
            .iter()
            .enumerate()
            .filter_map(|(j, c)| c.map(|c| (self.reference_forehead[j], cands[c].point)))
            .unzip();
        let head = kabsch(&from, &to).unwrap_or(self.head);
        (forehead, head)
    }

    /// Where each lip dot is predicted in the image: its stabilised position (moved on by its
    /// velocity when it was seen last frame and `lip_motion` is steady) carried by this
    /// frame's head motion and projected.
    fn lip_predictions(
        &self,
        head: &RigidTransform,
        k: &mouthpiece_frame::Intrinsics,
        lip_motion: LipMotion,
    ) -> Small<[f64; 2]> {
        let tracks = self.tracks.as_ref().expect("called with tracks");
        tracks[..self.layout.lip_dots]
            .iter()
            .map(|t| {
                let q = if t.missing == 0 && lip_motion != LipMotion::Stopped {
                    t.stab + t.stab_vel * self.step_ratio
                } else {
                    t.stab
                };
                camera::project(k, &head.apply(&q)).unwrap_or(t.pixel)
            })
            .enumerate()
            .map(|(i, p)| match lip_motion {
                LipMotion::JawJumped(shift) if i > self.layout.right_corner() => {
                    [p[0] + shift[0], p[1] + shift[1]]
                }
                _ => p,
            })
            .collect()
    }

    /// Lip names by prediction on the candidates the forehead left, with the second chances
    /// ([`Recovery`]); returns every name (lip dots, then the given forehead ones).
    fn assign_lips(
        &self,
        cands: &[Candidate],
        k: &mouthpiece_frame::Intrinsics,
        solver: &mut labels::Assignment,
        forehead: &[Option<usize>],
        head: &RigidTransform,
        lip_motion: LipMotion,
    ) -> Small<Option<usize>> {
        let n = self.layout.lip_dots;
        let tracks = self.tracks.as_ref().expect("called with tracks");
        let mut taken: Small<bool> = smallvec::smallvec![false; cands.len()];
        for c in forehead.iter().flatten() {
            taken[*c] = true;
        }
        let lip_preds = self.lip_predictions(head, k, lip_motion);
        let gates = self.gated(&lip_preds, &tracks[..n], Slot::Lip, head);
        let mut lip = labels::assign(&gates, cands, &taken, solver);
        for c in lip.iter().flatten() {
            taken[*c] = true;
        }
        let recover = Recovery {
            tracker: self,
            preds: &lip_preds,
            gates: &gates,
            cands,
            tracks: &tracks[..n],
            head,
            k,
        };
        recover.run(&mut lip, &mut taken, solver);
        lip.into_iter().chain(forehead.iter().copied()).collect()
    }

    /// Gate per prediction: a fraction of the distance to the nearest other prediction of the
    /// group, at least `min_gate_px`, widened a little for dots missing for a while. Lip dots
    /// are gated in depth too: a candidate further than [`TrackConfig::lip_depth_gate_m`]
    /// from the dot's expected depth is not this dot (widened for dots missing for a while).
    /// The window spans the dot's last depth and its last place carried by this frame's head
    /// motion (`head`, reference → now): a head moving fast in depth moved the lips 8 mm
    /// between two frames, out of a gate around their last depth, while the head pose's own
    /// noise makes the carried depth alone the worse guess in some sessions.
    fn gated(
        &self,
        preds: &[[f64; 2]],
        tracks: &[DotTrack],
        slot: Slot,
        head: &RigidTransform,
    ) -> Small<labels::Prediction> {
        preds
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let nearest = preds
                    .iter()
                    .enumerate()
                    .filter(|(j, _)| *j != i)
                    .map(|(_, q)| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt())
                    .fold(f64::INFINITY, f64::min);
                let base = (self.config.gate_fraction * nearest).max(self.config.min_gate_px);
                let missing = tracks[i].missing.min(10) as f64;
                let mut gate =
                    labels::Prediction::in_image(*p, base * (1.0 + 0.05 * missing), slot);
                if slot == Slot::Lip {
                    let gate_m = self.config.lip_depth_gate_m * (1.0 + 0.2 * missing);
                    let [low, high] = depth_window(&tracks[i], head, gate_m);
                    gate.z = 0.5 * (low + high);
                    gate.z_gate = 0.5 * (high - low);
                }
                gate
            })
            .collect()
    }

    fn update_tracks(&mut self, names: &[Option<usize>], cands: &[Candidate]) {
        let n = self.layout.lip_dots;
        let all_seen = names.iter().all(|c| c.is_some());
        if self.tracks.is_none() {
            if !all_seen {
                return;
            }
            // First full naming: this forehead is the reference until calibrated.
            self.reference_forehead = names[n..]
                .iter()
                .map(|c| cands[c.expect("all seen")].point)
                .collect();
            self.head = RigidTransform::IDENTITY;
            self.rest = names[..n]
                .iter()
                .map(|c| cands[c.expect("all seen")].point)
                .collect();
            self.tracks = Some(
                names
                    .iter()
                    .map(|c| {
                        let c = &cands[c.expect("all seen")];
                        DotTrack {
                            pixel: c.pixel,
                            pixel_vel: [0.0; 2],
                            stab: c.point,
                            stab_vel: Vec3::zeros(),
                            depth: c.point.z,
                            missing: 0,
                        }
                    })
                    .collect(),
            );
            tracing::info!("all dots named from geometry; tracking");
            return;
        }
        if self.frames_without_names > self.config.lost_after_frames {
            tracing::info!(
                frames = self.frames_without_names,
                "dots lost; re-acquiring from geometry"
            );
            self.tracks = None;
            return;
        }
        self.head = self.head_now(names, cands);
        let inverse = self.head.inverse();
        let tracks = self.tracks.as_mut().expect("checked");
        for (track, name) in tracks.iter_mut().zip(names) {
            match name {
                Some(c) => {
                    let c = &cands[*c];
                    let stab = inverse.apply(&c.point);
                    if track.missing == 0 {
                        track.pixel_vel =
                            [c.pixel[0] - track.pixel[0], c.pixel[1] - track.pixel[1]];
                        track.stab_vel = stab - track.stab;
                    } else {
                        track.pixel_vel = [0.0; 2];
                        track.stab_vel = Vec3::zeros();
                    }
                    track.pixel = c.pixel;
                    track.depth = c.point.z;
                    track.stab = stab;
                    track.missing = 0;
                }
                None => track.missing = track.missing.saturating_add(1),
            }
        }
    }

    /// Collects fully seen frames while calibrating; takes the neutral pose once the window
    /// spans `calibration_s` of a still, closed mouth.
    fn update_calibration(
        &mut self,
        t: f64,
        depth: &DepthImage,
        depth_scale: f64,
        k: Intrinsics,
    ) -> Result<(), TrackError> {
        if !self.calibrating {
            return Ok(());
        }
        let dots = &self.out.dots;
        let complete = dots.lip.iter().chain(&dots.forehead).all(|d| d.is_some());
        if !complete {
            // The window must be continuous.
            self.window.clear();
            self.window_crops.clear();
            return Ok(());
        }
        // A frame at the window's last moment (a clock standing still) replaces it: the
        // window spans time, not frames.
        if self.window.back().is_some_and(|(last, _)| *last >= t) {
            self.window.pop_back();
            self.window_crops.pop_back();
        }
        self.window.push_back((t, dots.clone()));
        if self.config.forehead_surface_margin_m > 0.0 {
            let n = self.layout.lip_dots;
            let pixels: Small<[f64; 2]> = self.out.pixels[n..].iter().flatten().copied().collect();
            let z = dots.forehead.iter().flatten().map(|p| p.z).sum::<f64>()
                / dots.forehead.len() as f64;
            let margin_px = self.config.forehead_surface_margin_m * k.fx / z.max(0.1);
            self.window_crops
                .push_back(forehead::DepthCrop::around_forehead(
                    depth, &pixels, margin_px,
                ));
        }
        let span = |w: &VecDeque<(f64, PerformerDots)>| {
            w.back().map_or(0.0, |b| b.0) - w.front().map_or(0.0, |f| f.0)
        };
        // Keep just over the calibration span.
        while self.window.len() > 2
            && span(&self.window) - (self.window[1].0 - self.window[0].0) >= self.calibration_s
        {
            self.window.pop_front();
            self.window_crops.pop_front();
        }
        if self.window.len() > CALIBRATION_WINDOW_MAX_FRAMES {
            thin_out(&mut self.window);
            thin_out(&mut self.window_crops);
        }
        // One frame interval short of the span is a full second of frames at any rate.
        let interval = if self.window.len() > 1 {
            span(&self.window) / (self.window.len() - 1) as f64
        } else {
            0.0
        };
        if span(&self.window) + interval < self.calibration_s - 1e-9 {
            return Ok(());
        }
        if !self.window_is_still() {
            return Ok(());
        }
        let mut acc = NeutralAccumulator::new(self.layout);
        for (_, d) in &self.window {
            acc.push(d).map_err(TrackError::Neutral)?;
        }
        let neutral = acc.finish().map_err(TrackError::Neutral)?;
        tracing::info!(
            frames = neutral.frames,
            mouth_width_mm = neutral.mouth_width() * 1e3,
            "neutral pose taken"
        );
        // Re-base the head motion on the neutral forehead.
        self.reference_forehead = neutral
            .forehead_camera
            .iter()
            .map(|p| p.expect("complete window"))
            .collect();
        if let Some(tracks) = &mut self.tracks {
            for (track, p) in tracks
                .iter_mut()
                .zip(neutral.lip_camera.iter().chain(&self.reference_forehead))
            {
                track.stab = *p;
                track.stab_vel = Vec3::zeros();
            }
        }
        self.head = RigidTransform::IDENTITY;
        self.rest = neutral.lip_camera.clone();
        let missing = MissingDots {
            hold: self.config.missing_hold_s,
            decay: self.config.missing_decay_s,
        };
        self.stabiliser = Some(Stabiliser::new(neutral, missing).map_err(TrackError::Neutral)?);
        self.forehead_surface = self.build_forehead_surface(depth_scale, &k);
        self.calibrating = false;
        self.calibration_s = self.config.calibration_s;
        self.window.clear();
        self.window_crops.clear();
        self.out.status.neutral_taken = true;
        Ok(())
    }

    /// Each named lip dot but the corners: its depth again, from a patch stretched along
    /// the lip (the line through its neighbours' pixels; [`TrackConfig::lip_depth_along_m`]).
    /// Names are settled by then: this only sharpens the depth.
    fn lip_depths_along_the_lips(
        &mut self,
        lip: &[Option<usize>],
        cands: &mut [Candidate],
        view: &DepthView,
    ) {
        let (along_m, across_m) = (
            self.config.lip_depth_along_m,
            self.config.lip_depth_across_m,
        );
        if along_m <= 0.0 {
            return;
        }
        let n = lip.len();
        let corners = [self.layout.left_corner(), self.layout.right_corner()];
        for i in 0..n {
            if corners.contains(&i) {
                continue;
            }
            let Some(c) = lip[i] else { continue };
            let here = cands[c].pixel;
            let prev = lip[(i + n - 1) % n].map(|p| cands[p].pixel);
            let next = lip[(i + 1) % n].map(|p| cands[p].pixel);
            let (a, b) = match (prev, next) {
                (Some(p), Some(q)) => (p, q),
                (Some(p), None) => (p, here),
                (None, Some(q)) => (here, q),
                (None, None) => continue,
            };
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let len = (dx * dx + dy * dy).sqrt();
            if len < 1.0 {
                continue;
            }
            let gap = |p: Option<[f64; 2]>| {
                p.map_or(f64::INFINITY, |p| {
                    ((p[0] - here[0]).powi(2) + (p[1] - here[1]).powi(2)).sqrt()
                })
            };
            let nearest_px = gap(prev).min(gap(next));
            let z_hint = cands[c].point.z;
            let px = |m: f64| (m * view.k.fx / z_hint * 64.0).round() / 64.0;
            // Short of the neighbours: towards a corner the lip bends away.
            let along_px =
                px(along_m).min((LIP_PATCH_NEIGHBOUR_FRACTION * nearest_px * 64.0).round() / 64.0);
            if let Some((z, _)) = depth::depth_by_plane_along(
                view.depth,
                view.scale,
                here,
                depth::Ellipse {
                    along: [dx / len, dy / len],
                    half_len: along_px,
                    half_width: px(across_m),
                },
                self.depth_range,
                &mut self.depth_buf,
            ) {
                cands[c].point = camera::deproject(view.k, here, z);
            }
        }
    }

    /// The neutral forehead surface from the calibration window (see [`forehead`]).
    fn build_forehead_surface(
        &self,
        scale: f64,
        k: &Intrinsics,
    ) -> Option<forehead::ForeheadSurface> {
        if self.window_crops.len() != self.window.len() {
            return None;
        }
        let crops: Vec<&forehead::DepthCrop> = self.window_crops.iter().collect();
        let z = self.reference_forehead.iter().map(|p| p.z).sum::<f64>()
            / self.reference_forehead.len().max(1) as f64;
        let step_px = (FOREHEAD_SAMPLE_SPACING_M * k.fx / z.max(0.1))
            .round()
            .max(1.0) as usize;
        let surface = forehead::ForeheadSurface::build(
            &crops,
            scale,
            self.depth_range,
            k,
            self.reference_forehead.clone(),
            step_px,
        );
        match &surface {
            Some(s) => tracing::info!(samples = s.samples(), "forehead surface taken"),
            None => tracing::warn!(
                "too little forehead surface with depth: the head motion comes from the forehead dots alone"
            ),
        }
        surface
    }

    /// With every forehead dot named and a neutral surface, the forehead dots become the
    /// neutral ones carried by the head motion fitted to the surface and their pixels.
    fn fit_forehead_surface(
        &self,
        forehead: &[Option<usize>],
        cands: &mut [Candidate],
        view: &DepthView,
    ) {
        let Some(surface) = &self.forehead_surface else {
            return;
        };
        let rays: Small<Option<Vec3>> =
            forehead.iter().map(|c| c.map(|c| cands[c].point)).collect();
        let (from, to): (Small<Vec3>, Small<Vec3>) = self
            .reference_forehead
            .iter()
            .zip(&rays)
            .filter_map(|(f, r)| r.map(|r| (*f, r)))
            .unzip();
        if from.len() < forehead.len() {
            return;
        }
        let Some(start) = kabsch(&from, &to) else {
            return;
        };
        let Some(head) = surface.refine(
            &start,
            &rays,
            view.depth,
            view.scale,
            view.k,
            forehead::SurfaceFit::default(),
        ) else {
            return;
        };
        // The dots' own fit is off by a degree or two at worst: a refinement that turned or
        // moved the forehead far from it fitted something else (a hand over most of the
        // forehead).
        let turned = ((head.rotation.transpose() * start.rotation).trace() - 1.0) / 2.0;
        let moved = self
            .reference_forehead
            .iter()
            .map(|p| (head.apply(p) - start.apply(p)).norm())
            .fold(0.0, f64::max);
        if turned.clamp(-1.0, 1.0).acos() > SURFACE_FIT_MAX_TURN_RAD
            || moved > SURFACE_FIT_MAX_SHIFT_M
        {
            tracing::debug!(
                moved_m = moved,
                "forehead surface fit far from the dots' fit; not used"
            );
            return;
        }
        for (c, reference) in forehead.iter().zip(&self.reference_forehead) {
            if let Some(c) = c {
                cands[*c].point = head.apply(reference);
            }
        }
    }

    /// Whether the lips, with head motion removed, stayed within the tolerance over the
    /// window, and the mouth is closed.
    fn window_is_still(&self) -> bool {
        let n = self.layout.lip_dots;
        let first = &self.window[0].1;
        let reference: Vec<Vec3> = first
            .forehead
            .iter()
            .map(|p| p.expect("complete"))
            .collect();
        let mut sum = vec![Vec3::zeros(); n];
        let mut sum_sq = vec![0.0; n];
        for (_, d) in &self.window {
            let cur: Vec<Vec3> = d.forehead.iter().map(|p| p.expect("complete")).collect();
            let Some(h) = kabsch(&cur, &reference) else {
                return false;
            };
            for (i, p) in d.lip.iter().enumerate() {
                let q = h.apply(&p.expect("complete"));
                sum[i] += q;
                sum_sq[i] += q.norm_squared();
            }
        }
        let m = self.window.len() as f64;
        // One noisy dot (a mouth corner on a steep surface) must not block calibration; speech
        // moves most dots: judge the 75th percentile of the per-dot wobble.
        let mut wobble: Vec<f64> = (0..n)
            .map(|i| {
                let mean = sum[i] / m;
                (sum_sq[i] / m - mean.norm_squared()).max(0.0).sqrt()
            })
            .collect();
        wobble.sort_by(f64::total_cmp);
        let worst = wobble[(3 * (n - 1)) / 4];
        let lip = |i: usize| first.lip[i].expect("complete");
        let width = (lip(self.layout.left_corner()) - lip(self.layout.right_corner())).norm();
        let upper_mid = lip(self.layout.right_corner() / 2);
        let lower_mid = lip((n + self.layout.right_corner()) / 2);
        let opening = (upper_mid - lower_mid).norm() / width.max(1e-9);
        tracing::trace!(worst_rms_mm = worst * 1e3, opening, "calibration window");
        worst <= self.config.still_tolerance_m && opening <= self.config.max_opening_ratio
    }
}

/// The second chances for lip dots over one frame, after the first pass of naming by
/// prediction ([`Recovery::run`]).
struct Recovery<'a> {
    tracker: &'a Tracker,
    /// Per lip dot: its first-pass prediction (pixels) and gates.
    preds: &'a [[f64; 2]],
    gates: &'a [labels::Prediction],
    cands: &'a [Candidate],
    tracks: &'a [DotTrack],
    /// This frame's head motion (reference → now) and the colour intrinsics.
    head: &'a RigidTransform,
    k: &'a mouthpiece_frame::Intrinsics,
}

impl Recovery<'_> {
    /// Second chances for lip dots the prediction missed because they moved more than it said.
    /// Speech moves neighbouring dots together (the jaw drops or lifts the whole lower lip
    /// between two frames), so:
    /// 1. a missing dot next to a found one is looked for where its prediction lands when
    ///    moved as that neighbour moved (its miss against its own prediction), repeated
    ///    along the mouth while it finds dots;
    /// 2. lip dots between the corners still missing are looked for with one common shift
    ///    of their predictions across the lip line (a jaw's motion), the shift that lands
    ///    the most of them on free candidates (at least two, or with a corner unseen all
    ///    of them but one and at least three); then 1 again.
    ///    Shifts along the lip line are not tried: a shift of one dot spacing along the lip
    ///    would land each prediction on its neighbour;
    /// 3. a dot that stayed at its prediction while the lip beside it jumped has likely
    ///    taken its own motion-blur ghost: it takes the blob its neighbour's motion points to
    ///    (within its gate; right there when the neighbour moved less than its gate)
    ///    ([`Recovery::leave_ghosts`]);
    /// 4. last, a dot still missing is looked for at its found neighbours' positions plus
    ///    its rest offset to them ([`Recovery::keep_rest_offsets`]).
    ///
    /// Same gates (pixel and depth) as the first pass, candidates nobody took.
    fn run(&self, lip: &mut [Option<usize>], taken: &mut [bool], solver: &mut labels::Assignment) {
        self.follow_neighbours(lip, taken, solver);
        if self.shift_across_lip_line(lip, taken, solver) {
            self.follow_neighbours(lip, taken, solver);
        }
        self.leave_ghosts(lip, taken);
        // Dots found from their neighbours' places may show a jump the dots beside them
        // stayed behind on their ghosts for.
        if self.keep_rest_offsets(lip, taken, solver) {
            self.leave_ghosts(lip, taken);
        }
    }

    /// Names missing dots at moved predictions, with the first pass's gates recomputed for
    /// this frame's positions (found or predicted). True when any dot was found.
    fn name_moved(
        &self,
        lip: &mut [Option<usize>],
        taken: &mut [bool],
        solver: &mut labels::Assignment,
        moved: &[(usize, [f64; 2])],
    ) -> bool {
        if moved.is_empty() {
            return false;
        }
        let n = lip.len();
        let mut all: Small<[f64; 2]> = (0..n)
            .map(|i| lip[i].map_or(self.preds[i], |c| self.cands[c].pixel))
            .collect();
        for &(i, p) in moved {
            all[i] = p;
        }
        let gates = self.tracker.gated(&all, self.tracks, Slot::Lip, self.head);
        let these: Small<labels::Prediction> = moved.iter().map(|&(i, _)| gates[i]).collect();
        let mut found = false;
        for (&(i, _), c) in moved
            .iter()
            .zip(labels::assign(&these, self.cands, taken, solver))
        {
            if let Some(c) = c {
                lip[i] = Some(c);
                taken[c] = true;
                found = true;
            }
        }
        found
    }

    /// A lip dot that stayed where it was while a neighbour jumped has probably taken the
    /// motion blur's ghost of itself (the exposure also saw where the lip just was): when a
    /// free candidate lies where the neighbour's motion puts the dot, within its gate, the
    /// dot takes that one instead and the ghost is left.
    fn leave_ghosts(&self, lip: &mut [Option<usize>], taken: &mut [bool]) {
        let preds: Small<Option<[f64; 2]>> = self.preds.iter().map(|p| Some(*p)).collect();
        self.leave_ghosts_from(lip, taken, &preds);
        // The same against where each dot was last frame: a dot whose prediction was off
        // (seen again only last frame, no velocity yet) shows no miss while it sits on its
        // ghost, but its neighbour's step since last frame still points to it.
        let last: Small<Option<[f64; 2]>> = self
            .tracks
            .iter()
            .map(|t| (t.missing == 0).then_some(t.pixel))
            .collect();
        self.leave_ghosts_from(lip, taken, &last);
    }

    /// [`Self::leave_ghosts`] with each dot's miss measured from `from` (a dot without one
    /// is left as it is).
    fn leave_ghosts_from(
        &self,
        lip: &mut [Option<usize>],
        taken: &mut [bool],
        from: &[Option<[f64; 2]>],
    ) {
        let n = lip.len();
        let gates = self.gates;
        let miss = |lip: &[Option<usize>], i: usize| {
            let from = from[i]?;
            lip[i].map(|c| {
                let p = self.cands[c].pixel;
                [p[0] - from[0], p[1] - from[1]]
            })
        };
        let norm = |v: [f64; 2]| (v[0] * v[0] + v[1] * v[1]).sqrt();
        let layout = self.tracker.layout;
        let is_corner = |i: usize| i == layout.left_corner() || i == layout.right_corner();
        // Corners neither move nor lead: a corner moves about half as far as the lip beside
        // it, and a corner name is the one most often on the wrong blob.
        for i in (0..n).filter(|&i| !is_corner(i)) {
            let Some(own) = miss(lip, i) else { continue };
            let g = gates[i];
            // The neighbour that moved most beyond its prediction.
            let Some(moved) = [(i + n - 1) % n, (i + 1) % n]
                .iter()
                .filter(|&&j| !is_corner(j))
                .filter_map(|&j| miss(lip, j))
                .max_by(|a, b| norm(*a).total_cmp(&norm(*b)))
            else {
                continue;
            };
            let apart = norm([own[0] - moved[0], own[1] - moved[1]]);
            // A neighbour that jumped beyond its gate pulls from anywhere within the gate; one
            // that moved less only to a blob right where its motion points.
            let reach = if norm(moved) > g.gate_px && apart > g.gate_px {
                g.gate_px
            } else if apart > 0.5 * g.gate_px {
                0.25 * g.gate_px
            } else {
                continue;
            };
            let base = from[i].expect("a dot with a miss has a place it is measured from");
            let target = [base[0] + moved[0], base[1] + moved[1]];
            let better = (0..self.cands.len())
                .filter(|&j| !taken[j] && self.cands[j].role != DotRole::Forehead)
                .filter(|&j| (self.cands[j].point.z - g.z).abs() <= g.z_gate)
                .map(|j| {
                    let p = self.cands[j].pixel;
                    (j, norm([p[0] - target[0], p[1] - target[1]]))
                })
                .filter(|&(_, d)| d < reach)
                .min_by(|a, b| a.1.total_cmp(&b.1));
            if let Some((j, _)) = better {
                if let Some(old) = lip[i] {
                    taken[old] = false;
                }
                lip[i] = Some(j);
                taken[j] = true;
                tracing::debug!(dot = %PerformerLayout::lip_name(i), "stayed while its neighbour moved: took the blob the neighbour's motion points to");
            }
        }
    }

    /// Missing dots looked for at their found neighbours' positions now (head motion
    /// removed) plus their rest offsets to them: the lips move together (the jaw carries the
    /// whole lower lip). Only dots with a found neighbour. True when any was found.
    fn keep_rest_offsets(
        &self,
        lip: &mut [Option<usize>],
        taken: &mut [bool],
        solver: &mut labels::Assignment,
    ) -> bool {
        let n = lip.len();
        let (head, k) = (self.head, self.k);
        let rest = &self.tracker.rest;
        let inverse = head.inverse();
        let moved: Small<(usize, [f64; 2])> = (0..n)
            .filter(|&i| lip[i].is_none())
            .filter_map(|i| {
                let mut sum = Vec3::zeros();
                let mut count = 0.0;
                for j in [(i + n - 1) % n, (i + 1) % n] {
                    if let Some(c) = lip[j] {
                        let now = inverse.apply(&self.cands[c].point);
                        sum += now + (rest[i] - rest[j]);
                        count += 1.0;
                    }
                }
                (count > 0.0)
                    .then(|| camera::project(k, &head.apply(&(sum / count))))
                    .flatten()
                    .map(|px| (i, px))
            })
            .collect();
        self.name_moved(lip, taken, solver, &moved)
    }

    /// Missing dots next to found ones, moved as those neighbours moved, along the mouth.
    fn follow_neighbours(
        &self,
        lip: &mut [Option<usize>],
        taken: &mut [bool],
        solver: &mut labels::Assignment,
    ) {
        let n = lip.len();
        for _ in 0..n {
            let moved: Small<(usize, [f64; 2])> = (0..n)
                .filter(|&i| lip[i].is_none())
                .filter_map(|i| {
                    let misses: Small<[f64; 2]> = [(i + n - 1) % n, (i + 1) % n]
                        .iter()
                        .filter_map(|&j| {
                            lip[j].map(|c| {
                                let p = self.cands[c].pixel;
                                [p[0] - self.preds[j][0], p[1] - self.preds[j][1]]
                            })
                        })
                        .collect();
                    if misses.is_empty() {
                        return None;
                    }
                    let k = misses.len() as f64;
                    let dx = misses.iter().map(|m| m[0]).sum::<f64>() / k;
                    let dy = misses.iter().map(|m| m[1]).sum::<f64>() / k;
                    Some((i, [self.preds[i][0] + dx, self.preds[i][1] + dy]))
                })
                .collect();
            if !self.name_moved(lip, taken, solver, &moved) {
                break;
            }
        }
    }

    /// Missing dots between the corners, all moved by the one shift across the lip line
    /// that lands the most of them (at least two) on free candidates. True when it found
    /// any.
    fn shift_across_lip_line(
        &self,
        lip: &mut [Option<usize>],
        taken: &mut [bool],
        solver: &mut labels::Assignment,
    ) -> bool {
        let n = lip.len();
        let layout = self.tracker.layout;
        let (left, right) = (layout.left_corner(), layout.right_corner());
        // Corners anchor the names around the mouth: with one unseen, only a shift that
        // lands all missing dots but one (at least three) counts (measured: at least two
        // finds a few more dots but names more of them wrongly; all of them finds fewer).
        let corners_seen = lip[left].is_some() && lip[right].is_some();
        let missing: Small<usize> = (0..n)
            .filter(|&i| lip[i].is_none() && i != left && i != right)
            .collect();
        if missing.len() < 2 {
            return false;
        }
        let preds = self.preds;
        let along = [
            preds[left][0] - preds[right][0],
            preds[left][1] - preds[right][1],
        ];
        let length = (along[0] * along[0] + along[1] * along[1]).sqrt();
        if length < 1.0 {
            return false;
        }
        let along = [along[0] / length, along[1] / length];
        let spacing = 2.0 * length / n as f64;
        let free: Small<usize> = (0..self.cands.len())
            .filter(|&j| !taken[j] && self.cands[j].role != DotRole::Forehead)
            .collect();
        let gates = self.gates;
        let lands = |g: &labels::Prediction, c: &Candidate, shift: [f64; 2]| {
            let d2 = (c.pixel[0] - g.pixel[0] - shift[0]).powi(2)
                + (c.pixel[1] - g.pixel[1] - shift[1]).powi(2);
            (d2 < g.gate_px * g.gate_px && (c.point.z - g.z).abs() <= g.z_gate).then_some(d2)
        };
        // (dots landed, summed squared residual, shift)
        let mut best: Option<(usize, f64, [f64; 2])> = None;
        for &i in &missing {
            for &j in &free {
                let g = &gates[i];
                let c = &self.cands[j].pixel;
                let shift = [c[0] - g.pixel[0], c[1] - g.pixel[1]];
                if (shift[0] * along[0] + shift[1] * along[1]).abs() > 0.3 * spacing {
                    continue;
                }
                let (mut count, mut residual) = (0, 0.0);
                for &m in &missing {
                    let nearest = free
                        .iter()
                        .filter_map(|&f| lands(&gates[m], &self.cands[f], shift))
                        .fold(f64::INFINITY, f64::min);
                    if nearest.is_finite() {
                        count += 1;
                        residual += nearest;
                    }
                }
                if best.is_none_or(|(c, r, _)| count > c || (count == c && residual < r)) {
                    best = Some((count, residual, shift));
                }
            }
        }
        let enough = |count: usize| {
            if corners_seen {
                count >= 2
            } else {
                count >= 3 && count + 1 >= missing.len()
            }
        };
        let Some((count, _, shift)) = best.filter(|b| enough(b.0)) else {
            return false;
        };
        let moved: Small<(usize, [f64; 2])> = missing
            .iter()
            .map(|&i| (i, [preds[i][0] + shift[0], preds[i][1] + shift[1]]))
            .collect();
        let found = self.name_moved(lip, taken, solver, &moved);
        if found {
            tracing::debug!(count, shift_px = ?shift, "lip dots found moved together");
        }
        found
    }
}

#[cfg(test)]
mod tests;
