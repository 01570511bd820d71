//! The publisher: frames, rigs, `status` and `hello` from the hub onto the booth's subjects.
//!
//! It reads the hub's frame ring like a WebSocket client: the processing thread never
//! waits for it. A publisher that falls behind loses the oldest frames (the ring overran);
//! while the broker is away frames are dropped instead of queued (a live frame sent seconds
//! late is worse than none). Both count in `mouthpiece_nats_frames_dropped_total`.

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use async_nats::connection::State;
use async_nats::HeaderMap;
use mouthpiece_server::hub::{PublishedFrame, StreamInfo};
use mouthpiece_server::protocol::{
    self, encode_binary_frame, FrameSelection, FrameView, ServerMessage, StatusMessage,
};
use mouthpiece_server::Hub;
use tokio::sync::broadcast::error::RecvError;

use crate::{Connections, NatsSettings, Subjects};

/// Header on every frame and rig message: when the booth handed it to the client, Unix
/// microseconds (for latency and gap measurements on the subscriber's side).
pub const SENT_HEADER: &str = "Mouthpiece-Sent-Us";

/// How often `status` goes out when nothing changes (a late subscriber learns the state).
pub const STATUS_EVERY: Duration = Duration::from_secs(5);

/// Every optional field: a NATS subscriber cannot ask for a selection.
pub fn full_selection() -> FrameSelection {
    FrameSelection {
        characters: None,
        curve: true,
        performer: true,
        rig: true,
    }
}

pub(crate) async fn run(
    client: async_nats::Client,
    hub: Hub,
    subjects: Subjects,
    settings: NatsSettings,
    server_name: String,
    connected: Arc<Connections>,
) {
    let counters = hub.nats();
    let mut frames = hub.subscribe_frames();
    let mut status = hub.watch_status();
    let mut info = hub.watch_info();
    let mut connections = connected.subscribe();
    let mut heartbeat = tokio::time::interval(STATUS_EVERY);
    heartbeat.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let selection = full_selection();
    let mut names = character_names(&info.borrow());
    let mut publisher = Publisher {
        client,
        subjects,
        settings,
        binary: Vec::with_capacity(4096),
    };
    loop {
        tokio::select! {
            received = frames.recv() => match received {
                Ok(frame) => {
                    if publisher.client.connection_state() != State::Connected {
                        counters.frames_dropped.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                    if publisher.frame(&frame, &selection, &names).await {
                        counters.frames_published.fetch_add(1, Ordering::Relaxed);
                    } else {
                        counters.frames_dropped.fetch_add(1, Ordering::Relaxed);
                    }
                }
                Err(RecvError::Lagged(lost)) => {
                    counters.frames_dropped.fetch_add(lost, Ordering::Relaxed);
                }
                Err(RecvError::Closed) => return,
            },
            changed = status.changed() => {
                if changed.is_err() { return; }
                let text = status_json(&status.borrow_and_update());
                publisher.text(publisher.subjects.status(), text).await;
            }
            changed = info.changed() => {
                if changed.is_err() { return; }
                let current = info.borrow_and_update().clone();
                names = character_names(&current);
                let text = hub.hello_json(&current, &server_name, "control");
                publisher.text(publisher.subjects.hello(), text).await;
            }
            changed = connections.changed() => {
                if changed.is_err() { return; }
                // On every (re)connection: what a WebSocket client gets first.
                let text = hub.hello_json(&hub.info(), &server_name, "control");
                publisher.text(publisher.subjects.hello(), text).await;
                let text = status_json(&hub.status());
                publisher.text(publisher.subjects.status(), text).await;
            }
            _ = heartbeat.tick() => {
                let text = status_json(&hub.status());
                publisher.text(publisher.subjects.status(), text).await;
            }
        }
    }
}

fn character_names(info: &StreamInfo) -> Vec<String> {
    info.characters.iter().map(|c| c.name.clone()).collect()
}

/// The `status` message as a WebSocket client gets it.
pub fn status_json(status: &mouthpiece_server::Status) -> String {
    protocol::to_json(&ServerMessage::Status(StatusMessage::from_status(
        status, None,
    )))
}

struct Publisher {
    client: async_nats::Client,
    subjects: Subjects,
    settings: NatsSettings,
    binary: Vec<u8>,
}

impl Publisher {
    /// Publishes one frame (JSON, binary, rigs); false when the client refused it.
    async fn frame(
        &mut self,
        frame: &PublishedFrame,
        selection: &FrameSelection,
        names: &[String],
    ) -> bool {
        let mut headers = HeaderMap::new();
        headers.insert(SENT_HEADER, unix_micros_now().to_string().as_str());
        let json = FrameView::new(frame, selection).to_json();
        let mut ok = self
            .client
            .publish_with_headers(self.subjects.frame(), headers.clone(), json.into())
            .await
            .is_ok();
        if self.settings.binary {
            self.binary.clear();
            encode_binary_frame(frame, selection, names, &mut self.binary);
            ok &= self
                .client
                .publish_with_headers(
                    self.subjects.frame_bin(),
                    headers.clone(),
                    bytes::Bytes::copy_from_slice(&self.binary),
                )
                .await
                .is_ok();
        }
        if self.settings.rig {
            for character in &frame.frame.characters {
                let Some(rig) = &character.rig else { continue };
                let payload = serde_json::json!({
                    "type": "rig",
                    "seq": frame.seq,
                    "t": frame.frame.t,
                    "wall_us": frame.frame.wall_us,
                    "timecode": frame.timecode,
                    "character": character.name,
                    "rig": rig,
                });
                ok &= self
                    .client
                    .publish_with_headers(
                        self.subjects.rig(&character.name),
                        headers.clone(),
                        payload.to_string().into(),
                    )
                    .await
                    .is_ok();
            }
        }
        ok
    }

    /// Publishes a control-plane message when connected (a stale one is not queued).
    async fn text(&self, subject: String, text: String) {
        if self.client.connection_state() != State::Connected {
            return;
        }
        if let Err(e) = self.client.publish(subject, text.into()).await {
            tracing::debug!("NATS publish failed: {e}");
        }
    }
}

/// Now, Unix microseconds.
pub fn unix_micros_now() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as i64)
}
