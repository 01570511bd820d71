//! Per-step cost of the retarget core: one performer step (Kabsch + stabilisation) and one
//! character (closed form + curve), as the daemon runs it for every camera frame; and the
//! rig's step (jaw, lip fits, named curves).
//!
//!     cargo bench -p mouthpiece-retarget --bench retarget

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use mouthpiece_retarget::{
    Character, CharacterSettings, NeutralAccumulator, OneEuroParams, PerformerDots,
    PerformerLayout, RetargetConfig, Retargeter, Rig, RigSettings, ShapeSmoothing, StabilisedFrame,
    Vec3,
};
use nalgebra::Rotation3;

const WOLF: &str = include_str!("../../../config/characters/wolf.toml");

fn performer(t: f64) -> PerformerDots {
    let r = Rotation3::from_euler_angles(0.1 * t.sin(), 0.2 * (0.7 * t).sin(), 0.05 * t.cos());
    let shift = Vec3::new(0.02 * t.sin(), 0.01 * t.cos(), 0.6);
    let mut d = PerformerDots::new(PerformerLayout::default());
    let open = 0.01 * (5.0 * t).sin().max(0.0);
    for (k, slot) in d.lip.iter_mut().enumerate() {
        let a = k as f64 / 12.0 * std::f64::consts::TAU;
        let y = 0.008 * a.sin() - if a.sin() < 0.0 { open } else { 0.0 };
        *slot = Some(r * Vec3::new(0.025 * a.cos(), -y, -0.006 * a.sin().abs()) + shift);
    }
    for (k, p) in [
        [-0.035, -0.095, 0.02],
        [0.035, -0.095, 0.02],
        [0.0, -0.115, 0.025],
    ]
    .iter()
    .enumerate()
    {
        d.forehead[k] = Some(r * Vec3::from(*p) + shift);
    }
    d
}

fn retargeter(settings: CharacterSettings) -> Retargeter {
    let character = Character::from_toml_str(WOLF).unwrap();
    let mut acc = NeutralAccumulator::new(character.performer_layout());
    for _ in 0..30 {
        acc.push(&performer(0.0)).unwrap();
    }
    let config = RetargetConfig {
        character: settings,
        ..Default::default()
    };
    Retargeter::new(character, acc.finish().unwrap(), config).unwrap()
}

fn bench(c: &mut Criterion) {
    let frames: Vec<PerformerDots> = (0..600).map(|i| performer(i as f64 / 60.0)).collect();
    let cases = [
        ("step/no-curve", CharacterSettings::default()),
        (
            "step/bspline8",
            CharacterSettings {
                smoothing: ShapeSmoothing::BSpline {
                    samples_per_span: 8,
                },
                one_euro: None,
            },
        ),
        (
            "step/bspline8+one-euro",
            CharacterSettings {
                smoothing: ShapeSmoothing::BSpline {
                    samples_per_span: 8,
                },
                one_euro: Some(OneEuroParams::new(1.0, 0.007).unwrap()),
            },
        ),
    ];
    for (name, settings) in cases {
        let mut rt = retargeter(settings);
        let mut i = 0usize;
        let mut t = 0.0;
        c.bench_function(name, |b| {
            b.iter(|| {
                t += 1.0 / 60.0;
                let out = rt.step(t, black_box(&frames[i % frames.len()])).unwrap();
                i += 1;
                black_box(out.character.points[3]);
            })
        });
    }
    // The rig (docs/rig.md) on stabilised frames: jaw, both lip fits, every curve.
    let mut rt = retargeter(CharacterSettings::default());
    let stabilised: Vec<StabilisedFrame> = frames
        .iter()
        .enumerate()
        .map(|(i, f)| rt.step(i as f64 / 60.0, f).unwrap().performer.clone())
        .collect();
    let mut rig = Rig::new(rt.stabiliser().neutral(), RigSettings::default()).unwrap();
    let mut i = 0usize;
    c.bench_function("rig/step", |b| {
        b.iter(|| {
            let out = rig.step(black_box(&stabilised[i % stabilised.len()]));
            i += 1;
            black_box(out.jaw.angle_deg);
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
