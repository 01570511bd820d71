//! The accept loop and the per-connection front door (TLS, HTTP routing, WebSocket upgrade).

use std::future::Future;
use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio::task::JoinSet;
use tokio_tungstenite::tungstenite::handshake::derive_accept_key;
use tokio_tungstenite::tungstenite::protocol::{Role, WebSocketConfig};
use tokio_tungstenite::WebSocketStream;
use tracing::{debug, info, warn, Instrument};

use crate::config::{Access, ServerConfig};
use crate::connection::{BoxedIo, Pending, Shared};
use crate::error::ServerError;
use crate::http::{self, HeadError, Request};
use crate::hub::Hub;
use crate::protocol::{FOXGLOVE_SUBPROTOCOL, SUBPROTOCOL, TOKEN_PROTOCOL_PREFIX};

/// The booth console page, bundled in the binary.
const CONSOLE_HTML: &str = include_str!("../assets/console.html");
/// The console's script.
const CONSOLE_JS: &str = include_str!("../assets/console.js");
/// The console's take player and paint check.
const CONSOLE_TAKES_JS: &str = include_str!("../assets/console-takes.js");

/// An upgrade the front door said yes to: protocol, subprotocol to name in the response,
/// access level, `Sec-WebSocket-Accept` value, the client's place under `max_clients`.
type Accepted = (Flavor, Option<&'static str>, Access, String, ClientCount);

/// Which protocol a session speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Flavor {
    Mouthpiece,
    Foxglove,
}

/// Serves `listener` until `shutdown` completes; then closes every client (code 1001) and
/// returns.
///
/// Fails before serving when the configuration is unusable: tokens missing on a
/// non-loopback address, bad limits, unreadable TLS files.
pub async fn run(
    listener: TcpListener,
    config: ServerConfig,
    hub: Hub,
    shutdown: impl Future,
) -> Result<(), ServerError> {
    let addr = listener.local_addr().map_err(|source| ServerError::Io {
        context: "reading the listener's address".into(),
        source,
    })?;
    config.validate(addr)?;
    let tls = match &config.tls {
        Some(files) => Some(crate::tls::acceptor(files)?),
        None => None,
    };
    let scheme = if tls.is_some() { "wss" } else { "ws" };
    info!(%addr, "serving {scheme}://{addr}/ (protocols {SUBPROTOCOL}, {FOXGLOVE_SUBPROTOCOL})");
    let (stop_tx, stop_rx) = watch::channel(false);
    let shared = Arc::new(Shared {
        config,
        hub,
        shutdown: stop_rx,
        connections: AtomicUsize::new(0),
        tls,
        local: addr,
        pending: Pending::default(),
    });
    let mut tasks = JoinSet::new();
    tokio::pin!(shutdown);
    loop {
        tokio::select! {
            _ = &mut shutdown => break,
            Some(_) = tasks.join_next(), if !tasks.is_empty() => {}
            accepted = listener.accept() => match accepted {
                Ok((stream, peer)) => {
                    let open = shared.connections.fetch_add(1, Ordering::Relaxed);
                    // Full: a connection still in its handshake makes room (the oldest of the
                    // peer holding the most), so connections opened and left silent cannot
                    // lock everyone else out.
                    if open >= shared.config.limits.max_connections && !shared.pending.evict() {
                        shared.connections.fetch_sub(1, Ordering::Relaxed);
                        shared.hub.inner.metrics.connections_rejected.fetch_add(1, Ordering::Relaxed);
                        debug!(%peer, "too many connections: closed");
                        continue;
                    }
                    let shared = shared.clone();
                    let span = tracing::info_span!("conn", %peer);
                    // Created before spawning, so an aborted task still gives its slot back.
                    let open = OpenConnection(shared.clone());
                    let handshake = shared.pending.register(peer);
                    tasks.spawn(async move {
                        let _open = open;
                        handle_connection(&shared, stream, peer, handshake).await;
                    }.instrument(span));
                }
                Err(e) => {
                    // Out of file descriptors and the like: back off rather than spin.
                    warn!(error = %e, "accept failed");
                    tokio::time::sleep(std::time::Duration::from_millis(50)).await;
                }
            },
        }
    }
    info!("shutting down: closing {} connection(s)", tasks.len());
    let _ = stop_tx.send(true);
    let grace = shared.config.limits.shutdown_grace;
    let drained =
        tokio::time::timeout(grace, async { while tasks.join_next().await.is_some() {} }).await;
    if drained.is_err() {
        tasks.abort_all();
        while tasks.join_next().await.is_some() {}
    }
    Ok(())
}

