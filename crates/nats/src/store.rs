//! The studio's take store: the object store bucket of take files and the key-value bucket
//! of their metadata. Used by the uploader and by `mouthpiece takes list|fetch`.

use std::path::Path;
use std::time::Duration;

use async_nats::jetstream::object_store::ObjectInfo;
use async_nats::jetstream::{self, kv, object_store};
use futures_util::StreamExt;
use mouthpiece_output::shown;
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
    /// The takes bucket's name (objects and links must stay in it).
    bucket: String,
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
        Ok(TakeStore {
            objects,
            meta,
            bucket: takes_bucket(studio),
        })
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
        Ok(TakeStore {
            objects,
            meta,
            bucket: takes_bucket(studio),
        })
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
    ///
    /// The object's info is not trusted: an object without a SHA-256 digest, a link into
    /// another bucket or to another link, and data whose size or digest differs from the
    /// info are refused ([`verified_info`], [`Received`]) and nothing is kept.
    pub async fn fetch(&self, name: &str, out: &Path) -> Result<u64, NatsError> {
        self.fetch_with_timeout(name, out, FETCH_IDLE_TIMEOUT).await
    }

    /// [`TakeStore::fetch`], waiting at most `idle` for each piece of the object: an object
    /// whose metadata promises chunks the store does not hold is an error after that long.
    ///
    /// A link is followed here, at most once and within the bucket, never by the client
    /// library (which follows any chain, into any bucket, and a link to itself without end).
    /// The temporary file is created new, never through an existing name or a symbolic link.
    pub async fn fetch_with_timeout(
        &self,
        name: &str,
        out: &Path,
        idle: Duration,
    ) -> Result<u64, NatsError> {
        let info_of = |object: String| async move {
            tokio::time::timeout(idle, self.objects.info(&object))
                .await
                .map_err(|_| store_error(&format!("cannot get {}", shown(&object)), "no answer"))?
                .map_err(|e| store_error(&format!("cannot get {}", shown(&object)), e))
        };
        let info = info_of(name.to_owned()).await?;
        let (target, target_info) = match link_target(&info, self.bucket_name())? {
            Some(target) => {
                let linked = info_of(target.clone()).await?;
                if linked.options.as_ref().is_some_and(|o| o.link.is_some()) {
                    return Err(untrusted(name, Refused::LinkToLink));
                }
                (target, linked)
            }
            None => (name.to_owned(), info),
        };
        if target_info.deleted {
            return Err(NatsError::Store(format!("{} was deleted", shown(&target))));
        }
        let mut object = tokio::time::timeout(idle, self.objects.get(&target))
            .await
            .map_err(|_| store_error(&format!("cannot get {}", shown(name)), "no answer"))?
            .map_err(|e| store_error(&format!("cannot get {}", shown(name)), e))?;
        if object.info().nuid != target_info.nuid {
            return Err(NatsError::Store(format!(
                "{} changed while it was fetched (or became a link): try again",
                shown(name)
            )));
        }
        // The info the data is read with is the one checked.
        let expected =
            verified_info(object.info(), self.bucket_name()).map_err(|why| untrusted(name, why))?;
        let partial = partial_path(out);
        let mut file = create_new_file(&partial)
            .await
            .map_err(|e| store_error(&format!("cannot create {}", partial.display()), e))?;
        let result = async {
            let mut received = Received::new(expected);
            let mut buffer = vec![0u8; 64 * 1024];
            let mut read = 0u64;
            loop {
                let n = tokio::time::timeout(idle, object.read(&mut buffer))
                    .await
                    .map_err(|_| {
                        NatsError::Store(format!(
                            "cannot fetch {}: no data for {} s after {read} bytes (the store \
                             does not hold the chunks its metadata names)",
                            shown(name),
                            idle.as_secs_f64()
                        ))
                    })?
                    .map_err(|e| store_error(&format!("cannot fetch {}", shown(name)), e))?;
                if n == 0 {
                    break;
                }
                read += n as u64;
                received
                    .update(&buffer[..n])
                    .map_err(|why| untrusted(name, why))?;
                file.write_all(&buffer[..n])
                    .await
                    .map_err(|e| store_error(&format!("cannot write {}", partial.display()), e))?;
            }
            let written = received.finish().map_err(|why| untrusted(name, why))?;
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

    /// The takes bucket's name.
    fn bucket_name(&self) -> &str {
        self.bucket.as_str()
    }
}

fn untrusted(name: &str, why: Refused) -> NatsError {
    NatsError::Untrusted {
        object: shown(name).into_owned(),
        why,
    }
}

/// An object's info from the JSON the store holds (what the client library reads before
/// [`TakeStore::fetch`] checks it); the entry point of the store's fuzz target.
pub fn info_from_json(json: &[u8]) -> Result<ObjectInfo, serde_json::Error> {
    serde_json::from_slice(json)
}

/// Why an object's info or data is not trusted; each says what it found.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Refused {
    #[error("is a link to another link")]
    LinkToLink,
    #[error("is a link into another bucket ({0}): refused")]
    LinkOutOfBucket(String),
    #[error("is a link to a whole bucket: refused")]
    LinkToBucket,
    #[error("its info names another bucket ({0}): refused")]
    OtherBucket(String),
    #[error("is deleted")]
    Deleted,
    #[error("is a link: refused")]
    Link,
    #[error("has no digest: its data cannot be verified, refused")]
    NoDigest,
    #[error("has a digest that is not SHA-256=<base64url of 32 bytes> ({0}): refused")]
    BadDigest(String),
    #[error("sent more than the {size} bytes its info gives: refused, nothing kept")]
    TooLong { size: u64 },
    #[error("sent {got} bytes, its info gives {size}: refused, nothing kept")]
    WrongSize { got: u64, size: u64 },
    #[error("data does not match the digest in its info: refused, nothing kept")]
    DigestMismatch,
}

