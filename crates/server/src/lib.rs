//! mouthpiece's streaming server: WebSocket protocol `mouthpiece.v1`, a Foxglove bridge
//! (`foxglove.websocket.v1`), the live viewer page, `/healthz` and `/metrics`, all on one
//! port.
//!
//! # Using it from the daemon
//!
//! ```no_run
//! use mouthpiece_server::{run, Hub, HubConfig, ServerConfig, StreamFrame, StreamInfo, Status};
//!
//! # async fn demo() -> Result<(), mouthpiece_server::ServerError> {
//! let (hub, mut control) = Hub::new(&HubConfig::default());
//! hub.set_info(StreamInfo { frame_rate: 30.0, ..StreamInfo::default() });
//! let listener = tokio::net::TcpListener::bind("127.0.0.1:9870").await.map_err(|source| {
//!     mouthpiece_server::ServerError::Io { context: "binding 127.0.0.1:9870".into(), source }
//! })?;
//! let server = tokio::spawn(run(listener, ServerConfig::default(), hub.clone(), async {
//!     let _ = tokio::signal::ctrl_c().await;
//! }));
//!
//! // On the processing thread (never blocks, never waits for a client):
//! let mut frame = StreamFrame::default();
//! frame.t = 0.033;
//! hub.publish(&frame);
//! hub.update_status(|s| s.calibrating = true);
//!
//! // Control requests from clients, answered from the processing thread:
//! while let Some(request) = control.try_recv() {
//!     // match request.command { ... }
//!     request.reply(Ok(serde_json::json!({"ok": true})));
//! }
//! # server.await.ok(); Ok(()) }
//! ```
//!
//! - [`Hub::publish`] stamps `seq` (every published frame counts) and the SMPTE timecode,
//!   and puts the frame into a ring every client reads at its own pace. Publishing never
//!   blocks; a client that falls [`HubConfig::client_queue_frames`] behind loses the oldest
//!   frames and is told (`status` with `lagged`); one that loses more than
//!   [`Limits::max_dropped_frames`] within [`Limits::lag_window`], or whose socket stays
//!   blocked for [`Limits::write_timeout`], is closed with a reason.
//! - [`Hub::set_status`] / [`Hub::update_status`]: source up/down, calibrating, recording;
//!   sent to every client on change.
//! - [`Hub::set_info`]: characters (point names, neutral points, `M`), performer point
//!   names, frame rate; sent as `hello` (again on change, e.g. after a config reload).
//! - [`ControlReceiver`]: `calibrate` and `record` requests from clients holding the control
//!   token, in a bounded queue ([`HubConfig::control_queue`]; when full, clients get
//!   `busy`). Answer each with [`ControlRequest::reply`]: `Ok(detail)` reaches the client as
//!   `result`, `Err(ControlFailure)` as `error` (`control_failed`). Unanswered requests
//!   time out after [`Limits::control_timeout`].
//! - [`run`] serves until its `shutdown` future completes, then closes clients with 1001.
//!
//! The wire protocol is in `docs/protocol.md` with JSON Schemas in `docs/schemas/`.
//!
//! # Layout
//!
//! - [`protocol`]: message types, parsing of client messages, the binary frame encoder.
//! - [`hub`]: [`Hub`], frames, status, stream info, the control queue.
//! - `server`: accept loop, TLS, the first HTTP request (page, health, metrics, upgrade,
//!   tokens, origin).
//! - `session`: one `mouthpiece.v1` client (reader task + writer loop).
//! - `foxglove`: one `foxglove.websocket.v1` client.
//! - [`control`]: control requests from any transport (WebSocket, NATS) to the daemon.
//! - [`metrics`]: counters and histograms for `/metrics`.
//! - [`nats`]: the NATS link's counters for `/metrics` and `/healthz`.
//! - [`preview`]: the opt-in camera preview (downscaled JPEG with the dots, latest only).
//! - [`console`]: health figures, the last calibration and the session's takes.
//! - [`takes_http`]: `/take`, chunks of a take for the console's player.
//! - [`timecode`]: SMPTE time-of-day timecode.
//! - [`timecode_clock`]: the clock frames are stamped from: time of day or the studio's LTC
//!   (locked, free-running, lost).
//! - [`loadgen`]: the load tool behind `mouthpiece-loadgen` and the load tests.

pub mod audio;
pub mod config;
mod connection;
pub mod console;
pub mod control;
mod error;
mod foxglove;
pub mod foxglove_scene;
pub mod head;
pub mod host;
pub mod http;
pub mod hub;
pub mod loadgen;
pub mod metrics;
pub mod nats;
pub mod osc;
pub mod preview;
pub mod protocol;
pub mod rig;
mod server;
mod session;
pub mod takes_http;
pub mod timecode;
pub mod timecode_clock;
mod tls;

pub use audio::{AudioCounters, AudioState, AudioStatus, SILENCE_DBFS};
pub use config::{Access, Limits, ServerConfig, TlsFiles, Token};
pub use console::{CalibrationReport, Health, TakeSummary, TuneClass, TuneFound, TuneReport};
pub use error::ServerError;
pub use foxglove::{
    check_client_message as check_foxglove_client_message, FIRST_CHARACTER_CHANNEL, HEAD_CHANNEL,
    MAX_SUBSCRIPTIONS_PER_CLIENT, PERFORMER_CHANNEL,
};
pub use hub::{
    CharacterInfo, ControlCommand, ControlFailure, ControlOutcome, ControlReceiver, ControlRequest,
    Hub, HubConfig, Recording, SourceState, Status, StreamInfo,
};
pub use metrics::MetricsSource;
/// The output vocabulary the hub publishes, defined once in `mouthpiece-output`.
pub use mouthpiece_output::{
    CharacterFrame, CharacterHead, HeadPose, LookMode, PerformerFrame, RigCurves, RigJaw, RigLip,
    RigLips, RigState, RigVisemes, RigidPose, StreamFrame, CURVE_NAMES,
};
pub use nats::NatsCounters;
pub use osc::{OscCounters, OscTargetCounters, OscTargetFigures};
pub use preview::{BgrImage, DotState, ImageDot, Overlay, PixelBox, PreviewInput};
pub use server::run;
pub use takes_http::{ChunkAudio, ChunkFrame, TakeArchive, TakeChunk, TakeChunkError};

/// Loads the certificate and key as [`run`] will, so that a configuration check refuses
/// what serving would refuse.
pub fn check_tls(files: &TlsFiles) -> Result<(), ServerError> {
    tls::acceptor(files).map(|_| ())
}
pub use timecode::{FrameTime, Timecode, TimecodeRate};
