//! `mouthpiece lipsync` end to end: phone files → takes for the human and the wolf that
//! `export` turns into glTF; bad input (exit 2, file and line named, nothing written); and
//! real speech: Festival (Debian `festival`, `festvox-kallpc16k`) speaks two sentences, and
//! PocketSphinx (Debian `libpocketsphinx-dev`, `pocketsphinx-en-us`) aligns and recognises
//! them, measured by `bench/lipsync_accuracy.py`. Fails when Festival or the model is missing
//! (scripts/test installs them).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn mouthpiece() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_mouthpiece"));
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
/// the targets for alignment (median ≤ 20 ms, p90 ≤ 50 ms, ≥ 85 % of frames in the
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
