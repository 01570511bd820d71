//! One UDP target of a sender thread: a connected, non-blocking socket opened on first use
//! and again a second after a failure, the target's counters, and its failures logged at most
//! once per interval. The VMC and Live Link senders each keep one per target.

use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use mouthpiece_output::Throttle;
use mouthpiece_server::OscTargetCounters;

/// How long a target whose socket could not be opened is left before the next try.
const REOPEN_AFTER: Duration = Duration::from_secs(1);

/// A UDP socket connected to `addr` (so that the kernel reports a refusing target on later
/// sends), non-blocking.
pub(crate) fn open_socket(addr: SocketAddr) -> std::io::Result<UdpSocket> {
    let local: SocketAddr = if addr.is_ipv4() {
        (std::net::Ipv4Addr::UNSPECIFIED, 0).into()
    } else {
        (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
    };
    let socket = UdpSocket::bind(local)?;
    socket.connect(addr)?;
    socket.set_nonblocking(true)?;
    Ok(socket)
}

/// One target's socket and counters.
pub(crate) struct UdpLink {
    addr: SocketAddr,
    /// The target as configured (`host:port`), for the log.
    label: String,
    /// The protocol's name in log lines (`OSC`, `Live Link`).
    protocol: &'static str,
    socket: Option<UdpSocket>,
    /// When to try opening the socket again after a failure.
    retry_at: Option<Instant>,
    pub(crate) counters: Arc<OscTargetCounters>,
    failures: Throttle,
}

impl UdpLink {
    pub(crate) fn new(
        addr: SocketAddr,
        label: &str,
        protocol: &'static str,
        throttle: Duration,
    ) -> Self {
        UdpLink {
            addr,
            label: label.to_owned(),
            protocol,
            socket: None,
            retry_at: None,
            counters: Arc::new(OscTargetCounters::new(label)),
            failures: Throttle::new(throttle),
        }
    }

    fn failed(&mut self, what: &str, e: &std::io::Error) {
        self.counters.errors.fetch_add(1, Ordering::Relaxed);
        if let Some(held_back) = self.failures.allow(Instant::now()) {
            tracing::warn!(
                target_addr = %self.label,
                held_back,
                "{}: {what} {}: {e}",
                self.protocol,
                self.addr
            );
        }
    }

    /// Sends one datagram; a failure is counted and logged (throttled), never an error: a
    /// receiver started later gets the datagrams after it.
    pub(crate) fn send(&mut self, bytes: &[u8]) {
        if self.socket.is_none() {
            if self.retry_at.is_some_and(|at| Instant::now() < at) {
                self.counters.errors.fetch_add(1, Ordering::Relaxed);
                return;
            }
            match open_socket(self.addr) {
                Ok(socket) => {
                    self.socket = Some(socket);
                    self.retry_at = None;
                }
                Err(e) => {
                    self.retry_at = Some(Instant::now() + REOPEN_AFTER);
                    self.failed("cannot open a socket to", &e);
                    return;
                }
            }
        }
        let Some(socket) = &self.socket else { return };
        match socket.send(bytes) {
            Ok(_) => {
                self.counters.sent.fetch_add(1, Ordering::Relaxed);
            }
            Err(e) => self.failed("cannot send to", &e),
        }
    }
}
