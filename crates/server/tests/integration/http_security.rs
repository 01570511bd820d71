//! Plain HTTP on the WebSocket port, tokens, origins, client limits and TLS.

use crate::helper_common as common;

use std::sync::Arc;
use std::time::Duration;

use common::*;
use mouthpiece_server::{run, Hub, HubConfig, Limits, ServerConfig, ServerError, TlsFiles, Token};
use serde_json::json;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

#[tokio::test]
async fn serves_viewer_health_and_metrics_on_the_same_port() {
    let server = TestServer::start(ServerConfig::default()).await;
    let (status, body) = http_get(server.addr, "/", "").await;
    assert_eq!(status, 200);
    assert!(body.contains("<canvas"), "the viewer page");
    let (status, body) = http_get(server.addr, "/console.js", "").await;
    assert_eq!(status, 200);
    assert!(body.contains("mouthpiece.v1"));
    let (status, body) = http_get(server.addr, "/healthz", "").await;
    assert_eq!(status, 200);
    let health: serde_json::Value = serde_json::from_str(&body).unwrap();
    assert_eq!(health["status"], "ok");
    server.publish(0);
    let mut ws = connect_v1(&server.url()).await;
    next_of_type(&mut ws, "hello").await;
    let (status, body) = http_get(server.addr, "/metrics", "").await;
    assert_eq!(status, 200);
    for line in [
        "mouthpiece_frames_in_total 1",
        "mouthpiece_clients 1",
        "mouthpiece_processing_seconds_count 1",
        "# TYPE mouthpiece_fanout_latency_seconds histogram",
        "mouthpiece_frames_dropped_total 0",
    ] {
        assert!(
            body.lines().any(|l| l == line),
            "missing {line:?} in\n{body}"
        );
    }
    assert_eq!(http_get(server.addr, "/nope", "").await.0, 404);
    assert_eq!(http_get(server.addr, "/ws", "").await.0, 426);
    server.stop().await;
}

#[tokio::test]
async fn garbage_and_oversized_heads_get_http_errors() {
    let server = TestServer::start(ServerConfig::default()).await;
    for (bytes, status) in [
        (b"\x00\x01\x02garbage\r\n\r\n".to_vec(), 400),
        (
            [
                b"GET / HTTP/1.1\r\nX: ".to_vec(),
                vec![b'a'; 20_000],
                b"\r\n\r\n".to_vec(),
            ]
            .concat(),
            431,
        ),
        (
            b"POST /metrics HTTP/1.1\r\nHost: localhost\r\n\r\n".to_vec(),
            405,
        ),
        (
            b"GET / HTTP/1.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\r\n".to_vec(),
            400,
        ),
    ] {
        let mut s = TcpStream::connect(server.addr).await.unwrap();
        let _ = s.write_all(&bytes).await;
        let mut buf = Vec::new();
        let _ = tokio::time::timeout(Duration::from_secs(5), s.read_to_end(&mut buf)).await;
        assert_eq!(
            parse_response(&buf).0,
            status,
            "{}",
            String::from_utf8_lossy(&buf)
        );
    }
    server.stop().await;
}

fn tokens() -> ServerConfig {
    ServerConfig {
        read_token: Some(Token::new("read-token-0123456789").unwrap()),
        control_token: Some(Token::new("control-token-0123456789").unwrap()),
        ..ServerConfig::default()
    }
}

#[tokio::test]
async fn wrong_or_missing_tokens_are_refused_with_401() {
    let server = TestServer::start(tokens()).await;
    for protocols in [
        vec!["mouthpiece.v1"],
        vec!["mouthpiece.v1", "mouthpiece.token.read-token-012345678X"],
        vec!["foxglove.websocket.v1"],
    ] {
        let err = connect(&server.url(), &protocols)
            .await
            .unwrap_err()
            .to_string();
        assert!(err.contains("401"), "{protocols:?}: {err}");
    }
    let err = connect(&format!("{}?token=nope", server.url()), &["mouthpiece.v1"])
        .await
        .unwrap_err();
    assert!(err.to_string().contains("401"));
    // Header form, for non-browser clients.
    let (status, body) = http_get(
        server.addr,
        "/",
        "Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\n\
         Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nAuthorization: Bearer wrong\r\n",
    )
    .await;
    assert_eq!(status, 401);
    assert!(body.contains("wrong token"));
    let mut ws = connect(
        &server.url(),
        &["mouthpiece.v1", "mouthpiece.token.control-token-0123456789"],
    )
    .await
    .unwrap();
    assert_eq!(next_json(&mut ws).await["access"], "control");
    server.stop().await;
}

