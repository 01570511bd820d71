//! V4L2 cameras (`v4l2:COLOUR_NODE[+DEPTH_NODE]`) through the `v4l` crate: a colour node in
//! YUYV, MJPG, RGB3 or BGR3 and an optional depth node in Z16, paired by buffer timestamp.
//!
//! Threads: one capture thread per node owns its `v4l` device and mmap stream (2–4 buffers),
//! copies each dequeued buffer with its timestamp into a bounded channel of 2 that drops the
//! oldest (live: the newest frame wins). Conversion (MJPG decoding included) happens in
//! `next_frame`, on the consumer's thread, only for the pair handed out.
//!
//! V4L2 reports no intrinsics: they come from the configuration (a 58°x45° field of view is
//! assumed, with a warning, when the configuration has none).

use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime};

use crossbeam_channel::{bounded, Receiver, RecvTimeoutError, Sender, TrySendError};
use mouthpiece_frame::{
    Calibration, ColorImage, DepthImage, Extrinsics, Frame, FrameSource, Intrinsics, SourceError,
    SourceInfo,
};
use v4l::buffer::Type;
use v4l::io::traits::CaptureStream;
use v4l::prelude::*;
use v4l::video::Capture;
use v4l::{Format, FourCC};

use crate::convert::{self, ColorFormat};
use crate::devices::{V4l2Format, V4l2Node, DEPTH_FOURCCS};
use crate::pairing::{Pairer, Stamped};
use crate::{
    format_error, lost_error, open_error, open_error_with, registration, CaptureConfig,
    DEFAULT_FOV_RAD,
};

/// How long one dequeue may block before the capture thread checks its stop flag.
const DEQUEUE_TIMEOUT: Duration = Duration::from_millis(500);

/// The colour FourCCs we convert, in order of preference.
const COLOR_FOURCCS: [(&[u8; 4], ColorFormat); 4] = [
    (b"YUYV", ColorFormat::Yuyv),
    (b"MJPG", ColorFormat::Mjpg),
    (b"RGB3", ColorFormat::Rgb24),
    (b"BGR3", ColorFormat::Bgr24),
];

/// `/dev/video*` nodes, in numeric order.
pub fn video_nodes() -> Vec<PathBuf> {
    let mut nodes: Vec<(u32, PathBuf)> = std::fs::read_dir("/dev")
        .map(|dir| {
            dir.filter_map(Result::ok)
                .filter_map(|e| {
                    let name = e.file_name().to_string_lossy().into_owned();
                    let n = name.strip_prefix("video")?.parse().ok()?;
                    Some((n, e.path()))
                })
                .collect()
        })
        .unwrap_or_default();
    nodes.sort();
    nodes.into_iter().map(|(_, p)| p).collect()
}

/// Card, driver, formats and sizes of one node.
pub fn describe_node(path: &Path) -> V4l2Node {
    let mut node = V4l2Node {
        path: path.to_path_buf(),
        card: String::new(),
        driver: String::new(),
        formats: Vec::new(),
        looks_like_depth: false,
        error: None,
    };
    let dev = match Device::with_path(path) {
        Ok(d) => d,
        Err(e) => {
            node.error = Some(explain_open_error(&e));
            return node;
        }
    };
    match dev.query_caps() {
        Ok(caps) => {
            node.card = caps.card;
            node.driver = caps.driver;
        }
        Err(e) => node.error = Some(format!("cannot query capabilities: {e}")),
    }
    for desc in dev.enum_formats().unwrap_or_default() {
        let fourcc = fourcc_string(desc.fourcc);
        let mut sizes: Vec<(u32, u32)> = dev
            .enum_framesizes(desc.fourcc)
            .unwrap_or_default()
            .into_iter()
            .flat_map(|fs| fs.size.to_discrete())
            .map(|d| (d.width, d.height))
            .collect();
        sizes.dedup();
        node.looks_like_depth |= DEPTH_FOURCCS.contains(&fourcc.as_str());
        node.formats.push(V4l2Format {
            fourcc,
            description: desc.description,
            sizes,
        });
    }
    node
}

fn fourcc_string(f: FourCC) -> String {
    f.str()
        .map(str::to_string)
        .unwrap_or_else(|_| format!("{:?}", f.repr))
}

