//! `mouthpiece record`: a source to a file, every request checked before anything is opened
//! or written (the format from the name, the colour encoding, the duration, the output's
//! directory, the sound device).

use std::path::{Path, PathBuf};

use mouthpiece_recording::{ColorEncoding, WriterOptions};

use crate::record::{self, OutputFormat, RecordError, RecordLimits, RecordSummary};
use crate::spec::SpecError;
use crate::{CaptureConfig, Frame, SourceError, SourceSpec};

/// The sound to record beside the frames (`--audio`).
#[derive(Debug, Clone)]
pub struct AudioRequest {
    /// ALSA PCM name, already checked (`mouthpiece_config::check_alsa_device`).
    pub device: String,
    pub rate: u32,
    pub channels: u16,
}

/// What to record, as the command line gave it.
#[derive(Debug, Clone)]
pub struct RecordJob {
    pub source: String,
    pub out: PathBuf,
    pub seconds: Option<f64>,
    /// `raw`, `jpeg` or `jpeg:QUALITY`.
    pub color: String,
    pub audio: Option<AudioRequest>,
}

/// Why a recording was refused or failed.
#[derive(Debug, thiserror::Error)]
pub enum RecordJobError {
    #[error(transparent)]
    Spec(#[from] SpecError),
    #[error("--color jpeg:{quality}: quality must be 1 to 100")]
    Quality { quality: String },
    #[error("--color {0:?}: expected raw, jpeg or jpeg:QUALITY")]
    Color(String),
    #[error("--seconds {0}: expected a positive number")]
    Seconds(f64),
    #[error("--out {}: directory {} does not exist", out.display(), dir.display())]
    NoDirectory { out: PathBuf, dir: PathBuf },
    #[error("--audio needs an .mcap --out ({} cannot hold sound)", .0.display())]
    SoundNeedsMcap(PathBuf),
    #[error("--audio-rate {0}: expected 8000 to 192000 Hz")]
    AudioRate(u32),
    #[error("--audio-channels {0}: expected 1 to 32")]
    AudioChannels(u16),
    #[error("--audio {device}: cannot record from this ALSA device")]
    AudioOpen {
        device: String,
        #[source]
        source: SourceError,
    },
    /// The user named something that cannot work (an unknown format, what an `.oni` cannot
    /// hold, a replay that cannot be read).
    #[error(transparent)]
    Refused(RecordError),
    #[error(transparent)]
    Record(RecordError),
}

impl RecordJobError {
    /// The caller's request, not the machine, is at fault (exit code 2).
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, Self::Record(_))
    }
}

/// `raw`, `jpeg` or `jpeg:QUALITY`.
pub fn parse_color(s: &str) -> Result<ColorEncoding, RecordJobError> {
    match s.split_once(':') {
        None if s == "raw" => Ok(ColorEncoding::Raw),
        None if s == "jpeg" => Ok(ColorEncoding::Jpeg { quality: 90 }),
        Some(("jpeg", q)) => match q.parse::<u8>() {
            Ok(quality @ 1..=100) => Ok(ColorEncoding::Jpeg { quality }),
            _ => Err(RecordJobError::Quality {
                quality: q.to_string(),
            }),
        },
        _ => Err(RecordJobError::Color(s.to_string())),
    }
}

/// `s` cut to about 80 characters for an error message.
fn cut(s: &str) -> String {
    if s.chars().count() <= 80 {
        s.to_owned()
    } else {
        format!("{}…", s.chars().take(80).collect::<String>())
    }
}

/// Opens the sound device before anything is recorded: a device that cannot be opened is
/// the caller's (and no file is written).
fn open_audio(
    audio: &AudioRequest,
) -> Result<Box<dyn mouthpiece_frame::AudioSource>, RecordJobError> {
    if !(8_000..=192_000).contains(&audio.rate) {
        return Err(RecordJobError::AudioRate(audio.rate));
    }
    if !(1..=32).contains(&audio.channels) {
        return Err(RecordJobError::AudioChannels(audio.channels));
    }
    let request = crate::alsa::AlsaRequest {
        device: audio.device.clone(),
        sample_rate: audio.rate,
        channels: audio.channels,
        // 10 ms periods, 200 ms of buffer, as the daemon's defaults.
        period_frames: (audio.rate / 100).max(1),
        buffer_frames: (audio.rate / 5).max(2),
        stall_timeout: std::time::Duration::from_secs(2),
    };
    let source =
        crate::alsa::AlsaSource::open(&request).map_err(|source| RecordJobError::AudioOpen {
            device: cut(&audio.device),
            source,
        })?;
    Ok(Box::new(source))
}

/// Records `job` until its duration, the end of a replay, or `stop`; a source lost midway
/// finishes the file and says so in the summary (`lost`).
pub fn record(
    job: &RecordJob,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    progress: impl FnMut(&Frame),
) -> Result<RecordSummary, RecordJobError> {
    let spec = SourceSpec::parse(&job.source)?;
    let format = OutputFormat::from_path(&job.out).map_err(RecordJobError::Refused)?;
    let color = parse_color(&job.color)?;
    if let Some(s) = job.seconds {
        if !(s > 0.0 && s.is_finite()) {
            return Err(RecordJobError::Seconds(s));
        }
    }
    if let Some(dir) = job.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        if !dir.is_dir() {
            return Err(RecordJobError::NoDirectory {
                out: job.out.clone(),
                dir: dir.to_path_buf(),
            });
        }
    }
    if job.audio.is_some() && format != OutputFormat::Mcap {
        return Err(RecordJobError::SoundNeedsMcap(job.out.clone()));
    }
    let audio = job.audio.as_ref().map(open_audio).transpose()?;
    let limits = RecordLimits {
        seconds: job.seconds,
        stop,
    };
    let config = CaptureConfig::default();
    let out: &Path = &job.out;
    let result = match format {
        OutputFormat::Mcap => {
            let options = WriterOptions {
                color,
                ..Default::default()
            };
            record::record_mcap_with_audio(&spec, &config, out, options, &limits, audio, progress)
        }
        OutputFormat::Oni => record::record_oni(&spec, &config, out, &limits, progress),
    };
    let replay = matches!(spec, SourceSpec::Replay(_));
    result.map_err(|source| match &source {
        RecordError::OniUnsupported(_) | RecordError::UnknownFormat { .. } => {
            RecordJobError::Refused(source)
        }
        RecordError::Source(SourceError::Open { .. } | SourceError::Format { .. }) if replay => {
            RecordJobError::Refused(source)
        }
        _ => RecordJobError::Record(source),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colour_encodings_parse() {
        assert_eq!(parse_color("raw").unwrap(), ColorEncoding::Raw);
        assert_eq!(
            parse_color("jpeg").unwrap(),
            ColorEncoding::Jpeg { quality: 90 }
        );
        assert_eq!(
            parse_color("jpeg:75").unwrap(),
            ColorEncoding::Jpeg { quality: 75 }
        );
        assert!(parse_color("jpeg:0").is_err());
        assert!(parse_color("png").is_err());
    }
}
