//! `mouthpiece.v1` end to end against a real server on 127.0.0.1:0.

use crate::helper_common as common;

use std::time::Duration;

use common::*;
use futures_util::{SinkExt, StreamExt};
use mouthpiece_server::{
    ControlCommand, ControlFailure, HubConfig, Limits, Recording, ServerConfig, SourceState, Token,
};
use serde_json::json;
use tokio_tungstenite::tungstenite::Message;

#[tokio::test]
async fn hello_then_frames_in_order_after_subscribe() {
    let server = TestServer::start(ServerConfig::default()).await;
    let mut ws = connect_v1(&server.url()).await;
    let hello = next_json(&mut ws).await;
    assert_eq!(hello["type"], "hello");
    assert_eq!(hello["protocol"], "mouthpiece.v1");
    assert_eq!(hello["characters"][1]["name"], "wolf");
    assert_eq!(
        hello["characters"][0]["points"].as_array().unwrap().len(),
        12
    );
    assert_eq!(hello["characters"][0]["m"].as_array().unwrap().len(), 12);
    assert_eq!(hello["frame_rate"], 60.0);
    assert_eq!(hello["access"], "control");
    assert_eq!(hello["timecode_rate"], "30");
    let status = next_json(&mut ws).await;
    assert_eq!(status["type"], "status");
    assert_eq!(status["source"], "up");

    // Frames before the subscription are not sent.
    server.publish(0);
    send_json(&mut ws, json!({"type": "subscribe", "id": "s1"})).await;
    let result = next_of_type(&mut ws, "result").await;
    assert_eq!(result["id"], "s1");
    assert_eq!(result["detail"]["characters"], json!(["human", "wolf"]));
    for i in 1..=5 {
        server.publish(i);
    }
    for expected in 1..=5u64 {
        let f = next_of_type(&mut ws, "frame").await;
        assert_eq!(f["seq"], expected);
        assert_eq!(f["characters"].as_array().unwrap().len(), 2);
        assert_eq!(f["characters"][0]["points"].as_array().unwrap().len(), 12);
        assert!(
            f["characters"][0].get("curve").is_none(),
            "curve only on request"
        );
        assert!(f.get("performer").is_none(), "performer only on request");
        assert_eq!(f["head"]["rotation"].as_array().unwrap().len(), 4);
        assert!(f["wall_us"].as_i64().unwrap() > 0);
        let tc = f["timecode"].as_str().unwrap();
        assert_eq!(tc.len(), 11, "{tc}");
        assert!((f["t"].as_f64().unwrap() - expected as f64 / 60.0).abs() < 1e-9);
    }
    server.stop().await;
}

#[tokio::test]
async fn subscription_selects_characters_fields_and_rate() {
    let server = TestServer::start(ServerConfig::default()).await;
    let mut ws = connect_v1(&server.url()).await;
    send_json(
        &mut ws,
        json!({"type": "subscribe", "characters": ["wolf"], "fields": ["curve", "performer"], "max_rate": 30}),
    )
    .await;
    next_of_type(&mut ws, "result").await;
    for i in 0..10 {
        server.publish(i);
    }
    let mut seqs = Vec::new();
    for _ in 0..5 {
        let f = next_of_type(&mut ws, "frame").await;
        assert_eq!(f["characters"].as_array().unwrap().len(), 1);
        assert_eq!(f["characters"][0]["name"], "wolf");
        assert_eq!(f["characters"][0]["curve"].as_array().unwrap().len(), 48);
        assert_eq!(f["performer"]["points"].as_array().unwrap().len(), 12);
        seqs.push(f["seq"].as_u64().unwrap());
    }
    assert_eq!(seqs, [0, 2, 4, 6, 8], "60 fps decimated to 30");

    send_json(
        &mut ws,
        json!({"type": "subscribe", "id": 3, "characters": ["dragon"]}),
    )
    .await;
    let e = next_of_type(&mut ws, "error").await;
    assert_eq!(e["code"], "bad_request");
    assert_eq!(e["id"], 3);
    assert!(e["message"].as_str().unwrap().contains("dragon"));
    server.stop().await;
}

