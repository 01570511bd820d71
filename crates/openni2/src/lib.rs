//! Safe OpenNI2: devices, streams, frames and the `.oni` recorder, without `unsafe` for callers.
//!
//! # Design
//!
//! OpenNI2 is process-global and not thread-safe in practice (its drivers run their own
//! threads, and several of its teardown paths race with them).
//! This crate therefore runs **one OpenNI thread per process** (`openni2`), started on first
//! use, that owns every native handle and makes every OpenNI call, teardown included:
//!
//! - the public types ([`Device`], [`Stream`], [`Recorder`], [`FrameReader`]) hold only ids;
//!   each method sends a closure over a bounded command channel and waits for the reply;
//! - frames are read on the OpenNI thread (`oniWaitForAnyStream` + `oniStreamReadFrame`),
//!   copied into owned buffers, released at once, and handed out through one bounded channel
//!   per [`FrameReader`], with either back-pressure (replay: no frame lost) or drop-oldest
//!   (live: the newest frame wins, drops counted);
//! - `oniInitialize` runs once; **`oniShutdown` is never called**: measured here, it segfaults
//!   whenever a driver thread is still running (streams running, or stopped without a pause),
//!   while process exit without it is clean. Teardown follows the notes: stop streams, wait
//!   [`TEARDOWN_PAUSE`], destroy streams, close the device; recorders are destroyed first.
//!   A dropped stream is only stopped; its device destroys it on close, once every sibling
//!   is stopped too (destroying one while another ran crashed the file player).
//!
//! Handles are `NonNull` on the OpenNI thread and never leave it. Errors carry the
//! [`Status`] and `oniGetExtendedError()` text.
//!
//! # Layout
//! - `runtime`: the OpenNI thread, its command loop and frame pump (all `unsafe` lives there).
//! - [`oni_file`]: pure-Rust `.oni` file surgery (the cropping-record fix).
//! - [`oni_check`]: pure-Rust validation of every record, before the player sees a file.
//! - [`oni_writer`]: pure-Rust `.oni` writer (uncompressed depth + RGB888 colour), for
//!   recordings made without a device (the synthetic performer).

mod recorder_thread;
mod runtime;

pub mod oni_check;
pub mod oni_file;
pub mod oni_writer;

use std::ffi::CString;
use std::fmt;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError, TryRecvError};
use openni2_sys as sys;

pub use runtime::TEARDOWN_PAUSE;

/// An OpenNI status code (`OniStatus`), kept as the library returned it.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Status(pub u32);

impl Status {
    pub const OK: Status = Status(sys::OniStatus::ONI_STATUS_OK.0);
    pub const TIME_OUT: Status = Status(sys::OniStatus::ONI_STATUS_TIME_OUT.0);

    pub fn name(self) -> &'static str {
        match sys::OniStatus(self.0) {
            sys::OniStatus::ONI_STATUS_OK => "OK",
            sys::OniStatus::ONI_STATUS_ERROR => "ERROR",
            sys::OniStatus::ONI_STATUS_NOT_IMPLEMENTED => "NOT_IMPLEMENTED",
            sys::OniStatus::ONI_STATUS_NOT_SUPPORTED => "NOT_SUPPORTED",
            sys::OniStatus::ONI_STATUS_BAD_PARAMETER => "BAD_PARAMETER",
            sys::OniStatus::ONI_STATUS_OUT_OF_FLOW => "OUT_OF_FLOW",
            sys::OniStatus::ONI_STATUS_NO_DEVICE => "NO_DEVICE",
            sys::OniStatus::ONI_STATUS_TIME_OUT => "TIME_OUT",
            _ => "UNKNOWN",
        }
    }
}

impl fmt::Debug for Status {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}({})", self.name(), self.0)
    }
}

impl fmt::Display for Status {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "ONI_STATUS_{} ({})", self.name(), self.0)
    }
}

/// Everything that can go wrong talking to OpenNI2.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An OpenNI call failed; `message` is `oniGetExtendedError()` at the time.
    #[error("{call} failed with {status}: {message}")]
    Call {
        call: &'static str,
        status: Status,
        message: String,
    },
    /// The OpenNI thread could not be started or has stopped.
    #[error("the OpenNI2 thread is not running: {0}")]
    Runtime(String),
    /// An argument OpenNI cannot take (a URI or path with a NUL byte, an unknown stream, …).
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// A property or mode the device does not offer.
    #[error("{0}")]
    Unsupported(String),
}

