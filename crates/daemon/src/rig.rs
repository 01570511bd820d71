//! The retarget core's rig (docs/rig.md) as the server publishes it.

use mouthpiece_retarget::rig::{LipMotion, RigFrame, CURVE_NAMES};
use mouthpiece_server::{RigCurves, RigJaw, RigLip, RigLips, RigState};

fn lip(m: &LipMotion) -> RigLip {
    RigLip {
        rotation: m.rotation.map(|v| v as f32),
        translation: m.translation.map(|v| v as f32),
        residual: m.residual as f32,
    }
}

/// The server's copy of one step's rig (no allocation).
pub fn rig_state(rig: &RigFrame) -> RigState {
    let mut curves = [0.0f32; 18];
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
    }
}

/// Whether the server's curve list is the retarget core's.
pub fn names_agree() -> bool {
    CURVE_NAMES == mouthpiece_server::RIG_CURVE_NAMES
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_server_names_the_curves_as_the_core_does() {
        assert!(names_agree());
        let mut frame = RigFrame::default();
        frame.curves.0[3].1 = 0.25;
        frame.jaw.angle_deg = 7.0;
        let s = rig_state(&frame);
        assert_eq!(s.curve("mouthPucker"), Some(0.25));
        assert_eq!(s.jaw.angle_deg, 7.0);
    }
}
