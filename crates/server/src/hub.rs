//! The hub: the handle the processing loop publishes through, and the control path back.
//!
//! [`Hub::publish`] never blocks and never waits for a client: it stamps the frame with the
//! next `seq` and its timecode, copies it into a recycled slot and puts it into a
//! fixed-size ring ([`tokio::sync::broadcast`]). Each client reads the ring at its own pace;
//! a client that falls more than the ring's length behind loses the oldest frames and is
//! told how many (`status` with `lagged`). In steady state publishing does not allocate:
//! slots are reused once every client has let go of them.
//!
//! Control requests (calibrate, record) travel the other way through a small bounded queue
//! ([`ControlReceiver`]); each carries a one-shot reply slot that the daemon fills with
//! [`ControlRequest::reply`].

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};
use tokio::sync::{broadcast, mpsc, oneshot, watch};

pub use mouthpiece_output::{CharacterFrame, HeadPose, PerformerFrame, StreamFrame};

use crate::console::{CalibrationReport, Health, TakeSummary, TuneReport};
use crate::metrics::Metrics;
use crate::timecode::{Timecode, TimecodeRate};

/// A frame as the server holds it: the daemon's data plus stream position and timecode.
#[derive(Debug, Clone, Default)]
pub struct PublishedFrame {
    /// Counts every frame of the stream from 0; a gap means the client lost frames.
    pub seq: u64,
    /// SMPTE timecode of `wall_us` (or of `t` when there is no wall clock).
    pub timecode: Timecode,
    /// When it was published, for the fan-out latency histogram.
    pub published_at: Option<Instant>,
    /// The frame.
    pub frame: StreamFrame,
    /// JSON text for subscriptions to all characters, indexed by (curve, performer):
    /// serialized once per frame by the first client that needs it, shared by the rest.
    pub(crate) json_cache: [std::sync::OnceLock<tokio_tungstenite::tungstenite::Utf8Bytes>; 4],
}

/// A character as described in `hello`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct CharacterInfo {
    /// Name used in `subscribe` and `frame`.
    pub name: String,
    /// Point names, in frame order (`P1`..`P12` by default).
    pub points: Vec<String>,
    /// Neutral points `P_n^0` in the character's mouth frame, its own units.
    pub neutral: Vec<[f32; 3]>,
    /// The deformation parameters `M_n` (per point, per axis) the daemon chose.
    pub m: Vec<[f32; 3]>,
    /// How `M` was chosen: `per-point`, `per-axis` or `manual`.
    pub m_mode: String,
    /// Units of the points (the character file's).
    pub units: String,
}

/// The stream's description, sent in `hello`; the daemon sets it at start and on reload.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct StreamInfo {
    /// Characters being driven.
    pub characters: Vec<CharacterInfo>,
    /// Names of the performer's lip dots (`D1`..`D12`), in `performer.points` order.
    pub performer_points: Vec<String>,
    /// Nominal frame rate of the source, frames per second.
    pub frame_rate: f64,
    /// Where frames come from (free text: `replay recordings/demo.mcap`, `openni2 ...`).
    pub source: String,
    /// The performer's neutral mouth frame in the neutral head's (camera) coordinates, once
    /// calibrated: where `performer` points and the head pose meet.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mouth_frame: Option<mouthpiece_output::RigidPose>,
}

/// The take being recorded.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Recording {
    /// Slate (scene) name.
    pub slate: String,
    /// Take number.
    pub take: u32,
    /// File being written, if the daemon tells.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub file: Option<String>,
    /// When the take started, Unix microseconds (for the elapsed time), if the daemon tells.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub started_wall_us: Option<i64>,
}

/// Whether frames are flowing from the source.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SourceState {
    /// Frames are coming.
    #[default]
    Up,
    /// The camera is absent or failed; the daemon retries.
    Down,
}

impl SourceState {
    /// `up` or `down`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Up => "up",
            Self::Down => "down",
        }
    }
}

