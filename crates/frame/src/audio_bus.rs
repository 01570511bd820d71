//! [`AudioBus`]: one audio thread, several consumers (the take writer, the live speech
//! analyser), each behind its own bounded queue that drops its oldest event when full.
//!
//! The audio thread never waits for a consumer: [`AudioBus::publish`] is a non-blocking
//! `try_send` into every subscriber's queue; a full queue loses its oldest event (counted
//! per subscriber and in total), so a slow consumer hears the newest sound and never holds
//! back the device or the other consumers. A consumer receives with a crossbeam
//! [`Receiver`], so it can `select!` over the sound and its other inputs.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::SystemTime;

use crossbeam_channel::{Receiver, Sender, TrySendError};

use crate::audio::{AudioBlock, AudioSourceInfo};

/// What the audio thread tells its consumers.
#[derive(Debug, Clone)]
pub enum AudioEvent {
    /// A source was opened; blocks in its format follow (their `first_frame` starts at 0).
    Started(AudioSourceInfo),
    /// A block of sound.
    Block(Arc<AudioBlock>),
    /// The source stopped (lost, failed, ended): no sound until the next `Started`.
    Stopped {
        /// Why, in words.
        reason: String,
        /// Wall-clock time just after the last sample delivered (the time of the loss when
        /// no block came).
        at: SystemTime,
        /// Sample frames delivered by the source before it stopped.
        frames: u64,
    },
}

struct Subscriber {
    tx: Sender<AudioEvent>,
    /// The bus's own end of the queue: how it drops the oldest event.
    oldest: Receiver<AudioEvent>,
    dropped: Arc<AtomicU64>,
}

/// The audio thread's fan-out to its consumers.
#[derive(Default)]
pub struct AudioBus {
    subscribers: Mutex<Vec<Subscriber>>,
    dropped: AtomicU64,
}

impl std::fmt::Debug for AudioBus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AudioBus")
            .field("subscribers", &self.subscribers().len())
            .field("dropped", &self.dropped())
            .finish()
    }
}

/// A consumer's end of the bus; dropping it unsubscribes.
#[derive(Debug)]
pub struct AudioSubscription {
    /// Events in the order published (minus the ones dropped).
    pub events: Receiver<AudioEvent>,
    dropped: Arc<AtomicU64>,
}

impl AudioSubscription {
    /// Events this subscriber lost because its queue was full.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

impl AudioBus {
    pub fn new() -> Arc<AudioBus> {
        Arc::new(AudioBus::default())
    }

    /// A new consumer whose queue holds at most `capacity` events (at least 1).
    pub fn subscribe(&self, capacity: usize) -> AudioSubscription {
        let (tx, rx) = crossbeam_channel::bounded(capacity.max(1));
        let dropped = Arc::new(AtomicU64::new(0));
        self.lock().push(Subscriber {
            tx,
            oldest: rx.clone(),
            dropped: dropped.clone(),
        });
        AudioSubscription {
            events: rx,
            dropped,
        }
    }

    /// Offers `event` to every subscriber without waiting; a full queue drops its oldest
    /// event. Returns how many events were dropped by this call.
    pub fn publish(&self, event: AudioEvent) -> u64 {
        let mut dropped = 0;
        let mut subscribers = self.lock();
        // A subscriber whose subscription was dropped holds the only other `dropped` Arc.
        subscribers.retain(|s| Arc::strong_count(&s.dropped) > 1);
        for s in subscribers.iter() {
            let mut event = event.clone();
            loop {
                match s.tx.try_send(event) {
                    Ok(()) => break,
                    Err(TrySendError::Full(back)) => {
                        event = back;
                        if s.oldest.try_recv().is_ok() {
                            dropped += 1;
                            s.dropped.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                    Err(TrySendError::Disconnected(_)) => break,
                }
            }
        }
        drop(subscribers);
        self.dropped.fetch_add(dropped, Ordering::Relaxed);
        dropped
    }

    /// Events dropped over all subscribers since the bus was made.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Subscribers now listening.
    pub fn subscribers(&self) -> Vec<u64> {
        self.lock()
            .iter()
            .filter(|s| Arc::strong_count(&s.dropped) > 1)
            .map(|s| s.dropped.load(Ordering::Relaxed))
            .collect()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<Subscriber>> {
        self.subscribers.lock().unwrap_or_else(|p| p.into_inner())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::audio::AudioFormat;
    use std::time::Instant;

    fn block(seq: u64) -> AudioEvent {
        AudioEvent::Block(Arc::new(AudioBlock {
            seq,
            first_frame: seq * 4,
            format: AudioFormat {
                sample_rate: 48_000,
                channels: 1,
            },
            samples: vec![0; 4],
            host_rx: Instant::now(),
            wall_clock: None,
        }))
    }

    fn seqs(sub: &AudioSubscription) -> Vec<u64> {
        sub.events
            .try_iter()
            .filter_map(|e| match e {
                AudioEvent::Block(b) => Some(b.seq),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn a_full_queue_drops_its_oldest_and_counts_it_without_holding_back_the_others() {
        let bus = AudioBus::new();
        let slow = bus.subscribe(3);
        let fast = bus.subscribe(100);
        for seq in 0..10 {
            bus.publish(block(seq));
        }
        assert_eq!(seqs(&slow), [7, 8, 9], "the newest three are kept");
        assert_eq!(slow.dropped(), 7);
        assert_eq!(seqs(&fast), (0..10).collect::<Vec<_>>());
        assert_eq!(fast.dropped(), 0);
        assert_eq!(bus.dropped(), 7);
    }

    #[test]
    fn a_dropped_subscription_is_forgotten() {
        let bus = AudioBus::new();
        let sub = bus.subscribe(1);
        assert_eq!(bus.subscribers().len(), 1);
        drop(sub);
        bus.publish(block(0));
        assert!(bus.subscribers().is_empty());
        assert_eq!(bus.dropped(), 0);
    }
}
