//! The synthetic performer: a head with painted lip and forehead dots, speaking, seen by a
//! depth camera, with exact ground truth.
//!
//! There is no depth camera on our machines and no public recording of a performer with
//! painted dots, so mouthpiece renders its own. [`Synth`] is an iterator of
//! ([`Frame`], [`GroundTruth`]); `mouthpiece synth` writes it to an MCAP session.
//!
//! Layout:
//! - `head`: the analytic head (skull, nose, cheeks, chin, lips with relief, mouth interior,
//!   teeth) as a Lagrangian surface and its mesh;
//! - `motion`: speech-like mouth motion and head motion, deterministic per seed;
//! - `render`: a z-buffer rasteriser over the head's screen box, shading, dots, noise models.
//!
//! Conventions: camera frame of OpenCV (x right, y down, z forward, metres); the performer's
//! left is +x. Dots are named as in docs/method.md §1 (`D1` left corner, `D2..` upper lip left to right,
//! …, `F1..F3` forehead).
//!
//! Default paint colours (HSV in OpenCV's 0–180 hue scale), chosen far from skin (hue ≈ 10,
//! low saturation) and lips (hue ≈ 0/180):
//! - lip dots: [`LIP_DOT_RGB`], green, hue ≈ 66 (rendered: [`LIP_DOT_HUE_RANGE_CV`]);
//! - forehead dots: [`FOREHEAD_DOT_RGB`], blue, hue ≈ 111 (rendered: [`FOREHEAD_DOT_HUE_RANGE_CV`]).

pub mod args;
mod dots;
mod head;
mod layout;
mod motion;
mod render;
mod rng;
pub mod session;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use mouthpiece_frame::{Calibration, Extrinsics, Frame, Intrinsics};
pub use mouthpiece_recording::{GroundTruth, HeadPose, MouthTruth};

pub use dots::dot_positions;
pub use head::HINGE;
pub use layout::{DotLayout, ForeheadDot, LayoutError};
pub use motion::{HeadState, MouthState};

/// Default lip-dot paint, RGB: a saturated green (OpenCV HSV ≈ (64, 200, 200)).
pub const LIP_DOT_RGB: [u8; 3] = [40, 200, 70];
/// Default forehead-dot paint, RGB: a saturated blue (OpenCV HSV ≈ (111, 210, 230)).
pub const FOREHEAD_DOT_RGB: [u8; 3] = [40, 90, 230];
/// OpenCV-scale (0–180) hue ranges that contain the default lip-dot paint under the
/// renderer's lighting and noise (for detector defaults).
pub const LIP_DOT_HUE_RANGE_CV: (u8, u8) = (40, 85);
/// OpenCV-scale hue range of the default forehead-dot paint.
pub const FOREHEAD_DOT_HUE_RANGE_CV: (u8, u8) = (98, 128);
/// Minimum OpenCV-scale saturation (0–255) of the painted dots as rendered (shading, motion
/// blur into the lips and sensor noise included).
pub const DOT_MIN_SATURATION_CV: u8 = 80;
/// Default dot radius, metres.
pub const DEFAULT_DOT_RADIUS_M: f64 = 0.00225;

/// How much the head moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum HeadMotion {
    /// A perfectly still head.
    None,
    /// Yaw within ±10°, pitch ±3°, roll ±2°, ±5 mm.
    #[default]
    Mild,
    /// Yaw ±30°, pitch ±15°, roll ±10°, ±5 cm.
    Strong,
    /// The strong motion played [`FAST_HEAD_SPEEDUP`] times as fast: the same poses, turns
    /// and nods at 1.5 times the strong motion's angular and linear speed (and 2.25 times its
    /// acceleration), for checking the tracker past the motion it was tuned on.
    Fast,
}

/// How many times faster [`HeadMotion::Fast`] runs through the strong motion's poses.
pub const FAST_HEAD_SPEEDUP: f64 = 1.5;

/// Depth sensor noise.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum NoiseModel {
    /// Exact depth (rounded to millimetres).
    None,
    /// Structured light (Kinect v1 style): depth quantised in disparity (steps grow with z²),
    /// σ ≈ 1.5 mm at 0.6 m, missing depth at silhouette edges, on steep and on dark surfaces.
    #[default]
    Kinect,
    /// Active stereo (RealSense style): RMS ≈ 0.5 % of z, speckle holes.
    Realsense,
}

