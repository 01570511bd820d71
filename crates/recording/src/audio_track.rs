//! A recording's sound as takes and `record --audio` write it: `/audio` blocks at the wall
//! clock of their first sample, `/audio/events` (started, gap, stopped) and the
//! `mouthpiece.audio` summary record (docs/recording-format.md, "Sound").

use std::collections::BTreeMap;
use std::io::{Seek, Write};
use std::time::{SystemTime, UNIX_EPOCH};

use mouthpiece_frame::{AudioBlock, AudioEvent, AudioFormat, AudioSourceInfo};
use serde_json::json;

use crate::{RecordingError, SessionWriter, TOPIC_AUDIO_EVENTS};

/// What an [`AudioTrack`] writes to: a session or a take.
pub trait AudioSink {
    /// A JSON message on `topic` at `log_time` (ns).
    fn write_json_value(
        &mut self,
        topic: &str,
        log_time: u64,
        value: &serde_json::Value,
    ) -> Result<(), RecordingError>;
    /// A block of sound on `/audio`, its first sample at `log_time` (ns).
    fn write_audio(
        &mut self,
        log_time: u64,
        format: AudioFormat,
        samples: &[i16],
    ) -> Result<(), RecordingError>;
    /// A metadata record.
    fn write_metadata(
        &mut self,
        name: &str,
        metadata: BTreeMap<String, String>,
    ) -> Result<(), RecordingError>;
}

impl<W: Write + Seek> AudioSink for SessionWriter<W> {
    fn write_json_value(
        &mut self,
        topic: &str,
        log_time: u64,
        value: &serde_json::Value,
    ) -> Result<(), RecordingError> {
        self.write_json(topic, log_time, value)
    }

    fn write_audio(
        &mut self,
        log_time: u64,
        format: AudioFormat,
        samples: &[i16],
    ) -> Result<(), RecordingError> {
        SessionWriter::write_audio(self, log_time, format, samples)
    }

    fn write_metadata(
        &mut self,
        name: &str,
        metadata: BTreeMap<String, String>,
    ) -> Result<(), RecordingError> {
        SessionWriter::write_metadata(self, name, metadata)
    }
}

/// Wall-clock ns since the Unix epoch, at microsecond resolution (0 before the epoch).
pub fn wall_ns(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64 * 1000)
}

/// A recording's sound so far: what it wrote and where it had gaps or stopped, for the
/// summary record.
#[derive(Debug, Default)]
pub struct AudioTrack {
    device: Option<String>,
    format: Option<AudioFormat>,
    blocks: u64,
    sample_frames: u64,
    /// The next block's `first_frame` if nothing is lost (`None`: no device open).
    expected_frame: Option<u64>,
    gaps: u64,
    first_ns: Option<u64>,
    /// Wall-clock ns just after the last sample written.
    end_ns: Option<u64>,
    stopped: Option<(u64, String)>,
}

impl AudioTrack {
    /// Writes one event of the audio thread's bus.
    pub fn write(
        &mut self,
        sink: &mut dyn AudioSink,
        event: AudioEvent,
    ) -> Result<(), RecordingError> {
        match event {
            AudioEvent::Started(info) => self.started(sink, &info),
            AudioEvent::Block(block) => self.block(sink, &block),
            AudioEvent::Stopped { reason, at, frames } => self.stopped(sink, &reason, at, frames),
        }
    }

    /// A device opened now: the `started` event.
    pub fn started(
        &mut self,
        sink: &mut dyn AudioSink,
        info: &AudioSourceInfo,
    ) -> Result<(), RecordingError> {
        let now = wall_ns(SystemTime::now());
        self.device = Some(info.spec.clone());
        self.format = Some(info.format);
        self.expected_frame = Some(0);
        sink.write_json_value(
            TOPIC_AUDIO_EVENTS,
            now,
            &json!({
                "event": "started",
                "wall_us": now / 1000,
                "device": info.spec,
                "description": info.description,
                "sample_rate": info.format.sample_rate,
                "channels": info.format.channels,
            }),
        )
    }

    /// A block of sound, at the wall clock of its first sample (a block without one is left
    /// out), after a `gap` event when frames were lost before it.
    pub fn block(
        &mut self,
        sink: &mut dyn AudioSink,
        block: &AudioBlock,
    ) -> Result<(), RecordingError> {
        let Some(wall) = block.wall_clock else {
            return Ok(());
        };
        let log_time = wall_ns(wall);
        if let Some(expected) = self.expected_frame {
            if block.first_frame > expected {
                self.gaps += 1;
                sink.write_json_value(
                    TOPIC_AUDIO_EVENTS,
                    log_time,
                    &json!({
                        "event": "gap",
                        "wall_us": log_time / 1000,
                        "missing_frames": block.first_frame - expected,
                    }),
                )?;
            }
        }
        self.format.get_or_insert(block.format);
        self.first_ns.get_or_insert(log_time);
        sink.write_audio(log_time, block.format, &block.samples)?;
        self.blocks += 1;
        self.sample_frames += block.frames();
        self.expected_frame = Some(block.first_frame + block.frames());
        self.end_ns = Some(log_time + block.format.duration_of(block.frames()).as_nanos() as u64);
        Ok(())
    }

    /// The device was lost at `at` (just after its last sample delivered) having delivered
    /// `device_frames`: the `stopped` event.
    pub fn stopped(
        &mut self,
        sink: &mut dyn AudioSink,
        reason: &str,
        at: SystemTime,
        device_frames: u64,
    ) -> Result<(), RecordingError> {
        let at = wall_ns(at);
        self.stopped = Some((at, reason.to_owned()));
        self.expected_frame = None;
        sink.write_json_value(
            TOPIC_AUDIO_EVENTS,
            at,
            &json!({
                "event": "stopped",
                "wall_us": at / 1000,
                "reason": reason,
                "device_frames": device_frames,
            }),
        )
    }

    /// Sample frames the device has delivered up to the last block (0 before any).
    pub fn device_frames(&self) -> u64 {
        self.expected_frame.unwrap_or(0)
    }

    /// Why the sound stopped early, if it did.
    pub fn stop_reason(&self) -> Option<&str> {
        self.stopped.as_ref().map(|(_, reason)| reason.as_str())
    }

    /// Writes the `mouthpiece.audio` record: what sound the recording holds, how many blocks
    /// were `dropped` before they reached the writer, and where it stopped.
    pub fn finish(&self, sink: &mut dyn AudioSink, dropped: u64) -> Result<(), RecordingError> {
        let mut m = BTreeMap::new();
        let mut put = |k: &str, v: String| {
            m.insert(k.to_owned(), v);
        };
        put("device", self.device.clone().unwrap_or_default());
        if let Some(format) = self.format {
            put("sample_rate", format.sample_rate.to_string());
            put("channels", format.channels.to_string());
        }
        put("blocks", self.blocks.to_string());
        put("sample_frames", self.sample_frames.to_string());
        put("dropped_blocks", dropped.to_string());
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
        sink.write_metadata("mouthpiece.audio", m)
    }
}
