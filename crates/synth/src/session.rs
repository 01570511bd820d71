//! A synthetic session written to a file (`mouthpiece synth`): an MCAP session with ground
//! truth and, optionally, a WAV's sound on `/audio`; or an OpenNI2 `.oni` (by the output's
//! extension; frames and timestamps only, see `docs/capture.md`).

use std::path::{Path, PathBuf};

use mouthpiece_capture::oni_write::{OniFrameWriter, OniWriteError};
use mouthpiece_frame::AudioFormat;
use mouthpiece_recording::{ColorEncoding, RecordingError, SessionWriter, WriterOptions};

use crate::{MouthState, Synth, SynthConfig, SynthError, MAX_SECONDS};

/// What `mouthpiece synth` writes, and from what.
pub struct SessionOptions {
    pub config: SynthConfig,
    /// `.oni` by its extension, else MCAP.
    pub out: PathBuf,
    /// Colour encoding of an MCAP session (`.oni` colour is always lossless).
    pub color: ColorEncoding,
    /// Mouth keys replacing the seed's speech (from a weights CSV or Festival's line).
    pub speech: Option<Vec<(f64, MouthState)>>,
    /// A 16-bit PCM WAV (`--speech-audio`) written on `/audio`, sample 0 at the end of the
    /// neutral lead-in.
    pub sound: Option<PathBuf>,
}

/// What was written.
#[derive(Debug, Clone, Copy)]
pub struct SessionSummary {
    pub frames: u64,
    pub oni: bool,
    pub bytes: u64,
}

