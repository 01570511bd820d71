//! Live Link Face's OSC remote control (docs/livelink.md, *Remote control*): the app's
//! command set on a UDP port, so that Switchboard and show-control tools drive the booth as
//! they drive an iPhone.
//!
//! One thread (`mouthpiece-livelink-control`) owns the socket. A datagram from an address
//! outside the allow list is counted and dropped, never answered (OSC has no
//! authentication; an answer would tell a scanner that something listens). A datagram that
//! is not a plain OSC message with string, integer and float arguments, or whose arguments
//! do not fit its command, is counted as malformed; an unknown address as unknown; neither is
//! answered. Each allowed source address may send [`COMMANDS_PER_SECOND`] datagrams a second
//! (a burst of as many); what it sends beyond that is counted as flooded and dropped
//! unread, so one runaway script can neither fill the journal nor starve another
//! controller. Takes go through the daemon's control queue, as the WebSocket `record` request
//! does: they are the daemon's ordinary takes. Replies go to the address set with
//! `/OSCSetSendTarget`, else to the sender.

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mouthpiece_output::{Throttle, TokenBucket};
use mouthpiece_server::{
    ControlCommand, ControlOutcome, Hub, MetricsSource, Timecode, TimecodeRate,
};
use rosc::{OscMessage, OscPacket, OscType};
use tokio::sync::oneshot;

use crate::livelink::{LiveLinkOutput, RemoteChange};

/// The app's OSC addresses: commands taken and replies sent.
pub mod address {
    pub const RECORD_START: &str = "/RecordStart";
    pub const RECORD_START_CONFIRM: &str = "/RecordStartConfirm";
    pub const RECORD_STOP: &str = "/RecordStop";
    pub const RECORD_STOP_CONFIRM: &str = "/RecordStopConfirm";
    pub const SLATE: &str = "/Slate";
    pub const TAKE: &str = "/Take";
    pub const SET_SEND_TARGET: &str = "/OSCSetSendTarget";
    pub const SET_SEND_TARGET_CONFIRM: &str = "/OSCSetSendTargetConfirm";
    pub const ADD_ADDRESS: &str = "/AddLiveLinkAddress";
    pub const CLEAR_ADDRESSES: &str = "/ClearAllLiveLinkAddresses";
    pub const SUBJECT: &str = "/LiveLinkSubject";
    pub const STREAM_START: &str = "/LiveLinkStreamStart";
    pub const STREAM_STOP: &str = "/LiveLinkStreamStop";
    pub const BATTERY_QUERY: &str = "/BatteryQuery";
    pub const BATTERY: &str = "/Battery";
    pub const THERMALS_QUERY: &str = "/ThermalsQuery";
    pub const THERMALS: &str = "/Thermals";
}

/// The battery level answered: a booth runs on mains, always full.
pub const BATTERY_LEVEL: f32 = 1.0;

/// The thermal state answered: 0, iOS's "nominal" (1 fair, 2 serious, 3 critical).
pub const THERMAL_STATE: i32 = 0;

/// How long a take request may wait for the daemon before it is given up (and not answered).
pub const ANSWER_LIMIT: Duration = Duration::from_secs(30);

/// The longest datagram read; a longer one is cut and then fails to parse.
const MAX_DATAGRAM: usize = 4096;

/// Argument type tags taken: strings, 32-bit integers and floats, and their 64-bit kinds.
pub const TYPE_TAGS: &[u8] = b"sifdh";

/// Most arguments in one command (the app's take at most two).
pub const MAX_ARGS: usize = 8;

/// Datagrams a second taken from one source address, with a burst of as many. A take needs
/// a handful of commands (slate, take, start, stop); Switchboard polls battery and thermals
/// every few seconds. The same figure as the WebSocket's default per-client message rate.
pub const COMMANDS_PER_SECOND: u32 = 50;

/// Source addresses whose rate is tracked at once. A source quiet for a second has a full
/// bucket and is forgotten first; past this many busy sources, a new one waits (flooded)
/// until one falls quiet.
pub const MAX_TRACKED_SOURCES: usize = 1024;

