//! Pixels ↔ camera-frame points for the tracker's nalgebra points: thin adapters over the
//! one camera model in `mouthpiece_frame` (`Intrinsics::project`/`deproject`, lens
//! distortion as OpenCV's `plumb_bob`, and `registration`).

use mouthpiece_frame::{Calibration, DepthImage, Intrinsics};

use crate::Vec3;

/// The mean of `pixels`; `None` when there are none.
pub fn pixel_mean(pixels: &[[f64; 2]]) -> Option<[f64; 2]> {
    let n = pixels.len() as f64;
    (!pixels.is_empty()).then(|| {
        [
            pixels.iter().map(|p| p[0]).sum::<f64>() / n,
            pixels.iter().map(|p| p[1]).sum::<f64>() / n,
        ]
    })
}

/// Projects a camera-frame point to a (distorted) pixel. `None` behind the camera.
pub fn project(k: &Intrinsics, p: &Vec3) -> Option<[f64; 2]> {
    k.project([p.x, p.y, p.z])
}

/// The camera-frame point seen at pixel `px` (distorted, as in the image) at depth `z`
/// (metres along the optical axis).
pub fn deproject(k: &Intrinsics, px: [f64; 2], z: f64) -> Vec3 {
    Vec3::from(k.deproject(px, z))
}

/// Re-samples a depth image from its own camera onto the colour camera's pixel grid
/// (`mouthpiece_frame::registration`), into `out`. Colour pixels nothing lands on stay 0
/// (the depth-at-a-dot estimate fills small gaps by its plane fit).
pub fn register_depth(depth: &DepthImage, calib: &Calibration, out: &mut DepthImage) {
    mouthpiece_frame::registration::register_depth_into(
        depth,
        &calib.depth,
        &calib.color,
        &calib.depth_to_color,
        calib.depth_scale_m,
        out,
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn distorted() -> Intrinsics {
        Intrinsics {
            distortion: [0.12, -0.25, 0.001, -0.0015, 0.05],
            ..Intrinsics::default_vga()
        }
    }

    #[test]
    fn project_then_deproject_round_trips_with_distortion() {
        let k = distorted();
        for p in [
            Vec3::new(0.03, -0.02, 0.6),
            Vec3::new(-0.2, 0.15, 0.7),
            Vec3::new(0.0, 0.0, 1.0),
        ] {
            let px = project(&k, &p).unwrap();
            let q = deproject(&k, px, p.z);
            assert!((p - q).norm() < 1e-9, "{p:?} vs {q:?}");
        }
    }

    #[test]
    fn distortion_moves_off_centre_pixels() {
        let p = Vec3::new(-0.2, 0.15, 0.7);
        let a = project(&distorted(), &p).unwrap();
        let b = project(&Intrinsics::default_vga(), &p).unwrap();
        assert!((a[0] - b[0]).abs() > 1.0);
    }

    /// The one camera model against OpenCV's own (`calib3d`): random points seen through a
    /// strongly distorted lens project to OpenCV's `projectPoints` pixels, and those pixels
    /// undistort to OpenCV's `undistortPoints` rays.
    #[test]
    fn the_camera_model_is_opencvs() {
        use opencv::core::{Mat, Point2d, Point3d, TermCriteria, TermCriteria_Type, Vector};
        let k = distorted();
        let camera =
            Mat::from_slice_2d(&[[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]]).unwrap();
        let dist = Mat::from_slice(&k.distortion).unwrap();
        // A fixed pseudo-random spread over the image (a 0.55 x 0.4 field of view at
        // 0.5–1.2 m).
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut unit = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let points: Vec<Vec3> = (0..200)
            .map(|_| {
                let z = 0.5 + 0.7 * unit();
                Vec3::new((unit() - 0.5) * 0.55 * z, (unit() - 0.5) * 0.4 * z, z)
            })
            .collect();
        let object: Vector<Point3d> = points.iter().map(|p| Point3d::new(p.x, p.y, p.z)).collect();
        let mut pixels: Vector<Point2d> = Vector::new();
        let zero = Mat::from_slice(&[0.0f64; 3]).unwrap();
        opencv::calib3d::project_points_def(&object, &zero, &zero, &camera, &dist, &mut pixels)
            .unwrap();
        let mut rays: Vector<Point2d> = Vector::new();
        let criteria = TermCriteria::new(
            TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
            100,
            1e-14,
        )
        .unwrap();
        opencv::calib3d::undistort_points_iter(
            &pixels,
            &mut rays,
            &camera,
            &dist,
            &Mat::default(),
            &Mat::default(),
            criteria,
        )
        .unwrap();
        assert_eq!(pixels.len(), points.len());
        let (mut worst_px, mut worst_ray) = (0.0f64, 0.0f64);
        for ((p, cv_px), cv_ray) in points.iter().zip(pixels.iter()).zip(rays.iter()) {
            let ours = project(&k, p).unwrap();
            worst_px = worst_px.max((ours[0] - cv_px.x).abs().max((ours[1] - cv_px.y).abs()));
            let ray = k.undistort([cv_px.x, cv_px.y]);
            worst_ray = worst_ray.max((ray[0] - cv_ray.x).abs().max((ray[1] - cv_ray.y).abs()));
        }
        eprintln!(
            "largest difference from OpenCV: {worst_px:e} px projected, {worst_ray:e} undistorted"
        );
        assert!(
            worst_px < 1e-6,
            "projection differs from OpenCV's by {worst_px} px"
        );
        // Both iterate towards the same fixed point; a ray of 1e-9 is 5e-7 px.
        assert!(
            worst_ray < 1e-9,
            "undistortion differs from OpenCV's by {worst_ray}"
        );
    }
}
