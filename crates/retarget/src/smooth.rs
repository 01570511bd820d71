//! Shape smoothing across the points of one time step (docs/method.md §8). The points, in order
//! around the mouth, form a closed loop; every method here wraps around it. The result is the
//! `curve` output; the points themselves stay unsmoothed.

use crate::{Error, Vec3};

/// Savitzky–Golay, 5 points, quadratic: weights for offsets −2..=2.
pub const SAVITZKY_GOLAY_5: [f64; 5] = [
    -3.0 / 35.0,
    12.0 / 35.0,
    17.0 / 35.0,
    12.0 / 35.0,
    -3.0 / 35.0,
];

/// Largest moving-average radius: each curve point costs `2 · radius + 1` terms, and a
/// radius past half the loop (at most [`crate::layout::MAX_DOT_NUMBER`] points) only wraps
/// around it again.
pub const MAX_MA_RADIUS: usize = crate::layout::MAX_DOT_NUMBER.div_ceil(2);
/// Most B-spline samples per span: the curve has this many points per character point.
pub const MAX_SAMPLES_PER_SPAN: usize = 64;

/// Weights of the moving average's neighbours.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MovingAverageKind {
    /// Equal weights.
    Plain,
    /// Triangular: weight `radius + 1 − |j|` for offset `j`.
    Weighted,
    /// Weight `alpha^|j|` for offset `j` (0 < alpha ≤ 1).
    Exponential {
        /// Decay per step along the loop.
        alpha: f64,
    },
}

/// Which smoothing makes the `curve`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum ShapeSmoothing {
    /// No curve.
    #[default]
    None,
    /// Moving average over the `radius` neighbours on each side.
    MovingAverage {
        /// Neighbour weights.
        kind: MovingAverageKind,
        /// Neighbours on each side (≥ 1).
        radius: usize,
    },
    /// Savitzky–Golay 5-point quadratic.
    SavitzkyGolay5,
    /// Closed uniform cubic B-spline with the points as control points, sampled
    /// `samples_per_span` times per span (one span per point).
    BSpline {
        /// Samples per span (≥ 1).
        samples_per_span: usize,
    },
}

impl ShapeSmoothing {
    /// Short name used on the wire (`curve.method`): `ma`, `ma-weighted`, `ma-exp`, `sg5`,
    /// `bspline`; `none` when off.
    pub fn name(&self) -> &'static str {
        match self {
            ShapeSmoothing::None => "none",
            ShapeSmoothing::MovingAverage {
                kind: MovingAverageKind::Plain,
                ..
            } => "ma",
            ShapeSmoothing::MovingAverage {
                kind: MovingAverageKind::Weighted,
                ..
            } => "ma-weighted",
            ShapeSmoothing::MovingAverage {
                kind: MovingAverageKind::Exponential { .. },
                ..
            } => "ma-exp",
            ShapeSmoothing::SavitzkyGolay5 => "sg5",
            ShapeSmoothing::BSpline { .. } => "bspline",
        }
    }

    /// Checks the parameters.
    pub fn validate(&self) -> Result<(), Error> {
        match *self {
            ShapeSmoothing::MovingAverage { radius, .. }
                if radius == 0 || radius > MAX_MA_RADIUS =>
            {
                Err(Error::InvalidConfig {
                    key: "smooth.radius",
                    reason: format!("must be from 1 to {MAX_MA_RADIUS}, got {radius}"),
                })
            }
            ShapeSmoothing::MovingAverage {
                kind: MovingAverageKind::Exponential { alpha },
                ..
            } if !(alpha > 0.0 && alpha <= 1.0) => Err(Error::InvalidConfig {
                key: "smooth.alpha",
                reason: format!("must be in (0, 1], got {alpha}"),
            }),
            ShapeSmoothing::BSpline { samples_per_span }
                if samples_per_span == 0 || samples_per_span > MAX_SAMPLES_PER_SPAN =>
            {
                Err(Error::InvalidConfig {
                    key: "smooth.samples_per_span",
                    reason: format!(
                        "must be from 1 to {MAX_SAMPLES_PER_SPAN}, got {samples_per_span}"
                    ),
                })
            }
            _ => Ok(()),
        }
    }

    /// Number of curve points for a loop of `n` points.
    pub fn curve_len(&self, n: usize) -> usize {
        match *self {
            ShapeSmoothing::None => 0,
            ShapeSmoothing::BSpline { samples_per_span } => n * samples_per_span,
            _ => n,
        }
    }
}