#[tokio::test]
async fn foreign_origins_are_refused_and_allowed_ones_accepted() {
    let config = ServerConfig {
        allowed_origins: vec!["https://app.foxglove.dev".into()],
        ..ServerConfig::default()
    };
    let server = TestServer::start(config).await;
    let handshake = |origin: &str| {
        format!(
            "Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\n\
             Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Protocol: mouthpiece.v1\r\nOrigin: {origin}\r\n"
        )
    };
    let (status, body) = http_get(server.addr, "/", &handshake("http://evil.example")).await;
    assert_eq!(status, 403);
    assert!(body.contains("evil.example"));
    let mut s = TcpStream::connect(server.addr).await.unwrap();
    s.write_all(
        format!(
            "GET / HTTP/1.1\r\nHost: {}\r\n{}\r\n",
            server.addr,
            handshake("https://app.foxglove.dev")
        )
        .as_bytes(),
    )
    .await
    .unwrap();
    let mut buf = [0u8; 512];
    let n = s.read(&mut buf).await.unwrap();
    let head = String::from_utf8_lossy(&buf[..n]);
    assert!(head.starts_with("HTTP/1.1 101"), "{head}");
    assert!(
        head.contains("Sec-WebSocket-Accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo="),
        "{head}"
    );
    assert!(head.contains("Sec-WebSocket-Protocol: mouthpiece.v1"));
    // Same origin (the viewer page) is always allowed.
    let own = format!("http://{}", server.addr);
    let mut s = TcpStream::connect(server.addr).await.unwrap();
    s.write_all(
        format!(
            "GET / HTTP/1.1\r\nHost: {}\r\n{}\r\n",
            server.addr,
            handshake(&own)
        )
        .as_bytes(),
    )
    .await
    .unwrap();
    let n = s.read(&mut buf).await.unwrap();
    assert!(buf[..n].starts_with(b"HTTP/1.1 101"));
    server.stop().await;
}