/// What the remote control counted (the daemon's status line shows them).
#[derive(Debug, Default)]
pub struct RemoteCounters {
    /// Commands carried out.
    pub taken: AtomicU64,
    /// Datagrams from an address outside the allow list (dropped, not answered).
    pub refused: AtomicU64,
    /// Datagrams that are not a message the control takes, or with the wrong arguments.
    pub malformed: AtomicU64,
    /// Messages to an address the control does not know.
    pub unknown: AtomicU64,
    /// Commands the daemon refused or did not answer (a take that would not start).
    pub failed: AtomicU64,
    /// Datagrams from an allowed address beyond its [`COMMANDS_PER_SECOND`] (dropped unread).
    pub flooded: AtomicU64,
}

impl MetricsSource for RemoteCounters {
    fn render_metrics(&self, out: &mut String) {
        use std::fmt::Write as _;
        let name = "mouthpiece_livelink_control_datagrams_total";
        let _ = writeln!(
            out,
            "# HELP {name} Datagrams at the Live Link Face remote control, by what became of them.\n\
             # TYPE {name} counter"
        );
        for (outcome, value) in [
            ("taken", &self.taken),
            ("refused", &self.refused),
            ("malformed", &self.malformed),
            ("unknown", &self.unknown),
            ("failed", &self.failed),
            ("flooded", &self.flooded),
        ] {
            let _ = writeln!(
                out,
                "{name}{{outcome=\"{outcome}\"}} {}",
                value.load(Ordering::Relaxed)
            );
        }
    }
}

/// The remote control's configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct RemoteSettings {
    /// The UDP address to listen on.
    pub listen: SocketAddr,
    /// Source addresses taken.
    pub allowed: Vec<IpAddr>,
    /// The timecode rate of the confirmations' timecodes.
    pub rate: TimecodeRate,
}

/// The running remote control; stops its thread when dropped.
pub struct LiveLinkRemote {
    local: SocketAddr,
    allowed: Arc<Mutex<Vec<IpAddr>>>,
    counters: Arc<RemoteCounters>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for LiveLinkRemote {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveLinkRemote")
            .field("local", &self.local)
            .finish_non_exhaustive()
    }
}

impl LiveLinkRemote {
    /// Binds the control port and starts its thread; takes go to `hub`'s control queue,
    /// stream changes to `output`.
    pub fn start(
        settings: RemoteSettings,
        hub: Hub,
        output: LiveLinkOutput,
        throttle: Duration,
    ) -> std::io::Result<Self> {
        let socket = UdpSocket::bind(settings.listen)?;
        // Wakes the thread to answer take requests and to notice `stop`.
        socket.set_read_timeout(Some(Duration::from_millis(50)))?;
        let local = socket.local_addr()?;
        let allowed = Arc::new(Mutex::new(settings.allowed));
        let counters = Arc::new(RemoteCounters::default());
        let stop = Arc::new(AtomicBool::new(false));
        let mut control = Control {
            socket,
            allowed: allowed.clone(),
            counters: counters.clone(),
            hub,
            output,
            rate: settings.rate,
            send_target: None,
            slate: None,
            take: None,
            pending: Vec::new(),
            refusals: Throttle::new(throttle),
            faults: Throttle::new(throttle),
            rates: SourceRates::new(COMMANDS_PER_SECOND),
            floods: Throttle::new(throttle),
        };
        let stopping = stop.clone();
        let thread = std::thread::Builder::new()
            .name("mouthpiece-livelink-control".into())
            .spawn(move || control.run(&stopping))?;
        tracing::info!(%local, "Live Link Face remote control listening");
        Ok(LiveLinkRemote {
            local,
            allowed,
            counters,
            stop,
            thread: Some(thread),
        })
    }

    /// The bound address (the port chosen when the configuration said 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.local
    }

    /// Replaces the allow list (a reload).
    pub fn set_allowed(&self, allowed: Vec<IpAddr>) {
        *self.allowed.lock().unwrap_or_else(|e| e.into_inner()) = allowed;
    }

    pub fn counters(&self) -> &RemoteCounters {
        &self.counters
    }

    /// The counters, for `/metrics`.
    pub fn metrics(&self) -> Arc<dyn MetricsSource> {
        self.counters.clone()
    }

    /// One line for the systemd status.
    pub fn status(&self) -> String {
        let c = &self.counters;
        format!(
            "livelink control on {}: {} taken, {} refused, {} malformed, {} unknown, {} failed, \
             {} flooded",
            self.local,
            c.taken.load(Ordering::Relaxed),
            c.refused.load(Ordering::Relaxed),
            c.malformed.load(Ordering::Relaxed),
            c.unknown.load(Ordering::Relaxed),
            c.failed.load(Ordering::Relaxed),
            c.flooded.load(Ordering::Relaxed)
        )
    }
}

