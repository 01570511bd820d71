//! SMPTE timecode (time of day), so a take lines up with audio recorded beside it.
//!
//! Rates 23.976, 24, 25, 30, 48, 50, 60 are non-drop-frame; 29.97 and 59.94 are
//! drop-frame (`HH:MM:SS;FF`), the convention of broadcast and audio recorders at those
//! rates. A 23.976 timecode counts 24 labels per (1.001 s) second, as recorders do.

use std::fmt;
use std::str::FromStr;

use serde::{Serialize, Serializer};

/// A timecode rate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TimecodeRate {
    /// 24000/1001, non-drop.
    Fps23_976,
    /// 24.
    Fps24,
    /// 25 (PAL regions).
    Fps25,
    /// 30000/1001, drop-frame.
    Fps29_97Df,
    /// 30.
    #[default]
    Fps30,
    /// 48.
    Fps48,
    /// 50.
    Fps50,
    /// 60000/1001, drop-frame.
    Fps59_94Df,
    /// 60.
    Fps60,
}

impl TimecodeRate {
    /// Every rate, in the order of their names.
    pub const ALL: [TimecodeRate; 9] = [
        Self::Fps23_976,
        Self::Fps24,
        Self::Fps25,
        Self::Fps29_97Df,
        Self::Fps30,
        Self::Fps48,
        Self::Fps50,
        Self::Fps59_94Df,
        Self::Fps60,
    ];

    /// The name used in configuration and in `hello` (`"29.97df"`, `"25"`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Self::Fps23_976 => "23.976",
            Self::Fps24 => "24",
            Self::Fps25 => "25",
            Self::Fps29_97Df => "29.97df",
            Self::Fps30 => "30",
            Self::Fps48 => "48",
            Self::Fps50 => "50",
            Self::Fps59_94Df => "59.94df",
            Self::Fps60 => "60",
        }
    }

    /// (numerator, denominator) of the real frame rate.
    pub fn fraction(self) -> (u64, u64) {
        match self {
            Self::Fps23_976 => (24000, 1001),
            Self::Fps24 => (24, 1),
            Self::Fps25 => (25, 1),
            Self::Fps29_97Df => (30000, 1001),
            Self::Fps30 => (30, 1),
            Self::Fps48 => (48, 1),
            Self::Fps50 => (50, 1),
            Self::Fps59_94Df => (60000, 1001),
            Self::Fps60 => (60, 1),
        }
    }

    /// Frame labels per second (the `FF` range).
    pub fn nominal(self) -> u64 {
        let (n, d) = self.fraction();
        n.div_ceil(d)
    }

    /// Whether labels are counted drop-frame (29.97, 59.94).
    pub fn drop_frame(self) -> bool {
        self.dropped_per_minute() > 0
    }

    /// Real frames in one 24-hour day of labels (the count wraps at midnight).
    pub fn frames_per_day(self) -> u64 {
        let drop = self.dropped_per_minute();
        // 144 ten-minute blocks a day, each losing nine minutes' dropped labels.
        144 * (self.nominal() * 600 - 9 * drop)
    }

    /// Labels dropped per minute (except every tenth minute), 0 for non-drop rates.
    fn dropped_per_minute(self) -> u64 {
        match self {
            Self::Fps29_97Df => 2,
            Self::Fps59_94Df => 4,
            _ => 0,
        }
    }
}

impl fmt::Display for TimecodeRate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// An unknown timecode rate name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown timecode rate {0:?} (expected one of 23.976, 24, 25, 29.97df, 30, 48, 50, 59.94df, 60)")]
pub struct UnknownRate(pub String);

impl FromStr for TimecodeRate {
    type Err = UnknownRate;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|r| r.name() == s)
            .ok_or_else(|| UnknownRate(s.to_owned()))
    }
}

