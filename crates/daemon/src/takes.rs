//! Takes: recording while live, like the booth's audio recorder.
//!
//! One MCAP file per take in the configured folder, named
//! `<slate>_T<take, 3 digits>_<UTC start, YYYYMMDDTHHMMSSZ>.mcap`, holding the raw frames
//! (`/camera/color`, `/camera/depth`, `/camera/calibration`) and every derived channel as JSON:
//! `/performer/points` (tracked dots, camera frame), `/performer/stabilised` (lip dots in the
//! neutral mouth frame), `/head`, and `/character/<name>` per character (its points, curve,
//! head and, once the neutral pose is taken, the rig: docs/rig.md). Every derived message
//! carries `seq`, `t`, `wall_us` and the SMPTE `timecode`; the file's metadata record
//! `mouthpiece.take` names slate, take, timecode rate and start timecode.
//!
//! The processing thread never writes: it hands [`TakeItem`]s to a writer thread through a
//! bounded queue (`[takes] queue_frames`); when the queue is full the item is dropped from
//! the take (counted, logged throttled), never from the live stream. The writer closes an
//! MCAP chunk every `flush_s` seconds, so a killed daemon leaves a file readable up to its
//! last second. A write error (disk full) or free space under `min_free_mb` stops the take;
//! the processing thread sees it on its next [`Takes::poll`] and tells the clients.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use crossbeam_channel::{Receiver, Sender, TrySendError};
use mouthpiece_frame::Frame;
use mouthpiece_recording::{SessionWriter, WriterOptions};
use serde::Serialize;

use crate::throttle::Throttle;

