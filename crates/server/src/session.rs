//! One `mouthpiece.v1` client: a reader task and a writer loop.
//!
//! The reader parses what the client sends, answers through the client's small control
//! queue, and never touches frames. The writer owns the socket's send half and the
//! subscription: it takes frames from the hub's ring at the client's own pace, so a slow
//! client only ever delays itself. When the ring overruns it, the client loses the oldest
//! frames and gets `status` with `lagged`; past `max_dropped_frames` within `lag_window`,
//! or when one write blocks longer than `write_timeout`, it is closed with a reason.

mod reader;
mod writer;

use std::net::SocketAddr;
use std::sync::atomic::AtomicU64;
use std::sync::Arc;
use std::time::{Duration, Instant};

use futures_util::stream::{SplitSink, SplitStream};
use futures_util::StreamExt;
use tokio::sync::mpsc;
use tokio_tungstenite::tungstenite::protocol::frame::coding::CloseCode;
use tokio_tungstenite::tungstenite::Message;
use tracing::info;

use crate::config::Access;
use crate::connection::{Shared, Ws};
use crate::protocol::{
    self, ErrorCode, ErrorMessage, FrameFormat, FrameSelection, RequestId, ServerMessage, Subscribe,
};

use reader::read_loop;
use writer::Writer;

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

fn error_json(code: ErrorCode, message: impl Into<String>, id: Option<RequestId>) -> String {
    protocol::to_json(&ServerMessage::Error(ErrorMessage {
        code,
        message: message.into(),
        id,
    }))
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
