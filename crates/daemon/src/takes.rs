//! Takes: recording while live, like the booth's audio recorder.
//!
//! One MCAP file per take in the configured folder, named
//! `<slate>_T<take, 3 digits>_<UTC start, YYYYMMDDTHHMMSSZ>.mcap`, holding the raw frames
//! (`/camera/color`, `/camera/depth`, `/camera/calibration`) and every derived channel as JSON:
//! `/performer/points` (tracked dots, camera frame), `/performer/stabilised` (lip dots in the
//! neutral mouth frame), `/head`, and `/character/<name>` per character. Every derived message
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
    #[error("a take is already recording ({0})")]
    AlreadyRecording(String),
    #[error("no take is recording")]
    NotRecording,
    #[error("invalid slate {0:?}: use 1-64 letters, digits, '-', '_' or '.'")]
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

struct Active {
    info: TakeInfo,
    queue: Sender<TakeItem>,
    writer: JoinHandle<WriterResult>,
    failed: Arc<Mutex<Option<String>>>,
    stop: Arc<AtomicBool>,
    dropped: Arc<AtomicU64>,
}

struct WriterResult {
    frames: u64,
    error: Option<String>,
}

/// How a take ended.
#[derive(Debug, Clone, PartialEq)]
pub struct TakeEnded {
    pub info: TakeInfo,
    pub frames: u64,
    /// Items dropped because the writer fell behind.
    pub dropped: u64,
    /// Why it stopped by itself (disk full, write error); `None` when stopped on request.
    pub error: Option<String>,
}

/// The take recorder owned by the processing thread.
pub struct Takes {
    settings: TakeSettings,
    active: Option<Active>,
    drop_warnings: Throttle,
}

impl Takes {
    pub fn new(settings: TakeSettings) -> Self {
        Takes {
            settings,
            active: None,
            drop_warnings: Throttle::new(Duration::from_secs(10)),
        }
    }

    pub fn settings(&self) -> &TakeSettings {
        &self.settings
    }

    pub fn current(&self) -> Option<&TakeInfo> {
        self.active.as_ref().map(|a| &a.info)
    }

    pub fn is_recording(&self) -> bool {
        self.active.is_some()
    }