/// Why a session cannot be written.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error(transparent)]
    Synth(#[from] SynthError),
    #[error("--speech-audio and --speech-text need an MCAP session (--out NAME.mcap): .oni files hold no sound")]
    SoundInOni,
    #[error("--speech-audio {path}: not a readable WAV file")]
    WavOpen {
        path: PathBuf,
        #[source]
        source: hound::Error,
    },
    #[error("--speech-audio {path}: expected 16-bit PCM, 8000 to 192000 Hz, 1 to 32 channels; got {bits}-bit {format}, {rate} Hz, {channels} channels")]
    WavFormat {
        path: PathBuf,
        bits: u16,
        format: String,
        rate: u32,
        channels: u16,
    },
    #[error("--speech-audio {path}: {samples} samples is more than a day of sound")]
    WavTooLong { path: PathBuf, samples: u64 },
    #[error("--speech-audio {path}: cut short")]
    WavShort {
        path: PathBuf,
        #[source]
        source: hound::Error,
    },
    #[error("cannot write the session {path}")]
    OniCreate {
        path: PathBuf,
        #[source]
        source: OniWriteError,
    },
    #[error(transparent)]
    Oni(#[from] OniWriteError),
    #[error("cannot write the session {path}")]
    Create {
        path: PathBuf,
        #[source]
        source: RecordingError,
    },
    #[error(transparent)]
    Write(#[from] RecordingError),
}

impl SessionError {
    /// The caller's request or files, not the machine, are at fault (exit code 2).
    pub fn is_bad_input(&self) -> bool {
        match self {
            Self::Synth(_)
            | Self::SoundInOni
            | Self::WavOpen { .. }
            | Self::WavFormat { .. }
            | Self::WavTooLong { .. }
            | Self::WavShort { .. } => true,
            Self::OniCreate { source, .. } | Self::Oni(source) => source.is_bad_input(),
            Self::Create { .. } | Self::Write(_) => false,
        }
    }
}

/// Whether `out` names an `.oni` file.
pub fn is_oni(out: &Path) -> bool {
    out.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("oni"))
}

/// An `.oni` holds no sound: refused before anything is rendered (or spoken).
pub fn refuse_sound_in_oni(out: &Path, sound: bool) -> Result<(), SessionError> {
    if sound && is_oni(out) {
        return Err(SessionError::SoundInOni);
    }
    Ok(())
}

/// Renders the session and writes it; every input is checked before the file is created.
pub fn write_session(options: SessionOptions) -> Result<SessionSummary, SessionError> {
    let SessionOptions {
        config,
        out,
        color,
        speech,
        sound,
    } = options;
    let calibration = config.calibration();
    let neutral_seconds = config.neutral_seconds;
    let fps = config.fps;
    let mut synth = Synth::new(config)?;
    let oni = is_oni(&out);
    refuse_sound_in_oni(&out, sound.is_some())?;
    if let Some(keys) = speech {
        synth.set_speech(keys);
    }
    let total = synth.frame_count();
    let frames = if oni {
        let mut writer = OniFrameWriter::create(&out, &calibration, fps).map_err(|source| {
            SessionError::OniCreate {
                path: out.clone(),
                source,
            }
        })?;
        while let Some((frame, _truth)) = synth.render_next() {
            writer.write_frame(&frame)?;
        }
        writer.finish()?.depth_frames as u64
    } else {
        let mut sound = match &sound {
            Some(path) => Some(SpeechAudio::read(path, neutral_seconds)?),
            None => None,
        };
        let options = WriterOptions {
            color,
            ..WriterOptions::default()
        };
        let mut writer =
            SessionWriter::create(&out, options).map_err(|source| SessionError::Create {
                path: out.clone(),
                source,
            })?;
        while let Some((frame, truth)) = synth.render_next() {
            if let Some(sound) = &mut sound {
                sound.write_until(&mut writer, frame.device_ts_us * 1000)?;
            }
            writer.write_frame_with_ground_truth(&frame, Some(&truth))?;
        }
        if let Some(sound) = &mut sound {
            sound.write_until(&mut writer, u64::MAX)?;
        }
        writer.finish()?.frames
    };
    debug_assert_eq!(frames, total);
    Ok(SessionSummary {
        frames,
        oni,
        bytes: std::fs::metadata(&out).map(|m| m.len()).unwrap_or(0),
    })
}

/// A WAV's samples, written in 10 ms blocks at their true times.
struct SpeechAudio {
    format: AudioFormat,
    samples: Vec<i16>,
    /// Log time of sample 0, ns (the session's clock: 0 at the first frame).
    start_ns: u64,
    /// Next sample frame to write.
    next: usize,
}

impl SpeechAudio {
    fn read(path: &Path, start_s: f64) -> Result<SpeechAudio, SessionError> {
        let reader = hound::WavReader::open(path).map_err(|source| SessionError::WavOpen {
            path: path.to_path_buf(),
            source,
        })?;
        let spec = reader.spec();
        if spec.sample_format != hound::SampleFormat::Int
            || spec.bits_per_sample != 16
            || !(8_000..=192_000).contains(&spec.sample_rate)
            || !(1..=32).contains(&spec.channels)
        {
            return Err(SessionError::WavFormat {
                path: path.to_path_buf(),
                bits: spec.bits_per_sample,
                format: format!("{:?}", spec.sample_format),
                rate: spec.sample_rate,
                channels: spec.channels,
            });
        }
        // Checked against a day of sound before anything is allocated.
        let len = u64::from(reader.len());
        if len > MAX_SECONDS as u64 * u64::from(spec.sample_rate) * u64::from(spec.channels) {
            return Err(SessionError::WavTooLong {
                path: path.to_path_buf(),
                samples: len,
            });
        }
        let samples = reader
            .into_samples::<i16>()
            .collect::<Result<Vec<_>, _>>()
            .map_err(|source| SessionError::WavShort {
                path: path.to_path_buf(),
                source,
            })?;
        Ok(SpeechAudio {
            format: AudioFormat {
                sample_rate: spec.sample_rate,
                channels: spec.channels,
            },
            samples,
            start_ns: (start_s * 1e9).round() as u64,
            next: 0,
        })
    }

    /// Writes the blocks that start before `until_ns`.
    fn write_until(
        &mut self,
        writer: &mut SessionWriter,
        until_ns: u64,
    ) -> Result<(), RecordingError> {
        let channels = usize::from(self.format.channels);
        let block = self.format.sample_rate as usize / 100;
        let total = self.samples.len() / channels;
        while self.next < total {
            let at = self.start_ns
                + (self.next as u128 * 1_000_000_000 / u128::from(self.format.sample_rate)) as u64;
            if at >= until_ns {
                break;
            }
            let end = (self.next + block).min(total);
            writer.write_audio(
                at,
                self.format,
                &self.samples[self.next * channels..end * channels],
            )?;
            self.next = end;
        }
        Ok(())
    }
}