/// One SMPTE timecode; serializes as `"HH:MM:SS:FF"` (`;` before the frames when drop-frame).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Timecode {
    /// 0..24
    pub hours: u8,
    /// 0..60
    pub minutes: u8,
    /// 0..60
    pub seconds: u8,
    /// 0..nominal rate
    pub frames: u8,
    /// Drop-frame counting.
    pub drop_frame: bool,
}

/// A time of day as a position on a rate's frame grid: whole frames since midnight (real
/// frames, as Unreal's `FFrameNumber` counts them; drop-frame labels are a matter of
/// [`Timecode`]) and how far into the next one, `0 ≤ sub_frame < 1`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameTime {
    pub frame: u64,
    pub sub_frame: f64,
}

impl FrameTime {
    /// The position of a time of day given in microseconds since midnight.
    pub fn from_micros_of_day(micros: u64, rate: TimecodeRate) -> Self {
        let (num, den) = rate.fraction();
        let scaled = u128::from(micros) * u128::from(num);
        let per_frame = u128::from(den) * 1_000_000;
        FrameTime {
            frame: (scaled / per_frame) as u64,
            sub_frame: (scaled % per_frame) as f64 / per_frame as f64,
        }
    }

    /// The position of a Unix time in microseconds, as time of day in UTC.
    pub fn from_unix_micros(unix_us: i64, rate: TimecodeRate) -> Self {
        const DAY_US: i64 = 86_400 * 1_000_000;
        Self::from_micros_of_day(unix_us.rem_euclid(DAY_US) as u64, rate)
    }

    /// A published frame's position: of its wall clock (`wall_us`), else of its stream time
    /// `t` taken as a time of day (the rule of every frame's `timecode`).
    pub fn of_stream(wall_us: Option<i64>, t: f64, rate: TimecodeRate) -> Self {
        match wall_us {
            Some(wall) => Self::from_unix_micros(wall, rate),
            None => Self::from_micros_of_day((t.max(0.0) * 1e6) as u64, rate),
        }
    }

    /// The timecode label of [`FrameTime::frame`].
    pub fn timecode(self, rate: TimecodeRate) -> Timecode {
        Timecode::from_frame_count(self.frame, rate)
    }
}

impl Timecode {
    /// The timecode of a time of day given in microseconds since midnight.
    pub fn from_micros_of_day(micros: u64, rate: TimecodeRate) -> Self {
        FrameTime::from_micros_of_day(micros, rate).timecode(rate)
    }

    /// The timecode of a Unix time in microseconds, as time of day in UTC.
    pub fn from_unix_micros(unix_us: i64, rate: TimecodeRate) -> Self {
        FrameTime::from_unix_micros(unix_us, rate).timecode(rate)
    }

    /// The timecode label of the `frame`-th frame counted from 00:00:00:00.
    pub fn from_frame_count(frame: u64, rate: TimecodeRate) -> Self {
        let nominal = rate.nominal();
        let drop = rate.dropped_per_minute();
        let mut label = frame;
        if drop > 0 {
            // Labels 0..drop of every minute not divisible by ten are skipped.
            let per_minute = nominal * 60 - drop;
            let per_ten_minutes = nominal * 600 - 9 * drop;
            let tens = frame / per_ten_minutes;
            let rest = frame % per_ten_minutes;
            label += 9 * drop * tens;
            if rest >= drop {
                label += drop * ((rest - drop) / per_minute);
            }
        }
        let per_hour = nominal * 3600;
        Self {
            hours: ((label / per_hour) % 24) as u8,
            minutes: ((label / (nominal * 60)) % 60) as u8,
            seconds: ((label / nominal) % 60) as u8,
            frames: (label % nominal) as u8,
            drop_frame: drop > 0,
        }
    }
}

