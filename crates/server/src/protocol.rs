//! The wire protocol `mouthpiece.v1`: message types (serde) and the binary `frame` layout.
//!
//! Every text message is a JSON object with a `type` field. `docs/protocol.md` is the
//! human-readable description and `docs/schemas/*.json` the JSON Schemas; the tests check
//! real server output against those schemas, so this module and the docs cannot drift apart.

use serde::{Deserialize, Serialize};

use crate::hub::{HeadPose, PublishedFrame, StreamInfo};
use crate::timecode::Timecode;

/// The subprotocol name negotiated in `Sec-WebSocket-Protocol`.
pub const SUBPROTOCOL: &str = "mouthpiece.v1";
/// The Foxglove WebSocket subprotocol the server also speaks.
pub const FOXGLOVE_SUBPROTOCOL: &str = "foxglove.websocket.v1";
/// Prefix of the `Sec-WebSocket-Protocol` entry that carries an access token.
pub const TOKEN_PROTOCOL_PREFIX: &str = "mouthpiece.token.";
/// Magic bytes at the start of a binary `frame`.
pub const BINARY_MAGIC: &[u8; 4] = b"MPF1";
/// Version of the binary `frame` layout: 2 added each character's head block and, on
/// request, its rig block.
pub const BINARY_VERSION: u16 = 2;
/// Size of the fixed binary header, before the character blocks.
pub const BINARY_HEADER_LEN: usize = 76;

/// A request id chosen by the client: echoed in the `result` or `error` that answers it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum RequestId {
    /// A numeric id.
    Number(i64),
    /// A string id.
    Text(String),
}

/// Messages a client sends.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ClientMessage {
    /// Start (or change) the stream of frames this client receives.
    Subscribe(Subscribe),
    /// Ask the daemon to take a new neutral calibration.
    Calibrate {
        /// Echoed in the answer.
        #[serde(default)]
        id: Option<RequestId>,
        /// How long to average the neutral pose, seconds (the daemon's default when absent).
        #[serde(default)]
        duration_s: Option<f64>,
    },
    /// Start or stop recording a take.
    Record {
        /// Echoed in the answer.
        #[serde(default)]
        id: Option<RequestId>,
        /// `start` or `stop`.
        action: RecordAction,
        /// Slate name (scene), start only.
        #[serde(default)]
        slate: Option<String>,
        /// Take number, start only (the daemon picks the next one when absent).
        #[serde(default)]
        take: Option<u32>,
    },
    /// Liveness check; answered with `pong`.
    Ping {
        /// Echoed in the `pong`.
        #[serde(default)]
        id: Option<RequestId>,
    },
    /// Start, change or stop the camera preview (binary `MPP1` messages).
    Preview(PreviewSubscribe),
    /// Turn a character's head to a viewpoint, or back to following the performer.
    LookAt {
        /// Echoed in the answer.
        #[serde(default)]
        id: Option<RequestId>,
        /// The character's name, as in `hello`.
        character: String,
        /// `[x, y, z]` in the character's model frame, or `null` (or absent) to follow the
        /// performer again.
        #[serde(default)]
        point: Option<[f64; 3]>,
    },
    /// Check the paint: propose colour ranges from the live frames and count what the ranges
    /// in use and the proposed ones find (`run`), or write the last offered proposal into the
    /// configuration file and reload it (`apply`).
    TuneColours {
        /// Echoed in the answer.
        #[serde(default)]
        id: Option<RequestId>,
        /// `run` or `apply`.
        action: TuneAction,
        /// Seconds of frames to sample (`run`; default 2, at most 10).
        #[serde(default)]
        seconds: Option<f64>,
    },
}

/// `tune_colours` actions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TuneAction {
    /// Sample, propose and check.
    Run,
    /// Write the last offered proposal and reload.
    Apply,
}

/// The `preview` request.
#[derive(Debug, Clone, PartialEq, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PreviewSubscribe {
    /// Echoed in the `result`.
    #[serde(default)]
    pub id: Option<RequestId>,
    /// `false` stops the preview (default `true`).
    #[serde(default)]
    pub enable: Option<bool>,
    /// Images per second, at most 15 (default 10).
    #[serde(default)]
    pub max_rate: Option<f64>,
    /// Widest image, pixels, 64–1280 (default 480); never wider than the camera's.
    #[serde(default)]
    pub max_width: Option<u32>,
}

