//! The OpenNI thread: owns every native handle, makes every OpenNI call, pumps frames.
//!
//! Callers send closures (`FnOnce(&mut State)`) over a bounded channel and wait for the
//! reply on a one-slot channel. Between commands the thread waits on the streams of the
//! active frame readers (`oniWaitForAnyStream`, short timeout), copies each frame out and
//! releases it at once.

use std::collections::HashMap;
use std::ffi::{c_int, c_void, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::ptr::{self, NonNull};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::thread;
use std::time::{Duration, Instant};

use crossbeam_channel::{bounded, Receiver, RecvTimeoutError, Sender, TryRecvError, TrySendError};
use openni2_sys as sys;

use crate::{
    DeviceInfo, Error, Overflow, OwnedFrame, PixelFormat, ReaderEvent, Result, SensorType, Status,
    VideoMode,
};

/// Pause between stopping streams and destroying them (or closing their device). The Dummy
/// driver never joins its frame thread and the file player walks its stream list without a
/// lock: destroying right after stopping segfaults now and then (measured: 1–2 runs in 10).
pub const TEARDOWN_PAUSE: Duration = Duration::from_millis(100);

/// How long one `oniWaitForAnyStream` may block the command loop.
const WAIT_SLICE_MS: c_int = 10;
/// Capacity of the command channel (callers block when the OpenNI thread is this far behind).
const COMMAND_QUEUE: usize = 64;
/// At most this many unhandled disconnect notices are kept.
const MAX_DEVICE_EVENTS: usize = 64;
const THREAD_NAME: &str = "openni2";

type Command = Box<dyn FnOnce(&mut State) + Send>;

pub(crate) struct Runtime {
    tx: Sender<Command>,
}

static RUNTIME: OnceLock<std::result::Result<Runtime, String>> = OnceLock::new();

/// Device events from OpenNI's callback thread: (uri, reason).
static DEVICE_EVENTS: Mutex<Vec<(String, String)>> = Mutex::new(Vec::new());

pub(crate) fn get() -> Result<&'static Runtime> {
    match RUNTIME.get_or_init(start) {
        Ok(rt) => Ok(rt),
        Err(msg) => Err(Error::Runtime(msg.clone())),
    }
}

fn start() -> std::result::Result<Runtime, String> {
    let (tx, rx) = bounded::<Command>(COMMAND_QUEUE);
    let (ready_tx, ready_rx) = bounded::<std::result::Result<(), String>>(1);
    thread::Builder::new()
        .name(THREAD_NAME.into())
        .spawn(move || match State::initialize() {
            Ok(state) => {
                let _ = ready_tx.send(Ok(()));
                state.run(rx);
            }
            Err(err) => {
                let _ = ready_tx.send(Err(err.to_string()));
            }
        })
        .map_err(|e| format!("cannot spawn the OpenNI2 thread: {e}"))?;
    ready_rx
        .recv()
        .map_err(|_| "the OpenNI2 thread died during start-up".to_string())??;
    Ok(Runtime { tx })
}

impl Runtime {
    /// Runs `f` on the OpenNI thread and returns its result.
    pub(crate) fn call<R: Send + 'static>(
        &self,
        f: impl FnOnce(&mut State) -> R + Send + 'static,
    ) -> Result<R> {
        if thread::current().name() == Some(THREAD_NAME) {
            return Err(Error::Runtime(
                "re-entrant call from the OpenNI2 thread".into(),
            ));
        }
        let (reply_tx, reply_rx) = bounded(1);
        self.tx
            .send(Box::new(move |state: &mut State| {
                let _ = reply_tx.send(f(state));
            }))
            .map_err(|_| Error::Runtime("the OpenNI2 thread has stopped".into()))?;
        reply_rx
            .recv()
            .map_err(|_| Error::Runtime("the OpenNI2 call panicked; see the log".into()))
    }
}

/// Where a reader's frames go.
pub(crate) struct Sink {
    pub(crate) tx: Sender<ReaderEvent>,
    /// A receiver of the same channel, to drop the oldest event when the channel is full.
    pub(crate) drain: Receiver<ReaderEvent>,
    pub(crate) overflow: Overflow,
    pub(crate) dropped: Arc<AtomicU64>,
}

