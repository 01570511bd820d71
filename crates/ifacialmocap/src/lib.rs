//! iFacialMocap output (docs/ifacialmocap.md): one character's face sent the way the
//! iFacialMocap iPhone app sends it, so VTuber apps that take that app (VSeeFace, VNyan,
//! VMagicMirror, Warudo) take mouthpiece instead.
//!
//! The protocol: a receiver sends the ASCII handshake [`HANDSHAKE`] (optionally followed by
//! [`V2_SUFFIX`]) to the sender's UDP port ([`DEFAULT_PORT`]); the sender then streams one
//! text datagram per frame to the receiver's address, at [`DEFAULT_PORT`] as the app does
//! (or another port, `reply_port`):
//!
//! ```text
//! eyeBlink_L-0|…|jawOpen-42|…|tongueOut-0|=head#x,y,z,px,py,pz|rightEye#x,y,z|leftEye#x,y,z|
//! ```
//!
//! The blend shapes are ARKit's in the app's spelling ([`IFM_NAMES`]) with integer values
//! 0–100 (`&` instead of `-` between name and value for a receiver that asked for v2); the
//! head and eyes are Euler angles in degrees as Unity's `Quaternion.Euler(x, y, z)` takes
//! them on a humanoid facing +z (x pitch, down positive; y yaw, to the character's right
//! positive; z roll, towards its left shoulder positive) and the head position in metres
//! (always 0: the character's head turns about its pivot, it does not move).
//!
//! The values are [`ArkitFace`]'s, the same the Live Link outputs send. The processing thread
//! only computes the character's face (fixed size, no allocation) and offers it to a bounded
//! queue; the `mouthpiece-ifacialmocap` thread owns the socket, answers handshakes, counts
//! and ignores every other datagram, and sends each frame to every receiver.

use std::net::{IpAddr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use crossbeam_channel::{Receiver, RecvTimeoutError, Sender, TrySendError};
use mouthpiece_output::{ArkitFace, HeadAxes, StreamFrame, BLENDSHAPES};

/// What a receiver sends to start the stream (the app's published handshake).
pub const HANDSHAKE: &str = "iFacialMocap_sahuasouryya9218sauhuiayeta91555dy3719";

/// Appended to [`HANDSHAKE`] by receivers that want the v2 layout (`&` between a blend
/// shape's name and value).
pub const V2_SUFFIX: &str = "|sendDataVersion=v2";

/// The app's UDP port: where it listens for the handshake and where it sends the frames.
pub const DEFAULT_PORT: u16 = 49983;

/// Most receivers streamed to at once; a handshake from one more replaces the oldest.
pub const MAX_RECEIVERS: usize = 8;

/// Frames waiting for the sender thread; a full queue drops its oldest frame.
pub const QUEUE_FRAMES: usize = 8;

/// ARKit's blend-shape names in the app's spelling, in
/// [`ARKIT_NAMES`](mouthpiece_output::ARKIT_NAMES) order: a side suffix `Left`/`Right` becomes
/// `_L`/`_R` (`eyeBlink_L`, `mouthSmile_R`), except where left and
/// right is the direction of the motion (`jawLeft`, `jawRight`, `mouthLeft`, `mouthRight`).
pub const IFM_NAMES: [&str; BLENDSHAPES] = [
    "eyeBlink_L",
    "eyeLookDown_L",
    "eyeLookIn_L",
    "eyeLookOut_L",
    "eyeLookUp_L",
    "eyeSquint_L",
    "eyeWide_L",
    "eyeBlink_R",
    "eyeLookDown_R",
    "eyeLookIn_R",
    "eyeLookOut_R",
    "eyeLookUp_R",
    "eyeSquint_R",
    "eyeWide_R",
    "jawForward",
    "jawLeft",
    "jawRight",
    "jawOpen",
    "mouthClose",
    "mouthFunnel",
    "mouthPucker",
    "mouthLeft",
    "mouthRight",
    "mouthSmile_L",
    "mouthSmile_R",
    "mouthFrown_L",
    "mouthFrown_R",
    "mouthDimple_L",
    "mouthDimple_R",
    "mouthStretch_L",
    "mouthStretch_R",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthPress_L",
    "mouthPress_R",
    "mouthLowerDown_L",
    "mouthLowerDown_R",
    "mouthUpperUp_L",
    "mouthUpperUp_R",
    "browDown_L",
    "browDown_R",
    "browInnerUp",
    "browOuterUp_L",
    "browOuterUp_R",
    "cheekPuff",
    "cheekSquint_L",
    "cheekSquint_R",
    "noseSneer_L",
    "noseSneer_R",
    "tongueOut",
];

/// Which separator goes between a blend shape's name and its value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// `name-value` (the handshake alone).
    V1,
    /// `name&value` (the handshake followed by [`V2_SUFFIX`]).
    V2,
}

