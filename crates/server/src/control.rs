//! Control requests from any transport: the WebSocket session's reader and the NATS
//! request/reply responder both queue a [`ControlCommand`] for the daemon here and turn its
//! answer into the same `result` or `error` message.

use std::time::Duration;

use tokio::sync::oneshot;

use crate::hub::{ControlCommand, ControlOutcome, ControlQueueError, Hub};
use crate::protocol::{
    self, ClientMessage, ErrorCode, ErrorMessage, RecordAction, RequestId, ResultMessage,
    ServerMessage,
};

/// A control request as parsed from a client's message.
#[derive(Debug, Clone, PartialEq)]
pub struct ControlCall {
    /// The request's `id`, echoed in the answer.
    pub id: Option<RequestId>,
    /// `calibrate`, `record` or `look_at`.
    pub request: &'static str,
    /// What the daemon is asked to do.
    pub command: ControlCommand,
}

/// The control request in `message`, or `None` when it is not one (subscribe, ping, ...).
pub fn control_call(message: ClientMessage) -> Option<ControlCall> {
    let (id, request, command) = match message {
        ClientMessage::Calibrate { id, duration_s } => (
            id,
            "calibrate",
            ControlCommand::Calibrate {
                duration: duration_s.map(Duration::from_secs_f64),
            },
        ),
        ClientMessage::LookAt {
            id,
            character,
            point,
        } => (id, "look_at", ControlCommand::LookAt { character, point }),
        ClientMessage::Record {
            id,
            action,
            slate,
            take,
        } => (
            id,
            "record",
            match action {
                RecordAction::Start => ControlCommand::RecordStart { slate, take },
                RecordAction::Stop => ControlCommand::RecordStop,
            },
        ),
        ClientMessage::TuneColours {
            id,
            action,
            seconds,
        } => (
            id,
            "tune_colours",
            ControlCommand::TuneColours {
                apply: action == protocol::TuneAction::Apply,
                seconds: seconds.map(Duration::from_secs_f64),
            },
        ),
        _ => return None,
    };
    Some(ControlCall {
        id,
        request,
        command,
    })
}

/// A request refused before it reached the daemon: `bad_request` for a `look_at` at a
/// character the stream does not have.
pub fn refuse_early(hub: &Hub, call: &ControlCall) -> Option<String> {
    match &call.command {
        ControlCommand::LookAt { character, .. } => {
            crate::head::unknown_character(&hub.info(), character)
                .map(|message| error_json(ErrorCode::BadRequest, message, call.id.clone()))
        }
        _ => None,
    }
}

/// A request queued for the daemon; [`Pending::answer`] waits for its reply.
#[derive(Debug)]
pub struct Pending {
    rx: oneshot::Receiver<ControlOutcome>,
    id: Option<RequestId>,
    request: &'static str,
    wait: Duration,
}

/// Queues `call` for the daemon without waiting. `Err` is the `error` message to send at
/// once (`busy`: the queue is full; `unavailable`: no daemon). `timeout` is how long the
/// answer may take (a calibration gets its averaging time on top).
pub fn queue(
    hub: &Hub,
    call: ControlCall,
    client: String,
    timeout: Duration,
) -> Result<Pending, String> {
    tracing::info!(command = ?call.command, %client, "control request");
    // A calibration is answered once the neutral pose is taken: wait its duration longer.
    let longer = match &call.command {
        ControlCommand::Calibrate {
            duration: Some(duration),
        } => *duration,
        // The paint check samples live frames for its duration before it answers.
        ControlCommand::TuneColours {
            seconds: Some(seconds),
            ..
        } => *seconds,
        _ => Duration::ZERO,
    };
    match hub.request_control(call.command, client) {
        Ok(rx) => Ok(Pending {
            rx,
            id: call.id,
            request: call.request,
            wait: timeout + longer,
        }),
        Err(ControlQueueError::Full) => Err(error_json(
            ErrorCode::Busy,
            "the daemon has too many control requests waiting; try again".into(),
            call.id,
        )),
        Err(ControlQueueError::NoDaemon) => Err(error_json(
            ErrorCode::Unavailable,
            "no daemon is taking control requests".into(),
            call.id,
        )),
    }
}

impl Pending {
    /// The daemon's answer as a `result` or `error` message (`timeout` when it took too long).
    pub async fn answer(self) -> String {
        let Pending {
            rx,
            id,
            request,
            wait,
        } = self;
        match tokio::time::timeout(wait, rx).await {
            Ok(Ok(Ok(detail))) => protocol::to_json(&ServerMessage::Result(ResultMessage {
                id,
                request,
                detail,
            })),
            Ok(Ok(Err(failure))) => error_json(ErrorCode::ControlFailed, failure.message, id),
            Ok(Err(_)) => error_json(
                ErrorCode::Unavailable,
                format!("the daemon dropped the {request} request"),
                id,
            ),
            Err(_) => error_json(
                ErrorCode::Timeout,
                format!(
                    "the daemon did not answer {request} within {} s",
                    wait.as_secs()
                ),
                id,
            ),
        }
    }
}

/// Answers one control message given as text (a NATS request's payload): parses it, refuses
/// what is not a control request, queues it and waits for the daemon. The caller has
/// already decided the sender may control.
pub async fn answer_text(hub: &Hub, text: &str, client: String, timeout: Duration) -> String {
    let message = match protocol::parse_client_message(text) {
        Ok(message) => message,
        Err(failure) => return error_json(failure.code, failure.message, failure.id),
    };
    // A ping is answered here as on the WebSocket: `pong` with the request's id.
    if let ClientMessage::Ping { id } = message {
        return protocol::to_json(&ServerMessage::Pong {
            id,
            server_wall_us: unix_micros_now(),
        });
    }
    let Some(call) = control_call(message) else {
        return error_json(
            ErrorCode::BadRequest,
            "expected a control request: calibrate, record, look_at or tune_colours (or ping)"
                .into(),
            None,
        );
    };
    if let Some(refused) = refuse_early(hub, &call) {
        return refused;
    }
    match queue(hub, call, client, timeout) {
        Ok(pending) => pending.answer().await,
        Err(refused) => refused,
    }
}

/// The host clock, Unix microseconds (a `pong`'s `server_wall_us`).
pub(crate) fn unix_micros_now() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as i64)
}

/// An `error` message.
pub fn error_json(code: ErrorCode, message: String, id: Option<RequestId>) -> String {
    protocol::to_json(&ServerMessage::Error(ErrorMessage { code, message, id }))
}
