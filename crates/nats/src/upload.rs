//! Take upload: every closed take in the takes folder goes to the studio's object store
//! (`<booth>/<file name>`) with its metadata in the key-value bucket.
//!
//! A take is closed once its MCAP file ends with the format's closing magic (the writer
//! writes it last, before syncing); a file still recording, or cut short by a crash, is left
//! alone. The uploader looks at the folder when a take ends (the hub's status lists it),
//! on every (re)connection and every [`SCAN_EVERY`], so a booth that was offline uploads its
//! backlog when the broker returns. After the store has confirmed the object (its size) and
//! the metadata is written, `<file>.uploaded` is created beside the take; the take itself
//! stays on the booth's disk (removing it is the operator's decision).

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use async_nats::connection::State;
use async_nats::jetstream::object_store::ObjectMetadata;
use mouthpiece_server::Hub;
use mouthpiece_takes::read::{TakeMetadata, CHARACTER_PREFIX, TAKE_METADATA, TOPIC_HEAD};

use crate::store::{TakeRecord, TakeStore};
use crate::{Connections, NatsError, NatsSettings};

/// How often the folder is looked at when nothing else prompts it.
pub const SCAN_EVERY: Duration = Duration::from_secs(10);

/// The suffix of the marker written once a take is in the store.
pub const MARKER_SUFFIX: &str = ".uploaded";

/// Most bytes of a take's summary section read (its channels, statistics and indexes).
const MAX_SUMMARY_BYTES: usize = 64 << 20;

pub(crate) async fn run(
    client: async_nats::Client,
    hub: Hub,
    settings: NatsSettings,
    folder: PathBuf,
    connected: Arc<Connections>,
) {
    let counters = hub.nats();
    let mut status = hub.watch_status();
    let mut connections = connected.subscribe();
    let mut tick = tokio::time::interval(SCAN_EVERY);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut store: Option<TakeStore> = None;
    let mut last_take = status.borrow().takes.last().map(|t| t.file.clone());
    loop {
        tokio::select! {
            changed = status.changed() => {
                if changed.is_err() { return; }
                // Only a take that ended prompts a look (status changes for many reasons).
                let last = status.borrow_and_update().takes.last().map(|t| t.file.clone());
                if last == last_take { continue; }
                last_take = last;
            }
            changed = connections.changed() => {
                if changed.is_err() { return; }
            }
            _ = tick.tick() => {}
        }
        let waiting = closed_takes_waiting(&folder, &hub);
        counters
            .takes_waiting
            .store(waiting.len() as u64, Ordering::Relaxed);
        if waiting.is_empty() || client.connection_state() != State::Connected {
            continue;
        }
        if store.is_none() {
            match TakeStore::open(&client, &settings.studio).await {
                Ok(opened) => store = Some(opened),
                Err(e) => {
                    counters.upload_errors.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!("takes not uploaded yet: {e}");
                    continue;
                }
            }
        }
        let Some(opened) = &store else { continue };
        for path in waiting {
            match upload_take(opened, &settings.booth, &path).await {
                Ok(record) => {
                    counters.takes_uploaded.fetch_add(1, Ordering::Relaxed);
                    let _ = counters.takes_waiting.fetch_update(
                        Ordering::Relaxed,
                        Ordering::Relaxed,
                        |n| Some(n.saturating_sub(1)),
                    );
                    tracing::info!(
                        object = record.object,
                        size = record.size,
                        "take uploaded to the studio's object store"
                    );
                }
                Err(e) => {
                    counters.upload_errors.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!(file = %path.display(), "take upload failed, retried later: {e}");
                    // The store may be gone with the connection: open it again next time.
                    store = None;
                    break;
                }
            }
        }
    }
}

