//! The performer's neutral pose (docs/method.md §3): per-dot robust averages over the calibration
//! frames, the forehead reference shape, and the performer's mouth frame.

use crate::kabsch::spans_plane;
use crate::layout::{PerformerDots, PerformerLayout};
use crate::{Error, MouthFrame, Vec3};

/// The neutral pose of a performer.
#[derive(Debug, Clone, PartialEq)]
pub struct NeutralPose {
    /// The dot layout it was taken with.
    pub layout: PerformerLayout,
    /// `D⁰` in the camera frame, per lip dot.
    pub lip_camera: Vec<Vec3>,
    /// The forehead reference shape in the camera frame; `None` for a forehead dot never seen
    /// (it is then ignored for head tracking).
    pub forehead_camera: Vec<Option<Vec3>>,
    /// The performer's mouth frame in the camera frame.
    pub frame: MouthFrame,
    /// `D⁰` in the mouth frame, per lip dot.
    pub lip: Vec<Vec3>,
    /// Number of frames averaged.
    pub frames: usize,
}

impl NeutralPose {
    /// The neutral pose from already-averaged positions (camera frame). Fails like
    /// [`NeutralAccumulator::finish`].
    pub fn from_positions(
        layout: PerformerLayout,
        lip_camera: Vec<Option<Vec3>>,
        forehead_camera: Vec<Option<Vec3>>,
        frames: usize,
    ) -> Result<Self, Error> {
        let mut lip = Vec::with_capacity(lip_camera.len());
        for (i, p) in lip_camera.iter().enumerate() {
            lip.push(p.ok_or_else(|| Error::NeutralMissingDot {
                dot: PerformerLayout::lip_name(i),
            })?);
        }
        let seen: Vec<Vec3> = forehead_camera.iter().flatten().copied().collect();
        if !spans_plane(&seen) {
            return Err(Error::NeutralForehead {
                seen: seen.len(),
                collinear: seen.len() >= 3,
            });
        }
        let left = lip[layout.left_corner()];
        let right = lip[layout.right_corner()];
        let forehead_centroid = seen.iter().sum::<Vec3>() / seen.len() as f64;
        let up = forehead_centroid - (left + right) * 0.5;
        let frame = MouthFrame::from_corners(left, right, up).map_err(|e| match e {
            Error::CoincidentCorners { .. } => Error::CoincidentCorners {
                left: PerformerLayout::lip_name(layout.left_corner()),
                right: PerformerLayout::lip_name(layout.right_corner()),
            },
            other => other,
        })?;
        let lip_mouth = lip.iter().map(|p| frame.to_mouth(p)).collect();
        Ok(Self {
            layout,
            lip_camera: lip,
            forehead_camera,
            frame,
            lip: lip_mouth,
            frames,
        })
    }

    /// Performer neutral mouth width (corner to corner), metres.
    pub fn mouth_width(&self) -> f64 {
        self.frame.width
    }
}

/// Collects the calibration frames and averages them robustly.
///
/// The performer's head need not be still while the mouth rests: before averaging, each
/// frame is carried onto a common head pose (its forehead dots fitted rigidly onto the
/// average forehead, twice), so that a head turning a little during the calibration second
/// neither blurs the neutral shape nor bends the forehead reference out of rigid.
#[derive(Debug, Clone)]
pub struct NeutralAccumulator {
    layout: PerformerLayout,
    frames: Vec<PerformerDots>,
}

impl NeutralAccumulator {
    /// An empty accumulator for a layout.
    pub fn new(layout: PerformerLayout) -> Self {
        Self {
            layout,
            frames: Vec::new(),
        }
    }

    /// Adds one calibration frame.
    pub fn push(&mut self, dots: &PerformerDots) -> Result<(), Error> {
        dots.check(self.layout)?;
        self.frames.push(dots.clone());
        Ok(())
    }

    /// Frames pushed so far.
    pub fn frames(&self) -> usize {
        self.frames.len()
    }

    /// The neutral pose: each dot's robust mean over the head-registered frames; every lip dot
    /// must have been seen, and at least 3 non-collinear forehead dots.
    pub fn finish(&self) -> Result<NeutralPose, Error> {
        if self.frames.is_empty() {
            return Err(Error::NeutralEmpty);
        }
        // Empty: the frames as pushed (no head motion could be measured in any).
        let mut registered: Vec<PerformerDots> = Vec::new();
        let mut reference = self.mean_forehead(&self.frames);
        for _ in 0..2 {
            let seen: Vec<Vec3> = reference.iter().flatten().copied().collect();
            if !spans_plane(&seen) {
                break;
            }
            registered = self
                .frames
                .iter()
                .filter_map(|frame| {
                    let (from, to): (Vec<Vec3>, Vec<Vec3>) = frame
                        .forehead
                        .iter()
                        .zip(&reference)
                        .filter_map(|(p, r)| Some(((*p)?, (*r)?)))
                        .unzip();
                    // A frame whose head motion cannot be measured cannot be registered.
                    let motion = crate::kabsch::kabsch(&from, &to)?;
                    let carry = |d: &Option<Vec3>| d.map(|p| motion.apply(&p));
                    Some(PerformerDots {
                        lip: frame.lip.iter().map(carry).collect(),
                        forehead: frame.forehead.iter().map(carry).collect(),
                    })
                })
                .collect();
            if registered.is_empty() {
                break;
            }
            reference = self.mean_forehead(&registered);
        }
        let frames = if registered.is_empty() {
            &self.frames
        } else {
            &registered
        };
        let lip = means(frames, self.layout.lip_dots, |f, i| f.lip[i]);
        NeutralPose::from_positions(self.layout, lip, reference, self.frames.len())
    }

