//! The safe PocketSphinx decoder. Every unsafe call into the library lives in this module.
//!
//! Ownership: a [`Decoder`] owns one `ps_decoder_t` and the `cmd_ln_t` configuration it was
//! made from, frees both on drop, and is neither `Send` nor `Sync` (raw pointers): one thread
//! uses a decoder. Strings handed to the library are `CString`s that outlive the call; strings
//! the library returns are copied at once (`ps_seg_word` is only valid until the next
//! `ps_seg_next`; `ps_lookup_word`'s result is ours to free with `ckd_free`).

use std::collections::BTreeSet;
use std::ffi::{c_char, c_int, CStr, CString};
use std::path::{Path, PathBuf};
use std::ptr::NonNull;
use std::sync::Once;

use pocketsphinx_sys as sys;

use crate::Error;

/// Frames per second of the model's front end (10 ms shift).
pub const FRAME_RATE: f64 = 100.0;

/// The model files.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelPaths {
    /// The acoustic model directory (`en-us/`).
    pub hmm: PathBuf,
    /// The pronunciation dictionary.
    pub dict: PathBuf,
    /// The phone bigram for phone recognition.
    pub phone_lm: PathBuf,
}

impl ModelPaths {
    /// The layout of Debian's `pocketsphinx-en-us` package under `dir`
    /// (`/usr/share/pocketsphinx/model/en-us`).
    pub fn en_us(dir: &Path) -> Self {
        Self {
            hmm: dir.join("en-us"),
            dict: dir.join("cmudict-en-us.dict"),
            phone_lm: dir.join("en-us-phone.lm.bin"),
        }
    }

    /// Where Debian installs the model.
    pub fn debian() -> Self {
        Self::en_us(Path::new("/usr/share/pocketsphinx/model/en-us"))
    }

    pub(crate) fn check(&self) -> Result<(), Error> {
        for p in [&self.hmm, &self.dict, &self.phone_lm] {
            if !p.exists() {
                return Err(Error::ModelMissing {
                    path: p.display().to_string(),
                });
            }
        }
        Ok(())
    }
}

/// A phone (or filler) with its times, seconds, as the recogniser names it (`SH`, `SIL`,
/// `+NSN+`).
#[derive(Debug, Clone, PartialEq)]
pub struct TimedPhone {
    pub start: f64,
    pub end: f64,
    pub phone: String,
}

/// Prefix of the single-phone words the alignment grammar uses.
const PHONE_WORD: &str = "ph_";

/// A PocketSphinx decoder.
pub struct Decoder {
    ps: NonNull<sys::ps_decoder_t>,
    config: NonNull<sys::cmd_ln_t>,
    dict: PathBuf,
    /// Phone words already added to the dictionary.
    phone_words: BTreeSet<String>,
}

impl std::fmt::Debug for Decoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Decoder").field("dict", &self.dict).finish()
    }
}

fn quiet_library_logs() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // SAFETY: a null stream turns the library's logging off (documented in err.h); it
        // only sets a global the library reads when it logs.
        unsafe { sys::err_set_logfp(std::ptr::null_mut()) };
    });
}

/// Sends the library's log to `path`, unbuffered: the last line before a crash is kept.
fn log_unbuffered(path: &Path) -> Result<(), Error> {
    let c = cstring(&path.display().to_string(), "log path")?;
    // SAFETY: `c` and the mode are NUL-terminated; the stream stays open for the process's
    // life (the library keeps it; this runs in the short-lived child of `crate::decode`).
    unsafe {
        let fp = libc::fopen(c.as_ptr(), c"w".as_ptr());
        if fp.is_null() {
            return Err(Error::Init {
                what: format!("cannot open the log {}", path.display()),
            });
        }
        libc::setvbuf(fp, std::ptr::null_mut(), libc::_IONBF, 0);
        sys::err_set_logfp(fp.cast());
    }
    Ok(())
}

fn cstring(s: &str, what: &str) -> Result<CString, Error> {
    CString::new(s).map_err(|_| Error::Init {
        what: format!("{what} contains a NUL byte"),
    })
}

