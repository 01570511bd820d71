//! OSC output (docs/osc.md): characters' rig curves, head and eyes as VMC protocol messages
//! over UDP, each target getting its own character's, once per processed frame.
//!
//! The processing thread only copies the sent characters' curves and rotations into
//! [`VmcFrames`] (a fixed array of [`VmcFrame`]s, no allocation) and offers it to a bounded queue
//! ([`QUEUE_FRAMES`]); when the queue is full the oldest frame is dropped and counted. The
//! `mouthpiece-osc` thread takes frames off the queue, converts the rotations to the VMC
//! protocol's (Unity's) axes, encodes one OSC bundle (`rosc`) and sends it to each target on
//! a non-blocking connected UDP socket. A target that refuses (nothing listens: the kernel
//! reports the ICMP "port unreachable" as `ECONNREFUSED` on a later send) or cannot be reached
//! is counted and logged at most once per `[logging] throttle_s`; it never blocks anything.
//! Counters: the server's [`OscCounters`] (`/metrics`, `/healthz`, the systemd status).

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use crossbeam_channel::{Receiver, Sender, TrySendError};
use link::UdpLink;
use mouthpiece_output::{
    CurveNaming, MouthSource, RigCurves, RigVisemes, StreamFrame, VisemeNaming,
};
use mouthpiece_server::OscCounters;
use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion};
use rosc::{OscBundle, OscMessage, OscPacket, OscTime, OscType};

/// Frames waiting for the sender thread; a full queue drops its oldest frame.
pub const QUEUE_FRAMES: usize = 8;

/// The largest datagram sent: an Ethernet frame's UDP payload unfragmented (1500 bytes less
/// the IPv4 and UDP headers). A frame's messages that do not fit one are sent as several
/// bundles, `Blend/Apply` in the last.
pub const MAX_DATAGRAM: usize = 1472;

/// The VMC protocol's addresses (names of the messages).
pub mod address {
    /// `(int) 1`: the sender has an avatar and sends it.
    pub const OK: &str = "/VMC/Ext/OK";
    /// `(float)` the sender's time, seconds.
    pub const TIME: &str = "/VMC/Ext/T";
    /// `(string) bone, (float) px, py, pz, qx, qy, qz, qw`: a bone's local pose, Unity axes.
    pub const BONE: &str = "/VMC/Ext/Bone/Pos";
    /// `(string) name, (float) value`: one blend shape's value.
    pub const BLEND_VAL: &str = "/VMC/Ext/Blend/Val";
    /// No arguments: apply the values sent since the last one.
    pub const BLEND_APPLY: &str = "/VMC/Ext/Blend/Apply";
    /// `(string) camera | speech | blend`: what drove the character's mouth in this frame
    /// (mouthpiece's own address, outside VMC: receivers ignore what they do not know).
    pub const SOURCE: &str = "/mouthpiece/Source";
}

/// Most characters sent over OSC at once (each target gets one).
pub const MAX_CHARACTERS: usize = 8;

/// One resolved target.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Target {
    /// As configured (`host:port`): the counters' label.
    pub label: String,
    pub addr: SocketAddr,
    /// Index of its character in [`OscSettings::characters`].
    pub character: usize,
}

/// A character whose rig, head and eyes go out.
#[derive(Debug, Clone, PartialEq)]
pub struct OscCharacter {
    pub name: String,
    /// Its head-frame axes (left, up, forward) in its model frame, as columns.
    pub axes: Matrix3<f64>,
}

/// `[osc]` checked and resolved (the daemon resolves it from its configuration).
#[derive(Debug, Clone, PartialEq)]
pub struct OscSettings {
    pub targets: Vec<Target>,
    /// The characters the targets name, at most [`MAX_CHARACTERS`].
    pub characters: Vec<OscCharacter>,
    pub head: bool,
    pub eyes: bool,
    /// The curves' blend-shape names.
    pub names: CurveNaming,
    /// The visemes sent, and their names.
    pub visemes: VisemeNaming,
}

