//! Festival speaks a line (`synth --speech-text`): its WAV and its own phone labels (the
//! timing it spoke with), in a temporary directory.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Longest line Festival is given, characters (a paragraph; Festival's time grows with it,
/// and a session holds it whole).
pub const MAX_SPEECH_TEXT_CHARS: usize = 4_000;

/// What to install when Festival is missing.
pub const INSTALL: &str =
    "install Festival and its voice (Debian: apt-get install festival festvox-kallpc16k)";

/// Why Festival did not speak the line; all but the temporary files are the caller's (the
/// line, or Festival missing).
#[derive(Debug, thiserror::Error)]
pub enum FestivalError {
    #[error("--speech-text: {chars} characters, more than {MAX_SPEECH_TEXT_CHARS}")]
    TooLong { chars: usize },
    #[error("--speech-text: nothing to say (the line has no letters or digits)")]
    NothingToSay,
    #[error("--speech-text: control character U+{code:04X} at character {position}")]
    Control { code: u32, position: usize },
    #[error("--speech-text needs Festival, and `{}` was not found: {INSTALL}", program.display())]
    NotFound { program: PathBuf },
    #[error("--speech-text: cannot run `{}`: {cause}", program.display())]
    Run {
        program: PathBuf,
        cause: std::io::Error,
    },
    #[error(
        "--speech-text: Festival did not speak the line ({status}; it said: {said}); {INSTALL}"
    )]
    Failed { status: String, said: String },
    #[error("cannot {what}")]
    Files {
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
}

impl FestivalError {
    /// The line or the machine's Festival, not a temporary file, is at fault.
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, Self::Files { .. })
    }
}

/// Festival's rendering of a line: its WAV and phone labels (kept while this lives).
pub struct Spoken {
    pub dir: tempfile::TempDir,
    pub wav: PathBuf,
    /// Festival's segment labels (`utt.save.segs`).
    pub labels: String,
}

/// Checks the line and quotes it as a Scheme string: control characters are refused
/// (naming the position), `\` and `"` escaped.
pub fn scheme_string(text: &str) -> Result<String, FestivalError> {
    let chars = text.chars().count();
    if chars > MAX_SPEECH_TEXT_CHARS {
        return Err(FestivalError::TooLong { chars });
    }
    if !text.chars().any(char::is_alphanumeric) {
        return Err(FestivalError::NothingToSay);
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
                return Err(FestivalError::Control {
                    code: c as u32,
                    position: i + 1,
                })
            }
            c => s.push(c),
        }
    }
    s.push('"');
    Ok(s)
}

/// Runs `festival` (the program's path) on the line.
pub fn speak(text: &str, festival: &Path) -> Result<Spoken, FestivalError> {
    let quoted = scheme_string(text)?;
    let files = |what| move |source| FestivalError::Files { what, source };
    let dir = tempfile::tempdir().map_err(files("make a temporary directory for Festival"))?;
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
    .map_err(files("write Festival's script"))?;
    let out = match Command::new(festival).arg("-b").arg(&scm).output() {
        Ok(out) => out,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(FestivalError::NotFound {
                program: festival.to_path_buf(),
            })
        }
        Err(cause) => {
            return Err(FestivalError::Run {
                program: festival.to_path_buf(),
                cause,
            })
        }
    };
    let stderr = String::from_utf8_lossy(&out.stderr);
    if !out.status.success() || !wav.exists() || !segs.exists() {
        let last: Vec<&str> = stderr.lines().rev().take(3).collect();
        let said = last.into_iter().rev().collect::<Vec<_>>().join(" / ");
        return Err(FestivalError::Failed {
            status: out.status.to_string(),
            said: cut(&said),
        });
    }
    let labels = std::fs::read_to_string(&segs).map_err(files("read Festival's phone labels"))?;
    Ok(Spoken { dir, wav, labels })
}

/// `s` cut to 80 characters, control characters escaped.
fn cut(s: &str) -> String {
    match s.char_indices().nth(80) {
        Some((i, _)) => format!("{}…", mouthpiece_output::shown(&s[..i])),
        None => mouthpiece_output::shown(s).into_owned(),
    }
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
        let e = speak("Hello.", Path::new("/nonexistent/festival"))
            .err()
            .unwrap();
        assert!(e.is_bad_input(), "{e}");
        let e = e.to_string();
        assert!(
            e.contains("festvox-kallpc16k") && e.contains("apt-get"),
            "{e}"
        );
    }
}
