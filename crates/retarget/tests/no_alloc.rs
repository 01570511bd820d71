//! A retarget step allocates nothing once warmed up (the daemon calls it for every frame).

use mouthpiece_retarget::jsonl::OutputLine;
use mouthpiece_retarget::{
    Character, CharacterSettings, NeutralAccumulator, OneEuroParams, PerformerDots,
    PerformerLayout, RetargetConfig, Retargeter, ShapeSmoothing, Vec3,
};

mod counting_alloc;

#[global_allocator]
static GLOBAL: counting_alloc::Counting = counting_alloc::Counting;

fn dots(t: f64, missing: Option<usize>) -> PerformerDots {
    let mut d = PerformerDots::new(PerformerLayout::default());
    let shift = Vec3::new(0.01 * t.sin(), 0.0, 0.6);
    for (k, slot) in d.lip.iter_mut().enumerate() {
        let a = k as f64 / 12.0 * std::f64::consts::TAU;
        let open = if a.sin() < 0.0 {
            0.005 * (3.0 * t).sin()
        } else {
            0.0
        };
        *slot = (Some(k) != missing)
            .then(|| Vec3::new(0.025 * a.cos(), -0.008 * a.sin() + open, 0.0) + shift);
    }
    for (k, p) in [[-0.03, -0.1, 0.02], [0.03, -0.1, 0.02], [0.0, -0.12, 0.03]]
        .iter()
        .enumerate()
    {
        d.forehead[k] = Some(Vec3::from(*p) + shift);
    }
    d
}

#[test]
fn steady_state_steps_do_not_allocate() {
    let wolf = include_str!("../../../config/characters/wolf.toml");
    let character = Character::from_toml_str(wolf).unwrap();
    let mut acc = NeutralAccumulator::new(character.performer_layout());
    acc.push(&dots(0.0, None)).unwrap();
    let settings = CharacterSettings {
        smoothing: ShapeSmoothing::BSpline {
            samples_per_span: 8,
        },
        one_euro: Some(OneEuroParams::new(1.0, 0.01).unwrap()),
    };
    let mut line = OutputLine::for_character(&character, &settings.smoothing);
    let config = RetargetConfig {
        character: settings,
        ..Default::default()
    };
    let mut rt = Retargeter::new(character, acc.finish().unwrap(), config).unwrap();
    // Inputs prepared up front; the first steps may grow buffers.
    let inputs: Vec<PerformerDots> = (0..200)
        .map(|i| dots(i as f64 / 30.0, Some(i % 12)))
        .collect();
    for (i, d) in inputs.iter().take(5).enumerate() {
        let out = rt.step(i as f64 / 30.0, d).unwrap();
        line.update(i as u64, &out);
    }
    let before = counting_alloc::allocations();
    for (i, d) in inputs.iter().enumerate().skip(5) {
        let out = rt.step(i as f64 / 30.0, d).unwrap();
        line.update(i as u64, &out);
    }
    let after = counting_alloc::allocations();
    assert_eq!(
        after - before,
        0,
        "allocations during 195 steady-state steps"
    );
}
