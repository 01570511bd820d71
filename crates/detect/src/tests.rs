//! Detector tests on images drawn with OpenCV: anti-aliased discs of known colour and
//! sub-pixel centre on a skin-coloured background.

use opencv::core::{Mat, Point, Scalar, CV_8UC3};
use opencv::imgproc;
use opencv::prelude::*;

use super::*;

const SKIN: (f64, f64, f64) = (120.0, 150.0, 205.0); // BGR
const GREEN: (f64, f64, f64) = (50.0, 175.0, 40.0);
const BLUE: (f64, f64, f64) = (190.0, 90.0, 30.0);
const RED: (f64, f64, f64) = (40.0, 30.0, 200.0);

struct Canvas {
    mat: Mat,
}

impl Canvas {
    fn new(w: i32, h: i32) -> Self {
        let mat = Mat::new_rows_cols_with_default(
            h,
            w,
            CV_8UC3,
            Scalar::new(SKIN.0, SKIN.1, SKIN.2, 0.0),
        )
        .unwrap();
        Self { mat }
    }

    /// A filled disc at a sub-pixel centre, each pixel blended by its exact-ish coverage
    /// (16x16 supersampling), as a camera integrates paint and skin over a pixel.
    fn disc(&mut self, centre: [f64; 2], radius: f64, bgr: (f64, f64, f64)) {
        self.ellipse(centre, [radius, radius], bgr);
    }

    /// An axis-aligned ellipse, blended like [`Self::disc`] (a dot seen at a grazing angle).
    fn ellipse(&mut self, centre: [f64; 2], radii: [f64; 2], bgr: (f64, f64, f64)) {
        let radius = radii[0].max(radii[1]);
        let n = 16;
        let x0 = (centre[0] - radius - 1.0).floor() as i32;
        let y0 = (centre[1] - radius - 1.0).floor() as i32;
        let x1 = (centre[0] + radius + 1.0).ceil() as i32;
        let y1 = (centre[1] + radius + 1.0).ceil() as i32;
        for y in y0..=y1 {
            for x in x0..=x1 {
                let mut inside = 0;
                for sy in 0..n {
                    for sx in 0..n {
                        let px = x as f64 - 0.5 + (sx as f64 + 0.5) / n as f64;
                        let py = y as f64 - 0.5 + (sy as f64 + 0.5) / n as f64;
                        if ((px - centre[0]) / radii[0]).powi(2)
                            + ((py - centre[1]) / radii[1]).powi(2)
                            <= 1.0
                        {
                            inside += 1;
                        }
                    }
                }
                let a = inside as f64 / (n * n) as f64;
                if a == 0.0 {
                    continue;
                }
                let p = self.mat.at_2d_mut::<opencv::core::Vec3b>(y, x).unwrap();
                for (k, c) in [bgr.0, bgr.1, bgr.2].into_iter().enumerate() {
                    p[k] = (a * c + (1.0 - a) * p[k] as f64).round() as u8;
                }
            }
        }
    }

    fn image(&self) -> ColorImage {
        let size = self.mat.size().unwrap();
        ColorImage {
            width: size.width as u32,
            height: size.height as u32,
            data: self.mat.data_bytes().unwrap().to_vec(),
        }
    }
}

fn flat_depth(w: u32, h: u32, mm: u16) -> DepthImage {
    DepthImage {
        width: w,
        height: h,
        data: vec![mm; (w * h) as usize],
    }
}

fn nearest(blobs: &[Blob], p: [f64; 2]) -> &Blob {
    blobs
        .iter()
        .min_by(|a, b| dist(a.center, p).total_cmp(&dist(b.center, p)))
        .expect("no blobs")
}

