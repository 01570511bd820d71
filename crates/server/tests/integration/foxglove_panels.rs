//! The Foxglove channels that Foxglove Studio's own panels draw (image, image annotations,
//! 3D scene, transforms), and the rig's channel for the Plot panel, checked with Foxglove's
//! own client library (`@foxglove/ws-protocol`) and Foxglove's published JSON Schemas
//! (`@foxglove/schemas`, validated with `ajv`; our own channels against the schema the
//! server advertises): `tests/js/foxglove-client.js`, installed from the committed lock
//! file (npm, `scripts/test`). Needs Node.js.

use crate::helper_common as common;

use std::path::PathBuf;
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use common::*;
use mouthpiece_server::preview::OwnedBgr;
use mouthpiece_server::{DotState, ImageDot, Overlay, PixelBox, PreviewInput, ServerConfig};
use serde_json::Value;

fn js_dir() -> PathBuf {
    let js = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/js");
    if !js
        .join("node_modules/@foxglove/ws-protocol/package.json")
        .exists()
    {
        let status = Command::new("npm")
            .args(["ci", "--silent", "--no-audit", "--no-fund"])
            .current_dir(&js)
            .status()
            .expect("npm (Debian package `npm`, installed by scripts/test)");
        assert!(status.success(), "npm ci in tests/js failed");
    }
    js
}

