//! `mouthpiece run` with `[nats]` against a real `nats-server` (JetStream on): frames and
//! `hello` reach a NATS subscriber, control over request/reply records a take, the take is
//! uploaded and `mouthpiece takes list|fetch` finds it; with the broker gone the booth goes
//! on (the WebSocket side, local takes) and its backlog arrives once the broker is back.
//! The booth authenticates with a password that never shows in its log.

use crate::helper_harness as harness;

use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

use futures_util::StreamExt;
use harness::{eventually, free_port, NatsServer};
use serde_json::{json, Value};

const WAIT: Duration = Duration::from_secs(60);
const PASSWORD: &str = "booth-pw-0f9e8d7c";

struct Daemon {
    child: Child,
    port: u16,
    dir: PathBuf,
}

impl Daemon {
    fn start(dir: &Path, nats_url: &str) -> Daemon {
        let port = free_port();
        let demo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../recordings/demo.mcap");
        let config = format!(
            "[source]\nspec = \"replay:{}?loop=1&speed=1.0\"\n\
             [server]\nlisten = \"127.0.0.1:{port}\"\n\
             [takes]\nfolder = \"takes\"\nflush_s = 0.5\nmin_free_mb = 1\n\
             [nats]\nservers = [\"{nats_url}\"]\nbooth = \"booth-a\"\nstudio = \"e2e\"\n\
             user = \"booth\"\npassword = {{ env = \"MOUTHPIECE_TEST_NATS_PASSWORD\" }}\n",
            demo.display()
        );
        std::fs::write(dir.join("mouthpiece.toml"), config).unwrap();
        let stderr = std::fs::File::create(dir.join("stderr.log")).unwrap();
        let child = crate::mouthpiece()
            .args(["run", "--config"])
            .arg(dir.join("mouthpiece.toml"))
            .env("MOUTHPIECE_TEST_NATS_PASSWORD", PASSWORD)
            .env("RUST_LOG", "debug")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(stderr)
            .spawn()
            .unwrap();
        Daemon {
            child,
            port,
            dir: dir.to_owned(),
        }
    }

    fn log(&self) -> String {
        std::fs::read_to_string(self.dir.join("stderr.log")).unwrap_or_default()
    }

    /// The log's warnings and errors (the debug log is long).
    fn problems(&self) -> String {
        self.log()
            .lines()
            .filter(|l| l.contains("WARN") || l.contains("ERROR"))
            .collect::<Vec<_>>()
            .join("\n")
    }

    fn signal(&self, signal: i32) {
        // SAFETY: kill(2) with our own child's pid and a valid signal number.
        let rc = unsafe { libc::kill(self.child.id() as i32, signal) };
        assert_eq!(rc, 0);
    }

