//! The live analyser on Festival speech (Debian `festival`, `festvox-kallpc16k`; fails when
//! they are missing, as `scripts/test` installs them): the shipped profiles are what the
//! learning sentences give, and on evaluation sentences never learned from the analyser
//! keeps an accuracy floor, at 16 kHz and at a microphone's 48 kHz.

use crate::helper_festival as festival;

use festival::*;
use mouthpiece_lipsync::live::{LiveSettings, Profiles, SHIPPED_PROFILES};

#[test]
fn shipped_profiles_are_learned_from_the_learning_sentences() {
    let dir = tempfile::tempdir().unwrap();
    let table = table();
    let lines: Vec<Spoken> = LEARNING
        .iter()
        .enumerate()
        .map(|(i, t)| speak(t, dir.path(), &format!("l{i}")))
        .collect();
    let learned = learn(&table, &lines, "");
    let shipped = Profiles::from_toml_str(SHIPPED_PROFILES, "shipped").unwrap();
    assert_eq!(learned.classes.len(), shipped.classes.len());
    for (a, b) in learned.classes.iter().zip(&shipped.classes) {
        assert_eq!(a.name, b.name);
        assert_eq!(a.frames, b.frames, "{}", a.name);
        for (x, y) in a.mean.iter().zip(&b.mean).chain(a.var.iter().zip(&b.var)) {
            assert!(
                (x - y).abs() <= 1e-3 * (1.0 + y.abs()),
                "{}: {x} vs {y}",
                a.name
            );
        }
    }
    // The evaluation sentences are not among the learning ones.
    for (_, e) in EVALUATION {
        assert!(!LEARNING.contains(&e));
    }
}

#[test]
fn held_out_sentences_keep_the_accuracy_floor_at_16_and_48_khz() {
    let dir = tempfile::tempdir().unwrap();
    let table = table();
    let shipped = Profiles::from_toml_str(SHIPPED_PROFILES, "shipped").unwrap();
    let lines: Vec<Spoken> = EVALUATION[..2]
        .iter()
        .map(|(n, t)| speak(t, dir.path(), n))
        .collect();
    for (rate, factor, block) in [(16_000, 1, 160), (48_000, 3, 480)] {
        let mut m = Measures::default();
        for line in &lines {
            let mut a = analyser(&shipped, LiveSettings::default());
            let (steps, _) = analyse(&mut a, &upsample(&line.samples, factor), rate, block);
            // One step every 10 ms of sound.
            let expected = line.samples.len() / 160;
            assert!(steps.len().abs_diff(expected) <= 3, "{} steps", steps.len());
            measure(&table, &line.phones, &steps, &mut m);
        }
        eprintln!(
            "{rate} Hz: class {:.3} shape {:.3} boundary median {:.4} p90 {:.4} matched {:.3}",
            m.class_share(),
            m.shape_share(),
            m.boundary(0.5),
            m.boundary(0.9),
            m.matched_share()
        );
        assert!(
            m.class_share() >= FLOOR_CLASS,
            "{rate} Hz: class {}",
            m.class_share()
        );
        assert!(
            m.boundary(0.5) <= 0.030,
            "{rate} Hz: median {}",
            m.boundary(0.5)
        );
        assert!(
            m.matched_share() >= 0.8,
            "{rate} Hz: matched {}",
            m.matched_share()
        );
    }
}

/// Sound → points p95 on the eight evaluation sentences at a microphone's 48 kHz in 10 ms
/// blocks, by the stream's own clock (nothing of this machine's timing): the onset lag p95,
/// the wait for a block, and the mouth's time to halfway toward a new class, within the
/// 150 ms target less 1 ms for processing (measured: microseconds a block). Festival and
/// the analyser are deterministic, so the figure is the same on every run.
#[test]
fn sound_to_points_p95_is_within_150_ms_on_the_evaluation_sentences() {
    let dir = tempfile::tempdir().unwrap();
    let table = table();
    let shipped = Profiles::from_toml_str(SHIPPED_PROFILES, "shipped").unwrap();
    let mut m = Measures::default();
    for (n, t) in EVALUATION {
        let line = speak(t, dir.path(), n);
        let mut a = analyser(&shipped, LiveSettings::default());
        let (steps, _) = analyse(&mut a, &upsample(&line.samples, 3), 48_000, 480);
        measure(&table, &line.phones, &steps, &mut m);
    }
    let halfway = LiveSettings::default().mouth_tau_s * std::f64::consts::LN_2;
    let budget = m.lag(0.95) + 0.010 + halfway;
    eprintln!(
        "class {:.3} onset lag p95 {:.4} sound to points p95 {budget:.4}",
        m.class_share(),
        m.lag(0.95)
    );
    assert!(budget <= 0.149, "sound to points p95 {budget}");
    // Not bought with accuracy: the class share of the docs' table (64.1 %).
    assert!(m.class_share() >= 0.64, "class {}", m.class_share());
}

/// Frames of the right class on SA1 + SA2 (measured 0.678 at both rates; the most frequent
/// class alone, silence, covers about a fifth).
const FLOOR_CLASS: f64 = 0.6;
