//! Reading a daemon's take back: the one place that knows the file's layout for its readers
//! (`mouthpiece export` and `play`, the WAV beside an export, the console's take player, the
//! NATS uploader's take record).
//!
//! [`TakeMetadata`] is the `mouthpiece.take` record, parsed once. Every step the daemon
//! published is recorded as it went out, per character on `/character/<name>` (points,
//! confidence, curve, rig, head and eyes, what drove the mouth) and the performer's head on
//! `/head`, whether the camera, the microphone's speech or both drove it. [`write_lines`]
//! turns a character's recorded steps into take lines as they are: nothing is re-run, so what
//! `export` and `play` write or send is what WebSocket subscribers received during the take
//! (the numbers are the same 32-bit floats); `t` counts from the take's first step.
//!
//! A [`ReadError`] names the file, and for a message its topic and log time; names from the
//! file are escaped with [`shown()`](mouthpiece_output::shown()).
//! [`ReadError::is_bad_input`] tells the file's fault from the machine's.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use mouthpiece_output::shown;
use mouthpiece_recording::{MessageReader, RawMessage, RecordingError, TOPIC_COLOR};
use mouthpiece_server::{Timecode, TimecodeRate};
use serde_json::{json, Map, Value};

mod chunk;

pub use chunk::{
    decode_raw_audio, read_chunk, RawAudio, RawAudioError, LATE_AUDIO_S, MAX_AUDIO_BYTES,
    MAX_CHUNK_BYTES, TOPIC_AUDIO,
};

/// The metadata record that marks a daemon's take (written before any message).
pub const TAKE_METADATA: &str = "mouthpiece.take";
/// The channel of the performer's head, one message per step.
pub const TOPIC_HEAD: &str = "/head";
/// The tracked dots of a take (camera frame, metres).
pub const TOPIC_POINTS: &str = "/performer/points";
/// What precedes a character's name in its channel's topic.
pub const CHARACTER_PREFIX: &str = "/character/";

/// Longest `/character/<name>` or `/head` message read (a step is a few kilobytes).
pub const MAX_MESSAGE: usize = 1 << 20;

/// Why a take could not be read back.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The file named by the user cannot be opened.
    #[error("cannot open session {}", path.display())]
    Open {
        path: PathBuf,
        #[source]
        source: RecordingError,
    },
    /// The file is not readable as a recording (or the disk failed reading it).
    #[error(transparent)]
    Recording(#[from] RecordingError),
    #[error("{}: {} at log time {log_time} ns: a message of {bytes} bytes (at most {MAX_MESSAGE})", path.display(), shown(topic))]
    TooLarge {
        path: PathBuf,
        topic: String,
        log_time: u64,
        bytes: usize,
    },
    #[error("{}: {} at log time {log_time} ns: not a JSON object", path.display(), shown(topic))]
    NotJson {
        path: PathBuf,
        topic: String,
        log_time: u64,
        #[source]
        source: serde_json::Error,
    },
    #[error(
        "{}: the take recorded no step of character {} ({}); it recorded: {}",
        path.display(),
        shown(character),
        shown(&format!("{CHARACTER_PREFIX}{character}")),
        if recorded.is_empty() { "no character".to_owned() } else {
            recorded.iter().map(|n| shown(n).to_string()).collect::<Vec<_>>().join(", ")
        }
    )]
    NoSteps {
        path: PathBuf,
        character: String,
        /// The characters it recorded (the first 64 names).
        recorded: Vec<String>,
    },
    #[error("{}: {} at log time {log_time} ns: timecode {} is not HH:MM:SS:FF", path.display(), shown(topic), shown(label))]
    BadTimecode {
        path: PathBuf,
        topic: String,
        log_time: u64,
        label: String,
    },
    #[error("{}: {} at log time {log_time} ns: `head` is not a character head", path.display(), shown(topic))]
    NotAHead {
        path: PathBuf,
        topic: String,
        log_time: u64,
        #[source]
        source: serde_json::Error,
    },
    #[error("{}: {} at log time {log_time} ns: {what}", path.display(), shown(topic))]
    BadHead {
        path: PathBuf,
        topic: String,
        log_time: u64,
        what: &'static str,
    },
    #[error("{}: the {TAKE_METADATA} metadata record has no take number (take = {})", path.display(), shown(take))]
    BadMetadata { path: PathBuf, take: String },
    #[error("cannot write the temporary take")]
    Write(#[source] std::io::Error),
}

