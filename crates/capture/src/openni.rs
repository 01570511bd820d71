//! OpenNI2 sources: cameras (`openni2:[URI]`, `openni2:Dummy`) and `.oni` replay
//! (`replay:FILE.oni`), plus `.oni` recording with OpenNI2's own recorder.
//!
//! Frames come from the OpenNI thread of `mouthpiece-openni2` through a bounded
//! [`FrameReader`]: drop-oldest for cameras (latency first), back-pressure for files (every
//! frame; the file player runs in manual mode, speed −1, and waits for the reader). Pairing
//! and pacing happen here, on the caller's thread, in [`FrameSource::next_frame`].

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use mouthpiece_frame::{
    Calibration, ColorImage, DepthImage, Extrinsics, Frame, FrameSource, Intrinsics, SourceError,
    SourceInfo,
};
use openni2::{
    oni_file, Device, FrameReader, Overflow, OwnedFrame, PixelFormat, ReaderEvent, Recorder,
    SensorType, Stream, VideoMode,
};

use crate::pairing::{Pairer, Stamped};
use crate::spec::ReplaySpec;
use crate::{
    convert, format_error, lost_error, open_error, open_error_with, registration, CaptureConfig,
    DEFAULT_FOV_RAD,
};

/// Events buffered between the OpenNI thread and the pairing here.
const READER_CAPACITY: usize = 8;
/// A file player that delivers nothing for this long, before the frame counts its file
/// declares are read, has stopped. The counts end every readable file (a truncated one is
/// repaired first, with its counts), so this only ends a player that broke; it is long so
/// that a loaded machine's scheduling pauses never end a replay early.
mod replay;
mod session;

use session::*;

const FILE_STALL: Duration = Duration::from_secs(15);

impl Stamped for OwnedFrame {
    fn ts_us(&self) -> u64 {
        self.timestamp_us
    }
}

/// One open device with its two streams and reader. Field order is drop order: reader,
/// streams (stop, pause, destroy), then the device.
struct Session {
    reader: FrameReader,
    depth: Stream,
    color: Stream,
    /// Held so that it closes last, after its streams.
    _device: Device,
}

struct Negotiated {
    depth_mode: VideoMode,
    color_mode: VideoMode,
    calibration: Calibration,
    /// Depth arrives on its own grid and is registered here.
    software_registration: bool,
    depth_fov: (f64, f64),
    color_fov: (f64, f64),
}

struct ReplayState {
    spec: ReplaySpec,
    /// The file OpenNI2 plays (a fixed copy when the original lacked cropping records).
    play_path: PathBuf,
    _fixed_copy: Option<tempfile::TempDir>,
    frames: (u32, u32),
    received: (u32, u32),
    /// Pacing (`None`: unpaced).
    pacer: Option<crate::pace::Pacer>,
    /// Frames before this recording time (µs) are read and dropped (seeking forward).
    skip_until_us: u64,
    /// Added to device timestamps so that they keep increasing across loops.
    loop_offset_us: u64,
    last_ts_us: u64,
    loops: u64,
    ended: bool,
}

enum Kind {
    Live,
    Replay(Box<ReplayState>),
}

/// A depth + colour source through OpenNI2: a camera, the Dummy device, or an `.oni` file.
pub struct OpenNiSource {
    session: Option<Session>,
    kind: Kind,
    spec: String,
    info: SourceInfo,
    negotiated: Negotiated,
    calibration: Arc<Calibration>,
    pairer: Pairer<OwnedFrame, OwnedFrame>,
    config: CaptureConfig,
    seq: u64,
    reader_drops: u64,
    /// Set after a loss: later calls repeat it instead of touching a dead device.
    lost: Option<String>,
}

impl OpenNiSource {
    /// Opens a camera by URI (`None`: the first device OpenNI2 lists; `Dummy`: the
    /// Dummy device).
    pub fn open_device(
        uri: Option<&str>,
        config: &CaptureConfig,
    ) -> Result<OpenNiSource, SourceError> {
        Self::open_device_impl(uri, config, None).map(|(s, _)| s)
    }

    fn open_device_impl(
        uri: Option<&str>,
        config: &CaptureConfig,
        record_to: Option<&Path>,
    ) -> Result<(OpenNiSource, Option<OniRecording>), SourceError> {
        let spec = format!("openni2:{}", uri.unwrap_or(""));
        let uri = match uri {
            Some(u) => u.to_string(),
            None => {
                let devices = openni2::devices()
                    .map_err(|e| open_error_with(&spec, "cannot list OpenNI2 devices", e))?;
                devices.first().map(|d| d.uri.clone()).ok_or_else(|| {
                    open_error(
                        &spec,
                        "no OpenNI2 device found (is one plugged in? try openni2:Dummy to test)",
                    )
                })?
            }
        };
        let (session, negotiated, description, recorder) =
            open_session(&spec, &uri, false, config, record_to)?;
        let recording = recorder.map(|r| OniRecording::new(r, record_to, &negotiated));
        Ok((
            Self::assemble(spec, session, negotiated, description, Kind::Live, config),
            recording,
        ))
    }

