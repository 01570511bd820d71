//! MCAP session replay (`replay:FILE.mcap`) on top of the recording crate's
//! [`SessionReader`], which decodes frames, loops, seeks and tolerates truncated files; this
//! module adds pacing (recorded speed × `speed`, or unpaced) and the [`FrameSource`] face.
//! Runs entirely on the caller's thread.

use std::time::{Duration, Instant};

use mouthpiece_frame::{Frame, FrameSource, SourceError, SourceInfo};
use mouthpiece_recording::{RecordingError, SessionReader};

use crate::pace::{Pacer, ReplayClock};
use crate::spec::{ReplaySpec, SourceSpec};
use crate::{open_error_with, CaptureConfig};

/// A recorded MCAP session played back.
pub struct McapReplay {
    spec: String,
    reader: SessionReader,
    info: SourceInfo,
    /// `None`: unpaced.
    pacer: Option<Pacer>,
    /// The first two frames (log time, frame), read at open time to learn the sizes and the
    /// frame rate, handed out first.
    ahead: std::collections::VecDeque<(u64, Frame)>,
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
        // The frame rate from the first two frames' device clocks (a recording does not
        // state it); unknown (0) for a single frame.
        let second = reader.next_frame().map_err(|e| recording_error(&spec, e))?;
        let fps = match &second {
            Some(s) if s.frame.device_ts_us > first.frame.device_ts_us => {
                let period_s = (s.frame.device_ts_us - first.frame.device_ts_us) as f64 / 1e6;
                (100.0 / period_s).round() / 100.0
            }
            _ => 0.0,
        };
        let f = &first.frame;
        let info = SourceInfo {
            spec: spec.clone(),
            description: format!("MCAP session {}", replay.path.display()),
            color_width: f.color.width,
            color_height: f.color.height,
            depth_width: f.depth.width,
            depth_height: f.depth.height,
            fps,
            live: false,
        };
        tracing::info!(%spec, "MCAP replay open");
        Ok(McapReplay {
            spec,
            reader,
            info,
            pacer: replay
                .speed
                .map(|speed| Pacer::new(speed).sharing(ReplayClock::for_path(&replay.path))),
            ahead: [Some(first), second]
                .into_iter()
                .flatten()
                .map(|f| (f.log_time, f.frame))
                .collect(),
            truncation_warned: false,
        })
    }

    /// Continues from `t` after the session's first frame (backwards too).
    pub fn seek(&mut self, t: Duration) -> Result<(), SourceError> {
        self.ahead.clear();
        if let Some(p) = &mut self.pacer {
            p.reset();
        }
        self.reader
            .seek(t)
            .map_err(|e| recording_error(&self.spec, e))
    }

    fn pace(&mut self, log_time: u64) {
        let Some(pacer) = &mut self.pacer else { return };
        let wait = pacer.wait(Instant::now(), log_time, &self.spec);
        if !wait.is_zero() {
            std::thread::sleep(wait);
        }
    }
}

impl FrameSource for McapReplay {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        if let Some((log_time, mut frame)) = self.ahead.pop_front() {
            self.pace(log_time);
            frame.host_rx = Instant::now();
            return Ok(Some(frame));
        }
        match self
            .reader
            .next_frame()
            .map_err(|e| recording_error(&self.spec, e))?
        {
            Some(mut sf) => {
                self.pace(sf.log_time);
                // Received when handed out, as a camera's frame would be: the decoding and
                // the pacing sleep before this are not part of the capture-to-client time.
                sf.frame.host_rx = Instant::now();
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

#[cfg(test)]
mod tests {
    use super::*;
    use mouthpiece_frame::{Calibration, ColorImage, DepthImage, Intrinsics};
    use mouthpiece_recording::{SessionWriter, WriterOptions};
    use std::sync::Arc;

    /// A replayed frame counts as received when it is handed out, after the pacing sleep,
    /// as a camera's frame would: otherwise capture-to-client latency includes the sleep.
    #[test]
    fn paced_frames_are_stamped_when_handed_out() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.mcap");
        let mut writer = SessionWriter::create(&path, WriterOptions::default()).unwrap();
        let calibration = Arc::new(Calibration::registered(Intrinsics::ideal(
            8, 8, 8.0, 8.0, 4.0, 4.0,
        )));
        for i in 0..3u64 {
            writer
                .write_frame(&Frame {
                    seq: i,
                    device_ts_us: i * 33_333,
                    host_rx: Instant::now(),
                    wall_clock: None,
                    color: ColorImage::new(8, 8),
                    depth: DepthImage::new(8, 8),
                    calibration: calibration.clone(),
                })
                .unwrap();
        }
        writer.finish().unwrap();
        // A quarter of recorded speed: frames 133 ms apart.
        let spec = ReplaySpec {
            speed: Some(0.25),
            ..ReplaySpec::new(&path)
        };
        let mut replay = McapReplay::open(&spec, &CaptureConfig::default()).unwrap();
        // The frame rate from the first two frames' device clocks (the recording's, not the
        // replay speed's).
        assert_eq!(replay.info().fps, 30.0);
        let before_first = Instant::now();
        let first = replay.next_frame().unwrap().unwrap();
        assert!(first.host_rx >= before_first);
        let second = replay.next_frame().unwrap().unwrap();
        let handed_out = Instant::now();
        // Due 133 ms after the first frame's anchor, which was set after `before_first`.
        assert!(
            second.host_rx >= before_first + Duration::from_millis(130),
            "stamped {:?} after the first call began: before the pacing sleep",
            second.host_rx - before_first
        );
        assert!(second.host_rx <= handed_out);
        let third = replay.next_frame().unwrap().unwrap();
        assert_eq!(
            [first.seq, second.seq, third.seq],
            [0, 1, 2],
            "the frames read ahead at open come first, in order"
        );
        assert!(replay.next_frame().unwrap().is_none());
    }
}