/// What a datagram received on the port is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request {
    /// A handshake: stream to its sender in this layout.
    Start(Layout),
    /// Anything else: counted and ignored.
    Malformed,
}

/// Reads a datagram received on the port: only the exact handshake (optionally with
/// [`V2_SUFFIX`], and a trailing newline some tools add) starts a stream.
pub fn parse_request(datagram: &[u8]) -> Request {
    let text = datagram.strip_suffix(b"\n").unwrap_or(datagram);
    let text = text.strip_suffix(b"\r").unwrap_or(text);
    if text == HANDSHAKE.as_bytes() {
        return Request::Start(Layout::V1);
    }
    match text.strip_prefix(HANDSHAKE.as_bytes()) {
        Some(rest) if rest == V2_SUFFIX.as_bytes() => Request::Start(Layout::V2),
        _ => Request::Malformed,
    }
}

/// A blend shape's value as the app sends it: 0..=1 scaled to an integer 0–100, rounded.
pub fn percent(v: f32) -> u32 {
    if v.is_finite() {
        (v.clamp(0.0, 1.0) * 100.0).round() as u32
    } else {
        0
    }
}

/// Writes one frame's datagram into `out` (cleared first).
pub fn encode(face: &ArkitFace, layout: Layout, out: &mut String) {
    use std::fmt::Write;
    out.clear();
    let sep = match layout {
        Layout::V1 => '-',
        Layout::V2 => '&',
    };
    for (name, v) in IFM_NAMES.iter().zip(&face.blendshapes) {
        // Writing into a String cannot fail.
        let _ = write!(out, "{name}{sep}{}|", percent(*v));
    }
    // The angles: ArkitFace's (pitch, yaw, roll) are Unity's Euler (x, y, z) of the same turn
    // (docs/ifacialmocap.md, *Head and eyes*).
    let deg = |a: [f32; 3]| [a[1], a[0], a[2]].map(|r| f64::from(r).to_degrees());
    let [hx, hy, hz] = deg(face.head);
    let [rx, ry, rz] = deg(face.eye_right);
    let [lx, ly, lz] = deg(face.eye_left);
    let _ = write!(
        out,
        "=head#{hx:.6},{hy:.6},{hz:.6},0.000000,0.000000,0.000000|\
         rightEye#{rx:.6},{ry:.6},{rz:.6}|leftEye#{lx:.6},{ly:.6},{lz:.6}|"
    );
}

/// The output's counters (the status line; all since the start).
#[derive(Debug, Default)]
pub struct IfmCounters {
    /// Handshakes answered.
    pub handshakes: AtomicU64,
    /// Datagrams received that were not a handshake (ignored).
    pub malformed: AtomicU64,
    /// Datagrams sent.
    pub sent: AtomicU64,
    /// Sends that failed.
    pub errors: AtomicU64,
    /// Frames dropped because the sender thread was behind.
    pub dropped: AtomicU64,
    /// Receivers being streamed to.
    pub receivers: AtomicU64,
}

impl IfmCounters {
    /// Appends the Prometheus text (`/metrics`): `mouthpiece_ifacialmocap_…`.
    pub fn render_metrics(&self, out: &mut String) {
        use std::fmt::Write as _;
        let n = |a: &AtomicU64| a.load(Ordering::Relaxed);
        for (name, kind, help, value) in [
            (
                "handshakes_total",
                "counter",
                "Handshakes answered.",
                n(&self.handshakes),
            ),
            (
                "malformed_total",
                "counter",
                "Datagrams received that were not a handshake (ignored).",
                n(&self.malformed),
            ),
            ("sent_total", "counter", "Datagrams sent.", n(&self.sent)),
            (
                "errors_total",
                "counter",
                "Sends that failed.",
                n(&self.errors),
            ),
            (
                "dropped_total",
                "counter",
                "Frames dropped because the sender thread was behind.",
                n(&self.dropped),
            ),
            (
                "receivers",
                "gauge",
                "Receivers being streamed to.",
                n(&self.receivers),
            ),
        ] {
            let _ = writeln!(
                out,
                "# HELP mouthpiece_ifacialmocap_{name} {help}\n# TYPE mouthpiece_ifacialmocap_{name} {kind}\nmouthpiece_ifacialmocap_{name} {value}"
            );
        }
    }
}