/// Where a link object points, when `info` is one: `Ok(None)` for a plain object; refused
/// when the link leads into another bucket or to a whole bucket.
pub fn link_target(info: &ObjectInfo, bucket: &str) -> Result<Option<String>, NatsError> {
    let Some(link) = info.options.as_ref().and_then(|o| o.link.as_ref()) else {
        return Ok(None);
    };
    let name = &info.name;
    match &link.name {
        _ if link.bucket != bucket => Err(untrusted(
            name,
            Refused::LinkOutOfBucket(shown(&link.bucket).into_owned()),
        )),
        None => Err(untrusted(name, Refused::LinkToBucket)),
        Some(target) => Ok(Some(target.clone())),
    }
}

/// What the data of an object must be: its size and SHA-256 digest, from its info.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Expected {
    pub size: u64,
    pub sha256: [u8; 32],
}

/// Checks an object's info before its data is read: in `bucket`, not deleted, not a link,
/// with a well-formed `SHA-256=<base64url>` digest (an object without one cannot be
/// verified and is refused). The reason in words when refused.
pub fn verified_info(info: &ObjectInfo, bucket: &str) -> Result<Expected, Refused> {
    if info.bucket != bucket {
        return Err(Refused::OtherBucket(shown(&info.bucket).into_owned()));
    }
    if info.deleted {
        return Err(Refused::Deleted);
    }
    if info.options.as_ref().is_some_and(|o| o.link.is_some()) {
        return Err(Refused::Link);
    }
    let Some(digest) = info.digest.as_deref() else {
        return Err(Refused::NoDigest);
    };
    let sha256 = parse_digest(digest)
        .ok_or_else(|| Refused::BadDigest(shown(&excerpt(digest)).into_owned()))?;
    Ok(Expected {
        size: info.size as u64,
        sha256,
    })
}