/// `record` actions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RecordAction {
    /// Start a take.
    Start,
    /// Stop the current take.
    Stop,
}

/// Optional parts of a frame, sent only when subscribed to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum OptionalField {
    /// The smoothed closed curve through each character's points.
    Curve,
    /// The performer's lip dots (head motion removed, performer mouth frame).
    Performer,
    /// Each character's `rig`: jaw, lip motions, ARKit-named curves.
    Rig,
    /// Not part of `frame`: a `health` message about once a second.
    Health,
}

/// Frame encoding of a subscription.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FrameFormat {
    /// JSON text messages (the default).
    #[default]
    Json,
    /// The little-endian binary layout (see `docs/protocol.md`).
    Binary,
}

/// The `subscribe` request.
#[derive(Debug, Clone, PartialEq, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Subscribe {
    /// Echoed in the `result`.
    #[serde(default)]
    pub id: Option<RequestId>,
    /// Characters to receive, by name; absent or empty means all.
    #[serde(default)]
    pub characters: Option<Vec<String>>,
    /// Optional fields to include.
    #[serde(default)]
    pub fields: Vec<OptionalField>,
    /// Maximum frames per second; the server skips frames to stay at or under it.
    #[serde(default)]
    pub max_rate: Option<f64>,
    /// `json` (default) or `binary`.
    #[serde(default)]
    pub format: FrameFormat,
}

/// Error codes of the `error` message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorCode {
    /// The text was not valid JSON.
    BadJson,
    /// The message's `type` is missing or not one the server knows.
    UnknownType,
    /// A known message with missing or wrongly typed fields, or values out of range.
    BadRequest,
    /// Binary messages from clients are not part of the protocol.
    UnsupportedBinary,
    /// The connection's token does not allow this action.
    Forbidden,
    /// Too many messages per second: this one was ignored.
    RateLimited,
    /// The daemon's control queue is full; try again.
    Busy,
    /// The daemon did not answer the control request in time.
    Timeout,
    /// No daemon is listening for control requests.
    Unavailable,
    /// The daemon refused or failed the control request (message says why).
    ControlFailed,
}

/// The `error` message.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ErrorMessage {
    /// Machine-readable code.
    pub code: ErrorCode,
    /// What went wrong, for people.
    pub message: String,
    /// The id of the request this answers, when it had one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<RequestId>,
}

/// Server-to-client messages other than `frame` (which is serialized from a [`FrameView`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ServerMessage<'a> {
    /// First message on every connection, and again when the stream's description changes.
    Hello(HelloMessage<'a>),
    /// Source and session state, or how many frames this client lost.
    Status(StatusMessage<'a>),
    /// A request could not be served.
    Error(ErrorMessage),
    /// A request succeeded.
    Result(ResultMessage),
    /// Answer to `ping`.
    Pong {
        /// The ping's id.
        #[serde(skip_serializing_if = "Option::is_none")]
        id: Option<RequestId>,
        /// Server wall-clock time, Unix microseconds.
        server_wall_us: i64,
    },
}

/// The `hello` message.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HelloMessage<'a> {
    /// Always `mouthpiece.v1`.
    pub protocol: &'static str,
    /// Server name and version.
    pub server: ServerIdentity,
    /// Stream description from the daemon.
    #[serde(flatten)]
    pub info: &'a StreamInfo,
    /// SMPTE timecode rate of the `timecode` field.
    pub timecode_rate: &'a str,
    /// How the time fields of `frame` are defined.
    pub clock: ClockDescription,
    /// What this connection may do: `read` or `control`.
    pub access: &'static str,
    /// The rig's curve names, in the order of `rig.curves` and of the binary rig block.
    pub rig_curves: &'static [&'static str],
    /// The rig's VRM viseme names, in the order of `rig.visemes` and of the binary rig block.
    pub rig_visemes: &'static [&'static str],
}

/// Server name and version in `hello`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ServerIdentity {
    /// Program name.
    pub name: String,
    /// Program version.
    pub version: &'static str,
}

/// Description of the time fields, in `hello`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ClockDescription {
    /// Meaning of `t`.
    pub t: &'static str,
    /// Meaning of `capture_us`.
    pub capture_us: &'static str,
    /// Meaning of `wall_us`.
    pub wall_us: &'static str,
    /// Meaning of `timecode`.
    pub timecode: &'static str,
}

