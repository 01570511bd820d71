//! Minimal WebDriver client for tests: headless Chromium through chromedriver's WebDriver
//! HTTP API (plain HTTP/1.1, no client library). Shared by the viewer test here and the
//! daemon's end-to-end test (`crates/mouthpiece/tests`, included by path).
//!
//! Needs Debian's `chromium` and `chromium-driver` (scripts/packages/test.apt).

use std::io::{Read, Write};
use std::net::TcpStream as StdTcpStream;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{json, Value};

/// Minimal WebDriver client over HTTP/1.1 (one request per connection).
pub struct WebDriver {
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
    pub fn start() -> WebDriver {
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

    pub fn request(
        &self,
        method: &str,
        path: &str,
        body: Option<&Value>,
    ) -> std::io::Result<Value> {
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

    pub fn call(&self, method: &str, path: &str, body: Option<Value>) -> Value {
        let id = self.session.as_deref().unwrap_or_default();
        let v = self
            .request(method, &format!("/session/{id}{path}"), body.as_ref())
            .unwrap();
        assert!(v["value"].get("error").is_none(), "{method} {path}: {v}");
        v["value"].clone()
    }

    pub fn script(&self, js: &str) -> Value {
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

/// Opens `page` in a new headless Chromium session (`profile` holds its user data).
pub fn open_page(page: &str, profile: &std::path::Path) -> WebDriver {
    let mut driver = WebDriver::start();
    let caps = json!({"capabilities": {"alwaysMatch": {
        "browserName": "chrome",
        "goog:chromeOptions": {
            "binary": "/usr/bin/chromium",
            "args": [
                "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                "--disable-quic", "--no-first-run", "--disable-component-update", "--disable-sync",
                "--disable-dev-shm-usage", "--window-size=1200,500",
                format!("--user-data-dir={}", profile.display()),
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
    driver
}

/// Screenshot (base64 PNG) of the element matching `selector`.
pub fn element_screenshot(driver: &WebDriver, selector: &str) -> String {
    let canvas = driver.call(
        "POST",
        "/element",
        Some(json!({"using": "css selector", "value": selector})),
    );
    let element = canvas
        .as_object()
        .and_then(|o| o.values().next())
        .and_then(Value::as_str)
        .unwrap()
        .to_owned();
    driver
        .call("GET", &format!("/element/{element}/screenshot"), None)
        .as_str()
        .unwrap()
        .to_owned()
}
