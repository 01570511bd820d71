//! `mouthpiece record --audio`: the microphone on its own thread beside the frames, written
//! to the session as the takes write it: `/audio` (Foxglove `RawAudio`, `pcm-s16`),
//! `/audio/events` (started, gap, stopped) and a `mouthpiece.audio` summary record.
//!
//! Clock: every block is stamped with the wall clock at the host instant of its first sample
//! (as the daemon stamps it), and the recorder stamps every frame with the wall clock at its
//! host receipt, so sound and frames share one clock whatever the camera's own clock is.
//! A device lost mid-recording ends the sound only: the video goes on and the session says
//! where the sound stopped.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime};

use crossbeam_channel::{Receiver, Sender};
use mouthpiece_frame::{AudioBlock, AudioSource, AudioSourceInfo};
use mouthpiece_recording::{AudioTrack, RecordingError, SessionWriter};

enum Event {
    Block(AudioBlock),
    Stopped { reason: String, at: SystemTime },
}

/// The audio thread and what it has delivered so far.
pub struct AudioRecorder {
    info: AudioSourceInfo,
    rx: Receiver<Event>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    /// What was written, as a take's sound is (counters, events, the summary).
    track: AudioTrack,
}

impl AudioRecorder {
    /// Starts reading `source` on its own thread.
    pub fn start(mut source: Box<dyn AudioSource>) -> std::io::Result<AudioRecorder> {
        let info = source.info().clone();
        // Ten minutes of 10 ms blocks: a writer that falls further behind makes the device
        // overrun, which shows as a gap.
        let (tx, rx) = crossbeam_channel::bounded(60_000);
        let stop = Arc::new(AtomicBool::new(false));
        let stopping = stop.clone();
        let thread = std::thread::Builder::new()
            .name("mouthpiece-record-audio".into())
            .spawn(move || read(source.as_mut(), &tx, &stopping))?;
        Ok(AudioRecorder {
            info,
            rx,
            stop,
            thread: Some(thread),
            track: AudioTrack::default(),
        })
    }

    /// Writes the `started` event (at the recording's start).
    pub fn begin(&mut self, writer: &mut SessionWriter) -> Result<(), RecordingError> {
        self.track.started(writer, &self.info)
    }

    /// Writes what the thread had delivered when called: only that many events, so a
    /// device that never blocks (ALSA's `null`) and refills the queue as fast as it is
    /// emptied cannot keep the recording in here (the frames, and `--seconds`, go on).
    pub fn drain(&mut self, writer: &mut SessionWriter) -> Result<(), RecordingError> {
        for _ in 0..self.rx.len() {
            let Ok(event) = self.rx.try_recv() else {
                break;
            };
            match event {
                Event::Block(block) => self.track.block(writer, &block)?,
                Event::Stopped { reason, at } => {
                    let frames = self.track.device_frames();
                    self.track.stopped(writer, &reason, at, frames)?
                }
            }
        }
        Ok(())
    }

    /// Stops the thread, writes what is left and the `mouthpiece.audio` summary. Returns why
    /// the sound stopped early, if it did.
    pub fn finish(mut self, writer: &mut SessionWriter) -> Result<Option<String>, RecordingError> {
        self.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            // Drained meanwhile, so that a thread waiting on a full channel can end.
            while !thread.is_finished() {
                self.drain(writer)?;
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
            let _ = thread.join();
        }
        self.drain(writer)?;
        self.track.finish(writer, 0)?;
        Ok(self.track.stop_reason().map(str::to_owned))
    }
}

impl Drop for AudioRecorder {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
    }
}

/// How far the sound may run ahead of the wall clock (a device's buffer filled at the start
/// comes at once) before the device counts as broken: one that never blocks (ALSA's `null`)
/// would otherwise fill the session with silence as fast as the disk takes it.
const MAX_AHEAD: Duration = Duration::from_secs(2);

/// The thread: blocks out, stamped on the wall clock, until stopped or the source fails.
fn read(source: &mut dyn AudioSource, tx: &Sender<Event>, stop: &AtomicBool) {
    let mut last_wall = None;
    let started = Instant::now();
    let mut delivered = Duration::ZERO;
    while !stop.load(Ordering::Acquire) {
        let reason = match source.next_block() {
            Ok(Some(mut block)) => {
                let length = block.format.duration_of(block.frames());
                delivered += length;
                let elapsed = started.elapsed();
                if delivered > elapsed + MAX_AHEAD {
                    format!(
                        "the device delivers sound faster than real time ({:.1} s of sound in \
                         {:.1} s)",
                        delivered.as_secs_f64(),
                        elapsed.as_secs_f64()
                    )
                } else {
                    let wall = SystemTime::now() - block.first_sample_at().elapsed();
                    block.wall_clock = Some(wall);
                    last_wall = Some(wall + length);
                    if tx.send(Event::Block(block)).is_err() {
                        return;
                    }
                    continue;
                }
            }
            Ok(None) => "the audio source ended".to_owned(),
            Err(err) => {
                let mut text = err.to_string();
                let mut cause = std::error::Error::source(&err);
                while let Some(c) = cause {
                    text.push_str(": ");
                    text.push_str(&c.to_string());
                    cause = c.source();
                }
                text
            }
        };
        tracing::warn!(device = %source.info().spec, "sound lost; the video goes on: {reason}");
        let at = last_wall.unwrap_or_else(SystemTime::now);
        let _ = tx.send(Event::Stopped { reason, at });
        return;
    }
}
