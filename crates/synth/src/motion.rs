//! What the performer does over time: speech-like mouth motion and head motion, both
//! deterministic functions of the seed and the time.

use crate::rng::Rng;
use crate::HeadMotion;

/// The mouth's articulation at one instant. All zero is the neutral pose (closed, relaxed).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MouthState {
    /// Jaw rotation about the hinge axis, radians (opening > 0).
    pub jaw: f64,
    /// Lip spreading (corners outward), 0..1.
    pub spread: f64,
    /// Rounding and pucker (corners inward, lips forward), 0..1.
    pub round: f64,
    /// Upper-lip raise, 0..1.
    pub raise: f64,
    /// Lower lip rolled in under the upper lip (as in "m", "b", "p"), 0..1.
    pub roll_in: f64,
}

impl MouthState {
    fn lerp(a: &Self, b: &Self, s: f64) -> Self {
        let l = |x: f64, y: f64| x + (y - x) * s;
        Self {
            jaw: l(a.jaw, b.jaw),
            spread: l(a.spread, b.spread),
            round: l(a.round, b.round),
            raise: l(a.raise, b.raise),
            roll_in: l(a.roll_in, b.roll_in),
        }
    }
}

/// Keyframed speech: syllables at 3–6 Hz in phrases separated by pauses, after a still
/// neutral lead-in.
#[derive(Debug, Clone)]
pub struct SpeechTrack {
    keys: Vec<(f64, MouthState)>,
}

impl SpeechTrack {
    pub fn new(seed: u64, neutral_s: f64, duration_s: f64) -> Self {
        let mut rng = Rng::new(seed ^ 0x5eec_4000);
        let mut keys = vec![
            (0.0, MouthState::default()),
            (neutral_s, MouthState::default()),
        ];
        let mut t = neutral_s + rng.range(0.15, 0.4);
        keys.push((t, MouthState::default()));
        while t < duration_s + 1.0 {
            let rate = rng.range(3.0, 6.0);
            let syllables = 2 + (rng.next_u64() % 8) as usize;
            let period = 1.0 / rate;
            for _ in 0..syllables {
                // Onset: a consonant, sometimes a lip closure with the lower lip rolled in.
                let bilabial = rng.unit() < 0.25;
                let onset = MouthState {
                    jaw: if bilabial { 0.0 } else { rng.range(0.01, 0.05) },
                    spread: rng.range(0.0, 0.3),
                    round: 0.0,
                    raise: rng.range(0.0, 0.2),
                    roll_in: if bilabial { rng.range(0.7, 1.0) } else { 0.0 },
                };
                // Nucleus: a vowel, spread ("ee") or rounded ("oo") or open ("ah").
                let kind = rng.unit();
                let nucleus = if kind < 0.35 {
                    MouthState {
                        jaw: rng.range(0.05, 0.12),
                        spread: rng.range(0.5, 1.0),
                        round: 0.0,
                        raise: rng.range(0.2, 0.7),
                        roll_in: 0.0,
                    }
                } else if kind < 0.6 {
                    MouthState {
                        jaw: rng.range(0.04, 0.1),
                        spread: 0.0,
                        round: rng.range(0.5, 1.0),
                        raise: rng.range(0.0, 0.3),
                        roll_in: 0.0,
                    }
                } else {
                    MouthState {
                        jaw: rng.range(0.12, 0.24),
                        spread: rng.range(0.0, 0.4),
                        round: rng.range(0.0, 0.2),
                        raise: rng.range(0.1, 0.6),
                        roll_in: 0.0,
                    }
                };
                keys.push((t + 0.2 * period, onset));
                keys.push((t + 0.6 * period, nucleus));
                t += period;
            }
            // Pause: back to rest.
            let pause = rng.range(0.25, 0.9);
            keys.push((t + 0.15, MouthState::default()));
            t += pause;
            keys.push((t, MouthState::default()));
        }
        Self { keys }
    }

    /// A track through given keys (times increasing), e.g. the mouth states of a lip-sync
    /// take's samples.
    pub fn from_keys(keys: Vec<(f64, MouthState)>) -> Self {
        assert!(!keys.is_empty(), "a speech track needs at least one key");
        Self { keys }
    }

    /// The mouth at time `t` (smooth: cosine easing between keys).
    pub fn at(&self, t: f64) -> MouthState {
        let i = self.keys.partition_point(|(kt, _)| *kt <= t);
        if i == 0 {
            return self.keys[0].1;
        }
        if i >= self.keys.len() {
            return self.keys[self.keys.len() - 1].1;
        }
        let (t0, a) = &self.keys[i - 1];
        let (t1, b) = &self.keys[i];
        let s = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0);
        let eased = 0.5 - 0.5 * (std::f64::consts::PI * s).cos();
        MouthState::lerp(a, b, eased)
    }
}

