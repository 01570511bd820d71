//! The mouth frame (docs/method.md §2): origin between the corners, x towards the subject's left
//! corner, y up (made orthogonal to x), z = x × y out of the mouth.

use nalgebra::Matrix3;

use crate::{Error, Vec3};

/// An orthonormal right-handed frame given in a parent frame (the camera for the performer,
/// the model for a character).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MouthFrame {
    /// Origin in parent coordinates: the midpoint of the corners.
    pub origin: Vec3,
    /// Columns are the frame's x, y, z axes in parent coordinates.
    pub axes: Matrix3<f64>,
    /// Corner-to-corner distance, parent units.
    pub width: f64,
}

/// Relative size below which two corners count as coincident, or `up` as parallel to x.
const DEGENERATE: f64 = 1e-9;

impl MouthFrame {
    /// Builds the frame from the subject's left and right corners and an "up" direction (any
    /// length; only its part orthogonal to the corner line is used).
    pub fn from_corners(left: Vec3, right: Vec3, up: Vec3) -> Result<Self, Error> {
        let across = left - right;
        let width = across.norm();
        let scale = left.norm().max(right.norm()).max(1.0);
        if width.is_nan() || width <= DEGENERATE * scale {
            return Err(Error::CoincidentCorners {
                left: "left".into(),
                right: "right".into(),
            });
        }
        let x = across / width;
        let up_len = up.norm();
        let y_raw = up - x * up.dot(&x);
        let orthogonal = y_raw.norm();
        if up_len.is_nan() || up_len <= 0.0 || orthogonal.is_nan() || orthogonal <= 1e-6 * up_len {
            return Err(Error::UpParallelToCorners);
        }
        let y = y_raw.normalize();
        let z = x.cross(&y);
        Ok(Self {
            origin: (left + right) * 0.5,
            axes: Matrix3::from_columns(&[x, y, z]),
            width,
        })
    }

    /// A parent-frame point in this frame's coordinates.
    pub fn to_mouth(&self, p: &Vec3) -> Vec3 {
        self.axes.tr_mul(&(p - self.origin))
    }

    /// A point in this frame back in parent coordinates.
    pub fn to_parent(&self, p: &Vec3) -> Vec3 {
        self.axes * p + self.origin
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn corners_land_on_x_axis() {
        let left = Vec3::new(0.03, 0.01, 0.6);
        let right = Vec3::new(-0.02, 0.015, 0.62);
        let f = MouthFrame::from_corners(left, right, Vec3::new(0.0, -1.0, 0.0)).unwrap();
        let w = (left - right).norm();
        assert_relative_eq!(
            f.to_mouth(&left),
            Vec3::new(w / 2.0, 0.0, 0.0),
            epsilon = 1e-12
        );
        assert_relative_eq!(
            f.to_mouth(&right),
            Vec3::new(-w / 2.0, 0.0, 0.0),
            epsilon = 1e-12
        );
        assert_relative_eq!(f.axes.determinant(), 1.0, epsilon = 1e-12);
        let p = Vec3::new(0.1, 0.2, 0.3);
        assert_relative_eq!(f.to_parent(&f.to_mouth(&p)), p, epsilon = 1e-12);
    }

    #[test]
    fn camera_frame_performer_faces_camera() {
        // OpenCV camera: x right, y down, z forward. The performer's left is the camera's +x,
        // the forehead is at -y, so the mouth frame's z must point back at the camera (-z).
        let f = MouthFrame::from_corners(
            Vec3::new(0.025, 0.0, 0.6),
            Vec3::new(-0.025, 0.0, 0.6),
            Vec3::new(0.0, -1.0, 0.0),
        )
        .unwrap();
        assert_relative_eq!(f.axes.column(2).into_owned(), Vec3::new(0.0, 0.0, -1.0));
    }

    #[test]
    fn degenerate_inputs_are_rejected() {
        let p = Vec3::new(1.0, 2.0, 3.0);
        assert!(matches!(
            MouthFrame::from_corners(p, p, Vec3::y()),
            Err(Error::CoincidentCorners { .. })
        ));
        assert!(matches!(
            MouthFrame::from_corners(Vec3::x(), -Vec3::x(), Vec3::new(3.0, 0.0, 0.0)),
            Err(Error::UpParallelToCorners)
        ));
        assert!(matches!(
            MouthFrame::from_corners(Vec3::x(), -Vec3::x(), Vec3::zeros()),
            Err(Error::UpParallelToCorners)
        ));
    }
}
