//! The writer: owns the socket's send half and the subscription, sends the client's frames,
//! previews, health and replies at the client's own pace, and closes it when it lags or
//! stalls.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use futures_util::stream::{SplitSink, SplitStream};
use futures_util::SinkExt;
use tokio::sync::{broadcast, mpsc};
use tokio_tungstenite::tungstenite::protocol::frame::coding::CloseCode;
use tokio_tungstenite::tungstenite::protocol::CloseFrame;
use tokio_tungstenite::tungstenite::Message;
use tracing::{debug, warn};

use super::{error_json, truncate_reason, Decimator, Outgoing, ReaderEnd};
use crate::config::Access;
use crate::connection::{Shared, Ws};
use crate::hub::{PublishedFrame, StreamInfo};
use crate::protocol::{
    self, ErrorCode, ErrorMessage, FrameFormat, FrameSelection, FrameView, ResultMessage,
    ServerMessage, StatusMessage, Subscribe,
};

pub(super) struct Writer {
    pub(super) shared: Arc<Shared>,
    pub(super) sink: SplitSink<Ws, Message>,
    pub(super) access: Access,
    pub(super) selection: FrameSelection,
    pub(super) format: FrameFormat,
    pub(super) decimator: Decimator,
    pub(super) character_names: Vec<String>,
    pub(super) lag_window_start: Instant,
    pub(super) lagged_in_window: u64,
    pub(super) buffer: Vec<u8>,
    /// The camera preview, while this client asks for it.
    pub(super) preview: Option<crate::preview::ClientPreview>,
    /// Health figures, while the subscription asks for them.
    pub(super) health: Option<tokio::sync::watch::Receiver<crate::console::Health>>,
    /// The reader's half of the connection after the reader asked to close the client.
    pub(super) unread: Option<SplitStream<Ws>>,
}

/// Why the writer stopped (for the log).
type WriterExit = String;

enum SendError {
    /// The client did not take the bytes within `write_timeout`.
    Stalled,
    /// The connection is gone.
    Gone,
}

impl Writer {
    pub(super) async fn run(
        &mut self,
        mut reader: tokio::task::JoinHandle<ReaderEnd>,
        mut out_rx: mpsc::Receiver<Outgoing>,
        started: Instant,
        last_heard: Arc<AtomicU64>,
    ) -> WriterExit {
        let hub = self.shared.hub.clone();
        let mut info_rx = hub.inner.info.subscribe();
        let mut status_rx = hub.inner.status.subscribe();
        let mut shutdown = self.shared.shutdown.clone();
        let limits = self.shared.config.limits.clone();
        let mut frames: Option<broadcast::Receiver<Arc<PublishedFrame>>> = None;
        let mut ping = tokio::time::interval_at(
            tokio::time::Instant::now() + limits.ping_interval,
            limits.ping_interval,
        );

        let info = info_rx.borrow_and_update().clone();
        if let Err(e) = self.send_hello(&info).await {
            return self.exit(e);
        }
        status_rx.mark_changed();

        loop {
            tokio::select! {
                biased;
                _ = shutdown.changed() => {
                    return self.close(CloseCode::Away, "server shutting down").await;
                }
                exit = &mut reader => {
                    return match exit {
                        Ok((Some((code, reason)), stream)) => {
                            self.unread = Some(stream);
                            self.close(code, &reason).await
                        }
                        _ => "client closed".into(),
                    };
                }
                Some(out) = out_rx.recv() => {
                    let sent = match out {
                        Outgoing::Text(text) => self.send(Message::text(text)).await,
                        Outgoing::Preview(request) => {
                            let text = self.preview_request(&request);
                            self.send(Message::text(text)).await
                        }
                        Outgoing::Subscribe(sub) => {
                            let reply = self.subscribe(&sub, &hub.info());
                            self.health = sub
                                .fields
                                .contains(&protocol::OptionalField::Health)
                                .then(|| {
                                    let mut rx = hub.inner.health.subscribe();
                                    rx.mark_changed();
                                    rx
                                });
                            if reply.is_ok() && frames.is_none() {
                                frames = Some(hub.inner.frames.subscribe());
                            }
                            self.send(Message::text(protocol::to_json(&match reply {
                                Ok(result) => ServerMessage::Result(result),
                                Err(error) => ServerMessage::Error(error),
                            })))
                            .await
                        }
                    };
                    if let Err(e) = sent {
                        return self.exit(e);
                    }
                }
                Ok(()) = status_rx.changed() => {
                    let status = status_rx.borrow_and_update().clone();
                    let text = protocol::to_json(&ServerMessage::Status(StatusMessage::from_status(&status, None)));
                    if let Err(e) = self.send(Message::text(text)).await {
                        return self.exit(e);
                    }
                }
                Ok(()) = info_rx.changed() => {
                    let info = info_rx.borrow_and_update().clone();
                    if let Err(e) = self.send_hello(&info).await {
                        return self.exit(e);
                    }
                }
                received = next_frame(&mut frames) => match received {
                    Ok(frame) => {
                        if let Err(e) = self.send_frame(&frame).await {
                            return self.exit(e);
                        }
                    }
                    Err(broadcast::error::RecvError::Lagged(lost)) => {
                        if let Some(reason) = self.note_lag(lost, &limits) {
                            hub.inner.metrics.clients_closed_slow.fetch_add(1, Ordering::Relaxed);
                            warn!(reason, "closing slow client");
                            return self.close(CloseCode::Policy, &reason).await;
                        }
                        let status = hub.status();
                        let text = protocol::to_json(&ServerMessage::Status(StatusMessage::from_status(&status, Some(lost))));
                        if let Err(e) = self.send(Message::text(text)).await {
                            return self.exit(e);
                        }
                    }
                    Err(broadcast::error::RecvError::Closed) => {
                        return self.close(CloseCode::Away, "stream ended").await;
                    }
                },
                image = crate::preview::next_image(&mut self.preview) => {
                    if let Err(e) = self.send(Message::Binary(image.message.clone())).await {
                        return self.exit(e);
                    }
                    hub.inner.preview.counters.sent.fetch_add(1, Ordering::Relaxed);
                }
                Ok(()) = next_health(&mut self.health) => {
                    if let Err(e) = self.send(Message::text(hub.health_json())).await {
                        return self.exit(e);
                    }
                }
                _ = ping.tick() => {
                    let heard_ms = last_heard.load(Ordering::Relaxed);
                    let silent = started.elapsed().saturating_sub(Duration::from_millis(heard_ms));
                    if silent > limits.idle_timeout {
                        let reason = format!("no response for {} s", silent.as_secs());
                        return self.close(CloseCode::Away, &reason).await;
                    }
                    if let Err(e) = self.send(Message::Ping(Vec::new().into())).await {
                        return self.exit(e);
                    }
                }
            }
        }
    }

