//! A common shift across the lip: lip dots between the corners still missing are looked for
//! with one shift of all their predictions across the lip line (a jaw's motion). Every shift
//! from a missing dot's prediction to a free candidate that lands enough of them on free
//! candidates is proposed (at least two with both corners named; with a corner unseen, all
//! of them but one and at least three: without both corners the lip line is less sure, and
//! two dots agree by chance too often), and the one score ([`score::score`]) picks among the
//! proposals and the names without any: a shift onto the lip's paint beats one onto its
//! motion-blur ghosts. Shifts along the lip line are not tried: a shift of one dot spacing
//! along the lip would land each prediction on its neighbour.

use mouthpiece_detect::DotRole;

use super::{name_moved, score, Candidates, Context, NameSet, Pass, Scratch, Step};
use crate::labels::{self, Candidate, Small};
use crate::prediction::{lips_depth, CornerLine};

/// Largest part of a shift along the lip line, as a share of the spacing between lip dots
/// (half the mouth's width over half the lip dots).
pub const MAX_ALONG_SHARE: f64 = 0.3;

/// A common shift is looked for only with at least this many lip dots between the corners
/// missing: one dot alone is the single-dot steps' business.
pub const MIN_MISSING: usize = 2;

/// With both corners named, a shift must land at least this many missing dots ...
pub const MIN_LANDED_WITH_CORNERS: usize = 2;
/// ... with a corner unseen, at least this many (and all the missing dots but one): without
/// both corners the lip line is less sure, and two dots agree by chance too often.
pub const MIN_LANDED_WITHOUT_CORNERS: usize = 3;

pub(crate) struct ShiftAcrossLip;

impl Step for ShiftAcrossLip {
    fn name(&self) -> &'static str {
        "shift-across-lip"
    }

    fn run(
        &self,
        ctx: &Context,
        pass: &Pass,
        names: &mut NameSet,
        cands: &mut Candidates,
        scratch: &mut Scratch,
    ) -> bool {
        let n = ctx.layout.lip_dots;
        let (left, right) = (ctx.layout.left_corner(), ctx.layout.right_corner());
        let corners_seen = names.get(left).is_some() && names.get(right).is_some();
        let missing: Small<usize> = (0..n)
            .filter(|&i| names.get(i).is_none() && i != left && i != right)
            .collect();
        if missing.len() < MIN_MISSING {
            return false;
        }
        let preds = &pass.preds;
        let spacing = score::spacing_px(ctx, preds, lips_depth(ctx));
        let Some(line) = CornerLine::measurable(preds, &ctx.layout, spacing) else {
            return false;
        };
        let list = &cands.list;
        let free: Small<usize> = (0..list.len())
            .filter(|&j| !names.taken()[j] && list[j].role != DotRole::Forehead)
            .collect();
        let gates = &pass.gates;
        let lands = |g: &labels::Prediction, c: &Candidate, shift: [f64; 2]| {
            let d2 = (c.pixel[0] - g.pixel[0] - shift[0]).powi(2)
                + (c.pixel[1] - g.pixel[1] - shift[1]).powi(2);
            d2 < g.gate_px * g.gate_px && (c.point.z - g.z).abs() <= g.z_gate
        };
        let enough = |count: usize| {
            if corners_seen {
                count >= MIN_LANDED_WITH_CORNERS
            } else {
                count >= MIN_LANDED_WITHOUT_CORNERS && count + 1 >= missing.len()
            }
        };
        // Every shift from a missing dot's prediction to a free candidate that lands enough
        // of the missing dots is proposed: the missing dots named at their predictions so
        // shifted. The one score picks among the proposals and the names without any.
        let mut best: Option<(f64, NameSet, [f64; 2])> = None;
        for &i in &missing {
            for &j in &free {
                let g = &gates[i];
                let c = &list[j].pixel;
                let shift = [c[0] - g.pixel[0], c[1] - g.pixel[1]];
                if line.runs_along(&shift, n, MAX_ALONG_SHARE) {
                    continue;
                }
                let count = missing
                    .iter()
                    .filter(|&&m| free.iter().any(|&f| lands(&gates[m], &list[f], shift)))
                    .count();
                if !enough(count) {
                    continue;
                }
                let moved: Small<(usize, [f64; 2])> = missing
                    .iter()
                    .map(|&m| (m, [preds[m][0] + shift[0], preds[m][1] + shift[1]]))
                    .collect();
                let mut proposal = names.clone();
                if !name_moved(ctx, pass, &mut proposal, cands, &mut scratch.solver, &moved) {
                    continue;
                }
                let total = score::score(ctx, preds, &pass.head, &proposal, cands).total();
                if best.as_ref().is_none_or(|(b, _, _)| total > *b) {
                    best = Some((total, proposal, shift));
                }
            }
        }
        let Some((total, proposal, shift)) = best else {
            return false;
        };
        if total <= score::score(ctx, preds, &pass.head, names, cands).total() {
            return false;
        }
        *names = proposal;
        tracing::debug!(shift_px = ?shift, "lip dots found moved together");
        true
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;

    /// The jaw drops the whole lower lip between the corners by 7 px, beyond every gate: the
    /// first pass names none of it and its neighbours (the corners) did not move; one shift
    /// across the lip line lands all five.
    #[test]
    fn a_lower_lip_that_moved_together_is_found_with_one_shift() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let truth = lower_lip_moved(&rest, [0.0, 7.0]);
        let mut cands = scene.candidates_at(&truth);
        let pass = scene.pass(&rest, &cands);
        let (first, names) = scene.run_after_first_pass(&ShiftAcrossLip, &pass, &mut cands);
        assert!(
            (7..12).all(|i| first.get(i).is_none()),
            "{:?}",
            named(&first)
        );
        assert_eq!(named(&names), identity());
    }

    /// A shift along the lip line would land each prediction on its neighbour: not tried.
    #[test]
    fn a_shift_along_the_lip_is_not_tried() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let truth = lower_lip_moved(&rest, [9.0, 0.0]);
        let mut cands = scene.candidates_at(&truth);
        let pass = scene.pass(&rest, &cands);
        let (first, names) = scene.run_after_first_pass(&ShiftAcrossLip, &pass, &mut cands);
        assert_eq!(named(&names), named(&first));
    }

    /// The lower lip dropped 7 px onto its paint (each dot 0.4 px to one side or the other)
    /// and left faint ghosts exactly 7 px above its predictions: both shifts land all five
    /// missing dots, the ghosts' with no residual at all. The score's paint term picks the
    /// paint.
    #[test]
    fn of_two_shifts_landing_as_many_dots_the_score_picks_the_one_on_paint() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let mut truth = lower_lip_moved(&rest, [0.0, 7.0]);
        for (k, p) in truth[7..12].iter_mut().enumerate() {
            p[0] += if k % 2 == 0 { 0.4 } else { -0.4 };
        }
        let mut cands = scene.candidates_at(&truth);
        let face = neutral_face();
        let ghosts: Vec<usize> = (7..12)
            .map(|i| {
                let at = [rest[i][0], rest[i][1] - 7.0];
                scene.push(&mut cands, at, face[i].z, DotRole::Lip, 0.4)
            })
            .collect();
        let pass = scene.pass(&rest, &cands);
        let (first, names) = scene.run_after_first_pass(&ShiftAcrossLip, &pass, &mut cands);
        assert!(
            (7..12).all(|i| first.get(i).is_none()),
            "{:?}",
            named(&first)
        );
        assert_eq!(named(&names), identity(), "ghosts at {ghosts:?}");
    }
}
