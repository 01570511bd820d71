//! A three-node NATS cluster on this machine: one node killed during a session costs the
//! subscribers a short gap, and with every node down the booth's takes wait and arrive in
//! the object store once the cluster is back.
//!
//! The gap is measured from the frames' own timestamps (when the booth handed each to its
//! client), not from the test's clock: a loaded machine slows everything alike.

use crate::helper_harness as harness;
use crate::helper_harness_take as take;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use futures_util::StreamExt;
use harness::{eventually, NatsServer};
use mouthpiece_nats::publish::SENT_HEADER;
use mouthpiece_nats::store::TakeStore;
use mouthpiece_nats::{NatsLink, NatsSettings};
use mouthpiece_server::{Hub, HubConfig, StreamFrame};

const WAIT: Duration = Duration::from_secs(60);
/// The gap allowed when one node dies (the requirement); typically ~0.1 s here.
const MAX_GAP: Duration = Duration::from_secs(2);

fn sent_us(message: &async_nats::Message) -> i64 {
    message
        .headers
        .as_ref()
        .and_then(|h| h.get(SENT_HEADER))
        .and_then(|v| v.as_str().parse().ok())
        .expect("every frame carries its sending time")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_dead_node_costs_a_short_gap_and_takes_recorded_with_all_down_arrive_later() {
    harness::init_logs();
    let mut nodes = NatsServer::cluster();
    let urls: Vec<String> = nodes.iter().map(|n| n.url()).collect();
    let folder = tempfile::tempdir().unwrap();
    let (hub, _control) = Hub::new(&HubConfig::default());
    let link = NatsLink::start(
        hub.clone(),
        NatsSettings::new(urls.clone(), "b1"),
        "t".into(),
        folder.path().to_owned(),
    )
    .await
    .unwrap();
    let subscriber = async_nats::ConnectOptions::new()
        .retry_on_initial_connect()
        .reconnect_delay_callback(|n| mouthpiece_nats::reconnect_delay(n, Duration::from_secs(1)))
        .connect(mouthpiece_nats::server_addrs(&urls).unwrap())
        .await
        .unwrap();
    let mut frames = subscriber.subscribe("mouthpiece.b1.frame").await.unwrap();

    // Frames at 100 Hz, as the processing thread publishes them.
    let stop = Arc::new(AtomicBool::new(false));
    let publisher = std::thread::spawn({
        let (hub, stop) = (hub.clone(), stop.clone());
        move || {
            let mut frame = StreamFrame::default();
            while !stop.load(Ordering::Relaxed) {
                frame.t += 0.01;
                hub.publish(&frame);
                std::thread::sleep(Duration::from_millis(10));
            }
        }
    });
    let first = tokio::time::timeout(WAIT, frames.next())
        .await
        .unwrap()
        .unwrap();
    let mut last = sent_us(&first);
    // Kill the node the booth is connected to: the booth and (perhaps) the subscriber move.
    let booth_port = link.client().server_info().port;
    let victim = nodes.iter().position(|n| n.port == booth_port).unwrap();
    let before_kill = mouthpiece_nats::publish::unix_micros_now();
    nodes[victim].kill();
    let mut largest_gap = 0i64;
    let mut after_kill = 0;
    // Two hundred frames sent after the kill (about 2 s of them) must arrive.
    while after_kill < 200 {
        let message = tokio::time::timeout(WAIT, frames.next())
            .await
            .expect("frames stopped after one node died")
            .unwrap();
        let sent = sent_us(&message);
        largest_gap = largest_gap.max(sent - last);
        last = sent;
        if sent > before_kill {
            after_kill += 1;
        }
    }
    let gap = Duration::from_micros(largest_gap as u64);
    eprintln!("largest gap between frames with one of three nodes killed: {gap:?}");
    assert!(gap <= MAX_GAP, "gap {gap:?} with one node killed");
    assert!(link.client().server_info().port != booth_port);
    stop.store(true, Ordering::Relaxed);
    publisher.join().unwrap();

    // Every node down: the takes recorded meanwhile wait ...
    for node in &mut nodes {
        node.kill();
    }
    let counters = hub.nats();
    let recorded: Vec<_> = (0..3)
        .map(|_| take::record_take(folder.path(), "offline", 6))
        .collect();
    eventually(WAIT, async || {
        (counters.takes_waiting.load(Ordering::Relaxed) == 3).then_some(())
    })
    .await
    .expect("the takes recorded with the cluster down are not waiting");
    // ... and arrive once the cluster is back.
    for node in &mut nodes {
        node.restart_no_wait();
    }
    for node in &nodes {
        node.wait_until_ready();
    }
    eventually(Duration::from_secs(120), async || {
        (counters.takes_uploaded.load(Ordering::Relaxed) == 3).then_some(())
    })
    .await
    .expect("the takes recorded with the cluster down never arrived");
    let reader = async_nats::connect(urls[0].as_str()).await.unwrap();
    let listed = TakeStore::open_existing(&reader, "studio")
        .await
        .unwrap()
        .list()
        .await
        .unwrap();
    let mut names: Vec<String> = listed.iter().map(|r| r.file.clone()).collect();
    names.sort();
    let mut expected: Vec<String> = recorded
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    expected.sort();
    assert_eq!(names, expected);
}
