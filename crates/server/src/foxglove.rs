//! The Foxglove WebSocket protocol (`foxglove.websocket.v1`, foxglove/ws-protocol
//! `docs/spec.md`), enough for Foxglove Studio to list the channels and plot them live.
//!
//! Channels, all `json` with a JSON Schema (`schemaEncoding: jsonschema`):
//! `/head` (id 1), `/performer` (id 2), `/character/<name>` (ids 100, 101, ... in `hello`
//! order), `/rig/<name>` (ids 200, 201, ...: the character's rig, docs/rig.md, for plotting). Server → client: `serverInfo`, `advertise`, `unadvertise`, `status`, and binary
//! Message Data (opcode 0x01). Client → server: `subscribe`, `unsubscribe`; anything else is
//! answered with an error `status`. Fan-out, lag and slow-client rules are the same as for
//! `mouthpiece.v1` clients.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use futures_util::stream::SplitSink;
use futures_util::{SinkExt, StreamExt};
use serde::Deserialize;
use serde_json::{json, Value};
use tokio::sync::{broadcast, mpsc};
use tokio_tungstenite::tungstenite::protocol::frame::coding::CloseCode;
use tokio_tungstenite::tungstenite::protocol::CloseFrame;
use tokio_tungstenite::tungstenite::{Error as WsError, Message};
use tracing::{debug, info, warn};

use crate::connection::{Shared, Ws};
use crate::foxglove_scene as scene;
use crate::hub::{PublishedFrame, StreamInfo};
use crate::preview::{ClientPreview, PreviewRequest};
use crate::session::truncate_reason;

/// Channel id of `/head`.
pub const HEAD_CHANNEL: u32 = 1;
/// Channel id of `/performer`.
pub const PERFORMER_CHANNEL: u32 = 2;
/// Channel id of the first `/character/<name>`.
pub const FIRST_CHARACTER_CHANNEL: u32 = 100;
/// Channel id of the first `/rig/<name>` (same order as the characters; with more than 100
/// characters the rigs' ids start after the last character's).
pub const FIRST_RIG_CHANNEL: u32 = 200;

/// Status levels of the spec.
const INFO: u8 = 0;
const WARNING: u8 = 1;
const ERROR: u8 = 2;

#[derive(Debug, Clone, PartialEq)]
struct Channel {
    id: u32,
    topic: String,
    kind: ChannelKind,
}

#[derive(Debug, Clone, PartialEq)]
enum ChannelKind {
    Head,
    Performer,
    Character(String),
    /// A character's rig: jaw, lips and the named curves (docs/rig.md).
    Rig(String),
    /// `foxglove.CompressedImage`, `foxglove.ImageAnnotations`, `foxglove.SceneUpdate`,
    /// `foxglove.FrameTransforms` (see [`crate::foxglove_scene`]).
    Image,
    Annotations,
    Scene,
    Transforms,
}

fn channels(info: &StreamInfo) -> Vec<Channel> {
    let mut list = vec![
        Channel {
            id: HEAD_CHANNEL,
            topic: "/head".into(),
            kind: ChannelKind::Head,
        },
        Channel {
            id: PERFORMER_CHANNEL,
            topic: "/performer".into(),
            kind: ChannelKind::Performer,
        },
    ];
    for (id, topic, kind) in [
        (scene::IMAGE_CHANNEL, "/camera/image", ChannelKind::Image),
        (
            scene::ANNOTATIONS_CHANNEL,
            "/camera/annotations",
            ChannelKind::Annotations,
        ),
        (scene::SCENE_CHANNEL, "/scene", ChannelKind::Scene),
        (scene::TRANSFORMS_CHANNEL, "/tf", ChannelKind::Transforms),
    ] {
        list.push(Channel {
            id,
            topic: topic.into(),
            kind,
        });
    }
    for (i, c) in info.characters.iter().enumerate() {
        list.push(Channel {
            id: FIRST_CHARACTER_CHANNEL + i as u32,
            topic: format!("/character/{}", c.name),
            kind: ChannelKind::Character(c.name.clone()),
        });
    }
    // After the characters' ids even when there are more than 100 of them.
    let first_rig = FIRST_RIG_CHANNEL.max(FIRST_CHARACTER_CHANNEL + info.characters.len() as u32);
    for (i, c) in info.characters.iter().enumerate() {
        list.push(Channel {
            id: first_rig + i as u32,
            topic: format!("/rig/{}", c.name),
            kind: ChannelKind::Rig(c.name.clone()),
        });
    }
    list
}

