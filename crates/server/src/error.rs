//! The server crate's error type.

use std::net::SocketAddr;

/// Everything that can stop the server from starting or running.
///
/// Per-client problems never surface here: they are answered to that client (`error` or a
/// close with a reason) and logged once.
#[derive(Debug, thiserror::Error)]
pub enum ServerError {
    /// A configuration value is out of range.
    #[error("server configuration: {key}: {message}")]
    Config {
        /// The key.
        key: String,
        /// What was expected.
        message: String,
    },
    /// Listening beyond loopback without both tokens.
    #[error("refusing to serve on {addr} without a read token and a control token (only 127.0.0.1/::1 may run without tokens)")]
    TokensRequired {
        /// The address.
        addr: SocketAddr,
    },
    /// A token that cannot be used.
    #[error("bad token: {reason}")]
    BadToken {
        /// Why.
        reason: String,
    },
    /// Reading the certificate or key failed, or rustls refused them.
    #[error("TLS: {context}")]
    Tls {
        /// Which file or step.
        context: String,
        /// The cause.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// An I/O error on the listener or a file.
    #[error("{context}")]
    Io {
        /// What was being done.
        context: String,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
}
