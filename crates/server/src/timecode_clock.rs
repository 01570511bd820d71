//! The clock every published frame's timecode is read from: the host's time of day
//! (`[timecode] source = "system"`), or the studio's LTC (`source = "ltc"`).
//!
//! With LTC, the daemon's LTC thread reports each decoded frame with the wall-clock time at
//! which it ended ([`TimecodeClock::observe`]). The latest agreeing one is the *lock*: LTC
//! label ↔ host time. A frame's timecode is a pure function of the lock and the frame's
//! wall-clock time ([`ltc_frame_at`]): the label that ran on the LTC line at that moment,
//! counted on from the lock at the rate. So when LTC stops or turns to noise nothing jumps:
//! the same function runs on from the last lock on the host clock (*free-running*), and the
//! error grows only with the drift between the host's clock and the studio's.
//!
//! A label that does not follow the lock (the generator was reset, a tape was cued) starts
//! a candidate; once [`CONFIRM_FRAMES`] consecutive frames agree with each other the clock
//! jumps to them. A lone odd frame (a click that looked like a sync word) is ignored.

use std::sync::Mutex;

use serde::{Deserialize, Serialize};

use crate::timecode::{FrameTime, Timecode, TimecodeRate};

/// Consecutive agreeing LTC frames needed to lock, or to follow a jump.
pub const CONFIRM_FRAMES: u32 = 3;

/// No agreeing LTC frame for this long (microseconds): the clock is free-running.
pub const LTC_TIMEOUT_US: i64 = 500_000;

/// Where the timecode comes from now.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ClockState {
    /// `source = "system"`: the host's time of day, UTC.
    #[default]
    System,
    /// LTC is read and agrees with itself.
    Locked,
    /// LTC stopped or turned to noise: counting on from the last lock on the host clock.
    FreeRunning,
    /// No LTC has been read since the daemon started: frames carry the host's time of day
    /// until it comes.
    Lost,
}

impl ClockState {
    /// `system`, `locked`, `free_running` or `lost`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::System => "system",
            Self::Locked => "locked",
            Self::FreeRunning => "free_running",
            Self::Lost => "lost",
        }
    }
}

/// The `timecode` object of `status`: changes only when the state does.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct TimecodeStatus {
    /// `system` or `ltc`.
    pub source: String,
    pub state: ClockState,
    /// The rate (`25`, `29.97df`, ...).
    pub rate: String,
}

/// The latest lock: the LTC frame `frame` (counted from 00:00:00:00 at the rate) ended at
/// `end_wall_us` (Unix microseconds, host clock).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Lock {
    pub frame: u64,
    pub end_wall_us: i64,
}

/// The LTC frame running at `wall_us` according to `lock`: the frame after the locked one
/// began when the locked one ended; from there one frame per `1/rate` of host time, wrapping
/// at midnight. Pure, so any span of free-run can be computed without waiting for it.
pub fn ltc_frame_at(lock: Lock, wall_us: i64, rate: TimecodeRate) -> u64 {
    let (num, den) = rate.fraction();
    let elapsed = i128::from(wall_us) - i128::from(lock.end_wall_us);
    let per = i128::from(den) * 1_000_000;
    // Floor division: a time before the lock's end counts back into the locked frame.
    let frames = (elapsed * i128::from(num)).div_euclid(per);
    let day = i128::from(rate.frames_per_day());
    (i128::from(lock.frame) + 1 + frames).rem_euclid(day) as u64
}

/// The LTC frame expected to end at `wall_us` given `lock`, rounded to the nearest.
fn expected_end(lock: Lock, wall_us: i64, rate: TimecodeRate) -> u64 {
    let (num, den) = rate.fraction();
    let elapsed = i128::from(wall_us) - i128::from(lock.end_wall_us);
    let per = i128::from(den) * 1_000_000;
    let frames = (2 * elapsed * i128::from(num) + per).div_euclid(2 * per);
    let day = i128::from(rate.frames_per_day());
    (i128::from(lock.frame) + frames).rem_euclid(day) as u64
}

#[derive(Debug, Default)]
struct ClockInner {
    lock: Option<Lock>,
    /// A run of frames that agree with each other but not with the lock, and its length.
    candidate: Option<(Lock, u32)>,
    state: ClockState,
    /// The last label decoded, for `/healthz`.
    last_label: Option<Timecode>,
    /// Agreeing frames read since the daemon started; frames refused by the lock.
    agreeing: u64,
    disagreeing: u64,
    /// Jumps followed.
    jumps: u64,
}

/// The timecode clock the hub stamps frames with. Cheap to read; the LTC thread writes.
#[derive(Debug)]
pub struct TimecodeClock {
    rate: TimecodeRate,
    ltc: bool,
    inner: Mutex<ClockInner>,
}

impl TimecodeClock {
    /// The host's time of day at `rate`.
    pub fn system(rate: TimecodeRate) -> TimecodeClock {
        TimecodeClock {
            rate,
            ltc: false,
            inner: Mutex::new(ClockInner::default()),
        }
    }

