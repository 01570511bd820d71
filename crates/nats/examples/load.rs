//! Load benchmark of the NATS path (docs/performance.md, *NATS*): N booths publish into one
//! `nats-server`, M subscribers take every booth's frames.
//!
//! Each booth is what the daemon runs: a hub fed by a thread at the frame rate (frames of the
//! demo's shape: human and wolf, 12 points each, curve, rig, performer) and a NATS link
//! publishing `.frame`, `.frame.bin` and `.rig.<character>`. Each subscriber is its own
//! connection subscribed to `mouthpiece.*.frame`. Latency is booth → subscriber: from the
//! frame's `wall_us` (stamped when the booth's processing thread published it to its hub)
//! to its arrival, wall clock of one machine. Frames lost by the broker path are the frames
//! the booths handed to NATS that a subscriber never got (sequence gaps and missing tails);
//! frames a booth dropped before NATS (its publisher fell behind) are counted apart.
//!
//! ```text
//! cargo run --release -p mouthpiece-nats --example load -- --booths 4 --subscribers 64
//! cargo run --release -p mouthpiece-nats --example load -- --matrix
//! ```
//!
//! Without `--server` it starts its own `nats-server` on a free loopback port.

use std::collections::HashMap;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use futures_util::StreamExt;
use mouthpiece_nats::{NatsLink, NatsSettings};
use mouthpiece_server::{
    CharacterFrame, CharacterInfo, Hub, HubConfig, PerformerFrame, RigState, StreamFrame,
    StreamInfo,
};

struct Options {
    booths: usize,
    subscribers: usize,
    seconds: f64,
    rate: f64,
    server: Option<String>,
    matrix: bool,
}

fn options() -> Options {
    let mut o = Options {
        booths: 4,
        subscribers: 64,
        seconds: 10.0,
        rate: 60.0,
        server: None,
        matrix: false,
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = || args.next().unwrap_or_else(|| panic!("{arg} needs a value"));
        match arg.as_str() {
            "--booths" => o.booths = value().parse().expect("--booths N"),
            "--subscribers" => o.subscribers = value().parse().expect("--subscribers N"),
            "--seconds" => o.seconds = value().parse().expect("--seconds S"),
            "--rate" => o.rate = value().parse().expect("--rate HZ"),
            "--server" => o.server = Some(value()),
            "--matrix" => o.matrix = true,
            other => panic!("unknown argument {other} (--booths --subscribers --seconds --rate --server --matrix)"),
        }
    }
    assert!(o.booths >= 1 && o.booths <= 64, "--booths 1..64");
    assert!(
        o.subscribers >= 1 && o.subscribers <= 512,
        "--subscribers 1..512"
    );
    assert!(o.seconds > 0.0 && o.seconds <= 600.0, "--seconds up to 600");
    assert!(o.rate > 0.0 && o.rate <= 1000.0, "--rate up to 1000");
    o
}