fn explain_open_error(e: &io::Error) -> String {
    match e.raw_os_error() {
        Some(2) => "no such device node".into(),
        Some(13) => "permission denied (is the user in the video group?)".into(),
        Some(16) => "device busy (in use by another process)".into(),
        Some(19) => "no such device (unplugged?)".into(),
        _ => e.to_string(),
    }
}

/// One dequeued buffer, copied.
struct RawFrame {
    data: Vec<u8>,
    ts_us: u64,
    host_rx: Instant,
}

impl Stamped for RawFrame {
    fn ts_us(&self) -> u64 {
        self.ts_us
    }
}

enum NodeEvent {
    Frame(RawFrame),
    Lost(String),
}

/// A node's capture thread.
struct NodeThread {
    stop: Arc<AtomicBool>,
    rx: Receiver<NodeEvent>,
    dropped: Arc<AtomicU64>,
    handle: Option<JoinHandle<()>>,
}

impl Drop for NodeThread {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            // Dequeues time out after DEQUEUE_TIMEOUT, so the thread notices the flag soon.
            let _ = h.join();
        }
    }
}

struct Negotiated {
    device: Device,
    width: u32,
    height: u32,
    fourcc: FourCC,
    fps: f64,
}

/// Opens a node and sets the closest format among `wanted` (in preference order).
fn negotiate(
    spec: &str,
    path: &Path,
    wanted: &[&[u8; 4]],
    config: &CaptureConfig,
) -> Result<Negotiated, SourceError> {
    let device = Device::with_path(path).map_err(|e| {
        open_error_with(
            spec,
            format!("cannot open {}: {}", path.display(), explain_open_error(&e)),
            e,
        )
    })?;
    let formats = device.enum_formats().map_err(|e| {
        open_error_with(
            spec,
            format!("{} is not a capture device", path.display()),
            e,
        )
    })?;
    let offered: Vec<FourCC> = formats.iter().map(|f| f.fourcc).collect();
    let Some(&fourcc) = wanted
        .iter()
        .map(|w| FourCC::new(w))
        .collect::<Vec<_>>()
        .iter()
        .find(|f| offered.contains(f))
    else {
        let offered: Vec<String> = offered.iter().map(|f| fourcc_string(*f)).collect();
        let wanted: Vec<String> = wanted
            .iter()
            .map(|w| String::from_utf8_lossy(&w[..]).trim().to_string())
            .collect();
        return Err(format_error(
            spec,
            format!(
                "{} offers no supported pixel format: it has [{}], mouthpiece reads [{}]",
                path.display(),
                offered.join(", "),
                wanted.join(", ")
            ),
        ));
    };
    let sizes: Vec<(u32, u32)> = device
        .enum_framesizes(fourcc)
        .unwrap_or_default()
        .into_iter()
        .flat_map(|fs| fs.size.to_discrete())
        .map(|d| (d.width, d.height))
        .collect();
    let (w, h) = sizes
        .iter()
        .copied()
        .min_by_key(|&(w, h)| {
            (w as i64 - config.width as i64).abs() + (h as i64 - config.height as i64).abs()
        })
        .unwrap_or((config.width, config.height));
    let agreed = device.set_format(&Format::new(w, h, fourcc)).map_err(|e| {
        open_error_with(
            spec,
            format!(
                "{} refused {w}x{h} {}",
                path.display(),
                fourcc_string(fourcc)
            ),
            e,
        )
    })?;
    if agreed.fourcc != fourcc {
        return Err(format_error(
            spec,
            format!(
                "{} switched to pixel format {} instead of {}",
                path.display(),
                fourcc_string(agreed.fourcc),
                fourcc_string(fourcc)
            ),
        ));
    }
    let _ = device.set_params(&v4l::video::capture::Parameters::with_fps(config.fps));
    let fps = device
        .params()
        .ok()
        .filter(|p| p.interval.numerator > 0)
        .map(|p| p.interval.denominator as f64 / p.interval.numerator as f64)
        .unwrap_or(0.0);
    Ok(Negotiated {
        device,
        width: agreed.width,
        height: agreed.height,
        fourcc,
        fps,
    })
}

