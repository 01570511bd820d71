//! The mouth from speech at the pipeline level: a Festival line (never learned from) comes in
//! as 10 ms sound blocks while 60 fps camera steps come in; the lip dots are lost for a
//! stretch. With `speech = "fallback"` the character's mouth keeps moving from the sound
//! while they are lost and hands back to the camera when they return, without a step larger
//! than the two sources' own motion at either handover. Needs Debian `festival` +
//! `festvox-kallpc16k` (scripts/test installs them).

#[path = "../../../tests/speech/festival.rs"]
mod festival;

use std::time::{Duration, Instant};

use mouthpiece_frame::audio::{AudioBlock, AudioFormat};
use mouthpiece_output::MouthSource;
use mouthpiece_pipeline::handover::{HandoverSettings, SpeechMode};
use mouthpiece_pipeline::speech::SpeechDriver;
use mouthpiece_retarget::{Character, CharacterSettings, CharacterStep, ShapeSmoothing, Vec3};

use festival::speak;

fn human() -> Character {
    let text = include_str!("../../../config/characters/human.toml");
    Character::from_toml_str(text).unwrap()
}

/// Largest move of any point between two steps.
fn step_size(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (p - q).norm())
        .fold(0.0, f64::max)
}

/// How far the camera holds the lower lip open, metres.
const CAMERA_OPEN: f64 = 0.1;

#[test]
fn fallback_keeps_the_mouth_moving_while_the_dots_are_lost_and_hands_back_without_a_jump() {
    // Two held-out sentences back to back: about 5 s of speech.
    let (rate, mut samples) = speak("She had your dark suit in greasy wash water all year.");
    samples.extend(speak("Don't ask me to carry an oily rag like that.").1);
    let seconds = samples.len() as f64 / f64::from(rate);
    let character = human();
    let neutral = character.neutral.clone();
    let settings = HandoverSettings {
        mode: SpeechMode::Fallback,
        hold_s: 0.3,
        blend_s: 0.15,
    };
    let mut driver =
        SpeechDriver::new(&[(character, settings)], CharacterSettings::default()).unwrap();
    let format = AudioFormat {
        sample_rate: rate,
        channels: 1,
    };
    let block = (rate / 100) as usize;
    let start = Instant::now();
    let (lost_from, lost_to) = (1.0, 3.5);
    let mut fed = 0usize;
    let mut step = CharacterStep {
        t: 0.0,
        points: neutral.clone(),
        confidence: vec![1.0; neutral.len()],
        curve: Vec::new(),
        head: Default::default(),
    };
    let (mut previous, mut last_camera): (Option<Vec<Vec3>>, Vec<Vec3>) = (None, neutral.clone());
    let mut rows = Vec::new();
    let n = (seconds * 60.0) as usize;
    let lowest = neutral.iter().map(|p| p.y).fold(f64::MAX, f64::min);
    for k in 0..n {
        let t = k as f64 / 60.0;
        // The sound up to this step, as the audio thread delivers it.
        while (fed + block) as f64 / f64::from(rate) <= t && fed + block <= samples.len() {
            let b = AudioBlock {
                seq: (fed / block) as u64,
                first_frame: fed as u64,
                format,
                samples: samples[fed..fed + block].to_vec(),
                host_rx: start + format.duration_of((fed + block) as u64),
                wall_clock: None,
            };
            driver.push_audio(&b).unwrap();
            fed += block;
        }
        // The camera: the lower lip held far open (further than speech ever opens it, so the
        // two sources are far apart at both handovers) and moving a little while seen; the
        // last points held while the dots are lost (the retarget's hold).
        let lost = (lost_from..lost_to).contains(&t);
        if !lost {
            let open = CAMERA_OPEN + 0.002 * (2.0 * std::f64::consts::PI * 0.7 * t).sin();
            last_camera = neutral
                .iter()
                .map(|p| {
                    let lower = if p.y < 0.5 * lowest { 1.0 } else { 0.0 };
                    p + Vec3::new(0.0, -open * lower, 0.0)
                })
                .collect();
        }
        step.t = t;
        step.points.clone_from(&last_camera);
        let now = start + Duration::from_secs_f64(t);
        let source = driver.drive(0, t, now, lost, &ShapeSmoothing::None, &mut step);
        let size = previous
            .as_ref()
            .map_or(0.0, |p| step_size(p, &step.points));
        let opening = step_size(&step.points, &neutral);
        rows.push((t, source, size, opening));
        previous = Some(step.points.clone());
    }
    let during = |from: f64, to: f64| rows.iter().filter(move |r| r.0 >= from && r.0 < to);
    // Camera before the loss and before the hold has passed; speech after the blend.
    assert!(during(0.0, lost_from + 0.29).all(|r| r.1 == MouthSource::Camera));
    assert!(during(lost_from + 0.32, lost_from + 0.44).all(|r| r.1 == MouthSource::Blend));
    assert!(during(lost_from + 0.47, lost_to).all(|r| r.1 == MouthSource::Speech));
    assert!(during(lost_to, lost_to + 0.14).all(|r| r.1 == MouthSource::Blend));
    assert!(during(lost_to + 0.17, seconds).all(|r| r.1 == MouthSource::Camera));
    // The mouth keeps moving from the sound: it opens and closes during the loss.
    let openings: Vec<f64> = during(lost_from + 0.5, lost_to).map(|r| r.3).collect();
    let (lo, hi) = openings
        .iter()
        .fold((f64::MAX, 0.0f64), |(a, b), &o| (a.min(o), b.max(o)));
    eprintln!("speech opening {lo}..{hi}");
    assert!(hi - lo > 0.002, "speech moved the mouth only {lo}..{hi}");
    // The normal motion bound: the largest step of either source alone.
    let normal = during(0.0, lost_from)
        .chain(during(lost_from + 0.5, lost_to))
        .chain(during(lost_to + 0.2, seconds))
        .map(|r| r.2)
        .fold(0.0, f64::max);
    // A handover may add to that the blend's own move: the smoothstep's steepest slope
    // (1.5 / blend) times one step, of the distance between the two sources (at most the
    // camera's opening plus speech's). Without the blend the first step would cover the
    // whole distance, at least CAMERA_OPEN - hi.
    let blend_move = 1.5 / (settings.blend_s * 60.0) * (CAMERA_OPEN + 0.002 + hi);
    assert!(
        CAMERA_OPEN - hi > normal + blend_move,
        "the test's sources are too close"
    );
    for (from, to) in [
        (lost_from + 0.25, lost_from + 0.5),
        (lost_to - 0.05, lost_to + 0.2),
    ] {
        let biggest = during(from, to).map(|r| r.2).fold(0.0, f64::max);
        eprintln!("handover at {from}: largest step {biggest}, normal {normal} + {blend_move}");
        assert!(
            biggest <= normal + blend_move,
            "handover at {from}: a step of {biggest} beyond the normal {normal}"
        );
    }
}
