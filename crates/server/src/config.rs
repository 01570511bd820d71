//! Server configuration: tokens, origins, limits, TLS.

use std::fmt;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use subtle::ConstantTimeEq;

use crate::error::ServerError;

/// An access token. Its `Debug` never shows the secret.
#[derive(Clone, PartialEq, Eq)]
pub struct Token(String);

impl fmt::Debug for Token {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Token(<redacted>)")
    }
}

impl Token {
    /// A token; at least 16 characters of `A-Z a-z 0-9 - . _ ~`, so that it fits in a
    /// `Sec-WebSocket-Protocol` entry and a URL query unchanged.
    pub fn new(secret: impl Into<String>) -> Result<Token, ServerError> {
        let secret = secret.into();
        if secret.len() < 16
            || !secret
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b"-._~".contains(&b))
        {
            return Err(ServerError::BadToken {
                reason: format!(
                    "a token needs at least 16 characters from A-Z a-z 0-9 - . _ ~ (got {} characters)",
                    secret.len()
                ),
            });
        }
        Ok(Token(secret))
    }

    /// Reads a token from a file (surrounding whitespace ignored).
    pub fn from_file(path: &Path) -> Result<Token, ServerError> {
        let text = read_small(path).map_err(|source| ServerError::Io {
            context: format!("reading token file {}", path.display()),
            source,
        })?;
        Token::new(text.trim()).map_err(|e| match e {
            ServerError::BadToken { reason } => ServerError::BadToken {
                reason: format!("{}: {reason}", path.display()),
            },
            other => other,
        })
    }

    /// Reads a token from an environment variable; `None` when it is unset or empty.
    pub fn from_env(var: &str) -> Result<Option<Token>, ServerError> {
        match std::env::var(var) {
            Ok(v) if !v.trim().is_empty() => Token::new(v.trim()).map(Some).map_err(|e| match e {
                ServerError::BadToken { reason } => ServerError::BadToken {
                    reason: format!("environment variable {var}: {reason}"),
                },
                other => other,
            }),
            _ => Ok(None),
        }
    }

    /// Constant-time comparison with what a client presented.
    pub fn matches(&self, presented: &str) -> bool {
        self.0.as_bytes().ct_eq(presented.as_bytes()).into()
    }

    /// The secret, for clients (tests, loadgen) that must present it.
    pub fn expose(&self) -> &str {
        &self.0
    }
}

/// A token file of at most 4 KiB (`/dev/zero` is an error, not unbounded memory).
fn read_small(path: &Path) -> std::io::Result<String> {
    use std::io::Read;
    let mut bytes = Vec::new();
    std::fs::File::open(path)?
        .take(4097)
        .read_to_end(&mut bytes)?;
    if bytes.len() > 4096 {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            "longer than 4096 bytes",
        ));
    }
    String::from_utf8(bytes)
        .map_err(|_| std::io::Error::new(std::io::ErrorKind::InvalidData, "not UTF-8 text"))
}

/// What a connection may do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Access {
    /// Subscribe and ping.
    Read,
    /// Also calibrate and record.
    Control,
}

impl Access {
    /// `read` or `control`.
    pub fn as_str(self) -> &'static str {
        match self {
            Access::Read => "read",
            Access::Control => "control",
        }
    }
}

/// Certificate and key files for `wss://` (PEM).
#[derive(Debug, Clone, PartialEq)]
pub struct TlsFiles {
    /// Certificate chain, PEM.
    pub cert: PathBuf,
    /// Private key (PKCS#8, PKCS#1 or SEC1), PEM.
    pub key: PathBuf,
}

/// Limits that protect the pipeline and the other clients from one client.
#[derive(Debug, Clone, PartialEq)]
pub struct Limits {
    /// WebSocket clients at once; more get HTTP 503.
    pub max_clients: usize,
    /// TCP connections at once, including ones still in the handshake; more are closed.
    pub max_connections: usize,
    /// Largest client message (and frame), bytes; larger closes with 1009.
    pub max_message_bytes: usize,
    /// Client messages per second (burst of the same size); more get `rate_limited`.
    pub max_messages_per_second: u32,
    /// Replies waiting for one client; overflow closes it (it is not reading).
    pub control_queue_per_client: usize,
    /// A client that loses more than this many frames within `lag_window` is closed.
    pub max_dropped_frames: u64,
    /// Window for `max_dropped_frames`.
    pub lag_window: Duration,
    /// A single write to a client blocked this long closes it.
    pub write_timeout: Duration,
    /// TLS plus HTTP request head must arrive within this.
    pub handshake_timeout: Duration,
    /// The server pings each client this often.
    pub ping_interval: Duration,
    /// A client silent this long (no pong, no message) is closed: half-open connections.
    pub idle_timeout: Duration,
    /// How long a client waits for the daemon to answer a control request.
    pub control_timeout: Duration,
    /// On shutdown, how long clients get to receive the close before being dropped.
    pub shutdown_grace: Duration,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_clients: 128,
            max_connections: 512,
            max_message_bytes: 64 * 1024,
            max_messages_per_second: 50,
            control_queue_per_client: 32,
            max_dropped_frames: 600,
            lag_window: Duration::from_secs(10),
            write_timeout: Duration::from_secs(5),
            handshake_timeout: Duration::from_secs(10),
            ping_interval: Duration::from_secs(5),
            idle_timeout: Duration::from_secs(20),
            control_timeout: Duration::from_secs(30),
            shutdown_grace: Duration::from_millis(500),
        }
    }
}

