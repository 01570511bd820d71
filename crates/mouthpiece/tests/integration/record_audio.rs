//! `mouthpiece record --audio`: the microphone beside the frames, through a real ALSA PCM
//! (tests/alsa: the `file` plugin streaming Festival's speech, paced by JACK's dummy driver),
//! the session read back by Foxglove's own MCAP reader.

use crate::helper_alsa_booth as booth;
use crate::helper_alsa_read_back as read_back;
use crate::repo;

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use read_back::python;

/// Waits until `what` holds (a generous limit: a loaded machine passes too).
fn wait_until(what: &str, mut check: impl FnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(120);
    while !check() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// A device string that would make alsa-lib run a command or write a file is refused before
/// alsa-lib sees it.
#[test]
fn a_device_string_with_a_pipe_or_the_file_plugin_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s.mcap");
    let ran = dir.path().join("ran");
    let written = dir.path().join("written.raw");
    let demo = repo().join("recordings/demo.mcap");
    for device in [
        format!("file:'|touch {}'", ran.display()),
        format!("file:FILE={},raw", written.display()),
    ] {
        let run = crate::mouthpiece()
            .args(["record", "--source"])
            .arg(format!("replay:{}", demo.display()))
            .arg("--out")
            .arg(&out)
            .args(["--audio", &device])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{stderr}");
        assert!(
            stderr.contains("--audio") && stderr.contains("refused"),
            "{stderr}"
        );
        assert!(
            !ran.exists() && !written.exists() && !out.exists(),
            "{stderr}"
        );
    }
}

#[test]
fn a_device_that_cannot_be_opened_is_named_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s.mcap");
    let demo = repo().join("recordings/demo.mcap");
    let run = crate::mouthpiece()
        .args(["record", "--source"])
        .arg(format!("replay:{}", demo.display()))
        .arg("--out")
        .arg(&out)
        .args(["--audio", "no_such_microphone"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("--audio no_such_microphone"), "{stderr}");
    assert!(!out.exists(), "no file when the device cannot be opened");
}

#[test]
fn a_recording_holds_the_booths_sound_bit_exact_and_where_it_stopped() {
    let dir = tempfile::tempdir().unwrap();
    let speech = booth::festival(
        "Hello from the booth. This is the voice of the performer, recorded with the face.",
        dir.path(),
    );
    let mut booth = booth::Booth::start(&speech);
    let out = dir.path().join("session.mcap");
    let demo = repo().join("recordings/demo.mcap");
    let log = dir.path().join("stderr.log");
    let mut command = crate::mouthpiece();
    command
        .args(["record", "--source"])
        .arg(format!("replay:{}?loop=1", demo.display()))
        .arg("--out")
        .arg(&out)
        .args(["--audio", "booth", "--audio-rate", "48000"])
        .env("RUST_LOG", "info")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap());
    for (k, v) in booth.env() {
        command.env(k, v);
    }
    let mut child = command.spawn().unwrap();
    let read_log = || std::fs::read_to_string(&log).unwrap_or_default();
    wait_until("the recording started", || {
        read_log().contains("recording MCAP session")
    });
    // Some sound and video, then the device's clock dies mid-recording.
    wait_until("a few megabytes of session", || {
        std::fs::metadata(&out).map_or(0, |m| m.len()) > 30_000_000
    });
    booth.pull_the_plug();
    wait_until("the sound reported lost", || {
        read_log().contains("sound lost")
    });
    // Video goes on after the loss.
    let size_at_loss = std::fs::metadata(&out).unwrap().len();
    wait_until("video after the loss", || {
        std::fs::metadata(&out).unwrap().len() > size_at_loss + 10_000_000
    });
    // SAFETY: kill(2) on our own child with SIGINT (its Ctrl-C handler closes the file).
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let status = child.wait().unwrap();
    assert!(status.success(), "{}", read_log());

    let found = read_back::check_take_audio(&out, &booth.s16, None);
    eprintln!("{found}");
    assert!(found["blocks"].as_u64().unwrap() >= 1, "{found}");
    assert_eq!(
        found["exact"], true,
        "the sound is the booth's, bit for bit: {found}"
    );
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
    assert!(
        found["first_audio"].as_u64().unwrap() < stopped_ns,
        "{found}"
    );
    assert_eq!(
        found["audio_meta"]["stopped_unix_us"],
        stopped["wall_us"].to_string(),
        "{found}"
    );
    // Frames and sound on one clock (the host's wall clock): both within the recording.
    assert!(
        found["first_frame"].as_u64().unwrap() > 1_600_000_000_000_000_000,
        "frames on the wall clock: {found}"
    );

    // Timestamps in file order: /audio and the frames each strictly increasing.
    let monotonic = Command::new(python())
        .arg("-c")
        .arg(
            "import sys\nfrom mcap.reader import make_reader\n\
             last = {}\n\
             with open(sys.argv[1], 'rb') as f:\n\
             \x20   for s, c, m in make_reader(f).iter_messages(topics=['/audio', '/camera/color'], log_time_order=False):\n\
             \x20       assert m.log_time > last.get(c.topic, -1), (c.topic, m.log_time, last)\n\
             \x20       last[c.topic] = m.log_time\n\
             print('ok')\n",
        )
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        monotonic.status.success(),
        "{}",
        String::from_utf8_lossy(&monotonic.stderr)
    );
}

/// ALSA's `null` device never blocks: it refills the sound queue as fast as the recording
/// empties it. `--seconds` still ends the recording, with a session holding frames and sound,
/// and the sound is given up (the video goes on) once it runs seconds ahead of the clock.
#[test]
fn seconds_end_the_recording_whatever_the_sound_device_does() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s.mcap");
    let demo = repo().join("recordings/demo.mcap");
    let log = dir.path().join("stderr.log");
    let mut child = crate::mouthpiece()
        .args(["record", "--source"])
        .arg(format!("replay:{}?loop=1", demo.display()))
        .arg("--out")
        .arg(&out)
        .args(["--audio", "null", "--seconds", "1"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .unwrap();
    // A watchdog for a hang, not a measurement.
    let mut ended = None;
    wait_until("the recording ended by itself", || {
        ended = child.try_wait().unwrap();
        ended.is_some()
    });
    let stderr = std::fs::read_to_string(&log).unwrap_or_default();
    assert!(ended.unwrap().success(), "{stderr}");
    // The device is given up once it runs seconds ahead of the clock: the session says so.
    assert!(stderr.contains("faster than real time"), "{stderr}");
    let summary = Command::new(python())
        .arg("-c")
        .arg(
            "import sys\nfrom mcap.reader import make_reader\n\
             n = {}\n\
             with open(sys.argv[1], 'rb') as f:\n\
             \x20   for s, c, m in make_reader(f).iter_messages(topics=['/audio', '/camera/color']):\n\
             \x20       n[c.topic] = n.get(c.topic, 0) + 1\n\
             print(n.get('/audio', 0), n.get('/camera/color', 0))\n",
        )
        .arg(&out)
        .output()
        .unwrap();
    let counts = String::from_utf8_lossy(&summary.stdout);
    let counts: Vec<u64> = counts
        .split_whitespace()
        .map(|n| n.parse().unwrap())
        .collect();
    assert!(
        counts.len() == 2 && counts.iter().all(|&n| n > 0),
        "/audio and /camera/color messages: {counts:?} {}",
        String::from_utf8_lossy(&summary.stderr)
    );
}
