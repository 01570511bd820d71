//! Real server messages checked against docs/schemas with Python's `jsonschema` (an
//! independent validator), and the Python example client run against a live server.
//! Python: `MOUTHPIECE_PYTHON`, else `python3`; it needs `jsonschema` and `websockets`
//! (scripts/packages/test-python.txt).

use crate::helper_common as common;

use std::io::Write;
use std::path::PathBuf;
use std::process::Command;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use common::*;
use futures_util::SinkExt;
use mouthpiece_server::{ControlCommand, ControlFailure, HubConfig, ServerConfig, Token};
use serde_json::{json, Value};
use tokio_tungstenite::tungstenite::Message;

fn python() -> String {
    std::env::var("MOUTHPIECE_PYTHON").unwrap_or_else(|_| "python3".into())
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

#[tokio::test]
async fn server_messages_match_the_published_schemas() {
    let config = ServerConfig {
        read_token: Some(Token::new("read-token-0123456789").unwrap()),
        control_token: Some(Token::new("control-token-0123456789").unwrap()),
        ..ServerConfig::default()
    };
    let mut server = TestServer::start_with(
        config,
        HubConfig {
            client_queue_frames: 4,
            ..HubConfig::default()
        },
    )
    .await;
    let mut control = server.control.take().unwrap();
    std::thread::spawn(move || {
        while let Some(r) = control.blocking_recv() {
            match r.command.clone() {
                ControlCommand::Calibrate { .. } => r.reply(Ok(json!({"frames": 30}))),
                ControlCommand::RecordStart { slate, take } => r.reply(Ok(json!({
                    "file": format!("{}_{}.mcap", slate.unwrap_or_default(), take.unwrap_or(1))
                }))),
                ControlCommand::RecordStop => r.reply(Err(ControlFailure::new("not recording"))),
                ControlCommand::LookAt { character, point } => r.reply(Ok(json!({
                    "character": character,
                    "point": point,
                    "mode": if point.is_some() { "look_at" } else { "follow" },
                    "in_reach": point.map(|_| true),
                }))),
                ControlCommand::TuneColours { apply, .. } => r.reply(if apply {
                    Err(ControlFailure::new("no proposal to apply"))
                } else {
                    Ok(json!({"sampling_s": 2.0}))
                }),
            }
        }
    });
    let mut log: Vec<Value> = Vec::new();
    let mut sent = Vec::new();
    let mut ws = connect(
        &server.url(),
        &["mouthpiece.v1", "mouthpiece.token.control-token-0123456789"],
    )
    .await
    .unwrap();
    let mut client_msgs = vec![
        json!({"type": "subscribe", "id": 1, "fields": ["curve", "performer", "rig"], "max_rate": 120, "format": "json"}),
        json!({"type": "ping", "id": "p"}),
        json!({"type": "calibrate", "id": 2, "duration_s": 1.0}),
        json!({"type": "record", "id": 3, "action": "start", "slate": "scene 4", "take": 2}),
        json!({"type": "record", "id": 4, "action": "stop"}),
        json!({"type": "subscribe", "id": 5, "characters": ["ghost"]}),
        json!({"type": "look_at", "id": 6, "character": "wolf", "point": [0.1, -0.2, 3.0]}),
        json!({"type": "look_at", "id": 7, "character": "wolf", "point": null}),
        json!({"type": "look_at", "id": 8, "character": "ghost", "point": [0, 0, 1]}),
    ];
    for m in &client_msgs {
        send_json(&mut ws, m.clone()).await;
        sent.push(m.clone());
    }
    ws.send(Message::text("{oops")).await.unwrap();
    ws.send(Message::text(r#"{"type":"dance"}"#)).await.unwrap();
    // Expect: hello, status, result(sub), pong, result(calibrate), result(record), error(stop),
    // error(ghost), result(look_at) twice, error(look_at ghost), error(bad_json),
    // error(unknown_type).
    let mut want_errors = 5;
    let mut want_results = 5;
    let mut pong = false;
    while want_errors + want_results > 0 || !pong {
        let v = next_json(&mut ws).await;
        match v["type"].as_str() {
            Some("error") => want_errors -= 1,
            Some("result") => want_results -= 1,
            Some("pong") => pong = true,
            _ => {}
        }
        log.push(v);
    }
    // Frames, a lag notice (burst beyond the 4-frame ring), status changes, a new hello.
    for i in 0..3 {
        server.publish(i);
    }
    let mut burst = mouthpiece_server::StreamFrame::default();
    for i in 3..40 {
        mouthpiece_server::loadgen::synthetic_frame(i, 60.0, &mut burst);
        burst.wall_us = None;
        server.hub.publish(&burst);
    }
    server.hub.update_status(|s| {
        s.calibrating = true;
        s.recording = Some(mouthpiece_server::Recording {
            slate: "scene 4".into(),
            take: 2,
            file: Some("takes/scene 4_2.mcap".into()),
            started_wall_us: Some(1_763_781_131_123_456),
        });
    });
    server
        .hub
        .set_info(mouthpiece_server::loadgen::synthetic_info(30.0));
    let mut frames = 0;
    let mut lagged = false;
    while frames < 3 || !lagged {
        let v = next_json(&mut ws).await;
        match v["type"].as_str() {
            Some("frame") => frames += 1,
            Some("status") if v.get("lagged").is_some() => lagged = true,
            _ => {}
        }
        log.push(v);
    }
    // A read-only client's forbidden error and a default (no optional fields) frame.
    let mut reader = connect(
        &format!("{}?token=read-token-0123456789", server.url()),
        &["mouthpiece.v1"],
    )
    .await
    .unwrap();
    let m = json!({"type": "calibrate"});
    send_json(&mut reader, m.clone()).await;
    client_msgs.push(m);
    log.push(next_of_type(&mut reader, "error").await);
    let m = json!({"type": "subscribe", "characters": ["wolf"]});
    send_json(&mut reader, m.clone()).await;
    client_msgs.push(m);
    log.push(next_of_type(&mut reader, "result").await);
    server.publish(100);
    log.push(next_of_type(&mut reader, "frame").await);

    // The console's messages: health, the calibration and take list in status, a preview
    // image (its overlay JSON is checked like a message).
    let mut console = connect(
        &server.url(),
        &["mouthpiece.v1", "mouthpiece.token.read-token-0123456789"],
    )
    .await
    .unwrap();
    for m in [
        json!({"type": "subscribe", "id": "c", "fields": ["health"]}),
        json!({"type": "preview", "id": "p", "max_rate": 5, "max_width": 160}),
    ] {
        send_json(&mut console, m.clone()).await;
        client_msgs.push(m);
    }
    client_msgs.push(json!({"type": "preview", "enable": false}));
    client_msgs.push(json!({"type": "tune_colours", "id": "t", "action": "run", "seconds": 2}));
    client_msgs.push(json!({"type": "tune_colours", "action": "apply"}));
    server.hub.set_health(mouthpiece_server::Health {
        fps: 30.0,
        dots_found: 0.99,
        processing_ms: 0.5,
        capture_to_publish_ms: 0.7,
        disk_free_mb: Some(5000),
        image: Some([320, 240]),
    });
    let (mut health, mut preview_result) = (false, false);
    while !(health && preview_result) {
        let v = next_json(&mut console).await;
        health |= v["type"] == "health";
        preview_result |= v["type"] == "result" && v["request"] == "preview";
        log.push(v);
    }
    server
        .hub
        .set_calibration(mouthpiece_server::CalibrationReport {
            wall_us: 1_763_781_131_123_456,
            frames: 30,
            mouth_width_mm: 52.5,
            lip_wobble_mm: 0.21,
        });
    server.hub.add_take(mouthpiece_server::TakeSummary {
        slate: "scene 4".into(),
        take: 2,
        file: "takes/scene 4_T002.mcap".into(),
        frames: 120,
        seconds: 4.0,
        error: None,
    });
    server.hub.update_status(|s| {
        s.audio = mouthpiece_server::AudioStatus {
            state: mouthpiece_server::AudioState::Live,
            device: "default".into(),
            sample_rate: 48000,
            channels: 1,
            level_dbfs: -23.5,
            peak_dbfs: -6.0,
            clip: false,
            overruns: 0,
            dropped_blocks: 0,
        }
    });
    let class = |per_frame: f64| mouthpiece_server::TuneClass {
        name: "lip".into(),
        role: "lip".into(),
        hue: vec![[0, 8], [172, 179]],
        saturation: [100, 255],
        value: [40, 255],
        per_frame,
    };
    server.hub.set_tune(Some(mouthpiece_server::TuneReport {
        state: "done".into(),
        message: "not offered".into(),
        frames: 30,
        in_use: Some(mouthpiece_server::TuneFound {
            share: 1.0,
            per_frame: 15.0,
            dots: 15,
            classes: vec![class(12.0)],
        }),
        proposed: Some(mouthpiece_server::TuneFound {
            share: 0.73,
            per_frame: 11.0,
            dots: 15,
            classes: vec![class(8.0)],
        }),
        offered: false,
        toml: Some("[[detect.class]]\n".into()),
    }));
    loop {
        let v = next_of_type(&mut console, "status").await;
        let done = v.get("takes").is_some()
            && v.get("calibration").is_some()
            && v["audio"]["state"] == "live"
            && v.get("tune").is_some();
        log.push(v);
        if done {
            break;
        }
    }
    let image = std::sync::Arc::new(mouthpiece_server::preview::OwnedBgr {
        width: 320,
        height: 240,
        data: vec![90; 320 * 240 * 3],
    });
    let overlay_json = 'image: loop {
        server.hub.offer_preview(mouthpiece_server::PreviewInput {
            seq: 7,
            t: 1.0,
            capture_us: 1_000_000,
            wall_us: None,
            image: image.clone(),
            overlay: mouthpiece_server::Overlay {
                dots: vec![mouthpiece_server::ImageDot {
                    name: "D1".into(),
                    x: 10.0,
                    y: 20.0,
                    state: mouthpiece_server::DotState::Predicted,
                }],
                search: vec![
                    mouthpiece_server::PixelBox {
                        x: 0.0,
                        y: 0.0,
                        width: 50.0,
                        height: 40.0,
                    },
                    mouthpiece_server::PixelBox {
                        x: 0.0,
                        y: 60.0,
                        width: 50.0,
                        height: 30.0,
                    },
                ],
            },
        });
        let deadline = std::time::Instant::now() + Duration::from_millis(500);
        while std::time::Instant::now() < deadline {
            use futures_util::StreamExt;
            let Ok(Some(Ok(m))) =
                tokio::time::timeout(Duration::from_millis(100), console.next()).await
            else {
                continue;
            };
            if let Message::Binary(b) = m {
                assert_eq!(&b[..4], b"MPP1");
                assert_eq!(
                    u16::from_le_bytes([b[40], b[41]]),
                    160,
                    "downscaled to max_width"
                );
                let len = u32::from_le_bytes(b[48..52].try_into().unwrap()) as usize;
                break 'image serde_json::from_slice::<Value>(&b[56..56 + len]).unwrap();
            }
        }
    };
    log.push(overlay_json);
    server.stop().await;

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("messages.jsonl");
    let mut file = std::fs::File::create(&path).unwrap();
    for m in &log {
        writeln!(file, "{}", json!({"dir": "server", "msg": m})).unwrap();
    }
    for m in &client_msgs {
        writeln!(file, "{}", json!({"dir": "client", "msg": m})).unwrap();
    }
    drop(file);
    let out = Command::new(python())
        .arg(repo().join("crates/server/tests/validate_schemas.py"))
        .arg(repo().join("docs/schemas"))
        .arg(&path)
        .output()
        .expect("running Python (set MOUTHPIECE_PYTHON)");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{stdout}");
    assert!(
        out.status.success(),
        "schema validation failed:\n{stdout}\n{stderr}"
    );
}

/// Every JSON example in the docs (the ```json blocks' messages) is valid under the published
/// schemas: field names, types and enum spellings as the wire has them.
#[test]
fn the_docs_examples_match_the_published_schemas() {
    let mut pages: Vec<PathBuf> = std::fs::read_dir(repo().join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    pages.sort();
    pages.push(repo().join("README.md"));
    let out = Command::new(python())
        .arg(repo().join("crates/server/tests/validate_schemas.py"))
        .arg(repo().join("docs/schemas"))
        .arg("--docs")
        .args(&pages)
        .output()
        .expect("running Python (set MOUTHPIECE_PYTHON)");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "a docs example does not match its schema:\n{stdout}\n{stderr}"
    );
    // The protocol page's examples are among them.
    for kind in ["hello 1", "frame 1", "status 2", "pong 1"] {
        assert!(stdout.contains(kind), "{stdout}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_python_example_client_receives_frames() {
    let server = TestServer::start(ServerConfig::default()).await;
    let stop = Arc::new(AtomicBool::new(false));
    let publisher = mouthpiece_server::loadgen::spawn_publisher(
        server.hub.clone(),
        60.0,
        u64::MAX,
        stop.clone(),
    );
    let url = server.url();
    let out = tokio::task::spawn_blocking(move || {
        Command::new(python())
            .arg(repo().join("examples/client.py"))
            .args([url.as_str(), "--character", "wolf", "--count", "20"])
            .output()
    })
    .await
    .unwrap()
    .expect("running Python (set MOUTHPIECE_PYTHON)");
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let _ = tokio::time::timeout(
        Duration::from_secs(2),
        tokio::task::spawn_blocking(move || publisher.join()),
    )
    .await;
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "client.py failed:\n{stdout}\n{stderr}"
    );
    assert!(stdout.starts_with("connected to mouthpiece"), "{stdout}");
    let frames: Vec<&str> = stdout.lines().filter(|l| l.starts_with("frame ")).collect();
    assert_eq!(frames.len(), 20, "{stdout}");
    assert!(
        frames.iter().all(|l| l.contains(" wolf: 12 points")),
        "{stdout}"
    );
    assert!(!stdout.contains("lost"), "{stdout}");
    server.stop().await;
}
