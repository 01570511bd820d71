//! `mouthpiece lipsync` end to end: phone files → takes for the human and the wolf that
//! `export` turns into glTF; bad input (exit 2, file and line named, nothing written); and
//! real speech: Festival (Debian `festival`, `festvox-kallpc16k`) speaks two sentences, and
//! PocketSphinx (Debian `libpocketsphinx-dev`, `pocketsphinx-en-us`) aligns and recognises
//! them, measured by `bench/lipsync_accuracy.py`. Fails when Festival or the model is missing
//! (scripts/test installs them).

use crate::repo;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

fn mouthpiece() -> Command {
    let mut c = crate::mouthpiece();
    c.env("RUST_LOG", "warn");
    c
}

fn run_ok(cmd: &mut Command) -> Output {
    let out = cmd.output().expect("spawn");
    assert!(
        out.status.success(),
        "{cmd:?} failed: {}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

const SA1_PHN: &str = "0 3050 h#\n3050 4559 sh\n4559 5723 ix\n5723 6642 hv\n6642 8772 eh\n\
8772 9190 dcl\n9190 10337 jh\n10337 11517 ih\n11517 12500 dcl\n12500 12640 d\n\
12640 14714 ah\n14714 15870 kcl\n15870 16334 k\n16334 18088 s\n18088 20417 ux\n\
20417 21199 q\n21199 22560 en\n22560 22920 gcl\n22920 23373 g\n23373 24194 r\n\
24194 25817 iy\n25817 27477 z\n27477 28582 iy\n28582 29280 w\n29280 30612 ao\n\
30612 31876 sh\n31876 32670 epi\n32670 33192 w\n33192 34160 ao\n34160 35257 dx\n\
35257 36160 axr\n36160 37720 q\n37720 39154 ao\n39154 40131 l\n40131 40600 y\n\
40600 42199 ih\n42199 43800 axr\n43800 46720 h#\n";

fn character(name: &str) -> PathBuf {
    repo().join(format!("config/characters/{name}.toml"))
}

fn read_take(path: &Path) -> Vec<Value> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

fn points(v: &Value) -> Vec<[f64; 3]> {
    v["points"]
        .as_object()
        .unwrap()
        .values()
        .map(|p| {
            let a = p.as_array().unwrap();
            [
                a[0].as_f64().unwrap(),
                a[1].as_f64().unwrap(),
                a[2].as_f64().unwrap(),
            ]
        })
        .collect()
}

#[test]
fn phone_file_to_takes_for_human_and_wolf_that_export_to_gltf() {
    let dir = tempfile::tempdir().unwrap();
    let phn = dir.path().join("sa1.phn");
    std::fs::write(&phn, SA1_PHN).unwrap();
    for name in ["human", "wolf"] {
        let take = dir.path().join(format!("{name}.jsonl"));
        let csv = dir.path().join(format!("{name}.csv"));
        run_ok(
            mouthpiece()
                .args(["lipsync", "--character"])
                .arg(character(name))
                .arg("--phonemes")
                .arg(&phn)
                .arg("--out")
                .arg(&take)
                .arg("--weights")
                .arg(&csv),
        );
        let lines = read_take(&take);
        // 46720 samples at 16 kHz = 2.92 s at 60 fps: samples 0..=175.
        assert_eq!(lines.len(), 176);
        assert_eq!(lines[0]["character"], name);
        for (k, l) in lines.iter().enumerate() {
            assert_eq!(l["seq"], k as u64);
            assert!((l["t"].as_f64().unwrap() - k as f64 / 60.0).abs() < 1e-12);
            assert_eq!(points(l).len(), 12);
        }
        // Silence at both ends: the character's neutral mouth exactly; speech moves it.
        let neutral = points(&lines[0]);
        assert_eq!(points(&lines[175]), neutral);
        let moved = lines
            .iter()
            .map(|l| {
                points(l)
                    .iter()
                    .zip(&neutral)
                    .map(|(a, b)| (0..3).map(|k| (a[k] - b[k]).abs()).fold(0.0, f64::max))
                    .fold(0.0, f64::max)
            })
            .fold(0.0, f64::max);
        let scale = if name == "wolf" { 0.01 } else { 0.003 };
        assert!(moved > scale, "{name}: the mouth moves ({moved})");
        let csv_text = std::fs::read_to_string(&csv).unwrap();
        assert!(csv_text.starts_with("t,phone,class,closed,open,spread,round,bite\n"));
        assert_eq!(csv_text.lines().count(), 177);
        // The take exports.
        let gltf = dir.path().join(format!("{name}.glb"));
        run_ok(
            mouthpiece()
                .arg("export")
                .arg(&take)
                .arg("--character")
                .arg(character(name))
                .arg("--out")
                .arg(&gltf),
        );
        assert!(std::fs::metadata(&gltf).unwrap().len() > 1000);
    }
    // Identical phone files give identical takes.
    let again = dir.path().join("again.jsonl");
    run_ok(
        mouthpiece()
            .args(["lipsync", "--character"])
            .arg(character("human"))
            .arg("--phonemes")
            .arg(&phn)
            .arg("--out")
            .arg(&again),
    );
    assert_eq!(
        std::fs::read(&again).unwrap(),
        std::fs::read(dir.path().join("human.jsonl")).unwrap()
    );
}

fn expect_bad_input(args: &[&str], file: &Path, expect: &str, out: &Path) {
    let o = mouthpiece()
        .args(["lipsync", "--character"])
        .arg(character("human"))
        .args(args)
        .arg(file)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
    assert!(
        err.contains(expect),
        "{args:?}: expected {expect:?} in {err}"
    );
    assert!(!out.exists(), "nothing written");
}

#[test]
fn bad_input_exits_2_naming_file_and_line_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("take.jsonl");
    let f = |name: &str, text: &[u8]| {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p
    };
    let unknown = f("u.phn", b"0 1600 h#\n1600 3200 zz\n");
    expect_bad_input(
        &["--phonemes"],
        &unknown,
        &format!("{}:2: unknown phone \"zz\"", unknown.display()),
        &out,
    );
    let overlap = f("o.lab", b"0 2000000 sil\n1000000 3000000 aa\n");
    expect_bad_input(
        &["--phonemes"],
        &overlap,
        &format!("{}:2:", overlap.display()),
        &out,
    );
    let backwards = f(
        "b.jsonl",
        b"{\"start\": 0.5, \"end\": 0.2, \"phone\": \"aa\"}\n",
    );
    expect_bad_input(
        &["--phonemes"],
        &backwards,
        "ends (0.2 s) before it starts",
        &out,
    );
    let wav = f("x.wav", b"RIFF\x10\x00\x00\x00WAVEjunk");
    expect_bad_input(
        &["--audio"],
        &wav,
        &format!("{}: cannot read WAV audio", wav.display()),
        &out,
    );
    // An empty transcript (the audio is fine: Festival is not needed for this).
    let mut good = std::io::Cursor::new(Vec::new());
    {
        let mut w = WavWriter::new(&mut good, 16_000);
        w.silence(8000);
    }
    let good = f("s.wav", &good.into_inner());
    let o = mouthpiece()
        .args(["lipsync", "--character"])
        .arg(character("human"))
        .arg("--audio")
        .arg(&good)
        .args(["--transcript", " ... "])
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--transcript: the transcript is empty"),
        "{err}"
    );
    assert!(!out.exists());
}

