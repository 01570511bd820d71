//! The renderer against its own ground truth, without the detector: visible dot centres land
//! on pixels of their paint, with the depth there equal to their z within the noise model;
//! hidden dots are really hidden; the head pose carries the neutral forehead onto the current.

use mouthpiece_frame::{Frame, Intrinsics};
use mouthpiece_synth::{
    GroundTruth, HeadMotion, JawOptions, NoiseModel, Synth, SynthConfig, DOT_MIN_SATURATION_CV,
    FOREHEAD_DOT_HUE_RANGE_CV, LIP_DOT_HUE_RANGE_CV,
};

/// OpenCV's BGR → HSV (hue 0–180, saturation and value 0–255).
fn hsv(bgr: [u8; 3]) -> (f64, f64, f64) {
    let (b, g, r) = (bgr[0] as f64, bgr[1] as f64, bgr[2] as f64);
    let v = r.max(g).max(b);
    let min = r.min(g).min(b);
    let s = if v > 0.0 { (v - min) / v * 255.0 } else { 0.0 };
    if v == min {
        return (0.0, s, v);
    }
    let mut h = if v == r {
        60.0 * (g - b) / (v - min)
    } else if v == g {
        120.0 + 60.0 * (b - r) / (v - min)
    } else {
        240.0 + 60.0 * (r - g) / (v - min)
    };
    if h < 0.0 {
        h += 360.0;
    }
    (h / 2.0, s, v)
}

fn is_paint(bgr: [u8; 3], lip: bool) -> bool {
    let (h, s, _) = hsv(bgr);
    let (lo, hi) = if lip {
        LIP_DOT_HUE_RANGE_CV
    } else {
        FOREHEAD_DOT_HUE_RANGE_CV
    };
    h >= lo as f64 && h <= hi as f64 && s >= DOT_MIN_SATURATION_CV as f64
}

fn project(k: &Intrinsics, p: [f64; 3]) -> (i64, i64) {
    let px = k.project_ideal(p).expect("in front of the camera");
    (px[0].round() as i64, px[1].round() as i64)
}

struct Tally {
    visible: usize,
    hidden: usize,
    depth_missing: usize,
}

/// Checks one frame; `depth_tol(z)` is the allowed |depth − z| in metres.
fn check_frame(frame: &Frame, gt: &GroundTruth, depth_tol: impl Fn(f64) -> f64, tally: &mut Tally) {
    let k = frame.calibration.color;
    let t = gt.t;
    for (name, &p) in &gt.points {
        let lip = name.starts_with('D');
        let (u, v) = project(&k, p);
        let inside = u >= 0 && v >= 0 && u < k.width as i64 && v < k.height as i64;
        if gt.is_visible(name) {
            assert!(inside, "t={t:.3} {name} visible but outside the image");
            tally.visible += 1;
            let bgr = frame.color.pixel(u as u32, v as u32);
            assert!(
                is_paint(bgr, lip),
                "t={t:.3} {name} visible at ({u}, {v}) but the pixel is {bgr:?} = HSV {:?}",
                hsv(bgr)
            );
            let d = frame.depth.at(u as u32, v as u32);
            if d == 0 {
                tally.depth_missing += 1;
            } else {
                let err = (d as f64 / 1000.0 - p[2]).abs();
                assert!(
                    err <= depth_tol(p[2]),
                    "t={t:.3} {name}: depth {d} mm vs z {:.4} m",
                    p[2]
                );
            }
        } else {
            tally.hidden += 1;
            if !inside {
                continue;
            }
            // Another visible dot of the same paint may cover the same pixel.
            let near_other = gt.points.iter().any(|(other, &q)| {
                other != name && other.starts_with('D') == lip && gt.is_visible(other) && {
                    let (ou, ov) = project(&k, q);
                    (ou - u).abs() <= 4 && (ov - v).abs() <= 4
                }
            });
            if !near_other {
                let bgr = frame.color.pixel(u as u32, v as u32);
                assert!(
                    !is_paint(bgr, lip),
                    "t={t:.3} {name} hidden but its pixel ({u}, {v}) shows its paint {bgr:?}"
                );
            }
        }
    }
}

#[test]
fn exact_render_matches_ground_truth_under_strong_motion() {
    let config = SynthConfig {
        seed: 5,
        seconds: 10.0,
        head_motion: HeadMotion::Strong,
        noise: NoiseModel::None,
        colour_effects: false,
        ..SynthConfig::default()
    };
    let mut tally = Tally {
        visible: 0,
        hidden: 0,
        depth_missing: 0,
    };
    // The pixel samples the paint up to a dot radius from its centre: allow the surface's
    // slope over that (steep at the mouth corners) plus millimetre rounding.
    for (frame, gt) in Synth::new(config).unwrap().step_by(3) {
        check_frame(&frame, &gt, |_| 0.005, &mut tally);
    }
    assert_eq!(
        tally.depth_missing, 0,
        "exact depth has no holes on visible dots"
    );
    assert!(tally.visible > 500, "{} visible", tally.visible);
    assert!(
        tally.hidden > 0,
        "strong motion and lip roll-in hide some dots"
    );
}

