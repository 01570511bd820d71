//! A mouthpiece booth on NATS (docs/nats.md): one job, the booth's NATS link.
//!
//! - [`publish`]: frames (JSON and the binary layout), each character's rig, `status` and
//!   `hello` published on `mouthpiece.<booth>.*`. The publisher reads the hub's frame ring
//!   like a WebSocket client does, so the processing thread never waits for it: when the
//!   publisher falls behind (a slow broker) it loses the oldest frames, and while the broker
//!   is away frames are dropped rather than queued to go out late; both are counted
//!   (`mouthpiece_nats_frames_dropped_total`).
//! - [`respond`]: control (`calibrate`, `record`, `look_at`) and `hello` over request/reply,
//!   answered through the server's own control handling. Who may send a control request is
//!   the NATS server's decision (its users' publish permissions).
//! - [`upload`]: every closed take in the takes folder goes to the studio's JetStream object
//!   store with its metadata in a key-value bucket; the local file stays, with an
//!   `.uploaded` marker once the store has confirmed it. The backlog of a booth that was
//!   offline goes up when the broker is back.
//! - [`store`]: listing and fetching takes from the store (`mouthpiece takes`).
//!
//! Everything runs as tasks on the daemon's tokio runtime; the client reconnects by itself
//! with a growing delay, and the booth (WebSocket, OSC, local takes) never depends on it.

use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use mouthpiece_config::{NatsConfig, Secret};

pub mod publish;
pub mod respond;
pub mod store;
pub mod subjects;
pub mod upload;

pub use subjects::Subjects;

/// How the booth authenticates to the NATS server.
#[derive(Clone, Default)]
pub enum Auth {
    /// No credentials.
    #[default]
    None,
    UserPassword {
        user: String,
        password: Secret,
    },
    Token(Secret),
    /// An NKey seed.
    NKey(Secret),
    /// A `.creds` file (JWT and seed).
    CredentialsFile(PathBuf),
}

impl std::fmt::Debug for Auth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Never the secret; the user name and the file are not secrets.
        match self {
            Auth::None => f.write_str("None"),
            Auth::UserPassword { user, .. } => write!(f, "UserPassword({user:?}, ***)"),
            Auth::Token(_) => f.write_str("Token(***)"),
            Auth::NKey(_) => f.write_str("NKey(***)"),
            Auth::CredentialsFile(path) => write!(f, "CredentialsFile({path:?})"),
        }
    }
}

/// TLS towards the NATS server.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Tls {
    /// CA certificate(s) to verify the server with.
    pub ca: Option<PathBuf>,
    /// Client certificate and key (mutual TLS).
    pub client: Option<(PathBuf, PathBuf)>,
}

/// Everything the NATS link needs, from `[nats]`.
#[derive(Debug, Clone)]
pub struct NatsSettings {
    pub servers: Vec<String>,
    /// Subject-safe (checked by the configuration).
    pub booth: String,
    /// Subject-safe; names the buckets.
    pub studio: String,
    pub upload_takes: bool,
    pub auth: Auth,
    pub tls: Tls,
    /// Publish `.frame.bin`.
    pub binary: bool,
    /// Publish `.rig.<character>`.
    pub rig: bool,
    /// Longest wait between reconnection attempts.
    pub reconnect_max: Duration,
}

impl NatsSettings {
    /// The settings of a validated `[nats]`; `None` while it is off.
    pub fn from_config(config: &NatsConfig) -> Option<NatsSettings> {
        if !config.enabled() {
            return None;
        }
        let secrets = &config.secrets;
        let auth = if let (Some(user), Some(password)) = (&config.user, &secrets.password) {
            Auth::UserPassword {
                user: user.clone(),
                password: password.clone(),
            }
        } else if let Some(token) = &secrets.token {
            Auth::Token(token.clone())
        } else if let Some(seed) = &secrets.nkey {
            Auth::NKey(seed.clone())
        } else if let Some(path) = &config.credentials_file {
            Auth::CredentialsFile(path.clone())
        } else {
            Auth::None
        };
        Some(NatsSettings {
            servers: config.servers.clone(),
            booth: config.booth.clone().unwrap_or_default(),
            studio: config.studio.clone(),
            upload_takes: config.upload_takes,
            auth,
            tls: Tls {
                ca: config.tls_ca.clone(),
                client: config.tls_cert.clone().zip(config.tls_key.clone()),
            },
            binary: config.binary,
            rig: config.rig,
            reconnect_max: config.reconnect_max_s.duration(),
        })
    }