#[test]
fn a_long_take_is_streamed_to_its_file_not_held_in_memory() {
    // Ten minutes of phones (just under the phone files' 600 s limit) at 60 fps: a 270 MB
    // take. Held in memory (as it once was) it cannot be made under a 256 MB address-space
    // limit; streamed it needs about 20 MB.
    let dir = tempfile::tempdir().unwrap();
    let phn = dir.path().join("long.phn");
    let names = ["sh", "iy", "aa", "m", "p", "s", "ow", "l"];
    let mut text = String::new();
    let (mut t, mut k) = (0u64, 0usize);
    // The longest phone is 3199 samples: the last one ends before 600 s.
    while t + 3200 <= 16_000 * 600 {
        let d = 800 + (k as u64 * 977) % 2400;
        text.push_str(&format!("{t} {} {}\n", t + d, names[k % names.len()]));
        t += d;
        k += 1;
    }
    std::fs::write(&phn, text).unwrap();
    let out = dir.path().join("take.jsonl");
    let o = Command::new("sh")
        .arg("-c")
        .arg("ulimit -v 262144 && exec \"$@\"")
        .arg("sh")
        .arg(env!("CARGO_BIN_EXE_mouthpiece"))
        .args(["lipsync", "--character"])
        .arg(character("human"))
        .arg("--phonemes")
        .arg(&phn)
        .arg("--out")
        .arg(&out)
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{:?}: {err}", o.status);
    let size = std::fs::metadata(&out).unwrap().len();
    assert!(
        size > 256 << 20,
        "the take is larger than the limit: {size} bytes"
    );
    let lines = std::fs::read(&out)
        .unwrap()
        .iter()
        .filter(|&&b| b == b'\n')
        .count();
    // One line per 60 fps frame from 0 to the last phone's end (`t` samples at 16 kHz).
    assert_eq!(lines as u64, t * 60 / 16_000 + 1);
}

