//! `mouthpiece lipsync learn`: a booth's own live profiles from its actor's recordings (WAV
//! files) and their phone files, every file checked and named in errors; too little speech
//! (fewer than [`MIN_CLASSES`] classes profiled) is refused.

use std::path::{Path, PathBuf};

use super::features::SAMPLE_RATES;
use super::learn::{learn_from_recordings, Recording, MIN_FRAMES};
use super::profiles::Profiles;
use crate::input::{cut, read_text, ReadError, MAX_PHONE_FILE_BYTES};
use crate::phones::{self, PhoneFormat};
use crate::take::{DEFAULT_CLASSES, DEFAULT_CLASSES_NAME};
use crate::{ClassTable, Error};

/// Fewest classes (of the shipped table's 16) a learned file must profile: fewer means too
/// little speech to stand in for the shipped profiles.
pub const MIN_CLASSES: usize = 12;
/// Longest recording read, seconds (an hour).
pub const MAX_RECORDING_S: u64 = 3_600;
/// How far the phones may run past the end of the sound, seconds (a label file's last
/// silence often does).
const PHONES_PAST_END_S: f64 = 0.5;

/// Why profiles cannot be learned from the files given.
#[derive(Debug, thiserror::Error)]
pub enum LearnError {
    #[error("give one --phones per --audio, in the same order: got {audio} --audio and {phones} --phones")]
    Count { audio: usize, phones: usize },
    #[error("the shipped class table")]
    Table(#[source] Error),
    #[error(
        "--phones {0}: unknown phone file type (expected .phn, .TextGrid, .lab, .segs or .jsonl)"
    )]
    PhoneType(String),
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error(transparent)]
    Lipsync(#[from] Error),
    #[error("--audio {name}: not a readable WAV file")]
    WavOpen {
        name: String,
        #[source]
        source: hound::Error,
    },
    #[error("--audio {name}: expected 16-bit PCM, {} to {} Hz, 1 to 32 channels; got {bits}-bit {format}, {rate} Hz, {channels} channels", SAMPLE_RATES.0, SAMPLE_RATES.1)]
    WavFormat {
        name: String,
        bits: u16,
        format: String,
        rate: u32,
        channels: u16,
    },
    #[error("--audio {name}: longer than {MAX_RECORDING_S} s")]
    WavTooLong { name: String },
    #[error("--audio {name}: cut short")]
    WavShort {
        name: String,
        #[source]
        source: hound::Error,
    },
    #[error("--phones {name}: the phones run to {end:.2} s, but --audio {wav} holds {seconds:.2} s: not its timing")]
    PastEnd {
        name: String,
        end: f64,
        wav: String,
        seconds: f64,
    },
    #[error("{seconds:.1} s of speech is too little to learn from: {have} of {of} classes have at least {MIN_FRAMES} frames ({} ms), {MIN_CLASSES} are needed; missing: {missing}. Record more (the shipped profiles are learned from 40 sentences, about 2 minutes)", MIN_FRAMES * 10)]
    TooLittle {
        seconds: f64,
        have: usize,
        of: usize,
        missing: String,
    },
}

impl LearnError {
    /// The caller's files, not the machine, are at fault (all but the shipped table).
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, Self::Table(_))
    }
}

/// What was learned.
pub struct Learned {
    pub profiles: Profiles,
    /// Seconds of sound learned from.
    pub seconds: f64,
    /// Classes with too little speech to profile (never chosen live).
    pub missing: Vec<String>,
}

/// A WAV's first channel and rate; a format the analyser cannot read or a file longer than
/// [`MAX_RECORDING_S`] is refused naming the file.
fn read_wav(path: &Path) -> Result<(Vec<i16>, u32), LearnError> {
    let name = || path.display().to_string();
    let reader = hound::WavReader::open(path).map_err(|source| LearnError::WavOpen {
        name: name(),
        source,
    })?;
    let spec = reader.spec();
    if spec.sample_format != hound::SampleFormat::Int
        || spec.bits_per_sample != 16
        || !(SAMPLE_RATES.0..=SAMPLE_RATES.1).contains(&spec.sample_rate)
        || !(1..=32).contains(&spec.channels)
    {
        return Err(LearnError::WavFormat {
            name: name(),
            bits: spec.bits_per_sample,
            format: format!("{:?}", spec.sample_format),
            rate: spec.sample_rate,
            channels: spec.channels,
        });
    }
    // Checked before anything is allocated.
    if u64::from(reader.duration()) > MAX_RECORDING_S * u64::from(spec.sample_rate) {
        return Err(LearnError::WavTooLong { name: name() });
    }
    let samples = reader
        .into_samples::<i16>()
        .step_by(usize::from(spec.channels))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|source| LearnError::WavShort {
            name: name(),
            source,
        })?;
    Ok((samples, spec.sample_rate))
}

/// Learns profiles against the shipped class table from each `audio[i]` with the phone
/// timing of `phones[i]`.
pub fn learn_from_files(audio: &[PathBuf], phones: &[PathBuf]) -> Result<Learned, LearnError> {
    if audio.len() != phones.len() {
        return Err(LearnError::Count {
            audio: audio.len(),
            phones: phones.len(),
        });
    }
    let table = ClassTable::from_toml_str(DEFAULT_CLASSES, DEFAULT_CLASSES_NAME)
        .map_err(LearnError::Table)?;
    let mut sounds = Vec::new();
    for (wav, phone_file) in audio.iter().zip(phones) {
        let name = phone_file.display().to_string();
        let ext = phone_file
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("");
        let format =
            PhoneFormat::from_extension(ext).ok_or_else(|| LearnError::PhoneType(name.clone()))?;
        let text = read_text(phone_file, "phone file", MAX_PHONE_FILE_BYTES)?;
        let spans = phones::read(&text, format, &name)?;
        let (samples, rate) = read_wav(wav)?;
        let seconds = samples.len() as f64 / f64::from(rate);
        let end = spans.last().map_or(0.0, |p| p.end);
        if end > seconds + PHONES_PAST_END_S {
            return Err(LearnError::PastEnd {
                name,
                end,
                wav: wav.display().to_string(),
                seconds,
            });
        }
        sounds.push((samples, rate, spans, name));
    }
    let recordings: Vec<Recording> = sounds
        .iter()
        .map(|(samples, rate, spans, name)| Recording {
            samples,
            rate: *rate,
            phones: spans,
            name,
        })
        .collect();
    let seconds: f64 = sounds
        .iter()
        .map(|(s, r, _, _)| s.len() as f64 / f64::from(*r))
        .sum();
    let files: Vec<String> = audio.iter().map(|p| p.display().to_string()).collect();
    let learned_on = format!(
        "{} recording(s), {seconds:.1} s: {}",
        sounds.len(),
        cut(&files.join(", "))
    );
    let profiles = learn_from_recordings(&table, &recordings, &learned_on)?;
    let missing: Vec<String> = table
        .classes
        .iter()
        .filter(|c| !profiles.classes.iter().any(|p| p.name == c.name))
        .map(|c| c.name.clone())
        .collect();
    if profiles.classes.len() < MIN_CLASSES {
        return Err(LearnError::TooLittle {
            seconds,
            have: profiles.classes.len(),
            of: table.len(),
            missing: missing.join(", "),
        });
    }
    Ok(Learned {
        profiles,
        seconds,
        missing,
    })
}