impl Decoder {
    /// A decoder for `mode`: `allphone` (phone recognition) or alignment (grammar set later).
    /// The library logs to `log` when given (the child process of [`crate::decode`] reads it
    /// to say which model file it was reading when it failed), else nowhere.
    pub(crate) fn new(
        model: &ModelPaths,
        allphone: bool,
        log: Option<&Path>,
    ) -> Result<Self, Error> {
        model.check()?;
        match log {
            Some(path) => log_unbuffered(path)?,
            None => quiet_library_logs(),
        }
        let path = |p: &Path| p.display().to_string();
        let mut args: Vec<String> = vec![
            "mouthpiece".into(),
            "-hmm".into(),
            path(&model.hmm),
            "-dict".into(),
            path(&model.dict),
            "-samprate".into(),
            "16000".into(),
        ];
        if allphone {
            // Settings verified with the Debian command-line tool (see docs/lipsync.md).
            for a in [
                "-allphone",
                &path(&model.phone_lm),
                "-backtrace",
                "yes",
                "-beam",
                "1e-20",
                "-pbeam",
                "1e-20",
                "-lw",
                "2.0",
            ] {
                args.push(a.to_string());
            }
        } else {
            // Wide beams: the grammar is a single path, so search breadth costs little.
            for a in ["-beam", "1e-60", "-wbeam", "1e-40", "-pbeam", "1e-60"] {
                args.push(a.to_string());
            }
        }
        let owned: Vec<CString> = args
            .iter()
            .map(|a| cstring(a, "model path"))
            .collect::<Result<_, _>>()?;
        let mut argv: Vec<*mut c_char> = owned.iter().map(|c| c.as_ptr() as *mut c_char).collect();
        // SAFETY: `ps_args()` returns the library's static argument table; argv points into
        // `owned`, alive for the call, and the library copies what it keeps. A null first
        // argument asks for a new configuration; strict = TRUE rejects unknown options.
        let config = unsafe {
            sys::cmd_ln_parse_r(
                std::ptr::null_mut(),
                sys::ps_args(),
                argv.len() as i32,
                argv.as_mut_ptr(),
                1,
            )
        };
        let config = NonNull::new(config).ok_or_else(|| Error::Init {
            what: "the configuration was refused".into(),
        })?;
        // SAFETY: `config` is a valid configuration; `ps_init` takes its own reference.
        let ps = unsafe { sys::ps_init(config.as_ptr()) };
        let Some(ps) = NonNull::new(ps) else {
            // SAFETY: we hold the only other reference to `config`.
            unsafe { sys::cmd_ln_free_r(config.as_ptr()) };
            return Err(Error::Init {
                what: format!(
                    "the decoder did not start with model {} (wrong or damaged model files?)",
                    model.hmm.display()
                ),
            });
        };
        Ok(Self {
            ps,
            config,
            dict: model.dict.clone(),
            phone_words: BTreeSet::new(),
        })
    }

    /// A phone recogniser (no transcript).
    pub fn phone_recognizer(model: &ModelPaths) -> Result<Self, Error> {
        Self::new(model, true, None)
    }

    /// An aligner (give it a transcript with [`Decoder::align`]).
    pub fn aligner(model: &ModelPaths) -> Result<Self, Error> {
        Self::new(model, false, None)
    }

    /// Every pronunciation of `word` in the dictionary (`word`, `word(2)`, …), as phone lists.
    pub fn pronunciations(&mut self, word: &str) -> Result<Vec<Vec<String>>, Error> {
        let mut out = Vec::new();
        for k in 1.. {
            let key = if k == 1 {
                word.to_string()
            } else {
                format!("{word}({k})")
            };
            let c = cstring(&key, "transcript word")?;
            // SAFETY: `ps` is valid, `c` outlives the call; the result is null or a string we
            // own and free with `ckd_free` right after copying it.
            let phones = unsafe {
                let p = sys::ps_lookup_word(self.ps.as_ptr(), c.as_ptr());
                if p.is_null() {
                    None
                } else {
                    let s = CStr::from_ptr(p).to_string_lossy().into_owned();
                    sys::ckd_free(p.cast());
                    Some(s)
                }
            };
            match phones {
                Some(p) => out.push(p.split_whitespace().map(str::to_string).collect()),
                None => break,
            }
        }
        Ok(out)
    }

