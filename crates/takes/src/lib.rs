//! Takes: recording while live, like the booth's audio recorder.
//!
//! One MCAP file per take in the configured folder, named
//! `<slate>_T<take, 3 digits>_<UTC start, YYYYMMDDTHHMMSSZ>.mcap`, holding the raw frames
//! (`/camera/color`, `/camera/depth`, `/camera/calibration`) and every derived channel as JSON:
//! `/performer/points` (tracked dots, camera frame), `/performer/stabilised` (lip dots in the
//! neutral mouth frame), `/head`, and `/character/<name>` per character (its points, curve,
//! head and, once the neutral pose is taken, the rig: docs/rig.md). Every derived message
//! carries `seq`, `t`, `wall_us` and the SMPTE `timecode`; the file's metadata record
//! `mouthpiece.take` names slate, take, timecode rate and start timecode. On a booth without
//! a camera ([`Takes::push_step`]) a take has no camera channels: each speech-driven step
//! writes the derived channels alone, logged at its wall clock.
//!
//! The processing thread never writes: it hands [`TakeItem`]s to a writer thread through a
//! bounded queue (`[takes] queue_frames`); when the queue is full the item is dropped from
//! the take (counted, logged throttled), never from the live stream. The writer closes an
//! MCAP chunk every `flush_s` seconds, so a killed daemon leaves a file readable up to its
//! last second. A write error (disk full) or free space under `min_free_mb` stops the take;
//! the processing thread sees it on its next [`Takes::poll`] and tells the clients.
//!
//! Sound ([`Takes::set_audio`]): the writer subscribes to the audio thread's bus when the take
//! starts and writes every block on `/audio` (Foxglove `RawAudio`, `pcm-s16`) at the wall
//! clock of its first sample, the clock of the frames' log times; `/audio/events` says where
//! the sound started and stopped (a lost device) and why, and the metadata record
//! `mouthpiece.audio`, written when the take closes, sums it up.
//!
//! Reading a take back ([`read`]) lives here too, beside its writer: the `mouthpiece.take`
//! record ([`read::TakeMetadata`]), a character's recorded steps as take lines and their
//! timecodes (`mouthpiece export` and `play`), its recorded heads, where the frames lie (the WAV beside an
//! export), and the chunks of images, dots and sound the console's player shows. The binary,
//! the daemon and the NATS uploader read takes through it.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime};

use crossbeam_channel::{Sender, TrySendError};
use mouthpiece_frame::{AudioBus, Frame};
use serde::Serialize;

use mouthpiece_output::{CharacterHead, HeadPose, RigState, Throttle};

use crate::writer::WriterJob;

mod file;
pub mod read;
mod writer;

pub use file::{create_new_take_file, file_name, free_mb, next_take, unix_us, utc_stamp};
pub use mouthpiece_output::valid_slate;