    /// Opens an `.oni` recording for replay.
    pub fn open_file(
        replay: &ReplaySpec,
        config: &CaptureConfig,
    ) -> Result<OpenNiSource, SourceError> {
        Self::open_file_impl(replay, config, None).map(|(s, _)| s)
    }

    /// Opens an OpenNI2 camera or `.oni` replay and records its streams to `path` with
    /// OpenNI2's recorder, attached before the streams start.
    pub fn open_recording(
        spec: &crate::SourceSpec,
        config: &CaptureConfig,
        path: &Path,
    ) -> Result<(OpenNiSource, OniRecording), SourceError> {
        let (source, recording) = match spec {
            crate::SourceSpec::OpenNi2 { uri } => {
                Self::open_device_impl(uri.as_deref(), config, Some(path))?
            }
            crate::SourceSpec::Replay(r) => Self::open_file_impl(r, config, Some(path))?,
            other => return Err(open_error(&other.to_string(), "not an OpenNI2 source")),
        };
        let recording =
            recording.ok_or_else(|| open_error(&source.spec, "the recorder did not start"))?;
        Ok((source, recording))
    }

    fn assemble(
        spec: String,
        session: Session,
        negotiated: Negotiated,
        description: String,
        kind: Kind,
        config: &CaptureConfig,
    ) -> OpenNiSource {
        let live = matches!(kind, Kind::Live);
        let fps = negotiated.color_mode.fps as f64;
        let info = SourceInfo {
            spec: spec.clone(),
            description,
            color_width: negotiated.color_mode.width,
            color_height: negotiated.color_mode.height,
            depth_width: negotiated.calibration.depth.width,
            depth_height: negotiated.calibration.depth.height,
            fps,
            live,
        };
        OpenNiSource {
            session: Some(session),
            kind,
            spec,
            info,
            calibration: Arc::new(negotiated.calibration.clone()),
            negotiated,
            pairer: Pairer::new(config.tolerance_us(fps)),
            config: config.clone(),
            seq: 0,
            reader_drops: 0,
            lost: None,
        }
    }

    /// The depth and colour modes the device agreed to.
    pub fn modes(&self) -> (VideoMode, VideoMode) {
        (self.negotiated.depth_mode, self.negotiated.color_mode)
    }

    /// True when depth is registered in software (the device could not).
    pub fn software_registration(&self) -> bool {
        self.negotiated.software_registration
    }

    /// Frames dropped because they had no partner within the pairing tolerance.
    pub fn unpaired(&self) -> u64 {
        self.pairer.unpaired
    }

    fn build_frame(
        &mut self,
        depth: OwnedFrame,
        color: OwnedFrame,
        device_ts_us: u64,
    ) -> Result<Frame, SourceError> {
        let spec = &self.spec;
        let fmt_err = |e: convert::ConvertError| SourceError::Format {
            spec: spec.clone(),
            message: "cannot convert the frame".into(),
            cause: Some(Box::new(e)),
        };
        let bgr = match color.pixel_format {
            PixelFormat::RGB888 => {
                convert::rgb_to_bgr(color.width, color.height, &color.data).map_err(fmt_err)?
            }
            PixelFormat::YUYV => {
                convert::yuyv_to_bgr(color.width, color.height, &color.data).map_err(fmt_err)?
            }
            PixelFormat::YUV422 => {
                convert::uyvy_to_bgr(color.width, color.height, &color.data).map_err(fmt_err)?
            }
            other => {
                return Err(format_error(
                    spec,
                    format!("unsupported colour pixel format {other}"),
                ))
            }
        };
        let mut mm =
            convert::depth_to_mm(depth.width, depth.height, &depth.data, 0.001).map_err(fmt_err)?;
        if depth.pixel_format == PixelFormat::DEPTH_100_UM {
            mm.iter_mut()
                .for_each(|d| *d = ((*d as u32 + 5) / 10) as u16);
        }
        let mut depth_img = DepthImage {
            width: depth.width,
            height: depth.height,
            data: mm,
        };
        if self.negotiated.software_registration {
            let native = &self.negotiated;
            let depth_k = self.config.depth_intrinsics.unwrap_or_else(|| {
                Intrinsics::from_fov(
                    depth.width,
                    depth.height,
                    native.depth_fov.0,
                    native.depth_fov.1,
                )
            });
            let e = self.config.depth_to_color.unwrap_or(Extrinsics::IDENTITY);
            depth_img = registration::register_depth(
                &depth_img,
                &depth_k,
                &self.calibration.color,
                &e,
                0.001,
            );
        }
        let frame = Frame {
            seq: self.seq,
            device_ts_us,
            host_rx: color.host_rx.max(depth.host_rx),
            wall_clock: matches!(self.kind, Kind::Live).then(SystemTime::now),
            color: ColorImage {
                width: color.width,
                height: color.height,
                data: bgr,
            },
            depth: depth_img,
            calibration: Arc::clone(&self.calibration),
        };
        self.seq += 1;
        tracing::trace!(seq = frame.seq, ts = device_ts_us, "OpenNI2 pair");
        Ok(frame)
    }