/// Daemon state shown to every client (`status`); clients get it on connect and on change.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Status {
    /// Source up or down.
    pub source: SourceState,
    /// Neutral calibration running.
    pub calibrating: bool,
    /// Take being recorded.
    pub recording: Option<Recording>,
    /// Free text (why the source is down, disk full, ...).
    pub message: Option<String>,
    /// The last neutral calibration, once there was one.
    pub calibration: Option<crate::console::CalibrationReport>,
    /// Takes recorded in this run of the daemon, oldest first.
    pub takes: Vec<crate::console::TakeSummary>,
    /// The microphone: state, format, level meter (set by the daemon's audio thread).
    pub audio: crate::audio::AudioStatus,
    /// Why the configured microphone is not live (cannot be opened, lost).
    pub audio_message: Option<String>,
    /// The last paint check (`tune_colours`).
    pub tune: Option<crate::console::TuneReport>,
    /// The timecode's source and state (locked, free-running, lost), set by the daemon's
    /// LTC thread when it changes.
    pub timecode: crate::timecode_clock::TimecodeStatus,
}

/// A control action requested by a client.
#[derive(Debug, Clone, PartialEq)]
pub enum ControlCommand {
    /// Take a new neutral calibration, averaging for `duration` (daemon default when `None`).
    Calibrate {
        /// Averaging time.
        duration: Option<Duration>,
    },
    /// Start recording a take.
    RecordStart {
        /// Slate name (validated: letters, digits, space, `-`, `_`, `.`; at most 64).
        slate: Option<String>,
        /// Take number; the daemon picks the next when `None`.
        take: Option<u32>,
    },
    /// Stop the current take.
    RecordStop,
    /// Turn a character's head to a viewpoint (its model frame), or back to following the
    /// performer (`None`).
    LookAt {
        /// The character's name (checked against the stream's characters).
        character: String,
        /// Finite, within ±1e6.
        point: Option<[f64; 3]>,
    },
    /// Propose colour ranges from `seconds` of live frames and check them (`apply: false`),
    /// or write the last offered proposal into the configuration and reload (`apply: true`).
    TuneColours {
        apply: bool,
        /// Sampling time (`None`: the daemon's default).
        seconds: Option<Duration>,
    },
}

/// Why the daemon refused or failed a control request; the client gets it as an `error`.
#[derive(Debug, Clone, PartialEq)]
pub struct ControlFailure {
    /// Shown to the client.
    pub message: String,
}

impl ControlFailure {
    /// A failure with this message.
    pub fn new(message: impl Into<String>) -> Self {
        Self {
            message: message.into(),
        }
    }
}

/// The daemon's answer to a control request: details on success (sent as `result.detail`).
pub type ControlOutcome = Result<serde_json::Value, ControlFailure>;

/// One control request from a client, waiting for the daemon's answer.
#[derive(Debug)]
pub struct ControlRequest {
    /// What to do.
    pub command: ControlCommand,
    /// Who asked (peer address), for logs.
    pub client: String,
    reply: oneshot::Sender<ControlOutcome>,
}

impl ControlRequest {
    /// Answers the client. Never blocks; a client that went away is ignored.
    pub fn reply(self, outcome: ControlOutcome) {
        let _ = self.reply.send(outcome);
    }
}

/// The daemon's end of the control queue.
#[derive(Debug)]
pub struct ControlReceiver {
    rx: mpsc::Receiver<ControlRequest>,
}

impl ControlReceiver {
    /// The next request if one is waiting; never blocks (for the processing loop).
    pub fn try_recv(&mut self) -> Option<ControlRequest> {
        self.rx.try_recv().ok()
    }

    /// Waits for the next request (outside a tokio runtime); `None` when the hub is gone.
    pub fn blocking_recv(&mut self) -> Option<ControlRequest> {
        self.rx.blocking_recv()
    }

    /// Waits for the next request; `None` when the hub is gone.
    pub async fn recv(&mut self) -> Option<ControlRequest> {
        self.rx.recv().await
    }
}

/// Sizes of the hub's queues.
#[derive(Debug, Clone, PartialEq)]
pub struct HubConfig {
    /// Frames each client may be behind before it loses the oldest (the ring's length).
    pub client_queue_frames: usize,
    /// Control requests waiting for the daemon before clients get `busy`.
    pub control_queue: usize,
    /// Rate of the `timecode` field.
    pub timecode_rate: TimecodeRate,
    /// Read the timecode from the studio's LTC (fed by the daemon's LTC thread through
    /// [`Hub::timecode_clock`]) instead of the host's time of day.
    pub timecode_ltc: bool,
}

impl Default for HubConfig {
    fn default() -> Self {
        Self {
            client_queue_frames: 128,
            control_queue: 16,
            timecode_rate: TimecodeRate::default(),
            timecode_ltc: false,
        }
    }
}

