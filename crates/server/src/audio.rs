//! The microphone as clients see it: the `audio` object of `status` (state, device, agreed
//! format, level meter with peak hold and clip warning, overruns, dropped blocks) and the
//! audio thread's counters for `/metrics` and `/healthz`. The daemon's audio thread sets both;
//! the server only reads them.

use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};

use serde::{Deserialize, Serialize};

/// Where the sound comes from now.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AudioState {
    /// No `[audio]` table and no sound in the replayed recording.
    #[default]
    Off,
    /// Configured, but the device cannot be opened or was lost; retried with backoff.
    NoDevice,
    /// A microphone delivers sound.
    Live,
    /// The sound of a replayed recording.
    Replay,
}

impl AudioState {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Off => "off",
            Self::NoDevice => "no_device",
            Self::Live => "live",
            Self::Replay => "replay",
        }
    }
}

/// Level of silence in the meter, dBFS (the meter never says `-inf`).
pub const SILENCE_DBFS: f64 = -120.0;

/// The `audio` object of `status`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AudioStatus {
    pub state: AudioState,
    /// The device (ALSA PCM name) or `replay:FILE`; empty when off.
    pub device: String,
    /// What the device agreed to (0 until opened).
    pub sample_rate: u32,
    pub channels: u32,
    /// RMS level over the last ~100 ms, dBFS (full-scale square wave = 0).
    pub level_dbfs: f64,
    /// Highest sample over the last ~2 s, dBFS.
    pub peak_dbfs: f64,
    /// A sample at or above −1 dBFS within the last ~2 s.
    pub clip: bool,
    /// Overruns (xruns) recovered from since the daemon started.
    pub overruns: u64,
    /// Blocks dropped from consumers' queues since the daemon started.
    pub dropped_blocks: u64,
}

impl Default for AudioStatus {
    fn default() -> Self {
        AudioStatus {
            state: AudioState::Off,
            device: String::new(),
            sample_rate: 0,
            channels: 0,
            level_dbfs: SILENCE_DBFS,
            peak_dbfs: SILENCE_DBFS,
            clip: false,
            overruns: 0,
            dropped_blocks: 0,
        }
    }
}

/// The audio thread's counters (`/metrics`).
#[derive(Debug, Default)]
pub struct AudioCounters {
    /// Blocks received from the device.
    pub blocks: AtomicU64,
    /// Blocks dropped from consumers' queues (oldest first).
    pub dropped: AtomicU64,
    /// Overruns (xruns) recovered from.
    pub overruns: AtomicU64,
    /// Attempts to open (or reopen) the device.
    pub reopen_attempts: AtomicU64,
}

impl AudioCounters {
    /// Appends the Prometheus text.
    pub fn render_metrics(&self, out: &mut String) {
        for (name, help, counter) in [
            (
                "mouthpiece_audio_blocks_total",
                "Audio blocks received from the device.",
                &self.blocks,
            ),
            (
                "mouthpiece_audio_dropped_blocks_total",
                "Audio blocks dropped from consumers' queues (oldest first).",
                &self.dropped,
            ),
            (
                "mouthpiece_audio_overruns_total",
                "Audio device overruns (xruns) recovered from.",
                &self.overruns,
            ),
            (
                "mouthpiece_audio_open_attempts_total",
                "Attempts to open or reopen the audio device.",
                &self.reopen_attempts,
            ),
        ] {
            let _ = writeln!(
                out,
                "# HELP {name} {help}\n# TYPE {name} counter\n{name} {}",
                counter.load(Ordering::Relaxed)
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_status_object_has_exactly_the_documented_fields() {
        let value = serde_json::to_value(AudioStatus::default()).unwrap();
        let mut keys: Vec<_> = value.as_object().unwrap().keys().cloned().collect();
        keys.sort();
        assert_eq!(
            keys,
            [
                "channels",
                "clip",
                "device",
                "dropped_blocks",
                "level_dbfs",
                "overruns",
                "peak_dbfs",
                "sample_rate",
                "state"
            ]
        );
        assert_eq!(value["state"], "off");
        let no_device = AudioStatus {
            state: AudioState::NoDevice,
            ..AudioStatus::default()
        };
        assert_eq!(
            serde_json::to_value(no_device).unwrap()["state"],
            "no_device"
        );
    }

    #[test]
    fn counters_show_in_metrics() {
        let counters = AudioCounters::default();
        counters.overruns.fetch_add(2, Ordering::Relaxed);
        let mut text = String::new();
        counters.render_metrics(&mut text);
        assert!(text.contains("mouthpiece_audio_overruns_total 2"), "{text}");
        assert!(text.contains("mouthpiece_audio_blocks_total 0"), "{text}");
    }
}