/// What the processing thread hands the sender: one character's values in one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VmcFrame {
    /// The stream's `t` (seconds since the daemon started).
    pub t: f64,
    /// The rig's curves; `None` (not calibrated, or a frame that could not be tracked): every
    /// curve at rest, 0, as the stream shows the character at rest.
    pub curves: Option<RigCurves>,
    /// The rig's visemes (at rest, 0, when there is no rig).
    pub visemes: Option<RigVisemes>,
    /// Head rotation, model frame, `[w, x, y, z]`.
    pub head: [f32; 4],
    /// Eye rotations relative to the head, `[w, x, y, z]`.
    pub eye_left: [f32; 4],
    pub eye_right: [f32; 4],
    /// What drove the mouth (the WebSocket frame's `characters[].source`).
    pub source: MouthSource,
}

impl VmcFrame {
    /// `character`'s values in `frame`; `None` when the frame does not carry it (a character
    /// that could not be bound is left out of the stream).
    pub fn from_stream(frame: &StreamFrame, character: &str) -> Option<Self> {
        let c = frame.characters.iter().find(|c| c.name == character)?;
        let head = c.head.unwrap_or_default();
        Some(VmcFrame {
            t: frame.t,
            curves: c.rig.map(|r| r.curves),
            visemes: c.rig.map(|r| r.visemes),
            head: head.rotation,
            eye_left: head.eye_left,
            eye_right: head.eye_right,
            source: c.source,
        })
    }
}

/// One frame's values of each sent character, in [`OscSettings::characters`] order (`None`:
/// the frame does not carry that character). Fixed-size and `Copy`: offering it to the queue
/// does not allocate.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct VmcFrames(pub [Option<VmcFrame>; MAX_CHARACTERS]);

impl VmcFrames {
    /// The values of `characters` in `frame`.
    pub fn from_stream(frame: &StreamFrame, characters: &[String]) -> Self {
        let mut out = VmcFrames::default();
        for (slot, name) in out.0.iter_mut().zip(characters) {
            *slot = VmcFrame::from_stream(frame, name);
        }
        out
    }
}

/// The rotation whose matrix is `axes` (the head frame's axes as columns, a right-handed
/// orthonormal frame).
pub fn axes_rotation(axes: &Matrix3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(axes))
}

/// A rotation of the character's model frame (`[w, x, y, z]`) as a VMC bone rotation
/// `[x, y, z, w]`: written in the character's head-frame axes (`Aᵀ R A`: left, up, forward;
/// `a` is `A` as a quaternion, [`axes_rotation`]), then mirrored into Unity's left-handed
/// axes (x right, y up, z forward), which keeps the rotation's angle and maps the quaternion
/// `(w, x, y, z)` to `(w, x, −y, −z)`. `w ≥ 0`.
pub fn unity_rotation(q_wxyz: [f32; 4], a: &UnitQuaternion<f64>) -> [f32; 4] {
    let [w, x, y, z] = q_wxyz.map(f64::from);
    let q = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
    let h = a.inverse() * q * a;
    let s = if h.w < 0.0 { -1.0 } else { 1.0 };
    [s * h.i, -s * h.j, -s * h.k, s * h.w].map(|v| v as f32)
}

/// The bundles sent each frame, built once and refilled in place: `OK`, `T`, the bones
/// (`Head`, `LeftEye`, `RightEye` as configured), one `Blend/Val` per curve, one per viseme
/// (as configured), `Blend/Apply`; in as few bundles as keep each under [`MAX_DATAGRAM`]
/// bytes, in that order.
#[derive(Debug, Clone)]
pub struct VmcPacket {
    packets: Vec<OscPacket>,
    /// Which bones the bundle holds, in order.
    bones: Vec<Bone>,
    /// Whether visemes follow the curves.
    visemes: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Bone {
    Head,
    LeftEye,
    RightEye,
}

impl Bone {
    /// Unity's `HumanBodyBones` names.
    fn name(self) -> &'static str {
        match self {
            Bone::Head => "Head",
            Bone::LeftEye => "LeftEye",
            Bone::RightEye => "RightEye",
        }
    }
}

fn message(addr: &str, args: Vec<OscType>) -> OscPacket {
    OscPacket::Message(OscMessage {
        addr: addr.to_owned(),
        args,
    })
}

