//! mouthpiece sessions as MCAP files.
//!
//! A session is one MCAP file that existing tools open (Foxglove Studio shows the images,
//! Python's `mcap` package reads everything). `docs/recording-format.md` is the reference for
//! every channel, schema, encoding and metadata record; the short version:
//!
//! | topic | schema (encoding) | message encoding |
//! |---|---|---|
//! | `/camera/color` | `foxglove_msgs/msg/CompressedImage` (jpeg) or `foxglove_msgs/msg/RawImage` (bgr8) (`ros2msg`) | `cdr` |
//! | `/camera/depth` | `foxglove_msgs/msg/RawImage` 16UC1, device units (mm) (`ros2msg`) | `cdr` |
//! | `/camera/calibration` | `foxglove_msgs/msg/CameraCalibration` (`ros2msg`) | `cdr` |
//! | `/audio` | `foxglove_msgs/msg/RawAudio` `pcm-s16` (`ros2msg`) | `cdr` |
//! | `/groundtruth/points` | `mouthpiece.GroundTruth` (`jsonschema`) | `json` |
//! | anything else | whatever [`SessionWriter::write_json`] is given | `json` |
//!
//! Metadata records `mouthpiece.session` and `mouthpiece.calibration` (the full
//! [`Calibration`](mouthpiece_frame::Calibration): depth intrinsics, depth→colour extrinsics,
//! depth scale) come before the first frame.
//!
//! Layout: [`SessionWriter`] writes, [`SessionReader`] yields [`Frame`](mouthpiece_frame::Frame)s
//! (with their ground truth when present) and [`MessageReader`] yields every message; both
//! readers tolerate a file cut at any byte (a killed writer): they replay up to the last
//! complete chunk and log a warning.
//!
//! Durability: the writer closes a chunk at least every [`WriterOptions::flush_interval`] of
//! capture time (1 s by default) and flushes it to the OS, so a writer killed with SIGKILL
//! leaves a file readable up to its last second.

mod audio_track;
pub mod cdr;
mod ground_truth;
mod reader;
mod writer;

pub use audio_track::{wall_ns, AudioSink, AudioTrack};
pub use ground_truth::{GroundTruth, HeadPose, MouthTruth};
pub use reader::{
    AudioMessage, AudioReader, MessageReader, RawMessage, SessionFrame, SessionReader,
    MAX_AUDIO_CHANNELS, MAX_AUDIO_RATE,
};
pub use writer::{ColorEncoding, SessionSummary, SessionWriter, WriterOptions};

/// Colour images.
pub const TOPIC_COLOR: &str = "/camera/color";
/// Depth images.
pub const TOPIC_DEPTH: &str = "/camera/depth";
/// Colour camera calibration (Foxglove `CameraCalibration`).
pub const TOPIC_CALIBRATION: &str = "/camera/calibration";
/// Sound (Foxglove `RawAudio`, `pcm-s16`).
pub const TOPIC_AUDIO: &str = "/audio";
/// Where a take's sound started, stopped and why (JSON).
pub const TOPIC_AUDIO_EVENTS: &str = "/audio/events";
/// Ground truth of synthetic sessions.
pub const TOPIC_GROUND_TRUTH: &str = "/groundtruth/points";
/// Metadata record with format version and the meaning of `log_time`.
pub const METADATA_SESSION: &str = "mouthpiece.session";
/// Metadata record with the full calibration (JSON in key `calibration`).
pub const METADATA_CALIBRATION: &str = "mouthpiece.calibration";
/// This writer's format version (in `mouthpiece.session`).
pub const FORMAT_VERSION: &str = "1";
/// `frame_id` of the colour camera in image and calibration messages.
pub const FRAME_ID_COLOR: &str = "color";
/// `frame_id` of the depth camera in depth messages.
pub const FRAME_ID_DEPTH: &str = "depth";

/// Everything that can go wrong reading or writing a session.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    #[error("cannot open {path}")]
    Open {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot create {path}")]
    Create {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("I/O error on {path}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    /// Bytes that are not MCAP (a wrong file, a corrupted chunk, a file cut before its
    /// header). `offset`: how far the file had been read, bytes (the damage lies before it,
    /// within the last chunk read).
    #[error("{path}: not readable as an MCAP session (read {offset} bytes)")]
    Mcap {
        path: String,
        offset: u64,
        #[source]
        source: mcap::McapError,
    },
    #[error("{path}: message on {topic} at log time {log_time} ns cannot be decoded: {what}")]
    Decode {
        path: String,
        topic: String,
        log_time: u64,
        what: String,
        #[source]
        source: Option<Box<dyn std::error::Error + Send + Sync>>,
    },
    #[error("{path}: metadata record {name} is invalid")]
    Metadata {
        path: String,
        name: String,
        #[source]
        source: serde_json::Error,
    },
    #[error("frame {seq}: {what}")]
    BadFrame { seq: u64, what: String },
    #[error("cannot encode a message for {topic}")]
    Encode {
        topic: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("writing {path}")]
    Write {
        path: String,
        #[source]
        source: mcap::McapError,
    },
}

/// `s` quoted for an error, cut to 80 characters.
pub(crate) fn excerpt(s: &str) -> String {
    if s.chars().count() <= 80 {
        format!("{s:?}")
    } else {
        format!(
            "{:?}… ({} bytes)",
            s.chars().take(80).collect::<String>(),
            s.len()
        )
    }
}

impl RecordingError {
    /// The file's content is wrong (not MCAP, a corrupted chunk, a message that does not
    /// decode), as opposed to the system failing to read or write it: the caller's bad input.
    pub fn is_bad_input(&self) -> bool {
        matches!(
            self,
            Self::Mcap { .. } | Self::Decode { .. } | Self::Metadata { .. } | Self::BadFrame { .. }
        )
    }
}
