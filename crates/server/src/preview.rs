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

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, Weak};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};
use tokio::sync::watch;

use crate::hub::Hub;

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
    /// Where the tracker looks while dots are missing; `None` when all are tracked.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub search: Option<PixelBox>,
}

/// What the processing thread hands over for one preview image.
pub struct PreviewInput {
    /// The frame's `seq` (as [`Hub::publish`] returned it).
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

/// The overlay JSON carried in a preview message (`type` `preview_frame`).
#[derive(Debug, Serialize)]
struct OverlayJson<'a> {
    #[serde(rename = "type")]
    kind: &'static str,
    seq: u64,
    t: f64,
    width: u32,
    height: u32,
    source_width: u32,
    source_height: u32,
    #[serde(flatten)]
    overlay: &'a Overlay,
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

impl Hub {
    /// Whether a preview image of the frame at stream time `t` is wanted: some client asked
    /// for the preview and an image is due at the highest rate asked for. Cheap (one lock,
    /// no allocation); call it from the processing thread after [`Hub::publish`].
    pub fn preview_due(&self, t: f64) -> bool {
        let shared = &self.inner.preview;
        let mut demand = lock(&shared.demand);
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
    pub fn offer_preview(&self, input: PreviewInput) {
        let shared = &self.inner.preview;
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
    pub fn latest_preview(&self) -> Option<Arc<EncodedPreview>> {
        self.inner.preview.latest.borrow().clone()
    }

    /// How many clients (and Foxglove image subscriptions) want the preview now.
    pub fn preview_clients(&self) -> usize {
        lock(&self.inner.preview.demand).requests.len()
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
    pub(crate) fn start(hub: &Hub, request: PreviewRequest) -> Self {
        let mut latest = hub.inner.preview.latest.subscribe();
        latest.mark_unchanged();
        Self {
            guard: register(&hub.inner.preview, request),
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

/// Integer factor the image is shrunk by so that it is at most `max_width` wide.
pub fn downscale_factor(width: u32, max_width: u32) -> u32 {
    width.div_ceil(max_width.max(1)).max(1)
}

/// Shrinks a packed BGR image by an integer `factor`, each output pixel the mean of a
/// `factor` × `factor` block (a box filter: no aliasing of the fine paint dots into moiré).
/// Returns the new width, height and bytes.
pub fn downscale_bgr(image: &dyn BgrImage, factor: u32) -> (u32, u32, Vec<u8>) {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let f = factor.max(1) as usize;
    let (ow, oh) = ((w / f).max(1), (h / f).max(1));
    let src = image.bgr();
    if f == 1 {
        return (w as u32, h as u32, src[..w * h * 3].to_vec());
    }
    let mut out = vec![0u8; ow * oh * 3];
    let mut sums = vec![0u32; ow * 3];
    let n = (f * f) as u32;
    for oy in 0..oh {
        sums.iter_mut().for_each(|s| *s = 0);
        for y in oy * f..(oy * f + f).min(h) {
            let row = &src[y * w * 3..(y + 1) * w * 3];
            for (ox, sum) in sums.chunks_exact_mut(3).enumerate() {
                for px in row[ox * f * 3..(ox * f + f) * 3].chunks_exact(3) {
                    sum[0] += u32::from(px[0]);
                    sum[1] += u32::from(px[1]);
                    sum[2] += u32::from(px[2]);
                }
            }
        }
        let line = &mut out[oy * ow * 3..(oy + 1) * ow * 3];
        for (o, s) in line.iter_mut().zip(&sums) {
            *o = ((s + n / 2) / n) as u8;
        }
    }
    (ow as u32, oh as u32, out)
}

/// Why an image could not be encoded.
#[derive(Debug, thiserror::Error)]
pub enum PreviewError {
    /// The image's bytes do not match its size.
    #[error("preview image is {width}x{height} but has {bytes} bytes (expected {expected})")]
    BadImage {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
        /// Bytes given.
        bytes: usize,
        /// Bytes needed.
        expected: usize,
    },
    /// The JPEG encoder failed.
    #[error("JPEG encoding failed")]
    Jpeg(#[source] jpeg_encoder::EncodingError),
}

/// Downscales and encodes one preview image and builds its binary message.
pub fn encode(
    input: &PreviewInput,
    max_width: u32,
    quality: u8,
) -> Result<EncodedPreview, PreviewError> {
    let image = &*input.image;
    let (sw, sh) = (image.width(), image.height());
    let expected = sw as usize * sh as usize * 3;
    if image.bgr().len() < expected || sw == 0 || sh == 0 || sw > 16384 || sh > 16384 {
        return Err(PreviewError::BadImage {
            width: sw,
            height: sh,
            bytes: image.bgr().len(),
            expected,
        });
    }
    let factor = downscale_factor(sw, max_width.min(sw));
    let (w, h, pixels) = downscale_bgr(image, factor);
    let mut jpeg = Vec::with_capacity(pixels.len() / 8);
    let encoder = jpeg_encoder::Encoder::new(&mut jpeg, quality.clamp(1, 100));
    encoder
        .encode(&pixels, w as u16, h as u16, jpeg_encoder::ColorType::Bgr)
        .map_err(PreviewError::Jpeg)?;
    let mut encoded = EncodedPreview {
        seq: input.seq,
        t: input.t,
        capture_us: input.capture_us,
        wall_us: input.wall_us,
        width: w,
        height: h,
        source_width: sw,
        source_height: sh,
        jpeg,
        overlay: input.overlay.clone(),
        message: Default::default(),
    };
    encoded.message = encode_preview_message(&encoded).into();
    Ok(encoded)
}

/// The overlay JSON of a preview message.
pub fn overlay_json(p: &EncodedPreview) -> String {
    serde_json::to_string(&OverlayJson {
        kind: "preview_frame",
        seq: p.seq,
        t: p.t,
        width: p.width,
        height: p.height,
        source_width: p.source_width,
        source_height: p.source_height,
        overlay: &p.overlay,
    })
    .unwrap_or_default()
}

/// The binary preview message (layout in `docs/protocol.md`): a 56-byte header, the
/// overlay JSON, the JPEG.
pub fn encode_preview_message(p: &EncodedPreview) -> Vec<u8> {
    let json = overlay_json(p);
    let mut out = Vec::with_capacity(PREVIEW_HEADER_LEN + json.len() + p.jpeg.len());
    out.extend_from_slice(PREVIEW_MAGIC);
    out.extend_from_slice(&PREVIEW_VERSION.to_le_bytes());
    let flags: u16 = if p.wall_us.is_some() { 1 } else { 0 };
    out.extend_from_slice(&flags.to_le_bytes());
    out.extend_from_slice(&p.seq.to_le_bytes());
    out.extend_from_slice(&p.t.to_le_bytes());
    out.extend_from_slice(&p.capture_us.to_le_bytes());
    out.extend_from_slice(&p.wall_us.unwrap_or(0).to_le_bytes());
    for v in [p.width, p.height, p.source_width, p.source_height] {
        out.extend_from_slice(&(v.min(u32::from(u16::MAX)) as u16).to_le_bytes());
    }
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(&(p.jpeg.len() as u32).to_le_bytes());
    debug_assert_eq!(out.len(), PREVIEW_HEADER_LEN);
    out.extend_from_slice(json.as_bytes());
    out.extend_from_slice(&p.jpeg);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gradient(w: u32, h: u32) -> OwnedBgr {
        let mut data = Vec::with_capacity((w * h * 3) as usize);
        for y in 0..h {
            for x in 0..w {
                data.extend_from_slice(&[(x % 256) as u8, (y % 256) as u8, 128]);
            }
        }
        OwnedBgr {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn box_filter_averages_blocks() {
        let img = OwnedBgr {
            width: 4,
            height: 2,
            data: vec![
                0, 0, 0, 10, 10, 10, 100, 0, 0, 100, 0, 0, //
                20, 20, 20, 30, 30, 30, 100, 0, 0, 100, 0, 4,
            ],
        };
        let (w, h, px) = downscale_bgr(&img, 2);
        assert_eq!((w, h), (2, 1));
        assert_eq!(px, vec![15, 15, 15, 100, 0, 1]);
        assert_eq!(downscale_factor(640, 480), 2);
        assert_eq!(downscale_factor(640, 640), 1);
        assert_eq!(downscale_factor(640, 200), 4);
    }

    #[test]
    fn encoded_message_follows_the_layout_and_decodes() {
        let input = PreviewInput {
            seq: 42,
            t: 1.5,
            capture_us: 1_500_000,
            wall_us: Some(1_700_000_000_000_000),
            image: Arc::new(gradient(640, 480)),
            overlay: Overlay {
                dots: vec![ImageDot {
                    name: "D1".into(),
                    x: 300.0,
                    y: 200.0,
                    state: DotState::Tracked,
                }],
                search: None,
            },
        };
        let p = encode(&input, 320, 70).unwrap();
        assert_eq!((p.width, p.height), (320, 240));
        let m = &p.message[..];
        assert_eq!(&m[0..4], b"MPP1");
        assert_eq!(u16::from_le_bytes([m[4], m[5]]), 1);
        assert_eq!(u16::from_le_bytes([m[6], m[7]]), 1);
        assert_eq!(u64::from_le_bytes(m[8..16].try_into().unwrap()), 42);
        assert_eq!(f64::from_le_bytes(m[16..24].try_into().unwrap()), 1.5);
        assert_eq!(u16::from_le_bytes([m[40], m[41]]), 320);
        assert_eq!(u16::from_le_bytes([m[44], m[45]]), 640);
        let json_len = u32::from_le_bytes(m[48..52].try_into().unwrap()) as usize;
        let jpeg_len = u32::from_le_bytes(m[52..56].try_into().unwrap()) as usize;
        assert_eq!(m.len(), 56 + json_len + jpeg_len);
        let overlay: serde_json::Value = serde_json::from_slice(&m[56..56 + json_len]).unwrap();
        assert_eq!(overlay["type"], "preview_frame");
        assert_eq!(overlay["dots"][0]["name"], "D1");
        assert_eq!(overlay["dots"][0]["state"], "tracked");
        let jpeg = &m[56 + json_len..];
        assert_eq!(&jpeg[..2], &[0xFF, 0xD8], "a JPEG file");
        let mut decoder = jpeg_decoder::Decoder::new(jpeg);
        let pixels = decoder.decode().unwrap();
        let info = decoder.info().unwrap();
        assert_eq!((info.width, info.height), (320, 240));
        // The gradient survives: blue (x) grows to the right, green (y) down (RGB out).
        let at = |x: usize, y: usize| &pixels[(y * 320 + x) * 3..(y * 320 + x) * 3 + 3];
        assert!(at(100, 10)[2] > at(10, 10)[2] + 100, "{:?}", at(100, 10));
        assert!(at(10, 100)[1] > at(10, 10)[1] + 100);
    }

    #[test]
    fn a_bad_image_is_refused() {
        let input = PreviewInput {
            seq: 0,
            t: 0.0,
            capture_us: 0,
            wall_us: None,
            image: Arc::new(OwnedBgr {
                width: 10,
                height: 10,
                data: vec![0; 20],
            }),
            overlay: Overlay::default(),
        };
        assert!(matches!(
            encode(&input, 320, 70),
            Err(PreviewError::BadImage { .. })
        ));
    }

    #[test]
    fn requests_are_checked_and_combined() {
        assert!(PreviewRequest::new(Some(0.0), None).is_err());
        assert!(PreviewRequest::new(Some(30.0), None).is_err());
        assert!(PreviewRequest::new(None, Some(10)).is_err());
        let shared = Arc::new(PreviewShared::new());
        let a = register(&shared, PreviewRequest::new(Some(2.0), Some(200)).unwrap());
        let b = register(&shared, PreviewRequest::new(Some(5.0), Some(100)).unwrap());
        let both = lock(&shared.demand).combined().unwrap();
        assert_eq!((both.max_rate, both.max_width), (5.0, 200));
        drop(b);
        let one = lock(&shared.demand).combined().unwrap();
        assert_eq!((one.max_rate, one.max_width), (2.0, 200));
        drop(a);
        assert!(lock(&shared.demand).combined().is_none());
    }

    #[test]
    fn images_are_due_at_the_highest_rate_asked_for_and_only_when_asked() {
        let (hub, _control) = Hub::new(&crate::HubConfig::default());
        assert!(!hub.preview_due(0.0), "nobody asked");
        let _guard = register(
            &hub.inner.preview,
            PreviewRequest::new(Some(10.0), None).unwrap(),
        );
        let due = (0..60)
            .filter(|i| hub.preview_due(f64::from(*i) / 60.0))
            .count();
        assert_eq!(due, 10, "one second at 60 fps, 10 images asked for");
        let mut gate = RateGate::new(5.0);
        let sent = (0..60).filter(|i| gate.admit(f64::from(*i) / 60.0)).count();
        assert_eq!(sent, 5);
        assert!(gate.admit(0.0), "a replay that loops starts over");
    }

    #[test]
    fn offers_reach_the_latest_cell_and_newer_ones_replace_waiting_ones() {
        let (hub, _control) = Hub::new(&crate::HubConfig::default());
        let image: Arc<dyn BgrImage> = Arc::new(gradient(64, 48));
        let offer = |seq| PreviewInput {
            seq,
            t: seq as f64,
            capture_us: 0,
            wall_us: None,
            image: image.clone(),
            overlay: Overlay::default(),
        };
        hub.offer_preview(offer(1));
        assert!(hub.latest_preview().is_none(), "nobody asked: not encoded");
        let _guard = register(&hub.inner.preview, PreviewRequest::default());
        for seq in 2..50 {
            hub.offer_preview(offer(seq));
        }
        let deadline = Instant::now() + Duration::from_secs(10);
        while hub.latest_preview().map(|p| p.seq) != Some(49) {
            assert!(Instant::now() < deadline, "the newest offer gets encoded");
            std::thread::sleep(Duration::from_millis(5));
        }
        let c = &hub.inner.preview.counters;
        assert_eq!(
            c.encoded.load(Ordering::Relaxed) + c.replaced.load(Ordering::Relaxed),
            48,
            "every offer was either encoded or replaced by a newer one"
        );
    }
}
