//! `mouthpiece record --audio`: the microphone on its own thread beside the frames, written
//! to the session as the takes write it: `/audio` (Foxglove `RawAudio`, `pcm-s16`),
//! `/audio/events` (started, gap, stopped) and a `mouthpiece.audio` summary record.
//!
//! Clock: every block is stamped with the wall clock at the host instant of its first sample
//! (as the daemon stamps it), and the recorder stamps every frame with the wall clock at its
//! host receipt, so sound and frames share one clock whatever the camera's own clock is.
//! A device lost mid-recording ends the sound only: the video goes on and the session says
//! where the sound stopped.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{SystemTime, UNIX_EPOCH};

use crossbeam_channel::{Receiver, Sender};
use mouthpiece_frame::{AudioBlock, AudioFormat, AudioSource, AudioSourceInfo};
use mouthpiece_recording::{RecordingError, SessionWriter, TOPIC_AUDIO_EVENTS};
use serde_json::json;

enum Event {
    Block(AudioBlock),
    Stopped { reason: String, at: SystemTime },
}

/// Wall-clock ns since the Unix epoch, at microsecond resolution (as takes stamp sound).
fn ns(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64 * 1000)
}

/// The audio thread and what it has delivered so far.
pub struct AudioRecorder {
    info: AudioSourceInfo,
    rx: Receiver<Event>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    format: Option<AudioFormat>,
    blocks: u64,
    sample_frames: u64,
    expected_frame: u64,
    gaps: u64,
    first_ns: Option<u64>,
    end_ns: Option<u64>,
    stopped: Option<(u64, String)>,
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
            format: None,
            blocks: 0,
            sample_frames: 0,
            expected_frame: 0,
            gaps: 0,
            first_ns: None,
            end_ns: None,
            stopped: None,
        })
    }

    /// Writes the `started` event (at the recording's start).
    pub fn begin(&mut self, writer: &mut SessionWriter) -> Result<(), RecordingError> {
        let now = ns(SystemTime::now());
        writer.write_json(
            TOPIC_AUDIO_EVENTS,
            now,
            &json!({
                "event": "started",
                "wall_us": now / 1000,
                "device": self.info.spec,
                "description": self.info.description,
                "sample_rate": self.info.format.sample_rate,
                "channels": self.info.format.channels,
            }),
        )
    }

    /// Writes what the thread delivered since the last call.
    pub fn drain(&mut self, writer: &mut SessionWriter) -> Result<(), RecordingError> {
        while let Ok(event) = self.rx.try_recv() {
            self.write(writer, event)?;
        }
        Ok(())
    }

    fn write(&mut self, writer: &mut SessionWriter, event: Event) -> Result<(), RecordingError> {
        match event {
            Event::Block(block) => {
                let log_time = ns(block.wall_clock.unwrap_or_else(SystemTime::now));
                if block.first_frame > self.expected_frame {
                    self.gaps += 1;
                    writer.write_json(
                        TOPIC_AUDIO_EVENTS,
                        log_time,
                        &json!({
                            "event": "gap",
                            "wall_us": log_time / 1000,
                            "missing_frames": block.first_frame - self.expected_frame,
                        }),
                    )?;
                }
                self.format.get_or_insert(block.format);
                self.first_ns.get_or_insert(log_time);
                writer.write_audio(log_time, block.format, &block.samples)?;
                self.blocks += 1;
                self.sample_frames += block.frames();
                self.expected_frame = block.first_frame + block.frames();
                self.end_ns =
                    Some(log_time + block.format.duration_of(block.frames()).as_nanos() as u64);
                Ok(())
            }
            Event::Stopped { reason, at } => {
                let at = ns(at);
                self.stopped = Some((at, reason.clone()));
                writer.write_json(
                    TOPIC_AUDIO_EVENTS,
                    at,
                    &json!({
                        "event": "stopped",
                        "wall_us": at / 1000,
                        "reason": reason,
                        "device_frames": self.expected_frame,
                    }),
                )
            }
        }
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
        let mut m = BTreeMap::new();
        let mut put = |k: &str, v: String| {
            m.insert(k.to_owned(), v);
        };
        put("device", self.info.spec.clone());
        let format = self.format.unwrap_or(self.info.format);
        put("sample_rate", format.sample_rate.to_string());
        put("channels", format.channels.to_string());
        put("blocks", self.blocks.to_string());
        put("sample_frames", self.sample_frames.to_string());
        put("dropped_blocks", "0".to_owned());
        put("gaps", self.gaps.to_string());
        if let Some(first) = self.first_ns {
            put("first_unix_us", (first / 1000).to_string());
        }
        if let Some(end) = self.end_ns {
            put("end_unix_us", (end / 1000).to_string());
        }
        if let Some((at, reason)) = &self.stopped {
            put("stopped_unix_us", (at / 1000).to_string());
            put("stop_reason", reason.clone());
        }
        writer.write_metadata("mouthpiece.audio", m)?;
        Ok(self.stopped.take().map(|s| s.1))
    }
}

impl Drop for AudioRecorder {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
    }
}

/// The thread: blocks out, stamped on the wall clock, until stopped or the source fails.
fn read(source: &mut dyn AudioSource, tx: &Sender<Event>, stop: &AtomicBool) {
    let mut last_wall = None;
    while !stop.load(Ordering::Acquire) {
        let reason = match source.next_block() {
            Ok(Some(mut block)) => {
                let wall = SystemTime::now() - block.first_sample_at().elapsed();
                block.wall_clock = Some(wall);
                last_wall = Some(wall + block.format.duration_of(block.frames()));
                if tx.send(Event::Block(block)).is_err() {
                    return;
                }
                continue;
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
