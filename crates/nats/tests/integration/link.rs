//! The NATS link against a real `nats-server` (JetStream on), driven through a real hub: a
//! thread publishes frames as the processing thread does, and a stand-in for the daemon
//! answers control requests from the hub's queue.

use crate::helper_harness as harness;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use futures_util::StreamExt;
use harness::{eventually, NatsServer};
use mouthpiece_nats::{NatsLink, NatsSettings};
use mouthpiece_server::{
    CharacterFrame, CharacterInfo, ControlCommand, ControlFailure, Hub, HubConfig, RigState,
    StreamFrame, StreamInfo,
};
use serde_json::{json, Value};

const WAIT: Duration = Duration::from_secs(20);

fn hub() -> Hub {
    let (hub, mut control) = Hub::new(&HubConfig::default());
    hub.set_info(StreamInfo {
        characters: vec![CharacterInfo {
            name: "wolf".into(),
            ..CharacterInfo::default()
        }],
        frame_rate: 100.0,
        source: "test".into(),
        ..StreamInfo::default()
    });
    // The daemon's side of control: record start succeeds, calibrate fails.
    std::thread::spawn(move || {
        while let Some(request) = control.blocking_recv() {
            let outcome = match &request.command {
                ControlCommand::RecordStart { slate, .. } => {
                    Ok(json!({"slate": slate.clone().unwrap_or_default(), "take": 1}))
                }
                ControlCommand::RecordStop => Ok(json!({"stopped": true})),
                ControlCommand::Calibrate { .. } => Err(ControlFailure::new("no performer seen")),
                ControlCommand::LookAt { .. } => Ok(json!({})),
                ControlCommand::TuneColours { .. } => Err(ControlFailure::new("no frames")),
            };
            request.reply(outcome);
        }
    });
    hub
}

/// Publishes frames at about 100 Hz from a plain thread (like the processing thread) until
/// `stop`; `wall_us` is the publication time.
fn publish_frames(hub: Hub, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let mut frame = StreamFrame {
            characters: vec![CharacterFrame {
                name: "wolf".into(),
                points: vec![[0.0, 1.0, 2.0]],
                confidence: vec![1.0],
                rig: Some(RigState::default()),
                ..CharacterFrame::default()
            }],
            ..StreamFrame::default()
        };
        let mut i = 0u64;
        while !stop.load(Ordering::Relaxed) {
            frame.t = i as f64 / 100.0;
            frame.wall_us = Some(mouthpiece_nats::publish::unix_micros_now());
            hub.publish(&frame);
            i += 1;
            std::thread::sleep(Duration::from_millis(10));
        }
    })
}

async fn client(urls: &[String]) -> async_nats::Client {
    async_nats::ConnectOptions::new()
        .retry_on_initial_connect()
        .reconnect_delay_callback(|n| mouthpiece_nats::reconnect_delay(n, Duration::from_secs(1)))
        .connect(mouthpiece_nats::server_addrs(urls).unwrap())
        .await
        .unwrap()
}

async fn start_link(hub: &Hub, urls: Vec<String>, folder: &std::path::Path) -> NatsLink {
    NatsLink::start(
        hub.clone(),
        NatsSettings::new(urls, "b1"),
        "mouthpiece-test".into(),
        folder.to_owned(),
    )
    .await
    .unwrap()
}

