//! `mouthpiece-loadgen`: many WebSocket clients against a mouthpiece server.
//!
//! Without `--url` it starts an in-process server on 127.0.0.1 with a synthetic publisher
//! thread at `--fps`, so the whole path (publish → ring → per-client writer → socket →
//! client) is measured on this machine. With `--url` it only runs the clients against a
//! running daemon. Prints a JSON report; exits 1 when a fast client lost frames, was
//! disconnected, or p99 latency exceeds `--max-p99-ms`.

use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::Parser;
use mouthpiece_server::loadgen::{self, LoadClients, LoadConfig};
use mouthpiece_server::{run, Hub, HubConfig, ServerConfig};

#[derive(Parser, Debug)]
#[command(about = "Load test for the mouthpiece WebSocket server")]
struct Args {
    /// Clients that read everything.
    #[arg(long, default_value_t = 64)]
    clients: usize,
    /// Clients that subscribe and then stop reading.
    #[arg(long, default_value_t = 1)]
    stalled: usize,
    /// Frames per second of the synthetic stream (in-process server only).
    #[arg(long, default_value_t = 60.0)]
    fps: f64,
    /// How long to stream, seconds.
    #[arg(long, default_value_t = 30.0)]
    seconds: f64,
    /// A running server to test instead of the in-process one (ws://host:port/).
    #[arg(long)]
    url: Option<String>,
    /// Token to present.
    #[arg(long)]
    token: Option<String>,
    /// Fail when p99 capture-to-client latency exceeds this, milliseconds.
    #[arg(long, default_value_t = 5.0)]
    max_p99_ms: f64,
    /// The subscribe message each client sends.
    #[arg(long, default_value = r#"{"type":"subscribe","id":1}"#)]
    subscribe: String,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()),
        )
        .init();
    let args = Args::parse();
    let frames = (args.fps * args.seconds).round() as u64;
    let mut server = None;
    let url = match &args.url {
        Some(url) => url.clone(),
        None => {
            let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
            let addr = listener.local_addr()?;
            let (hub, _control) = Hub::new(&HubConfig::default());
            hub.set_info(loadgen::synthetic_info(args.fps));
            let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
            let mut config = ServerConfig::default();
            config.limits.max_clients = args.clients + args.stalled + 8;
            let handle = tokio::spawn(run(listener, config, hub.clone(), async {
                let _ = stop_rx.await;
            }));
            server = Some((hub, stop_tx, handle, _control));
            format!("ws://{addr}/")
        }
    };
    let config = LoadConfig {
        url: url.clone(),
        token: args.token.clone(),
        fast_clients: args.clients,
        stalled_clients: args.stalled,
        subscribe: args.subscribe.clone(),
    };
    eprintln!(
        "loadgen: {} clients (+{} stalled) on {url}, {} fps for {} s",
        args.clients, args.stalled, args.fps, args.seconds
    );
    let rss_before = rss_kib();
    let clients = LoadClients::connect(&config, Duration::from_secs(30)).await;
    let published = match &server {
        Some((hub, ..)) => {
            let stop = Arc::new(AtomicBool::new(false));
            let publisher = loadgen::spawn_publisher(hub.clone(), args.fps, frames, stop);
            let published = tokio::task::spawn_blocking(move || publisher.join())
                .await
                .context("publisher task")?
                .map_err(|_| anyhow::anyhow!("publisher thread panicked"))?;
            Some(published)
        }
        None => {
            tokio::time::sleep(Duration::from_secs_f64(args.seconds)).await;
            None
        }
    };
    tokio::time::sleep(Duration::from_millis(300)).await;
    let report = clients.finish().await;
    let rss_after = rss_kib();
    if let Some((hub, stop, handle, _control)) = server {
        eprint!(
            "{}",
            hub.metrics_text()
                .lines()
                .filter(|l| !l.starts_with('#') && !l.contains("_bucket"))
                .map(|l| format!("  {l}\n"))
                .collect::<String>()
        );
        let _ = stop.send(());
        let _ = handle.await;
    }
    let complete = report
        .fast
        .iter()
        .filter(|c| published.is_none_or(|p| c.frames == p))
        .count();
    let summary = serde_json::json!({
        "clients": args.clients,
        "stalled": args.stalled,
        "fps": args.fps,
        "seconds": args.seconds,
        "published": published,
        "fast_clients_complete": complete,
        "fast_clients_disconnected": report.fast.iter().filter(|c| c.disconnected).count(),
        "gaps": report.fast.iter().map(|c| c.gaps + c.out_of_order).sum::<u64>(),
        "stalled_lagged": report.stalled.iter().map(|c| c.lagged).sum::<u64>(),
        "connect_errors": report.connect_errors,
        "latency_ms": report.latency,
        "rss_kib_before": rss_before,
        "rss_kib_after": rss_after,
    });
    println!("{}", serde_json::to_string_pretty(&summary)?);
    if complete != report.fast.len() || report.fast.len() != args.clients {
        bail!(
            "{} of {} fast clients received every frame",
            complete,
            args.clients
        );
    }
    if report.latency.p99_ms > args.max_p99_ms {
        bail!(
            "p99 latency {:.2} ms exceeds {:.2} ms",
            report.latency.p99_ms,
            args.max_p99_ms
        );
    }
    Ok(())
}

/// Resident set size of this process, KiB (Linux).
fn rss_kib() -> Option<u64> {
    std::fs::read_to_string("/proc/self/status")
        .ok()?
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()
}
