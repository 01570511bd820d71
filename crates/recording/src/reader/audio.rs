//! [`AudioReader`]: a session's sound (`/audio`, Foxglove `RawAudio` `pcm-s16`) as blocks of
//! samples with their log times, in file order.

use std::path::Path;

use mouthpiece_frame::AudioFormat;

use crate::cdr::RawAudio;
use crate::{MessageReader, RecordingError};

/// Highest sample rate a recording may claim, Hz.
pub const MAX_AUDIO_RATE: u32 = 768_000;
/// Most channels a recording may claim.
pub const MAX_AUDIO_CHANNELS: u32 = 256;

/// One `/audio` message.
#[derive(Debug, Clone, PartialEq)]
pub struct AudioMessage {
    /// Wall-clock time of the first sample, ns since the Unix epoch (the frames' clock).
    pub log_time: u64,
    pub format: AudioFormat,
    /// Interleaved samples.
    pub samples: Vec<i16>,
}

impl AudioMessage {
    /// Sample frames in the message.
    pub fn frames(&self) -> u64 {
        (self.samples.len() / usize::from(self.format.channels.max(1))) as u64
    }
}

/// The `/audio` messages of a session, in file order.
pub struct AudioReader {
    messages: MessageReader,
}

impl AudioReader {
    pub fn open(path: impl AsRef<Path>) -> Result<AudioReader, RecordingError> {
        Ok(AudioReader {
            messages: MessageReader::open(path)?,
        })
    }

    /// Starts again from the first message.
    pub fn rewind(&mut self) -> Result<(), RecordingError> {
        self.messages.rewind()
    }

    /// The next `/audio` message, `Ok(None)` at the end.
    pub fn next_audio(&mut self) -> Result<Option<AudioMessage>, RecordingError> {
        while let Some(message) = self.messages.next_message()? {
            if &*message.topic != crate::TOPIC_AUDIO {
                continue;
            }
            let path = self.messages.path().display().to_string();
            let bad = |what: String| RecordingError::Decode {
                path: path.clone(),
                topic: crate::TOPIC_AUDIO.into(),
                log_time: message.log_time,
                what,
                source: None,
            };
            let raw = RawAudio::decode(&message.data).map_err(|e| RecordingError::Decode {
                path: path.clone(),
                topic: crate::TOPIC_AUDIO.into(),
                log_time: message.log_time,
                what: "not a RawAudio message".into(),
                source: Some(Box::new(e)),
            })?;
            if raw.format != "pcm-s16" {
                return Err(bad(format!(
                    "format {} is not pcm-s16",
                    crate::excerpt(&raw.format)
                )));
            }
            if !(1..=MAX_AUDIO_RATE).contains(&raw.sample_rate)
                || !(1..=MAX_AUDIO_CHANNELS).contains(&raw.number_of_channels)
            {
                return Err(bad(format!(
                    "{} Hz, {} channels is not a usable format (1 to {MAX_AUDIO_RATE} Hz, 1 to {MAX_AUDIO_CHANNELS} channels)",
                    raw.sample_rate, raw.number_of_channels
                )));
            }
            let frame_bytes = 2 * raw.number_of_channels as usize;
            if raw.data.len() % frame_bytes != 0 {
                return Err(bad(format!(
                    "{} bytes of data is not a whole number of {}-channel 16-bit sample frames",
                    raw.data.len(),
                    raw.number_of_channels
                )));
            }
            let samples = raw
                .data
                .chunks_exact(2)
                .map(|b| i16::from_le_bytes([b[0], b[1]]))
                .collect();
            return Ok(Some(AudioMessage {
                log_time: message.log_time,
                format: AudioFormat {
                    sample_rate: raw.sample_rate,
                    channels: raw.number_of_channels as u16,
                },
                samples,
            }));
        }
        Ok(None)
    }

    /// Whether the session has any sound (reads until the first `/audio` message).
    pub fn has_audio(path: impl AsRef<Path>) -> Result<bool, RecordingError> {
        Ok(AudioReader::open(path)?.next_audio()?.is_some())
    }
}
