//! The booth console page in headless Chromium (`webdriver`), fed by the hub directly: what a
//! technician sees. The "waiting for the camera image" note goes once an image is drawn; the
//! page never scrolls sideways at 1024 and 1280 pixels wide, even with a long device name and
//! take file; the device text stays inside its tile (cut short, the whole text in its title);
//! the zoomed mouth shows every lip dot with a label no other label or dot covers; the
//! microphone meter shows the level, holds the peak, warns of clipping and says plainly when
//! there is no microphone.
//!
//! Needs Debian's `chromium` and `chromium-driver` (scripts/packages/test.apt).

use crate::helper_common as common;
use crate::helper_webdriver as webdriver;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::*;
use mouthpiece_server::{
    AudioState, AudioStatus, DotState, Health, Hub, ImageDot, Overlay, PreviewInput, ServerConfig,
    TakeSummary, SILENCE_DBFS,
};
use serde_json::{json, Value};
use webdriver::{open_page, WebDriver};

const LONG_DEVICE: &str = "openni2:device/usb/0000:00:14.0-3.2.1/PrimeSense-Carmine-1.09-serial-1412130045-with-a-name-far-too-long-for-any-tile";

/// The twelve lip dots as a 640 × 480 camera at 0.9 m sees a mouth (about 40 px wide), and
/// the forehead dots.
fn dots() -> Vec<ImageDot> {
    let mut dots = Vec::new();
    let (cx, cy, half_w) = (320.0f32, 330.0f32, 20.0f32);
    let mut lip = |name: String, x: f32, y: f32| {
        dots.push(ImageDot {
            name,
            x,
            y,
            state: DotState::Tracked,
        })
    };
    lip("D1".into(), cx - half_w, cy);
    for i in 0..5 {
        let x = cx - half_w + (i as f32 + 1.0) * 2.0 * half_w / 6.0;
        lip(format!("D{}", i + 2), x, cy - 5.0);
    }
    lip("D7".into(), cx + half_w, cy);
    for i in 0..5 {
        let x = cx + half_w - (i as f32 + 1.0) * 2.0 * half_w / 6.0;
        lip(format!("D{}", i + 8), x, cy + 6.0);
    }
    for (name, x, y) in [
        ("F1", 290.0, 200.0),
        ("F2", 320.0, 170.0),
        ("F3", 350.0, 200.0),
    ] {
        lip(name.into(), x, y);
    }
    dots
}

/// Offers a preview image with the dots every 100 ms until `stop`.
fn spawn_previews(hub: Hub, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let image = Arc::new(mouthpiece_server::preview::OwnedBgr {
            width: 640,
            height: 480,
            data: vec![70; 640 * 480 * 3],
        });
        let mut seq = 0;
        while !stop.load(Ordering::Relaxed) {
            hub.offer_preview(PreviewInput {
                seq,
                t: seq as f64 / 10.0,
                capture_us: seq * 100_000,
                wall_us: None,
                image: image.clone(),
                overlay: Overlay {
                    dots: dots(),
                    search: Vec::new(),
                },
            });
            seq += 1;
            std::thread::sleep(Duration::from_millis(100));
        }
    })
}

fn wait_until(driver: &WebDriver, what: &str, js: &str, done: impl Fn(&Value) -> bool) -> Value {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let v = driver.script(js);
        if done(&v) {
            return v;
        }
        assert!(Instant::now() < deadline, "{what}: last seen {v}");
        std::thread::sleep(Duration::from_millis(150));
    }
}

const LAYOUT: &str = "const d = document.scrollingElement; \
    const tile = [...document.querySelectorAll('.tile')].find(t => t.querySelector('.k').textContent === 'device'); \
    const v = tile && tile.querySelector('.v'); \
    const tr = tile && tile.getBoundingClientRect(), vr = v && v.getBoundingClientRect(); \
    return {inner: innerWidth, client: document.documentElement.clientWidth, scroll: d.scrollWidth, \
      images: window.mouthpiece.preview.images, \
      note: getComputedStyle(document.getElementById('camera-note')).display, \
      device: v ? {right: vr.right, tile_right: tr.right, title: v.title, cut: v.scrollWidth > v.clientWidth} : null};";

const INSET: &str = "const i = window.mouthpiece.inset; if (!i) return null; \
    return {width: i.width, height: i.height, radius: i.radius, dots: i.dots, labels: i.labels};";

