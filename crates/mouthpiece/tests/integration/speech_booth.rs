//! A booth without a camera through the real binary: `[source] spec = "none"`, the
//! microphone a real ALSA PCM (tests/alsa: the `file` plugin streaming Festival's speech,
//! paced by JACK's dummy driver), a take started and stopped over the WebSocket control
//! API, read back: its frames are the character's speech-driven steps, the mouth moves with
//! the sound, the sound is on `/audio`, and `export` turns it into keyframes and a WAV.
//! Needs Debian `festival`, `jackd2`, `libasound2-plugins`.

use crate::helper_alsa_booth as booth;
use crate::helper_daemon_run as daemon;
use crate::helper_speech_cover_mouth as cover_mouth;
use crate::live_record::{assert_rows_are_live, export_as_recorded, keep, LiveSteps};

use std::path::Path;
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use mouthpiece_recording::{AudioReader, MessageReader, SessionWriter, WriterOptions};
use mouthpiece_synth::{Synth, SynthConfig};
use serde_json::{json, Value};
use tokio_tungstenite::tungstenite::Message;

use cover_mouth::cover_mouth;
use daemon::{free_port, run_command, Daemon};

type Client =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// `mouthpiece run` on `config` in `dir`, its microphone the booth's PCM.
fn start_daemon(dir: &Path, config: &str, booth: &booth::Booth) -> Daemon {
    std::fs::write(dir.join("mouthpiece.toml"), config).unwrap();
    let mut command = run_command(dir, Path::new("mouthpiece.toml"));
    command
        .env("RUST_LOG", "info")
        .stderr(std::fs::File::create(dir.join("stderr.log")).unwrap());
    for (k, v) in booth.env() {
        command.env(k, v);
    }
    Daemon::spawn(&mut command)
}

/// A `mouthpiece.v1` client subscribed to the frames.
async fn connect(port: u16) -> Client {
    use tokio_tungstenite::tungstenite::client::IntoClientRequest;
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let mut request = format!("ws://127.0.0.1:{port}/")
            .into_client_request()
            .unwrap();
        request.headers_mut().insert(
            "Sec-WebSocket-Protocol",
            tokio_tungstenite::tungstenite::http::HeaderValue::from_static("mouthpiece.v1"),
        );
        if let Ok((mut ws, _)) = tokio_tungstenite::connect_async(request).await {
            ws.send(Message::Text(
                json!({"type": "subscribe", "fields": ["rig"]})
                    .to_string()
                    .into(),
            ))
            .await
            .unwrap();
            return ws;
        }
        assert!(Instant::now() < deadline, "the daemon never listened");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

async fn next_json(ws: &mut Client) -> Value {
    loop {
        let message = tokio::time::timeout(Duration::from_secs(30), ws.next())
            .await
            .expect("a message within 30 s")
            .expect("the connection open")
            .unwrap();
        if let Message::Text(text) = message {
            return serde_json::from_str(&text).unwrap();
        }
    }
}

/// The sources that drove the mouth, in order, each run once: blends between them left out
/// and the sources of a dip into a blend and back counted as one run.
fn sources_in_order<'a>(sources: impl IntoIterator<Item = &'a str>) -> Vec<&'a str> {
    let mut order: Vec<&str> = Vec::new();
    for source in sources {
        if source != "blend" && order.last() != Some(&source) {
            order.push(source);
        }
    }
    order
}

/// Sends a control request and returns its answer (`result` or `error` with its `id`),
/// keeping the human's entry of every frame received meanwhile.
async fn request_keeping(ws: &mut Client, body: Value, live: &mut LiveSteps) -> Value {
    let id = body["id"].clone();
    ws.send(Message::Text(body.to_string().into()))
        .await
        .unwrap();
    loop {
        let v = next_json(ws).await;
        keep(&v, "human", live);
        if (v["type"] == "result" || v["type"] == "error") && v["id"] == id {
            return v;
        }
    }
}

/// Festival speech (48 kHz) with `pause_s` of silence before and after each line, `times`
/// times.
fn speech_with_pauses(dir: &Path, times: usize, pause_s: f64) -> Vec<i16> {
    let line = booth::festival(
        "Hello from the booth without a camera. The voice alone moves the mouth of the character.",
        dir,
    );
    let pause = (48_000.0 * pause_s) as usize;
    let mut sound = Vec::new();
    for _ in 0..times {
        sound.extend(std::iter::repeat_n(0i16, pause));
        sound.extend_from_slice(&line);
    }
    sound.extend(std::iter::repeat_n(0i16, pause));
    sound
}

