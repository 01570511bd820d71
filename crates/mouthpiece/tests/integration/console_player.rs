//! The console plays a take back in headless Chromium (Debian's `chromium` and
//! `chromium-driver`): the real daemon serves a take written here (synthetic frames, tracked
//! dots, and a `/audio` channel of `foxglove.RawAudio` `pcm-s16` blocks in CDR as takes write
//! them, a 440 Hz tone), and
//! the page shows its images with the dots drawn where they were tracked and schedules its
//! sound, all of it, on the same clock. `/take` serves nothing but the takes in the takes
//! folder, and only with a token.

use crate::helper_daemon_run as daemon;
use crate::helper_webdriver as webdriver;

use std::io::{Read, Write};
use std::path::Path;
use std::time::{Duration, Instant};

use daemon::{free_port, run_command, Daemon};
use mouthpiece_recording::{SessionReader, SessionWriter, WriterOptions};
use serde_json::json;

const CONTROL: &str = "player-control-token-0123";
const READ: &str = "player-read-token-0123456";
const TAKE: &str = "play_T001_20260101T000000Z.mcap";
const RATE: u32 = 48_000;

/// 20 ms of a 440 Hz tone starting at sample `first`.
fn tone(first: u64) -> Vec<i16> {
    (first..first + 960)
        .map(|i| {
            (8000.0 * (i as f64 * 440.0 * std::f64::consts::TAU / f64::from(RATE)).sin()) as i16
        })
        .collect()
}

/// The take: the session's frames, three dots tracked at fixed places, and 2 s of sound.
fn write_take(session: &Path, take: &Path) {
    let mut reader = SessionReader::open(session).unwrap();
    let mut writer = SessionWriter::create(take, WriterOptions::default()).unwrap();
    let mut first = None;
    let mut blocks = 0u64;
    let format = mouthpiece_frame::AudioFormat {
        sample_rate: RATE,
        channels: 1,
    };
    while let Some(f) = reader.next_frame().unwrap() {
        let log_time = writer.write_frame(&f.frame).unwrap();
        let first = *first.get_or_insert(log_time);
        writer
            .write_json(
                "/performer/points",
                log_time,
                &json!({"seq": f.frame.seq, "points": {
                    "D1": [-0.02, 0.0, 0.6], "D7": [0.02, 0.0, 0.6], "F2": [0.0, -0.1, 0.6], "D2": null}}),
            )
            .unwrap();
        while blocks * 20_000_000 <= log_time - first {
            let at = first + blocks * 20_000_000;
            writer.write_audio(at, format, &tone(blocks * 960)).unwrap();
            blocks += 1;
        }
    }
    // The rest of the last frame's time.
    writer.finish().unwrap();
}

