//! Frame sources: everything that hands the pipeline depth + colour pairs.
//!
//! One entry point, [`open_source`], takes a spec (`replay:PATH[?loop=1&speed=1.0&start=S]`,
//! `openni2:[URI]`, `v4l2:COLOUR_NODE[+DEPTH_NODE]`; see `docs/capture.md`) and returns a
//! boxed [`FrameSource`]. Every source delivers BGR8 colour, millimetre depth on the colour
//! grid when registered, a gap-free sequence number, the device timestamp, the host receive
//! time and the calibration; live sources hand out the newest pair and count what they skip.
//!
//! # Layout
//! - [`spec`]: spec parsing.
//! - [`convert`]: pixel format conversions (YUYV/UYVY, RGB, MJPG, Z16 units).
//! - [`registration`]: software depth→colour registration (re-exported from `mouthpiece_frame`).
//! - [`pace`]: replay pacing (recorded speed × `speed=`, clock jumps not waited out).
//! - `openni`: OpenNI2 cameras and `.oni` replay and recording (feature `openni2`), on top
//!   of the safe `mouthpiece-openni2` layer.
//! - `oni_write`: frames to `.oni` without a device (the synthetic performer), through the
//!   plain-Rust writer of `mouthpiece-openni2` (feature `openni2`).
//! - `v4l2`: V4L2 cameras (feature `v4l2`).
//! - `mcap_replay`: MCAP session replay through the recording crate (feature `mcap`);
//!   `mcap_audio`: its sound (`/audio`) as an `AudioSource`, paced with its frames.
//! - [`record`]: `mouthpiece record` (any source to MCAP; OpenNI2 sources to `.oni`).
//! - `devices`: what `mouthpiece devices` lists.
//! - `alsa`: the microphone through ALSA, an [`mouthpiece_frame::AudioSource`] (feature `alsa`).
//!
//! This crate has no `unsafe`: all native calls live in `mouthpiece-openni2` and `v4l`.

#![forbid(unsafe_code)]
// Helpers shared by the backends go unused when a backend feature is off.
#![cfg_attr(
    not(all(
        feature = "openni2",
        feature = "v4l2",
        feature = "mcap",
        feature = "alsa"
    )),
    allow(dead_code)
)]

#[cfg(feature = "alsa")]
pub mod alsa;
pub mod convert;
pub mod devices;
pub mod pace;
/// Software depth→colour registration: the one implementation, in `mouthpiece_frame`.
pub use mouthpiece_frame::registration;
pub mod spec;

#[cfg(feature = "mcap")]
pub mod mcap_audio;
#[cfg(feature = "mcap")]
pub mod mcap_replay;
#[cfg(feature = "openni2")]
pub mod oni_write;
#[cfg(feature = "openni2")]
pub mod openni;
pub mod record;
#[cfg(feature = "mcap")]
pub mod record_audio;
#[cfg(all(feature = "mcap", feature = "alsa"))]
pub mod record_job;
#[cfg(feature = "mcap")]
pub mod session_file;
#[cfg(feature = "v4l2")]
pub mod v4l2;

mod pairing;

use std::path::Path;
use std::time::Duration;

use mouthpiece_frame::{Extrinsics, Intrinsics};
pub use mouthpiece_frame::{Frame, FrameSource, SourceError, SourceInfo};
pub use spec::{ReplaySpec, SourceSpec, SpecError};

/// What a source should ask the device for, and what the device cannot tell us.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureConfig {
    /// Preferred colour (and depth) resolution; the closest mode is taken. Default 640x480.
    pub width: u32,
    pub height: u32,
    /// Preferred frame rate. Default 30.
    pub fps: u32,
    /// Colour intrinsics; overrides the device's (OpenNI2: from its field of view). V4L2
    /// devices report none: without this a 58°x45° field of view is assumed, with a warning.
    pub color_intrinsics: Option<Intrinsics>,
    /// Depth intrinsics (unregistered depth only).
    pub depth_intrinsics: Option<Intrinsics>,
    /// Depth camera → colour camera (unregistered depth only). Default identity.
    pub depth_to_color: Option<Extrinsics>,
    /// Metres per unit of V4L2 Z16 depth (RealSense D4xx default: 0.001). Depth is delivered
    /// in millimetres whatever this is.
    pub depth_units_m: f64,
    /// V4L2 buffers per node (2–4).
    pub v4l2_buffers: u32,
    /// Largest depth/colour timestamp difference that still makes a pair; default half a
    /// frame period.
    pub pair_tolerance: Option<Duration>,
    /// A live source that delivers nothing for this long is reported lost.
    pub stall_timeout: Duration,
}

