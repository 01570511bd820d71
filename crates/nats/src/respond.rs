//! Request/reply: `mouthpiece.<booth>.control` (calibrate, record, look_at) answered with
//! the same `result` or `error` message as on the WebSocket, through the server's own
//! control handling; `mouthpiece.<booth>.hello` answered with the current `hello`.
//!
//! Who may send a control request is the NATS server's decision: a user without publish
//! permission on the control subject never reaches the booth.

use std::sync::atomic::Ordering;
use std::time::Duration;

use futures_util::StreamExt;
use mouthpiece_server::control;
use mouthpiece_server::protocol::ErrorCode;
use mouthpiece_server::{Hub, Limits};

use crate::Subjects;

/// Largest control request read; a longer one is answered with `bad_request`.
pub const MAX_REQUEST_BYTES: usize = 64 * 1024;

pub(crate) async fn run(
    client: async_nats::Client,
    hub: Hub,
    subjects: Subjects,
    server_name: String,
) {
    let control = match client.subscribe(subjects.control()).await {
        Ok(s) => s,
        Err(e) => {
            tracing::error!("NATS: cannot subscribe to {}: {e}", subjects.control());
            return;
        }
    };
    let hello = match client.subscribe(subjects.hello()).await {
        Ok(s) => s,
        Err(e) => {
            tracing::error!("NATS: cannot subscribe to {}: {e}", subjects.hello());
            return;
        }
    };
    let timeout = Limits::default().control_timeout;
    let mut control = control;
    let mut hello = hello;
    loop {
        tokio::select! {
            message = control.next() => {
                let Some(message) = message else { return };
                let Some(reply) = message.reply.clone() else { continue };
                hub.nats().control_requests.fetch_add(1, Ordering::Relaxed);
                let (client, hub) = (client.clone(), hub.clone());
                tokio::spawn(async move {
                    let answer = answer(&hub, &message.payload, timeout).await;
                    if let Err(e) = client.publish(reply, answer.into()).await {
                        tracing::warn!("NATS: control reply not sent: {e}");
                    }
                });
            }
            message = hello.next() => {
                let Some(message) = message else { return };
                // The booth's own `hello` publications have no reply subject.
                let Some(reply) = message.reply else { continue };
                let text = hub.hello_json(&hub.info(), &server_name, "control");
                let _ = client.publish(reply, text.into()).await;
            }
        }
    }
}

/// The reply to one control request's payload.
pub async fn answer(hub: &Hub, payload: &[u8], timeout: Duration) -> String {
    if payload.len() > MAX_REQUEST_BYTES {
        return control::error_json(
            ErrorCode::BadRequest,
            format!(
                "a control request is at most {MAX_REQUEST_BYTES} bytes, got {}",
                payload.len()
            ),
            None,
        );
    }
    let Ok(text) = std::str::from_utf8(payload) else {
        return control::error_json(
            ErrorCode::BadJson,
            "a control request is JSON text (UTF-8)".into(),
            None,
        );
    };
    control::answer_text(hub, text, "nats".to_owned(), timeout).await
}
