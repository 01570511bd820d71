//! `mouthpiece synth` end to end: the file it writes is read by Python's `mcap` package (an
//! independent reader, `tests/read_session.py`) and by our own reader; bad input exits 2.

use crate::{mouthpiece, repo};
use std::process::Command;

use mouthpiece_recording::SessionReader;
use mouthpiece_synth::{Synth, SynthConfig};

fn python() -> String {
    std::env::var("MOUTHPIECE_PYTHON").unwrap_or_else(|_| "python3".into())
}

#[test]
fn python_mcap_reads_what_synth_writes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s.mcap");
    let status = mouthpiece()
        .args(["synth", "--out"])
        .arg(&out)
        .args(["--seconds", "2", "--seed", "42", "--size", "160x120"])
        .status()
        .unwrap();
    assert!(status.success());

    // What was written: the same config rendered in memory.
    let config = SynthConfig {
        seed: 42,
        seconds: 2.0,
        camera: SynthConfig::camera_for_size(160, 120),
        ..SynthConfig::default()
    };
    let depth_frame = 47;
    let (frame, _) = Synth::new(config).unwrap().nth(depth_frame).unwrap();
    let depth_file = dir.path().join("depth.raw");
    let bytes: Vec<u8> = frame
        .depth
        .data
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    std::fs::write(&depth_file, bytes).unwrap();
    let expected = serde_json::json!({
        "frames": 60, "depth_frame": depth_frame, "depth_file": depth_file,
        "width": 160, "height": 120, "color_format": "jpeg",
    });
    let expected_file = dir.path().join("expected.json");
    std::fs::write(&expected_file, expected.to_string()).unwrap();

    let output = Command::new(python())
        .arg(repo().join("tests/read_session.py"))
        .arg(&out)
        .arg(&expected_file)
        .output()
        .expect("run Python (set MOUTHPIECE_PYTHON)");
    assert!(
        output.status.success(),
        "read_session.py failed:\n{}\n{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );

    // And our reader gives back the same depth and the ground truth.
    let f = SessionReader::open(&out)
        .unwrap()
        .nth(depth_frame)
        .unwrap()
        .unwrap();
    assert_eq!(f.frame.depth, frame.depth);
    assert!(f.ground_truth.is_some());
}

#[test]
fn bad_input_exits_2_and_names_it() {
    let dir = tempfile::tempdir().unwrap();
    let layout = dir.path().join("layout.toml");
    std::fs::write(&layout, "lip_dots = 5\n").unwrap();
    let output = mouthpiece()
        .args(["synth", "--seconds", "1", "--seed", "1", "--out"])
        .arg(dir.path().join("x.mcap"))
        .arg("--layout")
        .arg(&layout)
        .output()
        .unwrap();
    assert_eq!(output.status.code(), Some(2));
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(
        err.contains("layout.toml") && err.contains("lip_dots"),
        "{err}"
    );

    let output = mouthpiece()
        .args([
            "synth",
            "--seconds",
            "1",
            "--seed",
            "1",
            "--distance",
            "9",
            "--out",
        ])
        .arg(dir.path().join("x.mcap"))
        .output()
        .unwrap();
    assert_eq!(output.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&output.stderr).contains("distance"));
}

/// Runs `synth` with `args` (one second unless they say): it must exit 2 naming `named` and
/// leave no file.
fn synth_refuses(out: &str, args: &[&str], named: &str) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(out);
    let mut cmd = mouthpiece();
    cmd.args(["synth", "--seed", "1", "--size", "64x48", "--out"])
        .arg(&path);
    if !args.contains(&"--seconds") {
        cmd.args(["--seconds", "1"]);
    }
    let output = cmd.args(args).output().unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{args:?}: {err}");
    assert!(err.contains(named), "{args:?}: {err}");
    assert!(!path.exists(), "{args:?} left {out}");
}

/// A frame rate near zero wrote an empty session that looked like success.
#[test]
fn a_frame_rate_near_zero_exits_2() {
    synth_refuses("a.mcap", &["--fps", "1e-300"], "fps");
    synth_refuses("b.oni", &["--fps", "1e-300"], "fps");
    synth_refuses("c.mcap", &["--fps", "0.5"], "fps");
}

/// A length of 10^300 s planned speech without end.
#[test]
fn a_length_past_a_day_exits_2() {
    synth_refuses("d.mcap", &["--seconds", "1e300"], "seconds");
    synth_refuses("e.mcap", &["--seconds", "1e9"], "seconds");
}

/// Non-finite lens distortion.
#[test]
fn non_finite_distortion_exits_2() {
    synth_refuses("f.mcap", &["--distortion", "NaN,0,0,0,0"], "distortion");
}

