use super::*;
use crate::file::TakeFile;
use crate::writer::write_take;
use mouthpiece_recording::{SessionWriter, WriterOptions};
use std::path::Path;
use std::time::UNIX_EPOCH;

#[test]
fn one_slate_rule_for_protocol_config_and_takes() {
    for (slate, ok) in [
        ("scene4", true),
        ("Scene_4.b-2", true),
        ("4", true),
        ("-rf", false),
        (".hidden", false),
        ("_x", false),
        ("..", false),
        ("", false),
        ("a b", false),
        ("a/b", false),
        ("\u{e9}t\u{e9}", false),
        (&"a".repeat(64), true),
        (&"a".repeat(65), false),
    ] {
        assert_eq!(valid_slate(slate), ok, "{slate:?}");
        assert_eq!(
            mouthpiece_config::Slate::try_from(slate.to_owned()).is_ok(),
            ok,
            "config: {slate:?}"
        );
        let message = serde_json::json!({"type": "record", "action": "start", "slate": slate});
        assert_eq!(
            mouthpiece_server::protocol::parse_client_message(&message.to_string()).is_ok(),
            ok,
            "protocol: {slate:?}"
        );
    }
}

#[test]
fn file_names_carry_slate_take_and_utc_time() {
    // 2026-11-22 03:04:05 UTC
    let t = UNIX_EPOCH + Duration::from_secs(1_795_316_645);
    assert_eq!(
        file_name("scene12", 7, t),
        "scene12_T007_20261122T030405Z.mcap"
    );
    assert_eq!(utc_stamp(UNIX_EPOCH), "19700101T000000Z");
    // Leap day.
    assert_eq!(
        utc_stamp(UNIX_EPOCH + Duration::from_secs(951_782_400)),
        "20000229T000000Z"
    );
}

#[test]
fn next_take_follows_the_highest_of_the_slate() {
    let dir = tempfile::tempdir().unwrap();
    assert_eq!(next_take(dir.path(), "sc1"), 1);
    for name in [
        "sc1_T001_20260101T000000Z.mcap",
        "sc1_T009_20260101T000100Z.mcap",
        "sc10_T050_x.mcap",
        "sc1_Tx.mcap",
    ] {
        std::fs::write(dir.path().join(name), b"").unwrap();
    }
    assert_eq!(next_take(dir.path(), "sc1"), 10);
    assert_eq!(next_take(dir.path(), "sc10"), 51);
    assert_eq!(next_take(dir.path(), "other"), 1);
}

#[test]
fn slates_that_are_not_file_names_are_rejected() {
    assert!(valid_slate("scene-12_b.2"));
    for bad in ["", "../x", ".hidden", "-rf", "a b", "a/b", &"x".repeat(65)] {
        assert!(!valid_slate(bad), "{bad:?}");
    }
}

pub(crate) fn settings(folder: &Path) -> TakeSettings {
    TakeSettings {
        folder: folder.to_owned(),
        flush: Duration::from_millis(100),
        min_free_mb: 0,
        queue_frames: 64,
        timecode_rate: "30".into(),
        max_write_bytes_s: None,
    }
}

fn frame(seq: u64) -> Arc<Frame> {
    use mouthpiece_frame::{Calibration, ColorImage, DepthImage, Intrinsics};
    let mut color = ColorImage::new(64, 48);
    color
        .data
        .iter_mut()
        .enumerate()
        .for_each(|(i, b)| *b = (i as u64 * 7 + seq) as u8);
    let mut depth = DepthImage::new(64, 48);
    depth
        .data
        .iter_mut()
        .enumerate()
        .for_each(|(i, d)| *d = 600 + (i as u16 % 50));
    Arc::new(Frame {
        seq,
        device_ts_us: seq * 33_333,
        host_rx: Instant::now(),
        wall_clock: Some(UNIX_EPOCH + Duration::from_micros(1_795_316_645_000_000 + seq * 33_333)),
        color,
        depth,
        calibration: Arc::new(Calibration::registered(Intrinsics::ideal(
            64, 48, 52.5, 52.5, 31.5, 23.5,
        ))),
    })
}

