//! Rendering speed: frames per second of the synthetic performer at 640x480 (one core).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use mouthpiece_synth::{HeadMotion, NoiseModel, Synth, SynthConfig};

fn render(c: &mut Criterion) {
    let mut group = c.benchmark_group("synth");
    group.throughput(Throughput::Elements(1));
    for (name, noise) in [
        ("640x480_kinect_mild", NoiseModel::Kinect),
        ("640x480_none_mild", NoiseModel::None),
    ] {
        let config = SynthConfig {
            seconds: 1.0e6,
            head_motion: HeadMotion::Mild,
            noise,
            ..SynthConfig::default()
        };
        let mut synth = Synth::new(config).expect("default config is valid");
        // Skip the still lead-in so the mouth and head move.
        for _ in 0..60 {
            synth.next();
        }
        group.bench_function(name, |b| b.iter(|| synth.next().expect("endless session")));
    }
    group.finish();
}

criterion_group!(benches, render);
criterion_main!(benches);
