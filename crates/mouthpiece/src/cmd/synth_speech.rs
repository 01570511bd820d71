//! `synth --speech-text "A line."`: Festival speaks the line, and its own phone timing drives
//! the synthetic mouth through the project's lip-sync classes and basic poses (as
//! `lipsync --phonemes` → `synth --speech` would), while its sound goes on `/audio`: sound
//! and mouth come from one timing, with no recogniser between them.

use std::path::{Path, PathBuf};

use anyhow::Context as _;
use mouthpiece_lipsync::phones::{self, PhoneFormat};
use mouthpiece_synth::MouthState;

use mouthpiece_speech::festival::Spoken;

use crate::exit::{bad_input, bad_input_if};

/// Festival's rendering of a line: its WAV (kept in a temporary directory) and the mouth keys
/// from its phones.
pub struct SpokenLine {
    _dir: tempfile::TempDir,
    pub wav: PathBuf,
    pub keys: Vec<(f64, MouthState)>,
}

/// Festival speaks `text`; the mouth keys (after `neutral_seconds`) from its phone timing
/// through the shipped class table and segments and the basic poses `poses`.
pub fn speak(
    text: &str,
    poses: Option<&Path>,
    neutral_seconds: f64,
    festival_bin: &Path,
) -> anyhow::Result<SpokenLine> {
    use crate::cmd::lipsync::{load_tables, mouth_keys_from_weights, write_weights_csv};
    // The tables are checked before Festival runs.
    let tables = load_tables(None, poses, None)?;
    let Spoken { dir, wav, labels } = mouthpiece_speech::festival::speak(text, festival_bin)
        .map_err(|e| bad_input_if(e.is_bad_input(), e))?;
    let phones =
        phones::read(&labels, PhoneFormat::Label, "Festival's phone labels").map_err(bad_input)?;
    let weights = mouthpiece_lipsync::weights_for_phones(
        &phones,
        "Festival's phone labels",
        &tables.classes,
        &tables.segments,
        mouthpiece_lipsync::DEFAULT_T_CHANGE,
        60.0,
    )
    .map_err(bad_input)?;
    // The same CSV `lipsync --weights` writes, read as `synth --speech` reads it.
    let mut csv = Vec::new();
    write_weights_csv(&weights, &phones, &tables, &mut csv)?;
    let csv = String::from_utf8(csv).context("the weights are not UTF-8")?;
    let pose_table = mouthpiece_lipsync::BasicPoses::from_toml_str(
        &match poses {
            Some(p) => crate::cmd::lipsync::read_text(
                p,
                "pose file",
                crate::cmd::lipsync::MAX_TABLE_FILE_BYTES,
            )?,
            None => crate::cmd::lipsync::DEFAULT_POSES.to_string(),
        },
        &poses.map_or("config/lipsync/poses.toml".to_string(), |p| {
            p.display().to_string()
        }),
    )
    .map_err(bad_input)?;
    let mut keys = vec![(0.0, MouthState::default())];
    keys.extend(mouth_keys_from_weights(
        &csv,
        "Festival's line",
        &pose_table,
        neutral_seconds,
    )?);
    Ok(SpokenLine {
        _dir: dir,
        wav,
        keys,
    })
}