/// A plain HTTP GET; the status code and body.
fn get(port: u16, target: &str) -> (u16, String) {
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    write!(
        s,
        "GET {target} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).unwrap();
    let text = String::from_utf8_lossy(&raw).into_owned();
    let code = text[9..12].parse().unwrap();
    let body = text
        .split_once("\r\n\r\n")
        .map(|(_, b)| b.to_owned())
        .unwrap_or_default();
    (code, body)
}

const PLAYER: &str = "const p = window.mouthpiece && window.mouthpiece.player; if (!p) return null; \
    const c = document.getElementById('player-canvas').getContext('2d'); \
    const px = (p.shownDots || []).map(d => { const [x, y] = p.toCanvas(d.x, d.y); \
      const v = c.getImageData(Math.round(x), Math.round(y), 1, 1).data; return {name: d.name, rgb: [v[0], v[1], v[2]]}; }); \
    return {playing: p.playing, ended: p.ended, failed: p.error, notes: p.notes, chunks: p.chunks, \
      shown: p.framesShown, last_t: p.lastT, dots: p.dotsDrawn, clock: p.clock, audio: p.audio, pixels: px, \
      connected: window.mouthpiece.connected};";

#[test]
fn a_take_plays_in_the_page_with_its_dots_and_its_sound() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("performer.mcap");
    let synth = crate::mouthpiece()
        .args(["synth", "--out"])
        .arg(&session)
        .args(["--seconds", "2", "--seed", "5", "--size", "320x240"])
        .output()
        .unwrap();
    assert!(synth.status.success(), "{synth:?}");
    std::fs::create_dir(dir.path().join("takes")).unwrap();
    write_take(&session, &dir.path().join("takes").join(TAKE));
    std::fs::write(dir.path().join("secret.mcap"), b"not for the page").unwrap();

    let port = free_port();
    std::fs::write(
        dir.path().join("mouthpiece.toml"),
        format!(
            "[source]\nspec = \"replay:{}?loop=1\"\n\
             [server]\nlisten = \"127.0.0.1:{port}\"\n\
             read_token = {{ env = \"MP_TEST_READ\" }}\ncontrol_token = {{ env = \"MP_TEST_CONTROL\" }}\n\
             [takes]\nfolder = \"takes\"\nmin_free_mb = 1\n",
            session.display()
        ),
    )
    .unwrap();
    let stderr = std::fs::File::create(dir.path().join("stderr.log")).unwrap();
    let _daemon = Daemon::listening(
        run_command(dir.path(), &dir.path().join("mouthpiece.toml"))
            .env("MP_TEST_CONTROL", CONTROL)
            .env("MP_TEST_READ", READ)
            .stderr(stderr),
        port,
    );

    // The door: a token, a take's name, nothing outside the folder.
    let ok = format!("/take?file={TAKE}&token={READ}&seconds=1");
    let (code, _) = get(port, &ok);
    assert_eq!(code, 200);
    for (target, want) in [
        (format!("/take?file={TAKE}"), 401),
        (
            format!("/take?file={TAKE}&token=wrong-token-0123456789"),
            401,
        ),
        (format!("/take?file=..%2Fsecret.mcap&token={READ}"), 400),
        (format!("/take?file=../mouthpiece.toml&token={READ}"), 400),
        (format!("/take?file=%2Fetc%2Fpasswd&token={READ}"), 400),
        (format!("/take?file=other_T009.mcap&token={READ}"), 404),
        (format!("/take?file={TAKE}&token={READ}&seconds=600"), 400),
        (format!("/take?file={TAKE}&token={READ}&from=nan"), 400),
    ] {
        let (code, body) = get(port, &target);
        assert_eq!(code, want, "{target}: {body}");
        assert!(!body.contains("not for the page"), "{target}: {body}");
    }

    let profile = tempfile::tempdir().unwrap();
    let driver = webdriver::open_page(
        &format!("http://127.0.0.1:{port}/?token={READ}"),
        profile.path(),
    );
    let deadline = Instant::now() + Duration::from_secs(30);
    while driver.script(PLAYER)["connected"] != true {
        assert!(Instant::now() < deadline, "the page did not connect");
        std::thread::sleep(Duration::from_millis(150));
    }
    driver.script(&format!(
        "window.mouthpiece.playTake('{TAKE}', 'play take 1'); return null;"
    ));
    let deadline = Instant::now() + Duration::from_secs(60);
    let done = loop {
        let v = driver.script(PLAYER);
        if v["ended"] == true || !v["failed"].is_null() {
            break v;
        }
        assert!(
            Instant::now() < deadline,
            "the take did not play to its end: {v}"
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    assert!(done["failed"].is_null(), "{done}");
    // Pictures with their dots, to the end of the take.
    assert!(done["shown"].as_u64().unwrap() >= 10, "{done}");
    assert!(done["last_t"].as_f64().unwrap() > 1.8, "{done}");
    assert_eq!(
        done["dots"].as_u64().unwrap(),
        3 * done["shown"].as_u64().unwrap(),
        "three seen dots per picture (the unseen one left out): {done}"
    );
    for p in done["pixels"].as_array().unwrap() {
        let rgb: Vec<i64> = p["rgb"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c.as_i64().unwrap())
            .collect();
        let off: i64 = rgb
            .iter()
            .zip([0x3d, 0xdc, 0x84])
            .map(|(a, b)| (a - b).abs())
            .sum();
        assert!(
            off <= 24,
            "dot {} not drawn where it was tracked: {rgb:?}; {done}",
            p["name"]
        );
    }
    // The sound: all of it, from the first picture on, as written.
    let audio = done["audio"].as_array().unwrap();
    assert!(!audio.is_empty(), "no sound: {done}");
    assert!(audio[0]["start_s"].as_f64().unwrap().abs() < 1e-6, "{done}");
    let samples: u64 = audio.iter().map(|a| a["samples"].as_u64().unwrap()).sum();
    assert!(
        samples >= u64::from(RATE) * 19 / 10,
        "{samples} samples: {done}"
    );
    for a in audio {
        assert_eq!(a["sample_rate"], RATE, "{a}");
        assert_eq!(a["channels"], 1, "{a}");
        assert_eq!(a["scheduled"], true, "{a}");
        // Mean |sample| of a sine of amplitude 8000: 8000 · 2/π ≈ 5093.
        let mean = a["sum"].as_f64().unwrap() / a["samples"].as_f64().unwrap();
        assert!(
            (mean - 5093.0).abs() < 150.0,
            "not the tone that was written: {mean}; {a}"
        );
    }
}
