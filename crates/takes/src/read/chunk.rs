//! One chunk of a take as the console's player reads it: its colour images as stored (JPEG),
//! the tracked dots projected into the image, and the sound of its `/audio` channel
//! (`foxglove.RawAudio`, `pcm-s16`) placed on the same clock.
//!
//! A chunk holds at most the caller's cap of images (the player's: [`MAX_CHUNK_BYTES`]) and
//! [`MAX_AUDIO_BYTES`] of sound; a chunk that reaches the first cap ends early (its `next_s`
//! says where the next one starts). Sound is written as it arrives, after the pictures of its
//! time, so a chunk reads [`LATE_AUDIO_S`] past its end for it. Each read goes through the
//! file from its start (chunks are decompressed and checked, not kept): a chunk late in a long
//! take costs a read of everything before it.

use std::path::Path;

use mouthpiece_frame::{Calibration, Intrinsics};
use mouthpiece_recording::cdr::{CameraCalibration, CompressedImage, COMPRESSED_IMAGE_SCHEMA_NAME};
use mouthpiece_recording::{MessageReader, RawMessage};
use mouthpiece_server::{ChunkAudio, ChunkFrame, DotState, ImageDot, TakeChunk, TakeChunkError};

use super::{CHARACTER_PREFIX, TOPIC_POINTS};

/// Most image bytes in one chunk.
pub const MAX_CHUNK_BYTES: usize = 24 << 20;
/// Most sound bytes in one chunk (10 s of 8 channels at 96 kHz).
pub const MAX_AUDIO_BYTES: usize = 16 << 20;
/// The sound channel of a take.
pub const TOPIC_AUDIO: &str = mouthpiece_recording::TOPIC_AUDIO;
/// How far past a chunk's end its messages are read for sound written late, seconds.
pub const LATE_AUDIO_S: f64 = 1.0;

/// A `foxglove.RawAudio` message.
#[derive(Debug, Clone, PartialEq)]
pub struct RawAudio {
    pub data: Vec<u8>,
    pub format: String,
    pub sample_rate: u32,
    pub channels: u32,
}

