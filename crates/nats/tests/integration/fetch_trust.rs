//! `takes fetch` against a real `nats-server` holding hostile objects: the info of an object
//! (size, digest, link, bucket) is checked against what is received, and whatever does not
//! match is refused with nothing left in the folder.

use crate::helper_harness as harness;

use async_nats::jetstream::object_store::{ObjectInfo, ObjectLink, ObjectOptions};
use async_nats::HeaderMap;
use base64::Engine as _;
use harness::NatsServer;
use mouthpiece_nats::store::{partial_path, TakeStore};
use mouthpiece_nats::NatsError;

const BUCKET: &str = "mouthpiece-takes-studio";

/// A store with one honest object, `booth-1/honest.mcap`, and its info.
async fn store_with_one_object(server: &NatsServer) -> (async_nats::Client, TakeStore, ObjectInfo) {
    let client = async_nats::connect(server.url()).await.unwrap();
    let store = TakeStore::open(&client, "studio").await.unwrap();
    let data: Vec<u8> = (0..5000u32).map(|i| (i % 251) as u8).collect();
    let info = store
        .objects
        .put("booth-1/honest.mcap", &mut data.as_slice())
        .await
        .unwrap();
    (client, store, info)
}

/// Writes `info` as the metadata of `info.name` in `bucket`, as a hostile writer could
/// (the data chunks of the object it names are shared with the original).
async fn plant(client: &async_nats::Client, bucket: &str, info: &ObjectInfo) {
    let js = async_nats::jetstream::new(client.clone());
    let name = base64::engine::general_purpose::URL_SAFE.encode(&info.name);
    let mut headers = HeaderMap::new();
    headers.insert("Nats-Rollup", "sub");
    js.publish_with_headers(
        format!("$O.{bucket}.M.{name}"),
        headers,
        serde_json::to_vec(info).unwrap().into(),
    )
    .await
    .unwrap()
    .await
    .unwrap();
}

