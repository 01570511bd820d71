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

/// Writes `info` as object `name`'s metadata, as a hostile store (or another client) could:
/// straight to the bucket's metadata subject, replacing what was there.
async fn put_raw_info(
    client: &async_nats::Client,
    name: &str,
    mut info: async_nats::jetstream::object_store::ObjectInfo,
) {
    use base64::Engine as _;
    let bucket = mouthpiece_nats::subjects::takes_bucket("studio");
    info.name = name.to_owned();
    let subject = format!(
        "$O.{bucket}.M.{}",
        base64::engine::general_purpose::URL_SAFE.encode(name)
    );
    let mut headers = async_nats::HeaderMap::new();
    headers.insert("Nats-Rollup", "sub");
    async_nats::jetstream::new(client.clone())
        .publish_with_headers(subject, headers, serde_json::to_vec(&info).unwrap().into())
        .await
        .unwrap()
        .await
        .unwrap();
}

fn link_to(name: &str) -> Option<async_nats::jetstream::object_store::ObjectOptions> {
    Some(async_nats::jetstream::object_store::ObjectOptions {
        link: Some(async_nats::jetstream::object_store::ObjectLink {
            name: Some(name.to_owned()),
            bucket: mouthpiece_nats::subjects::takes_bucket("studio"),
        }),
        max_chunk_size: None,
    })
}

/// Hostile objects: links to themselves (A → A, A → B → A) are refused, not followed; an
/// object whose metadata names chunks the store does not hold is an error after the idle
/// timeout; a dangling symbolic link planted at `<file>.partial` is not written through.
/// Nothing is left in the folder after any of them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fetch_refuses_links_missing_chunks_and_a_planted_partial_and_leaves_nothing() {
    harness::init_logs();
    let server = NatsServer::start();
    let client = reader(&server.url()).await;
    let store = TakeStore::open(&client, "studio").await.unwrap();
    let real = "booth-1/real_T001_x.mcap";
    let bytes = b"a take's bytes, a few of them".repeat(100);
    store.objects.put(real, &mut &bytes[..]).await.unwrap();
    let info = store.objects.info(real).await.unwrap();

    let mut itself = info.clone();
    itself.options = link_to("booth-1/self_T002_x.mcap");
    put_raw_info(&client, "booth-1/self_T002_x.mcap", itself).await;
    let mut a = info.clone();
    a.options = link_to("booth-1/b_T004_x.mcap");
    put_raw_info(&client, "booth-1/a_T003_x.mcap", a).await;
    let mut b = info.clone();
    b.options = link_to("booth-1/a_T003_x.mcap");
    put_raw_info(&client, "booth-1/b_T004_x.mcap", b).await;
    let mut holes = info.clone();
    holes.nuid = "NOCHUNKSHERE0000000000".into();
    holes.chunks = 5;
    holes.size = 5 * 128 * 1024;
    put_raw_info(&client, "booth-1/holes_T005_x.mcap", holes).await;

    let out = tempfile::tempdir().unwrap();
    let idle = Duration::from_secs(2);
    // Each fetch ends (the watchdog only catches a hang, it measures nothing).
    let fetch = async |name: &str, file: &Path| {
        tokio::time::timeout(
            Duration::from_secs(120),
            store.fetch_with_timeout(name, file, idle),
        )
        .await
        .unwrap_or_else(|_| panic!("fetching {name} did not end"))
    };
    for (name, expected) in [
        ("booth-1/self_T002_x.mcap", "is a link"),
        ("booth-1/a_T003_x.mcap", "is a link"),
        ("booth-1/holes_T005_x.mcap", "no data for"),
    ] {
        let file = out.path().join(name.rsplit('/').next().unwrap());
        let err = fetch(name, &file).await.unwrap_err().to_string();
        assert!(err.contains(expected), "{name}: {err}");
        let left: Vec<_> = std::fs::read_dir(out.path()).unwrap().collect();
        assert!(left.is_empty(), "{name}: left behind {left:?}");
    }

    // A dangling link at the partial name: refused, its target never created.
    let elsewhere = tempfile::tempdir().unwrap();
    let victim = elsewhere.path().join("victim.mcap");
    let file = out.path().join("real_T001_x.mcap");
    std::os::unix::fs::symlink(&victim, mouthpiece_nats::store::partial_path(&file)).unwrap();
    let err = fetch(real, &file).await.unwrap_err().to_string();
    assert!(err.contains("cannot create"), "{err}");
    assert!(!victim.exists(), "written through the planted link");
    assert!(!file.exists());
    std::fs::remove_file(mouthpiece_nats::store::partial_path(&file)).unwrap();

    // The real object still comes whole.
    assert_eq!(fetch(real, &file).await.unwrap(), bytes.len() as u64);
    assert_eq!(std::fs::read(&file).unwrap(), bytes);
}

