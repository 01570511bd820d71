//! The LTC thread (`[timecode] source = "ltc"`): reads one channel of the booth's audio from
//! the [`AudioBus`](mouthpiece_frame::AudioBus) (its own bounded drop-oldest queue, like the
//! take writer's), decodes the studio's linear timecode with `mouthpiece-ltc`, and feeds the
//! hub's [`TimecodeClock`] each frame with the wall-clock time it ended at. Every published
//! frame's timecode is read from that clock, so takes, Broadcast WAV and every output carry
//! the studio's time.
//!
//! The wall-clock time of a sample comes from its block's `wall_clock` (the same clock the
//! video frames use) plus its position in the block at the agreed sample rate. A new source
//! (the device reopened, its sample count back at zero) starts a new decoder; the clock keeps
//! its lock and free-runs until the LTC is read again. Nothing waits for this thread: the
//! hub only reads the clock.

use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use mouthpiece_frame::{AudioBlock, AudioEvent, AudioSubscription};
use mouthpiece_ltc::channel::Block;
use mouthpiece_ltc::{ChannelDecoder, Decoded, LtcRate};
use mouthpiece_server::timecode_clock::{ClockState, TimecodeClock};
use mouthpiece_server::{Hub, Timecode, TimecodeRate};

use crate::audio::AudioShared;

/// Blocks the LTC thread's queue holds (about 2 s of 10 ms blocks): LTC read late is still
/// right, since each frame carries the time its samples were captured.
pub const LTC_QUEUE_BLOCKS: usize = 200;

/// How long the thread waits for sound before it checks the clock's state anyway.
const IDLE_TICK: Duration = Duration::from_millis(100);

/// The LTC decoder for a rate the server counts.
pub fn ltc_rate(rate: TimecodeRate) -> Option<LtcRate> {
    let (num, den) = rate.fraction();
    LtcRate::new(num as f64 / den as f64, rate.drop_frame())
}

/// Unix microseconds of `t`.
fn unix_micros(t: SystemTime) -> i64 {
    match t.duration_since(UNIX_EPOCH) {
        Ok(d) => d.as_micros() as i64,
        Err(e) => -(e.duration().as_micros() as i64),
    }
}

/// Decodes one channel of the audio stream's blocks into the clock. No thread of its own, so
/// the thread below and tests drive it alike.
pub struct LtcReader {
    reader: ChannelDecoder,
    clock: Arc<TimecodeClock>,
    /// Frames decoded since the start, for logs and tests.
    pub frames_read: u64,
    warned_channels: bool,
}

impl LtcReader {
    /// Reads channel `channel` (0-based) for `clock`; `None` when the clock's rate is not an
    /// LTC rate (the configuration refuses those).
    pub fn new(channel: usize, clock: Arc<TimecodeClock>) -> Option<LtcReader> {
        Some(LtcReader {
            reader: ChannelDecoder::new(channel, ltc_rate(clock.rate())?),
            clock,
            frames_read: 0,
            warned_channels: false,
        })
    }

    /// Forgets the stream (a source stopped or started): the next block starts a decoder.
    pub fn restart(&mut self) {
        self.reader.restart();
    }

    /// Decodes `block`, tells the clock each LTC frame and the time the block ends; returns
    /// the labels decoded.
    pub fn block(&mut self, block: &AudioBlock) -> &[Decoded] {
        let format = block.format;
        let channels = usize::from(format.channels);
        if format.sample_rate == 0 || channels == 0 {
            return &[];
        }
        if self.reader.channel() >= channels {
            if !self.warned_channels {
                tracing::warn!(
                    channel = self.reader.channel() + 1,
                    channels,
                    "the audio device delivers fewer channels than the LTC channel: no LTC"
                );
                self.warned_channels = true;
            }
            return &[];
        }
        self.reader.block(&Block {
            samples: &block.samples,
            sample_rate: format.sample_rate,
            channels: format.channels,
            first_frame: block.first_frame,
            first_wall_us: unix_micros(block.wall_clock.unwrap_or_else(SystemTime::now)),
        });
        for d in self.reader.decoded() {
            if d.reverse {
                // Played backwards: a label, but not a clock.
                continue;
            }
            let label = Timecode {
                hours: d.label.hours,
                minutes: d.label.minutes,
                seconds: d.label.seconds,
                frames: d.label.frames,
                drop_frame: d.label.drop_frame,
            };
            // The frame's label held until its last sample; the next begins one sample on.
            self.clock
                .observe(label, self.reader.wall_of(d.end_sample + 1));
            self.frames_read += 1;
        }
        if let Some(next) = self.reader.next_frame() {
            self.clock.tick(self.reader.wall_of(next));
        }
        self.reader.decoded()
    }
}

