//! The load tool: many `mouthpiece.v1` clients against a server, measuring what each
//! receives (order, gaps, latency from capture to receipt), plus a synthetic publisher.
//!
//! Used by the `mouthpiece-loadgen` binary and by the load tests. The synthetic stream is a
//! moving mouth (two characters, performer dots, head sway) so the viewer test can see it
//! move as well.

use std::f32::consts::TAU;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use futures_util::{SinkExt, StreamExt};
use serde::{Deserialize, Serialize};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::HeaderValue;
use tokio_tungstenite::tungstenite::Message;

use crate::hub::{
    CharacterFrame, CharacterInfo, HeadPose, Hub, PerformerFrame, StreamFrame, StreamInfo,
};
use crate::RigidPose;

/// Microseconds since the Unix epoch, now.
pub fn unix_micros() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as i64)
}

const POINTS: usize = 12;

fn mouth(width: f32, height: f32, open: f32, smile: f32) -> Vec<[f32; 3]> {
    // D1 left corner, D2..D6 upper lip left to right, D7 right corner, D8..D12 lower lip.
    (0..POINTS)
        .map(|i| {
            let a = std::f32::consts::PI * i as f32 / 6.0;
            let x = width / 2.0 * a.cos();
            let upper = i < 6 || i == 0;
            let s = a.sin();
            let y = if upper {
                height / 2.0 * s + smile * (1.0 - s)
            } else {
                (height / 2.0 + open) * s + smile * (1.0 + s)
            };
            [x, y, 0.1 * height * s.abs()]
        })
        .collect()
}

/// Uniform cubic B-spline through a closed loop of control points, `per_segment` samples each.
pub fn closed_bspline(points: &[[f32; 3]], per_segment: usize) -> Vec<[f32; 3]> {
    let n = points.len();
    let mut out = Vec::with_capacity(n * per_segment);
    for i in 0..n {
        let p = |k: usize| points[(i + k + n - 1) % n];
        for s in 0..per_segment {
            let u = s as f32 / per_segment as f32;
            let b = [
                (1.0 - u).powi(3) / 6.0,
                (3.0 * u.powi(3) - 6.0 * u * u + 4.0) / 6.0,
                (-3.0 * u.powi(3) + 3.0 * u * u + 3.0 * u + 1.0) / 6.0,
                u.powi(3) / 6.0,
            ];
            let mut q = [0.0f32; 3];
            for (k, w) in b.iter().enumerate() {
                for (axis, v) in q.iter_mut().enumerate() {
                    *v += w * p(k)[axis];
                }
            }
            out.push(q);
        }
    }
    out
}

/// The stream description matching [`synthetic_frame`]: characters `human` and `wolf`.
pub fn synthetic_info(frame_rate: f64) -> StreamInfo {
    let names: Vec<String> = (1..=POINTS).map(|i| format!("P{i}")).collect();
    let human = mouth(5.0, 1.6, 0.0, 0.0);
    let wolf = mouth(9.0, 1.2, 0.0, 0.0);
    let performer = mouth(0.05, 0.016, 0.0, 0.0);
    let ratio = |c: &[[f32; 3]]| -> Vec<[f32; 3]> {
        c.iter()
            .zip(&performer)
            .map(|(p, d)| {
                let r = |a: f32, b: f32| {
                    if b.abs() > 1e-4 {
                        (a / b).clamp(0.05, 20.0)
                    } else {
                        100.0
                    }
                };
                [r(p[0], d[0]), r(p[1], d[1]), r(p[2], d[2])]
            })
            .collect()
    };
    StreamInfo {
        characters: vec![
            CharacterInfo {
                name: "human".into(),
                points: names.clone(),
                m: ratio(&human),
                neutral: human,
                m_mode: "per-point".into(),
                units: "cm".into(),
            },
            CharacterInfo {
                name: "wolf".into(),
                points: names,
                m: ratio(&wolf),
                neutral: wolf,
                m_mode: "per-point".into(),
                units: "cm".into(),
            },
        ],
        performer_points: (1..=POINTS).map(|i| format!("D{i}")).collect(),
        frame_rate,
        source: "synthetic (mouthpiece-server loadgen)".into(),
        // A mouth 60 cm in front of the camera, 8 cm below the head's centre.
        mouth_frame: Some(mouthpiece_output::RigidPose {
            rotation: [0.0, 1.0, 0.0, 0.0],
            translation: [0.0, 0.08, 0.6],
        }),
    }
}