/// Why a take could not start or had to stop.
#[derive(Debug, thiserror::Error)]
pub enum TakeError {
    #[error("a take is already recording")]
    AlreadyRecording,
    #[error("no take is recording")]
    NotRecording,
    #[error("invalid slate {0:?}: use 1-64 letters, digits, '-', '_' or '.', starting with a letter or digit")]
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
    pub head: HeadRecord,
    pub characters: Vec<CharacterRecord>,
    pub status: serde_json::Value,
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct HeadRecord {
    pub rotation: [f64; 4],
    pub translation: [f64; 3],
    pub lost: bool,
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct CharacterRecord {
    pub name: String,
    pub points: Vec<(String, [f32; 3])>,
    pub confidence: Vec<f32>,
    pub curve: Option<Vec<[f32; 3]>>,
    /// The character's head and eyes (docs/head.md).
    pub head: Option<mouthpiece_server::CharacterHead>,
    /// The rig (docs/rig.md): jaw, lip motions and the named curves; `None` before the
    /// neutral pose is taken.
    pub rig: Option<mouthpiece_server::RigState>,
}

/// What the processing thread hands the writer.
#[derive(Debug)]
pub enum TakeItem {
    Frame {
        frame: Arc<Frame>,
        derived: Box<Derived>,
    },
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
enum StopSlot {
    /// The writer is still running; the reply to give when it ends.
    Waiting(Option<OnStopped>),
    /// The writer has ended with this.
    Done(Result<TakeEnded, String>),
}

impl StopSlot {
    /// The writer's end: the reply waiting (if any) gets `result`.
    fn finish(slot: &Mutex<StopSlot>, result: Result<TakeEnded, String>) {
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
}

impl Takes {
    pub fn new(settings: TakeSettings) -> Self {
        Takes {
            settings,
            active: None,
            closing: Vec::new(),
            naming: Arc::new(Mutex::new(())),
            drop_warnings: Throttle::new(Duration::from_secs(10)),
        }
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
        let Some(active) = &self.active else { return };
        match active.queue.try_send(TakeItem::Frame { frame, derived }) {
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

/// Everything a take's writer thread needs.
struct WriterJob {
    slate: String,
    take: Option<u32>,
    source: String,
    settings: TakeSettings,
    naming: Arc<Mutex<()>>,
    items: Receiver<TakeItem>,
    failed: Arc<AtomicBool>,
    dropped: Arc<AtomicU64>,
    started: OnStarted,
    ended: OnEnded,
    on_stopped: Arc<Mutex<StopSlot>>,
}

impl WriterJob {
    fn run(self) {
        let opened = open_take(
            &self.settings,
            &self.naming,
            &self.slate,
            self.take,
            &self.source,
        );
        let (info, writer, file) = match opened {
            Ok(opened) => opened,
            Err(e) => {
                let message = crate::source::error_chain(&e);
                tracing::error!(slate = %self.slate, "cannot start take: {message}");
                self.failed.store(true, Ordering::Release);
                (self.started)(Err(message.clone()));
                let ended = TakeEnded {
                    info: None,
                    frames: 0,
                    dropped: 0,
                    error: Some(message),
                };
                (self.ended)(&ended);
                StopSlot::finish(&self.on_stopped, Err(ended.error.unwrap_or_default()));
                return;
            }
        };
        tracing::info!(slate = %info.slate, take = info.take, path = %info.path.display(), "take started");
        (self.started)(Ok(info.clone()));
        let result = write_take(writer, self.items, &self.settings, &self.failed);
        let synced = match &result.error {
            None => sync_take(&file, &info.path),
            Some(_) => Ok(()),
        };
        let ended = TakeEnded {
            info: Some(info),
            frames: result.frames,
            dropped: self.dropped.load(Ordering::Relaxed),
            error: result.error.or_else(|| {
                synced
                    .err()
                    .map(|e| format!("cannot sync the take to disk: {e}"))
            }),
        };
        let path = ended.info.as_ref().map(|i| i.path.display().to_string());
        match &ended.error {
            None => tracing::info!(
                path,
                frames = ended.frames,
                dropped = ended.dropped,
                "take closed and synced to disk: {} frames kept",
                ended.frames
            ),
            Some(error) => {
                tracing::error!(path, frames = ended.frames, "take stopped: {error}")
            }
        }
        (self.ended)(&ended);
        let result = match &ended.error {
            None => Ok(ended.clone()),
            Some(error) => Err(format!(
                "take {} ended with an error: {error}",
                path.unwrap_or_default()
            )),
        };
        StopSlot::finish(&self.on_stopped, result);
    }
}

/// Creates the folder, checks its free space, picks the take number and creates the file,
/// never over an existing file or through a symbolic link.
fn open_take(
    settings: &TakeSettings,
    naming: &Mutex<()>,
    slate: &str,
    take: Option<u32>,
    source: &str,
) -> Result<(TakeInfo, TakeWriter, std::fs::File), TakeError> {
    let folder = &settings.folder;
    std::fs::create_dir_all(folder).map_err(|source| TakeError::Folder {
        path: folder.clone(),
        source,
    })?;
    if let Some(free_mb) = free_mb(folder) {
        if free_mb < settings.min_free_mb {
            return Err(TakeError::LowSpace {
                path: folder.clone(),
                free_mb,
                min_mb: settings.min_free_mb,
            });
        }
    }
    let (take, started, path, file) = {
        // One writer at a time scans the folder and claims its name.
        let _naming = naming.lock().unwrap_or_else(|p| p.into_inner());
        let take = take.unwrap_or_else(|| next_take(folder, slate));
        let started = SystemTime::now();
        let (path, file) = create_new_take_file(folder, &file_name(slate, take, started))?;
        (take, started, path, file)
    };
    let sync_handle = file.try_clone().map_err(|source| TakeError::Folder {
        path: path.clone(),
        source,
    })?;
    let options = WriterOptions {
        flush_interval: settings.flush,
        ..WriterOptions::default()
    };
    let mut writer = SessionWriter::new(
        std::io::BufWriter::with_capacity(1 << 20, TakeFile::new(file, settings.max_write_bytes_s)),
        path.display().to_string(),
        options,
    )?;
    let started_unix_us = unix_us(started);
    let metadata: std::collections::BTreeMap<String, String> = [
        ("slate".to_owned(), slate.to_owned()),
        ("take".to_owned(), take.to_string()),
        ("started_unix_us".to_owned(), started_unix_us.to_string()),
        ("timecode_rate".to_owned(), settings.timecode_rate.clone()),
        ("source".to_owned(), source.to_owned()),
    ]
    .into_iter()
    .collect();
    writer.write_metadata("mouthpiece.take", metadata)?;
    Ok((
        TakeInfo {
            slate: slate.to_owned(),
            take,
            path,
            started,
        },
        writer,
        sync_handle,
    ))
}

/// Creates `name` in `folder`, or `name` with `-2`, `-3`, ... before `.mcap` when a file
/// (or a link) of that name exists: `O_CREAT | O_EXCL` neither truncates nor follows links.
pub fn create_new_take_file(
    folder: &Path,
    name: &str,
) -> Result<(PathBuf, std::fs::File), TakeError> {
    let stem = name.strip_suffix(".mcap").unwrap_or(name);
    let mut last_error = None;
    for n in 1..=1000u32 {
        let candidate = if n == 1 {
            name.to_owned()
        } else {
            format!("{stem}-{n}.mcap")
        };
        let path = folder.join(&candidate);
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&path)
        {
            Ok(file) => return Ok((path, file)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last_error = Some(e),
            Err(source) => return Err(TakeError::Folder { path, source }),
        }
    }
    Err(TakeError::Folder {
        path: folder.join(name),
        source: last_error.unwrap_or_else(|| std::io::Error::other("no free file name")),
    })
}

type TakeWriter = SessionWriter<std::io::BufWriter<TakeFile>>;

/// A take's file, written no faster than `[takes] max_write_mb_s` when that is set: each
/// write waits until the bytes written so far fit the rate since the file was created.
struct TakeFile {
    file: std::fs::File,
    max_bytes_s: Option<f64>,
    created: Instant,
    written: u64,
}

impl TakeFile {
    fn new(file: std::fs::File, max_bytes_s: Option<f64>) -> Self {
        TakeFile {
            file,
            max_bytes_s,
            created: Instant::now(),
            written: 0,
        }
    }
}

impl std::io::Write for TakeFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.file.write(buf)?;
        self.written += n as u64;
        if let Some(rate) = self.max_bytes_s {
            let due = Duration::from_secs_f64(self.written as f64 / rate);
            if let Some(wait) = due.checked_sub(self.created.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

impl std::io::Seek for TakeFile {
    fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
        self.file.seek(pos)
    }
}

/// `fsync` of the take's file and of its folder (so the new name survives a power cut).
fn sync_take(file: &std::fs::File, path: &Path) -> std::io::Result<()> {
    file.sync_all()?;
    if let Some(folder) = path.parent() {
        std::fs::File::open(folder)?.sync_all()?;
    }
    Ok(())
}

struct WriterResult {
    frames: u64,
    error: Option<String>,
}

fn write_take(
    mut writer: TakeWriter,
    items: Receiver<TakeItem>,
    settings: &TakeSettings,
    failed: &AtomicBool,
) -> WriterResult {
    let mut frames = 0;
    let mut last_space_check = Instant::now();
    let mut error = None;
    // Runs until the queue is closed (stop) and drained, or a write fails.
    for item in items.iter() {
        let TakeItem::Frame { frame, derived } = item;
        if let Err(e) = write_one(&mut writer, &frame, &derived) {
            error = Some(crate::source::error_chain(&e));
            break;
        }
        frames += 1;
        if last_space_check.elapsed() >= Duration::from_secs(1) {
            last_space_check = Instant::now();
            if let Some(free) = free_mb(&settings.folder) {
                if free < settings.min_free_mb {
                    error = Some(format!(
                        "disk almost full: {free} MB free in {} (minimum {} MB)",
                        settings.folder.display(),
                        settings.min_free_mb
                    ));
                    break;
                }
            }
        }
    }
    if error.is_some() {
        failed.store(true, Ordering::Release);
        // Flush what fits; the file stays readable up to its last complete chunk.
        let _ = writer.flush();
        drop(writer);
        return WriterResult { frames, error };
    }
    if let Err(e) = writer.finish() {
        failed.store(true, Ordering::Release);
        return WriterResult {
            frames,
            error: Some(crate::source::error_chain(&e)),
        };
    }
    WriterResult {
        frames,
        error: None,
    }
}

fn write_one(
    writer: &mut TakeWriter,
    frame: &Frame,
    derived: &Derived,
) -> Result<(), mouthpiece_recording::RecordingError> {
    use serde_json::{json, Map, Value};
    let log_time = writer.write_frame(frame)?;
    // Every derived message starts with the same stamp, so each channel lines up on its own.
    let stamped = |body: Value| -> Value {
        let mut message = Map::new();
        message.insert("seq".into(), json!(derived.seq));
        message.insert("t".into(), json!(derived.t));
        message.insert("wall_us".into(), json!(derived.wall_us));
        message.insert("timecode".into(), json!(derived.timecode));
        if let Value::Object(body) = body {
            message.extend(body);
        }
        Value::Object(message)
    };
    let performer: Map<String, Value> = derived
        .performer
        .iter()
        .map(|(name, p)| (name.clone(), json!(p)))
        .collect();
    writer.write_json(
        "/performer/points",
        log_time,
        &stamped(json!({ "points": performer, "status": derived.status })),
    )?;
    if !derived.stabilised.is_empty() {
        let points: Map<String, Value> = derived
            .stabilised
            .iter()
            .map(|(n, p, _)| (n.clone(), json!(p)))
            .collect();
        let confidence: Map<String, Value> = derived
            .stabilised
            .iter()
            .map(|(n, _, c)| (n.clone(), json!(c)))
            .collect();
        writer.write_json(
            "/performer/stabilised",
            log_time,
            &stamped(json!({ "points": points, "confidence": confidence })),
        )?;
    }
    writer.write_json("/head", log_time, &stamped(json!(derived.head)))?;
    for character in &derived.characters {
        let points: Map<String, Value> = character
            .points
            .iter()
            .map(|(n, p)| (n.clone(), json!(p)))
            .collect();
        let confidence: Map<String, Value> = character
            .points
            .iter()
            .zip(&character.confidence)
            .map(|((n, _), c)| (n.clone(), json!(c)))
            .collect();
        let mut body = json!({
            "character": character.name,
            "points": points,
            "confidence": confidence,
        });
        if let Some(curve) = &character.curve {
            body["curve"] = json!(curve);
        }
        if let Some(head) = &character.head {
            body["head"] = json!(head);
        }
        if let Some(rig) = &character.rig {
            body["rig"] = json!(rig);
        }
        writer.write_json(
            &format!("/character/{}", character.name),
            log_time,
            &stamped(body),
        )?;
    }
    Ok(())
}

/// The protocol's rule ([`mouthpiece_server::protocol::valid_slate`]): what a client may
/// not ask for, the daemon does not record either.
pub fn valid_slate(slate: &str) -> bool {
    mouthpiece_server::protocol::valid_slate(slate)
}

/// `<slate>_T<take>_<YYYYMMDDTHHMMSSZ>.mcap`
pub fn file_name(slate: &str, take: u32, started: SystemTime) -> String {
    format!("{slate}_T{take:03}_{}.mcap", utc_stamp(started))
}

/// One more than the highest take number of `slate` in `folder` (1 when none).
pub fn next_take(folder: &Path, slate: &str) -> u32 {
    let prefix = format!("{slate}_T");
    let highest = std::fs::read_dir(folder)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|entry| {
            let name = entry.file_name().into_string().ok()?;
            let rest = name.strip_prefix(&prefix)?;
            let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
            if rest[digits.len()..].starts_with('_') {
                digits.parse::<u32>().ok()
            } else {
                None
            }
        })
        .max();
    highest.map_or(1, |h| h.saturating_add(1))
}

/// `YYYYMMDDTHHMMSSZ` in UTC.
pub fn utc_stamp(time: SystemTime) -> String {
    let secs = time.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs()) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let (y, m, d) = civil_from_days(days);
    format!(
        "{y:04}{m:02}{d:02}T{:02}{:02}{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

/// Days since 1970-01-01 → (year, month, day), proleptic Gregorian (H. Hinnant's algorithm).
fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let y = yoe + era * 400;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (if m <= 2 { y + 1 } else { y }, m, d)
}

pub fn unix_us(time: SystemTime) -> i64 {
    time.duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as i64)
}

/// Free space for unprivileged users on the file system holding `path`, MB.
pub fn free_mb(path: &Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c_path = std::ffi::CString::new(path.as_os_str().as_bytes()).ok()?;
    // SAFETY: statvfs is plain data; all-zero is a valid value to be overwritten.
    let mut stat: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: `c_path` is a valid NUL-terminated string and `stat` a valid out-pointer.
    let rc = unsafe { libc::statvfs(c_path.as_ptr(), &mut stat) };
    if rc != 0 {
        return None;
    }
    Some((stat.f_bavail as u64).saturating_mul(stat.f_frsize as u64) / (1024 * 1024))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_slate_rule_for_protocol_config_and_takes() {
        for (slate, ok) in [
            ("scene4", true),
            ("Scene_4.b-2", true),
            ("4", true),
            ("-rf", false),
            (".hidden", false),
            ("_x", false),
            ("..", false),
            ("", false),
            ("a b", false),
            ("a/b", false),
            ("\u{e9}t\u{e9}", false),
            (&"a".repeat(64), true),
            (&"a".repeat(65), false),
        ] {
            assert_eq!(valid_slate(slate), ok, "{slate:?}");
            assert_eq!(
                mouthpiece_config::Slate::try_from(slate.to_owned()).is_ok(),
                ok,
                "config: {slate:?}"
            );
            let message = serde_json::json!({"type": "record", "action": "start", "slate": slate});
            assert_eq!(
                mouthpiece_server::protocol::parse_client_message(&message.to_string()).is_ok(),
                ok,
                "protocol: {slate:?}"
            );
        }
    }

    #[test]
    fn file_names_carry_slate_take_and_utc_time() {
        // 2026-11-22 03:04:05 UTC
        let t = UNIX_EPOCH + Duration::from_secs(1_795_316_645);
        assert_eq!(
            file_name("scene12", 7, t),
            "scene12_T007_20261122T030405Z.mcap"
        );
        assert_eq!(utc_stamp(UNIX_EPOCH), "19700101T000000Z");
        // Leap day.
        assert_eq!(
            utc_stamp(UNIX_EPOCH + Duration::from_secs(951_782_400)),
            "20000229T000000Z"
        );
    }

    #[test]
    fn next_take_follows_the_highest_of_the_slate() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(next_take(dir.path(), "sc1"), 1);
        for name in [
            "sc1_T001_20260101T000000Z.mcap",
            "sc1_T009_20260101T000100Z.mcap",
            "sc10_T050_x.mcap",
            "sc1_Tx.mcap",
        ] {
            std::fs::write(dir.path().join(name), b"").unwrap();
        }
        assert_eq!(next_take(dir.path(), "sc1"), 10);
        assert_eq!(next_take(dir.path(), "sc10"), 51);
        assert_eq!(next_take(dir.path(), "other"), 1);
    }

    #[test]
    fn slates_that_are_not_file_names_are_rejected() {
        assert!(valid_slate("scene-12_b.2"));
        for bad in ["", "../x", ".hidden", "-rf", "a b", "a/b", &"x".repeat(65)] {
            assert!(!valid_slate(bad), "{bad:?}");
        }
    }

    fn settings(folder: &Path) -> TakeSettings {
        TakeSettings {
            folder: folder.to_owned(),
            flush: Duration::from_millis(100),
            min_free_mb: 0,
            queue_frames: 64,
            timecode_rate: "30".into(),
            max_write_bytes_s: None,
        }
    }

    fn frame(seq: u64) -> Arc<Frame> {
        use mouthpiece_frame::{Calibration, ColorImage, DepthImage, Intrinsics};
        let mut color = ColorImage::new(64, 48);
        color
            .data
            .iter_mut()
            .enumerate()
            .for_each(|(i, b)| *b = (i as u64 * 7 + seq) as u8);
        let mut depth = DepthImage::new(64, 48);
        depth
            .data
            .iter_mut()
            .enumerate()
            .for_each(|(i, d)| *d = 600 + (i as u16 % 50));
        Arc::new(Frame {
            seq,
            device_ts_us: seq * 33_333,
            host_rx: Instant::now(),
            wall_clock: Some(
                UNIX_EPOCH + Duration::from_micros(1_795_316_645_000_000 + seq * 33_333),
            ),
            color,
            depth,
            calibration: Arc::new(Calibration::registered(Intrinsics::ideal(
                64, 48, 52.5, 52.5, 31.5, 23.5,
            ))),
        })
    }

    fn derived(seq: u64) -> Box<Derived> {
        Box::new(Derived {
            seq,
            t: seq as f64 / 30.0,
            wall_us: 1_795_316_645_000_000 + seq as i64 * 33_333,
            timecode: format!("03:04:05:{:02}", seq % 30),
            performer: vec![("D1".into(), Some([0.01, 0.02, 0.6])), ("F1".into(), None)],
            stabilised: vec![("D1".into(), [0.025, 0.0, 0.0], 1.0)],
            head: HeadRecord {
                rotation: [1.0, 0.0, 0.0, 0.0],
                translation: [0.0; 3],
                lost: false,
            },
            characters: vec![CharacterRecord {
                name: "wolf".into(),
                points: vec![("P1".into(), [0.07, 0.0, 0.0])],
                confidence: vec![1.0],
                curve: None,
                head: Some(Default::default()),
                rig: (seq >= 5).then(|| rig(seq)),
            }],
            status: serde_json::json!({"calibrating": false}),
        })
    }

    /// A rig with values that differ per frame.
    fn rig(seq: u64) -> mouthpiece_server::RigState {
        let mut rig = mouthpiece_server::RigState::default();
        rig.jaw.angle_deg = seq as f32;
        rig.jaw.slide_m = -0.0005 * seq as f32;
        for (k, c) in rig.curves.0.iter_mut().enumerate() {
            *c = ((k as u64 + seq) % 10) as f32 / 10.0;
        }
        rig
    }

    /// The `/character/<name>` messages of a take, in order.
    fn character_messages(path: &Path, name: &str) -> Vec<serde_json::Value> {
        let mut reader = mouthpiece_recording::MessageReader::open(path).unwrap();
        let topic = format!("/character/{name}");
        let mut out = Vec::new();
        while let Some(message) = reader.next_message().unwrap() {
            if *message.topic == *topic {
                out.push(serde_json::from_slice(&message.data).unwrap());
            }
        }
        out
    }

    #[test]
    fn the_rig_is_recorded_per_frame_once_there_is_one() {
        let dir = tempfile::tempdir().unwrap();
        let mut takes = Takes::new(settings(dir.path()));
        let info = start_wait(&mut takes, "rig", None).unwrap();
        for seq in 0..10 {
            takes.push(frame(seq), derived(seq));
        }
        stop_wait(&mut takes).unwrap();
        let messages = character_messages(&info.path, "wolf");
        assert_eq!(messages.len(), 10);
        for m in &messages {
            let seq = m["seq"].as_u64().unwrap();
            if seq < 5 {
                // Before the neutral pose: no `rig` key at all (as in takes made before the
                // rig existed), and the rest of the message as ever.
                assert!(m.get("rig").is_none(), "{m}");
                assert_eq!(m["points"]["P1"], serde_json::json!([0.07f32, 0.0, 0.0]));
                continue;
            }
            let want = rig(seq);
            assert_eq!(m["rig"]["jaw"]["angle_deg"], want.jaw.angle_deg, "{m}");
            assert_eq!(m["rig"]["jaw"]["slide_m"], want.jaw.slide_m, "{m}");
            let curves = m["rig"]["curves"].as_object().unwrap();
            let names: std::collections::BTreeSet<&str> =
                curves.keys().map(String::as_str).collect();
            let want_names = mouthpiece_server::RIG_CURVE_NAMES.into_iter().collect();
            assert_eq!(names, want_names, "every curve, by name");
            for (k, name) in mouthpiece_server::RIG_CURVE_NAMES.iter().enumerate() {
                assert_eq!(curves[*name], want.curves.0[k], "{name} at {seq}");
            }
            assert_eq!(m["rig"]["lips"]["upper"]["rotation"][0], 1.0, "{m}");
        }
    }

    fn topics(path: &Path) -> (std::collections::BTreeMap<String, usize>, Vec<String>) {
        let mut reader = mouthpiece_recording::MessageReader::open(path).unwrap();
        let mut topics = std::collections::BTreeMap::new();
        while let Some(message) = reader.next_message().unwrap() {
            *topics.entry(message.topic.to_string()).or_insert(0) += 1;
        }
        let metadata = reader
            .metadata()
            .iter()
            .map(|(name, _)| name.clone())
            .collect();
        (topics, metadata)
    }

    /// Depth messages readable from a file being written (0 while its header is not out).
    fn depth_messages(path: &Path) -> usize {
        let Ok(mut reader) = mouthpiece_recording::MessageReader::open(path) else {
            return 0;
        };
        let mut n = 0;
        while let Ok(Some(message)) = reader.next_message() {
            n += usize::from(&*message.topic == "/camera/depth");
        }
        n
    }

    const WAIT: Duration = Duration::from_secs(10);

    /// Starts a take and waits for the writer thread's answer.
    fn start_wait(takes: &mut Takes, slate: &str, take: Option<u32>) -> Result<TakeInfo, String> {
        let (tx, rx) = crossbeam_channel::bounded(1);
        takes.start(
            slate,
            take,
            "replay:test.mcap",
            Box::new(move |r| {
                let _ = tx.send(r);
            }),
            Box::new(|_| {}),
        );
        rx.recv_timeout(WAIT).expect("the writer answers")
    }

    /// Stops the take and waits until it is closed.
    fn stop_wait(takes: &mut Takes) -> Result<TakeEnded, String> {
        let (tx, rx) = crossbeam_channel::bounded(1);
        takes.stop(Box::new(move |r| {
            let _ = tx.send(r);
        }));
        rx.recv_timeout(WAIT).expect("the writer answers")
    }

    #[test]
    fn a_take_holds_raw_frames_and_every_derived_channel() {
        let dir = tempfile::tempdir().unwrap();
        let mut takes = Takes::new(settings(dir.path()));
        let info = start_wait(&mut takes, "scene1", None).unwrap();
        assert_eq!(info.take, 1);
        for seq in 0..10 {
            takes.push(frame(seq), derived(seq));
        }
        let ended = stop_wait(&mut takes).unwrap();
        assert_eq!((ended.frames, ended.dropped, ended.error), (10, 0, None));
        let (topics, metadata) = topics(&info.path);
        for topic in [
            "/camera/color",
            "/camera/depth",
            "/performer/points",
            "/performer/stabilised",
            "/head",
            "/character/wolf",
        ] {
            assert_eq!(topics.get(topic), Some(&10), "{topic}: {topics:?}");
        }
        assert!(topics.contains_key("/camera/calibration"), "{topics:?}");
        assert!(
            metadata.iter().any(|m| m == "mouthpiece.take"),
            "{metadata:?}"
        );
        // The next take of the slate counts on.
        let next = start_wait(&mut takes, "scene1", None).unwrap().take;
        assert_eq!(next, 2);
        stop_wait(&mut takes).unwrap();
        let err = stop_wait(&mut takes).unwrap_err();
        assert!(err.contains("no take is recording"), "{err}");
    }

    #[test]
    fn a_take_killed_mid_way_is_readable_up_to_its_last_flush() {
        let dir = tempfile::tempdir().unwrap();
        let mut takes = Takes::new(settings(dir.path()));
        let path = start_wait(&mut takes, "crash", Some(3)).unwrap().path;
        // Frames 100 ms apart in capture time: every frame closes a chunk (flush = 100 ms).
        for seq in 0..8 {
            let mut f = (*frame(seq)).clone();
            f.wall_clock = Some(UNIX_EPOCH + Duration::from_millis(1_795_316_645_000 + seq * 100));
            takes.push(Arc::new(f), derived(seq));
        }
        // Wait for the writer to drain, then copy the file as a kill -9 would leave it: no
        // summary, no footer.
        let deadline = Instant::now() + Duration::from_secs(10);
        while Instant::now() < deadline && depth_messages(&path) < 7 {
            std::thread::sleep(Duration::from_millis(20));
        }
        let snapshot = dir.path().join("killed.mcap");
        std::fs::copy(&path, &snapshot).unwrap();
        stop_wait(&mut takes).unwrap();
        let (topics, _) = topics(&snapshot);
        assert!(
            topics.get("/camera/depth").copied().unwrap_or(0) >= 7,
            "{topics:?}"
        );
        assert!(
            topics.get("/character/wolf").copied().unwrap_or(0) >= 7,
            "{topics:?}"
        );
    }

    #[test]
    fn a_capped_take_file_writes_no_faster_than_its_cap() {
        use std::io::Write;
        let dir = tempfile::tempdir().unwrap();
        let file = std::fs::File::create(dir.path().join("capped")).unwrap();
        let mut capped = TakeFile::new(file, Some(1e6));
        let started = Instant::now();
        for _ in 0..5 {
            capped.write_all(&[7u8; 60_000]).unwrap();
        }
        // 300 kB at 1 MB/s: 0.3 s at least.
        assert!(
            started.elapsed() >= Duration::from_millis(300),
            "{:?}",
            started.elapsed()
        );
        assert_eq!(
            std::fs::metadata(dir.path().join("capped")).unwrap().len(),
            300_000
        );
    }

    #[test]
    fn disk_full_stops_the_take_and_says_so() {
        // /dev/full fails every write with ENOSPC.
        let file = std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap();
        let writer = SessionWriter::new(
            std::io::BufWriter::new(TakeFile::new(file, None)),
            "/dev/full".into(),
            WriterOptions {
                flush_interval: Duration::from_millis(10),
                ..WriterOptions::default()
            },
        )
        .unwrap();
        let (queue, items) = crossbeam_channel::bounded(64);
        for seq in 0..10 {
            queue
                .send(TakeItem::Frame {
                    frame: frame(seq),
                    derived: derived(seq),
                })
                .unwrap();
        }
        drop(queue);
        let dir = tempfile::tempdir().unwrap();
        let failed = AtomicBool::new(false);
        let result = write_take(writer, items, &settings(dir.path()), &failed);
        let error = result.error.unwrap();
        assert!(error.contains("No space left on device"), "{error}");
        assert!(failed.load(Ordering::Acquire));
    }

    #[test]
    fn a_take_that_cannot_start_says_why_and_stops_recording() {
        let dir = tempfile::tempdir().unwrap();
        let not_a_folder = dir.path().join("file");
        std::fs::write(&not_a_folder, b"").unwrap();
        let mut takes = Takes::new(settings(&not_a_folder));
        let err = start_wait(&mut takes, "s", None).unwrap_err();
        assert!(err.contains("takes folder"), "{err}");
        let deadline = Instant::now() + WAIT;
        while takes.is_recording() && Instant::now() < deadline {
            takes.poll();
            std::thread::sleep(Duration::from_millis(5));
        }
        assert!(!takes.is_recording());
        // A stop that comes after the failure is answered too.
        let err = stop_wait(&mut takes).unwrap_err();
        assert!(err.contains("no take"), "{err}");
    }

    #[test]
    fn takes_never_overwrite_a_file_or_follow_a_link() {
        let dir = tempfile::tempdir().unwrap();
        let mut takes = Takes::new(settings(dir.path()));
        // Links where the next takes would go (this second and the next few), to a file
        // that must stay untouched.
        let victim = dir.path().join("victim");
        std::fs::write(&victim, b"precious").unwrap();
        let now = SystemTime::now();
        for s in 0..3 {
            std::os::unix::fs::symlink(
                &victim,
                dir.path()
                    .join(file_name("s", 1, now + Duration::from_secs(s))),
            )
            .unwrap();
        }
        let mut paths = Vec::new();
        for _ in 0..3 {
            // The same slate and take number, within the same second.
            let info = start_wait(&mut takes, "s", Some(1)).unwrap();
            takes.push(frame(0), derived(0));
            let ended = stop_wait(&mut takes).unwrap();
            assert_eq!(ended.frames, 1);
            paths.push(info.path);
        }
        assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
        paths.sort();
        paths.dedup();
        assert_eq!(paths.len(), 3, "{paths:?}");
        for path in &paths {
            assert!(!path.is_symlink(), "{}", path.display());
            assert_eq!(topics(path).0.get("/camera/depth"), Some(&1));
        }
    }

    #[test]
    fn starting_and_stopping_never_wait_for_the_writer() {
        let dir = tempfile::tempdir().unwrap();
        let mut takes = Takes::new(settings(dir.path()));
        // The writer thread is held inside its start callback: if `start` or `stop`
        // waited for it (file creation, draining), this test would hang.
        let (release, held) = crossbeam_channel::bounded::<()>(1);
        let (started_tx, started_rx) = crossbeam_channel::bounded(1);
        takes.start(
            "s",
            None,
            "x",
            Box::new(move |r| {
                let _ = held.recv_timeout(WAIT);
                let _ = started_tx.send(r);
            }),
            Box::new(|_| {}),
        );
        for seq in 0..5 {
            takes.push(frame(seq), derived(seq));
        }
        let (stopped_tx, stopped_rx) = crossbeam_channel::bounded(1);
        let before = Instant::now();
        takes.stop(Box::new(move |r| {
            let _ = stopped_tx.send(r);
        }));
        assert!(before.elapsed() < Duration::from_secs(1));
        assert!(stopped_rx.try_recv().is_err(), "not closed yet");
        release.send(()).unwrap();
        started_rx.recv_timeout(WAIT).unwrap().unwrap();
        let ended = stopped_rx.recv_timeout(WAIT).unwrap().unwrap();
        assert_eq!(
            ended.frames, 5,
            "frames queued before the file opened are kept"
        );
        takes.shutdown();
    }

    #[test]
    fn free_space_is_reported() {
        let dir = tempfile::tempdir().unwrap();
        assert!(free_mb(dir.path()).is_some());
        assert_eq!(free_mb(Path::new("/nonexistent/x")), None);
    }
}