pub(crate) fn derived(seq: u64) -> Box<Derived> {
    Box::new(Derived {
        seq,
        t: seq as f64 / 30.0,
        wall_us: 1_795_316_645_000_000 + seq as i64 * 33_333,
        timecode: format!("03:04:05:{:02}", seq % 30),
        performer: vec![("D1".into(), Some([0.01, 0.02, 0.6])), ("F1".into(), None)],
        stabilised: vec![("D1".into(), [0.025, 0.0, 0.0], 1.0)],
        head: HeadPose::default(),
        characters: vec![CharacterRecord {
            name: "wolf".into(),
            points: vec![("P1".into(), [0.07, 0.0, 0.0])],
            confidence: vec![1.0],
            curve: None,
            head: Some(Default::default()),
            rig: (seq >= 5).then(|| rig(seq)),
            source: if seq >= 5 {
                mouthpiece_output::MouthSource::Speech
            } else {
                mouthpiece_output::MouthSource::Camera
            },
        }],
        status: serde_json::json!({"calibrating": false}),
    })
}

/// A rig with values that differ per frame.
fn rig(seq: u64) -> RigState {
    let mut rig = RigState::default();
    rig.jaw.angle_deg = seq as f32;
    rig.jaw.slide_m = -0.0005 * seq as f32;
    for (k, c) in rig.curves.0.iter_mut().enumerate() {
        *c = ((k as u64 + seq) % 10) as f32 / 10.0;
    }
    rig
}

/// The `/character/<name>` messages of a take, in order.
fn character_messages(path: &Path, name: &str) -> Vec<serde_json::Value> {
    let mut reader = mouthpiece_recording::MessageReader::open(path).unwrap();
    let topic = format!("/character/{name}");
    let mut out = Vec::new();
    while let Some(message) = reader.next_message().unwrap() {
        if *message.topic == *topic {
            out.push(serde_json::from_slice(&message.data).unwrap());
        }
    }
    out
}

#[test]
fn the_rig_is_recorded_per_frame_once_there_is_one() {
    let dir = tempfile::tempdir().unwrap();
    let mut takes = Takes::new(settings(dir.path()));
    let info = start_wait(&mut takes, "rig", None).unwrap();
    for seq in 0..10 {
        takes.push(frame(seq), derived(seq));
    }
    stop_wait(&mut takes).unwrap();
    let messages = character_messages(&info.path, "wolf");
    assert_eq!(messages.len(), 10);
    for m in &messages {
        let seq = m["seq"].as_u64().unwrap();
        // Which source drove the mouth is recorded with every frame.
        assert_eq!(
            m["source"],
            if seq < 5 { "camera" } else { "speech" },
            "{m}"
        );
        if seq < 5 {
            // Before the neutral pose: no `rig` key at all (as in takes made before the
            // rig existed), and the rest of the message as ever.
            assert!(m.get("rig").is_none(), "{m}");
            assert_eq!(m["points"]["P1"], serde_json::json!([0.07f32, 0.0, 0.0]));
            continue;
        }
        let want = rig(seq);
        assert_eq!(m["rig"]["jaw"]["angle_deg"], want.jaw.angle_deg, "{m}");
        assert_eq!(m["rig"]["jaw"]["slide_m"], want.jaw.slide_m, "{m}");
        let curves = m["rig"]["curves"].as_object().unwrap();
        let names: std::collections::BTreeSet<&str> = curves.keys().map(String::as_str).collect();
        let want_names = mouthpiece_output::CURVE_NAMES.into_iter().collect();
        assert_eq!(names, want_names, "every curve, by name");
        for (k, name) in mouthpiece_output::CURVE_NAMES.iter().enumerate() {
            assert_eq!(curves[*name], want.curves.0[k], "{name} at {seq}");
        }
        assert_eq!(m["rig"]["lips"]["upper"]["rotation"][0], 1.0, "{m}");
    }
}

