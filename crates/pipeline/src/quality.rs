//! How good a neutral pose is: the lip wobble over the frames it was averaged from (the
//! calibration report on the console), from a short history of the tracked dots.

use std::collections::VecDeque;

use mouthpiece_retarget::kabsch::kabsch;
use mouthpiece_retarget::{NeutralPose, Vec3};

/// The last frames' dots in the camera frame (lip, then forehead), kept so that a new
/// neutral pose can be judged on the frames it was averaged from. Buffers are recycled.
#[derive(Debug, Default)]
pub struct DotHistory {
    entries: VecDeque<(f64, Vec<Option<Vec3>>)>,
    spare: Vec<Vec<Option<Vec3>>>,
}

impl DotHistory {
    /// Adds this frame's dots (time `t`, seconds) and forgets frames older than `keep_s`.
    pub fn push(&mut self, t: f64, dots: impl Iterator<Item = Option<Vec3>>, keep_s: f64) {
        while self
            .entries
            .front()
            .is_some_and(|(t0, _)| t - t0 > keep_s || *t0 > t)
        {
            if let Some((_, v)) = self.entries.pop_front() {
                self.spare.push(v);
            }
        }
        let mut v = self.spare.pop().unwrap_or_default();
        v.clear();
        v.extend(dots);
        self.entries.push_back((t, v));
    }

    /// The newest `n` frames, oldest first.
    pub fn last(&self, n: usize) -> impl Iterator<Item = &[Option<Vec3>]> {
        let skip = self.entries.len().saturating_sub(n);
        self.entries.iter().skip(skip).map(|(_, v)| v.as_slice())
    }
}

/// Lip wobble: RMS distance (metres) of the lip dots from their neutral places over the
/// frames a neutral pose was averaged from, each frame first carried onto the neutral head
/// (its forehead dots fitted rigidly onto the neutral forehead, so the head's own motion
/// does not count). Each frame lists the lip dots, then the forehead dots. `None` when no
/// frame had all dots and a forehead to fit.
pub fn lip_wobble<'a>(
    neutral: &NeutralPose,
    frames: impl Iterator<Item = &'a [Option<Vec3>]>,
) -> Option<f64> {
    let n = neutral.lip_camera.len();
    let mut sum = 0.0;
    let mut count = 0usize;
    let mut from = Vec::new();
    let mut to = Vec::new();
    for frame in frames {
        from.clear();
        to.clear();
        for (seen, reference) in frame.iter().skip(n).zip(&neutral.forehead_camera) {
            if let (Some(s), Some(r)) = (seen, reference) {
                from.push(*s);
                to.push(*r);
            }
        }
        let Some(head) = kabsch(&from, &to) else {
            continue;
        };
        for (seen, rest) in frame.iter().take(n).zip(&neutral.lip_camera) {
            if let Some(p) = seen {
                sum += (head.apply(p) - rest).norm_squared();
                count += 1;
            }
        }
    }
    (count > 0).then(|| (sum / count as f64).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;
    use mouthpiece_retarget::{PerformerLayout, RigidTransform};
    use nalgebra::{Rotation3, Vector3};

    #[test]
    fn lip_wobble_is_the_lip_jitter_with_head_motion_removed() {
        let layout = PerformerLayout {
            lip_dots: 4,
            forehead_dots: 3,
        };
        let lip = [
            Vector3::new(-0.025, 0.0, 0.6),
            Vector3::new(0.0, -0.008, 0.59),
            Vector3::new(0.025, 0.0, 0.6),
            Vector3::new(0.0, 0.008, 0.59),
        ];
        let forehead = [
            Vector3::new(-0.035, -0.09, 0.62),
            Vector3::new(0.035, -0.09, 0.62),
            Vector3::new(0.0, -0.13, 0.63),
        ];
        let neutral = NeutralPose::from_positions(
            layout,
            lip.iter().map(|p| Some(*p)).collect(),
            forehead.iter().map(|p| Some(*p)).collect(),
            20,
        )
        .unwrap();
        // 20 frames: the head turns up to 6 degrees and moves, each lip dot is off its rest
        // place by exactly 0.5 mm in a varying direction.
        let mut history = DotHistory::default();
        for i in 0..20 {
            let a = 0.1 * (i as f64 / 3.0).sin();
            let head = RigidTransform {
                rotation: *Rotation3::from_euler_angles(0.3 * a, a, 0.0).matrix(),
                translation: Vector3::new(0.01 * a, 0.0, 0.005),
            };
            let jitter = |k: usize| {
                let phi = (i * 7 + k * 3) as f64;
                Vector3::new(phi.cos(), phi.sin(), 0.0) * 0.0005
            };
            let dots: Vec<Option<Vec3>> = lip
                .iter()
                .enumerate()
                .map(|(k, p)| Some(head.apply(&(p + jitter(k)))))
                .chain(forehead.iter().map(|p| Some(head.apply(p))))
                .collect();
            history.push(i as f64 / 30.0, dots.into_iter(), 2.0);
        }
        let wobble = lip_wobble(&neutral, history.last(20)).unwrap();
        assert!((wobble - 0.0005).abs() < 1e-6, "{wobble}");
        // Without the head's motion removed the figure would be far larger: the fit matters.
        assert!(lip_wobble(&neutral, history.last(0)).is_none());
    }

    #[test]
    fn history_keeps_only_recent_frames_and_recycles() {
        let mut h = DotHistory::default();
        for i in 0..100 {
            h.push(f64::from(i) * 0.1, std::iter::once(None), 1.0);
        }
        assert_eq!(h.last(usize::MAX).count(), 11);
        assert!(h.spare.len() <= 1);
    }
}