/// Everything that decides a synthetic session.
#[derive(Debug, Clone)]
pub struct SynthConfig {
    pub seed: u64,
    pub fps: f64,
    /// Length of the session; the iterator ends after `round(seconds * fps)` frames.
    pub seconds: f64,
    /// The colour camera. Default: 640x480, fx = fy = 525, cx = 319.5, cy = 239.5, and its
    /// `distortion` applied when non-zero.
    pub camera: Intrinsics,
    /// `None`: depth on the colour pixel grid (registered). `Some`: a separate depth camera
    /// with these intrinsics, placed by `depth_to_color`.
    pub depth_camera: Option<(Intrinsics, Extrinsics)>,
    /// Camera to the mouth (neutral), metres.
    pub distance_m: f64,
    pub head_motion: HeadMotion,
    pub noise: NoiseModel,
    /// Colour effects: sensor noise, exposure drift, motion blur on fast lip motion, uneven
    /// light. On by default; tests of pure geometry turn them off.
    pub colour_effects: bool,
    /// Still, closed, relaxed mouth at the start (the neutral pose), seconds.
    pub neutral_seconds: f64,
    pub layout: DotLayout,
    /// Where the jaw hinges and how it slides (default: the head's own hinge, no slide).
    pub jaw: JawOptions,
}

/// The synthetic jaw's hinge and slide (`--hinge`, `--jaw-slide`; docs/synth.md). The default,
/// all zero, is the head's own hinge ([`HINGE`]: 25 mm above and 80 mm behind the mouth
/// centre) and a jaw that only turns.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct JawOptions {
    /// The hinge moved back (> 0, further behind the mouth; < 0 forward), as a fraction of its
    /// default distance behind the mouth centre: 0.25 puts it 100 mm behind.
    pub hinge_back: f64,
    /// The hinge moved down (> 0; < 0 up), as a fraction of its default height above the mouth
    /// centre: 0.25 puts it 18.75 mm above.
    pub hinge_down: f64,
    /// Slide amplitude, metres: sideways within ± it (a smooth seeded motion), and forward by
    /// it at the widest speech opening (0.24 rad; none below 0.06 rad).
    pub slide_m: f64,
}

/// Largest move of the hinge, as a fraction of its default distance along each axis.
pub const MAX_HINGE_MOVE: f64 = 0.5;
/// Largest jaw slide amplitude, metres.
pub const MAX_JAW_SLIDE_M: f64 = 0.005;

impl JawOptions {
    /// The hinge moves are within ±[`MAX_HINGE_MOVE`]; the error names the axis (`back`,
    /// `down`).
    pub fn validate_hinge(&self) -> Result<(), JawError> {
        for (axis, v) in [("back", self.hinge_back), ("down", self.hinge_down)] {
            if !(v.is_finite() && v.abs() <= MAX_HINGE_MOVE) {
                return Err(JawError::Hinge { axis, value: v });
            }
        }
        Ok(())
    }

    /// The slide amplitude is from 0 to [`MAX_JAW_SLIDE_M`].
    pub fn validate_slide(&self) -> Result<(), JawError> {
        let v = self.slide_m;
        if !(v.is_finite() && (0.0..=MAX_JAW_SLIDE_M).contains(&v)) {
            return Err(JawError::Slide { value: v });
        }
        Ok(())
    }

    /// The hinge axis's (y, z) in the head frame (y down, z into the head; metres).
    pub fn hinge(&self) -> [f64; 2] {
        [
            HINGE[0] * (1.0 - self.hinge_down),
            HINGE[1] * (1.0 + self.hinge_back),
        ]
    }
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            seed: 1,
            fps: 30.0,
            seconds: 10.0,
            camera: Intrinsics::default_vga(),
            depth_camera: None,
            distance_m: 0.6,
            head_motion: HeadMotion::Mild,
            noise: NoiseModel::Kinect,
            colour_effects: true,
            neutral_seconds: 1.5,
            layout: DotLayout::default(),
            jaw: JawOptions::default(),
        }
    }
}

impl SynthConfig {
    /// The camera for an image size, with the default focal length (525 px at 640 wide, scaled)
    /// and the principal point at the centre.
    pub fn camera_for_size(width: u32, height: u32) -> Intrinsics {
        let f = 525.0 * width as f64 / 640.0;
        Intrinsics::ideal(
            width,
            height,
            f,
            f,
            (width as f64 - 1.0) / 2.0,
            (height as f64 - 1.0) / 2.0,
        )
    }