fn point_schema(with_confidence: bool) -> Value {
    let mut props = json!({
        "x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}
    });
    if with_confidence {
        props["confidence"] = json!({"type": "number", "minimum": 0, "maximum": 1});
    }
    json!({"type": "object", "properties": props, "required": ["x", "y", "z"]})
}

fn schema(kind: &ChannelKind) -> (String, Value) {
    let well_known = match kind {
        ChannelKind::Image => scene::schema(scene::IMAGE_CHANNEL),
        ChannelKind::Annotations => scene::schema(scene::ANNOTATIONS_CHANNEL),
        ChannelKind::Scene => scene::schema(scene::SCENE_CHANNEL),
        ChannelKind::Transforms => scene::schema(scene::TRANSFORMS_CHANNEL),
        _ => None,
    };
    if let Some((name, schema)) = well_known {
        return (name.to_owned(), schema);
    }
    let common = json!({
        "seq": {"type": "integer", "description": "frame number in the stream"},
        "t": {"type": "number", "description": "seconds since the start of the stream"},
        "capture_us": {"type": "integer", "description": "capture clock, microseconds"}
    });
    let (name, mut props, required): (&str, Value, Vec<&str>) = match kind {
        ChannelKind::Head => (
            "mouthpiece.Head",
            json!({
                "rotation": {
                    "type": "object",
                    "description": "unit quaternion carrying the neutral head onto the current one",
                    "properties": {"w": {"type": "number"}, "x": {"type": "number"},
                                   "y": {"type": "number"}, "z": {"type": "number"}}
                },
                "translation": point_schema(false),
                "lost": {"type": "boolean", "description": "fewer than 3 forehead dots seen"}
            }),
            vec!["rotation", "translation", "lost"],
        ),
        ChannelKind::Performer => (
            "mouthpiece.Performer",
            json!({"points": {"type": "array", "items": point_schema(true)}}),
            vec!["points"],
        ),
        ChannelKind::Character(_) => (
            "mouthpiece.Character",
            json!({
                "name": {"type": "string"},
                "points": {"type": "array", "items": point_schema(true)},
                "curve": {"type": "array", "items": point_schema(false)},
                "head": crate::head::foxglove_schema(),
                "source": {
                    "type": "string",
                    "enum": ["camera", "speech", "blend"],
                    "description": "what drove the mouth: the camera's dots, the microphone's speech, or a blend of the two during a handover"
                }
            }),
            vec!["name", "points", "source"],
        ),
        ChannelKind::Rig(_) => (
            "mouthpiece.Rig",
            crate::rig::foxglove_properties(),
            vec!["name", "jaw", "lips", "curves"],
        ),
        ChannelKind::Image
        | ChannelKind::Annotations
        | ChannelKind::Scene
        | ChannelKind::Transforms => unreachable!("well-known schemas are returned above"),
    };
    for (k, v) in common.as_object().into_iter().flatten() {
        props[k] = v.clone();
    }
    (
        name.to_owned(),
        json!({"type": "object", "properties": props, "required": required}),
    )
}

fn advertise(channels: &[Channel]) -> String {
    let list: Vec<Value> = channels
        .iter()
        .map(|c| {
            let (schema_name, schema) = schema(&c.kind);
            json!({
                "id": c.id,
                "topic": c.topic,
                "encoding": "json",
                "schemaName": schema_name,
                "schema": schema.to_string(),
                "schemaEncoding": "jsonschema",
            })
        })
        .collect();
    json!({"op": "advertise", "channels": list}).to_string()
}

fn xyz(p: &[f32; 3]) -> Value {
    json!({"x": p[0], "y": p[1], "z": p[2]})
}

