//! One `mouthpiece.v1` client: a reader task and a writer loop.
//!
//! The reader parses what the client sends, answers through the client's small control
//! queue, and never touches frames. The writer owns the socket's send half and the
//! subscription: it takes frames from the hub's ring at the client's own pace, so a slow
//! client only ever delays itself. When the ring overruns it, the client loses the oldest
//! frames and gets `status` with `lagged`; past `max_dropped_frames` within `lag_window`,
//! or when one write blocks longer than `write_timeout`, it is closed with a reason.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use futures_util::stream::{SplitSink, SplitStream};
use futures_util::{SinkExt, StreamExt};
use tokio::sync::{broadcast, mpsc};
use tokio_tungstenite::tungstenite::protocol::frame::coding::CloseCode;
use tokio_tungstenite::tungstenite::protocol::CloseFrame;
use tokio_tungstenite::tungstenite::{Error as WsError, Message};
use tracing::{debug, info, warn};

use crate::config::Access;
use crate::hub::{ControlCommand, ControlQueueError, PublishedFrame, StreamInfo};
use crate::protocol::{
    self, ClientMessage, ClockDescription, ErrorCode, ErrorMessage, FrameFormat, FrameSelection,
    FrameView, HelloMessage, RecordAction, RequestId, ResultMessage, ServerIdentity, ServerMessage,
    StatusMessage, Subscribe, SUBPROTOCOL,
};
use crate::server::{Shared, Ws};

/// What the reader hands the writer.
enum Outgoing {
    /// A ready JSON message (error, result, pong).
    Text(String),
    /// A new subscription, validated by the writer against the current `hello`.
    Subscribe(Subscribe),
    /// Start, change or stop the camera preview.
    Preview(protocol::PreviewSubscribe),
}

/// Why the reader stopped; a reason means "close the client with it".
type ReaderExit = Option<(CloseCode, String)>;

/// The reader's end: why it stopped, and its half of the connection (to linger on).
type ReaderEnd = (ReaderExit, SplitStream<Ws>);

pub(crate) async fn run(shared: &Arc<Shared>, ws: Ws, access: Access, peer: SocketAddr) {
    let (sink, stream) = ws.split();
    let limits = &shared.config.limits;
    let (out_tx, out_rx) = mpsc::channel(limits.control_queue_per_client);
    let started = Instant::now();
    let last_heard = Arc::new(AtomicU64::new(0));
    let reader = tokio::spawn({
        let (shared, last_heard) = (shared.clone(), last_heard.clone());
        async move {
            let mut stream = stream;
            let exit = read_loop(
                shared,
                &mut stream,
                out_tx,
                access,
                peer,
                started,
                last_heard,
            )
            .await;
            (exit, stream)
        }
    });
    let abort = reader.abort_handle();
    let mut writer = Writer {
        shared: shared.clone(),
        sink,
        access,
        selection: FrameSelection::default(),
        format: FrameFormat::Json,
        decimator: Decimator::default(),
        character_names: Vec::new(),
        lag_window_start: Instant::now(),
        lagged_in_window: 0,
        buffer: Vec::new(),
        preview: None,
        health: None,
        unread: None,
    };
    let reason = writer.run(reader, out_rx, started, last_heard).await;
    abort.abort();
    if let Some(stream) = writer.unread.take() {
        linger(writer.sink, stream, limits.write_timeout).await;
    }
    info!(reason, "client disconnected");
}

/// After a close frame to a client that may still be sending: reads (and drops) what it
/// sends until it answers the close or goes, for at most `limit`. Closing a socket that
/// still holds unread data makes the kernel send a reset, which throws away whatever was
/// not yet delivered, the close frame included: the client would see a cut (1006) instead
/// of the code and reason.
async fn linger(sink: SplitSink<Ws, Message>, stream: SplitStream<Ws>, limit: Duration) {
    let Ok(mut ws) = stream.reunite(sink) else {
        return;
    };
    let _ = tokio::time::timeout(limit, async { while let Some(Ok(_)) = ws.next().await {} }).await;
}

