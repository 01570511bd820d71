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

fn describe(err: &openni2::Error) -> String {
    match err.status() {
        Some(status) if status.name() == "NO_DEVICE" => format!("no such device ({err})"),
        _ => err.to_string(),
    }
}

fn pick_mode(
    modes: &[VideoMode],
    formats: &[PixelFormat],
    config: &CaptureConfig,
) -> Option<VideoMode> {
    modes
        .iter()
        .filter(|m| formats.contains(&m.pixel_format))
        .copied()
        .min_by_key(|m| {
            let format_rank = formats
                .iter()
                .position(|f| *f == m.pixel_format)
                .unwrap_or(formats.len());
            (
                (m.width as i64 - config.width as i64).abs()
                    + (m.height as i64 - config.height as i64).abs(),
                (m.fps as i64 - config.fps as i64).abs(),
                format_rank,
            )
        })
}

const DEPTH_FORMATS: [PixelFormat; 2] = [PixelFormat::DEPTH_1_MM, PixelFormat::DEPTH_100_UM];
const COLOR_FORMATS: [PixelFormat; 3] =
    [PixelFormat::RGB888, PixelFormat::YUYV, PixelFormat::YUV422];

fn fov_of(k: &Intrinsics) -> (f64, f64) {
    (
        2.0 * (k.width as f64 / 2.0 / k.fx).atan(),
        2.0 * (k.height as f64 / 2.0 / k.fy).atan(),
    )
}

