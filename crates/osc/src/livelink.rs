//! Live Link Face's UDP stream (docs/livelink.md): each sent character's face as one datagram
//! per frame per target, laid out as the iPhone app sends it, so Unreal's Live Link Face
//! source takes it unchanged.
//!
//! The processing thread turns the sent characters' frames into their 61 values
//! ([`ArkitFace::livelink_values`]: the same numbers every ARKit-speaking output sends) and
//! offers them with the frame's position on the timecode grid to a bounded queue
//! ([`QUEUE_FRAMES`], oldest dropped and counted when full); the `mouthpiece-livelink`
//! thread encodes one datagram per character ([`encode_datagram`]) and sends it to that
//! character's targets on non-blocking connected UDP sockets, as the OSC output does.
//!
//! The remote control ([`crate::remote`]) changes what goes out while the daemon runs
//! ([`RemoteChange`]): added and cleared targets, the subject name, streaming on or off, all
//! for the first sent character (the one an iPhone would be); a reload keeps those changes.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use crossbeam_channel::{Receiver, Sender};
use mouthpiece_output::{ArkitFace, HeadAxes, StreamFrame, LIVELINK_VALUES};
use mouthpiece_server::{FrameTime, MetricsSource, OscCounters, TimecodeRate};

use crate::link::UdpLink;
use crate::{push_drop_oldest, MAX_CHARACTERS};

/// The packet version Unreal's Live Link Face source reads (6: device id, subject, frame
/// time with its rate, 61 values).
pub const PACKET_VERSION: u32 = 6;

/// Frames waiting for the sender thread; a full queue drops its oldest frame.
pub const QUEUE_FRAMES: usize = 8;

/// The device id's length as sent: `$` and a 36-character UUID.
pub const DEVICE_ID_BYTES: usize = 37;

/// Writes one datagram into `out` (cleared first): little-endian `u32` version 6, the device
/// id as `$` and its 36 characters, then big-endian: `i32` subject length and the subject's
/// UTF-8 bytes, `i32` frame number and `f32` sub-frame, `i32` rate numerator and
/// denominator, `u8` 61 and the 61 `f32` values. `device_id` must be a 36-character UUID (the
/// configuration checks it).
pub fn encode_datagram(
    out: &mut Vec<u8>,
    device_id: &str,
    subject: &str,
    time: FrameTime,
    rate: TimecodeRate,
    values: &[f32; LIVELINK_VALUES],
) {
    out.clear();
    out.extend_from_slice(&PACKET_VERSION.to_le_bytes());
    out.push(b'$');
    out.extend_from_slice(device_id.as_bytes());
    out.extend_from_slice(&(subject.len() as i32).to_be_bytes());
    out.extend_from_slice(subject.as_bytes());
    // Frames since midnight fit an i32 at every rate (at most 5.2 million at 60 fps).
    out.extend_from_slice(&(time.frame as i32).to_be_bytes());
    out.extend_from_slice(&(time.sub_frame as f32).to_be_bytes());
    let (num, den) = rate.fraction();
    out.extend_from_slice(&(num as i32).to_be_bytes());
    out.extend_from_slice(&(den as i32).to_be_bytes());
    out.push(LIVELINK_VALUES as u8);
    for v in values {
        out.extend_from_slice(&v.to_be_bytes());
    }
}

/// A character whose face goes out.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveLinkCharacter {
    /// Its configured name (as in the stream's `characters[].name`).
    pub name: String,
    /// The Live Link subject name.
    pub subject: String,
    /// Its device id (36-character UUID).
    pub device_id: String,
    /// Its head-frame axes in its model frame.
    pub axes: HeadAxes,
}

/// One resolved target of one character.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LiveLinkTarget {
    /// As configured (`host:port`), or the address given by the remote control.
    pub label: String,
    pub addr: SocketAddr,
    /// Index of its character in [`LiveLinkSettings::characters`].
    pub character: usize,
}

/// `[livelink]` checked and resolved by the daemon.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveLinkSettings {
    /// Send at all (`[livelink] enabled`).
    pub enabled: bool,
    /// The characters sent, at most [`MAX_CHARACTERS`]; the first is the one the remote
    /// control steers.
    pub characters: Vec<LiveLinkCharacter>,
    pub targets: Vec<LiveLinkTarget>,
    /// The timecode rate: the frame time's grid and the rate sent.
    pub rate: TimecodeRate,
}