/// `[ifacialmocap]` checked and resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct IfmSettings {
    /// Where handshakes are listened for.
    pub listen: SocketAddr,
    /// The port frames go to on a receiver's host; 0: the port its handshake came from.
    pub reply_port: u16,
    /// The character sent.
    pub character: String,
    /// Its head-frame axes in its model frame.
    pub axes: HeadAxes,
}

enum Control {
    Configure(IfmSettings),
    Stop,
}

/// One frame of the sent character (`None`: the frame does not carry it).
type Frame = ArkitFace;

/// The processing thread's and the daemon's handle on the iFacialMocap output (cheap to
/// clone); its thread stops when the last handle is dropped.
#[derive(Clone)]
pub struct IfmOutput {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for IfmOutput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("IfmOutput")
            .field("active", &self.inner.active.load(Ordering::Relaxed))
            .finish_non_exhaustive()
    }
}

struct Inner {
    frames: Sender<Frame>,
    frames_rx: Receiver<Frame>,
    control: Sender<Control>,
    control_rx: Receiver<Control>,
    active: AtomicBool,
    /// The sent character and its axes.
    character: Mutex<Option<(String, HeadAxes)>>,
    /// The port's address as first bound.
    local: Mutex<Option<SocketAddr>>,
    counters: Arc<IfmCounters>,
    thread: Mutex<Option<JoinHandle<()>>>,
}

impl Drop for Inner {
    fn drop(&mut self) {
        let _ = self.control.try_send(Control::Stop);
        if let Some(thread) = self
            .thread
            .get_mut()
            .unwrap_or_else(|e| e.into_inner())
            .take()
        {
            let _ = thread.join();
        }
    }
}

impl Default for IfmOutput {
    fn default() -> Self {
        Self::new()
    }
}

impl IfmOutput {
    /// An output that sends nothing until [`IfmOutput::configure`] enables it.
    pub fn new() -> Self {
        let (frames, frames_rx) = crossbeam_channel::bounded(QUEUE_FRAMES);
        let (control, control_rx) = crossbeam_channel::bounded(4);
        IfmOutput {
            inner: Arc::new(Inner {
                frames,
                frames_rx,
                control,
                control_rx,
                active: AtomicBool::new(false),
                character: Mutex::new(None),
                local: Mutex::new(None),
                counters: Arc::new(IfmCounters::default()),
                thread: Mutex::new(None),
            }),
        }
    }