/// Why a take could not start or had to stop.
#[derive(Debug, thiserror::Error)]
pub enum TakeError {
    #[error("a take is already recording")]
    AlreadyRecording,
    #[error("no take is recording")]
    NotRecording,
    #[error("invalid slate {0:?}: use {rule}", rule = mouthpiece_output::SLATE_RULE)]
    BadSlate(String),
    #[error("cannot create the takes folder {path}")]
    Folder {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("only {free_mb} MB free in {path} (minimum {min_mb} MB)")]
    LowSpace {
        path: PathBuf,
        free_mb: u64,
        min_mb: u64,
    },
    #[error(transparent)]
    Recording(#[from] mouthpiece_recording::RecordingError),
    #[error("cannot start the take writer thread")]
    Thread(#[source] std::io::Error),
}

/// Settings from `[takes]`.
#[derive(Debug, Clone)]
pub struct TakeSettings {
    pub folder: PathBuf,
    pub flush: Duration,
    pub min_free_mb: u64,
    pub queue_frames: usize,
    /// Timecode rate name for the metadata record.
    pub timecode_rate: String,
    /// `[takes] max_write_mb_s` in bytes per second; `None`: no cap.
    pub max_write_bytes_s: Option<f64>,
}

/// One frame's derived data, as written to the take.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Derived {
    pub seq: u64,
    pub t: f64,
    pub wall_us: i64,
    pub timecode: String,
    /// `D1..`, `F1..` in the camera frame, metres; `None` when not seen.
    pub performer: Vec<(String, Option<[f64; 3]>)>,
    /// Lip dots in the neutral mouth frame, metres, with confidence; empty until calibrated.
    pub stabilised: Vec<(String, [f64; 3], f64)>,
    /// The performer's head pose.
    pub head: HeadPose,
    pub characters: Vec<CharacterRecord>,
    pub status: serde_json::Value,
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct CharacterRecord {
    pub name: String,
    pub points: Vec<(String, [f32; 3])>,
    pub confidence: Vec<f32>,
    pub curve: Option<Vec<[f32; 3]>>,
    /// The character's head and eyes (docs/head.md).
    pub head: Option<CharacterHead>,
    /// The rig (docs/rig.md): jaw, lip motions and the named curves; `None` before the
    /// neutral pose is taken.
    pub rig: Option<RigState>,
    /// What drove the mouth (docs/daemon.md, "Speech").
    pub source: mouthpiece_output::MouthSource,
}

/// What the processing thread hands the writer.
#[derive(Debug)]
pub enum TakeItem {
    Frame {
        frame: Arc<Frame>,
        derived: Box<Derived>,
    },
    /// A step without a camera frame (a booth without a camera: speech alone drives the
    /// characters): only the derived channels, logged at the step's wall clock.
    Step { derived: Box<Derived> },
}

/// What is recording now (for status and replies).
#[derive(Debug, Clone, PartialEq)]
pub struct TakeInfo {
    pub slate: String,
    pub take: u32,
    pub path: PathBuf,
    pub started: SystemTime,
}

/// Called on the writer thread once the take's file is open (or could not be).
pub type OnStarted = Box<dyn FnOnce(Result<TakeInfo, String>) + Send>;
/// Called on the writer thread when a take has ended, whatever the reason (for status).
pub type OnEnded = Box<dyn FnOnce(&TakeEnded) + Send>;
/// Called on the writer thread when a stopped take is closed and synced (the stop's reply).
pub type OnStopped = Box<dyn FnOnce(Result<TakeEnded, String>) + Send>;

struct Active {
    queue: Sender<TakeItem>,
    writer: JoinHandle<()>,
    /// Set by the writer when the take stopped by itself (write error, disk full).
    failed: Arc<AtomicBool>,
    dropped: Arc<AtomicU64>,
    /// The stop request's reply, handed to the writer before its queue closes.
    on_stopped: Arc<Mutex<StopSlot>>,
}

/// Between a stop request and the writer's end, whichever comes first.
pub(crate) enum StopSlot {
    /// The writer is still running; the reply to give when it ends.
    Waiting(Option<OnStopped>),
    /// The writer has ended with this.
    Done(Result<TakeEnded, String>),
}

impl StopSlot {
    /// The writer's end: the reply waiting (if any) gets `result`.
    pub(crate) fn finish(slot: &Mutex<StopSlot>, result: Result<TakeEnded, String>) {
        let waiting = {
            let mut slot = slot.lock().unwrap_or_else(|p| p.into_inner());
            match std::mem::replace(&mut *slot, StopSlot::Done(result.clone())) {
                StopSlot::Waiting(waiting) => waiting,
                StopSlot::Done(_) => None,
            }
        };
        if let Some(reply) = waiting {
            reply(result);
        }
    }

    /// A stop request: answered now if the writer has ended, else when it does.
    fn request(slot: &Mutex<StopSlot>, reply: OnStopped) {
        let done = {
            let mut slot = slot.lock().unwrap_or_else(|p| p.into_inner());
            match &mut *slot {
                StopSlot::Waiting(waiting) => {
                    *waiting = Some(reply);
                    return;
                }
                StopSlot::Done(result) => result.clone(),
            }
        };
        reply(done);
    }
}

/// How a take ended.
#[derive(Debug, Clone, PartialEq)]
pub struct TakeEnded {
    /// `None` when the take never started (its file could not be created).
    pub info: Option<TakeInfo>,
    pub frames: u64,
    /// Items dropped because the writer fell behind.
    pub dropped: u64,
    /// Why it stopped by itself (disk full, write error); `None` when stopped on request.
    pub error: Option<String>,
}

/// The take recorder owned by the processing thread. It never touches the file system
/// itself: the folder scan, the free-space check, creating the file, draining and syncing
/// all happen on the take's writer thread, which reports back through callbacks, so
/// starting and stopping takes never stalls the live stream.
pub struct Takes {
    settings: TakeSettings,
    active: Option<Active>,
    /// Writers of stopped takes still draining their queues.
    closing: Vec<JoinHandle<()>>,
    /// Held by a writer while it picks its take number and creates its file.
    naming: Arc<Mutex<()>>,
    drop_warnings: Throttle,
    /// The audio thread's bus and the queue length each take's writer subscribes with.
    audio: Option<(Arc<AudioBus>, usize)>,
}

impl Takes {
    pub fn new(settings: TakeSettings) -> Self {
        Takes {
            settings,
            active: None,
            closing: Vec::new(),
            naming: Arc::new(Mutex::new(())),
            drop_warnings: Throttle::new(Duration::from_secs(10)),
            audio: None,
        }
    }

    /// Records the sound of `bus` in every take from now on (`/audio`): each take's writer
    /// subscribes with a queue of `queue_blocks` blocks (oldest dropped when full).
    pub fn set_audio(&mut self, bus: Arc<AudioBus>, queue_blocks: usize) {
        self.audio = Some((bus, queue_blocks));
    }

    pub fn settings(&self) -> &TakeSettings {
        &self.settings
    }

    pub fn is_recording(&self) -> bool {
        self.active.is_some()
    }

    /// Starts a take without waiting: `started` gets its file (or why there is none) from
    /// the writer thread, `ended` how it ended. `take = None` picks one more than the
    /// highest take of this slate in the folder.
    pub fn start(
        &mut self,
        slate: &str,
        take: Option<u32>,
        source: &str,
        started: OnStarted,
        ended: OnEnded,
    ) {
        if self.active.is_some() {
            started(Err(TakeError::AlreadyRecording.to_string()));
            return;
        }
        if !valid_slate(slate) {
            started(Err(TakeError::BadSlate(slate.to_owned()).to_string()));
            return;
        }
        self.reap();
        let (queue, items) = crossbeam_channel::bounded(self.settings.queue_frames.max(1));
        let failed = Arc::new(AtomicBool::new(false));
        let dropped = Arc::new(AtomicU64::new(0));
        let on_stopped = Arc::new(Mutex::new(StopSlot::Waiting(None)));
        let job = WriterJob {
            slate: slate.to_owned(),
            take,
            source: source.to_owned(),
            settings: self.settings.clone(),
            naming: self.naming.clone(),
            items,
            failed: failed.clone(),
            dropped: dropped.clone(),
            started,
            ended,
            on_stopped: on_stopped.clone(),
            audio: self
                .audio
                .as_ref()
                .map(|(bus, queue)| bus.subscribe(*queue)),
        };
        let writer = match std::thread::Builder::new()
            .name("mouthpiece-take".into())
            .spawn(move || job.run())
        {
            Ok(writer) => writer,
            Err(e) => {
                // The job (and its callbacks) went down with the failed spawn.
                tracing::error!("cannot start the take writer thread: {e}");
                return;
            }
        };
        self.drop_warnings.reset();
        self.active = Some(Active {
            queue,
            writer,
            failed,
            dropped,
            on_stopped,
        });
    }

    /// Hands one frame and its derived data to the writer; never blocks.
    pub fn push(&mut self, frame: Arc<Frame>, derived: Box<Derived>) {
        self.send(TakeItem::Frame { frame, derived });
    }

    /// Hands one step without a camera frame (speech alone, no camera) to the writer; its
    /// messages are logged at `derived.wall_us`. Never blocks.
    pub fn push_step(&mut self, derived: Box<Derived>) {
        self.send(TakeItem::Step { derived });
    }

    fn send(&mut self, item: TakeItem) {
        let Some(active) = &self.active else { return };
        match active.queue.try_send(item) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                let total = active.dropped.fetch_add(1, Ordering::Relaxed) + 1;
                if let Some(held_back) = self.drop_warnings.allow(Instant::now()) {
                    tracing::warn!(
                        total,
                        held_back,
                        "take writer behind: frame dropped from the take"
                    );
                }
            }
        }
    }

