//! [`SessionReader`]: frames from the messages (colour and depth paired by device time),
//! with calibration and ground truth, seeking and looping; images decoded with their sizes
//! checked before anything is allocated.

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant, UNIX_EPOCH};

use mouthpiece_frame::{Calibration, ColorImage, DepthImage, Frame, Intrinsics};

use super::messages::{MessageReader, RawMessage};
use crate::cdr::{CameraCalibration, CompressedImage, RawImage};
use crate::{GroundTruth, RecordingError};

/// Largest colour or depth image decoded (4096 x 4096).
pub const MAX_IMAGE_PIXELS: u64 = 4096 * 4096;

/// One frame of a session, with what came with it.
#[derive(Debug, Clone)]
pub struct SessionFrame {
    pub frame: Frame,
    /// The frame's log time in the file (ns).
    pub log_time: u64,
    /// The `/groundtruth/points` message at the same log time, in synthetic sessions.
    pub ground_truth: Option<GroundTruth>,
}

struct Pending<T> {
    log_time: u64,
    device_ts_us: u64,
    value: T,
}

/// Frames of a session in order, with calibration and ground truth; can skip forward to a
/// time and loop. Tolerates truncated files (see the module docs).
pub struct SessionReader {
    messages: MessageReader,
    calibration: Option<Arc<Calibration>>,
    calibration_from_metadata: bool,
    metadata_seen: usize,
    wall_clock_log_time: bool,
    color: Option<Pending<ColorImage>>,
    depth: Option<Pending<DepthImage>>,
    ground_truth: Option<(u64, GroundTruth)>,
    seq: u64,
    looping: bool,
    /// Added to device timestamps so they keep increasing across loops.
    loop_offset_us: u64,
    pass_first_ts_us: Option<u64>,
    pass_last_ts_us: Option<u64>,
    pass_frames: u64,
    first_log_time: Option<u64>,
    skip_until_log_time: Option<u64>,
    unpaired_warned: bool,
}

impl SessionReader {
    pub fn open(path: impl AsRef<Path>) -> Result<Self, RecordingError> {
        let messages = MessageReader::open(path)?;
        tracing::info!(path = %messages.path().display(), "replaying session");
        Ok(Self {
            messages,
            calibration: None,
            calibration_from_metadata: false,
            metadata_seen: 0,
            wall_clock_log_time: false,
            color: None,
            depth: None,
            ground_truth: None,
            seq: 0,
            looping: false,
            loop_offset_us: 0,
            pass_first_ts_us: None,
            pass_last_ts_us: None,
            pass_frames: 0,
            first_log_time: None,
            skip_until_log_time: None,
            unpaired_warned: false,
        })
    }

    pub fn path(&self) -> &Path {
        self.messages.path()
    }

    /// When on, the reader starts again at the end of the file; `seq` and device timestamps
    /// keep increasing.
    pub fn set_looping(&mut self, looping: bool) {
        self.looping = looping;
    }

    /// True when the last pass hit the cut of a truncated file.
    pub fn is_truncated(&self) -> bool {
        self.messages.is_truncated()
    }

    /// The calibration of the most recent frame (known after the first frame).
    pub fn calibration(&self) -> Option<&Arc<Calibration>> {
        self.calibration.as_ref()
    }

    /// Log time (ns) of the first frame of the file, once read.
    pub fn first_log_time(&self) -> Option<u64> {
        self.first_log_time
    }

    /// Goes back to the start of the file (frame numbering continues).
    pub fn rewind(&mut self) -> Result<(), RecordingError> {
        self.messages.rewind()?;
        self.color = None;
        self.depth = None;
        self.ground_truth = None;
        self.metadata_seen = 0;
        Ok(())
    }

    /// Positions the reader so that the next frame is the first one at or after `offset`
    /// from the session's first frame. Reads forward without decoding images (fast); going
    /// backwards rewinds first.
    pub fn seek(&mut self, offset: Duration) -> Result<(), RecordingError> {
        let first = match self.first_log_time {
            Some(t) => t,
            None => {
                // Find the first frame's time, then start over.
                self.rewind()?;
                let Some(f) = self.next_frame()? else {
                    return Ok(());
                };
                self.seq = self.seq.saturating_sub(1);
                f.log_time
            }
        };
        let target = first + offset.as_nanos() as u64;
        self.rewind()?;
        self.pass_frames = 0;
        self.pass_first_ts_us = None;
        self.pass_last_ts_us = None;
        self.skip_until_log_time = Some(target);
        Ok(())
    }