    pub fn validate(&self) -> Result<(), SynthError> {
        let bad = |what: String| Err(SynthError::Config(what));
        // A frame rate near 0 gave an empty session that looked like success; seconds in
        // the billions made the speech track plan syllables without end.
        if !(MIN_FPS..=MAX_FPS).contains(&self.fps) {
            return bad(format!(
                "fps must be from {MIN_FPS} to {MAX_FPS}, got {}",
                self.fps
            ));
        }
        if !(0.0..=MAX_SECONDS).contains(&self.seconds) {
            return bad(format!(
                "seconds must be from 0 to {MAX_SECONDS} (a day), got {}",
                self.seconds
            ));
        }
        if !self
            .camera
            .distortion
            .iter()
            .all(|k| k.is_finite() && k.abs() <= 10.0)
        {
            return bad(format!(
                "lens distortion coefficients must be finite and within ±10, got {:?}",
                self.camera.distortion
            ));
        }
        if !(0.25..=3.0).contains(&self.distance_m) {
            return bad(format!(
                "distance must be within 0.25–3 m, got {} m",
                self.distance_m
            ));
        }
        let c = &self.camera;
        if c.width < 16 || c.height < 16 || c.width > 8192 || c.height > 8192 {
            return bad(format!(
                "image size {}x{} is out of range (16–8192)",
                c.width, c.height
            ));
        }
        if !(c.fx > 0.0 && c.fy > 0.0) {
            return bad("focal lengths must be positive".into());
        }
        if let Some((d, _)) = &self.depth_camera {
            if d.width < 16
                || d.height < 16
                || d.width > 8192
                || d.height > 8192
                || d.fx <= 0.0
                || d.fy <= 0.0
            {
                return bad("depth camera intrinsics out of range".into());
            }
        }
        self.jaw.validate_hinge()?;
        self.jaw.validate_slide()?;
        Ok(self.layout.validate()?)
    }

    /// Renders depth from a separate depth camera `mm` millimetres to the colour camera's
    /// right (a baseline along x, no lens distortion) instead of registered to the colour
    /// grid.
    pub fn set_depth_baseline_mm(&mut self, mm: f64) -> Result<(), SynthError> {
        if !(mm.is_finite() && mm.abs() <= MAX_DEPTH_BASELINE_MM) {
            return Err(SynthError::DepthBaseline { mm });
        }
        let mut depth_to_color = Extrinsics::IDENTITY;
        // The depth camera sits `mm` to the colour camera's right: a point at its origin is
        // at +x in the colour frame.
        depth_to_color.translation = [mm / 1000.0, 0.0, 0.0];
        let mut depth = self.camera;
        depth.distortion = [0.0; 5];
        self.depth_camera = Some((depth, depth_to_color));
        Ok(())
    }

    /// The calibration frames carry.
    pub fn calibration(&self) -> Calibration {
        match &self.depth_camera {
            None => Calibration::registered(self.camera),
            Some((depth, depth_to_color)) => Calibration {
                color: self.camera,
                depth: *depth,
                depth_to_color: *depth_to_color,
                depth_scale_m: 0.001,
                depth_registered: false,
            },
        }
    }
}

/// Slowest frame rate of a synthetic session.
pub const MIN_FPS: f64 = 1.0;
/// Fastest frame rate of a synthetic session.
pub const MAX_FPS: f64 = 1000.0;
/// Largest baseline of a separate depth camera, millimetres.
pub const MAX_DEPTH_BASELINE_MM: f64 = 200.0;
/// Longest synthetic session, seconds (a day).
pub const MAX_SECONDS: f64 = 86_400.0;

/// A jaw option out of the synthetic performer's range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum JawError {
    #[error("the hinge's move {axis} must be within ±{} %, got {} %", 100.0 * MAX_HINGE_MOVE, 100.0 * .value)]
    Hinge { axis: &'static str, value: f64 },
    #[error("the jaw's slide must be from 0 to {} mm, got {} mm", 1e3 * MAX_JAW_SLIDE_M, 1e3 * .value)]
    Slide { value: f64 },
}

