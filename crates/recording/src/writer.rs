//! [`SessionWriter`]: frames, calibration, ground truth and JSON channels into one MCAP file.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::Path;
use std::time::{Duration, UNIX_EPOCH};

use mcap::records::{MessageHeader, Metadata};
use mouthpiece_frame::{Calibration, Frame};
use serde::Serialize;

use crate::cdr::{self, CameraCalibration, CompressedImage, RawImage, Time};
use crate::{GroundTruth, RecordingError};

/// How colour frames are stored on `/camera/color`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColorEncoding {
    /// `RawImage` bgr8: lossless, ≈ 0.9 MB a frame before chunk compression.
    Raw,
    /// `CompressedImage` jpeg (4:4:4, no chroma subsampling so that small dots keep their
    /// colour), quality 1–100.
    Jpeg { quality: u8 },
}

impl Default for ColorEncoding {
    fn default() -> Self {
        ColorEncoding::Jpeg { quality: 90 }
    }
}

/// Writer settings. The defaults are what `mouthpiece synth` and takes use.
#[derive(Debug, Clone)]
pub struct WriterOptions {
    pub color: ColorEncoding,
    /// Close the current chunk (and flush it to the OS) once it spans this much capture time:
    /// bounds what a killed writer loses.
    pub flush_interval: Duration,
    /// Close the current chunk once it holds this many uncompressed bytes.
    pub chunk_size: u64,
    /// Chunk compression. `None` stores chunks uncompressed.
    pub compression: Option<mcap::Compression>,
    /// zstd level (ignored for lz4).
    pub zstd_level: u32,
}

impl Default for WriterOptions {
    fn default() -> Self {
        Self {
            color: ColorEncoding::default(),
            flush_interval: Duration::from_secs(1),
            chunk_size: 8 * 1024 * 1024,
            compression: Some(mcap::Compression::Zstd),
            zstd_level: 3,
        }
    }
}

/// What was written, returned by [`SessionWriter::finish`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionSummary {
    pub frames: u64,
    pub messages: u64,
    pub first_log_time: Option<u64>,
    pub last_log_time: Option<u64>,
}

/// Writes one session. Messages must come in capture order. Dropping the writer without
/// [`finish`](Self::finish) still writes the summary (best effort); a writer killed outright
/// leaves a file readable up to its last flushed chunk.
pub struct SessionWriter<W: Write + Seek = BufWriter<File>> {
    mcap: mcap::Writer<W>,
    path: String,
    options: WriterOptions,
    channels: HashMap<String, u16>,
    sequence: u32,
    session_written: bool,
    last_calibration: Option<Calibration>,
    chunk_start_log_time: Option<u64>,
    frames: u64,
    messages: u64,
    first_log_time: Option<u64>,
    last_log_time: Option<u64>,
    jpeg_buf: Vec<u8>,
}

impl SessionWriter<BufWriter<File>> {
    /// Creates (or replaces) the file at `path`.
    pub fn create(path: impl AsRef<Path>, options: WriterOptions) -> Result<Self, RecordingError> {
        let path = path.as_ref();
        let file = File::create(path).map_err(|source| RecordingError::Create {
            path: path.display().to_string(),
            source,
        })?;
        Self::new(
            BufWriter::with_capacity(1 << 20, file),
            path.display().to_string(),
            options,
        )
    }
}

impl<W: Write + Seek> SessionWriter<W> {
    /// Writes into any seekable sink; `name` is used in errors.
    pub fn new(sink: W, name: String, options: WriterOptions) -> Result<Self, RecordingError> {
        let mcap_options = mcap::WriteOptions::new()
            .profile("")
            .library(concat!("mouthpiece-recording ", env!("CARGO_PKG_VERSION")))
            .compression(options.compression)
            .compression_level(options.zstd_level)
            // Compression in the writing thread: the daemon runs it on a thread of its own.
            .compression_threads(0)
            .chunk_size(Some(options.chunk_size));
        let mcap = mcap_options
            .create(sink)
            .map_err(|source| RecordingError::Write {
                path: name.clone(),
                source,
            })?;
        tracing::info!(path = %name, "recording session");
        Ok(Self {
            mcap,
            path: name,
            options,
            channels: HashMap::new(),
            sequence: 0,
            session_written: false,
            last_calibration: None,
            chunk_start_log_time: None,
            frames: 0,
            messages: 0,
            first_log_time: None,
            last_log_time: None,
            jpeg_buf: Vec::new(),
        })
    }

    /// The capture time of a frame as the file's `log_time`: wall-clock nanoseconds since the
    /// Unix epoch when the frame has a wall-clock time, otherwise the device timestamp in ns.
    pub fn frame_log_time(frame: &Frame) -> u64 {
        match frame
            .wall_clock
            .and_then(|w| w.duration_since(UNIX_EPOCH).ok())
        {
            Some(d) => d.as_nanos() as u64,
            None => frame.device_ts_us * 1000,
        }
    }