/// What the remote control changes (for the first character).
#[derive(Debug, Clone, PartialEq)]
pub enum RemoteChange {
    /// `/AddLiveLinkAddress`: one more target.
    AddTarget(SocketAddr),
    /// `/ClearAllLiveLinkAddresses`: no target at all (the configured ones too).
    ClearTargets,
    /// `/LiveLinkSubject`: the subject name.
    Subject(String),
    /// `/LiveLinkStreamStart` (`true`) and `/LiveLinkStreamStop` (`false`).
    Streaming(bool),
}

/// Changes made by the remote control, laid over the configuration.
#[derive(Debug, Clone, Default, PartialEq)]
struct Overrides {
    added: Vec<SocketAddr>,
    cleared: bool,
    subject: Option<String>,
    streaming: Option<bool>,
}

/// One frame's values of each sent character, in [`LiveLinkSettings::characters`] order.
#[derive(Debug, Clone, Copy)]
struct FaceFrame {
    time: FrameTime,
    faces: [Option<[f32; LIVELINK_VALUES]>; MAX_CHARACTERS],
}

enum Control {
    Configure(LiveLinkSettings),
    Remote(RemoteChange),
    Stop,
}

/// The processing thread's, the daemon's and the remote control's handle on the Live Link
/// output (cheap to clone). The sender thread starts with the first configuration and stops
/// when the last handle is dropped.
#[derive(Clone)]
pub struct LiveLinkOutput {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for LiveLinkOutput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveLinkOutput")
            .field("active", &self.inner.shared.active.load(Ordering::Relaxed))
            .finish_non_exhaustive()
    }
}

/// What the sender thread tells the processing thread.
struct Shared {
    /// Some target gets frames: worth computing them.
    active: AtomicBool,
    /// The sent characters' names and axes, in order.
    characters: Mutex<Vec<(String, HeadAxes)>>,
}

struct Inner {
    frames: Sender<FaceFrame>,
    frames_rx: Receiver<FaceFrame>,
    control: Sender<Control>,
    control_rx: Receiver<Control>,
    shared: Arc<Shared>,
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

impl LiveLinkOutput {
    /// An output with nothing configured; `throttle`: how often a failing target is logged.
    pub fn new(throttle: Duration) -> Self {
        let (frames, frames_rx) = crossbeam_channel::bounded(QUEUE_FRAMES);
        let (control, control_rx) = crossbeam_channel::bounded(16);
        LiveLinkOutput {
            inner: Arc::new(Inner {
                frames,
                frames_rx,
                control,
                control_rx,
                shared: Arc::new(Shared {
                    active: AtomicBool::new(false),
                    characters: Mutex::new(Vec::new()),
                }),
                counters: Arc::new(OscCounters::default()),
                throttle,
                thread: Mutex::new(None),
            }),
        }
    }

    /// The per-target counters and the drops.
    pub fn counters(&self) -> &OscCounters {
        &self.inner.counters
    }

    fn ensure_thread(&self) -> std::io::Result<()> {
        let inner = &self.inner;
        let mut thread = inner.thread.lock().unwrap_or_else(|e| e.into_inner());
        if thread.is_none() {
            let frames = inner.frames_rx.clone();
            let control = inner.control_rx.clone();
            let shared = inner.shared.clone();
            let counters = inner.counters.clone();
            let throttle = inner.throttle;
            *thread = Some(
                std::thread::Builder::new()
                    .name("mouthpiece-livelink".into())
                    .spawn(move || run(frames, control, shared, counters, throttle))?,
            );
        }
        Ok(())
    }

    fn send_control(&self, message: Control) -> std::io::Result<()> {
        self.ensure_thread()?;
        self.inner
            .control
            .try_send(message)
            .map_err(|_| std::io::Error::other("the Live Link sender thread is not taking changes"))
    }

    /// Applies a configuration (at start and on reload). Targets kept from the last
    /// configuration keep their sockets and counters; the remote control's changes stay.
    pub fn configure(&self, settings: LiveLinkSettings) -> std::io::Result<()> {
        self.send_control(Control::Configure(settings))
    }

    /// Applies a remote-control change.
    pub fn remote(&self, change: RemoteChange) -> std::io::Result<()> {
        self.send_control(Control::Remote(change))
    }

