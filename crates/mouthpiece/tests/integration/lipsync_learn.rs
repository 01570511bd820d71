//! `mouthpiece lipsync learn` on Festival speech (Debian `festival`, `festvox-kallpc16k`): the
//! profiles it learns from one voice classify held-out sentences of that voice at least as
//! well as the shipped ones; the daemon's `[audio] speech_profiles` reads them; too little or
//! mismatched input is bad input (exit 2) and leaves no file.

use crate::helper_festival as festival;

use std::path::Path;
use std::process::Output;

use festival::*;
use mouthpiece_lipsync::live::{LiveSettings, Profiles, SHIPPED_PROFILES};

fn mouthpiece(dir: &Path, args: &[&str]) -> Output {
    crate::mouthpiece()
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

/// Writes a spoken line as `NAME.wav` (16-bit, its rate) beside Festival's `NAME.segs`.
fn write_wav(line: &Spoken, path: &Path) {
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: line.rate,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut w = hound::WavWriter::create(path, spec).unwrap();
    for s in &line.samples {
        w.write_sample(*s).unwrap();
    }
    w.finalize().unwrap();
}

/// Class share of SA1 + SA2 (never learned from) at 48 kHz in 10 ms blocks.
fn held_out_class(profiles: &Profiles, dir: &Path) -> f64 {
    let table = table();
    let mut m = Measures::default();
    for (n, t) in &EVALUATION[..2] {
        let line = speak(t, dir, n);
        let mut a = analyser(profiles, LiveSettings::default());
        let (steps, _) = analyse(&mut a, &upsample(&line.samples, 3), 48_000, 480);
        measure(&table, &line.phones, &steps, &mut m);
    }
    m.class_share()
}

#[test]
fn profiles_learned_from_a_voice_classify_its_held_out_sentences_as_well_as_the_shipped() {
    let dir = tempfile::tempdir().unwrap();
    let mut args = vec!["lipsync".to_string(), "learn".into()];
    for (i, t) in LEARNING.iter().enumerate() {
        let name = format!("l{i}");
        let line = speak(t, dir.path(), &name);
        write_wav(&line, &dir.path().join(format!("{name}.wav")));
        args.extend([
            "--audio".into(),
            format!("{name}.wav"),
            "--phones".into(),
            format!("{name}.segs"),
        ]);
    }
    args.extend(["--out".into(), "booth.toml".into()]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let out = mouthpiece(dir.path(), &args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(dir.path().join("booth.toml")).unwrap();
    let learned = Profiles::from_toml_str(&text, "booth.toml").unwrap();
    let shipped = Profiles::from_toml_str(SHIPPED_PROFILES, "shipped").unwrap();
    let (a, b) = (
        held_out_class(&learned, dir.path()),
        held_out_class(&shipped, dir.path()),
    );
    eprintln!("SA1 + SA2 class: learned {a:.3}, shipped {b:.3}");
    assert!(a >= b && a >= 0.6, "learned {a} shipped {b}");

    // The daemon takes the file instead of the shipped profiles, relative to its config.
    let config = "[source]\nspec = \"none\"\n[audio]\nspeech_profiles = \"booth.toml\"\n\
                  [characters.settings.human]\nspeech = \"always\"\n\
                  [characters.settings.wolf]\nspeech = \"always\"\n";
    std::fs::write(dir.path().join("booth-config.toml"), config).unwrap();
    let out = mouthpiece(dir.path(), &["check-config", "booth-config.toml"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // A profile file that is not one is refused at the key, exit 2.
    std::fs::write(dir.path().join("booth.toml"), "version = 1\nmean = [1.0\n").unwrap();
    let out = mouthpiece(dir.path(), &["check-config", "booth-config.toml"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("audio.speech_profiles") && err.contains("booth.toml"),
        "{err}"
    );
}

#[test]
fn too_little_or_mismatched_input_exits_2_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let line = speak("Two blue fish swam in the tank.", dir.path(), "short");
    write_wav(&line, &dir.path().join("short.wav"));
    let refused = |args: &[&str], says: &[&str]| {
        let out = mouthpiece(dir.path(), args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        for s in says {
            assert!(err.contains(s), "{args:?}: {err}");
        }
        assert!(!dir.path().join("p.toml").exists(), "{args:?}");
    };
    let base = ["lipsync", "learn", "--out", "p.toml"];
    // One sentence: too few classes.
    refused(
        &[
            &base[..],
            &["--audio", "short.wav", "--phones", "short.segs"],
        ]
        .concat(),
        &["too little", "missing"],
    );
    // A --phones short.
    refused(
        &[
            &base[..],
            &["--audio", "short.wav", "--audio", "short.wav"],
            &["--phones", "short.segs"],
        ]
        .concat(),
        &["2 --audio and 1 --phones"],
    );
    // Phones that run far past the sound.
    let long = "#\n1.0 125 pau\n60.0 125 aa\n";
    std::fs::write(dir.path().join("long.lab"), long).unwrap();
    refused(
        &[&base[..], &["--audio", "short.wav", "--phones", "long.lab"]].concat(),
        &["long.lab", "60.00 s"],
    );
    // Not a WAV.
    refused(
        &[
            &base[..],
            &["--audio", "short.segs", "--phones", "short.segs"],
        ]
        .concat(),
        &["short.segs", "not a readable WAV"],
    );
}