    fn exit(&self, e: SendError) -> WriterExit {
        match e {
            SendError::Stalled => {
                self.shared
                    .hub
                    .inner
                    .metrics
                    .clients_closed_slow
                    .fetch_add(1, Ordering::Relaxed);
                let reason = format!(
                    "client too slow: a write blocked for {} s",
                    self.shared.config.limits.write_timeout.as_secs_f32()
                );
                warn!(reason, "closing slow client");
                reason
            }
            SendError::Gone => "connection lost".into(),
        }
    }

    async fn send(&mut self, message: Message) -> Result<(), SendError> {
        let timeout = self.shared.config.limits.write_timeout;
        match tokio::time::timeout(timeout, self.sink.send(message)).await {
            Ok(Ok(())) => Ok(()),
            Ok(Err(e)) => {
                debug!(error = %e, "send failed");
                Err(SendError::Gone)
            }
            Err(_) => Err(SendError::Stalled),
        }
    }

    /// Sends a close frame with `reason` (best effort: the peer may be gone) and returns it.
    ///
    /// A client closed for not reading has a full socket: its close frame waits behind the
    /// replies it has not read, for as long as one write may take (`write_timeout`), so a
    /// client that does read them then gets the code and reason rather than a bare cut.
    async fn close(&mut self, code: CloseCode, reason: &str) -> WriterExit {
        let frame = CloseFrame {
            code,
            reason: truncate_reason(reason).into(),
        };
        let wait = self
            .shared
            .config
            .limits
            .write_timeout
            .max(Duration::from_secs(1));
        let _ = tokio::time::timeout(wait, self.sink.send(Message::Close(Some(frame)))).await;
        reason.to_owned()
    }

    async fn send_hello(&mut self, info: &StreamInfo) -> Result<(), SendError> {
        self.character_names = info.characters.iter().map(|c| c.name.clone()).collect();
        let text = self
            .shared
            .hub
            .hello_json(info, &self.shared.config.name, self.access.as_str());
        self.send(Message::text(text)).await
    }

