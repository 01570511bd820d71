//! The camera preview: an opt-in, lossy, bounded stream of downscaled JPEG images with the
//! tracked dots of the same frame, for the booth console page and Foxglove's image panel.
//!
//! Data path, from the processing thread to a client:
//!
//! ```text
//! processing thread ── Hub::preview_due(t)? ──► Hub::offer_preview(input)   (never blocks)
//!        input slot (capacity 1, newest wins; a frame still waiting is replaced, counted)
//!   preview encoder thread: downscale (box filter) + JPEG + binary message, once per image
//!        latest-image cell (tokio watch: latest value only)
//!   each client's writer: at most its own `max_rate`; only ever the newest image
//! ```
//!
//! Nothing here can slow the frame stream: the processing thread only copies a pointer to
//! the frame (and the overlay) into the slot when an image is due at the highest rate any
//! client asked for; the encoding runs on a thread of its own; clients read the latest
//! image, so a slow one skips images rather than queueing them. Without a client asking,
//! nothing is encoded.

mod encoding;

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, Weak};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};
use tokio::sync::watch;

pub use encoding::{
    downscale_bgr, downscale_factor, encode, encode_preview_message, overlay_json, PreviewError,
};

/// Magic bytes of a binary preview message.
pub const PREVIEW_MAGIC: &[u8; 4] = b"MPP1";
/// Version of the preview message layout.
pub const PREVIEW_VERSION: u16 = 1;
/// Size of the fixed preview header, before the overlay JSON.
pub const PREVIEW_HEADER_LEN: usize = 56;
/// Highest image rate a client may ask for, images per second.
pub const MAX_PREVIEW_RATE: f64 = 15.0;
/// Widest image a client may ask for, pixels (never wider than the camera's).
pub const MAX_PREVIEW_WIDTH: u32 = 1280;
/// Narrowest image a client may ask for, pixels.
pub const MIN_PREVIEW_WIDTH: u32 = 64;
/// Rate when the client does not say, images per second.
pub const DEFAULT_PREVIEW_RATE: f64 = 10.0;
/// Width when the client does not say, pixels.
pub const DEFAULT_PREVIEW_WIDTH: u32 = 480;
/// JPEG quality of preview images (1–100).
pub const PREVIEW_JPEG_QUALITY: u8 = 70;

/// A colour image the preview can encode: packed 8-bit BGR rows, no padding.
pub trait BgrImage: Send + Sync {
    /// Width, pixels.
    fn width(&self) -> u32;
    /// Height, pixels.
    fn height(&self) -> u32;
    /// `width * height * 3` bytes, row after row, blue first.
    fn bgr(&self) -> &[u8];
}

/// A plain owned BGR image (tests, synthetic streams).
#[derive(Debug, Clone, PartialEq)]
pub struct OwnedBgr {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Packed BGR bytes.
    pub data: Vec<u8>,
}

impl BgrImage for OwnedBgr {
    fn width(&self) -> u32 {
        self.width
    }
    fn height(&self) -> u32 {
        self.height
    }
    fn bgr(&self) -> &[u8] {
        &self.data
    }
}

/// How a dot was placed in this frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DotState {
    /// Found in this frame's image.
    Tracked,
    /// Not found: where the tracker carries it (its last place in the head's frame, moved
    /// with the head), which is what the stream sends for it.
    Predicted,
    /// Not found and nothing to carry it by (no neutral pose yet): its last place seen.
    Lost,
}

/// One dot on the image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ImageDot {
    /// `D1`..`D12`, `F1`..`F3`.
    pub name: String,
    /// Pixel centre in the camera's colour image (not the downscaled preview), x right.
    pub x: f32,
    /// Pixel centre, y down.
    pub y: f32,
    /// How it was placed.
    pub state: DotState,
}

/// A rectangle of the camera's colour image, pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PixelBox {
    /// Left edge.
    pub x: f32,
    /// Top edge.
    pub y: f32,
    /// Width.
    pub width: f32,
    /// Height.
    pub height: f32,
}

/// What is drawn over the image: the dots and, while some are lost, where they are looked for.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Overlay {
    /// Every dot with a place (seen, predicted or last seen).
    pub dots: Vec<ImageDot>,
    /// Where the tracker looks while dots are missing (the box round the forehead's dots and
    /// the one round the lips', or one box round all); empty when all are tracked.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub search: Vec<PixelBox>,
}

/// What the processing thread hands over for one preview image.
pub struct PreviewInput {
    /// The frame's `seq` (as [`crate::Hub::publish`] returned it).
    pub seq: u64,
    /// The frame's `t`.
    pub t: f64,
    /// The frame's `capture_us`.
    pub capture_us: u64,
    /// The frame's `wall_us`.
    pub wall_us: Option<i64>,
    /// The camera's colour image.
    pub image: Arc<dyn BgrImage>,
    /// Dots of the same frame.
    pub overlay: Overlay,
}

