//! The studio's take store: the object store bucket of take files and the key-value bucket
//! of their metadata. Used by the uploader and by `mouthpiece takes list|fetch`.

use std::path::Path;

use async_nats::jetstream::{self, kv, object_store};
use futures_util::StreamExt;
use serde::{Deserialize, Serialize};
use tokio::io::AsyncWriteExt;

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
    pub async fn fetch(&self, name: &str, out: &Path) -> Result<u64, NatsError> {
        let mut object = self
            .objects
            .get(name)
            .await
            .map_err(|e| store_error(&format!("cannot get {name}"), e))?;
        let partial = partial_path(out);
        let result = async {
            let mut file = tokio::fs::File::create(&partial)
                .await
                .map_err(|e| store_error(&format!("cannot create {}", partial.display()), e))?;
            let written = tokio::io::copy(&mut object, &mut file)
                .await
                .map_err(|e| store_error(&format!("cannot fetch {name}"), e))?;
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
            let _ = tokio::fs::remove_file(&partial).await;
        }
        result
    }
}

/// `<out>.partial`: where a file is written before it is renamed into place.
pub fn partial_path(out: &Path) -> std::path::PathBuf {
    let mut name = out.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    out.with_file_name(name)
}