    /// The address handshakes are listened for on, as bound by the first configuration
    /// (the actual port when `listen` asked for port 0); `None` before.
    pub fn local_addr(&self) -> Option<SocketAddr> {
        *self.inner.local.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The counters.
    pub fn counters(&self) -> Arc<IfmCounters> {
        self.inner.counters.clone()
    }

    /// Applies a configuration (at start and on reload). `None`: disabled: the thread stops,
    /// the port is closed and the receivers forgotten. The first configuration binds the port
    /// here, so a port in use is the caller's error; on a reload a changed `listen` rebinds it
    /// on the thread (kept as it was, with a warning, when the new one cannot be bound).
    pub fn configure(&self, settings: Option<IfmSettings>) -> std::io::Result<()> {
        let inner = &self.inner;
        let mut thread = inner.thread.lock().unwrap_or_else(|e| e.into_inner());
        let Some(settings) = settings else {
            inner.active.store(false, Ordering::Release);
            *inner.character.lock().unwrap_or_else(|e| e.into_inner()) = None;
            if let Some(t) = thread.take() {
                // The control queue is drained by the thread at every round.
                let _ = inner.control.send(Control::Stop);
                let _ = t.join();
            }
            inner.counters.receivers.store(0, Ordering::Relaxed);
            return Ok(());
        };
        if thread.is_none() {
            let socket = bind(settings.listen)?;
            *inner.local.lock().unwrap_or_else(|e| e.into_inner()) = socket.local_addr().ok();
            let frames = inner.frames_rx.clone();
            let control = inner.control_rx.clone();
            let counters = inner.counters.clone();
            let first = settings.clone();
            *thread = Some(
                std::thread::Builder::new()
                    .name("mouthpiece-ifacialmocap".into())
                    .spawn(move || run(socket, first, frames, control, counters))?,
            );
        } else if inner
            .control
            .try_send(Control::Configure(settings.clone()))
            .is_err()
        {
            return Err(std::io::Error::other(
                "the iFacialMocap thread is not taking configurations",
            ));
        }
        *inner.character.lock().unwrap_or_else(|e| e.into_inner()) =
            Some((settings.character.clone(), settings.axes));
        inner.active.store(true, Ordering::Release);
        Ok(())
    }

    /// Offers the sent character's face in `frame` to the thread. Never blocks: a full queue
    /// loses its oldest frame (counted).
    pub fn offer(&self, frame: &StreamFrame) {
        let inner = &self.inner;
        if !inner.active.load(Ordering::Acquire) {
            return;
        }
        let face = {
            let character = inner.character.lock().unwrap_or_else(|e| e.into_inner());
            let Some((name, axes)) = character.as_ref() else {
                return;
            };
            let Some(c) = frame.characters.iter().find(|c| &c.name == name) else {
                return;
            };
            ArkitFace::from_character(c, axes)
        };
        match inner.frames.try_send(face) {
            Ok(()) => {}
            Err(TrySendError::Full(face)) => {
                if inner.frames_rx.try_recv().is_ok() {
                    inner.counters.dropped.fetch_add(1, Ordering::Relaxed);
                }
                if inner.frames.try_send(face).is_err() {
                    inner.counters.dropped.fetch_add(1, Ordering::Relaxed);
                }
            }
            Err(TrySendError::Disconnected(_)) => {}
        }
    }

    /// One line for the systemd status; `None` while disabled.
    pub fn status(&self) -> Option<String> {
        if !self.inner.active.load(Ordering::Acquire) {
            return None;
        }
        let c = &self.inner.counters;
        let n = |a: &AtomicU64| a.load(Ordering::Relaxed);
        Some(format!(
            "ifacialmocap {} receivers, {} sent, {} errors, {} malformed, {} dropped",
            n(&c.receivers),
            n(&c.sent),
            n(&c.errors),
            n(&c.malformed),
            n(&c.dropped)
        ))
    }
}

fn bind(listen: SocketAddr) -> std::io::Result<UdpSocket> {
    let socket = UdpSocket::bind(listen)
        .map_err(|e| std::io::Error::new(e.kind(), format!("binding {listen}: {e}")))?;
    socket.set_nonblocking(true)?;
    Ok(socket)
}

/// How long the thread waits for a frame before it looks at the socket again.
const POLL: Duration = Duration::from_millis(20);

/// The thread: answers handshakes, ignores the rest, sends each frame to every receiver.
fn run(
    mut socket: UdpSocket,
    mut settings: IfmSettings,
    frames: Receiver<Frame>,
    control: Receiver<Control>,
    counters: Arc<IfmCounters>,
) {
    let mut receivers: Vec<(SocketAddr, Layout)> = Vec::with_capacity(MAX_RECEIVERS);
    let mut buf = [0u8; 512];
    let mut text = String::with_capacity(2048);
    loop {
        while let Ok(c) = control.try_recv() {
            match c {
                Control::Stop => return,
                Control::Configure(mut new) => {
                    if new.listen != settings.listen {
                        match bind(new.listen) {
                            Ok(s) => {
                                socket = s;
                                receivers.clear();
                            }
                            Err(e) => {
                                tracing::warn!("ifacialmocap: keeping {}: {e}", settings.listen);
                                new.listen = settings.listen;
                            }
                        }
                    }
                    // Receivers asked for frames at the old reply port.
                    if new.reply_port != settings.reply_port {
                        receivers.clear();
                    }
                    counters
                        .receivers
                        .store(receivers.len() as u64, Ordering::Relaxed);
                    settings = new;
                }
            }
        }
        // Every datagram waiting on the port.
        loop {
            match socket.recv_from(&mut buf) {
                Ok((n, from)) => match parse_request(&buf[..n]) {
                    Request::Start(layout) => {
                        let to = reply_address(from, settings.reply_port);
                        counters.handshakes.fetch_add(1, Ordering::Relaxed);
                        if let Some(r) = receivers.iter_mut().find(|r| r.0 == to) {
                            r.1 = layout;
                        } else {
                            if receivers.len() == MAX_RECEIVERS {
                                receivers.remove(0);
                            }
                            tracing::info!("ifacialmocap: streaming to {to}");
                            receivers.push((to, layout));
                        }
                        counters
                            .receivers
                            .store(receivers.len() as u64, Ordering::Relaxed);
                    }
                    Request::Malformed => {
                        counters.malformed.fetch_add(1, Ordering::Relaxed);
                    }
                },
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => break,
                // An ICMP error reported on the socket, or an interrupted call: try again
                // with the next round.
                Err(_) => break,
            }
        }
        match frames.recv_timeout(POLL) {
            Ok(face) => {
                for layout in [Layout::V1, Layout::V2] {
                    if !receivers.iter().any(|r| r.1 == layout) {
                        continue;
                    }
                    encode(&face, layout, &mut text);
                    for (to, _) in receivers.iter().filter(|r| r.1 == layout) {
                        match socket.send_to(text.as_bytes(), to) {
                            Ok(_) => counters.sent.fetch_add(1, Ordering::Relaxed),
                            Err(_) => counters.errors.fetch_add(1, Ordering::Relaxed),
                        };
                    }
                }
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => return,
        }
    }
}

/// Where a receiver's frames go: its host, at `reply_port` (0: the handshake's own port).
fn reply_address(from: SocketAddr, reply_port: u16) -> SocketAddr {
    let ip: IpAddr = from.ip();
    SocketAddr::new(
        ip,
        if reply_port == 0 {
            from.port()
        } else {
            reply_port
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use mouthpiece_output::ARKIT_NAMES;

    #[test]
    fn names_follow_the_apps_spelling_rule() {
        for (arkit, ifm) in ARKIT_NAMES.iter().zip(&IFM_NAMES) {
            let direction = ["jawLeft", "jawRight", "mouthLeft", "mouthRight"].contains(arkit);
            let want = match (arkit.strip_suffix("Left"), arkit.strip_suffix("Right")) {
                (Some(stem), _) if !direction => format!("{stem}_L"),
                (_, Some(stem)) if !direction => format!("{stem}_R"),
                _ => arkit.to_string(),
            };
            assert_eq!(*ifm, want);
        }
        assert_eq!(IFM_NAMES[17], "jawOpen");
        assert!(IFM_NAMES.contains(&"mouthSmile_L"));
        assert!(IFM_NAMES.contains(&"eyeBlink_R"));
    }

    #[test]
    fn only_the_handshake_starts_a_stream() {
        assert_eq!(
            parse_request(HANDSHAKE.as_bytes()),
            Request::Start(Layout::V1)
        );
        let v2 = format!("{HANDSHAKE}{V2_SUFFIX}");
        assert_eq!(parse_request(v2.as_bytes()), Request::Start(Layout::V2));
        let nl = format!("{HANDSHAKE}\n");
        assert_eq!(parse_request(nl.as_bytes()), Request::Start(Layout::V1));
        for bad in [
            &b""[..],
            b"iFacialMocap",
            b"iFacialMocap_sahuasouryya9218sauhuiayeta91555dy371",
            b"iFacialMocap_sahuasouryya9218sauhuiayeta91555dy3719|sendDataVersion=v3",
            b"\xff\xfe\x00garbage",
            b"iFacialMocap_UDPTCP_sahuasouryya9218sauhuiayeta91555dy3719",
        ] {
            assert_eq!(parse_request(bad), Request::Malformed, "{bad:?}");
        }
    }

    #[test]
    fn frames_go_to_the_apps_port_unless_told_otherwise() {
        let from: SocketAddr = "192.0.2.7:50123".parse().unwrap();
        assert_eq!(
            reply_address(from, DEFAULT_PORT),
            "192.0.2.7:49983".parse().unwrap()
        );
        assert_eq!(reply_address(from, 0), from);
    }

    #[test]
    fn percentages_round_and_clamp() {
        assert_eq!(percent(0.0), 0);
        assert_eq!(percent(0.424), 42);
        assert_eq!(percent(0.425), 43);
        assert_eq!(percent(1.7), 100);
        assert_eq!(percent(-0.2), 0);
        assert_eq!(percent(f32::NAN), 0);
    }
}