    /// Offers the frame's values of the sent characters to the sender thread, at `time`, its
    /// place on the timecode grid as the hub stamped it ([`mouthpiece_server::Hub::frame_time`]:
    /// the studio's LTC when it follows one). Never blocks: a full queue loses its oldest
    /// frame (counted).
    pub fn offer(&self, frame: &StreamFrame, time: FrameTime) {
        let inner = &self.inner;
        if !inner.shared.active.load(Ordering::Acquire) {
            return;
        }
        let mut out = FaceFrame {
            time,
            faces: [None; MAX_CHARACTERS],
        };
        {
            let characters = inner
                .shared
                .characters
                .lock()
                .unwrap_or_else(|e| e.into_inner());
            for (slot, (name, axes)) in out.faces.iter_mut().zip(characters.iter()) {
                *slot = frame
                    .characters
                    .iter()
                    .find(|c| &c.name == name)
                    .map(|c| ArkitFace::from_character(c, axes).livelink_values());
            }
        }
        if out.faces.iter().any(Option::is_some) {
            push_drop_oldest(&inner.frames, &inner.frames_rx, out, &|| {
                inner.counters.dropped.fetch_add(1, Ordering::Relaxed);
            });
        }
    }

    /// The per-target counters and drops, for `/metrics` (`mouthpiece_livelink_…`).
    pub fn metrics(&self) -> Arc<dyn MetricsSource> {
        Arc::new(LiveLinkMetrics(self.inner.counters.clone()))
    }

    /// One line for the systemd status; `None` when no target is configured.
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
            "livelink {}; {} dropped",
            each.join(", "),
            self.inner.counters.dropped.load(Ordering::Relaxed)
        ))
    }
}

/// The Live Link output's counters under their own metric names.
#[derive(Debug)]
struct LiveLinkMetrics(Arc<OscCounters>);

impl MetricsSource for LiveLinkMetrics {
    fn render_metrics(&self, out: &mut String) {
        self.0.render_metrics_as("livelink", "Live Link", out);
    }
}

/// One target on the sender thread.
struct Link {
    target: LiveLinkTarget,
    udp: UdpLink,
}

impl Link {
    fn new(target: LiveLinkTarget, throttle: Duration) -> Self {
        Link {
            udp: UdpLink::new(target.addr, &target.label, "Live Link", throttle),
            target,
        }
    }
}

/// The sender thread's state: the configuration, the remote control's changes over it, and
/// the links they make.
struct SenderState {
    settings: LiveLinkSettings,
    overrides: Overrides,
    links: Vec<Link>,
    throttle: Duration,
}

impl SenderState {
    /// The targets the configuration and the remote control's changes make.
    fn effective_targets(&self) -> Vec<LiveLinkTarget> {
        let mut targets: Vec<LiveLinkTarget> = if self.overrides.cleared {
            Vec::new()
        } else {
            self.settings.targets.clone()
        };
        if !self.settings.characters.is_empty() {
            for addr in &self.overrides.added {
                let target = LiveLinkTarget {
                    label: addr.to_string(),
                    addr: *addr,
                    character: 0,
                };
                if !targets.contains(&target) {
                    targets.push(target);
                }
            }
        }
        targets
    }

    fn streaming(&self) -> bool {
        self.overrides.streaming.unwrap_or(self.settings.enabled)
    }

    /// The subject sent for character `i`.
    fn subject(&self, i: usize) -> &str {
        match (&self.overrides.subject, i) {
            (Some(subject), 0) => subject,
            _ => &self.settings.characters[i].subject,
        }
    }

    /// Rebuilds the links after a change; kept targets keep their sockets and counters.
    fn relink(&mut self, shared: &Shared, counters: &OscCounters) {
        let mut kept = std::mem::take(&mut self.links);
        for target in self.effective_targets() {
            let link = match kept.iter().position(|l| l.target == target) {
                Some(i) => kept.swap_remove(i),
                None => Link::new(target, self.throttle),
            };
            self.links.push(link);
        }
        counters.set_targets(self.links.iter().map(|l| l.udp.counters.clone()).collect());
        *shared.characters.lock().unwrap_or_else(|e| e.into_inner()) = self
            .settings
            .characters
            .iter()
            .take(MAX_CHARACTERS)
            .map(|c| (c.name.clone(), c.axes))
            .collect();
        let active = self.streaming() && !self.links.is_empty();
        shared.active.store(active, Ordering::Release);
        let shown: Vec<String> = self
            .links
            .iter()
            .map(|l| format!("{} ({})", l.target.label, self.subject(l.target.character)))
            .collect();
        tracing::info!(
            streaming = self.streaming(),
            "Live Link Face stream to [{}]",
            shown.join(", ")
        );
    }