/// Opens a device and its streams, agrees on modes, starts streaming.
fn open_session(
    spec: &str,
    uri: &str,
    is_file: bool,
    config: &CaptureConfig,
    record_to: Option<&Path>,
) -> Result<(Session, Negotiated, String, Option<Recorder>), SourceError> {
    let device = Device::open(uri).map_err(|e| {
        let hint = if is_file {
            "OpenNI2's file driver could not open it".to_string()
        } else {
            "is it plugged in, and not in use by another process?".to_string()
        };
        open_error_with(
            spec,
            format!(
                "cannot open OpenNI2 device {uri:?}: {} ({hint})",
                describe(&e)
            ),
            e,
        )
    })?;
    let description = format!(
        "{} {} ({})",
        device.info().vendor,
        device.info().name,
        device.info().uri
    );
    let call = |what: &str, e: openni2::Error| open_error_with(spec, format!("{what}: {e}"), e);
    if is_file {
        device
            .set_playback_speed(-1.0)
            .map_err(|e| call("cannot set manual playback", e))?;
        device
            .set_playback_repeat(false)
            .map_err(|e| call("cannot turn playback repeat off", e))?;
    }
    let has = |sensor| {
        device
            .sensor_modes(sensor)
            .map_err(|e| call("cannot list sensor modes", e))
    };
    let depth_modes = has(SensorType::Depth)?
        .ok_or_else(|| open_error(spec, "the device has no depth sensor"))?;
    let color_modes = has(SensorType::Color)?
        .ok_or_else(|| open_error(spec, "the device has no colour sensor"))?;
    let depth = device
        .create_stream(SensorType::Depth)
        .map_err(|e| call("cannot create the depth stream", e))?;
    let color = device
        .create_stream(SensorType::Color)
        .map_err(|e| call("cannot create the colour stream", e))?;
    if !is_file {
        for (stream, modes, formats) in [
            (&depth, &depth_modes, &DEPTH_FORMATS[..]),
            (&color, &color_modes, &COLOR_FORMATS[..]),
        ] {
            let Some(mode) = pick_mode(modes, formats, config) else {
                continue;
            };
            if stream.video_mode().ok() == Some(mode) {
                continue;
            }
            // Some drivers (the Dummy) have one fixed mode and refuse the call; the mode
            // actually in use is read back below either way.
            if let Err(err) = stream.set_video_mode(mode) {
                tracing::warn!(sensor = %stream.sensor(), %mode, %err, "mode refused; keeping the device's");
            }
        }
        for s in [&depth, &color] {
            if let Err(err) = s.set_mirroring(false) {
                tracing::warn!(%err, sensor = %s.sensor(), "cannot turn mirroring off");
            }
        }
    }
    // What the device agreed to, not what was asked.
    let depth_mode = depth
        .video_mode()
        .map_err(|e| call("the depth stream reports no mode", e))?;
    let color_mode = color
        .video_mode()
        .map_err(|e| call("the colour stream reports no mode", e))?;
    if !DEPTH_FORMATS.contains(&depth_mode.pixel_format) {
        return Err(format_error(
            spec,
            format!(
                "unsupported depth pixel format {} (supported: DEPTH_1_MM, DEPTH_100_UM)",
                depth_mode.pixel_format
            ),
        ));
    }
    if !COLOR_FORMATS.contains(&color_mode.pixel_format) {
        return Err(format_error(
            spec,
            format!(
                "unsupported colour pixel format {} (supported: RGB888, YUYV, YUV422)",
                color_mode.pixel_format
            ),
        ));
    }

    let mut hardware_registration = false;
    if !is_file {
        match device.supports_registration() {
            Ok(true) => match device.set_registration(true) {
                Ok(()) => hardware_registration = true,
                Err(err) => {
                    tracing::warn!(%err, "hardware registration refused; registering in software")
                }
            },
            Ok(false) => {
                tracing::info!("device cannot register depth to colour; registering in software")
            }
            Err(err) => tracing::warn!(%err, "cannot query registration support"),
        }
        if let Err(err) = device.enable_depth_color_sync() {
            tracing::debug!(%err, "depth/colour frame sync not available");
        }
    }
    let fov = |s: &Stream, what: &str| -> Result<(f64, f64), SourceError> {
        Ok(
            match s
                .field_of_view()
                .map_err(|e| call("cannot read the field of view", e))?
            {
                Some((h, v)) => (h as f64, v as f64),
                None => {
                    tracing::warn!(stream = what, "no field of view reported; assuming 58°x45° (set intrinsics in the config)");
                    DEFAULT_FOV_RAD
                }
            },
        )
    };
    let depth_fov = fov(&depth, "depth")?;
    let color_fov = fov(&color, "colour")?;
    let color_k = config.color_intrinsics.unwrap_or_else(|| {
        Intrinsics::from_fov(
            color_mode.width,
            color_mode.height,
            color_fov.0,
            color_fov.1,
        )
    });
    let calibration = if hardware_registration {
        Calibration::registered(color_k)
    } else {
        let depth_k = config.depth_intrinsics.unwrap_or_else(|| {
            Intrinsics::from_fov(
                depth_mode.width,
                depth_mode.height,
                depth_fov.0,
                depth_fov.1,
            )
        });
        Calibration {
            color: color_k,
            depth: depth_k,
            depth_to_color: config.depth_to_color.unwrap_or(Extrinsics::IDENTITY),
            depth_scale_m: 0.001,
            depth_registered: false,
        }
    };

    // The recorder goes on before the streams start, so that it gets both streams' first
    // frames: OpenNI2 rewrites each stream's timestamps from its own first recorded frame,
    // and a recorder that missed one would shift depth against colour by a frame.
    let recorder = match record_to {
        Some(path) => {
            let err = |what: &str, e: openni2::Error| SourceError::Open {
                spec: path.display().to_string(),
                message: format!("{what}: {e}"),
                cause: Some(Box::new(e)),
            };
            let mut recorder =
                Recorder::create(path).map_err(|e| err("cannot create the .oni recorder", e))?;
            recorder
                .attach(&depth, false)
                .map_err(|e| err("cannot record the depth stream", e))?;
            recorder
                .attach(&color, false)
                .map_err(|e| err("cannot record the colour stream", e))?;
            recorder
                .start()
                .map_err(|e| err("cannot start recording", e))?;
            // Returns once the recorder's thread has taken the start: frames from here on
            // are recorded.
            tracing::info!(file = %path.display(), "recording .oni with OpenNI2's recorder");
            Some(recorder)
        }
        None => None,
    };
    depth
        .start()
        .map_err(|e| call("cannot start the depth stream", e))?;
    color
        .start()
        .map_err(|e| call("cannot start the colour stream", e))?;
    let overflow = if is_file {
        Overflow::Backpressure
    } else {
        Overflow::DropOldest
    };
    let reader = FrameReader::start(&[&depth, &color], READER_CAPACITY, overflow)
        .map_err(|e| call("cannot start reading frames", e))?;
    tracing::info!(
        %spec, device = %description, depth = %depth_mode, color = %color_mode,
        registration = if hardware_registration { "hardware" } else { "software" },
        "OpenNI2 source open"
    );
    let negotiated = Negotiated {
        depth_mode,
        color_mode,
        software_registration: !hardware_registration,
        calibration: Calibration {
            depth_registered: true,
            ..calibration.clone()
        },
        depth_fov: if config.depth_intrinsics.is_some() {
            fov_of(&calibration.depth)
        } else {
            depth_fov
        },
        color_fov: if config.color_intrinsics.is_some() {
            fov_of(&calibration.color)
        } else {
            color_fov
        },
    };
    // `negotiated.calibration` describes the frames handed out: depth on the colour grid.
    let negotiated = Negotiated {
        calibration: calibration_out(&calibration),
        ..negotiated
    };
    Ok((
        Session {
            reader,
            depth,
            color,
            _device: device,
        },
        negotiated,
        description,
        recorder,
    ))
}