fn topics(path: &Path) -> (std::collections::BTreeMap<String, usize>, Vec<String>) {
    let mut reader = mouthpiece_recording::MessageReader::open(path).unwrap();
    let mut topics = std::collections::BTreeMap::new();
    while let Some(message) = reader.next_message().unwrap() {
        *topics.entry(message.topic.to_string()).or_insert(0) += 1;
    }
    let metadata = reader
        .metadata()
        .iter()
        .map(|(name, _)| name.clone())
        .collect();
    (topics, metadata)
}

/// Depth messages readable from a file being written (0 while its header is not out).
fn depth_messages(path: &Path) -> usize {
    let Ok(mut reader) = mouthpiece_recording::MessageReader::open(path) else {
        return 0;
    };
    let mut n = 0;
    while let Ok(Some(message)) = reader.next_message() {
        n += usize::from(&*message.topic == "/camera/depth");
    }
    n
}

const WAIT: Duration = Duration::from_secs(10);

/// Starts a take and waits for the writer thread's answer.
pub(crate) fn start_wait(
    takes: &mut Takes,
    slate: &str,
    take: Option<u32>,
) -> Result<TakeInfo, String> {
    let (tx, rx) = crossbeam_channel::bounded(1);
    takes.start(
        slate,
        take,
        "replay:test.mcap",
        Box::new(move |r| {
            let _ = tx.send(r);
        }),
        Box::new(|_| {}),
    );
    rx.recv_timeout(WAIT).expect("the writer answers")
}

/// Stops the take and waits until it is closed.
pub(crate) fn stop_wait(takes: &mut Takes) -> Result<TakeEnded, String> {
    let (tx, rx) = crossbeam_channel::bounded(1);
    takes.stop(Box::new(move |r| {
        let _ = tx.send(r);
    }));
    rx.recv_timeout(WAIT).expect("the writer answers")
}

#[test]
fn a_take_holds_raw_frames_and_every_derived_channel() {
    let dir = tempfile::tempdir().unwrap();
    let mut takes = Takes::new(settings(dir.path()));
    let info = start_wait(&mut takes, "scene1", None).unwrap();
    assert_eq!(info.take, 1);
    for seq in 0..10 {
        takes.push(frame(seq), derived(seq));
    }
    let ended = stop_wait(&mut takes).unwrap();
    assert_eq!((ended.frames, ended.dropped, ended.error), (10, 0, None));
    let (topics, metadata) = topics(&info.path);
    for topic in [
        "/camera/color",
        "/camera/depth",
        "/performer/points",
        "/performer/stabilised",
        "/head",
        "/character/wolf",
    ] {
        assert_eq!(topics.get(topic), Some(&10), "{topic}: {topics:?}");
    }
    assert!(topics.contains_key("/camera/calibration"), "{topics:?}");
    assert!(
        metadata.iter().any(|m| m == "mouthpiece.take"),
        "{metadata:?}"
    );
    // The next take of the slate counts on.
    let next = start_wait(&mut takes, "scene1", None).unwrap().take;
    assert_eq!(next, 2);
    stop_wait(&mut takes).unwrap();
    let err = stop_wait(&mut takes).unwrap_err();
    assert!(err.contains("no take is recording"), "{err}");
}