async fn next_json(sub: &mut async_nats::Subscriber) -> Value {
    let message = tokio::time::timeout(WAIT, sub.next())
        .await
        .expect("no message in time")
        .unwrap();
    serde_json::from_slice(&message.payload).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_rig_status_and_hello_reach_a_subscriber() {
    let server = NatsServer::start();
    let folder = tempfile::tempdir().unwrap();
    let hub = hub();
    let _link = start_link(&hub, vec![server.url()], folder.path()).await;
    let sub = client(&[server.url()]).await;
    let mut frames = sub.subscribe("mouthpiece.b1.frame").await.unwrap();
    let mut binary = sub.subscribe("mouthpiece.b1.frame.bin").await.unwrap();
    let mut rig = sub.subscribe("mouthpiece.b1.rig.wolf").await.unwrap();
    let mut status = sub.subscribe("mouthpiece.b1.status").await.unwrap();
    // `hello` on request, as a WebSocket client gets it first.
    let hello = eventually(WAIT, async || {
        sub.request("mouthpiece.b1.hello", "".into()).await.ok()
    })
    .await
    .expect("no hello");
    let hello: Value = serde_json::from_slice(&hello.payload).unwrap();
    assert_eq!(hello["type"], "hello", "{hello}");
    assert_eq!(hello["protocol"], "mouthpiece.v1", "{hello}");
    assert_eq!(hello["characters"][0]["name"], "wolf", "{hello}");

    let stop = Arc::new(AtomicBool::new(false));
    let publisher = publish_frames(hub.clone(), stop.clone());
    let frame = next_json(&mut frames).await;
    assert_eq!(frame["type"], "frame", "{frame}");
    assert_eq!(frame["characters"][0]["name"], "wolf", "{frame}");
    assert!(frame["characters"][0]["rig"].is_object(), "{frame}");
    let bin = tokio::time::timeout(WAIT, binary.next())
        .await
        .unwrap()
        .unwrap();
    assert_eq!(&bin.payload[..4], b"MPF1", "binary frame magic");
    assert!(bin
        .headers
        .unwrap()
        .get(mouthpiece_nats::publish::SENT_HEADER)
        .is_some());
    let rig = next_json(&mut rig).await;
    assert_eq!(rig["character"], "wolf", "{rig}");
    hub.update_status(|s| s.calibrating = true);
    let seen = loop {
        let s = next_json(&mut status).await;
        if s["calibrating"] == true {
            break s;
        }
    };
    assert_eq!(seen["type"], "status", "{seen}");
    stop.store(true, Ordering::Relaxed);
    publisher.join().unwrap();
    let counters = hub.nats();
    assert!(counters.frames_published.load(Ordering::Relaxed) > 0);
    let metrics = hub.metrics_text();
    assert!(metrics.contains("mouthpiece_nats_connected 1"), "{metrics}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn control_over_request_reply_answers_like_the_websocket() {
    let server = NatsServer::start();
    let folder = tempfile::tempdir().unwrap();
    let hub = hub();
    let _link = start_link(&hub, vec![server.url()], folder.path()).await;
    let c = client(&[server.url()]).await;
    let ask = async |request: Value| -> Value {
        let reply = eventually(WAIT, async || {
            c.request("mouthpiece.b1.control", request.to_string().into())
                .await
                .ok()
        })
        .await
        .expect("no control reply");
        serde_json::from_slice(&reply.payload).unwrap()
    };
    let result = ask(json!({"type": "record", "action": "start", "slate": "s1", "id": 7})).await;
    assert_eq!(result["type"], "result", "{result}");
    assert_eq!(result["id"], 7, "{result}");
    assert_eq!(result["request"], "record", "{result}");
    assert_eq!(result["detail"]["slate"], "s1", "{result}");
    let failed = ask(json!({"type": "calibrate", "id": "c"})).await;
    assert_eq!(failed["type"], "error", "{failed}");
    assert_eq!(failed["code"], "control_failed", "{failed}");
    assert_eq!(failed["message"], "no performer seen", "{failed}");
    let unknown = ask(json!({"type": "look_at", "character": "cat", "point": null})).await;
    assert_eq!(unknown["code"], "bad_request", "{unknown}");
    // A ping is answered as on the WebSocket, with its id.
    let pong = ask(json!({"type": "ping", "id": 9})).await;
    assert_eq!(pong["type"], "pong", "{pong}");
    assert_eq!(pong["id"], 9, "{pong}");
    assert!(pong["server_wall_us"].as_i64().unwrap() > 0, "{pong}");
    let not_control = ask(json!({"type": "subscribe"})).await;
    assert_eq!(not_control["code"], "bad_request", "{not_control}");
    let bad = ask(json!("not an object")).await;
    assert_eq!(bad["type"], "error", "{bad}");
    assert!(hub.nats().control_requests.load(Ordering::Relaxed) >= 5);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_user_without_publish_permission_on_control_cannot_control() {
    let dir = tempfile::tempdir().unwrap();
    let conf = dir.path().join("nats.conf");
    std::fs::write(
        &conf,
        r#"
authorization {
  users = [
    { user: booth, password: booth-pw }
    { user: director, password: director-pw }
    { user: viewer, password: viewer-pw, permissions: {
        publish: { allow: ["_INBOX.>", "mouthpiece.*.hello"] }
        subscribe: { allow: [">"] }
    } }
  ]
}
"#,
    )
    .unwrap();
    let server = NatsServer::start_with(&["-c", conf.to_str().unwrap()]);
    let folder = tempfile::tempdir().unwrap();
    let hub = hub();
    let mut settings = NatsSettings::new(vec![server.url()], "b1");
    settings.auth = mouthpiece_nats::Auth::UserPassword {
        user: "booth".into(),
        password: mouthpiece_config::Secret::new("booth-pw"),
    };
    let _link = NatsLink::start(hub.clone(), settings, "t".into(), folder.path().to_owned())
        .await
        .unwrap();
    let connect = async |user: &str, password: &str| {
        async_nats::ConnectOptions::with_user_and_password(user.into(), password.into())
            .request_timeout(Some(Duration::from_secs(2)))
            .connect(server.url())
            .await
            .unwrap()
    };
    let director = connect("director", "director-pw").await;
    let request = json!({"type": "record", "action": "stop", "id": 1}).to_string();
    let answer = eventually(WAIT, async || {
        director
            .request("mouthpiece.b1.control", request.clone().into())
            .await
            .ok()
    })
    .await
    .expect("the director's control request was not answered");
    let answer: Value = serde_json::from_slice(&answer.payload).unwrap();
    assert_eq!(answer["type"], "result", "{answer}");
    let before = hub.nats().control_requests.load(Ordering::Relaxed);

    let viewer = connect("viewer", "viewer-pw").await;
    // The viewer reads (hello on request is allowed) ...
    let hello = viewer
        .request("mouthpiece.b1.hello", "".into())
        .await
        .unwrap();
    assert!(String::from_utf8_lossy(&hello.payload).contains("\"hello\""));
    // ... but a control request never reaches the booth.
    let refused = viewer
        .request("mouthpiece.b1.control", request.clone().into())
        .await;
    assert!(
        refused.is_err(),
        "the viewer's control request was answered"
    );
    assert_eq!(
        hub.nats().control_requests.load(Ordering::Relaxed),
        before,
        "the booth saw the viewer's request"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_the_broker_away_frames_are_dropped_and_counted_and_flow_again_after() {
    let mut server = NatsServer::start();
    let folder = tempfile::tempdir().unwrap();
    let hub = hub();
    let _link = start_link(&hub, vec![server.url()], folder.path()).await;
    let counters = hub.nats();
    let stop = Arc::new(AtomicBool::new(false));
    let publisher = publish_frames(hub.clone(), stop.clone());
    eventually(WAIT, async || {
        (counters.frames_published.load(Ordering::Relaxed) > 10).then_some(())
    })
    .await
    .expect("frames never published");
    server.kill();
    eventually(WAIT, async || {
        (!counters.connected.load(Ordering::Relaxed)).then_some(())
    })
    .await
    .expect("the link never noticed the broker went away");
    let dropped = counters.frames_dropped.load(Ordering::Relaxed);
    eventually(WAIT, async || {
        (counters.frames_dropped.load(Ordering::Relaxed) > dropped + 5).then_some(())
    })
    .await
    .expect("frames published while the broker is away are not counted as dropped");
    // Dropped, not queued to go out late: nothing more is handed to the client.
    let published = counters.frames_published.load(Ordering::Relaxed);
    let dropped = counters.frames_dropped.load(Ordering::Relaxed);
    eventually(WAIT, async || {
        (counters.frames_dropped.load(Ordering::Relaxed) > dropped + 20).then_some(())
    })
    .await
    .expect("frames stopped being counted while the broker is away");
    assert_eq!(
        counters.frames_published.load(Ordering::Relaxed),
        published,
        "frames were queued for the client while the broker was away"
    );
    assert_eq!(
        hub.nats().status().as_deref(),
        Some("NATS down (reconnecting)")
    );
    let health = hub.nats().health_json().unwrap();
    assert_eq!(health["connected"], false, "{health}");
    // The hub (the WebSocket side) kept publishing all along.
    let published = hub.frames_published();
    eventually(WAIT, async || {
        (hub.frames_published() > published + 10).then_some(())
    })
    .await
    .unwrap();

    server.restart();
    let sub = client(&[server.url()]).await;
    let mut frames = sub.subscribe("mouthpiece.b1.frame").await.unwrap();
    let frame = next_json(&mut frames).await;
    assert_eq!(frame["type"], "frame");
    assert!(counters.connected.load(Ordering::Relaxed));
    assert!(counters.connects.load(Ordering::Relaxed) >= 2);
    stop.store(true, Ordering::Relaxed);
    publisher.join().unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_booth_starts_without_its_broker_and_connects_when_it_comes() {
    // Nothing listens on this port yet.
    let port = harness::free_port();
    let url = format!("nats://127.0.0.1:{port}");
    let folder = tempfile::tempdir().unwrap();
    let hub = hub();
    let link = tokio::time::timeout(
        Duration::from_secs(5),
        start_link(&hub, vec![url.clone()], folder.path()),
    )
    .await
    .expect("the link waited for a broker that is not there");
    let counters = hub.nats();
    assert!(!counters.connected.load(Ordering::Relaxed));
    assert_eq!(
        hub.nats().status().as_deref(),
        Some("NATS down (reconnecting)")
    );
    let mut server = NatsServer::start_on(port);
    eventually(WAIT, async || {
        counters.connected.load(Ordering::Relaxed).then_some(())
    })
    .await
    .expect("the link never connected to the broker that came");
    server.kill();
    drop(link);
}