impl Error {
    /// The OpenNI status, when the error came from an OpenNI call.
    pub fn status(&self) -> Option<Status> {
        match self {
            Error::Call { status, .. } => Some(*status),
            _ => None,
        }
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Which sensor a stream reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SensorType {
    Ir,
    Color,
    Depth,
}

impl SensorType {
    fn to_sys(self) -> sys::OniSensorType {
        match self {
            SensorType::Ir => sys::OniSensorType::ONI_SENSOR_IR,
            SensorType::Color => sys::OniSensorType::ONI_SENSOR_COLOR,
            SensorType::Depth => sys::OniSensorType::ONI_SENSOR_DEPTH,
        }
    }

    fn from_sys(s: sys::OniSensorType) -> Option<Self> {
        match s {
            sys::OniSensorType::ONI_SENSOR_IR => Some(SensorType::Ir),
            sys::OniSensorType::ONI_SENSOR_COLOR => Some(SensorType::Color),
            sys::OniSensorType::ONI_SENSOR_DEPTH => Some(SensorType::Depth),
            _ => None,
        }
    }
}

impl fmt::Display for SensorType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SensorType::Ir => "ir",
            SensorType::Color => "color",
            SensorType::Depth => "depth",
        })
    }
}

/// An `OniPixelFormat` value, kept as the library reported it.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct PixelFormat(pub u32);

impl PixelFormat {
    pub const DEPTH_1_MM: PixelFormat =
        PixelFormat(sys::OniPixelFormat::ONI_PIXEL_FORMAT_DEPTH_1_MM.0);
    pub const DEPTH_100_UM: PixelFormat =
        PixelFormat(sys::OniPixelFormat::ONI_PIXEL_FORMAT_DEPTH_100_UM.0);
    pub const SHIFT_9_2: PixelFormat =
        PixelFormat(sys::OniPixelFormat::ONI_PIXEL_FORMAT_SHIFT_9_2.0);
    pub const SHIFT_9_3: PixelFormat =
        PixelFormat(sys::OniPixelFormat::ONI_PIXEL_FORMAT_SHIFT_9_3.0);
    pub const RGB888: PixelFormat = PixelFormat(sys::OniPixelFormat::ONI_PIXEL_FORMAT_RGB888.0);
    pub const YUV422: PixelFormat = PixelFormat(sys::OniPixelFormat::ONI_PIXEL_FORMAT_YUV422.0);
    pub const GRAY8: PixelFormat = PixelFormat(sys::OniPixelFormat::ONI_PIXEL_FORMAT_GRAY8.0);
    pub const GRAY16: PixelFormat = PixelFormat(sys::OniPixelFormat::ONI_PIXEL_FORMAT_GRAY16.0);
    pub const JPEG: PixelFormat = PixelFormat(sys::OniPixelFormat::ONI_PIXEL_FORMAT_JPEG.0);
    pub const YUYV: PixelFormat = PixelFormat(sys::OniPixelFormat::ONI_PIXEL_FORMAT_YUYV.0);

    pub fn name(self) -> &'static str {
        match self {
            Self::DEPTH_1_MM => "DEPTH_1_MM",
            Self::DEPTH_100_UM => "DEPTH_100_UM",
            Self::SHIFT_9_2 => "SHIFT_9_2",
            Self::SHIFT_9_3 => "SHIFT_9_3",
            Self::RGB888 => "RGB888",
            Self::YUV422 => "YUV422",
            Self::GRAY8 => "GRAY8",
            Self::GRAY16 => "GRAY16",
            Self::JPEG => "JPEG",
            Self::YUYV => "YUYV",
            _ => "UNKNOWN",
        }
    }

    /// Bytes per pixel of the uncompressed formats (`None` for JPEG and unknown ones).
    pub fn bytes_per_pixel(self) -> Option<usize> {
        match self {
            Self::DEPTH_1_MM
            | Self::DEPTH_100_UM
            | Self::SHIFT_9_2
            | Self::SHIFT_9_3
            | Self::GRAY16 => Some(2),
            Self::YUV422 | Self::YUYV => Some(2),
            Self::RGB888 => Some(3),
            Self::GRAY8 => Some(1),
            _ => None,
        }
    }
}