/// The next binary message (frames; previews are not asked for here).
async fn next_binary(ws: &mut Client) -> Vec<u8> {
    loop {
        match tokio::time::timeout(Duration::from_secs(5), ws.next())
            .await
            .unwrap()
            .unwrap()
            .unwrap()
        {
            Message::Binary(b) => break b.to_vec(),
            _ => continue,
        }
    }
}

/// Decodes the documented binary layout (docs/protocol.md) independently of the encoder,
/// checking every field against the published frame; `rig_curves` is `hello.rig_curves`.
fn check_binary_frame(
    bytes: &[u8],
    expected: &mouthpiece_server::StreamFrame,
    with_rig: bool,
    rig_curves: &[serde_json::Value],
    rig_visemes: &[serde_json::Value],
) {
    let u16_at = |o: usize| u16::from_le_bytes([bytes[o], bytes[o + 1]]);
    let u64_at = |o: usize| u64::from_le_bytes(bytes[o..o + 8].try_into().unwrap());
    let f32_at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    assert_eq!(&bytes[0..4], b"MPF1");
    assert_eq!(u16_at(4), 2);
    let rig_flag = if with_rig { 32 } else { 0 };
    assert_eq!(
        u16_at(6),
        2 | 4 | 8 | 16 | rig_flag,
        "curve, performer, wall clock, heads, rig"
    );
    assert_eq!(
        f64::from_le_bytes(bytes[16..24].try_into().unwrap()),
        expected.t
    );
    assert_eq!(u64_at(24), expected.capture_us);
    assert_eq!(u64_at(32) as i64, expected.wall_us.unwrap());
    assert_eq!(u16_at(44), 2);
    assert!((f32_at(48) as f64 - expected.head.pose.rotation[0]).abs() < 1e-6);
    assert!((f32_at(48 + 24) as f64 - expected.head.pose.translation[2]).abs() < 1e-6);
    let mut o = 76;
    for (index, c) in expected.characters.iter().enumerate() {
        assert_eq!(u16_at(o) as usize, index);
        assert_eq!(u16_at(o + 2), 12);
        o += 4;
        for p in &c.points {
            for v in p {
                assert_eq!(f32_at(o), *v);
                o += 4;
            }
        }
        o += 4 * 12; // confidence
        let k = u16_at(o) as usize;
        assert_eq!(k, 48);
        o += 4 + k * 12;
        // The head block.
        let head = c.head.as_ref().expect("the synthetic frame drives heads");
        assert_eq!(bytes[o], 1, "head present");
        assert_eq!(bytes[o + 1], 0, "follow");
        assert_eq!(bytes[o + 2], 0xFF, "in_reach null while following");
        assert_eq!(bytes[o + 3], c.source.code(), "mouth source");
        o += 4;
        for q in [head.rotation, head.eye_left, head.eye_right] {
            for v in q {
                assert_eq!(f32_at(o), v);
                o += 4;
            }
        }
        assert_eq!(f32_at(o), head.progress);
        o += 4;
        if with_rig {
            let rig = c.rig.as_ref().expect("the synthetic frame has a rig");
            assert_eq!(u16_at(o), 1, "rig present");
            assert_eq!(u16_at(o + 2) as usize, rig_curves.len());
            assert_eq!(u16_at(o + 4) as usize, rig_visemes.len());
            o += 8;
            assert_eq!(f32_at(o), rig.jaw.angle_deg);
            assert_eq!(f32_at(o + 4), rig.jaw.slide_m);
            o += 8;
            for lip in [&rig.lips.upper, &rig.lips.lower] {
                assert_eq!(f32_at(o), lip.rotation[0]);
                assert_eq!(f32_at(o + 16), lip.translation[0]);
                assert_eq!(f32_at(o + 28), lip.residual);
                o += 32;
            }
            for name in rig_curves {
                let name = name.as_str().unwrap();
                assert_eq!(f32_at(o), rig.curve(name).unwrap(), "{name}");
                o += 4;
            }
            for (i, name) in rig_visemes.iter().enumerate() {
                assert_eq!(f32_at(o), rig.visemes.0[i], "{name}");
                o += 4;
            }
        }
    }
    assert_eq!(u16_at(o), 12);
    o += 4;
    assert_eq!(f32_at(o), expected.performer.as_ref().unwrap().points[0][0]);
    o += 12 * 12 + 12 * 4;
    assert_eq!(o, bytes.len());
}

