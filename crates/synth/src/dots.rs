//! Exact dot centres for a mouth state without rendering: what the renderer paints, for the
//! lip-sync basic poses (derived from this mouth model).

use crate::head;
use crate::layout::DotLayout;
use crate::motion::MouthState;

/// Lip dots (`D1..Dn`) and forehead dots of a still, unturned head for `mouth`, in the head
/// frame (origin at the neutral mouth centre, x the performer's left, y down, z into the
/// head; metres).
pub fn dot_positions(layout: &DotLayout, mouth: &MouthState) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let zc = head::seam_zc();
    let place = |(a, v): (f64, f64)| head::deform(&head::attrs_at(a, v, zc), mouth);
    let lip = head::lip_dot_material(layout.lip_dots, zc)
        .into_iter()
        .map(place)
        .collect();
    let forehead = layout
        .forehead
        .iter()
        .map(|f| place(head::front_material(f.x_mm / 1000.0, f.y_mm / 1000.0)))
        .collect();
    (lip, forehead)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn neutral_corners_are_a_mouth_width_apart_and_opening_moves_the_lower_lip_down() {
        let layout = DotLayout::default();
        let (lip, forehead) = dot_positions(&layout, &MouthState::default());
        assert_eq!((lip.len(), forehead.len()), (12, 3));
        let width = lip[0][0] - lip[6][0];
        assert!((0.045..0.06).contains(&width), "{width}");
        let open = MouthState {
            jaw: 0.2,
            ..MouthState::default()
        };
        let (opened, forehead_open) = dot_positions(&layout, &open);
        // Lower-lip middle (D10) moves down (+y); the forehead does not move.
        assert!(opened[9][1] - lip[9][1] > 0.005);
        assert_eq!(forehead, forehead_open);
    }
}

#[cfg(test)]
mod jaw_tests {
    use crate::head::{self, JawPose};
    use crate::layout::DotLayout;
    use crate::motion::MouthState;
    use crate::JawOptions;

    /// `--hinge` turns the jaw about the moved hinge, `--jaw-slide` carries the lower lip
    /// sideways and forward and leaves the upper lip.
    #[test]
    fn the_jaw_turns_about_the_moved_hinge_and_slides_the_lower_lip() {
        let zc = head::seam_zc();
        let dots: Vec<head::Attrs> = head::lip_dot_material(DotLayout::default().lip_dots, zc)
            .into_iter()
            .map(|(a, v)| head::attrs_at(a, v, zc))
            .collect();
        let open = MouthState {
            jaw: 0.2,
            ..MouthState::default()
        };
        let (upper, lower) = (&dots[3], &dots[9]);
        let rest = head::deform(lower, &MouthState::default());
        let moved = |jaw: &JawPose| head::deform_with(lower, &open, jaw);
        let dist = |p: [f64; 3], h: [f64; 2]| (p[1] - h[0]).hypot(p[2] - h[1]);
        let opts = JawOptions {
            hinge_back: 0.25,
            hinge_down: -0.25,
            ..JawOptions::default()
        };
        assert_eq!(opts.hinge(), [-0.03125, 0.1]);
        let far = JawPose {
            hinge: opts.hinge(),
            ..JawPose::default()
        };
        let step = |p: [f64; 3]| (p[1] - rest[1]).hypot(p[2] - rest[2]);
        let (d0, d1) = (step(moved(&JawPose::default())), step(moved(&far)));
        // A chord of the same angle: in proportion to the distance from the hinge.
        let ratio = dist(rest, far.hinge) / dist(rest, head::HINGE);
        assert!(
            (d1 / d0 - ratio).abs() < 1e-9 && ratio > 1.2,
            "{d0} {d1} {ratio}"
        );
        assert_eq!(moved(&JawPose::default()), head::deform(lower, &open));
        let slid = JawPose {
            slide: [0.002, 0.003],
            ..JawPose::default()
        };
        let (a, b) = (moved(&JawPose::default()), moved(&slid));
        assert!((b[0] - a[0] - 0.002).abs() < 1e-12 && (a[2] - b[2] - 0.003).abs() < 1e-12);
        assert_eq!(
            head::deform_with(upper, &open, &slid),
            head::deform(upper, &open)
        );
    }
}