    /// The next frame, `Ok(None)` at the end of a non-looping session.
    pub fn next_frame(&mut self) -> Result<Option<SessionFrame>, RecordingError> {
        let mut empty_passes = 0;
        loop {
            let Some(msg) = self.messages.next_message()? else {
                if self.looping && empty_passes == 0 {
                    if self.pass_frames == 0 {
                        empty_passes += 1;
                    }
                    self.start_next_pass()?;
                    continue;
                }
                return Ok(None);
            };
            self.absorb_metadata()?;
            if let Some(target) = self.skip_until_log_time {
                // Calibration is state, not a frame: always taken.
                if &*msg.topic == crate::TOPIC_CALIBRATION {
                    self.handle(msg)?;
                    continue;
                }
                if msg.log_time < target {
                    continue;
                }
                self.skip_until_log_time = None;
            }
            if let Some(frame) = self.handle(msg)? {
                return Ok(Some(frame));
            }
        }
    }

    fn start_next_pass(&mut self) -> Result<(), RecordingError> {
        if let (Some(first), Some(last)) = (self.pass_first_ts_us, self.pass_last_ts_us) {
            let span = last.saturating_sub(first);
            let period = if self.pass_frames > 1 {
                span / (self.pass_frames - 1)
            } else {
                33_333
            };
            self.loop_offset_us += span + period;
        }
        self.pass_frames = 0;
        self.pass_first_ts_us = None;
        self.pass_last_ts_us = None;
        tracing::debug!(path = %self.path().display(), "looping");
        self.rewind()
    }

    fn absorb_metadata(&mut self) -> Result<(), RecordingError> {
        let all = self.messages.metadata();
        while self.metadata_seen < all.len() {
            let (name, map) = &all[self.metadata_seen];
            self.metadata_seen += 1;
            if name == crate::METADATA_SESSION {
                self.wall_clock_log_time =
                    map.get("log_time").map(String::as_str) == Some("wall_clock");
            } else if name == crate::METADATA_CALIBRATION {
                if let Some(json) = map.get("calibration") {
                    let cal: Calibration =
                        serde_json::from_str(json).map_err(|source| RecordingError::Metadata {
                            path: self.messages.path().display().to_string(),
                            name: name.clone(),
                            source,
                        })?;
                    self.calibration = Some(Arc::new(cal));
                    self.calibration_from_metadata = true;
                }
            }
        }
        Ok(())
    }

    fn decode_error(
        &self,
        msg: &RawMessage,
        what: impl Into<String>,
        source: Option<Box<dyn std::error::Error + Send + Sync>>,
    ) -> RecordingError {
        RecordingError::Decode {
            path: self.messages.path().display().to_string(),
            topic: msg.topic.to_string(),
            log_time: msg.log_time,
            what: what.into(),
            source,
        }
    }