    /// Writes a frame (colour, depth, and the calibration when it is new). Returns its log time.
    pub fn write_frame(&mut self, frame: &Frame) -> Result<u64, RecordingError> {
        self.write_frame_with_ground_truth(frame, None)
    }

    /// Writes a frame with its ground truth (ground truth first, then colour and depth, all at
    /// the frame's log time). Returns the log time.
    pub fn write_frame_with_ground_truth(
        &mut self,
        frame: &Frame,
        ground_truth: Option<&GroundTruth>,
    ) -> Result<u64, RecordingError> {
        check_frame(frame)?;
        let log_time = Self::frame_log_time(frame);
        if !self.session_written {
            let base = if frame.wall_clock.is_some() {
                "wall_clock"
            } else {
                "device"
            };
            let mut m = BTreeMap::new();
            m.insert(
                "format_version".to_string(),
                crate::FORMAT_VERSION.to_string(),
            );
            m.insert("log_time".to_string(), base.to_string());
            m.insert(
                "writer".to_string(),
                format!("mouthpiece-recording {}", env!("CARGO_PKG_VERSION")),
            );
            self.write_metadata(crate::METADATA_SESSION, m)?;
            self.session_written = true;
        }
        if self.last_calibration.as_ref() != Some(&*frame.calibration) {
            self.write_calibration(&frame.calibration, log_time, frame.device_ts_us)?;
        }
        if let Some(gt) = ground_truth {
            self.write_ground_truth(log_time, gt)?;
        }
        let stamp = Time::from_micros(frame.device_ts_us);
        let color_payload = match self.options.color {
            ColorEncoding::Raw => RawImage {
                timestamp: stamp,
                frame_id: crate::FRAME_ID_COLOR.into(),
                width: frame.color.width,
                height: frame.color.height,
                encoding: "bgr8".into(),
                step: frame.color.width * 3,
                data: frame.color.data.clone(),
            }
            .encode(),
            ColorEncoding::Jpeg { quality } => {
                self.encode_jpeg(frame, quality)?;
                CompressedImage {
                    timestamp: stamp,
                    frame_id: crate::FRAME_ID_COLOR.into(),
                    data: std::mem::take(&mut self.jpeg_buf),
                    format: "jpeg".into(),
                }
                .encode()
            }
        };
        let (color_schema, color_text) = match self.options.color {
            ColorEncoding::Raw => (cdr::RAW_IMAGE_SCHEMA_NAME, cdr::raw_image_schema()),
            ColorEncoding::Jpeg { .. } => (
                cdr::COMPRESSED_IMAGE_SCHEMA_NAME,
                cdr::compressed_image_schema(),
            ),
        };
        let color_channel = self.channel(
            crate::TOPIC_COLOR,
            color_schema,
            "ros2msg",
            color_text.as_bytes(),
            "cdr",
        )?;
        self.write_raw(color_channel, log_time, &color_payload)?;

        let mut depth_bytes = Vec::with_capacity(frame.depth.data.len() * 2);
        for v in &frame.depth.data {
            depth_bytes.extend_from_slice(&v.to_le_bytes());
        }
        let depth_payload = RawImage {
            timestamp: stamp,
            frame_id: crate::FRAME_ID_DEPTH.into(),
            width: frame.depth.width,
            height: frame.depth.height,
            encoding: "16UC1".into(),
            step: frame.depth.width * 2,
            data: depth_bytes,
        }
        .encode();
        let depth_channel = self.channel(
            crate::TOPIC_DEPTH,
            cdr::RAW_IMAGE_SCHEMA_NAME,
            "ros2msg",
            cdr::raw_image_schema().as_bytes(),
            "cdr",
        )?;
        self.write_raw(depth_channel, log_time, &depth_payload)?;
        self.frames += 1;
        tracing::trace!(seq = frame.seq, log_time, "frame written");
        self.maybe_flush(log_time)?;
        Ok(log_time)
    }

