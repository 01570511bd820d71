//! Width jumps: a fast rounded vowel draws the corners in, and a spread one pushes them out,
//! by up to 15 % of the mouth's width between two frames, while the constant-velocity
//! prediction keeps the width it had; a head turning at the same time moves one side more
//! than the other. The dots beside a corner move most, and on a small or turned face they
//! lie 6–8 px apart: they land nearer a neighbour's prediction than their own, names slip one
//! place towards the corner and the corner goes missing.
//!
//! With lip dots missing and candidates left, each side's stretch along the corner line is
//! measured ([`sides_on_paint`]) and, when one side changed, the frame is named again with the
//! predictions stretched by it. Those names are proposed, and taken when they score better
//! ([`super::take_if_better`], the rule of every hypothesis).

use mouthpiece_detect::DotRole;

use super::{
    lips_missing_with_candidates_left, take_if_better_under, Candidates, Context, NameSet, Pass,
    Scratch, Step,
};
use crate::labels::{Candidate, Small};
use crate::naming::checks::depth_window;
#[cfg(test)]
use crate::prediction::stretch_sides;
use crate::prediction::{CornerLine, LipMotion};

/// Largest stretch of a side tried, as a share of its half of the width (either way) ...
pub const STRETCH_MAX: f64 = 0.3;
/// ... in steps of this.
pub const STRETCH_STEP: f64 = 0.02;

/// Stretches within this of 0 on both sides are no change: the steady names stand.
pub const STRETCH_NO_CHANGE: f64 = 0.05;

/// A stretched prediction is on paint when a lip candidate's centre is within this share of
/// a dot's radius.
pub const ON_PAINT_SHARE: f64 = 1.0;

pub(crate) struct WidthJump;

impl Step for WidthJump {
    fn name(&self) -> &'static str {
        "width-jump"
    }

    fn run(
        &self,
        ctx: &Context,
        pass: &Pass,
        names: &mut NameSet,
        cands: &mut Candidates,
        scratch: &mut Scratch,
    ) -> bool {
        if !lips_missing_with_candidates_left(ctx, pass, names, cands) {
            return false;
        }
        let Some(stretch) = sides_on_paint(ctx, pass, &cands.list) else {
            return false;
        };
        let motion = LipMotion::SidesStretched(stretch);
        let taken = take_if_better_under(ctx, pass, names, cands, scratch, motion);
        match taken {
            Some((steady, stretched)) => tracing::debug!(
                steady,
                stretched,
                ?stretch,
                "the mouth's width jumped: named from stretched places"
            ),
            None => tracing::trace!(?stretch, "width jump tried, names not taken"),
        }
        taken.is_some()
    }
}

/// Each side's stretch along the corner line (named heuristic *sides on paint*): per side,
/// the share from -[`STRETCH_MAX`] to [`STRETCH_MAX`] that puts the most of that side's lip
/// predictions within [`ON_PAINT_SHARE`] of a dot's radius of a lip candidate in the dot's
/// depth window; among equals, the one whose predictions lie nearest their candidates (the
/// paint fits a range of stretches equally by count). The two sides are independent: a
/// side's stretch moves only its own dots; a side that gains nothing stays at 0. `None`
/// unless a side puts more predictions on paint than its steady ones, one side's stretch is
/// beyond [`STRETCH_NO_CHANGE`], and the two are not a slide ([`shifted`]).
fn sides_on_paint(ctx: &Context, pass: &Pass, cands: &[Candidate]) -> Option<[f64; 2]> {
    let n = ctx.layout.lip_dots;
    let line = CornerLine::of(&pass.preds, &ctx.layout)?;
    let windows: Small<[f64; 2]> = ctx.tracks[..n]
        .iter()
        .map(|t| depth_window(t, &pass.head, ctx.config.lip_depth_gate_m))
        .collect();
    // How many of a side's predictions (0: left, 1: right) are on paint when that side is
    // stretched by `share`, and their summed distance to it.
    let on_paint = |side: usize, share: f64| -> (usize, f64) {
        let mut fit = (0, 0.0);
        for (p, w) in pass.preds.iter().zip(&windows) {
            let along = line.along(p);
            if (along >= 0.0) != (side == 0) {
                continue;
            }
            let q = line.moved(p, share * along);
            let nearest = cands
                .iter()
                .filter(|c| c.role != DotRole::Forehead && (w[0]..=w[1]).contains(&c.point.z))
                .map(|c| ((c.pixel[0] - q[0]).hypot(c.pixel[1] - q[1]), c.point.z))
                .filter(|&(d, z)| d <= ON_PAINT_SHARE * ctx.dot_radius_px(z))
                .map(|(d, _)| d)
                .min_by(f64::total_cmp);
            if let Some(d) = nearest {
                fit = (fit.0 + 1, fit.1 + d);
            }
        }
        fit
    };
    let steps = (STRETCH_MAX / STRETCH_STEP).round() as i64;
    let mut best = [0.0; 2];
    let (mut gained, mut changed) = (false, false);
    for (side, share) in best.iter_mut().enumerate() {
        let steady = on_paint(side, 0.0);
        let (s, fit) = (-steps..=steps)
            .map(|k| k as f64 * STRETCH_STEP)
            .map(|s| (s, on_paint(side, s)))
            .max_by(|a, b| a.1 .0.cmp(&b.1 .0).then(b.1 .1.total_cmp(&a.1 .1)))?;
        if fit.0 > steady.0 {
            *share = s;
            gained = true;
            changed |= s.abs() > STRETCH_NO_CHANGE;
        }
    }
    (gained && changed && !shifted(best)).then_some(best)
}