impl Timecode {
    /// The frame count from 00:00:00:00 of this label at `rate` (the inverse of
    /// [`Timecode::from_frame_count`]); `None` when the label does not exist at the rate (a
    /// field out of range, or a label drop-frame counting skips).
    pub fn to_frame_count(&self, rate: TimecodeRate) -> Option<u64> {
        let nominal = rate.nominal();
        let drop = rate.dropped_per_minute();
        let (h, m, s, f) = (
            u64::from(self.hours),
            u64::from(self.minutes),
            u64::from(self.seconds),
            u64::from(self.frames),
        );
        if h >= 24 || m >= 60 || s >= 60 || f >= nominal {
            return None;
        }
        if drop > 0 && s == 0 && f < drop && !m.is_multiple_of(10) {
            return None;
        }
        let minutes = h * 60 + m;
        let label = (minutes * 60 + s) * nominal + f;
        // Labels skipped before this one: `drop` per minute, but not in tenth minutes.
        Some(label - drop * (minutes - minutes / 10))
    }
}

impl fmt::Display for Timecode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let sep = if self.drop_frame { ';' } else { ':' };
        write!(
            f,
            "{:02}:{:02}:{:02}{sep}{:02}",
            self.hours, self.minutes, self.seconds, self.frames
        )
    }
}

impl Serialize for Timecode {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_drop_labels_count_real_seconds() {
        let tc = Timecode::from_micros_of_day(
            ((13 * 60 + 5) * 60 + 7) * 1_000_000 + 520_000,
            TimecodeRate::Fps25,
        );
        assert_eq!(tc.to_string(), "13:05:07:13");
        assert_eq!(
            Timecode::from_unix_micros(-1, TimecodeRate::Fps24).to_string(),
            "23:59:59:23"
        );
    }

    #[test]
    fn drop_frame_skips_two_labels_per_minute_except_tenths() {
        let r = TimecodeRate::Fps29_97Df;
        // Frame 1800 (one minute of 30-label counting minus the two dropped) is 00:01:00;02.
        assert_eq!(
            Timecode::from_frame_count(1799, r).to_string(),
            "00:00:59;29"
        );
        assert_eq!(
            Timecode::from_frame_count(1800, r).to_string(),
            "00:01:00;02"
        );
        // The tenth minute keeps its labels 00 and 01.
        assert_eq!(
            Timecode::from_frame_count(17982, r).to_string(),
            "00:10:00;00"
        );
        // One hour of real time at 29.97 is 107892 frames and reads exactly 01:00:00;00.
        assert_eq!(
            Timecode::from_frame_count(107_892, r).to_string(),
            "01:00:00;00"
        );
        assert_eq!(
            Timecode::from_micros_of_day(3_600 * 1_000_000, r).to_string(),
            "01:00:00;00"
        );
        let r = TimecodeRate::Fps59_94Df;
        assert_eq!(
            Timecode::from_frame_count(215_784, r).to_string(),
            "01:00:00;00"
        );
    }

    #[test]
    fn frame_counts_round_trip_through_labels() {
        for r in TimecodeRate::ALL {
            let day = r.frames_per_day();
            for frame in (0..day).step_by(997).chain([day - 1, 1799, 1800, 17_982]) {
                let tc = Timecode::from_frame_count(frame, r);
                assert_eq!(tc.to_frame_count(r), Some(frame), "{r} {tc}");
            }
            // The day wraps: the frame after the last is midnight.
            assert_eq!(
                Timecode::from_frame_count(day, r),
                Timecode::from_frame_count(0, r)
            );
        }
        let dropped = Timecode {
            minutes: 1,
            frames: 1,
            drop_frame: true,
            ..Timecode::default()
        };
        assert_eq!(dropped.to_frame_count(TimecodeRate::Fps29_97Df), None);
        let beyond = Timecode {
            frames: 25,
            ..Timecode::default()
        };
        assert_eq!(beyond.to_frame_count(TimecodeRate::Fps25), None);
    }

    #[test]
    fn rate_names_round_trip() {
        for r in TimecodeRate::ALL {
            assert_eq!(r.name().parse::<TimecodeRate>().unwrap(), r);
        }
        assert!("29.97".parse::<TimecodeRate>().is_err());
    }
}