/// A hinge moved past ±50 % or a jaw slide out of 0–5 mm is refused at the door, naming the
/// flag.
#[test]
fn a_hinge_or_a_jaw_slide_out_of_range_exits_2() {
    synth_refuses("g.mcap", &["--hinge", "back=+80%"], "--hinge");
    synth_refuses("h.mcap", &["--hinge", "sideways=5%"], "--hinge");
    synth_refuses("i.mcap", &["--jaw-slide", "NaN"], "--jaw-slide");
    synth_refuses("j.mcap", &["--jaw-slide", "12"], "--jaw-slide");
    let output = mouthpiece()
        .args(["evaluate", "--seeds", "1", "--hinge", "down=-70%"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{err}");
    assert!(err.contains("--hinge"), "{err}");
}

/// `synth --speech-text`: Festival says the line; the session holds its sound on `/audio`
/// from the end of the neutral lead-in, and its mouth, driven by Festival's own phone timing,
/// is open on the line's vowels and closed on its `m`/`b`/`p` and in the lead-in.
#[test]
fn speech_text_says_the_line_with_its_sound_and_an_open_mouth_on_its_vowels() {
    use mouthpiece_lipsync::phones::{self, PhoneFormat};
    use mouthpiece_recording::AudioReader;
    let line = "Bob ate a big bowl of apple pie.";
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("line.mcap");
    let output = mouthpiece()
        .args([
            "synth",
            "--seconds",
            "4.5",
            "--seed",
            "3",
            "--size",
            "160x120",
        ])
        .args(["--head-motion", "none", "--speech-text", line, "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    // Festival again, for the line's phones and length (its synthesis is deterministic).
    let scm = dir.path().join("t.scm");
    std::fs::write(
        &scm,
        format!(
            "(set! u (Utterance Text \"{line}\"))\n(utt.synth u)\n(utt.save.wave u \"{0}/t.wav\" 'riff)\n(utt.save.segs u \"{0}/t.segs\")\n",
            dir.path().display()
        ),
    )
    .unwrap();
    let status = Command::new("festival")
        .arg("-b")
        .arg(&scm)
        .status()
        .expect("festival (Debian festival + festvox-kallpc16k)");
    assert!(status.success());
    let segs = std::fs::read_to_string(dir.path().join("t.segs")).unwrap();
    let phones = phones::read(&segs, PhoneFormat::Label, "t.segs").unwrap();
    let wav = hound::WavReader::open(dir.path().join("t.wav")).unwrap();
    let wav_frames = u64::from(wav.duration());

    // The sound: all of the line, its first sample at the end of the 1.5 s lead-in.
    let mut audio = AudioReader::open(&out).unwrap();
    let (mut first, mut frames) = (None, 0);
    while let Some(m) = audio.next_audio().unwrap() {
        first.get_or_insert(m.log_time);
        frames += m.frames();
    }
    assert_eq!(frames, wav_frames, "the line's samples on /audio");
    let sessions: Vec<_> = SessionReader::open(&out)
        .unwrap()
        .map(Result::unwrap)
        .collect();
    let start = sessions[0].log_time;
    let lead = first.unwrap() - start;
    assert!(
        lead.abs_diff(1_500_000_000) < 1_000_000,
        "sound at {lead} ns"
    );

    // The mouth: the jaw at each frame, by the frame's time after the lead-in.
    let jaw_at = |t: f64| -> f64 {
        let f = sessions
            .iter()
            .min_by_key(|f| (f.log_time - start).abs_diff(((t + 1.5) * 1e9) as u64))
            .unwrap();
        f.ground_truth.as_ref().unwrap().mouth.unwrap().jaw
    };
    let centres = |set: &[&str]| -> Vec<f64> {
        phones
            .iter()
            .filter(|p| set.contains(&p.phone.as_str()) && p.end - p.start >= 0.05)
            .map(|p| jaw_at(0.5 * (p.start + p.end)))
            .collect()
    };
    let vowels = centres(&["aa", "ae", "ah", "ao", "aw", "ay", "eh", "ey", "ih", "ow"]);
    let closed = centres(&["m", "b", "p"]);
    eprintln!("jaw on vowels {vowels:?}, on m/b/p {closed:?}");
    assert!(vowels.len() >= 5 && closed.len() >= 3, "{phones:?}");
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!(mean(&vowels) > 0.08, "vowels {vowels:?}");
    assert!(mean(&vowels) > 3.0 * mean(&closed), "{vowels:?} {closed:?}");
    for f in &sessions {
        if f.log_time - start < 1_400_000_000 {
            assert_eq!(f.ground_truth.as_ref().unwrap().mouth.unwrap().jaw, 0.0);
        }
    }
}

/// Without Festival, `--speech-text` is bad input saying what to install, and leaves no file.
#[test]
fn speech_text_without_festival_exits_2_saying_what_to_install() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("line.mcap");
    let output = mouthpiece()
        .env("PATH", dir.path())
        .args(["synth", "--seconds", "1", "--seed", "1", "--size", "64x48"])
        .args(["--speech-text", "Hello there.", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{err}");
    assert!(
        err.contains("Festival") && err.contains("festvox-kallpc16k"),
        "{err}"
    );
    assert!(!out.exists());
    // A line with a control character is refused naming it.
    synth_refuses("c.mcap", &["--speech-text", "Hello\u{1b} there."], "U+001B");
    // And .oni sessions hold no sound.
    synth_refuses("s.oni", &["--speech-text", "Hello."], "--speech-text");
}