/// The JSON payload of one channel for one frame; `None` when the frame has no such data.
fn payload(
    kind: &ChannelKind,
    frame: &PublishedFrame,
    info: &StreamInfo,
    timestamp_ns: u64,
) -> Option<Vec<u8>> {
    let f = &frame.frame;
    let mut value = match kind {
        ChannelKind::Scene => {
            return serde_json::to_vec(&scene::scene_update(frame, info, timestamp_ns)).ok()
        }
        ChannelKind::Transforms => {
            return serde_json::to_vec(&scene::frame_transforms(frame, info, timestamp_ns)).ok()
        }
        ChannelKind::Image | ChannelKind::Annotations => return None,
        ChannelKind::Head => {
            let [w, x, y, z] = f.head.pose.rotation;
            json!({
                "rotation": {"w": w, "x": x, "y": y, "z": z},
                "translation": {"x": f.head.pose.translation[0], "y": f.head.pose.translation[1], "z": f.head.pose.translation[2]},
                "lost": f.head.lost,
            })
        }
        ChannelKind::Performer => {
            let p = f.performer.as_ref()?;
            json!({"points": points_with_confidence(&p.points, &p.confidence)})
        }
        ChannelKind::Character(name) => {
            let c = f.characters.iter().find(|c| &c.name == name)?;
            let mut v = json!({
                "name": c.name,
                "points": points_with_confidence(&c.points, &c.confidence),
                "source": c.source.as_str(),
            });
            if let Some(curve) = &c.curve {
                v["curve"] = curve.iter().map(xyz).collect();
            }
            if let Some(head) = &c.head {
                v["head"] = crate::head::foxglove_payload(head);
            }
            v
        }
        ChannelKind::Rig(name) => {
            let c = f.characters.iter().find(|c| &c.name == name)?;
            crate::rig::foxglove_payload(&c.name, c.rig.as_ref()?)
        }
    };
    value["seq"] = json!(frame.seq);
    value["t"] = json!(f.t);
    value["capture_us"] = json!(f.capture_us);
    serde_json::to_vec(&value).ok()
}

fn points_with_confidence(points: &[[f32; 3]], confidence: &[f32]) -> Value {
    points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let mut v = xyz(p);
            v["confidence"] = json!(confidence.get(i).copied().unwrap_or(0.0));
            v
        })
        .collect()
}

/// Message Data: opcode 0x01, u32 subscription id, u64 timestamp (ns), payload.
fn message_data(subscription: u32, timestamp_ns: u64, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(13 + payload.len());
    out.push(0x01);
    out.extend_from_slice(&subscription.to_le_bytes());
    out.extend_from_slice(&timestamp_ns.to_le_bytes());
    out.extend_from_slice(payload);
    out
}

fn status(level: u8, message: &str) -> String {
    json!({"op": "status", "level": level, "message": message}).to_string()
}

#[derive(Debug, Deserialize)]
#[serde(tag = "op", rename_all = "camelCase")]
enum ClientOp {
    Subscribe {
        subscriptions: Vec<SubscriptionRequest>,
    },
    Unsubscribe {
        #[serde(rename = "subscriptionIds")]
        subscription_ids: Vec<u32>,
    },
}

#[derive(Debug, Deserialize)]
struct SubscriptionRequest {
    id: u32,
    #[serde(rename = "channelId")]
    channel_id: u32,
}

/// Most subscriptions one client may hold: each channel a few times over is plenty; every
/// subscription costs a send per frame.
pub const MAX_SUBSCRIPTIONS_PER_CLIENT: usize = 32;

/// Parses one client text message (`subscribe`, `unsubscribe`); the error is what the
/// client is told.
fn parse_client_op(text: &str) -> Result<ClientOp, String> {
    match serde_json::from_str::<Value>(text) {
        Err(e) => Err(format!("invalid JSON: {e}")),
        Ok(v) => {
            let op = v.get("op").and_then(Value::as_str).unwrap_or("").to_owned();
            serde_json::from_value::<ClientOp>(v).map_err(|e| {
                if matches!(op.as_str(), "subscribe" | "unsubscribe") {
                    format!("bad {op} message: {e}")
                } else {
                    format!(
                        "unsupported op {op:?} (this server supports subscribe and unsubscribe)"
                    )
                }
            })
        }
    }
}

/// Parses a client message of the Foxglove subprotocol as a session does (for fuzzing and
/// tests): `Ok` when it is a valid `subscribe` or `unsubscribe`.
pub fn check_client_message(text: &str) -> Result<(), String> {
    parse_client_op(text).map(|_| ())
}

