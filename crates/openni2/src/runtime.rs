//! The OpenNI thread: owns every native handle, makes every OpenNI call, pumps frames.
//!
//! Callers send closures (`FnOnce(&mut State)`) over a bounded channel and wait for the
//! reply on a one-slot channel. Between commands the thread waits on the streams of the
//! active frame readers (`oniWaitForAnyStream`, short timeout), copies each frame out and
//! releases it at once.

mod devices;
mod readers;
mod recorders;
mod streams;

use std::collections::HashMap;
use std::ffi::{c_int, c_void, CStr};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::ptr::{self, NonNull};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::thread;
use std::time::Duration;

use crossbeam_channel::{bounded, Receiver, RecvTimeoutError, Sender, TryRecvError, TrySendError};
use openni2_sys as sys;

use crate::{DeviceInfo, Error, Overflow, ReaderEvent, Result, SensorType, Status};

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

static RUNTIME: OnceLock<std::result::Result<Runtime, StartError>> = OnceLock::new();

/// Why the OpenNI thread did not start (kept for every later call, hence shared causes).
#[derive(Debug, Clone, thiserror::Error)]
enum StartError {
    #[error("cannot spawn the OpenNI2 thread: {0}")]
    Spawn(Arc<std::io::Error>),
    #[error("the OpenNI2 thread died during start-up")]
    Died,
    #[error("{0}")]
    Initialize(Arc<Error>),
}

/// Device events from OpenNI's callback thread: (uri, reason).
static DEVICE_EVENTS: Mutex<Vec<(String, String)>> = Mutex::new(Vec::new());

pub(crate) fn get() -> Result<&'static Runtime> {
    match RUNTIME.get_or_init(start) {
        Ok(rt) => Ok(rt),
        Err(err) => Err(Error::Runtime(err.to_string())),
    }
}

fn start() -> std::result::Result<Runtime, StartError> {
    let (tx, rx) = bounded::<Command>(COMMAND_QUEUE);
    let (ready_tx, ready_rx) = bounded::<std::result::Result<(), StartError>>(1);
    thread::Builder::new()
        .name(THREAD_NAME.into())
        .spawn(move || match State::initialize() {
            Ok(state) => {
                let _ = ready_tx.send(Ok(()));
                state.run(rx);
            }
            Err(err) => {
                let _ = ready_tx.send(Err(StartError::Initialize(Arc::new(err))));
            }
        })
        .map_err(|e| StartError::Spawn(Arc::new(e)))?;
    ready_rx.recv().map_err(|_| StartError::Died)??;
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
}