    fn add_phone_word(&mut self, phone: &str, audio: &str) -> Result<String, Error> {
        let word = format!("{PHONE_WORD}{}", phone.to_ascii_lowercase());
        if self.phone_words.contains(&word) {
            return Ok(word);
        }
        let (w, p) = (cstring(&word, "phone")?, cstring(phone, "phone")?);
        // SAFETY: `ps` is valid; both strings outlive the call and the library copies them.
        // update = FALSE: the grammar search is built afterwards from the dictionary.
        let id = unsafe { sys::ps_add_word(self.ps.as_ptr(), w.as_ptr(), p.as_ptr(), 0) };
        if id < 0 {
            return Err(Error::Decode {
                audio: audio.to_string(),
                what: format!("the model refused phone {:?}", crate::cut(phone)),
            });
        }
        self.phone_words.insert(word.clone());
        Ok(word)
    }

    /// Runs one utterance through the active search and returns its segments. `audio`
    /// names the audio in errors.
    fn decode(&mut self, samples: &[i16], audio: &str) -> Result<Vec<TimedPhone>, Error> {
        let fail = |what: &str| Error::Decode {
            audio: audio.to_string(),
            what: what.into(),
        };
        if samples.is_empty() {
            return Err(fail("no audio"));
        }
        // SAFETY: `ps` is valid; `samples` outlives the call (the library copies the audio
        // into its feature buffers); full_utt = TRUE, no_search = FALSE.
        unsafe {
            if sys::ps_start_utt(self.ps.as_ptr()) < 0 {
                return Err(fail("cannot start an utterance"));
            }
            if sys::ps_process_raw(self.ps.as_ptr(), samples.as_ptr(), samples.len(), 0, 1) < 0 {
                sys::ps_end_utt(self.ps.as_ptr());
                return Err(fail("cannot process the audio"));
            }
            if sys::ps_end_utt(self.ps.as_ptr()) < 0 {
                return Err(fail("cannot end the utterance"));
            }
        }
        let mut out = Vec::new();
        // SAFETY: the iterator belongs to the decoder's current hypothesis; each word pointer
        // is copied before `ps_seg_next`, which frees the iterator when it returns null.
        unsafe {
            let mut score: i32 = 0;
            if sys::ps_get_hyp(self.ps.as_ptr(), &mut score).is_null() {
                return Err(Error::NoPath {
                    audio: audio.to_string(),
                });
            }
            let mut seg = sys::ps_seg_iter(self.ps.as_ptr());
            while !seg.is_null() {
                let word = CStr::from_ptr(sys::ps_seg_word(seg))
                    .to_string_lossy()
                    .into_owned();
                let (mut sf, mut ef): (c_int, c_int) = (0, 0);
                sys::ps_seg_frames(seg, &mut sf, &mut ef);
                out.push(TimedPhone {
                    start: sf as f64 / FRAME_RATE,
                    end: (ef + 1) as f64 / FRAME_RATE,
                    phone: word,
                });
                seg = sys::ps_seg_next(seg);
            }
        }
        if out.is_empty() {
            return Err(Error::NoPath {
                audio: audio.to_string(),
            });
        }
        Ok(out)
    }

    /// Phone recognition: every phone and filler the recogniser hears in `samples` (16 kHz;
    /// `audio` names them in errors).
    pub fn recognize_phones(
        &mut self,
        samples: &[i16],
        audio: &str,
    ) -> Result<Vec<TimedPhone>, Error> {
        self.decode(samples, audio)
    }