fn spawn_node(
    spec: &str,
    path: &Path,
    device: Device,
    buffers: u32,
) -> Result<NodeThread, SourceError> {
    let mut stream =
        MmapStream::with_buffers(&device, Type::VideoCapture, buffers).map_err(|e| {
            open_error_with(
                spec,
                format!(
                    "cannot start streaming {}: {}",
                    path.display(),
                    explain_open_error(&e)
                ),
                e,
            )
        })?;
    stream.set_timeout(DEQUEUE_TIMEOUT);
    let (tx, rx): (Sender<NodeEvent>, Receiver<NodeEvent>) = bounded(2);
    let drain = rx.clone();
    let stop = Arc::new(AtomicBool::new(false));
    let dropped = Arc::new(AtomicU64::new(0));
    let (stop2, dropped2) = (Arc::clone(&stop), Arc::clone(&dropped));
    let node = path.display().to_string();
    let handle = std::thread::Builder::new()
        .name(format!("v4l2 {}", path.display()))
        .spawn(move || {
            let _device = device; // keep the node open while streaming
            let send_newest = |ev: NodeEvent| match tx.try_send(ev) {
                Ok(()) => true,
                Err(TrySendError::Full(ev)) => {
                    let _ = drain.try_recv();
                    dropped2.fetch_add(1, Ordering::Relaxed);
                    tx.try_send(ev).is_ok()
                }
                Err(TrySendError::Disconnected(_)) => false,
            };
            while !stop2.load(Ordering::Relaxed) {
                match stream.next() {
                    Ok((buf, meta)) => {
                        let used = (meta.bytesused as usize).min(buf.len());
                        let ts_us =
                            meta.timestamp.sec as u64 * 1_000_000 + meta.timestamp.usec as u64;
                        let frame = RawFrame {
                            data: buf[..used].to_vec(),
                            ts_us,
                            host_rx: Instant::now(),
                        };
                        tracing::trace!(%node, ts_us, bytes = used, "V4L2 buffer");
                        if !send_newest(NodeEvent::Frame(frame)) {
                            return;
                        }
                    }
                    Err(e) if e.kind() == io::ErrorKind::TimedOut => continue,
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                    Err(e) => {
                        let _ = send_newest(NodeEvent::Lost(format!(
                            "{node}: {}",
                            explain_open_error(&e)
                        )));
                        return;
                    }
                }
            }
        })
        .map_err(|e| open_error_with(spec, "cannot start a capture thread", e))?;
    Ok(NodeThread {
        stop,
        rx,
        dropped,
        handle: Some(handle),
    })
}

/// A V4L2 colour node, optionally with a depth node.
pub struct V4l2Source {
    spec: String,
    info: SourceInfo,
    color_format: ColorFormat,
    color_size: (u32, u32),
    depth_size: Option<(u32, u32)>,
    calibration: Arc<Calibration>,
    native_depth_k: Intrinsics,
    depth_to_color: Extrinsics,
    depth_units_m: f64,
    color: NodeThread,
    depth: Option<NodeThread>,
    pairer: Pairer<RawFrame, RawFrame>,
    stall_timeout: Duration,
    seq: u64,
    lost: Option<String>,
}