    /// Starts a take. `take = None` picks one more than the highest take of this slate in
    /// the folder.
    pub fn start(
        &mut self,
        slate: &str,
        take: Option<u32>,
        source: &str,
    ) -> Result<&TakeInfo, TakeError> {
        if let Some(active) = &self.active {
            return Err(TakeError::AlreadyRecording(
                active.info.path.display().to_string(),
            ));
        }
        if !valid_slate(slate) {
            return Err(TakeError::BadSlate(slate.to_owned()));
        }
        let folder = &self.settings.folder;
        std::fs::create_dir_all(folder).map_err(|source| TakeError::Folder {
            path: folder.clone(),
            source,
        })?;
        if let Some(free_mb) = free_mb(folder) {
            if free_mb < self.settings.min_free_mb {
                return Err(TakeError::LowSpace {
                    path: folder.clone(),
                    free_mb,
                    min_mb: self.settings.min_free_mb,
                });
            }
        }
        let take = take.unwrap_or_else(|| next_take(folder, slate));
        let started = SystemTime::now();
        let path = folder.join(file_name(slate, take, started));
        let options = WriterOptions {
            flush_interval: self.settings.flush,
            ..WriterOptions::default()
        };
        let writer = SessionWriter::create(&path, options)?;
        let metadata: std::collections::BTreeMap<String, String> = [
            ("slate".to_owned(), slate.to_owned()),
            ("take".to_owned(), take.to_string()),
            ("started_unix_us".to_owned(), unix_us(started).to_string()),
            (
                "timecode_rate".to_owned(),
                self.settings.timecode_rate.clone(),
            ),
            ("source".to_owned(), source.to_owned()),
        ]
        .into_iter()
        .collect();
        let (queue, items) = crossbeam_channel::bounded(self.settings.queue_frames.max(1));
        let failed = Arc::new(Mutex::new(None));
        let stop = Arc::new(AtomicBool::new(false));
        let dropped = Arc::new(AtomicU64::new(0));
        let thread = {
            let failed = failed.clone();
            let stop = stop.clone();
            let settings = self.settings.clone();
            std::thread::Builder::new()
                .name("mouthpiece-take".into())
                .spawn(move || write_take(writer, metadata, items, settings, failed, stop))
                .map_err(TakeError::Thread)?
        };
        let info = TakeInfo {
            slate: slate.to_owned(),
            take,
            path,
            started,
        };
        tracing::info!(slate, take, path = %info.path.display(), "take started");
        self.drop_warnings.reset();
        self.active = Some(Active {
            info,
            queue,
            writer: thread,
            failed,
            stop,
            dropped,
        });
        Ok(&self.active.as_ref().expect("just set").info)
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

    /// `Some` when the writer stopped by itself (disk full, write error): the take is over.
    pub fn poll(&mut self) -> Option<TakeEnded> {
        let failed = self
            .active
            .as_ref()?
            .failed
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone();
        failed.map(|_| self.finish())
    }

    /// Stops the take: the writer drains its queue, writes the summary and closes the file.
    pub fn stop(&mut self) -> Result<TakeEnded, TakeError> {
        if self.active.is_none() {
            return Err(TakeError::NotRecording);
        }
        Ok(self.finish())
    }

    fn finish(&mut self) -> TakeEnded {
        let active = self.active.take().expect("checked by callers");
        active.stop.store(true, Ordering::Release);
        drop(active.queue);
        let result = active.writer.join().unwrap_or_else(|_| WriterResult {
            frames: 0,
            error: Some("the take writer panicked".into()),
        });
        let ended = TakeEnded {
            info: active.info,
            frames: result.frames,
            dropped: active.dropped.load(Ordering::Relaxed),
            error: result.error,
        };
        match &ended.error {
            None => tracing::info!(path = %ended.info.path.display(), frames = ended.frames,
                dropped = ended.dropped, "take closed"),
            Some(error) => {
                tracing::error!(path = %ended.info.path.display(), frames = ended.frames,
                "take stopped: {error}")
            }
        }
        ended
    }
}

impl Drop for Takes {
    fn drop(&mut self) {
        if self.active.is_some() {
            self.finish();
        }
    }
}

fn write_take(
    mut writer: SessionWriter,
    metadata: std::collections::BTreeMap<String, String>,
    items: Receiver<TakeItem>,
    settings: TakeSettings,
    failed: Arc<Mutex<Option<String>>>,
    stop: Arc<AtomicBool>,
) -> WriterResult {
    let mut frames = 0;
    let mut last_space_check = Instant::now();
    // Written here, not in `start`: all file I/O stays off the processing thread.
    let mut error = writer
        .write_metadata("mouthpiece.take", metadata)
        .err()
        .map(|e| crate::source::error_chain(&e));
    // Runs until the queue is closed (stop) and drained, or a write fails.
    for item in items.iter().take_while(|_| error.is_none()) {
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
    let _ = stop.load(Ordering::Acquire);
    if let Some(message) = &error {
        *failed.lock().unwrap_or_else(|p| p.into_inner()) = Some(message.clone());
        // Flush what fits; the file stays readable up to its last complete chunk.
        let _ = writer.flush();
        drop(writer);
        return WriterResult { frames, error };
    }
    if let Err(e) = writer.finish() {
        let message = crate::source::error_chain(&e);
        *failed.lock().unwrap_or_else(|p| p.into_inner()) = Some(message.clone());
        return WriterResult {
            frames,
            error: Some(message),
        };
    }
    WriterResult {
        frames,
        error: None,
    }
}

fn write_one(
    writer: &mut SessionWriter,
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
        writer.write_json(
            &format!("/character/{}", character.name),
            log_time,
            &stamped(body),
        )?;
    }
    Ok(())
}

/// Letters, digits, `-`, `_`, `.`; 1-64 characters; not starting with `.`.
pub fn valid_slate(slate: &str) -> bool {
    !slate.is_empty()
        && slate.len() <= 64
        && !slate.starts_with('.')
        && slate
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
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
        for bad in ["", "../x", ".hidden", "a b", "a/b", &"x".repeat(65)] {
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
            }],
            status: serde_json::json!({"calibrating": false}),
        })
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

    #[test]
    fn a_take_holds_raw_frames_and_every_derived_channel() {
        let dir = tempfile::tempdir().unwrap();
        let mut takes = Takes::new(settings(dir.path()));
        let info = takes
            .start("scene1", None, "replay:test.mcap")
            .unwrap()
            .clone();
        assert_eq!(info.take, 1);
        for seq in 0..10 {
            takes.push(frame(seq), derived(seq));
        }
        let ended = takes.stop().unwrap();
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
        let next = takes.start("scene1", None, "x").unwrap().take;
        assert_eq!(next, 2);
        takes.stop().unwrap();
        assert!(matches!(takes.stop(), Err(TakeError::NotRecording)));
    }

    #[test]
    fn a_take_killed_mid_way_is_readable_up_to_its_last_flush() {
        let dir = tempfile::tempdir().unwrap();
        let mut takes = Takes::new(settings(dir.path()));
        let path = takes.start("crash", Some(3), "x").unwrap().path.clone();
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
        takes.stop().unwrap();
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
    fn disk_full_stops_the_take_and_says_so() {
        let dir = tempfile::tempdir().unwrap();
        let mut takes = Takes::new(settings(dir.path()));
        // /dev/full fails every write with ENOSPC: point the take's file at it.
        let started = SystemTime::now();
        let name = file_name("full", 1, started);
        std::os::unix::fs::symlink("/dev/full", dir.path().join(&name)).unwrap();
        std::os::unix::fs::symlink(
            "/dev/full",
            dir.path()
                .join(file_name("full", 1, started + Duration::from_secs(1))),
        )
        .unwrap();
        takes.start("full", Some(1), "x").unwrap();
        let deadline = Instant::now() + Duration::from_secs(10);
        let mut ended = None;
        let mut seq = 0;
        while ended.is_none() && Instant::now() < deadline {
            takes.push(frame(seq), derived(seq));
            seq += 1;
            std::thread::sleep(Duration::from_millis(10));
            ended = takes.poll();
        }
        let ended = ended.expect("the take stopped by itself");
        let error = ended.error.unwrap();
        assert!(error.contains("No space left on device"), "{error}");
        assert!(!takes.is_recording());
    }

    #[test]
    fn free_space_is_reported() {
        let dir = tempfile::tempdir().unwrap();
        assert!(free_mb(dir.path()).is_some());
        assert_eq!(free_mb(Path::new("/nonexistent/x")), None);
    }
}