/// Binary frames, with and without the rig, decoded from the documented table.
#[tokio::test]
async fn binary_frames_follow_the_documented_layout() {
    let server = TestServer::start(ServerConfig::default()).await;
    let mut ws = connect_v1(&server.url()).await;
    let hello = next_of_type(&mut ws, "hello").await;
    let rig_curves = hello["rig_curves"].as_array().unwrap().clone();
    assert_eq!(rig_curves[0], "jawOpen");
    let rig_visemes = hello["rig_visemes"].as_array().unwrap().clone();
    assert_eq!(rig_visemes, ["aa", "ih", "ou", "ee", "oh"]);
    let mut expected = mouthpiece_server::StreamFrame::default();
    mouthpiece_server::loadgen::synthetic_frame(7, 60.0, &mut expected);
    for with_rig in [false, true] {
        let mut fields = vec!["curve", "performer"];
        if with_rig {
            fields.push("rig");
        }
        send_json(
            &mut ws,
            json!({"type": "subscribe", "format": "binary", "fields": fields}),
        )
        .await;
        next_of_type(&mut ws, "result").await;
        server.hub.publish(&expected);
        let bytes = next_binary(&mut ws).await;
        check_binary_frame(&bytes, &expected, with_rig, &rig_curves, &rig_visemes);
    }
    server.stop().await;
}

#[tokio::test]
async fn status_and_hello_follow_the_daemon() {
    let server = TestServer::start(ServerConfig::default()).await;
    let mut ws = connect_v1(&server.url()).await;
    next_of_type(&mut ws, "status").await;
    server.hub.update_status(|s| {
        s.source = SourceState::Down;
        s.message = Some("camera unplugged".into());
    });
    let s = next_of_type(&mut ws, "status").await;
    assert_eq!(s["source"], "down");
    assert_eq!(s["message"], "camera unplugged");
    server.hub.update_status(|s| {
        s.source = SourceState::Up;
        s.message = None;
        s.recording = Some(Recording {
            slate: "scene4".into(),
            take: 2,
            ..Recording::default()
        });
    });
    let s = next_of_type(&mut ws, "status").await;
    assert_eq!(s["recording"]["take"], 2);
    let mut info = mouthpiece_server::loadgen::synthetic_info(30.0);
    info.characters.truncate(1);
    server.hub.set_info(info);
    let h = next_of_type(&mut ws, "hello").await;
    assert_eq!(h["characters"].as_array().unwrap().len(), 1);
    assert_eq!(h["frame_rate"], 30.0);
    send_json(&mut ws, json!({"type": "ping", "id": 9})).await;
    let p = next_of_type(&mut ws, "pong").await;
    assert_eq!(p["id"], 9);
    server.stop().await;
}