impl VmcPacket {
    pub fn new(head: bool, eyes: bool, names: CurveNaming, visemes: VisemeNaming) -> Self {
        let mut bones = Vec::new();
        if head {
            bones.push(Bone::Head);
        }
        if eyes {
            bones.extend([Bone::LeftEye, Bone::RightEye]);
        }
        let mut content = vec![
            message(address::OK, vec![OscType::Int(1)]),
            message(address::TIME, vec![OscType::Float(0.0)]),
        ];
        for bone in &bones {
            let mut args = vec![OscType::String(bone.name().to_owned())];
            args.extend([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0].map(OscType::Float));
            content.push(message(address::BONE, args));
        }
        let viseme_names = visemes.names();
        for name in names
            .names()
            .iter()
            .chain(viseme_names.into_iter().flatten())
        {
            content.push(message(
                address::BLEND_VAL,
                vec![OscType::String((*name).to_owned()), OscType::Float(0.0)],
            ));
        }
        content.push(message(
            address::SOURCE,
            vec![OscType::String(MouthSource::Camera.as_str().to_owned())],
        ));
        content.push(message(address::BLEND_APPLY, Vec::new()));
        // "Immediately" (OSC 1.0): the receiver applies the values when they arrive.
        let bundle = |content| {
            OscPacket::Bundle(OscBundle {
                timetag: OscTime {
                    seconds: 0,
                    fractional: 1,
                },
                content,
            })
        };
        // Each message costs its bytes and a 4-byte size in a bundle; a bundle's header
        // ("#bundle", the time tag) is 16.
        let mut packets = Vec::new();
        let mut current = Vec::new();
        let mut size = 16;
        for m in content {
            let cost = 4 + rosc::encoder::encode(&m).map_or(0, |b| b.len());
            if size + cost > MAX_DATAGRAM && !current.is_empty() {
                packets.push(bundle(std::mem::take(&mut current)));
                size = 16;
            }
            size += cost;
            current.push(m);
        }
        packets.push(bundle(current));
        VmcPacket {
            packets,
            bones,
            visemes: viseme_names.is_some(),
        }
    }

    /// Puts `frame`'s values into the bundle (no allocation); `axes`: [`axes_rotation`] of
    /// the character's head frame.
    pub fn fill(&mut self, frame: &VmcFrame, axes: &UnitQuaternion<f64>) {
        let mut messages = self
            .packets
            .iter_mut()
            .flat_map(|p| match p {
                OscPacket::Bundle(b) => b.content.iter_mut(),
                OscPacket::Message(_) => unreachable!("built as bundles"),
            })
            .map(|p| match p {
                OscPacket::Message(m) => m,
                OscPacket::Bundle(_) => unreachable!("built of messages"),
            });
        let _ok = messages.next();
        if let Some(m) = messages.next() {
            m.args[0] = OscType::Float(frame.t as f32);
        }
        for bone in &self.bones {
            let q = match bone {
                Bone::Head => frame.head,
                Bone::LeftEye => frame.eye_left,
                Bone::RightEye => frame.eye_right,
            };
            let r = unity_rotation(q, axes);
            if let Some(m) = messages.next() {
                for (arg, v) in m.args[4..8].iter_mut().zip(r) {
                    *arg = OscType::Float(v);
                }
            }
        }
        let curves = frame.curves.unwrap_or_default();
        let visemes = frame.visemes.unwrap_or_default();
        let visemes = if self.visemes { &visemes.0[..] } else { &[] };
        for v in curves.0.iter().chain(visemes) {
            if let Some(m) = messages.next() {
                m.args[1] = OscType::Float(*v);
            }
        }
        if let Some(m) = messages.next() {
            let source = frame.source.as_str();
            // Replaced only when the source changes: a handover, not every frame, allocates.
            if !matches!(&m.args[0], OscType::String(s) if s == source) {
                m.args[0] = OscType::String(source.to_owned());
            }
        }
    }

    /// The bundles, in the order they are sent.
    pub fn packets(&self) -> &[OscPacket] {
        &self.packets
    }

    /// Encodes bundle `i` into `out` (cleared first; its buffer is reused).
    pub fn encode(&self, i: usize, out: &mut Vec<u8>) {
        out.clear();
        // Writing into a Vec cannot fail.
        let Ok(_) = rosc::encoder::encode_into(&self.packets[i], out);
    }
}