/// Everything [`crate::run`] needs besides the listener and the hub.
#[derive(Debug, Clone, PartialEq)]
pub struct ServerConfig {
    /// Server name in `hello` and Foxglove's `serverInfo`.
    pub name: String,
    /// Token that allows subscribing.
    pub read_token: Option<Token>,
    /// Token that also allows calibrate and record.
    pub control_token: Option<Token>,
    /// Browser origins allowed besides the server's own (`*` allows any).
    pub allowed_origins: Vec<String>,
    /// Host names the server answers to besides `localhost`, the loopback addresses and the
    /// address it listens on (see [`ServerConfig::host_allowed`]).
    pub allowed_hosts: Vec<String>,
    /// Limits.
    pub limits: Limits,
    /// Serve `wss://` and `https://` with these.
    pub tls: Option<TlsFiles>,
}

impl Default for ServerConfig {
    fn default() -> Self {
        Self {
            name: "mouthpiece".into(),
            read_token: None,
            control_token: None,
            allowed_origins: Vec::new(),
            allowed_hosts: Vec::new(),
            limits: Limits::default(),
            tls: None,
        }
    }
}

impl ServerConfig {
    /// Checks the configuration against the address it will serve.
    pub fn validate(&self, addr: SocketAddr) -> Result<(), ServerError> {
        if !addr.ip().is_loopback() && (self.read_token.is_none() || self.control_token.is_none()) {
            return Err(ServerError::TokensRequired { addr });
        }
        let l = &self.limits;
        let checks: [(&str, bool); 5] = [
            ("max_clients", l.max_clients > 0),
            ("max_connections", l.max_connections >= l.max_clients),
            ("max_message_bytes", l.max_message_bytes >= 1024),
            ("max_messages_per_second", l.max_messages_per_second > 0),
            ("control_queue_per_client", l.control_queue_per_client > 0),
        ];
        for (key, ok) in checks {
            if !ok {
                return Err(ServerError::Config {
                    key: key.into(),
                    message:
                        "must be positive (max_connections ≥ max_clients, max_message_bytes ≥ 1024)"
                            .into(),
                });
            }
        }
        Ok(())
    }

    /// The access a presented token grants; `None` means refuse the connection.
    pub fn access_for(&self, presented: Option<&str>) -> Option<Access> {
        if self.read_token.is_none() && self.control_token.is_none() {
            return Some(Access::Control);
        }
        let presented = presented.unwrap_or("");
        if self
            .control_token
            .as_ref()
            .is_some_and(|t| t.matches(presented))
        {
            return Some(Access::Control);
        }
        match &self.read_token {
            Some(t) if t.matches(presented) => Some(Access::Read),
            Some(_) => None,
            None => Some(Access::Read),
        }
    }

    /// Whether a request's `Host` names this server listening on `local` (DNS rebinding;
    /// see [`crate::host`]).
    pub fn host_allowed(&self, host: Option<&str>, local: SocketAddr) -> bool {
        crate::host::host_allowed(host, local, &self.allowed_hosts)
    }

    /// Whether a browser page from `origin` may connect (`host` is the request's Host).
    pub fn origin_allowed(&self, origin: Option<&str>, host: Option<&str>) -> bool {
        let Some(origin) = origin else {
            // Not a browser: tokens are the protection.
            return true;
        };
        if let Some(host) = host {
            let same = origin
                .strip_prefix("http://")
                .or_else(|| origin.strip_prefix("https://"))
                .is_some_and(|rest| rest.eq_ignore_ascii_case(host));
            if same {
                return true;
            }
        }
        self.allowed_origins
            .iter()
            .any(|o| o == "*" || o.eq_ignore_ascii_case(origin))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_grant_levels() {
        let mut c = ServerConfig::default();
        assert_eq!(c.access_for(None), Some(Access::Control));
        c.read_token = Some(Token::new("read-token-0123456789").unwrap());
        c.control_token = Some(Token::new("control-token-0123456789").unwrap());
        assert_eq!(c.access_for(None), None);
        assert_eq!(c.access_for(Some("read-token-012345678")), None);
        assert_eq!(
            c.access_for(Some("read-token-0123456789")),
            Some(Access::Read)
        );
        assert_eq!(
            c.access_for(Some("control-token-0123456789")),
            Some(Access::Control)
        );
        assert!(Token::new("short").is_err());
        assert!(Token::new("has space in it 0123456789").is_err());
        assert_eq!(format!("{:?}", c.read_token.unwrap()), "Token(<redacted>)");
    }

    #[test]
    fn non_loopback_needs_both_tokens() {
        let mut c = ServerConfig::default();
        assert!(c.validate("127.0.0.1:9870".parse().unwrap()).is_ok());
        assert!(matches!(
            c.validate("0.0.0.0:9870".parse().unwrap()),
            Err(ServerError::TokensRequired { .. })
        ));
        c.read_token = Some(Token::new("read-token-0123456789").unwrap());
        c.control_token = Some(Token::new("control-token-0123456789").unwrap());
        assert!(c.validate("0.0.0.0:9870".parse().unwrap()).is_ok());
    }

    #[test]
    fn origins() {
        let mut c = ServerConfig::default();
        assert!(c.origin_allowed(None, Some("127.0.0.1:9870")));
        assert!(c.origin_allowed(Some("http://127.0.0.1:9870"), Some("127.0.0.1:9870")));
        assert!(!c.origin_allowed(Some("http://evil.example"), Some("127.0.0.1:9870")));
        c.allowed_origins = vec!["https://app.foxglove.dev".into()];
        assert!(c.origin_allowed(Some("https://app.foxglove.dev"), Some("127.0.0.1:9870")));
    }
}