#[tokio::test]
async fn control_requests_reach_the_daemon_and_answers_come_back() {
    let mut server = TestServer::start(ServerConfig::default()).await;
    let mut control = server.control.take().unwrap();
    // The daemon's side, on a plain thread like the processing loop.
    let daemon = std::thread::spawn(move || {
        let mut seen = Vec::new();
        while let Some(request) = control.blocking_recv() {
            seen.push(request.command.clone());
            match request.command.clone() {
                ControlCommand::RecordStart { slate, take } => {
                    let slate = slate.unwrap_or_default();
                    request.reply(Ok(
                        json!({"file": format!("{slate}_take{}.mcap", take.unwrap_or(1))}),
                    ))
                }
                ControlCommand::RecordStop => {
                    request.reply(Err(ControlFailure::new("not recording")))
                }
                ControlCommand::Calibrate { .. } => request.reply(Ok(json!({"frames": 30}))),
                ControlCommand::LookAt { character, point } => request.reply(Ok(
                    json!({"character": character, "point": point, "in_reach": true}),
                )),

                ControlCommand::TuneColours { .. } => request.reply(Ok(json!({"sampling_s": 2.0}))),
            }
            if seen.len() == 4 {
                return seen;
            }
        }
        seen
    });
    let mut ws = connect_v1(&server.url()).await;
    send_json(
        &mut ws,
        json!({"type": "record", "id": 1, "action": "start", "slate": "scene4", "take": 3}),
    )
    .await;
    let r = next_of_type(&mut ws, "result").await;
    assert_eq!(r["id"], 1);
    assert_eq!(r["request"], "record");
    assert_eq!(r["detail"]["file"], "scene4_take3.mcap");
    send_json(
        &mut ws,
        json!({"type": "record", "id": 2, "action": "stop"}),
    )
    .await;
    let e = next_of_type(&mut ws, "error").await;
    assert_eq!(
        (e["id"].as_i64(), e["code"].as_str()),
        (Some(2), Some("control_failed"))
    );
    assert_eq!(e["message"], "not recording");
    send_json(
        &mut ws,
        json!({"type": "calibrate", "id": "c", "duration_s": 1.0}),
    )
    .await;
    let r = next_of_type(&mut ws, "result").await;
    assert_eq!(r["detail"]["frames"], 30);
    // look_at: an unknown character and a point JSON cannot hold never reach the daemon.
    send_json(
        &mut ws,
        json!({"type": "look_at", "id": 10, "character": "ghost", "point": [0, 0, 1]}),
    )
    .await;
    let e = next_of_type(&mut ws, "error").await;
    assert_eq!(
        (e["id"].as_i64(), e["code"].as_str()),
        (Some(10), Some("bad_request"))
    );
    assert!(e["message"].as_str().unwrap().contains("ghost"), "{e}");
    ws.send(tokio_tungstenite::tungstenite::Message::text(
        r#"{"type":"look_at","id":11,"character":"wolf","point":[1e999,0,0]}"#,
    ))
    .await
    .unwrap();
    let e = next_of_type(&mut ws, "error").await;
    assert!(
        matches!(e["code"].as_str(), Some("bad_json" | "bad_request")),
        "{e}"
    );
    send_json(
        &mut ws,
        json!({"type": "look_at", "id": 12, "character": "wolf", "point": [0.1, 0.2, 3.0]}),
    )
    .await;
    let r = next_of_type(&mut ws, "result").await;
    assert_eq!(
        (r["id"].as_i64(), r["request"].as_str()),
        (Some(12), Some("look_at"))
    );
    assert_eq!(r["detail"]["in_reach"], true);
    let seen = daemon.join().unwrap();
    assert_eq!(
        seen[3],
        ControlCommand::LookAt {
            character: "wolf".into(),
            point: Some([0.1, 0.2, 3.0])
        }
    );
    assert_eq!(
        seen[2],
        ControlCommand::Calibrate {
            duration: Some(Duration::from_secs(1))
        }
    );
    // The daemon's receiver is gone now: requests get `unavailable`.
    send_json(&mut ws, json!({"type": "calibrate", "id": "d"})).await;
    let e = next_of_type(&mut ws, "error").await;
    assert_eq!(e["code"], "unavailable");
    server.stop().await;
}