impl ReadError {
    /// The file's content is wrong, or the file named cannot be opened (the user's to fix), as
    /// opposed to the machine failing to read or write.
    pub fn is_bad_input(&self) -> bool {
        match self {
            Self::Recording(e) => e.is_bad_input(),
            Self::Write(_) => false,
            _ => true,
        }
    }
}

/// The take's `mouthpiece.take` record, as its writer writes it when the take starts.
#[derive(Debug, Clone, PartialEq)]
pub struct TakeMetadata {
    pub slate: String,
    pub take: u32,
    /// When the take started, microseconds since the Unix epoch (0 when not recorded).
    pub started_unix_us: i64,
    /// The timecode rate's name (`[takes]`'s, e.g. `"29.97df"`), as recorded.
    pub timecode_rate: String,
    /// What the booth was reading (`replay:…`, a camera, speech alone).
    pub source: String,
}

impl TakeMetadata {
    /// The record of the take at `path`; `None` for a recording that is not a daemon's take
    /// (a plain recording from `record` or `synth`). Reads only up to the first message: the
    /// record precedes every message.
    pub fn read(path: &Path) -> Result<Option<Self>, ReadError> {
        let mut reader = open(path)?;
        reader.next_message()?;
        Self::from_reader(&reader)
    }

    /// The record among the metadata `reader` has seen so far.
    pub fn from_reader(reader: &MessageReader) -> Result<Option<Self>, ReadError> {
        reader
            .metadata()
            .iter()
            .find(|(name, _)| name == TAKE_METADATA)
            .map(|(_, record)| Self::from_record(reader.path(), record))
            .transpose()
    }

    /// The record's fields (`path`: the take, for the error); the take number is required,
    /// the rest read empty (0) when missing.
    pub fn from_record(path: &Path, record: &BTreeMap<String, String>) -> Result<Self, ReadError> {
        let field = |key: &str| record.get(key).cloned().unwrap_or_default();
        let take = field("take");
        Ok(Self {
            take: take.parse().map_err(|_| ReadError::BadMetadata {
                path: path.to_owned(),
                take,
            })?,
            slate: field("slate"),
            started_unix_us: field("started_unix_us").parse().unwrap_or(0),
            timecode_rate: field("timecode_rate"),
            source: field("source"),
        })
    }

    /// The recorded timecode rate; `None` when its name is not one of [`TimecodeRate::ALL`].
    pub fn rate(&self) -> Option<TimecodeRate> {
        self.timecode_rate.parse().ok()
    }

    /// The time-of-day timecode at the take's start, at its rate (empty for an unknown rate).
    pub fn start_timecode(&self) -> String {
        self.rate()
            .map(|rate| Timecode::from_unix_micros(self.started_unix_us, rate).to_string())
            .unwrap_or_default()
    }
}

fn open(path: &Path) -> Result<MessageReader, ReadError> {
    MessageReader::open(path).map_err(|source| ReadError::Open {
        path: path.to_owned(),
        source,
    })
}

/// Whether `path` is a daemon's take (its steps recorded) rather than a plain recording
/// from `record` or `synth` (camera images only). Reads only the file's first message.
pub fn is_daemon_take(path: &Path) -> Result<bool, ReadError> {
    let mut reader = open(path)?;
    reader.next_message()?;
    Ok(reader
        .metadata()
        .iter()
        .any(|(name, _)| name == TAKE_METADATA))
}

/// Whether a take holds no camera image: a booth without a camera, speech alone.
pub fn has_no_images(path: &Path) -> Result<bool, ReadError> {
    let mut reader = open(path)?;
    while let Some(m) = reader.next_message()? {
        if &*m.topic == TOPIC_COLOR {
            return Ok(false);
        }
    }
    Ok(true)
}

/// A message of at most [`MAX_MESSAGE`] bytes as a JSON object.
fn json_object(path: &Path, m: &RawMessage) -> Result<Map<String, Value>, ReadError> {
    if m.data.len() > MAX_MESSAGE {
        return Err(ReadError::TooLarge {
            path: path.to_owned(),
            topic: m.topic.to_string(),
            log_time: m.log_time,
            bytes: m.data.len(),
        });
    }
    serde_json::from_slice(&m.data).map_err(|source| ReadError::NotJson {
        path: path.to_owned(),
        topic: m.topic.to_string(),
        log_time: m.log_time,
        source,
    })
}