    /// Applies a control message; `false` to stop.
    fn control(&mut self, message: Control, shared: &Shared, counters: &OscCounters) -> bool {
        match message {
            Control::Stop => return false,
            Control::Configure(settings) => self.settings = settings,
            Control::Remote(change) => match change {
                RemoteChange::AddTarget(addr) => {
                    if !self.overrides.added.contains(&addr) {
                        self.overrides.added.push(addr);
                    }
                }
                RemoteChange::ClearTargets => {
                    self.overrides.added.clear();
                    self.overrides.cleared = true;
                }
                RemoteChange::Subject(subject) => self.overrides.subject = Some(subject),
                RemoteChange::Streaming(on) => self.overrides.streaming = Some(on),
            },
        }
        self.relink(shared, counters);
        true
    }
}

/// The sender thread: changes and frames until [`Control::Stop`] or every handle is gone.
fn run(
    frames: Receiver<FaceFrame>,
    control: Receiver<Control>,
    shared: Arc<Shared>,
    counters: Arc<OscCounters>,
    throttle: Duration,
) {
    let mut state = SenderState {
        settings: LiveLinkSettings {
            enabled: false,
            characters: Vec::new(),
            targets: Vec::new(),
            rate: TimecodeRate::default(),
        },
        overrides: Overrides::default(),
        links: Vec::new(),
        throttle,
    };
    let mut bytes = Vec::with_capacity(512);
    tracing::info!("Live Link sender started");
    'run: loop {
        crossbeam_channel::select! {
            recv(control) -> message => {
                let Ok(message) = message else { break };
                if !state.control(message, &shared, &counters) {
                    break;
                }
            }
            recv(frames) -> frame => {
                let Ok(frame) = frame else { break };
                // A change given before the frame was offered applies to it.
                while let Ok(message) = control.try_recv() {
                    if !state.control(message, &shared, &counters) {
                        break 'run;
                    }
                }
                if !state.streaming() {
                    continue;
                }
                for c in 0..state.settings.characters.len().min(MAX_CHARACTERS) {
                    let Some(values) = &frame.faces[c] else { continue };
                    if !state.links.iter().any(|l| l.target.character == c) {
                        continue;
                    }
                    encode_datagram(
                        &mut bytes,
                        &state.settings.characters[c].device_id,
                        state.subject(c),
                        frame.time,
                        state.settings.rate,
                        values,
                    );
                    for link in state.links.iter_mut().filter(|l| l.target.character == c) {
                        link.udp.send(&bytes);
                    }
                }
            }
        }
    }
    tracing::info!("Live Link sender stopped");
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The layout's fixed parts at their offsets, read back by hand (not with the encoder).
    #[test]
    fn a_datagram_has_the_published_layout() {
        let mut values = [0.0f32; LIVELINK_VALUES];
        for (i, v) in values.iter_mut().enumerate() {
            *v = i as f32 / 100.0;
        }
        let id = "0B2C5E4F-6A7D-4E8F-9A0B-1C2D3E4F5A6B";
        let rate = TimecodeRate::Fps29_97Df;
        // One hour of 29.97 drop-frame: 107892 frames and a bit.
        let time = FrameTime::from_micros_of_day(3_600_000_000, rate);
        assert_eq!(time.frame, 107_892);
        assert_eq!(time.timecode(rate).to_string(), "01:00:00;00");
        let mut out = Vec::new();
        encode_datagram(&mut out, id, "wolf", time, rate, &values);
        assert_eq!(out.len(), 4 + 37 + 4 + 4 + 16 + 1 + 61 * 4);
        assert_eq!(&out[0..4], &[6, 0, 0, 0]);
        // Read as Unreal does: a u8 version, then a big-endian i32 length 36 ('$' = 0x24)
        // and the 36 characters.
        assert_eq!(out[0], 6);
        assert_eq!(i32::from_be_bytes(out[1..5].try_into().unwrap()), 36);
        assert_eq!(&out[5..41], id.as_bytes());
        assert_eq!(&out[41..45], &[0, 0, 0, 4]);
        assert_eq!(&out[45..49], b"wolf");
        assert_eq!(i32::from_be_bytes(out[49..53].try_into().unwrap()), 107_892);
        let sub = f32::from_be_bytes(out[53..57].try_into().unwrap());
        assert!((f64::from(sub) - time.sub_frame).abs() < 1e-6 && sub > 0.0);
        assert_eq!(i32::from_be_bytes(out[57..61].try_into().unwrap()), 30000);
        assert_eq!(i32::from_be_bytes(out[61..65].try_into().unwrap()), 1001);
        assert_eq!(out[65], 61);
        for (i, v) in values.iter().enumerate() {
            let at = 66 + 4 * i;
            assert_eq!(f32::from_be_bytes(out[at..at + 4].try_into().unwrap()), *v);
        }
    }
}