fn overlay() -> Overlay {
    let dot = |name: &str, x, y, state| ImageDot {
        name: name.into(),
        x,
        y,
        state,
    };
    Overlay {
        dots: vec![
            dot("D1", 100.0, 120.0, DotState::Tracked),
            dot("D2", 140.0, 110.0, DotState::Predicted),
            dot("F1", 160.0, 40.0, DotState::Lost),
        ],
        search: vec![PixelBox {
            x: 60.0,
            y: 20.0,
            width: 160.0,
            height: 140.0,
        }],
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn foxglove_studio_panels_get_image_annotations_scene_and_transforms() {
    let server = TestServer::start(ServerConfig::default()).await;
    let stop = Arc::new(AtomicBool::new(false));
    let publisher = {
        let hub = server.hub.clone();
        let stop = stop.clone();
        let image: Arc<OwnedBgr> = Arc::new(OwnedBgr {
            width: 320,
            height: 240,
            data: (0..320 * 240 * 3).map(|i| (i % 251) as u8).collect(),
        });
        std::thread::spawn(move || {
            let mut frame = mouthpiece_server::StreamFrame::default();
            let mut i = 0u64;
            while !stop.load(Ordering::Relaxed) {
                mouthpiece_server::loadgen::synthetic_frame(i, 30.0, &mut frame);
                let seq = hub.publish(&frame);
                if hub.preview_due(frame.t) {
                    hub.offer_preview(PreviewInput {
                        seq,
                        t: frame.t,
                        capture_us: frame.capture_us,
                        wall_us: frame.wall_us,
                        image: image.clone(),
                        overlay: overlay(),
                    });
                }
                i += 1;
                std::thread::sleep(Duration::from_millis(33));
            }
        })
    };
    let url = server.url();
    let output = tokio::task::spawn_blocking(move || {
        let js = js_dir();
        Command::new("node")
            .arg(js.join("foxglove-client.js"))
            .arg(&url)
            .arg("3")
            .output()
            .expect("node (Debian package `nodejs`)")
    })
    .await
    .unwrap();
    stop.store(true, Ordering::Relaxed);
    publisher.join().unwrap();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let summary: Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(summary["problems"], serde_json::json!([]), "{summary}");

    let channel = |topic: &str| {
        summary["channels"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["topic"] == topic)
            .unwrap_or_else(|| panic!("{topic} advertised: {summary}"))
            .clone()
    };
    for (topic, schema) in [
        ("/camera/image", "foxglove.CompressedImage"),
        ("/camera/annotations", "foxglove.ImageAnnotations"),
        ("/scene", "foxglove.SceneUpdate"),
        ("/tf", "foxglove.FrameTransforms"),
    ] {
        let c = channel(topic);
        assert_eq!(c["schemaName"], schema, "{c}");
        assert_eq!(c["encoding"], "json", "{c}");
        assert_eq!(c["schemaEncoding"], "jsonschema", "{c}");
        assert_eq!(c["schemaTitle"], schema, "{c}");
        let n = summary["messages"][topic].as_u64().unwrap_or(0);
        assert!(n >= 2, "{topic}: {n} messages in 3 s");
    }
    // The rig, a channel of our own for Foxglove's Plot panel: validated by the client
    // against the schema the server advertised (any problem is in `problems` above).
    for name in ["human", "wolf"] {
        let topic = format!("/rig/{name}");
        let c = channel(&topic);
        assert_eq!(c["schemaName"], "mouthpiece.Rig", "{c}");
        assert_eq!(c["schemaEncoding"], "jsonschema", "{c}");
        let n = summary["messages"][&topic].as_u64().unwrap_or(0);
        assert!(n >= 2, "{topic}: {n} messages in 3 s");
        let sample = &summary["samples"][&topic];
        assert_eq!(sample["name"], name, "{sample}");
        assert_eq!(sample["curves"].as_object().unwrap().len(), 27, "{sample}");
        assert!(sample["jaw"]["angle_deg"].is_number(), "{sample}");
    }
    // Same rate limit as the preview's default (10 images a second).
    let images = summary["messages"]["/camera/image"].as_u64().unwrap();
    assert!(images <= 35, "{images} images in 3 s");

    let s = &summary["samples"];
    let image = &s["/camera/image"];
    assert_eq!(image["format"], "jpeg");
    assert_eq!(image["frame_id"], "camera");
    assert_eq!(image["data"]["starts"], "ffd8", "a JPEG: {image}");

    // Annotations in the JPEG's pixels: the 320-wide image is sent whole (under 480 wide).
    let a = &s["/camera/annotations"];
    assert_eq!(a["circles"].as_array().unwrap().len(), 3, "{a}");
    assert_eq!(a["circles"][0]["position"]["x"], 100.0);
    let labels: Vec<&str> = a["texts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l["text"].as_str().unwrap())
        .collect();
    assert_eq!(labels, ["D1", "D2", "F1"]);
    assert_eq!(a["points"][0]["points"].as_array().unwrap().len(), 4);

    // The scene: the performer in `mouth`, each character in its own frame.
    let scene = &s["/scene"];
    let entities = scene["entities"].as_array().unwrap();
    let frames: Vec<&str> = entities
        .iter()
        .map(|e| e["frame_id"].as_str().unwrap())
        .collect();
    assert_eq!(
        frames,
        ["mouth", "character_human", "character_wolf"],
        "{scene}"
    );
    for e in entities {
        assert_eq!(e["spheres"].as_array().unwrap().len(), 12, "{e}");
        assert!(!e["lines"][0]["points"].as_array().unwrap().is_empty());
    }
    // Character points in metres: the wolf is 9 cm wide.
    let wolf = &entities[2]["spheres"];
    let xs: Vec<f64> = wolf
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["pose"]["position"]["x"].as_f64().unwrap())
        .collect();
    let width =
        xs.iter().cloned().fold(f64::MIN, f64::max) - xs.iter().cloned().fold(f64::MAX, f64::min);
    assert!((width - 0.09).abs() < 0.01, "wolf width {width} m");

    // The transform tree camera -> head -> mouth -> characters.
    let tf = s["/tf"]["transforms"].as_array().unwrap();
    let pairs: Vec<(String, String)> = tf
        .iter()
        .map(|t| {
            (
                t["parent_frame_id"].as_str().unwrap().to_owned(),
                t["child_frame_id"].as_str().unwrap().to_owned(),
            )
        })
        .collect();
    for (parent, child) in [
        ("camera", "head"),
        ("head", "mouth"),
        ("mouth", "character_human"),
        ("mouth", "character_wolf"),
    ] {
        assert!(
            pairs.iter().any(|(p, c)| p == parent && c == child),
            "{parent} -> {child} in {pairs:?}"
        );
    }
    let mouth = tf.iter().find(|t| t["child_frame_id"] == "mouth").unwrap();
    assert_eq!(mouth["translation"]["z"], 0.6, "the mouth frame from hello");
    server.stop().await;
}