/// `SHA-256=<base64url>` as the object store writes it (with or without padding).
pub fn parse_digest(digest: &str) -> Option<[u8; 32]> {
    use base64::Engine as _;
    let encoded = digest.strip_prefix("SHA-256=")?;
    let engine = base64::engine::GeneralPurpose::new(
        &base64::alphabet::URL_SAFE,
        base64::engine::GeneralPurposeConfig::new()
            .with_decode_padding_mode(base64::engine::DecodePaddingMode::Indifferent),
    );
    if encoded.len() > 64 {
        return None;
    }
    engine.decode(encoded).ok()?.try_into().ok()
}

fn excerpt(s: &str) -> String {
    s.chars().take(80).collect()
}

/// The data of an object as it arrives, checked against what its info promised: never
/// more bytes than its size, and at the end exactly its size and its digest.
pub struct Received {
    expected: Expected,
    bytes: u64,
    digest: ring::digest::Context,
}

impl Received {
    pub fn new(expected: Expected) -> Received {
        Received {
            expected,
            bytes: 0,
            digest: ring::digest::Context::new(&ring::digest::SHA256),
        }
    }

    /// Takes the next piece; refused once the data is longer than the info says.
    pub fn update(&mut self, data: &[u8]) -> Result<(), Refused> {
        self.bytes += data.len() as u64;
        if self.bytes > self.expected.size {
            return Err(Refused::TooLong {
                size: self.expected.size,
            });
        }
        self.digest.update(data);
        Ok(())
    }

    /// The byte count when the data is whole and its digest matches.
    pub fn finish(self) -> Result<u64, Refused> {
        if self.bytes != self.expected.size {
            return Err(Refused::WrongSize {
                got: self.bytes,
                size: self.expected.size,
            });
        }
        if self.digest.finish().as_ref() != self.expected.sha256.as_slice() {
            return Err(Refused::DigestMismatch);
        }
        Ok(self.bytes)
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

#[cfg(test)]
mod tests {
    use super::*;

    fn expected(data: &[u8]) -> Expected {
        let digest = ring::digest::digest(&ring::digest::SHA256, data);
        Expected {
            size: data.len() as u64,
            sha256: digest.as_ref().try_into().unwrap(),
        }
    }

    #[test]
    fn data_must_have_the_size_and_digest_of_its_info() {
        let data = b"a take's bytes";
        let mut whole = Received::new(expected(data));
        whole.update(&data[..4]).unwrap();
        whole.update(&data[4..]).unwrap();
        assert_eq!(whole.finish(), Ok(data.len() as u64));

        let mut short = Received::new(expected(data));
        short.update(&data[..4]).unwrap();
        assert_eq!(
            short.finish(),
            Err(Refused::WrongSize {
                got: 4,
                size: data.len() as u64
            })
        );

        let mut long = Received::new(expected(data));
        long.update(data).unwrap();
        assert!(long
            .update(b"x")
            .unwrap_err()
            .to_string()
            .contains("more than"));

        let mut changed = Received::new(expected(data));
        changed.update(b"A take's bytes").unwrap();
        assert_eq!(changed.finish(), Err(Refused::DigestMismatch));
    }

    #[test]
    fn digests_are_sha256_in_base64url() {
        use base64::Engine as _;
        let sum = ring::digest::digest(&ring::digest::SHA256, b"x");
        let padded = base64::engine::general_purpose::URL_SAFE.encode(sum);
        let bare = base64::engine::general_purpose::URL_SAFE_NO_PAD.encode(sum);
        for text in [format!("SHA-256={padded}"), format!("SHA-256={bare}")] {
            assert_eq!(
                parse_digest(&text).unwrap().as_slice(),
                sum.as_ref(),
                "{text}"
            );
        }
        for bad in [
            "",
            "SHA-256=",
            "MD5=abc",
            "SHA-256=not base64!",
            "SHA-256=AAAA",
            &format!("SHA-256={}", "A".repeat(10_000)),
        ] {
            assert!(parse_digest(bad).is_none(), "{bad}");
        }
    }
}