impl V4l2Source {
    pub fn open(
        spec: &str,
        color_path: &Path,
        depth_path: Option<&Path>,
        config: &CaptureConfig,
    ) -> Result<V4l2Source, SourceError> {
        let wanted: Vec<&[u8; 4]> = COLOR_FOURCCS.iter().map(|(f, _)| *f).collect();
        let color = negotiate(spec, color_path, &wanted, config)?;
        let color_format = COLOR_FOURCCS
            .iter()
            .find(|(f, _)| FourCC::new(f) == color.fourcc)
            .map(|(_, c)| *c)
            .ok_or_else(|| format_error(spec, "unsupported colour format"))?;
        let depth = match depth_path {
            Some(p) => Some((p, negotiate(spec, p, &[b"Z16 ", b"Y16 "], config)?)),
            None => {
                tracing::warn!(%spec, "no depth node given: frames carry no depth readings");
                None
            }
        };
        let color_k = config.color_intrinsics.unwrap_or_else(|| {
            tracing::warn!(%spec, "V4L2 reports no intrinsics and the configuration has none: assuming 58°x45°");
            Intrinsics::from_fov(color.width, color.height, DEFAULT_FOV_RAD.0, DEFAULT_FOV_RAD.1)
        });
        if (color_k.width, color_k.height) != (color.width, color.height) {
            return Err(open_error(
                spec,
                format!(
                    "configured colour intrinsics are for {}x{}, the camera delivers {}x{}",
                    color_k.width, color_k.height, color.width, color.height
                ),
            ));
        }
        let depth_size = depth.as_ref().map(|(_, d)| (d.width, d.height));
        let native_depth_k = match (config.depth_intrinsics, depth_size) {
            (Some(k), _) => k,
            (None, Some((w, h))) => {
                Intrinsics::from_fov(w, h, DEFAULT_FOV_RAD.0, DEFAULT_FOV_RAD.1)
            }
            (None, None) => color_k,
        };
        let fps = color.fps;
        let description = format!(
            "{} {}x{} {} @ {:.1} fps{}",
            color_path.display(),
            color.width,
            color.height,
            color_format,
            fps,
            depth
                .as_ref()
                .map(|(p, d)| format!(
                    " + {} {}x{} {}",
                    p.display(),
                    d.width,
                    d.height,
                    fourcc_string(d.fourcc)
                ))
                .unwrap_or_default()
        );
        let color_thread = spawn_node(spec, color_path, color.device, config.v4l2_buffers)?;
        let depth_thread = match depth {
            Some((p, d)) => Some(spawn_node(spec, p, d.device, config.v4l2_buffers)?),
            None => None,
        };
        tracing::info!(%spec, %description, "V4L2 source open");
        Ok(V4l2Source {
            spec: spec.to_string(),
            info: SourceInfo {
                spec: spec.to_string(),
                description,
                color_width: color.width,
                color_height: color.height,
                depth_width: color.width,
                depth_height: color.height,
                fps,
                live: true,
            },
            color_format,
            color_size: (color.width, color.height),
            depth_size,
            calibration: Arc::new(Calibration::registered(color_k)),
            native_depth_k,
            depth_to_color: config.depth_to_color.unwrap_or(Extrinsics::IDENTITY),
            depth_units_m: config.depth_units_m,
            color: color_thread,
            depth: depth_thread,
            pairer: Pairer::new(config.tolerance_us(fps)),
            stall_timeout: config.stall_timeout,
            seq: 0,
            lost: None,
        })
    }

    fn accept(&mut self, ev: NodeEvent, is_depth: bool) -> Result<(), SourceError> {
        match ev {
            NodeEvent::Frame(f) if is_depth => self.pairer.push_depth(f, true),
            NodeEvent::Frame(f) => self.pairer.push_color(f, true),
            NodeEvent::Lost(msg) => {
                self.lost = Some(msg.clone());
                return Err(lost_error(&self.spec, msg, None));
            }
        }
        Ok(())
    }

    fn build(&mut self, depth: Option<RawFrame>, color: RawFrame) -> Result<Frame, SourceError> {
        let (w, h) = self.color_size;
        let spec = self.spec.clone();
        let fmt_err = |e: convert::ConvertError| SourceError::Format {
            spec: spec.clone(),
            message: "cannot convert the frame".into(),
            cause: Some(Box::new(e)),
        };
        let bgr = convert::to_bgr(self.color_format, w, h, &color.data).map_err(fmt_err)?;
        let depth_img = match (depth.as_ref(), self.depth_size) {
            (Some(d), Some((dw, dh))) => {
                let mm =
                    convert::depth_to_mm(dw, dh, &d.data, self.depth_units_m).map_err(fmt_err)?;
                let native = DepthImage {
                    width: dw,
                    height: dh,
                    data: mm,
                };
                registration::register_depth(
                    &native,
                    &self.native_depth_k,
                    &self.calibration.color,
                    &self.depth_to_color,
                    0.001,
                )
            }
            _ => DepthImage::new(w, h),
        };
        let frame = Frame {
            seq: self.seq,
            device_ts_us: color.ts_us,
            host_rx: depth
                .as_ref()
                .map_or(color.host_rx, |d| d.host_rx.max(color.host_rx)),
            wall_clock: Some(SystemTime::now()),
            color: ColorImage {
                width: w,
                height: h,
                data: bgr,
            },
            depth: depth_img,
            calibration: Arc::clone(&self.calibration),
        };
        self.seq += 1;
        Ok(frame)
    }
}