#[test]
fn noisy_render_matches_ground_truth_within_the_kinect_model() {
    let config = SynthConfig {
        seed: 9,
        seconds: 5.0,
        ..SynthConfig::default()
    };
    let mut tally = Tally {
        visible: 0,
        hidden: 0,
        depth_missing: 0,
    };
    // Kinect: σ = 1.5 mm·(z/0.6)², steps z²/(8·0.075·fx); allow 5σ + a step + the slope.
    let tol = |z: f64| 5.0 * 0.0015 * (z / 0.6).powi(2) + z * z / (8.0 * 0.075 * 525.0) + 0.005;
    for (frame, gt) in Synth::new(config).unwrap().step_by(2) {
        check_frame(&frame, &gt, tol, &mut tally);
    }
    assert!(tally.visible > 900, "{} visible", tally.visible);
    assert!(
        (tally.depth_missing as f64) < 0.1 * tally.visible as f64,
        "{} of {} visible dots without depth",
        tally.depth_missing,
        tally.visible
    );
}

#[test]
fn head_pose_carries_the_neutral_forehead_onto_the_current_one() {
    let config = SynthConfig {
        seed: 2,
        seconds: 6.0,
        head_motion: HeadMotion::Strong,
        ..SynthConfig::default()
    };
    let frames: Vec<GroundTruth> = Synth::new(config)
        .unwrap()
        .step_by(10)
        .map(|(_, gt)| gt)
        .collect();
    let neutral = &frames[0];
    let mut moved = 0;
    for gt in &frames {
        for name in ["F1", "F2", "F3"] {
            let q = gt.head.apply(neutral.point(name).unwrap());
            let p = gt.point(name).unwrap();
            let err =
                ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2)).sqrt();
            assert!(
                err < 1e-9,
                "t={} {name}: pose maps neutral to {q:?}, truth {p:?}",
                gt.t
            );
        }
        let r = gt.head.rotation;
        assert!(((r[0] * r[0] + r[1] * r[1] + r[2] * r[2] + r[3] * r[3]) - 1.0).abs() < 1e-9);
        if r[0] < 0.99 {
            moved += 1;
        }
    }
    assert!(moved > 5, "the head turns");
}

#[test]
fn neutral_mouth_is_about_50_mm_wide_and_still() {
    let config = SynthConfig {
        seconds: 1.4,
        head_motion: HeadMotion::None,
        ..SynthConfig::default()
    };
    let truths: Vec<GroundTruth> = Synth::new(config).unwrap().map(|(_, gt)| gt).collect();
    let d1 = truths[0].point("D1").unwrap();
    let d7 = truths[0].point("D7").unwrap();
    let width =
        ((d1[0] - d7[0]).powi(2) + (d1[1] - d7[1]).powi(2) + (d1[2] - d7[2]).powi(2)).sqrt();
    assert!((0.045..0.056).contains(&width), "mouth width {width}");
    // Performer's left corner is +x in the camera frame (docs/method.md §1, §2).
    assert!(d1[0] > d7[0]);
    for gt in &truths {
        assert_eq!(gt.points, truths[0].points, "the neutral lead-in is still");
        assert!(
            gt.visible.values().all(|&v| v),
            "all dots visible in the neutral pose"
        );
    }
}

#[test]
fn same_seed_same_session_other_seed_other_session() {
    let run = |seed| {
        let config = SynthConfig {
            seed,
            seconds: 2.0,
            ..SynthConfig::default()
        };
        Synth::new(config)
            .unwrap()
            .skip(55)
            .map(|(f, gt)| (f.color.data, f.depth.data, gt))
            .collect::<Vec<_>>()
    };
    let a = run(4);
    assert!(a == run(4), "deterministic per seed");
    assert!(a != run(5), "the seed matters");
}

/// OpenCV's distorted projection, written out independently of the renderer's.
fn project_distorted(k: &Intrinsics, p: [f64; 3]) -> (i64, i64) {
    let (x, y) = (p[0] / p[2], p[1] / p[2]);
    let [k1, k2, p1, p2, k3] = k.distortion;
    let r2 = x * x + y * y;
    let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
    let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
    let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
    (
        (k.fx * xd + k.cx).round() as i64,
        (k.fy * yd + k.cy).round() as i64,
    )
}

