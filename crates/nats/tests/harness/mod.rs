//! A real `nats-server` for tests: started on free loopback ports in a temporary folder,
//! JetStream on, killed when dropped. Shared by the NATS tests of several crates
//! (`#[path]`). A missing `nats-server` fails the test with how to install it.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// How to get the server when it is missing.
pub const INSTALL_HINT: &str = "nats-server is not installed: `apt-get install nats-server` \
     (Debian 12 and later; scripts/test installs it), or put a nats-server 2.9+ on PATH";

pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn binary() -> String {
    let name = std::env::var("NATS_SERVER").unwrap_or_else(|_| "nats-server".to_owned());
    match Command::new(&name).arg("--version").output() {
        Ok(out) if out.status.success() => name,
        _ => panic!("{INSTALL_HINT}"),
    }
}

/// One `nats-server` process.
pub struct NatsServer {
    child: Option<Child>,
    pub port: u16,
    pub cluster_port: Option<u16>,
    /// JetStream's store and the log live here (kept across [`NatsServer::restart`]).
    pub dir: PathBuf,
    args: Vec<String>,
    _temp: Option<tempfile::TempDir>,
}

impl NatsServer {
    /// A single server with JetStream.
    pub fn start() -> NatsServer {
        Self::start_with(&[])
    }

    /// A single server with JetStream and extra command-line arguments (e.g. `-c FILE`).
    pub fn start_with(extra: &[&str]) -> NatsServer {
        Self::start_on_with(free_port(), extra)
    }

    /// A single server with JetStream on `port`.
    pub fn start_on(port: u16) -> NatsServer {
        Self::start_on_with(port, &[])
    }

    fn start_on_with(port: u16, extra: &[&str]) -> NatsServer {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_owned();
        let mut args: Vec<String> = vec![
            "-js".into(),
            "-a".into(),
            "127.0.0.1".into(),
            "-p".into(),
            port.to_string(),
            "-sd".into(),
            dir.join("js").display().to_string(),
        ];
        args.extend(extra.iter().map(|s| s.to_string()));
        let mut server = NatsServer {
            child: None,
            port,
            cluster_port: None,
            dir,
            args,
            _temp: Some(temp),
        };
        server.spawn();
        server
    }

    /// Three clustered servers with JetStream, routes to each other.
    pub fn cluster() -> Vec<NatsServer> {
        let temp = tempfile::tempdir().unwrap();
        let ports: Vec<(u16, u16)> = (0..3).map(|_| (free_port(), free_port())).collect();
        let mut nodes = Vec::new();
        for (i, (port, cluster)) in ports.iter().enumerate() {
            let dir = temp.path().join(format!("n{i}"));
            std::fs::create_dir_all(&dir).unwrap();
            let routes: Vec<String> = ports
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, (_, c))| format!("nats://127.0.0.1:{c}"))
                .collect();
            let args = vec![
                "-js".into(),
                "-n".into(),
                format!("n{i}"),
                "-a".into(),
                "127.0.0.1".into(),
                "-p".into(),
                port.to_string(),
                "-sd".into(),
                dir.join("js").display().to_string(),
                "--cluster_name".into(),
                "mp".into(),
                "-cluster".into(),
                format!("nats://127.0.0.1:{cluster}"),
                "-routes".into(),
                routes.join(","),
            ];
            nodes.push(NatsServer {
                child: None,
                port: *port,
                cluster_port: Some(*cluster),
                dir,
                args,
                _temp: None,
            });
        }
        for node in &mut nodes {
            node.spawn_no_wait();
        }
        for node in &nodes {
            node.wait_ready();
        }
        // The temporary folder lives as long as the first node.
        nodes[0]._temp = Some(temp);
        nodes
    }

    pub fn url(&self) -> String {
        format!("nats://127.0.0.1:{}", self.port)
    }

    fn spawn_no_wait(&mut self) {
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(self.dir.join("server.log"))
            .unwrap();
        let child = Command::new(binary())
            .args(&self.args)
            .stdin(Stdio::null())
            .stdout(log.try_clone().unwrap())
            .stderr(log)
            .spawn()
            .unwrap_or_else(|e| panic!("{INSTALL_HINT} ({e})"));
        self.child = Some(child);
    }

    fn spawn(&mut self) {
        self.spawn_no_wait();
        self.wait_ready();
    }

    /// Waits until the client port accepts connections (bounded: 20 s).
    fn wait_ready(&self) {
        let until = Instant::now() + Duration::from_secs(20);
        while Instant::now() < until {
            if std::net::TcpStream::connect(("127.0.0.1", self.port)).is_ok() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        panic!(
            "nats-server on port {} did not start: {}",
            self.port,
            self.log()
        );
    }

    /// Kills the server (SIGKILL: a crash, not a shutdown).
    pub fn kill(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }

    /// Starts it again on the same port and store.
    pub fn restart(&mut self) {
        self.kill();
        self.spawn();
    }

    /// Starts it again without waiting (cluster nodes wait for each other).
    pub fn restart_no_wait(&mut self) {
        self.kill();
        self.spawn_no_wait();
    }

    pub fn wait_until_ready(&self) {
        self.wait_ready();
    }

    pub fn log(&self) -> String {
        std::fs::read_to_string(self.dir.join("server.log")).unwrap_or_default()
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }
}

impl Drop for NatsServer {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Polls `check` until it gives `Some`, for at most `limit` (a bound, not a pace: the
/// answer usually comes in milliseconds).
pub async fn eventually<T>(
    limit: Duration,
    mut check: impl AsyncFnMut() -> Option<T>,
) -> Option<T> {
    let until = Instant::now() + limit;
    loop {
        if let Some(v) = check().await {
            return Some(v);
        }
        if Instant::now() >= until {
            return None;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// Logs of the code under test in the test's output (shown when it fails).
pub fn init_logs() {
    let _ = tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "mouthpiece_nats=debug,info".into()),
        )
        .with_test_writer()
        .try_init();
}