/// The handle the daemon holds: cheap to clone, usable from any thread.
#[derive(Debug, Clone)]
pub struct Hub {
    pub(crate) inner: Arc<HubInner>,
}

#[derive(Debug)]
pub(crate) struct HubInner {
    pub(crate) frames: broadcast::Sender<Arc<PublishedFrame>>,
    pub(crate) status: watch::Sender<Status>,
    pub(crate) info: watch::Sender<Arc<StreamInfo>>,
    pub(crate) control: mpsc::Sender<ControlRequest>,
    pub(crate) metrics: Metrics,
    pub(crate) timecode_rate: TimecodeRate,
    /// Where frames' timecodes come from: the host's time of day or the studio's LTC.
    pub(crate) clock: Arc<crate::timecode_clock::TimecodeClock>,
    next_seq: AtomicU64,
    /// Recycled frame slots; a slot is reused once nobody else holds it.
    pool: Mutex<Vec<Arc<PublishedFrame>>>,
    pool_size: usize,
    /// Tokens set by [`Hub::set_tokens`] (a config reload); they replace the
    /// `ServerConfig`'s for new connections.
    tokens: Mutex<Option<(Option<crate::config::Token>, Option<crate::config::Token>)>>,
    /// Set when a daemon thread died: `/healthz` answers 503 with it.
    failure: Mutex<Option<String>>,
    /// The camera preview (images, demand, encoder).
    pub(crate) preview: Arc<crate::preview::PreviewShared>,
    /// Health figures, latest only.
    pub(crate) health: watch::Sender<crate::console::Health>,
    /// The daemon's OSC output counters (`/metrics`, `/healthz`).
    pub(crate) osc: Arc<crate::osc::OscCounters>,
    /// The takes the console plays back (`/take`).
    pub(crate) takes: crate::takes_http::TakeService,
    /// The daemon's audio thread counters (`/metrics`).
    pub(crate) audio: Arc<crate::audio::AudioCounters>,
    /// The daemon's NATS link (`/metrics`, `/healthz`).
    pub(crate) nats: Arc<crate::nats::NatsCounters>,
    /// Other outputs' counters shown in `/metrics`, by name.
    metrics_sources: Mutex<Vec<(&'static str, Arc<dyn crate::metrics::MetricsSource>)>>,
}

impl Hub {
    /// A hub and the daemon's end of its control queue.
    pub fn new(config: &HubConfig) -> (Hub, ControlReceiver) {
        let capacity = config.client_queue_frames.max(1);
        let (frames, _) = broadcast::channel(capacity);
        let (control, rx) = mpsc::channel(config.control_queue.max(1));
        let clock = if config.timecode_ltc {
            crate::timecode_clock::TimecodeClock::ltc(config.timecode_rate)
        } else {
            crate::timecode_clock::TimecodeClock::system(config.timecode_rate)
        };
        let status = Status {
            timecode: clock.status(),
            ..Status::default()
        };
        let hub = Hub {
            inner: Arc::new(HubInner {
                frames,
                status: watch::Sender::new(status),
                info: watch::Sender::new(Arc::new(StreamInfo::default())),
                control,
                metrics: Metrics::default(),
                timecode_rate: config.timecode_rate,
                clock: Arc::new(clock),
                next_seq: AtomicU64::new(0),
                pool: Mutex::new(Vec::new()),
                // The ring's slots plus frames in flight in client tasks.
                pool_size: capacity + 64,
                tokens: Mutex::new(None),
                failure: Mutex::new(None),
                preview: Arc::new(crate::preview::PreviewShared::new()),
                health: watch::Sender::new(crate::console::Health::default()),
                osc: Arc::default(),
                takes: Default::default(),
                audio: Arc::default(),
                nats: Arc::default(),
                metrics_sources: Mutex::new(Vec::new()),
            }),
        };
        (hub, ControlReceiver { rx })
    }

    /// Where a frame falls on the timecode grid: of its wall clock by the timecode clock (the
    /// host's time of day, or the studio's LTC), else of its stream time `t` as a time of day.
    /// The one rule for every frame's `timecode` and every output that carries one.
    pub fn frame_time(&self, frame: &StreamFrame) -> crate::timecode::FrameTime {
        let inner = &self.inner;
        match frame.wall_us {
            Some(wall) => inner.clock.frame_time_at(wall),
            None => crate::timecode::FrameTime::from_micros_of_day(
                (frame.t.max(0.0) * 1e6) as u64,
                inner.timecode_rate,
            ),
        }
    }