/// Closed takes in `folder` without an upload marker, oldest first. The take recording
/// now is left out even when its file looks complete.
pub fn closed_takes_waiting(folder: &Path, hub: &Hub) -> Vec<PathBuf> {
    let recording = hub
        .status()
        .recording
        .and_then(|r| r.file)
        .map(PathBuf::from);
    let Ok(entries) = std::fs::read_dir(folder) else {
        return Vec::new();
    };
    let mut found: Vec<(std::time::SystemTime, PathBuf)> = entries
        .filter_map(Result::ok)
        // The entry's own type, not its target's: a symbolic link is never a take.
        .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .filter(|p| Some(p) != recording.as_ref())
        .filter(|p| std::fs::symlink_metadata(marker_path(p)).is_err())
        .filter(|p| ends_closed(p))
        .map(|p| {
            let modified = std::fs::symlink_metadata(&p)
                .and_then(|m| m.modified())
                .unwrap_or(std::time::UNIX_EPOCH);
            (modified, p)
        })
        .collect();
    found.sort();
    found.into_iter().map(|(_, p)| p).collect()
}

/// `<take>.uploaded`.
pub fn marker_path(take: &Path) -> PathBuf {
    let mut name = take.file_name().unwrap_or_default().to_os_string();
    name.push(MARKER_SUFFIX);
    take.with_file_name(name)
}

/// Opens a take for reading without following a symbolic link (`O_NOFOLLOW`; a link put in
/// the takes folder never sends another file to the store), and only a regular file.
pub fn open_take(path: &Path) -> std::io::Result<std::fs::File> {
    use std::os::unix::fs::OpenOptionsExt as _;
    let file = std::fs::OpenOptions::new()
        .read(true)
        // Non-blocking: opening a FIFO planted under a take's name does not wait for a writer.
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK)
        .open(path)?;
    if !file.metadata()?.is_file() {
        return Err(std::io::Error::other("not a regular file"));
    }
    Ok(file)
}

/// Whether the file ends with MCAP's closing magic (written last when a take closes).
fn ends_closed(path: &Path) -> bool {
    use std::io::{Read, Seek, SeekFrom};
    let Ok(mut file) = open_take(path) else {
        return false;
    };
    let mut end = [0u8; 8];
    file.seek(SeekFrom::End(-8)).is_ok() && file.read_exact(&mut end).is_ok() && end == *mcap::MAGIC
}

/// Uploads one take and its metadata, then writes its marker.
pub async fn upload_take(
    store: &TakeStore,
    booth: &str,
    path: &Path,
) -> Result<TakeRecord, NatsError> {
    let owned = path.to_owned();
    let booth_owned = booth.to_owned();
    let mut record = tokio::task::spawn_blocking(move || read_record(&owned, &booth_owned))
        .await
        .map_err(|e| NatsError::Store(format!("metadata reader died: {e}")))??;
    let mut file = open_take(path)
        .map(tokio::fs::File::from_std)
        .map_err(|e| NatsError::Store(format!("cannot open {}: {e}", path.display())))?;
    let meta = ObjectMetadata {
        name: record.object.clone(),
        description: Some(format!(
            "{} take {} from booth {}",
            record.slate, record.take, record.booth
        )),
        metadata: [
            ("booth".to_owned(), record.booth.clone()),
            ("slate".to_owned(), record.slate.clone()),
            ("take".to_owned(), record.take.to_string()),
            ("timecode".to_owned(), record.timecode.clone()),
        ]
        .into_iter()
        .collect(),
        ..Default::default()
    };
    let info = store
        .objects
        .put(meta, &mut file)
        .await
        .map_err(|e| NatsError::Store(format!("cannot put {}: {e}", record.object)))?;
    if info.size as u64 != record.size {
        return Err(NatsError::Store(format!(
            "the store holds {} bytes of {}, the file has {}",
            info.size, record.object, record.size
        )));
    }
    record.uploaded_unix_us = crate::publish::unix_micros_now();
    let value = serde_json::to_vec(&record).unwrap_or_default();
    store
        .meta
        .put(record.key(), value.into())
        .await
        .map_err(|e| {
            NatsError::Store(format!(
                "cannot write the metadata of {}: {e}",
                record.object
            ))
        })?;
    let marker = serde_json::json!({
        "bucket": info.bucket,
        "object": record.object,
        "size": record.size,
        "digest": info.digest,
        "uploaded_unix_us": record.uploaded_unix_us,
    });
    write_marker(&marker_path(path), marker.to_string().as_bytes())
        .map_err(|e| NatsError::Store(format!("take uploaded but its marker not written: {e}")))?;
    Ok(record)
}