    fn mean_forehead(&self, frames: &[PerformerDots]) -> Vec<Option<Vec3>> {
        means(frames, self.layout.forehead_dots, |f, j| f.forehead[j])
    }
}

/// Per dot `0..count`, the robust mean of its positions over the frames that saw it.
fn means(
    frames: &[PerformerDots],
    count: usize,
    dot: impl Fn(&PerformerDots, usize) -> Option<Vec3>,
) -> Vec<Option<Vec3>> {
    (0..count)
        .map(|i| robust_mean(&frames.iter().filter_map(|f| dot(f, i)).collect::<Vec<_>>()))
        .collect()
}

/// Mean of the samples after rejecting outliers: a sample is dropped when, on any axis, it is
/// further than 3 MAD (median absolute deviation, unscaled) from that axis' median. `None`
/// for no samples.
pub fn robust_mean(samples: &[Vec3]) -> Option<Vec3> {
    if samples.is_empty() {
        return None;
    }
    let mut scratch = Vec::with_capacity(samples.len());
    let mut median = Vec3::zeros();
    let mut limit = Vec3::zeros();
    for k in 0..3 {
        scratch.clear();
        scratch.extend(samples.iter().map(|p| p[k]));
        let m = median_of(&mut scratch);
        scratch.clear();
        scratch.extend(samples.iter().map(|p| (p[k] - m).abs()));
        median[k] = m;
        limit[k] = 3.0 * median_of(&mut scratch);
    }
    let mut sum = Vec3::zeros();
    let mut count = 0usize;
    for p in samples {
        if (0..3).all(|k| (p[k] - median[k]).abs() <= limit[k]) {
            sum += p;
            count += 1;
        }
    }
    // At least half the samples lie within one MAD of the median on each axis, but not
    // necessarily on all three at once; fall back to the median if everything was rejected.
    Some(if count > 0 {
        sum / count as f64
    } else {
        median
    })
}

/// Median (mean of the two middle values for an even count). Reorders `v`.
fn median_of(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn outliers_are_rejected() {
        let mut s: Vec<Vec3> = (0..9)
            .map(|i| Vec3::new(1.0 + 0.001 * (i as f64 - 4.0), 2.0, 3.0))
            .collect();
        s.push(Vec3::new(5.0, 2.0, 3.0));
        let m = robust_mean(&s).unwrap();
        assert_relative_eq!(m, Vec3::new(1.0, 2.0, 3.0), epsilon = 1e-12);
    }

    #[test]
    fn missing_corner_is_an_error() {
        let layout = PerformerLayout::default();
        let mut acc = NeutralAccumulator::new(layout);
        let mut dots = PerformerDots::new(layout);
        for (i, d) in dots.lip.iter_mut().enumerate() {
            *d = Some(Vec3::new(i as f64 * 0.01, 0.0, 0.6));
        }
        dots.lip[6] = None;
        dots.forehead = vec![
            Some(Vec3::new(0.0, -0.1, 0.6)),
            Some(Vec3::new(0.05, -0.1, 0.6)),
            Some(Vec3::new(0.0, -0.12, 0.61)),
        ];
        acc.push(&dots).unwrap();
        assert!(matches!(acc.finish(), Err(Error::NeutralMissingDot { dot }) if dot == "D7"));
    }

    #[test]
    fn a_head_turning_during_calibration_leaves_the_neutral_shape_rigid() {
        use nalgebra::{Rotation3, Vector3};
        let layout = PerformerLayout::default();
        // A face at rest: lips on an ellipse, forehead above, at 0.6 m.
        let lip: Vec<Vec3> = (0..layout.lip_dots)
            .map(|i| {
                let a = std::f64::consts::TAU * i as f64 / layout.lip_dots as f64;
                Vec3::new(0.025 * a.cos(), 0.01 * a.sin(), 0.6 + 0.005 * a.sin().abs())
            })
            .collect();
        let forehead = vec![
            Vec3::new(0.03, -0.1, 0.605),
            Vec3::new(0.0, -0.118, 0.6),
            Vec3::new(-0.03, -0.1, 0.605),
        ];
        let pivot = Vec3::new(0.0, 0.0, 0.7);
        let mut acc = NeutralAccumulator::new(layout);
        // The head turns 4° one way over the window and back a little: averaging the raw
        // positions would shrink the mouth and bend the forehead.
        for k in 0..30 {
            let yaw = (4.0 * (k as f64 / 29.0) - 1.0 * (k as f64 / 29.0).powi(3)).to_radians();
            let r = Rotation3::from_axis_angle(&Vector3::y_axis(), yaw);
            let carry = |p: &Vec3| Some(r * (p - pivot) + pivot);
            acc.push(&PerformerDots {
                lip: lip.iter().map(carry).collect(),
                forehead: forehead.iter().map(carry).collect(),
            })
            .unwrap();
        }
        let neutral = acc.finish().unwrap();
        // Rigid: every distance of the true shape is kept.
        let all = |l: &[Vec3], f: &[Vec3]| l.iter().chain(f).copied().collect::<Vec<_>>();
        let truth = all(&lip, &forehead);
        let got = all(
            &neutral.lip_camera,
            &neutral
                .forehead_camera
                .iter()
                .map(|p| p.unwrap())
                .collect::<Vec<_>>(),
        );
        for a in 0..truth.len() {
            for b in a + 1..truth.len() {
                let d = ((truth[a] - truth[b]).norm() - (got[a] - got[b]).norm()).abs();
                assert!(d < 1e-9, "distance {a}-{b} off by {d}");
            }
        }
        assert_relative_eq!(
            neutral.mouth_width(),
            (lip[0] - lip[layout.right_corner()]).norm(),
            epsilon = 1e-9
        );
    }
}