/// The calibration of delivered frames: depth registered onto the colour grid.
fn calibration_out(native: &Calibration) -> Calibration {
    Calibration {
        color: native.color,
        depth: native.color,
        depth_to_color: Extrinsics::IDENTITY,
        depth_scale_m: native.depth_scale_m,
        depth_registered: true,
    }
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

    fn open_file_impl(
        replay: &ReplaySpec,
        config: &CaptureConfig,
        record_to: Option<&Path>,
    ) -> Result<(OpenNiSource, Option<OniRecording>), SourceError> {
        let spec = crate::SourceSpec::Replay(replay.clone()).to_string();
        let path = &replay.path;
        if !path.is_file() {
            return Err(open_error(
                &spec,
                format!("no such file: {}", path.display()),
            ));
        }
        // Check every record in Rust before OpenNI2 sees the file: its player crashes the
        // process (signal 11) on some inconsistent files instead of failing.
        let records = openni2::oni_check::validate(path, true).map_err(|e| match e {
            oni_file::OniFileError::Io { .. } => {
                open_error_with(&spec, format!("cannot read {}", path.display()), e)
            }
            _ => SourceError::Format {
                spec: spec.clone(),
                message: format!("{} is not a readable .oni file", path.display()),
                cause: Some(Box::new(e)),
            },
        })?;
        let complete = records
            .last()
            .is_some_and(|r| r.kind == oni_file::record_type::END);
        if !records
            .iter()
            .any(|r| r.kind == oni_file::record_type::NEW_DATA)
        {
            return Err(format_error(
                &spec,
                format!("{} holds no frames", path.display()),
            ));
        }
        let nodes: std::collections::HashSet<u32> = records
            .iter()
            .filter(|r| {
                r.kind == oni_file::record_type::NODE_ADDED
                    || r.kind == oni_file::record_type::NODE_ADDED_1_0_0_5
            })
            .map(|r| r.node_id)
            .collect();
        let cropped: std::collections::HashSet<u32> = records
            .iter()
            .filter(|r| r.property.as_deref() == Some("xnCropping"))
            .map(|r| r.node_id)
            .collect();
        let (play_path, fixed_copy) = if !complete || !nodes.is_subset(&cropped) {
            // Cut short (OpenNI2's player refuses such files), or written from streams without
            // cropping (Dummy driver, some third-party drivers: OpenNI2 would play no frames).
            // Play a repaired copy; the user's file is not touched.
            let dir = tempfile::tempdir()
                .map_err(|e| open_error_with(&spec, "cannot create a temporary directory", e))?;
            let copy = dir
                .path()
                .join(path.file_name().unwrap_or_else(|| "replay.oni".as_ref()));
            if complete {
                std::fs::copy(path, &copy).map_err(|e| {
                    open_error_with(&spec, format!("cannot copy {}", path.display()), e)
                })?;
            } else {
                let repair =
                    oni_file::repair_truncated(path, &copy).map_err(|e| SourceError::Format {
                        spec: spec.clone(),
                        message: format!("{} is truncated and cannot be repaired", path.display()),
                        cause: Some(Box::new(e)),
                    })?;
                tracing::warn!(
                    file = %path.display(), frames = ?repair.frames, dropped_bytes = repair.dropped_bytes,
                    "playing a truncated .oni up to its last complete frame"
                );
            }
            oni_file::add_missing_cropping(&copy, |_| DEFAULT_FOV_RAD).map_err(|e| {
                open_error_with(
                    &spec,
                    "cannot add the cropping records OpenNI2's player needs",
                    e,
                )
            })?;
            tracing::info!(file = %path.display(), "file lacks cropping records; playing a fixed copy");
            (copy, Some(dir))
        } else {
            (path.clone(), None)
        };
        let uri = play_path
            .to_str()
            .ok_or_else(|| open_error(&spec, "the path is not UTF-8"))?
            .to_string();
        let (session, negotiated, description, recorder) =
            open_session(&spec, &uri, true, config, record_to)?;
        let recording = recorder.map(|r| OniRecording::new(r, record_to, &negotiated));
        let frames = (
            session
                .depth
                .number_of_frames()
                .ok()
                .flatten()
                .unwrap_or(u32::MAX),
            session
                .color
                .number_of_frames()
                .ok()
                .flatten()
                .unwrap_or(u32::MAX),
        );
        let state = ReplayState {
            spec: replay.clone(),
            play_path,
            _fixed_copy: fixed_copy,
            frames,
            received: (0, 0),
            pacer: replay.speed.map(crate::pace::Pacer::new),
            skip_until_us: (replay.start_s * 1e6) as u64,
            loop_offset_us: 0,
            last_ts_us: 0,
            loops: 0,
            ended: false,
        };
        Ok((
            Self::assemble(
                spec,
                session,
                negotiated,
                description,
                Kind::Replay(Box::new(state)),
                config,
            ),
            recording,
        ))
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

    /// Replay only: continue from `t` after the start of the recording. Forward seeks read
    /// and drop frames; backward seeks reopen the file and read forward (OpenNI2's seek
    /// command crashes its player, an upstream OpenNI2 bug).
    pub fn seek(&mut self, t: Duration) -> Result<(), SourceError> {
        let target = t.as_micros() as u64;
        let Kind::Replay(state) = &mut self.kind else {
            return Err(open_error(&self.spec, "only replays can seek"));
        };
        let position = state.last_ts_us.saturating_sub(state.loop_offset_us);
        if target < position || state.ended {
            self.restart()?;
        }
        if let Kind::Replay(state) = &mut self.kind {
            state.skip_until_us = target;
            if let Some(p) = &mut state.pacer {
                p.reset();
            }
        }
        Ok(())
    }

    /// Reopens the replay file from its start.
    fn restart(&mut self) -> Result<(), SourceError> {
        let Kind::Replay(state) = &mut self.kind else {
            return Ok(());
        };
        // Drop first: the old player must be gone before a new one opens the file.
        self.session = None;
        self.pairer.clear();
        let uri = state.play_path.to_str().unwrap_or_default().to_string();
        let (session, _, _, _) = open_session(&self.spec, &uri, true, &self.config, None)?;
        state.received = (0, 0);
        state.ended = false;
        if let Some(p) = &mut state.pacer {
            p.reset();
        }
        self.session = Some(session);
        Ok(())
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

    fn next_replay(&mut self) -> Result<Option<Frame>, SourceError> {
        loop {
            let Kind::Replay(state) = &mut self.kind else {
                unreachable!("replay only")
            };
            if state.ended {
                return Ok(None);
            }
            if let Some((d, c)) = self.pairer.take_in_order() {
                let Kind::Replay(state) = &mut self.kind else {
                    unreachable!()
                };
                let rec_ts = c.timestamp_us;
                if rec_ts < state.skip_until_us {
                    continue;
                }
                if let Some(pacer) = &mut state.pacer {
                    let wait = pacer.wait(Instant::now(), rec_ts.saturating_mul(1000), &self.spec);
                    if !wait.is_zero() {
                        std::thread::sleep(wait);
                    }
                }
                let ts = rec_ts + state.loop_offset_us;
                state.last_ts_us = ts;
                // Received when handed out (after the pacing sleep), as a camera's frame.
                return self.build_frame(d, c, ts).map(|mut f| {
                    f.host_rx = Instant::now();
                    Some(f)
                });
            }
            let Kind::Replay(state) = &mut self.kind else {
                unreachable!()
            };
            let all_read = state.received.0 >= state.frames.0 && state.received.1 >= state.frames.1;
            let event = if all_read {
                None
            } else {
                let session = self
                    .session
                    .as_ref()
                    .ok_or_else(|| lost_error(&self.spec, "replay closed", None))?;
                session
                    .reader
                    .recv_timeout(FILE_STALL)
                    .map_err(|e| SourceError::Format {
                        spec: self.spec.clone(),
                        message: "the OpenNI2 player stopped".into(),
                        cause: Some(Box::new(e)),
                    })?
            };
            match event {
                Some(ev) => self.accept(ev, false)?,
                None => {
                    let Kind::Replay(state) = &mut self.kind else {
                        unreachable!()
                    };
                    if !all_read {
                        tracing::warn!(
                            spec = %self.spec,
                            depth = state.received.0,
                            color = state.received.1,
                            "the recording ended early (truncated file?): played to its last readable frame"
                        );
                    }
                    if state.spec.looping && self.seq > 0 {
                        let period = if self.info.fps > 0.0 {
                            (1e6 / self.info.fps) as u64
                        } else {
                            33_333
                        };
                        state.loop_offset_us = state.last_ts_us + period;
                        state.loops += 1;
                        state.skip_until_us = 0;
                        tracing::info!(spec = %self.spec, loops = state.loops, "replay looping");
                        self.restart()?;
                        continue;
                    }
                    state.ended = true;
                    // Stop the player (it spins after the end) and release the file.
                    self.session = None;
                    tracing::info!(spec = %self.spec, frames = self.seq, unpaired = self.pairer.unpaired, "replay finished");
                    return Ok(None);
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
