//! `mouthpiece run` end to end: the real binary on a session written at test time, a real
//! WebSocket client, real signals.

use crate::helper_daemon_run as run;
use crate::helper_webdriver as webdriver;
use std::os::unix::net::UnixDatagram;
mod livelink;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use mouthpiece_frame::{Calibration, ColorImage, DepthImage, Frame, Intrinsics};
use mouthpiece_recording::{MessageReader, SessionWriter, WriterOptions};
use serde_json::{json, Value};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::HeaderValue;
use tokio_tungstenite::tungstenite::Message;

type Client =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// A session of `frames` frames at 30 fps, 160x120, whose images `fill` paints per frame.
fn write_session_with(
    path: &Path,
    frames: u64,
    mut fill: impl FnMut(u64, &mut ColorImage, &mut DepthImage),
) {
    let mut writer = SessionWriter::create(path, WriterOptions::default()).unwrap();
    let calibration = Arc::new(Calibration::registered(Intrinsics::ideal(
        160, 120, 131.0, 131.0, 79.5, 59.5,
    )));
    for seq in 0..frames {
        let mut color = ColorImage::new(160, 120);
        let mut depth = DepthImage::new(160, 120);
        fill(seq, &mut color, &mut depth);
        writer
            .write_frame(&Frame {
                seq,
                device_ts_us: seq * 33_333,
                host_rx: Instant::now(),
                wall_clock: None,
                color,
                depth,
                calibration: calibration.clone(),
            })
            .unwrap();
    }
    writer.finish().unwrap();
}

/// A short session: `frames` frames at 30 fps, 160x120, a moving gradient.
fn write_session(path: &Path, frames: u64) {
    write_session_with(path, frames, |seq, color, depth| {
        color
            .data
            .iter_mut()
            .enumerate()
            .for_each(|(i, b)| *b = ((i as u64 + seq * 3) % 251) as u8);
        depth.data.iter_mut().for_each(|d| *d = 600);
    });
}

/// Like [`write_session`] but every pixel is noise, so that frames compress little and a
/// take's size is known from the session's: `frames` frames at 30 fps, 160x120.
fn write_noisy_session(path: &Path, frames: u64) {
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    write_session_with(path, frames, |_, color, depth| {
        color.data.iter_mut().for_each(|b| *b = next() as u8);
        depth
            .data
            .iter_mut()
            .for_each(|d| *d = 400 + (next() % 1000) as u16);
    });
}

use run::free_port;

/// The daemon started with a config written for the test (or the embedded default), its log
/// kept in its folder; killed when dropped ([`run::Daemon`]).
struct Daemon {
    process: run::Daemon,
    port: u16,
    dir: tempfile::TempDir,
    stderr: PathBuf,
}

impl Daemon {
    /// Starts `mouthpiece run --config` with `extra` config text after a `[source]` and
    /// `[takes]` pointing into a temporary directory.
    fn start(source_spec: &str, extra: &str, args: &[&str], env: &[(&str, &str)]) -> Daemon {
        Self::start_with_dir(tempfile::tempdir().unwrap(), source_spec, extra, args, env)
    }

    fn start_with_dir(
        dir: tempfile::TempDir,
        source_spec: &str,
        extra: &str,
        args: &[&str],
        env: &[(&str, &str)],
    ) -> Daemon {
        let port = free_port();
        let config = format!(
            "[source]\nspec = \"{source_spec}\"\nretry_initial_s = 0.2\nretry_max_s = 0.4\nstall_timeout_s = 1.0\n\
             [server]\nlisten = \"127.0.0.1:{port}\"\n[takes]\nfolder = \"takes\"\nflush_s = 0.5\nmin_free_mb = 1\n{extra}"
        );
        std::fs::write(dir.path().join("mouthpiece.toml"), config).unwrap();
        Self::start_in(dir, port, args, env)
    }

    /// Starts the daemon on a `frames`-frame session ([`write_session`]) replayed in a loop;
    /// the session lives in the daemon's directory.
    fn start_looping(frames: u64, extra: &str, args: &[&str], env: &[(&str, &str)]) -> Daemon {
        let dir = tempfile::tempdir().unwrap();
        let session = dir.path().join("s.mcap");
        write_session(&session, frames);
        Self::start_with_dir(
            dir,
            &format!("replay:{}?loop=1", session.display()),
            extra,
            args,
            env,
        )
    }