    /// Settings for `servers` and `booth` with everything else at its default (tests, tools).
    pub fn new(servers: Vec<String>, booth: &str) -> NatsSettings {
        NatsSettings {
            servers,
            booth: booth.to_owned(),
            studio: "studio".to_owned(),
            upload_takes: true,
            auth: Auth::None,
            tls: Tls::default(),
            binary: true,
            rig: true,
            reconnect_max: Duration::from_secs(5),
        }
    }

    pub fn subjects(&self) -> Subjects {
        Subjects::new(&self.booth)
    }
}

/// Why the NATS link could not be set up. Never holds a credential.
#[derive(Debug, thiserror::Error)]
pub enum NatsError {
    #[error("bad NATS server address {0:?}")]
    Address(String),
    #[error("cannot read the NATS credentials file {path}")]
    Credentials {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot connect to NATS ({servers}): {message}")]
    Connect { servers: String, message: String },
    #[error("NATS: {0}")]
    Store(String),
    /// An object whose info or data cannot be trusted (no digest, a link out of the bucket,
    /// a size or digest that does not match what was received).
    #[error("object {object} {why}")]
    Untrusted {
        object: String,
        why: crate::store::Refused,
    },
}

/// The reconnection delay after `attempts` failed attempts: none at first (another node of
/// a cluster is usually there at once), then doubling from 100 ms up to `max`.
pub fn reconnect_delay(attempts: usize, max: Duration) -> Duration {
    if attempts <= 1 {
        return Duration::ZERO;
    }
    let exponent = (attempts - 2).min(16) as u32;
    Duration::from_millis(100u64 << exponent).min(max)
}

/// Connection options for the daemon: unlimited reconnection with backoff, credentials and
/// TLS from the settings.
pub async fn connect_options(
    settings: &NatsSettings,
    name: &str,
) -> Result<async_nats::ConnectOptions, NatsError> {
    let max = settings.reconnect_max;
    let options = async_nats::ConnectOptions::new()
        .name(name)
        .retry_on_initial_connect()
        .max_reconnects(None)
        .connection_timeout(Duration::from_secs(2))
        .ping_interval(Duration::from_secs(2))
        // Messages waiting for the socket; the publisher drops frames rather than fill it.
        .client_capacity(1024)
        .reconnect_delay_callback(move |attempts| reconnect_delay(attempts, max));
    with_credentials(options, settings).await
}

/// Adds the settings' credentials and TLS to `options`.
pub async fn with_credentials(
    mut options: async_nats::ConnectOptions,
    settings: &NatsSettings,
) -> Result<async_nats::ConnectOptions, NatsError> {
    options = match &settings.auth {
        Auth::None => options,
        Auth::UserPassword { user, password } => {
            options.user_and_password(user.clone(), password.expose().to_owned())
        }
        Auth::Token(token) => options.token(token.expose().to_owned()),
        Auth::NKey(seed) => options.nkey(seed.expose().to_owned()),
        Auth::CredentialsFile(path) => {
            options
                .credentials_file(path)
                .await
                .map_err(|source| NatsError::Credentials {
                    path: path.clone(),
                    source,
                })?
        }
    };
    if let Some(ca) = &settings.tls.ca {
        options = options.add_root_certificates(ca.clone()).require_tls(true);
    }
    if let Some((cert, key)) = &settings.tls.client {
        options = options
            .add_client_certificate(cert.clone(), key.clone())
            .require_tls(true);
    }
    Ok(options)
}

/// The server addresses of the settings.
pub fn server_addrs(servers: &[String]) -> Result<Vec<async_nats::ServerAddr>, NatsError> {
    servers
        .iter()
        .map(|s| {
            s.parse::<async_nats::ServerAddr>()
                .map_err(|_| NatsError::Address(s.clone()))
        })
        .collect()
}

/// How long [`connect_once`] tries the servers in all (each server gets
/// [`CONNECT_TIMEOUT_PER_SERVER`] of it) before it gives up.
pub const CONNECT_DEADLINE: Duration = Duration::from_secs(10);

/// How long [`connect_once`] waits for one server to answer.
pub const CONNECT_TIMEOUT_PER_SERVER: Duration = Duration::from_secs(5);

/// Connects once for tools such as `mouthpiece takes`: the servers are tried in turn, and
/// when none has answered within [`CONNECT_DEADLINE`] in all it is an error, however many
/// servers are listed.
pub async fn connect_once(settings: &NatsSettings) -> Result<async_nats::Client, NatsError> {
    let options = async_nats::ConnectOptions::new()
        .name("mouthpiece tool")
        .connection_timeout(CONNECT_TIMEOUT_PER_SERVER);
    let options = with_credentials(options, settings).await?;
    let servers = settings.servers.join(", ");
    let addrs = server_addrs(&settings.servers)?;
    match tokio::time::timeout(CONNECT_DEADLINE, options.connect(addrs)).await {
        Ok(connected) => connected.map_err(|e| NatsError::Connect {
            servers,
            message: e.to_string(),
        }),
        Err(_) => Err(NatsError::Connect {
            servers,
            message: format!("no server answered within {} s", CONNECT_DEADLINE.as_secs()),
        }),
    }
}

/// Counts connections: every task that must act on (re)connection watches it.
pub type Connections = tokio::sync::watch::Sender<u64>;

/// The running NATS link of a daemon: its tasks stop when this is dropped.
#[derive(Debug)]
pub struct NatsLink {
    client: async_nats::Client,
    tasks: Vec<tokio::task::JoinHandle<()>>,
}

impl NatsLink {
    /// Starts the link on the current tokio runtime: connects in the background (the booth
    /// starts whether or not a server is there), then publishes, answers requests and
    /// uploads takes from `takes_folder`.
    pub async fn start(
        hub: mouthpiece_server::Hub,
        settings: NatsSettings,
        server_name: String,
        takes_folder: PathBuf,
    ) -> Result<NatsLink, NatsError> {
        let counters = hub.nats();
        counters.enabled.store(true, Ordering::Relaxed);
        let connected: Arc<Connections> = Arc::new(tokio::sync::watch::Sender::new(0));
        let options = connect_options(&settings, &format!("mouthpiece booth {}", settings.booth))
            .await?
            .event_callback({
                let counters = counters.clone();
                let connected = connected.clone();
                let servers = settings.servers.join(", ");
                move |event| {
                    let counters = counters.clone();
                    let connected = connected.clone();
                    let servers = servers.clone();
                    async move { on_event(&event, &counters, &connected, &servers) }
                }
            });
        let addrs = server_addrs(&settings.servers)?;
        let client = options
            .connect(addrs)
            .await
            .map_err(|e| NatsError::Connect {
                servers: settings.servers.join(", "),
                message: e.to_string(),
            })?;
        tracing::info!(booth = %settings.booth, servers = %settings.servers.join(", "), "NATS link started");
        let subjects = settings.subjects();
        let mut tasks = Vec::new();
        tasks.push(tokio::spawn(publish::run(
            client.clone(),
            hub.clone(),
            subjects.clone(),
            settings.clone(),
            server_name.clone(),
            connected.clone(),
        )));
        tasks.push(tokio::spawn(respond::run(
            client.clone(),
            hub.clone(),
            subjects,
            server_name,
        )));
        if settings.upload_takes {
            tasks.push(tokio::spawn(upload::run(
                client.clone(),
                hub,
                settings,
                takes_folder,
                connected,
            )));
        }
        Ok(NatsLink { client, tasks })
    }