    /// Publishes one frame to every subscribed client and returns its `seq`.
    ///
    /// Never blocks and never waits for a client; call it from the processing thread.
    pub fn publish(&self, frame: &StreamFrame) -> u64 {
        self.publish_at(frame, self.frame_time(frame))
    }

    /// [`Hub::publish`] with the frame's place on the timecode grid already read
    /// ([`Hub::frame_time`]), so that outputs beside the hub carry the same timecode.
    pub fn publish_at(&self, frame: &StreamFrame, time: crate::timecode::FrameTime) -> u64 {
        let inner = &self.inner;
        let seq = inner.next_seq.fetch_add(1, Ordering::Relaxed);
        let timecode = time.timecode(inner.timecode_rate);
        let mut slot = self.take_slot();
        {
            // take_slot only returns slots nobody else holds.
            let published = Arc::make_mut(&mut slot);
            published.seq = seq;
            published.timecode = timecode;
            published.published_at = Some(Instant::now());
            published.frame.clone_from(frame);
            for cached in &mut published.json_cache {
                cached.take();
            }
        }
        inner.metrics.frames_in.fetch_add(1, Ordering::Relaxed);
        if let Some(p) = frame.processing {
            inner.metrics.processing.observe(p.as_secs_f64());
        }
        // No receivers is fine: nobody is subscribed.
        let _ = inner.frames.send(slot.clone());
        self.return_slot(slot);
        tracing::trace!(seq, "published frame");
        seq
    }

    fn take_slot(&self) -> Arc<PublishedFrame> {
        let mut pool = self.inner.pool.lock().unwrap_or_else(|e| e.into_inner());
        // Oldest first: the slot most likely to have been released by every client.
        if let Some(i) = pool.iter().position(|s| Arc::strong_count(s) == 1) {
            return pool.remove(i);
        }
        Arc::new(PublishedFrame::default())
    }

    fn return_slot(&self, slot: Arc<PublishedFrame>) {
        let mut pool = self.inner.pool.lock().unwrap_or_else(|e| e.into_inner());
        if pool.len() < self.inner.pool_size {
            pool.push(slot);
        }
    }

    /// Replaces the daemon status shown to clients (sent to each client on change).
    pub fn set_status(&self, status: Status) {
        self.inner.status.send_if_modified(|s| {
            let changed = *s != status;
            *s = status;
            changed
        });
    }

    /// Changes part of the status in place.
    pub fn update_status(&self, change: impl FnOnce(&mut Status)) {
        self.inner.status.send_if_modified(|s| {
            let before = s.clone();
            change(s);
            *s != before
        });
    }

    /// Marks the service failed (a thread of the daemon died): `/healthz` answers 503 with
    /// `reason` from now on.
    pub fn set_failure(&self, reason: String) {
        *self.inner.failure.lock().unwrap_or_else(|e| e.into_inner()) = Some(reason);
    }

