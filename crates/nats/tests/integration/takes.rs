//! Take upload against a real `nats-server`: real take files written by the takes crate,
//! uploaded to the object store with their metadata, kept locally with a marker, and the
//! backlog of a booth that was offline uploaded when the broker returns.

use crate::helper_harness as harness;
use crate::helper_harness_take as take;

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::Duration;

use harness::{eventually, NatsServer};
use mouthpiece_nats::store::TakeStore;
use mouthpiece_nats::upload::marker_path;
use mouthpiece_nats::{NatsLink, NatsSettings};
use mouthpiece_server::{Hub, HubConfig};
use take::record_take;

const WAIT: Duration = Duration::from_secs(30);

async fn start_link(hub: &Hub, url: String, folder: &Path) -> NatsLink {
    NatsLink::start(
        hub.clone(),
        NatsSettings::new(vec![url], "booth-1"),
        "t".into(),
        folder.to_owned(),
    )
    .await
    .unwrap()
}

async fn reader(url: &str) -> async_nats::Client {
    async_nats::connect(url).await.unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn closed_takes_go_to_the_object_store_with_metadata_and_stay_with_a_marker() {
    harness::init_logs();
    let server = NatsServer::start();
    let folder = tempfile::tempdir().unwrap();
    let a = record_take(folder.path(), "scene.1", 30);
    let b = record_take(folder.path(), "scene.1", 12);
    // A take still recording (or cut by a crash) has no closing magic: left alone.
    let bytes = std::fs::read(&a).unwrap();
    let open = folder.path().join("open_T001_x.mcap");
    std::fs::write(&open, &bytes[..bytes.len() / 2]).unwrap();
    // Oldest of all, so that it would be tried first.
    std::fs::File::options()
        .write(true)
        .open(&open)
        .unwrap()
        .set_modified(std::time::UNIX_EPOCH + Duration::from_secs(1_000_000))
        .unwrap();

    let (hub, _control) = Hub::new(&HubConfig::default());
    let _link = start_link(&hub, server.url(), folder.path()).await;
    let counters = hub.nats();
    eventually(WAIT, async || {
        (counters.takes_uploaded.load(Ordering::Relaxed) == 2).then_some(())
    })
    .await
    .expect("the two closed takes were not uploaded");

    let client = reader(&server.url()).await;
    let store = TakeStore::open_existing(&client, "studio").await.unwrap();
    let records = store.list().await.unwrap();
    assert_eq!(records.len(), 2, "{records:?}");
    for (record, path, frames) in [(&records[0], &a, 30), (&records[1], &b, 12)] {
        let name = path.file_name().unwrap().to_str().unwrap();
        assert_eq!(record.object, format!("booth-1/{name}"));
        assert!(name.starts_with("scene.1_T"), "{name}");
        assert_eq!(record.slate, "scene.1");
        assert_eq!(record.booth, "booth-1");
        assert_eq!(record.frames, frames, "{record:?}");
        assert_eq!(record.characters, vec!["wolf".to_owned()]);
        assert!(record.duration_s > 0.0, "{record:?}");
        assert_eq!(record.timecode.len(), 11, "{record:?}");
        assert_eq!(record.timecode_rate, "30");
        // The local file stays, marked.
        assert!(path.exists());
        assert!(marker_path(path).exists());
        let out = folder.path().join("fetched.mcap");
        let n = store.fetch(&record.object, &out).await.unwrap();
        assert_eq!(n, record.size);
        assert_eq!(std::fs::read(&out).unwrap(), std::fs::read(path).unwrap());
    }
    assert_eq!(records[0].take + 1, records[1].take);
    assert!(
        !marker_path(&open).exists(),
        "an unfinished take was uploaded"
    );
    assert_eq!(counters.takes_waiting.load(Ordering::Relaxed), 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_booth_that_was_offline_uploads_its_backlog_when_the_broker_returns() {
    let mut server = NatsServer::start();
    let folder = tempfile::tempdir().unwrap();
    let (hub, _control) = Hub::new(&HubConfig::default());
    let _link = start_link(&hub, server.url(), folder.path()).await;
    let counters = hub.nats();
    eventually(WAIT, async || {
        counters.connected.load(Ordering::Relaxed).then_some(())
    })
    .await
    .unwrap();
    server.kill();
    let takes: Vec<PathBuf> = (0..3).map(|_| record_take(folder.path(), "s", 5)).collect();
    // Noticed on the next scan: waiting, not uploaded.
    eventually(WAIT, async || {
        (counters.takes_waiting.load(Ordering::Relaxed) == 3).then_some(())
    })
    .await
    .unwrap_or_else(|| {
        panic!(
            "the backlog is not counted while the broker is away: {:?}",
            counters.health_json()
        )
    });
    assert_eq!(counters.takes_uploaded.load(Ordering::Relaxed), 0);
    assert!(takes.iter().all(|t| !marker_path(t).exists()));

    server.restart();
    eventually(WAIT, async || {
        (counters.takes_uploaded.load(Ordering::Relaxed) == 3).then_some(())
    })
    .await
    .expect("the backlog was not uploaded after the broker returned");
    let client = reader(&server.url()).await;
    let records = TakeStore::open_existing(&client, "studio")
        .await
        .unwrap()
        .list()
        .await
        .unwrap();
    assert_eq!(records.len(), 3);
    assert!(takes.iter().all(|t| marker_path(t).exists() && t.exists()));
}
