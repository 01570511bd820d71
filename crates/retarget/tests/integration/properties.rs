//! Property tests of the retarget core: invariance to head motion, the identity
//! character, closed form = recursion, Kabsch recovering rotations.

use mouthpiece_retarget::kabsch::kabsch;
use mouthpiece_retarget::{
    Character, CharacterRetarget, CharacterSettings, MMode, NeutralAccumulator, PerformerDots,
    PerformerLayout, RetargetConfig, Retargeter, StabilisedFrame, Stabiliser, Vec3,
};
use nalgebra::{Matrix3, Rotation3};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random_rotation(rng: &mut ChaCha8Rng, max_angle: f64) -> Matrix3<f64> {
    let axis = Vec3::new(
        rng.random_range(-1.0..1.0),
        rng.random_range(-1.0..1.0),
        rng.random_range(-1.0..1.0),
    );
    let axis = if axis.norm() < 1e-3 {
        Vec3::z()
    } else {
        axis.normalize()
    };
    Rotation3::from_scaled_axis(axis * rng.random_range(-max_angle..max_angle)).into_inner()
}

/// A performer's head in head-local coordinates (x left, y up, z out of the face, metres):
/// 12 lip dots around the mouth, 3 forehead dots.
struct Head {
    lips: Vec<Vec3>,
    forehead: Vec<Vec3>,
}

fn random_head(rng: &mut ChaCha8Rng) -> Head {
    let half = rng.random_range(0.02..0.03);
    let lips = (0..12)
        .map(|k| {
            let a = k as f64 / 12.0 * std::f64::consts::TAU;
            let mut p = Vec3::new(half * a.cos(), 0.008 * a.sin(), 0.008 * a.sin().abs());
            if k != 0 && k != 6 {
                p += Vec3::new(
                    rng.random_range(-1e-3..1e-3),
                    rng.random_range(-1e-3..1e-3),
                    rng.random_range(-1e-3..1e-3),
                );
            }
            p
        })
        .collect();
    let forehead = vec![
        Vec3::new(-0.035, 0.095, -0.02) + Vec3::new(rng.random_range(-0.005..0.005), 0.0, 0.0),
        Vec3::new(0.035, 0.095, -0.02),
        Vec3::new(0.0, 0.115 + rng.random_range(-0.005..0.005), -0.025),
    ];
    Head { lips, forehead }
}

/// Lip shapes over time (head-local): the neutral, then random speech-like deformations.
fn random_shapes(rng: &mut ChaCha8Rng, head: &Head, frames: usize) -> Vec<Vec<Vec3>> {
    (0..frames)
        .map(|_| {
            head.lips
                .iter()
                .map(|p| {
                    p + Vec3::new(
                        rng.random_range(-3e-3..3e-3),
                        rng.random_range(-6e-3..6e-3),
                        rng.random_range(-3e-3..3e-3),
                    )
                })
                .collect()
        })
        .collect()
}

/// Head-local → camera (the performer faces the camera) after a rigid head motion.
fn to_camera(r: &Matrix3<f64>, t: &Vec3, p: &Vec3) -> Vec3 {
    let flip = Matrix3::from_diagonal(&Vec3::new(1.0, -1.0, -1.0));
    flip * (r * p + t) + Vec3::new(0.0, 0.05, 0.6)
}

fn dots(
    head: &Head,
    lips: &[Vec3],
    r: &Matrix3<f64>,
    t: &Vec3,
    missing: &[usize],
) -> PerformerDots {
    let mut d = PerformerDots::new(PerformerLayout::default());
    for (i, p) in lips.iter().enumerate() {
        d.lip[i] = (!missing.contains(&i)).then(|| to_camera(r, t, p));
    }
    for (i, p) in head.forehead.iter().enumerate() {
        d.forehead[i] = Some(to_camera(r, t, p));
    }
    d
}

fn random_character(rng: &mut ChaCha8Rng) -> Character {
    let w = rng.random_range(0.5..20.0);
    let pts: Vec<Vec3> = (0..12)
        .map(|k| {
            let a = k as f64 / 12.0 * std::f64::consts::TAU;
            Vec3::new(
                w / 2.0 * a.cos(),
                w * 0.3 * a.sin(),
                w * rng.random_range(0.0..1.5) * a.sin().abs(),
            )
        })
        .collect();
    let r = random_rotation(rng, std::f64::consts::PI);
    let model: Vec<Vec3> = pts
        .iter()
        .map(|p| r * p + Vec3::new(1.0, 2.0, 3.0))
        .collect();
    let names = (1..=12).map(|i| format!("P{i}")).collect();
    Character::new(
        "creature",
        names,
        model,
        r * Vec3::y(),
        (0..12).collect(),
        MMode::PerPoint,
        None,
    )
    .unwrap()
}

