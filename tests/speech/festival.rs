//! Festival speech for the speech tests (Debian `festival` + `festvox-kallpc16k`): a line
//! spoken by Festival's default voice, as the sample rate and mono 16-bit samples. Included
//! by the tests that need it with `#[path]`.

#![allow(dead_code)]

use std::process::Command;

/// Festival speaking `text` (its default voice and rate, 16 kHz).
pub fn speak(text: &str) -> (u32, Vec<i16>) {
    let dir = tempfile::tempdir().unwrap();
    let wav = dir.path().join("line.wav");
    let scm = dir.path().join("line.scm");
    std::fs::write(
        &scm,
        format!(
            "(set! u (Utterance Text \"{text}\"))\n(utt.synth u)\n(utt.save.wave u \"{}\" 'riff)\n",
            wav.display()
        ),
    )
    .unwrap();
    let out = Command::new("festival")
        .arg("-b")
        .arg(&scm)
        .output()
        .expect("festival");
    assert!(out.status.success());
    let mut r = hound::WavReader::open(&wav).unwrap();
    let rate = r.spec().sample_rate;
    (rate, r.samples::<i16>().map(Result::unwrap).collect())
}
