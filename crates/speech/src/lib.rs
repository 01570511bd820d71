//! Phones and their times from speech, fully offline.
//!
//! - [`wav`]: a WAV file (any rate, any PCM or float format; the first channel) → 16 kHz
//!   16-bit samples, the rate of the acoustic model.
//! - [`Decoder`]: CMU PocketSphinx (Debian's 5prealpha library and `en-us` model) behind a safe
//!   API. Every unsafe call into the library is in this crate's `decoder` module.
//!   - [`Decoder::recognize_phones`]: phone recognition with the model's phone bigram
//!     ("allphone" search): no transcript needed.
//!   - [`Decoder::align`]: forced alignment to a transcript. The 5prealpha API has no aligner,
//!     so each word's dictionary pronunciations become a grammar (JSGF) whose *words are single
//!     phones*: the recogniser can only walk the transcript's phones, in order, with optional
//!     silence between them, and its word segmentation is the phone segmentation.

mod decoder;
pub mod festival;
mod isolated;
pub mod wav;

pub use decoder::{transcript_words, Decoder, ModelPaths, TimedPhone};
pub use isolated::{decode, Task, MAX_WORDS_PER_SECOND};

/// `s` cut to 80 characters (an ellipsis marks the cut) with its control characters
/// escaped ([`mouthpiece_output::shown()`]): errors never echo megabytes, nor an escape
/// sequence.
pub(crate) fn cut(s: &str) -> String {
    match s.char_indices().nth(80) {
        Some((i, _)) => format!("{}…", mouthpiece_output::shown(&s[..i])),
        None => mouthpiece_output::shown(s).into_owned(),
    }
}

/// The acoustic model's sample rate.
pub const MODEL_RATE: u32 = 16_000;

/// What can go wrong.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The WAV file cannot be read.
    #[error("{path}: cannot read WAV audio: {source}")]
    Wav {
        path: String,
        #[source]
        source: hound::Error,
    },
    /// The WAV file reads but is unusable (no samples, unsupported format).
    #[error("{path}: {what}")]
    BadAudio { path: String, what: String },
    /// A model file is missing.
    #[error("PocketSphinx model file {path} not found (install Debian's pocketsphinx-en-us, or pass the model directory)")]
    ModelMissing { path: String },
    /// The library refused to start (bad model files, bad settings).
    #[error("PocketSphinx could not start: {what}")]
    Init { what: String },
    /// The library crashed or exited while decoding in its child process: a damaged or
    /// wrong model file (named when the library's log says which it was reading).
    #[error(
        "PocketSphinx {how} while reading model file {file}: damaged or wrong model files{detail}"
    )]
    Crashed {
        file: String,
        how: String,
        detail: String,
    },
    /// A transcript with more words than the audio can hold.
    #[error(
        "{source_name}: the transcript has {words} words, more than {max} (at most \
         {per_second} a second of the {seconds:.1} s of audio in {audio} can be aligned)"
    )]
    TooManyWords {
        source_name: String,
        audio: String,
        words: usize,
        max: usize,
        per_second: f64,
        seconds: f64,
    },
    /// The search found no path through the audio.
    #[error(
        "{audio}: PocketSphinx found no path through the audio (is it speech, and does the \
         transcript say what it says?)"
    )]
    NoPath { audio: String },
    /// A transcript word with a NUL or another control character (no dictionary holds one,
    /// and the library takes C strings).
    #[error("{source_name}: word {word} holds a control character")]
    BadWord { source_name: String, word: String },
    /// The transcript has no words.
    #[error("{source_name}: the transcript is empty")]
    EmptyTranscript { source_name: String },
    /// A transcript word the pronunciation dictionary does not have.
    #[error("{source_name}: word {word:?} is not in the pronunciation dictionary {dict}")]
    UnknownWord {
        source_name: String,
        word: String,
        dict: String,
    },
    /// Decoding failed or found nothing.
    #[error("{audio}: PocketSphinx: {what}")]
    Decode { audio: String, what: String },
}

impl Error {
    /// Whether the input (audio, transcript, model directory) is at fault rather than the
    /// program or the machine.
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, Self::Decode { .. })
    }
}
