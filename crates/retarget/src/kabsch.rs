//! Rigid alignment of two point sets by least squares (docs/method.md §4): Kabsch with the
//! reflection fix, i.e. Umeyama without scale.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion};

use crate::Vec3;

/// A rigid motion `p ↦ R p + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidTransform {
    /// Rotation matrix (orthonormal, det +1).
    pub rotation: Matrix3<f64>,
    /// Translation.
    pub translation: Vec3,
}

impl Default for RigidTransform {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl RigidTransform {
    /// No motion.
    pub const IDENTITY: Self = Self {
        rotation: Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        translation: Vec3::new(0.0, 0.0, 0.0),
    };

    /// Applies the motion to a point.
    pub fn apply(&self, p: &Vec3) -> Vec3 {
        self.rotation * p + self.translation
    }

    /// The inverse motion.
    pub fn inverse(&self) -> Self {
        let rt = self.rotation.transpose();
        Self {
            rotation: rt,
            translation: -(rt * self.translation),
        }
    }

    /// The rotation as a unit quaternion `[w, x, y, z]`, with `w >= 0`.
    pub fn quaternion_wxyz(&self) -> [f64; 4] {
        let q =
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(self.rotation));
        let q = q.quaternion();
        let sign = if q.w < 0.0 { -1.0 } else { 1.0 };
        [sign * q.w, sign * q.i, sign * q.j, sign * q.k]
    }
}

/// Relative spread below which a point set counts as collinear (ratio of the second to the
/// largest singular value of the centred points).
const COLLINEAR: f64 = 1e-6;

/// Whether the points span a plane (at least 3 of them, not collinear).
pub fn spans_plane(points: &[Vec3]) -> bool {
    if points.len() < 3 {
        return false;
    }
    let centroid = centroid(points);
    let mut cov = Matrix3::zeros();
    for p in points {
        let d = p - centroid;
        cov += d * d.transpose();
    }
    if !cov.iter().all(|v| v.is_finite()) {
        return false;
    }
    let mut s = cov.symmetric_eigenvalues();
    s.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
    // Eigenvalues of the scatter matrix are squared singular values.
    s[0] > 0.0 && s[1].max(0.0).sqrt() > COLLINEAR * s[0].sqrt()
}

fn centroid(points: &[Vec3]) -> Vec3 {
    points.iter().sum::<Vec3>() / points.len() as f64
}

/// The rigid motion that best maps `from[i]` onto `to[i]` in the least-squares sense, or
/// `None` when the correspondence does not determine a rotation (fewer than 3 pairs, or
/// collinear points).
pub fn kabsch(from: &[Vec3], to: &[Vec3]) -> Option<RigidTransform> {
    assert_eq!(from.len(), to.len(), "kabsch needs paired points");
    if !spans_plane(from) || !spans_plane(to) {
        return None;
    }
    let cf = centroid(from);
    let ct = centroid(to);
    let mut h = Matrix3::zeros();
    for (a, b) in from.iter().zip(to) {
        h += (a - cf) * (b - ct).transpose();
    }
    // Products of huge coordinates overflow to inf and NaN, on which the SVD never converges.
    if !h.iter().all(|v| v.is_finite()) {
        return None;
    }
    let svd = h.svd(true, true);
    let u = svd.u?;
    let v = svd.v_t?.transpose();
    let d = (v * u.transpose()).determinant().signum();
    let fix = Matrix3::from_diagonal(&Vec3::new(1.0, 1.0, d));
    let rotation = v * fix * u.transpose();
    Some(RigidTransform {
        rotation,
        translation: ct - rotation * cf,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn recovers_a_known_motion() {
        let r = Rotation3::from_euler_angles(0.3, -0.2, 1.1).into_inner();
        let t = Vec3::new(0.1, -0.05, 0.02);
        let from = [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.1, 0.0, 0.0),
            Vec3::new(0.0, 0.07, 0.01),
        ];
        let to: Vec<Vec3> = from.iter().map(|p| r * p + t).collect();
        let m = kabsch(&from, &to).unwrap();
        assert_relative_eq!(m.rotation, r, epsilon = 1e-12);
        assert_relative_eq!(m.translation, t, epsilon = 1e-12);
    }

    #[test]
    fn mirror_images_still_give_a_rotation() {
        let from = [Vec3::x(), Vec3::y(), Vec3::z(), Vec3::new(0.5, 0.5, 0.9)];
        let to: Vec<Vec3> = from.iter().map(|p| Vec3::new(-p.x, p.y, p.z)).collect();
        let m = kabsch(&from, &to).unwrap();
        assert_relative_eq!(m.rotation.determinant(), 1.0, epsilon = 1e-12);
    }

    #[test]
    fn collinear_points_are_refused() {
        let from = [Vec3::zeros(), Vec3::x(), Vec3::x() * 2.0];
        assert!(kabsch(&from, &from).is_none());
        assert!(kabsch(&from[..2], &from[..2]).is_none());
    }

    #[test]
    fn quaternion_of_quarter_turn_about_z() {
        let r = Rotation3::from_axis_angle(&Vec3::z_axis(), std::f64::consts::FRAC_PI_2);
        let q = RigidTransform {
            rotation: r.into_inner(),
            translation: Vec3::zeros(),
        }
        .quaternion_wxyz();
        let h = std::f64::consts::FRAC_1_SQRT_2;
        assert_relative_eq!(q.as_slice(), [h, 0.0, 0.0, h].as_slice(), epsilon = 1e-12);
    }
}