impl Sink {
    /// Delivers an event; `false` when the consumer is gone.
    fn deliver(&self, ev: ReaderEvent, force: bool) -> bool {
        match self.tx.try_send(ev) {
            Ok(()) => true,
            Err(TrySendError::Disconnected(_)) => false,
            Err(TrySendError::Full(ev)) => {
                if self.overflow == Overflow::DropOldest || force {
                    let _ = self.drain.try_recv();
                    self.dropped.fetch_add(1, Ordering::Relaxed);
                    !matches!(self.tx.try_send(ev), Err(TrySendError::Disconnected(_)))
                } else {
                    // Back-pressure readers are not polled while full; this is a race with a
                    // consumer that cannot make the channel fuller, so it does not happen.
                    self.dropped.fetch_add(1, Ordering::Relaxed);
                    true
                }
            }
        }
    }
}

struct DeviceEntry {
    handle: NonNull<sys::_OniDevice>,
    uri: String,
    /// Streams dropped by their owner: stopped, destroyed only when the device closes. The
    /// file player's and the Dummy driver's threads walk their stream lists without a lock,
    /// so destroying one stream while a sibling still runs crashed them (≈ 1 run in 25 of the
    /// dummy test); at close every stream is stopped, and one pause covers them all.
    retired_streams: Vec<NonNull<sys::_OniStream>>,
}

struct StreamEntry {
    handle: NonNull<sys::_OniStream>,
    device: u64,
    sensor: SensorType,
    started: bool,
}

struct RecorderEntry {
    handle: NonNull<sys::_OniRecorder>,
    streams: Vec<u64>,
}

struct ReaderEntry {
    streams: Vec<u64>,
    sink: Sink,
    active: bool,
}

/// Everything the OpenNI thread owns. Never leaves that thread.
pub(crate) struct State {
    next_id: u64,
    devices: HashMap<u64, DeviceEntry>,
    streams: HashMap<u64, StreamEntry>,
    recorders: HashMap<u64, RecorderEntry>,
    readers: HashMap<u64, ReaderEntry>,
}

/// `oniGetExtendedError()` as a string.
fn extended_error() -> String {
    // SAFETY: oniGetExtendedError returns a pointer to a NUL-terminated thread-local buffer
    // (or null), valid until the next OpenNI call on this thread; it is copied at once.
    unsafe {
        let p = sys::oniGetExtendedError();
        if p.is_null() {
            String::new()
        } else {
            CStr::from_ptr(p).to_string_lossy().trim().to_string()
        }
    }
}

fn check(call: &'static str, status: sys::OniStatus) -> Result<()> {
    if status == sys::OniStatus::ONI_STATUS_OK {
        Ok(())
    } else {
        let mut message = extended_error();
        if message.is_empty() {
            message = "(OpenNI2 gave no further detail)".into();
        }
        Err(Error::Call {
            call,
            status: Status(status.0),
            message,
        })
    }
}

fn c_chars_to_string(chars: &[std::ffi::c_char]) -> String {
    let bytes: Vec<u8> = chars
        .iter()
        .take_while(|&&c| c != 0)
        .map(|&c| c as u8)
        .collect();
    String::from_utf8_lossy(&bytes).into_owned()
}

fn device_info_from_sys(info: &sys::OniDeviceInfo) -> DeviceInfo {
    DeviceInfo {
        uri: c_chars_to_string(&info.uri),
        vendor: c_chars_to_string(&info.vendor),
        name: c_chars_to_string(&info.name),
        usb_vendor_id: info.usbVendorId,
        usb_product_id: info.usbProductId,
    }
}

fn push_device_event(info: *const sys::OniDeviceInfo, reason: &str) {
    if info.is_null() {
        return;
    }
    // SAFETY: OpenNI passes a valid device info for the duration of the callback.
    let uri = c_chars_to_string(unsafe { &(*info).uri });
    let mut events = DEVICE_EVENTS.lock().unwrap_or_else(|e| e.into_inner());
    if events.len() < MAX_DEVICE_EVENTS {
        events.push((uri, reason.to_string()));
    }
}

unsafe extern "C" fn on_device_disconnected(info: *const sys::OniDeviceInfo, _cookie: *mut c_void) {
    // A panic must not unwind into C.
    let _ = catch_unwind(|| push_device_event(info, "OpenNI2 reported the device disconnected"));
}

unsafe extern "C" fn on_device_state_changed(
    info: *const sys::OniDeviceInfo,
    state: sys::OniDeviceState,
    _cookie: *mut c_void,
) {
    let _ = catch_unwind(|| {
        if state == sys::OniDeviceState::ONI_DEVICE_STATE_ERROR {
            push_device_event(info, "OpenNI2 reported the device in an error state");
        }
    });
}