    fn accept(&mut self, ev: ReaderEvent, live: bool) -> Result<(), SourceError> {
        match ev {
            ReaderEvent::Frame(f) => {
                if let Kind::Replay(state) = &mut self.kind {
                    match f.sensor {
                        SensorType::Depth => state.received.0 += 1,
                        _ => state.received.1 += 1,
                    }
                }
                match f.sensor {
                    SensorType::Depth => self.pairer.push_depth(f, live),
                    SensorType::Color => self.pairer.push_color(f, live),
                    SensorType::Ir => {}
                }
                Ok(())
            }
            ReaderEvent::DeviceLost { uri, reason } => {
                Err(self.mark_lost(format!("device {uri} went away: {reason}"), None))
            }
            ReaderEvent::Failed(err) => {
                let msg = format!("reading frames failed: {err}");
                Err(self.mark_lost(msg, Some(Box::new(err))))
            }
        }
    }

    fn mark_lost(
        &mut self,
        message: String,
        cause: Option<Box<dyn std::error::Error + Send + Sync>>,
    ) -> SourceError {
        tracing::warn!(spec = %self.spec, %message, "OpenNI2 source lost");
        self.lost = Some(message.clone());
        self.session = None;
        lost_error(&self.spec, message, cause)
    }

    fn next_live(&mut self) -> Result<Option<Frame>, SourceError> {
        let deadline = Instant::now() + self.config.stall_timeout;
        loop {
            let Some(session) = &self.session else {
                return Err(lost_error(
                    &self.spec,
                    self.lost.clone().unwrap_or_else(|| "closed".into()),
                    None,
                ));
            };
            let mut events = Vec::new();
            while let Ok(Some(ev)) = session.reader.try_recv() {
                events.push(ev);
            }
            self.reader_drops = session.reader.dropped();
            for ev in events {
                self.accept(ev, true)?;
            }
            if let Some((d, c)) = self.pairer.take_newest() {
                let ts = c.timestamp_us;
                return self.build_frame(d, c, ts).map(Some);
            }
            let now = Instant::now();
            if now >= deadline {
                let secs = self.config.stall_timeout.as_secs_f64();
                return Err(
                    self.mark_lost(format!("no frame pair for {secs:.1} s (unplugged?)"), None)
                );
            }
            let Some(session) = &self.session else {
                continue;
            };
            match session
                .reader
                .recv_timeout((deadline - now).min(Duration::from_millis(200)))
            {
                Ok(Some(ev)) => self.accept(ev, true)?,
                Ok(None) => {}
                Err(err) => {
                    return Err(
                        self.mark_lost(format!("frame reader stopped: {err}"), Some(Box::new(err)))
                    )
                }
            }
        }
    }
}

impl FrameSource for OpenNiSource {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        match self.kind {
            Kind::Live => self.next_live(),
            Kind::Replay(_) => self.next_replay(),
        }
    }

    fn skipped(&self) -> u64 {
        self.pairer.skipped + self.reader_drops
    }
}

/// An `.oni` recording in progress (OpenNI2's recorder on a source's streams).
pub struct OniRecording {
    recorder: Option<Recorder>,
    path: PathBuf,
    depth_fov: (f64, f64),
    color_fov: (f64, f64),
}

impl OniRecording {
    fn new(recorder: Recorder, path: Option<&Path>, negotiated: &Negotiated) -> OniRecording {
        OniRecording {
            recorder: Some(recorder),
            path: path.map(Path::to_path_buf).unwrap_or_default(),
            depth_fov: negotiated.depth_fov,
            color_fov: negotiated.color_fov,
        }
    }

    /// Closes the file, then adds the `xnCropping`/`xnFOV` records OpenNI2's player needs
    /// where the source did not provide them, so that the file always plays.
    pub fn finish(mut self) -> Result<oni_file::CroppingFix, SourceError> {
        let spec = self.path.display().to_string();
        if let Some(rec) = self.recorder.take() {
            rec.finish().map_err(|e| SourceError::Format {
                spec: spec.clone(),
                message: "OpenNI2's recorder failed to close the file".into(),
                cause: Some(Box::new(e)),
            })?;
        }
        let (depth_fov, color_fov) = (self.depth_fov, self.color_fov);
        oni_file::add_missing_cropping(&self.path, |node_type| {
            if node_type == 2 {
                depth_fov
            } else {
                color_fov
            }
        })
        .map_err(|e| SourceError::Format {
            spec,
            message: "cannot add the cropping records OpenNI2's player needs".into(),
            cause: Some(Box::new(e)),
        })
    }
}