/// Starts the LTC thread on `events` (a subscription to the audio bus), reading channel
/// `channel` (0-based) into the hub's clock until the audio thread stops.
pub fn spawn(
    channel: usize,
    events: AudioSubscription,
    audio: Arc<AudioShared>,
    hub: Hub,
) -> std::io::Result<JoinHandle<()>> {
    let clock = hub.timecode_clock();
    let Some(reader) = LtcReader::new(channel, clock) else {
        return Err(std::io::Error::other(format!(
            "timecode rate {} is not an LTC rate",
            hub.timecode_clock().rate()
        )));
    };
    std::thread::Builder::new()
        .name("mouthpiece-ltc".into())
        .spawn(move || run(reader, &events, &audio, &hub))
}

fn run(mut reader: LtcReader, events: &AudioSubscription, audio: &AudioShared, hub: &Hub) {
    let clock = reader.clock.clone();
    let mut shown = clock.state();
    tracing::info!(channel = reader.reader.channel() + 1, rate = %clock.rate(), "LTC thread started");
    while !audio.is_stopping() {
        match events.events.recv_timeout(IDLE_TICK) {
            Ok(AudioEvent::Block(block)) => {
                reader.block(&block);
            }
            Ok(AudioEvent::Started(_) | AudioEvent::Stopped { .. }) => reader.restart(),
            Err(crossbeam_channel::RecvTimeoutError::Timeout) => {
                // No sound at all (the device is lost): the clock free-runs all the same.
                clock.tick(unix_micros(SystemTime::now()));
            }
            Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
        }
        let state = clock.state();
        if state != shown {
            match state {
                ClockState::Locked => tracing::info!("timecode locked to LTC"),
                ClockState::FreeRunning => {
                    tracing::warn!("timecode free-running: no LTC on the input")
                }
                _ => {}
            }
            shown = state;
            let status = clock.status();
            hub.update_status(|s| s.timecode = status);
        }
    }
    tracing::info!(frames = reader.frames_read, "LTC thread stopped");
}

#[cfg(test)]
mod tests {
    use super::*;
    use mouthpiece_frame::{AudioFormat, AudioSourceInfo};
    use mouthpiece_ltc::{Encoder, Label};
    use mouthpiece_server::HubConfig;

    /// The thread reads channel 2 of the bus's blocks into the hub's clock and shows the
    /// state in `status`; frames published after the lock carry the LTC's labels.
    #[test]
    fn the_thread_locks_the_hubs_clock_and_shows_it_in_status() {
        let (hub, _control) = Hub::new(&HubConfig {
            timecode_rate: TimecodeRate::Fps30,
            timecode_ltc: true,
            ..HubConfig::default()
        });
        assert_eq!(hub.status().timecode.state, ClockState::Lost);
        let audio = AudioShared::new(hub.audio_counters());
        let thread = spawn(
            1,
            audio.bus.subscribe(LTC_QUEUE_BLOCKS),
            audio.clone(),
            hub.clone(),
        )
        .unwrap();
        let format = AudioFormat {
            sample_rate: 48_000,
            channels: 2,
        };
        audio.bus.publish(AudioEvent::Started(AudioSourceInfo {
            spec: "test".into(),
            description: "scripted".into(),
            format,
            frames_per_block: 480,
            live: true,
        }));
        let start = Label {
            hours: 1,
            ..Label::default()
        };
        let mut encoder = Encoder::new(48_000, ltc_rate(TimecodeRate::Fps30).unwrap(), start);
        let mut ltc = Vec::new();
        for _ in 0..30 {
            encoder.frame(&mut ltc);
        }
        // Sound stamped an hour ahead: the thread's idle ticks (the host's now) never find the
        // LTC stale, however slowly this test runs.
        let t0 = SystemTime::now() + Duration::from_secs(3600);
        for (i, chunk) in ltc.chunks(480).enumerate() {
            let samples = chunk.iter().flat_map(|s| [0, *s]).collect();
            audio.bus.publish(AudioEvent::Block(Arc::new(AudioBlock {
                seq: i as u64,
                first_frame: i as u64 * 480,
                format,
                samples,
                host_rx: std::time::Instant::now(),
                wall_clock: Some(t0 + Duration::from_millis(10 * i as u64)),
            })));
        }
        let deadline = std::time::Instant::now() + Duration::from_secs(60);
        while hub.status().timecode.state != ClockState::Locked {
            assert!(
                std::time::Instant::now() < deadline,
                "{:?}",
                hub.status().timecode
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        // A frame captured half a second (15 frames) in is published as 01:00:00:15.
        let mut published = hub.subscribe_frames();
        let wall = unix_micros(t0 + Duration::from_micros(500_000 + 100));
        hub.publish(&mouthpiece_server::StreamFrame {
            wall_us: Some(wall),
            ..Default::default()
        });
        let frame = published.try_recv().unwrap();
        assert_eq!(frame.timecode.to_string(), "01:00:00:15");
        audio.stop();
        thread.join().unwrap();
    }
}