impl Default for CaptureConfig {
    fn default() -> Self {
        CaptureConfig {
            width: 640,
            height: 480,
            fps: 30,
            color_intrinsics: None,
            depth_intrinsics: None,
            depth_to_color: None,
            depth_units_m: 0.001,
            v4l2_buffers: 3,
            pair_tolerance: None,
            stall_timeout: Duration::from_secs(2),
        }
    }
}

/// A capture setting out of range; the message names the field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CaptureConfigError {
    #[error("v4l2_buffers = {0}: expected 2 to 4")]
    Buffers(u32),
    #[error("depth_units_m = {0}: expected a positive number of metres")]
    DepthUnits(f64),
    #[error("width/height/fps = {width}x{height}@{fps}: expected positive values")]
    Mode { width: u32, height: u32, fps: u32 },
    #[error("stall_timeout: expected more than 0 s")]
    StallTimeout,
}

impl CaptureConfig {
    /// Checks the values a user can get wrong; the message names the field.
    pub fn validate(&self) -> Result<(), CaptureConfigError> {
        use CaptureConfigError as E;
        if !(2..=4).contains(&self.v4l2_buffers) {
            return Err(E::Buffers(self.v4l2_buffers));
        }
        if !(self.depth_units_m > 0.0 && self.depth_units_m.is_finite()) {
            return Err(E::DepthUnits(self.depth_units_m));
        }
        if self.width == 0 || self.height == 0 || self.fps == 0 {
            return Err(E::Mode {
                width: self.width,
                height: self.height,
                fps: self.fps,
            });
        }
        if self.stall_timeout.is_zero() {
            return Err(E::StallTimeout);
        }
        Ok(())
    }

    fn tolerance_us(&self, fps: f64) -> u64 {
        match self.pair_tolerance {
            Some(t) => t.as_micros() as u64,
            None if fps > 0.0 => (1e6 / fps / 2.0) as u64,
            None => 16_667,
        }
    }
}

/// Field of view assumed when neither the device nor the configuration gives one
/// (PrimeSense/Kinect v1 depth camera: 58° x 45°), radians.
pub(crate) const DEFAULT_FOV_RAD: (f64, f64) = (
    58.0 * std::f64::consts::PI / 180.0,
    45.0 * std::f64::consts::PI / 180.0,
);

pub(crate) fn open_error(spec: &str, message: impl Into<String>) -> SourceError {
    SourceError::Open {
        spec: spec.to_string(),
        message: message.into(),
        cause: None,
    }
}

pub(crate) fn open_error_with(
    spec: &str,
    message: impl Into<String>,
    cause: impl std::error::Error + Send + Sync + 'static,
) -> SourceError {
    SourceError::Open {
        spec: spec.to_string(),
        message: message.into(),
        cause: Some(Box::new(cause)),
    }
}

pub(crate) fn format_error(spec: &str, message: impl Into<String>) -> SourceError {
    SourceError::Format {
        spec: spec.to_string(),
        message: message.into(),
        cause: None,
    }
}

pub(crate) fn lost_error(
    spec: &str,
    message: impl Into<String>,
    cause: Option<Box<dyn std::error::Error + Send + Sync>>,
) -> SourceError {
    SourceError::Disconnected {
        spec: spec.to_string(),
        message: message.into(),
        cause,
    }
}

/// Opens the source a spec names.
pub fn open_source(
    spec: &str,
    config: &CaptureConfig,
) -> Result<Box<dyn FrameSource>, SourceError> {
    let parsed = SourceSpec::parse(spec).map_err(|e| SourceError::Open {
        spec: spec.to_string(),
        message: e.reason.clone(),
        cause: Some(Box::new(e)),
    })?;
    open_parsed(&parsed, config)
}

/// Opens an already parsed spec.
pub fn open_parsed(
    spec: &SourceSpec,
    config: &CaptureConfig,
) -> Result<Box<dyn FrameSource>, SourceError> {
    let text = spec.to_string();
    config
        .validate()
        .map_err(|m| open_error(&text, format!("bad capture configuration: {m}")))?;
    match spec {
        SourceSpec::Replay(replay) => open_replay(&text, replay, config),
        SourceSpec::OpenNi2 { .. } => {
            open_openni2(spec, config).map(|s| Box::new(s) as Box<dyn FrameSource>)
        }
        SourceSpec::V4l2 { color, depth } => open_v4l2(&text, color, depth.as_deref(), config),
    }
}

