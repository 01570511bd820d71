//! The synthetic performer the retarget core's bench and the rig's instruction-count driver
//! (`examples/rig_cost.rs`) share: a head turning and drifting while the mouth opens and
//! closes, the wolf as character.

use mouthpiece_retarget::{
    Character, CharacterSettings, NeutralAccumulator, PerformerDots, PerformerLayout,
    RetargetConfig, Retargeter, StabilisedFrame, Vec3,
};
use nalgebra::Rotation3;

const WOLF: &str = include_str!("../../../../config/characters/wolf.toml");

/// The performer's dots (camera frame) at time `t`.
pub fn performer(t: f64) -> PerformerDots {
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

/// The wolf's retargeter, its neutral pose taken from 30 frames at rest.
pub fn retargeter(settings: CharacterSettings) -> Retargeter {
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

/// 600 frames (10 s at 60 fps) of the performer, and the retargeter whose stabiliser made
/// their stabilised frames (its neutral pose is the rig's).
pub fn stabilised_frames() -> (Retargeter, Vec<StabilisedFrame>) {
    let mut rt = retargeter(CharacterSettings::default());
    let stabilised = (0..600)
        .map(|i| {
            let t = i as f64 / 60.0;
            rt.step(t, &performer(t)).unwrap().performer.clone()
        })
        .collect();
    (rt, stabilised)
}