    fn health(&self) -> Option<Value> {
        use std::io::{Read, Write};
        let mut s = std::net::TcpStream::connect(("127.0.0.1", self.port)).ok()?;
        s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
        write!(
            s,
            "GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
        )
        .ok()?;
        let mut text = String::new();
        s.read_to_string(&mut text).ok()?;
        serde_json::from_str(text.split_once("\r\n\r\n")?.1).ok()
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn server_config(dir: &Path) -> PathBuf {
    let path = dir.join("nats.conf");
    std::fs::write(
        &path,
        format!(
            "authorization {{\n  users = [\n    {{ user: booth, password: \"{PASSWORD}\" }}\n    {{ user: director, password: director-pw }}\n  ]\n}}\n"
        ),
    )
    .unwrap();
    path
}

async fn director(url: &str) -> async_nats::Client {
    async_nats::ConnectOptions::with_user_and_password("director".into(), "director-pw".into())
        .retry_on_initial_connect()
        .request_timeout(Some(Duration::from_secs(10)))
        .connect(url)
        .await
        .unwrap()
}

async fn control(client: &async_nats::Client, request: Value) -> Value {
    let reply = eventually(WAIT, async || {
        client
            .request("mouthpiece.booth-a.control", request.to_string().into())
            .await
            .ok()
    })
    .await
    .expect("no control reply");
    serde_json::from_slice(&reply.payload).unwrap()
}

/// `mouthpiece takes` with the booth's config (its credentials) and `--server`.
fn takes_cli(dir: &Path, url: &str, args: &[&str]) -> std::process::Output {
    crate::mouthpiece()
        .arg("takes")
        .arg("--config")
        .arg(dir.join("mouthpiece.toml"))
        .args(["--server", url])
        .args(args)
        .env("MOUTHPIECE_TEST_NATS_PASSWORD", PASSWORD)
        .output()
        .unwrap()
}

fn local_takes(dir: &Path) -> Vec<PathBuf> {
    let mut takes: Vec<PathBuf> = std::fs::read_dir(dir.join("takes"))
        .map(|d| d.filter_map(Result::ok).map(|e| e.path()).collect())
        .unwrap_or_default();
    takes.retain(|p| p.extension().is_some_and(|e| e == "mcap"));
    takes.sort();
    takes
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_booth_on_nats_streams_takes_control_and_uploads_and_outlives_its_broker() {
    let conf_dir = tempfile::tempdir().unwrap();
    let conf = server_config(conf_dir.path());
    let mut server = NatsServer::start_with(&["-c", conf.to_str().unwrap()]);
    let url = server.url();
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::start(dir.path(), &url);
    let client = director(&url).await;

    // Frames and hello.
    let mut frames = client.subscribe("mouthpiece.booth-a.frame").await.unwrap();
    let first = tokio::time::timeout(WAIT, frames.next())
        .await
        .unwrap_or_else(|_| panic!("no frame on NATS: {}", daemon.problems()))
        .unwrap();
    let frame: Value = serde_json::from_slice(&first.payload).unwrap();
    assert_eq!(frame["type"], "frame", "{frame}");
    let hello = client
        .request("mouthpiece.booth-a.hello", "".into())
        .await
        .unwrap();
    let hello: Value = serde_json::from_slice(&hello.payload).unwrap();
    let names: Vec<&str> = hello["characters"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["human", "wolf"], "{hello}");

    // The documented Python subscriber (nats-py) gets hello and frames.
    let python = std::env::var("MOUTHPIECE_PYTHON").unwrap_or_else(|_| "python3".into());
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/nats_subscriber.py");
    let out = tokio::process::Command::new(&python)
        .arg(&example)
        .args([
            "--server", &url, "--booth", "booth-a", "--frames", "10", "--user", "director",
        ])
        .env("MOUTHPIECE_NATS_PASSWORD", "director-pw")
        .output()
        .await
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{python} {}: {stdout}{} (nats-py: pip install nats-py)",
        example.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.starts_with("hello: "), "{stdout}");
    let summary: Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    assert_eq!(summary["frames"], 10, "{stdout}");
    assert_eq!(summary["in_order"], true, "{stdout}");
    assert_eq!(summary["characters"], json!(["human", "wolf"]), "{stdout}");

    // A take over NATS control, uploaded once closed.
    let started = control(
        &client,
        json!({"type": "record", "action": "start", "slate": "nats", "id": 1}),
    )
    .await;
    assert_eq!(started["type"], "result", "{started}");
    // Thirty frames published after the take started (a new subscription: the first one
    // holds frames from before).
    drop(frames);
    let mut frames = client.subscribe("mouthpiece.booth-a.frame").await.unwrap();
    for _ in 0..30 {
        tokio::time::timeout(WAIT, frames.next()).await.unwrap();
    }
    let stopped = control(
        &client,
        json!({"type": "record", "action": "stop", "id": 2}),
    )
    .await;
    assert_eq!(stopped["type"], "result", "{stopped}");
    assert_eq!(stopped["request"], "record", "{stopped}");
    let mut last_cli = String::new();
    let listed = eventually(WAIT, async || {
        let out = takes_cli(dir.path(), &url, &["list", "--json"]);
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        last_cli = String::from_utf8_lossy(&out.stderr).into_owned();
        (out.status.success() && text.lines().count() == 1).then_some(text)
    })
    .await
    .unwrap_or_else(|| {
        panic!(
            "the take was not uploaded: {last_cli} {}",
            daemon.problems()
        )
    });
    let record: Value = serde_json::from_str(listed.trim()).unwrap();
    assert_eq!(record["booth"], "booth-a", "{record}");
    assert_eq!(record["slate"], "nats", "{record}");
    assert_eq!(record["characters"], json!(["human", "wolf"]), "{record}");
    assert!(record["frames"].as_u64().unwrap() >= 30, "{record}");
    assert!(record["duration_s"].as_f64().unwrap() >= 0.9, "{record}");
    let object = record["object"].as_str().unwrap();
    assert!(object.starts_with("booth-a/nats_T001_"), "{object}");
    let local = local_takes(dir.path());
    assert_eq!(local.len(), 1);
    let fetched = tempfile::tempdir().unwrap();
    let out = takes_cli(
        dir.path(),
        &url,
        &["fetch", object, "--out", fetched.path().to_str().unwrap()],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let copy = fetched.path().join(local[0].file_name().unwrap());
    assert_eq!(
        std::fs::read(&copy).unwrap(),
        std::fs::read(&local[0]).unwrap()
    );
    // Fetching again would overwrite: refused as bad input.
    let again = takes_cli(
        dir.path(),
        &url,
        &["fetch", object, "--out", fetched.path().to_str().unwrap()],
    );
    assert_eq!(again.status.code(), Some(2));
    let health = daemon.health().unwrap();
    assert_eq!(health["nats"]["connected"], true, "{health}");
    assert_eq!(health["nats"]["takes_uploaded"], 1, "{health}");

    // The broker goes away: the booth goes on and says NATS is down.
    server.kill();
    let health = eventually(WAIT, async || {
        daemon.health().filter(|h| h["nats"]["connected"] == false)
    })
    .await
    .expect("/healthz never said NATS is down");
    assert_eq!(health["status"], "ok", "{health}");
    let frames_then = health["frames"].as_u64().unwrap();
    // A take recorded meanwhile (SIGUSR1 starts one, SIGUSR2 stops it) stays local.
    daemon.signal(libc::SIGUSR1);
    eventually(WAIT, async || {
        daemon
            .health()
            .filter(|h| h["frames"].as_u64().unwrap() > frames_then + 30)
    })
    .await
    .expect("the booth stopped streaming without its broker");
    daemon.signal(libc::SIGUSR2);
    eventually(WAIT, async || {
        daemon.health().filter(|h| h["nats"]["takes_waiting"] == 1)
    })
    .await
    .expect("the take recorded without the broker is not waiting for upload");

    // The broker returns: the backlog goes up.
    server.restart();
    eventually(WAIT, async || {
        daemon
            .health()
            .filter(|h| h["nats"]["takes_uploaded"] == 2 && h["nats"]["connected"] == true)
    })
    .await
    .unwrap_or_else(|| panic!("the backlog was not uploaded: {}", daemon.problems()));
    let out = takes_cli(dir.path(), &url, &["list"]);
    let table = String::from_utf8_lossy(&out.stdout);
    assert_eq!(table.lines().count(), 3, "{table}");
    // Both takes stay on the booth's disk, marked as uploaded.
    for take in local_takes(dir.path()) {
        let mut marker = take.clone().into_os_string();
        marker.push(".uploaded");
        assert!(Path::new(&marker).exists(), "{}", take.display());
    }
    let log = daemon.log();
    assert!(log.contains("NATS connected"), "{log}");
    assert!(!log.contains(PASSWORD), "the password shows in the log");
    let _ = Instant::now();
}
