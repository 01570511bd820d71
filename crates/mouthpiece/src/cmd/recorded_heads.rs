//! The character's head as the daemon recorded it in a take (`/character/<name>` messages'
//! `head`, docs/head.md), for `mouthpiece export` of a take: the re-run tracker knows nothing
//! of the `look_at` requests made live over the WebSocket, the recorded head has their turns.

use std::path::Path;

use anyhow::Context;
use mouthpiece_recording::MessageReader;
use mouthpiece_retarget::head::HeadLine;

use crate::exit::bad_input;

/// Longest `/character/<name>` message read (a character message is a few kilobytes).
const MAX_MESSAGE: usize = 1 << 20;

/// Reads a take's recorded heads for one character alongside its frames, in file order
/// (a second pass over the file, one message at a time).
pub struct RecordedHeads {
    reader: MessageReader,
    topic: String,
    /// The head of the latest message at or before the last frame asked for.
    current: Option<HeadLine>,
    /// A message read past the last frame asked for, kept for a later frame.
    ahead: Option<(u64, Option<HeadLine>)>,
}

impl RecordedHeads {
    /// The recorded heads of `character` in the take `path` (an MCAP file).
    pub fn open(path: &Path, character: &str) -> anyhow::Result<Self> {
        let reader = MessageReader::open(path)
            .with_context(|| format!("cannot open session {}", path.display()))
            .map_err(bad_input)?;
        Ok(Self {
            reader,
            topic: format!("/character/{character}"),
            current: None,
            ahead: None,
        })
    }

    /// The head recorded with the frame logged at `log_time` (ns); a frame whose message was
    /// dropped from the take keeps the head recorded before it. `None` until the take has a
    /// recorded head (takes made before heads, or by `mouthpiece record`, have none).
    pub fn at(&mut self, log_time: u64) -> anyhow::Result<Option<HeadLine>> {
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
            let Some(m) = self
                .reader
                .next_message()
                .map_err(|e| bad_input(anyhow::Error::new(e)))?
            else {
                break;
            };
            if *m.topic != *self.topic {
                continue;
            }
            let where_ = || {
                format!(
                    "{}: {} at log time {} ns",
                    self.reader.path().display(),
                    self.topic,
                    m.log_time
                )
            };
            if m.data.len() > MAX_MESSAGE {
                return Err(bad_input(anyhow::anyhow!(
                    "{}: a message of {} bytes (at most {MAX_MESSAGE})",
                    where_(),
                    m.data.len()
                )));
            }
            let mut message: serde_json::Value = serde_json::from_slice(&m.data)
                .with_context(|| format!("{}: not JSON", where_()))
                .map_err(bad_input)?;
            let head: Option<HeadLine> = match message.get_mut("head").map(serde_json::Value::take)
            {
                None | Some(serde_json::Value::Null) => None,
                Some(v) => Some(
                    serde_json::from_value(v)
                        .with_context(|| format!("{}: `head` is not a character head", where_()))
                        .map_err(bad_input)?,
                ),
            };
            if let Some(h) = &head {
                let unit = h
                    .rotation
                    .iter()
                    .chain(&h.eye_left)
                    .chain(&h.eye_right)
                    .all(|c| c.is_finite());
                if !unit {
                    return Err(bad_input(anyhow::anyhow!(
                        "{}: the head's rotations are not finite",
                        where_()
                    )));
                }
            }
            self.ahead = Some((m.log_time, head.map(normalised)));
        }
        Ok(self.current)
    }
}

/// The recorded quaternions (32-bit floats) made unit again in 64 bits.
fn normalised(mut h: HeadLine) -> HeadLine {
    for q in [&mut h.rotation, &mut h.eye_left, &mut h.eye_right] {
        let n = q.iter().map(|c| c * c).sum::<f64>().sqrt();
        if n > 0.0 {
            q.iter_mut().for_each(|c| *c /= n);
        }
    }
    h
}