pub(crate) async fn run(shared: &Arc<Shared>, ws: Ws, peer: SocketAddr) {
    let (mut sink, mut stream) = ws.split();
    let limits = shared.config.limits.clone();
    let hub = shared.hub.clone();
    let metrics = &hub.inner.metrics;
    let (op_tx, mut op_rx) =
        mpsc::channel::<Result<ClientOp, String>>(limits.control_queue_per_client);
    let started = Instant::now();
    let last_heard = Arc::new(AtomicU64::new(0));
    let heard = last_heard.clone();
    let max_bytes = limits.max_message_bytes;
    let reader_shared = shared.clone();
    let reader = tokio::spawn(async move {
        let metrics = &reader_shared.hub.inner.metrics;
        let rate = reader_shared.config.limits.max_messages_per_second;
        let mut bucket = mouthpiece_output::TokenBucket::new(rate, Instant::now());
        let mut refused_in_a_row = 0u32;
        while let Some(message) = stream.next().await {
            heard.store(started.elapsed().as_millis() as u64, Ordering::Relaxed);
            if matches!(
                message,
                Ok(Message::Text(_) | Message::Binary(_) | Message::Ping(_))
            ) {
                if !bucket.take(Instant::now()) {
                    metrics.bad_messages.fetch_add(1, Ordering::Relaxed);
                    refused_in_a_row += 1;
                    if refused_in_a_row > rate.saturating_mul(2) {
                        return Some((
                            CloseCode::Policy,
                            format!("too many messages (limit {rate} per second)"),
                        ));
                    }
                    continue;
                }
                refused_in_a_row = 0;
            }
            let parsed = match message {
                Ok(Message::Text(text)) => parse_client_op(&text),
                Ok(Message::Binary(_)) => {
                    Err("client publishing and services are not supported".into())
                }
                Ok(Message::Close(_)) => return None,
                Ok(_) => continue,
                Err(WsError::Capacity(_)) => {
                    metrics.bad_messages.fetch_add(1, Ordering::Relaxed);
                    return Some((
                        CloseCode::Size,
                        format!("message too big (limit {max_bytes} bytes)"),
                    ));
                }
                Err(_) => return None,
            };
            if parsed.is_err() {
                metrics.bad_messages.fetch_add(1, Ordering::Relaxed);
            }
            if op_tx.try_send(parsed).is_err() {
                return Some((CloseCode::Policy, "too many unanswered requests".to_owned()));
            }
        }
        None
    });
    let abort = reader.abort_handle();
    let mut reader = reader;

    let write_timeout = limits.write_timeout;

    let mut info_rx = hub.inner.info.subscribe();
    let mut shutdown = shared.shutdown.clone();
    let info = info_rx.borrow_and_update().clone();
    let mut current = channels(&info);
    let mut current_info = info.clone();
    // The image channels draw on the camera preview, at the preview's default rate and size.
    let mut preview: Option<ClientPreview> = None;
    let server_info = json!({
        "op": "serverInfo",
        "name": shared.config.name,
        "capabilities": [],
        "metadata": {"protocol": "foxglove.websocket.v1", "mouthpiece": env!("CARGO_PKG_VERSION")},
        "sessionId": format!("{}", std::process::id()),
    })
    .to_string();
    let mut subscriptions: BTreeMap<u32, u32> = BTreeMap::new();
    let mut frames: Option<broadcast::Receiver<Arc<PublishedFrame>>> = None;
    let mut lag_window_start = Instant::now();
    let mut lagged_in_window = 0u64;
    let mut ping = tokio::time::interval_at(
        tokio::time::Instant::now() + limits.ping_interval,
        limits.ping_interval,
    );

    let result: Result<(), (Option<CloseCode>, String)> = async {
        send_within(&mut sink, write_timeout, Message::text(server_info)).await.map_err(|e| (None, e))?;
        send_within(&mut sink, write_timeout, Message::text(advertise(&current))).await.map_err(|e| (None, e))?;
        loop {
            tokio::select! {
                biased;
                _ = shutdown.changed() => return Err((Some(CloseCode::Away), "server shutting down".into())),
                exit = &mut reader => return match exit {
                    Ok(Some((code, reason))) => Err((Some(code), reason)),
                    _ => Err((None, "client closed".into())),
                },
                Some(op) = op_rx.recv() => {
                    let reply = match op {
                        Err(message) => Some(status(ERROR, &message)),
                        Ok(ClientOp::Subscribe { subscriptions: subs }) => {
                            let mut problems = Vec::new();
                            for s in subs {
                                if !current.iter().any(|c| c.id == s.channel_id) {
                                    problems.push(format!("no channel with id {}", s.channel_id));
                                } else if subscriptions.len() >= MAX_SUBSCRIPTIONS_PER_CLIENT && !subscriptions.contains_key(&s.id) {
                                    problems.push(format!("subscription {} refused: at most {MAX_SUBSCRIPTIONS_PER_CLIENT} subscriptions per client", s.id));
                                } else if let std::collections::btree_map::Entry::Vacant(slot) = subscriptions.entry(s.id) {
                                    slot.insert(s.channel_id);
                                } else {
                                    problems.push(format!("subscription id {} already in use", s.id));
                                }
                            }
                            if !subscriptions.is_empty() && frames.is_none() {
                                frames = Some(hub.inner.frames.subscribe());
                            }
                            debug!(?subscriptions, "foxglove subscriptions");
                            update_preview(&hub, &subscriptions, &mut preview);
                            (!problems.is_empty()).then(|| status(ERROR, &problems.join("; ")))
                        }
                        Ok(ClientOp::Unsubscribe { subscription_ids }) => {
                            for id in subscription_ids {
                                subscriptions.remove(&id);
                            }
                            if subscriptions.is_empty() {
                                frames = None;
                            }
                            update_preview(&hub, &subscriptions, &mut preview);
                            None
                        }
                    };
                    if let Some(text) = reply {
                        send_within(&mut sink, write_timeout, Message::text(text)).await.map_err(|e| (None, e))?;
                    }
                }
                Ok(()) = info_rx.changed() => {
                    let info = info_rx.borrow_and_update().clone();
                    current_info = info.clone();
                    let next = channels(&info);
                    if next != current {
                        let gone: Vec<u32> = current.iter().map(|c| c.id).collect();
                        let text = json!({"op": "unadvertise", "channelIds": gone}).to_string();
                        send_within(&mut sink, write_timeout, Message::text(text)).await.map_err(|e| (None, e))?;
                        subscriptions.retain(|_, ch| next.iter().any(|c| c.id == *ch));
                        current = next;
                        update_preview(&hub, &subscriptions, &mut preview);
                        send_within(&mut sink, write_timeout, Message::text(advertise(&current))).await.map_err(|e| (None, e))?;
                    }
                }
                received = async {
                    match frames.as_mut() {
                        Some(rx) => rx.recv().await,
                        None => std::future::pending().await,
                    }
                } => match received {
                    Ok(frame) => {
                        let ts = frame.frame.wall_us.map_or_else(
                            || frame.frame.capture_us.saturating_mul(1000),
                            |w| (w.max(0) as u64).saturating_mul(1000),
                        );
                        // Each channel's payload is serialised once per frame, however many
                        // subscriptions name it.
                        let mut bodies: BTreeMap<u32, Option<Vec<u8>>> = BTreeMap::new();
                        for (&sub, &channel) in &subscriptions {
                            let body = bodies.entry(channel).or_insert_with(|| {
                                current.iter().find(|c| c.id == channel).and_then(|c| payload(&c.kind, &frame, &current_info, ts))
                            });
                            let Some(body) = body.as_deref() else { continue };
                            send_within(&mut sink, write_timeout, Message::binary(message_data(sub, ts, body))).await.map_err(|e| (None, e))?;
                            metrics.frames_out.fetch_add(1, Ordering::Relaxed);
                        }
                        if let Some(at) = frame.published_at {
                            metrics.fanout_latency.observe(at.elapsed().as_secs_f64());
                        }
                    }
                    Err(broadcast::error::RecvError::Lagged(lost)) => {
                        metrics.frames_dropped.fetch_add(lost, Ordering::Relaxed);
                        if lag_window_start.elapsed() > limits.lag_window {
                            lag_window_start = Instant::now();
                            lagged_in_window = 0;
                        }
                        lagged_in_window += lost;
                        if lagged_in_window > limits.max_dropped_frames {
                            metrics.clients_closed_slow.fetch_add(1, Ordering::Relaxed);
                            return Err((Some(CloseCode::Policy), format!(
                                "too slow: lost {lagged_in_window} frames within {} s",
                                limits.lag_window.as_secs()
                            )));
                        }
                        let text = status(WARNING, &format!("lagged: lost {lost} frames"));
                        send_within(&mut sink, write_timeout, Message::text(text)).await.map_err(|e| (None, e))?;
                    }
                    Err(broadcast::error::RecvError::Closed) => {
                        return Err((Some(CloseCode::Away), "stream ended".into()));
                    }
                },
                image = crate::preview::next_image(&mut preview) => {
                    let ts = image.wall_us.map_or_else(
                        || image.capture_us.saturating_mul(1000),
                        |w| (w.max(0) as u64).saturating_mul(1000),
                    );
                    for (&sub, &channel) in &subscriptions {
                        let body = match channel {
                            scene::IMAGE_CHANNEL => scene::compressed_image(&image, ts),
                            scene::ANNOTATIONS_CHANNEL => scene::image_annotations(&image, ts),
                            _ => continue,
                        };
                        let Ok(body) = serde_json::to_vec(&body) else { continue };
                        send_within(&mut sink, write_timeout, Message::binary(message_data(sub, ts, &body))).await.map_err(|e| (None, e))?;
                        hub.inner.preview.counters.sent.fetch_add(1, Ordering::Relaxed);
                    }
                }
                _ = ping.tick() => {
                    let heard_ms = last_heard.load(Ordering::Relaxed);
                    let silent = started.elapsed().saturating_sub(Duration::from_millis(heard_ms));
                    if silent > limits.idle_timeout {
                        return Err((Some(CloseCode::Away), format!("no response for {} s", silent.as_secs())));
                    }
                    send_within(&mut sink, write_timeout, Message::Ping(Vec::new().into())).await.map_err(|e| (None, e))?;
                }
            }
        }
    }
    .await;
    abort.abort();
    let reason = match result {
        Ok(()) => String::new(),
        Err((code, reason)) => {
            if let Some(code) = code {
                if code == CloseCode::Policy {
                    warn!(reason, "closing foxglove client");
                }
                let _ = tokio::time::timeout(Duration::from_secs(1), async {
                    let _ = sink.send(Message::text(status(INFO, &reason))).await;
                    sink.send(Message::Close(Some(CloseFrame {
                        code,
                        reason: truncate_reason(&reason).into(),
                    })))
                    .await
                })
                .await;
            }
            reason
        }
    };
    info!(%peer, reason, "foxglove client disconnected");
}