/// Counts a TCP connection against `max_connections` until it ends, aborted or not.
struct OpenConnection(Arc<Shared>);

impl Drop for OpenConnection {
    fn drop(&mut self) {
        self.0.connections.fetch_sub(1, Ordering::Relaxed);
    }
}

/// Who a connection counts against in [`Pending`]: its IPv4 address, or the /64 network of
/// its IPv6 address (one host usually holds a whole /64). Local processes all share the
/// loopback address, so among them eviction is simply oldest-first.
fn peer_key(peer: SocketAddr) -> IpAddr {
    match peer.ip().to_canonical() {
        IpAddr::V6(v6) => {
            let mut octets = v6.octets();
            octets[8..].fill(0);
            IpAddr::V6(octets.into())
        }
        v4 => v4,
    }
}

/// A connection's place in [`Pending`]; leaves it when dropped.
struct Handshake<'a> {
    pending: &'a Pending,
    id: u64,
    evicted: Arc<tokio::sync::Notify>,
}

impl Pending {
    fn register(&self, peer: SocketAddr) -> (u64, Arc<tokio::sync::Notify>) {
        let id = self.next.fetch_add(1, Ordering::Relaxed);
        let evicted = Arc::new(tokio::sync::Notify::new());
        self.queue
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push_back((id, peer_key(peer), evicted.clone()));
        (id, evicted)
    }

    /// Tells one pending connection to close; false when there is none. The one chosen is
    /// the oldest of the peer holding the most pending handshakes (ties: the peer whose
    /// oldest handshake is oldest), so a peer that floods the front door pays for it alone.
    fn evict(&self) -> bool {
        let mut queue = self.queue.lock().unwrap_or_else(|e| e.into_inner());
        let mut held: std::collections::HashMap<IpAddr, usize> = std::collections::HashMap::new();
        for (_, peer, _) in queue.iter() {
            *held.entry(*peer).or_default() += 1;
        }
        let Some(most) = held.values().copied().max() else {
            return false;
        };
        let Some(index) = queue.iter().position(|(_, peer, _)| held[peer] == most) else {
            return false;
        };
        match queue.remove(index) {
            Some((_, _, evicted)) => {
                evicted.notify_one();
                true
            }
            None => false,
        }
    }

    fn remove(&self, id: u64) {
        self.queue
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .retain(|(i, _, _)| *i != id);
    }
}

impl Drop for Handshake<'_> {
    fn drop(&mut self) {
        self.pending.remove(self.id);
    }
}

async fn handle_connection(
    shared: &Arc<Shared>,
    tcp: TcpStream,
    peer: SocketAddr,
    (id, evicted): (u64, Arc<tokio::sync::Notify>),
) {
    let handshake = Handshake {
        pending: &shared.pending,
        id,
        evicted,
    };
    let _ = tcp.set_nodelay(true);
    let limits = &shared.config.limits;
    let front = async {
        let mut io: BoxedIo = match &shared.tls {
            Some(acceptor) => match acceptor.accept(tcp).await {
                Ok(tls) => Box::new(tls),
                Err(e) => {
                    debug!(error = %e, "TLS handshake failed");
                    return None;
                }
            },
            None => Box::new(tcp),
        };
        match http::read_head(&mut io).await {
            Ok((req, rest)) => Some((io, req, rest)),
            Err(e) => {
                let (status, why) = match e {
                    HeadError::TooLarge => (431, "request head too large".to_owned()),
                    HeadError::Malformed(m) => (400, format!("malformed HTTP request: {m}")),
                    HeadError::Closed | HeadError::Io(_) => return None,
                };
                debug!(status, why, "bad request head");
                let _ = http::respond_error(&mut io, status, &why).await;
                None
            }
        }
    };
    let front = async {
        tokio::select! {
            r = front => Some(r),
            _ = handshake.evicted.notified() => {
                debug!("closed to make room (max_connections reached while it was silent)");
                None
            }
        }
    };
    let Ok(Some(Some((mut io, req, rest)))) =
        tokio::time::timeout(limits.handshake_timeout, front).await
    else {
        shared
            .hub
            .inner
            .metrics
            .connections_rejected
            .fetch_add(1, Ordering::Relaxed);
        return;
    };
    drop(handshake);
    // Before anything else: a request that does not name this server (DNS rebinding).
    if !shared.config.host_allowed(req.header("host"), shared.local) {
        shared
            .hub
            .inner
            .metrics
            .connections_rejected
            .fetch_add(1, Ordering::Relaxed);
        let (status, why) = match req.header("host") {
            None => (400, "missing Host header".to_owned()),
            Some(host) => (
                403,
                format!(
                    "host {:?} is not one of this server's names (localhost, its addresses, or the configured allowed_hosts)",
                    host.chars().take(80).collect::<String>()
                ),
            ),
        };
        info!(status, why, "request refused");
        let _ = http::respond_error(&mut io, status, &why).await;
        return;
    }
    if req.is_upgrade() {
        upgrade(shared, io, req, rest, peer).await;
    } else {
        shared
            .hub
            .inner
            .metrics
            .http_requests
            .fetch_add(1, Ordering::Relaxed);
        let _ = serve_http(shared, &mut io, &req).await;
    }
}

