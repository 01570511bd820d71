//! The studio's LTC through a real ALSA capture PCM (tests/alsa: the `file` plugin streaming a
//! two-channel file, paced by JACK's dummy driver): a tone stands for the microphone on
//! channel 1, libltc's encoder writes 25 fps LTC on channel 2 with a dropout (noise) and a
//! jump. The daemon's audio thread reads the device; the LTC reader decodes channel 2 into the
//! hub's clock, and frames published through the hub carry the LTC's time to the frame.
//! One test function: ALSA reads its configuration path once per process.

#[path = "../../../tests/alsa/booth.rs"]
mod booth;

use std::path::Path;
use std::time::{Duration, Instant};

use mouthpiece_config::Config;
use mouthpiece_daemon::audio::{spawn, AudioShared};
use mouthpiece_daemon::ltc::{ltc_rate, LtcReader};
use mouthpiece_frame::AudioEvent;
use mouthpiece_ltc::{Encoder, Label};
use mouthpiece_server::timecode_clock::ClockState;
use mouthpiece_server::{Hub, HubConfig, StreamFrame, Timecode, TimecodeRate};

const RATE: usize = 48_000;

fn label(h: u8, m: u8, s: u8, f: u8) -> Label {
    Label {
        hours: h,
        minutes: m,
        seconds: s,
        frames: f,
        drop_frame: false,
    }
}

/// What channel 2 carries at each sample: `Some((label, first sample, end sample))` per
/// encoded frame; the segments' bounds for the checks.
struct Timeline {
    frames: Vec<(Label, u64, u64)>,
    /// Where the noise starts and ends, and where the jump's first frame starts.
    noise: (u64, u64),
    jump_at: u64,
}

impl Timeline {
    fn label_at(&self, sample: u64) -> Option<(Label, u64)> {
        self.frames
            .iter()
            .find(|(_, start, end)| (*start..=*end).contains(&sample))
            .map(|(l, start, end)| (*l, (sample - start).min(end - sample)))
    }
}

/// Interleaved stereo: a quiet 440 Hz tone on 1, LTC on 2: 0.5 s silence, 10:00:00:00 for
/// 4 s, 2 s of noise, LTC again where it would have been (10:00:06:00) for 2 s, a jump to
/// 14:00:00:00 for 3 s, 1 s of silence.
fn booth_audio() -> (Vec<i16>, Timeline) {
    let rate = ltc_rate(TimecodeRate::Fps25).unwrap();
    let mut ltc: Vec<i16> = vec![0; RATE / 2];
    let mut frames = Vec::new();
    let mut run = |ltc: &mut Vec<i16>, start: Label, count: usize| {
        let mut encoder = Encoder::new(RATE as u32, rate, start);
        for _ in 0..count {
            let l = encoder.label();
            let first = ltc.len() as u64;
            encoder.frame(ltc);
            frames.push((l, first, ltc.len() as u64 - 1));
        }
    };
    run(&mut ltc, label(10, 0, 0, 0), 100);
    let noise_start = ltc.len() as u64;
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    for _ in 0..RATE * 2 {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        ltc.push(((state >> 48) as i16) / 3);
    }
    let noise = (noise_start, ltc.len() as u64);
    run(&mut ltc, label(10, 0, 6, 0), 50);
    let jump_at = ltc.len() as u64;
    run(&mut ltc, label(14, 0, 0, 0), 75);
    ltc.extend_from_slice(&[0; RATE]);
    let mut stereo = Vec::with_capacity(ltc.len() * 2);
    for (i, s) in ltc.iter().enumerate() {
        let tone = 2_000.0 * (2.0 * std::f64::consts::PI * 440.0 * i as f64 / RATE as f64).sin();
        stereo.push(tone as i16);
        stereo.push(*s);
    }
    (
        stereo,
        Timeline {
            frames,
            noise,
            jump_at,
        },
    )
}