impl std::fmt::Debug for PreviewInput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PreviewInput")
            .field("seq", &self.seq)
            .field("width", &self.image.width())
            .field("height", &self.image.height())
            .finish_non_exhaustive()
    }
}

/// One encoded preview image, shared by every client that sends it.
#[derive(Debug, Clone)]
pub struct EncodedPreview {
    /// The frame's `seq`.
    pub seq: u64,
    /// The frame's `t`.
    pub t: f64,
    /// The frame's `capture_us`.
    pub capture_us: u64,
    /// The frame's `wall_us`.
    pub wall_us: Option<i64>,
    /// JPEG size, pixels.
    pub width: u32,
    /// JPEG size, pixels.
    pub height: u32,
    /// Camera image size the overlay's pixels refer to.
    pub source_width: u32,
    /// Camera image size the overlay's pixels refer to.
    pub source_height: u32,
    /// The JPEG file.
    pub jpeg: Vec<u8>,
    /// The overlay.
    pub overlay: Overlay,
    /// The whole binary WebSocket message (layout in `docs/protocol.md`).
    pub message: tokio_tungstenite::tungstenite::Bytes,
}

/// What one client asked for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PreviewRequest {
    /// Images per second, in (0, [`MAX_PREVIEW_RATE`]].
    pub max_rate: f64,
    /// Widest image, pixels, in [[`MIN_PREVIEW_WIDTH`], [`MAX_PREVIEW_WIDTH`]].
    pub max_width: u32,
}

impl Default for PreviewRequest {
    fn default() -> Self {
        Self {
            max_rate: DEFAULT_PREVIEW_RATE,
            max_width: DEFAULT_PREVIEW_WIDTH,
        }
    }
}

impl PreviewRequest {
    /// Checks a client's values; the message names what was wrong.
    pub fn new(max_rate: Option<f64>, max_width: Option<u32>) -> Result<Self, String> {
        let d = Self::default();
        let max_rate = max_rate.unwrap_or(d.max_rate);
        if !(max_rate.is_finite() && max_rate > 0.0 && max_rate <= MAX_PREVIEW_RATE) {
            return Err(format!(
                "preview: max_rate must be in (0, {MAX_PREVIEW_RATE}] images per second, got {max_rate}"
            ));
        }
        let max_width = max_width.unwrap_or(d.max_width);
        if !(MIN_PREVIEW_WIDTH..=MAX_PREVIEW_WIDTH).contains(&max_width) {
            return Err(format!(
                "preview: max_width must be {MIN_PREVIEW_WIDTH}..={MAX_PREVIEW_WIDTH} pixels, got {max_width}"
            ));
        }
        Ok(Self {
            max_rate,
            max_width,
        })
    }
}

/// Counters for `/metrics`.
#[derive(Debug, Default)]
pub(crate) struct PreviewCounters {
    /// Images encoded.
    pub(crate) encoded: AtomicU64,
    /// Inputs replaced in the slot before the encoder took them.
    pub(crate) replaced: AtomicU64,
    /// Images written to clients.
    pub(crate) sent: AtomicU64,
    /// Bytes of the last image.
    pub(crate) last_bytes: AtomicU64,
}

/// The preview's shared state, held by the hub.
#[derive(Debug)]
pub(crate) struct PreviewShared {
    /// Client requests by registration id.
    demand: Mutex<Demand>,
    /// The input slot (capacity one) and the encoder thread's wake-up.
    input: Mutex<InputSlot>,
    ready: Condvar,
    /// The newest image.
    pub(crate) latest: watch::Sender<Option<Arc<EncodedPreview>>>,
    pub(crate) counters: PreviewCounters,
    /// Encoding time per image.
    pub(crate) encode_time: crate::metrics::Histogram,
}

#[derive(Debug, Default)]
struct Demand {
    next_id: u64,
    requests: Vec<(u64, PreviewRequest)>,
    /// Stream time the next image is due at the highest requested rate.
    next_due: Option<f64>,
}

impl Demand {
    fn combined(&self) -> Option<PreviewRequest> {
        self.requests
            .iter()
            .map(|(_, r)| *r)
            .reduce(|a, b| PreviewRequest {
                max_rate: a.max_rate.max(b.max_rate),
                max_width: a.max_width.max(b.max_width),
            })
    }
}

#[derive(Debug, Default)]
struct InputSlot {
    pending: Option<(PreviewInput, PreviewRequest)>,
    encoder_running: bool,
}