/// Smooths the closed loop `points` into `out` (cleared first; no allocation once `out` has
/// grown to size).
pub fn smooth_closed(points: &[Vec3], method: &ShapeSmoothing, out: &mut Vec<Vec3>) {
    out.clear();
    let n = points.len();
    if n == 0 {
        return;
    }
    let at = |i: isize| points[i.rem_euclid(n as isize) as usize];
    match *method {
        ShapeSmoothing::None => {}
        ShapeSmoothing::MovingAverage { kind, radius } => {
            let r = radius as isize;
            let weight = |j: isize| match kind {
                MovingAverageKind::Plain => 1.0,
                MovingAverageKind::Weighted => (r + 1 - j.abs()) as f64,
                MovingAverageKind::Exponential { alpha } => alpha.powi(j.abs() as i32),
            };
            let total: f64 = (-r..=r).map(weight).sum();
            for i in 0..n as isize {
                let sum: Vec3 = (-r..=r).map(|j| at(i + j) * weight(j)).sum();
                out.push(sum / total);
            }
        }
        ShapeSmoothing::SavitzkyGolay5 => {
            for i in 0..n as isize {
                let sum: Vec3 = (-2..=2)
                    .map(|j| at(i + j) * SAVITZKY_GOLAY_5[(j + 2) as usize])
                    .sum();
                out.push(sum);
            }
        }
        ShapeSmoothing::BSpline { samples_per_span } => {
            for i in 0..n as isize {
                let (p0, p1, p2, p3) = (at(i - 1), at(i), at(i + 1), at(i + 2));
                for s in 0..samples_per_span {
                    let b = bspline_basis(s as f64 / samples_per_span as f64);
                    out.push(p0 * b[0] + p1 * b[1] + p2 * b[2] + p3 * b[3]);
                }
            }
        }
    }
}

/// Uniform cubic B-spline basis at `u ∈ [0, 1)`: (1/6)[(1−u)³, 3u³−6u²+4, −3u³+3u²+3u+1, u³].
pub fn bspline_basis(u: f64) -> [f64; 4] {
    let (u2, u3) = (u * u, u * u * u);
    let v = 1.0 - u;
    [
        v * v * v / 6.0,
        (3.0 * u3 - 6.0 * u2 + 4.0) / 6.0,
        (-3.0 * u3 + 3.0 * u2 + 3.0 * u + 1.0) / 6.0,
        u3 / 6.0,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn ring(n: usize) -> Vec<Vec3> {
        (0..n)
            .map(|i| {
                let a = i as f64 / n as f64 * std::f64::consts::TAU;
                Vec3::new(a.cos(), a.sin(), 0.1 * (3.0 * a).sin())
            })
            .collect()
    }

    #[test]
    fn constants_are_preserved() {
        let pts = vec![Vec3::new(1.0, 2.0, 3.0); 12];
        for m in [
            ShapeSmoothing::MovingAverage {
                kind: MovingAverageKind::Plain,
                radius: 2,
            },
            ShapeSmoothing::MovingAverage {
                kind: MovingAverageKind::Weighted,
                radius: 3,
            },
            ShapeSmoothing::MovingAverage {
                kind: MovingAverageKind::Exponential { alpha: 0.5 },
                radius: 2,
            },
            ShapeSmoothing::SavitzkyGolay5,
            ShapeSmoothing::BSpline {
                samples_per_span: 4,
            },
        ] {
            let mut out = Vec::new();
            smooth_closed(&pts, &m, &mut out);
            assert_eq!(out.len(), m.curve_len(12));
            for p in out {
                assert_relative_eq!(p, pts[0], epsilon = 1e-12);
            }
        }
    }

    #[test]
    fn basis_sums_to_one() {
        for i in 0..10 {
            let b = bspline_basis(i as f64 / 10.0);
            assert_relative_eq!(b.iter().sum::<f64>(), 1.0, epsilon = 1e-15);
        }
    }

    #[test]
    fn weighted_average_by_hand() {
        let pts: Vec<Vec3> = (0..6).map(|i| Vec3::new(i as f64, 0.0, 0.0)).collect();
        let mut out = Vec::new();
        let m = ShapeSmoothing::MovingAverage {
            kind: MovingAverageKind::Weighted,
            radius: 1,
        };
        smooth_closed(&pts, &m, &mut out);
        // point 0: neighbours 5 (w1), 0 (w2), 1 (w1) → (5 + 0 + 1) / 4
        assert_relative_eq!(out[0].x, 1.5);
        assert_relative_eq!(out[2].x, 2.0);
        let m = ShapeSmoothing::MovingAverage {
            kind: MovingAverageKind::Exponential { alpha: 0.5 },
            radius: 1,
        };
        smooth_closed(&pts, &m, &mut out);
        assert_relative_eq!(out[0].x, (5.0 * 0.5 + 1.0 * 0.5) / 2.0);
        let _ = ring(4);
    }

    #[test]
    fn bad_parameters_are_refused() {
        assert!(ShapeSmoothing::BSpline {
            samples_per_span: 0
        }
        .validate()
        .is_err());
        assert!(ShapeSmoothing::MovingAverage {
            kind: MovingAverageKind::Plain,
            radius: 0
        }
        .validate()
        .is_err());
        assert!(ShapeSmoothing::MovingAverage {
            kind: MovingAverageKind::Exponential { alpha: 1.5 },
            radius: 1
        }
        .validate()
        .is_err());
    }
}
