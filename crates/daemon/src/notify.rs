//! systemd's notify protocol (`sd_notify(3)`): `READY=1`, `STATUS=…`, `WATCHDOG=1`,
//! `STOPPING=1`, `RELOADING=1`, sent as datagrams to the socket named by `$NOTIFY_SOCKET`
//! (a path, or an abstract socket when it starts with `@`).
//!
//! Small enough to write here rather than pull a crate for: one datagram per call, no unsafe.
//! Outside systemd (`NOTIFY_SOCKET` unset) every call is a no-op.

use std::io;
use std::os::unix::net::{SocketAddr, UnixDatagram};
use std::time::Duration;

/// A handle to the service manager, or nothing when not run by one.
#[derive(Debug)]
pub struct Notifier {
    target: Option<(UnixDatagram, SocketAddr)>,
    watchdog: Option<Duration>,
}

impl Notifier {
    /// From `$NOTIFY_SOCKET`, `$WATCHDOG_USEC` and `$WATCHDOG_PID` (the watchdog applies only
    /// when `WATCHDOG_PID` is unset or names this process).
    pub fn from_env() -> io::Result<Notifier> {
        let socket = std::env::var_os("NOTIFY_SOCKET");
        let watchdog = std::env::var("WATCHDOG_USEC")
            .ok()
            .and_then(|usec| usec.parse::<u64>().ok())
            .filter(|&usec| usec > 0)
            .filter(|_| {
                std::env::var("WATCHDOG_PID")
                    .ok()
                    .and_then(|pid| pid.parse::<u32>().ok())
                    .is_none_or(|pid| pid == std::process::id())
            })
            .map(Duration::from_micros);
        match socket {
            Some(path) if !path.is_empty() => {
                let mut notifier = Notifier::connect(path.to_str().ok_or_else(|| {
                    io::Error::new(io::ErrorKind::InvalidInput, "NOTIFY_SOCKET is not UTF-8")
                })?)?;
                notifier.watchdog = watchdog;
                Ok(notifier)
            }
            _ => Ok(Notifier::disabled()),
        }
    }

    /// Sends to the socket at `path` (`@name` for an abstract socket).
    pub fn connect(path: &str) -> io::Result<Notifier> {
        let addr = match path.strip_prefix('@') {
            Some(name) => abstract_addr(name.as_bytes())?,
            None => SocketAddr::from_pathname(path)?,
        };
        let socket = UnixDatagram::unbound()?;
        Ok(Notifier {
            target: Some((socket, addr)),
            watchdog: None,
        })
    }

    /// A notifier that sends nothing.
    pub fn disabled() -> Notifier {
        Notifier {
            target: None,
            watchdog: None,
        }
    }

    pub fn is_enabled(&self) -> bool {
        self.target.is_some()
    }

    /// The watchdog timeout systemd expects pings within (`WatchdogSec=`), if any. Ping at
    /// half of it.
    pub fn watchdog_timeout(&self) -> Option<Duration> {
        self.watchdog
    }

    /// Sends newline-separated `KEY=VALUE` assignments.
    pub fn notify(&self, state: &str) -> io::Result<()> {
        let Some((socket, addr)) = &self.target else {
            return Ok(());
        };
        let sent = socket.send_to_addr(state.as_bytes(), addr)?;
        if sent != state.len() {
            return Err(io::Error::new(
                io::ErrorKind::WriteZero,
                "short notify datagram",
            ));
        }
        Ok(())
    }

    /// Start-up is complete; `status` is shown by `systemctl status`.
    pub fn ready(&self, status: &str) -> io::Result<()> {
        self.notify(&format!("READY=1\nSTATUS={}", one_line(status)))
    }

    pub fn status(&self, status: &str) -> io::Result<()> {
        self.notify(&format!("STATUS={}", one_line(status)))
    }

    pub fn watchdog(&self) -> io::Result<()> {
        self.notify("WATCHDOG=1")
    }

    pub fn stopping(&self) -> io::Result<()> {
        self.notify("STOPPING=1")
    }

    /// A reload began (`Type=notify-reload` semantics); follow with [`reloaded`](Self::reloaded).
    pub fn reloading(&self) -> io::Result<()> {
        let now = monotonic_usec();
        self.notify(&format!("RELOADING=1\nMONOTONIC_USEC={now}"))
    }

    pub fn reloaded(&self, status: &str) -> io::Result<()> {
        self.ready(status)
    }
}

/// A status value may not contain newlines (they separate assignments).
fn one_line(s: &str) -> String {
    s.replace('\n', " ")
}

fn abstract_addr(name: &[u8]) -> io::Result<SocketAddr> {
    use std::os::linux::net::SocketAddrExt;
    SocketAddr::from_abstract_name(name)
}

/// CLOCK_MONOTONIC in microseconds, as systemd wants it with RELOADING=1.
fn monotonic_usec() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC is always available on Linux.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    if rc != 0 {
        return 0;
    }
    ts.tv_sec as u64 * 1_000_000 + ts.tv_nsec as u64 / 1_000
}

#[cfg(test)]
mod tests {
    use super::*;

    fn receive(socket: &UnixDatagram) -> String {
        let mut buf = [0u8; 4096];
        let n = socket.recv(&mut buf).unwrap();
        String::from_utf8(buf[..n].to_vec()).unwrap()
    }

    #[test]
    fn datagrams_reach_a_path_socket() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("notify.sock");
        let server = UnixDatagram::bind(&path).unwrap();
        server
            .set_read_timeout(Some(Duration::from_secs(5)))
            .unwrap();
        let notifier = Notifier::connect(path.to_str().unwrap()).unwrap();
        notifier.ready("streaming\nfrom replay").unwrap();
        assert_eq!(receive(&server), "READY=1\nSTATUS=streaming from replay");
        notifier.watchdog().unwrap();
        assert_eq!(receive(&server), "WATCHDOG=1");
        notifier.stopping().unwrap();
        assert_eq!(receive(&server), "STOPPING=1");
        notifier.reloading().unwrap();
        let reloading = receive(&server);
        assert!(
            reloading.starts_with("RELOADING=1\nMONOTONIC_USEC="),
            "{reloading}"
        );
    }

    #[test]
    fn datagrams_reach_an_abstract_socket() {
        let name = format!("mouthpiece-test-{}", std::process::id());
        let server = UnixDatagram::bind_addr(&abstract_addr(name.as_bytes()).unwrap()).unwrap();
        server
            .set_read_timeout(Some(Duration::from_secs(5)))
            .unwrap();
        let notifier = Notifier::connect(&format!("@{name}")).unwrap();
        notifier.status("source down").unwrap();
        assert_eq!(receive(&server), "STATUS=source down");
    }

    #[test]
    fn disabled_notifier_sends_nothing_and_succeeds() {
        let notifier = Notifier::disabled();
        assert!(!notifier.is_enabled());
        notifier.ready("x").unwrap();
        assert_eq!(notifier.watchdog_timeout(), None);
    }
}