struct Writer {
    shared: Arc<Shared>,
    sink: SplitSink<Ws, Message>,
    access: Access,
    selection: FrameSelection,
    format: FrameFormat,
    decimator: Decimator,
    character_names: Vec<String>,
    lag_window_start: Instant,
    lagged_in_window: u64,
    buffer: Vec<u8>,
    /// The camera preview, while this client asks for it.
    preview: Option<crate::preview::ClientPreview>,
    /// Health figures, while the subscription asks for them.
    health: Option<tokio::sync::watch::Receiver<crate::console::Health>>,
    /// The reader's half of the connection after the reader asked to close the client.
    unread: Option<SplitStream<Ws>>,
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
    async fn run(
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
        let rate = self.shared.hub.inner.timecode_rate.name();
        let text = protocol::to_json(&ServerMessage::Hello(HelloMessage {
            protocol: SUBPROTOCOL,
            server: ServerIdentity {
                name: self.shared.config.name.clone(),
                version: env!("CARGO_PKG_VERSION"),
            },
            info,
            timecode_rate: rate,
            clock: ClockDescription::default(),
            access: self.access.as_str(),
        }));
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
                    &self.shared.hub,
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

/// Close reasons must fit a control frame (123 bytes).
pub(crate) fn truncate_reason(reason: &str) -> String {
    let mut end = reason.len().min(123);
    while !reason.is_char_boundary(end) {
        end -= 1;
    }
    reason[..end].to_owned()
}

/// Skips frames so a subscription receives at most `max_rate` per second of stream time.
#[derive(Debug, Default, Clone)]
pub(crate) struct Decimator {
    max_rate: Option<f64>,
    next_due: Option<f64>,
}

impl Decimator {
    /// Whether the frame at stream time `t` is sent.
    pub(crate) fn admit(&mut self, t: f64) -> bool {
        let Some(rate) = self.max_rate else {
            return true;
        };
        let period = 1.0 / rate;
        // Half a millisecond of slack absorbs timestamp jitter at the nominal rate.
        const SLACK: f64 = 0.000_5;
        match self.next_due {
            // Not yet due, unless time jumped back (a replay looped): then start over.
            Some(due) if t + SLACK < due && due - t <= period + SLACK => false,
            Some(due) if t + SLACK >= due && t - due < period => {
                self.next_due = Some(due + period);
                true
            }
            _ => {
                self.next_due = Some(t + period);
                true
            }
        }
    }
}

#[derive(Clone, Copy)]
enum Kind {
    Binary,
    Other,
}

/// Messages per second with a burst of the same size.
pub(crate) struct TokenBucket {
    rate: f64,
    tokens: f64,
    last: Instant,
}

impl TokenBucket {
    pub(crate) fn new(rate: u32) -> Self {
        Self {
            rate: f64::from(rate),
            tokens: f64::from(rate),
            last: Instant::now(),
        }
    }

    pub(crate) fn take(&mut self) -> bool {
        let now = Instant::now();
        self.tokens =
            (self.tokens + now.duration_since(self.last).as_secs_f64() * self.rate).min(self.rate);
        self.last = now;
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

fn error_json(code: ErrorCode, message: impl Into<String>, id: Option<RequestId>) -> String {
    protocol::to_json(&ServerMessage::Error(ErrorMessage {
        code,
        message: message.into(),
        id,
    }))
}

async fn read_loop(
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
    let mut bucket = TokenBucket::new(limits.max_messages_per_second);
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
        if !bucket.take() {
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
                server_wall_us: unix_micros_now(),
            })),
            ClientMessage::Calibrate { id, duration_s } => control(
                &shared,
                &out,
                access,
                peer,
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
            } => match crate::head::unknown_character(&shared.hub.info(), &character) {
                Some(message) if access >= Access::Control => {
                    metrics.bad_messages.fetch_add(1, Ordering::Relaxed);
                    reply(error_json(ErrorCode::BadRequest, message, id))
                }
                _ => control(
                    &shared,
                    &out,
                    access,
                    peer,
                    id,
                    "look_at",
                    ControlCommand::LookAt { character, point },
                ),
            },
            ClientMessage::Record {
                id,
                action,
                slate,
                take,
            } => control(
                &shared,
                &out,
                access,
                peer,
                id,
                "record",
                match action {
                    RecordAction::Start => ControlCommand::RecordStart { slate, take },
                    RecordAction::Stop => ControlCommand::RecordStop,
                },
            ),
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
    id: Option<RequestId>,
    request: &'static str,
    command: ControlCommand,
) -> bool {
    let error = |code, message: String| Outgoing::Text(error_json(code, message, id.clone()));
    if access < Access::Control {
        shared
            .hub
            .inner
            .metrics
            .bad_messages
            .fetch_add(1, Ordering::Relaxed);
        return out
            .try_send(error(
                ErrorCode::Forbidden,
                format!("{request} needs the control token"),
            ))
            .is_ok();
    }
    info!(?command, "control request");
    // A calibration is answered once the neutral pose is taken: wait its duration longer.
    let longer = match &command {
        ControlCommand::Calibrate {
            duration: Some(duration),
        } => *duration,
        _ => Duration::ZERO,
    };
    let pending = match shared.hub.request_control(command, peer.to_string()) {
        Ok(rx) => rx,
        Err(ControlQueueError::Full) => {
            return out
                .try_send(error(
                    ErrorCode::Busy,
                    "the daemon has too many control requests waiting; try again".into(),
                ))
                .is_ok()
        }
        Err(ControlQueueError::NoDaemon) => {
            return out
                .try_send(error(
                    ErrorCode::Unavailable,
                    "no daemon is taking control requests".into(),
                ))
                .is_ok()
        }
    };
    let out = out.clone();
    let wait = shared.config.limits.control_timeout + longer;
    tokio::spawn(async move {
        let answer = match tokio::time::timeout(wait, pending).await {
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
        };
        // A full queue means the client is not reading; the reader closes it on its next
        // message, and the writer on its next stalled write.
        let _ = out.try_send(Outgoing::Text(answer));
    });
    true
}

fn unix_micros_now() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as i64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimator_halves_60_to_30_and_restarts_after_a_jump_back() {
        let mut d = Decimator {
            max_rate: Some(30.0),
            next_due: None,
        };
        let sent: Vec<bool> = (0..8).map(|i| d.admit(f64::from(i) / 60.0)).collect();
        assert_eq!(sent, [true, false, true, false, true, false, true, false]);
        assert!(d.admit(0.0), "a replay that loops starts over");
        let mut all = Decimator::default();
        assert!((0..10).all(|i| all.admit(f64::from(i))));
    }

    #[test]
    fn decimator_never_exceeds_the_rate() {
        let mut d = Decimator {
            max_rate: Some(45.0),
            next_due: None,
        };
        let n = (0..600).filter(|i| d.admit(f64::from(*i) / 60.0)).count();
        assert!((290..=450).contains(&n), "{n} frames in 10 s");
    }

    #[test]
    fn close_reasons_fit_a_control_frame() {
        assert_eq!(truncate_reason(&"é".repeat(100)).len(), 122);
    }
}
