//! Depth → colour registration: a depth image from its own camera re-sampled onto the
//! colour camera's pixel grid. The one implementation, used by the capture sources that
//! register in software and by the tracker for sessions recorded unregistered.

use crate::{DepthImage, Extrinsics, Intrinsics};

/// Re-samples `depth` (its camera `depth_k`, readings in units of `depth_scale_m`) onto the
/// colour camera `color_k`, into `out` (its buffer reused): each depth pixel is deprojected
/// (its lens distortion removed), moved into the colour frame by `depth_to_color` and
/// projected (the colour lens's distortion applied); where several land on one colour pixel
/// the nearest wins. Colour pixels nothing lands on stay 0.
pub fn register_depth_into(
    depth: &DepthImage,
    depth_k: &Intrinsics,
    color_k: &Intrinsics,
    depth_to_color: &Extrinsics,
    depth_scale_m: f64,
    out: &mut DepthImage,
) {
    out.width = color_k.width;
    out.height = color_k.height;
    out.data.clear();
    out.data
        .resize(color_k.width as usize * color_k.height as usize, 0);
    for v in 0..depth.height {
        for u in 0..depth.width {
            let raw = depth.at(u, v);
            if raw == 0 {
                continue;
            }
            let p = depth_k.deproject([u as f64, v as f64], raw as f64 * depth_scale_m);
            let q = depth_to_color.apply(p);
            let Some([x, y]) = color_k.project(q) else {
                continue;
            };
            let (xi, yi) = (x.round(), y.round());
            if xi < 0.0 || yi < 0.0 || xi >= color_k.width as f64 || yi >= color_k.height as f64 {
                continue;
            }
            let z = (q[2] / depth_scale_m).round();
            if !(1.0..=u16::MAX as f64).contains(&z) {
                continue;
            }
            let slot = &mut out.data[yi as usize * color_k.width as usize + xi as usize];
            if *slot == 0 || (z as u16) < *slot {
                *slot = z as u16;
            }
        }
    }
}

/// As [`register_depth_into`], into a new image; a depth image already on the colour grid
/// (same camera, identity extrinsics) is returned as it is.
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
    let mut out = DepthImage::new(0, 0);
    register_depth_into(
        depth,
        depth_k,
        color_k,
        depth_to_color,
        depth_scale_m,
        &mut out,
    );
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
        // ahead of the depth camera at 0.5 m is seen right of centre by the colour camera.
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

    #[test]
    fn a_flat_wall_shifts_by_the_baseline() {
        // A wall at 0.8 m seen by a depth camera 25 mm to the colour camera's right: the shift
        // is fx * b / z = 525 * 0.025 / 0.8 ≈ 16.4 px, so the leftmost 16 columns of the
        // colour image see no depth and the rest see the wall.
        let k = Intrinsics::default_vga();
        let e = Extrinsics {
            translation: [0.025, 0.0, 0.0],
            ..Extrinsics::IDENTITY
        };
        let depth = DepthImage {
            width: 640,
            height: 480,
            data: vec![800; 640 * 480],
        };
        let out = register_depth(&depth, &k, &k, &e, 0.001);
        assert_eq!(out.at(10, 240), 0);
        assert_eq!(out.at(20, 240), 800);
        assert_eq!(out.at(639, 240), 800);
    }

    /// Both lenses' distortion is honoured: a reading lands on the colour pixel where the
    /// distorted colour camera images its point (ignoring either distortion misses it by
    /// pixels at the image's edge).
    #[test]
    fn distortion_on_both_sides_is_applied() {
        let depth_k = Intrinsics {
            distortion: [-0.1, 0.05, 0.0005, -0.0008, 0.0],
            ..Intrinsics::default_vga()
        };
        let color_k = Intrinsics {
            distortion: [0.12, -0.25, 0.001, -0.0015, 0.05],
            ..Intrinsics::default_vga()
        };
        let e = Extrinsics {
            translation: [0.02, 0.001, 0.0],
            ..Extrinsics::IDENTITY
        };
        let mut d = DepthImage::new(640, 480);
        let (u, v) = (40u32, 420u32);
        d.data[(v * 640 + u) as usize] = 900;
        let r = register_depth(&d, &depth_k, &color_k, &e, 0.001);
        let q = e.apply(depth_k.deproject([u as f64, v as f64], 0.9));
        let [x, y] = color_k.project(q).unwrap();
        assert_eq!(r.at(x.round() as u32, y.round() as u32), 900);
        let ideal = color_k
            .project_ideal(e.apply(depth_k.deproject_ideal([u as f64, v as f64], 0.9)))
            .unwrap();
        assert!(
            (ideal[0] - x).abs() + (ideal[1] - y).abs() > 3.0,
            "{ideal:?} vs {x} {y}"
        );
    }
}
