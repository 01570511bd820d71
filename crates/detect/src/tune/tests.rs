//! Colour tuning tests on a drawn scene: skin, painted squares of two colours, a coloured
//! wall behind the performer.

use mouthpiece_frame::{ColorImage, DepthImage};

use super::hue::{circular_mean, hue_diff, hue_set};
use super::proposal::separate_hues;
use super::*;
use crate::{ColorClass, DotRole};

/// A 160x120 BGR image of skin with depth: the face at 0.6 m in the middle, a wall at
/// 1.8 m around it.
struct Scene {
    color: ColorImage,
    depth: DepthImage,
}

const W: u32 = 160;
const H: u32 = 120;

impl Scene {
    fn new() -> Self {
        let mut color = ColorImage::new(W, H);
        let mut depth = DepthImage::new(W, H);
        for y in 0..H {
            for x in 0..W {
                let i = (y * W + x) as usize;
                let face = (40..120).contains(&x) && (10..110).contains(&y);
                // BGR: skin (hue ≈ 10, saturation ≈ 100) or a grey wall.
                let bgr = if face { [120, 150, 205] } else { [60, 62, 64] };
                color.data[3 * i..3 * i + 3].copy_from_slice(&bgr);
                depth.data[i] = if face { 600 } else { 1800 };
            }
        }
        Self { color, depth }
    }

    fn square(&mut self, x0: u32, y0: u32, bgr: [u8; 3]) {
        for y in y0..y0 + 3 {
            for x in x0..x0 + 3 {
                let i = (y * W + x) as usize;
                self.color.data[3 * i..3 * i + 3].copy_from_slice(&bgr);
            }
        }
    }
}

const GREEN: [u8; 3] = [70, 200, 40]; // BGR, hue ≈ 66
const BLUE: [u8; 3] = [230, 90, 40]; // hue ≈ 112
const MAGENTA: [u8; 3] = [200, 30, 210]; // hue ≈ 152

/// Twelve green dots on a lip line, three blue ones above, and magenta dots on the wall
/// (a poster behind the performer).
fn scene() -> Scene {
    let mut s = Scene::new();
    for k in 0..12 {
        s.square(50 + 5 * k, 80 + (k % 2) * 6, GREEN);
    }
    for k in 0..3 {
        s.square(60 + 20 * k, 30, BLUE);
    }
    for k in 0..6 {
        s.square(5 + 5 * k, 5, MAGENTA);
        s.square(130, 20 + 6 * k, MAGENTA);
    }
    s
}

fn sample(with_depth: bool) -> Proposal {
    let s = scene();
    let mut sampler = ColourSampler::new(TuneOptions::default());
    for _ in 0..10 {
        let depth = with_depth.then_some((&s.depth, 0.001));
        let got = sampler.add_frame(&s.color, depth, 140.0).unwrap();
        assert_eq!(got.performer_m.is_some(), with_depth);
    }
    sampler.propose()
}

#[test]
fn depth_masks_the_background_and_roles_follow_count_and_height() {
    let p = sample(true);
    assert!(p.warnings.is_empty(), "{:?}", p.warnings);
    assert!(
        p.unused.is_empty(),
        "the wall's magenta was sampled: {:?}",
        p.unused
    );
    let performer = p.performer_m.unwrap();
    assert!((performer - 0.6).abs() < 0.011, "{performer}");
    assert_eq!(p.classes.len(), 2);
    let (lip, forehead) = (&p.classes[0], &p.classes[1]);
    assert_eq!(lip.class.role, DotRole::Lip);
    assert_eq!(lip.per_frame, 12.0);
    assert_eq!((lip.blobs, lip.frames_present), (120, 10));
    assert_eq!(forehead.class.role, DotRole::Forehead);
    assert_eq!(forehead.per_frame, 3.0);
    let hue_of = |c: &ProposedClass| hue_set(&c.class.hue);
    assert!(hue_of(lip)[66] && !hue_of(lip)[112] && !hue_of(lip)[10]);
    assert!(hue_of(forehead)[112] && !hue_of(forehead)[66]);
    let config = p.detect_config(&DetectConfig::default());
    config.validate().unwrap();
    // The snippet parses back to the same classes.
    let text = p.to_toml("scene");
    #[derive(serde::Deserialize)]
    struct File {
        detect: DetectConfig,
    }
    let back: File = toml::from_str(&text).unwrap();
    assert_eq!(back.detect.classes, config.classes, "{text}");
    assert!(
        text.contains("# hue 66: 120 blobs in 10 of 10 frames (12 per frame)"),
        "{text}"
    );
}

#[test]
fn without_depth_the_background_colour_is_seen() {
    let p = sample(false);
    assert!(p.performer_m.is_none());
    // Magenta: 12 wall dots per frame compete with the green lip dots.
    let seen: Vec<f64> = p
        .classes
        .iter()
        .map(|c| c.hue_centre)
        .chain(p.unused.iter().map(|c| c.hue))
        .collect();
    assert!(seen.iter().any(|h| (h - 152.0).abs() < 3.0), "{seen:?}");
    assert!(p.to_toml("scene").contains("no depth"));
}

#[test]
fn nothing_saturated_gives_no_class_and_a_warning() {
    let s = Scene::new();
    let mut sampler = ColourSampler::new(TuneOptions::default());
    sampler
        .add_frame(&s.color, Some((&s.depth, 0.001)), 140.0)
        .unwrap();
    let p = sampler.propose();
    assert!(p.classes.is_empty());
    assert!(
        p.warnings[0].contains("no saturated, compact colour blobs"),
        "{:?}",
        p.warnings
    );
}

#[test]
fn hue_ranges_wrap_around_red() {
    assert_eq!(hue_ranges(55, 76), vec![[55, 76]]);
    assert_eq!(hue_ranges(-8, 9), vec![[0, 9], [172, 179]]);
    assert_eq!(hue_ranges(170, 185), vec![[0, 5], [170, 179]]);
    assert_eq!(hue_ranges(-100, 100), vec![[0, 179]]);
    assert!((hue_diff(2.0, 178.0) - 4.0).abs() < 1e-9);
    assert!((circular_mean([178.0, 2.0].into_iter()) % 180.0).abs() < 1e-6);
}

#[test]
fn overlapping_classes_split_the_shared_hues() {
    let class = |hue: Vec<[u8; 2]>, centre: f64| ProposedClass {
        class: ColorClass {
            name: "x".into(),
            role: DotRole::Any,
            hue,
            saturation: [100, 255],
            value: [50, 255],
        },
        hue_centre: centre,
        blobs: 1,
        frames_present: 1,
        per_frame: 1.0,
    };
    let mut v = vec![
        class(vec![[0, 20], [170, 179]], 5.0),
        class(vec![[15, 40]], 28.0),
    ];
    separate_hues(&mut v);
    assert_eq!(v[0].class.hue, vec![[0, 16], [170, 179]]);
    assert_eq!(v[1].class.hue, vec![[17, 40]]);
}

#[test]
fn performer_distance_ignores_specks() {
    let mut d = DepthImage::new(100, 100);
    d.data.iter_mut().for_each(|v| *v = 2000);
    d.data[0] = 300; // one near pixel: a speck, not the performer
    for v in &mut d.data[5000..6000] {
        *v = 750;
    }
    let z = performer_distance(&d, 0.001, [0.2, 2.5], 0.015).unwrap();
    assert!((z - 0.75).abs() < 0.011, "{z}");
}
