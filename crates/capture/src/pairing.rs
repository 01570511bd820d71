//! Depth/colour pairing by device timestamp.
//!
//! Live: the newest colour frame that has a depth frame within tolerance wins; older
//! frames are discarded and the discarded colour frames counted as skipped. Replay: frames
//! pair in order; a frame with no partner within tolerance is dropped (counted as unpaired).

use std::collections::VecDeque;

pub(crate) trait Stamped {
    fn ts_us(&self) -> u64;
}

pub(crate) struct Pairer<D, C> {
    depth: VecDeque<D>,
    color: VecDeque<C>,
    tolerance_us: u64,
    /// Live queues keep at most this many frames per stream.
    live_capacity: usize,
    pub(crate) skipped: u64,
    pub(crate) unpaired: u64,
}

impl<D: Stamped, C: Stamped> Pairer<D, C> {
    pub(crate) fn new(tolerance_us: u64) -> Self {
        Pairer {
            depth: VecDeque::new(),
            color: VecDeque::new(),
            tolerance_us,
            live_capacity: 8,
            skipped: 0,
            unpaired: 0,
        }
    }

    pub(crate) fn push_depth(&mut self, d: D, live: bool) {
        self.depth.push_back(d);
        if live && self.depth.len() > self.live_capacity {
            self.depth.pop_front();
        }
    }

    pub(crate) fn push_color(&mut self, c: C, live: bool) {
        self.color.push_back(c);
        if live && self.color.len() > self.live_capacity {
            self.color.pop_front();
            self.skipped += 1;
        }
    }

    /// The oldest queued colour frame (colour-only sources).
    pub(crate) fn pop_color(&mut self) -> Option<C> {
        self.color.pop_front()
    }

    pub(crate) fn clear(&mut self) {
        self.depth.clear();
        self.color.clear();
    }

    pub(crate) fn pending(&self) -> (usize, usize) {
        (self.depth.len(), self.color.len())
    }

    /// The newest pair; everything older is discarded.
    pub(crate) fn take_newest(&mut self) -> Option<(D, C)> {
        let tol = self.tolerance_us;
        let (ci, di) = self.color.iter().enumerate().rev().find_map(|(ci, c)| {
            self.depth
                .iter()
                .enumerate()
                .filter(|(_, d)| d.ts_us().abs_diff(c.ts_us()) <= tol)
                .min_by_key(|(_, d)| d.ts_us().abs_diff(c.ts_us()))
                .map(|(di, _)| (ci, di))
        })?;
        self.skipped += ci as u64;
        self.color.drain(..ci);
        self.depth.drain(..di);
        Some((self.depth.pop_front()?, self.color.pop_front()?))
    }

    /// The oldest pair, in order; frames without a partner are dropped.
    pub(crate) fn take_in_order(&mut self) -> Option<(D, C)> {
        loop {
            let (d, c) = (self.depth.front()?, self.color.front()?);
            let (dt, ct) = (d.ts_us(), c.ts_us());
            if dt.abs_diff(ct) <= self.tolerance_us {
                return Some((self.depth.pop_front()?, self.color.pop_front()?));
            }
            self.unpaired += 1;
            if dt < ct {
                self.depth.pop_front();
            } else {
                self.color.pop_front();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, PartialEq)]
    struct F(u64);
    impl Stamped for F {
        fn ts_us(&self) -> u64 {
            self.0
        }
    }

    #[test]
    fn live_takes_the_newest_matching_pair_and_counts_skips() {
        let mut p = Pairer::new(5_000);
        for t in [0, 33_000, 66_000] {
            p.push_depth(F(t + 1_000), true);
            p.push_color(F(t), true);
        }
        p.push_color(F(99_000), true); // its depth has not arrived
        assert_eq!(p.take_newest(), Some((F(67_000), F(66_000))));
        assert_eq!(p.skipped, 2);
        assert_eq!(p.pending(), (0, 1));
        assert_eq!(p.take_newest(), None);
        p.push_depth(F(99_500), true);
        assert_eq!(p.take_newest(), Some((F(99_500), F(99_000))));
    }

    #[test]
    fn replay_pairs_in_order_and_drops_orphans() {
        let mut p = Pairer::new(5_000);
        for t in [0, 33_000, 66_000] {
            p.push_color(F(t), false);
        }
        for t in [33_000, 66_000] {
            p.push_depth(F(t), false);
        }
        assert_eq!(p.take_in_order(), Some((F(33_000), F(33_000))));
        assert_eq!(p.unpaired, 1);
        assert_eq!(p.take_in_order(), Some((F(66_000), F(66_000))));
        assert_eq!(p.take_in_order(), None);
    }

    #[test]
    fn live_queues_are_bounded() {
        let mut p: Pairer<F, F> = Pairer::new(1);
        for t in 0..100 {
            p.push_color(F(t * 1000), true);
            p.push_depth(F(t * 1000 + 500_000), true);
        }
        assert_eq!(p.pending(), (8, 8));
        assert_eq!(p.skipped, 92);
    }
}
