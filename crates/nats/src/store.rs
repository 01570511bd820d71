//! The studio's take store: the object store bucket of take files and the key-value bucket
//! of their metadata. Used by the uploader and by `mouthpiece takes list|fetch`.

use std::path::Path;
use std::time::Duration;

use async_nats::jetstream::{self, kv, object_store};
use futures_util::StreamExt;
use mouthpiece_config::quote_excerpt;
use serde::{Deserialize, Serialize};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

use crate::subjects::{escape, meta_bucket, takes_bucket};
use crate::NatsError;

/// One take's metadata, the value of its key (`<booth>.<escaped file stem>`) in the
/// metadata bucket.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TakeRecord {
    pub booth: String,
    pub slate: String,
    pub take: u32,
    /// The object's name in the takes bucket: `<booth>/<file name>`.
    pub object: String,
    /// The file's name on the booth.
    pub file: String,
    /// Bytes.
    pub size: u64,
    /// When the take started, Unix microseconds.
    pub started_unix_us: i64,
    /// SMPTE timecode of the start.
    pub timecode: String,
    pub timecode_rate: String,
    /// From the first to the last message, seconds.
    pub duration_s: f64,
    /// Frames recorded (messages on `/head`).
    pub frames: u64,
    /// The characters recorded (`/character/<name>` topics).
    pub characters: Vec<String>,
    /// Where the frames came from.
    pub source: String,
    /// When the upload was confirmed, Unix microseconds.
    pub uploaded_unix_us: i64,
}

impl TakeRecord {
    /// The key of this take in the metadata bucket.
    pub fn key(&self) -> String {
        record_key(&self.booth, &self.file)
    }
}

/// `<booth>.<file stem, escaped>`.
pub fn record_key(booth: &str, file: &str) -> String {
    let stem = file.strip_suffix(".mcap").unwrap_or(file);
    format!("{booth}.{}", escape(stem))
}

/// The studio's two buckets, created when missing.
#[derive(Clone)]
pub struct TakeStore {
    pub objects: object_store::ObjectStore,
    pub meta: kv::Store,
}

impl std::fmt::Debug for TakeStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("TakeStore")
    }
}

fn store_error(what: &str, e: impl std::fmt::Display) -> NatsError {
    NatsError::Store(format!("{what}: {e}"))
}

impl TakeStore {
    /// Opens (creating when missing) the studio's buckets.
    pub async fn open(client: &async_nats::Client, studio: &str) -> Result<TakeStore, NatsError> {
        let js = jetstream::new(client.clone());
        let bucket = takes_bucket(studio);
        let objects = match js.get_object_store(&bucket).await {
            Ok(store) => store,
            Err(_) => js
                .create_object_store(object_store::Config {
                    bucket: bucket.clone(),
                    description: Some("mouthpiece takes".into()),
                    ..Default::default()
                })
                .await
                .map_err(|e| store_error(&format!("cannot create object store {bucket}"), e))?,
        };
        let bucket = meta_bucket(studio);
        let meta = match js.get_key_value(&bucket).await {
            Ok(store) => store,
            Err(_) => {
                // The key-value bucket's stream, as the client's `create_key_value` makes it
                // (history 1). Made directly: `create_key_value` first asks for the account's
                // limits, whose answer from a 2.9 server this client cannot read.
                js.get_or_create_stream(jetstream::stream::Config {
                    name: format!("KV_{bucket}"),
                    description: Some("mouthpiece take metadata".into()),
                    subjects: vec![format!("$KV.{bucket}.>")],
                    max_messages_per_subject: 1,
                    allow_rollup: true,
                    deny_delete: true,
                    allow_direct: true,
                    discard: jetstream::stream::DiscardPolicy::New,
                    ..Default::default()
                })
                .await
                .map_err(|e| store_error(&format!("cannot create key-value bucket {bucket}"), e))?;
                js.get_key_value(&bucket).await.map_err(|e| {
                    store_error(&format!("cannot open key-value bucket {bucket}"), e)
                })?
            }
        };
        Ok(TakeStore { objects, meta })
    }

    /// Opens the studio's buckets without creating them (for reading).
    pub async fn open_existing(
        client: &async_nats::Client,
        studio: &str,
    ) -> Result<TakeStore, NatsError> {
        let js = jetstream::new(client.clone());
        let bucket = takes_bucket(studio);
        let objects = js.get_object_store(&bucket).await.map_err(|e| {
            store_error(
                &format!("no object store {bucket} (no take uploaded yet?)"),
                e,
            )
        })?;
        let bucket = meta_bucket(studio);
        let meta = js
            .get_key_value(&bucket)
            .await
            .map_err(|e| store_error(&format!("no key-value bucket {bucket}"), e))?;
        Ok(TakeStore { objects, meta })
    }