fn neutral_of(head: &Head, r: &Matrix3<f64>, t: &Vec3) -> mouthpiece_retarget::NeutralPose {
    let mut acc = NeutralAccumulator::new(PerformerLayout::default());
    for _ in 0..5 {
        acc.push(&dots(head, &head.lips, r, t, &[])).unwrap();
    }
    acc.finish().unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Moving the whole head rigidly (a different motion every frame, another for the neutral
    /// pose) does not change the character's output.
    #[test]
    fn output_is_invariant_under_rigid_head_motion(seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let head = random_head(&mut rng);
        let character = random_character(&mut rng);
        let shapes = random_shapes(&mut rng, &head, 20);
        let missing: Vec<Vec<usize>> = (0..20).map(|_| if rng.random_bool(0.2) { vec![rng.random_range(0..12)] } else { vec![] }).collect();
        let id = Matrix3::identity();
        let mut still = Retargeter::new(character.clone(), neutral_of(&head, &id, &Vec3::zeros()), RetargetConfig::default()).unwrap();
        let g = random_rotation(&mut rng, 0.5);
        let gt = Vec3::new(rng.random_range(-0.05..0.05), rng.random_range(-0.05..0.05), rng.random_range(-0.05..0.05));
        let mut moving = Retargeter::new(character.clone(), neutral_of(&head, &g, &gt), RetargetConfig::default()).unwrap();
        let scale = character.mouth_width();
        for (m, shape) in shapes.iter().enumerate() {
            let t = m as f64 / 30.0;
            let r = random_rotation(&mut rng, 0.6);
            let tr = Vec3::new(rng.random_range(-0.1..0.1), rng.random_range(-0.1..0.1), rng.random_range(-0.1..0.1));
            let a = still.step(t, &dots(&head, shape, &id, &Vec3::zeros(), &missing[m])).unwrap().character.points.clone();
            let b = moving.step(t, &dots(&head, shape, &r, &tr, &missing[m])).unwrap();
            for (p, q) in a.iter().zip(&b.character.points) {
                prop_assert!((p - q).norm() < 1e-9 * scale, "frame {m}: {p:?} vs {q:?}");
            }
            prop_assert!(!b.performer.head_lost);
        }
    }

    /// A character whose neutral points are the performer's own (P⁰ = D⁰) just shows the
    /// performer's stabilised lip motion.
    #[test]
    fn identity_character_gives_the_stabilised_motion(seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let head = random_head(&mut rng);
        let r0 = random_rotation(&mut rng, 0.3);
        let neutral = neutral_of(&head, &r0, &Vec3::new(0.01, -0.02, 0.03));
        let names = (1..=12).map(|i| format!("P{i}")).collect();
        let character = Character::new("self", names, neutral.lip.clone(), Vec3::y(), (0..12).collect(), MMode::PerPoint, None).unwrap();
        for (p, d) in character.neutral.iter().zip(&neutral.lip) {
            prop_assert!((p - d).norm() < 1e-12, "mouth-frame points must come out unchanged");
        }
        let mut rt = Retargeter::new(character, neutral, RetargetConfig::default()).unwrap();
        let flip = Matrix3::from_diagonal(&Vec3::new(1.0, -1.0, -1.0));
        let _ = flip;
        for (m, shape) in random_shapes(&mut rng, &head, 15).iter().enumerate() {
            let r = random_rotation(&mut rng, 0.5);
            let out = rt.step(m as f64 * 0.02, &dots(&head, shape, &r, &Vec3::new(0.0, 0.01, 0.0), &[])).unwrap();
            for (p, d) in out.character.points.iter().zip(&out.performer.lip) {
                prop_assert!((p - d).norm() < 1e-12);
            }
            // And the stabilised motion is the head-local shape change, in the mouth frame
            // (which for this head is head-local up to the corner line's tilt).
            let corner_gap = (out.performer.lip[0] - out.performer.lip[6]).norm();
            let true_gap = (shape[0] - shape[6]).norm();
            prop_assert!((corner_gap - true_gap).abs() < 1e-12);
        }
    }

    /// The closed form equals the source's recursion P^{m+1} = P^m + (D^{m+1} − D^m) ⊙ M.
    #[test]
    fn closed_form_equals_recursion(seed in any::<u64>(), frames in 1usize..60) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let head = random_head(&mut rng);
        let neutral = neutral_of(&head, &Matrix3::identity(), &Vec3::zeros());
        let character = random_character(&mut rng);
        let mut cr = CharacterRetarget::new(character.clone(), &neutral, CharacterSettings::default()).unwrap();
        let m = cr.m().to_vec();
        let mut p_rec = character.neutral.clone();
        let mut d_prev = neutral.lip.clone();
        for k in 0..frames {
            let d: Vec<Vec3> = neutral.lip.iter().map(|p| p + Vec3::new(rng.random_range(-5e-3..5e-3), rng.random_range(-5e-3..5e-3), rng.random_range(-5e-3..5e-3))).collect();
            for (n, &drv) in character.driver.iter().enumerate() {
                p_rec[n] += (d[drv] - d_prev[drv]).component_mul(&m[n]);
            }
            d_prev = d.clone();
            let frame = StabilisedFrame { t: k as f64, lip: d, confidence: vec![1.0; 12], head: Default::default(), head_lost: false };
            let out = cr.apply(&frame);
            for (a, b) in out.points.iter().zip(&p_rec) {
                prop_assert!((a - b).norm() < 1e-9 * character.mouth_width());
            }
        }
    }

    /// Kabsch recovers any rotation and translation, also from noisy points.
    #[test]
    fn kabsch_recovers_random_rotations(seed in any::<u64>(), count in 3usize..12) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let r = random_rotation(&mut rng, std::f64::consts::PI);
        let t = Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        let from: Vec<Vec3> = (0..count).map(|_| Vec3::new(rng.random_range(-0.1..0.1), rng.random_range(-0.1..0.1), rng.random_range(-0.1..0.1))).collect();
        prop_assume!(mouthpiece_retarget::kabsch::spans_plane(&from));
        // Keep clear of near-collinear sets, where the rotation is ill-conditioned.
        let c = from.iter().sum::<Vec3>() / count as f64;
        let cov = from.iter().fold(Matrix3::zeros(), |acc, p| acc + (p - c) * (p - c).transpose());
        let mut ev = cov.symmetric_eigenvalues();
        ev.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
        prop_assume!(ev[1] > 1e-4 * ev[0]);
        let to: Vec<Vec3> = from.iter().map(|p| r * p + t).collect();
        let got = kabsch(&from, &to).unwrap();
        prop_assert!((got.rotation - r).norm() < 1e-9, "{} vs {}", got.rotation, r);
        prop_assert!((got.translation - t).norm() < 1e-9);
        prop_assert!((got.rotation.determinant() - 1.0).abs() < 1e-12);
        // With noise: still close, still a rotation.
        let noisy: Vec<Vec3> = to.iter().map(|p| p + Vec3::new(rng.random_range(-1e-5..1e-5), rng.random_range(-1e-5..1e-5), rng.random_range(-1e-5..1e-5))).collect();
        let got = kabsch(&from, &noisy).unwrap();
        prop_assert!((got.rotation.determinant() - 1.0).abs() < 1e-12);
        prop_assert!((got.rotation.transpose() * got.rotation - Matrix3::identity()).norm() < 1e-12);
        let angle = Rotation3::from_matrix_unchecked(got.rotation.transpose() * r).angle();
        prop_assert!(angle < 0.05, "angle error {angle}");
    }
}

