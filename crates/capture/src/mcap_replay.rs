//! MCAP session replay (`replay:FILE.mcap`) on top of the recording crate's
//! [`SessionReader`], which decodes frames, loops, seeks and tolerates truncated files; this
//! module adds pacing (recorded speed × `speed`, or unpaced) and the [`FrameSource`] face.
//! Runs entirely on the caller's thread.

use std::time::{Duration, Instant};

use mouthpiece_frame::{Frame, FrameSource, SourceError, SourceInfo};
use mouthpiece_recording::{RecordingError, SessionReader};

use crate::spec::{ReplaySpec, SourceSpec};
use crate::{open_error_with, CaptureConfig};

/// A recorded MCAP session played back.
pub struct McapReplay {
    spec: String,
    reader: SessionReader,
    info: SourceInfo,
    speed: Option<f64>,
    /// (host instant, log time ns) the pacing is measured from.
    anchor: Option<(Instant, u64)>,
    last_log_time: u64,
    /// The first frame, read at open time to learn the sizes, handed out first.
    first: Option<Frame>,
    truncation_warned: bool,
}

fn recording_error(spec: &str, err: RecordingError) -> SourceError {
    match err {
        RecordingError::Open { .. } => open_error_with(spec, "cannot open the recording", err),
        other => SourceError::Format {
            spec: spec.to_string(),
            message: "cannot read the recording".into(),
            cause: Some(Box::new(other)),
        },
    }
}

impl McapReplay {
    pub fn open(replay: &ReplaySpec, _config: &CaptureConfig) -> Result<McapReplay, SourceError> {
        let spec = SourceSpec::Replay(replay.clone()).to_string();
        let mut reader =
            SessionReader::open(&replay.path).map_err(|e| recording_error(&spec, e))?;
        reader.set_looping(replay.looping);
        if replay.start_s > 0.0 {
            reader
                .seek(Duration::from_secs_f64(replay.start_s))
                .map_err(|e| recording_error(&spec, e))?;
        }
        let first = reader
            .next_frame()
            .map_err(|e| recording_error(&spec, e))?
            .ok_or_else(|| SourceError::Format {
                spec: spec.clone(),
                message: format!(
                    "{} holds no frames{}",
                    replay.path.display(),
                    if replay.start_s > 0.0 {
                        " after the start time"
                    } else {
                        ""
                    }
                ),
                cause: None,
            })?;
        let f = &first.frame;
        let info = SourceInfo {
            spec: spec.clone(),
            description: format!("MCAP session {}", replay.path.display()),
            color_width: f.color.width,
            color_height: f.color.height,
            depth_width: f.depth.width,
            depth_height: f.depth.height,
            fps: 0.0,
            live: false,
        };
        tracing::info!(%spec, "MCAP replay open");
        Ok(McapReplay {
            spec,
            reader,
            info,
            speed: replay.speed,
            anchor: None,
            last_log_time: first.log_time,
            first: Some(first.frame),
            truncation_warned: false,
        })
    }

    /// Continues from `t` after the session's first frame (backwards too).
    pub fn seek(&mut self, t: Duration) -> Result<(), SourceError> {
        self.first = None;
        self.anchor = None;
        self.reader
            .seek(t)
            .map_err(|e| recording_error(&self.spec, e))
    }

    fn pace(&mut self, log_time: u64) {
        let Some(speed) = self.speed else { return };
        if log_time < self.last_log_time {
            self.anchor = None; // looped
        }
        self.last_log_time = log_time;
        let (anchor, anchor_log) = *self.anchor.get_or_insert((Instant::now(), log_time));
        let due = anchor
            + Duration::from_secs_f64(log_time.saturating_sub(anchor_log) as f64 / 1e9 / speed);
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        }
    }
}

impl FrameSource for McapReplay {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        if let Some(first) = self.first.take() {
            let t = self.last_log_time;
            self.pace(t);
            return Ok(Some(first));
        }
        match self
            .reader
            .next_frame()
            .map_err(|e| recording_error(&self.spec, e))?
        {
            Some(sf) => {
                self.pace(sf.log_time);
                Ok(Some(sf.frame))
            }
            None => {
                if self.reader.is_truncated() && !self.truncation_warned {
                    self.truncation_warned = true;
                    tracing::warn!(spec = %self.spec, "the recording is truncated: played up to its last complete chunk");
                }
                Ok(None)
            }
        }
    }
}
