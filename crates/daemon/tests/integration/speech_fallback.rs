//! The daemon's processor with `speech = "fallback"`: the synthetic performer is rendered
//! frame by frame while Festival speech (never learned from) comes in on the audio bus as
//! the audio thread publishes it; for a stretch the lip dots are covered (a hand over the
//! mouth: the mouth's part of the colour image painted with skin). The character's mouth
//! keeps moving from the sound while they are covered, each frame says which source drove
//! it, and the mouth hands back to the camera without a step larger than the two sources'
//! own motion plus the blend's. Needs Debian `festival` + `festvox-kallpc16k`.

use crate::helper_speech_cover_mouth as cover_mouth;
use crate::helper_speech_festival as festival;

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use mouthpiece_config::Config;
use mouthpiece_daemon::live::{setup, LiveProcessor};
use mouthpiece_daemon::pipeline::{Output, Processor};
use mouthpiece_frame::audio::{AudioBlock, AudioFormat};
use mouthpiece_frame::{AudioBus, AudioEvent};
use mouthpiece_output::MouthSource;
use mouthpiece_synth::{Synth, SynthConfig};

use cover_mouth::cover_mouth;
use festival::speak;

fn step_size(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| {
            let d: f64 = (0..3).map(|k| f64::from(p[k] - q[k]).powi(2)).sum();
            d.sqrt()
        })
        .fold(0.0, f64::max)
}

#[test]
fn covered_lips_hand_the_mouth_to_speech_and_back_without_a_jump() {
    let config = Config::parse(
        "[characters.settings.human]\nspeech = \"fallback\"\nspeech_hold_ms = 300\n\
         speech_blend_ms = 150\n",
        Path::new("/etc/mouthpiece/test.toml"),
    )
    .unwrap();
    let mut processor = LiveProcessor::new(setup(&config).unwrap()).unwrap();
    let bus: Arc<AudioBus> = AudioBus::new();
    processor.set_audio(&bus);

    let (rate, mut samples) = speak("She had your dark suit in greasy wash water all year.");
    samples.extend(speak("Don't ask me to carry an oily rag like that.").1);
    let format = AudioFormat {
        sample_rate: rate,
        channels: 1,
    };
    let speech_from = 2.0; // after the neutral pose is taken
    let speech_s = samples.len() as f64 / f64::from(rate);
    let (covered_from, covered_to) = (speech_from + 1.0, speech_from + 3.5);
    let mut synth = Synth::new(SynthConfig {
        seconds: speech_from + speech_s.min(5.0),
        colour_effects: false,
        ..SynthConfig::default()
    })
    .unwrap();
    let base = Instant::now();
    let block = (rate / 100) as usize;
    let mut fed = 0usize;
    let mut out = Output::default();
    let mut rows: Vec<(f64, MouthSource, Vec<[f32; 3]>)> = Vec::new();
    while let Some((mut frame, truth)) = synth.render_next() {
        let t = truth.t;
        frame.host_rx = base + Duration::from_secs_f64(t);
        // The sound up to this frame, as the audio thread publishes it.
        while speech_from + ((fed + block) as f64) / f64::from(rate) <= t
            && fed + block <= samples.len()
        {
            let end = speech_from + ((fed + block) as f64) / f64::from(rate);
            bus.publish(AudioEvent::Block(Arc::new(AudioBlock {
                seq: (fed / block) as u64,
                first_frame: fed as u64,
                format,
                samples: samples[fed..fed + block].to_vec(),
                host_rx: base + Duration::from_secs_f64(end),
                wall_clock: None,
            })));
            fed += block;
        }
        if (covered_from..covered_to).contains(&t) {
            cover_mouth(&mut frame, &truth);
        }
        processor.process(&frame, &mut out);
        if let Some(c) = out.stream.characters.iter().find(|c| c.name == "human") {
            rows.push((t, c.source, c.points.clone()));
        }
    }
    let during = |from: f64, to: f64| rows.iter().filter(move |r| r.0 >= from && r.0 < to);
    assert!(during(0.0, covered_from + 0.25).all(|r| r.1 == MouthSource::Camera));
    assert!(
        during(covered_from + 0.5, covered_to).all(|r| r.1 == MouthSource::Speech),
        "{:?}",
        during(covered_from + 0.5, covered_to)
            .map(|r| (r.0, r.1))
            .collect::<Vec<_>>()
    );
    assert!(during(covered_to + 0.2, 1e9).all(|r| r.1 == MouthSource::Camera));
    assert!(during(covered_from, covered_to + 0.2).any(|r| r.1 == MouthSource::Blend));
    // The mouth keeps moving from the sound while the lips are covered.
    let first = &rows[0].2;
    let openings: Vec<f64> = during(covered_from + 0.5, covered_to)
        .map(|r| step_size(&r.2, first))
        .collect();
    let (lo, hi) = openings
        .iter()
        .fold((f64::MAX, 0.0f64), |(a, b), &o| (a.min(o), b.max(o)));
    assert!(hi - lo > 0.003, "speech moved the mouth only {lo}..{hi}");
    // Steps: the normal bound is the largest step of either source alone; a handover may
    // add the blend's own move (1.5 / blend of the distance between them per second).
    let steps: Vec<(f64, f64)> = rows
        .windows(2)
        .map(|w| (w[1].0, step_size(&w[0].2, &w[1].2)))
        .collect();
    let in_range = |from: f64, to: f64| {
        steps
            .iter()
            .filter(move |s| s.0 >= from && s.0 < to)
            .map(|s| s.1)
    };
    let normal = in_range(speech_from, covered_from)
        .chain(in_range(covered_from + 0.5, covered_to))
        .chain(in_range(covered_to + 0.2, 1e9))
        .fold(0.0, f64::max);
    let blend_move = 1.5 / (0.15 * 30.0) * hi.max(0.03);
    for (from, to) in [
        (covered_from + 0.25, covered_from + 0.5),
        (covered_to - 0.05, covered_to + 0.2),
    ] {
        let biggest = in_range(from, to).fold(0.0, f64::max);
        eprintln!("handover at {from}: largest step {biggest}, normal {normal} + {blend_move}");
        assert!(
            biggest <= normal + blend_move,
            "handover at {from}: a step of {biggest} beyond {normal} + {blend_move}"
        );
    }
}