    fn start_in(dir: tempfile::TempDir, port: u16, args: &[&str], env: &[(&str, &str)]) -> Daemon {
        let stderr = dir.path().join("stderr.log");
        let mut command = crate::mouthpiece();
        command.arg("run").current_dir(dir.path());
        // Without a config file in `dir`: the embedded default.
        let config = dir.path().join("mouthpiece.toml");
        if config.exists() {
            command.arg("--config").arg(config);
        }
        command
            .args(args)
            .env("RUST_LOG", "info")
            .env_remove("NOTIFY_SOCKET")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&stderr).unwrap());
        for (k, v) in env {
            command.env(k, v);
        }
        let daemon = Daemon {
            process: run::Daemon::spawn(&mut command),
            port,
            dir,
            stderr,
        };
        daemon.wait_for_port();
        daemon
    }

    fn wait_for_port(&self) {
        let deadline = Instant::now() + Duration::from_secs(20);
        while std::net::TcpStream::connect(("127.0.0.1", self.port)).is_err() {
            assert!(
                Instant::now() < deadline,
                "daemon did not listen; stderr:\n{}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    fn log(&self) -> String {
        std::fs::read_to_string(&self.stderr).unwrap_or_default()
    }

    fn signal(&self, signal: i32) {
        // SAFETY: kill(2) with our own child's pid and a valid signal number.
        let rc = unsafe { libc::kill(self.process.0.id() as i32, signal) };
        assert_eq!(rc, 0);
    }

    /// Waits for the exit; `None` when it did not exit within `limit`.
    fn wait_exit(&mut self, limit: Duration) -> Option<std::process::ExitStatus> {
        let deadline = Instant::now() + limit;
        loop {
            if let Some(status) = self.process.0.try_wait().unwrap() {
                return Some(status);
            }
            if Instant::now() >= deadline {
                return None;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    async fn connect(&self) -> Client {
        self.connect_with(json!({"type": "subscribe"})).await
    }

    /// Connects and sends `subscribe` (a `subscribe` message, with its fields).
    async fn connect_with(&self, subscribe: Value) -> Client {
        let mut request = format!("ws://127.0.0.1:{}/", self.port)
            .into_client_request()
            .unwrap();
        request.headers_mut().insert(
            "Sec-WebSocket-Protocol",
            HeaderValue::from_static("mouthpiece.v1"),
        );
        let (mut ws, _) = tokio_tungstenite::connect_async(request).await.unwrap();
        send(&mut ws, subscribe).await;
        ws
    }
}

async fn send(ws: &mut Client, v: Value) {
    ws.send(Message::text(v.to_string())).await.unwrap();
}

/// The next JSON message, failing after `limit`.
async fn next_json(ws: &mut Client, limit: Duration) -> Value {
    loop {
        let m = tokio::time::timeout(limit, ws.next())
            .await
            .expect("a message in time")
            .expect("open")
            .expect("ok");
        match m {
            Message::Text(t) => return serde_json::from_str(&t).unwrap(),
            Message::Close(f) => panic!("closed: {f:?}"),
            _ => continue,
        }
    }
}

/// The next message satisfying `pred` within `limit` overall.
async fn wait_for(ws: &mut Client, limit: Duration, pred: impl Fn(&Value) -> bool) -> Value {
    let deadline = Instant::now() + limit;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        assert!(!left.is_zero(), "no matching message within {limit:?}");
        let v = next_json(ws, left).await;
        if pred(&v) {
            return v;
        }
    }
}

fn topics(path: &Path) -> std::collections::BTreeMap<String, usize> {
    let mut reader = MessageReader::open(path).unwrap();
    let mut topics = std::collections::BTreeMap::new();
    while let Some(m) = reader.next_message().unwrap() {
        *topics.entry(m.topic.to_string()).or_insert(0) += 1;
    }
    topics
}

fn takes_in(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<_> = std::fs::read_dir(dir.join("takes"))
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    files.sort();
    files
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_receives_frames_and_sigterm_closes_it_with_1001_and_exits_0_within_2_s() {
    let mut daemon = Daemon::start_looping(60, "", &[], &[]);
    let mut ws = daemon.connect().await;
    let hello = wait_for(&mut ws, Duration::from_secs(10), |v| v["type"] == "hello").await;
    let names: Vec<&str> = hello["characters"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["human", "wolf"], "{hello}");
    // Units are spelt as the character files and the protocol document spell them.
    assert_eq!(hello["characters"][0]["units"], "m", "{hello}");
    let mut seqs = Vec::new();
    while seqs.len() < 20 {
        let f = wait_for(&mut ws, Duration::from_secs(10), |v| v["type"] == "frame").await;
        assert!(
            f["timecode"].as_str().is_some_and(|tc| tc.len() == 11),
            "{f}"
        );
        assert!(f["wall_us"].as_i64().is_some(), "{f}");
        seqs.push(f["seq"].as_u64().unwrap());
    }
    assert!(seqs.windows(2).all(|w| w[1] > w[0]), "{seqs:?}");

    daemon.signal(libc::SIGTERM);
    let sent = Instant::now();
    let code = loop {
        match tokio::time::timeout(Duration::from_secs(3), ws.next())
            .await
            .expect("closed in time")
        {
            Some(Ok(Message::Close(Some(frame)))) => break u16::from(frame.code),
            Some(Ok(_)) => continue,
            other => panic!("no close frame: {other:?}"),
        }
    };
    assert_eq!(code, 1001);
    let status = daemon
        .wait_exit(Duration::from_secs(2))
        .expect("exit within 2 s of SIGTERM");
    assert!(status.success(), "{status:?}\n{}", daemon.log());
    assert!(sent.elapsed() < Duration::from_secs(2));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_take_started_by_a_control_message_holds_every_channel() {
    let mut daemon = Daemon::start_looping(60, "", &[], &[]);
    let mut ws = daemon.connect().await;
    wait_for(&mut ws, Duration::from_secs(10), |v| v["type"] == "frame").await;
    // The wolf's head turns to a viewpoint in front of it, a little to its left (docs/head.md);
    // an unknown character is refused.
    send(
        &mut ws,
        json!({"type": "look_at", "id": 8, "character": "ghost", "point": [0, 0, 1]}),
    )
    .await;
    let refused = wait_for(&mut ws, Duration::from_secs(5), |v| v["type"] == "error").await;
    assert_eq!(
        (refused["id"].as_i64(), refused["code"].as_str()),
        (Some(8), Some("bad_request"))
    );
    send(
        &mut ws,
        json!({"type": "look_at", "id": 9, "character": "wolf", "point": [0.8, -2.5, 0.5]}),
    )
    .await;
    let looked = wait_for(&mut ws, Duration::from_secs(5), |v| {
        v["type"] == "result" || v["type"] == "error"
    })
    .await;
    assert_eq!(looked["type"], "result", "{looked}");
    assert_eq!(looked["detail"]["in_reach"], true, "{looked}");
    send(
        &mut ws,
        json!({"type": "record", "id": 1, "action": "start", "slate": "e2e", "take": 4}),
    )
    .await;
    // The reply and the status telling every client about the take come in either order.
    let (mut started, mut status_seen) = (None, false);
    while started.is_none() || !status_seen {
        let v = next_json(&mut ws, Duration::from_secs(5)).await;
        match v["type"].as_str() {
            Some("result") | Some("error") => started = Some(v),
            Some("status") if v["recording"]["slate"] == "e2e" => status_seen = true,
            _ => {}
        }
    }
    let started = started.unwrap();
    assert_eq!(started["type"], "result", "{started}");
    let file = PathBuf::from(started["detail"]["file"].as_str().unwrap());
    let name = file.file_name().unwrap().to_str().unwrap().to_owned();
    assert!(name.starts_with("e2e_T004_"), "{file:?}");
    tokio::time::sleep(Duration::from_millis(1500)).await;
    send(
        &mut ws,
        json!({"type": "record", "id": 2, "action": "stop"}),
    )
    .await;
    let stopped = wait_for(&mut ws, Duration::from_secs(5), |v| {
        v["type"] == "result" || v["type"] == "error"
    })
    .await;
    assert_eq!(stopped["type"], "result", "{stopped}");
    let frames = stopped["detail"]["frames"].as_u64().unwrap();
    assert!(frames >= 30, "{stopped}");
    let topics = topics(&file);
    for topic in [
        "/camera/color",
        "/camera/depth",
        "/performer/points",
        "/head",
        "/character/human",
        "/character/wolf",
    ] {
        assert_eq!(
            topics.get(topic).copied(),
            Some(frames as usize),
            "{topic}: {topics:?}"
        );
    }
    assert!(topics.contains_key("/camera/calibration"), "{topics:?}");
    // The take records the wolf's head (at rest: this session has no dots, so the wolf is
    // never bound to a performer; the turn itself is seen on the demo session below).
    let mut reader = MessageReader::open(&file).unwrap();
    let mut last_wolf = None;
    while let Some(m) = reader.next_message().unwrap() {
        if &*m.topic == "/character/wolf" {
            last_wolf = Some(serde_json::from_slice::<Value>(&m.data).unwrap());
        }
    }
    let last_wolf = last_wolf.unwrap();
    assert_eq!(
        last_wolf["head"]["rotation"],
        json!([1.0, 0.0, 0.0, 0.0]),
        "{last_wolf}"
    );
    assert_eq!(last_wolf["head"]["mode"], "follow", "{last_wolf}");
    // A second start while recording is refused; stop without a take is an error.
    send(
        &mut ws,
        json!({"type": "record", "id": 3, "action": "stop"}),
    )
    .await;
    let refused = wait_for(&mut ws, Duration::from_secs(5), |v| {
        v["type"] == "result" || v["type"] == "error"
    })
    .await;
    assert_eq!(refused["type"], "error", "{refused}");
    daemon.signal(libc::SIGTERM);
    assert!(daemon.wait_exit(Duration::from_secs(2)).unwrap().success());
}

#[test]
fn sigkill_during_a_take_leaves_a_readable_file() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("s.mcap");
    write_session(&session, 60);
    let mut daemon = Daemon::start(
        &format!("replay:{}?loop=1", session.display()),
        "",
        &["--record", "crash"],
        &[],
    );
    std::thread::sleep(Duration::from_millis(2500));
    daemon.signal(libc::SIGKILL);
    daemon.wait_exit(Duration::from_secs(2)).unwrap();
    let files = takes_in(daemon.dir.path());
    assert_eq!(files.len(), 1, "{files:?}\n{}", daemon.log());
    let topics = topics(&files[0]);
    // flush_s = 0.5: at most half a second (15 frames) of the ~2 s recorded is lost.
    let depth = topics.get("/camera/depth").copied().unwrap_or(0);
    assert!(depth >= 30, "only {depth} frames readable: {topics:?}");
    // The cut may fall between a frame's camera messages and its derived ones.
    let wolf = topics.get("/character/wolf").copied().unwrap_or(0);
    assert!(depth - wolf <= 1, "{topics:?}");
}

/// SIGTERM while the take writer is far behind (its disk capped at a quarter of what the
/// frames need): the daemon waits for the writer, so the take holds every frame up to the
/// signal, its summary and footer, and the log says how many frames were kept.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_keeps_the_tail_of_a_take_whose_writer_is_slow() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("s.mcap");
    write_noisy_session(&session, 90);
    // Bytes per frame in a take: the session's (same encoding) plus the derived channels.
    let per_frame = std::fs::metadata(&session).unwrap().len() as f64 / 90.0 + 2000.0;
    let cap_mb_s = per_frame * 30.0 / 4.0 / 1e6;
    let mut daemon = Daemon::start_with_dir(
        dir,
        &format!("replay:{}?loop=1", session.display()),
        &format!("queue_frames = 3600\nmax_write_mb_s = {cap_mb_s:.3}\n"),
        &[],
        &[],
    );
    let mut ws = daemon.connect().await;
    wait_for(&mut ws, Duration::from_secs(10), |v| v["type"] == "frame").await;
    send(
        &mut ws,
        json!({"type": "record", "id": 1, "action": "start", "slate": "slow"}),
    )
    .await;
    let started = wait_for(&mut ws, Duration::from_secs(5), |v| {
        v["type"] == "result" || v["type"] == "error"
    })
    .await;
    assert_eq!(started["type"], "result", "{started}");
    let file = PathBuf::from(started["detail"]["file"].as_str().unwrap());
    // About 1.5 s of take: 45 frames, of which the writer has written about a quarter.
    let mut last_seen = 0;
    for _ in 0..45 {
        let f = wait_for(&mut ws, Duration::from_secs(5), |v| v["type"] == "frame").await;
        last_seen = f["seq"].as_u64().unwrap();
    }
    daemon.signal(libc::SIGTERM);
    let sent = Instant::now();
    let status = daemon
        .wait_exit(Duration::from_secs(30))
        .unwrap_or_else(|| panic!("no exit within 30 s of SIGTERM\n{}", daemon.log()));
    let waited = sent.elapsed();
    let log = daemon.log();
    eprintln!("SIGTERM to exit: {waited:?} (writer capped at {cap_mb_s:.3} MB/s)");
    assert!(status.success(), "{status:?}\n{log}");
    let kept_line = log
        .lines()
        .find(|l| l.contains("take closed and synced to disk"))
        .unwrap_or_else(|| panic!("the log does not say what was kept:\n{log}"));
    let kept: u64 = kept_line
        .split("synced to disk: ")
        .nth(1)
        .and_then(|rest| rest.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{kept_line}"));
    assert!(kept_line.contains("dropped=0"), "{kept_line}");
    // The test means something only if the writer was still busy when the signal came.
    assert!(
        waited > Duration::from_millis(1500),
        "the writer drained in {waited:?}: not slow enough for this test\n{log}"
    );
    // The file is complete (summary and footer: the reader reaches its end without error)
    // and holds every frame from the start of the take to the last one sent before SIGTERM.
    let mut reader = MessageReader::open(&file).unwrap();
    let (mut depth, mut seqs) = (0u64, Vec::new());
    loop {
        match reader.next_message() {
            Ok(Some(m)) if &*m.topic == "/camera/depth" => depth += 1,
            Ok(Some(m)) if &*m.topic == "/performer/points" => {
                let v: Value = serde_json::from_slice(&m.data).unwrap();
                seqs.push(v["seq"].as_u64().unwrap());
            }
            Ok(Some(_)) => {}
            Ok(None) => break,
            Err(e) => panic!("the take is cut short after {depth} frames: {e}\n{log}"),
        }
    }
    assert!(
        !reader.is_truncated(),
        "the take is cut short after {depth} frames (no summary, no footer)\n{log}"
    );
    assert_eq!(depth, kept, "{log}");
    assert_eq!(seqs.len() as u64, kept);
    assert!(
        seqs.windows(2).all(|w| w[1] == w[0] + 1),
        "frames missing from the take: {seqs:?}"
    );
    let last = *seqs.last().unwrap();
    assert!(
        last >= last_seen,
        "the take ends at frame {last}, the clients saw {last_seen} before SIGTERM"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_source_that_fails_is_reported_down_and_streaming_resumes_when_it_returns() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("s.mcap");
    let away = dir.path().join("away.mcap");
    write_session(&session, 20);
    // No loop: at the end the source ends, and is reopened after the retry delay.
    let mut daemon = Daemon::start(&format!("replay:{}", session.display()), "", &[], &[]);
    let mut ws = daemon.connect().await;
    wait_for(&mut ws, Duration::from_secs(10), |v| v["type"] == "frame").await;
    std::fs::rename(&session, &away).unwrap();
    let down = wait_for(&mut ws, Duration::from_secs(10), |v| {
        v["type"] == "status"
            && v["source"] == "down"
            && v["message"]
                .as_str()
                .is_some_and(|m| m.contains("cannot open"))
    })
    .await;
    assert!(
        down["message"].as_str().unwrap().contains("source down"),
        "{down}"
    );
    std::fs::rename(&away, &session).unwrap();
    wait_for(&mut ws, Duration::from_secs(10), |v| {
        v["type"] == "status" && v["source"] == "up"
    })
    .await;
    let before = wait_for(&mut ws, Duration::from_secs(10), |v| v["type"] == "frame").await["seq"]
        .as_u64()
        .unwrap();
    let after = wait_for(&mut ws, Duration::from_secs(10), |v| v["type"] == "frame").await["seq"]
        .as_u64()
        .unwrap();
    assert!(after > before);
    daemon.signal(libc::SIGTERM);
    assert!(daemon.wait_exit(Duration::from_secs(2)).unwrap().success());
}

#[test]
fn a_bad_config_exits_2_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.toml");
    std::fs::write(
        &path,
        "[server]\nlisten = \"127.0.0.1:1\"\n[takes]\nmin_free_mb = \"lots\"\n",
    )
    .unwrap();
    let out = crate::mouthpiece()
        .arg("run")
        .arg("--config")
        .arg(&path)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("bad.toml:4:") && stderr.contains("takes.min_free_mb"),
        "{stderr}"
    );

    // A character file that does not exist: named by its key.
    std::fs::write(&path, "[characters]\nfiles = [\"nope.toml\"]\n").unwrap();
    let out = crate::mouthpiece()
        .arg("run")
        .arg("--config")
        .arg(&path)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("characters.files[0]") && stderr.contains("nope.toml"),
        "{stderr}"
    );
}

#[test]
fn systemd_gets_ready_watchdog_status_and_stopping() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("s.mcap");
    write_session(&session, 30);
    let socket_path = dir.path().join("notify.sock");
    let socket = UnixDatagram::bind(&socket_path).unwrap();
    socket
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    let mut daemon = Daemon::start(
        &format!("replay:{}?loop=1", session.display()),
        "",
        &[],
        &[
            ("NOTIFY_SOCKET", socket_path.to_str().unwrap()),
            ("WATCHDOG_USEC", "400000"),
        ],
    );
    let mut seen = Vec::new();
    let mut buf = [0u8; 4096];
    let deadline = Instant::now() + Duration::from_secs(10);
    while Instant::now() < deadline
        && !(seen.iter().any(|m: &String| m.starts_with("READY=1"))
            && seen.iter().filter(|m| *m == "WATCHDOG=1").count() >= 2)
    {
        if let Ok(n) = socket.recv(&mut buf) {
            seen.push(String::from_utf8_lossy(&buf[..n]).into_owned());
        }
    }
    assert!(
        seen.iter().any(|m| m.starts_with("READY=1\nSTATUS=")),
        "{seen:?}"
    );
    assert!(
        seen.iter().filter(|m| *m == "WATCHDOG=1").count() >= 2,
        "{seen:?}"
    );
    daemon.signal(libc::SIGTERM);
    let mut stopping = false;
    while let Ok(n) = socket.recv(&mut buf) {
        if &buf[..n] == b"STOPPING=1" {
            stopping = true;
            break;
        }
    }
    assert!(stopping, "no STOPPING=1");
    assert!(daemon.wait_exit(Duration::from_secs(2)).unwrap().success());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sighup_reloads_characters_without_dropping_clients_and_keeps_the_old_on_error() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("s.mcap");
    write_session(&session, 60);
    let repo = crate::repo();
    let wolf = repo
        .join("config/characters/wolf.toml")
        .canonicalize()
        .unwrap();
    let mut daemon = Daemon::start(
        &format!("replay:{}?loop=1", session.display()),
        "",
        &[],
        &[],
    );
    let config_path = daemon.dir.path().join("mouthpiece.toml");
    let original = std::fs::read_to_string(&config_path).unwrap();
    let mut ws = daemon.connect().await;
    wait_for(&mut ws, Duration::from_secs(10), |v| {
        v["type"] == "hello" && v["characters"].as_array().unwrap().len() == 2
    })
    .await;

    std::fs::write(
        &config_path,
        format!("{original}[characters]\nfiles = [\"{}\"]\n", wolf.display()),
    )
    .unwrap();
    daemon.signal(libc::SIGHUP);
    let hello = wait_for(&mut ws, Duration::from_secs(10), |v| v["type"] == "hello").await;
    let names: Vec<&str> = hello["characters"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["wolf"], "{hello}");
    // Frames published before the reload may still be on their way.
    wait_for(&mut ws, Duration::from_secs(10), |v| {
        v["type"] == "frame" && v["characters"].as_array().unwrap().len() == 1
    })
    .await;

    // A broken file is rejected: the daemon keeps running with the wolf, the client stays.
    std::fs::write(
        &config_path,
        format!("{original}[characters]\nfiles = [\"missing.toml\"]\n"),
    )
    .unwrap();
    daemon.signal(libc::SIGHUP);
    tokio::time::sleep(Duration::from_millis(500)).await;
    let frame = wait_for(&mut ws, Duration::from_secs(10), |v| v["type"] == "frame").await;
    let in_frame: Vec<&str> = frame["characters"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["name"].as_str().unwrap())
        .collect();
    assert_eq!(in_frame, ["wolf"], "{frame}");
    assert!(
        daemon.log().contains("new configuration rejected"),
        "{}",
        daemon.log()
    );
    assert!(daemon.process.0.try_wait().unwrap().is_none());
    daemon.signal(libc::SIGTERM);
    assert!(daemon.wait_exit(Duration::from_secs(2)).unwrap().success());
}

async fn connect_with_token(
    port: u16,
    token: &str,
) -> Result<Client, tokio_tungstenite::tungstenite::Error> {
    let mut request = format!("ws://127.0.0.1:{port}/")
        .into_client_request()
        .unwrap();
    request.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        HeaderValue::from_str(&format!("mouthpiece.v1, mouthpiece.token.{token}")).unwrap(),
    );
    let (mut ws, _) = tokio_tungstenite::connect_async(request).await?;
    send(&mut ws, json!({"type": "subscribe"})).await;
    Ok(ws)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sighup_replaces_tokens_and_connected_clients_stay() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("s.mcap");
    write_session(&session, 60);
    let daemon_dir = tempfile::tempdir().unwrap();
    std::fs::write(
        daemon_dir.path().join("read.token"),
        "old-read-token-0123456789\n",
    )
    .unwrap();
    std::fs::write(
        daemon_dir.path().join("control.token"),
        "old-control-token-0123456789\n",
    )
    .unwrap();
    let mut daemon = Daemon::start(
        &format!("replay:{}?loop=1", session.display()),
        "",
        &[],
        &[],
    );
    // Rewrite the config with tokens in files next to it, then restart on it.
    let config_path = daemon.dir.path().join("mouthpiece.toml");
    let text = std::fs::read_to_string(&config_path).unwrap().replace(
        "[server]\n",
        &format!(
            "[server]\nread_token = {{ file = \"{0}/read.token\" }}\ncontrol_token = {{ file = \"{0}/control.token\" }}\n",
            daemon_dir.path().display()
        ),
    );
    daemon.signal(libc::SIGTERM);
    daemon.wait_exit(Duration::from_secs(2)).unwrap();
    let port = daemon.port;
    let dir_kept = std::mem::replace(&mut daemon.dir, tempfile::tempdir().unwrap());
    std::fs::write(dir_kept.path().join("mouthpiece.toml"), text).unwrap();
    let mut daemon = Daemon::start_in(dir_kept, port, &[], &[]);

    assert!(connect_with_token(port, "wrong-token-0123456789")
        .await
        .is_err());
    let mut old_client = connect_with_token(port, "old-read-token-0123456789")
        .await
        .unwrap();
    wait_for(&mut old_client, Duration::from_secs(10), |v| {
        v["type"] == "frame"
    })
    .await;

    std::fs::write(
        daemon_dir.path().join("read.token"),
        "new-read-token-0123456789\n",
    )
    .unwrap();
    daemon.signal(libc::SIGHUP);
    let deadline = Instant::now() + Duration::from_secs(10);
    while connect_with_token(port, "old-read-token-0123456789")
        .await
        .is_ok()
    {
        assert!(
            Instant::now() < deadline,
            "old token still accepted\n{}",
            daemon.log()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let mut new_client = connect_with_token(port, "new-read-token-0123456789")
        .await
        .unwrap();
    wait_for(&mut new_client, Duration::from_secs(10), |v| {
        v["type"] == "frame"
    })
    .await;
    // The client connected with the old token was not dropped.
    wait_for(&mut old_client, Duration::from_secs(10), |v| {
        v["type"] == "frame"
    })
    .await;
    assert!(
        !daemon.log().contains("new-read-token"),
        "a token was logged"
    );
    daemon.signal(libc::SIGTERM);
    assert!(daemon.wait_exit(Duration::from_secs(2)).unwrap().success());
}

/// The wolf's points in a `frame` message, or `None` while it is not tracked yet (most of its
/// points must be seen: on a loaded test machine the daemon skips frames, and a dot may be
/// missing now and then).
fn tracked_wolf(frame: &Value) -> Option<Vec<[f64; 3]>> {
    let wolf = frame["characters"]
        .as_array()?
        .iter()
        .find(|c| c["name"] == "wolf")?;
    let seen = wolf["confidence"]
        .as_array()?
        .iter()
        .all(|c| c.as_f64() > Some(0.5));
    seen.then(|| {
        wolf["points"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| [0, 1, 2].map(|k| p[k].as_f64().unwrap()))
            .collect()
    })
}

/// Largest distance between matching points of two poses.
fn largest_move(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>().sqrt())
        .fold(0.0, f64::max)
}

/// README's main job: `mouthpiece run` with no config replays the demo session through the
/// whole pipeline; a client sees the performer tracked and the wolf's mouth moving, and so
/// does the viewer page in a real browser (headless Chromium).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_embedded_default_shows_the_performer_and_the_wolf_moving() {
    let port = free_port();
    let listen = format!("127.0.0.1:{port}");
    let daemon = Daemon::start_in(
        tempfile::tempdir().unwrap(),
        port,
        &["--listen", &listen],
        &[],
    );
    let mut ws = daemon.connect().await;
    send(
        &mut ws,
        json!({"type": "subscribe", "fields": ["performer"]}),
    )
    .await;
    // The demo starts with its neutral second; after calibration the wolf is driven.
    let first = wait_for(&mut ws, Duration::from_secs(20), |v| {
        v["type"] == "frame" && tracked_wolf(v).is_some()
    })
    .await;
    let performer = first["performer"]["points"]
        .as_array()
        .expect("performer points");
    assert_eq!(performer.len(), 12, "{first}");
    let wolf_first = tracked_wolf(&first).unwrap();
    let width = wolf_first
        .iter()
        .flat_map(|p| wolf_first.iter().map(move |q| largest_move(&[*p], &[*q])))
        .fold(0.0, f64::max);
    // Over the next 3 s of speech the wolf's mouth moves by a visible share of its width.
    let mut moved: f64 = 0.0;
    let deadline = Instant::now() + Duration::from_secs(3);
    while Instant::now() < deadline {
        let f = wait_for(&mut ws, Duration::from_secs(5), |v| v["type"] == "frame").await;
        if let Some(wolf) = tracked_wolf(&f) {
            moved = moved.max(largest_move(&wolf_first, &wolf));
        }
    }
    // The wolf turns its head to a viewpoint in front of it, a little to its left.
    send(
        &mut ws,
        json!({"type": "look_at", "id": 9, "character": "wolf", "point": [0.8, -2.5, 0.5]}),
    )
    .await;
    let looked = wait_for(&mut ws, Duration::from_secs(5), |v| v["type"] == "result").await;
    assert_eq!(looked["detail"]["in_reach"], true, "{looked}");
    let wolf_head = |v: &Value| {
        v["characters"]
            .as_array()
            .and_then(|c| c.iter().find(|c| c["name"] == "wolf"))
            .map(|c| c["head"].clone())
            .unwrap_or(Value::Null)
    };
    let turned = wait_for(&mut ws, Duration::from_secs(10), |v| {
        v["type"] == "frame" && wolf_head(v)["mode"] == "look_at" && wolf_head(v)["progress"] == 1.0
    })
    .await;
    assert_eq!(wolf_head(&turned)["in_reach"], true, "{turned}");
    assert!(
        moved > 0.05 * width,
        "the wolf's mouth hardly moves: {moved} against a width of {width}\n{}",
        daemon.log()
    );

    // The viewer page: connected, performer and both characters drawn, and moving.
    let page = format!("http://{listen}/");
    let state = tokio::task::spawn_blocking(move || {
        let profile = tempfile::tempdir().unwrap();
        let driver = webdriver::open_page(&page, profile.path());
        let read = || {
            driver.script(
                "const m = window.mouthpiece; if (!m || !m.frame) return null; \
                 const w = m.frame.characters.find(c => c.name === 'wolf'); \
                 return {frames: m.frames, errors: m.errors.length, \
                 performer: m.frame.performer ? m.frame.performer.points.length : 0, \
                 characters: m.frame.characters.map(c => c.name), \
                 wolf: w ? w.points : null, wolf_seen: w ? w.confidence.filter(c => c > 0.5).length : 0};",
            )
        };
        let deadline = Instant::now() + Duration::from_secs(30);
        let a = loop {
            let s = read();
            if s["frames"].as_u64().unwrap_or(0) >= 30 && s["wolf_seen"].as_u64() >= Some(9)
            {
                break s;
            }
            assert!(
                Instant::now() < deadline,
                "the page shows no tracked frames: {s}"
            );
            std::thread::sleep(Duration::from_millis(200));
        };
        let shot_a = webdriver::element_screenshot(&driver, "#view");
        std::thread::sleep(Duration::from_millis(700));
        let b = read();
        let shot_b = webdriver::element_screenshot(&driver, "#view");
        (a, b, shot_a != shot_b)
    })
    .await
    .unwrap();
    let (a, b, redrawn) = state;
    assert_eq!(a["errors"], 0, "{a}");
    assert_eq!(a["performer"], 12, "{a}");
    assert_eq!(a["characters"], json!(["human", "wolf"]), "{a}");
    assert_ne!(a["wolf"], b["wolf"], "the wolf moves on the page");
    assert!(redrawn, "the canvas changes between two moments");
}

