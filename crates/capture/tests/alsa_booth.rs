//! The ALSA source against a real ALSA capture PCM (the `file` plugin streaming Festival's
//! speech, paced by JACK's dummy driver: tests/alsa). One test function: ALSA reads its
//! configuration path once per process.

#![cfg(feature = "alsa")]

#[path = "../../../tests/alsa/booth.rs"]
mod booth;

use std::time::Duration;

use mouthpiece_capture::alsa::{AlsaRequest, AlsaSource};
use mouthpiece_frame::{AudioSource, SourceError};

fn request(device: &str, sample_rate: u32) -> AlsaRequest {
    AlsaRequest {
        device: device.into(),
        sample_rate,
        channels: 1,
        period_frames: 480,
        buffer_frames: 4800,
        stall_timeout: Duration::from_secs(2),
    }
}

/// Reads blocks until `frames` sample frames came; returns them and the blocks' first frames.
fn read(source: &mut AlsaSource, frames: usize) -> (Vec<i16>, Vec<u64>) {
    let mut samples = Vec::new();
    let mut firsts = Vec::new();
    while samples.len() < frames {
        let block = source.next_block().unwrap().unwrap();
        assert_eq!(block.format, source.info().format);
        firsts.push(block.first_frame);
        samples.extend_from_slice(&block.samples);
    }
    (samples, firsts)
}

#[test]
fn the_microphone_through_real_alsa() {
    let dir = tempfile::tempdir().unwrap();
    let speech = booth::festival("Hello from the booth.", dir.path());
    let mut booth = booth::Booth::start(&speech);
    for (k, v) in booth.env() {
        std::env::set_var(k, v);
    }

    // The sound arrives bit for bit, in the format asked for, in gap-free blocks.
    let mut source = AlsaSource::open(&request("booth", 48_000)).unwrap();
    assert_eq!(
        (
            source.info().format.sample_rate,
            source.info().format.channels
        ),
        (48_000, 1)
    );
    assert!(source.info().live);
    let (samples, firsts) = read(&mut source, speech.len());
    assert_eq!(&samples[..speech.len()], &speech[..], "bit-exact capture");
    let period = u64::from(source.info().frames_per_block);
    assert!(firsts.windows(2).all(|w| w[1] - w[0] == period), "no gap");
    assert_eq!(source.overruns(), 0);
    drop(source);

    // A device that agrees to another format and rate than asked (JACK delivers FLOAT_LE
    // at 48 kHz only): the agreed rate is read back and the samples are converted.
    let mut source = AlsaSource::open(&request("booth_float", 44_100)).unwrap();
    assert_eq!(
        source.info().format.sample_rate,
        48_000,
        "read back, not assumed"
    );
    assert!(
        source.info().description.contains("converted to S16"),
        "{}",
        source.info().description
    );
    let (samples, _) = read(&mut source, speech.len());
    let worst = samples
        .iter()
        .zip(&speech)
        .map(|(a, b)| (i32::from(*a) - i32::from(*b)).abs())
        .max()
        .unwrap();
    assert!(worst <= 1, "float → 16 bits within one step: {worst}");

    // A device that does not exist is an open error naming it.
    let Err(err) = AlsaSource::open(&request("no_such_booth", 48_000)) else {
        panic!("opened a device that does not exist");
    };
    assert!(matches!(err, SourceError::Open { .. }), "{err}");
    assert!(err.to_string().contains("no_such_booth"), "{err}");

    // The device's clock stops (the JACK server dies): reported lost, not a hang.
    booth.pull_the_plug();
    let lost = loop {
        match source.next_block() {
            Ok(Some(_)) => continue,
            Ok(None) => panic!("a device does not end"),
            Err(e) => break e,
        }
    };
    assert!(lost.is_retryable(), "{lost}");
}