    fn subscribe(
        &mut self,
        sub: &Subscribe,
        info: &StreamInfo,
    ) -> Result<ResultMessage, ErrorMessage> {
        if let Some(names) = &sub.characters {
            if let Some(unknown) = names
                .iter()
                .find(|n| !info.characters.iter().any(|c| &c.name == *n))
            {
                let known: Vec<_> = info.characters.iter().map(|c| c.name.as_str()).collect();
                return Err(ErrorMessage {
                    code: ErrorCode::BadRequest,
                    message: format!(
                        "subscribe: unknown character {unknown:?} (available: {})",
                        known.join(", ")
                    ),
                    id: sub.id.clone(),
                });
            }
        }
        self.selection = FrameSelection::from_subscribe(sub);
        self.format = sub.format;
        self.decimator = Decimator {
            max_rate: sub.max_rate,
            next_due: None,
        };
        debug!(?sub, "subscribed");
        Ok(ResultMessage {
            id: sub.id.clone(),
            request: "subscribe",
            detail: serde_json::json!({
                "characters": self.selection.characters.clone()
                    .unwrap_or_else(|| info.characters.iter().map(|c| c.name.clone()).collect()),
                "fields": sub.fields,
                "max_rate": sub.max_rate,
                "format": sub.format,
            }),
        })
    }

    async fn send_frame(&mut self, frame: &PublishedFrame) -> Result<(), SendError> {
        if !self.decimator.admit(frame.frame.t) {
            return Ok(());
        }
        let message = match self.format {
            FrameFormat::Json if self.selection.characters.is_none() => {
                let slot =
                    usize::from(self.selection.curve) * 2 + usize::from(self.selection.performer);
                let text = frame.json_cache[slot]
                    .get_or_init(|| FrameView::new(frame, &self.selection).to_json().into());
                Message::Text(text.clone())
            }
            FrameFormat::Json => Message::text(FrameView::new(frame, &self.selection).to_json()),
            FrameFormat::Binary => {
                self.buffer.clear();
                protocol::encode_binary_frame(
                    frame,
                    &self.selection,
                    &self.character_names,
                    &mut self.buffer,
                );
                Message::binary(self.buffer.clone())
            }
        };
        self.send(message).await?;
        let metrics = &self.shared.hub.inner.metrics;
        metrics.frames_out.fetch_add(1, Ordering::Relaxed);
        if let Some(at) = frame.published_at {
            metrics.fanout_latency.observe(at.elapsed().as_secs_f64());
        }
        if let Some(wall) = frame.frame.wall_us {
            let micros = crate::loadgen::unix_micros() - wall;
            metrics.capture_latency.observe(micros as f64 * 1e-6);
        }
        tracing::trace!(seq = frame.seq, "sent frame");
        Ok(())
    }

    /// Starts, changes or stops this client's preview; returns the `result` (or `error`) text.
    fn preview_request(&mut self, request: &protocol::PreviewSubscribe) -> String {
        if request.enable == Some(false) {
            self.preview = None;
            return protocol::to_json(&ServerMessage::Result(ResultMessage {
                id: request.id.clone(),
                request: "preview",
                detail: serde_json::json!({"enabled": false}),
            }));
        }
        let wanted = match crate::preview::PreviewRequest::new(request.max_rate, request.max_width)
        {
            Ok(r) => r,
            Err(message) => return error_json(ErrorCode::BadRequest, message, request.id.clone()),
        };
        match &mut self.preview {
            Some(p) => p.change(wanted),
            None => {
                self.preview = Some(crate::preview::ClientPreview::start(
                    &self.shared.hub.inner.preview,
                    wanted,
                ))
            }
        }
        debug!(?wanted, "preview");
        protocol::to_json(&ServerMessage::Result(ResultMessage {
            id: request.id.clone(),
            request: "preview",
            detail: serde_json::json!({
                "enabled": true,
                "max_rate": wanted.max_rate,
                "max_width": wanted.max_width,
            }),
        }))
    }

    /// Counts lost frames; returns a close reason when the client stays too far behind.
    fn note_lag(&mut self, lost: u64, limits: &crate::config::Limits) -> Option<String> {
        self.shared
            .hub
            .inner
            .metrics
            .frames_dropped
            .fetch_add(lost, Ordering::Relaxed);
        if self.lag_window_start.elapsed() > limits.lag_window {
            self.lag_window_start = Instant::now();
            self.lagged_in_window = 0;
        }
        self.lagged_in_window += lost;
        debug!(lost, in_window = self.lagged_in_window, "client lagged");
        (self.lagged_in_window > limits.max_dropped_frames).then(|| {
            format!(
                "too slow: lost {} frames within {} s",
                self.lagged_in_window,
                limits.lag_window.as_secs()
            )
        })
    }
}

async fn next_health(
    health: &mut Option<tokio::sync::watch::Receiver<crate::console::Health>>,
) -> Result<(), tokio::sync::watch::error::RecvError> {
    match health {
        Some(rx) => {
            let changed = rx.changed().await;
            rx.mark_unchanged();
            changed
        }
        None => std::future::pending().await,
    }
}

async fn next_frame(
    frames: &mut Option<broadcast::Receiver<Arc<PublishedFrame>>>,
) -> Result<Arc<PublishedFrame>, broadcast::error::RecvError> {
    match frames {
        Some(rx) => rx.recv().await,
        None => std::future::pending().await,
    }
}
