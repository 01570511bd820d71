//! The audio thread: opens the microphone (or a replayed recording's sound), stamps every
//! block with the wall clock the frames use, measures its level for the console, and offers
//! it to every consumer through the [`AudioBus`] (one bounded drop-oldest queue per
//! consumer: the take writer, the live speech analyser). A device that cannot be opened or
//! is lost is reported (log, `status`, `/healthz`, systemd's status line) and reopened with
//! the source's backoff. It never waits for a consumer or for video, and nothing waits for it.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime};

use mouthpiece_frame::{AudioBlock, AudioBus, AudioEvent, AudioSource, SourceError};
use mouthpiece_output::Throttle;
use mouthpiece_server::{AudioCounters, AudioState, AudioStatus, Hub, SILENCE_DBFS};

use crate::backoff::Backoff;
use crate::source::{catch_panic, error_chain};

/// Opens the audio source; called again after every loss.
pub type AudioOpener = Box<dyn FnMut() -> Result<Box<dyn AudioSource>, SourceError> + Send>;

/// A sample at or above this magnitude is a clip (−1 dBFS of 32768).
pub const CLIP_LEVEL: i32 = 29_205;
/// The RMS level's window.
pub const LEVEL_WINDOW: Duration = Duration::from_millis(100);
/// How long the peak and the clip warning hold.
pub const PEAK_HOLD: Duration = Duration::from_secs(2);

/// The level meter of the console: RMS over the last [`LEVEL_WINDOW`], peak and clip over
/// the last [`PEAK_HOLD`], all counted in sample frames (not host time), so a late thread
/// does not bend the figures.
#[derive(Debug, Default)]
pub struct Meter {
    /// Per block: (frames, sum of squares over all channels / channels).
    level: VecDeque<(u64, f64)>,
    /// Per block: (end frame, peak magnitude).
    peaks: VecDeque<(u64, i32)>,
    end: u64,
}

impl Meter {
    pub fn reset(&mut self) {
        *self = Meter::default();
    }

    pub fn add(&mut self, block: &AudioBlock) {
        let frames = block.frames();
        let rate = u64::from(block.format.sample_rate.max(1));
        let channels = f64::from(block.format.channels.max(1));
        let (mut sum, mut peak) = (0.0f64, 0i32);
        for &s in &block.samples {
            let v = f64::from(s);
            sum += v * v;
            peak = peak.max(i32::from(s).abs());
        }
        self.end = block.first_frame + frames;
        self.level.push_back((frames, sum / channels));
        let window = rate * LEVEL_WINDOW.as_millis() as u64 / 1000;
        while self.level.len() > 1 && self.level.iter().skip(1).map(|l| l.0).sum::<u64>() >= window
        {
            self.level.pop_front();
        }
        self.peaks.push_back((self.end, peak));
        let hold = rate * PEAK_HOLD.as_millis() as u64 / 1000;
        while self
            .peaks
            .front()
            .is_some_and(|(end, _)| end + hold < self.end)
        {
            self.peaks.pop_front();
        }
    }

    /// (level dBFS, peak dBFS, clip), rounded to 0.1 dB.
    pub fn figures(&self) -> (f64, f64, bool) {
        let frames: u64 = self.level.iter().map(|l| l.0).sum();
        let sum: f64 = self.level.iter().map(|l| l.1).sum();
        let level = if frames == 0 {
            SILENCE_DBFS
        } else {
            dbfs((sum / frames as f64).sqrt())
        };
        let peak = self.peaks.iter().map(|p| p.1).max().unwrap_or(0);
        (level, dbfs(f64::from(peak)), peak >= CLIP_LEVEL)
    }
}

/// `magnitude` of a 16-bit sample in dBFS, rounded to 0.1 dB, at least [`SILENCE_DBFS`].
pub fn dbfs(magnitude: f64) -> f64 {
    if magnitude <= 0.0 {
        return SILENCE_DBFS;
    }
    let db = 20.0 * (magnitude / 32768.0).log10();
    ((db * 10.0).round() / 10.0).clamp(SILENCE_DBFS, 0.0)
}

