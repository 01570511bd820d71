//! Stand-ins used by `mouthpiece run` until the capture (issue 4) and detection (issue 5)
//! crates land in this branch. Both are real (they read the real demo session and publish
//! what they have), but neither finds dots: see the report of issue 7.
//!
//! - [`ReplaySource`]: `replay:PATH[?loop=1&speed=1.0]` over the recording crate's
//!   [`SessionReader`], paced at recorded speed.
//! - [`FramesOnly`]: publishes every frame's timing with the characters at rest and
//!   confidence 0; no dots, no head pose.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use mouthpiece_frame::{Frame, FrameSource, SourceError, SourceInfo};
use mouthpiece_recording::SessionReader;
use mouthpiece_server::{CharacterFrame, CharacterInfo, StreamInfo};

use crate::pipeline::{Output, Processor};

/// An MCAP session replayed at recorded speed (times `speed`), optionally looping.
pub struct ReplaySource {
    reader: SessionReader,
    info: SourceInfo,
    speed: f64,
    /// Device time and host time of the first frame paced.
    origin: Option<(u64, Instant)>,
    seq: u64,
}

impl ReplaySource {
    pub fn open(spec: &str) -> Result<ReplaySource, SourceError> {
        let rest = spec
            .strip_prefix("replay:")
            .ok_or_else(|| SourceError::Open {
                spec: spec.into(),
                message: "only replay: sources are available in this build".into(),
                cause: None,
            })?;
        let (path, query) = rest.split_once('?').unwrap_or((rest, ""));
        let mut looping = false;
        let mut speed = 1.0;
        for pair in query.split('&').filter(|p| !p.is_empty()) {
            match pair.split_once('=') {
                Some(("loop", v)) => looping = v == "1" || v == "true",
                Some(("speed", v)) => {
                    speed = v
                        .parse::<f64>()
                        .ok()
                        .filter(|s| s.is_finite() && *s > 0.0)
                        .ok_or_else(|| SourceError::Open {
                            spec: spec.into(),
                            message: format!("bad speed {v:?}"),
                            cause: None,
                        })?
                }
                _ => {
                    return Err(SourceError::Open {
                        spec: spec.into(),
                        message: format!("unknown option {pair:?} (loop=1, speed=S)"),
                        cause: None,
                    })
                }
            }
        }
        let path = PathBuf::from(path);
        let mut reader = SessionReader::open(&path).map_err(|e| SourceError::Open {
            spec: spec.into(),
            message: format!("cannot open {}", path.display()),
            cause: Some(Box::new(e)),
        })?;
        reader.set_looping(looping);
        let (width, height) = reader
            .calibration()
            .map(|c| (c.color.width, c.color.height))
            .unwrap_or((0, 0));
        let info = SourceInfo {
            spec: spec.into(),
            description: format!("replay of {}", path.display()),
            color_width: width,
            color_height: height,
            depth_width: width,
            depth_height: height,
            fps: 30.0,
            live: false,
        };
        Ok(ReplaySource {
            reader,
            info,
            speed,
            origin: None,
            seq: 0,
        })
    }
}

impl FrameSource for ReplaySource {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        let next = self
            .reader
            .next_frame()
            .map_err(|e| SourceError::Disconnected {
                spec: self.info.spec.clone(),
                message: "replay failed".into(),
                cause: Some(Box::new(e)),
            })?;
        let Some(session_frame) = next else {
            return Ok(None);
        };
        let mut frame = session_frame.frame;
        let (ts0, t0) = *self
            .origin
            .get_or_insert((frame.device_ts_us, Instant::now()));
        let due = t0
            + Duration::from_secs_f64(
                frame.device_ts_us.saturating_sub(ts0) as f64 * 1e-6 / self.speed,
            );
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        }
        frame.seq = self.seq;
        self.seq += 1;
        frame.host_rx = Instant::now();
        frame.wall_clock = None;
        Ok(Some(frame))
    }
}

/// Publishes frames with the characters at rest (confidence 0): no detector in this build.
pub struct FramesOnly {
    characters: Vec<mouthpiece_retarget::Character>,
    names: Vec<String>,
    info_changed: bool,
}

impl FramesOnly {
    pub fn new(characters: Vec<mouthpiece_retarget::Character>) -> Self {
        tracing::warn!("no dot detector in this build: characters stay at rest (confidence 0)");
        let names = (1..=12)
            .map(|i| format!("D{i}"))
            .chain((1..=3).map(|i| format!("F{i}")))
            .collect();
        FramesOnly {
            characters,
            names,
            info_changed: true,
        }
    }
}

fn to_f32(v: &nalgebra::Vector3<f64>) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

impl Processor for FramesOnly {
    fn process(&mut self, _frame: &Frame, out: &mut Output) {
        out.flags.calibrating = true;
        out.flags.no_dots = true;
        out.performer_camera.clear();
        out.performer_camera.resize(self.names.len(), None);
        out.stream.performer = None;
        out.stream
            .characters
            .resize_with(self.characters.len(), CharacterFrame::default);
        for (c, slot) in self.characters.iter().zip(out.stream.characters.iter_mut()) {
            if slot.name != c.name {
                slot.name.clone_from(&c.name);
            }
            slot.points.clear();
            slot.points.extend(c.neutral.iter().map(to_f32));
            slot.confidence.clear();
            slot.confidence.resize(c.len(), 0.0);
        }
    }

    fn calibrate(&mut self, _duration: Option<Duration>) {}

    fn stream_info(&self, frame_rate: f64, source: &str) -> StreamInfo {
        StreamInfo {
            characters: self
                .characters
                .iter()
                .map(|c| CharacterInfo {
                    name: c.name.clone(),
                    points: c.point_names.clone(),
                    neutral: c.neutral.iter().map(to_f32).collect(),
                    m: Vec::new(),
                    m_mode: format!("{:?}", c.m_mode).to_lowercase(),
                    units: c
                        .units
                        .map(|u| format!("{u:?}").to_lowercase())
                        .unwrap_or_default(),
                })
                .collect(),
            performer_points: self.names[..12].to_vec(),
            frame_rate,
            source: source.to_owned(),
        }
    }

    fn take_info_changed(&mut self) -> bool {
        std::mem::take(&mut self.info_changed)
    }

    fn performer_names(&self) -> &[String] {
        &self.names
    }

    fn reload(&mut self, update: Box<dyn std::any::Any + Send>) -> Result<(), String> {
        let characters = update
            .downcast::<Vec<mouthpiece_retarget::Character>>()
            .map_err(|_| "internal: wrong reload payload".to_owned())?;
        self.characters = *characters;
        self.info_changed = true;
        Ok(())
    }
}

/// The factory `mouthpiece run` uses until capture and detection land: [`ReplaySource`] and
/// [`FramesOnly`] with the configured characters.
#[derive(Debug, Clone, Copy, Default)]
pub struct InterimFactory;

impl crate::daemon::Factory for InterimFactory {
    type Processor = FramesOnly;

    fn processor(
        &self,
        config: &mouthpiece_config::Config,
    ) -> Result<FramesOnly, crate::check::CheckError> {
        Ok(FramesOnly::new(crate::characters::load(config)?))
    }

    fn reload(
        &self,
        config: &mouthpiece_config::Config,
    ) -> Result<Box<dyn std::any::Any + Send>, crate::check::CheckError> {
        Ok(Box::new(crate::characters::load(config)?))
    }

    fn opener(&self, spec: &str) -> crate::source::Opener {
        let spec = spec.to_owned();
        Box::new(move || ReplaySource::open(&spec).map(|s| Box::new(s) as Box<dyn FrameSource>))
    }
}