impl Drop for LiveLinkRemote {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// A take request waiting for the daemon.
struct Pending {
    rx: oneshot::Receiver<ControlOutcome>,
    kind: PendingKind,
    until: Instant,
    /// Where the confirmation goes.
    reply_to: SocketAddr,
}

enum PendingKind {
    Start,
    /// The take's start timecode, read when the stop was asked for.
    Stop {
        timecode: String,
    },
}

/// The control thread's state.
struct Control {
    socket: UdpSocket,
    allowed: Arc<Mutex<Vec<IpAddr>>>,
    counters: Arc<RemoteCounters>,
    hub: Hub,
    output: LiveLinkOutput,
    rate: TimecodeRate,
    /// `/OSCSetSendTarget`: where replies go.
    send_target: Option<SocketAddr>,
    /// `/Slate` and `/Take`: used by a `/RecordStart` without arguments.
    slate: Option<String>,
    take: Option<u32>,
    pending: Vec<Pending>,
    refusals: Throttle,
    faults: Throttle,
    rates: SourceRates,
    floods: Throttle,
}

/// Each source address's rate of datagrams: one [`TokenBucket`] per address, forgotten once
/// full again.
struct SourceRates {
    rate: u32,
    buckets: HashMap<IpAddr, TokenBucket>,
}

impl SourceRates {
    fn new(rate: u32) -> Self {
        SourceRates {
            rate,
            buckets: HashMap::new(),
        }
    }

    /// True when one more datagram from `source` is within its rate.
    fn take(&mut self, source: IpAddr, now: Instant) -> bool {
        if !self.buckets.contains_key(&source) && self.buckets.len() >= MAX_TRACKED_SOURCES {
            self.buckets.retain(|_, bucket| !bucket.is_full(now));
            if self.buckets.len() >= MAX_TRACKED_SOURCES {
                return false;
            }
        }
        self.buckets
            .entry(source)
            .or_insert_with(|| TokenBucket::new(self.rate, now))
            .take(now)
    }
}

/// A command's arguments did not fit it.
struct BadArguments;

impl Control {
    fn run(&mut self, stop: &AtomicBool) {
        let mut buf = vec![0u8; MAX_DATAGRAM];
        while !stop.load(Ordering::Acquire) {
            self.answer_pending();
            match self.socket.recv_from(&mut buf) {
                Ok((n, source)) => self.datagram(&buf[..n], source),
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(e) => {
                    // An ICMP error for an earlier reply, or a transient failure: the socket
                    // stays usable.
                    if let Some(held_back) = self.faults.allow(Instant::now()) {
                        tracing::debug!(held_back, "Live Link control socket: {e}");
                    }
                }
            }
        }
    }

    fn datagram(&mut self, data: &[u8], source: SocketAddr) {
        let taken = {
            let list = self.allowed.lock().unwrap_or_else(|e| e.into_inner());
            mouthpiece_config::source_allowed(&list, source.ip())
        };
        if !taken {
            self.counters.refused.fetch_add(1, Ordering::Relaxed);
            if let Some(held_back) = self.refusals.allow(Instant::now()) {
                tracing::warn!(
                    %source,
                    held_back,
                    "Live Link control: refused a datagram from an address outside [livelink] allow"
                );
            }
            return;
        }
        let now = Instant::now();
        if !self.rates.take(source.ip(), now) {
            self.counters.flooded.fetch_add(1, Ordering::Relaxed);
            if let Some(held_back) = self.floods.allow(now) {
                tracing::warn!(
                    %source,
                    held_back,
                    "Live Link control: dropped datagrams beyond {COMMANDS_PER_SECOND} a second \
                     from one address"
                );
            }
            return;
        }
        let Some(message) = parse_message(data) else {
            self.counters.malformed.fetch_add(1, Ordering::Relaxed);
            self.fault(source, "not an OSC message the control takes");
            return;
        };
        tracing::debug!(%source, address = %message.addr, "Live Link control command");
        match self.command(&message, source) {
            Ok(true) => {
                self.counters.taken.fetch_add(1, Ordering::Relaxed);
            }
            Ok(false) => {
                self.counters.unknown.fetch_add(1, Ordering::Relaxed);
                self.fault(source, "unknown command");
            }
            Err(BadArguments) => {
                self.counters.malformed.fetch_add(1, Ordering::Relaxed);
                self.fault(source, "arguments that do not fit the command");
            }
        }
    }