#[tokio::test]
async fn clients_beyond_the_limit_get_503_and_others_are_unaffected() {
    let config = ServerConfig {
        limits: Limits {
            max_clients: 2,
            ..Limits::default()
        },
        ..ServerConfig::default()
    };
    let server = TestServer::start(config).await;
    let mut a = connect_v1(&server.url()).await;
    let mut b = connect_v1(&server.url()).await;
    next_of_type(&mut a, "hello").await;
    next_of_type(&mut b, "hello").await;
    let err = connect_v1_err(&server.url()).await;
    assert!(err.contains("503"), "{err}");
    drop(b);
    // The freed slot is usable again once the server noticed.
    let mut ok = false;
    for _ in 0..50 {
        if connect(&server.url(), &["mouthpiece.v1"]).await.is_ok() {
            ok = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(ok);
    send_json(&mut a, json!({"type": "ping"})).await;
    next_of_type(&mut a, "pong").await;
    server.stop().await;
}

async fn connect_v1_err(url: &str) -> String {
    connect(url, &["mouthpiece.v1"])
        .await
        .unwrap_err()
        .to_string()
}

#[tokio::test]
async fn unsupported_subprotocols_are_refused() {
    let server = TestServer::start(ServerConfig::default()).await;
    let err = connect(&server.url(), &["mqtt"])
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("400"), "{err}");
    server.stop().await;
}

#[tokio::test]
async fn refuses_to_serve_beyond_loopback_without_tokens() {
    let listener = tokio::net::TcpListener::bind("0.0.0.0:0").await.unwrap();
    let (hub, _control) = Hub::new(&HubConfig::default());
    let result = run(
        listener,
        ServerConfig::default(),
        hub,
        std::future::pending::<()>(),
    )
    .await;
    let err = result.unwrap_err();
    assert!(matches!(err, ServerError::TokensRequired { .. }));
    assert!(err
        .to_string()
        .contains("without a read token and a control token"));
}

#[tokio::test]
async fn serves_wss_and_https_with_a_configured_certificate() {
    let dir = tempfile::tempdir().unwrap();
    let cert = rcgen::generate_simple_self_signed(vec!["localhost".to_owned()]).unwrap();
    let cert_path = dir.path().join("cert.pem");
    let key_path = dir.path().join("key.pem");
    std::fs::write(&cert_path, cert.cert.pem()).unwrap();
    std::fs::write(&key_path, cert.key_pair.serialize_pem()).unwrap();
    let config = ServerConfig {
        tls: Some(TlsFiles {
            cert: cert_path.clone(),
            key: key_path.clone(),
        }),
        ..ServerConfig::default()
    };
    let server = TestServer::start(config).await;

    let mut roots = tokio_rustls::rustls::RootCertStore::empty();
    roots.add(cert.cert.der().clone()).unwrap();
    let provider = Arc::new(tokio_rustls::rustls::crypto::ring::default_provider());
    let client_config = tokio_rustls::rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .unwrap()
        .with_root_certificates(roots)
        .with_no_client_auth();
    let connector = tokio_rustls::TlsConnector::from(Arc::new(client_config));
    let name = tokio_rustls::rustls::pki_types::ServerName::try_from("localhost").unwrap();

    // wss://
    let tcp = TcpStream::connect(server.addr).await.unwrap();
    let tls = connector.connect(name.clone(), tcp).await.unwrap();
    let mut request =
        tokio_tungstenite::tungstenite::client::IntoClientRequest::into_client_request(format!(
            "wss://localhost:{}/",
            server.addr.port()
        ))
        .unwrap();
    request
        .headers_mut()
        .insert("Sec-WebSocket-Protocol", "mouthpiece.v1".parse().unwrap());
    let (mut ws, _) = tokio_tungstenite::client_async(request, tls).await.unwrap();
    let hello = {
        use futures_util::StreamExt;
        let m = tokio::time::timeout(Duration::from_secs(5), ws.next())
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        serde_json::from_str::<serde_json::Value>(m.to_text().unwrap()).unwrap()
    };
    assert_eq!(hello["type"], "hello");

    // https:// on the same port
    let tcp = TcpStream::connect(server.addr).await.unwrap();
    let mut tls = connector.connect(name, tcp).await.unwrap();
    tls.write_all(b"GET /healthz HTTP/1.1\r\nHost: localhost\r\n\r\n")
        .await
        .unwrap();
    let mut buf = Vec::new();
    let _ = tls.read_to_end(&mut buf).await;
    assert_eq!(parse_response(&buf).0, 200);

    // Plain TCP to the TLS port is dropped without disturbing anyone.
    assert_eq!(http_get(server.addr, "/healthz", "").await.0, 0);
    server.stop().await;

    // A key that does not match the certificate is a startup error naming both files.
    let other = rcgen::generate_simple_self_signed(vec!["localhost".to_owned()]).unwrap();
    std::fs::write(&key_path, other.key_pair.serialize_pem()).unwrap();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let (hub, _c) = Hub::new(&HubConfig::default());
    let config = ServerConfig {
        tls: Some(TlsFiles {
            cert: cert_path,
            key: key_path,
        }),
        ..ServerConfig::default()
    };
    let err = run(listener, config, hub, std::future::pending::<()>())
        .await
        .unwrap_err();
    assert!(err.to_string().contains("key.pem"), "{err}");
}

/// A raw request with the given `Host` header (or none); returns status and body.
async fn get_with_host(
    addr: std::net::SocketAddr,
    path: &str,
    host: Option<&str>,
    extra: &str,
) -> (u16, String) {
    let mut s = TcpStream::connect(addr).await.unwrap();
    let host = host.map(|h| format!("Host: {h}\r\n")).unwrap_or_default();
    s.write_all(format!("GET {path} HTTP/1.1\r\n{host}{extra}\r\n").as_bytes())
        .await
        .unwrap();
    let mut buf = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(5), s.read_to_end(&mut buf)).await;
    parse_response(&buf)
}

