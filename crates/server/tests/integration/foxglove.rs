//! The Foxglove WebSocket protocol (foxglove.websocket.v1), checked with a client written
//! from foxglove/ws-protocol docs/spec.md: serverInfo, advertise, subscribe, Message Data,
//! unsubscribe, status; payloads validated against the advertised JSON Schemas (Python
//! `jsonschema`).

use crate::helper_common as common;

use std::process::Command;
use std::time::Duration;

use common::*;
use futures_util::{SinkExt, StreamExt};
use mouthpiece_server::ServerConfig;
use serde_json::{json, Value};
use tokio_tungstenite::tungstenite::Message;

/// The next message: text as JSON, or binary Message Data split into (subscription, timestamp, payload).
enum Fox {
    Json(Value),
    Data(u32, u64, Value),
}

async fn next(ws: &mut Client) -> Fox {
    loop {
        let m = tokio::time::timeout(Duration::from_secs(5), ws.next())
            .await
            .expect("a message within 5 s")
            .unwrap()
            .unwrap();
        match m {
            Message::Text(t) => return Fox::Json(serde_json::from_str(&t).unwrap()),
            Message::Binary(b) => {
                assert_eq!(b[0], 0x01, "opcode Message Data");
                let sub = u32::from_le_bytes(b[1..5].try_into().unwrap());
                let ts = u64::from_le_bytes(b[5..13].try_into().unwrap());
                return Fox::Data(sub, ts, serde_json::from_slice(&b[13..]).unwrap());
            }
            _ => continue,
        }
    }
}

async fn next_json_op(ws: &mut Client, op: &str) -> Value {
    loop {
        if let Fox::Json(v) = next(ws).await {
            if v["op"] == op {
                return v;
            }
        }
    }
}

