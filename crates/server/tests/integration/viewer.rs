//! The viewer page in a real browser: headless Chromium driven through chromedriver's
//! WebDriver HTTP API (`webdriver`). The test serves a
//! synthetic moving stream; the page must connect, show frames, and draw something that
//! changes between two moments (two canvas screenshots differ).
//!
//! Needs Debian's `chromium` and `chromium-driver` (scripts/packages/test.apt).

use crate::helper_common as common;
use crate::helper_webdriver as webdriver;

use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::*;
use mouthpiece_server::ServerConfig;
use serde_json::{json, Value};
use webdriver::{element_screenshot, open_page, WebDriver};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_viewer_connects_shows_frames_and_moves_in_headless_chromium() {
    let server = TestServer::start(ServerConfig::default()).await;
    let stop = Arc::new(AtomicBool::new(false));
    let publisher = mouthpiece_server::loadgen::spawn_publisher(
        server.hub.clone(),
        30.0,
        u64::MAX,
        stop.clone(),
    );
    let page = format!("http://{}/", server.addr);
    let result = tokio::task::spawn_blocking(move || drive_browser(&page)).await;
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let _ = publisher.join();
    let (shot_a, shot_b, state) = result.unwrap();
    println!("viewer state: {state}");
    // For looking at it: MOUTHPIECE_VIEWER_SCREENSHOT=/tmp/viewer.b64 (base64 PNG of the canvas).
    if let Ok(path) = std::env::var("MOUTHPIECE_VIEWER_SCREENSHOT") {
        std::fs::write(path, &shot_b).unwrap();
    }
    assert_ne!(
        shot_a, shot_b,
        "the canvas drawing changes between two moments"
    );
    server.stop().await;
}

/// Returns two canvas screenshots (base64 PNG) taken 400 ms apart and the page's state.
fn drive_browser(page: &str) -> (String, String, Value) {
    let profile = tempfile::tempdir().unwrap();
    let driver = open_page(page, profile.path());

    let deadline = Instant::now() + Duration::from_secs(30);
    let state = loop {
        let state = driver.script(
            "const m = window.mouthpiece; return m ? {connected: m.connected, frames: m.frames, \
             fps: m.fps, latency: m.latencyMs, errors: m.errors.length, \
             characters: m.frame ? m.frame.characters.map(c => c.name) : [], \
             curve: m.frame ? m.frame.characters[0].curve.length : 0, \
             performer: !!(m.frame && m.frame.performer), \
             stats: document.getElementById('stats').textContent, \
             header: document.getElementById('state').textContent} : null",
        );
        if state["frames"].as_u64().unwrap_or(0) >= 20 {
            break state;
        }
        assert!(
            Instant::now() < deadline,
            "the page shows no frames: {state}"
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    assert_eq!(state["connected"], true, "{state}");
    assert_eq!(state["header"], "connected", "{state}");
    assert_eq!(state["errors"], 0, "{state}");
    assert_eq!(state["characters"], json!(["human", "wolf"]), "{state}");
    assert_eq!(
        state["curve"], 48,
        "the smoothed curve is subscribed: {state}"
    );
    assert_eq!(state["performer"], true, "{state}");
    assert!(state["stats"].as_str().unwrap().contains("fps"), "{state}");

    // Something is drawn: many pixels differ from the background.
    let drawn = driver.script(
        "const c = document.getElementById('view'); \
         const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; \
         let n = 0; for (let i = 0; i < d.length; i += 4) \
           if (Math.abs(d[i] - 0x11) + Math.abs(d[i+1] - 0x14) + Math.abs(d[i+2] - 0x18) > 60) n++; \
         return n;",
    );
    assert!(
        drawn.as_u64().unwrap() > 500,
        "canvas looks empty: {drawn} drawn pixels"
    );

    let shot = |d: &WebDriver| element_screenshot(d, "#view");
    let a = shot(&driver);
    std::thread::sleep(Duration::from_millis(400));
    let b = shot(&driver);
    assert!(a.len() > 1000, "screenshot is a real PNG");
    (a, b, state)
}