/// The audio thread's outside: its bus, its counters, its stop flag.
#[derive(Debug)]
pub struct AudioShared {
    pub bus: Arc<AudioBus>,
    pub counters: Arc<AudioCounters>,
    stop: AtomicBool,
}

impl AudioShared {
    pub fn new(counters: Arc<AudioCounters>) -> Arc<AudioShared> {
        Arc::new(AudioShared {
            bus: AudioBus::new(),
            counters,
            stop: AtomicBool::new(false),
        })
    }

    pub fn stop(&self) {
        self.stop.store(true, Ordering::Release);
    }

    pub fn is_stopping(&self) -> bool {
        self.stop.load(Ordering::Acquire)
    }
}

/// How the audio thread runs.
pub struct AudioPlan {
    pub opener: AudioOpener,
    /// The device or `replay:FILE`, for status and logs.
    pub device: String,
    /// `Live` for a microphone, `Replay` for a recording's sound.
    pub state_when_up: AudioState,
    pub backoff: Backoff,
    pub throttle: Duration,
}

/// Starts the audio thread.
pub fn spawn(
    plan: AudioPlan,
    shared: Arc<AudioShared>,
    hub: Hub,
) -> std::io::Result<JoinHandle<()>> {
    std::thread::Builder::new()
        .name("mouthpiece-audio".into())
        .spawn(move || run(plan, &shared, &hub))
}

fn run(mut plan: AudioPlan, shared: &AudioShared, hub: &Hub) {
    let mut open_failures = Throttle::new(plan.throttle);
    let mut overruns_before = 0u64;
    let device = plan.device.clone();
    publish(
        hub,
        shared,
        |a| {
            a.state = AudioState::NoDevice;
            a.device = device.clone();
        },
        Some("opening the audio device".into()),
    );
    while !shared.is_stopping() {
        shared
            .counters
            .reopen_attempts
            .fetch_add(1, Ordering::Relaxed);
        let opened = catch_panic(&mut plan.opener).unwrap_or_else(|panic| {
            Err(SourceError::Open {
                spec: device.clone(),
                message: format!("the audio source panicked while opening: {panic}"),
                cause: None,
            })
        });
        let reason = match opened {
            Ok(mut source) => {
                open_failures.reset();
                let info = source.info().clone();
                tracing::info!(device = %info.spec, description = %info.description, "audio source open");
                shared.bus.publish(AudioEvent::Started(info.clone()));
                let state = plan.state_when_up;
                publish(
                    hub,
                    shared,
                    |a| {
                        a.state = state;
                        a.device = info.spec.clone();
                        a.sample_rate = info.format.sample_rate;
                        a.channels = u32::from(info.format.channels);
                    },
                    None,
                );
                let (reason, delivered, frames, last_wall) =
                    catch_panic(|| pump(&mut *source, shared, hub, overruns_before))
                        .unwrap_or_else(|panic| {
                            (
                                Some(format!("the audio source panicked: {panic}")),
                                false,
                                0,
                                None,
                            )
                        });
                overruns_before += source.overruns();
                drop(source);
                if delivered {
                    plan.backoff.reset();
                }
                let Some(reason) = reason else { break };
                tracing::warn!(device = %device, "audio source lost: {reason}");
                shared.bus.publish(AudioEvent::Stopped {
                    reason: reason.clone(),
                    at: last_wall.unwrap_or_else(SystemTime::now),
                    frames,
                });
                reason
            }
            Err(err) => {
                let reason = error_chain(&err);
                if let Some(held_back) = open_failures.allow(Instant::now()) {
                    tracing::warn!(device = %device, held_back, "cannot open the audio device: {reason}");
                }
                reason
            }
        };
        let retry_in = plan.backoff.next_delay();
        let message = format!(
            "no microphone: {reason}; retrying in {:.1} s",
            retry_in.as_secs_f64()
        );
        publish(
            hub,
            shared,
            |a| {
                a.state = AudioState::NoDevice;
                a.level_dbfs = SILENCE_DBFS;
                a.peak_dbfs = SILENCE_DBFS;
                a.clip = false;
            },
            Some(message),
        );
        let until = Instant::now() + retry_in;
        while !shared.is_stopping() && Instant::now() < until {
            std::thread::sleep((until - Instant::now()).min(Duration::from_millis(50)));
        }
    }
    tracing::info!(device = %plan.device, "audio thread stopped");
}

