//! `mouthpiece lipsync learn`: a booth learns its own live lip-sync profiles from its actor's
//! recordings with known phone timing (docs/lipsync.md, "A booth's own voice"). Each window
//! of the sound is labelled with the class of the phone at its centre and the per-class
//! feature statistics are written as a profile file the daemon reads
//! (`[audio] speech_profiles`).

use std::io::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context as _;
use mouthpiece_lipsync::live::{learn_from_recordings, Profiles, Recording, SAMPLE_RATES};
use mouthpiece_lipsync::phones::{self, PhoneFormat};
use mouthpiece_lipsync::take::{DEFAULT_CLASSES, DEFAULT_CLASSES_NAME};
use mouthpiece_lipsync::ClassTable;

use crate::cmd::lipsync::{read_text, MAX_PHONE_FILE_BYTES};
use crate::exit::bad_input;

/// Fewest classes (of the shipped table's 16) a learned file must profile: fewer means too
/// little speech to stand in for the shipped profiles.
pub const MIN_CLASSES: usize = 12;
/// Longest recording read, seconds (an hour).
pub const MAX_RECORDING_S: u64 = 3_600;
/// How far the phones may run past the end of the sound, seconds (a label file's last
/// silence often does).
const PHONES_PAST_END_S: f64 = 0.5;

#[derive(Debug, clap::Args)]
pub struct LearnArgs {
    /// A recording of the actor (16-bit PCM WAV, 16 to 192 kHz, first channel); repeat with
    /// one `--phones` each, in the same order.
    #[arg(long, required = true, value_name = "WAV")]
    pub audio: Vec<PathBuf>,
    /// The phone timing of the `--audio` at the same position: TIMIT `.phn`, Praat
    /// `.TextGrid`, HTK/Festival `.lab` (or `.segs`), or `.jsonl`.
    #[arg(long, required = true, value_name = "FILE")]
    pub phones: Vec<PathBuf>,
    /// The profile file written (TOML).
    #[arg(long)]
    pub out: PathBuf,
}

/// A WAV's first channel and rate; a format the analyser cannot read or a file longer than
/// [`MAX_RECORDING_S`] is bad input naming the file.
fn read_wav(path: &Path) -> anyhow::Result<(Vec<i16>, u32)> {
    let name = path.display();
    let reader = hound::WavReader::open(path)
        .with_context(|| format!("--audio {name}: not a readable WAV file"))
        .map_err(bad_input)?;
    let spec = reader.spec();
    if spec.sample_format != hound::SampleFormat::Int
        || spec.bits_per_sample != 16
        || !(SAMPLE_RATES.0..=SAMPLE_RATES.1).contains(&spec.sample_rate)
        || !(1..=32).contains(&spec.channels)
    {
        return Err(bad_input(anyhow::anyhow!(
            "--audio {name}: expected 16-bit PCM, {} to {} Hz, 1 to 32 channels; got {}-bit {:?}, {} Hz, {} channels",
            SAMPLE_RATES.0,
            SAMPLE_RATES.1,
            spec.bits_per_sample,
            spec.sample_format,
            spec.sample_rate,
            spec.channels
        )));
    }
    // Checked before anything is allocated.
    if u64::from(reader.duration()) > MAX_RECORDING_S * u64::from(spec.sample_rate) {
        return Err(bad_input(anyhow::anyhow!(
            "--audio {name}: longer than {MAX_RECORDING_S} s"
        )));
    }
    let samples = reader
        .into_samples::<i16>()
        .step_by(usize::from(spec.channels))
        .collect::<Result<Vec<_>, _>>()
        .with_context(|| format!("--audio {name}: cut short"))
        .map_err(bad_input)?;
    Ok((samples, spec.sample_rate))
}

pub fn run(args: LearnArgs) -> anyhow::Result<()> {
    if args.audio.len() != args.phones.len() {
        return Err(bad_input(anyhow::anyhow!(
            "give one --phones per --audio, in the same order: got {} --audio and {} --phones",
            args.audio.len(),
            args.phones.len()
        )));
    }
    let table = ClassTable::from_toml_str(DEFAULT_CLASSES, DEFAULT_CLASSES_NAME)
        .context("the shipped class table")?;
    let mut sounds = Vec::new();
    for (wav, phone_file) in args.audio.iter().zip(&args.phones) {
        let name = phone_file.display().to_string();
        let ext = phone_file
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("");
        let format = PhoneFormat::from_extension(ext).ok_or_else(|| {
            bad_input(anyhow::anyhow!(
                "--phones {name}: unknown phone file type (expected .phn, .TextGrid, .lab, .segs or .jsonl)"
            ))
        })?;
        let text = read_text(phone_file, "phone file", MAX_PHONE_FILE_BYTES)?;
        let spans = phones::read(&text, format, &name).map_err(bad_input)?;
        let (samples, rate) = read_wav(wav)?;
        let seconds = samples.len() as f64 / f64::from(rate);
        let end = spans.last().map_or(0.0, |p| p.end);
        if end > seconds + PHONES_PAST_END_S {
            return Err(bad_input(anyhow::anyhow!(
                "--phones {name}: the phones run to {end:.2} s, but --audio {} holds {seconds:.2} s: not its timing",
                wav.display()
            )));
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
    let learned_on = format!(
        "{} recording(s), {seconds:.1} s: {}",
        sounds.len(),
        mouthpiece_lipsync::input::cut(
            &args
                .audio
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        )
    );
    let profiles = learn_from_recordings(&table, &recordings, &learned_on).map_err(bad_input)?;
    check_coverage(&table, &profiles, seconds)?;
    let mut file = mouthpiece_export::PendingFile::create(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))
        .map_err(bad_input)?;
    file.write_all(
        profiles
            .to_toml_string(
                "Live lip-sync profiles learned by `mouthpiece lipsync learn`\n\
                 (docs/lipsync.md); read by the daemon's `[audio] speech_profiles`.",
            )
            .as_bytes(),
    )
    .with_context(|| format!("cannot write {}", args.out.display()))?;
    file.commit()
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    tracing::info!(
        out = %args.out.display(),
        classes = profiles.classes.len(),
        seconds = format!("{seconds:.1}"),
        "live lip-sync profiles learned"
    );
    Ok(())
}

/// Too little speech (fewer than [`MIN_CLASSES`] classes profiled) is bad input naming the
/// classes missing; a few missing are only logged (the analyser never picks them).
fn check_coverage(table: &ClassTable, profiles: &Profiles, seconds: f64) -> anyhow::Result<()> {
    let missing: Vec<&str> = table
        .classes
        .iter()
        .filter(|c| !profiles.classes.iter().any(|p| p.name == c.name))
        .map(|c| c.name.as_str())
        .collect();
    if profiles.classes.len() < MIN_CLASSES {
        return Err(bad_input(anyhow::anyhow!(
            "{seconds:.1} s of speech is too little to learn from: {} of {} classes have at least {} frames ({} ms), {MIN_CLASSES} are needed; missing: {}. Record more (the shipped profiles are learned from 40 sentences, about 2 minutes)",
            profiles.classes.len(),
            table.len(),
            mouthpiece_lipsync::live::learn::MIN_FRAMES,
            mouthpiece_lipsync::live::learn::MIN_FRAMES * 10,
            missing.join(", ")
        )));
    }
    if !missing.is_empty() {
        tracing::warn!(
            missing = missing.join(", "),
            "classes with too little speech get no profile and are never chosen"
        );
    }
    Ok(())
}