    /// The client (tests, tools).
    pub fn client(&self) -> &async_nats::Client {
        &self.client
    }
}

impl Drop for NatsLink {
    fn drop(&mut self) {
        for task in &self.tasks {
            task.abort();
        }
    }
}

fn on_event(
    event: &async_nats::Event,
    counters: &mouthpiece_server::NatsCounters,
    connected: &Connections,
    servers: &str,
) {
    match event {
        async_nats::Event::Connected => {
            counters.connected.store(true, Ordering::Relaxed);
            counters.connects.fetch_add(1, Ordering::Relaxed);
            tracing::info!(servers, "NATS connected");
            connected.send_modify(|n| *n += 1);
        }
        async_nats::Event::Disconnected => {
            counters.connected.store(false, Ordering::Relaxed);
            tracing::warn!(
                servers,
                "NATS disconnected: reconnecting with backoff; the booth carries on"
            );
        }
        async_nats::Event::Closed => {
            counters.connected.store(false, Ordering::Relaxed);
            tracing::warn!(servers, "NATS connection closed");
        }
        other => tracing::warn!(servers, "NATS: {other}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reconnection_backs_off_up_to_the_maximum() {
        let max = Duration::from_secs(5);
        assert_eq!(reconnect_delay(1, max), Duration::ZERO);
        assert_eq!(reconnect_delay(2, max), Duration::from_millis(100));
        assert_eq!(reconnect_delay(3, max), Duration::from_millis(200));
        assert_eq!(reconnect_delay(40, max), max);
    }

    #[test]
    fn credentials_never_show_in_debug() {
        let mut settings = NatsSettings::new(vec!["nats://127.0.0.1:4222".into()], "b");
        settings.auth = Auth::UserPassword {
            user: "booth".into(),
            password: Secret::new("hunter2-password"),
        };
        let shown = format!("{settings:?}");
        assert!(!shown.contains("hunter2"), "{shown}");
        settings.auth = Auth::Token(Secret::new("tok-very-secret"));
        assert!(!format!("{settings:?}").contains("tok-very"));
    }
}