/// A booth without a camera: steps without a frame hold the derived channels alone, logged
/// at each step's wall clock, and count as the take's frames.
#[test]
fn a_take_of_steps_without_a_camera_holds_the_derived_channels_at_their_wall_clock() {
    let dir = tempfile::tempdir().unwrap();
    let mut takes = Takes::new(settings(dir.path()));
    let info = start_wait(&mut takes, "nocam", None).unwrap();
    for seq in 0..10 {
        takes.push_step(derived(seq));
    }
    let ended = stop_wait(&mut takes).unwrap();
    assert_eq!((ended.frames, ended.dropped, ended.error), (10, 0, None));
    let (topics, _) = topics(&info.path);
    for topic in ["/performer/points", "/head", "/character/wolf"] {
        assert_eq!(topics.get(topic), Some(&10), "{topic}: {topics:?}");
    }
    assert!(
        !topics.keys().any(|t| t.starts_with("/camera/")),
        "{topics:?}"
    );
    let mut reader = mouthpiece_recording::MessageReader::open(&info.path).unwrap();
    let mut wolf = Vec::new();
    while let Some(m) = reader.next_message().unwrap() {
        if &*m.topic == "/character/wolf" {
            wolf.push((
                m.log_time,
                serde_json::from_slice::<serde_json::Value>(&m.data).unwrap(),
            ));
        }
    }
    for (seq, (log_time, message)) in wolf.iter().enumerate() {
        assert_eq!(
            *log_time,
            (1_795_316_645_000_000 + seq as u64 * 33_333) * 1000
        );
        assert_eq!(message["seq"], seq);
    }
    assert_eq!(wolf[7].1["source"], "speech");
}

#[test]
fn a_take_killed_mid_way_is_readable_up_to_its_last_flush() {
    let dir = tempfile::tempdir().unwrap();
    let mut takes = Takes::new(settings(dir.path()));
    let path = start_wait(&mut takes, "crash", Some(3)).unwrap().path;
    // Frames 100 ms apart in capture time: every frame closes a chunk (flush = 100 ms).
    for seq in 0..8 {
        let mut f = (*frame(seq)).clone();
        f.wall_clock = Some(UNIX_EPOCH + Duration::from_millis(1_795_316_645_000 + seq * 100));
        takes.push(Arc::new(f), derived(seq));
    }
    // Wait for the writer to drain, then copy the file as a kill -9 would leave it: no
    // summary, no footer.
    let deadline = Instant::now() + Duration::from_secs(10);
    while Instant::now() < deadline && depth_messages(&path) < 7 {
        std::thread::sleep(Duration::from_millis(20));
    }
    let snapshot = dir.path().join("killed.mcap");
    std::fs::copy(&path, &snapshot).unwrap();
    stop_wait(&mut takes).unwrap();
    let (topics, _) = topics(&snapshot);
    assert!(
        topics.get("/camera/depth").copied().unwrap_or(0) >= 7,
        "{topics:?}"
    );
    assert!(
        topics.get("/character/wolf").copied().unwrap_or(0) >= 7,
        "{topics:?}"
    );
}

#[test]
fn a_capped_take_file_writes_no_faster_than_its_cap() {
    use std::io::Write;
    let dir = tempfile::tempdir().unwrap();
    let file = std::fs::File::create(dir.path().join("capped")).unwrap();
    let mut capped = TakeFile::new(file, Some(1e6));
    let started = Instant::now();
    for _ in 0..5 {
        capped.write_all(&[7u8; 60_000]).unwrap();
    }
    // 300 kB at 1 MB/s: 0.3 s at least.
    assert!(
        started.elapsed() >= Duration::from_millis(300),
        "{:?}",
        started.elapsed()
    );
    assert_eq!(
        std::fs::metadata(dir.path().join("capped")).unwrap().len(),
        300_000
    );
}

#[test]
fn disk_full_stops_the_take_and_says_so() {
    // /dev/full fails every write with ENOSPC.
    let file = std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap();
    let writer = SessionWriter::new(
        std::io::BufWriter::new(TakeFile::new(file, None)),
        "/dev/full".into(),
        WriterOptions {
            flush_interval: Duration::from_millis(10),
            ..WriterOptions::default()
        },
    )
    .unwrap();
    let (queue, items) = crossbeam_channel::bounded(64);
    for seq in 0..10 {
        queue
            .send(TakeItem::Frame {
                frame: frame(seq),
                derived: derived(seq),
            })
            .unwrap();
    }
    drop(queue);
    let dir = tempfile::tempdir().unwrap();
    let failed = AtomicBool::new(false);
    let result = write_take(writer, items, None, &settings(dir.path()), &failed);
    let error = result.error.unwrap();
    assert!(error.contains("No space left on device"), "{error}");
    assert!(failed.load(Ordering::Acquire));
}