impl Default for ClockDescription {
    fn default() -> Self {
        Self {
            t: "seconds since the start of the stream (float)",
            capture_us: "capture clock of the source, microseconds (device timestamp)",
            wall_us: "host wall-clock time when the frame was captured, Unix microseconds (live sources only)",
            timecode: "SMPTE timecode of wall_us at timecode_rate: the studio's LTC when [timecode] source is ltc (status.timecode says locked, free_running or lost), else time of day (UTC); of t when there is no wall_us",
        }
    }
}

/// The `status` message.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StatusMessage<'a> {
    /// `up` or `down`.
    pub source: &'a str,
    /// Whether a neutral calibration is running.
    pub calibrating: bool,
    /// The take being recorded, if any.
    pub recording: Option<&'a crate::hub::Recording>,
    /// Free text from the daemon (why the source is down, disk full, ...).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub message: Option<&'a str>,
    /// Frames this client lost since the previous `lagged` notice (only on lag notices).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lagged: Option<u64>,
    /// The last neutral calibration.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calibration: Option<&'a crate::console::CalibrationReport>,
    /// Takes recorded in this run of the daemon.
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    pub takes: &'a [crate::console::TakeSummary],
    /// The microphone (state, format, level meter).
    pub audio: &'a crate::audio::AudioStatus,
    /// Why the configured microphone is not live.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub audio_message: Option<&'a str>,
    /// The last paint check.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tune: Option<&'a crate::console::TuneReport>,
    /// The timecode's source and state.
    pub timecode: &'a crate::timecode_clock::TimecodeStatus,
}

impl<'a> StatusMessage<'a> {
    /// The `status` message for `status`, with `lagged` on lag notices.
    pub fn from_status(status: &'a crate::hub::Status, lagged: Option<u64>) -> Self {
        Self {
            source: status.source.as_str(),
            calibrating: status.calibrating,
            recording: status.recording.as_ref(),
            message: status.message.as_deref(),
            lagged,
            calibration: status.calibration.as_ref(),
            takes: &status.takes,
            audio: &status.audio,
            audio_message: status.audio_message.as_deref(),
            tune: status.tune.as_ref(),
            timecode: &status.timecode,
        }
    }
}

/// The `result` message: a request succeeded.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ResultMessage {
    /// The request's id.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<RequestId>,
    /// `subscribe`, `calibrate`, `record`.
    pub request: &'static str,
    /// Details from whoever served it (the daemon for control actions).
    pub detail: serde_json::Value,
}

/// What one subscription selects from each frame.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FrameSelection {
    /// Character indices into the frame's `characters` in the order of `StreamInfo`;
    /// `None` means all.
    pub characters: Option<Vec<String>>,
    /// Include each character's `curve`.
    pub curve: bool,
    /// Include `performer`.
    pub performer: bool,
    /// Include each character's `rig`.
    pub rig: bool,
}

impl FrameSelection {
    /// Builds the selection from a `subscribe` request.
    pub fn from_subscribe(sub: &Subscribe) -> Self {
        Self {
            characters: sub.characters.clone().filter(|c| !c.is_empty()),
            curve: sub.fields.contains(&OptionalField::Curve),
            performer: sub.fields.contains(&OptionalField::Performer),
            rig: sub.fields.contains(&OptionalField::Rig),
        }
    }

    fn wants(&self, name: &str) -> bool {
        self.characters
            .as_ref()
            .is_none_or(|names| names.iter().any(|n| n == name))
    }
}

/// A borrowed view of one published frame as one client sees it; serializes to `frame`.
#[derive(Debug, Serialize)]
pub struct FrameView<'a> {
    #[serde(rename = "type")]
    kind: &'static str,
    seq: u64,
    t: f64,
    capture_us: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    wall_us: Option<i64>,
    timecode: &'a Timecode,
    head: &'a HeadPose,
    characters: Vec<CharacterView<'a>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    performer: Option<&'a crate::hub::PerformerFrame>,
}

