//! The retarget core's results in the output vocabulary: its rig (docs/rig.md) and a
//! character's head (docs/head.md). The core keeps its math-side types; this is the one
//! place they become the published ones.

use mouthpiece_output::{CharacterHead, RigCurves, RigJaw, RigLip, RigLips, RigState, RigVisemes};
use mouthpiece_retarget::head::{wxyz, HeadFrame};
use mouthpiece_retarget::rig::{curves_from, LipMotion, RangeOverrides, Rig, RigFrame, CURVES};
use mouthpiece_retarget::Vec3;

fn lip(m: &LipMotion) -> RigLip {
    RigLip {
        rotation: m.rotation.map(|v| v as f32),
        translation: m.translation.map(|v| v as f32),
        residual: m.residual as f32,
    }
}

/// The published copy of one step's rig (no allocation).
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

/// The published copy of one step's rig with a character's own ranges (docs/rig.md:
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

/// The published entry for a character's head frame.
pub fn head(h: &HeadFrame) -> CharacterHead {
    let q = |q| wxyz(q).map(|c| c as f32);
    CharacterHead {
        rotation: q(&h.rotation),
        eye_left: q(&h.eye_left),
        eye_right: q(&h.eye_right),
        mode: h.mode,
        in_reach: h.in_reach,
        progress: h.progress as f32,
    }
}

/// A point as published (single precision).
pub fn point(v: &Vec3) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
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

    /// The head's mode, reach and progress are published as the core made them.
    #[test]
    fn a_head_frame_is_published_as_made() {
        let frame = HeadFrame {
            mode: mouthpiece_output::LookMode::LookAt,
            in_reach: Some(false),
            progress: 0.5,
            ..HeadFrame::default()
        };
        let h = head(&frame);
        assert_eq!(h.mode, mouthpiece_output::LookMode::LookAt);
        assert_eq!(h.in_reach, Some(false));
        assert_eq!(h.progress, 0.5);
        assert_eq!(h.rotation, [1.0, 0.0, 0.0, 0.0]);
    }

    /// A character with ranges of its own gets its curves with them; one without gets the
    /// performer's.
    #[test]
    fn a_characters_own_ranges_reach_its_entry() {
        use mouthpiece_retarget::retarget::StabilisedFrame;
        use mouthpiece_retarget::{NeutralPose, PerformerLayout, RigSettings, RigidTransform};
        // A 12-dot mouth in its own frame (forehead straight above).
        let mut lip = vec![Vec3::new(0.025, 0.0, 0.0)];
        lip.extend((0..5).map(|k| Vec3::new(0.016 - 0.008 * k as f64, 0.006, 0.0)));
        lip.push(Vec3::new(-0.025, 0.0, 0.0));
        lip.extend((0..5).map(|k| Vec3::new(-0.016 + 0.008 * k as f64, -0.008, 0.0)));
        let forehead = [(-0.03, 0.1), (0.03, 0.1), (0.0, 0.12)]
            .map(|(x, y)| Some(Vec3::new(x, y, -0.01)))
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
            .map(|p| Vec3::new(0.9 * p.x, p.y, p.z))
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