/// Head pose relative to neutral: yaw, pitch, roll (radians) and translation (m).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HeadState {
    pub yaw: f64,
    pub pitch: f64,
    pub roll: f64,
    pub translation: [f64; 3],
}

/// Smooth, bounded head motion: sums of sines with seeded phases and incommensurate periods,
/// whose amplitudes sum to the bound, faded in after the neutral lead-in.
#[derive(Debug, Clone)]
pub struct HeadTrack {
    motion: HeadMotion,
    neutral_s: f64,
    /// (period s, phase) per component, 6 channels × 3 sines.
    waves: [[(f64, f64); 3]; 6],
}

impl HeadTrack {
    pub fn new(seed: u64, motion: HeadMotion, neutral_s: f64) -> Self {
        let mut rng = Rng::new(seed ^ 0x4ead_0000);
        let mut waves = [[(1.0, 0.0); 3]; 6];
        for channel in &mut waves {
            for (k, w) in channel.iter_mut().enumerate() {
                let base = [7.3, 3.1, 1.7][k];
                *w = (
                    base * rng.range(0.8, 1.25),
                    rng.range(0.0, std::f64::consts::TAU),
                );
            }
        }
        Self {
            motion,
            neutral_s,
            waves,
        }
    }

    pub fn at(&self, t: f64) -> HeadState {
        let deg = std::f64::consts::PI / 180.0;
        // Bounds: yaw, pitch, roll (rad), x, y, z (m).
        let bounds = match self.motion {
            HeadMotion::None => return HeadState::default(),
            HeadMotion::Mild => [10.0 * deg, 3.0 * deg, 2.0 * deg, 0.005, 0.005, 0.005],
            HeadMotion::Strong | HeadMotion::Fast => {
                [30.0 * deg, 15.0 * deg, 10.0 * deg, 0.05, 0.05, 0.05]
            }
        };
        // The fast motion is the strong one on a faster clock (after the same neutral lead-in
        // and fade): every speed scaled by the same factor, the poses unchanged.
        let speed = if self.motion == HeadMotion::Fast {
            crate::FAST_HEAD_SPEEDUP
        } else {
            1.0
        };
        let fade = smoothstep(self.neutral_s, self.neutral_s + 1.0, t);
        let mut v = [0.0; 6];
        for (c, value) in v.iter_mut().enumerate() {
            let amps = [0.6, 0.3, 0.1];
            let s: f64 = self.waves[c]
                .iter()
                .zip(amps)
                .map(|((period, phase), a)| {
                    a * (std::f64::consts::TAU * speed * (t - self.neutral_s) / period + phase)
                        .sin()
                })
                .sum();
            *value = bounds[c] * fade * s;
            *value = value.clamp(-bounds[c], bounds[c]);
        }
        HeadState {
            yaw: v[0],
            pitch: v[1],
            roll: v[2],
            translation: [v[3], v[4], v[5]],
        }
    }
}

/// The jaw's slide (`--jaw-slide`): sideways, a smooth seeded motion within ±`amplitude`
/// (sums of sines, as the head's, faded in after the neutral lead-in); forward, `amplitude`
/// times how wide the mouth opens (none below 0.06 rad, all of it at 0.24 rad, the widest
/// speech opening): the condyles glide forward on wide openings.
#[derive(Debug, Clone)]
pub struct SlideTrack {
    amplitude: f64,
    neutral_s: f64,
    /// (period s, phase) of the sideways motion's three sines.
    waves: [(f64, f64); 3],
}

impl SlideTrack {
    pub fn new(seed: u64, amplitude: f64, neutral_s: f64) -> Self {
        // A stream of its own: the speech and the head are the same with or without a slide.
        let mut rng = Rng::new(seed ^ 0x511d_e000);
        let mut waves = [(1.0, 0.0); 3];
        for (k, w) in waves.iter_mut().enumerate() {
            let base = [2.3, 1.1, 0.6][k];
            *w = (
                base * rng.range(0.8, 1.25),
                rng.range(0.0, std::f64::consts::TAU),
            );
        }
        Self {
            amplitude,
            neutral_s,
            waves,
        }
    }

    /// Sideways and forward slide (metres) at time `t` with the jaw open by `jaw` radians.
    pub fn at(&self, t: f64, jaw: f64) -> [f64; 2] {
        if self.amplitude == 0.0 {
            return [0.0; 2];
        }
        let fade = smoothstep(self.neutral_s, self.neutral_s + 1.0, t);
        let side: f64 = self
            .waves
            .iter()
            .zip([0.6, 0.3, 0.1])
            .map(|((period, phase), a)| {
                a * (std::f64::consts::TAU * (t - self.neutral_s) / period + phase).sin()
            })
            .sum();
        [
            self.amplitude * fade * side,
            self.amplitude * smoothstep(0.06, 0.24, jaw),
        ]
    }
}