    /// Forced alignment of 16 kHz `samples` to `transcript` (words separated by spaces;
    /// punctuation other than apostrophes ignored; case ignored). `source_name` names the
    /// transcript in errors, `audio` the audio. Returns the transcript's phones with times,
    /// fillers (`SIL`, `<sil>`) where the recogniser put silence. A transcript of more than
    /// [`crate::MAX_WORDS_PER_SECOND`] words a second of audio is refused before the grammar
    /// is built.
    pub fn align(
        &mut self,
        samples: &[i16],
        transcript: &str,
        source_name: &str,
        audio: &str,
    ) -> Result<Vec<TimedPhone>, Error> {
        let words = crate::isolated::checked_words(transcript, source_name, samples.len(), audio)?;
        let mut rules = Vec::with_capacity(words.len());
        for word in &words {
            let prons = self.pronunciations(word)?;
            if prons.is_empty() {
                return Err(Error::UnknownWord {
                    source_name: source_name.to_string(),
                    word: crate::cut(word),
                    dict: self.dict.display().to_string(),
                });
            }
            let mut alternatives = Vec::with_capacity(prons.len());
            for pron in prons {
                let mut seq = Vec::with_capacity(pron.len());
                for phone in pron {
                    seq.push(self.add_phone_word(&phone, audio)?);
                }
                alternatives.push(format!("( {} )", seq.join(" ")));
            }
            rules.push(alternatives.join(" | "));
        }
        let mut jsgf = String::from("#JSGF V1.0;\ngrammar transcript;\npublic <utt> =");
        for k in 0..rules.len() {
            jsgf.push_str(&format!(" <w{k}>"));
        }
        jsgf.push_str(";\n");
        for (k, r) in rules.iter().enumerate() {
            jsgf.push_str(&format!("<w{k}> = {r};\n"));
        }
        let name = cstring("transcript", "search name")?;
        let grammar = cstring(&jsgf, "transcript")?;
        // SAFETY: `ps` is valid; the strings outlive the calls and the library copies them.
        unsafe {
            if sys::ps_set_jsgf_string(self.ps.as_ptr(), name.as_ptr(), grammar.as_ptr()) < 0 {
                return Err(Error::Decode {
                    audio: audio.to_string(),
                    what: format!("the grammar of transcript {source_name} was refused"),
                });
            }
            if sys::ps_set_search(self.ps.as_ptr(), name.as_ptr()) < 0 {
                return Err(Error::Decode {
                    audio: audio.to_string(),
                    what: "cannot switch to the transcript grammar".into(),
                });
            }
        }
        let segs = self.decode(samples, audio)?;
        Ok(segs
            .into_iter()
            .map(|mut s| {
                if let Some(p) = s.phone.strip_prefix(PHONE_WORD) {
                    s.phone = p.to_ascii_uppercase();
                }
                s
            })
            .collect())
    }
}

/// Transcript words for the dictionary: lowercase, letters, digits and apostrophes kept.
pub fn transcript_words(text: &str) -> Vec<String> {
    text.split(|c: char| c.is_whitespace() || (c.is_ascii_punctuation() && c != '\''))
        .map(|w| w.trim_matches('\'').to_lowercase())
        .filter(|w| !w.is_empty())
        .collect()
}

impl Drop for Decoder {
    fn drop(&mut self) {
        // SAFETY: we own one reference to each; the decoder goes first (it holds its own
        // reference to the configuration), then ours.
        unsafe {
            sys::ps_free(self.ps.as_ptr());
            sys::cmd_ln_free_r(self.config.as_ptr());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transcript_words_drop_punctuation_keep_apostrophes() {
        assert_eq!(
            transcript_words("Don't ask me -- to carry an oily rag, like that!"),
            ["don't", "ask", "me", "to", "carry", "an", "oily", "rag", "like", "that"]
        );
        assert!(transcript_words(" ... ").is_empty());
    }

    #[test]
    fn missing_model_is_named() {
        let m = ModelPaths::en_us(Path::new("/nonexistent/model"));
        let err = Decoder::aligner(&m).unwrap_err();
        assert!(
            err.to_string().contains("/nonexistent/model/en-us"),
            "{err}"
        );
    }
}
