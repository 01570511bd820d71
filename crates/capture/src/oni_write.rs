//! Frames → `.oni`, through mouthpiece-openni2's plain-Rust writer (no device, no OpenNI
//! calls): how `mouthpiece synth --out FILE.oni` writes a synthetic session.
//!
//! An `.oni` holds per stream an image size, a frame rate and a field of view, nothing more.
//! OpenNI2's player (and so `replay:FILE.oni`) gives back intrinsics from the field of view
//! with the principal point at the image centre, no lens distortion, and no depth→colour
//! transform. So only frames whose calibration is exactly that can be written: a registered
//! camera (depth on the colour grid, same size), no distortion, principal point at
//! ((w−1)/2, (h−1)/2), millimetre depth. Anything else is refused rather than silently lost.
//! Ground truth, wall-clock times and sequence numbers are not stored either (replay numbers
//! frames from 0 again; device timestamps are kept to the microsecond).

use std::path::{Path, PathBuf};

use mouthpiece_frame::{Calibration, Frame};
use openni2::oni_file::OniFileError;
use openni2::oni_writer::{OniStreamSpec, OniWriteSummary, OniWriter};

/// Why frames cannot be written to an `.oni`.
#[derive(Debug, thiserror::Error)]
pub enum OniWriteError {
    /// The calibration holds something an `.oni` cannot (bad input: write MCAP instead).
    #[error("{path}: an .oni recording cannot hold {what}; write a .mcap session instead")]
    Unsupported { path: PathBuf, what: String },
    /// A frame does not fit the recording's streams.
    #[error("{path}: frame {seq}: {reason}")]
    Frame {
        path: PathBuf,
        seq: u64,
        reason: String,
    },
    #[error(transparent)]
    File(#[from] OniFileError),
}

impl OniWriteError {
    /// The caller's request, not the machine, is at fault.
    pub fn is_bad_input(&self) -> bool {
        matches!(self, Self::Unsupported { .. } | Self::Frame { .. })
    }
}

/// Writes [`Frame`]s to a depth + RGB888 `.oni`.
pub struct OniFrameWriter {
    path: PathBuf,
    writer: OniWriter,
    calibration: Calibration,
    rgb: Vec<u8>,
}

/// Horizontal and vertical field of view (radians) of a pinhole camera.
fn fov(k: &mouthpiece_frame::Intrinsics) -> (f64, f64) {
    (
        2.0 * (k.width as f64 / 2.0 / k.fx).atan(),
        2.0 * (k.height as f64 / 2.0 / k.fy).atan(),
    )
}

/// What of `c` an `.oni` cannot hold, if anything.
fn unsupported(c: &Calibration) -> Option<String> {
    let k = &c.color;
    if !c.depth_registered || !c.depth_to_color.is_identity() || c.depth != c.color {
        return Some("depth that is not registered to the colour grid (a depth baseline)".into());
    }
    if k.has_distortion() {
        return Some(format!("lens distortion {:?}", k.distortion));
    }
    if (c.depth_scale_m - 0.001).abs() > 1e-12 {
        return Some(format!(
            "depth units of {} m (only millimetres)",
            c.depth_scale_m
        ));
    }
    let (cx, cy) = ((k.width as f64 - 1.0) / 2.0, (k.height as f64 - 1.0) / 2.0);
    if (k.cx - cx).abs() > 1e-9 || (k.cy - cy).abs() > 1e-9 {
        return Some(format!(
            "a principal point ({}, {}) off the image centre ({cx}, {cy})",
            k.cx, k.cy
        ));
    }
    None
}

impl OniFrameWriter {
    /// Creates `path` for frames taken with `calibration` at `fps` frames a second.
    pub fn create(
        path: &Path,
        calibration: &Calibration,
        fps: f64,
    ) -> Result<OniFrameWriter, OniWriteError> {
        if let Some(what) = unsupported(calibration) {
            return Err(OniWriteError::Unsupported {
                path: path.to_path_buf(),
                what,
            });
        }
        let k = &calibration.color;
        let (hfov, vfov) = fov(k);
        let spec = OniStreamSpec {
            width: k.width,
            height: k.height,
            fps: fps.round().max(1.0) as u32,
            hfov,
            vfov,
        };
        let writer = OniWriter::create(path, spec, spec)?;
        Ok(OniFrameWriter {
            path: path.to_path_buf(),
            writer,
            calibration: calibration.clone(),
            rgb: Vec::new(),
        })
    }

    /// Appends one pair: depth and colour under the frame's device timestamp.
    pub fn write_frame(&mut self, frame: &Frame) -> Result<(), OniWriteError> {
        let bad = |reason: String| OniWriteError::Frame {
            path: self.path.clone(),
            seq: frame.seq,
            reason,
        };
        if *frame.calibration != self.calibration {
            return Err(bad(
                "its calibration differs from the first frame's (an .oni holds one per stream)"
                    .into(),
            ));
        }
        let (w, h) = (self.calibration.color.width, self.calibration.color.height);
        if (frame.color.width, frame.color.height) != (w, h)
            || (frame.depth.width, frame.depth.height) != (w, h)
        {
            return Err(bad(format!(
                "colour {}x{} and depth {}x{}, the recording's streams are {w}x{h}",
                frame.color.width, frame.color.height, frame.depth.width, frame.depth.height
            )));
        }
        self.rgb.clear();
        self.rgb.extend(
            frame
                .color
                .data
                .chunks_exact(3)
                .flat_map(|bgr| [bgr[2], bgr[1], bgr[0]]),
        );
        self.writer
            .write_depth(frame.device_ts_us, &frame.depth.data)?;
        self.writer.write_color(frame.device_ts_us, &self.rgb)?;
        Ok(())
    }

    /// Closes the recording (trailing records, frame counts, seek tables).
    pub fn finish(self) -> Result<OniWriteSummary, OniWriteError> {
        Ok(self.writer.finish()?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mouthpiece_frame::{Extrinsics, Intrinsics};

    #[test]
    fn refuses_what_an_oni_cannot_hold() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.oni");
        let k = Intrinsics::ideal(64, 48, 50.0, 50.0, 31.5, 23.5);
        assert!(OniFrameWriter::create(&path, &Calibration::registered(k), 30.0).is_ok());

        let mut distorted = k;
        distorted.distortion[0] = 0.1;
        let mut off_centre = k;
        off_centre.cx = 30.0;
        let mut baseline = Calibration::registered(k);
        baseline.depth_registered = false;
        baseline.depth_to_color = Extrinsics {
            translation: [0.025, 0.0, 0.0],
            ..Extrinsics::IDENTITY
        };
        for (c, needle) in [
            (Calibration::registered(distorted), "lens distortion"),
            (Calibration::registered(off_centre), "principal point"),
            (baseline, "not registered"),
        ] {
            let err = OniFrameWriter::create(&path, &c, 30.0).err().unwrap();
            assert!(err.is_bad_input());
            assert!(err.to_string().contains(needle), "{err}");
        }
    }
}
