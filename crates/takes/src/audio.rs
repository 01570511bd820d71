//! A take's sound: `/audio` blocks, `/audio/events` (started, gap, stopped) and the
//! `mouthpiece.audio` summary record, from the audio thread's events.

use std::collections::BTreeMap;

use mouthpiece_frame::{AudioEvent, AudioFormat};
use mouthpiece_recording::{RecordingError, TOPIC_AUDIO_EVENTS};
use serde_json::json;

use crate::file::unix_us;
use crate::writer::TakeWriter;

/// What the take's sound was, for the summary.
#[derive(Debug, Default)]
pub(crate) struct AudioTrack {
    device: Option<String>,
    format: Option<AudioFormat>,
    blocks: u64,
    sample_frames: u64,
    /// The next block's `first_frame` if nothing is lost.
    expected_frame: Option<u64>,
    gaps: u64,
    first_ns: Option<u64>,
    /// Wall-clock ns just after the last sample written.
    end_ns: Option<u64>,
    stopped: Option<(u64, String)>,
}

fn ns(t: std::time::SystemTime) -> u64 {
    unix_us(t).max(0) as u64 * 1000
}

impl AudioTrack {
    pub(crate) fn write(
        &mut self,
        writer: &mut TakeWriter,
        event: AudioEvent,
    ) -> Result<(), RecordingError> {
        match event {
            AudioEvent::Started(info) => {
                let now = ns(std::time::SystemTime::now());
                self.device = Some(info.spec.clone());
                self.format = Some(info.format);
                self.expected_frame = Some(0);
                writer.write_json(
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
            AudioEvent::Block(block) => {
                let Some(wall) = block.wall_clock else {
                    return Ok(());
                };
                let log_time = ns(wall);
                if let Some(expected) = self.expected_frame {
                    if block.first_frame > expected {
                        self.gaps += 1;
                        writer.write_json(
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
                writer.write_audio(log_time, block.format, &block.samples)?;
                self.blocks += 1;
                self.sample_frames += block.frames();
                self.expected_frame = Some(block.first_frame + block.frames());
                self.end_ns =
                    Some(log_time + block.format.duration_of(block.frames()).as_nanos() as u64);
                Ok(())
            }
            AudioEvent::Stopped { reason, at, frames } => {
                let at = ns(at);
                self.stopped = Some((at, reason.clone()));
                self.expected_frame = None;
                writer.write_json(
                    TOPIC_AUDIO_EVENTS,
                    at,
                    &json!({
                        "event": "stopped",
                        "wall_us": at / 1000,
                        "reason": reason,
                        "device_frames": frames,
                    }),
                )
            }
        }
    }

    /// Writes the `mouthpiece.audio` record: what sound the take holds and where it stopped.
    pub(crate) fn finish(
        &self,
        writer: &mut TakeWriter,
        dropped: u64,
    ) -> Result<(), RecordingError> {
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
        writer.write_metadata("mouthpiece.audio", m)
    }
}