async fn serve_http(shared: &Shared, io: &mut BoxedIo, req: &Request) -> std::io::Result<()> {
    if req.method != "GET" {
        return http::respond_error(io, 405, "only GET is served here").await;
    }
    match req.path.as_str() {
        "/" | "/index.html" => {
            http::respond(io, 200, "text/html; charset=utf-8", CONSOLE_HTML.as_bytes()).await
        }
        "/console.js" => {
            http::respond(
                io,
                200,
                "text/javascript; charset=utf-8",
                CONSOLE_JS.as_bytes(),
            )
            .await
        }
        "/console-takes.js" => {
            http::respond(
                io,
                200,
                "text/javascript; charset=utf-8",
                CONSOLE_TAKES_JS.as_bytes(),
            )
            .await
        }
        "/take" => crate::takes_http::serve(&shared.hub, &shared.config, io, req).await,
        "/healthz" => {
            if let Some(reason) = shared.hub.failure() {
                let body = serde_json::json!({ "status": "failed", "reason": reason });
                return http::respond(io, 503, "application/json", body.to_string().as_bytes())
                    .await;
            }
            let status = shared.hub.status();
            let mut body = serde_json::json!({
                "status": "ok",
                "source": status.source.as_str(),
                "clients": shared.hub.clients(),
                "frames": shared.hub.frames_published(),
                "audio": {
                    "state": status.audio.state.as_str(),
                    "device": status.audio.device,
                    "message": status.audio_message,
                },
            });
            body["timecode"] = shared.hub.inner.clock.health_json();
            if let Some(osc) = shared.hub.inner.osc.health_json() {
                body["osc"] = osc;
            }
            if let Some(nats) = shared.hub.inner.nats.health_json() {
                body["nats"] = nats;
            }
            http::respond(io, 200, "application/json", body.to_string().as_bytes()).await
        }
        "/metrics" => {
            let text = shared.hub.metrics_text();
            http::respond(
                io,
                200,
                "text/plain; version=0.0.4; charset=utf-8",
                text.as_bytes(),
            )
            .await
        }
        "/ws" => {
            http::respond_error(
                io,
                426,
                "this is the WebSocket endpoint: connect with a WebSocket client",
            )
            .await
        }
        _ => http::respond_error(io, 404, "not found (try /, /healthz, /metrics, /take)").await,
    }
}

