//! Frame types and the [`FrameSource`] trait.
//!
//! Every stage of mouthpiece speaks in these types: a capture backend (replay, OpenNI2,
//! V4L2, the synthetic performer) produces [`Frame`]s; detection and tracking consume them;
//! recordings store them. Keeping them in a crate of their own lets the recording format,
//! the capture backends and the detector depend on the same definitions without depending
//! on each other.
//!
//! Conventions (see `docs/method.md` §10):
//! - colour is BGR8, row-major, tightly packed (`width * 3` bytes a row), OpenCV's order;
//! - depth is `u16` in device units (`Calibration::depth_scale_m` metres each; 1 mm by
//!   default), 0 = no reading, row-major;
//! - the camera frame is OpenCV's: x right, y down, z forward, metres.

use std::sync::Arc;
use std::time::{Instant, SystemTime};

use serde::{Deserialize, Serialize};

pub mod audio;
pub mod audio_bus;
pub mod registration;

pub use audio::{AudioBlock, AudioFormat, AudioSource, AudioSourceInfo};
pub use audio_bus::{AudioBus, AudioEvent, AudioSubscription};

/// Pinhole intrinsics of one camera, plus lens distortion in OpenCV's `plumb_bob` order.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// `[k1, k2, p1, p2, k3]` (OpenCV / ROS `plumb_bob`); all zero for an ideal lens.
    pub distortion: [f64; 5],
}

impl Intrinsics {
    /// The synthetic performer's and the documentation's default camera: 640x480,
    /// fx = fy = 525, principal point at the image centre, no distortion.
    pub fn default_vga() -> Self {
        Self::ideal(640, 480, 525.0, 525.0, 319.5, 239.5)
    }

    /// A distortion-free camera.
    pub fn ideal(width: u32, height: u32, fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Self {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            distortion: [0.0; 5],
        }
    }

    /// Intrinsics from horizontal and vertical fields of view (radians), as OpenNI2 devices
    /// report them; principal point at the image centre.
    pub fn from_fov(width: u32, height: u32, hfov: f64, vfov: f64) -> Self {
        let fx = width as f64 / 2.0 / (hfov / 2.0).tan();
        let fy = height as f64 / 2.0 / (vfov / 2.0).tan();
        Self::ideal(
            width,
            height,
            fx,
            fy,
            (width as f64 - 1.0) / 2.0,
            (height as f64 - 1.0) / 2.0,
        )
    }

    pub fn has_distortion(&self) -> bool {
        self.distortion.iter().any(|&k| k != 0.0)
    }

    /// Projects a camera-frame point (metres, z forward) to a pixel as the camera images it,
    /// lens distortion included (Brown–Conrady, OpenCV's `k1 k2 p1 p2 k3`). `None` behind the
    /// camera.
    pub fn project(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        if p[2] <= 0.0 {
            return None;
        }
        let (x, y) = (p[0] / p[2], p[1] / p[2]);
        let (x, y) = if self.has_distortion() {
            let [k1, k2, p1, p2, k3] = self.distortion;
            let r2 = x * x + y * y;
            let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
            (
                x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
            )
        } else {
            (x, y)
        };
        Some([self.fx * x + self.cx, self.fy * y + self.cy])
    }

    /// Removes lens distortion from a pixel: the normalised image coordinates `(x, y)` of the
    /// ray through it (`x = X/Z`, `y = Y/Z`). Fixed-point iteration as OpenCV's
    /// `undistortPoints` does it, run to convergence (the inverse of [`Self::project`]).
    pub fn undistort(&self, px: [f64; 2]) -> [f64; 2] {
        let x0 = (px[0] - self.cx) / self.fx;
        let y0 = (px[1] - self.cy) / self.fy;
        if !self.has_distortion() {
            return [x0, y0];
        }
        let [k1, k2, p1, p2, k3] = self.distortion;
        let (mut x, mut y) = (x0, y0);
        for _ in 0..50 {
            let r2 = x * x + y * y;
            let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
            let dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
            let dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
            let (nx, ny) = ((x0 - dx) / radial, (y0 - dy) / radial);
            let step = (nx - x).abs() + (ny - y).abs();
            x = nx;
            y = ny;
            if step < 1e-12 {
                break;
            }
        }
        [x, y]
    }