impl State {
    fn initialize() -> Result<State> {
        // SAFETY: first OpenNI call of the process, on the thread that makes all later ones.
        check("oniInitialize", unsafe {
            sys::oniInitialize(sys::ONI_API_VERSION)
        })?;
        let callbacks = Box::leak(Box::new(sys::OniDeviceCallbacks {
            deviceConnected: None,
            deviceDisconnected: Some(on_device_disconnected),
            deviceStateChanged: Some(on_device_state_changed),
        }));
        let mut handle: sys::OniCallbackHandle = ptr::null_mut();
        // SAFETY: the callbacks struct is leaked (lives for the process); the callbacks only
        // copy strings into a mutex-guarded queue and never unwind.
        let status =
            unsafe { sys::oniRegisterDeviceCallbacks(callbacks, ptr::null_mut(), &mut handle) };
        if let Err(err) = check("oniRegisterDeviceCallbacks", status) {
            tracing::warn!(%err, "unplug notifications unavailable; relying on frame timeouts");
        }
        tracing::info!(version = %crate::version(), "OpenNI2 initialised");
        Ok(State {
            next_id: 1,
            devices: HashMap::new(),
            streams: HashMap::new(),
            recorders: HashMap::new(),
            readers: HashMap::new(),
        })
    }

    fn run(mut self, rx: Receiver<Command>) {
        loop {
            let reading = self.readers.values().any(|r| r.active);
            if reading {
                loop {
                    match rx.try_recv() {
                        Ok(cmd) => self.exec(cmd),
                        Err(TryRecvError::Empty) => break,
                        Err(TryRecvError::Disconnected) => return,
                    }
                }
            } else {
                match rx.recv_timeout(Duration::from_millis(100)) {
                    Ok(cmd) => self.exec(cmd),
                    Err(RecvTimeoutError::Timeout) => {}
                    Err(RecvTimeoutError::Disconnected) => return,
                }
            }
            self.handle_device_events();
            if self.readers.values().any(|r| r.active) {
                self.pump_one();
            }
        }
    }

    fn exec(&mut self, cmd: Command) {
        if catch_unwind(AssertUnwindSafe(|| cmd(self))).is_err() {
            tracing::error!("an OpenNI2 command panicked; the OpenNI2 thread carries on");
        }
    }

    fn new_id(&mut self) -> u64 {
        let id = self.next_id;
        self.next_id += 1;
        id
    }

    fn device(&self, id: u64) -> Result<&DeviceEntry> {
        self.devices
            .get(&id)
            .ok_or_else(|| Error::InvalidArgument(format!("no open device with id {id}")))
    }

    fn stream(&self, id: u64) -> Result<&StreamEntry> {
        self.streams
            .get(&id)
            .ok_or_else(|| Error::InvalidArgument(format!("no stream with id {id}")))
    }

    // ---- devices ----

    pub(crate) fn device_list(&mut self) -> Result<Vec<DeviceInfo>> {
        let mut list: *mut sys::OniDeviceInfo = ptr::null_mut();
        let mut count: c_int = 0;
        // SAFETY: out-pointers to locals; the list is released below.
        check("oniGetDeviceList", unsafe {
            sys::oniGetDeviceList(&mut list, &mut count)
        })?;
        let mut out = Vec::new();
        if !list.is_null() {
            // SAFETY: OpenNI returned `count` contiguous entries at `list`.
            let entries = unsafe { std::slice::from_raw_parts(list, count.max(0) as usize) };
            out.extend(entries.iter().map(device_info_from_sys));
            // SAFETY: `list` came from oniGetDeviceList and is released once.
            unsafe { sys::oniReleaseDeviceList(list) };
        }
        Ok(out)
    }

    pub(crate) fn open_device(&mut self, uri: CString) -> Result<(u64, DeviceInfo, bool)> {
        let mut handle: sys::OniDeviceHandle = ptr::null_mut();
        // SAFETY: `uri` is NUL-terminated and outlives the call; `handle` is an out-pointer.
        check("oniDeviceOpen", unsafe {
            sys::oniDeviceOpen(uri.as_ptr(), &mut handle)
        })?;
        let handle = NonNull::new(handle).ok_or_else(|| Error::Call {
            call: "oniDeviceOpen",
            status: Status(sys::OniStatus::ONI_STATUS_ERROR.0),
            message: "returned OK but no device".into(),
        })?;
        let mut raw = sys::OniDeviceInfo::default();
        // SAFETY: `handle` is an open device; `raw` is a valid out-struct.
        let info = match check("oniDeviceGetInfo", unsafe {
            sys::oniDeviceGetInfo(handle.as_ptr(), &mut raw)
        }) {
            Ok(()) => device_info_from_sys(&raw),
            Err(err) => {
                // SAFETY: no stream was created on the device yet.
                unsafe { sys::oniDeviceClose(handle.as_ptr()) };
                return Err(err);
            }
        };
        // SAFETY: `handle` is an open device; a property-support query has no side effects.
        let is_file = unsafe {
            sys::oniDeviceIsPropertySupported(
                handle.as_ptr(),
                sys::ONI_DEVICE_PROPERTY_PLAYBACK_SPEED.0 as c_int,
            )
        } != 0;
        let id = self.new_id();
        self.devices.insert(
            id,
            DeviceEntry {
                handle,
                uri: info.uri.clone(),
                retired_streams: Vec::new(),
            },
        );
        Ok((id, info, is_file))
    }