async fn upgrade(
    shared: &Arc<Shared>,
    mut io: BoxedIo,
    req: Request,
    rest: Vec<u8>,
    peer: SocketAddr,
) {
    let metrics = &shared.hub.inner.metrics;
    let decision: Result<Accepted, (u16, String)> = async {
        if req.method != "GET" {
            return Err((400, "a WebSocket upgrade must be a GET".into()));
        }
        if !req.header_has_token("connection", "upgrade") {
            return Err((400, "missing \"Connection: Upgrade\"".into()));
        }
        if req.header("sec-websocket-version") != Some("13") {
            return Err((400, "unsupported WebSocket version (need 13)".into()));
        }
        let Some(key) = req.header("sec-websocket-key") else {
            return Err((400, "missing Sec-WebSocket-Key".into()));
        };
        if !shared.config.origin_allowed(req.header("origin"), req.header("host")) {
            return Err((
                403,
                format!(
                    "origin {:?} is not allowed (add it to the server's allowed origins)",
                    req.header("origin").unwrap_or_default()
                ),
            ));
        }
        let offered = req.subprotocols();
        let token_entry = offered
            .iter()
            .find_map(|p| p.strip_prefix(TOKEN_PROTOCOL_PREFIX))
            .map(str::to_owned);
        let bearer = req
            .header("authorization")
            .and_then(|v| v.strip_prefix("Bearer "))
            .map(|v| v.trim().to_owned());
        let token = token_entry.or(bearer).or_else(|| req.query_param("token"));
        let Some(access) = shared.hub.access_for(&shared.config, token.as_deref()) else {
            return Err((
                401,
                if token.is_some() {
                    "wrong token".into()
                } else {
                    "a token is required (Sec-WebSocket-Protocol entry mouthpiece.token.<token>, ?token=, or Authorization: Bearer)".into()
                },
            ));
        };
        let (flavor, selected) = if offered.contains(&SUBPROTOCOL) {
            (Flavor::Mouthpiece, Some(SUBPROTOCOL))
        } else if offered.contains(&FOXGLOVE_SUBPROTOCOL) {
            (Flavor::Foxglove, Some(FOXGLOVE_SUBPROTOCOL))
        } else if offered.iter().all(|p| p.starts_with(TOKEN_PROTOCOL_PREFIX)) {
            // No subprotocol asked for: speak mouthpiece.v1 without naming it (RFC 6455 §4.2.2).
            (Flavor::Mouthpiece, None)
        } else {
            return Err((
                400,
                format!("no supported subprotocol offered (supported: {SUBPROTOCOL}, {FOXGLOVE_SUBPROTOCOL})"),
            ));
        };
        // Checked and counted in one step, so simultaneous upgrades cannot overshoot.
        let Some(counted) = ClientCount::reserve(shared) else {
            return Err((503, format!("server full ({} clients)", shared.config.limits.max_clients)));
        };
        Ok((flavor, selected, access, derive_accept_key(key.as_bytes()), counted))
    }
    .await;
    let (flavor, selected, access, accept, _counted) = match decision {
        Ok(d) => d,
        Err((status, why)) => {
            metrics.connections_rejected.fetch_add(1, Ordering::Relaxed);
            info!(status, why, "WebSocket upgrade refused");
            let _ = http::respond_error(&mut io, status, &why).await;
            return;
        }
    };
    let mut response = format!(
        "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Accept: {accept}\r\n"
    );
    if let Some(p) = selected {
        response.push_str(&format!("Sec-WebSocket-Protocol: {p}\r\n"));
    }
    response.push_str("\r\n");
    if io.write_all(response.as_bytes()).await.is_err() || io.flush().await.is_err() {
        return;
    }
    let limits = &shared.config.limits;
    let ws_config = WebSocketConfig::default()
        .max_message_size(Some(limits.max_message_bytes))
        .max_frame_size(Some(limits.max_message_bytes));
    let ws = WebSocketStream::from_partially_read(io, rest, Role::Server, Some(ws_config)).await;
    metrics.clients_accepted.fetch_add(1, Ordering::Relaxed);
    info!(?flavor, access = access.as_str(), "client connected");
    match flavor {
        Flavor::Mouthpiece => crate::session::run(shared, ws, access, peer).await,
        Flavor::Foxglove => crate::foxglove::run(shared, ws, peer).await,
    }
}

/// Counts a session in the `clients` gauge for as long as it lives, aborted or not.
struct ClientCount(Arc<Shared>);

impl ClientCount {
    /// Takes a place under `max_clients`, or `None` when the server is full.
    fn reserve(shared: &Arc<Shared>) -> Option<Self> {
        let max = shared.config.limits.max_clients as u64;
        shared
            .hub
            .inner
            .metrics
            .clients
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
                (n < max).then_some(n + 1)
            })
            .ok()?;
        Some(Self(shared.clone()))
    }
}

impl Drop for ClientCount {
    fn drop(&mut self) {
        self.0
            .hub
            .inner
            .metrics
            .clients
            .fetch_sub(1, Ordering::Relaxed);
    }
}