impl FrameSource for V4l2Source {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        if let Some(msg) = &self.lost {
            return Err(lost_error(&self.spec, msg.clone(), None));
        }
        let deadline = Instant::now() + self.stall_timeout;
        loop {
            while let Ok(ev) = self.color.rx.try_recv() {
                self.accept(ev, false)?;
            }
            let depth_events: Vec<NodeEvent> = self
                .depth
                .as_ref()
                .map(|d| d.rx.try_iter().collect())
                .unwrap_or_default();
            for ev in depth_events {
                self.accept(ev, true)?;
            }
            if self.depth.is_none() {
                // Colour only: the newest colour frame.
                let (_, n) = self.pairer.pending();
                if n > 0 {
                    let mut newest = None;
                    while let Some(c) = self.pairer.pop_color() {
                        if newest.is_some() {
                            self.pairer.skipped += 1;
                        }
                        newest = Some(c);
                    }
                    if let Some(c) = newest {
                        return self.build(None, c).map(Some);
                    }
                }
            } else if let Some((d, c)) = self.pairer.take_newest() {
                return self.build(Some(d), c).map(Some);
            }
            let now = Instant::now();
            if now >= deadline {
                let msg = format!(
                    "no frame for {:.1} s (unplugged or stalled?)",
                    self.stall_timeout.as_secs_f64()
                );
                self.lost = Some(msg.clone());
                return Err(lost_error(&self.spec, msg, None));
            }
            match self
                .color
                .rx
                .recv_timeout((deadline - now).min(Duration::from_millis(50)))
            {
                Ok(ev) => self.accept(ev, false)?,
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => {
                    let msg = "the colour capture thread stopped".to_string();
                    self.lost = Some(msg.clone());
                    return Err(lost_error(&self.spec, msg, None));
                }
            }
        }
    }

    fn skipped(&self) -> u64 {
        self.pairer.skipped
            + self.color.dropped.load(Ordering::Relaxed)
            + self
                .depth
                .as_ref()
                .map_or(0, |d| d.dropped.load(Ordering::Relaxed))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::open_source;

    #[test]
    fn a_missing_node_is_a_clear_open_error() {
        let err = open_source("v4l2:/dev/video-does-not-exist", &CaptureConfig::default())
            .err()
            .unwrap();
        let text = err.to_string();
        assert!(text.contains("v4l2:/dev/video-does-not-exist"), "{text}");
        assert!(text.contains("no such device node"), "{text}");
    }

    #[test]
    fn a_file_that_is_not_a_device_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let fake = dir.path().join("video0");
        std::fs::write(&fake, b"not a device").unwrap();
        let spec = format!("v4l2:{}", fake.display());
        let err = open_source(&spec, &CaptureConfig::default()).err().unwrap();
        assert!(err.to_string().contains(&spec), "{err}");
    }

    /// Opens a real V4L2 colour camera and reads 10 frames. Needs hardware, so it is opt-in:
    /// `cargo test -p mouthpiece-capture real_device -- --ignored`. Without a camera it fails
    /// (it never passes on a machine that has none).
    #[test]
    #[ignore = "needs a V4L2 colour camera; run with --ignored on a booth machine"]
    fn real_device() {
        let nodes = video_nodes();
        let colour = nodes
            .iter()
            .map(|p| describe_node(p))
            .find(|n| {
                n.error.is_none()
                    && n.formats.iter().any(|f| {
                        COLOR_FOURCCS
                            .iter()
                            .any(|(c, _)| f.fourcc.as_bytes() == &c[..])
                    })
            })
            .unwrap_or_else(|| {
                panic!(
                    "no V4L2 colour node on this machine ({} /dev/video* nodes)",
                    nodes.len()
                )
            });
        let spec = format!("v4l2:{}", colour.path.display());
        let mut src = open_source(&spec, &CaptureConfig::default()).unwrap();
        let mut last = None;
        for _ in 0..10 {
            let f = src.next_frame().unwrap().unwrap();
            assert_eq!(
                f.color.data.len(),
                (f.color.width * f.color.height * 3) as usize
            );
            if let Some(prev) = last {
                assert!(f.device_ts_us > prev);
            }
            last = Some(f.device_ts_us);
        }
    }
}