#[test]
fn a_take_that_cannot_start_says_why_and_stops_recording() {
    let dir = tempfile::tempdir().unwrap();
    let not_a_folder = dir.path().join("file");
    std::fs::write(&not_a_folder, b"").unwrap();
    let mut takes = Takes::new(settings(&not_a_folder));
    let err = start_wait(&mut takes, "s", None).unwrap_err();
    assert!(err.contains("takes folder"), "{err}");
    let deadline = Instant::now() + WAIT;
    while takes.is_recording() && Instant::now() < deadline {
        takes.poll();
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(!takes.is_recording());
    // A stop that comes after the failure is answered too.
    let err = stop_wait(&mut takes).unwrap_err();
    assert!(err.contains("no take"), "{err}");
}

#[test]
fn takes_never_overwrite_a_file_or_follow_a_link() {
    let dir = tempfile::tempdir().unwrap();
    let mut takes = Takes::new(settings(dir.path()));
    // Links where the next takes would go (this second and the next few), to a file
    // that must stay untouched.
    let victim = dir.path().join("victim");
    std::fs::write(&victim, b"precious").unwrap();
    let now = SystemTime::now();
    for s in 0..3 {
        std::os::unix::fs::symlink(
            &victim,
            dir.path()
                .join(file_name("s", 1, now + Duration::from_secs(s))),
        )
        .unwrap();
    }
    let mut paths = Vec::new();
    for _ in 0..3 {
        // The same slate and take number, within the same second.
        let info = start_wait(&mut takes, "s", Some(1)).unwrap();
        takes.push(frame(0), derived(0));
        let ended = stop_wait(&mut takes).unwrap();
        assert_eq!(ended.frames, 1);
        paths.push(info.path);
    }
    assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
    paths.sort();
    paths.dedup();
    assert_eq!(paths.len(), 3, "{paths:?}");
    for path in &paths {
        assert!(!path.is_symlink(), "{}", path.display());
        assert_eq!(topics(path).0.get("/camera/depth"), Some(&1));
    }
}

#[test]
fn starting_and_stopping_never_wait_for_the_writer() {
    let dir = tempfile::tempdir().unwrap();
    let mut takes = Takes::new(settings(dir.path()));
    // The writer thread is held inside its start callback: if `start` or `stop`
    // waited for it (file creation, draining), this test would hang.
    let (release, held) = crossbeam_channel::bounded::<()>(1);
    let (started_tx, started_rx) = crossbeam_channel::bounded(1);
    takes.start(
        "s",
        None,
        "x",
        Box::new(move |r| {
            let _ = held.recv_timeout(WAIT);
            let _ = started_tx.send(r);
        }),
        Box::new(|_| {}),
    );
    for seq in 0..5 {
        takes.push(frame(seq), derived(seq));
    }
    let (stopped_tx, stopped_rx) = crossbeam_channel::bounded(1);
    let before = Instant::now();
    takes.stop(Box::new(move |r| {
        let _ = stopped_tx.send(r);
    }));
    assert!(before.elapsed() < Duration::from_secs(1));
    assert!(stopped_rx.try_recv().is_err(), "not closed yet");
    release.send(()).unwrap();
    started_rx.recv_timeout(WAIT).unwrap().unwrap();
    let ended = stopped_rx.recv_timeout(WAIT).unwrap().unwrap();
    assert_eq!(
        ended.frames, 5,
        "frames queued before the file opened are kept"
    );
    takes.shutdown();
}

#[test]
fn free_space_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    assert!(free_mb(dir.path()).is_some());
    assert_eq!(free_mb(Path::new("/nonexistent/x")), None);
}

