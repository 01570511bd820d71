use super::*;

const RATE: u32 = 48_000;

fn rates() -> [(&'static str, LtcRate); 5] {
    [
        ("23.976", LtcRate::new(24_000.0 / 1001.0, false).unwrap()),
        ("24", LtcRate::new(24.0, false).unwrap()),
        ("25", LtcRate::new(25.0, false).unwrap()),
        ("29.97df", LtcRate::new(30_000.0 / 1001.0, true).unwrap()),
        ("30", LtcRate::new(30.0, false).unwrap()),
    ]
}

fn label(h: u8, m: u8, s: u8, f: u8, drop_frame: bool) -> Label {
    Label {
        hours: h,
        minutes: m,
        seconds: s,
        frames: f,
        drop_frame,
    }
}

/// The label after `l`, counted from the SMPTE rules (not libltc's code).
fn next(l: Label, rate: LtcRate) -> Label {
    let mut n = l;
    n.frames += 1;
    if n.frames == rate.nominal {
        n.frames = 0;
        n.seconds += 1;
        if n.seconds == 60 {
            n.seconds = 0;
            n.minutes += 1;
            if n.minutes == 60 {
                n.minutes = 0;
                n.hours = (n.hours + 1) % 24;
            }
        }
    }
    if rate.drop_frame && n.seconds == 0 && n.frames < 2 && !n.minutes.is_multiple_of(10) {
        n.frames = 2;
    }
    n
}

/// `frames` LTC frames from `start`; returns the audio and each frame's label and end.
fn encode(rate: LtcRate, start: Label, frames: usize) -> (Vec<i16>, Vec<(Label, u64)>) {
    let mut encoder = Encoder::new(RATE, rate, start);
    let mut audio = Vec::new();
    let mut labels = Vec::new();
    for _ in 0..frames {
        let l = encoder.label();
        encoder.frame(&mut audio);
        labels.push((l, audio.len() as u64 - 1));
    }
    (audio, labels)
}

fn decode(rate: LtcRate, audio: &[i16], block: usize) -> (Vec<Decoded>, u64) {
    let mut decoder = Decoder::new(RATE, rate);
    let mut out = Vec::new();
    for (i, chunk) in audio.chunks(block).enumerate() {
        decoder.write(chunk, (i * block) as u64, &mut out);
    }
    (out, decoder.refused())
}

#[test]
fn every_rate_decodes_to_the_frame_across_a_minute() {
    for (name, rate) in rates() {
        // Start a second before a minute that is not a tenth: drop-frame skips labels there.
        let start = label(10, 0, 59, rate.nominal - 5, rate.drop_frame);
        let (audio, labels) = encode(rate, start, 60);
        // The encoder counts as SMPTE does.
        for w in labels.windows(2) {
            assert_eq!(w[1].0, next(w[0].0, rate), "{name}: encoder count");
        }
        if rate.drop_frame {
            assert!(
                labels.iter().any(|(l, _)| *l == label(10, 1, 0, 2, true)),
                "{name}: 10:01:00;02 follows 10:00:59;29"
            );
        }
        let samples_per_frame = f64::from(RATE) / rate.fps;
        assert!(
            (audio.len() as f64 / 60.0 - samples_per_frame).abs() < 1.0,
            "{name}: {} samples for 60 frames",
            audio.len()
        );
        let (decoded, refused) = decode(rate, &audio, 480);
        assert_eq!(refused, 0, "{name}");
        // libltc recognises a frame by the sync word at its end, so the first is found too.
        assert!(
            decoded.len() >= labels.len() - 1,
            "{name}: {}",
            decoded.len()
        );
        for d in &decoded {
            let (want, end) = labels
                .iter()
                .find(|(l, _)| *l == d.label)
                .unwrap_or_else(|| panic!("{name}: decoded {} was never encoded", d.label));
            assert!(
                d.end_sample.abs_diff(*end) <= 2,
                "{name}: {want} ended at {end}, decoded {}",
                d.end_sample
            );
            assert!(!d.reverse);
        }
        // In order, none missing once the first was found.
        for w in decoded.windows(2) {
            assert_eq!(w[1].label, next(w[0].label, rate), "{name}");
        }
    }
}

#[test]
fn ltc_at_another_rate_is_refused() {
    let [r23, r24, r25, _, r30] = rates().map(|r| r.1);
    for (sent, read) in [(r25, r30), (r30, r25), (r24, r25), (r25, r24), (r23, r25)] {
        let (audio, _) = encode(sent, label(1, 0, 0, 0, false), 50);
        let (decoded, refused) = decode(read, &audio, 480);
        assert!(
            decoded.is_empty(),
            "{} read as {}: {decoded:?}",
            sent.fps,
            read.fps
        );
        assert!(refused > 40, "{refused}");
    }
}

#[test]
fn block_size_does_not_change_what_is_decoded() {
    let rate = rates()[3].1;
    let (audio, _) = encode(rate, label(1, 2, 3, 4, true), 30);
    let (a, _) = decode(rate, &audio, 64);
    let (b, _) = decode(rate, &audio, 4096);
    assert_eq!(a, b);
}

#[test]
fn a_label_the_rate_does_not_have_is_invalid() {
    let df = rates()[3].1;
    let r25 = rates()[2].1;
    assert!(!label(0, 1, 0, 0, true).valid_at(df), "dropped label");
    assert!(
        label(0, 10, 0, 0, true).valid_at(df),
        "tenth minute keeps it"
    );
    assert!(!label(0, 0, 0, 25, false).valid_at(r25));
    assert!(!label(0, 0, 0, 3, true).valid_at(r25), "drop flag at 25");
    assert!(!label(24, 0, 0, 0, false).valid_at(r25));
    assert!(LtcRate::new(29.97, false).is_none());
    assert!(LtcRate::new(50.0, false).is_none());
}

#[test]
fn noise_is_not_timecode() {
    // White noise at three levels and a hum: a deterministic generator, so no run differs.
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut noise = |amplitude: f64| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        ((state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) * amplitude
    };
    for (name, rate) in rates() {
        let mut audio = Vec::new();
        for amplitude in [300.0, 8_000.0, 32_000.0] {
            audio.extend((0..RATE * 4).map(|_| noise(amplitude) as i16));
        }
        audio.extend((0..RATE * 2).map(|i| {
            (20_000.0
                * (2.0 * std::f64::consts::PI * 1_000.0 * f64::from(i) / f64::from(RATE)).sin())
                as i16
        }));
        let (decoded, _) = decode(rate, &audio, 480);
        assert!(decoded.is_empty(), "{name}: {decoded:?}");
    }
}
