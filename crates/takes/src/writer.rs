//! A take's writer thread: opens the take's file, writes every frame and its derived
//! channels, watches the free space, and closes and syncs the file.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use crossbeam_channel::Receiver;
use mouthpiece_frame::AudioSubscription;
use mouthpiece_output::error_chain;
use mouthpiece_recording::{AudioTrack, SessionWriter, WriterOptions};

use crate::file::{
    create_new_take_file, file_name, free_mb, next_take, sync_take, unix_us, TakeFile,
};
use crate::{
    Derived, OnEnded, OnStarted, StopSlot, TakeEnded, TakeError, TakeInfo, TakeItem, TakeSettings,
};

/// Everything a take's writer thread needs.
pub(crate) struct WriterJob {
    pub(crate) slate: String,
    pub(crate) take: Option<u32>,
    pub(crate) source: String,
    pub(crate) settings: TakeSettings,
    pub(crate) naming: Arc<Mutex<()>>,
    pub(crate) items: Receiver<TakeItem>,
    pub(crate) failed: Arc<AtomicBool>,
    pub(crate) dropped: Arc<AtomicU64>,
    pub(crate) started: OnStarted,
    pub(crate) ended: OnEnded,
    pub(crate) on_stopped: Arc<Mutex<StopSlot>>,
    /// The take's subscription to the audio thread (with `[audio]` or a replayed sound).
    pub(crate) audio: Option<AudioSubscription>,
}

impl WriterJob {
    pub(crate) fn run(self) {
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
                let message = error_chain(&e);
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
        let result = write_take(writer, self.items, self.audio, &self.settings, &self.failed);
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
    writer.write_metadata(crate::read::TAKE_METADATA, metadata)?;
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

pub(crate) type TakeWriter = SessionWriter<std::io::BufWriter<TakeFile>>;

pub(crate) struct WriterResult {
    pub(crate) frames: u64,
    pub(crate) error: Option<String>,
}

pub(crate) fn write_take(
    mut writer: TakeWriter,
    items: Receiver<TakeItem>,
    audio: Option<AudioSubscription>,
    settings: &TakeSettings,
    failed: &AtomicBool,
) -> WriterResult {
    let mut frames = 0;
    let mut last_space_check = Instant::now();
    let mut error = None;
    let mut track = AudioTrack::default();
    let never = crossbeam_channel::never();
    let sound = audio.as_ref().map_or(&never, |a| &a.events);
    // Runs until the queue is closed (stop) and drained, or a write fails.
    loop {
        let item = crossbeam_channel::select! {
            recv(items) -> item => match item {
                Ok(item) => item,
                Err(_) => break,
            },
            recv(sound) -> event => {
                if let Ok(event) = event {
                    if let Err(e) = track.write(&mut writer, event) {
                        error = Some(error_chain(&e));
                        break;
                    }
                }
                continue;
            }
        };
        let written = match item {
            TakeItem::Frame { frame, derived } => writer
                .write_frame(&frame)
                .and_then(|log_time| write_derived(&mut writer, log_time, &derived)),
            TakeItem::Step { derived } => {
                let log_time = u64::try_from(derived.wall_us).unwrap_or(0) * 1000;
                write_derived(&mut writer, log_time, &derived)
            }
        };
        if let Err(e) = written {
            error = Some(error_chain(&e));
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
    if error.is_none() {
        // The sound already queued when the take stopped, and the summary.
        for event in sound.try_iter() {
            if let Err(e) = track.write(&mut writer, event) {
                error = Some(error_chain(&e));
                break;
            }
        }
    }
    if let (None, Some(audio)) = (&error, &audio) {
        if let Err(e) = track.finish(&mut writer, audio.dropped()) {
            error = Some(error_chain(&e));
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
            error: Some(error_chain(&e)),
        };
    }
    WriterResult {
        frames,
        error: None,
    }
}

/// The derived channels of one frame or step, logged at `log_time` (ns).
fn write_derived(
    writer: &mut TakeWriter,
    log_time: u64,
    derived: &Derived,
) -> Result<(), mouthpiece_recording::RecordingError> {
    use serde_json::{json, Map, Value};
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
        crate::read::TOPIC_POINTS,
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
    writer.write_json(
        crate::read::TOPIC_HEAD,
        log_time,
        &stamped(json!(derived.head)),
    )?;
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
            "source": character.source.as_str(),
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
            &format!("{}{}", crate::read::CHARACTER_PREFIX, character.name),
            log_time,
            &stamped(body),
        )?;
    }
    Ok(())
}