#[test]
fn stabiliser_holds_then_decays_missing_dots() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let head = random_head(&mut rng);
    let neutral = neutral_of(&head, &Matrix3::identity(), &Vec3::zeros());
    let mut st = Stabiliser::new(
        neutral.clone(),
        mouthpiece_retarget::MissingDots {
            hold: 0.5,
            decay: 1.0,
        },
    )
    .unwrap();
    let id = Matrix3::identity();
    let mut shape = head.lips.clone();
    shape[3] += Vec3::new(0.0, 0.004, 0.0);
    let seen = st
        .step(0.0, &dots(&head, &shape, &id, &Vec3::zeros(), &[]))
        .unwrap()
        .lip[3];
    assert!((seen - neutral.lip[3]).norm() > 0.003);
    for (t, expect_lambda) in [
        (0.4, 0.0),
        (0.5, 0.0),
        (1.0, 0.5),
        (1.25, 0.75),
        (1.5, 1.0),
        (9.0, 1.0),
    ] {
        let out = st
            .step(t, &dots(&head, &head.lips, &id, &Vec3::zeros(), &[3]))
            .unwrap();
        let expect = seen + (neutral.lip[3] - seen) * expect_lambda;
        assert!(
            (out.lip[3] - expect).norm() < 1e-12,
            "t {t}: {:?} vs {expect:?}",
            out.lip[3]
        );
        assert_eq!(out.confidence[3], 0.0);
        assert_eq!(out.confidence[2], 1.0);
    }
    // Time going backwards is refused.
    assert!(st
        .step(1.0, &dots(&head, &head.lips, &id, &Vec3::zeros(), &[]))
        .is_err());
}

#[test]
fn head_lost_keeps_the_last_pose() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let head = random_head(&mut rng);
    let neutral = neutral_of(&head, &Matrix3::identity(), &Vec3::zeros());
    let mut st = Stabiliser::new(neutral, Default::default()).unwrap();
    let r = random_rotation(&mut rng, 0.3);
    let t = Vec3::new(0.01, 0.02, -0.01);
    let first = st
        .step(0.0, &dots(&head, &head.lips, &r, &t, &[]))
        .unwrap()
        .clone();
    assert!(!first.head_lost);
    let mut d = dots(&head, &head.lips, &r, &t, &[]);
    d.forehead[1] = None;
    let second = st.step(0.1, &d).unwrap();
    assert!(second.head_lost);
    assert_eq!(second.head, first.head);
    for (a, b) in second.lip.iter().zip(&first.lip) {
        assert!((a - b).norm() < 1e-12);
    }
}