    /// Notices a take that stopped by itself (its `ended` callback has told the clients)
    /// and forgets writers that have finished. Cheap: no file system access.
    pub fn poll(&mut self) {
        if self
            .active
            .as_ref()
            .is_some_and(|a| a.failed.load(Ordering::Acquire))
        {
            self.close_active(None);
        }
        self.reap();
    }

    /// Stops the take without waiting: the writer drains its queue, writes the summary,
    /// syncs the file and then calls `stopped`.
    pub fn stop(&mut self, stopped: OnStopped) {
        if self.active.is_none() {
            stopped(Err(TakeError::NotRecording.to_string()));
            return;
        }
        self.close_active(Some(stopped));
    }

    /// Stops the take (if any) and waits until every writer has drained its queue and
    /// synced its file: for the daemon's exit. Bounded by the queues' length.
    pub fn shutdown(&mut self) {
        if self.active.is_some() {
            self.close_active(None);
        }
        for writer in self.closing.drain(..) {
            if writer.join().is_err() {
                tracing::error!("a take writer panicked while closing its take");
            }
        }
    }

    fn close_active(&mut self, stopped: Option<OnStopped>) {
        let Some(active) = self.active.take() else {
            return;
        };
        if let Some(stopped) = stopped {
            StopSlot::request(&active.on_stopped, stopped);
        }
        // Closing the queue is the writer's signal to drain and finish.
        drop(active.queue);
        self.closing.push(active.writer);
    }

    fn reap(&mut self) {
        let (done, running): (Vec<_>, Vec<_>) =
            self.closing.drain(..).partition(|w| w.is_finished());
        self.closing = running;
        for writer in done {
            if writer.join().is_err() {
                tracing::error!("a take writer panicked");
            }
        }
    }
}

impl Drop for Takes {
    fn drop(&mut self) {
        self.shutdown();
    }
}

#[cfg(test)]
mod tests;