const AUDIO: &str = "const a = window.mouthpiece.audio; \
    return {state: a.state, text: document.getElementById('mic-state').textContent, \
      held: Number.isFinite(a.heldPeak) ? a.heldPeak : null, clip: !document.getElementById('meter-clip').hidden, \
      level: document.getElementById('meter-level').style.width, \
      peak_shown: !document.getElementById('meter-peak').hidden};";

fn audio(state: AudioState, level: f64, peak: f64, clip: bool) -> AudioStatus {
    AudioStatus {
        state,
        device: "hw:CARD=USB,DEV=0".into(),
        sample_rate: 48000,
        channels: 1,
        level_dbfs: level,
        peak_dbfs: peak,
        clip,
        overruns: 0,
        dropped_blocks: 0,
    }
}

fn set_audio(hub: &Hub, audio: AudioStatus, message: Option<&str>) {
    hub.update_status(|s| {
        s.audio = audio;
        s.audio_message = message.map(str::to_owned);
    });
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_console_reads_cleanly_at_booth_widths_in_headless_chromium() {
    let server = TestServer::start(ServerConfig::default()).await;
    let mut info = mouthpiece_server::loadgen::synthetic_info(30.0);
    info.source = LONG_DEVICE.into();
    server.hub.set_info(info);
    server.hub.set_health(Health {
        fps: 30.0,
        dots_found: 1.0,
        disk_free_mb: Some(50_000),
        image: Some([640, 480]),
        ..Health::default()
    });
    server.hub.add_take(TakeSummary {
        slate: "scene-with-a-rather-long-slate-name".into(),
        take: 12,
        file: "takes/scene-with-a-rather-long-slate-name_T012_20260101T101010Z.mcap".into(),
        frames: 900,
        seconds: 30.0,
        error: None,
    });
    let stop = Arc::new(AtomicBool::new(false));
    let previews = spawn_previews(server.hub.clone(), stop.clone());
    let page = format!("http://{}/", server.addr);
    let hub = server.hub.clone();
    let result = tokio::task::spawn_blocking(move || drive(&page, &hub)).await;
    stop.store(true, Ordering::Relaxed);
    let _ = previews.join();
    result.unwrap();
    server.stop().await;
}

fn drive(page: &str, hub: &Hub) {
    let profile = tempfile::tempdir().unwrap();
    let driver = open_page(page, profile.path());
    for width in [1024, 1280] {
        driver.call(
            "POST",
            "/window/rect",
            Some(json!({"width": width, "height": 800})),
        );
        driver.call("POST", "/refresh", Some(json!({})));
        let v = wait_until(&driver, "an image and the status", LAYOUT, |v| {
            v["images"].as_u64().unwrap_or(0) >= 2 && !v["device"].is_null()
        });
        // The note goes once the image is there.
        assert_eq!(v["note"], "none", "at {width}: {v}");
        // No sideways scrolling.
        let scroll = v["scroll"].as_f64().unwrap();
        assert!(
            scroll <= v["inner"].as_f64().unwrap() && scroll <= v["client"].as_f64().unwrap(),
            "the page scrolls sideways at {width} px: {v}"
        );
        // The device text stays in its tile, cut short, whole in its title.
        let d = &v["device"];
        assert!(
            d["right"].as_f64().unwrap() <= d["tile_right"].as_f64().unwrap() + 0.5,
            "device text spills out of its tile at {width} px: {v}"
        );
        assert_eq!(d["title"], LONG_DEVICE, "{v}");
        assert_eq!(d["cut"], true, "{v}");

        // The zoomed mouth: every lip dot, every label readable.
        let inset = wait_until(&driver, "the zoomed mouth", INSET, |v| !v.is_null());
        check_inset(&inset, width);
    }

    // The microphone.
    let a = wait_until(&driver, "no microphone", AUDIO, |v| v["state"] == "off");
    assert!(a["text"].as_str().unwrap().contains("no microphone"), "{a}");
    assert_eq!(a["peak_shown"], false, "{a}");
    set_audio(
        hub,
        audio(AudioState::NoDevice, SILENCE_DBFS, SILENCE_DBFS, false),
        Some("cannot open hw:CARD=USB,DEV=0: No such device"),
    );
    let a = wait_until(&driver, "no device", AUDIO, |v| v["state"] == "no_device");
    let text = a["text"].as_str().unwrap();
    assert!(
        text.contains("no microphone")
            && text.contains("hw:CARD=USB,DEV=0")
            && text.contains("No such device"),
        "{a}"
    );
    // The peak is held for as long as the page is told (here: the whole test).
    driver.script("window.mouthpiece.audio.holdMs = 1e9; window.mouthpiece.audio.clipHoldMs = 1e9; return null;");
    set_audio(hub, audio(AudioState::Live, -20.0, -6.0, false), None);
    let a = wait_until(&driver, "live level", AUDIO, |v| v["state"] == "live");
    assert_eq!(a["level"], "66.7%", "-20 dBFS on a -60..0 scale: {a}");
    assert_eq!(a["held"], -6.0, "{a}");
    assert_eq!(a["clip"], false, "{a}");
    assert_eq!(a["peak_shown"], true, "{a}");
    assert!(
        a["text"].as_str().unwrap().contains("48000 Hz · mono"),
        "the agreed format: {a}"
    );
    set_audio(hub, audio(AudioState::Live, -30.0, -0.5, true), None);
    let a = wait_until(&driver, "clip", AUDIO, |v| v["clip"] == true);
    assert_eq!(a["held"], -0.5, "{a}");
    // Quieter again: the peak and the warning are held.
    set_audio(hub, audio(AudioState::Live, -40.0, -35.0, false), None);
    let a = wait_until(&driver, "quieter", AUDIO, |v| v["level"] == "33.3%");
    assert_eq!(a["held"], -0.5, "{a}");
    assert_eq!(a["clip"], true, "{a}");
    // A peak at −1 dBFS is a clip even when the device does not say so.
    driver.script("window.mouthpiece.audio.clipAt = -Infinity; return null;");
    wait_until(&driver, "clip warning let go", AUDIO, |v| {
        v["clip"] == false
    });
    set_audio(hub, audio(AudioState::Live, -10.0, -1.0, false), None);
    wait_until(&driver, "clip at -1 dBFS", AUDIO, |v| v["clip"] == true);
    set_audio(hub, AudioStatus::default(), None);
    let a = wait_until(&driver, "off again", AUDIO, |v| v["state"] == "off");
    assert_eq!(a["clip"], false, "{a}");
}

fn check_inset(inset: &Value, width: u32) {
    let labels = inset["labels"].as_array().unwrap();
    let dots = inset["dots"].as_array().unwrap();
    assert_eq!(
        dots.len(),
        12,
        "every lip dot in the inset at {width}: {inset}"
    );
    assert_eq!(labels.len(), 12, "{inset}");
    let r = inset["radius"].as_f64().unwrap();
    let (w, h) = (
        inset["width"].as_f64().unwrap(),
        inset["height"].as_f64().unwrap(),
    );
    let f = |v: &Value, k: &str| v[k].as_f64().unwrap();
    // Dots far enough apart to tell (more than two discs).
    for (i, a) in dots.iter().enumerate() {
        for b in &dots[i + 1..] {
            let d = (f(a, "x") - f(b, "x")).hypot(f(a, "y") - f(b, "y"));
            assert!(
                d > 4.0 * r,
                "dots {} and {} {d:.1} px apart at {width}",
                a["name"],
                b["name"]
            );
        }
    }
    for (i, a) in labels.iter().enumerate() {
        // Inside the inset.
        assert!(
            f(a, "x") >= 0.0
                && f(a, "y") >= 0.0
                && f(a, "x") + f(a, "w") <= w
                && f(a, "y") + f(a, "h") <= h,
            "label {} outside the inset at {width}: {a}",
            a["name"]
        );
        // No label over another label.
        for b in &labels[i + 1..] {
            let apart = f(a, "x") + f(a, "w") <= f(b, "x")
                || f(b, "x") + f(b, "w") <= f(a, "x")
                || f(a, "y") + f(a, "h") <= f(b, "y")
                || f(b, "y") + f(b, "h") <= f(a, "y");
            assert!(
                apart,
                "labels {} and {} overlap at {width}: {a} {b}",
                a["name"], b["name"]
            );
        }
        // No label over a dot.
        for d in dots {
            let covers = f(d, "x") + r > f(a, "x")
                && f(d, "x") - r < f(a, "x") + f(a, "w")
                && f(d, "y") + r > f(a, "y")
                && f(d, "y") - r < f(a, "y") + f(a, "h");
            assert!(
                !covers,
                "label {} covers dot {} at {width}",
                a["name"], d["name"]
            );
        }
    }
}
