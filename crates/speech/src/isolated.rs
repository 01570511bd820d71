//! Decoding in a child process. PocketSphinx trusts its model files: a truncated `mdef`
//! makes it read past its buffers (signal 11) and a truncated `transition_matrices` makes it
//! call `exit(1)`, taking the caller with it. [`decode`] therefore forks, decodes in the
//! child and sends the phones back through a pipe; a child that dies or exits without an
//! answer is reported as [`Error::Crashed`], naming the model file the library's log says it
//! was reading.
//!
//! The child only runs the library and writes to the pipe, then leaves with `_exit` (no
//! destructors, no flushing of the parent's buffers). glibc's `fork` keeps `malloc` and
//! stdio usable in the child of a threaded parent.

use std::io::{Read, Write};
use std::os::fd::{FromRawFd, OwnedFd};
use std::path::Path;

use crate::decoder::{transcript_words, Decoder, ModelPaths, TimedPhone};
use crate::{cut, Error, MODEL_RATE};

/// Most transcript words a second of audio may hold (fast speech is 4–5; more is a
/// transcript that does not belong to the audio, and a grammar that costs without end).
pub const MAX_WORDS_PER_SECOND: f64 = 10.0;

/// What to decode.
#[derive(Debug, Clone, Copy)]
pub enum Task<'a> {
    /// Forced alignment to a transcript; `source_name` names the transcript in errors.
    Align {
        transcript: &'a str,
        source_name: &'a str,
    },
    /// Phone recognition.
    Recognise,
}

/// The transcript's words, checked: not empty, at most [`MAX_WORDS_PER_SECOND`] a second of
/// `samples` (16 kHz) and at least 10.
pub(crate) fn checked_words(
    transcript: &str,
    source_name: &str,
    samples: usize,
    audio: &str,
) -> Result<Vec<String>, Error> {
    let words = transcript_words(transcript);
    if words.is_empty() {
        return Err(Error::EmptyTranscript {
            source_name: source_name.to_string(),
        });
    }
    if let Some(word) = words.iter().find(|w| w.chars().any(char::is_control)) {
        return Err(Error::BadWord {
            source_name: source_name.to_string(),
            word: crate::cut(word),
        });
    }
    let seconds = samples as f64 / MODEL_RATE as f64;
    let max = ((seconds * MAX_WORDS_PER_SECOND).ceil() as usize).max(10);
    if words.len() > max {
        return Err(Error::TooManyWords {
            source_name: source_name.to_string(),
            audio: audio.to_string(),
            words: words.len(),
            max,
            per_second: MAX_WORDS_PER_SECOND,
            seconds,
        });
    }
    Ok(words)
}

/// Decodes 16 kHz `samples` (`audio` names them in errors) in a child process: see the
/// module docs.
pub fn decode(
    model: &ModelPaths,
    samples: &[i16],
    audio: &str,
    task: Task,
) -> Result<Vec<TimedPhone>, Error> {
    model.check()?;
    if let Task::Align {
        transcript,
        source_name,
    } = task
    {
        checked_words(transcript, source_name, samples.len(), audio)?;
    }
    let log = tempfile::Builder::new()
        .prefix("mouthpiece-pocketsphinx-")
        .suffix(".log")
        .tempfile()
        .map_err(|e| Error::Init {
            what: format!("cannot create the library's log file: {e}"),
        })?;
    let mut fds = [0; 2];
    // SAFETY: `fds` has room for the two descriptors `pipe2` writes.
    if unsafe { libc::pipe2(fds.as_mut_ptr(), libc::O_CLOEXEC) } != 0 {
        return Err(Error::Init {
            what: format!("cannot make a pipe: {}", std::io::Error::last_os_error()),
        });
    }
    // SAFETY: both descriptors were just made and are owned here only.
    let (read_end, write_end) =
        unsafe { (OwnedFd::from_raw_fd(fds[0]), OwnedFd::from_raw_fd(fds[1])) };
    // SAFETY: the child runs only the decoder and writes to the pipe, then `_exit`s.
    let pid = unsafe { libc::fork() };
    if pid < 0 {
        return Err(Error::Init {
            what: format!(
                "cannot start a process: {}",
                std::io::Error::last_os_error()
            ),
        });
    }
    if pid == 0 {
        drop(read_end);
        let answer = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            encode(&run(model, samples, audio, task, log.path()))
        }))
        .unwrap_or_default();
        let mut pipe = std::fs::File::from(write_end);
        let code = i32::from(pipe.write_all(answer.as_bytes()).is_err() || answer.is_empty());
        // SAFETY: leaves the child at once, without running the parent's destructors.
        unsafe { libc::_exit(code) };
    }
    drop(write_end);
    let mut answer = Vec::new();
    let read = std::fs::File::from(read_end).read_to_end(&mut answer);
    let mut status = 0;
    loop {
        // SAFETY: `pid` is our child; `status` is written by the call.
        let r = unsafe { libc::waitpid(pid, &mut status, 0) };
        if r == pid
            || (r < 0 && std::io::Error::last_os_error().kind() != std::io::ErrorKind::Interrupted)
        {
            break;
        }
    }
    let clean = libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0;
    if clean && read.is_ok() {
        if let Some(result) = parse(&String::from_utf8_lossy(&answer)) {
            return result;
        }
    }
    let how = if libc::WIFSIGNALED(status) {
        format!("crashed (signal {})", libc::WTERMSIG(status))
    } else if libc::WIFEXITED(status) {
        format!("exited (status {})", libc::WEXITSTATUS(status))
    } else {
        "stopped without an answer".to_string()
    };
    let text = std::fs::read(log.path()).unwrap_or_default();
    let (file, detail) = blame(&String::from_utf8_lossy(&text), model);
    Err(Error::Crashed { file, how, detail })
}

