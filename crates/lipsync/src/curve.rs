//! Stage curves: a weight over a stage's normalised time u ∈ [0, 1], given by control points
//! and interpolated by a monotone cubic Hermite spline (PCHIP, Fritsch–Butland interior
//! slopes) whose slope is 0 at both ends.
//!
//! Why this curve: it is C¹, it never overshoots its control points (weights stay within the
//! range the designer drew, so a mouth never opens past its pose), and the flat ends make every
//! join C¹ whatever the time scaling of the stage: the mapping stretches stable stages, which
//! would break any non-zero slope matching at a join.

/// Why control points do not make a stage curve.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CurveError {
    #[error("needs at least 2 control points, got {0}")]
    TooFew(usize),
    #[error("control points must run from u = 0 to u = 1")]
    Ends,
    #[error("control point {0} is not finite")]
    NotFinite(usize),
    #[error("control point {0}: u must increase")]
    NotIncreasing(usize),
}

/// A stage curve.
#[derive(Debug, Clone, PartialEq)]
pub struct StageCurve {
    u: Vec<f64>,
    w: Vec<f64>,
    /// Slope dw/du at each control point.
    m: Vec<f64>,
}

impl StageCurve {
    /// A constant.
    pub fn constant(w: f64) -> Self {
        Self {
            u: vec![0.0, 1.0],
            w: vec![w, w],
            m: vec![0.0, 0.0],
        }
    }

    /// From control points `(u, w)`: at least two, u strictly increasing from 0 to 1, w finite.
    pub fn from_points(points: &[(f64, f64)]) -> Result<Self, CurveError> {
        if points.len() < 2 {
            return Err(CurveError::TooFew(points.len()));
        }
        if points[0].0 != 0.0 || points[points.len() - 1].0 != 1.0 {
            return Err(CurveError::Ends);
        }
        for (i, p) in points.iter().enumerate() {
            if !(p.0.is_finite() && p.1.is_finite()) {
                return Err(CurveError::NotFinite(i));
            }
            if i > 0 && p.0 <= points[i - 1].0 {
                return Err(CurveError::NotIncreasing(i));
            }
        }
        let u: Vec<f64> = points.iter().map(|p| p.0).collect();
        let w: Vec<f64> = points.iter().map(|p| p.1).collect();
        let n = u.len();
        let mut m = vec![0.0; n];
        for k in 1..n - 1 {
            let (h0, h1) = (u[k] - u[k - 1], u[k + 1] - u[k]);
            let (d0, d1) = ((w[k] - w[k - 1]) / h0, (w[k + 1] - w[k]) / h1);
            if d0 * d1 > 0.0 {
                let (w1, w2) = (2.0 * h1 + h0, h1 + 2.0 * h0);
                m[k] = (w1 + w2) / (w1 / d0 + w2 / d1);
            }
        }
        Ok(Self { u, w, m })
    }

    /// Value at the start.
    pub fn first(&self) -> f64 {
        self.w[0]
    }

    /// Value at the end.
    pub fn last(&self) -> f64 {
        self.w[self.w.len() - 1]
    }

    /// Control points.
    pub fn points(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        self.u.iter().copied().zip(self.w.iter().copied())
    }

    /// The weight at `u` (clamped to [0, 1]).
    pub fn at(&self, u: f64) -> f64 {
        let u = u.clamp(0.0, 1.0);
        let n = self.u.len();
        // Segment k: u[k] ≤ u ≤ u[k+1].
        let k = self.u[1..n - 1].partition_point(|&x| x <= u);
        let h = self.u[k + 1] - self.u[k];
        let s = (u - self.u[k]) / h;
        let (s2, s3) = (s * s, s * s * s);
        let h00 = 2.0 * s3 - 3.0 * s2 + 1.0;
        let h10 = s3 - 2.0 * s2 + s;
        let h01 = -2.0 * s3 + 3.0 * s2;
        let h11 = s3 - s2;
        h00 * self.w[k] + h10 * h * self.m[k] + h01 * self.w[k + 1] + h11 * h * self.m[k + 1]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_points_are_a_smoothstep() {
        let c = StageCurve::from_points(&[(0.0, 0.2), (1.0, 0.8)]).unwrap();
        for i in 0..=10 {
            let u = i as f64 / 10.0;
            let s = u * u * (3.0 - 2.0 * u);
            assert!((c.at(u) - (0.2 + 0.6 * s)).abs() < 1e-15);
        }
    }

    #[test]
    fn passes_through_points_without_overshoot_and_is_c1() {
        let pts = [(0.0, 0.0), (0.3, 0.9), (0.5, 1.0), (0.8, 0.2), (1.0, 0.25)];
        let c = StageCurve::from_points(&pts).unwrap();
        for &(u, w) in &pts {
            assert!((c.at(u) - w).abs() < 1e-15);
        }
        let n = 20_000;
        let mut prev_slope = 0.0;
        for i in 0..n {
            let (a, b) = (i as f64 / n as f64, (i + 1) as f64 / n as f64);
            let (wa, wb) = (c.at(a), c.at(b));
            assert!(
                (-1e-12..=1.0 + 1e-12).contains(&wa),
                "overshoot {wa} at {a}"
            );
            let slope = (wb - wa) * n as f64;
            // C¹: no slope jumps between neighbouring steps (second derivative is bounded).
            assert!((slope - prev_slope).abs() < 0.05, "slope jump at {a}");
            prev_slope = slope;
        }
        // Flat ends.
        assert!((c.at(1e-6) - c.at(0.0)).abs() < 1e-9);
        assert!((c.at(1.0) - c.at(1.0 - 1e-6)).abs() < 1e-9);
    }

    #[test]
    fn rejects_bad_points() {
        assert!(StageCurve::from_points(&[(0.0, 1.0)]).is_err());
        assert!(StageCurve::from_points(&[(0.1, 1.0), (1.0, 1.0)]).is_err());
        assert!(
            StageCurve::from_points(&[(0.0, 1.0), (0.5, 1.0), (0.5, 1.0), (1.0, 0.0)]).is_err()
        );
        assert!(StageCurve::from_points(&[(0.0, f64::NAN), (1.0, 1.0)]).is_err());
    }
}