    fn fault(&mut self, source: SocketAddr, what: &str) {
        if let Some(held_back) = self.faults.allow(Instant::now()) {
            tracing::warn!(%source, held_back, "Live Link control: ignored {what}");
        }
    }

    /// Where replies go now.
    fn reply_to(&self, source: SocketAddr) -> SocketAddr {
        self.send_target.unwrap_or(source)
    }

    fn reply(&self, to: SocketAddr, addr: &str, args: Vec<OscType>) {
        let packet = OscPacket::Message(OscMessage {
            addr: addr.to_owned(),
            args,
        });
        match rosc::encoder::encode(&packet) {
            Ok(bytes) => {
                if let Err(e) = self.socket.send_to(&bytes, to) {
                    tracing::warn!(%to, "Live Link control: cannot send {addr}: {e}");
                }
            }
            Err(e) => tracing::error!("Live Link control: cannot encode {addr}: {e}"),
        }
    }

    fn change(&self, change: RemoteChange) {
        if let Err(e) = self.output.remote(change) {
            tracing::error!("Live Link control: {e}");
            self.counters.failed.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Carries out one command: `Ok(false)` when the address is not one of the app's.
    fn command(&mut self, m: &OscMessage, source: SocketAddr) -> Result<bool, BadArguments> {
        use address::*;
        let args = m.args.as_slice();
        match m.addr.as_str() {
            RECORD_START => {
                let (slate, take) = match args {
                    [] => (self.slate.clone(), self.take),
                    [slate] => (Some(string(slate)?), self.take),
                    [slate, take] => (Some(string(slate)?), take_number(take)?),
                    _ => return Err(BadArguments),
                };
                self.slate.clone_from(&slate);
                self.take = take;
                self.queue(
                    ControlCommand::RecordStart {
                        slate: slate.filter(|s| !s.is_empty()),
                        take,
                    },
                    PendingKind::Start,
                    source,
                );
            }
            RECORD_STOP => {
                no_args(args)?;
                let timecode = self.take_timecode();
                self.queue(
                    ControlCommand::RecordStop,
                    PendingKind::Stop { timecode },
                    source,
                );
            }
            SLATE => {
                let [slate] = args else {
                    return Err(BadArguments);
                };
                self.slate = Some(string(slate)?);
            }
            TAKE => {
                let [take] = args else {
                    return Err(BadArguments);
                };
                self.take = take_number(take)?;
            }
            SET_SEND_TARGET => {
                let target = socket_addr(args)?;
                self.send_target = Some(target);
                tracing::info!(%target, "Live Link control: replies go to {target}");
                self.reply(target, SET_SEND_TARGET_CONFIRM, Vec::new());
            }
            ADD_ADDRESS => {
                let target = socket_addr(args)?;
                self.change(RemoteChange::AddTarget(target));
            }
            CLEAR_ADDRESSES => {
                no_args(args)?;
                self.change(RemoteChange::ClearTargets);
            }
            SUBJECT => {
                let [subject] = args else {
                    return Err(BadArguments);
                };
                let subject = string(subject)?;
                if subject.is_empty()
                    || subject.len() > 255
                    || subject.chars().any(char::is_control)
                {
                    return Err(BadArguments);
                }
                self.change(RemoteChange::Subject(subject));
            }
            STREAM_START => {
                no_args(args)?;
                self.change(RemoteChange::Streaming(true));
            }
            STREAM_STOP => {
                no_args(args)?;
                self.change(RemoteChange::Streaming(false));
            }
            BATTERY_QUERY => {
                no_args(args)?;
                let to = self.reply_to(source);
                self.reply(to, BATTERY, vec![OscType::Float(BATTERY_LEVEL)]);
            }
            THERMALS_QUERY => {
                no_args(args)?;
                let to = self.reply_to(source);
                self.reply(to, THERMALS, vec![OscType::Int(THERMAL_STATE)]);
            }
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// The timecode of the take now recording (its start), `""` when none is.
    fn take_timecode(&self) -> String {
        self.hub
            .status()
            .recording
            .and_then(|r| r.started_wall_us)
            .map(|us| Timecode::from_unix_micros(us, self.rate).to_string())
            .unwrap_or_default()
    }

    fn queue(&mut self, command: ControlCommand, kind: PendingKind, source: SocketAddr) {
        match self
            .hub
            .request_control(command, format!("livelink {source}"))
        {
            Ok(rx) => self.pending.push(Pending {
                rx,
                kind,
                until: Instant::now() + ANSWER_LIMIT,
                reply_to: self.reply_to(source),
            }),
            Err(e) => {
                self.counters.failed.fetch_add(1, Ordering::Relaxed);
                tracing::warn!("Live Link control: take request not queued: {e:?}");
            }
        }
    }

    /// Sends the confirmations of take requests the daemon has answered.
    fn answer_pending(&mut self) {
        let now = Instant::now();
        let mut waiting = Vec::with_capacity(self.pending.len());
        for mut p in std::mem::take(&mut self.pending) {
            match p.rx.try_recv() {
                Ok(Ok(detail)) => self.confirm(&p, &detail),
                Ok(Err(failure)) => {
                    self.counters.failed.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!("Live Link control: {}", failure.message);
                }
                Err(oneshot::error::TryRecvError::Empty) if now < p.until => waiting.push(p),
                Err(_) => {
                    self.counters.failed.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!("Live Link control: the daemon did not answer a take request");
                }
            }
        }
        self.pending = waiting;
    }

    fn confirm(&self, p: &Pending, detail: &serde_json::Value) {
        match &p.kind {
            PendingKind::Start => {
                let timecode = self.take_timecode();
                self.reply(
                    p.reply_to,
                    address::RECORD_START_CONFIRM,
                    vec![OscType::String(timecode)],
                );
            }
            PendingKind::Stop { timecode } => {
                let file = detail["file"].as_str().unwrap_or_default().to_owned();
                // The app's third path is its reference video; a booth writes none.
                self.reply(
                    p.reply_to,
                    address::RECORD_STOP_CONFIRM,
                    vec![
                        OscType::String(timecode.clone()),
                        OscType::String(file),
                        OscType::String(String::new()),
                    ],
                );
            }
        }
    }
}

fn no_args(args: &[OscType]) -> Result<(), BadArguments> {
    if args.is_empty() {
        Ok(())
    } else {
        Err(BadArguments)
    }
}

fn string(arg: &OscType) -> Result<String, BadArguments> {
    match arg {
        OscType::String(s) => Ok(s.clone()),
        _ => Err(BadArguments),
    }
}

/// A take number: an integer (a whole float taken too); 0 or less lets the daemon pick.
fn take_number(arg: &OscType) -> Result<Option<u32>, BadArguments> {
    let n = match *arg {
        OscType::Int(n) => i64::from(n),
        OscType::Long(n) => n,
        OscType::Float(f) if f.fract() == 0.0 && f.is_finite() => f as i64,
        _ => return Err(BadArguments),
    };
    Ok(u32::try_from(n).ok().filter(|n| *n > 0))
}

/// `ip:string port:int` as a socket address.
fn socket_addr(args: &[OscType]) -> Result<SocketAddr, BadArguments> {
    let [OscType::String(ip), port] = args else {
        return Err(BadArguments);
    };
    let ip: IpAddr = ip.parse().map_err(|_| BadArguments)?;
    let port = match *port {
        OscType::Int(p) => i64::from(p),
        OscType::Long(p) => p,
        _ => return Err(BadArguments),
    };
    let port = u16::try_from(port)
        .ok()
        .filter(|p| *p > 0)
        .ok_or(BadArguments)?;
    Ok(SocketAddr::new(ip, port))
}

/// The OSC message in `data`, or `None`. Only a plain message is taken (no bundle: the app's
/// commands are single messages), with at most [`MAX_ARGS`] arguments of the kinds in
/// [`TYPE_TAGS`]; this is checked on the raw bytes before the decoder sees them, so nothing
/// nested (bundles in bundles, arrays in arrays) is ever built from a hostile datagram.
pub fn parse_message(data: &[u8]) -> Option<OscMessage> {
    if data.first() != Some(&b'/') || !data.len().is_multiple_of(4) {
        return None;
    }
    let address_end = data.iter().position(|b| *b == 0)?;
    let tags_start = (address_end + 4) & !3;
    let tags = data.get(tags_start..)?;
    let tags_end = tags.iter().position(|b| *b == 0)?;
    let tags = &tags[..tags_end];
    if tags.first() != Some(&b',')
        || tags.len() > MAX_ARGS + 1
        || !tags[1..].iter().all(|t| TYPE_TAGS.contains(t))
    {
        return None;
    }
    match rosc::decoder::decode_udp(data) {
        Ok(([], OscPacket::Message(m))) => Some(m),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn encoded(addr: &str, args: Vec<OscType>) -> Vec<u8> {
        rosc::encoder::encode(&OscPacket::Message(OscMessage {
            addr: addr.into(),
            args,
        }))
        .unwrap()
    }

    #[test]
    fn the_app_commands_parse_and_hostile_datagrams_do_not() {
        let m = parse_message(&encoded(
            "/RecordStart",
            vec![OscType::String("scene-1".into()), OscType::Int(3)],
        ))
        .unwrap();
        assert_eq!(m.addr, "/RecordStart");
        assert_eq!(take_number(&m.args[1]).ok(), Some(Some(3)));
        assert!(parse_message(&encoded("/RecordStop", Vec::new())).is_some());
        // A bundle, an array, a blob, too many arguments, junk, truncation: refused.
        let bundle = rosc::encoder::encode(&OscPacket::Bundle(rosc::OscBundle {
            timetag: rosc::OscTime {
                seconds: 0,
                fractional: 1,
            },
            content: vec![OscPacket::Message(OscMessage {
                addr: "/RecordStop".into(),
                args: Vec::new(),
            })],
        }))
        .unwrap();
        let array = encoded(
            "/Slate",
            vec![OscType::Array(rosc::OscArray {
                content: vec![OscType::Int(1)],
            })],
        );
        let blob = encoded("/Slate", vec![OscType::Blob(vec![1, 2, 3])]);
        let many = encoded("/Slate", vec![OscType::Int(1); MAX_ARGS + 1]);
        let good = encoded("/Slate", vec![OscType::String("a".into())]);
        for bad in [
            bundle,
            array,
            blob,
            many,
            good[..good.len() - 4].to_vec(),
            b"/a\0\0,[[[[[[[[[[[[".to_vec(),
            Vec::new(),
            vec![0xff; 64],
        ] {
            assert!(parse_message(&bad).is_none(), "{bad:?}");
        }
    }

    #[test]
    fn arguments_are_checked() {
        let ip = |s: &str| OscType::String(s.into());
        assert_eq!(
            socket_addr(&[ip("127.0.0.1"), OscType::Int(11111)]).ok(),
            Some("127.0.0.1:11111".parse().unwrap())
        );
        for bad in [
            vec![ip("127.0.0.1"), OscType::Int(0)],
            vec![ip("127.0.0.1"), OscType::Int(70000)],
            vec![ip("localhost"), OscType::Int(1)],
            vec![ip("127.0.0.1")],
            vec![OscType::Int(1), OscType::Int(1)],
        ] {
            assert!(socket_addr(&bad).is_err(), "{bad:?}");
        }
        assert_eq!(take_number(&OscType::Int(-1)).ok(), Some(None));
        assert!(take_number(&OscType::String("1".into())).is_err());
    }

    #[test]
    fn each_source_has_its_own_rate_and_quiet_sources_are_forgotten() {
        let t0 = Instant::now();
        let mut rates = SourceRates::new(5);
        let a: IpAddr = "10.0.0.1".parse().unwrap();
        let b: IpAddr = "10.0.0.2".parse().unwrap();
        assert_eq!((0..50).filter(|_| rates.take(a, t0)).count(), 5);
        assert!(
            rates.take(b, t0),
            "a flood from one address leaves the others alone"
        );
        // Many busy sources: the table stays bounded, a new source waits until one is quiet.
        for i in 0..MAX_TRACKED_SOURCES as u32 {
            rates.take(IpAddr::from((0x0b00_0000 + i).to_be_bytes()), t0);
        }
        assert!(rates.buckets.len() <= MAX_TRACKED_SOURCES);
        let late: IpAddr = "12.0.0.1".parse().unwrap();
        assert!(!rates.take(late, t0));
        assert!(rates.take(late, t0 + Duration::from_secs(2)));
        assert_eq!(rates.buckets.len(), 1, "the quiet ones were forgotten");
    }
}