/// The child's work.
fn run(
    model: &ModelPaths,
    samples: &[i16],
    audio: &str,
    task: Task,
    log: &Path,
) -> Result<Vec<TimedPhone>, Error> {
    let log_text = || std::fs::read(log).unwrap_or_default();
    let started = |d: Result<Decoder, Error>| {
        d.map_err(|e| match e {
            Error::Init { what } => {
                let (file, detail) = blame(&String::from_utf8_lossy(&log_text()), model);
                Error::Init {
                    what: format!("{what}; reading {file}{detail}"),
                }
            }
            other => other,
        })
    };
    match task {
        Task::Align {
            transcript,
            source_name,
        } => started(Decoder::new(model, false, Some(log)))?.align(
            samples,
            transcript,
            source_name,
            audio,
        ),
        Task::Recognise => {
            started(Decoder::new(model, true, Some(log)))?.recognize_phones(samples, audio)
        }
    }
}

/// The model file the library's log names last (it logs each file as it opens it) and the
/// last error it logged, cut short.
fn blame(log: &str, model: &ModelPaths) -> (String, String) {
    let mut file = None;
    let mut error = None;
    for line in log.lines() {
        if line.starts_with("ERROR") || line.starts_with("FATAL") {
            error = Some(line.trim().to_string());
        }
        let candidates = [&model.hmm, &model.dict, &model.phone_lm];
        for word in line.split(|c: char| c.is_whitespace() || c == '\'' || c == '"' || c == ',') {
            let word = word.trim_end_matches([':', '.']);
            if candidates
                .iter()
                .any(|p| Path::new(word).starts_with(p) || Path::new(word) == p.as_path())
                && !word.is_empty()
                && Path::new(word).is_file()
            {
                file = Some(word.to_string());
            }
        }
    }
    let file = file.unwrap_or_else(|| format!("(one of) {}", model.hmm.display()));
    let detail = error.map(|e| format!(" ({})", cut(&e))).unwrap_or_default();
    (file, detail)
}

/// The child's answer: `ok` then `start\tend\tphone` lines, or `err`, the variant, then its
/// fields one a line.
fn encode(result: &Result<Vec<TimedPhone>, Error>) -> String {
    let clean = |s: &str| s.replace(['\n', '\t', '\r'], " ");
    match result {
        Ok(phones) => {
            let mut s = String::from("ok\n");
            for p in phones {
                s.push_str(&format!(
                    "{:?}\t{:?}\t{}\n",
                    p.start,
                    p.end,
                    clean(&p.phone)
                ));
            }
            s
        }
        Err(e) => {
            let fields: Vec<&str> = match e {
                Error::Init { what } => vec!["init", what],
                Error::ModelMissing { path } => vec!["missing", path],
                Error::EmptyTranscript { source_name } => vec!["empty", source_name],
                Error::UnknownWord {
                    source_name,
                    word,
                    dict,
                } => vec!["word", source_name, word, dict],
                Error::NoPath { audio } => vec!["nopath", audio],
                Error::Decode { audio, what } => vec!["decode", audio, what],
                other => return format!("err\nother\n{}\n", clean(&other.to_string())),
            };
            let mut s = String::from("err\n");
            for f in fields {
                s.push_str(&clean(f));
                s.push('\n');
            }
            s
        }
    }
}