/// Every message of `topic` in `take` as JSON, with its log time.
fn json_messages(take: &Path, topic: &str) -> Vec<(u64, Value)> {
    let mut reader = MessageReader::open(take).unwrap();
    let mut found = Vec::new();
    while let Some(m) = reader.next_message().unwrap() {
        if &*m.topic == topic {
            found.push((m.log_time, serde_json::from_slice(&m.data).unwrap()));
        }
    }
    found
}

/// The take's sound as (log time of each sample block, its RMS) in 10 ms blocks.
fn sound_levels(take: &Path) -> Vec<(u64, f64)> {
    let mut reader = AudioReader::open(take).unwrap();
    let mut levels = Vec::new();
    while let Some(m) = reader.next_audio().unwrap() {
        let n = m.samples.len().max(1) as f64;
        let rms = (m.samples.iter().map(|&s| f64::from(s).powi(2)).sum::<f64>() / n).sqrt();
        levels.push((m.log_time, rms));
    }
    levels.sort_by_key(|l| l.0);
    levels
}

/// How far a step's points are from `rest`: the largest point distance.
fn displacement(points: &Value, rest: &Value) -> f64 {
    let points = points.as_object().unwrap();
    points
        .iter()
        .map(|(name, p)| {
            (0..3)
                .map(|k| (p[k].as_f64().unwrap() - rest[name][k].as_f64().unwrap()).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .fold(0.0, f64::max)
}

fn pearson(xs: &[f64], ys: &[f64]) -> f64 {
    let n = xs.len() as f64;
    let (mx, my) = (xs.iter().sum::<f64>() / n, ys.iter().sum::<f64>() / n);
    let cov: f64 = xs.iter().zip(ys).map(|(x, y)| (x - mx) * (y - my)).sum();
    let vx: f64 = xs.iter().map(|x| (x - mx).powi(2)).sum();
    let vy: f64 = ys.iter().map(|y| (y - my).powi(2)).sum();
    cov / (vx * vy).sqrt()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_take_on_a_booth_without_a_camera_holds_the_speech_driven_steps_and_the_sound() {
    let dir = tempfile::tempdir().unwrap();
    let sound = speech_with_pauses(dir.path(), 4, 1.0);
    let booth = booth::Booth::start(&sound);
    let port = free_port();
    let config = format!(
        "[source]\nspec = \"none\"\n[server]\nlisten = \"127.0.0.1:{port}\"\n\
         [takes]\nfolder = \"takes\"\nflush_s = 0.5\nmin_free_mb = 1\n\
         [audio]\ndevice = \"booth\"\n\
         [characters.settings.human]\nspeech = \"always\"\n\
         [characters.settings.wolf]\nspeech = \"always\"\n"
    );
    let mut daemon = start_daemon(dir.path(), &config, &booth);
    let log = || std::fs::read_to_string(dir.path().join("stderr.log")).unwrap_or_default();
    let mut ws = connect(port).await;
    let mut live = LiveSteps::new();
    let started = request_keeping(
        &mut ws,
        json!({"type": "record", "id": 1, "action": "start", "slate": "nocam", "take": 1}),
        &mut live,
    )
    .await;
    assert_eq!(started["type"], "result", "{started}\n{}", log());
    // The file as the daemon names it, relative to its working directory.
    let take = dir.path().join(started["detail"]["file"].as_str().unwrap());
    // Four seconds of steps (50 a second) published while the take records: a line's worth
    // of speech and a pause.
    let mut published = 0;
    let deadline = Instant::now() + Duration::from_secs(120);
    while published < 200 {
        assert!(
            Instant::now() < deadline,
            "no 200 frames in 2 minutes\n{}",
            log()
        );
        let v = next_json(&mut ws).await;
        keep(&v, "human", &mut live);
        if v["type"] == "frame" {
            let human = v["characters"]
                .as_array()
                .unwrap()
                .iter()
                .find(|c| c["name"] == "human")
                .cloned()
                .unwrap();
            assert_eq!(human["source"], "speech", "{v}");
            published += 1;
        }
    }
    let stopped = request_keeping(
        &mut ws,
        json!({"type": "record", "id": 2, "action": "stop"}),
        &mut live,
    )
    .await;
    assert_eq!(stopped["type"], "result", "{stopped}\n{}", log());
    let frames = stopped["detail"]["frames"].as_u64().unwrap();
    assert!(daemon.terminate().success(), "{}", log());

    // The take's frames: the character's steps, every one driven by speech, no camera.
    let steps = json_messages(&take, "/character/human");
    assert!(frames >= 150, "{stopped}");
    assert_eq!(steps.len() as u64, frames, "a message per step");
    assert_eq!(json_messages(&take, "/character/wolf").len() as u64, frames);
    assert_eq!(json_messages(&take, "/head").len() as u64, frames);
    assert!(json_messages(&take, "/camera/color").is_empty());
    assert!(steps.iter().all(|(_, s)| s["source"] == "speech"));
    assert!(steps.windows(2).all(|w| w[0].0 < w[1].0), "in time order");
    let metadata = MessageReader::open(&take).unwrap();
    let mut metadata = metadata;
    while metadata.next_message().unwrap().is_some() {}
    let take_meta = &metadata
        .metadata()
        .iter()
        .find(|(n, _)| n == "mouthpiece.take")
        .unwrap()
        .1;
    assert_eq!(take_meta["source"], "none");

    // The sound is on /audio, over the steps' span.
    let levels = sound_levels(&take);
    assert!(levels.len() >= 150, "{} sound blocks", levels.len());
    let (first_step, last_step) = (steps[0].0, steps.last().unwrap().0);
    assert!(
        levels[0].0 <= first_step + 100_000_000
            && levels.last().unwrap().0 + 100_000_000 >= last_step
    );

    // The mouth moves with the sound: its distance from the quietest step's pose follows the
    // sound's level around each step (the loudness over the 100 ms before it).
    let level_at = |t: u64| {
        let window: Vec<f64> = levels
            .iter()
            .filter(|(at, _)| *at <= t && *at + 100_000_000 > t)
            .map(|l| l.1)
            .collect();
        window.iter().sum::<f64>() / window.len().max(1) as f64
    };
    let loudness: Vec<f64> = steps.iter().map(|(t, _)| level_at(*t)).collect();
    let quietest = loudness
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .unwrap()
        .0;
    let rest = steps[quietest].1["points"].clone();
    let moved: Vec<f64> = steps
        .iter()
        .map(|(_, s)| displacement(&s["points"], &rest))
        .collect();
    let r = pearson(&loudness, &moved);
    let max_moved = moved.iter().copied().fold(0.0, f64::max);
    eprintln!(
        "{} steps, mouth vs sound r = {r:.2}, largest move {max_moved:.4}",
        steps.len()
    );
    assert!(max_moved > 1e-3, "the mouth never moved");
    assert!(r > 0.3, "the mouth does not follow the sound: r = {r:.2}");

    // `export` reads the take as recorded: a row per step, each the frame subscribers
    // received live, to float32, and the sound beside them.
    let csv = export_as_recorded(&take, "human", &dir.path().join("nocam.csv"));
    let rows = assert_rows_are_live(&csv, &live);
    assert_eq!(rows.len() as u64, frames, "a row per step");
    let exported: Vec<&Value> = rows.iter().filter_map(|(seq, _)| live.get(seq)).collect();
    assert!(exported.iter().all(|h| h["source"] == "speech"));
    // Speech alone measures the rig on its own dots: every step carries the curves, and the
    // jaw opens with the sound (the outputs that send curves, VMC, Live Link, iFacialMocap,
    // have something to send on a booth without a camera).
    assert!(exported.iter().all(|h| h["rig"]["curves"].is_object()));
    let jaw_open = exported
        .iter()
        .map(|h| h["rig"]["curves"]["jawOpen"].as_f64().unwrap())
        .fold(0.0, f64::max);
    assert!(jaw_open > 0.1, "jawOpen at most {jaw_open}");
    assert!(
        dir.path().join("nocam.wav").exists(),
        "the WAV beside the CSV"
    );
}

/// The synthetic performer for `seconds`, the lips covered over `covered` (session seconds).
/// Returns by how much a looping replay advances the device clock each pass, microseconds.
fn write_covered_session(path: &Path, seconds: f64, covered: (f64, f64)) -> u64 {
    let mut synth = Synth::new(SynthConfig {
        seconds,
        colour_effects: false,
        ..SynthConfig::default()
    })
    .unwrap();
    let mut writer = SessionWriter::create(path, WriterOptions::default()).unwrap();
    let mut stamps = Vec::new();
    while let Some((mut frame, truth)) = synth.render_next() {
        if (covered.0..covered.1).contains(&truth.t) {
            cover_mouth(&mut frame, &truth);
        }
        stamps.push(frame.device_ts_us);
        writer.write_frame(&frame).unwrap();
    }
    writer.finish().unwrap();
    // The replay's loop: the span plus one frame period.
    stamps.last().unwrap() - stamps[0] + (stamps[1] - stamps[0])
}

fn step_size(a: &Value, b: &Value) -> f64 {
    a.as_array()
        .unwrap()
        .iter()
        .zip(b.as_array().unwrap())
        .map(|(p, q)| {
            (0..3)
                .map(|k| (p[k].as_f64().unwrap() - q[k].as_f64().unwrap()).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .fold(0.0, f64::max)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn covered_lips_on_a_replayed_session_hand_the_mouth_to_the_booths_speech_and_back() {
    let dir = tempfile::tempdir().unwrap();
    let (seconds, covered_from, covered_to) = (9.0, 4.0, 6.5);
    let session = dir.path().join("covered.mcap");
    let pass_us = write_covered_session(&session, seconds, (covered_from, covered_to));
    // Speech all along (short pauses), longer than the passes the test may watch.
    let sound = speech_with_pauses(dir.path(), 24, 0.2);
    let booth = booth::Booth::start(&sound);
    let port = free_port();
    let config = format!(
        "[source]\nspec = \"replay:{}?loop=1\"\n[server]\nlisten = \"127.0.0.1:{port}\"\n\
         [takes]\nfolder = \"takes\"\nmin_free_mb = 1\n[audio]\ndevice = \"booth\"\n\
         [characters.settings.human]\nspeech = \"fallback\"\nspeech_hold_ms = 300\n\
         speech_blend_ms = 150\n",
        session.display()
    );
    let _daemon = start_daemon(dir.path(), &config, &booth);
    let log = || std::fs::read_to_string(dir.path().join("stderr.log")).unwrap_or_default();
    let mut ws = connect(port).await;
    // A take over the whole measurement: camera, speech and the handovers in one record.
    let mut live = LiveSteps::new();
    let started = request_keeping(
        &mut ws,
        json!({"type": "record", "id": 1, "action": "start", "slate": "mixed"}),
        &mut live,
    )
    .await;
    assert_eq!(started["type"], "result", "{started}\n{}", log());
    let take = dir.path().join(started["detail"]["file"].as_str().unwrap());
    // Whole passes over the session, from the first that starts after the client connected,
    // by the session's own clock (the replay's device time, `capture_us`, less its passes),
    // until one runs camera, then speech during the loss, then camera again. Speech counts
    // as coming in only while the microphone's newest sound is fresh: on a loaded machine
    // the test's own sound server can stall for longer, and the share of speech then dips
    // towards the camera and back (a blend) or a pass sees no speech at all; a few passes
    // are allowed for that.

    // The pass measured: camera, speech, camera, speech driving for over a second.
    let handed_over = |rows: &[(f64, String, Value)]| {
        let speech: Vec<f64> = rows
            .iter()
            .filter(|r| r.1 == "speech")
            .map(|r| r.0)
            .collect();
        rows.len() > 100
            && sources_in_order(rows.iter().map(|r| r.1.as_str())) == ["camera", "speech", "camera"]
            && speech.last().unwrap() - speech[0] > 1.0
    };
    const PASSES: usize = 6;
    let mut rows: Vec<(f64, String, Value)> = Vec::new();
    let mut tried: Vec<Vec<String>> = Vec::new();
    let mut first_pass = None;
    let mut current_pass = None;
    let deadline = Instant::now() + Duration::from_secs(300);
    loop {
        assert!(
            Instant::now() < deadline,
            "no pass in 5 minutes went camera, speech, camera: {tried:?}\n{}",
            log()
        );
        let v = next_json(&mut ws).await;
        keep(&v, "human", &mut live);
        if v["type"] != "frame" {
            continue;
        }
        let capture = v["capture_us"].as_u64().unwrap();
        let pass = capture / pass_us;
        if pass == *first_pass.get_or_insert(pass) {
            continue;
        }
        if current_pass != Some(pass) {
            if current_pass.is_some() {
                if handed_over(&rows) {
                    break;
                }
                tried.push(
                    sources_in_order(rows.iter().map(|r| r.1.as_str()))
                        .iter()
                        .map(|s| s.to_string())
                        .collect(),
                );
                assert!(
                    tried.len() < PASSES,
                    "in {PASSES} passes the mouth never went camera, speech (over a second), \
                     camera: {tried:?}\n{}",
                    log()
                );
                rows.clear();
            }
            current_pass = Some(pass);
        }
        let t = (capture % pass_us) as f64 / 1e6;
        let human = v["characters"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["name"] == "human")
            .cloned()
            .unwrap_or_else(|| panic!("no human in {v}"));
        rows.push((
            t,
            human["source"].as_str().unwrap_or("camera").to_owned(),
            human["points"].clone(),
        ));
    }
    if !tried.is_empty() {
        eprintln!("passes before the one measured: {tried:?}");
    }
    let speech: Vec<&(f64, String, Value)> = rows.iter().filter(|r| r.1 == "speech").collect();
    let (speech_from, speech_to) = (speech[0].0, speech.last().unwrap().0);
    eprintln!("speech from {speech_from:.2} to {speech_to:.2} s of the session");
    // Within the cover, after the hold (300 ms), and back to the camera soon after it.
    assert!(speech_from >= covered_from + 0.2 && speech_to < covered_to + 0.5);
    assert!(
        speech_to - speech_from > 1.0,
        "speech drove {speech_from}..{speech_to}"
    );
    // The mouth moves from the sound while the lips are covered.
    let openings: Vec<f64> = speech.iter().map(|r| step_size(&r.2, &rows[0].2)).collect();
    let (lo, hi) = openings
        .iter()
        .fold((f64::MAX, 0.0f64), |(a, b), &o| (a.min(o), b.max(o)));
    assert!(hi - lo > 0.003, "speech moved the mouth only {lo}..{hi}");
    // No jump at either handover beyond the sources' own motion and the blend's
    // (docs/daemon.md: 1.5 / blend of their distance per second).
    let (mut normal, mut handover) = (0.0f64, 0.0f64);
    for w in rows.windows(2) {
        let step = step_size(&w[0].2, &w[1].2);
        if w[0].1 == w[1].1 && w[1].1 != "blend" {
            normal = normal.max(step);
        } else {
            handover = handover.max(step);
        }
    }
    // A frame dropped under load makes a step span more time: the longest gap between frames.
    let frame_s = rows
        .windows(2)
        .map(|w| w[1].0 - w[0].0)
        .fold(1.0 / 30.0, f64::max);
    let blend_move = 1.5 / 0.15 * frame_s * hi.max(0.03);
    eprintln!("largest handover step {handover}, normal {normal} + blend {blend_move}");
    assert!(
        handover <= normal + blend_move,
        "a handover step of {handover} beyond {normal} + {blend_move}"
    );

    // The take's export is what went out live, row for row, through both handovers.
    let stopped = request_keeping(
        &mut ws,
        json!({"type": "record", "id": 2, "action": "stop"}),
        &mut live,
    )
    .await;
    assert_eq!(stopped["type"], "result", "{stopped}\n{}", log());
    let csv = export_as_recorded(&take, "human", &dir.path().join("mixed.csv"));
    let exported = assert_rows_are_live(&csv, &live);
    let exported_runs = sources_in_order(
        exported
            .iter()
            .filter_map(|(seq, _)| live.get(seq))
            .map(|h| h["source"].as_str().unwrap_or("camera")),
    );
    assert!(
        exported_runs
            .windows(3)
            .any(|w| w == ["camera", "speech", "camera"]),
        "the take's rows came from {exported_runs:?}"
    );
    // While speech drives the mouth, the rig's curves are measured on the speech-driven
    // dots: the jaw opens and closes with the sound (the camera sees no lips then).
    let jaw_open: Vec<f64> = live
        .values()
        .filter(|h| h["source"] == "speech")
        .filter_map(|h| h["rig"]["curves"]["jawOpen"].as_f64())
        .collect();
    let (lo, hi) = jaw_open
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    assert!(
        !jaw_open.is_empty() && hi - lo > 0.05,
        "jawOpen under speech from {lo} to {hi} over {} steps",
        jaw_open.len()
    );
}