/// Writes one take line (the `retarget` output format) per recorded step of `character`;
/// returns how many. The performer's head is the `/head` message of the step's log time.
/// A take without a step of `character` is an error naming the characters it recorded.
pub fn write_lines(path: &Path, character: &str, out: &mut dyn Write) -> Result<u64, ReadError> {
    let mut reader = open(path)?;
    let topic = format!("{CHARACTER_PREFIX}{character}");
    let mut head: Option<(u64, Value)> = None;
    let mut first: Option<u64> = None;
    let mut lines = 0u64;
    let mut recorded = std::collections::BTreeSet::new();
    while let Some(m) = reader.next_message()? {
        if let Some(name) = m.topic.strip_prefix(CHARACTER_PREFIX) {
            if recorded.len() < 64 && !recorded.contains(name) {
                recorded.insert(name.to_owned());
            }
        }
        let is_head = &*m.topic == TOPIC_HEAD;
        if !is_head && *m.topic != *topic {
            continue;
        }
        let message = json_object(path, &m)?;
        if is_head {
            head = Some((m.log_time, Value::Object(message)));
            continue;
        }
        let first = *first.get_or_insert(m.log_time);
        let field = |k: &str| message.get(k).cloned().unwrap_or(Value::Null);
        let pose = match &head {
            Some((t, pose)) if *t == m.log_time => pose.clone(),
            _ => {
                json!({"rotation": [1.0, 0.0, 0.0, 0.0], "translation": [0.0, 0.0, 0.0], "lost": false})
            }
        };
        let mut line = json!({
            "t": m.log_time.saturating_sub(first) as f64 / 1e9,
            "seq": field("seq"),
            "character": character,
            "points": field("points"),
            "confidence": field("confidence"),
            "head": {"rotation": pose["rotation"], "translation": pose["translation"]},
            "head_lost": pose["lost"].as_bool().unwrap_or(false),
            // The take holds the curve's points; the line format names how it was made.
            "curve": match field("curve") {
                Value::Null => Value::Null,
                points => json!({"method": "recorded", "closed": true, "points": points}),
            },
            "source": field("source"),
        });
        for (from, to) in [("rig", "rig"), ("head", "character_head")] {
            if let Some(v) = message.get(from).filter(|v| !v.is_null()) {
                line[to] = v.clone();
            }
        }
        serde_json::to_writer(&mut *out, &line).map_err(|e| ReadError::Write(e.into()))?;
        out.write_all(b"\n").map_err(ReadError::Write)?;
        lines += 1;
    }
    if lines == 0 {
        return Err(ReadError::NoSteps {
            path: path.to_owned(),
            character: character.to_owned(),
            recorded: recorded.into_iter().collect(),
        });
    }
    Ok(lines)
}

/// The timecode label each recorded step of `character` was published with (the studio's LTC
/// when the booth followed one), in the order of [`write_lines`]' lines. A label that is not
/// `HH:MM:SS:FF` (`;` before the frames for drop-frame) is an error naming the message.
pub fn timecodes(path: &Path, character: &str) -> Result<Vec<String>, ReadError> {
    let mut reader = open(path)?;
    let topic = format!("{CHARACTER_PREFIX}{character}");
    let mut labels = Vec::new();
    while let Some(m) = reader.next_message()? {
        if *m.topic != *topic || m.data.len() > MAX_MESSAGE {
            continue;
        }
        let message = json_object(path, &m)?;
        let label = message
            .get("timecode")
            .and_then(Value::as_str)
            .unwrap_or_default();
        if !is_timecode_label(label) {
            return Err(ReadError::BadTimecode {
                path: path.to_owned(),
                topic,
                log_time: m.log_time,
                label: label.to_owned(),
            });
        }
        labels.push(label.to_owned());
    }
    Ok(labels)
}

/// `HH:MM:SS:FF`, or `HH:MM:SS;FF` (drop-frame), digits only.
pub fn is_timecode_label(label: &str) -> bool {
    let b = label.as_bytes();
    b.len() == 11
        && [2, 5].iter().all(|&i| b[i] == b':')
        && (b[8] == b':' || b[8] == b';')
        && [0, 1, 3, 4, 6, 7, 9, 10]
            .iter()
            .all(|&i| b[i].is_ascii_digit())
}

/// A recorded timecode label as a [`Timecode`]; `None` when it is not one.
pub fn parse_timecode_label(label: &str) -> Option<Timecode> {
    if !is_timecode_label(label) {
        return None;
    }
    let field = |i: usize| -> Option<u8> { label.get(i..i + 2)?.parse().ok() };
    Some(Timecode {
        hours: field(0)?,
        minutes: field(3)?,
        seconds: field(6)?,
        frames: field(9)?,
        drop_frame: label.as_bytes()[8] == b';',
    })
}