    /// Writes sound on `/audio` (Foxglove `RawAudio`, `pcm-s16`): `samples` interleaved,
    /// the first one at `log_time` (wall-clock ns, the frames' clock). Returns nothing to
    /// keep: the channel is created on first use.
    pub fn write_audio(
        &mut self,
        log_time: u64,
        format: mouthpiece_frame::AudioFormat,
        samples: &[i16],
    ) -> Result<(), RecordingError> {
        let mut data = Vec::with_capacity(samples.len() * 2);
        for s in samples {
            data.extend_from_slice(&s.to_le_bytes());
        }
        let payload = cdr::RawAudio {
            timestamp: Time {
                sec: (log_time / 1_000_000_000) as i32,
                nanosec: (log_time % 1_000_000_000) as u32,
            },
            data,
            format: "pcm-s16".into(),
            sample_rate: format.sample_rate,
            number_of_channels: u32::from(format.channels),
        }
        .encode();
        let channel = self.channel(
            crate::TOPIC_AUDIO,
            cdr::RAW_AUDIO_SCHEMA_NAME,
            "ros2msg",
            cdr::raw_audio_schema().as_bytes(),
            "cdr",
        )?;
        self.write_raw(channel, log_time, &payload)?;
        self.maybe_flush(log_time)
    }

    /// Writes a ground-truth message on `/groundtruth/points`.
    pub fn write_ground_truth(
        &mut self,
        log_time: u64,
        gt: &GroundTruth,
    ) -> Result<(), RecordingError> {
        let data = serde_json::to_vec(gt).map_err(|e| RecordingError::Encode {
            topic: crate::TOPIC_GROUND_TRUTH.into(),
            source: Box::new(e),
        })?;
        let channel = self.channel(
            crate::TOPIC_GROUND_TRUTH,
            "mouthpiece.GroundTruth",
            "jsonschema",
            GroundTruth::json_schema().as_bytes(),
            "json",
        )?;
        self.write_raw(channel, log_time, &data)
    }

    /// Writes any serialisable value as a JSON message on `topic` (a schemaless `json` channel,
    /// created on first use). For the derived channels of later stages.
    pub fn write_json<T: Serialize + ?Sized>(
        &mut self,
        topic: &str,
        log_time: u64,
        value: &T,
    ) -> Result<(), RecordingError> {
        let data = serde_json::to_vec(value).map_err(|e| RecordingError::Encode {
            topic: topic.into(),
            source: Box::new(e),
        })?;
        self.write_json_bytes(topic, log_time, &data)
    }

    /// Writes already-serialised JSON on `topic` (schemaless `json` channel).
    pub fn write_json_bytes(
        &mut self,
        topic: &str,
        log_time: u64,
        json: &[u8],
    ) -> Result<(), RecordingError> {
        let channel = match self.channels.get(topic) {
            Some(&id) => id,
            None => {
                let id = self
                    .mcap
                    .add_channel(0, topic, "json", &BTreeMap::new())
                    .map_err(|source| RecordingError::Write {
                        path: self.path.clone(),
                        source,
                    })?;
                self.channels.insert(topic.to_string(), id);
                id
            }
        };
        self.write_raw(channel, log_time, json)?;
        self.maybe_flush(log_time)
    }

    /// Writes a metadata record (closes the current chunk first, as MCAP requires).
    pub fn write_metadata(
        &mut self,
        name: &str,
        metadata: BTreeMap<String, String>,
    ) -> Result<(), RecordingError> {
        self.mcap
            .write_metadata(&Metadata {
                name: name.to_string(),
                metadata,
            })
            .map_err(|source| RecordingError::Write {
                path: self.path.clone(),
                source,
            })
    }

    /// Closes the current chunk and flushes it to the OS: everything written so far survives
    /// the process being killed.
    pub fn flush(&mut self) -> Result<(), RecordingError> {
        self.chunk_start_log_time = None;
        self.mcap.flush().map_err(|source| RecordingError::Write {
            path: self.path.clone(),
            source,
        })
    }

    /// Frames written so far.
    pub fn frames_written(&self) -> u64 {
        self.frames
    }

    /// Writes the summary and closes the file.
    pub fn finish(mut self) -> Result<SessionSummary, RecordingError> {
        self.mcap.finish().map_err(|source| RecordingError::Write {
            path: self.path.clone(),
            source,
        })?;
        let summary = SessionSummary {
            frames: self.frames,
            messages: self.messages,
            first_log_time: self.first_log_time,
            last_log_time: self.last_log_time,
        };
        let mut sink = self.mcap.into_inner();
        sink.flush().map_err(|source| RecordingError::Io {
            path: self.path.clone(),
            source,
        })?;
        tracing::info!(path = %self.path, frames = summary.frames, "session closed");
        Ok(summary)
    }