/// What can go wrong setting up the synthetic performer.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("invalid synthetic performer configuration: {0}")]
    Config(String),
    #[error("invalid synthetic performer configuration: {0}")]
    Jaw(#[from] JawError),
    #[error("--depth-baseline-mm must be within ±{MAX_DEPTH_BASELINE_MM}, got {mm}")]
    DepthBaseline { mm: f64 },
    #[error("cannot read dot layout {path}")]
    LayoutRead {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("dot layout {path} is invalid")]
    LayoutParse {
        path: PathBuf,
        #[source]
        source: Box<toml::de::Error>,
    },
    #[error("dot layout {path}: {problem}")]
    LayoutInvalid { path: PathBuf, problem: LayoutError },
    #[error("invalid synthetic performer configuration: {0}")]
    Layout(#[from] LayoutError),
}

/// The synthetic performer: an iterator of frames with their ground truth.
pub struct Synth {
    config: SynthConfig,
    calibration: Arc<Calibration>,
    renderer: render::Renderer,
    speech: motion::SpeechTrack,
    head: motion::HeadTrack,
    slide: motion::SlideTrack,
    next_index: u64,
    frame_count: u64,
}

impl Synth {
    pub fn new(config: SynthConfig) -> Result<Self, SynthError> {
        config.validate()?;
        let frame_count = (config.seconds * config.fps).round() as u64;
        let speech = motion::SpeechTrack::new(config.seed, config.neutral_seconds, config.seconds);
        let head = motion::HeadTrack::new(config.seed, config.head_motion, config.neutral_seconds);
        let slide =
            motion::SlideTrack::new(config.seed, config.jaw.slide_m, config.neutral_seconds);
        let renderer = render::Renderer::new(&config);
        tracing::info!(
            seed = config.seed,
            frames = frame_count,
            width = config.camera.width,
            height = config.camera.height,
            "synthetic performer ready"
        );
        Ok(Self {
            calibration: Arc::new(config.calibration()),
            config,
            renderer,
            speech,
            head,
            slide,
            next_index: 0,
            frame_count,
        })
    }

    pub fn config(&self) -> &SynthConfig {
        &self.config
    }

    /// Frames the iterator yields in total.
    pub fn frame_count(&self) -> u64 {
        self.frame_count
    }

    /// Dot names in order (`D1..Dn`, then the forehead dots).
    pub fn dot_names(&self) -> Vec<String> {
        self.renderer.dot_names()
    }

    /// The mouth and head at time `t` (what frame `t * fps` shows).
    pub fn state_at(&self, t: f64) -> (MouthState, HeadState) {
        (self.speech.at(t), self.head.at(t))
    }

    /// The jaw's hinge and slide at time `t` for the mouth `mouth` shows then.
    fn jaw_at(&self, t: f64, mouth: &MouthState) -> head::JawPose {
        head::JawPose {
            hinge: self.config.jaw.hinge(),
            slide: self.slide.at(t, mouth.jaw),
        }
    }

    /// Drives the mouth from keyed states instead of the seed's speech (a lip-sync take);
    /// keys must be in time order. Between keys the mouth eases as it does between the seed's.
    pub fn set_speech(&mut self, keys: Vec<(f64, MouthState)>) {
        self.speech = motion::SpeechTrack::from_keys(keys);
    }

    /// Renders the next frame. Deterministic: frame `i` of a seed is always the same.
    pub fn render_next(&mut self) -> Option<(Frame, GroundTruth)> {
        if self.next_index >= self.frame_count {
            return None;
        }
        let i = self.next_index;
        self.next_index += 1;
        let t = i as f64 / self.config.fps;
        let (mouth, head) = self.state_at(t);
        let jaw = self.jaw_at(t, &mouth);
        let out = self.renderer.render(i, t, &mouth, &head, &jaw);
        let frame = Frame {
            seq: i,
            device_ts_us: (t * 1e6).round() as u64,
            host_rx: Instant::now(),
            wall_clock: None,
            color: out.color,
            depth: out.depth,
            calibration: self.calibration.clone(),
        };
        tracing::trace!(seq = i, "synthetic frame rendered");
        Some((frame, out.ground_truth))
    }
}

impl Iterator for Synth {
    type Item = (Frame, GroundTruth);
    fn next(&mut self) -> Option<Self::Item> {
        self.render_next()
    }
}
