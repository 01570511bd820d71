//! `mouthpiece run`: wires the source thread, the processing thread, the take recorder and the
//! async server together, and handles signals, sd_notify and the watchdog.
//!
//! Threads: `mouthpiece-source` (owns the source), `mouthpiece-process` (processing, takes
//! control), `mouthpiece-take` (while a take records), `mouthpiece-osc` (once `[osc]` has a
//! target: the VMC sender behind a bounded queue), `mouthpiece-ifacialmocap` (while
//! `[ifacialmocap]` is enabled: answers handshakes, streams to receivers, behind a bounded
//! queue), and a 2-thread tokio runtime for the
//! server, the NATS link (once `[nats]` has servers), the signals and the watchdog. Start-up: validate the config, bind the port, start
//! the threads, then `READY=1`. Signals: SIGTERM/SIGINT stop (a take written out to its
//! last queued frame and synced, clients closed with 1001, exit 0 within 2 s when no take
//! drains); SIGHUP reloads characters, tokens, colour ranges, `[rig]`, `[osc]` and
//! `[ifacialmocap]`;
//! SIGUSR1 starts a take with the default slate, SIGUSR2 stops it.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use mouthpiece_config::Config;
use mouthpiece_server::{Hub, HubConfig, ServerConfig, TimecodeRate};
use tokio::signal::unix::{signal, SignalKind};

use crate::backoff::Backoff;
use crate::error::CheckError;
use crate::notify::Notifier;
use crate::pipeline::{self, Command, Processor};
use crate::source::{self, SourceShared, SourceState};
use mouthpiece_takes::{TakeSettings, Takes};

/// How long the exit waits for a take still recording to be written out and synced.
pub const TAKE_DRAIN_LIMIT: Duration = Duration::from_secs(20);