impl fmt::Debug for PixelFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}({})", self.name(), self.0)
    }
}

impl fmt::Display for PixelFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A stream's output mode: pixel format, resolution and frame rate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct VideoMode {
    pub pixel_format: PixelFormat,
    pub width: u32,
    pub height: u32,
    pub fps: u32,
}

impl VideoMode {
    fn from_sys(m: &sys::OniVideoMode) -> Self {
        VideoMode {
            pixel_format: PixelFormat(m.pixelFormat.0),
            width: m.resolutionX.max(0) as u32,
            height: m.resolutionY.max(0) as u32,
            fps: m.fps.max(0) as u32,
        }
    }

    fn to_sys(self) -> sys::OniVideoMode {
        sys::OniVideoMode {
            pixelFormat: sys::OniPixelFormat(self.pixel_format.0),
            resolutionX: self.width as i32,
            resolutionY: self.height as i32,
            fps: self.fps as i32,
        }
    }
}

impl fmt::Display for VideoMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}x{} @ {} fps {}",
            self.width, self.height, self.fps, self.pixel_format
        )
    }
}

/// What OpenNI2 knows about a device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceInfo {
    pub uri: String,
    pub vendor: String,
    pub name: String,
    pub usb_vendor_id: u16,
    pub usb_product_id: u16,
}

/// Starts the OpenNI thread and initialises OpenNI2 if that has not happened yet.
/// Every other entry point calls it; calling it first only moves the start-up cost.
pub fn initialize() -> Result<()> {
    runtime::get().map(|_| ())
}

/// The devices OpenNI2's drivers enumerate (the Dummy device is not listed; open it by URI
/// `Dummy`).
pub fn devices() -> Result<Vec<DeviceInfo>> {
    runtime::get()?.call(runtime::State::device_list)?
}

/// The OpenNI2 library's version (`major.minor.maintenance.build`).
pub fn version() -> String {
    // SAFETY: oniGetVersion takes no arguments and only reads constants.
    let v = unsafe { sys::oniGetVersion() };
    format!("{}.{}.{}.{}", v.major, v.minor, v.maintenance, v.build)
}

/// An open device (a camera, the `Dummy` device, or an `.oni` file's player).
///
/// Dropping it (after its streams, which keep it alive) closes the device on the OpenNI thread
/// and waits for that to finish, so a reopen right after a drop finds the device free.
pub struct Device {
    inner: Arc<DeviceInner>,
}

struct DeviceInner {
    id: u64,
    info: DeviceInfo,
    is_file: bool,
}

impl Drop for DeviceInner {
    fn drop(&mut self) {
        let id = self.id;
        if let Ok(rt) = runtime::get() {
            if let Err(err) = rt.call(move |s| s.close_device(id)) {
                tracing::warn!(%err, "closing OpenNI2 device failed");
            }
        }
    }
}

impl Device {
    /// Opens a device by URI: a camera's URI from [`devices`], `Dummy`, or an `.oni` path.
    pub fn open(uri: &str) -> Result<Device> {
        let c_uri = CString::new(uri)
            .map_err(|_| Error::InvalidArgument(format!("URI {uri:?} contains a NUL byte")))?;
        let (id, info, is_file) = runtime::get()?.call(move |s| s.open_device(c_uri))??;
        tracing::info!(uri = %info.uri, name = %info.name, vendor = %info.vendor, "OpenNI2 device open");
        Ok(Device {
            inner: Arc::new(DeviceInner { id, info, is_file }),
        })
    }

    /// Opens an `.oni` recording through OpenNI2's file driver.
    pub fn open_file(path: &Path) -> Result<Device> {
        let uri = path.to_str().ok_or_else(|| {
            Error::InvalidArgument(format!("path {} is not UTF-8", path.display()))
        })?;
        Device::open(uri)
    }

    pub fn info(&self) -> &DeviceInfo {
        &self.inner.info
    }

    /// True for a recording played by OpenNI2's file driver.
    pub fn is_file(&self) -> bool {
        self.inner.is_file
    }

