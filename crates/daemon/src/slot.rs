//! The latest-frame slot between the source thread and the processing thread.
//!
//! Capacity one, newest wins: a source that runs ahead of processing overwrites the frame
//! that was not taken yet (counted), so processing always works on the freshest frame and no
//! queue of stale frames builds up. Never blocks the producer beyond a short lock.

use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::Duration;

/// A single-value mailbox where `put` replaces an untaken value.
#[derive(Debug)]
pub struct LatestSlot<T> {
    inner: Mutex<Inner<T>>,
    ready: Condvar,
}

#[derive(Debug)]
struct Inner<T> {
    value: Option<T>,
    overwritten: u64,
    closed: bool,
}

/// What [`LatestSlot::take_timeout`] found.
#[derive(Debug, PartialEq, Eq)]
pub enum Taken<T> {
    Value(T),
    /// Nothing arrived within the timeout.
    Empty,
    /// The slot was closed and is empty.
    Closed,
}

impl<T> Default for LatestSlot<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T> LatestSlot<T> {
    pub fn new() -> Self {
        LatestSlot {
            inner: Mutex::new(Inner {
                value: None,
                overwritten: 0,
                closed: false,
            }),
            ready: Condvar::new(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, Inner<T>> {
        // A panicking holder cannot leave the slot inconsistent: every update is one assignment.
        self.inner
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// Stores `value`, replacing (and dropping) one that was not taken yet. Returns true when
    /// a value was replaced.
    pub fn put(&self, value: T) -> bool {
        let old = {
            let mut inner = self.lock();
            let old = inner.value.replace(value);
            if old.is_some() {
                inner.overwritten += 1;
            }
            old
        };
        self.ready.notify_one();
        // Dropped outside the lock: a frame's buffers are large.
        let replaced = old.is_some();
        drop(old);
        replaced
    }

    /// Waits up to `timeout` for a value.
    pub fn take_timeout(&self, timeout: Duration) -> Taken<T> {
        let inner = self.lock();
        let (mut inner, _) = self
            .ready
            .wait_timeout_while(inner, timeout, |i| i.value.is_none() && !i.closed)
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        match inner.value.take() {
            Some(v) => Taken::Value(v),
            None if inner.closed => Taken::Closed,
            None => Taken::Empty,
        }
    }

    /// Values replaced before they were taken, since the start.
    pub fn overwritten(&self) -> u64 {
        self.lock().overwritten
    }

    /// Wakes the consumer; later `take_timeout`s return what is left, then `Closed`.
    pub fn close(&self) {
        self.lock().closed = true;
        self.ready.notify_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use std::time::Instant;

    #[test]
    fn newest_wins_and_overwrites_are_counted() {
        let slot = LatestSlot::new();
        assert!(!slot.put(1));
        assert!(slot.put(2));
        assert!(slot.put(3));
        assert_eq!(slot.take_timeout(Duration::ZERO), Taken::Value(3));
        assert_eq!(slot.take_timeout(Duration::from_millis(1)), Taken::Empty);
        assert_eq!(slot.overwritten(), 2);
    }

    #[test]
    fn take_waits_for_a_value_from_another_thread() {
        let slot = Arc::new(LatestSlot::new());
        let producer = {
            let slot = slot.clone();
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(20));
                slot.put(7u32);
            })
        };
        let start = Instant::now();
        assert_eq!(slot.take_timeout(Duration::from_secs(5)), Taken::Value(7));
        assert!(start.elapsed() < Duration::from_secs(5));
        producer.join().unwrap();
    }

    #[test]
    fn close_wakes_the_consumer() {
        let slot = Arc::new(LatestSlot::<u8>::new());
        let closer = {
            let slot = slot.clone();
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(20));
                slot.close();
            })
        };
        assert_eq!(slot.take_timeout(Duration::from_secs(5)), Taken::Closed);
        closer.join().unwrap();
    }
}
