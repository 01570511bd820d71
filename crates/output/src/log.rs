//! How the long-running outputs report trouble: an error with its causes on one line, and
//! a repeated warning at most once per interval (a source that fails to open every half
//! second, a full disk under a take, a refusing OSC target must not fill the journal), and a
//! panic caught on a long-running thread as its message.

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

/// A rate limit on messages from one sender: `rate` per second, with a burst of the same
/// size. A sender that keeps within the rate is never refused; one that floods gets `rate` a
/// second through, whatever it sends.
#[derive(Clone, Debug)]
pub struct TokenBucket {
    rate: f64,
    tokens: f64,
    last: Instant,
}

impl TokenBucket {
    /// A full bucket: a burst of `rate` messages is taken at once.
    pub fn new(rate: u32, now: Instant) -> Self {
        Self {
            rate: f64::from(rate),
            tokens: f64::from(rate),
            last: now,
        }
    }

    /// True when one more message is within the rate (and counts it).
    pub fn take(&mut self, now: Instant) -> bool {
        self.refill(now);
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }

    /// True when the sender has been quiet long enough for a whole burst: such a bucket can
    /// be forgotten and made again at no cost to the sender.
    pub fn is_full(&mut self, now: Instant) -> bool {
        self.refill(now);
        self.tokens >= self.rate
    }

    fn refill(&mut self, now: Instant) {
        let elapsed = now.saturating_duration_since(self.last).as_secs_f64();
        self.tokens = (self.tokens + elapsed * self.rate).min(self.rate);
        self.last = self.last.max(now);
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

/// Runs `f`, turning a panic into its message.
pub fn catch_panic<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).map_err(|p| panic_message(&*p))
}

/// The message of a panic payload (`panic!("...")` gives a `&str` or a `String`).
pub fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| (*s).to_owned())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(no message)".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_token_bucket_takes_a_burst_then_its_rate() {
        let t0 = Instant::now();
        let mut bucket = TokenBucket::new(10, t0);
        let burst = (0..100).filter(|_| bucket.take(t0)).count();
        assert_eq!(burst, 10, "a burst of the rate");
        // A flood for 2 s, a message every millisecond: 10 a second get through.
        let through = (1..=2000)
            .filter(|ms| bucket.take(t0 + Duration::from_millis(*ms)))
            .count();
        assert_eq!(through, 20);
        assert!(!bucket.is_full(t0 + Duration::from_millis(2000)));
        assert!(bucket.is_full(t0 + Duration::from_millis(3000)));
        // A clock read out of order never adds tokens.
        let mut bucket = TokenBucket::new(1, t0 + Duration::from_secs(5));
        assert!(bucket.take(t0 + Duration::from_secs(5)));
        assert!(!bucket.take(t0));
    }

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