/// Why the daemon could not run.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    /// The configuration is unusable (exit code 2).
    #[error(transparent)]
    Config(#[from] CheckError),
    #[error("cannot listen on {addr}")]
    Bind {
        addr: std::net::SocketAddr,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot start the async runtime or a thread")]
    Runtime(#[source] std::io::Error),
    #[error("the server failed")]
    Server(#[from] mouthpiece_server::ServerError),
    /// A thread of the daemon died (a panic): exit non-zero so that systemd restarts it.
    #[error("the {thread} thread died: {message}")]
    ThreadDied {
        thread: &'static str,
        message: String,
    },
}

pub use crate::factory::Factory;

/// Start-up options from the command line.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// The config file, for SIGHUP; `None` for the embedded default.
    pub config_path: Option<PathBuf>,
    /// Start a take at once with this slate (and take number).
    pub record: Option<(String, Option<u32>)>,
    /// Applied again after each reload (CLI flags override the file).
    pub overrides: Overrides,
}

/// Command-line values that override the file.
#[derive(Debug, Clone, Default)]
pub struct Overrides {
    pub listen: Option<std::net::SocketAddr>,
    pub source: Option<String>,
}

pub use crate::settings::{server_config, timecode_rate};

/// Runs the daemon until SIGTERM or SIGINT.
pub fn run<F: Factory>(config: Config, factory: F, options: RunOptions) -> Result<(), DaemonError> {
    crate::check::check(&config)?;
    let server_config = server_config(&config)?;
    let rate = timecode_rate(&config)?;
    let processor = factory.processor(&config)?;
    let osc = crate::osc::settings(&config)?;
    let livelink = crate::livelink::settings(&config, rate)?;
    let ifacialmocap = crate::ifacialmocap::settings(&config)?;
    let _ = crate::logging::set_level(&config.logging.level);
    tracing::info!("{}", config.summary());

    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("mouthpiece-server")
        .enable_all()
        .build()
        .map_err(DaemonError::Runtime)?;
    let result = runtime.block_on(serve(
        config,
        factory,
        options,
        processor,
        (server_config, osc, livelink, ifacialmocap),
        rate,
    ));
    // Threads still blocked in a source's read must not hold up the exit.
    runtime.shutdown_timeout(Duration::from_millis(200));
    result
}

async fn serve<F: Factory>(
    config: Config,
    factory: F,
    options: RunOptions,
    processor: F::Processor,
    (server_config, osc_settings, livelink_settings, ifm_settings): (
        ServerConfig,
        crate::osc::OscSettings,
        crate::livelink::LiveLinkSettings,
        Option<crate::ifacialmocap::IfmSettings>,
    ),
    rate: TimecodeRate,
) -> Result<(), DaemonError> {
    let notifier = Notifier::from_env().unwrap_or_else(|e| {
        tracing::warn!("NOTIFY_SOCKET unusable, not notifying systemd: {e}");
        Notifier::disabled()
    });
    let addr = config.server.listen.0;
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|source| DaemonError::Bind { addr, source })?;
    let local = listener
        .local_addr()
        .map_err(|source| DaemonError::Bind { addr, source })?;
    let (hub, control) = Hub::new(&HubConfig {
        timecode_rate: rate,
        timecode_ltc: config.timecode.source == mouthpiece_config::TimecodeSource::Ltc,
        ..HubConfig::default()
    });
    // The console's player reads the takes folder (`/take`).
    hub.set_take_archive(Some(Arc::new(crate::take_player::TakeFolder::new(
        config.takes.folder.clone(),
    ))));

    let spec = config.source.spec.as_str().to_owned();
    // The first `hello` already names the characters.
    hub.set_info(processor.stream_info(0.0, &spec));
    let shared = SourceShared::new();
    let backoff = Backoff::new(
        config.source.retry_initial_s.duration(),
        config.source.retry_max_s.duration(),
    );
    let throttle = config.logging.throttle_s.duration();
    let osc = crate::osc::OscOutput::new(hub.osc(), throttle);
    osc.configure(osc_settings).map_err(DaemonError::Runtime)?;
    let livelink = crate::livelink::LiveLinkOutput::new(throttle);
    livelink
        .configure(livelink_settings)
        .map_err(DaemonError::Runtime)?;
    let ifacialmocap = crate::ifacialmocap::IfmOutput::new();
    ifacialmocap
        .configure(ifm_settings)
        .map_err(DaemonError::Runtime)?;
    hub.set_metrics_source("livelink", Some(livelink.metrics()));
    hub.set_metrics_source(
        "ifacialmocap",
        Some(std::sync::Arc::new(crate::ifacialmocap::IfmMetrics(
            ifacialmocap.counters(),
        ))),
    );
    let source_thread = source::spawn(
        factory.opener(&spec, config.source.stall_timeout_s.duration()),
        spec.clone(),
        shared.clone(),
        backoff,
        throttle,
    )
    .map_err(DaemonError::Runtime)?;

    // The microphone (or a replayed recording's sound) on a thread of its own.
    let audio = crate::audio::AudioShared::new(hub.audio_counters());
    let audio_thread = match crate::capture::audio_plan(&config) {
        Some(plan) => Some(
            crate::audio::spawn(plan, audio.clone(), hub.clone()).map_err(DaemonError::Runtime)?,
        ),
        None => None,
    };
    // The studio's LTC, read from a channel of that sound on a thread of its own (the
    // configuration requires [audio] and a channel for it).
    let ltc_thread = match (config.timecode.channel, &audio_thread) {
        (Some(channel), Some(_)) if hub.timecode_clock().is_ltc() => Some(
            crate::ltc::spawn(
                channel.saturating_sub(1) as usize,
                audio.bus.subscribe(crate::ltc::LTC_QUEUE_BLOCKS),
                audio.clone(),
                hub.clone(),
            )
            .map_err(DaemonError::Runtime)?,
        ),
        _ => None,
    };
    let audio_queue = config
        .audio
        .as_ref()
        .map_or(200, |a| a.queue_blocks as usize);

    let (commands_tx, commands_rx) = crossbeam_channel::bounded(8);
    let epoch = Instant::now();
    let heartbeat = Arc::new(AtomicU64::new(0));
    let stop = Arc::new(AtomicBool::new(false));
    let mut takes = Takes::new(TakeSettings {
        folder: config.takes.folder.clone(),
        flush: config.takes.flush_s.duration(),
        min_free_mb: config.takes.min_free_mb,
        queue_frames: config.takes.queue_frames as usize,
        timecode_rate: rate.name().to_owned(),
        max_write_bytes_s: (config.takes.max_write_mb_s > 0.0)
            .then_some(config.takes.max_write_mb_s * 1e6),
    });
    if audio_thread.is_some() {
        takes.set_audio(audio.bus.clone(), audio_queue);
    }
    let mut processor = processor;
    if audio_thread.is_some() {
        processor.set_audio(&audio.bus);
    }
    let processing = pipeline::spawn(
        processor,
        pipeline::Context {
            source: shared.clone(),
            spec: spec.clone(),
            hub: hub.clone(),
            control,
            commands: commands_rx,
            takes,
            default_slate: config.takes.slate.0.clone(),
            timecode_rate: rate,
            stall_timeout: config.source.stall_timeout_s.duration(),
            heartbeat: heartbeat.clone(),
            epoch,
            stop: stop.clone(),
            osc: osc.clone(),
            livelink: livelink.clone(),
            ifacialmocap: ifacialmocap.clone(),
            tuner: crate::tune::Tuner::new(hub.clone(), options.config_path.clone()),
        },
    )
    .map_err(DaemonError::Runtime)?;
    if let Some((slate, take)) = options.record.clone() {
        let _ = commands_tx.try_send(Command::RecordStart { slate, take });
    } else if config.takes.record_at_start {
        let _ = commands_tx.try_send(Command::RecordStart {
            slate: config.takes.slate.0.clone(),
            take: None,
        });
    }

    // The NATS link: its own tasks on this runtime, fed from the hub like a WebSocket
    // client; the booth runs the same whether or not a broker is there.
    let _nats = match mouthpiece_nats::NatsSettings::from_config(&config.nats) {
        Some(settings) => match mouthpiece_nats::NatsLink::start(
            hub.clone(),
            settings,
            server_config.name.clone(),
            config.takes.folder.clone(),
        )
        .await
        {
            Ok(link) => Some(link),
            Err(e) => {
                tracing::error!("NATS link not started, the booth runs without it: {e}");
                None
            }
        },
        None => None,
    };

    // Live Link Face's remote control: its own thread; takes go through the control queue.
    let remote = match crate::livelink::remote_settings(&config, rate) {
        Some(settings) => {
            let addr = settings.listen;
            Some(
                crate::livelink::LiveLinkRemote::start(
                    settings,
                    hub.clone(),
                    livelink.clone(),
                    throttle,
                )
                .map_err(|source| DaemonError::Bind { addr, source })?,
            )
        }
        None => None,
    };
    if let Some(remote) = &remote {
        hub.set_metrics_source("livelink_control", Some(remote.metrics()));
    }

    let (shutdown_tx, shutdown_rx) = tokio::sync::oneshot::channel::<()>();
    let mut server = tokio::spawn(mouthpiece_server::run(
        listener,
        server_config,
        hub.clone(),
        async {
            let _ = shutdown_rx.await;
        },
    ));
    tracing::info!(%local, "mouthpiece running: viewer at http://{local}/");
    let _ = notifier.ready(&format!("serving on {local}, source {spec}"));

    let mut sigterm = signal(SignalKind::terminate()).map_err(DaemonError::Runtime)?;
    let mut sigint = signal(SignalKind::interrupt()).map_err(DaemonError::Runtime)?;
    let mut sighup = signal(SignalKind::hangup()).map_err(DaemonError::Runtime)?;
    let mut sigusr1 = signal(SignalKind::user_defined1()).map_err(DaemonError::Runtime)?;
    let mut sigusr2 = signal(SignalKind::user_defined2()).map_err(DaemonError::Runtime)?;
    let watchdog_every = notifier
        .watchdog_timeout()
        .map(|t| t / 2)
        .unwrap_or(Duration::from_secs(5));
    // Also how soon a dead thread is noticed.
    let mut tick = tokio::time::interval(watchdog_every.min(Duration::from_secs(1)));
    let mut current = config;
    let mut last_status = String::new();
    let mut server_result = None;
    let mut died: Option<&'static str> = None;
    loop {
        tokio::select! {
            _ = sigterm.recv() => { tracing::info!("SIGTERM: stopping"); break; }
            _ = sigint.recv() => { tracing::info!("SIGINT: stopping"); break; }
            _ = sighup.recv() => {
                let _ = notifier.reloading();
                match reload(&factory, &options, &current, local) {
                    Ok((config, payload, new_server, new_osc, new_livelink, new_ifm)) => {
                        if commands_tx.try_send(Command::Reload(payload)).is_ok() {
                            hub.set_tokens(new_server.read_token, new_server.control_token);
                            if let Err(e) = osc.configure(new_osc) {
                                tracing::error!("SIGHUP: OSC output not reconfigured: {e}");
                            }
                            if let Err(e) = livelink.configure(new_livelink) {
                                tracing::error!("SIGHUP: Live Link output not reconfigured: {e}");
                            }
                            if let Some(remote) = &remote {
                                remote.set_allowed(config.livelink.allowed());
                            }
                            if let Err(e) = ifacialmocap.configure(new_ifm) {
                                tracing::error!("SIGHUP: iFacialMocap output not reconfigured: {e}");
                            }
                            tracing::info!("SIGHUP: {}", config.summary());
                            current = config;
                        } else {
                            tracing::error!("SIGHUP: processing is busy; reload not applied");
                        }
                    }
                    Err(e) => tracing::error!("SIGHUP: new configuration rejected, old one kept: {}", source::error_chain(&e)),
                }
                let _ = notifier.reloaded(&status_line(&shared, &hub, &osc, &livelink, remote.as_ref(), &ifacialmocap));
            }
            _ = sigusr1.recv() => {
                let _ = commands_tx.try_send(Command::RecordStart { slate: current.takes.slate.0.clone(), take: None });
            }
            _ = sigusr2.recv() => { let _ = commands_tx.try_send(Command::RecordStop); }
            _ = tick.tick() => {
                // A thread that ended while nothing asked it to has died (a panic).
                if processing.is_finished() {
                    died = Some("processing");
                    break;
                }
                if source_thread.is_finished() {
                    died = Some("source");
                    break;
                }
                if audio_thread.as_ref().is_some_and(|t| t.is_finished()) {
                    died = Some("audio");
                    break;
                }
                if ltc_thread.as_ref().is_some_and(|t| t.is_finished()) {
                    died = Some("ltc");
                    break;
                }
                // Ping only while the processing loop turns: a hung pipeline gets restarted.
                let age = epoch.elapsed().as_millis() as u64 - heartbeat.load(Ordering::Relaxed).min(epoch.elapsed().as_millis() as u64);
                if Duration::from_millis(age) < watchdog_every {
                    let _ = notifier.watchdog();
                } else {
                    tracing::warn!(stalled_ms = age, "processing thread not turning; withholding watchdog ping");
                }
                let status = status_line(&shared, &hub, &osc, &livelink, remote.as_ref(), &ifacialmocap);
                if status != last_status {
                    let _ = notifier.status(&status);
                    last_status = status;
                }
            }
            result = &mut server => {
                server_result = Some(result);
                break;
            }
        }
    }

    let mut processing = Some(processing);
    let mut source_thread = Some(source_thread);
    let mut audio_thread = audio_thread;
    let mut ltc_thread = ltc_thread;
    let failure = died.map(|thread| {
        let handle = match thread {
            "processing" => processing.take(),
            "audio" => audio_thread.take(),
            "ltc" => ltc_thread.take(),
            _ => source_thread.take(),
        };
        let message = match handle.map(|h| h.join()) {
            Some(Err(payload)) => format!("panicked: {}", source::panic_message(&*payload)),
            _ => "ended on its own".to_owned(),
        };
        tracing::error!("the {thread} thread died ({message}): stopping so that the service manager restarts the daemon");
        let reason = format!("the {thread} thread died: {message}");
        hub.set_failure(reason.clone());
        hub.update_status(|s| s.message = Some(reason.clone()));
        let _ = notifier.status(&reason);
        DaemonError::ThreadDied { thread, message }
    });

    // Stop: processing first (it closes the take), then the server (clients get 1001).
    let _ = notifier.stopping();
    let stopping = Instant::now();
    stop.store(true, Ordering::Release);
    shared.stop();
    audio.stop();
    if let Some(processing) = processing {
        // The processing thread finishes the take before it ends: every queued frame
        // written, the file and its folder synced (its writer logs what was kept).
        let joined = tokio::task::spawn_blocking(move || processing.join());
        if tokio::time::timeout(TAKE_DRAIN_LIMIT, joined)
            .await
            .is_err()
        {
            tracing::error!(
                "processing thread did not stop within {} s: the take may lack its last frames",
                TAKE_DRAIN_LIMIT.as_secs()
            );
        }
    }
    let _ = shutdown_tx.send(());
    let server_result = match server_result {
        Some(r) => Some(r),
        None => tokio::time::timeout(Duration::from_millis(400), &mut server)
            .await
            .ok(),
    };
    if let Some(source_thread) = source_thread.filter(|t| t.is_finished()) {
        let _ = source_thread.join();
    }
    tracing::info!(
        elapsed_ms = stopping.elapsed().as_millis() as u64,
        "stopped"
    );
    if let Some(failure) = failure {
        return Err(failure);
    }
    match server_result {
        Some(Ok(Err(e))) => Err(e.into()),
        _ => Ok(()),
    }
}

fn status_line(
    shared: &SourceShared,
    hub: &Hub,
    osc: &crate::osc::OscOutput,
    livelink: &crate::livelink::LiveLinkOutput,
    remote: Option<&crate::livelink::LiveLinkRemote>,
    ifacialmocap: &crate::ifacialmocap::IfmOutput,
) -> String {
    let source = match shared.state().1 {
        SourceState::Starting => "source starting".to_owned(),
        SourceState::Up(info) => format!("source up ({})", info.description),
        SourceState::Down { reason, .. } => format!("source down: {reason}"),
    };
    let mut line = format!(
        "{source}; {} clients; {} frames",
        hub.clients(),
        hub.frames_published()
    );
    if let Some(osc) = osc.status() {
        line.push_str("; ");
        line.push_str(&osc);
    }
    if let Some(livelink) = livelink.status() {
        line.push_str("; ");
        line.push_str(&livelink);
    }
    if let Some(remote) = remote {
        line.push_str("; ");
        line.push_str(&remote.status());
    }
    if let Some(ifm) = ifacialmocap.status() {
        line.push_str("; ");
        line.push_str(&ifm);
    }
    let status = hub.status();
    match status.audio.state {
        mouthpiece_server::AudioState::Off => {}
        mouthpiece_server::AudioState::NoDevice => {
            line.push_str("; ");
            line.push_str(status.audio_message.as_deref().unwrap_or("no microphone"));
        }
        state => line.push_str(&format!(
            "; audio {} ({}, {} Hz, {} ch)",
            state.as_str(),
            status.audio.device,
            status.audio.sample_rate,
            status.audio.channels
        )),
    }
    if status.timecode.source == "ltc" {
        line.push_str(&format!(
            "; timecode LTC {}",
            status.timecode.state.as_str()
        ));
    }
    if let Some(nats) = hub.nats().status() {
        line.push_str("; ");
        line.push_str(&nats);
    }
    line
}

/// What a validated reload carries: the config, the processor's payload, the server's
/// settings (tokens), the OSC output's, the Live Link output's and the iFacialMocap output's.
type Reloaded<R> = (
    Config,
    R,
    ServerConfig,
    crate::osc::OscSettings,
    crate::livelink::LiveLinkSettings,
    Option<crate::ifacialmocap::IfmSettings>,
);

/// Loads the config again (same file, same CLI overrides) and validates everything a reload
/// changes.
///
/// The listen address does not change before a restart, so the new tokens are checked against
/// the address actually `bound`: a daemon serving the network never drops its tokens because
/// the new file says loopback.
fn reload<F: Factory>(
    factory: &F,
    options: &RunOptions,
    current: &Config,
    bound: std::net::SocketAddr,
) -> Result<Reloaded<<F::Processor as Processor>::Reload>, CheckError> {
    let mut config = match &options.config_path {
        Some(path) => Config::load(path)?,
        None => Config::embedded(),
    };
    apply_overrides(&mut config, &options.overrides);
    crate::check::check(&config)?;
    let server = server_config(&config)?;
    crate::hardening::check_against(&config, &server, bound)?;
    let payload = factory.reload(&config)?;
    let osc = crate::osc::settings(&config)?;
    let livelink = crate::livelink::settings(&config, timecode_rate(current)?)?;
    let ifacialmocap = crate::ifacialmocap::settings(&config)?;
    for (what, changed) in [
        ("source", config.source != current.source),
        (
            "server.listen",
            config.server.listen != current.server.listen,
        ),
        ("takes", config.takes != current.takes),
        ("timecode", config.timecode != current.timecode),
        ("nats", config.nats != current.nats),
        (
            "livelink.control",
            config.livelink.control != current.livelink.control,
        ),
    ] {
        if changed {
            tracing::warn!("{what} changed: takes effect after a restart");
        }
    }
    let _ = crate::logging::set_level(&config.logging.level);
    Ok((config, payload, server, osc, livelink, ifacialmocap))
}

/// CLI flags win over the file.
pub fn apply_overrides(config: &mut Config, overrides: &Overrides) {
    if let Some(listen) = overrides.listen {
        config.server.listen = mouthpiece_config::ListenAddr(listen);
    }
    if let Some(source) = &overrides.source {
        config.source.spec = mouthpiece_config::SourceSpec(source.clone());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reload_is_validated_against_the_bound_address() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("mouthpiece.toml");
        // The new file says loopback and has no tokens; the running server is on the network.
        std::fs::write(&path, "[server]\nlisten = \"127.0.0.1:9870\"\n").unwrap();
        let options = RunOptions {
            config_path: Some(path.clone()),
            ..RunOptions::default()
        };
        let current = Config::load(&path).unwrap();
        let bound: std::net::SocketAddr = "0.0.0.0:9870".parse().unwrap();
        let Err(err) = reload(&crate::live::LiveFactory, &options, &current, bound) else {
            panic!("tokens dropped on a network-facing server");
        };
        let text = err.to_string();
        assert!(text.contains("0.0.0.0:9870"), "{text}");
        assert!(text.contains("server.listen"), "{text}");
        // The same file is fine for a server on loopback.
        let loopback: std::net::SocketAddr = "127.0.0.1:9870".parse().unwrap();
        assert!(reload(&crate::live::LiveFactory, &options, &current, loopback).is_ok());
    }
}
