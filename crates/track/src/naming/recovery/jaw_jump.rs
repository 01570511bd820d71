//! Jaw jumps: the jaw drops or snaps shut within a frame, the whole lower lip lands beyond
//! its prediction together and leaves motion-blur ghosts where it was (faint: part of the
//! exposure), some of its dots on the ghosts, others missing. When lip dots are missing with
//! candidates left, or two or more lower-lip dots sit on blobs under half a dot's area with
//! lip candidates left, the median offset from those dots' predictions to the nearest free
//! lip candidate (within [`JAW_JUMP_PX`] and their depth windows) is the jaw's jump; the
//! frame is named again with the lower lip between the corners predicted that much further.
//! Those names are taken if they name more lip dots, or as many on
//! [`BETTER_AREA_RATIO`] times the blob area (one fewer when two or more lower-lip dots were
//! on ghosts: a corner merged with its neighbour may fail the checks under the new names,
//! and missing beats five names on ghosts), and the corners are still the extremes.

use mouthpiece_detect::DotRole;
use mouthpiece_retarget::RigidTransform;

use super::{Candidates, Context, NameSet, Pass, Scratch, Step};
use crate::labels::{Candidate, Small};
use crate::naming::checked_pass;
use crate::naming::checks::{self, depth_window, disc_area};
use crate::prediction::{lip_predictions, LipMotion};

/// Farthest a lower-lip dot is looked for beyond its prediction when the jaw jumps, pixels
/// (the synthetic jaw moves the lower lip up to 13 px between frames).
pub const JAW_JUMP_PX: f64 = 12.0;

/// A lower-lip dot on a blob under this share of a dot's area is taken to be on a ghost.
/// (0.6 was measured: the character of the mild sessions 0.05–0.07 % of the width better,
/// but seed 32, Kinect-like, strong, 10 s, took the jaw's names wrongly: its worst rig curve
/// 0.085 → 0.203.)
pub const GHOST_AREA_SHARE: f64 = 0.5;

/// The jaw's names with as many lip dots win when their lower lip's blobs cover this many
/// times the area.
pub const BETTER_AREA_RATIO: f64 = 1.3;

/// This many lower-lip dots on ghosts (with as many lip candidates free) say the jaw jumped
/// even with every lip dot named, and allow the jaw's names one dot fewer: one dot on a
/// small blob is a faint dot, two are the lower lip left behind.
pub const GHOSTS_FOR_A_JUMP: usize = 2;

pub(crate) struct JawJump;

impl Step for JawJump {
    fn name(&self) -> &'static str {
        "jaw-jump"
    }

    fn run(
        &self,
        ctx: &Context,
        pass: &Pass,
        names: &mut NameSet,
        cands: &mut Candidates,
        scratch: &mut Scratch,
    ) -> bool {
        let layout = ctx.layout;
        let n = layout.lip_dots;
        let list = &cands.list;
        let ghosts = lower_lip_on_ghosts(ctx, names.as_slice(), cands);
        let on_ghosts = ghosts.iter().filter(|g| **g).count();
        let free_lips = (0..list.len())
            .filter(|c| list[*c].role != DotRole::Forehead && !names.taken()[*c])
            .count();
        let lower_area = |names: &NameSet, cands: &Candidates| -> f64 {
            names.as_slice()[layout.right_corner() + 1..n]
                .iter()
                .flatten()
                .map(|&c| ctx.blobs[cands.blob[c]].area as f64)
                .sum()
        };
        if !((names.lips_named(n) < n && pass.steady_named < list.len())
            || (on_ghosts >= GHOSTS_FOR_A_JUMP && free_lips >= GHOSTS_FOR_A_JUMP))
        {
            return false;
        }
        let Some(shift) = jaw_shift(ctx, names.as_slice(), &ghosts, list, &pass.head) else {
            return false;
        };
        let (_, jumped) = checked_pass(
            ctx,
            &pass.forehead,
            pass.head,
            LipMotion::JawJumped(shift),
            cands,
            scratch,
        );
        let slack = usize::from(on_ghosts >= GHOSTS_FOR_A_JUMP);
        let (before, after) = (names.lips_named(n), jumped.lips_named(n));
        let better = after > before
            || (after + slack >= before
                && lower_area(&jumped, cands) > BETTER_AREA_RATIO * lower_area(names, cands));
        if better && checks::corners_are_extremes(ctx, jumped.as_slice(), &cands.list) {
            tracing::debug!(
                before,
                jumped = after,
                ?shift,
                "the jaw jumped: lower lip named from its shifted places"
            );
            *names = jumped;
            return true;
        }
        false
    }
}