/// Why a `foxglove.RawAudio` message could not be read.
#[derive(Debug, thiserror::Error)]
pub enum RawAudioError {
    #[error("bad CDR: {0}")]
    Cdr(#[source] mouthpiece_recording::cdr::CdrError),
    #[error("bad JSON: {0}")]
    Json(#[source] serde_json::Error),
    #[error("bad base64 data: {0}")]
    Base64(#[source] base64::DecodeError),
    #[error("message encoding {0:?} is not read here (cdr, json)")]
    Encoding(String),
}

/// Decodes `foxglove.RawAudio` in CDR (`foxglove_msgs/msg/RawAudio`: timestamp, `uint8[]
/// data`, `string format`, `uint32 sample_rate`, `uint32 number_of_channels`) or JSON (`data`
/// in base64).
pub fn decode_raw_audio(encoding: &str, data: &[u8]) -> Result<RawAudio, RawAudioError> {
    match encoding {
        "cdr" => {
            let m =
                mouthpiece_recording::cdr::RawAudio::decode(data).map_err(RawAudioError::Cdr)?;
            Ok(RawAudio {
                data: m.data,
                format: m.format,
                sample_rate: m.sample_rate,
                channels: m.number_of_channels,
            })
        }
        "json" => {
            use base64::Engine as _;
            #[derive(serde::Deserialize)]
            struct Json {
                data: String,
                format: String,
                sample_rate: u32,
                number_of_channels: u32,
            }
            let j: Json = serde_json::from_slice(data).map_err(RawAudioError::Json)?;
            Ok(RawAudio {
                data: base64::engine::general_purpose::STANDARD
                    .decode(j.data.as_bytes())
                    .map_err(RawAudioError::Base64)?,
                format: j.format,
                sample_rate: j.sample_rate,
                channels: j.number_of_channels,
            })
        }
        other => Err(RawAudioError::Encoding(other.chars().take(40).collect())),
    }
}

/// Sound gathered for a chunk: blocks placed at their times, silence between.
struct AudioGather {
    sample_rate: u32,
    channels: u16,
    start_s: f64,
    pcm: Vec<u8>,
}

/// The chunk of the take at `path` from `from_s` for `seconds` (times from its first
/// picture, or its first step when it has no camera), with at most `max_bytes` of images.
pub fn read_chunk(
    path: &Path,
    from_s: f64,
    seconds: f64,
    max_bytes: usize,
) -> Result<TakeChunk, TakeChunkError> {
    let unreadable = |e: &dyn std::fmt::Display| {
        TakeChunkError::Unreadable(format!(
            "{}: {e}",
            path.file_name().unwrap_or_default().to_string_lossy()
        ))
    };
    let mut reader = MessageReader::open(path).map_err(|e| unreadable(&e))?;
    let to_s = from_s + seconds;
    let mut chunk = TakeChunk::default();
    let mut calibration: Option<Intrinsics> = None;
    let mut first_ns: Option<u64> = None;
    let mut last_frame_ns: Option<u64> = None;
    let mut image_bytes = 0usize;
    let mut audio: Option<AudioGather> = None;
    let mut raw_colour_noted = false;
    let mut seen_colour = false;
    let mut no_camera_noted = false;
    let mut ended_early = false;
    // Where the chunk ends (earlier when the images reach their cap), and whether a picture
    // past it was seen (else the take ends in this chunk).
    let mut end_s = to_s;
    let mut past_end = false;
    loop {
        let Some(msg) = reader.next_message().map_err(|e| unreadable(&e))? else {
            chunk.end = !past_end;
            break;
        };
        if calibration.is_none() {
            calibration = calibration_from_metadata(&reader);
        }
        let t = |first: u64| msg.log_time.saturating_sub(first) as f64 / 1e9;
        // Sound is written as it arrives, after the pictures of its time: read on a little.
        if first_ns.is_some_and(|first| t(first) >= end_s + LATE_AUDIO_S) {
            break;
        }
        match &*msg.topic {
            mouthpiece_recording::TOPIC_CALIBRATION if calibration.is_none() => {
                if let Ok(c) = CameraCalibration::decode(&msg.data) {
                    calibration = Some(intrinsics_from(&c));
                }
            }
            mouthpiece_recording::TOPIC_COLOR => {
                seen_colour = true;
                let first = *first_ns.get_or_insert(msg.log_time);
                let t = t(first);
                if t < from_s {
                    continue;
                }
                if t >= end_s {
                    past_end = true;
                    continue;
                }
                if &*msg.schema_name != COMPRESSED_IMAGE_SCHEMA_NAME {
                    if !raw_colour_noted {
                        chunk.notes.push(
                            "this take stores its colour losslessly: the player shows no image"
                                .into(),
                        );
                        raw_colour_noted = true;
                    }
                    last_frame_ns = None;
                    continue;
                }
                let image = CompressedImage::decode(&msg.data).map_err(|e| unreadable(&e))?;
                if image_bytes + image.data.len() > max_bytes && !chunk.frames.is_empty() {
                    chunk.next_s = t;
                    end_s = t;
                    ended_early = true;
                    past_end = true;
                    continue;
                }
                image_bytes += image.data.len();
                chunk.frames.push(ChunkFrame {
                    t,
                    jpeg: image.data,
                    dots: Vec::new(),
                });
                last_frame_ns = Some(msg.log_time);
            }
            // A take from a booth without a camera: no pictures, its steps keep the time.
            topic if topic.starts_with(CHARACTER_PREFIX) && !seen_colour => {
                let first = *first_ns.get_or_insert(msg.log_time);
                if t(first) >= end_s {
                    past_end = true;
                }
                if !no_camera_noted {
                    chunk.notes.push(
                        "this take has no camera: the characters were driven by its sound".into(),
                    );
                    no_camera_noted = true;
                }
            }
            TOPIC_POINTS if last_frame_ns == Some(msg.log_time) => {
                if let (Some(k), Some(frame)) = (&calibration, chunk.frames.last_mut()) {
                    frame.dots = dots_in_image(&msg, k);
                }
            }
            TOPIC_AUDIO => {
                let Some(first) = first_ns else { continue };
                let t = t(first);
                if t < from_s || t >= end_s {
                    continue;
                }
                add_audio(&mut audio, &mut chunk.notes, &msg, t);
            }
            _ => {}
        }
    }
    if let Some(k) = &calibration {
        chunk.width = k.width;
        chunk.height = k.height;
    }
    if !ended_early {
        chunk.next_s = to_s;
    }
    chunk.audio = audio.map(|a| ChunkAudio {
        sample_rate: a.sample_rate,
        channels: a.channels,
        start_s: a.start_s,
        pcm_s16le: a.pcm,
    });
    Ok(chunk)
}

fn add_audio(gather: &mut Option<AudioGather>, notes: &mut Vec<String>, msg: &RawMessage, t: f64) {
    let mut note = |text: String| {
        if !notes.contains(&text) {
            notes.push(text);
        }
    };
    let block = match decode_raw_audio(&msg.message_encoding, &msg.data) {
        Ok(b) => b,
        Err(e) => return note(format!("sound not played: {e}")),
    };
    if block.format != "pcm-s16" {
        return note(format!(
            "sound not played: format {:?} (pcm-s16 is played)",
            block.format.chars().take(40).collect::<String>()
        ));
    }
    if !(8000..=192_000).contains(&block.sample_rate) || !(1..=8).contains(&block.channels) {
        return note(format!(
            "sound not played: {} Hz, {} channels (8–192 kHz, 1–8 channels are played)",
            block.sample_rate, block.channels
        ));
    }
    let a = gather.get_or_insert_with(|| AudioGather {
        sample_rate: block.sample_rate,
        channels: block.channels as u16,
        start_s: t,
        pcm: Vec::new(),
    });
    if a.sample_rate != block.sample_rate || u32::from(a.channels) != block.channels {
        return note("sound not played past a change of format".into());
    }
    let frame_bytes = 2 * usize::from(a.channels);
    // The block's place after the chunk's first sample; a gap is filled with silence.
    let at = ((t - a.start_s) * f64::from(a.sample_rate))
        .round()
        .max(0.0) as usize
        * frame_bytes;
    let whole = block.data.len() / frame_bytes * frame_bytes;
    let end = at.max(a.pcm.len()) + whole;
    if end > MAX_AUDIO_BYTES {
        return note("sound cut: too much in one chunk".into());
    }
    if at > a.pcm.len() {
        a.pcm.resize(at, 0);
    }
    a.pcm.extend_from_slice(&block.data[..whole]);
}

fn calibration_from_metadata(reader: &MessageReader) -> Option<Intrinsics> {
    reader
        .metadata()
        .iter()
        .find(|(name, _)| name == mouthpiece_recording::METADATA_CALIBRATION)
        .and_then(|(_, map)| map.get("calibration"))
        .and_then(|json| serde_json::from_str::<Calibration>(json).ok())
        .map(|c| c.color)
}

fn intrinsics_from(c: &CameraCalibration) -> Intrinsics {
    let mut k = Intrinsics::ideal(c.width, c.height, c.k[0], c.k[4], c.k[2], c.k[5]);
    for (d, s) in k.distortion.iter_mut().zip(&c.d) {
        *d = *s;
    }
    k
}

/// The seen dots of a `/performer/points` message in image pixels.
fn dots_in_image(msg: &RawMessage, k: &Intrinsics) -> Vec<ImageDot> {
    #[derive(serde::Deserialize)]
    struct Points {
        points: serde_json::Map<String, serde_json::Value>,
    }
    let Ok(p) = serde_json::from_slice::<Points>(&msg.data) else {
        return Vec::new();
    };
    p.points
        .iter()
        .filter_map(|(name, v)| {
            let xyz: [f64; 3] = serde_json::from_value(v.clone()).ok()?;
            let [x, y] = k.project(xyz)?;
            Some(ImageDot {
                name: name.clone(),
                x: x as f32,
                y: y as f32,
                state: DotState::Tracked,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests;
