//! A daemon's take (an MCAP file with the `mouthpiece.take` metadata record): every step
//! the daemon published is recorded as it went out, per character on `/character/<name>`
//! (points, confidence, curve, rig, head and eyes, what drove the mouth) and the performer's
//! head on `/head`, whether the camera, the microphone's speech or both drove it. `export`
//! and `play` turn a character's recorded steps into take lines as they are: nothing is
//! re-run, so what they write or send is what WebSocket subscribers received during the take
//! (the numbers are the same 32-bit floats). `t` counts from the take's first step.

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

/// The metadata record that marks a daemon's take (written before any message).
const TAKE_METADATA: &str = "mouthpiece.take";

/// Whether `path` is a daemon's take (its steps recorded) rather than a plain recording
/// from `record` or `synth` (camera images only). Reads only the file's first message.
pub fn is_daemon_take(path: &Path) -> anyhow::Result<bool> {
    let mut reader = MessageReader::open(path)
        .with_context(|| format!("cannot open session {}", path.display()))
        .map_err(bad_input)?;
    reader.next_message().map_err(recording_error)?;
    Ok(reader
        .metadata()
        .iter()
        .any(|(name, _)| name == TAKE_METADATA))
}

/// Whether a take holds no camera image: a booth without a camera, speech alone.
pub fn has_no_images(path: &Path) -> anyhow::Result<bool> {
    let mut reader = MessageReader::open(path)
        .with_context(|| format!("cannot open session {}", path.display()))
        .map_err(bad_input)?;
    while let Some(m) = reader.next_message().map_err(recording_error)? {
        if &*m.topic == TOPIC_COLOR {
            return Ok(false);
        }
    }
    Ok(true)
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
    let mut recorded = std::collections::BTreeSet::new();
    while let Some(m) = reader.next_message().map_err(recording_error)? {
        if let Some(name) = m.topic.strip_prefix("/character/") {
            if recorded.len() < 64 && !recorded.contains(name) {
                recorded.insert(name.to_owned());
            }
        }
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
        let recorded: Vec<String> = recorded
            .iter()
            .map(|n| mouthpiece_output::shown(n).to_string())
            .collect();
        return Err(bad_input(anyhow!(
            "{}: the take recorded no step of character {} ({}); it recorded: {}",
            path.display(),
            mouthpiece_output::shown(character),
            mouthpiece_output::shown(&topic),
            if recorded.is_empty() {
                "no character".to_owned()
            } else {
                recorded.join(", ")
            }
        )));
    }
    Ok(lines)
}

/// The timecode label each recorded step of `character` was published with (the studio's LTC
/// when the booth followed one), in the order of [`write_lines`]' lines. A label that is not
/// `HH:MM:SS:FF` (`;` before the frames for drop-frame) is bad input naming the message.
pub fn timecodes(path: &Path, character: &str) -> anyhow::Result<Vec<String>> {
    let mut reader = MessageReader::open(path)
        .with_context(|| format!("cannot open session {}", path.display()))
        .map_err(bad_input)?;
    let topic = format!("/character/{character}");
    let mut labels = Vec::new();
    while let Some(m) = reader.next_message().map_err(recording_error)? {
        if *m.topic != *topic || m.data.len() > MAX_MESSAGE {
            continue;
        }
        let message: Value = serde_json::from_slice(&m.data)
            .with_context(|| {
                format!(
                    "{}: {topic} at log time {} ns: not JSON",
                    path.display(),
                    m.log_time
                )
            })
            .map_err(bad_input)?;
        let label = message["timecode"].as_str().unwrap_or_default();
        if !is_timecode_label(label) {
            return Err(bad_input(anyhow!(
                "{}: {topic} at log time {} ns: timecode {} is not HH:MM:SS:FF",
                path.display(),
                m.log_time,
                mouthpiece_output::shown(label)
            )));
        }
        labels.push(label.to_owned());
    }
    Ok(labels)
}

/// `HH:MM:SS:FF`, or `HH:MM:SS;FF` (drop-frame), digits only.
fn is_timecode_label(label: &str) -> bool {
    let b = label.as_bytes();
    b.len() == 11
        && [2, 5].iter().all(|&i| b[i] == b':')
        && (b[8] == b':' || b[8] == b';')
        && [0, 1, 3, 4, 6, 7, 9, 10]
            .iter()
            .all(|&i| b[i].is_ascii_digit())
}

#[cfg(test)]
mod tests {
    #[test]
    fn timecode_labels_are_checked() {
        for good in ["10:00:00:00", "23:59:59;29"] {
            assert!(super::is_timecode_label(good), "{good}");
        }
        for bad in [
            "",
            "10:00:00",
            "10:00:00:0x",
            "10:00:00:00,1",
            "1\n:00:00:00",
        ] {
            assert!(!super::is_timecode_label(bad), "{bad}");
        }
    }
}