/// Updates the `audio` object of `status` (and the message about it).
fn publish(
    hub: &Hub,
    shared: &AudioShared,
    change: impl FnOnce(&mut AudioStatus),
    message: Option<String>,
) {
    let overruns = shared.counters.overruns.load(Ordering::Relaxed);
    let dropped = shared.bus.dropped();
    hub.update_status(|s| {
        change(&mut s.audio);
        s.audio.overruns = overruns;
        s.audio.dropped_blocks = dropped;
        s.audio_message = message;
    });
}

/// Moves blocks to the bus until the source fails, ends or the daemon stops. Returns why
/// it stopped (`None`: the daemon stops), whether any block came, the sample frames
/// delivered and the wall-clock time just after the last one.
fn pump(
    source: &mut dyn AudioSource,
    shared: &AudioShared,
    hub: &Hub,
    overruns_before: u64,
) -> (Option<String>, bool, u64, Option<SystemTime>) {
    let mut meter = Meter::default();
    let mut delivered = false;
    let mut frames = 0u64;
    let mut last_wall = None;
    let mut next_meter_at = 0u64;
    loop {
        if shared.is_stopping() {
            return (None, delivered, frames, last_wall);
        }
        match source.next_block() {
            Ok(Some(mut block)) => {
                delivered = true;
                // The frames' clock: the wall clock at the host instant of the first sample.
                let first = block.first_sample_at();
                let wall = SystemTime::now() - first.elapsed();
                block.wall_clock = Some(wall);
                let span = block.format.duration_of(block.frames());
                frames = block.first_frame + block.frames();
                last_wall = Some(wall + span);
                meter.add(&block);
                let dropped = shared.bus.publish(AudioEvent::Block(Arc::new(block)));
                shared.counters.blocks.fetch_add(1, Ordering::Relaxed);
                shared
                    .counters
                    .dropped
                    .fetch_add(dropped, Ordering::Relaxed);
                shared
                    .counters
                    .overruns
                    .store(overruns_before + source.overruns(), Ordering::Relaxed);
                // The meter goes out about ten times a second of sound.
                if frames >= next_meter_at {
                    next_meter_at = frames + u64::from(source.info().format.sample_rate) / 10;
                    let (level, peak, clip) = meter.figures();
                    publish(
                        hub,
                        shared,
                        |a| {
                            a.level_dbfs = level;
                            a.peak_dbfs = peak;
                            a.clip = clip;
                        },
                        None,
                    );
                }
            }
            Ok(None) => {
                return (
                    Some("the audio source ended".into()),
                    delivered,
                    frames,
                    last_wall,
                )
            }
            Err(err) => return (Some(error_chain(&err)), delivered, frames, last_wall),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mouthpiece_frame::{AudioFormat, AudioSourceInfo};

    fn block(first_frame: u64, samples: Vec<i16>) -> AudioBlock {
        AudioBlock {
            seq: 0,
            first_frame,
            format: AudioFormat {
                sample_rate: 1000,
                channels: 1,
            },
            samples,
            host_rx: Instant::now(),
            wall_clock: None,
        }
    }

    #[test]
    fn the_meter_measures_rms_holds_the_peak_and_flags_clips() {
        let mut meter = Meter::default();
        // Full-scale square wave: 0 dBFS RMS; 100 frames at 1 kHz = the whole window.
        let square: Vec<i16> = (0..100)
            .map(|i| if i % 2 == 0 { 32767 } else { -32767 })
            .collect();
        meter.add(&block(0, square));
        let (level, peak, clip) = meter.figures();
        assert_eq!((level, peak, clip), (0.0, 0.0, true));
        // Half a second of a quiet signal (−20 dBFS): the level follows within the window,
        // the peak and the clip hold.
        for i in 0..5 {
            meter.add(&block(100 + i * 100, vec![3277; 100]));
        }
        let (level, peak, clip) = meter.figures();
        assert_eq!(level, -20.0);
        assert_eq!((peak, clip), (0.0, true));
        // Past the two-second hold the peak is the quiet signal's.
        for i in 5..30 {
            meter.add(&block(100 + i * 100, vec![3277; 100]));
        }
        let (_, peak, clip) = meter.figures();
        assert_eq!((peak, clip), (-20.0, false));
        assert_eq!(dbfs(0.0), SILENCE_DBFS);
    }

    /// A scripted device: `blocks` blocks, then lost.
    struct Scripted {
        info: AudioSourceInfo,
        left: u32,
        at: u64,
    }

    impl AudioSource for Scripted {
        fn info(&self) -> &AudioSourceInfo {
            &self.info
        }
        fn next_block(&mut self) -> Result<Option<AudioBlock>, SourceError> {
            std::thread::sleep(Duration::from_millis(1));
            if self.left == 0 {
                return Err(SourceError::Disconnected {
                    spec: "test".into(),
                    message: "unplugged".into(),
                    cause: None,
                });
            }
            self.left -= 1;
            let b = block(self.at, vec![1000; 10]);
            self.at += 10;
            Ok(Some(b))
        }
        fn overruns(&self) -> u64 {
            1
        }
    }

    #[test]
    fn a_lost_device_is_reported_and_reopened_and_consumers_hear_where_it_stopped() {
        let (hub, _control) = Hub::new(&mouthpiece_server::HubConfig::default());
        let shared = AudioShared::new(hub.audio_counters());
        let events = shared.bus.subscribe(10_000);
        let mut attempt = 0;
        let opener: AudioOpener = Box::new(move || {
            attempt += 1;
            // Opens on attempts 1 and 3 only, so the counts below do not depend on when
            // the test stops the thread.
            if attempt != 1 && attempt != 3 {
                return Err(SourceError::Open {
                    spec: "test".into(),
                    message: "no such device".into(),
                    cause: None,
                });
            }
            Ok(Box::new(Scripted {
                info: AudioSourceInfo {
                    spec: "test".into(),
                    description: "scripted".into(),
                    format: AudioFormat {
                        sample_rate: 1000,
                        channels: 1,
                    },
                    frames_per_block: 10,
                    live: true,
                },
                left: 5,
                at: 0,
            }))
        });
        let ms = Duration::from_millis;
        let thread = spawn(
            AudioPlan {
                opener,
                device: "test".into(),
                state_when_up: AudioState::Live,
                backoff: Backoff::new(ms(1), ms(2)),
                throttle: ms(1000),
            },
            shared.clone(),
            hub.clone(),
        )
        .unwrap();
        // Open, 5 blocks, lost; cannot open; open, 5 blocks, lost.
        let mut seen = Vec::new();
        let deadline = Instant::now() + Duration::from_secs(20);
        while seen
            .iter()
            .filter(|e| matches!(e, AudioEvent::Stopped { .. }))
            .count()
            < 2
            && Instant::now() < deadline
        {
            if let Ok(e) = events.events.recv_timeout(ms(50)) {
                seen.push(e);
            }
        }
        shared.stop();
        thread.join().unwrap();
        let kinds: Vec<&str> = seen
            .iter()
            .map(|e| match e {
                AudioEvent::Started(_) => "started",
                AudioEvent::Block(_) => "block",
                AudioEvent::Stopped { .. } => "stopped",
            })
            .collect();
        let once = [
            "started", "block", "block", "block", "block", "block", "stopped",
        ];
        assert_eq!(kinds, [once, once].concat());
        let AudioEvent::Stopped { frames, reason, .. } = &seen[6] else {
            unreachable!()
        };
        assert_eq!(*frames, 50);
        assert!(reason.contains("unplugged"), "{reason}");
        let c = hub.audio_counters();
        assert_eq!(c.blocks.load(Ordering::Relaxed), 10);
        assert!(c.reopen_attempts.load(Ordering::Relaxed) >= 3);
        assert_eq!(
            c.overruns.load(Ordering::Relaxed),
            2,
            "one per opening, summed"
        );
        let status = hub.status();
        assert_eq!(status.audio.device, "test");
        assert_eq!(status.audio.sample_rate, 1000);
        assert!(
            status.audio.state == AudioState::NoDevice || status.audio.state == AudioState::Live
        );
        assert!(matches!(&seen[7], AudioEvent::Started(_)));
    }
}