/// The human's points in a `frame` message when every one is seen.
fn tracked_human(frame: &Value) -> Option<Vec<[f64; 3]>> {
    let human = frame["characters"]
        .as_array()?
        .iter()
        .find(|c| c["name"] == "human")?;
    let seen = human["confidence"]
        .as_array()?
        .iter()
        .all(|c| c.as_f64() > Some(0.5));
    seen.then(|| {
        human["points"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| [0, 1, 2].map(|k| p[k].as_f64().unwrap()))
            .collect()
    })
}

/// `calibrate` is answered when the neutral pose has been taken over its `duration_s` (not at
/// once); a replay without `loop=1` that ends and is reopened starts its clock again: the
/// status shows the source going down and up, and soon after it is back the characters are
/// tracked again (new points every frame, not the last ones repeated), on the neutral pose
/// already taken.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn calibrate_answers_once_calibrated_and_a_reopened_replay_is_tracked_again() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("s.mcap");
    // 1.5 s of still, closed mouth, then speech.
    let synth = crate::mouthpiece()
        .args(["synth", "--seconds", "3", "--seed", "1", "--out"])
        .arg(&session)
        .output()
        .unwrap();
    assert!(
        synth.status.success(),
        "{}",
        String::from_utf8_lossy(&synth.stderr)
    );
    let spec = format!("replay:{}", session.display());
    let daemon = Daemon::start_with_dir(dir, &spec, "", &[], &[]);
    let mut ws = daemon.connect().await;
    wait_for(&mut ws, Duration::from_secs(10), |v| v["type"] == "frame").await;
    let asked = Instant::now();
    send(
        &mut ws,
        json!({"type": "calibrate", "id": 7, "duration_s": 0.5}),
    )
    .await;
    let answer = wait_for(&mut ws, Duration::from_secs(20), |v| {
        v["id"] == 7 && (v["type"] == "result" || v["type"] == "error")
    })
    .await;
    let waited = asked.elapsed();
    assert_eq!(answer["type"], "result", "{answer}\n{}", daemon.log());
    assert_eq!(answer["detail"]["calibrated"], true, "{answer}");
    assert!(
        waited >= Duration::from_millis(450),
        "answered after {waited:?}, before half a second of frames"
    );

    // The replay ends after 3 s and is reopened 0.2 s later, its clock back at 0.
    wait_for(&mut ws, Duration::from_secs(10), |v| {
        v["type"] == "status" && v["source"] == "down"
    })
    .await;
    wait_for(&mut ws, Duration::from_secs(10), |v| {
        v["type"] == "status" && v["source"] == "up"
    })
    .await;
    let up = Instant::now();
    let mut previous: Option<Vec<[f64; 3]>> = None;
    loop {
        let f = wait_for(&mut ws, Duration::from_secs(5), |v| v["type"] == "frame").await;
        let now = tracked_human(&f);
        if let (Some(a), Some(b)) = (&previous, &now) {
            if a != b {
                break;
            }
        }
        previous = now;
        assert!(
            up.elapsed() < Duration::from_secs(3),
            "not tracked again after the restart: {f}\n{}",
            daemon.log()
        );
    }
    assert!(
        !daemon.log().contains("recalibrating"),
        "the same performer kept the neutral pose\n{}",
        daemon.log()
    );
}