#[test]
fn lens_distortion_moves_the_dots_where_opencv_puts_them() {
    let mut camera = SynthConfig::camera_for_size(640, 480);
    camera.distortion = [-0.25, 0.08, 0.001, -0.001, 0.0];
    let config = SynthConfig {
        seed: 3,
        seconds: 3.0,
        camera,
        head_motion: HeadMotion::Strong,
        noise: NoiseModel::None,
        colour_effects: false,
        ..SynthConfig::default()
    };
    let mut checked = 0;
    for (frame, gt) in Synth::new(config).unwrap().step_by(5) {
        assert_eq!(frame.calibration.color.distortion, camera.distortion);
        for (name, &p) in &gt.points {
            if gt.is_visible(name) {
                let (u, v) = project_distorted(&camera, p);
                let bgr = frame.color.pixel(u as u32, v as u32);
                assert!(
                    is_paint(bgr, name.starts_with('D')),
                    "t={} {name} at ({u}, {v}): {bgr:?}",
                    gt.t
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 150);
}

#[test]
fn separate_depth_camera_sees_the_dots_at_their_depth() {
    let color = SynthConfig::camera_for_size(640, 480);
    let depth_to_color = mouthpiece_frame::Extrinsics {
        translation: [0.025, 0.0, 0.0],
        ..Default::default()
    };
    let config = SynthConfig {
        seed: 8,
        seconds: 3.0,
        depth_camera: Some((color, depth_to_color)),
        noise: NoiseModel::None,
        colour_effects: false,
        ..SynthConfig::default()
    };
    let (mut good, mut total) = (0, 0);
    for (frame, gt) in Synth::new(config).unwrap().step_by(5) {
        let cal = &frame.calibration;
        assert!(!cal.depth_registered);
        for (name, &p) in &gt.points {
            if !gt.is_visible(name) {
                continue;
            }
            // Colour frame → depth frame: the inverse of depth_to_color (a pure translation).
            let q = [p[0] - 0.025, p[1], p[2]];
            let (u, v) = project(&cal.depth, q);
            let d = frame.depth.at(u as u32, v as u32) as f64 / 1000.0;
            total += 1;
            if (d - q[2]).abs() < 0.005 {
                good += 1;
            }
        }
    }
    // Dots seen by the colour camera may be hidden from the depth camera 25 mm away.
    assert!(good as f64 > 0.9 * total as f64, "{good} of {total}");
}

/// `SynthConfig::jaw` reaches the rendered session: with the hinge moved back the lower lip
/// of an open mouth is elsewhere and the upper lip is not; a sliding jaw's ground truth says
/// how far it slid, and its lower lip is that far to the side.
#[test]
fn the_sessions_jaw_hinges_and_slides_as_configured() {
    let run = |jaw: JawOptions| -> Vec<GroundTruth> {
        let config = SynthConfig {
            seed: 3,
            seconds: 3.0,
            camera: SynthConfig::camera_for_size(160, 120),
            head_motion: HeadMotion::None,
            noise: NoiseModel::None,
            colour_effects: false,
            jaw,
            ..SynthConfig::default()
        };
        Synth::new(config).unwrap().map(|(_, gt)| gt).collect()
    };
    let plain = run(JawOptions::default());
    let hinged = run(JawOptions {
        hinge_back: 0.25,
        ..JawOptions::default()
    });
    let slid = run(JawOptions {
        slide_m: 0.003,
        ..JawOptions::default()
    });
    let open = (0..plain.len())
        .max_by(|&a, &b| {
            let jaw = |i: usize| plain[i].mouth.unwrap().jaw;
            jaw(a).total_cmp(&jaw(b))
        })
        .unwrap();
    let (p, h, s) = (&plain[open], &hinged[open], &slid[open]);
    assert!(p.mouth.unwrap().jaw > 0.1, "{:?}", p.mouth);
    assert_eq!(p.mouth, h.mouth, "the same speech");
    let d = |a: &GroundTruth, b: &GroundTruth, dot: &str| {
        let (x, y) = (a.point(dot).unwrap(), b.point(dot).unwrap());
        [x[0] - y[0], x[1] - y[1], x[2] - y[2]]
    };
    assert_eq!(
        d(h, p, "D4"),
        [0.0; 3],
        "the upper lip does not move with the jaw"
    );
    let lower = d(h, p, "D10");
    assert!(lower[1] > 0.001, "further from the hinge, lower: {lower:?}");
    let m = s.mouth.unwrap();
    assert!(m.slide.abs() > 1e-4 && m.glide > 0.0, "{m:?}");
    assert!((d(s, p, "D10")[0] - m.slide).abs() < 1e-12);
    assert!(plain.iter().all(|g| g.mouth.unwrap().slide == 0.0));
}