/// Offers `item` to a bounded queue without waiting: when the queue is full its oldest item
/// is dropped (and counted) to make room. `rx` is a receiver of the same queue.
pub fn push_drop_oldest<T>(tx: &Sender<T>, rx: &Receiver<T>, item: T, dropped: &dyn Fn()) {
    match tx.try_send(item) {
        Ok(()) => {}
        Err(TrySendError::Full(item)) => {
            if rx.try_recv().is_ok() {
                dropped();
            }
            // The sender thread may have taken one meanwhile; a queue refilled by nobody
            // else cannot be full again, but count the loss rather than wait if it is.
            if tx.try_send(item).is_err() {
                dropped();
            }
        }
        Err(TrySendError::Disconnected(_)) => {}
    }
}

enum Control {
    Configure(OscSettings),
    Stop,
}

/// The processing thread's and the daemon's handle on the OSC output (cheap to clone). The
/// sender thread starts with the first configuration that has a target and stops when the
/// last handle is dropped.
#[derive(Clone)]
pub struct OscOutput {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for OscOutput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OscOutput")
            .field("active", &self.inner.active.load(Ordering::Relaxed))
            .finish_non_exhaustive()
    }
}

struct Inner {
    frames: Sender<VmcFrames>,
    /// Kept to drop the oldest frame when the queue is full, and handed to the thread.
    frames_rx: Receiver<VmcFrames>,
    control: Sender<Control>,
    control_rx: Receiver<Control>,
    /// Some target is configured: frames are worth offering.
    active: AtomicBool,
    /// The characters whose values go out, in [`OscSettings::characters`] order.
    characters: Mutex<Vec<String>>,
    counters: Arc<OscCounters>,
    throttle: Duration,
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

impl OscOutput {
    /// An output with no target yet; `throttle`: how often a failing target is logged.
    pub fn new(counters: Arc<OscCounters>, throttle: Duration) -> Self {
        let (frames, frames_rx) = crossbeam_channel::bounded(QUEUE_FRAMES);
        let (control, control_rx) = crossbeam_channel::bounded(4);
        OscOutput {
            inner: Arc::new(Inner {
                frames,
                frames_rx,
                control,
                control_rx,
                active: AtomicBool::new(false),
                characters: Mutex::new(Vec::new()),
                counters,
                throttle,
                thread: Mutex::new(None),
            }),
        }
    }

    /// Applies a configuration (at start and on reload): new targets, character and bones.
    /// Targets kept from the last configuration keep their sockets and counters.
    pub fn configure(&self, settings: OscSettings) -> std::io::Result<()> {
        let inner = &self.inner;
        let active = !settings.targets.is_empty();
        {
            let mut thread = inner.thread.lock().unwrap_or_else(|e| e.into_inner());
            if thread.is_none() {
                if !active {
                    inner.counters.set_targets(Vec::new());
                    return Ok(());
                }
                let frames = inner.frames_rx.clone();
                let control = inner.control_rx.clone();
                let counters = inner.counters.clone();
                let throttle = inner.throttle;
                *thread = Some(
                    std::thread::Builder::new()
                        .name("mouthpiece-osc".into())
                        .spawn(move || run(frames, control, counters, throttle))?,
                );
            }
        }
        *inner.characters.lock().unwrap_or_else(|e| e.into_inner()) = settings
            .characters
            .iter()
            .take(MAX_CHARACTERS)
            .map(|c| c.name.clone())
            .collect();
        if inner
            .control
            .try_send(Control::Configure(settings))
            .is_err()
        {
            return Err(std::io::Error::other(
                "the OSC sender thread is not taking configurations",
            ));
        }
        inner.active.store(active, Ordering::Release);
        Ok(())
    }

    /// Offers the frame's values of the configured characters to the sender thread. Never
    /// blocks: a full queue loses its oldest frame (counted).
    pub fn offer(&self, frame: &StreamFrame) {
        let inner = &self.inner;
        if !inner.active.load(Ordering::Acquire) {
            return;
        }
        let vmc = {
            let characters = inner.characters.lock().unwrap_or_else(|e| e.into_inner());
            VmcFrames::from_stream(frame, &characters)
        };
        if vmc.0.iter().any(Option::is_some) {
            push_drop_oldest(&inner.frames, &inner.frames_rx, vmc, &|| {
                inner.counters.dropped.fetch_add(1, Ordering::Relaxed);
            });
        }
    }