fn python() -> String {
    std::env::var("MOUTHPIECE_PYTHON").unwrap_or_else(|_| "python3".into())
}

/// `GET path` on the daemon's port: the body.
fn http_body(port: u16, path: &str) -> String {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut text = String::new();
    s.read_to_string(&mut text).unwrap();
    text.split_once("\r\n\r\n")
        .map(|(_, body)| body.to_owned())
        .unwrap_or_default()
}

/// A per-target OSC counter from `/metrics` (`None` when the target is not listed).
fn osc_counter(metrics: &str, name: &str, target: &str) -> Option<u64> {
    let prefix = format!("{name}{{target=\"{target}\"}} ");
    metrics
        .lines()
        .find_map(|l| l.strip_prefix(&prefix))
        .map(|v| v.trim().parse().unwrap())
}

/// The wolf's `t`, `rig` and `head` of every frame for `seconds` (JSON lines for the OSC
/// receiver) and the largest `jawOpen` among frames received after `settle`.
async fn collect_wolf(ws: &mut Client, seconds: f64, settle: f64, lines: &mut Vec<String>) -> f64 {
    let started = Instant::now();
    let mut jaw: f64 = 0.0;
    while started.elapsed().as_secs_f64() < seconds {
        let f = wait_for(ws, Duration::from_secs(5), |v| v["type"] == "frame").await;
        let Some(wolf) = f["characters"]
            .as_array()
            .and_then(|c| c.iter().find(|c| c["name"] == "wolf"))
        else {
            continue;
        };
        lines.push(json!({"t": f["t"], "rig": wolf["rig"], "head": wolf["head"]}).to_string());
        if started.elapsed().as_secs_f64() >= settle {
            if let Some(v) = wolf["rig"]["curves"]["jawOpen"].as_f64() {
                jaw = jaw.max(v);
            }
        }
    }
    jaw
}