/// Where a recording's frames lie: its camera images, or for a take from a booth without a
/// camera the steps of its first character. Read from every message's log time (no image is
/// decoded), with the take's metadata.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameSpan {
    /// Log time of the first and the last frame, ns.
    pub first_ns: u64,
    pub last_ns: u64,
    pub frames: u64,
    /// The timecode the first frame was published with (`/head` is stamped with every frame);
    /// `None` for a recording without one.
    pub first_label: Option<String>,
}

/// The frames of the recording at `path` (`None`: it has none) and its take's metadata
/// (`None`: not a daemon's take).
pub fn frame_span(path: &Path) -> Result<(Option<FrameSpan>, Option<TakeMetadata>), ReadError> {
    let mut messages = MessageReader::open(path)?;
    let (mut first, mut last, mut frames) = (None, 0u64, 0u64);
    let mut steps: (Option<u64>, u64, u64) = (None, 0, 0);
    let mut step_topic: Option<String> = None;
    let mut first_label: Option<String> = None;
    while let Some(m) = messages.next_message()? {
        if first_label.is_none() && &*m.topic == TOPIC_HEAD && m.data.len() < MAX_MESSAGE {
            first_label = serde_json::from_slice::<Value>(&m.data)
                .ok()
                .and_then(|v| v["timecode"].as_str().map(str::to_owned));
        }
        if &*m.topic == TOPIC_COLOR {
            first.get_or_insert(m.log_time);
            last = last.max(m.log_time);
            frames += 1;
        } else if m.topic.starts_with(CHARACTER_PREFIX)
            && step_topic.get_or_insert_with(|| m.topic.to_string()) == &*m.topic
        {
            steps.0.get_or_insert(m.log_time);
            steps.1 = steps.1.max(m.log_time);
            steps.2 += 1;
        }
    }
    if first.is_none() {
        (first, last, frames) = steps;
    }
    let span = first.map(|first_ns| FrameSpan {
        first_ns,
        last_ns: last,
        frames,
        first_label,
    });
    Ok((span, TakeMetadata::from_reader(&messages)?))
}

/// A character's head as the daemon recorded it (`/character/<name>` messages' `head`,
/// docs/head.md), read alongside the take's frames in file order (a second pass over the
/// file, one message at a time). `H` is the caller's head type, deserialized from the message.
pub struct RecordedHeads<H> {
    reader: MessageReader,
    topic: String,
    /// The head of the latest message at or before the last frame asked for.
    current: Option<H>,
    /// A message read past the last frame asked for, kept for a later frame.
    ahead: Option<(u64, Option<H>)>,
}

impl<H: serde::de::DeserializeOwned + Copy> RecordedHeads<H> {
    /// The recorded heads of `character` in the take `path`.
    pub fn open(path: &Path, character: &str) -> Result<Self, ReadError> {
        Ok(Self {
            reader: open(path)?,
            topic: format!("{CHARACTER_PREFIX}{character}"),
            current: None,
            ahead: None,
        })
    }

    /// The head recorded with the frame logged at `log_time` (ns); a frame whose message was
    /// dropped from the take keeps the head recorded before it. `None` until the take has a
    /// recorded head (takes made before heads, or by `mouthpiece record`, have none). `check`
    /// vets (and may normalise) each head read; its refusal is an error naming the message.
    pub fn at(
        &mut self,
        log_time: u64,
        check: impl Fn(H) -> Result<H, &'static str>,
    ) -> Result<Option<H>, ReadError> {
        loop {
            if let Some((t, head)) = self.ahead {
                if t > log_time {
                    break;
                }
                self.ahead = None;
                if head.is_some() {
                    self.current = head;
                }
            }
            let Some(m) = self.reader.next_message()? else {
                break;
            };
            if *m.topic != *self.topic {
                continue;
            }
            let path = self.reader.path();
            let mut message = json_object(path, &m)?;
            let head = match message.remove("head") {
                None | Some(Value::Null) => None,
                Some(v) => {
                    let head = serde_json::from_value(v).map_err(|source| ReadError::NotAHead {
                        path: path.to_owned(),
                        topic: self.topic.clone(),
                        log_time: m.log_time,
                        source,
                    })?;
                    Some(check(head).map_err(|what| ReadError::BadHead {
                        path: path.to_owned(),
                        topic: self.topic.clone(),
                        log_time: m.log_time,
                        what,
                    })?)
                }
            };
            self.ahead = Some((m.log_time, head));
        }
        Ok(self.current)
    }
}

#[cfg(test)]
mod tests;