    pub(crate) fn close_device(&mut self, id: u64) {
        // Streams keep their device alive (Arc), so none is left; be defensive anyway.
        let orphans: Vec<u64> = self
            .streams
            .iter()
            .filter(|(_, s)| s.device == id)
            .map(|(&k, _)| k)
            .collect();
        for sid in orphans {
            self.destroy_stream(sid);
        }
        if let Some(dev) = self.devices.remove(&id) {
            if !dev.retired_streams.is_empty() {
                thread::sleep(TEARDOWN_PAUSE);
            }
            for stream in dev.retired_streams {
                // SAFETY: stopped when retired, at least TEARDOWN_PAUSE ago, with every
                // sibling stopped too; destroyed exactly once.
                unsafe { sys::oniStreamDestroy(stream.as_ptr()) };
            }
            // SAFETY: the device is open, its streams are destroyed (above) and it is closed
            // exactly once.
            let status = unsafe { sys::oniDeviceClose(dev.handle.as_ptr()) };
            if let Err(err) = check("oniDeviceClose", status) {
                tracing::warn!(uri = %dev.uri, %err, "closing OpenNI2 device");
            }
            tracing::info!(uri = %dev.uri, "OpenNI2 device closed");
        }
    }

    pub(crate) fn sensor_modes(
        &mut self,
        id: u64,
        sensor: SensorType,
    ) -> Result<Option<Vec<VideoMode>>> {
        let dev = self.device(id)?;
        // SAFETY: open device; the returned info (or null) is owned by OpenNI and copied here.
        let info = unsafe { sys::oniDeviceGetSensorInfo(dev.handle.as_ptr(), sensor.to_sys()) };
        if info.is_null() {
            return Ok(None);
        }
        // SAFETY: non-null sensor info from OpenNI, valid while the device is open.
        let info = unsafe { &*info };
        if info.pSupportedVideoModes.is_null() || info.numSupportedVideoModes <= 0 {
            return Ok(Some(Vec::new()));
        }
        // SAFETY: OpenNI reports `numSupportedVideoModes` contiguous modes at the pointer.
        let modes = unsafe {
            std::slice::from_raw_parts(
                info.pSupportedVideoModes,
                info.numSupportedVideoModes as usize,
            )
        };
        Ok(Some(modes.iter().map(VideoMode::from_sys).collect()))
    }

    pub(crate) fn supports_registration(&mut self, id: u64) -> Result<bool> {
        let dev = self.device(id)?;
        // SAFETY: open device; a capability query.
        Ok(unsafe {
            sys::oniDeviceIsImageRegistrationModeSupported(
                dev.handle.as_ptr(),
                sys::OniImageRegistrationMode::ONI_IMAGE_REGISTRATION_DEPTH_TO_COLOR,
            )
        } != 0)
    }

    pub(crate) fn set_registration(&mut self, id: u64, on: bool) -> Result<()> {
        let dev = self.device(id)?;
        let mode = if on {
            sys::OniImageRegistrationMode::ONI_IMAGE_REGISTRATION_DEPTH_TO_COLOR
        } else {
            sys::OniImageRegistrationMode::ONI_IMAGE_REGISTRATION_OFF
        };
        // SAFETY: the property takes an OniImageRegistrationMode by pointer, size given.
        let status = unsafe {
            sys::oniDeviceSetProperty(
                dev.handle.as_ptr(),
                sys::ONI_DEVICE_PROPERTY_IMAGE_REGISTRATION.0 as c_int,
                (&mode as *const sys::OniImageRegistrationMode).cast(),
                std::mem::size_of_val(&mode) as c_int,
            )
        };
        check("oniDeviceSetProperty(IMAGE_REGISTRATION)", status)
    }