#[tokio::test]
async fn control_needs_the_control_token_and_unanswered_requests_time_out() {
    let config = ServerConfig {
        read_token: Some(Token::new("read-token-0123456789").unwrap()),
        control_token: Some(Token::new("control-token-0123456789").unwrap()),
        limits: Limits {
            control_timeout: Duration::from_millis(300),
            ..Limits::default()
        },
        ..ServerConfig::default()
    };
    let server = TestServer::start(config).await;
    let mut reader = connect(
        &server.url(),
        &["mouthpiece.v1", "mouthpiece.token.read-token-0123456789"],
    )
    .await
    .unwrap();
    assert_eq!(next_json(&mut reader).await["access"], "read");
    send_json(&mut reader, json!({"type": "calibrate", "id": 5})).await;
    let e = next_of_type(&mut reader, "error").await;
    assert_eq!(e["code"], "forbidden");
    assert_eq!(e["id"], 5);
    send_json(
        &mut reader,
        json!({"type": "look_at", "id": 15, "character": "ghost", "point": null}),
    )
    .await;
    let e = next_of_type(&mut reader, "error").await;
    assert_eq!(
        (e["code"].as_str(), e["id"].as_i64()),
        (Some("forbidden"), Some(15))
    );
    // A read client may still subscribe.
    send_json(&mut reader, json!({"type": "subscribe"})).await;
    next_of_type(&mut reader, "result").await;

    let mut controller = connect(
        &format!("{}?token=control-token-0123456789", server.url()),
        &["mouthpiece.v1"],
    )
    .await
    .unwrap();
    assert_eq!(next_json(&mut controller).await["access"], "control");
    // Nobody answers on the daemon side (the receiver is held but not read).
    send_json(
        &mut controller,
        json!({"type": "record", "id": 6, "action": "start"}),
    )
    .await;
    let e = next_of_type(&mut controller, "error").await;
    assert_eq!(
        (e["code"].as_str(), e["id"].as_i64()),
        (Some("timeout"), Some(6))
    );
    server.stop().await;
}