    /// One line for the systemd status: per target sent and errors, and the drops; `None`
    /// when no target is configured.
    pub fn status(&self) -> Option<String> {
        let targets = self.inner.counters.targets();
        if targets.is_empty() {
            return None;
        }
        let each: Vec<String> = targets
            .iter()
            .map(|t| format!("{} {} sent {} errors", t.target, t.sent, t.errors))
            .collect();
        Some(format!(
            "osc {}; {} dropped",
            each.join(", "),
            self.inner.counters.dropped.load(Ordering::Relaxed)
        ))
    }
}

/// One configured target on the sender thread.
struct Link {
    target: Target,
    udp: UdpLink,
}

impl Link {
    fn new(target: Target, throttle: Duration) -> Self {
        Link {
            udp: UdpLink::new(target.addr, &target.label, "OSC", throttle),
            target,
        }
    }
}

/// What the sender thread holds between frames.
struct SenderState {
    links: Vec<Link>,
    packet: VmcPacket,
    /// Per character: [`axes_rotation`] of its head frame.
    axes: Vec<UnitQuaternion<f64>>,
    throttle: Duration,
}

impl SenderState {
    /// Applies a control message; `false` to stop.
    fn control(&mut self, message: Control, counters: &OscCounters) -> bool {
        let Control::Configure(settings) = message else {
            return false;
        };
        let mut kept = std::mem::take(&mut self.links);
        for target in settings.targets {
            let link = match kept.iter().position(|l| l.target == target) {
                Some(i) => kept.swap_remove(i),
                None => Link::new(target, self.throttle),
            };
            self.links.push(link);
        }
        counters.set_targets(self.links.iter().map(|l| l.udp.counters.clone()).collect());
        self.packet = VmcPacket::new(
            settings.head,
            settings.eyes,
            settings.names,
            settings.visemes,
        );
        self.axes = settings
            .characters
            .iter()
            .take(MAX_CHARACTERS)
            .map(|c| axes_rotation(&c.axes))
            .collect();
        let shown: Vec<String> = self
            .links
            .iter()
            .map(|l| {
                let name = settings
                    .characters
                    .get(l.target.character)
                    .map_or("?", |c| c.name.as_str());
                format!("{} ({name})", l.target.label)
            })
            .collect();
        tracing::info!("OSC (VMC protocol) to [{}]", shown.join(", "));
        true
    }
}

/// The sender thread: configurations and frames until [`Control::Stop`] or every handle is
/// gone. A configuration waiting when a frame arrives is applied first (it was given before
/// the frame was offered).
fn run(
    frames: Receiver<VmcFrames>,
    control: Receiver<Control>,
    counters: Arc<OscCounters>,
    throttle: Duration,
) {
    let mut state = SenderState {
        links: Vec::new(),
        packet: VmcPacket::new(true, true, CurveNaming::Arkit, VisemeNaming::Vrm0),
        axes: Vec::new(),
        throttle,
    };
    let mut bytes = Vec::with_capacity(2048);
    tracing::info!("OSC sender started");
    'run: loop {
        crossbeam_channel::select! {
            recv(control) -> message => {
                let Ok(message) = message else { break };
                if !state.control(message, &counters) {
                    break;
                }
            }
            recv(frames) -> frame => {
                let Ok(frame) = frame else { break };
                while let Ok(message) = control.try_recv() {
                    if !state.control(message, &counters) {
                        break 'run;
                    }
                }
                if state.links.is_empty() {
                    continue;
                }
                // One character at a time: its values into the bundles, then to its targets.
                for (c, axes) in state.axes.iter().enumerate() {
                    let Some(values) = &frame.0[c] else { continue };
                    if !state.links.iter().any(|l| l.target.character == c) {
                        continue;
                    }
                    state.packet.fill(values, axes);
                    for i in 0..state.packet.packets().len() {
                        state.packet.encode(i, &mut bytes);
                        for link in state.links.iter_mut().filter(|l| l.target.character == c) {
                            link.udp.send(&bytes);
                        }
                    }
                }
            }
        }
    }
    tracing::info!("OSC sender stopped");
}

mod link;
pub mod livelink;
pub mod remote;
mod sender;
pub use sender::VmcSender;

#[cfg(test)]
mod tests;
