//! The OpenNI thread's recorders: creating them, attaching streams, starting and
//! destroying them.

use std::ffi::CString;
use std::ptr::{self, NonNull};
use std::thread;

use openni2_sys as sys;

use super::{check, RecorderEntry, State, TEARDOWN_PAUSE};
use crate::{Error, Result, Status};

impl State {
    /// Creates a recorder; returns its id and the threads OpenNI2 started for it (see
    /// [`crate::recorder_thread`]).
    pub(crate) fn create_recorder(&mut self, path: CString) -> Result<(u64, Vec<u32>)> {
        let mut handle: sys::OniRecorderHandle = ptr::null_mut();
        let before = crate::recorder_thread::threads_named_like_this_one();
        // SAFETY: NUL-terminated path outliving the call; `handle` is an out-pointer.
        check("oniCreateRecorder", unsafe {
            sys::oniCreateRecorder(path.as_ptr(), &mut handle)
        })?;
        let threads: Vec<u32> = crate::recorder_thread::threads_named_like_this_one()
            .into_iter()
            .filter(|t| !before.contains(t))
            .collect();
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
        Ok((id, threads))
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
