//! The daemon's microphone end to end, through a real ALSA PCM (tests/alsa: the `file`
//! plugin streaming Festival's speech, paced by JACK's dummy driver), the real binary, a take
//! read back by Foxglove's own MCAP reader and its export checked with Python's `wave`.

use crate::helper_alsa_booth as booth;
use crate::helper_alsa_read_back as read_back;
use crate::helper_daemon_run as daemon;
use crate::repo;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use daemon::{free_port, run_command, Daemon};
use serde_json::Value;

use read_back::python;

/// `GET path` on the daemon's port: the body (empty when it cannot connect).
fn http_body(port: u16, path: &str) -> String {
    use std::io::{Read, Write};
    let Ok(mut s) = std::net::TcpStream::connect(("127.0.0.1", port)) else {
        return String::new();
    };
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let _ = write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n"
    );
    let mut text = String::new();
    let _ = s.read_to_string(&mut text);
    text.split_once("\r\n\r\n")
        .map(|(_, body)| body.to_owned())
        .unwrap_or_default()
}

fn metric(port: u16, name: &str) -> u64 {
    http_body(port, "/metrics")
        .lines()
        .find_map(|l| l.strip_prefix(&format!("{name} ")))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or(0)
}

/// Waits until `what` holds (a generous limit: a loaded machine passes too).
fn wait_until(what: &str, mut check: impl FnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(60);
    while !check() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn mouthpiece(dir: &Path, args: &[&str]) -> std::process::Output {
    crate::mouthpiece()
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

#[test]
fn a_take_from_the_booth_holds_its_sound_and_where_it_stopped_and_exports_a_broadcast_wav() {
    let dir = tempfile::tempdir().unwrap();
    let speech = booth::festival(
        "Hello from the booth. This is the voice of the performer, recorded with the face.",
        dir.path(),
    );
    let mut booth = booth::Booth::start(&speech);
    let port = free_port();
    let demo = repo().join("recordings/demo.mcap");
    let config = format!(
        "[source]\nspec = \"replay:{}?loop=1\"\nretry_initial_s = 0.2\nretry_max_s = 0.4\nstall_timeout_s = 1.0\n\
         [server]\nlisten = \"127.0.0.1:{port}\"\n[takes]\nfolder = \"takes\"\nflush_s = 0.5\nmin_free_mb = 1\n\
         [audio]\ndevice = \"booth\"\n",
        demo.display()
    );
    std::fs::write(dir.path().join("mouthpiece.toml"), config).unwrap();
    let mut command = run_command(dir.path(), Path::new("mouthpiece.toml"));
    command
        .args(["--record", "booth"])
        .env("RUST_LOG", "info")
        .stderr(std::fs::File::create(dir.path().join("stderr.log")).unwrap());
    for (k, v) in booth.env() {
        command.env(k, v);
    }
    let mut daemon = Daemon::spawn(&mut command);
    let log = || std::fs::read_to_string(dir.path().join("stderr.log")).unwrap_or_default();

    wait_until("the microphone live in /healthz", || {
        http_body(port, "/healthz").contains("\"state\":\"live\"")
    });
    // A second of sound (100 blocks of 10 ms), then the device's clock dies mid-take.
    wait_until("sound", || {
        metric(port, "mouthpiece_audio_blocks_total") >= 100
    });
    booth.pull_the_plug();
    wait_until("the microphone reported gone", || {
        let health: Value = serde_json::from_str(&http_body(port, "/healthz")).unwrap_or_default();
        health["audio"]["state"] == "no_device" && health["audio"]["message"].is_string()
    });
    // Video goes on without the sound: more frames are published after the loss.
    let frames_at_loss: u64 = serde_json::from_str::<Value>(&http_body(port, "/healthz")).unwrap()
        ["frames"]
        .as_u64()
        .unwrap();
    wait_until("video after the loss", || {
        serde_json::from_str::<Value>(&http_body(port, "/healthz")).unwrap()["frames"]
            .as_u64()
            .unwrap()
            >= frames_at_loss + 30
    });
    assert!(
        metric(port, "mouthpiece_audio_open_attempts_total") >= 2,
        "retried"
    );
    let status = daemon.terminate();
    assert!(status.success(), "{}", log());

    let takes: Vec<PathBuf> = std::fs::read_dir(dir.path().join("takes"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(takes.len(), 1, "{takes:?}");
    let take = &takes[0];
    let out = dir.path().join("booth.csv");
    let exported = mouthpiece(
        dir.path(),
        &[
            "export",
            take.to_str().unwrap(),
            "--character",
            repo()
                .join("config/characters/human.toml")
                .to_str()
                .unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
    );
    assert!(
        exported.status.success(),
        "{}",
        String::from_utf8_lossy(&exported.stderr)
    );
    let wav = dir.path().join("booth.wav");
    assert!(wav.exists(), "the WAV beside the CSV");

    let found = read_back::check_take_audio(take, &booth.s16, Some(&wav));
    eprintln!("{found}");
    assert!(found["blocks"].as_u64().unwrap() >= 50, "{found}");
    assert_eq!(
        found["exact"], true,
        "the take's sound is the booth's, bit for bit: {found}"
    );
    // The take's video runs on after the sound stopped, and the take says where it stopped.
    let stopped = found["events"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["event"] == "stopped")
        .unwrap_or_else(|| panic!("no stop event: {found}"));
    let stopped_ns = stopped["wall_us"].as_u64().unwrap() * 1000;
    assert!(
        found["last_frame"].as_u64().unwrap() > stopped_ns,
        "{found}"
    );
    assert_eq!(
        found["audio_meta"]["stopped_unix_us"],
        stopped["wall_us"].to_string(),
        "{found}"
    );
    // The WAV: 48 kHz mono 16-bit, as long as the exported frames, sample 0 at the first
    // frame, every sample where the documented layout puts it (laid out again in Python: each
    // block where its time says, or continuing the one before when within 40 ms of its end),
    // the bext time reference that instant as samples since midnight.
    let w = &found["wav"];
    assert_eq!(
        (
            w["rate"].as_u64(),
            w["channels"].as_u64(),
            w["width"].as_u64()
        ),
        (Some(48_000), Some(1), Some(2)),
        "{w}"
    );
    assert_eq!(w["length"], w["expected_length"], "{w}");
    assert_eq!(w["time_reference"], w["expected_time_reference"], "{w}");
    assert_eq!(w["laid_out_as_documented"], true, "{w}");

    // The take replayed: its sound takes the microphone's path (state `replay`) and a take of
    // the replay holds it again, bit for bit.
    let port = free_port();
    let config = format!(
        "[source]\nspec = \"replay:{}\"\n[server]\nlisten = \"127.0.0.1:{port}\"\n[takes]\nfolder = \"again\"\nflush_s = 0.5\nmin_free_mb = 1\n",
        take.display()
    );
    std::fs::write(dir.path().join("again.toml"), config).unwrap();
    let mut daemon =
        Daemon::spawn(run_command(dir.path(), Path::new("again.toml")).args(["--record", "again"]));
    wait_until("the recording's sound as the microphone", || {
        http_body(port, "/healthz").contains("\"state\":\"replay\"")
    });
    wait_until("replayed sound", || {
        metric(port, "mouthpiece_audio_blocks_total") >= 50
    });
    assert!(daemon.terminate().success());
    let again: Vec<PathBuf> = std::fs::read_dir(dir.path().join("again"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    let found = read_back::check_take_audio(&again[0], &booth.s16, None);
    assert!(found["blocks"].as_u64().unwrap() >= 20, "{found}");
    assert_eq!(
        found["exact"], true,
        "the replayed take's sound is the booth's: {found}"
    );
}

/// `synth --speech --speech-audio`: Festival's line and the mouth lip-synced from it in one
/// session; replayed by the daemon, a take keeps sound and picture together: the offset
/// between them (take vs session, frames matched by device time, sound by content) is
/// within one frame (33 ms).
#[test]
fn a_synthetic_speech_session_keeps_sound_and_picture_within_a_frame_through_the_daemon() {
    let dir = tempfile::tempdir().unwrap();
    booth::festival("The quick brown fox jumps over the lazy dog.", dir.path());
    let wav = dir.path().join("line.wav");
    let run = |args: &[&str]| {
        let out = mouthpiece(dir.path(), args);
        assert!(
            out.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    };
    let human = repo().join("config/characters/human.toml");
    run(&[
        "lipsync",
        "--character",
        human.to_str().unwrap(),
        "--audio",
        "line.wav",
        "--out",
        "line.jsonl",
        "--weights",
        "line.csv",
    ]);
    run(&[
        "synth",
        "--speech",
        "line.csv",
        "--speech-audio",
        wav.to_str().unwrap(),
        "--seconds",
        "5",
        "--seed",
        "7",
        "--size",
        "320x240",
        "--out",
        "speech.mcap",
    ]);
    let session = dir.path().join("speech.mcap");
    let port = free_port();
    std::fs::write(
        dir.path().join("replay.toml"),
        format!(
            "[source]\nspec = \"replay:{}\"\n[server]\nlisten = \"127.0.0.1:{port}\"\n[takes]\nfolder = \"takes\"\nflush_s = 0.5\nmin_free_mb = 1\n",
            session.display()
        ),
    )
    .unwrap();
    let mut daemon = Daemon::spawn(
        run_command(dir.path(), Path::new("replay.toml")).args(["--record", "speech"]),
    );
    wait_until("the session's sound", || {
        metric(port, "mouthpiece_audio_blocks_total") >= 150
    });
    assert!(daemon.terminate().success());
    let take = std::fs::read_dir(dir.path().join("takes"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let measured = Command::new(python())
        .arg(repo().join("tests/python/sound_picture_offset.py"))
        .arg(&session)
        .arg(&take)
        .output()
        .unwrap();
    assert!(
        measured.status.success(),
        "{}",
        String::from_utf8_lossy(&measured.stderr)
    );
    let found: Value = serde_json::from_slice(&measured.stdout).unwrap();
    eprintln!("sound-picture offset: {found}");
    let offset = found["offset_ms"].as_f64().unwrap();
    assert!(offset.abs() <= 33.0, "{found}");
}