/// Frame `index` of a synthetic stream at `fps`: a mouth opening and closing 1.5 times a
/// second, a smile coming and going, the head swaying. `wall_us` is now.
pub fn synthetic_frame(index: u64, fps: f64, frame: &mut StreamFrame) {
    let t = index as f64 / fps;
    let phase = (t as f32) * 1.5 * TAU;
    let open = 0.5 * (1.0 + phase.sin());
    let smile = 0.3 * (phase * 0.37).sin();
    let human = mouth(5.0, 1.6, 1.8 * open, smile);
    let wolf = mouth(9.0, 1.2, 3.5 * open, 0.5 * smile);
    let performer = mouth(0.05, 0.016, 0.018 * open, 0.003 * smile);
    let yaw = 0.1 * (t as f32 * 0.5 * TAU).sin();
    frame.t = t;
    frame.capture_us = (t * 1e6) as u64;
    frame.wall_us = Some(unix_micros());
    frame.head = HeadPose {
        pose: RigidPose {
            rotation: [
                f64::from((yaw / 2.0).cos()),
                0.0,
                f64::from((yaw / 2.0).sin()),
                0.0,
            ],
            translation: [0.01 * f64::from(yaw), 0.0, 0.6],
        },
        lost: false,
    };
    let confidence = vec![1.0; POINTS];
    let mut rig = mouthpiece_output::RigState::default();
    rig.jaw.angle_deg = 20.0 * open;
    rig.curves.0[0] = 0.8 * open;
    rig.curves.0[6] = smile.max(0.0);
    rig.curves.0[7] = smile.max(0.0);
    // The heads turn with the performer's yaw; the eyes turn back against it.
    let (c, s) = ((yaw / 2.0).cos(), (yaw / 2.0).sin());
    let head = Some(mouthpiece_output::CharacterHead {
        rotation: [c, 0.0, s, 0.0],
        eye_left: [c, 0.0, -s, 0.0],
        eye_right: [c, 0.0, -s, 0.0],
        ..Default::default()
    });
    frame.characters = vec![
        CharacterFrame {
            name: "human".into(),
            curve: Some(closed_bspline(&human, 4)),
            points: human,
            confidence: confidence.clone(),
            rig: Some(rig),
            head,
            // The synthetic stream shows a speech-driven mouth too.
            source: mouthpiece_output::MouthSource::Speech,
        },
        CharacterFrame {
            name: "wolf".into(),
            curve: Some(closed_bspline(&wolf, 4)),
            points: wolf,
            confidence: confidence.clone(),
            rig: Some(rig),
            head,
            source: Default::default(),
        },
    ];
    frame.performer = Some(PerformerFrame {
        points: performer,
        confidence,
    });
    frame.processing = Some(Duration::from_micros(400 + (index % 7) * 50));
}

/// Publishes a synthetic stream on its own thread (like the daemon's processing thread) at
/// `fps` until `frames` are out or `stop` is set. Returns how many were published.
pub fn spawn_publisher(
    hub: Hub,
    fps: f64,
    frames: u64,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<u64> {
    std::thread::spawn(move || {
        let start = Instant::now();
        let mut frame = StreamFrame::default();
        let mut published = 0;
        while published < frames && !stop.load(Ordering::Relaxed) {
            let due = start + Duration::from_secs_f64(published as f64 / fps);
            if let Some(wait) = due.checked_duration_since(Instant::now()) {
                std::thread::sleep(wait);
            }
            synthetic_frame(published, fps, &mut frame);
            hub.publish(&frame);
            published += 1;
        }
        published
    })
}

/// How one load client behaves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClientKind {
    /// Reads everything as fast as it arrives.
    Fast,
    /// Connects, subscribes, then stops reading (a stalled engine).
    Stalled,
}