/// Many servers that accept a connection and never answer: `connect_once` gives up within its
/// one overall deadline instead of trying each in turn for minutes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connecting_to_many_silent_servers_gives_up_at_the_overall_deadline() {
    // Listening sockets never accepted from: the kernel completes the handshake, and no
    // NATS INFO ever comes.
    let silent: Vec<std::net::TcpListener> = (0..16)
        .map(|_| std::net::TcpListener::bind("127.0.0.1:0").unwrap())
        .collect();
    let servers = silent
        .iter()
        .map(|l| format!("nats://{}", l.local_addr().unwrap()))
        .collect();
    let settings = NatsSettings::new(servers, "booth-1");
    // 16 servers of 5 s each would take 80 s; the watchdog only catches that.
    let result = tokio::time::timeout(
        Duration::from_secs(60),
        mouthpiece_nats::connect_once(&settings),
    )
    .await
    .expect("connect_once did not give up");
    let err = result.unwrap_err().to_string();
    assert!(err.contains("no server answered within"), "{err}");
}

/// Symbolic links planted in the takes folder: a link to a take elsewhere is not uploaded,
/// and a link at `<take>.uploaded.partial` is not written through (its target keeps its
/// bytes); the real take is uploaded and marked.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_uploader_follows_no_link_in_the_takes_folder() {
    harness::init_logs();
    let server = NatsServer::start();
    let folder = tempfile::tempdir().unwrap();
    let elsewhere = tempfile::tempdir().unwrap();
    let outside = record_take(elsewhere.path(), "secret", 5);
    // Older than the real take, so that it would be uploaded first.
    std::fs::File::options()
        .write(true)
        .open(&outside)
        .unwrap()
        .set_modified(std::time::UNIX_EPOCH + Duration::from_secs(1_000_000))
        .unwrap();
    let linked = folder.path().join("x_T009_y.mcap");
    std::os::unix::fs::symlink(&outside, &linked).unwrap();
    let real = record_take(folder.path(), "scene", 5);
    let victim = elsewhere.path().join("precious.txt");
    std::fs::write(&victim, b"precious").unwrap();
    std::os::unix::fs::symlink(
        &victim,
        mouthpiece_nats::store::partial_path(&marker_path(&real)),
    )
    .unwrap();

    let (hub, _control) = Hub::new(&HubConfig::default());
    let _link = start_link(&hub, server.url(), folder.path()).await;
    eventually(WAIT, async || {
        std::fs::symlink_metadata(marker_path(&real))
            .is_ok()
            .then_some(())
    })
    .await
    .expect("the real take was not uploaded");
    assert!(std::fs::symlink_metadata(marker_path(&real))
        .unwrap()
        .is_file());
    assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
    let client = reader(&server.url()).await;
    let records = TakeStore::open_existing(&client, "studio")
        .await
        .unwrap()
        .list()
        .await
        .unwrap();
    let objects: Vec<&str> = records.iter().map(|r| r.object.as_str()).collect();
    assert_eq!(
        objects,
        [format!(
            "booth-1/{}",
            real.file_name().unwrap().to_str().unwrap()
        )],
        "only the real take"
    );
    assert!(std::fs::symlink_metadata(marker_path(&linked)).is_err());
}