fn open_replay(
    text: &str,
    replay: &ReplaySpec,
    config: &CaptureConfig,
) -> Result<Box<dyn FrameSource>, SourceError> {
    if !replay.path.exists() {
        return Err(open_error(
            text,
            format!("no such file: {}", replay.path.display()),
        ));
    }
    if replay.path.is_dir() {
        return Err(open_error(
            text,
            format!("{} is a directory, not a recording", replay.path.display()),
        ));
    }
    match replay
        .path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("oni") => open_oni_replay(text, replay, config),
        Some("mcap") => open_mcap_replay(text, replay, config),
        _ => Err(open_error(
            text,
            format!(
                "cannot tell the format of {}: expected a .mcap or .oni file",
                replay.path.display()
            ),
        )),
    }
}

#[cfg(feature = "mcap")]
fn open_mcap_replay(
    text: &str,
    replay: &ReplaySpec,
    config: &CaptureConfig,
) -> Result<Box<dyn FrameSource>, SourceError> {
    let _ = text;
    mcap_replay::McapReplay::open(replay, config).map(|s| Box::new(s) as Box<dyn FrameSource>)
}

#[cfg(not(feature = "mcap"))]
fn open_mcap_replay(
    text: &str,
    _: &ReplaySpec,
    _: &CaptureConfig,
) -> Result<Box<dyn FrameSource>, SourceError> {
    Err(open_error(
        text,
        "MCAP replay needs the mcap feature, which this build lacks",
    ))
}

#[cfg(feature = "openni2")]
fn open_oni_replay(
    text: &str,
    replay: &ReplaySpec,
    config: &CaptureConfig,
) -> Result<Box<dyn FrameSource>, SourceError> {
    let _ = text;
    openni::OpenNiSource::open_file(replay, config).map(|s| Box::new(s) as Box<dyn FrameSource>)
}

#[cfg(not(feature = "openni2"))]
fn open_oni_replay(
    text: &str,
    _: &ReplaySpec,
    _: &CaptureConfig,
) -> Result<Box<dyn FrameSource>, SourceError> {
    Err(open_error(
        text,
        ".oni replay needs the openni2 feature, which this build lacks",
    ))
}

/// Opens an OpenNI2 source (camera, `Dummy`, or an `.oni` replay) as its concrete type, for
/// callers that need more than [`FrameSource`] (`.oni` recording, seeking).
#[cfg(feature = "openni2")]
pub fn open_openni2(
    spec: &SourceSpec,
    config: &CaptureConfig,
) -> Result<openni::OpenNiSource, SourceError> {
    match spec {
        SourceSpec::OpenNi2 { uri } => openni::OpenNiSource::open_device(uri.as_deref(), config),
        SourceSpec::Replay(r)
            if r.path
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("oni")) =>
        {
            openni::OpenNiSource::open_file(r, config)
        }
        other => Err(open_error(
            &other.to_string(),
            "not an OpenNI2 source (openni2:… or replay:….oni)",
        )),
    }
}

#[cfg(not(feature = "openni2"))]
fn open_openni2(spec: &SourceSpec, _: &CaptureConfig) -> Result<Box<dyn FrameSource>, SourceError> {
    Err(open_error(
        &spec.to_string(),
        "OpenNI2 support is not built in (feature openni2)",
    ))
}

#[cfg(feature = "v4l2")]
fn open_v4l2(
    text: &str,
    color: &Path,
    depth: Option<&Path>,
    config: &CaptureConfig,
) -> Result<Box<dyn FrameSource>, SourceError> {
    v4l2::V4l2Source::open(text, color, depth, config).map(|s| Box::new(s) as Box<dyn FrameSource>)
}

#[cfg(not(feature = "v4l2"))]
fn open_v4l2(
    text: &str,
    _: &Path,
    _: Option<&Path>,
    _: &CaptureConfig,
) -> Result<Box<dyn FrameSource>, SourceError> {
    Err(open_error(
        text,
        "V4L2 support is not built in (feature v4l2)",
    ))
}