    pub(crate) fn enable_sync(&mut self, id: u64) -> Result<()> {
        let dev = self.device(id)?;
        // SAFETY: open device.
        check("oniDeviceEnableDepthColorSync", unsafe {
            sys::oniDeviceEnableDepthColorSync(dev.handle.as_ptr())
        })
    }

    pub(crate) fn set_playback_speed(&mut self, id: u64, speed: f32) -> Result<()> {
        let dev = self.device(id)?;
        // SAFETY: the property takes a float by pointer, size given.
        let status = unsafe {
            sys::oniDeviceSetProperty(
                dev.handle.as_ptr(),
                sys::ONI_DEVICE_PROPERTY_PLAYBACK_SPEED.0 as c_int,
                (&speed as *const f32).cast(),
                std::mem::size_of::<f32>() as c_int,
            )
        };
        check("oniDeviceSetProperty(PLAYBACK_SPEED)", status)
    }

    pub(crate) fn set_playback_repeat(&mut self, id: u64, repeat: bool) -> Result<()> {
        let dev = self.device(id)?;
        let value: sys::OniBool = repeat.into();
        // SAFETY: the property takes an OniBool by pointer, size given.
        let status = unsafe {
            sys::oniDeviceSetProperty(
                dev.handle.as_ptr(),
                sys::ONI_DEVICE_PROPERTY_PLAYBACK_REPEAT_ENABLED.0 as c_int,
                (&value as *const sys::OniBool).cast(),
                std::mem::size_of::<sys::OniBool>() as c_int,
            )
        };
        check("oniDeviceSetProperty(PLAYBACK_REPEAT_ENABLED)", status)
    }

    // ---- streams ----

    pub(crate) fn create_stream(&mut self, device: u64, sensor: SensorType) -> Result<u64> {
        let dev = self.device(device)?;
        let mut handle: sys::OniStreamHandle = ptr::null_mut();
        // SAFETY: open device; `handle` is an out-pointer.
        let status = unsafe {
            sys::oniDeviceCreateStream(dev.handle.as_ptr(), sensor.to_sys(), &mut handle)
        };
        check("oniDeviceCreateStream", status)?;
        let handle = NonNull::new(handle).ok_or_else(|| Error::Call {
            call: "oniDeviceCreateStream",
            status: Status(sys::OniStatus::ONI_STATUS_ERROR.0),
            message: "returned OK but no stream".into(),
        })?;
        let id = self.new_id();
        self.streams.insert(
            id,
            StreamEntry {
                handle,
                device,
                sensor,
                started: false,
            },
        );
        Ok(id)
    }

    pub(crate) fn destroy_stream(&mut self, id: u64) {
        // A recorder must not outlive a stream attached to it.
        let recorders: Vec<u64> = self
            .recorders
            .iter()
            .filter(|(_, r)| r.streams.contains(&id))
            .map(|(&k, _)| k)
            .collect();
        for rid in recorders {
            let _ = self.destroy_recorder(rid);
        }
        for reader in self.readers.values_mut() {
            reader.streams.retain(|&s| s != id);
        }
        let Some(stream) = self.streams.remove(&id) else {
            return;
        };
        if stream.started {
            // SAFETY: a started stream; stopping is always allowed.
            unsafe { sys::oniStreamStop(stream.handle.as_ptr()) };
        }
        tracing::debug!(sensor = %stream.sensor, "OpenNI2 stream stopped and retired");
        match self.devices.get_mut(&stream.device) {
            Some(dev) => dev.retired_streams.push(stream.handle),
            None => {
                thread::sleep(TEARDOWN_PAUSE);
                // SAFETY: stopped above, its device already gone (cannot happen: streams keep
                // their device open), destroyed exactly once.
                unsafe { sys::oniStreamDestroy(stream.handle.as_ptr()) };
            }
        }
    }

    fn get_stream_property<T: Default + Copy>(&self, id: u64, property: u32) -> Result<Option<T>> {
        // Not gated on oniStreamIsPropertySupported: drivers answer properties they do not
        // declare (the Dummy driver's VIDEO_MODE); a failed get means "not available".
        let stream = self.stream(id)?;
        let mut value = T::default();
        let mut size = std::mem::size_of::<T>() as c_int;
        // SAFETY: `value` is a T-sized buffer and its size is passed; T is the property's C type.
        let status = unsafe {
            sys::oniStreamGetProperty(
                stream.handle.as_ptr(),
                property as c_int,
                (&mut value as *mut T).cast(),
                &mut size,
            )
        };
        if status != sys::OniStatus::ONI_STATUS_OK {
            return Ok(None);
        }
        Ok(Some(value))
    }

