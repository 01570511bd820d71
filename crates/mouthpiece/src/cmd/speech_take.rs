//! A take from a booth without a camera (`[source] spec = "none"`): no camera frames, only
//! the speech-driven steps the daemon wrote (`/character/<name>`, `/head`). `export` turns
//! the character's recorded steps into its take lines as they are (nothing is re-run: there
//! is no picture to run on), `t` counted from the first step.

use std::io::Write;
use std::path::Path;

use anyhow::{anyhow, Context as _};
use mouthpiece_recording::{MessageReader, TOPIC_COLOR};
use serde_json::{json, Map, Value};

use crate::exit::{bad_input, bad_input_if};

/// Longest `/character/<name>` or `/head` message read (a step is a few kilobytes).
const MAX_MESSAGE: usize = 1 << 20;

fn recording_error(err: mouthpiece_recording::RecordingError) -> anyhow::Error {
    let bad = err.is_bad_input();
    bad_input_if(bad, err)
}

/// Whether `path` is a take without camera frames whose characters' steps were recorded:
/// its first character step comes before any colour image (a camera take writes each
/// frame's image before its derived channels). Reads only as far as that.
pub fn is_speech_only(path: &Path) -> anyhow::Result<bool> {
    let mut reader = MessageReader::open(path)
        .with_context(|| format!("cannot open session {}", path.display()))
        .map_err(bad_input)?;
    while let Some(m) = reader.next_message().map_err(recording_error)? {
        if &*m.topic == TOPIC_COLOR {
            return Ok(false);
        }
        if m.topic.starts_with("/character/") {
            return Ok(true);
        }
    }
    Ok(false)
}

/// Writes one take line (the `retarget` output format) per recorded step of `character`;
/// returns how many. The performer's head is the `/head` message of the step's log time.
pub fn write_lines(path: &Path, character: &str, out: &mut dyn Write) -> anyhow::Result<u64> {
    let mut reader = MessageReader::open(path)
        .with_context(|| format!("cannot open session {}", path.display()))
        .map_err(bad_input)?;
    let topic = format!("/character/{character}");
    let mut head: Option<(u64, Value)> = None;
    let mut first: Option<u64> = None;
    let mut lines = 0u64;
    while let Some(m) = reader.next_message().map_err(recording_error)? {
        let is_head = &*m.topic == "/head";
        if !is_head && *m.topic != *topic {
            continue;
        }
        let where_ = || {
            format!(
                "{}: {} at log time {} ns",
                path.display(),
                m.topic,
                m.log_time
            )
        };
        if m.data.len() > MAX_MESSAGE {
            return Err(bad_input(anyhow!(
                "{}: a message of {} bytes (at most {MAX_MESSAGE})",
                where_(),
                m.data.len()
            )));
        }
        let message: Map<String, Value> = serde_json::from_slice(&m.data)
            .with_context(|| format!("{}: not a JSON object", where_()))
            .map_err(bad_input)?;
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
        serde_json::to_writer(&mut *out, &line).context("cannot write the temporary take")?;
        out.write_all(b"\n")
            .context("cannot write the temporary take")?;
        lines += 1;
    }
    if lines == 0 {
        return Err(bad_input(anyhow!(
            "{}: no camera frames and no step of character {character:?} ({topic})",
            path.display()
        )));
    }
    Ok(lines)
}