#[tokio::test]
async fn foxglove_clients_list_subscribe_and_receive_channels() {
    let server = TestServer::start(ServerConfig::default()).await;
    let mut ws = connect(&server.url(), &["foxglove.websocket.v1"])
        .await
        .unwrap();
    let info = next_json_op(&mut ws, "serverInfo").await;
    assert_eq!(info["name"], "mouthpiece");
    assert!(info["capabilities"].is_array());
    let adv = next_json_op(&mut ws, "advertise").await;
    let channels = adv["channels"].as_array().unwrap();
    let topics: Vec<&str> = channels
        .iter()
        .map(|c| c["topic"].as_str().unwrap())
        .collect();
    assert_eq!(
        topics,
        [
            "/head",
            "/performer",
            "/camera/image",
            "/camera/annotations",
            "/scene",
            "/tf",
            "/character/human",
            "/character/wolf",
            "/rig/human",
            "/rig/wolf"
        ]
    );
    let mut schemas = serde_json::Map::new();
    for c in channels {
        assert_eq!(c["encoding"], "json");
        assert_eq!(c["schemaEncoding"], "jsonschema");
        let schema: Value = serde_json::from_str(c["schema"].as_str().unwrap()).unwrap();
        assert_eq!(schema["type"], "object");
        schemas.insert(c["id"].to_string(), schema);
    }
    let id_of = |topic: &str| {
        channels.iter().find(|c| c["topic"] == topic).unwrap()["id"]
            .as_u64()
            .unwrap()
    };
    let subscribe = json!({"op": "subscribe", "subscriptions": [
        {"id": 7, "channelId": id_of("/character/wolf")},
        {"id": 8, "channelId": id_of("/head")},
        {"id": 9, "channelId": id_of("/performer")},
        {"id": 10, "channelId": id_of("/rig/wolf")},
    ]});
    ws.send(Message::text(subscribe.to_string())).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let mut payloads = Vec::new();
    for i in 0..3 {
        server.publish(i);
    }
    let mut seen = std::collections::BTreeMap::new();
    while seen.values().sum::<u32>() < 12 {
        if let Fox::Data(sub, ts, payload) = next(&mut ws).await {
            assert!(ts > 1_600_000_000_000_000_000, "wall-clock nanoseconds");
            *seen.entry(sub).or_insert(0) += 1;
            let channel = match sub {
                7 => id_of("/character/wolf"),
                8 => id_of("/head"),
                9 => id_of("/performer"),
                10 => id_of("/rig/wolf"),
                other => panic!("unknown subscription {other}"),
            };
            payloads.push(json!({"schema": schemas[&channel.to_string()], "payload": payload}));
        }
    }
    assert_eq!(
        seen.into_iter().collect::<Vec<_>>(),
        [(7, 3), (8, 3), (9, 3), (10, 3)]
    );
    let wolf = payloads
        .iter()
        .find(|p| p["payload"]["name"] == "wolf")
        .unwrap();
    assert_eq!(wolf["payload"]["points"].as_array().unwrap().len(), 12);
    assert!(wolf["payload"]["points"][0]["x"].is_number());
    // Which source drove the mouth, as the frame says, and the schema requires it.
    let mut frame = mouthpiece_server::StreamFrame::default();
    mouthpiece_server::loadgen::synthetic_frame(
        wolf["payload"]["seq"].as_u64().unwrap(),
        60.0,
        &mut frame,
    );
    assert_eq!(
        wolf["payload"]["source"],
        frame.characters[1].source.as_str(),
        "{wolf}"
    );
    assert!(wolf["schema"]["required"]
        .as_array()
        .unwrap()
        .contains(&json!("source")));
    // The rig channel carries the published frame's rig: jaw and every curve by name.
    let rig_schema = &schemas[&id_of("/rig/wolf").to_string()];
    let curve_names = rig_schema["properties"]["curves"]["required"]
        .as_array()
        .unwrap();
    assert_eq!(curve_names.len(), 27, "{rig_schema}");
    let mut rigs = 0;
    for p in payloads.iter().filter(|p| p["schema"] == *rig_schema) {
        let p = &p["payload"];
        assert_eq!(p["name"], "wolf");
        let mut frame = mouthpiece_server::StreamFrame::default();
        mouthpiece_server::loadgen::synthetic_frame(p["seq"].as_u64().unwrap(), 60.0, &mut frame);
        let rig = frame.characters[1].rig.unwrap();
        assert_eq!(p["jaw"]["angle_deg"], json!(rig.jaw.angle_deg), "{p}");
        assert_eq!(p["jaw"]["slide_m"], json!(rig.jaw.slide_m), "{p}");
        for (k, name) in mouthpiece_server::CURVE_NAMES.iter().enumerate() {
            assert_eq!(curve_names[k], *name);
            assert_eq!(p["curves"][*name], json!(rig.curves.0[k]), "{name}: {p}");
        }
        assert_eq!(p["lips"]["lower"]["rotation"]["w"], 1.0, "{p}");
        rigs += 1;
    }
    assert_eq!(rigs, 3);

    // Unsubscribe two; only the head remains.
    ws.send(Message::text(
        json!({"op": "unsubscribe", "subscriptionIds": [7, 9]}).to_string(),
    ))
    .await
    .unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    server.publish(3);
    match next(&mut ws).await {
        Fox::Data(sub, _, p) => assert_eq!((sub, p["seq"].as_u64()), (8, Some(3))),
        Fox::Json(v) => panic!("unexpected {v}"),
    }
    // Unsupported ops, unknown channels and bad JSON get an error status; the session goes on.
    for bad in [
        json!({"op": "getParameters", "parameterNames": []}).to_string(),
        json!({"op": "subscribe", "subscriptions": [{"id": 8, "channelId": 1}]}).to_string(),
        json!({"op": "subscribe", "subscriptions": [{"id": 10, "channelId": 999}]}).to_string(),
        "{nope".to_string(),
    ] {
        ws.send(Message::text(bad.clone())).await.unwrap();
        let status = next_json_op(&mut ws, "status").await;
        assert_eq!(status["level"], 2, "{bad}: {status}");
    }
    server.publish(4);
    loop {
        if let Fox::Data(sub, _, p) = next(&mut ws).await {
            assert_eq!((sub, p["seq"].as_u64()), (8, Some(4)));
            break;
        }
    }
    // Character list changes: unadvertise, advertise again.
    let mut info = mouthpiece_server::loadgen::synthetic_info(60.0);
    info.characters.remove(0);
    server.hub.set_info(info);
    let un = next_json_op(&mut ws, "unadvertise").await;
    assert_eq!(un["channelIds"].as_array().unwrap().len(), 10);
    let adv = next_json_op(&mut ws, "advertise").await;
    assert_eq!(adv["channels"].as_array().unwrap().len(), 8);
    server.stop().await;

    // The payloads match the schemas the server advertised.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("payloads.json");
    std::fs::write(&path, Value::Array(payloads).to_string()).unwrap();
    let python = std::env::var("MOUTHPIECE_PYTHON").unwrap_or_else(|_| "python3".into());
    let out = Command::new(python)
        .args([
            "-c",
            "import json,sys,jsonschema\n\
             for item in json.load(open(sys.argv[1])):\n\
             \x20   jsonschema.Draft202012Validator.check_schema(item['schema'])\n\
             \x20   jsonschema.validate(item['payload'], item['schema'])\n\
             print('ok')",
        ])
        .arg(&path)
        .output()
        .expect("running Python");
    assert!(
        out.status.success(),
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[tokio::test]
async fn subscriptions_per_client_are_capped() {
    let server = TestServer::start(ServerConfig::default()).await;
    let mut ws = connect(&server.url(), &["foxglove.websocket.v1"])
        .await
        .unwrap();
    let adv = next_json_op(&mut ws, "advertise").await;
    let head = adv["channels"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["topic"] == "/head")
        .unwrap()["id"]
        .clone();
    let cap = mouthpiece_server::MAX_SUBSCRIPTIONS_PER_CLIENT as u64;
    let subs: Vec<Value> = (0..1000)
        .map(|i| json!({"id": i, "channelId": head}))
        .collect();
    ws.send(Message::text(
        json!({"op": "subscribe", "subscriptions": subs}).to_string(),
    ))
    .await
    .unwrap();
    let status = next_json_op(&mut ws, "status").await;
    assert!(
        status["message"]
            .as_str()
            .unwrap()
            .contains(&format!("at most {cap} subscriptions")),
        "{status}"
    );
    tokio::time::sleep(Duration::from_millis(100)).await;
    server.publish(0);
    server.publish(1);
    let mut per_frame = std::collections::BTreeMap::<u64, u64>::new();
    while per_frame.get(&1).copied().unwrap_or(0) < cap {
        if let Fox::Data(sub, _, p) = next(&mut ws).await {
            assert!(u64::from(sub) < cap, "subscription {sub} beyond the cap");
            *per_frame.entry(p["seq"].as_u64().unwrap()).or_default() += 1;
        }
    }
    assert_eq!(per_frame.values().copied().collect::<Vec<_>>(), [cap, cap]);
    server.stop().await;
}
