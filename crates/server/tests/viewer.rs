//! The viewer page in a real browser: headless Chromium driven through chromedriver's
//! WebDriver HTTP API (plain HTTP/1.1 from this test, no client library). The test serves a
//! synthetic moving stream; the page must connect, show frames, and draw something that
//! changes between two moments (two canvas screenshots differ).
//!
//! Needs Debian's `chromium` and `chromium-driver` (scripts/packages/test.apt).

mod common;

use std::io::{Read, Write};
use std::net::TcpStream as StdTcpStream;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::*;
use mouthpiece_server::ServerConfig;
use serde_json::{json, Value};

/// Minimal WebDriver client over HTTP/1.1 (one request per connection).
struct WebDriver {
    port: u16,
    child: Child,
    session: Option<String>,
}

impl Drop for WebDriver {
    fn drop(&mut self) {
        if let Some(id) = self.session.take() {
            let _ = self.request("DELETE", &format!("/session/{id}"), None);
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl WebDriver {
    fn start() -> WebDriver {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let child = Command::new("chromedriver")
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("chromedriver (Debian package chromium-driver, scripts/packages/test.apt)");
        let driver = WebDriver {
            port,
            child,
            session: None,
        };
        let deadline = Instant::now() + Duration::from_secs(20);
        while driver.request("GET", "/status", None).is_err() {
            assert!(Instant::now() < deadline, "chromedriver did not start");
            std::thread::sleep(Duration::from_millis(100));
        }
        driver
    }

    fn request(&self, method: &str, path: &str, body: Option<&Value>) -> std::io::Result<Value> {
        let mut s = StdTcpStream::connect(("127.0.0.1", self.port))?;
        s.set_read_timeout(Some(Duration::from_secs(60)))?;
        let body = body.map(Value::to_string).unwrap_or_default();
        write!(
            s,
            "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{}\r\nContent-Type: application/json\r\n\
             Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
            self.port,
            body.len()
        )?;
        // chromedriver keeps the connection open: read the head, then exactly the body.
        let mut raw = Vec::new();
        let mut chunk = [0u8; 8192];
        let split = loop {
            if let Some(p) = raw.windows(4).position(|w| w == b"\r\n\r\n") {
                break p;
            }
            let n = s.read(&mut chunk)?;
            if n == 0 {
                return Err(std::io::Error::other("no HTTP head"));
            }
            raw.extend_from_slice(&chunk[..n]);
        };
        let head = String::from_utf8_lossy(&raw[..split]).to_ascii_lowercase();
        let length = head.lines().find_map(|l| {
            l.strip_prefix("content-length:")
                .and_then(|v| v.trim().parse::<usize>().ok())
        });
        let mut payload = raw[split + 4..].to_vec();
        match length {
            Some(len) => {
                while payload.len() < len {
                    let n = s.read(&mut chunk)?;
                    if n == 0 {
                        break;
                    }
                    payload.extend_from_slice(&chunk[..n]);
                }
            }
            None => {
                s.read_to_end(&mut payload)?;
                if head.contains("transfer-encoding: chunked") {
                    payload = dechunk(&payload);
                }
            }
        }
        serde_json::from_slice(&payload).map_err(std::io::Error::other)
    }

    fn call(&self, method: &str, path: &str, body: Option<Value>) -> Value {
        let id = self.session.as_deref().unwrap_or_default();
        let v = self
            .request(method, &format!("/session/{id}{path}"), body.as_ref())
            .unwrap();
        assert!(v["value"].get("error").is_none(), "{method} {path}: {v}");
        v["value"].clone()
    }

    fn script(&self, js: &str) -> Value {
        self.call(
            "POST",
            "/execute/sync",
            Some(json!({"script": js, "args": []})),
        )
    }
}

fn dechunk(mut data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let Some(eol) = data.windows(2).position(|w| w == b"\r\n") else {
            return out;
        };
        let size =
            usize::from_str_radix(String::from_utf8_lossy(&data[..eol]).trim(), 16).unwrap_or(0);
        if size == 0 {
            return out;
        }
        out.extend_from_slice(&data[eol + 2..eol + 2 + size]);
        data = &data[eol + 2 + size + 2..];
    }
}

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
    let mut driver = WebDriver::start();
    let profile = tempfile::tempdir().unwrap();
    let caps = json!({"capabilities": {"alwaysMatch": {
        "browserName": "chrome",
        "goog:chromeOptions": {
            "binary": "/usr/bin/chromium",
            "args": [
                "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                "--disable-quic", "--no-first-run", "--disable-component-update", "--disable-sync",
                "--disable-dev-shm-usage", "--window-size=1200,500",
                format!("--user-data-dir={}", profile.path().display()),
            ]
        }
    }}});
    let created = driver.request("POST", "/session", Some(&caps)).unwrap();
    let session = created["value"]["sessionId"]
        .as_str()
        .unwrap_or_else(|| panic!("no session: {created}"))
        .to_owned();
    driver.session = Some(session);
    driver.call("POST", "/url", Some(json!({"url": page})));

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

    let canvas = driver.call(
        "POST",
        "/element",
        Some(json!({"using": "css selector", "value": "#view"})),
    );
    let element = canvas
        .as_object()
        .and_then(|o| o.values().next())
        .and_then(Value::as_str)
        .unwrap()
        .to_owned();
    let shot = |d: &WebDriver| {
        d.call("GET", &format!("/element/{element}/screenshot"), None)
            .as_str()
            .unwrap()
            .to_owned()
    };
    let a = shot(&driver);
    std::thread::sleep(Duration::from_millis(400));
    let b = shot(&driver);
    assert!(a.len() > 1000, "screenshot is a real PNG");
    (a, b, state)
}