    fn handle(&mut self, msg: RawMessage) -> Result<Option<SessionFrame>, RecordingError> {
        match &*msg.topic {
            // Files from other writers: no mouthpiece.calibration record, take the
            // Foxglove calibration as a registered camera in millimetres.
            crate::TOPIC_CALIBRATION if !self.calibration_from_metadata => {
                let c = CameraCalibration::decode(&msg.data).map_err(|e| {
                    self.decode_error(&msg, "bad CameraCalibration", Some(Box::new(e)))
                })?;
                let mut distortion = [0.0; 5];
                for (d, s) in distortion.iter_mut().zip(&c.d) {
                    *d = *s;
                }
                let k = Intrinsics {
                    width: c.width,
                    height: c.height,
                    fx: c.k[0],
                    fy: c.k[4],
                    cx: c.k[2],
                    cy: c.k[5],
                    distortion,
                };
                self.calibration = Some(Arc::new(Calibration::registered(k)));
            }
            crate::TOPIC_GROUND_TRUTH => {
                let gt: GroundTruth = serde_json::from_slice(&msg.data).map_err(|e| {
                    self.decode_error(&msg, "bad ground truth JSON", Some(Box::new(e)))
                })?;
                self.ground_truth = Some((msg.log_time, gt));
            }
            crate::TOPIC_COLOR => {
                let (ts, image) = self.decode_color(&msg)?;
                if self.color.is_some() {
                    self.warn_unpaired(msg.log_time);
                }
                self.color = Some(Pending {
                    log_time: msg.log_time,
                    device_ts_us: ts,
                    value: image,
                });
            }
            crate::TOPIC_DEPTH => {
                let (ts, image) = self.decode_depth(&msg)?;
                if self.depth.is_some() {
                    self.warn_unpaired(msg.log_time);
                }
                self.depth = Some(Pending {
                    log_time: msg.log_time,
                    device_ts_us: ts,
                    value: image,
                });
            }
            _ => {}
        }
        let paired =
            matches!((&self.color, &self.depth), (Some(c), Some(d)) if c.log_time == d.log_time);
        if !paired {
            return Ok(None);
        }
        let (Some(color), Some(depth)) = (self.color.take(), self.depth.take()) else {
            return Ok(None);
        };
        let Some(calibration) = self.calibration.clone() else {
            return Err(RecordingError::Decode {
                path: self.messages.path().display().to_string(),
                topic: crate::TOPIC_CALIBRATION.into(),
                log_time: color.log_time,
                what: "frame before any calibration".into(),
                source: None,
            });
        };
        for (what, (w, h), k) in [
            (
                "colour",
                (color.value.width, color.value.height),
                &calibration.color,
            ),
            (
                "depth",
                (depth.value.width, depth.value.height),
                &calibration.depth,
            ),
        ] {
            if (w, h) != (k.width, k.height) {
                return Err(RecordingError::Decode {
                    path: self.messages.path().display().to_string(),
                    topic: if what == "colour" {
                        crate::TOPIC_COLOR
                    } else {
                        crate::TOPIC_DEPTH
                    }
                    .into(),
                    log_time: color.log_time,
                    what: format!(
                        "{what} image is {w}x{h} but the calibration says {}x{}",
                        k.width, k.height
                    ),
                    source: None,
                });
            }
        }
        let ground_truth = match self.ground_truth.take() {
            Some((t, gt)) if t == color.log_time => Some(gt),
            _ => None,
        };
        let log_time = color.log_time;
        self.first_log_time.get_or_insert(log_time);
        self.pass_first_ts_us.get_or_insert(color.device_ts_us);
        self.pass_last_ts_us = Some(color.device_ts_us);
        self.pass_frames += 1;
        let frame = Frame {
            seq: self.seq,
            device_ts_us: color.device_ts_us + self.loop_offset_us,
            host_rx: Instant::now(),
            wall_clock: self
                .wall_clock_log_time
                .then(|| UNIX_EPOCH + Duration::from_nanos(log_time)),
            color: color.value,
            depth: depth.value,
            calibration,
        };
        self.seq += 1;
        tracing::trace!(seq = frame.seq, log_time, "frame read");
        Ok(Some(SessionFrame {
            frame,
            log_time,
            ground_truth,
        }))
    }

    fn warn_unpaired(&mut self, log_time: u64) {
        if !self.unpaired_warned {
            self.unpaired_warned = true;
            tracing::warn!(path = %self.path().display(), log_time, "colour or depth image without its pair: skipped");
        }
    }

    /// Refuses images larger than [`MAX_IMAGE_PIXELS`] before anything is allocated.
    fn check_size(&self, msg: &RawMessage, width: u32, height: u32) -> Result<(), RecordingError> {
        if u64::from(width) * u64::from(height) > MAX_IMAGE_PIXELS {
            return Err(self.decode_error(
                msg,
                format!(
                    "{width}x{height} image is larger than the {MAX_IMAGE_PIXELS} pixels allowed"
                ),
                None,
            ));
        }
        Ok(())
    }