    /// The modes a sensor offers, or `None` when the device has no such sensor.
    pub fn sensor_modes(&self, sensor: SensorType) -> Result<Option<Vec<VideoMode>>> {
        let id = self.inner.id;
        runtime::get()?.call(move |s| s.sensor_modes(id, sensor))?
    }

    /// Whether the device can register depth to colour in hardware.
    pub fn supports_registration(&self) -> Result<bool> {
        let id = self.inner.id;
        runtime::get()?.call(move |s| s.supports_registration(id))?
    }

    /// Turns hardware depth→colour registration on or off.
    pub fn set_registration(&self, on: bool) -> Result<()> {
        let id = self.inner.id;
        runtime::get()?.call(move |s| s.set_registration(id, on))?
    }

    /// Asks the device to deliver depth and colour frames in sync (ignored by devices that
    /// cannot; the error is returned for the caller to log).
    pub fn enable_depth_color_sync(&self) -> Result<()> {
        let id = self.inner.id;
        runtime::get()?.call(move |s| s.enable_sync(id))?
    }

    /// Playback speed of a file device: 1.0 = recorded speed, −1.0 = manual (every frame, as
    /// fast as they are read; use it offline), 0.0 = as fast as possible (drops frames).
    pub fn set_playback_speed(&self, speed: f32) -> Result<()> {
        let id = self.inner.id;
        runtime::get()?.call(move |s| s.set_playback_speed(id, speed))?
    }

    /// Whether a file device starts over at its end.
    pub fn set_playback_repeat(&self, repeat: bool) -> Result<()> {
        let id = self.inner.id;
        runtime::get()?.call(move |s| s.set_playback_repeat(id, repeat))?
    }

    /// Creates a (stopped) stream on one of the device's sensors.
    pub fn create_stream(&self, sensor: SensorType) -> Result<Stream> {
        let id = self.inner.id;
        let stream_id = runtime::get()?.call(move |s| s.create_stream(id, sensor))??;
        Ok(Stream {
            id: stream_id,
            sensor,
            device: Arc::clone(&self.inner),
        })
    }
}

/// A stream of one sensor. Dropping it stops it; OpenNI2's stream is destroyed when its
/// device closes, after [`TEARDOWN_PAUSE`] (drivers crash when a stream is destroyed while a
/// sibling runs).
pub struct Stream {
    id: u64,
    sensor: SensorType,
    device: Arc<DeviceInner>,
}

impl Drop for Stream {
    fn drop(&mut self) {
        let id = self.id;
        if let Ok(rt) = runtime::get() {
            if let Err(err) = rt.call(move |s| s.destroy_stream(id)) {
                tracing::warn!(%err, "destroying OpenNI2 stream failed");
            }
        }
    }
}

impl Stream {
    pub fn sensor(&self) -> SensorType {
        self.sensor
    }

    /// URI of the device the stream belongs to.
    pub fn device_uri(&self) -> &str {
        &self.device.info.uri
    }

    pub fn video_mode(&self) -> Result<VideoMode> {
        let id = self.id;
        runtime::get()?.call(move |s| s.video_mode(id))?
    }

    pub fn set_video_mode(&self, mode: VideoMode) -> Result<()> {
        let id = self.id;
        runtime::get()?.call(move |s| s.set_video_mode(id, mode))?
    }

    /// Horizontal and vertical field of view in radians, when the stream reports them.
    pub fn field_of_view(&self) -> Result<Option<(f32, f32)>> {
        let id = self.id;
        runtime::get()?.call(move |s| s.field_of_view(id))?
    }

    /// Turns mirroring on or off; `Ok(false)` when the stream has no mirroring property.
    pub fn set_mirroring(&self, on: bool) -> Result<bool> {
        let id = self.id;
        runtime::get()?.call(move |s| s.set_mirroring(id, on))?
    }

    /// Whether the stream answers `ONI_STREAM_PROPERTY_CROPPING` (OpenNI2's recorder writes
    /// the cropping record only then; see [`oni_file`]).
    pub fn supports_cropping(&self) -> Result<bool> {
        let id = self.id;
        runtime::get()?.call(move |s| s.supports_cropping(id))?
    }

    /// Number of frames of a file stream (`None` for live streams).
    pub fn number_of_frames(&self) -> Result<Option<u32>> {
        let id = self.id;
        runtime::get()?.call(move |s| s.number_of_frames(id))?
    }

