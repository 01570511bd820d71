//! Pacing a replay at its recorded speed (× `speed=`), with jumps in the recording's clock
//! treated as discontinuities: a corrupt or spliced recording whose clock leaps ahead (by
//! 10^9 s, say) would otherwise make the replay wait that long for its next frame.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, Weak};
use std::time::{Duration, Instant};

/// Largest gap in the recording's clock between two frames that is waited out; a longer one
/// is logged and pacing starts again from the frame after it (its wait is skipped).
pub const MAX_GAP: Duration = Duration::from_secs(10);

/// When each frame of a replay is due.
#[derive(Debug, Clone)]
pub struct Pacer {
    speed: f64,
    /// (host instant, recording time ns) the waits are measured from.
    anchor: Option<(Instant, u64)>,
    last_ns: Option<u64>,
    /// Discontinuities seen (clock jumps past [`MAX_GAP`]).
    pub jumps: u64,
    /// Where each new anchor is published (for the recording's sound, paced with the frames).
    shared: Option<Arc<ReplayClock>>,
}

/// Where a replay's pacing is anchored: recording time `log_ns` is due at host instant `at`,
/// and later times `speed` times faster. A new anchor (a loop, a seek, a clock jump) bumps
/// `generation`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockAnchor {
    pub at: Instant,
    pub log_ns: u64,
    pub speed: f64,
    pub generation: u64,
}

impl ClockAnchor {
    /// The host instant recording time `t_ns` is due at (the anchor's for earlier times).
    pub fn due(&self, t_ns: u64) -> Instant {
        self.at
            + Duration::from_secs_f64(t_ns.saturating_sub(self.log_ns) as f64 / 1e9 / self.speed)
    }
}

/// A replay's pacing clock, shared by its frames (which set it) and its sound (which follows
/// it), so that a recording's audio is played at the instants its frames are.
#[derive(Debug, Default)]
pub struct ReplayClock {
    anchor: Mutex<Option<ClockAnchor>>,
    generation: AtomicU64,
}

impl ReplayClock {
    /// The clock of the replays of `path` in this process (one per file: the daemon replays
    /// a file once, as frames and as sound).
    pub fn for_path(path: &Path) -> Arc<ReplayClock> {
        static CLOCKS: Mutex<Option<HashMap<PathBuf, Weak<ReplayClock>>>> = Mutex::new(None);
        let key = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_owned());
        let mut clocks = CLOCKS.lock().unwrap_or_else(|p| p.into_inner());
        let clocks = clocks.get_or_insert_with(HashMap::new);
        clocks.retain(|_, c| c.strong_count() > 0);
        if let Some(clock) = clocks.get(&key).and_then(Weak::upgrade) {
            return clock;
        }
        let clock = Arc::new(ReplayClock::default());
        clocks.insert(key, Arc::downgrade(&clock));
        clock
    }

    fn set(&self, at: Instant, log_ns: u64, speed: f64) {
        let generation = self.generation.fetch_add(1, Ordering::AcqRel) + 1;
        *self.anchor.lock().unwrap_or_else(|p| p.into_inner()) = Some(ClockAnchor {
            at,
            log_ns,
            speed,
            generation,
        });
    }

    /// The current anchor, `None` before the first frame was paced.
    pub fn anchor(&self) -> Option<ClockAnchor> {
        *self.anchor.lock().unwrap_or_else(|p| p.into_inner())
    }
}

impl Pacer {
    /// `speed`: multiple of recorded speed, within the spec's limits (positive, finite).
    pub fn new(speed: f64) -> Pacer {
        Pacer {
            speed,
            anchor: None,
            last_ns: None,
            jumps: 0,
            shared: None,
        }
    }

    /// Publishes every anchor this pacer takes on `clock`.
    pub fn sharing(mut self, clock: Arc<ReplayClock>) -> Pacer {
        self.shared = Some(clock);
        self
    }

    /// Starts over: the next frame is due at once (after a seek or a loop).
    pub fn reset(&mut self) {
        self.anchor = None;
        self.last_ns = None;
    }

    /// How long to wait, from `now`, before handing out the frame recorded at `t_ns`.
    pub fn wait(&mut self, now: Instant, t_ns: u64, spec: &str) -> Duration {
        if let Some(last) = self.last_ns {
            if t_ns < last {
                // Looped, or a clock that went back: start again from here.
                self.anchor = None;
            } else if t_ns - last > MAX_GAP.as_nanos() as u64 {
                self.jumps += 1;
                tracing::warn!(
                    %spec,
                    gap_s = (t_ns - last) as f64 / 1e9,
                    max_gap_s = MAX_GAP.as_secs_f64(),
                    "the recording's clock jumps ahead between two frames; not waiting it out (pacing starts again from this frame)"
                );
                self.anchor = None;
            }
        }
        self.last_ns = Some(t_ns);
        if self.anchor.is_none() {
            if let Some(clock) = &self.shared {
                clock.set(now, t_ns, self.speed);
            }
        }
        let (anchor, anchor_ns) = *self.anchor.get_or_insert((now, t_ns));
        let due = anchor + Duration::from_secs_f64((t_ns - anchor_ns) as f64 / 1e9 / self.speed);
        due.saturating_duration_since(now)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Frames 1/30 s apart at half speed are due 1/15 s apart; a jump of 10^9 s in the
    /// recording's clock is not waited out, and pacing goes on from the frame after it.
    #[test]
    fn a_jump_in_the_recordings_clock_is_a_discontinuity_not_a_wait() {
        let mut pacer = Pacer::new(0.5);
        let t0 = Instant::now();
        let frame = 33_333_333u64;
        assert_eq!(pacer.wait(t0, 0, "test"), Duration::ZERO);
        let w = pacer.wait(t0, frame, "test");
        assert!(
            (w.as_secs_f64() - 2.0 * frame as f64 / 1e9).abs() < 1e-6,
            "{w:?}"
        );
        // A gap within the limit is waited out (9 s at half speed: 18 s).
        let w = pacer.wait(t0, frame + 9_000_000_000, "test");
        assert!((w.as_secs_f64() - 2.0 * (frame as f64 / 1e9 + 9.0)).abs() < 1e-6);
        let jump = 1_000_000_000 * 1_000_000_000u64;
        let after = frame + 9_000_000_000 + jump;
        assert_eq!(pacer.wait(t0, after, "test"), Duration::ZERO);
        assert_eq!(pacer.jumps, 1);
        let w = pacer.wait(t0, after + frame, "test");
        assert!(
            (w.as_secs_f64() - 2.0 * frame as f64 / 1e9).abs() < 1e-6,
            "{w:?}"
        );
        // Backwards (a loop): due at once.
        assert_eq!(pacer.wait(t0, 5, "test"), Duration::ZERO);
    }
}
