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
    LowSpace { path: PathBuf, free_mb: u64, min_mb: u64 },
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
    Frame { frame: Arc<Frame>, derived: Box<Derived> },
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
        Takes { settings, active: None, drop_warnings: Throttle::new(Duration::from_secs(10)) }
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
    pub fn start(&mut self, slate: &str, take: Option<u32>, source: &str) -> Result<&TakeInfo, TakeError> {
        if let Some(active) = &self.active {
            return Err(TakeError::AlreadyRecording(active.info.path.display().to_string()));
        }
        if !valid_slate(slate) {
            return Err(TakeError::BadSlate(slate.to_owned()));
        }
        let folder = &self.settings.folder;
        std::fs::create_dir_all(folder)
            .map_err(|source| TakeError::Folder { path: folder.clone(), source })?;
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
        let options = WriterOptions { flush_interval: self.settings.flush, ..WriterOptions::default() };
        let mut writer = SessionWriter::create(&path, options)?;
        let start_us = unix_us(started);
        writer.write_metadata(
            "mouthpiece.take",
            [
                ("slate".to_owned(), slate.to_owned()),
                ("take".to_owned(), take.to_string()),
                ("started_unix_us".to_owned(), start_us.to_string()),
                ("timecode_rate".to_owned(), self.settings.timecode_rate.clone()),
                ("source".to_owned(), source.to_owned()),
            ]
            .into_iter()
            .collect(),
        )?;
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
                .spawn(move || write_take(writer, items, settings, failed, stop))
                .map_err(TakeError::Thread)?
        };
        let info = TakeInfo { slate: slate.to_owned(), take, path, started };
        tracing::info!(slate, take, path = %info.path.display(), "take started");
        self.drop_warnings.reset();
        self.active = Some(Active { info, queue, writer: thread, failed, stop, dropped });
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
                    tracing::warn!(total, held_back, "take writer behind: frame dropped from the take");
                }
            }
        }
    }

    /// `Some` when the writer stopped by itself (disk full, write error): the take is over.
    pub fn poll(&mut self) -> Option<TakeEnded> {
        let failed = self.active.as_ref()?.failed.lock().unwrap_or_else(|p| p.into_inner()).clone();
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
            Some(error) => tracing::error!(path = %ended.info.path.display(), frames = ended.frames,
                "take stopped: {error}"),
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
    items: Receiver<TakeItem>,
    settings: TakeSettings,
    failed: Arc<Mutex<Option<String>>>,
    stop: Arc<AtomicBool>,
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
        return WriterResult { frames, error: Some(message) };
    }
    WriterResult { frames, error: None }
}

fn write_one(
    writer: &mut SessionWriter,
    frame: &Frame,
    derived: &Derived,
) -> Result<(), mouthpiece_recording::RecordingError> {
    let log_time = writer.write_frame(frame)?;
    #[derive(Serialize)]
    struct Stamp<'a, T: Serialize> {
        seq: u64,
        t: f64,
        wall_us: i64,
        timecode: &'a str,
        #[serde(flatten)]
        body: T,
    }
    let stamp = |body| Stamp { seq: derived.seq, t: derived.t, wall_us: derived.wall_us, timecode: &derived.timecode, body };
    #[derive(Serialize)]
    struct Points<'a, P: Serialize> {
        points: serde_json::Map<String, serde_json::Value>,
        #[serde(skip_serializing_if = "Option::is_none")]
        confidence: Option<P>,
        #[serde(skip_serializing_if = "Option::is_none")]
        status: Option<&'a serde_json::Value>,
    }
    let performer: serde_json::Map<_, _> = derived
        .performer
        .iter()
        .map(|(name, p)| (name.clone(), serde_json::json!(p)))
        .collect();
    writer.write_json(
        "/performer/points",
        log_time,
        &stamp(Points::<()> { points: performer, confidence: None, status: Some(&derived.status) }),
    )?;
    if !derived.stabilised.is_empty() {
        let points = derived.stabilised.iter().map(|(n, p, _)| (n.clone(), serde_json::json!(p))).collect();
        let confidence: serde_json::Map<_, _> =
            derived.stabilised.iter().map(|(n, _, c)| (n.clone(), serde_json::json!(c))).collect();
        writer.write_json(
            "/performer/stabilised",
            log_time,
            &stamp(Points { points, confidence: Some(confidence), status: None }),
        )?;
    }
    writer.write_json("/head", log_time, &stamp(&derived.head))?;
    for character in &derived.characters {
        let points = character.points.iter().map(|(n, p)| (n.clone(), serde_json::json!(p))).collect();
        let confidence: serde_json::Map<_, _> = character
            .points
            .iter()
            .zip(&character.confidence)
            .map(|((n, _), c)| (n.clone(), serde_json::json!(c)))
            .collect();
        #[derive(Serialize)]
        struct CharacterBody<'a> {
            character: &'a str,
            #[serde(flatten)]
            points: Points<'a, serde_json::Map<String, serde_json::Value>>,
            #[serde(skip_serializing_if = "Option::is_none")]
            curve: Option<&'a Vec<[f32; 3]>>,
        }
        writer.write_json(
            &format!("/character/{}", character.name),
            log_time,
            &stamp(CharacterBody {
                character: &character.name,
                points: Points { points, confidence: Some(confidence), status: None },
                curve: character.curve.as_ref(),
            }),
        )?;
    }
    Ok(())
}

/// Letters, digits, `-`, `_`, `.`; 1-64 characters; not starting with `.`.
pub fn valid_slate(slate: &str) -> bool {
    !slate.is_empty()
        && slate.len() <= 64
        && !slate.starts_with('.')
        && slate.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
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
    format!("{y:04}{m:02}{d:02}T{:02}{:02}{:02}Z", rem / 3600, rem % 3600 / 60, rem % 60)
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
    time.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_micros() as i64)
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
        assert_eq!(file_name("scene12", 7, t), "scene12_T007_20261122T030405Z.mcap");
        assert_eq!(utc_stamp(UNIX_EPOCH), "19700101T000000Z");
        // Leap day.
        assert_eq!(utc_stamp(UNIX_EPOCH + Duration::from_secs(951_782_400)), "20000229T000000Z");
    }

    #[test]
    fn next_take_follows_the_highest_of_the_slate() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(next_take(dir.path(), "sc1"), 1);
        for name in ["sc1_T001_20260101T000000Z.mcap", "sc1_T009_20260101T000100Z.mcap", "sc10_T050_x.mcap", "sc1_Tx.mcap"] {
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

    #[test]
    fn free_space_is_reported() {
        let dir = tempfile::tempdir().unwrap();
        assert!(free_mb(dir.path()).is_some());
        assert_eq!(free_mb(Path::new("/nonexistent/x")), None);
    }
}