#[tokio::test]
async fn foreign_host_names_are_refused_before_anything_else() {
    // DNS rebinding: a page at http://rebind.example:PORT whose name now resolves to
    // 127.0.0.1 sends its own origin, which matches its own Host.
    let config = ServerConfig {
        allowed_hosts: vec!["booth.local".into()],
        ..ServerConfig::default()
    };
    let server = TestServer::start(config).await;
    let port = server.addr.port();
    let upgrade = |origin: &str| {
        format!(
            "Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\n\
             Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Protocol: mouthpiece.v1\r\nOrigin: {origin}\r\n"
        )
    };
    let evil = format!("rebind.example:{port}");
    let (status, body) = get_with_host(
        server.addr,
        "/",
        Some(&evil),
        &upgrade(&format!("http://{evil}")),
    )
    .await;
    assert_eq!(status, 403, "{body}");
    assert!(body.contains("rebind.example"), "{body}");
    for path in ["/", "/healthz", "/metrics"] {
        assert_eq!(
            get_with_host(server.addr, path, Some(&evil), "").await.0,
            403
        );
    }
    assert_eq!(get_with_host(server.addr, "/", None, "").await.0, 400);
    // The server's own names.
    for host in [
        format!("127.0.0.1:{port}"),
        format!("localhost:{port}"),
        "LOCALHOST".to_owned(),
        format!("[::1]:{port}"),
        format!("booth.local:{port}"),
        "booth.local.".to_owned(),
    ] {
        assert_eq!(
            get_with_host(server.addr, "/healthz", Some(&host), "")
                .await
                .0,
            200,
            "{host}"
        );
    }
    let own = format!("localhost:{port}");
    let mut s = TcpStream::connect(server.addr).await.unwrap();
    s.write_all(
        format!(
            "GET / HTTP/1.1\r\nHost: {own}\r\n{}\r\n",
            upgrade(&format!("http://{own}"))
        )
        .as_bytes(),
    )
    .await
    .unwrap();
    let mut buf = [0u8; 512];
    let n = s.read(&mut buf).await.unwrap();
    assert!(buf[..n].starts_with(b"HTTP/1.1 101"));
    server.stop().await;
}

#[tokio::test]
async fn a_client_that_does_not_read_its_replies_gets_1008_with_a_reason() {
    use futures_util::{SinkExt, StreamExt};
    use tokio_tungstenite::tungstenite::Message;
    let config = ServerConfig {
        limits: Limits {
            max_messages_per_second: 1_000_000,
            control_queue_per_client: 2,
            ..Limits::default()
        },
        ..ServerConfig::default()
    };
    let server = TestServer::start(config).await;
    let ws = connect_v1(&server.url()).await;
    let (mut tx, mut rx) = ws.split();
    // Pings with long ids: their pongs fill the socket while the client does not read.
    let id = "i".repeat(16 * 1024);
    let sender = tokio::spawn(async move {
        for i in 0..4000 {
            // The first second paced, so that the replies fill the socket before the
            // queue of unanswered requests overflows; then as fast as it goes.
            if i < 1000 {
                tokio::time::sleep(Duration::from_millis(1)).await;
            }
            let ping = json!({"type": "ping", "id": id}).to_string();
            if tokio::time::timeout(Duration::from_secs(3), tx.send(Message::text(ping)))
                .await
                .map_or(true, |r| r.is_err())
            {
                break;
            }
        }
    });
    // Longer than a close frame used to wait behind unread data.
    tokio::time::sleep(Duration::from_millis(2000)).await;
    let mut close = None;
    while let Ok(Some(message)) = tokio::time::timeout(Duration::from_secs(10), rx.next()).await {
        match message {
            Ok(Message::Close(frame)) => {
                close = frame.map(|f| (u16::from(f.code), f.reason.to_string()));
                break;
            }
            Ok(_) => continue,
            Err(e) => panic!("cut without a close frame: {e}"),
        }
    }
    let (code, reason) = close.expect("a close frame");
    assert_eq!(code, 1008, "{reason}");
    assert!(reason.contains("not reading"), "{reason}");
    sender.abort();
    server.stop().await;
}

/// A TCP connection to `addr` from the loopback address `from` (any of 127.0.0.0/8).
async fn connect_from(from: &str, addr: std::net::SocketAddr) -> TcpStream {
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.bind(format!("{from}:0").parse().unwrap()).unwrap();
    socket.connect(addr).await.unwrap()
}

/// Sends `GET /healthz` on `s` and returns the status (0 when the server closed instead).
async fn healthz_on(mut s: TcpStream, addr: std::net::SocketAddr) -> u16 {
    if s.write_all(format!("GET /healthz HTTP/1.1\r\nHost: {addr}\r\n\r\n").as_bytes())
        .await
        .is_err()
    {
        return 0;
    }
    let mut buf = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(5), s.read_to_end(&mut buf)).await;
    parse_response(&buf).0
}

