//! The OpenNI thread's devices: listing, opening and closing them, their sensors' modes,
//! registration, frame sync and file playback settings.

use std::ffi::{c_int, CString};
use std::ptr::{self, NonNull};
use std::thread;

use openni2_sys as sys;

use super::{check, device_info_from_sys, DeviceEntry, State, TEARDOWN_PAUSE};
use crate::{DeviceInfo, Error, Result, SensorType, Status, VideoMode};

impl State {
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
}
