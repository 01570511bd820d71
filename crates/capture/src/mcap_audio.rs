//! A recording's sound (`/audio`) played back as an [`AudioSource`], paced with the same
//! recording's frames: each block is handed out at the host instant its log time is due on
//! the frames' [`ReplayClock`], so the daemon stamps sound and picture as they were recorded
//! relative to each other. It waits for the frames' first anchor, starts again when they
//! loop or jump, and waits at the end of its sound for the frames' next loop (a replay's
//! sound never ends by itself). At `speed` ≠ 1 the blocks are paced at that speed, not
//! resampled.

use std::sync::Arc;
use std::time::{Duration, Instant};

use mouthpiece_frame::{AudioBlock, AudioSource, AudioSourceInfo, SourceError};
use mouthpiece_recording::{AudioReader, RecordingError};

use crate::pace::{ClockAnchor, ReplayClock};
use crate::spec::{ReplaySpec, SourceSpec};

/// How often a waiting replay looks at the frames' clock again.
const POLL: Duration = Duration::from_millis(10);

pub struct McapAudioReplay {
    reader: AudioReader,
    clock: Arc<ReplayClock>,
    info: AudioSourceInfo,
    seq: u64,
    frames_out: u64,
    generation: Option<u64>,
}

fn error(spec: &str, err: RecordingError) -> SourceError {
    SourceError::Format {
        spec: spec.to_owned(),
        message: "cannot read the recording's sound".into(),
        cause: Some(Box::new(err)),
    }
}

impl McapAudioReplay {
    /// Opens the sound of `replay`'s file; an error when it has none.
    pub fn open(replay: &ReplaySpec) -> Result<McapAudioReplay, SourceError> {
        let spec = SourceSpec::Replay(replay.clone()).to_string();
        let mut reader = AudioReader::open(&replay.path).map_err(|e| error(&spec, e))?;
        let first = reader
            .next_audio()
            .map_err(|e| error(&spec, e))?
            .ok_or_else(|| SourceError::Open {
                spec: spec.clone(),
                message: format!("{} has no sound (/audio)", replay.path.display()),
                cause: None,
            })?;
        reader.rewind().map_err(|e| error(&spec, e))?;
        let info = AudioSourceInfo {
            spec: spec.clone(),
            description: format!(
                "the sound of {}: {} Hz, {} ch",
                replay.path.display(),
                first.format.sample_rate,
                first.format.channels
            ),
            format: first.format,
            frames_per_block: first.frames() as u32,
            live: false,
        };
        Ok(McapAudioReplay {
            reader,
            clock: ReplayClock::for_path(&replay.path),
            info,
            seq: 0,
            frames_out: 0,
            generation: None,
        })
    }

    /// The frames' anchor, waiting for the first one.
    fn anchor(&self) -> ClockAnchor {
        loop {
            if let Some(anchor) = self.clock.anchor() {
                return anchor;
            }
            std::thread::sleep(POLL);
        }
    }

    /// Sleeps until `until`, or returns false early when the frames' clock was re-anchored.
    fn sleep_until(&self, until: Instant, generation: u64) -> bool {
        loop {
            if self.clock.anchor().map(|a| a.generation) != Some(generation) {
                return false;
            }
            let now = Instant::now();
            if now >= until {
                return true;
            }
            std::thread::sleep((until - now).min(POLL));
        }
    }
}

impl AudioSource for McapAudioReplay {
    fn info(&self) -> &AudioSourceInfo {
        &self.info
    }

    fn next_block(&mut self) -> Result<Option<AudioBlock>, SourceError> {
        loop {
            let anchor = self.anchor();
            if self.generation != Some(anchor.generation) {
                self.generation = Some(anchor.generation);
                self.reader
                    .rewind()
                    .map_err(|e| error(&self.info.spec, e))?;
            }
            let Some(message) = self
                .reader
                .next_audio()
                .map_err(|e| error(&self.info.spec, e))?
            else {
                // The end of the sound: wait for the frames to loop.
                while self.clock.anchor().map(|a| a.generation) == Some(anchor.generation) {
                    std::thread::sleep(POLL);
                }
                continue;
            };
            if message.format != self.info.format {
                continue;
            }
            let span = message.format.duration_of(message.frames());
            if message.log_time + span.as_nanos() as u64 <= anchor.log_ns {
                continue; // before the frames' anchor (a loop or a seek past it)
            }
            let due = anchor.due(message.log_time);
            // Received when its last sample would have been.
            if !self.sleep_until(due + span, anchor.generation) {
                continue;
            }
            let frames = message.frames();
            let block = AudioBlock {
                seq: self.seq,
                first_frame: self.frames_out,
                format: message.format,
                samples: message.samples,
                host_rx: due + span,
                wall_clock: None,
            };
            self.seq += 1;
            self.frames_out += frames;
            return Ok(Some(block));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mcap_replay::McapReplay;
    use crate::CaptureConfig;
    use mouthpiece_frame::{
        AudioFormat, Calibration, ColorImage, DepthImage, Frame, FrameSource, Intrinsics,
    };
    use mouthpiece_recording::{SessionWriter, WriterOptions};

    /// The sound of a replay is due at the instants its frames are: a block recorded with
    /// frame k's log time starts at the host instant frame k is due.
    #[test]
    fn a_recordings_sound_is_paced_with_its_frames() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.mcap");
        let mut writer = SessionWriter::create(&path, WriterOptions::default()).unwrap();
        let calibration = Arc::new(Calibration::registered(Intrinsics::ideal(
            8, 8, 8.0, 8.0, 4.0, 4.0,
        )));
        let format = AudioFormat {
            sample_rate: 48_000,
            channels: 1,
        };
        for i in 0..6u64 {
            writer
                .write_frame(&Frame {
                    seq: i,
                    device_ts_us: 1_000_000 + i * 33_333,
                    host_rx: Instant::now(),
                    wall_clock: None,
                    color: ColorImage::new(8, 8),
                    depth: DepthImage::new(8, 8),
                    calibration: calibration.clone(),
                })
                .unwrap();
            // 1600 samples (one frame's worth) starting with the frame.
            writer
                .write_audio(
                    (1_000_000 + i * 33_333) * 1000,
                    format,
                    &vec![i as i16; 1600],
                )
                .unwrap();
        }
        writer.finish().unwrap();
        let spec = ReplaySpec {
            speed: Some(1.0),
            ..ReplaySpec::new(&path)
        };
        let mut frames = McapReplay::open(&spec, &CaptureConfig::default()).unwrap();
        let mut sound = McapAudioReplay::open(&spec).unwrap();
        assert_eq!(sound.info().format, format);
        frames.next_frame().unwrap().unwrap();
        let anchor = sound.clock.anchor().expect("the frames anchored the clock");
        for i in 0..6u64 {
            let block = sound.next_block().unwrap().unwrap();
            assert_eq!(block.samples, vec![i as i16; 1600], "in order, as recorded");
            assert_eq!(block.first_frame, i * 1600);
            assert_eq!(
                block.first_sample_at(),
                anchor.due((1_000_000 + i * 33_333) * 1000),
                "block {i} starts when frame {i} is due"
            );
        }
    }
}
