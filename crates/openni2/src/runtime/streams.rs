//! The OpenNI thread's streams: creating and destroying them, their properties (video mode,
//! field of view, mirroring, cropping, frame count), starting and stopping them.

use std::ffi::c_int;
use std::ptr::{self, NonNull};
use std::thread;

use openni2_sys as sys;

use super::{check, State, StreamEntry, TEARDOWN_PAUSE};
use crate::{Error, Result, SensorType, Status, VideoMode};

impl State {
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
}
