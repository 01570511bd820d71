//! Software depth→colour registration, for devices that cannot register in hardware.

use mouthpiece_frame::{DepthImage, Extrinsics, Intrinsics};

/// Re-projects every depth pixel into the colour camera and keeps the nearest reading per
/// colour pixel (a z-buffer), giving depth on the colour grid in the same units. Lens
/// distortion is ignored (OpenNI2 and V4L2 devices report none; configured distortion is
/// applied later by the tracker on the colour image).
pub fn register_depth(
    depth: &DepthImage,
    depth_k: &Intrinsics,
    color_k: &Intrinsics,
    depth_to_color: &Extrinsics,
    depth_scale_m: f64,
) -> DepthImage {
    let same_grid = depth_k == color_k
        && depth_to_color.is_identity()
        && (depth.width, depth.height) == (color_k.width, color_k.height);
    if same_grid {
        return depth.clone();
    }
    let mut out = DepthImage::new(color_k.width, color_k.height);
    for v in 0..depth.height {
        for u in 0..depth.width {
            let d = depth.at(u, v);
            if d == 0 {
                continue;
            }
            let p = depth_k.deproject_ideal([u as f64, v as f64], d as f64 * depth_scale_m);
            let q = depth_to_color.apply(p);
            let Some([x, y]) = color_k.project_ideal(q) else {
                continue;
            };
            let (x, y) = (x.round(), y.round());
            if x < 0.0 || y < 0.0 || x >= color_k.width as f64 || y >= color_k.height as f64 {
                continue;
            }
            let z = (q[2] / depth_scale_m).round();
            if !(1.0..=65535.0).contains(&z) {
                continue;
            }
            let i = y as usize * color_k.width as usize + x as usize;
            let cell = &mut out.data[i];
            if *cell == 0 || (z as u16) < *cell {
                *cell = z as u16;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_registration_is_a_copy() {
        let k = Intrinsics::ideal(4, 3, 3.0, 3.0, 1.5, 1.0);
        let mut d = DepthImage::new(4, 3);
        d.data[5] = 700;
        assert_eq!(register_depth(&d, &k, &k, &Extrinsics::IDENTITY, 0.001), d);
    }

    #[test]
    fn a_point_lands_where_the_colour_camera_sees_it() {
        // Depth camera 2.5 cm to the colour camera's right (colour frame): a point straight
        // ahead of the depth camera at 0.5 m is seen left of centre by... the colour camera
        // at x = +0.025 m.
        let k = Intrinsics::ideal(64, 48, 50.0, 50.0, 31.5, 23.5);
        let e = Extrinsics {
            translation: [0.025, 0.0, 0.0],
            ..Extrinsics::IDENTITY
        };
        let mut d = DepthImage::new(64, 48);
        let (u, v) = (31u32, 23u32);
        d.data[(v * 64 + u) as usize] = 500;
        let r = register_depth(&d, &k, &k, &e, 0.001);
        let p = k.deproject_ideal([u as f64, v as f64], 0.5);
        let q = k.project_ideal(e.apply(p)).unwrap();
        let (x, y) = (q[0].round() as u32, q[1].round() as u32);
        assert_eq!(r.at(x, y), 500);
        assert_eq!(r.data.iter().filter(|&&z| z != 0).count(), 1);
        assert_eq!(
            x, 34,
            "0.025 m at 0.5 m with f = 50 px is 2.5 px to the right"
        );
    }

    #[test]
    fn nearer_reading_wins_when_two_land_on_one_pixel() {
        let dk = Intrinsics::ideal(2, 1, 1.0, 1.0, 0.5, 0.0);
        let ck = Intrinsics::ideal(1, 1, 0.01, 0.01, 0.0, 0.0);
        let mut d = DepthImage::new(2, 1);
        d.data = vec![900, 600];
        let r = register_depth(&d, &dk, &ck, &Extrinsics::IDENTITY, 0.001);
        assert_eq!(r.data, vec![600]);
    }
}