    fn decode_color(&self, msg: &RawMessage) -> Result<(u64, ColorImage), RecordingError> {
        if msg.schema_name.ends_with("CompressedImage") {
            let m = CompressedImage::decode(&msg.data)
                .map_err(|e| self.decode_error(msg, "bad CompressedImage", Some(Box::new(e))))?;
            if m.format != "jpeg" && m.format != "jpg" {
                return Err(self.decode_error(
                    msg,
                    format!("unsupported colour format {:?} (jpeg only)", m.format),
                    None,
                ));
            }
            let mut decoder = jpeg_decoder::Decoder::new(&m.data[..]);
            // The header first: a few bytes may claim gigapixels.
            decoder
                .read_info()
                .map_err(|e| self.decode_error(msg, "bad JPEG", Some(Box::new(e))))?;
            if let Some(info) = decoder.info() {
                self.check_size(msg, u32::from(info.width), u32::from(info.height))?;
            }
            decoder.set_max_decoding_buffer_size(MAX_IMAGE_PIXELS as usize * 3);
            let pixels = decoder
                .decode()
                .map_err(|e| self.decode_error(msg, "bad JPEG", Some(Box::new(e))))?;
            let info = decoder
                .info()
                .ok_or_else(|| self.decode_error(msg, "JPEG without a header", None))?;
            let (w, h) = (u32::from(info.width), u32::from(info.height));
            let data = match info.pixel_format {
                jpeg_decoder::PixelFormat::RGB24 => {
                    let mut bgr = pixels;
                    for px in bgr.chunks_exact_mut(3) {
                        px.swap(0, 2);
                    }
                    bgr
                }
                jpeg_decoder::PixelFormat::L8 => pixels.iter().flat_map(|&v| [v, v, v]).collect(),
                other => {
                    return Err(self.decode_error(
                        msg,
                        format!("unsupported JPEG pixel format {other:?}"),
                        None,
                    ))
                }
            };
            Ok((
                m.timestamp.to_micros(),
                ColorImage {
                    width: w,
                    height: h,
                    data,
                },
            ))
        } else {
            let m = RawImage::decode(&msg.data)
                .map_err(|e| self.decode_error(msg, "bad RawImage", Some(Box::new(e))))?;
            self.check_size(msg, m.width, m.height)?;
            let (w, h) = (m.width as usize, m.height as usize);
            let step = m.step as usize;
            if step < w * 3 || m.data.len() < step * h.saturating_sub(1) + w * 3 {
                return Err(self.decode_error(
                    msg,
                    format!(
                        "{}x{} image with step {} has only {} bytes",
                        w,
                        h,
                        step,
                        m.data.len()
                    ),
                    None,
                ));
            }
            let mut data = Vec::with_capacity(w * h * 3);
            for row in 0..h {
                let line = &m.data[row * step..row * step + w * 3];
                match m.encoding.as_str() {
                    "bgr8" => data.extend_from_slice(line),
                    "rgb8" => data.extend(line.chunks_exact(3).flat_map(|p| [p[2], p[1], p[0]])),
                    other => {
                        return Err(self.decode_error(
                            msg,
                            format!("unsupported colour encoding {other:?} (bgr8 or rgb8)"),
                            None,
                        ))
                    }
                }
            }
            Ok((
                m.timestamp.to_micros(),
                ColorImage {
                    width: m.width,
                    height: m.height,
                    data,
                },
            ))
        }
    }

    fn decode_depth(&self, msg: &RawMessage) -> Result<(u64, DepthImage), RecordingError> {
        let m = RawImage::decode(&msg.data)
            .map_err(|e| self.decode_error(msg, "bad RawImage", Some(Box::new(e))))?;
        if m.encoding != "16UC1" && m.encoding != "mono16" {
            return Err(self.decode_error(
                msg,
                format!("unsupported depth encoding {:?} (16UC1)", m.encoding),
                None,
            ));
        }
        self.check_size(msg, m.width, m.height)?;
        let (w, h) = (m.width as usize, m.height as usize);
        let step = m.step as usize;
        if step < w * 2 || m.data.len() < step * h.saturating_sub(1) + w * 2 {
            return Err(self.decode_error(
                msg,
                format!(
                    "{}x{} depth with step {} has only {} bytes",
                    w,
                    h,
                    step,
                    m.data.len()
                ),
                None,
            ));
        }
        let mut data = Vec::with_capacity(w * h);
        for row in 0..h {
            let line = &m.data[row * step..row * step + w * 2];
            data.extend(
                line.chunks_exact(2)
                    .map(|b| u16::from_le_bytes([b[0], b[1]])),
            );
        }
        Ok((
            m.timestamp.to_micros(),
            DepthImage {
                width: m.width,
                height: m.height,
                data,
            },
        ))
    }
}

impl Iterator for SessionReader {
    type Item = Result<SessionFrame, RecordingError>;
    fn next(&mut self) -> Option<Self::Item> {
        self.next_frame().transpose()
    }
}