pub(crate) fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let s = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    s * s * (3.0 - 2.0 * s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn neutral_lead_in_is_still() {
        let speech = SpeechTrack::new(7, 1.5, 10.0);
        let head = HeadTrack::new(7, HeadMotion::Strong, 1.5);
        for i in 0..45 {
            let t = i as f64 / 30.0;
            assert_eq!(speech.at(t), MouthState::default());
            assert_eq!(head.at(t), HeadState::default());
        }
    }

    #[test]
    fn speech_moves_and_pauses_at_syllable_rates() {
        let speech = SpeechTrack::new(3, 1.5, 20.0);
        let jaw: Vec<f64> = (0..600)
            .map(|i| speech.at(1.5 + i as f64 / 30.0).jaw)
            .collect();
        let max = jaw.iter().cloned().fold(0.0, f64::max);
        assert!(max > 0.1, "the jaw opens ({max})");
        // Count openings (rising through half of the typical opening).
        let crossings = jaw
            .windows(2)
            .filter(|w| w[0] < 0.06 && w[1] >= 0.06)
            .count();
        let rate = crossings as f64 / 20.0;
        assert!((1.0..6.5).contains(&rate), "{rate} openings per second");
        assert!(
            jaw.iter().filter(|&&j| j == 0.0).count() > 10,
            "pauses return to rest"
        );
    }

    #[test]
    fn the_jaw_slides_within_its_amplitude_and_glides_forward_on_wide_openings() {
        assert_eq!(SlideTrack::new(4, 0.0, 1.5).at(3.0, 0.2), [0.0; 2]);
        let slide = SlideTrack::new(4, 0.003, 1.5);
        assert_eq!(
            slide.at(1.0, 0.0),
            [0.0; 2],
            "still during the neutral lead-in"
        );
        let mut max_side: f64 = 0.0;
        for i in 0..600 {
            let [side, fwd] = slide.at(1.5 + i as f64 / 30.0, 0.0);
            assert!(side.abs() <= 0.003 + 1e-12 && fwd == 0.0);
            max_side = max_side.max(side.abs());
        }
        assert!(max_side > 0.0015, "it slides sideways ({max_side})");
        assert_eq!(slide.at(5.0, 0.05)[1], 0.0, "no glide on a small opening");
        assert!((slide.at(5.0, 0.24)[1] - 0.003).abs() < 1e-12);
    }

    #[test]
    fn head_motion_stays_within_bounds() {
        let head = HeadTrack::new(11, HeadMotion::Strong, 1.5);
        let mut max_yaw: f64 = 0.0;
        for i in 0..3000 {
            let h = head.at(i as f64 / 30.0);
            assert!(h.yaw.abs() <= 30f64.to_radians() + 1e-12);
            assert!(h.pitch.abs() <= 15f64.to_radians() + 1e-12);
            assert!(h.translation.iter().all(|x| x.abs() <= 0.05 + 1e-12));
            max_yaw = max_yaw.max(h.yaw.abs());
        }
        assert!(
            max_yaw > 15f64.to_radians(),
            "strong motion turns the head ({max_yaw})"
        );
    }

    /// *Fast head motion*: the strong motion's poses on a clock 1.5 times as fast, so its
    /// peak yaw and pitch speeds (finite differences over 20 s, after the fade-in) are 1.5
    /// times the strong motion's, within the same bounds.
    #[test]
    fn fast_head_motion_is_the_strong_one_at_one_and_a_half_times_the_speed() {
        let (strong, fast) = (
            HeadTrack::new(11, HeadMotion::Strong, 1.5),
            HeadTrack::new(11, HeadMotion::Fast, 1.5),
        );
        // Strong from 3.0 s and fast from 2.5 s (both faded in) run through the same poses.
        let fast_t = |t: f64| 1.5 + (t - 1.5) / crate::FAST_HEAD_SPEEDUP;
        let (dt, mut most) = (1e-5, [[0.0f64; 2]; 2]);
        for i in 0..4000 {
            let t = 3.0 + i as f64 * 0.005;
            let pose = fast.at(fast_t(t));
            assert!((pose.yaw - strong.at(t).yaw).abs() < 1e-12);
            assert!((pose.pitch - strong.at(t).pitch).abs() < 1e-12);
            for (k, (head, t)) in [(&strong, t), (&fast, fast_t(t))].into_iter().enumerate() {
                let (a, b) = (head.at(t), head.at(t + dt));
                most[k][0] = most[k][0].max((b.yaw - a.yaw).abs() / dt);
                most[k][1] = most[k][1].max((b.pitch - a.pitch).abs() / dt);
            }
        }
        for (axis, (fast, strong)) in most[1].iter().zip(&most[0]).enumerate() {
            let ratio = fast / strong;
            assert!((ratio - 1.5).abs() < 1e-3, "axis {axis}: {ratio}");
        }
    }
}