    fn set_stream_property<T>(
        &self,
        id: u64,
        call: &'static str,
        property: u32,
        value: &T,
    ) -> Result<()> {
        let stream = self.stream(id)?;
        // SAFETY: `value` points to a T and its size is passed; T is the property's C type.
        let status = unsafe {
            sys::oniStreamSetProperty(
                stream.handle.as_ptr(),
                property as c_int,
                (value as *const T).cast(),
                std::mem::size_of::<T>() as c_int,
            )
        };
        check(call, status)
    }

    pub(crate) fn video_mode(&mut self, id: u64) -> Result<VideoMode> {
        self.get_stream_property::<sys::OniVideoMode>(id, sys::ONI_STREAM_PROPERTY_VIDEO_MODE.0)?
            .map(|m| VideoMode::from_sys(&m))
            .ok_or_else(|| Error::Unsupported("the stream does not report its video mode".into()))
    }

    pub(crate) fn set_video_mode(&mut self, id: u64, mode: VideoMode) -> Result<()> {
        let raw = mode.to_sys();
        self.set_stream_property(
            id,
            "oniStreamSetProperty(VIDEO_MODE)",
            sys::ONI_STREAM_PROPERTY_VIDEO_MODE.0,
            &raw,
        )
    }

    pub(crate) fn field_of_view(&mut self, id: u64) -> Result<Option<(f32, f32)>> {
        let h = self.get_stream_property::<f32>(id, sys::ONI_STREAM_PROPERTY_HORIZONTAL_FOV.0)?;
        let v = self.get_stream_property::<f32>(id, sys::ONI_STREAM_PROPERTY_VERTICAL_FOV.0)?;
        Ok(match (h, v) {
            (Some(h), Some(v)) if h > 0.0 && v > 0.0 => Some((h, v)),
            _ => None,
        })
    }

    pub(crate) fn set_mirroring(&mut self, id: u64, on: bool) -> Result<bool> {
        let stream = self.stream(id)?;
        let prop = sys::ONI_STREAM_PROPERTY_MIRRORING.0;
        // SAFETY: open stream; a capability query.
        if unsafe { sys::oniStreamIsPropertySupported(stream.handle.as_ptr(), prop as c_int) } == 0
        {
            return Ok(false);
        }
        let value: sys::OniBool = on.into();
        self.set_stream_property(id, "oniStreamSetProperty(MIRRORING)", prop, &value)?;
        Ok(true)
    }

    pub(crate) fn supports_cropping(&mut self, id: u64) -> Result<bool> {
        Ok(self
            .get_stream_property::<sys::OniCropping>(id, sys::ONI_STREAM_PROPERTY_CROPPING.0)?
            .is_some())
    }

    pub(crate) fn number_of_frames(&mut self, id: u64) -> Result<Option<u32>> {
        Ok(self
            .get_stream_property::<c_int>(id, sys::ONI_STREAM_PROPERTY_NUMBER_OF_FRAMES.0)?
            .filter(|&n| n >= 0)
            .map(|n| n as u32))
    }

    pub(crate) fn start_stream(&mut self, id: u64) -> Result<()> {
        let stream = self.stream(id)?;
        if stream.started {
            return Ok(());
        }
        // SAFETY: open, stopped stream.
        check("oniStreamStart", unsafe {
            sys::oniStreamStart(stream.handle.as_ptr())
        })?;
        if let Some(s) = self.streams.get_mut(&id) {
            s.started = true;
        }
        Ok(())
    }

    pub(crate) fn stop_stream(&mut self, id: u64) -> Result<()> {
        let stream = self.stream(id)?;
        if stream.started {
            // SAFETY: open, started stream.
            unsafe { sys::oniStreamStop(stream.handle.as_ptr()) };
        }
        if let Some(s) = self.streams.get_mut(&id) {
            s.started = false;
        }
        Ok(())
    }

    // ---- readers ----

    pub(crate) fn start_reader(&mut self, streams: Vec<u64>, sink: Sink) -> Result<u64> {
        for &sid in &streams {
            self.stream(sid)?;
        }
        let id = self.new_id();
        self.readers.insert(
            id,
            ReaderEntry {
                streams,
                sink,
                active: true,
            },
        );
        Ok(id)
    }

    pub(crate) fn stop_reader(&mut self, id: u64) {
        self.readers.remove(&id);
    }