    /// The studio's LTC at `rate`; [`ClockState::Lost`] until LTC is read.
    pub fn ltc(rate: TimecodeRate) -> TimecodeClock {
        TimecodeClock {
            rate,
            ltc: true,
            inner: Mutex::new(ClockInner {
                state: ClockState::Lost,
                ..ClockInner::default()
            }),
        }
    }

    pub fn rate(&self) -> TimecodeRate {
        self.rate
    }

    /// Whether the clock follows LTC.
    pub fn is_ltc(&self) -> bool {
        self.ltc
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, ClockInner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The timecode at `wall_us` (Unix microseconds): LTC counted on from the last lock, or
    /// the host's time of day when there is no lock.
    pub fn timecode_at(&self, wall_us: i64) -> Timecode {
        self.frame_time_at(wall_us).timecode(self.rate)
    }

    /// [`TimecodeClock::timecode_at`] as a place on the frame grid: the frame and how far
    /// into it `wall_us` is (Live Link's frame number and sub-frame).
    pub fn frame_time_at(&self, wall_us: i64) -> FrameTime {
        if self.ltc {
            if let Some(lock) = self.lock().lock {
                let (num, den) = self.rate.fraction();
                let elapsed = i128::from(wall_us) - i128::from(lock.end_wall_us);
                let per = i128::from(den) * 1_000_000;
                let into = (elapsed * i128::from(num)).rem_euclid(per);
                return FrameTime {
                    frame: ltc_frame_at(lock, wall_us, self.rate),
                    sub_frame: into as f64 / per as f64,
                };
            }
        }
        FrameTime::from_unix_micros(wall_us, self.rate)
    }

    /// One decoded LTC frame, `label`, that ended at `end_wall_us`. Returns the state after
    /// it.
    pub fn observe(&self, label: Timecode, end_wall_us: i64) -> ClockState {
        let mut inner = self.lock();
        inner.last_label = Some(label);
        let Some(frame) = label.to_frame_count(self.rate) else {
            inner.disagreeing += 1;
            return inner.state;
        };
        let seen = Lock { frame, end_wall_us };
        if let Some(lock) = inner.lock {
            if expected_end(lock, end_wall_us, self.rate) == frame {
                inner.lock = Some(seen);
                inner.candidate = None;
                inner.agreeing += 1;
                inner.state = ClockState::Locked;
                return inner.state;
            }
        }
        inner.disagreeing += 1;
        let run = match inner.candidate {
            Some((c, n)) if expected_end(c, end_wall_us, self.rate) == frame => n + 1,
            _ => 1,
        };
        if run >= CONFIRM_FRAMES {
            if inner.lock.is_some() {
                inner.jumps += 1;
                tracing::info!(timecode = %label, "LTC jumped: the clock follows");
            } else {
                tracing::info!(timecode = %label, "LTC locked");
            }
            inner.lock = Some(seen);
            inner.candidate = None;
            inner.state = ClockState::Locked;
        } else {
            inner.candidate = Some((seen, run));
        }
        inner.state
    }

    /// The state at `now_wall_us`: free-running once no agreeing frame came for
    /// [`LTC_TIMEOUT_US`]. The LTC thread calls it after every block and while no sound comes.
    pub fn tick(&self, now_wall_us: i64) -> ClockState {
        let mut inner = self.lock();
        if let (ClockState::Locked, Some(lock)) = (inner.state, inner.lock) {
            if now_wall_us - lock.end_wall_us > LTC_TIMEOUT_US {
                inner.state = ClockState::FreeRunning;
                tracing::warn!(
                    "LTC stopped or unreadable: the timecode free-runs from the last lock"
                );
            }
        }
        inner.state
    }

    pub fn state(&self) -> ClockState {
        if self.ltc {
            self.lock().state
        } else {
            ClockState::System
        }
    }

    /// The `timecode` object of `status`.
    pub fn status(&self) -> TimecodeStatus {
        TimecodeStatus {
            source: if self.ltc { "ltc" } else { "system" }.to_owned(),
            state: self.state(),
            rate: self.rate.name().to_owned(),
        }
    }

    /// `/healthz`'s `timecode` entry.
    pub fn health_json(&self) -> serde_json::Value {
        let inner = self.lock();
        serde_json::json!({
            "source": if self.ltc { "ltc" } else { "system" },
            "state": if self.ltc { inner.state } else { ClockState::System }.as_str(),
            "rate": self.rate.name(),
            "last_ltc": inner.last_label.map(|t| t.to_string()),
            "last_lock_wall_us": inner.lock.map(|l| l.end_wall_us),
            "jumps": inner.jumps,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RATES: [TimecodeRate; 5] = [
        TimecodeRate::Fps23_976,
        TimecodeRate::Fps24,
        TimecodeRate::Fps25,
        TimecodeRate::Fps29_97Df,
        TimecodeRate::Fps30,
    ];

    /// Host time of the end of LTC frame `k` counted from `start` ending at `t0`.
    fn end_of(rate: TimecodeRate, t0: i64, k: u64) -> i64 {
        let (num, den) = rate.fraction();
        t0 + (u128::from(k) * u128::from(den) * 1_000_000 / u128::from(num)) as i64
    }

    fn feed(clock: &TimecodeClock, first: u64, frames: u64, t0: i64) -> ClockState {
        let rate = clock.rate();
        let mut state = ClockState::Lost;
        for k in 0..frames {
            let label = Timecode::from_frame_count(first + k, rate);
            state = clock.observe(label, end_of(rate, t0, k));
            clock.tick(end_of(rate, t0, k));
        }
        state
    }

    const T0: i64 = 1_780_000_000_000_000;

    #[test]
    fn ten_minutes_of_free_run_stay_on_the_frame() {
        for rate in RATES {
            let clock = TimecodeClock::ltc(rate);
            let first = Timecode {
                hours: 10,
                drop_frame: rate.drop_frame(),
                ..Timecode::default()
            }
            .to_frame_count(rate)
            .unwrap();
            assert_eq!(feed(&clock, first, 50, T0), ClockState::Locked, "{rate}");
            let last = first + 49;
            let last_end = end_of(rate, T0, 49);
            // LTC stops: free-running half a second later.
            assert_eq!(
                clock.tick(last_end + LTC_TIMEOUT_US + 1),
                ClockState::FreeRunning
            );
            // Every second of ten minutes (and just inside each frame), the label is the one
            // the LTC would have shown had it run on: the frame whose span holds the instant.
            for k in (1..=600 * 30).step_by(7) {
                let (num, den) = rate.fraction();
                let k = k as u64 * num / (den * 30);
                let start = end_of(rate, last_end, k);
                let end = end_of(rate, last_end, k + 1);
                for at in [start + 200, end - 200] {
                    let want = Timecode::from_frame_count(last + 1 + k, rate);
                    assert_eq!(clock.timecode_at(at), want, "{rate} after {k} frames");
                }
            }
            assert_eq!(clock.state(), ClockState::FreeRunning);
            // Exactly ten minutes on.
            let ten = last_end + 600_000_000;
            let (num, den) = rate.fraction();
            let frames = 600 * num / den;
            assert_eq!(
                clock.timecode_at(ten + 1),
                Timecode::from_frame_count(last + 1 + frames, rate),
                "{rate}"
            );
            // LTC returns where it would have been: locked again, nothing jumps.
            let back = last + 1 + frames + 10;
            let back_end = end_of(rate, last_end, frames + 11);
            let label = Timecode::from_frame_count(back, rate);
            assert_eq!(clock.observe(label, back_end), ClockState::Locked, "{rate}");
        }
    }

    #[test]
    fn a_jump_is_followed_once_confirmed_and_a_lone_frame_is_not() {
        let rate = TimecodeRate::Fps25;
        let clock = TimecodeClock::ltc(rate);
        assert_eq!(clock.state(), ClockState::Lost);
        // Before the first lock: the host's time of day.
        assert_eq!(clock.timecode_at(T0), Timecode::from_unix_micros(T0, rate));
        // Two frames are not a lock yet; the third is.
        let states: Vec<_> = (0..3)
            .map(|k| {
                clock.observe(
                    Timecode::from_frame_count(1000 + k, rate),
                    T0 + k as i64 * 40_000,
                )
            })
            .collect();
        assert_eq!(
            states,
            [ClockState::Lost, ClockState::Lost, ClockState::Locked]
        );
        // A lone odd frame is ignored.
        clock.observe(Timecode::from_frame_count(90_000, rate), T0 + 3 * 40_000);
        assert_eq!(
            clock.timecode_at(T0 + 3 * 40_000 - 1),
            Timecode::from_frame_count(1003, rate)
        );
        // A new position: followed after three agreeing frames.
        for k in 0..3 {
            clock.observe(
                Timecode::from_frame_count(50_000 + k, rate),
                T0 + (4 + k as i64) * 40_000,
            );
            let want = if k < 2 { 1004 + k + 1 } else { 50_003 };
            assert_eq!(
                clock.timecode_at(T0 + (4 + k as i64) * 40_000 + 1),
                Timecode::from_frame_count(want, rate),
                "after {} frames of the new position",
                k + 1
            );
        }
        assert_eq!(clock.health_json()["jumps"], 1);
    }

    #[test]
    fn midnight_wraps_and_the_system_clock_is_time_of_day() {
        let rate = TimecodeRate::Fps29_97Df;
        let day = rate.frames_per_day();
        let lock = Lock {
            frame: day - 1,
            end_wall_us: T0,
        };
        assert_eq!(ltc_frame_at(lock, T0, rate), 0);
        assert_eq!(ltc_frame_at(lock, T0 - 1, rate), day - 1);
        let clock = TimecodeClock::system(rate);
        assert_eq!(clock.state(), ClockState::System);
        assert_eq!(clock.timecode_at(T0), Timecode::from_unix_micros(T0, rate));
        assert_eq!(clock.status().source, "system");
    }
}