impl PreviewShared {
    pub(crate) fn new() -> Self {
        Self {
            demand: Mutex::new(Demand::default()),
            input: Mutex::new(InputSlot::default()),
            ready: Condvar::new(),
            latest: watch::Sender::new(None),
            counters: PreviewCounters::default(),
            encode_time: crate::metrics::Histogram::default(),
        }
    }
}

/// A client's registered request; dropping it withdraws the request.
#[derive(Debug)]
pub(crate) struct DemandGuard {
    shared: Weak<PreviewShared>,
    id: u64,
}

impl DemandGuard {
    /// Replaces this client's request.
    pub(crate) fn update(&self, request: PreviewRequest) {
        if let Some(shared) = self.shared.upgrade() {
            let mut demand = lock(&shared.demand);
            if let Some(slot) = demand.requests.iter_mut().find(|(id, _)| *id == self.id) {
                slot.1 = request;
            }
        }
    }
}

impl Drop for DemandGuard {
    fn drop(&mut self) {
        if let Some(shared) = self.shared.upgrade() {
            lock(&shared.demand)
                .requests
                .retain(|(id, _)| *id != self.id);
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Registers a client's request (also used by the Foxglove image channel).
pub(crate) fn register(shared: &Arc<PreviewShared>, request: PreviewRequest) -> DemandGuard {
    let mut demand = lock(&shared.demand);
    demand.next_id += 1;
    let id = demand.next_id;
    demand.requests.push((id, request));
    DemandGuard {
        shared: Arc::downgrade(shared),
        id,
    }
}

/// Skips images so that a client gets at most `max_rate` per second of stream time.
#[derive(Debug, Clone)]
pub(crate) struct RateGate {
    period: f64,
    next_due: Option<f64>,
}

impl RateGate {
    pub(crate) fn new(max_rate: f64) -> Self {
        Self {
            period: 1.0 / max_rate,
            next_due: None,
        }
    }

    /// Whether an image of stream time `t` may go out now.
    pub(crate) fn admit(&mut self, t: f64) -> bool {
        // A millisecond of slack absorbs timestamp jitter at the nominal rate.
        const SLACK: f64 = 0.001;
        match self.next_due {
            // Time jumped back (a replay looped) by more than a period: start over.
            Some(due) if t + SLACK < due && due - t <= self.period + SLACK => false,
            Some(due) if t + SLACK >= due && t - due < self.period => {
                self.next_due = Some(due + self.period);
                true
            }
            _ => {
                self.next_due = Some(t + self.period);
                true
            }
        }
    }
}

impl PreviewShared {
    /// Whether a preview image of the frame at stream time `t` is wanted: some client asked
    /// for the preview and an image is due at the highest rate asked for. Cheap (one lock,
    /// no allocation); call it from the processing thread after [`crate::Hub::publish`].
    pub(crate) fn due(&self, t: f64) -> bool {
        let mut demand = lock(&self.demand);
        let Some(request) = demand.combined() else {
            demand.next_due = None;
            return false;
        };
        let period = 1.0 / request.max_rate;
        match demand.next_due {
            // Not yet due, unless time went back (a replay looped).
            Some(due) if t < due && due - t <= period => false,
            Some(due) if t >= due && t - due < period => {
                demand.next_due = Some(due + period);
                true
            }
            _ => {
                demand.next_due = Some(t + period);
                true
            }
        }
    }

    /// Hands a frame to the preview encoder. Never blocks: an image still waiting to be
    /// encoded is replaced by this newer one. Does nothing when no client wants the preview.
    pub(crate) fn offer(self: &Arc<Self>, input: PreviewInput) {
        let shared = self;
        let Some(request) = lock(&shared.demand).combined() else {
            return;
        };
        let mut slot = lock(&shared.input);
        if slot.pending.replace((input, request)).is_some() {
            shared.counters.replaced.fetch_add(1, Ordering::Relaxed);
        }
        if !slot.encoder_running {
            slot.encoder_running = true;
            let weak = Arc::downgrade(shared);
            let spawned = std::thread::Builder::new()
                .name("mouthpiece-preview".into())
                .spawn(move || encoder_loop(weak));
            if let Err(e) = spawned {
                slot.encoder_running = false;
                slot.pending = None;
                tracing::warn!("cannot start the preview encoder thread: {e}");
                return;
            }
        }
        drop(slot);
        shared.ready.notify_one();
    }

    /// The newest preview image, if one was encoded.
    pub(crate) fn latest_image(&self) -> Option<Arc<EncodedPreview>> {
        self.latest.borrow().clone()
    }

    /// How many clients (and Foxglove image subscriptions) want the preview now.
    pub(crate) fn clients(&self) -> usize {
        lock(&self.demand).requests.len()
    }
}

/// The encoder thread: waits for input, encodes, publishes. Ends when the hub is gone or
/// after a minute without input (started again on the next offer).
fn encoder_loop(shared: Weak<PreviewShared>) {
    const IDLE_EXIT: Duration = Duration::from_secs(60);
    let mut idle_since = Instant::now();
    loop {
        let Some(strong) = shared.upgrade() else {
            return;
        };
        let taken = {
            let mut slot = lock(&strong.input);
            if slot.pending.is_none() {
                let (guard, _) = strong
                    .ready
                    .wait_timeout(slot, Duration::from_millis(200))
                    .unwrap_or_else(|e| e.into_inner());
                slot = guard;
            }
            let taken = slot.pending.take();
            if taken.is_none() && idle_since.elapsed() > IDLE_EXIT {
                slot.encoder_running = false;
                return;
            }
            taken
        };
        let Some((input, request)) = taken else {
            continue;
        };
        idle_since = Instant::now();
        let started = Instant::now();
        match encode(&input, request.max_width, PREVIEW_JPEG_QUALITY) {
            Ok(encoded) => {
                strong.encode_time.observe(started.elapsed().as_secs_f64());
                strong.counters.encoded.fetch_add(1, Ordering::Relaxed);
                strong
                    .counters
                    .last_bytes
                    .store(encoded.message.len() as u64, Ordering::Relaxed);
                strong.latest.send_replace(Some(Arc::new(encoded)));
            }
            Err(e) => tracing::warn!(seq = input.seq, "preview image not encoded: {e}"),
        }
    }
}

/// One client's preview: its registered request, its rate and its view of the latest image.
#[derive(Debug)]
pub(crate) struct ClientPreview {
    guard: DemandGuard,
    gate: RateGate,
    latest: watch::Receiver<Option<Arc<EncodedPreview>>>,
    pub(crate) request: PreviewRequest,
}

impl ClientPreview {
    /// Registers `request` with the hub's preview.
    pub(crate) fn start(preview: &Arc<PreviewShared>, request: PreviewRequest) -> Self {
        let mut latest = preview.latest.subscribe();
        latest.mark_unchanged();
        Self {
            guard: register(preview, request),
            gate: RateGate::new(request.max_rate),
            latest,
            request,
        }
    }

    /// Changes the request in place.
    pub(crate) fn change(&mut self, request: PreviewRequest) {
        self.guard.update(request);
        self.gate = RateGate::new(request.max_rate);
        self.request = request;
    }

    /// The next image this client may receive: newer than the last one seen and within its
    /// rate (images in between are skipped).
    pub(crate) async fn next(&mut self) -> Arc<EncodedPreview> {
        loop {
            if self.latest.changed().await.is_err() {
                return std::future::pending().await;
            }
            let image = self.latest.borrow_and_update().clone();
            if let Some(image) = image {
                if self.gate.admit(image.t) {
                    return image;
                }
            }
        }
    }
}

/// [`ClientPreview::next`] when there is a preview, else never.
pub(crate) async fn next_image(preview: &mut Option<ClientPreview>) -> Arc<EncodedPreview> {
    match preview {
        Some(p) => p.next().await,
        None => std::future::pending().await,
    }
}

/// Appends the preview's figures to the `/metrics` text.
pub(crate) fn render_metrics(shared: &PreviewShared, out: &mut String) {
    use std::fmt::Write as _;
    let c = &shared.counters;
    for (name, help, value, kind) in [
        (
            "mouthpiece_preview_images_encoded_total",
            "Preview images encoded.",
            c.encoded.load(Ordering::Relaxed),
            "counter",
        ),
        (
            "mouthpiece_preview_images_replaced_total",
            "Preview frames replaced by a newer one before the encoder took them.",
            c.replaced.load(Ordering::Relaxed),
            "counter",
        ),
        (
            "mouthpiece_preview_images_sent_total",
            "Preview images written to clients.",
            c.sent.load(Ordering::Relaxed),
            "counter",
        ),
        (
            "mouthpiece_preview_image_bytes",
            "Size of the last preview message, bytes.",
            c.last_bytes.load(Ordering::Relaxed),
            "gauge",
        ),
        (
            "mouthpiece_preview_clients",
            "Clients (and Foxglove image subscriptions) receiving the preview.",
            lock(&shared.demand).requests.len() as u64,
            "gauge",
        ),
    ] {
        let _ = writeln!(
            out,
            "# HELP {name} {help}\n# TYPE {name} {kind}\n{name} {value}"
        );
    }
    shared.encode_time.render(
        out,
        "mouthpiece_preview_encode_seconds",
        "Downscale and JPEG encoding time per preview image.",
    );
}

#[cfg(test)]
mod tests;