/// `[osc]`: the daemon replays the demo session and sends the wolf's rig curves (PascalCase,
/// `names = "arkit-pascal"`), visemes (VRM 1.0 names, `visemes = "vrm1"`), head and
/// eyes as VMC protocol messages to a receiver written with python-osc
/// (`tests/python/vmc_receiver.py`), which checks the messages and compares them with the
/// WebSocket frames of the same times. A second target where nothing listens is counted and
/// changes nothing. SIGHUP applies a new `[rig]` range at once and new `[osc]` targets; a bad
/// target is refused and the old ones kept.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn osc_sends_the_streamed_rig_to_a_python_osc_receiver_and_rig_and_osc_reload_on_sighup() {
    let repo = crate::repo();
    let work = tempfile::tempdir().unwrap();
    let (port_file, stop_file, stream_file) = (
        work.path().join("port"),
        work.path().join("stop"),
        work.path().join("stream.jsonl"),
    );
    let wolf = mouthpiece_retarget::Character::from_toml_str(
        &std::fs::read_to_string(repo.join("config/characters/wolf.toml")).unwrap(),
    )
    .unwrap();
    let axes: Vec<Vec<f64>> = (0..3)
        .map(|r| (0..3).map(|c| wolf.frame.axes[(r, c)]).collect())
        .collect();
    let receiver = Command::new(python())
        .arg(repo.join("tests/python/vmc_receiver.py"))
        .arg("--port-file")
        .arg(&port_file)
        .arg("--stop-file")
        .arg(&stop_file)
        .arg("--stream")
        .arg(&stream_file)
        .args(["--axes", &json!(axes).to_string(), "--eyes"])
        .args(["--names", "arkit-pascal", "--visemes", "vrm1"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("running Python (set MOUTHPIECE_PYTHON)");
    let mut receiver = Guarded(receiver);
    let deadline = Instant::now() + Duration::from_secs(30);
    let osc_port: u16 = loop {
        if let Ok(text) = std::fs::read_to_string(&port_file) {
            break text.trim().parse().unwrap();
        }
        if let Some(status) = receiver.0.try_wait().unwrap() {
            let out = receiver.0.wait_with_output_now();
            panic!("the python-osc receiver ended ({status}): {out}");
        }
        assert!(
            Instant::now() < deadline,
            "the python-osc receiver did not start"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    // A port nothing listens on: the kernel refuses datagrams sent there.
    let closed = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let live = format!("127.0.0.1:{osc_port}");
    let refused = format!("127.0.0.1:{closed}");
    let config = |targets: &str, jaw_range: f64| {
        format!(
            "[osc]\ntargets = [{targets}]\ncharacter = \"wolf\"\nnames = \"arkit-pascal\"\nvisemes = \"vrm1\"\n[rig.ranges]\njawOpen = {jaw_range}\n"
        )
    };
    let both = format!("\"{refused}\", \"{live}\"");
    let demo = repo.join("recordings/demo.mcap").canonicalize().unwrap();
    let mut daemon = Daemon::start(
        &format!("replay:{}?loop=1", demo.display()),
        &config(&both, 1000.0),
        &[],
        &[],
    );
    let config_path = daemon.dir.path().join("mouthpiece.toml");
    let original = std::fs::read_to_string(&config_path).unwrap();
    let base = original.split("[osc]").next().unwrap().to_owned();
    let mut ws = daemon.connect().await;
    send(
        &mut ws,
        json!({"type": "subscribe", "fields": ["rig"], "characters": ["wolf"]}),
    )
    .await;
    // After the neutral second the rig is there.
    wait_for(&mut ws, Duration::from_secs(20), |v| {
        v["type"] == "frame" && v["characters"][0]["rig"].is_object()
    })
    .await;
    let mut lines = Vec::new();
    // A jaw range of 1000° keeps jawOpen near 0 ...
    let before = collect_wolf(&mut ws, 2.0, 0.0, &mut lines).await;
    assert!(before < 0.05, "jawOpen {before} with a 1000° range");
    // ... and after a reload to 2° every opening saturates it: no restart, clients stay.
    std::fs::write(&config_path, format!("{base}{}", config(&both, 2.0))).unwrap();
    daemon.signal(libc::SIGHUP);
    let after = collect_wolf(&mut ws, 3.0, 0.5, &mut lines).await;
    assert!(
        after > 0.9,
        "jawOpen at most {after} after the reload to a 2° range\n{}",
        daemon.log()
    );
    std::fs::write(&stream_file, lines.join("\n") + "\n").unwrap();

    // Both targets counted: the receiver's datagrams sent, the closed port's refusals.
    let metrics = http_body(daemon.port, "/metrics");
    let sent = osc_counter(&metrics, "mouthpiece_osc_sent_total", &live).unwrap();
    assert!(sent >= 60, "{metrics}");
    assert_eq!(
        osc_counter(&metrics, "mouthpiece_osc_errors_total", &live),
        Some(0),
        "{metrics}"
    );
    let errors = osc_counter(&metrics, "mouthpiece_osc_errors_total", &refused).unwrap();
    assert!(errors > 0, "{metrics}");
    let health: Value = serde_json::from_str(&http_body(daemon.port, "/healthz")).unwrap();
    assert_eq!(health["osc"]["targets"][1]["target"], live, "{health}");

    // A target that is not host:port is refused on reload; the old targets go on.
    std::fs::write(
        &config_path,
        format!("{base}{}", config("\"127.0.0.1:70000\"", 2.0)),
    )
    .unwrap();
    daemon.signal(libc::SIGHUP);
    let deadline = Instant::now() + Duration::from_secs(10);
    while !daemon.log().contains("new configuration rejected") {
        assert!(Instant::now() < deadline, "{}", daemon.log());
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(daemon.log().contains("osc.targets[0]"), "{}", daemon.log());
    tokio::time::sleep(Duration::from_millis(300)).await;
    let later = osc_counter(
        &http_body(daemon.port, "/metrics"),
        "mouthpiece_osc_sent_total",
        &live,
    )
    .unwrap();
    assert!(later > sent, "{later} after {sent}");

    // The receiver's target removed: it is no longer listed (or sent to).
    std::fs::write(
        &config_path,
        format!("{base}{}", config(&format!("\"{refused}\""), 2.0)),
    )
    .unwrap();
    daemon.signal(libc::SIGHUP);
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let metrics = http_body(daemon.port, "/metrics");
        if osc_counter(&metrics, "mouthpiece_osc_sent_total", &live).is_none() {
            assert!(
                osc_counter(&metrics, "mouthpiece_osc_errors_total", &refused).unwrap() >= errors,
                "{metrics}"
            );
            break;
        }
        assert!(Instant::now() < deadline, "{metrics}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // Still streaming, still running.
    wait_for(&mut ws, Duration::from_secs(5), |v| v["type"] == "frame").await;
    assert!(daemon.process.0.try_wait().unwrap().is_none());

    std::fs::write(&stop_file, "").unwrap();
    let out = receiver.0.wait_with_output_now();
    let code = receiver.0.try_wait().unwrap();
    assert!(
        code.is_some_and(|c| c.success()),
        "the python-osc receiver's checks failed ({code:?}):\n{out}"
    );
    let summary: Value = serde_json::from_str(out.lines().next().unwrap_or("")).unwrap();
    assert!(summary["matched"].as_u64() >= Some(60), "{summary}");
    assert!(
        summary["matched_with_rig"].as_u64() >= Some(60),
        "{summary}"
    );
    assert!(summary["max_jaw_open"].as_f64() > Some(0.9), "{summary}");
    daemon.signal(libc::SIGTERM);
    assert!(daemon.wait_exit(Duration::from_secs(2)).unwrap().success());
}

/// A child process killed when the test ends early.
struct Guarded(Child);

impl Drop for Guarded {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

trait WaitOutput {
    /// Waits (at most 60 s) for the child's exit and returns its stdout then stderr.
    fn wait_with_output_now(&mut self) -> String;
}

impl WaitOutput for Child {
    fn wait_with_output_now(&mut self) -> String {
        use std::io::Read;
        let deadline = Instant::now() + Duration::from_secs(60);
        while self.try_wait().unwrap().is_none() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(50));
        }
        let mut out = String::new();
        if let Some(s) = self.stdout.as_mut() {
            let _ = s.read_to_string(&mut out);
        }
        if let Some(s) = self.stderr.as_mut() {
            let _ = s.read_to_string(&mut out);
        }
        out
    }
}

/// Angle in degrees between the rotations of two unit quaternions `[w, x, y, z]` (without
/// acos's loss of precision near 1).
fn quat_angle_deg(a: [f64; 4], b: [f64; 4]) -> f64 {
    let dot: f64 = a.iter().zip(&b).map(|(p, q)| p * q).sum();
    let s = if dot < 0.0 { -1.0 } else { 1.0 };
    let norm = |f: &dyn Fn(f64, f64) -> f64| {
        a.iter()
            .zip(&b)
            .map(|(p, q)| f(*p, s * q).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    (4.0 * norm(&|p, q| p - q).atan2(norm(&|p, q| p + q))).to_degrees()
}

/// A take of the demo recorded by the daemon while a client turns the wolf's head to a
/// viewpoint over the WebSocket: `mouthpiece export` of that take (which runs the tracker
/// again, knowing nothing of the request) keeps the turn, as the take recorded it: the
/// exported head ends where the live stream's did, far from where it started.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_take_exported_keeps_the_look_at_turn_made_live() {
    let repo = crate::repo();
    let demo = repo.join("recordings/demo.mcap").canonicalize().unwrap();
    let mut daemon = Daemon::start(
        &format!("replay:{}?loop=1", demo.display()),
        "",
        &["--record", "turn"],
        &[],
    );
    let mut ws = daemon.connect().await;
    let wolf_head = |v: &Value| {
        v["characters"]
            .as_array()
            .and_then(|c| c.iter().find(|c| c["name"] == "wolf"))
            .map(|c| c["head"].clone())
            .unwrap_or(Value::Null)
    };
    let quat = |v: &Value| -> [f64; 4] { [0, 1, 2, 3].map(|k| v[k].as_f64().unwrap()) };
    // After the neutral second the wolf is driven, its head following the performer's.
    wait_for(&mut ws, Duration::from_secs(30), |v| {
        v["type"] == "frame" && tracked_wolf(v).is_some()
    })
    .await;
    send(
        &mut ws,
        json!({"type": "look_at", "id": 9, "character": "wolf", "point": [0.8, -2.5, 0.5]}),
    )
    .await;
    let looked = wait_for(&mut ws, Duration::from_secs(5), |v| v["type"] == "result").await;
    assert_eq!(looked["detail"]["in_reach"], true, "{looked}");
    let turned = wait_for(&mut ws, Duration::from_secs(10), |v| {
        v["type"] == "frame" && wolf_head(v)["mode"] == "look_at" && wolf_head(v)["progress"] == 1.0
    })
    .await;
    let faced = quat(&wolf_head(&turned)["rotation"]);
    // A few more frames facing the viewpoint, then the take stops.
    for _ in 0..10 {
        wait_for(&mut ws, Duration::from_secs(5), |v| v["type"] == "frame").await;
    }
    send(
        &mut ws,
        json!({"type": "record", "id": 2, "action": "stop"}),
    )
    .await;
    let stopped = wait_for(&mut ws, Duration::from_secs(10), |v| {
        (v["type"] == "result" || v["type"] == "error") && v["id"] == 2
    })
    .await;
    assert_eq!(stopped["type"], "result", "{stopped}");
    daemon.signal(libc::SIGTERM);
    assert!(daemon.wait_exit(Duration::from_secs(5)).is_some());
    let files = takes_in(daemon.dir.path());
    assert_eq!(files.len(), 1, "{files:?}\n{}", daemon.log());

    let csv = daemon.dir.path().join("take.csv");
    let text = crate::live_record::export_as_recorded(&files[0], "wolf", &csv);
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let qw = header
        .iter()
        .position(|c| *c == "head_qw")
        .expect("head columns");
    let heads: Vec<[f64; 4]> = lines
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            [0, 1, 2, 3].map(|k| cells[qw + k].parse().unwrap())
        })
        .collect();
    assert!(heads.len() >= 30, "{} rows", heads.len());
    let last = *heads.last().unwrap();
    // The export ends facing the viewpoint as the live stream did (the take holds 32-bit
    // floats), ...
    let off = quat_angle_deg(last, faced);
    assert!(
        off < 0.01,
        "the exported head ends {off:.2}° from the live one: {last:?} against {faced:?}"
    );
    // ... which is a turn: the head was somewhere else when the take began.
    let turn = quat_angle_deg(heads[0], last);
    assert!(turn > 10.0, "the exported head turned only {turn:.2}°");
}

/// `mouthpiece export TAKE --character wolf --out OUT`.
/// What was live is what is kept: a take's export is, frame for frame, what a WebSocket
/// subscriber received while it was recorded: every mouth point and every rig curve the same
/// 32-bit float, with no frame re-tracked (a re-run of the tracker recalibrates and differs).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_takes_export_is_what_subscribers_received_live() {
    let repo = crate::repo();
    let demo = repo.join("recordings/demo.mcap").canonicalize().unwrap();
    let mut daemon = Daemon::start(&format!("replay:{}?loop=1", demo.display()), "", &[], &[]);
    let mut ws = daemon
        .connect_with(json!({"type": "subscribe", "fields": ["rig"]}))
        .await;
    let wolf = |v: &Value| -> Option<Value> {
        v["characters"]
            .as_array()?
            .iter()
            .find(|c| c["name"] == "wolf")
            .cloned()
    };
    wait_for(&mut ws, Duration::from_secs(60), |v| {
        v["type"] == "frame" && wolf(v).is_some_and(|w| w["rig"].is_object())
    })
    .await;
    // Every frame from here on, by seq: the wolf's points and curves as received.
    let mut live = crate::live_record::LiveSteps::new();
    let keep = |v: &Value, live: &mut crate::live_record::LiveSteps| {
        crate::live_record::keep(v, "wolf", live)
    };
    send(
        &mut ws,
        json!({"type": "record", "id": 1, "action": "start", "slate": "live"}),
    )
    .await;
    let mut started = false;
    let mut frames_in_take = 0;
    while frames_in_take < 90 {
        let v = next_json(&mut ws, Duration::from_secs(10)).await;
        if v["type"] == "result" && v["id"] == 1 {
            started = true;
        }
        keep(&v, &mut live);
        if started && v["type"] == "frame" {
            frames_in_take += 1;
        }
    }
    send(
        &mut ws,
        json!({"type": "record", "id": 2, "action": "stop"}),
    )
    .await;
    loop {
        let v = next_json(&mut ws, Duration::from_secs(10)).await;
        keep(&v, &mut live);
        if v["id"] == 2 {
            assert_eq!(v["type"], "result", "{v}");
            break;
        }
    }
    daemon.signal(libc::SIGTERM);
    assert!(daemon.wait_exit(Duration::from_secs(10)).is_some());
    let files = takes_in(daemon.dir.path());
    assert_eq!(files.len(), 1, "{files:?}\n{}", daemon.log());

    let csv = daemon.dir.path().join("take.csv");
    let text = crate::live_record::export_as_recorded(&files[0], "wolf", &csv);
    let rows = crate::live_record::assert_rows_are_live(&text, &live);
    assert!(rows.len() >= 80, "{} rows", rows.len());

    // `play` of the same take sends, over VMC, the curves, visemes, head and eyes the
    // WebSocket carried (checked by the independent python-osc receiver, float32 exact).
    let stream: Vec<Value> = rows
        .iter()
        .filter_map(|(seq, t)| {
            let frame = live.get(seq)?;
            Some(json!({"t": t, "rig": frame["rig"], "head": frame["head"]}))
        })
        .collect();
    let work = daemon.dir.path().join("play");
    std::fs::create_dir_all(&work).unwrap();
    let summary = crate::lipsync::play_against_stream(
        &files[0],
        &repo.join("config/characters/wolf.toml"),
        &stream,
        &work,
    );
    assert!(
        summary["matched_with_rig"].as_u64().unwrap() >= rows.len() as u64 / 2,
        "{summary}"
    );
}

/// What a running daemon sends (hello, status, health, frames with every field, pong) is
/// valid under docs/schemas, checked by Python's `jsonschema`: the field names and enum
/// spellings the docs promise are the wire's.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_daemons_messages_match_the_published_schemas() {
    use std::io::Write as _;
    let repo = crate::repo();
    let demo = repo.join("recordings/demo.mcap").canonicalize().unwrap();
    let daemon = Daemon::start(&format!("replay:{}?loop=1", demo.display()), "", &[], &[]);
    let mut ws = daemon
        .connect_with(
            json!({"type": "subscribe", "fields": ["rig", "curve", "performer", "health"]}),
        )
        .await;
    let mut messages = Vec::new();
    let mut frames_with_rig = 0;
    let deadline = Instant::now() + Duration::from_secs(60);
    while frames_with_rig < 5 || !messages.iter().any(|m: &Value| m["type"] == "health") {
        assert!(Instant::now() < deadline, "{messages:?}");
        let v = next_json(&mut ws, Duration::from_secs(10)).await;
        if v["type"] == "frame"
            && v["characters"]
                .as_array()
                .is_some_and(|c| c.iter().all(|c| c["rig"].is_object()))
        {
            frames_with_rig += 1;
        }
        messages.push(v);
    }
    send(&mut ws, json!({"type": "ping", "id": "p1"})).await;
    messages.push(wait_for(&mut ws, Duration::from_secs(10), |v| v["type"] == "pong").await);
    let hello = messages
        .iter()
        .find(|m| m["type"] == "hello")
        .expect("hello");
    for character in hello["characters"].as_array().unwrap() {
        assert_eq!(character["m_mode"], "per-point", "{character}");
    }
    let file = daemon.dir.path().join("messages.jsonl");
    let mut out = std::fs::File::create(&file).unwrap();
    for m in &messages {
        writeln!(out, "{}", json!({"dir": "server", "msg": m})).unwrap();
    }
    drop(out);
    let python = std::env::var("MOUTHPIECE_PYTHON").unwrap_or_else(|_| "python3".into());
    let checked = Command::new(python)
        .arg(repo.join("crates/server/tests/validate_schemas.py"))
        .arg(repo.join("docs/schemas"))
        .arg(&file)
        .arg("--partial")
        .output()
        .expect("running Python (set MOUTHPIECE_PYTHON)");
    assert!(
        checked.status.success(),
        "the daemon's messages do not match the schemas:\n{}\n{}",
        String::from_utf8_lossy(&checked.stdout),
        String::from_utf8_lossy(&checked.stderr)
    );
}

/// The 27 rig curves of a datagram from `[ifacialmocap]`, decoded from the published layout
/// (`name-value|…|=head#…`, `_L`/`_R` the side suffixes), as ARKit-named integers 0–100.
fn ifm_curves(text: &str) -> Vec<i64> {
    let (shapes, transforms) = text.split_once('=').expect("one '='");
    assert!(
        transforms.starts_with("head#") && text.ends_with('|'),
        "{text}"
    );
    let mut by_name = std::collections::HashMap::new();
    for field in shapes.split('|').filter(|f| !f.is_empty()) {
        let (name, value) = field.split_once('-').expect(field);
        let name = match (name.strip_suffix("_L"), name.strip_suffix("_R")) {
            (Some(stem), _) => format!("{stem}Left"),
            (_, Some(stem)) => format!("{stem}Right"),
            _ => name.to_owned(),
        };
        by_name.insert(name, value.parse::<i64>().expect(field));
    }
    assert_eq!(by_name.len(), 52, "{text}");
    mouthpiece_output::CURVE_NAMES
        .iter()
        .map(|n| by_name[*n])
        .collect()
}

/// `[ifacialmocap]` in the daemon: a receiver that sends the handshake gets the wolf's face,
/// and every datagram's 27 rig curves (×100, rounded) are a frame the WebSocket streamed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ifacialmocap_streams_the_streamed_rig_to_a_receiver_that_asks() {
    let repo = crate::repo();
    let demo = repo.join("recordings/demo.mcap").canonicalize().unwrap();
    let ifm_port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let daemon = Daemon::start(
        &format!("replay:{}?loop=1", demo.display()),
        &format!(
            "[ifacialmocap]\nenabled = true\nport = {ifm_port}\nreply_port = 0\ncharacter = \"wolf\"\n"
        ),
        &[],
        &[],
    );
    let mut ws = daemon.connect().await;
    send(
        &mut ws,
        json!({"type": "subscribe", "fields": ["rig"], "characters": ["wolf"]}),
    )
    .await;
    wait_for(&mut ws, Duration::from_secs(20), |v| {
        v["type"] == "frame" && v["characters"][0]["rig"].is_object()
    })
    .await;
    let peer = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    peer.set_read_timeout(Some(Duration::from_millis(20)))
        .unwrap();
    peer.send_to(b"not a handshake", ("127.0.0.1", ifm_port))
        .unwrap();
    peer.send_to(
        b"iFacialMocap_sahuasouryya9218sauhuiayeta91555dy3719",
        ("127.0.0.1", ifm_port),
    )
    .unwrap();
    let mut streamed = std::collections::HashSet::new();
    let mut datagrams = Vec::new();
    let started = Instant::now();
    let mut buf = [0u8; 4096];
    while started.elapsed() < Duration::from_secs(3) {
        let f = wait_for(&mut ws, Duration::from_secs(5), |v| v["type"] == "frame").await;
        if let Some(curves) = f["characters"][0]["rig"]["curves"].as_object() {
            let row: Vec<i64> = mouthpiece_output::CURVE_NAMES
                .iter()
                .map(|n| {
                    let v = curves[*n].as_f64().unwrap() as f32;
                    (v.clamp(0.0, 1.0) * 100.0).round() as i64
                })
                .collect();
            streamed.insert(row);
        }
        while let Ok((n, _)) = peer.recv_from(&mut buf) {
            datagrams.push(String::from_utf8(buf[..n].to_vec()).unwrap());
        }
    }
    // Frames published after the last WebSocket frame read are not compared.
    let received = datagrams.len();
    assert!(
        received >= 30,
        "{received} datagrams in 3 s\n{}",
        daemon.log()
    );
    let matched = datagrams
        .iter()
        .filter(|d| streamed.contains(&ifm_curves(d)))
        .count();
    assert!(
        matched * 10 >= received * 9,
        "{matched} of {received} datagrams match a streamed frame"
    );
    assert!(
        datagrams.iter().any(|d| ifm_curves(d)[0] > 0),
        "jawOpen never above 0"
    );
    // The output's counters are in `/metrics`: the handshake answered, the stray datagram
    // counted, the frames sent.
    let metrics = http_body(daemon.port, "/metrics");
    let counter = |name: &str| -> u64 {
        metrics
            .lines()
            .find_map(|l| l.strip_prefix(&format!("mouthpiece_ifacialmocap_{name} ")))
            .unwrap_or_else(|| panic!("no {name} in\n{metrics}"))
            .parse()
            .unwrap()
    };
    assert!(counter("handshakes_total") >= 1, "{metrics}");
    assert!(counter("malformed_total") >= 1, "{metrics}");
    assert!(counter("sent_total") > 0, "{metrics}");
    assert_eq!(counter("receivers"), 1, "{metrics}");
}