/// Whether the server has closed `s` (it reads end of stream or an error within 50 ms).
async fn closed_by_server(s: &mut TcpStream) -> bool {
    let mut byte = [0u8; 1];
    matches!(
        tokio::time::timeout(Duration::from_millis(50), s.read(&mut byte)).await,
        Ok(Ok(0) | Err(_))
    )
}

fn small_front_door() -> ServerConfig {
    ServerConfig {
        limits: Limits {
            max_connections: 8,
            max_clients: 4,
            ..Limits::default()
        },
        ..ServerConfig::default()
    }
}

#[tokio::test]
async fn a_peer_flooding_the_front_door_evicts_only_its_own_handshakes() {
    let server = TestServer::start(small_front_door()).await;
    // A slow client (another machine, a TLS handshake on a busy booth PC) has connected but
    // not yet sent its request.
    let slow = connect_from("127.0.0.3", server.addr).await;
    tokio::time::sleep(Duration::from_millis(100)).await;
    // Meanwhile one peer opens 40 connections and says nothing on any of them.
    let mut flood = Vec::new();
    for _ in 0..40 {
        flood.push(connect_from("127.0.0.2", server.addr).await);
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    // The flood evicted its own handshakes, oldest first; the slow client is still there
    // and is served when it speaks. So is a new client from a third address.
    assert_eq!(
        healthz_on(slow, server.addr).await,
        200,
        "the slow client was evicted"
    );
    let third = connect_from("127.0.0.4", server.addr).await;
    assert_eq!(healthz_on(third, server.addr).await, 200);
    let mut closed = 0;
    for s in &mut flood {
        closed += usize::from(closed_by_server(s).await);
    }
    assert!(closed >= 40 - 8, "only {closed} of the flood's 40 closed");
    drop(flood);
    server.stop().await;
}

#[tokio::test]
async fn a_local_process_holding_silent_connections_does_not_lock_others_out() {
    // Local processes all connect from 127.0.0.1: one of them keeps opening connections
    // and never speaks, holding far more than max_connections over time.
    let server = TestServer::start(small_front_door()).await;
    let addr = server.addr;
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flooder = tokio::spawn({
        let stop = stop.clone();
        async move {
            let mut held = Vec::new();
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                if let Ok(s) = TcpStream::connect(addr).await {
                    held.push(s);
                }
                tokio::time::sleep(Duration::from_millis(1)).await;
            }
            held.len()
        }
    });
    tokio::time::sleep(Duration::from_millis(100)).await;
    // Another local client, connecting and speaking as a browser does, is served every time.
    for _ in 0..20 {
        let s = TcpStream::connect(addr).await.unwrap();
        assert_eq!(healthz_on(s, addr).await, 200, "locked out by the flood");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let mut ws = connect_v1(&server.url()).await;
    next_of_type(&mut ws, "hello").await;
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let held = flooder.await.unwrap();
    assert!(held > 8 * 4, "the flood opened {held} connections");
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn max_clients_is_exact_under_simultaneous_upgrades() {
    let config = ServerConfig {
        limits: Limits {
            max_clients: 3,
            ..Limits::default()
        },
        ..ServerConfig::default()
    };
    let server = TestServer::start(config).await;
    let addr = server.addr;
    let n = 48;
    let mut sockets = Vec::new();
    for _ in 0..n {
        sockets.push(TcpStream::connect(addr).await.unwrap());
    }
    // Every request head goes out at the same moment.
    let barrier = Arc::new(tokio::sync::Barrier::new(n));
    let mut tasks = Vec::new();
    for mut s in sockets {
        let barrier = barrier.clone();
        tasks.push(tokio::spawn(async move {
            let head = format!(
                "GET / HTTP/1.1\r\nHost: {addr}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
                 Sec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\
                 Sec-WebSocket-Protocol: mouthpiece.v1\r\n\r\n"
            );
            barrier.wait().await;
            s.write_all(head.as_bytes()).await.unwrap();
            let mut buf = vec![0u8; 4096];
            let got = tokio::time::timeout(Duration::from_secs(5), s.read(&mut buf))
                .await
                .expect("an answer within 5 s")
                .unwrap_or(0);
            let (status, _) = parse_response(&buf[..got]);
            (status, s)
        }));
    }
    let mut statuses = Vec::new();
    let mut open = Vec::new();
    for t in tasks {
        let (status, s) = t.await.unwrap();
        statuses.push(status);
        open.push(s);
    }
    let upgraded = statuses.iter().filter(|&&s| s == 101).count();
    let full = statuses.iter().filter(|&&s| s == 503).count();
    assert_eq!((upgraded, full), (3, n - 3), "statuses {statuses:?}");
    assert_eq!(server.hub.clients(), 3);
    drop(open);
    let deadline = std::time::Instant::now() + Duration::from_secs(5);
    while server.hub.clients() > 0 && std::time::Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }

    // Then clients come and go at the cap for three seconds, from threads of their own (not
    // the server's runtime): every time a place frees up, several upgrades race for it. A
    // client counts itself from its 101 until just before it closes, so the server holds at
    // least as many sessions as are counted here: never more than 3.
    let holding = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let peak = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let end = std::time::Instant::now() + Duration::from_secs(3);
    let threads: Vec<_> = (0..24)
        .map(|i| {
            let (holding, peak) = (holding.clone(), peak.clone());
            std::thread::spawn(move || churn_at_the_cap(addr, i, end, &holding, &peak))
        })
        .collect();
    let (mut admitted, mut refused) = (0, 0);
    for t in threads {
        let (a, r) = t.join().unwrap();
        admitted += a;
        refused += r;
    }
    let peak = peak.load(std::sync::atomic::Ordering::SeqCst);
    assert!(
        peak <= 3,
        "{peak} clients held an upgraded connection at once with max_clients 3 ({admitted} upgrades, {refused} refused)"
    );
    // The cap was met over and over, not just once.
    assert!(
        admitted >= 30 && refused >= 30,
        "{admitted} upgrades, {refused} refused"
    );
    server.stop().await;
}

/// One client thread of `max_clients_is_exact_under_simultaneous_upgrades`: upgrades, and
/// when it gets 101 holds the connection for a moment, until `end`. Returns (upgraded,
/// refused with 503).
fn churn_at_the_cap(
    addr: std::net::SocketAddr,
    i: u64,
    end: std::time::Instant,
    holding: &std::sync::atomic::AtomicUsize,
    peak: &std::sync::atomic::AtomicUsize,
) -> (usize, usize) {
    use std::io::{Read, Write};
    use std::sync::atomic::Ordering::SeqCst;
    let head = format!(
        "GET / HTTP/1.1\r\nHost: {addr}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
         Sec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\
         Sec-WebSocket-Protocol: mouthpiece.v1\r\n\r\n"
    );
    let (mut admitted, mut refused) = (0, 0);
    let mut round = 0u64;
    while std::time::Instant::now() < end {
        round += 1;
        let Ok(mut s) = std::net::TcpStream::connect(addr) else {
            continue;
        };
        s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        if s.write_all(head.as_bytes()).is_err() {
            continue;
        }
        let mut buf = Vec::new();
        let mut chunk = [0u8; 1024];
        while !buf.windows(4).any(|w| w == b"\r\n\r\n") {
            match s.read(&mut chunk) {
                Ok(0) | Err(_) => break,
                Ok(n) => buf.extend_from_slice(&chunk[..n]),
            }
        }
        match parse_response(&buf).0 {
            101 => {
                admitted += 1;
                let now = holding.fetch_add(1, SeqCst) + 1;
                peak.fetch_max(now, SeqCst);
                std::thread::sleep(Duration::from_micros(100 + (i * 37 + round * 53) % 400));
                holding.fetch_sub(1, SeqCst);
            }
            503 => refused += 1,
            _ => {}
        }
    }
    (admitted, refused)
}

#[tokio::test]
async fn healthz_reports_a_failed_daemon_with_503_and_the_reason() {
    let server = TestServer::start(ServerConfig::default()).await;
    let (status, _) = http_get(server.addr, "/healthz", "").await;
    assert_eq!(status, 200);
    server
        .hub
        .set_failure("the source thread died: panicked: attempt to add with overflow".into());
    let (status, body) = http_get(server.addr, "/healthz", "").await;
    assert_eq!(status, 503, "{body}");
    let health: serde_json::Value = serde_json::from_str(&body).unwrap();
    assert_eq!(health["status"], "failed");
    assert!(
        health["reason"]
            .as_str()
            .unwrap()
            .contains("source thread died"),
        "{body}"
    );
    server.stop().await;
}