#[test]
fn hostile_flags_and_files_exit_2_naming_them() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("take.jsonl");
    let phn = dir.path().join("p.phn");
    std::fs::write(&phn, "0 1600 sh\n1600 4800 iy\n").unwrap();
    // --fps 1e-300 gave a take of one sample; NaN --t-change.
    for (flag, value, expect) in [
        (
            "--fps",
            "1e-300",
            "--fps must be within 1 to 10000 samples per second, got 1e-300",
        ),
        ("--fps", "NaN", "--fps must be within"),
        (
            "--t-change",
            "NaN",
            "--t-change: the change-stage length T must be within",
        ),
    ] {
        expect_bad_input(&[flag, value, "--phonemes"], &phn, expect, &out);
    }
    // A file that never ends is refused at its size limit, naming it.
    let zero = dir.path().join("zero.phn");
    std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
    expect_bad_input(
        &["--phonemes"],
        &zero,
        &format!("{}: phone file longer than 67108864 bytes", zero.display()),
        &out,
    );
    expect_bad_input(
        &["--phonemes", &phn.display().to_string(), "--classes"],
        &zero,
        &format!("{}: class table longer than 4194304 bytes", zero.display()),
        &out,
    );
    // A class table listing a phone twice in one class: a panic, once.
    let classes = dir.path().join("c.toml");
    std::fs::write(
        &classes,
        std::fs::read_to_string(repo().join("config/lipsync/classes.toml"))
            .unwrap()
            .replace("phones = [\"f\", \"v\"", "phones = [\"f\", \"v\", \"F1\""),
    )
    .unwrap();
    expect_bad_input(
        &["--phonemes", &phn.display().to_string(), "--classes"],
        &classes,
        "phone \"F1\" (read as \"f\") is already in this class",
        &out,
    );
    // A TextGrid with NaN times: exit 0 and a take of null points, once.
    let grid = dir.path().join("n.TextGrid");
    std::fs::write(
        &grid,
        "\"ooTextFile\"\n\"TextGrid\"\n0\n0.5\n<exists>\n1\n\"IntervalTier\"\n\"phones\"\n0\n0.5\n2\n0\nNaN\n\"sh\"\n0.2\n0.5\n\"iy\"\n",
    )
    .unwrap();
    expect_bad_input(
        &["--phonemes"],
        &grid,
        &format!("{}:13:1: \"NaN\" is not a finite number", grid.display()),
        &out,
    );
    // A character that does not fit the poses: both files named (once: "character and
    // basic poses").
    let poses = dir.path().join("poses4.toml");
    let mut text = String::from(
        "[neutral]\nlip = [[0.02, 0.0, 0.0], [0.0, 0.005, 0.0], [-0.02, 0.0, 0.0], [0.0, -0.006, 0.0]]\nforehead = [[0.03, 0.1, 0.0], [-0.03, 0.1, 0.0], [0.0, 0.12, 0.0]]\n",
    );
    for name in ["closed", "open", "spread", "round", "bite"] {
        text.push_str(&format!("[[pose]]\nname = \"{name}\"\ndisplacement = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]\n"));
    }
    std::fs::write(&poses, text).unwrap();
    expect_bad_input(
        &["--phonemes", &phn.display().to_string(), "--poses"],
        &poses,
        &format!(
            "character {} does not fit the basic poses of {}",
            character("human").display(),
            poses.display()
        ),
        &out,
    );
}