#[tokio::test]
async fn bad_messages_get_errors_and_the_stream_goes_on() {
    let server = TestServer::start(ServerConfig::default()).await;
    let mut ws = connect_v1(&server.url()).await;
    send_json(&mut ws, json!({"type": "subscribe"})).await;
    next_of_type(&mut ws, "result").await;
    let cases: [(&str, &str); 6] = [
        ("{not json", "bad_json"),
        ("[1,2,3]", "unknown_type"),
        (r#"{"type":"teleport","id":4}"#, "unknown_type"),
        (r#"{"type":"record","action":"rewind"}"#, "bad_request"),
        (r#"{"type":"subscribe","max_rate":"fast"}"#, "bad_request"),
        (r#"{"type":"calibrate","duration_s":1e9}"#, "bad_request"),
    ];
    for (i, (text, code)) in cases.iter().enumerate() {
        ws.send(Message::text(*text)).await.unwrap();
        server.publish(i as u64);
        // The error and the frame may come in either order.
        let (mut error, mut frame) = (None, None);
        while error.is_none() || frame.is_none() {
            let v = next_json(&mut ws).await;
            match v["type"].as_str() {
                Some("error") => error = Some(v),
                Some("frame") => frame = Some(v),
                _ => {}
            }
        }
        assert_eq!(error.unwrap()["code"], *code, "for {text}");
        assert_eq!(frame.unwrap()["seq"], i as u64);
    }
    ws.send(Message::binary(vec![1, 2, 3])).await.unwrap();
    assert_eq!(
        next_of_type(&mut ws, "error").await["code"],
        "unsupported_binary"
    );
    server.stop().await;
}

#[tokio::test]
async fn oversized_messages_close_only_the_sender() {
    let server = TestServer::start(ServerConfig::default()).await;
    let mut good = connect_v1(&server.url()).await;
    send_json(&mut good, json!({"type": "subscribe"})).await;
    next_of_type(&mut good, "result").await;
    let mut bad = connect_v1(&server.url()).await;
    let huge = format!(r#"{{"type":"ping","pad":"{}"}}"#, "x".repeat(70 * 1024));
    let _ = bad.send(Message::text(huge)).await;
    let (code, reason) = expect_close(&mut bad).await;
    assert_eq!(code, 1009, "{reason}");
    assert!(reason.contains("65536"), "{reason}");
    server.publish(0);
    assert_eq!(next_of_type(&mut good, "frame").await["seq"], 0);
    server.stop().await;
}

#[tokio::test]
async fn message_floods_are_rate_limited_then_closed() {
    let config = ServerConfig {
        limits: Limits {
            max_messages_per_second: 10,
            ..Limits::default()
        },
        ..ServerConfig::default()
    };
    let server = TestServer::start(config).await;
    let mut ws = connect_v1(&server.url()).await;
    for _ in 0..15 {
        ws.send(Message::text(r#"{"type":"ping"}"#)).await.unwrap();
    }
    let mut pongs = 0;
    let mut limited = 0;
    while pongs + limited < 15 {
        let v = next_json(&mut ws).await;
        match v["type"].as_str() {
            Some("pong") => pongs += 1,
            Some("error") => {
                assert_eq!(v["code"], "rate_limited");
                limited += 1
            }
            _ => {}
        }
    }
    assert!((10..=11).contains(&pongs), "{pongs} pongs");
    for _ in 0..40 {
        if ws.send(Message::text(r#"{"type":"ping"}"#)).await.is_err() {
            break;
        }
    }
    let (code, reason) = expect_close(&mut ws).await;
    assert_eq!(code, 1008, "{reason}");
    assert!(reason.contains("too many messages"), "{reason}");
    server.stop().await;
}

#[tokio::test]
async fn a_slow_client_is_told_it_lagged_and_closed_past_the_limit() {
    let config = ServerConfig {
        limits: Limits {
            max_dropped_frames: 50,
            ..Limits::default()
        },
        ..ServerConfig::default()
    };
    let server = TestServer::start_with(
        config,
        HubConfig {
            client_queue_frames: 8,
            ..HubConfig::default()
        },
    )
    .await;
    let mut ws = connect_v1(&server.url()).await;
    send_json(&mut ws, json!({"type": "subscribe"})).await;
    next_of_type(&mut ws, "result").await;
    // A burst the client cannot have read yet: the ring overruns.
    for i in 0..30 {
        server.publish(i);
    }
    let mut lagged = 0;
    let mut frames = 0;
    while lagged + frames < 30 {
        let v = next_json(&mut ws).await;
        match v["type"].as_str() {
            Some("status") => lagged += v["lagged"].as_u64().unwrap_or(0),
            Some("frame") => frames += 1,
            _ => {}
        }
    }
    assert!(lagged > 0, "the burst overran the ring");
    for i in 30..200 {
        server.publish(i);
    }
    let (code, reason) = expect_close(&mut ws).await;
    assert_eq!(code, 1008);
    assert!(reason.starts_with("too slow: lost"), "{reason}");
    assert!(server
        .hub
        .metrics_text()
        .contains("mouthpiece_clients_closed_slow_total 1"));
    server.stop().await;
}

#[tokio::test]
async fn shutdown_closes_clients_with_1001() {
    let server = TestServer::start(ServerConfig::default()).await;
    let mut ws = connect_v1(&server.url()).await;
    next_of_type(&mut ws, "hello").await;
    let stopping = tokio::spawn(server.stop());
    let (code, reason) = expect_close(&mut ws).await;
    assert_eq!((code, reason.as_str()), (1001, "server shutting down"));
    stopping.await.unwrap();
}

#[tokio::test]
async fn clients_without_a_subprotocol_get_mouthpiece_v1() {
    let server = TestServer::start(ServerConfig::default()).await;
    let mut ws = connect(&server.url(), &[]).await.unwrap();
    assert_eq!(next_json(&mut ws).await["protocol"], "mouthpiece.v1");
    server.stop().await;
}