/// Fetches `name` into a fresh folder: the error, and what was left in the folder.
async fn fetch_refused(store: &TakeStore, name: &str) -> (String, Vec<String>) {
    let folder = tempfile::tempdir().unwrap();
    let out = folder.path().join("take.mcap");
    let err = store
        .fetch(name, &out)
        .await
        .expect_err("a hostile object was fetched");
    assert!(!partial_path(&out).exists());
    let left = std::fs::read_dir(folder.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    (format!("{err}"), left)
}

fn renamed(info: &ObjectInfo, name: &str) -> ObjectInfo {
    let mut info = info.clone();
    info.name = name.to_owned();
    info
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_honest_object_and_a_link_within_the_bucket_are_fetched_whole() {
    let server = NatsServer::start();
    let (client, store, info) = store_with_one_object(&server).await;
    let folder = tempfile::tempdir().unwrap();
    let out = folder.path().join("a.mcap");
    assert_eq!(
        store.fetch("booth-1/honest.mcap", &out).await.unwrap(),
        5000
    );
    let mut link = renamed(&info, "booth-1/link.mcap");
    link.options = Some(ObjectOptions {
        link: Some(ObjectLink {
            name: Some("booth-1/honest.mcap".into()),
            bucket: BUCKET.into(),
        }),
        max_chunk_size: None,
    });
    link.digest = None;
    plant(&client, BUCKET, &link).await;
    let out = folder.path().join("b.mcap");
    assert_eq!(store.fetch("booth-1/link.mcap", &out).await.unwrap(), 5000);
    assert_eq!(
        std::fs::read(&out).unwrap(),
        std::fs::read(folder.path().join("a.mcap")).unwrap()
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_object_without_a_digest_is_refused() {
    let server = NatsServer::start();
    let (client, store, info) = store_with_one_object(&server).await;
    let mut bad = renamed(&info, "booth-1/no-digest.mcap");
    bad.digest = None;
    plant(&client, BUCKET, &bad).await;
    let (err, left) = fetch_refused(&store, "booth-1/no-digest.mcap").await;
    assert!(
        err.contains("booth-1/no-digest.mcap") && err.contains("no digest"),
        "{err}"
    );
    assert!(left.is_empty(), "{left:?}");
    let mut bad = renamed(&info, "booth-1/odd-digest.mcap");
    bad.digest = Some("MD5=abc".into());
    plant(&client, BUCKET, &bad).await;
    let (err, left) = fetch_refused(&store, "booth-1/odd-digest.mcap").await;
    assert!(err.contains("digest") && err.contains("MD5=abc"), "{err}");
    assert!(left.is_empty(), "{left:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_size_or_digest_that_does_not_match_the_data_is_refused() {
    let server = NatsServer::start();
    let (client, store, info) = store_with_one_object(&server).await;
    for (name, size) in [
        ("booth-1/longer.mcap", info.size + 10),
        ("booth-1/shorter.mcap", info.size - 10),
    ] {
        let mut bad = renamed(&info, name);
        bad.size = size;
        plant(&client, BUCKET, &bad).await;
        let (err, left) = fetch_refused(&store, name).await;
        assert!(err.contains(name) && err.contains("bytes"), "{err}");
        assert!(left.is_empty(), "{left:?}");
    }
    let mut bad = renamed(&info, "booth-1/other-digest.mcap");
    let other = ring::digest::digest(&ring::digest::SHA256, b"something else");
    bad.digest = Some(format!(
        "SHA-256={}",
        base64::engine::general_purpose::URL_SAFE.encode(other)
    ));
    plant(&client, BUCKET, &bad).await;
    let (err, left) = fetch_refused(&store, "booth-1/other-digest.mcap").await;
    assert!(err.contains("digest"), "{err}");
    assert!(left.is_empty(), "{left:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn links_out_of_the_bucket_and_foreign_infos_are_refused() {
    let server = NatsServer::start();
    let (client, store, info) = store_with_one_object(&server).await;
    // Another bucket with a take in it, which a link could reach.
    let js = async_nats::jetstream::new(client.clone());
    let elsewhere = js
        .create_object_store(async_nats::jetstream::object_store::Config {
            bucket: "elsewhere".into(),
            ..Default::default()
        })
        .await
        .unwrap();
    elsewhere
        .put("secret.mcap", &mut &b"secret"[..])
        .await
        .unwrap();
    let link = |name: &str, target: Option<&str>, bucket: &str| {
        let mut link = renamed(&info, name);
        link.digest = None;
        link.options = Some(ObjectOptions {
            link: Some(ObjectLink {
                name: target.map(str::to_owned),
                bucket: bucket.into(),
            }),
            max_chunk_size: None,
        });
        link
    };
    plant(
        &client,
        BUCKET,
        &link("booth-1/out.mcap", Some("secret.mcap"), "elsewhere"),
    )
    .await;
    let (err, left) = fetch_refused(&store, "booth-1/out.mcap").await;
    assert!(err.contains("another bucket (elsewhere)"), "{err}");
    assert!(left.is_empty(), "{left:?}");
    plant(&client, BUCKET, &link("booth-1/whole.mcap", None, BUCKET)).await;
    let (err, _) = fetch_refused(&store, "booth-1/whole.mcap").await;
    assert!(err.contains("whole bucket"), "{err}");
    // A → B → A: refused at the second link, without following the chain.
    plant(
        &client,
        BUCKET,
        &link("booth-1/a.mcap", Some("booth-1/b.mcap"), BUCKET),
    )
    .await;
    plant(
        &client,
        BUCKET,
        &link("booth-1/b.mcap", Some("booth-1/a.mcap"), BUCKET),
    )
    .await;
    let (err, _) = fetch_refused(&store, "booth-1/a.mcap").await;
    assert!(err.contains("link to another link"), "{err}");
    // An info that claims another bucket's data.
    let mut foreign = renamed(&info, "booth-1/foreign.mcap");
    foreign.bucket = "elsewhere".into();
    plant(&client, BUCKET, &foreign).await;
    let (err, left) = fetch_refused(&store, "booth-1/foreign.mcap").await;
    assert!(err.contains("another bucket"), "{err}");
    assert!(left.is_empty(), "{left:?}");
    // The refusals are the store's contents at fault, told apart from a network failure.
    let err = store
        .fetch(
            "booth-1/out.mcap",
            &tempfile::tempdir().unwrap().path().join("x.mcap"),
        )
        .await
        .unwrap_err();
    assert!(matches!(err, NatsError::Untrusted { .. }), "{err:?}");
}