    pub fn start(&self) -> Result<()> {
        let id = self.id;
        runtime::get()?.call(move |s| s.start_stream(id))?
    }

    pub fn stop(&self) -> Result<()> {
        let id = self.id;
        runtime::get()?.call(move |s| s.stop_stream(id))?
    }
}

/// What a [`FrameReader`] does when its channel is full.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Overflow {
    /// Stop reading the streams until there is room (replay: no frame is lost; the file
    /// player waits in manual mode).
    Backpressure,
    /// Drop the oldest queued frame (live: the newest frame wins); drops are counted.
    DropOldest,
}

/// One frame copied out of OpenNI2, rows packed (`width * bytes_per_pixel` bytes a row).
#[derive(Debug, Clone)]
pub struct OwnedFrame {
    /// Index into the stream slice given to [`FrameReader::start`].
    pub stream_index: usize,
    pub sensor: SensorType,
    pub pixel_format: PixelFormat,
    pub width: u32,
    pub height: u32,
    /// Device timestamp, microseconds.
    pub timestamp_us: u64,
    pub frame_index: i32,
    /// Host monotonic time at which the OpenNI thread read the frame.
    pub host_rx: Instant,
    pub data: Vec<u8>,
}

/// What a [`FrameReader`] delivers.
#[derive(Debug)]
pub enum ReaderEvent {
    Frame(OwnedFrame),
    /// OpenNI2 reported the device disconnected (or in an error state).
    DeviceLost {
        uri: String,
        reason: String,
    },
    /// Reading failed; the reader has stopped.
    Failed(Error),
}

/// Reads frames of a set of started streams on the OpenNI thread into a bounded channel.
/// Dropping it stops the reading (not the streams).
pub struct FrameReader {
    id: u64,
    rx: Receiver<ReaderEvent>,
    dropped: Arc<AtomicU64>,
}

impl FrameReader {
    /// Starts reading `streams` (which must stay alive while the reader runs) into a channel
    /// of `capacity` events.
    pub fn start(streams: &[&Stream], capacity: usize, overflow: Overflow) -> Result<FrameReader> {
        let ids: Vec<u64> = streams.iter().map(|s| s.id).collect();
        let (tx, rx) = crossbeam_channel::bounded(capacity.max(1));
        let dropped = Arc::new(AtomicU64::new(0));
        let sink = runtime::Sink {
            tx,
            drain: rx.clone(),
            overflow,
            dropped: Arc::clone(&dropped),
        };
        let id = runtime::get()?.call(move |s| s.start_reader(ids, sink))??;
        Ok(FrameReader { id, rx, dropped })
    }