    /// Every take's record, sorted by booth, then start time.
    pub async fn list(&self) -> Result<Vec<TakeRecord>, NatsError> {
        let mut keys = self
            .meta
            .keys()
            .await
            .map_err(|e| store_error("cannot list the take metadata", e))?;
        let mut records = Vec::new();
        while let Some(key) = keys.next().await {
            let key = key.map_err(|e| store_error("cannot list the take metadata", e))?;
            let Some(value) = self
                .meta
                .get(&key)
                .await
                .map_err(|e| store_error(&format!("cannot read {key}"), e))?
            else {
                continue;
            };
            match serde_json::from_slice::<TakeRecord>(&value) {
                Ok(record) => records.push(record),
                Err(e) => tracing::warn!(key, "take metadata not understood: {e}"),
            }
        }
        records.sort_by(|a, b| {
            (a.booth.as_str(), a.started_unix_us, a.take).cmp(&(
                b.booth.as_str(),
                b.started_unix_us,
                b.take,
            ))
        });
        Ok(records)
    }

    /// Copies object `name` to `out`, written to a temporary file beside it and renamed into
    /// place once complete (no partial file is left behind). Returns the bytes written.
    /// Waits at most [`FETCH_IDLE_TIMEOUT`] for each piece of the object.
    pub async fn fetch(&self, name: &str, out: &Path) -> Result<u64, NatsError> {
        self.fetch_with_timeout(name, out, FETCH_IDLE_TIMEOUT).await
    }

    /// [`TakeStore::fetch`], waiting at most `idle` for each piece of the object: an object
    /// whose metadata promises chunks the store does not hold is an error after that long.
    ///
    /// The object's metadata is read first and a link is refused (never followed: the client
    /// library follows links without limit, so a link to itself would never end). The
    /// temporary file is created new, never through an existing name or a symbolic link.
    pub async fn fetch_with_timeout(
        &self,
        name: &str,
        out: &Path,
        idle: Duration,
    ) -> Result<u64, NatsError> {
        let info = tokio::time::timeout(idle, self.objects.info(name))
            .await
            .map_err(|_| store_error(&format!("cannot get {name}"), "no answer"))?
            .map_err(|e| store_error(&format!("cannot get {name}"), e))?;
        if let Some(link) = info.options.as_ref().and_then(|o| o.link.as_ref()) {
            return Err(NatsError::Store(format!(
                "{name} is a link (to bucket {}, object {}): links are not fetched; fetch the \
                 object itself",
                quote_excerpt(&link.bucket),
                quote_excerpt(link.name.as_deref().unwrap_or(""))
            )));
        }
        if info.deleted {
            return Err(NatsError::Store(format!("{name} was deleted")));
        }
        let mut object = tokio::time::timeout(idle, self.objects.get(name))
            .await
            .map_err(|_| store_error(&format!("cannot get {name}"), "no answer"))?
            .map_err(|e| store_error(&format!("cannot get {name}"), e))?;
        if object.info.nuid != info.nuid {
            return Err(NatsError::Store(format!(
                "{name} changed while it was fetched (or became a link): try again"
            )));
        }
        let partial = partial_path(out);
        let mut file = create_new_file(&partial)
            .await
            .map_err(|e| store_error(&format!("cannot create {}", partial.display()), e))?;
        let result = async {
            let mut written = 0u64;
            let mut buf = vec![0u8; 64 * 1024];
            loop {
                let n = tokio::time::timeout(idle, object.read(&mut buf))
                    .await
                    .map_err(|_| {
                        NatsError::Store(format!(
                            "cannot fetch {name}: no data for {} s after {written} bytes (the \
                             store does not hold the chunks its metadata names)",
                            idle.as_secs_f64()
                        ))
                    })?
                    .map_err(|e| store_error(&format!("cannot fetch {name}"), e))?;
                if n == 0 {
                    break;
                }
                file.write_all(&buf[..n])
                    .await
                    .map_err(|e| store_error(&format!("cannot write {}", partial.display()), e))?;
                written += n as u64;
            }
            file.sync_all()
                .await
                .map_err(|e| store_error(&format!("cannot write {}", partial.display()), e))?;
            file.shutdown().await.ok();
            tokio::fs::rename(&partial, out)
                .await
                .map_err(|e| store_error(&format!("cannot write {}", out.display()), e))?;
            Ok(written)
        }
        .await;
        if result.is_err() {
            // Only the file this call created: it was created new above.
            let _ = tokio::fs::remove_file(&partial).await;
        }
        result
    }
}

/// How long [`TakeStore::fetch`] waits for each piece of an object.
pub const FETCH_IDLE_TIMEOUT: Duration = Duration::from_secs(30);

/// Creates `path` for writing: a new file, never an existing one nor through a symbolic link
/// (`O_CREAT | O_EXCL | O_NOFOLLOW`: a name that exists, a dangling link included, is an
/// error).
async fn create_new_file(path: &Path) -> std::io::Result<tokio::fs::File> {
    tokio::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .custom_flags(libc::O_NOFOLLOW)
        .open(path)
        .await
}

/// `<out>.partial`: where a file is written before it is renamed into place.
pub fn partial_path(out: &Path) -> std::path::PathBuf {
    let mut name = out.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    out.with_file_name(name)
}
