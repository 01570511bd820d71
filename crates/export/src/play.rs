//! Pacing a take for `mouthpiece play`: when each frame is due, relative to the first.
//!
//! The reader has already checked that each line's `t` is finite and increasing. What is left
//! to bound is what the user and the file choose: the speed, and the gap between two lines
//! (a live take has a line per frame, so a long gap is a broken or hostile file, refused at
//! its line rather than waited on for years). With both bounded, every wait is at most
//! [`MAX_GAP_S`] / [`MIN_SPEED`] seconds and every offset fits a [`Duration`].

use std::time::Duration;

use crate::{ExportError, TakeFrame};

/// Slowest speed (a hundredth of the take's own pace).
pub const MIN_SPEED: f64 = 0.01;
/// Fastest speed.
pub const MAX_SPEED: f64 = 1000.0;
/// Longest time between two lines of a take that `play` waits through, seconds of the take.
pub const MAX_GAP_S: f64 = 60.0;

/// When each frame of a take is due, from the first frame's time and the playback speed.
#[derive(Clone, Debug)]
pub struct PlayClock {
    speed: f64,
    first_t: Option<f64>,
    previous_t: Option<f64>,
    source_name: String,
}

impl PlayClock {
    /// `speed`: 1 is the take's own timing, 2 twice as fast; from [`MIN_SPEED`] to
    /// [`MAX_SPEED`].
    pub fn new(speed: f64, source_name: impl Into<String>) -> Result<Self, ExportError> {
        Self::check_speed(speed)?;
        Ok(PlayClock {
            speed,
            first_t: None,
            previous_t: None,
            source_name: source_name.into(),
        })
    }

    /// The speed check alone, for a caller that checks its options before opening the take.
    pub fn check_speed(speed: f64) -> Result<(), ExportError> {
        if (MIN_SPEED..=MAX_SPEED).contains(&speed) {
            Ok(())
        } else {
            Err(ExportError::BadSpeed(speed))
        }
    }

    /// How long after the first frame this frame is due (zero for the first). A gap of more
    /// than [`MAX_GAP_S`] since the previous frame is an error naming the frame's line.
    pub fn due(&mut self, frame: &TakeFrame) -> Result<Duration, ExportError> {
        let bad = |problem: String| ExportError::BadLine {
            source_name: self.source_name.clone(),
            line: frame.line,
            problem,
        };
        if !frame.t.is_finite() {
            return Err(bad(format!("t is {}", frame.t)));
        }
        if let Some(previous) = self.previous_t {
            let gap = frame.t - previous;
            if !(0.0..=MAX_GAP_S).contains(&gap) {
                return Err(bad(format!(
                    "t is {gap} s after the previous line's; play waits from 0 to {MAX_GAP_S} s \
                     between two lines"
                )));
            }
        }
        self.previous_t = Some(frame.t);
        let first = *self.first_t.get_or_insert(frame.t);
        Duration::try_from_secs_f64((frame.t - first) / self.speed)
            .map_err(|_| bad(format!("t = {} is too far from the first line's", frame.t)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(line: u64, t: f64) -> TakeFrame {
        TakeFrame {
            line,
            t,
            points: Vec::new(),
            curve: None,
            head: None,
            rig: None,
        }
    }

    #[test]
    fn frames_are_due_at_their_time_from_the_first_divided_by_the_speed() {
        let mut clock = PlayClock::new(2.0, "take").unwrap();
        assert_eq!(clock.due(&frame(1, 10.0)).unwrap(), Duration::ZERO);
        assert_eq!(
            clock.due(&frame(2, 11.0)).unwrap(),
            Duration::from_millis(500)
        );
        assert_eq!(
            clock.due(&frame(3, 13.0)).unwrap(),
            Duration::from_millis(1500)
        );
    }

    #[test]
    fn speeds_outside_the_range_are_refused() {
        for speed in [0.0, -1.0, 1e-300, 1e300, f64::NAN, f64::INFINITY, 1000.5] {
            let err = PlayClock::new(speed, "take").unwrap_err();
            assert!(matches!(err, ExportError::BadSpeed(_)), "{speed}: {err}");
            assert!(err.is_bad_input());
        }
    }

    #[test]
    fn a_gap_longer_than_the_limit_is_an_error_at_its_line() {
        let mut clock = PlayClock::new(MIN_SPEED, "take.jsonl").unwrap();
        clock.due(&frame(1, 0.0)).unwrap();
        clock.due(&frame(2, MAX_GAP_S)).unwrap();
        let err = clock.due(&frame(3, 2.0 * MAX_GAP_S + 0.001)).unwrap_err();
        assert!(
            err.to_string().starts_with("take.jsonl: line 3: t is"),
            "{err}"
        );
        // Slowest speed, longest gaps: still a finite wait.
        let mut clock = PlayClock::new(MIN_SPEED, "take").unwrap();
        let mut last = Duration::ZERO;
        for i in 0..1000 {
            last = clock.due(&frame(i, i as f64 * MAX_GAP_S)).unwrap();
        }
        assert_eq!(last, Duration::from_secs_f64(999.0 * MAX_GAP_S / MIN_SPEED));
    }
}