/// A block of `n` samples of value `v`, its first sample at `wall`.
fn sound(first_frame: u64, n: usize, v: i16, wall: SystemTime) -> mouthpiece_frame::AudioEvent {
    mouthpiece_frame::AudioEvent::Block(Arc::new(mouthpiece_frame::AudioBlock {
        seq: first_frame / n as u64,
        first_frame,
        format: mouthpiece_frame::AudioFormat {
            sample_rate: 48_000,
            channels: 1,
        },
        samples: vec![v; n],
        host_rx: Instant::now(),
        wall_clock: Some(wall),
    }))
}

#[test]
fn a_take_records_the_sound_and_where_it_stopped() {
    use mouthpiece_frame::{AudioBus, AudioEvent, AudioFormat, AudioSourceInfo};
    let dir = tempfile::tempdir().unwrap();
    let bus = AudioBus::new();
    let mut takes = Takes::new(settings(dir.path()));
    takes.set_audio(bus.clone(), 1000);
    let info = start_wait(&mut takes, "voice", None).unwrap();
    let t0 = UNIX_EPOCH + Duration::from_micros(1_795_316_645_000_000);
    bus.publish(AudioEvent::Started(AudioSourceInfo {
        spec: "booth".into(),
        description: "test".into(),
        format: AudioFormat {
            sample_rate: 48_000,
            channels: 1,
        },
        frames_per_block: 480,
        live: true,
    }));
    for i in 0..10u64 {
        // Block 5 was lost to an overrun: a gap of 480 frames.
        if i != 5 {
            bus.publish(sound(
                i * 480,
                480,
                i as i16,
                t0 + Duration::from_millis(i * 10),
            ));
        }
        takes.push(frame(i), derived(i));
    }
    bus.publish(AudioEvent::Stopped {
        reason: "the device was unplugged".into(),
        at: t0 + Duration::from_millis(100),
        frames: 4800,
    });
    let ended = stop_wait(&mut takes).unwrap();
    assert_eq!(
        (ended.frames, ended.error),
        (10, None),
        "the video is all there"
    );
    let mut reader = mouthpiece_recording::AudioReader::open(&info.path).unwrap();
    let mut blocks = Vec::new();
    while let Some(m) = reader.next_audio().unwrap() {
        blocks.push(m);
    }
    assert_eq!(blocks.len(), 9);
    assert_eq!(blocks[5].samples[0], 6);
    assert_eq!(
        blocks[5].log_time, 1_795_316_645_060_000_000,
        "a block's log time is the wall clock of its first sample"
    );
    let (topics, metadata) = topics(&info.path);
    assert_eq!(
        topics.get("/audio/events"),
        Some(&3),
        "started, gap, stopped: {topics:?}"
    );
    assert!(
        metadata.iter().any(|m| m == "mouthpiece.audio"),
        "{metadata:?}"
    );
    let mut messages = mouthpiece_recording::MessageReader::open(&info.path).unwrap();
    let mut events = Vec::new();
    while let Some(m) = messages.next_message().unwrap() {
        if &*m.topic == "/audio/events" {
            events.push(serde_json::from_slice::<serde_json::Value>(&m.data).unwrap());
        }
    }
    assert_eq!(events[1]["event"], "gap");
    assert_eq!(events[1]["missing_frames"], 480);
    assert_eq!(events[2]["event"], "stopped");
    assert_eq!(events[2]["wall_us"], 1_795_316_645_100_000i64);
    let audio = messages
        .metadata()
        .iter()
        .find(|(name, _)| name == "mouthpiece.audio")
        .map(|(_, m)| m.clone())
        .unwrap();
    assert_eq!(audio["stopped_unix_us"], "1795316645100000");
    assert_eq!(audio["blocks"], "9");
    assert!(audio["stop_reason"].contains("unplugged"));
}