    /// The camera-frame point seen at pixel `px` (as in the image, distortion included) at
    /// depth `z` (metres along the optical axis).
    pub fn deproject(&self, px: [f64; 2], z: f64) -> [f64; 3] {
        let [x, y] = self.undistort(px);
        [x * z, y * z, z]
    }

    /// Projects a camera-frame point (metres, z forward) to pixel coordinates, ignoring
    /// distortion. `None` behind the camera.
    #[inline]
    pub fn project_ideal(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        if p[2] <= 0.0 {
            return None;
        }
        Some([
            self.fx * p[0] / p[2] + self.cx,
            self.fy * p[1] / p[2] + self.cy,
        ])
    }

    /// Back-projects an undistorted pixel at depth `z` (metres) into the camera frame.
    #[inline]
    pub fn deproject_ideal(&self, px: [f64; 2], z: f64) -> [f64; 3] {
        [
            (px[0] - self.cx) / self.fx * z,
            (px[1] - self.cy) / self.fy * z,
            z,
        ]
    }
}

/// A rigid transform: `p_to = rotation * p_from + translation` (metres).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Extrinsics {
    /// Row-major 3x3 rotation matrix.
    pub rotation: [[f64; 3]; 3],
    pub translation: [f64; 3],
}

impl Extrinsics {
    pub const IDENTITY: Extrinsics = Extrinsics {
        rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        translation: [0.0; 3],
    };

    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        let r = &self.rotation;
        let t = &self.translation;
        [
            r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2] + t[0],
            r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2] + t[1],
            r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2] + t[2],
        ]
    }

    pub fn is_identity(&self) -> bool {
        *self == Self::IDENTITY
    }
}

impl Default for Extrinsics {
    fn default() -> Self {
        Self::IDENTITY
    }
}

/// Everything needed to turn a frame's pixels and depths into 3D points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    /// The colour camera. Dots are found in its image; 3D points are in its frame.
    pub color: Intrinsics,
    /// The depth camera. Equal to `color` when `depth_registered`.
    pub depth: Intrinsics,
    /// Depth camera frame → colour camera frame.
    pub depth_to_color: Extrinsics,
    /// Metres per depth unit (0.001 for millimetre depth).
    pub depth_scale_m: f64,
    /// True when the depth image is already on the colour pixel grid (one depth value per
    /// colour pixel), as registered devices and the synthetic performer deliver it.
    pub depth_registered: bool,
}

impl Calibration {
    /// A registered RGB-D camera: depth on the colour grid, millimetre units.
    pub fn registered(color: Intrinsics) -> Self {
        Self {
            color,
            depth: color,
            depth_to_color: Extrinsics::IDENTITY,
            depth_scale_m: 0.001,
            depth_registered: true,
        }
    }
}

/// A BGR8 image, rows packed without padding.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ColorImage {
    pub width: u32,
    pub height: u32,
    /// `width * height * 3` bytes, B, G, R.
    pub data: Vec<u8>,
}

impl ColorImage {
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            data: vec![0; width as usize * height as usize * 3],
        }
    }

    pub fn pixel(&self, x: u32, y: u32) -> [u8; 3] {
        let i = (y as usize * self.width as usize + x as usize) * 3;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }
}

/// A depth image in device units (see [`Calibration::depth_scale_m`]), 0 = no reading.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DepthImage {
    pub width: u32,
    pub height: u32,
    /// `width * height` values, row-major.
    pub data: Vec<u16>,
}

impl DepthImage {
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            data: vec![0; width as usize * height as usize],
        }
    }

    pub fn at(&self, x: u32, y: u32) -> u16 {
        self.data[y as usize * self.width as usize + x as usize]
    }
}

