//! What the front door (`server`) hands every connection task: the byte stream it runs on and
//! the state all connections share.

use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::AtomicUsize;
use std::sync::Arc;

use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::watch;
use tokio_tungstenite::WebSocketStream;

use crate::config::ServerConfig;
use crate::hub::Hub;

/// A byte stream a session runs on: plain TCP or TLS.
pub(crate) trait Io: AsyncRead + AsyncWrite + Unpin + Send {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send> Io for T {}
pub(crate) type BoxedIo = Box<dyn Io>;
pub(crate) type Ws = WebSocketStream<BoxedIo>;

/// State every connection task shares.
pub(crate) struct Shared {
    pub(crate) config: ServerConfig,
    pub(crate) hub: Hub,
    pub(crate) shutdown: watch::Receiver<bool>,
    pub(crate) connections: AtomicUsize,
    pub(crate) tls: Option<tokio_rustls::TlsAcceptor>,
    /// The address the listener is bound to (for the `Host` check).
    pub(crate) local: SocketAddr,
    /// Connections still in TLS + request head, oldest first (see [`Pending`]).
    pub(crate) pending: Pending,
}

/// Connections that have not yet sent a full request head, oldest first. When
/// `max_connections` is reached, a new connection evicts one of them: the oldest of those
/// held by the peer holding the most (one peer opening connections and leaving them silent
/// only ever evicts its own, never another peer's handshake), see `Pending::evict` in `server`.
/// Connections past the front door are never evicted.
#[derive(Default)]
pub(crate) struct Pending {
    pub(crate) queue: std::sync::Mutex<std::collections::VecDeque<PendingEntry>>,
    pub(crate) next: std::sync::atomic::AtomicU64,
}

/// One pending handshake: its id, its peer (see `server::peer_key`), the signal that closes it.
pub(crate) type PendingEntry = (u64, IpAddr, Arc<tokio::sync::Notify>);