/// Frames and sound written until a disk with room for `space` bytes (`None`: room for all)
/// fills: the writer's result, and the file.
fn take_with_sound_on_a_disk(
    dir: &Path,
    space: Option<u64>,
) -> (crate::writer::WriterResult, std::path::PathBuf) {
    use mouthpiece_frame::AudioBus;
    let path = dir.join(format!("take-{}.mcap", space.unwrap_or(0)));
    let file = std::fs::File::create(&path).unwrap();
    let file = match space {
        Some(space) => TakeFile::with_space(file, space),
        None => TakeFile::new(file, None),
    };
    let writer = SessionWriter::new(
        std::io::BufWriter::new(file),
        path.display().to_string(),
        WriterOptions {
            flush_interval: Duration::from_millis(100),
            ..WriterOptions::default()
        },
    )
    .unwrap();
    let bus = AudioBus::new();
    let audio = bus.subscribe(1000);
    let (queue, items) = crossbeam_channel::bounded(1000);
    let t0 = UNIX_EPOCH + Duration::from_micros(1_795_316_645_000_000);
    // Two seconds: 60 frames and 200 blocks of 10 ms, on the frames' wall clock.
    for seq in 0..60 {
        queue
            .send(TakeItem::Frame {
                frame: frame(seq),
                derived: derived(seq),
            })
            .unwrap();
    }
    for i in 0..200u64 {
        bus.publish(sound(
            i * 480,
            480,
            i as i16,
            t0 + Duration::from_millis(i * 10),
        ));
    }
    drop(queue);
    let failed = AtomicBool::new(false);
    let result = write_take(writer, items, Some(audio), &settings(dir), &failed);
    assert_eq!(failed.load(Ordering::Acquire), result.error.is_some());
    (result, path)
}

#[test]
fn a_disk_that_fills_while_sound_is_recorded_stops_the_take_and_keeps_frames_and_sound() {
    let dir = tempfile::tempdir().unwrap();
    let (whole, path) = take_with_sound_on_a_disk(dir.path(), None);
    assert_eq!((whole.frames, whole.error), (60, None));
    let size = std::fs::metadata(&path).unwrap().len();
    // The same take on a disk with room for half of it.
    let (result, path) = take_with_sound_on_a_disk(dir.path(), Some(size / 2));
    let error = result.error.expect("the take stopped");
    assert!(error.contains("No space left on device"), "{error}");
    // What reached the disk reads back, up to its last complete chunk: frames whole, and the
    // sound bit for bit at the wall clock of its first sample.
    let mut frames = mouthpiece_recording::SessionReader::open(&path).unwrap();
    let mut kept = 0u64;
    while let Some(f) = frames.next_frame().unwrap() {
        assert_eq!(
            f.frame.device_ts_us,
            kept * 33_333,
            "in order, none missing"
        );
        assert_eq!(f.frame.color.width, 64);
        kept += 1;
    }
    let mut reader = mouthpiece_recording::AudioReader::open(&path).unwrap();
    let mut blocks = Vec::new();
    while let Some(m) = reader.next_audio().unwrap() {
        blocks.push(m);
    }
    blocks.sort_by_key(|b| b.log_time);
    eprintln!(
        "{kept} frames and {} blocks of sound kept of 60 and 200",
        blocks.len()
    );
    assert!(kept > 0 && kept < 60, "{kept} frames kept");
    assert!(
        !blocks.is_empty() && blocks.len() < 200,
        "{} blocks kept",
        blocks.len()
    );
    for (i, b) in blocks.iter().enumerate() {
        assert_eq!(
            b.samples,
            vec![i as i16; 480],
            "block {i} is the sound sent"
        );
        assert_eq!(
            b.log_time,
            1_795_316_645_000_000_000 + i as u64 * 10_000_000
        );
    }
    // The frames' derived channels came through with them (the last frame's may be in the
    // chunk the disk had no room for: a chunk can close right after a frame's images).
    let (topics, _) = topics(&path);
    let derived = topics.get("/character/wolf").copied().unwrap_or(0) as u64;
    assert!(
        (kept - 1..=kept).contains(&derived),
        "{kept} frames: {topics:?}"
    );
}