    fn handle_device_events(&mut self) {
        let events: Vec<(String, String)> = {
            let mut guard = DEVICE_EVENTS.lock().unwrap_or_else(|e| e.into_inner());
            std::mem::take(&mut *guard)
        };
        for (uri, reason) in events {
            tracing::warn!(%uri, %reason, "OpenNI2 device event");
            for reader in self.readers.values_mut().filter(|r| r.active) {
                let affected = reader.streams.iter().any(|sid| {
                    self.streams
                        .get(sid)
                        .and_then(|s| self.devices.get(&s.device))
                        .is_some_and(|d| d.uri == uri)
                });
                if affected {
                    reader.sink.deliver(
                        ReaderEvent::DeviceLost {
                            uri: uri.clone(),
                            reason: reason.clone(),
                        },
                        true,
                    );
                    reader.active = false;
                }
            }
        }
    }

    /// Waits briefly for any readable stream and moves one frame to its reader.
    fn pump_one(&mut self) {
        let mut handles: Vec<sys::OniStreamHandle> = Vec::new();
        let mut owners: Vec<(u64, usize)> = Vec::new();
        for (&rid, reader) in &self.readers {
            if !reader.active
                || (reader.sink.overflow == Overflow::Backpressure && reader.sink.tx.is_full())
            {
                continue;
            }
            for (index, sid) in reader.streams.iter().enumerate() {
                if let Some(s) = self.streams.get(sid).filter(|s| s.started) {
                    handles.push(s.handle.as_ptr());
                    owners.push((rid, index));
                }
            }
        }
        if handles.is_empty() {
            thread::sleep(Duration::from_millis(2));
            return;
        }
        let mut ready: c_int = -1;
        // SAFETY: `handles` are started streams owned by this thread; `ready` is an out-int.
        let status = unsafe {
            sys::oniWaitForAnyStream(
                handles.as_mut_ptr(),
                handles.len() as c_int,
                &mut ready,
                WAIT_SLICE_MS,
            )
        };
        if status == sys::OniStatus::ONI_STATUS_TIME_OUT {
            return;
        }
        if let Err(err) = check("oniWaitForAnyStream", status) {
            self.fail_readers(owners.iter().map(|o| o.0).collect(), err);
            return;
        }
        let Some(&(rid, index)) = usize::try_from(ready).ok().and_then(|i| owners.get(i)) else {
            return;
        };
        let handle = handles[ready as usize];
        let frame = match read_frame(handle, index) {
            Ok(frame) => frame,
            Err(err) => {
                self.fail_readers(vec![rid], err);
                return;
            }
        };
        tracing::trace!(sensor = %frame.sensor, ts = frame.timestamp_us, index = frame.frame_index, "OpenNI2 frame");
        if let Some(reader) = self.readers.get_mut(&rid) {
            if !reader.sink.deliver(ReaderEvent::Frame(frame), false) {
                reader.active = false;
            }
        }
    }

    fn fail_readers(&mut self, ids: Vec<u64>, err: Error) {
        let message = err.to_string();
        let mut first = Some(err);
        for rid in ids {
            if let Some(reader) = self.readers.get_mut(&rid) {
                if reader.active {
                    let err = first
                        .take()
                        .unwrap_or_else(|| Error::Runtime(message.clone()));
                    reader.sink.deliver(ReaderEvent::Failed(err), true);
                    reader.active = false;
                }
            }
        }
    }

    // ---- recorders ----

    pub(crate) fn create_recorder(&mut self, path: CString) -> Result<u64> {
        let mut handle: sys::OniRecorderHandle = ptr::null_mut();
        // SAFETY: NUL-terminated path outliving the call; `handle` is an out-pointer.
        check("oniCreateRecorder", unsafe {
            sys::oniCreateRecorder(path.as_ptr(), &mut handle)
        })?;
        let handle = NonNull::new(handle).ok_or_else(|| Error::Call {
            call: "oniCreateRecorder",
            status: Status(sys::OniStatus::ONI_STATUS_ERROR.0),
            message: "returned OK but no recorder".into(),
        })?;
        let id = self.new_id();
        self.recorders.insert(
            id,
            RecorderEntry {
                handle,
                streams: Vec::new(),
            },
        );
        Ok(id)
    }

    pub(crate) fn attach_to_recorder(
        &mut self,
        id: u64,
        stream: u64,
        allow_lossy: bool,
    ) -> Result<()> {
        let stream_handle = self.stream(stream)?.handle;
        let rec = self
            .recorders
            .get_mut(&id)
            .ok_or_else(|| Error::InvalidArgument(format!("no recorder {id}")))?;
        // SAFETY: live recorder and stream, both owned by this thread.
        let status = unsafe {
            sys::oniRecorderAttachStream(
                rec.handle.as_ptr(),
                stream_handle.as_ptr(),
                allow_lossy.into(),
            )
        };
        check("oniRecorderAttachStream", status)?;
        rec.streams.push(stream);
        Ok(())
    }

