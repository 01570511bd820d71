//! The retarget core's rig (docs/rig.md) as the server publishes it.

use mouthpiece_retarget::rig::{curves_from, LipMotion, RangeOverrides, Rig, RigFrame, CURVES};
use mouthpiece_server::{RigCurves, RigJaw, RigLip, RigLips, RigState, RigVisemes};

fn lip(m: &LipMotion) -> RigLip {
    RigLip {
        rotation: m.rotation.map(|v| v as f32),
        translation: m.translation.map(|v| v as f32),
        residual: m.residual as f32,
    }
}

/// The server's copy of one step's rig (no allocation).
pub fn rig_state(rig: &RigFrame) -> RigState {
    let mut curves = [0.0f32; CURVES];
    for (dst, (_, v)) in curves.iter_mut().zip(rig.curves.iter()) {
        *dst = *v as f32;
    }
    RigState {
        jaw: RigJaw {
            angle_deg: rig.jaw.angle_deg as f32,
            slide_m: rig.jaw.slide_m as f32,
        },
        lips: RigLips {
            upper: lip(&rig.lips.upper),
            lower: lip(&rig.lips.lower),
        },
        curves: RigCurves(curves),
        visemes: RigVisemes(std::array::from_fn(|i| {
            rig.visemes.0.get(i).map_or(0.0, |(_, v)| *v as f32)
        })),
    }
}

/// The server's copy of one step's rig with a character's own ranges (docs/rig.md:
/// character, then configuration, then the performer's learned ranges). No allocation.
pub fn rig_state_for(rig: &Rig, character: &RangeOverrides) -> RigState {
    let mut state = rig_state(rig.output());
    if !character.is_empty() {
        let mut values = [0.0; CURVES];
        curves_from(rig.measures(), &rig.ranges_for(character), &mut values);
        for (dst, v) in state.curves.0.iter_mut().zip(values) {
            *dst = v as f32;
        }
        state.set_visemes();
    }
    state
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rig_state_carries_the_frames_curves_by_name() {
        let mut frame = RigFrame::default();
        frame.curves.0[3].1 = 0.25;
        frame.jaw.angle_deg = 7.0;
        let s = rig_state(&frame);
        assert_eq!(s.curve("mouthPucker"), Some(0.25));
        assert_eq!(s.jaw.angle_deg, 7.0);
    }

    /// A character with ranges of its own gets its curves with them; one without gets the
    /// performer's.
    #[test]
    fn a_characters_own_ranges_reach_its_entry() {
        use mouthpiece_retarget::retarget::StabilisedFrame;
        use mouthpiece_retarget::{NeutralPose, PerformerLayout, RigSettings, RigidTransform};
        use nalgebra::Vector3;
        // A 12-dot mouth in its own frame (forehead straight above).
        let mut lip = vec![Vector3::new(0.025, 0.0, 0.0)];
        lip.extend((0..5).map(|k| Vector3::new(0.016 - 0.008 * k as f64, 0.006, 0.0)));
        lip.push(Vector3::new(-0.025, 0.0, 0.0));
        lip.extend((0..5).map(|k| Vector3::new(-0.016 + 0.008 * k as f64, -0.008, 0.0)));
        let forehead = [(-0.03, 0.1), (0.03, 0.1), (0.0, 0.12)]
            .map(|(x, y)| Some(Vector3::new(x, y, -0.01)))
            .to_vec();
        let neutral = NeutralPose::from_positions(
            PerformerLayout::default(),
            lip.iter().copied().map(Some).collect(),
            forehead,
            30,
        )
        .unwrap();
        let settings = RigSettings {
            learn_s: 0.0,
            ..RigSettings::default()
        };
        let mut rig = Rig::new(&neutral, settings).unwrap();
        // Lips drawn in by 10 %: pucker 0.1 (default range 0.25).
        let drawn: Vec<_> = neutral
            .lip
            .iter()
            .map(|p| Vector3::new(0.9 * p.x, p.y, p.z))
            .collect();
        rig.step(&StabilisedFrame {
            t: 0.0,
            confidence: vec![1.0; 12],
            lip: drawn,
            head: RigidTransform::IDENTITY,
            head_lost: false,
        });
        let performer = rig_state_for(&rig, &RangeOverrides::default());
        assert_eq!(performer, rig_state(rig.output()));
        // Drawn in to 0.9, lips closed: the rounding (0.05 mouth widths) is a pucker.
        assert!((performer.curve("mouthPucker").unwrap() - 0.05 / 0.15).abs() < 1e-6);
        let own = RangeOverrides::from_named([("mouthPucker", 0.2)]).unwrap();
        let s = rig_state_for(&rig, &own);
        assert!(
            (s.curve("mouthPucker").unwrap() - 0.25).abs() < 1e-6,
            "{s:?}"
        );
        assert_eq!(s.jaw, performer.jaw);
        assert_eq!(s.curve("mouthFunnel"), performer.curve("mouthFunnel"));
    }
}
