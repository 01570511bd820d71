//! Key reduction: drop the keys that linear interpolation between the kept ones reproduces.
//!
//! Streaming and O(1) memory per channel, so long takes stay cheap. From the last kept key
//! (the anchor) the reducer keeps, per axis, the interval of slopes that still reproduces
//! every sample since the anchor within the tolerance; a candidate end key is acceptable when
//! its own slope lies in all three intervals. As soon as the newest sample is not an
//! acceptable end, the previous sample becomes a key and the new anchor. Every dropped sample
//! is then reproduced within the tolerance on each axis (the max-norm), which the tests check
//! against a brute-force interpolation. This is the greedy "sleeve" method: not the global
//! minimum number of keys, but close, and it never looks back.

/// A key: time and value.
pub type Key = (f64, [f64; 3]);

/// Reducer for one channel (one point's translation).
#[derive(Clone, Debug)]
pub struct Reducer {
    tolerance: f64,
    anchor: Option<Key>,
    candidate: Option<Key>,
    slope_lo: [f64; 3],
    slope_hi: [f64; 3],
}

impl Reducer {
    /// `tolerance` ≥ 0, in the points' units, per axis.
    pub fn new(tolerance: f64) -> Self {
        Self {
            tolerance,
            anchor: None,
            candidate: None,
            slope_lo: [f64::NEG_INFINITY; 3],
            slope_hi: [f64::INFINITY; 3],
        }
    }

    /// Feeds the next sample (times strictly increasing); returns the key it settles, if any.
    pub fn push(&mut self, t: f64, v: [f64; 3]) -> Option<Key> {
        let Some((ta, va)) = self.anchor else {
            self.anchor = Some((t, v));
            return Some((t, v));
        };
        let Some((tc, vc)) = self.candidate else {
            self.candidate = Some((t, v));
            return None;
        };
        // The old candidate becomes an in-between sample of the segment anchor → (t, v).
        let mut lo = self.slope_lo;
        let mut hi = self.slope_hi;
        let mut fits = true;
        for k in 0..3 {
            lo[k] = lo[k].max((vc[k] - self.tolerance - va[k]) / (tc - ta));
            hi[k] = hi[k].min((vc[k] + self.tolerance - va[k]) / (tc - ta));
            let slope = (v[k] - va[k]) / (t - ta);
            fits &= lo[k] <= slope && slope <= hi[k];
        }
        if fits {
            self.slope_lo = lo;
            self.slope_hi = hi;
            self.candidate = Some((t, v));
            None
        } else {
            let key = (tc, vc);
            self.anchor = Some(key);
            self.candidate = Some((t, v));
            self.slope_lo = [f64::NEG_INFINITY; 3];
            self.slope_hi = [f64::INFINITY; 3];
            Some(key)
        }
    }

    /// Ends the channel: the last sample is always a key.
    pub fn finish(&mut self) -> Option<Key> {
        self.candidate.take()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn reduce(samples: &[Key], tolerance: f64) -> Vec<Key> {
        let mut r = Reducer::new(tolerance);
        let mut keys: Vec<Key> = samples.iter().filter_map(|&(t, v)| r.push(t, v)).collect();
        keys.extend(r.finish());
        keys
    }

    /// Linear interpolation of the keys at `t`, independently of the reducer's bookkeeping.
    fn interpolate(keys: &[Key], t: f64) -> [f64; 3] {
        let i = keys.partition_point(|k| k.0 <= t).clamp(1, keys.len() - 1);
        let ((t0, a), (t1, b)) = (keys[i - 1], keys[i]);
        let u = (t - t0) / (t1 - t0);
        [0, 1, 2].map(|k| a[k] + (b[k] - a[k]) * u)
    }

    #[test]
    fn straight_line_keeps_its_ends() {
        let samples: Vec<Key> = (0..100)
            .map(|i| (i as f64 * 0.01, [i as f64, 2.0 * i as f64, -(i as f64)]))
            .collect();
        let keys = reduce(&samples, 1e-9);
        assert_eq!(keys, vec![samples[0], samples[99]]);
    }

    #[test]
    fn a_corner_is_kept() {
        let samples: Vec<Key> = (0..21)
            .map(|i| {
                let x = if i <= 10 { i as f64 } else { 20.0 - i as f64 };
                (i as f64, [x, 0.0, 0.0])
            })
            .collect();
        let keys = reduce(&samples, 1e-6);
        assert_eq!(keys, vec![samples[0], samples[10], samples[20]]);
    }

    #[test]
    fn zero_tolerance_on_noise_keeps_everything() {
        // A random walk (fixed LCG): no three consecutive samples are collinear.
        let mut state = 12345u64;
        let mut x = 0.0;
        let samples: Vec<Key> = (0..50)
            .map(|i| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                x += 1.0 + (state >> 40) as f64 / (1u64 << 24) as f64;
                (i as f64, [if i % 2 == 0 { x } else { -x }, 0.0, 0.0])
            })
            .collect();
        let keys = reduce(&samples, 0.0);
        assert_eq!(keys.len(), samples.len());
    }

    proptest! {
        #[test]
        fn every_sample_is_reproduced_within_tolerance(
            steps in proptest::collection::vec((0.001f64..0.1, -1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0), 1..300),
            tolerance in 0.0f64..0.5,
        ) {
            let mut t = 0.0;
            let mut v = [0.0; 3];
            let samples: Vec<Key> = steps.iter().map(|&(dt, a, b, c)| {
                t += dt;
                v = [v[0] + a * 0.1, v[1] + b * 0.1, v[2] + c];
                (t, v)
            }).collect();
            let keys = reduce(&samples, tolerance);
            prop_assert_eq!(keys.first(), samples.first());
            prop_assert_eq!(keys.last(), samples.last());
            prop_assert!(keys.windows(2).all(|w| w[0].0 < w[1].0));
            prop_assert!(keys.iter().all(|k| samples.contains(k)));
            if keys.len() > 1 {
                for &(t, v) in &samples {
                    let w = interpolate(&keys, t);
                    for k in 0..3 {
                        prop_assert!((w[k] - v[k]).abs() <= tolerance + 1e-9,
                            "t={} axis {}: {} vs {}", t, k, w[k], v[k]);
                    }
                }
            }
        }
    }
}