    /// Why the service failed, if it did.
    pub fn failure(&self) -> Option<String> {
        self.inner
            .failure
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// The current status.
    pub fn status(&self) -> Status {
        self.inner.status.borrow().clone()
    }

    /// Sets the stream description; connected clients get a new `hello` when it changed.
    pub fn set_info(&self, info: StreamInfo) {
        self.inner.info.send_if_modified(|current| {
            let changed = **current != info;
            if changed {
                *current = Arc::new(info);
            }
            changed
        });
    }

    /// The current stream description.
    pub fn info(&self) -> Arc<StreamInfo> {
        self.inner.info.borrow().clone()
    }

    /// The clock frames' timecodes are read from; the daemon's LTC thread feeds it.
    pub fn timecode_clock(&self) -> Arc<crate::timecode_clock::TimecodeClock> {
        self.inner.clock.clone()
    }

    /// Frames published so far.
    pub fn frames_published(&self) -> u64 {
        self.inner.next_seq.load(Ordering::Relaxed)
    }

    /// Replaces the read and control tokens that new connections must present (the daemon's
    /// SIGHUP reload). Connected clients keep their access.
    pub fn set_tokens(
        &self,
        read: Option<crate::config::Token>,
        control: Option<crate::config::Token>,
    ) {
        *self.inner.tokens.lock().unwrap_or_else(|e| e.into_inner()) = Some((read, control));
    }

    /// The access a presented token grants: the tokens of the last [`Hub::set_tokens`], or
    /// the server configuration's.
    pub(crate) fn access_for(
        &self,
        config: &crate::config::ServerConfig,
        presented: Option<&str>,
    ) -> Option<crate::config::Access> {
        let tokens = self.inner.tokens.lock().unwrap_or_else(|e| e.into_inner());
        match &*tokens {
            Some((read, control)) => crate::config::ServerConfig {
                read_token: read.clone(),
                control_token: control.clone(),
                ..crate::config::ServerConfig::default()
            }
            .access_for(presented),
            None => config.access_for(presented),
        }
    }

    /// Clients currently connected (WebSocket sessions).
    pub fn clients(&self) -> u64 {
        self.inner.metrics.clients.load(Ordering::Relaxed)
    }

    /// Prometheus text of the server's metrics (what `/metrics` serves).
    pub fn metrics_text(&self) -> String {
        let mut text = self.inner.metrics.render();
        crate::preview::render_metrics(&self.inner.preview, &mut text);
        self.inner.osc.render_metrics(&mut text);
        self.inner.audio.render_metrics(&mut text);
        self.inner.nats.render_metrics(&mut text);
        for (_, source) in self
            .inner
            .metrics_sources
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
        {
            source.render_metrics(&mut text);
        }
        text
    }

    /// Shows (or with `None` stops showing) an output's counters in `/metrics`; `name` says
    /// which output, and a second call with the same name replaces the first (a restart).
    pub fn set_metrics_source(
        &self,
        name: &'static str,
        source: Option<Arc<dyn crate::metrics::MetricsSource>>,
    ) {
        let mut sources = self
            .inner
            .metrics_sources
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        sources.retain(|(n, _)| *n != name);
        if let Some(source) = source {
            sources.push((name, source));
        }
    }

    /// The audio thread's counters, for the daemon's audio thread to update.
    pub fn audio_counters(&self) -> Arc<crate::audio::AudioCounters> {
        self.inner.audio.clone()
    }

    /// The NATS link's counters, for the daemon's NATS task to update.
    pub fn nats(&self) -> Arc<crate::nats::NatsCounters> {
        self.inner.nats.clone()
    }

    /// A new receiver of published frames (the NATS publisher reads the ring like a
    /// client: when it falls behind it loses the oldest frames and learns how many).
    pub fn subscribe_frames(&self) -> broadcast::Receiver<Arc<PublishedFrame>> {
        self.inner.frames.subscribe()
    }

    /// A receiver of status changes.
    pub fn watch_status(&self) -> watch::Receiver<Status> {
        self.inner.status.subscribe()
    }

    /// A receiver of stream description changes (a new `hello`).
    pub fn watch_info(&self) -> watch::Receiver<Arc<StreamInfo>> {
        self.inner.info.subscribe()
    }

    /// The OSC output's counters, for the daemon's OSC sender to update.
    pub fn osc(&self) -> Arc<crate::osc::OscCounters> {
        self.inner.osc.clone()
    }

    /// Queues a control request for the daemon; the answer comes back on the returned slot.
    /// Queues a control request for the daemon without waiting; the receiver gets its
    /// answer. For transports outside this crate (the Live Link Face remote control).
    pub fn request_control(
        &self,
        command: ControlCommand,
        client: String,
    ) -> Result<oneshot::Receiver<ControlOutcome>, ControlQueueError> {
        let (reply, rx) = oneshot::channel();
        self.inner
            .control
            .try_send(ControlRequest {
                command,
                client,
                reply,
            })
            .map_err(|e| match e {
                mpsc::error::TrySendError::Full(_) => ControlQueueError::Full,
                mpsc::error::TrySendError::Closed(_) => ControlQueueError::NoDaemon,
            })?;
        Ok(rx)
    }

    /// Replaces the health figures; clients subscribed to `health` get them.
    pub fn set_health(&self, health: Health) {
        self.inner.health.send_replace(health);
    }

    /// Adds a finished take to the session's list in `status` (newest last, at most
    /// [`crate::console::MAX_LISTED_TAKES`]).
    pub fn add_take(&self, take: TakeSummary) {
        self.update_status(|s| {
            s.takes.push(take);
            let extra = s
                .takes
                .len()
                .saturating_sub(crate::console::MAX_LISTED_TAKES);
            s.takes.drain(..extra);
        });
    }

    /// Sets the last calibration shown in `status`.
    pub fn set_calibration(&self, report: CalibrationReport) {
        self.update_status(|s| s.calibration = Some(report));
    }

    /// Sets the last paint check shown in `status`.
    pub fn set_tune(&self, report: Option<TuneReport>) {
        self.update_status(|s| s.tune = report);
    }

    /// The `health` message text.
    pub(crate) fn health_json(&self) -> String {
        let health = self.inner.health.borrow().clone();
        serde_json::to_string(&crate::console::HealthMessage {
            kind: "health",
            clients: self.clients(),
            preview_clients: self.preview_clients(),
            health: &health,
        })
        .unwrap_or_default()
    }

    /// Whether a preview image of the frame at stream time `t` is wanted: some client asked
    /// for the preview and an image is due at the highest rate asked for. Cheap (one lock,
    /// no allocation); call it from the processing thread after [`Hub::publish`].
    pub fn preview_due(&self, t: f64) -> bool {
        self.inner.preview.due(t)
    }

    /// Hands a frame to the preview encoder. Never blocks: an image still waiting to be
    /// encoded is replaced by this newer one. Does nothing when no client wants the preview.
    pub fn offer_preview(&self, input: crate::preview::PreviewInput) {
        self.inner.preview.offer(input)
    }

    /// The newest preview image, if one was encoded.
    pub fn latest_preview(&self) -> Option<Arc<crate::preview::EncodedPreview>> {
        self.inner.preview.latest_image()
    }

    /// How many clients (and Foxglove image subscriptions) want the preview now.
    pub fn preview_clients(&self) -> usize {
        self.inner.preview.clients()
    }

    /// Serves the takes of `archive` at `/take` (the console's player); `None` stops.
    pub fn set_take_archive(&self, archive: Option<Arc<dyn crate::takes_http::TakeArchive>>) {
        self.inner.takes.set_archive(archive)
    }
}

/// Why a control request could not be queued.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ControlQueueError {
    /// Too many requests wait already.
    Full,
    /// No daemon takes requests.
    NoDaemon,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn publish_numbers_frames_and_recycles_slots() {
        let (hub, _control) = Hub::new(&HubConfig {
            client_queue_frames: 4,
            ..HubConfig::default()
        });
        let mut rx = hub.inner.frames.subscribe();
        let mut frame = StreamFrame {
            t: 1.0,
            ..StreamFrame::default()
        };
        for i in 0..3 {
            frame.t = f64::from(i);
            assert_eq!(hub.publish(&frame), u64::from(i as u32));
        }
        for i in 0..3u64 {
            let f = rx.try_recv().unwrap();
            assert_eq!(f.seq, i);
            assert_eq!(f.frame.t, i as f64);
        }
        drop(rx);
        // With no receiver holding them, slots come back and are reused.
        for _ in 0..100 {
            hub.publish(&frame);
        }
        assert!(hub.inner.pool.lock().unwrap().len() <= 4 + 64 + 1);
    }

    #[test]
    fn set_info_notifies_clients_only_on_change() {
        let (hub, _control) = Hub::new(&HubConfig::default());
        let mut rx = hub.inner.info.subscribe();
        rx.mark_unchanged();
        hub.set_info(StreamInfo::default());
        assert!(!rx.has_changed().unwrap());
        hub.set_info(StreamInfo {
            frame_rate: 30.0,
            ..StreamInfo::default()
        });
        assert!(rx.has_changed().unwrap());
    }

    #[test]
    fn a_lagging_receiver_loses_the_oldest_and_learns_how_many() {
        let (hub, _control) = Hub::new(&HubConfig {
            client_queue_frames: 4,
            ..HubConfig::default()
        });
        let mut rx = hub.inner.frames.subscribe();
        for _ in 0..10 {
            hub.publish(&StreamFrame::default());
        }
        assert!(matches!(
            rx.try_recv(),
            Err(broadcast::error::TryRecvError::Lagged(6))
        ));
        assert_eq!(rx.try_recv().unwrap().seq, 6);
    }
}