/// What one client saw.
#[derive(Debug, Clone, Default, Serialize)]
pub struct ClientReport {
    /// Frames received.
    pub frames: u64,
    /// First and last `seq` seen.
    pub first_seq: Option<u64>,
    /// Last `seq` seen.
    pub last_seq: Option<u64>,
    /// Times `seq` jumped forward by more than one.
    pub gaps: u64,
    /// Times `seq` did not increase.
    pub out_of_order: u64,
    /// Frames reported lost by `status lagged`.
    pub lagged: u64,
    /// The connection ended before the client closed it.
    pub disconnected: bool,
    /// Close reason from the server, if any.
    pub close_reason: Option<String>,
    /// Capture (`wall_us`) to receipt, microseconds, per frame.
    #[serde(skip)]
    pub latencies_us: Vec<u32>,
}

/// Latency percentiles over a set of clients, milliseconds.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Latency {
    /// Samples.
    pub samples: usize,
    /// Median.
    pub p50_ms: f64,
    /// 99th percentile.
    pub p99_ms: f64,
    /// Worst.
    pub max_ms: f64,
}

impl Latency {
    /// Percentiles over every sample of these clients.
    pub fn of<'a>(clients: impl IntoIterator<Item = &'a ClientReport>) -> Latency {
        let mut all: Vec<u32> = clients
            .into_iter()
            .flat_map(|c| c.latencies_us.iter().copied())
            .collect();
        if all.is_empty() {
            return Latency::default();
        }
        all.sort_unstable();
        let at = |q: f64| f64::from(all[((all.len() - 1) as f64 * q).round() as usize]) / 1000.0;
        Latency {
            samples: all.len(),
            p50_ms: at(0.5),
            p99_ms: at(0.99),
            max_ms: at(1.0),
        }
    }
}

#[derive(Deserialize)]
struct Incoming {
    #[serde(rename = "type")]
    kind: String,
    seq: Option<u64>,
    wall_us: Option<i64>,
    lagged: Option<u64>,
}

/// Connects one client to `url`, subscribes with `subscribe` (a JSON `subscribe` message),
/// and records what arrives until `stop` is set (then it closes) or the server closes.
pub async fn run_client(
    url: String,
    token: Option<String>,
    subscribe: String,
    kind: ClientKind,
    stop: Arc<AtomicBool>,
    subscribed: tokio::sync::mpsc::Sender<()>,
) -> Result<ClientReport, tokio_tungstenite::tungstenite::Error> {
    let mut request = url.into_client_request()?;
    let mut protocols = crate::protocol::SUBPROTOCOL.to_owned();
    if let Some(t) = &token {
        protocols.push_str(&format!(", {}{t}", crate::protocol::TOKEN_PROTOCOL_PREFIX));
    }
    request.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        HeaderValue::from_str(&protocols)
            .map_err(|e| tokio_tungstenite::tungstenite::Error::HttpFormat(e.into()))?,
    );
    let (mut ws, _) = if kind == ClientKind::Stalled {
        // A tiny receive buffer, so that the server's send path fills quickly and the
        // server has to deal with a client that really is not reading.
        let host = request.uri().host().unwrap_or("127.0.0.1").to_owned();
        let port = request.uri().port_u16().unwrap_or(80);
        let addr = tokio::net::lookup_host((host.as_str(), port))
            .await?
            .next()
            .ok_or_else(|| std::io::Error::other(format!("{host}: no address")))?;
        let socket = if addr.is_ipv4() {
            tokio::net::TcpSocket::new_v4()?
        } else {
            tokio::net::TcpSocket::new_v6()?
        };
        socket.set_recv_buffer_size(4096)?;
        let stream = socket.connect(addr).await?;
        tokio_tungstenite::client_async(request, tokio_tungstenite::MaybeTlsStream::Plain(stream))
            .await?
    } else {
        tokio_tungstenite::connect_async(request).await?
    };
    ws.send(Message::text(subscribe)).await?;
    let mut report = ClientReport::default();
    let mut announced = false;
    loop {
        if stop.load(Ordering::Relaxed) {
            let _ = ws.close(None).await;
            return Ok(report);
        }
        if kind == ClientKind::Stalled && announced {
            tokio::time::sleep(Duration::from_millis(20)).await;
            continue;
        }
        let next = tokio::time::timeout(Duration::from_millis(100), ws.next()).await;
        let message = match next {
            Err(_) => continue,
            Ok(None) => {
                report.disconnected = true;
                return Ok(report);
            }
            Ok(Some(Err(_))) => {
                report.disconnected = true;
                return Ok(report);
            }
            Ok(Some(Ok(m))) => m,
        };
        let received_us = unix_micros();
        let text = match message {
            Message::Text(t) => t,
            Message::Close(frame) => {
                report.disconnected = true;
                report.close_reason = frame.map(|f| f.reason.to_string());
                return Ok(report);
            }
            _ => continue,
        };
        let Ok(m) = serde_json::from_str::<Incoming>(&text) else {
            continue;
        };
        match m.kind.as_str() {
            "result" if !announced => {
                announced = true;
                let _ = subscribed.send(()).await;
            }
            "status" => report.lagged += m.lagged.unwrap_or(0),
            "frame" => {
                let seq = m.seq.unwrap_or(0);
                match report.last_seq {
                    Some(last) if seq == last + 1 => {}
                    Some(last) if seq > last + 1 => report.gaps += 1,
                    Some(_) => report.out_of_order += 1,
                    None => report.first_seq = Some(seq),
                }
                report.last_seq = Some(seq);
                report.frames += 1;
                if let Some(wall) = m.wall_us {
                    report
                        .latencies_us
                        .push((received_us - wall).clamp(0, i64::from(u32::MAX)) as u32);
                }
            }
            _ => {}
        }
    }
}