    /// Waits up to `timeout` for the next event; `Ok(None)` on timeout.
    pub fn recv_timeout(&self, timeout: Duration) -> Result<Option<ReaderEvent>> {
        match self.rx.recv_timeout(timeout) {
            Ok(ev) => Ok(Some(ev)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => {
                Err(Error::Runtime("the frame reader was stopped".into()))
            }
        }
    }

    /// The next event if one is queued.
    pub fn try_recv(&self) -> Result<Option<ReaderEvent>> {
        match self.rx.try_recv() {
            Ok(ev) => Ok(Some(ev)),
            Err(TryRecvError::Empty) => Ok(None),
            Err(TryRecvError::Disconnected) => {
                Err(Error::Runtime("the frame reader was stopped".into()))
            }
        }
    }

    /// Frames dropped because the channel was full ([`Overflow::DropOldest`]).
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

impl Drop for FrameReader {
    fn drop(&mut self) {
        let id = self.id;
        if let Ok(rt) = runtime::get() {
            // The reply only confirms the OpenNI thread will not touch the channel again.
            let _ = rt.call(move |s| s.stop_reader(id));
        }
    }
}

/// OpenNI2's own `.oni` recorder. Attach streams, [`start`](Recorder::start), and
/// [`finish`](Recorder::finish) to close the file (its thread spins a core while it exists,
/// so finish promptly). Dropping an unfinished recorder finishes it. Finishing stops the
/// streams it recorded (start them again to go on reading): OpenNI2 can deadlock when a
/// recorder is destroyed while its streams run.
pub struct Recorder {
    id: u64,
    finished: bool,
    path: std::path::PathBuf,
    attached: usize,
    /// The recorder's own thread(s), as found when it was created.
    threads: Vec<u32>,
}

/// How long [`Recorder::start`] waits for OpenNI2's recorder thread to take its start
/// message before calling it a failure (a loaded machine takes milliseconds, not seconds).
const RECORDER_START_TIMEOUT: Duration = Duration::from_secs(30);

/// How long [`Recorder::start`] waits for the recorder's thread to run on after its start
/// (it spins, so it is charged CPU time within milliseconds even on a loaded machine).
const RECORDER_RUN_ON_TIMEOUT: Duration = Duration::from_secs(5);

impl Recorder {
    /// Creates the file (truncating it) and the recorder.
    pub fn create(path: &Path) -> Result<Recorder> {
        let s = path.to_str().ok_or_else(|| {
            Error::InvalidArgument(format!("path {} is not UTF-8", path.display()))
        })?;
        let c = CString::new(s)
            .map_err(|_| Error::InvalidArgument(format!("path {s:?} contains a NUL byte")))?;
        let (id, threads) = runtime::get()?.call(move |st| st.create_recorder(c))??;
        Ok(Recorder {
            id,
            finished: false,
            path: path.to_path_buf(),
            attached: 0,
            threads,
        })
    }

    /// Attaches a stream; lossy compression lets OpenNI2 store colour as JPEG.
    pub fn attach(&mut self, stream: &Stream, allow_lossy: bool) -> Result<()> {
        let (id, sid) = (self.id, stream.id);
        runtime::get()?.call(move |s| s.attach_to_recorder(id, sid, allow_lossy))??;
        self.attached += 1;
        Ok(())
    }

    /// Starts recording, and returns once the recorder records: frames that arrive before
    /// that are lost, and a stream whose first frame is lost is shifted against the other
    /// (OpenNI2 rewrites each stream's timestamps from its own first recorded frame).
    ///
    /// `oniRecorderStart` only queues a message for the recorder's own thread, which then
    /// writes each attached node's `NODE_STATE_READY` and `NODE_DATA_BEGIN` records and
    /// sets its started flag; until the flag is set, frames are dropped. Waiting for those
    /// records in the file (the recorder writes with plain `write` calls, no buffering)
    /// makes the start independent of how soon that thread runs. The flag is set a few
    /// instructions after the last record, but a loaded machine can preempt the thread right
    /// there for longer than a frame (it happened: a depth stream shifted by one frame
    /// against colour). So the wait ends only once the thread has also run on: it spins
    /// without blocking, and `recorder_thread::ran_on` waits for the scheduler to charge
    /// it CPU time twice after the records were seen, millions of instructions later. It
    /// measures the thread's progress, not the clock.
    pub fn start(&self) -> Result<()> {
        let id = self.id;
        runtime::get()?.call(move |s| s.start_recorder(id))??;
        let deadline = Instant::now() + RECORDER_START_TIMEOUT;
        loop {
            let begun = oni_file::list_records(&self.path, true)
                .map(|records| {
                    records
                        .iter()
                        .filter(|r| r.kind == oni_file::record_type::NODE_DATA_BEGIN)
                        .count()
                })
                .unwrap_or(0);
            if begun >= self.attached {
                if !recorder_thread::ran_on(&self.threads, RECORDER_RUN_ON_TIMEOUT) {
                    tracing::warn!(file = %self.path.display(), "cannot see OpenNI2's recorder thread run on after its start; a stream's first frame may be missed");
                    std::thread::sleep(Duration::from_millis(5));
                }
                return Ok(());
            }
            if Instant::now() > deadline {
                return Err(Error::Runtime(format!(
                    "OpenNI2's recorder did not start writing {} within {} s",
                    self.path.display(),
                    RECORDER_START_TIMEOUT.as_secs()
                )));
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// Stops the recorded streams and the recording, and destroys the recorder; the file is
    /// complete when this returns.
    pub fn finish(mut self) -> Result<()> {
        self.finished = true;
        let id = self.id;
        runtime::get()?.call(move |s| s.destroy_recorder(id))?
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        if self.finished {
            return;
        }
        let id = self.id;
        if let Ok(rt) = runtime::get() {
            let _ = rt.call(move |s| s.destroy_recorder(id));
        }
    }
}