/// The default detector on `canvas` over a flat surface 0.6 m away (fx 525).
fn detect_at_600_mm(canvas: &Canvas) -> Detections {
    let (w, h) = (canvas.mat.cols() as u32, canvas.mat.rows() as u32);
    let mut det = Detector::new(DetectConfig::default()).unwrap();
    det.detect(
        &canvas.image(),
        Some((&flat_depth(w, h, 600), 0.001)),
        525.0,
        None,
    )
    .unwrap()
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

#[test]
fn finds_discs_at_their_sub_pixel_centres() {
    let mut canvas = Canvas::new(320, 240);
    // Radius 2 px: the synthetic performer's 2.25 mm dot at 0.6 m with fx = 525.
    let centres = [
        [100.3, 80.7],
        [130.55, 82.2],
        [160.9, 79.45],
        [115.25, 120.6],
    ];
    for c in centres {
        canvas.disc(c, 2.0, GREEN);
    }
    let forehead = [[120.4, 30.3], [150.7, 28.9]];
    for c in forehead {
        canvas.disc(c, 2.0, BLUE);
    }
    let mut det = Detector::new(DetectConfig::default()).unwrap();
    let depth = flat_depth(320, 240, 600);
    let found = det
        .detect(&canvas.image(), Some((&depth, 0.001)), 525.0, None)
        .unwrap();
    assert_eq!(found.blobs.len(), 6, "{found:?}");
    let mut worst: f64 = 0.0;
    for c in centres {
        let b = nearest(&found.blobs, c);
        assert_eq!(det.config().classes[b.class].role, DotRole::Lip);
        assert_eq!(b.depth_m, Some(0.6));
        worst = worst.max(dist(b.center, c));
    }
    for c in forehead {
        let b = nearest(&found.blobs, c);
        assert_eq!(det.config().classes[b.class].role, DotRole::Forehead);
        worst = worst.max(dist(b.center, c));
    }
    // The plain pixel mean of a thresholded 2 px disc is off by up to ~0.5 px.
    assert!(worst < 0.2, "worst centre error {worst} px");
}

#[test]
fn colour_weighting_beats_the_plain_pixel_mean() {
    // Many sub-pixel positions: the weighted centre must be clearly better on average than
    // the component's centroid that connected components reports.
    let cfg = DetectConfig::default();
    let mut det = Detector::new(cfg).unwrap();
    let depth = flat_depth(64, 64, 600);
    let (mut err_weighted, mut err_plain) = (0.0, 0.0);
    let n = 40;
    for i in 0..n {
        let c = [
            30.0 + (i as f64 * 0.137) % 1.0,
            31.0 + (i as f64 * 0.291) % 1.0,
        ];
        let mut canvas = Canvas::new(64, 64);
        canvas.disc(c, 2.2, GREEN);
        let img = canvas.image();
        let found = det
            .detect(&img, Some((&depth, 0.001)), 525.0, None)
            .unwrap();
        assert_eq!(found.blobs.len(), 1);
        err_weighted += dist(found.blobs[0].center, c).powi(2);
        // Plain mean of the thresholded pixels, for comparison.
        let mut plain = [0.0; 2];
        let mut count = 0.0;
        let hsv_ok = |x: u32, y: u32| {
            let [b, g, r] = img.pixel(x, y);
            g as i32 - r as i32 > 60 && g as i32 - b as i32 > 40
        };
        for y in 0..64 {
            for x in 0..64 {
                if hsv_ok(x, y) {
                    plain[0] += x as f64;
                    plain[1] += y as f64;
                    count += 1.0;
                }
            }
        }
        err_plain += dist([plain[0] / count, plain[1] / count], c).powi(2);
    }
    let (rms_w, rms_p) = (
        (err_weighted / n as f64).sqrt(),
        (err_plain / n as f64).sqrt(),
    );
    assert!(rms_w < 0.15, "weighted RMS {rms_w} px");
    assert!(rms_w < rms_p, "weighted {rms_w} vs plain {rms_p}");
}

#[test]
fn red_wraps_around_the_hue_circle() {
    let mut canvas = Canvas::new(200, 100);
    canvas.disc([50.0, 50.0], 3.0, RED);
    // A slightly magenta red (hue near 175) and a slightly orange one (hue near 3).
    canvas.disc([100.0, 50.0], 3.0, (70.0, 20.0, 210.0));
    canvas.disc([150.0, 50.0], 3.0, (10.0, 30.0, 220.0));
    let cfg = DetectConfig {
        classes: vec![ColorClass {
            name: "red".into(),
            role: DotRole::Any,
            hue: vec![[0, 8], [168, 179]],
            saturation: [150, 255],
            value: [60, 255],
        }],
        ..DetectConfig::default()
    };
    let mut det = Detector::new(cfg).unwrap();
    // The skin background (hue ~ 10, saturation ~ 105) must not show up.
    let found = det.detect(&canvas.image(), None, 525.0, None).unwrap();
    assert_eq!(found.blobs.len(), 3, "{found:?}");
}

#[test]
fn filters_reject_big_thin_and_depthless_blobs() {
    let mut canvas = Canvas::new(320, 240);
    canvas.disc([50.0, 50.0], 2.0, GREEN); // a dot
    canvas.disc([150.0, 60.0], 14.0, GREEN); // a green sticker: far too big at 0.6 m
    imgproc::line(
        &mut canvas.mat,
        Point::new(200, 150),
        Point::new(260, 152),
        Scalar::new(GREEN.0, GREEN.1, GREEN.2, 0.0),
        2,
        imgproc::LINE_8,
        0,
    )
    .unwrap(); // a thin stripe
    canvas.disc([80.0, 200.0], 2.0, GREEN); // a dot with no depth around it
    let mut depth = flat_depth(320, 240, 600);
    for y in 190..212 {
        for x in 70..92 {
            depth.data[y * 320 + x] = 0;
        }
    }
    let mut det = Detector::new(DetectConfig::default()).unwrap();
    let found = det
        .detect(&canvas.image(), Some((&depth, 0.001)), 525.0, None)
        .unwrap();
    assert_eq!(found.blobs.len(), 1, "{found:?}");
    assert!(dist(found.blobs[0].center, [50.0, 50.0]) < 0.3);
    assert_eq!(found.rejected, 3);
    assert!(found.faint.is_empty(), "{:?}", found.faint);
}

#[test]
fn a_blob_spreads_along_the_line_between_two_merged_dots() {
    let mut canvas = Canvas::new(320, 240);
    canvas.disc([50.0, 50.0], 2.0, GREEN);
    canvas.disc([150.0, 60.0], 2.0, GREEN);
    canvas.disc([150.0, 63.5], 2.0, GREEN); // 3.5 px below: one blob
    let found = detect_at_600_mm(&canvas);
    assert_eq!(found.blobs.len(), 2, "{found:?}");
    let single = nearest(&found.blobs, [50.0, 50.0]).spread;
    let merged = nearest(&found.blobs, [150.0, 61.75]).spread;
    // One dot: round. Two: the vertical spread exceeds the horizontal by (3.5 / 2)².
    assert!(
        (single[0] - single[2]).abs() < 0.2 && single[1].abs() < 0.2,
        "{single:?}"
    );
    let excess = merged[2] - merged[0];
    assert!((excess - 1.75f64.powi(2)).abs() < 0.5, "{merged:?}");
}

#[test]
fn specks_smaller_than_a_dot_are_kept_apart_as_faint() {
    let mut canvas = Canvas::new(320, 240);
    canvas.disc([50.0, 50.0], 2.0, GREEN); // a dot
                                           // Two pixels of paint: a dot at 0.6 m covers about 12.
    for x in [120, 121] {
        let px = canvas.mat.at_2d_mut::<opencv::core::Vec3b>(80, x).unwrap();
        *px = opencv::core::Vec3b::from([GREEN.0 as u8, GREEN.1 as u8, GREEN.2 as u8]);
    }
    let found = detect_at_600_mm(&canvas);
    assert_eq!(found.blobs.len(), 1, "{found:?}");
    assert_eq!(found.faint.len(), 1, "{found:?}");
    assert!(
        dist(found.faint[0].center, [120.5, 80.0]) < 0.3,
        "{found:?}"
    );
    assert_eq!(found.faint[0].area, 2);
}

#[test]
fn the_union_of_two_boxes_is_the_box_round_both_groups_of_points() {
    let upper = [[60.3, 40.7], [120.5, 44.2], [-3.5, 38.0]];
    let lower = [[100.2, 200.9], [80.0, 190.5]];
    let margin = 11.3;
    let a = PixelRect::around(upper, margin).unwrap();
    let b = PixelRect::around(lower, margin).unwrap();
    let both = PixelRect::around(upper.into_iter().chain(lower), margin).unwrap();
    assert_eq!(a.union(&b), both);
    assert_eq!(b.union(&a), both);
    assert_eq!(a.union(&a), a);
}

#[test]
fn the_gap_between_two_boxes_is_the_pixels_between_them_on_the_axis_most_apart() {
    let r = |x, y, width, height| PixelRect {
        x,
        y,
        width,
        height,
    };
    let a = r(10, 10, 20, 20); // columns 10..=29, rows 10..=29
    assert_eq!(a.gap(&r(15, 15, 5, 5)), 0, "inside");
    assert_eq!(a.gap(&r(29, 29, 5, 5)), 0, "sharing a corner pixel");
    assert_eq!(a.gap(&r(30, 10, 5, 5)), 0, "touching");
    assert_eq!(a.gap(&r(10, 33, 5, 5)), 3, "three rows between");
    assert_eq!(r(10, 33, 5, 5).gap(&a), 3, "either way round");
    assert_eq!(
        a.gap(&r(34, 31, 5, 5)),
        4,
        "diagonal: the larger of 4 columns and 1 row"
    );
}

#[test]
fn several_regions_find_what_each_holds_class_by_class_and_nothing_between() {
    // Two green dots and a blue one in the upper region, a green one in the lower, a green
    // one between the two regions.
    let mut canvas = Canvas::new(320, 240);
    canvas.disc([60.3, 40.2], 2.0, GREEN);
    canvas.disc([90.6, 44.1], 2.0, BLUE);
    canvas.disc([120.2, 40.7], 2.0, GREEN);
    canvas.disc([100.4, 120.5], 2.0, GREEN);
    canvas.disc([100.5, 200.3], 2.0, GREEN);
    let img = canvas.image();
    let mut det = Detector::new(DetectConfig::default()).unwrap();
    let upper = PixelRect::around([[60.0, 40.0], [120.0, 44.0]], 12.0).unwrap();
    let lower = PixelRect::around([[100.0, 200.0]], 12.0).unwrap();
    let mut found = Detections::default();
    det.detect_into(&img, None, 525.0, Some(&[upper, lower]), &mut found)
        .unwrap();
    assert_eq!(found.searched, [upper, lower]);
    let centres: Vec<[f64; 2]> = found.blobs.iter().map(|b| b.center).collect();
    let expected = [[60.3, 40.2], [120.2, 40.7], [100.5, 200.3], [90.6, 44.1]];
    assert_eq!(centres.len(), expected.len(), "{centres:?}");
    for (got, want) in centres.iter().zip(expected) {
        assert!(dist(*got, want) < 0.3, "{centres:?}");
    }
    // The same frame as one region round both finds the dot between them too, the others
    // in the same order.
    let both = PixelRect::around([[60.0, 40.0], [120.0, 44.0], [100.0, 200.0]], 12.0).unwrap();
    det.detect_into(&img, None, 525.0, Some(&[both]), &mut found)
        .unwrap();
    assert_eq!(found.blobs.len(), 5);
    assert!(dist(found.blobs[2].center, [100.4, 120.5]) < 0.3);
}

#[test]
fn search_region_limits_the_work_and_keeps_full_frame_coordinates() {
    let mut canvas = Canvas::new(320, 240);
    canvas.disc([40.4, 40.6], 2.0, GREEN);
    canvas.disc([250.2, 200.8], 2.0, GREEN);
    let img = canvas.image();
    let mut det = Detector::new(DetectConfig::default()).unwrap();
    let roi = PixelRect::around([[250.0, 200.0]], 10.0);
    let found = det.detect(&img, None, 525.0, roi).unwrap();
    assert_eq!(found.blobs.len(), 1);
    assert!(
        dist(found.blobs[0].center, [250.2, 200.8]) < 0.2,
        "{:?}",
        found.blobs[0]
    );
    assert_eq!(
        found.searched,
        [PixelRect::around([[250.0, 200.0]], 10.0).unwrap()]
    );
    // A region entirely outside the image finds nothing and does not fail.
    let off = PixelRect {
        x: 400,
        y: 400,
        width: 10,
        height: 10,
    };
    assert!(det
        .detect(&img, None, 525.0, Some(off))
        .unwrap()
        .blobs
        .is_empty());
    // A region that leaves the image is clipped.
    let edge = PixelRect {
        x: -20,
        y: -20,
        width: 80,
        height: 80,
    };
    let found = det.detect(&img, None, 525.0, Some(edge)).unwrap();
    assert_eq!(found.blobs.len(), 1);
    assert_eq!(
        found.searched[0],
        PixelRect {
            x: 0,
            y: 0,
            width: 60,
            height: 60
        }
    );
}

#[test]
fn an_image_without_dots_gives_nothing() {
    let canvas = Canvas::new(160, 120);
    let mut det = Detector::new(DetectConfig::default()).unwrap();
    let found = det.detect(&canvas.image(), None, 525.0, None).unwrap();
    assert!(found.blobs.is_empty());
}

#[test]
fn mismatched_sizes_are_an_error_not_a_panic() {
    let mut det = Detector::new(DetectConfig::default()).unwrap();
    let mut img = ColorImage::new(64, 48);
    img.data.pop();
    assert!(matches!(
        det.detect(&img, None, 525.0, None),
        Err(DetectError::ImageSize(_))
    ));
    let img = ColorImage::new(64, 48);
    let depth = DepthImage::new(32, 24);
    assert!(matches!(
        det.detect(&img, Some((&depth, 0.001)), 525.0, None),
        Err(DetectError::ImageSize(_))
    ));
}

#[test]
fn hue_table_wraps_and_peaks_inside_the_range() {
    let t = hue_weight_table(&[[0, 8], [170, 179]], 6);
    assert_eq!(t[4], 255);
    assert_eq!(t[175], 255);
    assert!(t[12] > 0 && t[12] < 255);
    assert_eq!(t[90], 0);
}

#[test]
fn a_dot_seen_at_a_grazing_angle_is_found() {
    // A forehead dot on a head turned 30° and more: 2 px tall, under a pixel wide.
    let mut canvas = Canvas::new(120, 80);
    canvas.ellipse([60.3, 40.6], [0.7, 2.2], BLUE);
    let depth = flat_depth(120, 80, 600);
    let mut det = Detector::new(DetectConfig::default()).unwrap();
    let found = det
        .detect(&canvas.image(), Some((&depth, 0.001)), 525.0, None)
        .unwrap();
    assert_eq!(found.blobs.len(), 1, "{found:?}");
    assert!(dist(found.blobs[0].center, [60.3, 40.6]) < 0.3, "{found:?}");
    // The 2x2 opening (a speckle filter) loses it: why it is not the default.
    let mut det = Detector::new(DetectConfig {
        morphology: Morphology::Open,
        ..DetectConfig::default()
    })
    .unwrap();
    let found = det
        .detect(&canvas.image(), Some((&depth, 0.001)), 525.0, None)
        .unwrap();
    assert!(found.blobs.is_empty(), "{found:?}");
}

#[test]
fn the_weight_table_is_opencvs_per_pixel_weight_at_any_image_width() {
    // The weight was once computed per pixel over the search region with `LUT` and
    // `multiply`; the table must give the same byte whatever the region's width (OpenCV
    // runs wide rows through SIMD and the row's tail through scalar code).
    let classes = default_classes();
    let class = &classes[0];
    let hue = hue_weight_table(&class.hue, 12);
    let sat = saturation_weight_table(class.saturation);
    let table = weight_table(&hue, &sat).unwrap();
    let (hue_lut, sat_lut) = (
        Mat::from_slice(&hue).unwrap(),
        Mat::from_slice(&sat).unwrap(),
    );
    for width in [1usize, 3, 7, 15, 17, 33, 67] {
        let pairs: Vec<(u8, u8)> = (0..=255u8)
            .flat_map(|h| (0..=255u8).map(move |s| (h, s)))
            .collect();
        for chunk in pairs.chunks(width * 8) {
            let rows = chunk.len().div_ceil(width);
            let mut hs = vec![0u8; rows * width];
            let mut ss = vec![0u8; rows * width];
            for (i, &(h, s)) in chunk.iter().enumerate() {
                hs[i] = h;
                ss[i] = s;
            }
            let hm = Mat::new_rows_cols_with_data(rows as i32, width as i32, &hs).unwrap();
            let sm = Mat::new_rows_cols_with_data(rows as i32, width as i32, &ss).unwrap();
            let (mut hw, mut sw, mut w) = (Mat::default(), Mat::default(), Mat::default());
            core::lut(&hm, &hue_lut, &mut hw).unwrap();
            core::lut(&sm, &sat_lut, &mut sw).unwrap();
            core::multiply(&hw, &sw, &mut w, 1.0 / 255.0, -1).unwrap();
            let got = w.data_bytes().unwrap();
            for (i, &(h, s)) in chunk.iter().enumerate() {
                assert_eq!(
                    got[i],
                    table[h as usize * 256 + s as usize],
                    "hue {h}, saturation {s}, width {width}"
                );
            }
        }
    }
}

#[test]
fn the_class_masks_are_opencvs_in_range_ored_over_each_classs_hue_ranges() {
    // Two classes as configured by default, and a red one whose hue wraps (two ranges),
    // with ranges that touch the byte's ends: every (h, s, v) byte triple of a coarse grid
    // plus every byte at the bounds themselves.
    let mut classes = default_classes();
    classes.push(ColorClass {
        name: "red".into(),
        role: DotRole::Lip,
        hue: vec![[0, 8], [170, 179]],
        saturation: [0, 200],
        value: [60, 255],
    });
    let bits = RangeBits::new(&classes);
    let mut levels: Vec<u8> = (0..=255u8).step_by(5).collect();
    for c in &classes {
        for r in c.hue.iter().chain([&c.saturation, &c.value]) {
            for b in [r[0], r[1]] {
                levels.extend([b.saturating_sub(1), b, b.saturating_add(1)]);
            }
        }
    }
    levels.sort_unstable();
    levels.dedup();
    let mut hsv = Vec::new();
    for &h in &levels {
        for &s in &levels {
            for &v in &levels {
                hsv.extend([h, s, v]);
            }
        }
    }
    let pixels = hsv.len() / 3;
    let image = Mat::new_rows_cols_with_data(1, pixels as i32 * 3, &hsv).unwrap();
    let image = image.reshape(3, 1).unwrap();
    let mut pixel_bits = Vec::new();
    bits.classify(&hsv, &mut pixel_bits);
    for (idx, class) in classes.iter().enumerate() {
        let mut expected = Mat::default();
        for (j, [lo, hi]) in class.hue.iter().enumerate() {
            let lower = Scalar::new(
                *lo as f64,
                class.saturation[0] as f64,
                class.value[0] as f64,
                0.0,
            );
            let upper = Scalar::new(
                *hi as f64,
                class.saturation[1] as f64,
                class.value[1] as f64,
                0.0,
            );
            let mut range = Mat::default();
            core::in_range(&image, &lower, &upper, &mut range).unwrap();
            if j == 0 {
                expected = range;
            } else {
                let mut or = Mat::default();
                core::bitwise_or_def(&expected, &range, &mut or).unwrap();
                expected = or;
            }
        }
        let mut mask = vec![0u8; pixels];
        bits.class_mask(idx, &pixel_bits, &mut mask);
        let expected = expected.data_bytes().unwrap();
        let inside = mask.iter().filter(|&&m| m == 255).count();
        assert!(
            inside > 0 && inside < pixels,
            "{}: {inside} of {pixels}",
            class.name
        );
        for (i, (&got, &want)) in mask.iter().zip(expected).enumerate() {
            assert_eq!(
                got,
                want,
                "{} at hsv {:?}",
                class.name,
                &hsv[3 * i..3 * i + 3]
            );
        }
    }
}

#[test]
fn components_are_found_the_same_wherever_the_mask_lies_in_the_region() {
    // Connected components run over the box round the mask's pixels only: dots in a corner
    // of a large region, at odd and even offsets, come out as from a region just round them.
    let mut canvas = Canvas::new(320, 240);
    for (i, c) in [[41.3, 37.8], [52.6, 38.4], [47.0, 51.2], [290.5, 201.7]]
        .iter()
        .enumerate()
    {
        canvas.disc(*c, 2.0, if i % 2 == 0 { GREEN } else { BLUE });
    }
    let depth = flat_depth(320, 240, 600);
    let mut det = Detector::new(DetectConfig::default()).unwrap();
    let image = canvas.image();
    let full = det
        .detect(&image, Some((&depth, 0.001)), 525.0, None)
        .unwrap();
    assert_eq!(full.blobs.len(), 4, "{:?}", full.blobs);
    for (x, y) in [(0, 0), (1, 1), (30, 27), (31, 26)] {
        let region = PixelRect {
            x,
            y,
            width: 80,
            height: 60,
        };
        let part = det
            .detect(&image, Some((&depth, 0.001)), 525.0, Some(region))
            .unwrap();
        let inside: Vec<&Blob> = full.blobs.iter().filter(|b| b.center[0] < 100.0).collect();
        assert_eq!(part.blobs.len(), inside.len(), "region at {x},{y}");
        for (a, b) in part.blobs.iter().zip(inside) {
            assert_eq!(a, b, "region at {x},{y}");
        }
    }
}

#[test]
fn opening_keeps_round_dots_and_their_centres() {
    // The opening only decides which components are real: round dots pass it, and their
    // centres come from the unopened components, as without it.
    let mut canvas = Canvas::new(160, 120);
    for c in [[40.3, 50.7], [90.55, 52.2]] {
        canvas.disc(c, 2.0, GREEN);
    }
    canvas.disc([70.4, 20.3], 2.0, BLUE);
    let depth = flat_depth(160, 120, 600);
    let detect = |morphology| {
        Detector::new(DetectConfig {
            morphology,
            ..DetectConfig::default()
        })
        .unwrap()
        .detect(&canvas.image(), Some((&depth, 0.001)), 525.0, None)
        .unwrap()
    };
    let plain = detect(Morphology::None);
    assert_eq!(plain.blobs.len(), 3, "{plain:?}");
    assert_eq!(detect(Morphology::Open).blobs, plain.blobs);
}