/// A load run's settings.
#[derive(Debug, Clone)]
pub struct LoadConfig {
    /// `ws://host:port/`.
    pub url: String,
    /// Token to present, if the server needs one.
    pub token: Option<String>,
    /// Clients that read everything.
    pub fast_clients: usize,
    /// Clients that stop reading after subscribing.
    pub stalled_clients: usize,
    /// The `subscribe` message each client sends.
    pub subscribe: String,
}

/// Everything a load run measured.
#[derive(Debug, Clone, Default, Serialize)]
pub struct LoadReport {
    /// Fast clients' reports.
    pub fast: Vec<ClientReport>,
    /// Stalled clients' reports.
    pub stalled: Vec<ClientReport>,
    /// Connections that failed.
    pub connect_errors: Vec<String>,
    /// Latency over the fast clients.
    pub latency: Latency,
}

/// Clients connected and subscribed, waiting for [`LoadClients::finish`].
#[derive(Debug)]
pub struct LoadClients {
    stop: Arc<AtomicBool>,
    tasks: Vec<(
        ClientKind,
        tokio::task::JoinHandle<Result<ClientReport, tokio_tungstenite::tungstenite::Error>>,
    )>,
}

impl LoadClients {
    /// Connects every client and returns once each has its subscription confirmed
    /// (or `timeout` passed).
    pub async fn connect(config: &LoadConfig, timeout: Duration) -> LoadClients {
        let stop = Arc::new(AtomicBool::new(false));
        let total = config.fast_clients + config.stalled_clients;
        let (tx, mut rx) = tokio::sync::mpsc::channel(total.max(1));
        let mut tasks = Vec::with_capacity(total);
        for i in 0..total {
            let kind = if i < config.fast_clients {
                ClientKind::Fast
            } else {
                ClientKind::Stalled
            };
            tasks.push((
                kind,
                tokio::spawn(run_client(
                    config.url.clone(),
                    config.token.clone(),
                    config.subscribe.clone(),
                    kind,
                    stop.clone(),
                    tx.clone(),
                )),
            ));
        }
        drop(tx);
        let _ = tokio::time::timeout(timeout, async {
            for _ in 0..total {
                if rx.recv().await.is_none() {
                    break;
                }
            }
        })
        .await;
        LoadClients { stop, tasks }
    }

    /// Stops every client and collects the reports.
    pub async fn finish(self) -> LoadReport {
        self.stop.store(true, Ordering::Relaxed);
        let mut report = LoadReport::default();
        for (kind, task) in self.tasks {
            match task.await {
                Ok(Ok(r)) if kind == ClientKind::Fast => report.fast.push(r),
                Ok(Ok(r)) => report.stalled.push(r),
                Ok(Err(e)) => report.connect_errors.push(e.to_string()),
                Err(e) => report.connect_errors.push(e.to_string()),
            }
        }
        report.latency = Latency::of(&report.fast);
        report
    }
}
