//! The OpenNI thread's frame readers: registering them, passing on device events, and the
//! pump that waits for a ready stream and copies its frame (rows packed) to the reader.

use std::ffi::c_int;
use std::ptr;
use std::thread;
use std::time::{Duration, Instant};

use openni2_sys as sys;

use super::{check, ReaderEntry, Sink, State, DEVICE_EVENTS, WAIT_SLICE_MS};
use crate::{Error, Overflow, OwnedFrame, PixelFormat, ReaderEvent, Result, SensorType, Status};

impl State {
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

    pub(super) fn handle_device_events(&mut self) {
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
    pub(super) fn pump_one(&mut self) {
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