/// Registers with the camera preview while a subscription is to an image channel.
fn update_preview(
    hub: &crate::hub::Hub,
    subscriptions: &BTreeMap<u32, u32>,
    preview: &mut Option<ClientPreview>,
) {
    let wants = subscriptions
        .values()
        .any(|c| *c == scene::IMAGE_CHANNEL || *c == scene::ANNOTATIONS_CHANNEL);
    match (wants, preview.is_some()) {
        (true, false) => {
            *preview = Some(ClientPreview::start(
                &hub.inner.preview,
                PreviewRequest::default(),
            ))
        }
        (false, true) => *preview = None,
        _ => {}
    }
}

async fn send_within(
    sink: &mut SplitSink<Ws, Message>,
    timeout: Duration,
    message: Message,
) -> Result<(), String> {
    match tokio::time::timeout(timeout, sink.send(message)).await {
        Ok(Ok(())) => Ok(()),
        Ok(Err(_)) => Err("connection lost".to_owned()),
        Err(_) => Err(format!(
            "client too slow: a write blocked for {} s",
            timeout.as_secs_f32()
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_character_has_a_rig_channel_and_ids_never_collide() {
        let mut info = crate::loadgen::synthetic_info(60.0);
        let ids = |info: &StreamInfo| {
            let list = channels(info);
            let mut ids: Vec<u32> = list.iter().map(|c| c.id).collect();
            ids.sort_unstable();
            ids.dedup();
            assert_eq!(ids.len(), list.len(), "ids collide: {list:?}");
            list
        };
        let list = ids(&info);
        let rig = |name: &str| {
            list.iter()
                .find(|c| c.topic == format!("/rig/{name}"))
                .unwrap()
                .id
        };
        assert_eq!((rig("human"), rig("wolf")), (200, 201));
        let template = info.characters[0].clone();
        info.characters = (0..150)
            .map(|i| {
                let mut c = template.clone();
                c.name = format!("c{i}");
                c
            })
            .collect();
        let list = ids(&info);
        assert_eq!(
            list.iter()
                .filter(|c| matches!(c.kind, ChannelKind::Rig(_)))
                .count(),
            150
        );
    }
}