#[test]
fn the_studios_ltc_through_real_alsa_stamps_the_frames() {
    let (audio, timeline) = booth_audio();
    let total_frames = (audio.len() / 2) as u64;
    let booth = booth::Booth::start(&audio);
    for (k, v) in booth.env() {
        std::env::set_var(k, v);
    }

    // The daemon's own configuration path: [audio] with two channels, LTC on the second.
    let config = Config::parse(
        "[audio]\ndevice = \"booth2\"\nchannels = 2\n\
         [timecode]\nrate = \"25\"\nsource = \"ltc\"\nchannel = 2\n",
        Path::new("/etc/mouthpiece/booth.toml"),
    )
    .unwrap();
    let (hub, _control) = Hub::new(&HubConfig {
        timecode_rate: TimecodeRate::Fps25,
        timecode_ltc: true,
        ..HubConfig::default()
    });
    let mut published = hub.subscribe_frames();
    let shared = AudioShared::new(hub.audio_counters());
    let events = shared.bus.subscribe(10_000);
    let plan = mouthpiece_daemon::capture::audio_plan(&config).unwrap();
    let thread = spawn(plan, shared.clone(), hub.clone()).unwrap();
    let clock = hub.timecode_clock();
    let channel = config.timecode.channel.unwrap() as usize - 1;
    let mut reader = LtcReader::new(channel, clock.clone()).unwrap();
    assert_eq!(clock.state(), ClockState::Lost, "no LTC read yet");

    let mut decoded = Vec::new();
    let mut states: Vec<(u64, ClockState)> = Vec::new();
    let mut checked = [0usize; 3];
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut end = 0u64;
    while end < total_frames {
        assert!(
            Instant::now() < deadline,
            "the booth's sound did not all come"
        );
        let event = events
            .events
            .recv_timeout(Duration::from_secs(30))
            .expect("sound from the booth");
        let AudioEvent::Block(block) = event else {
            continue;
        };
        assert_eq!(block.format.channels, 2);
        for d in reader.block(&block) {
            decoded.push(*d);
        }
        end = block.first_frame + block.frames();
        states.push((end, clock.state()));

        // A frame published at the wall-clock time of the block's middle sample carries the
        // label the LTC line held at that sample (or would have held, through the dropout).
        let mid = block.first_frame + block.frames() / 2;
        let first_wall = block
            .wall_clock
            .unwrap()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_micros() as i64;
        let wall = first_wall + ((mid - block.first_frame) * 1_000_000 / RATE as u64) as i64;
        hub.publish(&StreamFrame {
            wall_us: Some(wall),
            ..StreamFrame::default()
        });
        let frame = published.try_recv().expect("the frame just published");
        let want = if (timeline.noise.0..timeline.noise.1).contains(&mid) {
            // Free-running: 10:00:04:00 onwards as if the LTC had run on (1920 samples a frame).
            let since = mid - timeline.noise.0;
            let frames = (since / 1920) as u8;
            let margin = (since % 1920).min(1920 - since % 1920);
            Some((label(10, 0, 4 + frames / 25, frames % 25), margin))
        } else {
            timeline.label_at(mid)
        };
        let Some((want, margin)) = want else { continue };
        // Skip the first 3 frames of a segment (the lock needs them) and instants a few
        // samples from a frame boundary (the host clock's microsecond rounding).
        let settled = clock.state() != ClockState::Lost
            && !(timeline.jump_at..timeline.jump_at + 4 * 1920).contains(&mid);
        if settled && margin > 5 {
            let want = Timecode {
                hours: want.hours,
                minutes: want.minutes,
                seconds: want.seconds,
                frames: want.frames,
                drop_frame: false,
            };
            assert_eq!(frame.timecode, want, "published frame at sample {mid}");
            let segment = if mid < timeline.noise.0 {
                0
            } else if mid < timeline.jump_at {
                1
            } else {
                2
            };
            checked[segment] += 1;
        }
    }
    shared.stop();
    thread.join().unwrap();

    // Every LTC frame decoded is one that was encoded, where it was encoded, and none is
    // missing after the first of each run.
    let mut worst = 0;
    for d in &decoded {
        let found = timeline
            .frames
            .iter()
            .find(|(l, _, _)| *l == d.label)
            .unwrap_or_else(|| panic!("decoded {} was never encoded", d.label));
        // The last frame before the noise ends where the noise's first edge lets libltc see
        // it: within 1 ms; every other within 2 samples.
        let allowed = if found.2 + 1 == timeline.noise.0 {
            48
        } else {
            2
        };
        worst = worst.max(d.end_sample.abs_diff(found.2));
        assert!(
            d.end_sample.abs_diff(found.2) <= allowed,
            "{}: ended at {}, encoded to {}",
            d.label,
            d.end_sample,
            found.2
        );
    }
    assert!(
        decoded.len() >= timeline.frames.len() - 3,
        "{} of {} frames decoded",
        decoded.len(),
        timeline.frames.len()
    );
    assert!(
        !decoded
            .iter()
            .any(|d| (timeline.noise.0 + 2_000..timeline.noise.1).contains(&d.end_sample)),
        "noise read as timecode"
    );

    // States: lost until the first lock, locked, free-running in the noise, locked again.
    let state_at = |sample: u64| {
        states
            .iter()
            .find(|(end, _)| *end >= sample)
            .map(|s| s.1)
            .unwrap()
    };
    assert_eq!(state_at(RATE as u64 / 4), ClockState::Lost);
    assert_eq!(state_at(RATE as u64 * 3), ClockState::Locked);
    assert_eq!(
        state_at(timeline.noise.0 + RATE as u64),
        ClockState::FreeRunning,
        "LTC turned to noise"
    );
    assert_eq!(state_at(timeline.noise.1 + RATE as u64), ClockState::Locked);
    assert_eq!(state_at(timeline.jump_at + RATE as u64), ClockState::Locked);
    assert_eq!(clock.health_json()["jumps"], 1, "{}", clock.health_json());
    // The status clients see says the same.
    assert_eq!(hub.status().timecode.source, "ltc");
    // Frames were checked in each part: before the dropout, through it and after, after the
    // jump.
    assert!(checked.iter().all(|&n| n > 20), "{checked:?}");
    println!(
        "decoded {} of {} LTC frames, ends within {worst} samples; published frames checked: {checked:?}",
        decoded.len(),
        timeline.frames.len()
    );
}
