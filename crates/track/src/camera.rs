//! Pixels ↔ camera-frame points: lens distortion (OpenCV `plumb_bob`), deprojection, and
//! registering a depth image onto the colour grid.

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

/// Removes lens distortion from a pixel: the normalised image coordinates `(x, y)` of the
/// ray through it (`x = X/Z`, `y = Y/Z`). Fixed-point iteration as OpenCV's
/// `undistortPoints` does it, run to convergence.
pub fn undistort_normalised(k: &Intrinsics, px: [f64; 2]) -> [f64; 2] {
    let x0 = (px[0] - k.cx) / k.fx;
    let y0 = (px[1] - k.cy) / k.fy;
    if !k.has_distortion() {
        return [x0, y0];
    }
    let [k1, k2, p1, p2, k3] = k.distortion;
    let (mut x, mut y) = (x0, y0);
    for _ in 0..50 {
        let r2 = x * x + y * y;
        let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
        let dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        let (nx, ny) = ((x0 - dx) / radial, (y0 - dy) / radial);
        let step = (nx - x).abs() + (ny - y).abs();
        x = nx;
        y = ny;
        if step < 1e-12 {
            break;
        }
    }
    [x, y]
}

/// Projects a camera-frame point to a (distorted) pixel. `None` behind the camera.
pub fn project(k: &Intrinsics, p: &Vec3) -> Option<[f64; 2]> {
    k.project([p.x, p.y, p.z])
}

/// The camera-frame point seen at pixel `px` (distorted, as in the image) at depth `z`
/// (metres along the optical axis).
pub fn deproject(k: &Intrinsics, px: [f64; 2], z: f64) -> Vec3 {
    let [x, y] = undistort_normalised(k, px);
    Vec3::new(x * z, y * z, z)
}

/// Re-samples a depth image from its own camera onto the colour camera's pixel grid: each
/// depth pixel is deprojected, moved into the colour frame and projected; where several
/// land on one colour pixel the nearest wins. Colour pixels nothing lands on stay 0 (the
/// depth-at-a-dot estimate fills small gaps by its plane fit).
pub fn register_depth(depth: &DepthImage, calib: &Calibration, out: &mut DepthImage) {
    let c = &calib.color;
    out.width = c.width;
    out.height = c.height;
    out.data.clear();
    out.data.resize(c.width as usize * c.height as usize, 0);
    let scale = calib.depth_scale_m;
    let d = &calib.depth;
    // Undistorted ray directions depend only on the depth pixel: compute per pixel once.
    for v in 0..depth.height {
        for u in 0..depth.width {
            let raw = depth.at(u, v);
            if raw == 0 {
                continue;
            }
            let p = deproject(d, [u as f64, v as f64], raw as f64 * scale);
            let q = calib.depth_to_color.apply([p.x, p.y, p.z]);
            let Some([x, y]) = project(c, &Vec3::new(q[0], q[1], q[2])) else {
                continue;
            };
            let (xi, yi) = (x.round(), y.round());
            if xi < 0.0 || yi < 0.0 || xi >= c.width as f64 || yi >= c.height as f64 {
                continue;
            }
            let z = (q[2] / scale).round();
            if !(1.0..=u16::MAX as f64).contains(&z) {
                continue;
            }
            let slot = &mut out.data[yi as usize * c.width as usize + xi as usize];
            if *slot == 0 || (z as u16) < *slot {
                *slot = z as u16;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mouthpiece_frame::Extrinsics;

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

    #[test]
    fn registration_shifts_depth_by_the_baseline() {
        // A flat wall at 0.8 m seen by a depth camera 25 mm to the colour camera's right.
        let k = Intrinsics::default_vga();
        let mut calib = Calibration::registered(k);
        calib.depth_registered = false;
        calib.depth_to_color = Extrinsics {
            translation: [0.025, 0.0, 0.0],
            ..Extrinsics::IDENTITY
        };
        let depth = DepthImage {
            width: 640,
            height: 480,
            data: vec![800; 640 * 480],
        };
        let mut out = DepthImage::new(0, 0);
        register_depth(&depth, &calib, &mut out);
        // The shift is fx * b / z = 525 * 0.025 / 0.8 ≈ 16.4 px: the leftmost 16 columns of
        // the colour image see no depth, the rest see the wall.
        assert_eq!(out.at(10, 240), 0);
        assert_eq!(out.at(20, 240), 800);
        assert_eq!(out.at(639, 240), 800);
    }
}
