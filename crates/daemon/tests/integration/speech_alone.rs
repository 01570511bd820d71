//! A booth without a camera: `[source] spec = "none"` and `speech = "always"`. No frame is
//! ever processed; Festival speech comes in on the audio bus and the processor's steps come
//! from the sound alone, timed by its sample clock: every step says `speech`, and the mouth
//! moves (each of the default characters, human and wolf). Needs Debian `festival` + `festvox-kallpc16k`.

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

use festival::speak;

const BOOTH: &str = "[source]\nspec = \"none\"\n[audio]\n\
    [characters.settings.human]\nspeech = \"always\"\n\
    [characters.settings.wolf]\nspeech = \"always\"\n";

#[test]
fn without_a_camera_the_sound_times_the_steps_and_moves_the_mouth() {
    let config = Config::parse(BOOTH, Path::new("/etc/mouthpiece/test.toml")).unwrap();
    let mut processor = LiveProcessor::new(setup(&config).unwrap()).unwrap();
    let bus: Arc<AudioBus> = AudioBus::new();
    processor.set_audio(&bus);
    let (rate, samples) = speak("She had your dark suit in greasy wash water all year.");
    let format = AudioFormat {
        sample_rate: rate,
        channels: 1,
    };
    let base = Instant::now();
    let block = (rate / 100) as usize;
    let mut out = Output::default();
    let mut steps: Vec<(Instant, Vec<[f32; 3]>)> = Vec::new();
    let mut fed = 0;
    while fed + block <= samples.len() {
        let end = (fed + block) as f64 / f64::from(rate);
        bus.publish(AudioEvent::Block(Arc::new(AudioBlock {
            seq: (fed / block) as u64,
            first_frame: fed as u64,
            format,
            samples: samples[fed..fed + block].to_vec(),
            host_rx: base + Duration::from_secs_f64(end),
            wall_clock: None,
        })));
        fed += block;
        // The processing thread's turn: every step due, no camera frame at all.
        while let Some(heard_at) = processor.speech_step(&mut out) {
            let c = out
                .stream
                .characters
                .iter()
                .find(|c| c.name == "human")
                .expect("the character is in every step");
            assert_eq!(c.source, MouthSource::Speech);
            assert!(c.confidence.iter().all(|&x| x == 1.0));
            assert!(c.curve.is_some());
            steps.push((heard_at, c.points.clone()));
        }
    }
    let seconds = samples.len() as f64 / f64::from(rate);
    // 50 steps per second of sound, in the sound's order (its own clock).
    let expected = seconds * 50.0;
    assert!(
        (steps.len() as f64 - expected).abs() <= 0.05 * expected + 3.0,
        "{} steps for {seconds:.2} s",
        steps.len()
    );
    assert!(steps.windows(2).all(|w| w[0].0 < w[1].0));
    // The mouth moves with the sound.
    let first = &steps[0].1;
    let moved = steps
        .iter()
        .map(|(_, p)| {
            p.iter()
                .zip(first)
                .map(|(a, b)| {
                    (0..3)
                        .map(|k| f64::from(a[k] - b[k]).powi(2))
                        .sum::<f64>()
                        .sqrt()
                })
                .fold(0.0, f64::max)
        })
        .fold(0.0, f64::max);
    assert!(moved > 1e-3, "the mouth never moved ({moved})");
}

#[test]
fn no_camera_needs_sound_and_speech_always() {
    let path = Path::new("/etc/mouthpiece/test.toml");
    let config = Config::parse("[source]\nspec = \"none\"\n", path).unwrap();
    let Err(err) = setup(&config) else {
        panic!("spec none without [audio] accepted")
    };
    let err = err.to_string();
    assert!(
        err.contains("source.spec") && err.contains("[audio]"),
        "{err}"
    );
    let config = Config::parse(
        "[source]\nspec = \"none\"\n[audio]\n[characters.settings.human]\nspeech = \"fallback\"\n",
        path,
    )
    .unwrap();
    let Err(err) = setup(&config) else {
        panic!("spec none with speech fallback accepted")
    };
    let err = err.to_string();
    assert!(
        err.contains("source.spec") && err.contains("always"),
        "{err}"
    );
    assert!(err.contains("test.toml:2:"), "{err}");
}