/// One depth + colour pair, as a source delivers it.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Counts frames delivered by this source, from 0, without gaps (skipped frames are
    /// counted in [`FrameSource::skipped`], not here).
    pub seq: u64,
    /// The device's own timestamp of the colour image, microseconds (replay: as recorded).
    pub device_ts_us: u64,
    /// Host monotonic time at which the pair was received.
    pub host_rx: Instant,
    /// Wall-clock time of capture: live sources stamp it on receipt; replay gives the
    /// recorded one when the recording has it.
    pub wall_clock: Option<SystemTime>,
    pub color: ColorImage,
    pub depth: DepthImage,
    /// The calibration the frame was taken with; shared, it rarely changes.
    pub calibration: Arc<Calibration>,
}

/// What a source actually runs at (what the device agreed to, not what was asked for).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SourceInfo {
    /// The spec it was opened from, e.g. `replay:recordings/demo.mcap` or `openni2:Dummy`.
    pub spec: String,
    /// Human-readable device description (vendor and name, file name, …).
    pub description: String,
    pub color_width: u32,
    pub color_height: u32,
    pub depth_width: u32,
    pub depth_height: u32,
    /// Nominal frames per second; 0.0 when unknown.
    pub fps: f64,
    /// True for cameras: `next_frame` returns the newest pair and skips stale ones.
    pub live: bool,
}

/// Why a source could not deliver a frame.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// The source could not be opened (missing file, no such device, busy device, …).
    #[error("cannot open source {spec}: {message}")]
    Open {
        spec: String,
        message: String,
        #[source]
        cause: Option<Box<dyn std::error::Error + Send + Sync>>,
    },
    /// The device went away mid-stream (unplugged, driver error). Reopen to retry.
    #[error("source {spec} was lost: {message}")]
    Disconnected {
        spec: String,
        message: String,
        #[source]
        cause: Option<Box<dyn std::error::Error + Send + Sync>>,
    },
    /// The data could not be decoded (corrupt file, unsupported pixel format, …).
    #[error("source {spec}: bad data: {message}")]
    Format {
        spec: String,
        message: String,
        #[source]
        cause: Option<Box<dyn std::error::Error + Send + Sync>>,
    },
}

impl SourceError {
    /// True when reopening the source later may succeed (a live device that went away).
    pub fn is_retryable(&self) -> bool {
        matches!(
            self,
            SourceError::Disconnected { .. } | SourceError::Open { .. }
        )
    }
}

/// A producer of depth + colour frame pairs.
///
/// Blocking by design: capture runs on a thread of its own and the native libraries
/// (OpenNI2, V4L2) are blocking. `next_frame` returns `Ok(None)` at the end of a finite
/// source (a replay that does not loop). Live sources return the newest pair and count the
/// stale ones they dropped in [`FrameSource::skipped`].
pub trait FrameSource: Send {
    /// What the source actually runs at.
    fn info(&self) -> &SourceInfo;

    /// The next frame pair, waiting for it if necessary.
    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError>;

    /// How many frames were dropped because a newer one was already there.
    fn skipped(&self) -> u64 {
        0
    }
}

impl<S: FrameSource + ?Sized> FrameSource for Box<S> {
    fn info(&self) -> &SourceInfo {
        (**self).info()
    }
    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        (**self).next_frame()
    }
    fn skipped(&self) -> u64 {
        (**self).skipped()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn project_then_deproject_round_trips() {
        let k = Intrinsics::default_vga();
        let p = [0.03, -0.02, 0.6];
        let px = k.project_ideal(p).unwrap();
        let q = k.deproject_ideal(px, p[2]);
        for i in 0..3 {
            assert!((p[i] - q[i]).abs() < 1e-12, "{p:?} vs {q:?}");
        }
    }

    #[test]
    fn fov_gives_the_expected_focal_length() {
        // 90° horizontal field of view over 640 px: fx = 320.
        let k = Intrinsics::from_fov(640, 480, std::f64::consts::FRAC_PI_2, 1.0);
        assert!((k.fx - 320.0).abs() < 1e-9);
    }

    #[test]
    fn extrinsics_apply_rotation_then_translation() {
        let e = Extrinsics {
            rotation: [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [0.1, 0.0, 0.0],
        };
        assert_eq!(e.apply([1.0, 0.0, 0.0]), [0.1, 1.0, 0.0]);
    }
}
