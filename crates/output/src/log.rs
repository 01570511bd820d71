//! How the long-running outputs report trouble: an error with its causes on one line, and
//! a repeated warning at most once per interval (a source that fails to open every half
//! second, a full disk under a take, a refusing OSC target must not fill the journal).

use std::time::{Duration, Instant};

/// Lets a message through at most once per interval and counts the ones it held back.
#[derive(Debug, Clone)]
pub struct Throttle {
    interval: Duration,
    last: Option<Instant>,
    suppressed: u64,
}

impl Throttle {
    pub fn new(interval: Duration) -> Self {
        Throttle {
            interval,
            last: None,
            suppressed: 0,
        }
    }

    /// `Some(n)` when the message should be logged now, `n` being how many were held back
    /// since the last one logged; `None` to stay quiet.
    pub fn allow(&mut self, now: Instant) -> Option<u64> {
        match self.last {
            Some(last) if now.duration_since(last) < self.interval => {
                self.suppressed += 1;
                None
            }
            _ => {
                self.last = Some(now);
                Some(std::mem::take(&mut self.suppressed))
            }
        }
    }

    /// Forgets the history: the next message is logged (e.g. after the condition cleared).
    pub fn reset(&mut self) {
        self.last = None;
        self.suppressed = 0;
    }
}

/// `error: cause: cause`, for status messages and logs.
pub fn error_chain(err: &dyn std::error::Error) -> String {
    let mut text = err.to_string();
    let mut cause = err.source();
    while let Some(c) = cause {
        text.push_str(": ");
        text.push_str(&c.to_string());
        cause = c.source();
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn logs_once_per_interval_with_a_count() {
        let t0 = Instant::now();
        let s = Duration::from_secs;
        let mut throttle = Throttle::new(s(10));
        assert_eq!(throttle.allow(t0), Some(0));
        assert_eq!(throttle.allow(t0 + s(1)), None);
        assert_eq!(throttle.allow(t0 + s(9)), None);
        assert_eq!(throttle.allow(t0 + s(10)), Some(2));
        assert_eq!(throttle.allow(t0 + s(11)), None);
        throttle.reset();
        assert_eq!(throttle.allow(t0 + s(12)), Some(0));
    }
}