    fn write_calibration(
        &mut self,
        cal: &Calibration,
        log_time: u64,
        device_ts_us: u64,
    ) -> Result<(), RecordingError> {
        let json = serde_json::to_string(cal).map_err(|e| RecordingError::Encode {
            topic: crate::METADATA_CALIBRATION.into(),
            source: Box::new(e),
        })?;
        let mut m = BTreeMap::new();
        m.insert("calibration".to_string(), json);
        m.insert("depth_scale_m".to_string(), cal.depth_scale_m.to_string());
        m.insert(
            "depth_registered".to_string(),
            cal.depth_registered.to_string(),
        );
        m.insert(
            "depth_to_color".to_string(),
            serde_json::to_string(&cal.depth_to_color).unwrap_or_default(),
        );
        self.write_metadata(crate::METADATA_CALIBRATION, m)?;

        let c = &cal.color;
        let msg = CameraCalibration {
            timestamp: Time::from_micros(device_ts_us),
            frame_id: crate::FRAME_ID_COLOR.into(),
            width: c.width,
            height: c.height,
            distortion_model: "plumb_bob".into(),
            d: c.distortion.to_vec(),
            k: [c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [
                c.fx, 0.0, c.cx, 0.0, 0.0, c.fy, c.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
            ],
        };
        let channel = self.channel(
            crate::TOPIC_CALIBRATION,
            cdr::CAMERA_CALIBRATION_SCHEMA_NAME,
            "ros2msg",
            cdr::camera_calibration_schema().as_bytes(),
            "cdr",
        )?;
        self.write_raw(channel, log_time, &msg.encode())?;
        self.last_calibration = Some(cal.clone());
        Ok(())
    }

    fn encode_jpeg(&mut self, frame: &Frame, quality: u8) -> Result<(), RecordingError> {
        let (w, h) = (frame.color.width, frame.color.height);
        let too_big = |what: &str| RecordingError::BadFrame {
            seq: frame.seq,
            what: format!("colour image {w}x{h} {what}"),
        };
        let (w16, h16) = (
            u16::try_from(w).map_err(|_| too_big("is too wide for JPEG"))?,
            u16::try_from(h).map_err(|_| too_big("is too tall for JPEG"))?,
        );
        self.jpeg_buf.clear();
        let mut encoder = jpeg_encoder::Encoder::new(&mut self.jpeg_buf, quality.clamp(1, 100));
        encoder.set_sampling_factor(jpeg_encoder::SamplingFactor::F_1_1);
        encoder
            .encode(&frame.color.data, w16, h16, jpeg_encoder::ColorType::Bgr)
            .map_err(|e| RecordingError::Encode {
                topic: crate::TOPIC_COLOR.into(),
                source: Box::new(e),
            })
    }

    fn channel(
        &mut self,
        topic: &str,
        schema_name: &str,
        schema_encoding: &str,
        schema: &[u8],
        message_encoding: &str,
    ) -> Result<u16, RecordingError> {
        if let Some(&id) = self.channels.get(topic) {
            return Ok(id);
        }
        let map_err = |source| RecordingError::Write {
            path: self.path.clone(),
            source,
        };
        let schema_id = self
            .mcap
            .add_schema(schema_name, schema_encoding, schema)
            .map_err(map_err)?;
        let id = self
            .mcap
            .add_channel(schema_id, topic, message_encoding, &BTreeMap::new())
            .map_err(|source| RecordingError::Write {
                path: self.path.clone(),
                source,
            })?;
        self.channels.insert(topic.to_string(), id);
        Ok(id)
    }

    fn write_raw(
        &mut self,
        channel_id: u16,
        log_time: u64,
        data: &[u8],
    ) -> Result<(), RecordingError> {
        let header = MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time,
            publish_time: log_time,
        };
        self.sequence = self.sequence.wrapping_add(1);
        self.mcap
            .write_to_known_channel(&header, data)
            .map_err(|source| RecordingError::Write {
                path: self.path.clone(),
                source,
            })?;
        self.messages += 1;
        self.first_log_time.get_or_insert(log_time);
        self.last_log_time = Some(log_time);
        self.chunk_start_log_time.get_or_insert(log_time);
        Ok(())
    }

    fn maybe_flush(&mut self, log_time: u64) -> Result<(), RecordingError> {
        if let Some(start) = self.chunk_start_log_time {
            if log_time.saturating_sub(start) >= self.options.flush_interval.as_nanos() as u64 {
                self.flush()?;
            }
        }
        Ok(())
    }
}

fn check_frame(frame: &Frame) -> Result<(), RecordingError> {
    let bad = |what: String| {
        Err(RecordingError::BadFrame {
            seq: frame.seq,
            what,
        })
    };
    let c = &frame.color;
    if c.data.len() != c.width as usize * c.height as usize * 3 {
        return bad(format!(
            "colour {}x{} needs {} bytes, has {}",
            c.width,
            c.height,
            c.width as usize * c.height as usize * 3,
            c.data.len()
        ));
    }
    let d = &frame.depth;
    if d.data.len() != d.width as usize * d.height as usize {
        return bad(format!(
            "depth {}x{} needs {} values, has {}",
            d.width,
            d.height,
            d.width as usize * d.height as usize,
            d.data.len()
        ));
    }
    Ok(())
}