/// Written to a temporary name and renamed: a marker is whole or absent. The temporary file
/// is created new without following links (`O_CREAT | O_EXCL | O_NOFOLLOW`); whatever was at
/// its name (a crash's leftover, a planted link) is removed first, never written through.
fn write_marker(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write as _;
    use std::os::unix::fs::OpenOptionsExt as _;
    let partial = crate::store::partial_path(path);
    match std::fs::remove_file(&partial) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(e),
        _ => {}
    }
    let mut file = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .custom_flags(libc::O_NOFOLLOW)
        .open(&partial)?;
    file.write_all(bytes)?;
    drop(file);
    std::fs::rename(&partial, path)
}

/// A take's record from its file: the `mouthpiece.take` metadata (slate, take, start,
/// rate, source) and the summary (duration, frames, characters).
pub fn read_record(path: &Path, booth: &str) -> Result<TakeRecord, NatsError> {
    use mcap::sans_io::summary_reader::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};
    use std::io::{Read, Seek, SeekFrom};
    let fail = |what: String| NatsError::Store(format!("{}: {what}", path.display()));
    let mut file = open_take(path).map_err(|e| fail(format!("cannot open: {e}")))?;
    let size = file
        .metadata()
        .map_err(|e| fail(format!("cannot read: {e}")))?
        .len();
    let mut reader = SummaryReader::new_with_options(
        SummaryReaderOptions::default()
            .with_file_size(size)
            .with_record_length_limit(MAX_SUMMARY_BYTES),
    );
    while let Some(event) = reader.next_event() {
        match event.map_err(|e| fail(format!("not a readable take: {e}")))? {
            SummaryReadEvent::ReadRequest(need) => {
                let n = file
                    .read(reader.insert(need))
                    .map_err(|e| fail(format!("cannot read: {e}")))?;
                reader.notify_read(n);
            }
            SummaryReadEvent::SeekRequest(to) => {
                let at = file
                    .seek(to)
                    .map_err(|e| fail(format!("cannot read: {e}")))?;
                reader.notify_seeked(at);
            }
        }
    }
    let summary = reader
        .finish()
        .ok_or_else(|| fail("the take has no summary".into()))?;
    let index = summary
        .metadata_indexes
        .iter()
        .find(|m| m.name == TAKE_METADATA)
        .ok_or_else(|| fail(format!("no {TAKE_METADATA} metadata")))?;
    if index.length > MAX_SUMMARY_BYTES as u64 {
        return Err(fail(format!("metadata of {} bytes", index.length)));
    }
    let mut bytes = vec![0u8; index.length as usize];
    file.seek(SeekFrom::Start(index.offset))
        .and_then(|_| file.read_exact(&mut bytes))
        .map_err(|e| fail(format!("cannot read the metadata: {e}")))?;
    let metadata = match mcap::read::LinearReader::sans_magic(&bytes).next() {
        Some(Ok(mcap::records::Record::Metadata(m))) => m.metadata,
        _ => return Err(fail("the metadata record is not readable".into())),
    };
    let take =
        TakeMetadata::from_record(path, &metadata).map_err(|e| NatsError::Store(e.to_string()))?;
    let mut characters: Vec<String> = summary
        .channels
        .values()
        .filter_map(|c| c.topic.strip_prefix(CHARACTER_PREFIX).map(str::to_owned))
        .collect();
    characters.sort();
    characters.dedup();
    let stats = summary.stats.as_ref();
    let frames = summary
        .channels
        .iter()
        .find(|(_, c)| c.topic == TOPIC_HEAD)
        .and_then(|(id, _)| stats.and_then(|s| s.channel_message_counts.get(id).copied()))
        .unwrap_or(0);
    let duration_s = stats.map_or(0.0, |s| {
        s.message_end_time.saturating_sub(s.message_start_time) as f64 / 1e9
    });
    let file_name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    Ok(TakeRecord {
        booth: booth.to_owned(),
        timecode: take.start_timecode(),
        slate: take.slate,
        take: take.take,
        object: format!("{booth}/{file_name}"),
        file: file_name,
        size,
        started_unix_us: take.started_unix_us,
        timecode_rate: take.timecode_rate,
        duration_s,
        frames,
        characters,
        source: take.source,
        uploaded_unix_us: 0,
    })
}