#[derive(Debug, Serialize)]
struct CharacterView<'a> {
    name: &'a str,
    points: &'a [[f32; 3]],
    confidence: &'a [f32],
    #[serde(skip_serializing_if = "Option::is_none")]
    curve: Option<&'a [[f32; 3]]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    rig: Option<&'a mouthpiece_output::RigState>,
    head: Option<&'a mouthpiece_output::CharacterHead>,
    source: mouthpiece_output::MouthSource,
}

impl<'a> FrameView<'a> {
    /// The view of `frame` that `selection` asks for.
    pub fn new(frame: &'a PublishedFrame, selection: &FrameSelection) -> Self {
        let f = &frame.frame;
        Self {
            kind: "frame",
            seq: frame.seq,
            t: f.t,
            capture_us: f.capture_us,
            wall_us: f.wall_us,
            timecode: &frame.timecode,
            head: &f.head,
            characters: f
                .characters
                .iter()
                .filter(|c| selection.wants(&c.name))
                .map(|c| CharacterView {
                    name: &c.name,
                    points: &c.points,
                    confidence: &c.confidence,
                    curve: if selection.curve {
                        c.curve.as_deref()
                    } else {
                        None
                    },
                    rig: if selection.rig { c.rig.as_ref() } else { None },
                    head: c.head.as_ref(),
                    source: c.source,
                })
                .collect(),
            performer: if selection.performer {
                f.performer.as_ref()
            } else {
                None
            },
        }
    }

    /// JSON text of the `frame` message.
    pub fn to_json(&self) -> String {
        // Serializing plain numbers and strings cannot fail; NaN becomes null.
        serde_json::to_string(self).unwrap_or_default()
    }
}

mod binary;
pub use binary::{binary_rig_len, encode_binary_frame, BINARY_HEAD_LEN};

/// Serializes a server message; these contain only strings and numbers, so it cannot fail.
pub fn to_json(message: &ServerMessage<'_>) -> String {
    serde_json::to_string(message).unwrap_or_default()
}

/// Why a client's text could not be understood, mapped onto an `error`.
#[derive(Debug, Clone, PartialEq)]
pub struct ParseFailure {
    /// The error code.
    pub code: ErrorCode,
    /// Human-readable reason (serde's message, with line and column).
    pub message: String,
    /// The request id, when the text was JSON with an `id`.
    pub id: Option<RequestId>,
}

/// Parses one client text message, telling bad JSON, unknown types and bad fields apart.
pub fn parse_client_message(text: &str) -> Result<ClientMessage, ParseFailure> {
    let value: serde_json::Value = serde_json::from_str(text).map_err(|e| ParseFailure {
        code: ErrorCode::BadJson,
        message: format!("invalid JSON: {e}"),
        id: None,
    })?;
    let id = value
        .get("id")
        .and_then(|v| serde_json::from_value::<RequestId>(v.clone()).ok());
    let Some(kind) = value.get("type") else {
        return Err(ParseFailure {
            code: ErrorCode::UnknownType,
            message: "message has no \"type\" field".into(),
            id,
        });
    };
    let known = [
        "subscribe",
        "calibrate",
        "record",
        "ping",
        "preview",
        "look_at",
        "tune_colours",
    ];
    let kind_name = kind.as_str().unwrap_or_default().to_owned();
    match kind.as_str() {
        Some(k) if known.contains(&k) => {}
        Some(k) => {
            return Err(ParseFailure {
                code: ErrorCode::UnknownType,
                message: format!(
                    "unknown message type {k:?} (expected one of {})",
                    known.join(", ")
                ),
                id,
            })
        }
        None => {
            return Err(ParseFailure {
                code: ErrorCode::UnknownType,
                message: format!("\"type\" must be a string, got {kind}"),
                id,
            })
        }
    }
    let message: ClientMessage = serde_json::from_value(value).map_err(|e| ParseFailure {
        code: ErrorCode::BadRequest,
        message: format!("bad {kind_name} message: {e}"),
        id: id.clone(),
    })?;
    validate(&message).map_err(|message| ParseFailure {
        code: ErrorCode::BadRequest,
        message,
        id,
    })?;
    Ok(message)
}