/// A `nats-server` of our own, killed on drop.
struct OwnServer(Child, #[allow(dead_code)] tempfile::TempDir);

impl Drop for OwnServer {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn own_server() -> (OwnServer, String) {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let dir = tempfile::tempdir().unwrap();
    let child = Command::new("nats-server")
        .args(["-a", "127.0.0.1", "-p", &port.to_string()])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("nats-server not found: apt-get install nats-server, or give --server URL");
    for _ in 0..500 {
        if std::net::TcpStream::connect(("127.0.0.1", port)).is_ok() {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    (OwnServer(child, dir), format!("nats://127.0.0.1:{port}"))
}

fn demo_frame() -> StreamFrame {
    let character = |name: &str| CharacterFrame {
        name: name.into(),
        points: (0..12).map(|i| [i as f32 * 0.01, 0.02, 0.03]).collect(),
        confidence: vec![1.0; 12],
        curve: Some((0..12).map(|i| [i as f32 * 0.01, 0.0, 0.0]).collect()),
        rig: Some(RigState::default()),
        head: None,
        source: Default::default(),
    };
    StreamFrame {
        characters: vec![character("human"), character("wolf")],
        performer: Some(PerformerFrame {
            points: vec![[0.01, 0.02, 0.6]; 12],
            confidence: vec![1.0; 12],
        }),
        ..StreamFrame::default()
    }
}

fn now_us() -> i64 {
    mouthpiece_nats::publish::unix_micros_now()
}

/// The integer after `"key":` in a frame's JSON (cheaper than parsing the frame).
fn field(json: &[u8], key: &str) -> Option<i64> {
    let needle = format!("\"{key}\":");
    let at = json
        .windows(needle.len())
        .position(|w| w == needle.as_bytes())?
        + needle.len();
    let digits: Vec<u8> = json[at..]
        .iter()
        .copied()
        .take_while(|b| b.is_ascii_digit() || *b == b'-')
        .collect();
    std::str::from_utf8(&digits).ok()?.parse().ok()
}

#[derive(Default)]
struct Received {
    latencies_us: Vec<u32>,
    /// Per booth: last seq and frames received.
    booths: HashMap<String, (i64, u64)>,
    gaps: u64,
}

struct Outcome {
    booths: usize,
    subscribers: usize,
    published: u64,
    booth_dropped: u64,
    expected: u64,
    delivered: u64,
    lost: u64,
    p50: f64,
    p99: f64,
    p999: f64,
    max: f64,
}

async fn run_once(
    url: &str,
    booths: usize,
    subscribers: usize,
    seconds: f64,
    rate: f64,
) -> Outcome {
    // Subscribers first, so that they see every frame.
    let (done_tx, done_rx) = tokio::sync::watch::channel(false);
    let mut tasks = Vec::new();
    for _ in 0..subscribers {
        let client = async_nats::ConnectOptions::new()
            .subscription_capacity(1 << 16)
            .connect(url)
            .await
            .unwrap();
        let mut sub = client.subscribe("mouthpiece.*.frame").await.unwrap();
        client.flush().await.unwrap();
        let mut done = done_rx.clone();
        tasks.push(tokio::spawn(async move {
            let _client = client;
            let mut got = Received::default();
            loop {
                let message = tokio::select! {
                    m = sub.next() => match m { Some(m) => m, None => break },
                    _ = done.changed() => break,
                };
                let arrived = now_us();
                let json = &message.payload;
                let (Some(seq), Some(wall)) = (field(json, "seq"), field(json, "wall_us")) else {
                    continue;
                };
                got.latencies_us
                    .push((arrived - wall).clamp(0, u32::MAX as i64) as u32);
                let entry = got
                    .booths
                    .entry(message.subject.to_string())
                    .or_insert((seq - 1, 0));
                if seq > entry.0 + 1 {
                    got.gaps += (seq - entry.0 - 1) as u64;
                }
                entry.0 = seq;
                entry.1 += 1;
            }
            got
        }));
    }
    let info = StreamInfo {
        characters: ["human", "wolf"]
            .iter()
            .map(|n| CharacterInfo {
                name: (*n).into(),
                ..CharacterInfo::default()
            })
            .collect(),
        frame_rate: rate,
        ..StreamInfo::default()
    };
    let stop = Arc::new(AtomicBool::new(false));
    let mut links = Vec::new();
    let mut threads = Vec::new();
    let mut hubs = Vec::new();
    for b in 0..booths {
        let (hub, _control) = Hub::new(&HubConfig::default());
        hub.set_info(info.clone());
        let mut settings = NatsSettings::new(vec![url.to_owned()], &format!("load{b}"));
        settings.upload_takes = false;
        let link = NatsLink::start(hub.clone(), settings, "load".into(), std::env::temp_dir())
            .await
            .unwrap();
        // Wait for the connection before frames flow.
        while !hub.nats().connected.load(Ordering::Relaxed) {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        links.push(link);
        hubs.push(hub);
    }
    for hub in &hubs {
        let (hub, stop) = (hub.clone(), stop.clone());
        let period = Duration::from_secs_f64(1.0 / rate);
        let total = (seconds * rate) as u64;
        threads.push(std::thread::spawn(move || {
            let mut frame = demo_frame();
            let start = std::time::Instant::now();
            for i in 0..total {
                if stop.load(Ordering::Relaxed) {
                    break;
                }
                frame.t = i as f64 / rate;
                frame.wall_us = Some(now_us());
                hub.publish(&frame);
                let due = start + period * (i as u32 + 1);
                if let Some(wait) = due.checked_duration_since(std::time::Instant::now()) {
                    std::thread::sleep(wait);
                }
            }
        }));
    }
    for t in threads {
        t.join().unwrap();
    }
    // Let the last frames arrive, then close the subscriptions.
    tokio::time::sleep(Duration::from_secs(2)).await;
    let mut published = 0;
    let mut booth_dropped = 0;
    for hub in &hubs {
        published += hub.nats().frames_published.load(Ordering::Relaxed);
        booth_dropped += hub.nats().frames_dropped.load(Ordering::Relaxed);
    }
    let _ = done_tx.send(true);
    drop(links);
    let mut latencies: Vec<u32> = Vec::new();
    let mut delivered = 0u64;
    let mut lost = 0u64;
    for task in tasks {
        let got = task.await.unwrap();
        latencies.extend_from_slice(&got.latencies_us);
        let received: u64 = got.booths.values().map(|(_, n)| n).sum();
        delivered += received;
        // Gaps inside the sequence, plus whatever never came at all.
        lost += got.gaps;
        let _ = received;
    }
    let expected = published * subscribers as u64;
    lost = lost.max(expected.saturating_sub(delivered));
    latencies.sort_unstable();
    let quantile = |q: f64| -> f64 {
        if latencies.is_empty() {
            return f64::NAN;
        }
        let i = ((latencies.len() as f64 - 1.0) * q).round() as usize;
        latencies[i] as f64 / 1e3
    };
    Outcome {
        booths,
        subscribers,
        published,
        booth_dropped,
        expected,
        delivered,
        lost,
        p50: quantile(0.5),
        p99: quantile(0.99),
        p999: quantile(0.999),
        max: quantile(1.0),
    }
}

fn print_header() {
    println!("| booths | subscribers | frames published | dropped at booths | deliveries expected | delivered | lost by broker path | p50 ms | p99 ms | p99.9 ms | max ms |");
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
}

fn print_row(o: &Outcome) {
    println!(
        "| {} | {} | {} | {} | {} | {} | {} | {:.2} | {:.2} | {:.2} | {:.2} |",
        o.booths,
        o.subscribers,
        o.published,
        o.booth_dropped,
        o.expected,
        o.delivered,
        o.lost,
        o.p50,
        o.p99,
        o.p999,
        o.max
    );
}

fn main() {
    let o = options();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let (_own, url) = match &o.server {
        Some(url) => (None, url.clone()),
        None => {
            let (server, url) = own_server();
            (Some(server), url)
        }
    };
    let runs: Vec<(usize, usize)> = if o.matrix {
        vec![(1, 1), (1, 16), (1, 64), (4, 1), (4, 16), (4, 64)]
    } else {
        vec![(o.booths, o.subscribers)]
    };
    print_header();
    for (booths, subscribers) in runs {
        let outcome = runtime.block_on(run_once(&url, booths, subscribers, o.seconds, o.rate));
        print_row(&outcome);
    }
}
