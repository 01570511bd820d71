//! `mouthpiece lipsync learn`: a booth learns its own live lip-sync profiles from its actor's
//! recordings with known phone timing (docs/lipsync.md, "A booth's own voice"). Each window
//! of the sound is labelled with the class of the phone at its centre and the per-class
//! feature statistics are written as a profile file the daemon reads
//! (`[audio] speech_profiles`).

use std::io::Write as _;
use std::path::PathBuf;

use anyhow::Context as _;
use mouthpiece_lipsync::live::learn_files::learn_from_files;

use crate::exit::{bad_input, bad_input_if};

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

pub fn run(args: LearnArgs) -> anyhow::Result<()> {
    let learned = learn_from_files(&args.audio, &args.phones)
        .map_err(|e| bad_input_if(e.is_bad_input(), e))?;
    if !learned.missing.is_empty() {
        tracing::warn!(
            missing = learned.missing.join(", "),
            "classes with too little speech get no profile and are never chosen"
        );
    }
    let mut file = mouthpiece_export::PendingFile::create(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))
        .map_err(bad_input)?;
    file.write_all(
        learned
            .profiles
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
        classes = learned.profiles.classes.len(),
        seconds = format!("{:.1}", learned.seconds),
        "live lip-sync profiles learned"
    );
    Ok(())
}