#[test]
fn praat_utf16_textgrids_are_read() {
    let dir = tempfile::tempdir().unwrap();
    let text = "\"ooTextFile\"\n\"TextGrid\"\n0\n0.5\n<exists>\n1\n\"IntervalTier\"\n\"phones\"\n0\n0.5\n3\n0\n0.2\n\"spn\"\n0.2\n0.4\n\"ʃ\"\n0.4\n0.5\n\"IY1\"\n";
    let grid = dir.path().join("u.TextGrid");
    let mut bytes = vec![0xFE, 0xFF];
    for u in text.replace('ʃ', "SH").encode_utf16() {
        bytes.extend(u.to_be_bytes());
    }
    std::fs::write(&grid, bytes).unwrap();
    let out = dir.path().join("take.jsonl");
    let phones = dir.path().join("phones.jsonl");
    run_ok(
        mouthpiece()
            .args(["lipsync", "--character"])
            .arg(character("human"))
            .arg("--phonemes")
            .arg(&grid)
            .arg("--phones-out")
            .arg(&phones)
            .arg("--out")
            .arg(&out),
    );
    let read = std::fs::read_to_string(&phones).unwrap();
    assert!(
        read.contains("\"spn\"") && read.contains("\"sh\""),
        "{read}"
    );
}

/// A minimal 16-bit mono WAV writer (the test does not depend on a WAV crate).
struct WavWriter<'a> {
    out: &'a mut std::io::Cursor<Vec<u8>>,
    rate: u32,
}

impl<'a> WavWriter<'a> {
    fn new(out: &'a mut std::io::Cursor<Vec<u8>>, rate: u32) -> Self {
        Self { out, rate }
    }

    fn silence(&mut self, samples: u32) {
        use std::io::Write;
        let data = samples * 2;
        let mut h = Vec::new();
        h.extend_from_slice(b"RIFF");
        h.extend_from_slice(&(36 + data).to_le_bytes());
        h.extend_from_slice(b"WAVEfmt ");
        h.extend_from_slice(&16u32.to_le_bytes());
        h.extend_from_slice(&1u16.to_le_bytes());
        h.extend_from_slice(&1u16.to_le_bytes());
        h.extend_from_slice(&self.rate.to_le_bytes());
        h.extend_from_slice(&(self.rate * 2).to_le_bytes());
        h.extend_from_slice(&2u16.to_le_bytes());
        h.extend_from_slice(&16u16.to_le_bytes());
        h.extend_from_slice(b"data");
        h.extend_from_slice(&data.to_le_bytes());
        h.resize(h.len() + data as usize, 0);
        self.out.write_all(&h).unwrap();
    }
}