    pub(crate) fn start_recorder(&mut self, id: u64) -> Result<()> {
        let rec = self
            .recorders
            .get(&id)
            .ok_or_else(|| Error::InvalidArgument(format!("no recorder {id}")))?;
        // SAFETY: live recorder.
        check("oniRecorderStart", unsafe {
            sys::oniRecorderStart(rec.handle.as_ptr())
        })
    }

    pub(crate) fn destroy_recorder(&mut self, id: u64) -> Result<()> {
        let Some(rec) = self.recorders.remove(&id) else {
            return Ok(());
        };
        // Destroying a recorder while its streams run deadlocked inside OpenNI2 (the recorder
        // and a stream's frame thread take each other's locks; ≈ 1 run in 100 of the dummy
        // test under load): stop them first, and give their frame threads the pause.
        let mut stopped_any = false;
        for sid in &rec.streams {
            if let Some(stream) = self.streams.get_mut(sid).filter(|s| s.started) {
                // SAFETY: a started stream; stopping is always allowed.
                unsafe { sys::oniStreamStop(stream.handle.as_ptr()) };
                stream.started = false;
                stopped_any = true;
            }
        }
        if stopped_any {
            thread::sleep(TEARDOWN_PAUSE);
        }
        let mut handle = rec.handle.as_ptr();
        // SAFETY: live recorder, stopped then destroyed exactly once; destruction flushes the
        // queued frames, writes the end record and joins the recorder thread.
        unsafe { sys::oniRecorderStop(handle) };
        // SAFETY: as above.
        check("oniRecorderDestroy", unsafe {
            sys::oniRecorderDestroy(&mut handle)
        })
    }
}

/// Reads one frame of a ready stream, copies it with packed rows and releases it.
fn read_frame(handle: sys::OniStreamHandle, stream_index: usize) -> Result<OwnedFrame> {
    let mut frame: *mut sys::OniFrame = ptr::null_mut();
    // SAFETY: a started stream that oniWaitForAnyStream reported ready; `frame` is an out-ptr.
    check("oniStreamReadFrame", unsafe {
        sys::oniStreamReadFrame(handle, &mut frame)
    })?;
    if frame.is_null() {
        return Err(Error::Call {
            call: "oniStreamReadFrame",
            status: Status(sys::OniStatus::ONI_STATUS_ERROR.0),
            message: "returned OK but no frame".into(),
        });
    }
    let host_rx = Instant::now();
    // SAFETY: OpenNI gave us a reference-counted frame that stays valid until released below.
    let f = unsafe { &*frame };
    let result = copy_frame(f, stream_index, host_rx);
    // SAFETY: releases the reference taken by oniStreamReadFrame, exactly once.
    unsafe { sys::oniFrameRelease(frame) };
    result
}

fn copy_frame(f: &sys::OniFrame, stream_index: usize, host_rx: Instant) -> Result<OwnedFrame> {
    let pixel_format = PixelFormat(f.videoMode.pixelFormat.0);
    let sensor = SensorType::from_sys(f.sensorType).ok_or_else(|| {
        Error::Unsupported(format!("frame of unknown sensor type {}", f.sensorType.0))
    })?;
    let width = f.width.max(0) as usize;
    let height = f.height.max(0) as usize;
    let size = f.dataSize.max(0) as usize;
    let data = if f.data.is_null() || size == 0 {
        Vec::new()
    } else {
        // SAFETY: `data` points to `dataSize` bytes owned by the (unreleased) frame.
        let bytes = unsafe { std::slice::from_raw_parts(f.data as *const u8, size) };
        match pixel_format.bytes_per_pixel() {
            Some(bpp) => {
                let row = width * bpp;
                let stride = if f.stride > 0 { f.stride as usize } else { row };
                if stride < row || stride * height.saturating_sub(1) + row > size {
                    return Err(Error::Unsupported(format!(
                        "{sensor} frame of {width}x{height} {pixel_format} does not fit its {size} bytes (stride {stride})"
                    )));
                }
                let mut packed = Vec::with_capacity(row * height);
                for y in 0..height {
                    packed.extend_from_slice(&bytes[y * stride..y * stride + row]);
                }
                packed
            }
            None => bytes.to_vec(),
        }
    };
    Ok(OwnedFrame {
        stream_index,
        sensor,
        pixel_format,
        width: width as u32,
        height: height as u32,
        timestamp_us: f.timestamp,
        frame_index: f.frameIndex,
        host_rx,
        data,
    })
}