/// How far the lower lip jumped beyond its prediction, in pixels: the median offset from
/// the prediction of each lower-lip dot that is missing or on a ghost (`ghosts`) to the
/// nearest free lip candidate within [`JAW_JUMP_PX`] and its depth window. `None` when no
/// such candidate lies near one.
fn jaw_shift(
    ctx: &Context,
    names: &[Option<usize>],
    ghosts: &[bool],
    cands: &[Candidate],
    head: &RigidTransform,
) -> Option<[f64; 2]> {
    let n = ctx.layout.lip_dots;
    let preds = lip_predictions(ctx, head, LipMotion::Steady);
    let mut taken: Small<bool> = smallvec::smallvec![false; cands.len()];
    for c in names.iter().flatten() {
        taken[*c] = true;
    }
    let (mut dx, mut dy): (Small<f64>, Small<f64>) = (Small::new(), Small::new());
    for i in ctx.layout.right_corner() + 1..n {
        if names[i].is_some() && !ghosts[i] {
            continue;
        }
        let window = depth_window(&ctx.tracks[i], head, ctx.config.lip_depth_gate_m);
        let nearest = cands
            .iter()
            .enumerate()
            .filter(|&(j, c)| !taken[j] && c.role != DotRole::Forehead)
            .filter(|(_, c)| (window[0]..=window[1]).contains(&c.point.z))
            .map(|(_, c)| [c.pixel[0] - preds[i][0], c.pixel[1] - preds[i][1]])
            .filter(|d| d[0].hypot(d[1]) <= JAW_JUMP_PX)
            .min_by(|a, b| a[0].hypot(a[1]).total_cmp(&b[0].hypot(b[1])));
        if let Some(d) = nearest {
            dx.push(d[0]);
            dy.push(d[1]);
        }
    }
    let median = |v: &mut Small<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    (!dx.is_empty()).then(|| [median(&mut dx), median(&mut dy)])
}

/// Per lip dot: whether it is on the lower lip between the corners and named on a blob of
/// less than [`GHOST_AREA_SHARE`] of a dot's area (what a motion-blur ghost of the jaw's lip
/// looks like).
fn lower_lip_on_ghosts(ctx: &Context, names: &[Option<usize>], cands: &Candidates) -> Small<bool> {
    let n = ctx.layout.lip_dots;
    (0..n)
        .map(|i| {
            i > ctx.layout.right_corner()
                && names[i].is_some_and(|c| {
                    let r = ctx.dot_radius_px(cands.list[c].point.z);
                    (ctx.blobs[cands.blob[c]].area as f64) < GHOST_AREA_SHARE * disc_area(r)
                })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;

    /// The jaw drops 9 px within a frame: the lower lip between the corners lands beyond every
    /// gate and leaves faint ghosts where it was; D9..D11 are named on their ghosts, D8 and
    /// D12 are missing. The jaw's jump, measured from the missing dots to the free blobs,
    /// names the whole lower lip on its paint.
    #[test]
    fn a_lower_lip_on_its_ghosts_is_named_from_the_jaws_jump() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let truth = lower_lip_moved(&rest, [0.0, 9.0]);
        let mut cands = scene.candidates_at(&truth);
        let face = neutral_face();
        for (px, p) in rest.iter().zip(&face).take(11).skip(8) {
            scene.push(&mut cands, *px, p.z, DotRole::Lip, 0.3);
        }
        let mut pass = scene.pass(&rest, &cands);
        let mut names = scene.first_pass(&pass, &cands);
        pass.steady_named = names.count();
        assert_eq!(
            (names.get(7), names.get(8), names.get(9), names.get(11)),
            (None, Some(15), Some(16), None),
            "{:?}",
            named(&names)
        );
        let fired = JawJump.run(
            &scene.ctx(),
            &pass,
            &mut names,
            &mut cands,
            &mut Scratch::default(),
        );
        assert!(fired);
        assert_eq!(named(&names), identity());
    }
}
