//! Per-step cost of the retarget core: one performer step (Kabsch + stabilisation) and one
//! character (closed form + curve), as the daemon runs it for every camera frame; and the
//! rig's step (jaw, lip fits, named curves), and the same with dots unseen every other frame
//! (`rig/step-unseen`) or one misread (`rig/step-misread`).
//!
//!     cargo bench -p mouthpiece-retarget --bench retarget
//!     cargo bench -p mouthpiece-retarget --bench retarget -- rig/step

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use mouthpiece_retarget::{
    CharacterSettings, OneEuroParams, PerformerDots, Rig, RigSettings, ShapeSmoothing,
};

mod support;
use support::{performer, retargeter};

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
    // The rig (docs/rig.md) on stabilised frames: jaw, both lip fits, every curve. The same
    // frames as `examples/rig_cost.rs` counts instructions on.
    let (rt, stabilised) = support::stabilised_frames();
    // Variants that change every other frame.
    let every_other = |change: fn(&mut mouthpiece_retarget::StabilisedFrame)| -> Vec<_> {
        stabilised
            .iter()
            .enumerate()
            .map(|(k, f)| {
                let mut f = f.clone();
                if k % 2 == 1 {
                    change(&mut f);
                }
                f
            })
            .collect()
    };
    // The same with every other frame missing a corner and an upper-lip dot: the estimate
    // (docs/rig.md, "The dots the rig measures") solves for them on those frames, for the
    // seen dots on every frame, and learns from the complete ones.
    let with_unseen = every_other(|f| {
        f.confidence[0] = 0.0;
        f.confidence[2] = 0.0;
    });
    // The same with every other frame reading an upper-lip dot 12 mm off and missing a corner
    // (so that the misreads are not learned as shapes): the step is beyond the shape gate
    // there and a second solve, without that dot, disowns it.
    let with_misread = every_other(|f| {
        f.lip[3].z -= 0.012;
        f.confidence[0] = 0.0;
    });
    for (name, frames) in [
        ("rig/step", &stabilised),
        ("rig/step-unseen", &with_unseen),
        ("rig/step-misread", &with_misread),
    ] {
        let mut rig = Rig::new(rt.stabiliser().neutral(), RigSettings::default()).unwrap();
        let mut i = 0usize;
        c.bench_function(name, |b| {
            b.iter(|| {
                let out = rig.step(black_box(&frames[i % frames.len()]));
                i += 1;
                black_box(out.jaw.angle_deg);
            })
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