/// Reads [`encode`]'s text; `None` when it is not a whole answer.
fn parse(text: &str) -> Option<Result<Vec<TimedPhone>, Error>> {
    let mut lines = text.lines();
    match lines.next()? {
        "ok" => {
            let mut phones = Vec::new();
            for line in lines {
                let mut parts = line.splitn(3, '\t');
                let start = parts.next()?.parse().ok()?;
                let end = parts.next()?.parse().ok()?;
                let phone = parts.next()?.to_string();
                phones.push(TimedPhone { start, end, phone });
            }
            Some(Ok(phones))
        }
        "err" => {
            let kind = lines.next()?;
            let mut f = || lines.next().map(str::to_string);
            Some(Err(match kind {
                "init" => Error::Init { what: f()? },
                "missing" => Error::ModelMissing { path: f()? },
                "empty" => Error::EmptyTranscript { source_name: f()? },
                "word" => Error::UnknownWord {
                    source_name: f()?,
                    word: f()?,
                    dict: f()?,
                },
                "nopath" => Error::NoPath { audio: f()? },
                "decode" => Error::Decode {
                    audio: f()?,
                    what: f()?,
                },
                _ => Error::Decode {
                    audio: String::new(),
                    what: f()?,
                },
            }))
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DEBIAN: &str = "/usr/share/pocketsphinx/model/en-us";

    /// Debian's model with `file` (relative to the model directory) cut to `keep` bytes;
    /// every other file a link to Debian's.
    fn damaged(file: &str, keep: usize) -> (tempfile::TempDir, ModelPaths) {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("en-us")).unwrap();
        for rel in [
            "cmudict-en-us.dict",
            "en-us-phone.lm.bin",
            "en-us/feat.params",
            "en-us/mdef",
            "en-us/means",
            "en-us/noisedict",
            "en-us/sendump",
            "en-us/transition_matrices",
            "en-us/variances",
        ] {
            let from = Path::new(DEBIAN).join(rel);
            let to = dir.path().join(rel);
            if rel == file {
                let bytes = std::fs::read(&from).expect("Debian's pocketsphinx-en-us");
                std::fs::write(&to, &bytes[..keep.min(bytes.len())]).unwrap();
            } else {
                std::os::unix::fs::symlink(&from, &to).unwrap();
            }
        }
        let model = ModelPaths::en_us(dir.path());
        (dir, model)
    }

    fn tone() -> Vec<i16> {
        (0..16_000)
            .map(|i| (3000.0 * (i as f64 * 0.3).sin()) as i16)
            .collect()
    }

    #[test]
    fn damaged_model_files_are_errors_naming_the_file_not_crashes() {
        // A truncated mdef: signal 11 inside the library. A truncated transition_matrices:
        // the library calls exit(1). Both used to end the whole program.
        for (file, keep) in [("en-us/mdef", 100_000), ("en-us/transition_matrices", 1000)] {
            let (dir, model) = damaged(file, keep);
            let task = Task::Align {
                transcript: "hello",
                source_name: "t.txt",
            };
            let err = decode(&model, &tone(), "a.wav", task).unwrap_err();
            let expect = dir.path().join(file).display().to_string();
            assert!(
                matches!(err, Error::Crashed { .. }) || matches!(err, Error::Init { .. }),
                "{err:?}"
            );
            assert!(err.to_string().contains(&expect), "{file}: {err}");
            assert!(err.is_bad_input());
        }
    }

    #[test]
    fn the_child_answers_as_the_library_would() {
        let model = ModelPaths::debian();
        let err = decode(
            &model,
            &tone(),
            "a.wav",
            Task::Align {
                transcript: "hello zzqxv",
                source_name: "t.txt",
            },
        )
        .unwrap_err();
        assert!(
            err.to_string()
                .starts_with("t.txt: word \"zzqxv\" is not in"),
            "{err}"
        );
        let phones = decode(&model, &tone(), "a.wav", Task::Recognise).unwrap();
        assert!(!phones.is_empty());
    }

    #[test]
    fn a_transcript_longer_than_the_audio_can_hold_is_refused_before_the_grammar() {
        // 100 000 words for one second: the grammar and search would run without end.
        let text = "hello ".repeat(100_000);
        let task = Task::Align {
            transcript: &text,
            source_name: "long.txt",
        };
        let err = decode(&ModelPaths::debian(), &tone(), "a.wav", task).unwrap_err();
        assert!(
            err.to_string()
                .starts_with("long.txt: the transcript has 100000 words, more than 10"),
            "{err}"
        );
        // The audio is named too: a WAV cut short is as likely as a long transcript.
        assert!(err.to_string().contains("1.0 s of audio in a.wav"), "{err}");
    }

    /// A word with a NUL (or another control character) names the transcript and shows the
    /// word escaped; it never reaches the library.
    #[test]
    fn a_transcript_word_with_a_nul_names_the_transcript() {
        for text in ["hello wor\0ld", "hello \u{1b}[2Jworld"] {
            let task = Task::Align {
                transcript: text,
                source_name: "t.txt",
            };
            let err = decode(&ModelPaths::debian(), &tone(), "a.wav", task).unwrap_err();
            let shown = err.to_string();
            assert!(shown.starts_with("t.txt: word "), "{shown}");
            assert!(shown.contains("holds a control character"), "{shown}");
            assert!(!shown.contains(['\0', '\u{1b}']), "{shown:?}");
            assert!(err.is_bad_input());
        }
    }
}