/// Real speech through Festival and PocketSphinx: two sentences, both modes. The bounds are
/// the lip sync's targets for alignment (median ≤ 20 ms, p90 ≤ 50 ms, ≥ 85 % of frames in the
/// right class) and loose sanity bounds for recognition (docs/lipsync.md has the full table).
#[test]
fn festival_speech_through_pocketsphinx_meets_the_targets() {
    let out = Command::new("python3")
        .arg(repo().join("bench/lipsync_accuracy.py"))
        .arg("--bin")
        .arg(env!("CARGO_BIN_EXE_mouthpiece"))
        .args(["--sentences", "sa1,sa2", "--json"])
        .output()
        .expect("python3 is required");
    assert!(
        out.status.success(),
        "bench/lipsync_accuracy.py failed (Festival, festvox-kallpc16k and pocketsphinx-en-us \
         are required): {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let results: Vec<Value> = serde_json::from_slice(&out.stdout).unwrap();
    let get = |r: &Value, k: &str| r[k].as_f64().unwrap();
    let aligned = &results[0];
    assert_eq!(aligned["mode"], "transcript");
    eprintln!("{results:?}");
    assert!(get(aligned, "boundary_median_ms") <= 20.0, "{aligned}");
    assert!(get(aligned, "boundary_p90_ms") <= 50.0, "{aligned}");
    assert!(get(aligned, "dominant_class_share") >= 0.85, "{aligned}");
    let recognised = &results[1];
    assert_eq!(recognised["mode"], "recognition");
    assert!(get(recognised, "phones_matched") >= 0.4, "{recognised}");
    assert!(
        get(recognised, "dominant_class_share") >= 0.4,
        "{recognised}"
    );
}

/// The loop through the camera: a weights CSV holding each shipped pose drives the synthetic
/// performer (`synth --speech`, mild head motion); `lipsync poses` captures the poses back
/// from the rendered session through detection, tracking and head-motion removal; they match
/// the shipped poses within tracking error.
#[test]
fn synth_driven_by_weights_and_poses_captured_back_match_the_shipped_poses() {
    use std::fmt::Write as _;
    let dir = tempfile::tempdir().unwrap();
    let names = ["closed", "open", "spread", "round", "bite"];
    let mut csv = String::from("t,closed,open,spread,round,bite\n");
    let mut marks = String::new();
    for k in 0..=104 {
        let t = k as f64 * 0.05;
        let (i, local) = ((t / 1.0).floor() as usize, t % 1.0);
        let w = (local / 0.2)
            .min(1.0)
            .min((1.0 - local) / 0.2)
            .clamp(0.0, 1.0);
        let row: Vec<String> = (0..5)
            .map(|p| if p == i { format!("{w}") } else { "0".into() })
            .collect();
        writeln!(csv, "{t},{}", row.join(",")).unwrap();
    }
    // The poses that roll the lower lip in (closed, bite) hide its dots from the camera: they
    // are held in the session but not captured.
    for (i, name) in names
        .iter()
        .enumerate()
        .filter(|(i, _)| (1..=3).contains(i))
    {
        // The synthetic session starts with 1.5 s of neutral before the weights.
        let start = 1.5 + i as f64 + 0.3;
        writeln!(marks, "{name} = [{start}, {}]", start + 0.4).unwrap();
    }
    let csv_path = dir.path().join("w.csv");
    std::fs::write(&csv_path, csv).unwrap();
    let marks_path = dir.path().join("marks.toml");
    std::fs::write(&marks_path, marks).unwrap();
    let session = dir.path().join("s.mcap");
    run_ok(
        mouthpiece()
            .args(["synth", "--out"])
            .arg(&session)
            .args(["--seconds", "6.7", "--seed", "3"])
            .arg("--speech")
            .arg(&csv_path),
    );
    let out = dir.path().join("captured.toml");
    run_ok(
        mouthpiece()
            .args(["lipsync", "poses"])
            .arg(&session)
            .arg("--marks")
            .arg(&marks_path)
            .arg("--out")
            .arg(&out),
    );
    let captured: toml::Value = toml::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let shipped: toml::Value =
        toml::from_str(&std::fs::read_to_string(repo().join("config/lipsync/poses.toml")).unwrap())
            .unwrap();
    let disp = |v: &toml::Value, name: &str| -> Vec<[f64; 3]> {
        let pose = v["pose"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["name"].as_str() == Some(name))
            .unwrap();
        pose["displacement"]
            .as_array()
            .unwrap()
            .iter()
            .map(|d| {
                let a = d.as_array().unwrap();
                [0, 1, 2].map(|k| a[k].as_float().unwrap())
            })
            .collect()
    };
    for name in &names[1..=3] {
        let (c, s) = (disp(&captured, name), disp(&shipped, name));
        let err = c
            .iter()
            .zip(&s)
            .map(|(a, b)| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt())
            .fold(0.0, f64::max);
        let size = s
            .iter()
            .map(|b| b.iter().map(|x| x * x).sum::<f64>().sqrt())
            .fold(0.0, f64::max);
        eprintln!(
            "{name}: largest dot error {:.2} mm of a {:.1} mm pose",
            err * 1e3,
            size * 1e3
        );
        // Measured: open 1.0 mm, spread 1.1 mm, round 1.7 mm (Kinect-style depth noise, mild
        // head motion).
        assert!(
            err < 2.5e-3 && err < 0.3 * size,
            "{name}: {err} m (pose {size} m)"
        );
    }
}

/// Sends `take` with `mouthpiece play` to the python-osc VMC receiver
/// (`tests/python/vmc_receiver.py`, independent of the Rust encoder), which checks every frame
/// against the take's own lines: the rig's curves and visemes (float32 exact) and the head and
/// eye bones after the documented axis conversion. Returns the receiver's summary.
fn play_to_a_vmc_receiver(take: &Path, character_name: &str, work: &Path) -> Value {
    // What the receiver compares with: each line's time, rig and character head.
    let stream: Vec<Value> = read_take(take)
        .iter()
        .map(|l| serde_json::json!({"t": l["t"], "rig": l["rig"], "head": l["character_head"]}))
        .collect();
    play_against_stream(take, &character(character_name), &stream, work)
}

/// Sends `take` with `mouthpiece play` to the python-osc VMC receiver, which checks every
/// frame it receives against `stream` (one `{"t", "rig", "head"}` per frame, the rig and head
/// as WebSocket frames carry them). Returns the receiver's summary.
pub(crate) fn play_against_stream(
    take: &Path,
    character_file: &Path,
    stream: &[Value],
    work: &Path,
) -> Value {
    use std::process::Stdio;
    use std::time::{Duration, Instant};
    let python = std::env::var("MOUTHPIECE_PYTHON").unwrap_or_else(|_| "python3".into());
    let (port_file, stop_file, stream_file) = (
        work.join("port"),
        work.join("stop"),
        work.join("stream.jsonl"),
    );
    let _ = std::fs::remove_file(&port_file);
    let _ = std::fs::remove_file(&stop_file);
    let text: Vec<String> = stream.iter().map(Value::to_string).collect();
    std::fs::write(&stream_file, text.join("\n") + "\n").unwrap();
    let parsed = mouthpiece_retarget::Character::from_toml_str(
        &std::fs::read_to_string(character_file).unwrap(),
    )
    .unwrap();
    let axes: Vec<Vec<f64>> = (0..3)
        .map(|r| (0..3).map(|c| parsed.frame.axes[(r, c)]).collect())
        .collect();
    // At 1× the take, a kernel socket buffer of datagrams is plenty even for a slow receiver;
    // half the frames must match (all that arrive must be exact).
    let min_matched = stream.len() / 2;
    let mut receiver = Command::new(python)
        .arg(repo().join("tests/python/vmc_receiver.py"))
        .arg("--port-file")
        .arg(&port_file)
        .arg("--stop-file")
        .arg(&stop_file)
        .arg("--stream")
        .arg(&stream_file)
        .args(["--axes", &serde_json::json!(axes).to_string(), "--eyes"])
        .args(["--names", "arkit-pascal", "--visemes", "vrm1"])
        .args(["--min-matched", &min_matched.to_string()])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("running Python (set MOUTHPIECE_PYTHON)");
    let deadline = Instant::now() + Duration::from_secs(60);
    let port: u16 = loop {
        if let Ok(text) = std::fs::read_to_string(&port_file) {
            break text.trim().parse().unwrap();
        }
        if receiver.try_wait().unwrap().is_some() || Instant::now() > deadline {
            let _ = receiver.kill();
            let out = receiver.wait_with_output().unwrap();
            panic!(
                "the python-osc receiver did not start: {}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let played = mouthpiece()
        .arg("play")
        .arg(take)
        .arg("--character")
        .arg(character_file)
        .args(["--osc", &format!("127.0.0.1:{port}")])
        .args(["--names", "arkit-pascal", "--visemes", "vrm1"])
        .output()
        .unwrap();
    std::fs::write(&stop_file, b"").unwrap();
    let out = receiver.wait_with_output().unwrap();
    assert!(
        played.status.success(),
        "play: {}",
        String::from_utf8_lossy(&played.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "the receiver's checks failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_str(stdout.lines().next().unwrap_or("")).unwrap()
}

/// A speech-driven take and a camera take drive a VRM avatar over the VMC protocol alike:
/// `mouthpiece play` sends each take's rig curves, VRM 1.0 visemes, head and eyes, and the
/// mouth opens in both.
#[test]
fn a_speech_take_and_a_camera_take_both_play_over_vmc() {
    let dir = tempfile::tempdir().unwrap();
    let phn = dir.path().join("sa1.phn");
    std::fs::write(&phn, SA1_PHN).unwrap();
    let speech = dir.path().join("speech.jsonl");
    run_ok(
        mouthpiece()
            .args(["lipsync", "--character"])
            .arg(character("wolf"))
            .arg("--phonemes")
            .arg(&phn)
            .arg("--out")
            .arg(&speech),
    );
    let camera = dir.path().join("camera.jsonl");
    run_ok(
        mouthpiece()
            .arg("process")
            .arg(repo().join("recordings/demo.mcap"))
            .arg("--character")
            .arg(character("wolf"))
            .arg("--out")
            .arg(&camera),
    );
    for take in [&speech, &camera] {
        let summary = play_to_a_vmc_receiver(take, "wolf", dir.path());
        assert!(summary["matched_with_rig"].as_u64() > Some(0), "{summary}");
        assert!(
            summary["max_jaw_open"].as_f64() > Some(0.2),
            "{}: {summary}",
            take.display()
        );
    }
    // Bad flags are bad input, named.
    for (flag, value) in [
        ("--speed", "0"),
        ("--speed", "1e-300"),
        ("--osc", "nowhere"),
        ("--names", "JawOpen"),
    ] {
        let mut cmd = mouthpiece();
        cmd.arg("play")
            .arg(&speech)
            .arg("--character")
            .arg(character("wolf"));
        if flag != "--osc" {
            cmd.args(["--osc", "127.0.0.1:9"]);
        }
        let out = cmd.args([flag, value]).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{flag} {value}: {stderr}");
        assert!(stderr.contains(flag), "{flag} {value}: {stderr}");
    }
}

/// A take `play` cannot pace is refused at its line, exit 2, before anything waits or fills
/// memory: a gap of 1e20 s between two lines, an endless line (`/dev/zero`).
#[test]
fn play_refuses_an_endless_line_and_an_endless_gap_naming_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let phn = dir.path().join("sa1.phn");
    std::fs::write(&phn, SA1_PHN).unwrap();
    let speech = dir.path().join("speech.jsonl");
    run_ok(
        mouthpiece()
            .args(["lipsync", "--character"])
            .arg(character("wolf"))
            .arg("--phonemes")
            .arg(&phn)
            .arg("--out")
            .arg(&speech),
    );
    let text = std::fs::read_to_string(&speech).unwrap();
    let mut lines: Vec<serde_json::Value> = text
        .lines()
        .take(3)
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    lines[2]["t"] = serde_json::json!(1e20);
    let gap = dir.path().join("gap.jsonl");
    let gap_text: String = lines.iter().map(|l| format!("{l}\n")).collect();
    std::fs::write(&gap, gap_text).unwrap();
    for (take, expected) in [
        (gap.as_path(), "line 3"),
        (Path::new("/dev/zero"), "line 1"),
    ] {
        let out = mouthpiece()
            .arg("play")
            .arg(take)
            .arg("--character")
            .arg(character("wolf"))
            .args(["--osc", "127.0.0.1:9"])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{}: {stderr}", take.display());
        assert!(
            stderr.contains(&take.display().to_string()) && stderr.contains(expected),
            "{}: {stderr}",
            take.display()
        );
    }
}

/// A phone file under the size limit whose line is longer than the line limit: refused,
/// naming the file and the line, nothing written.
#[test]
fn a_phone_file_with_an_endless_line_names_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let phn = dir.path().join("long.phn");
    std::fs::write(&phn, format!("0 3050 h#\n{}\n", "9".repeat(2 << 20))).unwrap();
    let out = dir.path().join("take.jsonl");
    let run = mouthpiece()
        .args(["lipsync", "--character"])
        .arg(character("wolf"))
        .arg("--phonemes")
        .arg(&phn)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains(&format!("{} line 2", phn.display())) && stderr.contains("longer than"),
        "{stderr}"
    );
    assert!(!out.exists());
}
