//! The reader: parses what the client sends (rate-limited), answers through the client's
//! control queue, and forwards control requests to the daemon.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use futures_util::stream::SplitStream;
use futures_util::StreamExt;
use tokio::sync::mpsc;
use tokio_tungstenite::tungstenite::protocol::frame::coding::CloseCode;
use tokio_tungstenite::tungstenite::{Error as WsError, Message};
use tracing::{debug, info};

use mouthpiece_output::TokenBucket;

use super::{error_json, Outgoing, ReaderExit};
use crate::config::Access;
use crate::connection::{Shared, Ws};
use crate::protocol::{self, ClientMessage, ErrorCode, ServerMessage};

#[derive(Clone, Copy)]
enum Kind {
    Binary,
    Other,
}

pub(super) async fn read_loop(
    shared: Arc<Shared>,
    stream: &mut SplitStream<Ws>,
    out: mpsc::Sender<Outgoing>,
    access: Access,
    peer: SocketAddr,
    started: Instant,
    last_heard: Arc<AtomicU64>,
) -> ReaderExit {
    let limits = &shared.config.limits;
    let metrics = &shared.hub.inner.metrics;
    let mut bucket = TokenBucket::new(limits.max_messages_per_second, Instant::now());
    let mut refused_in_a_row = 0u32;
    // The writer stalls when the client does not read; its replies then pile up here.
    let overflow = || {
        Some((
            CloseCode::Policy,
            "too many unanswered requests: the client is not reading".to_owned(),
        ))
    };
    let reply = |text: String| out.try_send(Outgoing::Text(text)).is_ok();
    while let Some(message) = stream.next().await {
        last_heard.store(started.elapsed().as_millis() as u64, Ordering::Relaxed);
        let message_kind = match &message {
            Ok(Message::Binary(_)) => Kind::Binary,
            _ => Kind::Other,
        };
        // Text and binary messages and pings count against the rate limit; pongs answer ours.
        let text = match message {
            Ok(Message::Text(text)) => Some(text),
            Ok(Message::Binary(_) | Message::Ping(_)) => None,
            Ok(Message::Close(_)) => return None,
            Ok(_) => continue,
            Err(WsError::Capacity(e)) => {
                metrics.bad_messages.fetch_add(1, Ordering::Relaxed);
                info!(error = %e, "client message too big");
                return Some((
                    CloseCode::Size,
                    format!("message too big (limit {} bytes)", limits.max_message_bytes),
                ));
            }
            Err(WsError::ConnectionClosed | WsError::AlreadyClosed) => return None,
            Err(WsError::Io(e)) => {
                debug!(error = %e, "read failed");
                return None;
            }
            Err(e) => {
                metrics.bad_messages.fetch_add(1, Ordering::Relaxed);
                info!(error = %e, "WebSocket protocol error");
                return Some((CloseCode::Protocol, format!("protocol error: {e}")));
            }
        };
        if !bucket.take(Instant::now()) {
            metrics.bad_messages.fetch_add(1, Ordering::Relaxed);
            refused_in_a_row += 1;
            if refused_in_a_row > limits.max_messages_per_second.saturating_mul(2) {
                return Some((
                    CloseCode::Policy,
                    format!(
                        "too many messages (limit {} per second)",
                        limits.max_messages_per_second
                    ),
                ));
            }
            if !reply(error_json(
                ErrorCode::RateLimited,
                format!(
                    "more than {} messages per second: ignored",
                    limits.max_messages_per_second
                ),
                None,
            )) {
                return overflow();
            }
            continue;
        }
        refused_in_a_row = 0;
        let Some(text) = text else {
            // tungstenite answers pings itself.
            if matches!(message_kind, Kind::Binary) {
                metrics.bad_messages.fetch_add(1, Ordering::Relaxed);
                if !reply(error_json(
                    ErrorCode::UnsupportedBinary,
                    "clients send JSON text messages only",
                    None,
                )) {
                    return overflow();
                }
            }
            continue;
        };
        let message = match protocol::parse_client_message(&text) {
            Ok(m) => m,
            Err(failure) => {
                metrics.bad_messages.fetch_add(1, Ordering::Relaxed);
                debug!(message = failure.message, "bad client message");
                if !reply(error_json(failure.code, failure.message, failure.id)) {
                    return overflow();
                }
                continue;
            }
        };
        let ok = match message {
            ClientMessage::Subscribe(sub) => out.try_send(Outgoing::Subscribe(sub)).is_ok(),
            ClientMessage::Preview(request) => out.try_send(Outgoing::Preview(request)).is_ok(),
            ClientMessage::Ping { id } => reply(protocol::to_json(&ServerMessage::Pong {
                id,
                server_wall_us: crate::control::unix_micros_now(),
            })),
            other => match crate::control::control_call(other) {
                Some(call) => match crate::control::refuse_early(&shared.hub, &call) {
                    Some(refused) if access >= Access::Control => {
                        metrics.bad_messages.fetch_add(1, Ordering::Relaxed);
                        reply(refused)
                    }
                    _ => control(&shared, &out, access, peer, call),
                },
                None => true,
            },
        };
        if !ok {
            return overflow();
        }
    }
    None
}

/// Forwards a control request to the daemon; the answer arrives later on `out`.
/// Returns false when the client's queue overflowed.
fn control(
    shared: &Arc<Shared>,
    out: &mpsc::Sender<Outgoing>,
    access: Access,
    peer: SocketAddr,
    call: crate::control::ControlCall,
) -> bool {
    if access < Access::Control {
        shared
            .hub
            .inner
            .metrics
            .bad_messages
            .fetch_add(1, Ordering::Relaxed);
        return out
            .try_send(Outgoing::Text(error_json(
                ErrorCode::Forbidden,
                format!("{} needs the control token", call.request),
                call.id,
            )))
            .is_ok();
    }
    let timeout = shared.config.limits.control_timeout;
    let pending = match crate::control::queue(&shared.hub, call, peer.to_string(), timeout) {
        Ok(pending) => pending,
        Err(refused) => return out.try_send(Outgoing::Text(refused)).is_ok(),
    };
    let out = out.clone();
    tokio::spawn(async move {
        let answer = pending.answer().await;
        // A full queue means the client is not reading; the reader closes it on its next
        // message, and the writer on its next stalled write.
        let _ = out.try_send(Outgoing::Text(answer));
    });
    true
}
