//! The real daemon in an integration test: `mouthpiece run` as a child process, started in a
//! folder of the test's own, waited for until it listens, stopped with SIGTERM as systemd
//! stops it (or killed when the test fails first). Included by the tests that need it with
//! `#[path]`.

#![allow(dead_code)]

use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

/// A TCP port nobody listens on now.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// `mouthpiece run --config CONFIG` in `dir`, not told it runs under systemd, no input or
/// output (a test sets `stderr` where it reads the log, and its own environment).
pub fn run_command(dir: &Path, config: &Path) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_mouthpiece"));
    command
        .arg("run")
        .arg("--config")
        .arg(config)
        .current_dir(dir)
        .env_remove("NOTIFY_SOCKET")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    command
}

/// A running daemon, killed when dropped.
pub struct Daemon(pub Child);

impl Daemon {
    /// Spawns `command` (see [`run_command`]).
    pub fn spawn(command: &mut Command) -> Daemon {
        Daemon(command.spawn().unwrap())
    }

    /// [`Daemon::spawn`], then waits until it accepts connections on `port` (a generous
    /// limit: a loaded machine passes too).
    pub fn listening(command: &mut Command, port: u16) -> Daemon {
        let daemon = Daemon::spawn(command);
        let deadline = Instant::now() + Duration::from_secs(30);
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(Instant::now() < deadline, "the daemon did not listen");
            std::thread::sleep(Duration::from_millis(50));
        }
        daemon
    }

    /// SIGTERM, as systemd stops it, and its exit status.
    pub fn terminate(&mut self) -> ExitStatus {
        // SAFETY: kill(2) on our own child with SIGTERM.
        unsafe { libc::kill(self.0.id() as i32, libc::SIGTERM) };
        self.0.wait().unwrap()
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}
