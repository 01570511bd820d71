//! The tracker's session clock: seconds since the first frame, kept running forward across
//! source restarts.
//!
//! A source's device clock starts again when the source restarts (a replay reopened from its
//! beginning, a camera unplugged and plugged back in). The head stabiliser, the calibration
//! window and the retarget core all need a time that never decreases, so the clock splits
//! the device's timestamps into segments: a new segment starts when a timestamp goes
//! backwards, or when the owner says the source was reopened ([`SessionClock::restart`]), and
//! continues one frame interval after the previous segment's last frame.

/// The frame interval assumed before two frames have been seen, seconds (30 frames/s).
pub const DEFAULT_FRAME_INTERVAL_S: f64 = 1.0 / 30.0;

/// One frame's time on the session clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tick {
    /// Seconds since the session's first frame; never less than the previous tick's.
    pub t: f64,
    /// This frame starts a new segment (the source restarted): tracks made before it are
    /// not to be continued.
    pub restarted: bool,
}

/// See the module documentation.
#[derive(Debug, Clone, Default)]
pub struct SessionClock {
    /// The current segment's first device timestamp (µs) and its session time (s).
    origin: Option<(u64, f64)>,
    /// The last frame's device timestamp (µs) and session time (s).
    last: Option<(u64, f64)>,
    /// The last positive interval between frames, seconds.
    interval_s: f64,
    /// A restart was announced: the next frame starts a new segment.
    restart_pending: bool,
}

impl SessionClock {
    /// The session time of a frame with this device timestamp.
    pub fn tick(&mut self, device_ts_us: u64) -> Tick {
        let Some((origin_us, origin_t)) = self.origin else {
            self.origin = Some((device_ts_us, 0.0));
            self.last = Some((device_ts_us, 0.0));
            return Tick {
                t: 0.0,
                restarted: false,
            };
        };
        let (last_us, last_t) = self.last.expect("set with the origin");
        let backwards = device_ts_us < last_us;
        if backwards || self.restart_pending {
            self.restart_pending = false;
            let step = if self.interval_s > 0.0 {
                self.interval_s
            } else {
                DEFAULT_FRAME_INTERVAL_S
            };
            let t = last_t + step;
            self.origin = Some((device_ts_us, t));
            self.last = Some((device_ts_us, t));
            return Tick { t, restarted: true };
        }
        let t = origin_t + (device_ts_us - origin_us) as f64 * 1e-6;
        if t > last_t {
            self.interval_s = t - last_t;
        }
        self.last = Some((device_ts_us, t));
        Tick {
            t,
            restarted: false,
        }
    }

    /// The source was reopened: the next frame starts a new segment whatever its timestamp.
    pub fn restart(&mut self) {
        if self.origin.is_some() {
            self.restart_pending = true;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_runs_from_the_first_frame() {
        let mut c = SessionClock::default();
        assert_eq!(c.tick(5_000_000).t, 0.0);
        let t = c.tick(5_033_333);
        assert!((t.t - 0.033333).abs() < 1e-9 && !t.restarted);
    }

    #[test]
    fn a_clock_going_backwards_continues_one_interval_later() {
        let mut c = SessionClock::default();
        for i in 0..10u64 {
            c.tick(1_000_000 + i * 40_000);
        }
        let last = 9.0 * 0.04;
        let t = c.tick(0);
        assert!(t.restarted);
        assert!((t.t - (last + 0.04)).abs() < 1e-9, "{t:?}");
        let t = c.tick(40_000);
        assert!(!t.restarted);
        assert!((t.t - (last + 0.08)).abs() < 1e-9, "{t:?}");
    }

    #[test]
    fn an_announced_restart_starts_a_segment_even_when_time_jumps_ahead() {
        let mut c = SessionClock::default();
        c.tick(0);
        c.tick(33_333);
        c.restart();
        let t = c.tick(900_000_000);
        assert!(t.restarted && (t.t - 0.066666).abs() < 1e-6, "{t:?}");
        let t = c.tick(900_033_333);
        assert!(!t.restarted && (t.t - 0.099999).abs() < 1e-6, "{t:?}");
    }

    #[test]
    fn a_repeated_timestamp_is_the_same_moment() {
        let mut c = SessionClock::default();
        c.tick(0);
        c.tick(33_333);
        let t = c.tick(33_333);
        assert!(!t.restarted && (t.t - 0.033333).abs() < 1e-9);
    }
}