fn validate(message: &ClientMessage) -> Result<(), String> {
    match message {
        ClientMessage::Subscribe(sub) => match sub.max_rate {
            Some(r) if !(r.is_finite() && r > 0.0) => Err(format!(
                "subscribe: max_rate must be a positive number, got {r}"
            )),
            _ => Ok(()),
        },
        ClientMessage::Calibrate {
            duration_s: Some(d),
            ..
        } if !(d.is_finite() && *d > 0.0 && *d <= 60.0) => Err(format!(
            "calibrate: duration_s must be in (0, 60] seconds, got {d}"
        )),
        ClientMessage::Preview(p) if p.enable != Some(false) => {
            crate::preview::PreviewRequest::new(p.max_rate, p.max_width).map(|_| ())
        }
        ClientMessage::Record {
            action: RecordAction::Start,
            slate: Some(slate),
            ..
        } if !valid_slate(slate) => {
            Err(format!("record: slate must be {SLATE_RULE}, got {slate:?}"))
        }
        ClientMessage::LookAt { point: Some(p), .. } => crate::head::check_point(p),
        ClientMessage::TuneColours {
            seconds: Some(s), ..
        } if !(s.is_finite() && *s > 0.0 && *s <= 10.0) => {
            Err(format!("tune_colours: seconds must be in (0, 10], got {s}"))
        }
        _ => Ok(()),
    }
}

pub use mouthpiece_output::{valid_slate, SLATE_RULE};

impl crate::hub::Hub {
    /// The `hello` message for `info` (what a client gets first), as `server_name` with
    /// `access` (`read` or `control`).
    pub fn hello_json(&self, info: &StreamInfo, server_name: &str, access: &'static str) -> String {
        use crate::protocol::{ClockDescription, HelloMessage, ServerIdentity, ServerMessage};
        crate::protocol::to_json(&ServerMessage::Hello(HelloMessage {
            protocol: crate::protocol::SUBPROTOCOL,
            server: ServerIdentity {
                name: server_name.to_owned(),
                version: env!("CARGO_PKG_VERSION"),
            },
            info,
            timecode_rate: self.inner.timecode_rate.name(),
            clock: ClockDescription::default(),
            access,
            rig_curves: &mouthpiece_output::CURVE_NAMES,
            rig_visemes: &mouthpiece_output::VISEME_NAMES,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tells_bad_json_unknown_type_and_bad_fields_apart() {
        assert_eq!(
            parse_client_message("{nope").unwrap_err().code,
            ErrorCode::BadJson
        );
        let e = parse_client_message(r#"{"type":"dance","id":7}"#).unwrap_err();
        assert_eq!(e.code, ErrorCode::UnknownType);
        assert_eq!(e.id, Some(RequestId::Number(7)));
        assert_eq!(
            parse_client_message(r#"{"id":1}"#).unwrap_err().code,
            ErrorCode::UnknownType
        );
        let e = parse_client_message(r#"{"type":"record","id":"a","action":"pause"}"#).unwrap_err();
        assert_eq!(e.code, ErrorCode::BadRequest);
        assert_eq!(e.id, Some(RequestId::Text("a".into())));
        assert_eq!(
            parse_client_message(r#"{"type":"subscribe","max_rate":-1}"#)
                .unwrap_err()
                .code,
            ErrorCode::BadRequest
        );
        assert_eq!(
            parse_client_message(r#"{"type":"record","action":"start","slate":"../etc"}"#)
                .unwrap_err()
                .code,
            ErrorCode::BadRequest
        );
    }

    #[test]
    fn parses_every_client_message() {
        let m = parse_client_message(
            r#"{"type":"subscribe","characters":["wolf"],"fields":["curve"],"max_rate":30,"format":"binary"}"#,
        )
        .unwrap();
        let ClientMessage::Subscribe(sub) = m else {
            panic!("not a subscribe")
        };
        assert_eq!(sub.format, FrameFormat::Binary);
        assert_eq!(sub.max_rate, Some(30.0));
        assert!(matches!(
            parse_client_message(
                r#"{"type":"record","action":"start","slate":"scene-4","take":2}"#
            )
            .unwrap(),
            ClientMessage::Record {
                action: RecordAction::Start,
                take: Some(2),
                ..
            }
        ));
        assert!(matches!(
            parse_client_message(r#"{"type":"calibrate","duration_s":1.5}"#).unwrap(),
            ClientMessage::Calibrate { .. }
        ));
        assert!(matches!(
            parse_client_message(r#"{"type":"ping","id":"x"}"#).unwrap(),
            ClientMessage::Ping { .. }
        ));
    }
}
