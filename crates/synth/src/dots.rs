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
