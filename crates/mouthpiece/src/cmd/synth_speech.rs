//! `synth --speech-text "A line."`: Festival speaks the line, and its own phone timing drives
//! the synthetic mouth through the project's lip-sync classes and basic poses (as
//! `lipsync --phonemes` → `synth --speech` would), while its sound goes on `/audio`: sound
//! and mouth come from one timing, with no recogniser between them.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::Context as _;
use mouthpiece_lipsync::phones::{self, PhoneFormat};
use mouthpiece_synth::MouthState;

use crate::exit::bad_input;

/// Longest line `--speech-text` speaks, characters (a paragraph; Festival's time grows with
/// it, and the session holds it whole).
pub const MAX_SPEECH_TEXT_CHARS: usize = 4_000;

/// What to install when Festival is missing.
const INSTALL: &str =
    "install Festival and its voice (Debian: apt-get install festival festvox-kallpc16k)";

/// Festival's rendering of a line: its WAV (kept in a temporary directory) and phones.
pub struct SpokenLine {
    _dir: tempfile::TempDir,
    pub wav: PathBuf,
    pub keys: Vec<(f64, MouthState)>,
}

/// Checks the line and quotes it as a Scheme string: control characters are refused
/// (naming the position), `\` and `"` escaped.
fn scheme_string(text: &str) -> anyhow::Result<String> {
    let chars = text.chars().count();
    if chars > MAX_SPEECH_TEXT_CHARS {
        return Err(bad_input(anyhow::anyhow!(
            "--speech-text: {chars} characters, more than {MAX_SPEECH_TEXT_CHARS}"
        )));
    }
    if !text.chars().any(char::is_alphanumeric) {
        return Err(bad_input(anyhow::anyhow!(
            "--speech-text: nothing to say (the line has no letters or digits)"
        )));
    }
    let mut s = String::with_capacity(text.len() + 2);
    s.push('"');
    for (i, c) in text.chars().enumerate() {
        match c {
            '"' | '\\' => {
                s.push('\\');
                s.push(c);
            }
            '\n' | '\t' | '\r' => s.push(' '),
            c if c.is_control() => {
                return Err(bad_input(anyhow::anyhow!(
                    "--speech-text: control character U+{:04X} at character {}",
                    c as u32,
                    i + 1
                )))
            }
            c => s.push(c),
        }
    }
    s.push('"');
    Ok(s)
}

/// Runs `festival` on the line; the WAV and Festival's phone labels in a temporary directory.
fn festival(text: &str, festival: &Path) -> anyhow::Result<(tempfile::TempDir, PathBuf, String)> {
    let quoted = scheme_string(text)?;
    let dir = tempfile::tempdir().context("cannot make a temporary directory for Festival")?;
    let wav = dir.path().join("line.wav");
    let segs = dir.path().join("line.segs");
    let scm = dir.path().join("line.scm");
    let path = |p: &Path| scheme_string(&p.display().to_string());
    std::fs::write(
        &scm,
        format!(
            "(set! u (Utterance Text {quoted}))\n(utt.synth u)\n(utt.save.wave u {} 'riff)\n(utt.save.segs u {})\n",
            path(&wav)?,
            path(&segs)?
        ),
    )
    .context("cannot write Festival's script")?;
    let out = match Command::new(festival).arg("-b").arg(&scm).output() {
        Ok(out) => out,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(bad_input(anyhow::anyhow!(
                "--speech-text needs Festival, and `{}` was not found: {INSTALL}",
                festival.display()
            )))
        }
        Err(e) => {
            return Err(bad_input(anyhow::anyhow!(
                "--speech-text: cannot run `{}`: {e}",
                festival.display()
            )))
        }
    };
    let stderr = String::from_utf8_lossy(&out.stderr);
    if !out.status.success() || !wav.exists() || !segs.exists() {
        let last: Vec<&str> = stderr.lines().rev().take(3).collect();
        let said =
            mouthpiece_lipsync::input::cut(&last.into_iter().rev().collect::<Vec<_>>().join(" / "));
        return Err(bad_input(anyhow::anyhow!(
            "--speech-text: Festival did not speak the line ({}; it said: {said}); {INSTALL}",
            out.status
        )));
    }
    let labels = std::fs::read_to_string(&segs).context("cannot read Festival's phone labels")?;
    Ok((dir, wav, labels))
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
    let (dir, wav, labels) = festival(text, festival_bin)?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_line_is_quoted_for_scheme_and_control_characters_are_refused() {
        assert_eq!(
            scheme_string(r#"Say "hi" \ bye."#).unwrap(),
            r#""Say \"hi\" \\ bye.""#
        );
        assert_eq!(scheme_string("a\nb").unwrap(), "\"a b\"");
        let e = scheme_string("ab\u{7}c").unwrap_err().to_string();
        assert!(e.contains("U+0007") && e.contains("character 3"), "{e}");
        assert!(scheme_string(" .. ").is_err());
        assert!(scheme_string(&"a".repeat(MAX_SPEECH_TEXT_CHARS + 1)).is_err());
    }

    #[test]
    fn a_missing_festival_is_bad_input_saying_what_to_install() {
        let e = speak("Hello.", None, 1.5, Path::new("/nonexistent/festival"))
            .err()
            .unwrap();
        assert!(e.chain().any(|c| c.is::<crate::exit::BadInput>()), "{e:#}");
        let e = format!("{e:#}");
        assert!(
            e.contains("festvox-kallpc16k") && e.contains("apt-get"),
            "{e}"
        );
    }
}