/// Whether `stretch` moves one side in and the other out, both by more than
/// [`STRETCH_NO_CHANGE`] (named heuristic *drawn in or spread, not shifted*): the mouth
/// sliding along the corner line. Within a frame that is the head's motion, which the
/// forehead already predicts; the lips themselves draw in or spread about their middle, both
/// corners or one. Stretches of opposite signs that fit the paint are the names sliding
/// along the lip, each dot onto its neighbour's paint (seen on 20 s sessions: the left
/// corner drawn in 22 % and the right pushed out 26 %, D1 and D2 each named on the next
/// dot's paint).
fn shifted(stretch: [f64; 2]) -> bool {
    stretch[0] * stretch[1] < 0.0 && stretch.iter().all(|s| s.abs() > STRETCH_NO_CHANGE)
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;

    /// The mouth narrows by 18 % within a frame (a fast rounded vowel): the corners and the
    /// dots beside them land beyond their gates along the corner line, the first pass leaves
    /// them missing. The stretch is measured and the frame named from the stretched places.
    #[test]
    fn a_mouth_drawn_in_within_a_frame_is_named_from_its_new_width() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let mut truth = rest.clone();
        stretch_sides(&mut truth[..12], &scene.layout, [-0.18, -0.18]);
        let mut cands = scene.candidates_at(&truth);
        let run = scene.run_as_hypothesis(&WidthJump, &rest, &mut cands);
        assert!(run.first.lips_named(12) <= 8, "{:?}", named(&run.first));
        assert!(run.fired, "{:?}", named(&run.names));
        assert_eq!(named(&run.names), identity());
    }

    /// Each side drawn in by its own share (a rounded vowel with the head turning): each
    /// side's stretch is found on its own; paint where predicted is no change; a mouth slid
    /// along the corner line (one side in, the other out) is not taken for a stretch.
    #[test]
    fn each_sides_stretch_is_the_share_that_puts_its_predictions_on_paint() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let found_for = |scene: &mut Scene, stretch: [f64; 2]| {
            let mut moved = rest.clone();
            stretch_sides(&mut moved[..12], &scene.layout, stretch);
            let cands = scene.candidates_at(&moved);
            let pass = scene.pass(&rest, &cands);
            sides_on_paint(&scene.ctx(), &pass, &cands.list)
        };
        let found = found_for(&mut scene, [-0.2, -0.1]).expect("a change");
        assert!(
            (found[0] + 0.2).abs() < 0.011 && (found[1] + 0.1).abs() < 0.011,
            "{found:?}"
        );
        assert_eq!(found_for(&mut scene, [0.0, 0.0]), None);
        assert_eq!(found_for(&mut scene, [-0.2, 0.16]), None);
    }

    /// The shift rule alone (pure).
    #[test]
    fn stretches_of_opposite_signs_beyond_no_change_are_a_shift() {
        assert!(shifted([-0.2, 0.16]));
        assert!(!shifted([-0.2, -0.16]));
        assert!(!shifted([-0.2, 0.04]));
        assert!(!shifted([0.0, 0.3]));
    }
}
