//! Audio blocks and the [`AudioSource`] trait: the booth's microphone, or a recording's sound
//! played back, as the same stream of blocks.
//!
//! Samples are signed 16-bit, interleaved by channel, in the format the device agreed to
//! (read back from the device, never assumed). Each block carries the same clocks as a
//! [`crate::Frame`]: the host's monotonic time at which it was received and, when known, the
//! wall clock, so the offset between sound and picture can be computed and measured.

use std::time::{Duration, Instant, SystemTime};

use serde::{Deserialize, Serialize};

use crate::SourceError;

/// What an audio device agreed to deliver.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct AudioFormat {
    /// Samples per second per channel.
    pub sample_rate: u32,
    /// Interleaved channels per sample frame.
    pub channels: u16,
}

impl AudioFormat {
    /// How long `frames` sample frames last at this rate.
    pub fn duration_of(&self, frames: u64) -> Duration {
        if self.sample_rate == 0 {
            return Duration::ZERO;
        }
        Duration::from_nanos(
            ((frames as u128 * 1_000_000_000) / self.sample_rate as u128).min(u64::MAX as u128)
                as u64,
        )
    }
}

/// One block of sound, as a source delivers it.
#[derive(Debug, Clone)]
pub struct AudioBlock {
    /// Counts blocks delivered by this source, from 0.
    pub seq: u64,
    /// Index of this block's first sample frame since the stream started (gaps from overruns
    /// show as jumps, so a consumer knows where sound is missing).
    pub first_frame: u64,
    pub format: AudioFormat,
    /// `frames * channels` samples, interleaved.
    pub samples: Vec<i16>,
    /// Host monotonic time at which the block's last sample was received (the first sample
    /// was captured `format.duration_of(frames)` earlier).
    pub host_rx: Instant,
    /// Wall-clock time of the block's first sample, when known.
    pub wall_clock: Option<SystemTime>,
}

impl AudioBlock {
    /// Sample frames in the block (samples per channel).
    pub fn frames(&self) -> u64 {
        if self.format.channels == 0 {
            return 0;
        }
        (self.samples.len() / self.format.channels as usize) as u64
    }

    /// Host monotonic time at which the block's first sample was captured.
    pub fn first_sample_at(&self) -> Instant {
        let span = self.format.duration_of(self.frames());
        self.host_rx.checked_sub(span).unwrap_or(self.host_rx)
    }
}

/// What an audio source actually runs at.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AudioSourceInfo {
    /// The spec it was opened from, e.g. an ALSA PCM name or `replay:take.mcap`.
    pub spec: String,
    /// Human-readable description of the device.
    pub description: String,
    /// The format the device agreed to.
    pub format: AudioFormat,
    /// Sample frames per block the source delivers (the ALSA period), 0 when it varies.
    pub frames_per_block: u32,
    /// True for devices: blocks arrive in real time and can be overrun.
    pub live: bool,
}

/// A producer of audio blocks.
///
/// Blocking by design, like [`crate::FrameSource`]: audio runs on a thread of its own.
/// `next_block` returns `Ok(None)` at the end of a finite source.
pub trait AudioSource: Send {
    fn info(&self) -> &AudioSourceInfo;

    /// The next block, waiting for it if necessary.
    fn next_block(&mut self) -> Result<Option<AudioBlock>, SourceError>;

    /// Overruns (xruns) the device reported and this source recovered from.
    fn overruns(&self) -> u64 {
        0
    }
}

impl<S: AudioSource + ?Sized> AudioSource for Box<S> {
    fn info(&self) -> &AudioSourceInfo {
        (**self).info()
    }
    fn next_block(&mut self) -> Result<Option<AudioBlock>, SourceError> {
        (**self).next_block()
    }
    fn overruns(&self) -> u64 {
        (**self).overruns()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_block_knows_its_length_and_first_sample_time() {
        let format = AudioFormat {
            sample_rate: 48_000,
            channels: 2,
        };
        let host_rx = Instant::now() + Duration::from_secs(1);
        let block = AudioBlock {
            seq: 0,
            first_frame: 0,
            format,
            samples: vec![0; 960 * 2],
            host_rx,
            wall_clock: None,
        };
        assert_eq!(block.frames(), 960);
        assert_eq!(host_rx - block.first_sample_at(), Duration::from_millis(20));
    }
}
