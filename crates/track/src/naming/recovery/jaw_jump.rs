//! Jaw jumps: the jaw drops or snaps shut within a frame, the whole lower lip lands beyond
//! its prediction together and leaves motion-blur ghosts where it was (faint: part of the
//! exposure), some of its dots on the ghosts, others missing. When lip dots are missing with
//! candidates left, or two or more lower-lip dots sit on blobs under half a dot's area with
//! lip candidates left, the median offset from those dots' predictions to the nearest free
//! lip candidate (within [`JAW_JUMP_SPACINGS`] and their depth windows) is the jaw's jump; the
//! frame is named again with the lower lip between the corners predicted that much further.
//! Those names are proposed and taken when they score better
//! ([`super::take_if_better`]): a lower lip on ghosts loses by the paint term (ghosts are a
//! share of the paint) and the depth term (a ghost's depth is whatever surface is behind
//! it), so names with one dot fewer and the rest on paint can win.
//!
//! Ghosts can be too large to tell by their area (a fast jaw smears the paint too), with
//! every dot named on its own ghost and no miss anywhere. So on every frame the jump is also
//! measured from the whole lower lip ([`whole_lip_shift`], reaching further:
//! [`WHOLE_LIP_JUMP_SPACINGS`]) and proposed the same way, its names only if they land on free
//! paint ([`lands_on_free_blobs`]); so are the missing dots' when their jump runs along the
//! lip rather than across it ([`ALONG_LIP_SHARE`]). The jaw carries the lower lip alone:
//! when the frame left it on ghosts, the jaw's lower lip is also proposed with the frame's
//! upper lip ([`with_the_upper_lip_of`]).

use mouthpiece_detect::DotRole;
use mouthpiece_retarget::RigidTransform;

use super::{
    lips_missing_with_candidates_left, take_if_better, Candidates, Context, NameSet, Pass, Scratch,
    Step,
};
use crate::labels::{Candidate, Small};
use crate::naming::checks::{blob_and_paint_area, depth_window};
use crate::naming::{checked_pass, score};
use crate::prediction::{lip_predictions, lips_depth, CornerLine, LipMotion};

/// Farthest a lower-lip dot that is missing or on a ghost is looked for beyond its
/// prediction when the jaw jumps, in dot spacings ([`score::spacing_px`] at the dot's last
/// depth; 12 px for the synthetic performer at 0.6 m and 640x480, where its jaw moves the
/// lower lip up to 13 px between frames). Not further: the lower-lip dots lie a little more
/// than a spacing apart, and one hidden dot's nearest free blob would be its neighbour's
/// paint.
pub const JAW_JUMP_SPACINGS: f64 = 1.3;

/// Farthest the *whole-lip jump* looks beyond each lower-lip dot's prediction, in dot
/// spacings (16 px at 0.6 m and 640x480): a frame's jaw motion (up to 1.4 spacings) and the
/// lag of the ghosts the last frame may have named the lip on, which the prediction starts
/// from (up to half a spacing). It can reach past the dots' spacing where
/// [`JAW_JUMP_SPACINGS`] cannot, because it is the median over most of the lower lip and its
/// names must land on free paint ([`lands_on_free_blobs`]).
pub const WHOLE_LIP_JUMP_SPACINGS: f64 = 1.73;

/// A lower-lip dot on a blob under this share of a dot's area is taken to be on a ghost:
/// half a dot's paint is more than a blurred trail leaves and less than a dot half
/// occluded shows (0.6 took the jaw's names wrongly on a fast session: the lab notes).
pub const GHOST_AREA_SHARE: f64 = 0.5;

/// The whole-lip jump is tried only when it differs from the lost dots' by more than this
/// share of a dot spacing (otherwise it names the frame the same way; 1 px at 0.6 m and
/// 640x480).
pub const SAME_SHIFT_SPACINGS: f64 = 0.11;

/// A jump whose component along the line through the predicted corners exceeds this share
/// of the lip dots' spacing runs along the lip, not across it (named heuristic *a jump along
/// the lip lands on free paint*): its names must land on free paint like the whole lip's.
/// The jaw moves the lower lip across the mouth; a jump along it is the missing dots' own
/// paint out of their depth windows and their neighbours' paint nearest instead; taken, it
/// puts each dot on the next dot's paint until the slipped-names check catches it.
pub const ALONG_LIP_SHARE: f64 = 0.5;

/// This many lower-lip dots on ghosts (with as many lip candidates free) say the jaw jumped
/// even with every lip dot named: one dot on a small blob is a faint dot, two are the lower
/// lip left behind.
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
        // The jump is measured from the best names so far and, when they differ, from the
        // steady hypothesis's: another hypothesis's names may hide the lower lip's misses.
        let frame = names.clone();
        let mut taken = propose_from(ctx, pass, &frame, names, cands, scratch);
        if pass.steady.len() == frame.as_slice().len() && pass.steady[..] != *frame.as_slice() {
            let steady = NameSet::of(pass.steady.iter().copied(), cands.len());
            taken |= propose_from(ctx, pass, &steady, names, cands, scratch);
        }
        taken
    }
}

/// The jaw's proposals with the jump measured from the names `frame` (their lower lip
/// missing or on ghosts), each taken into `names` when it scores better. True when one was.
fn propose_from(
    ctx: &Context,
    pass: &Pass,
    frame: &NameSet,
    names: &mut NameSet,
    cands: &mut Candidates,
    scratch: &mut Scratch,
) -> bool {
    let layout = ctx.layout;
    let n = layout.lip_dots;
    let list = &cands.list;
    let ghosts = lower_lip_on_ghosts(ctx, frame.as_slice(), cands);
    let on_ghosts = ghosts.iter().filter(|g| **g).count();
    let free_lips = (0..list.len())
        .filter(|c| list[*c].role != DotRole::Forehead && !frame.taken()[*c])
        .count();
    let lost = lips_missing_with_candidates_left(ctx, pass, frame, cands)
        || (on_ghosts >= GHOSTS_FOR_A_JUMP && free_lips >= GHOSTS_FOR_A_JUMP);
    // Two estimates of the jump: from the dots that are missing or on ghosts, and from
    // the whole lower lip (its dots may sit on ghosts too large to tell by their area,
    // with every dot named).
    let from_lost = lost
        .then(|| jaw_shift(ctx, frame.as_slice(), &ghosts, list, &pass.head))
        .flatten();
    let same = SAME_SHIFT_SPACINGS * lower_lip_spacing_px(ctx, &pass.preds);
    let from_lip = whole_lip_shift(ctx, frame.as_slice(), list, &pass.head)
        .filter(|s| from_lost.is_none_or(|f| (s[0] - f[0]).hypot(s[1] - f[1]) > same));
    // Landing on free paint is judged against `frame`; each proposal that may stand is
    // taken when it scores better than the best so far.
    let mut taken = false;
    let estimates = [(from_lost, false), (from_lip, true)];
    for (shift, whole_lip) in estimates.into_iter().filter_map(|(s, w)| Some((s?, w))) {
        let must_land = whole_lip || runs_along_the_lip(ctx, &pass.preds, shift);
        let (_, jumped) = checked_pass(
            ctx,
            &pass.forehead,
            pass.head,
            LipMotion::JawJumped(shift),
            cands,
            scratch,
        );
        // When the frame left the lower lip on its ghosts, also the jaw's lower lip with
        // the frame's upper lip (landing on free paint), besides the jaw's names whole.
        let lower_lip_only = (on_ghosts >= GHOSTS_FOR_A_JUMP)
            .then(|| with_the_upper_lip_of(names, &jumped, layout.right_corner(), n))
            .flatten();
        let tries = [(lower_lip_only, true), (Some(jumped), must_land)];
        for (jumped, must_land) in tries.into_iter().filter_map(|(j, m)| Some((j?, m))) {
            if must_land && !lands_on_free_blobs(frame.as_slice(), jumped.as_slice()) {
                continue;
            }
            if let Some((before, after)) = take_if_better(ctx, pass, names, jumped, cands) {
                tracing::debug!(
                    before,
                    after,
                    ?shift,
                    "the jaw jumped: lower lip named from its shifted places (score, nats)"
                );
                taken = true;
            }
        }
    }
    taken
}

/// How far the lower lip jumped beyond its prediction, in pixels: the median offset from
/// the prediction of each lower-lip dot that is missing or on a ghost (`ghosts`) to the
/// nearest free lip candidate within [`JAW_JUMP_SPACINGS`] and its depth window. `None` when no
/// such candidate lies near one.
fn jaw_shift(
    ctx: &Context,
    names: &[Option<usize>],
    ghosts: &[bool],
    cands: &[Candidate],
    head: &RigidTransform,
) -> Option<[f64; 2]> {
    let offsets = jump_offsets(ctx, names, ghosts, cands, head, JAW_JUMP_SPACINGS);
    (!offsets.is_empty()).then(|| median_offset(offsets))
}

/// For each lower-lip dot between the corners that is missing or flagged in `lost`: the
/// offset from its prediction to the nearest free lip candidate within `reach` dot spacings
/// (at the dot's last depth) and its
/// depth window, if there is one.
fn jump_offsets(
    ctx: &Context,
    names: &[Option<usize>],
    lost: &[bool],
    cands: &[Candidate],
    head: &RigidTransform,
    reach: f64,
) -> Small<[f64; 2]> {
    let n = ctx.layout.lip_dots;
    let preds = lip_predictions(ctx, head, LipMotion::Steady);
    let mut taken: Small<bool> = smallvec::smallvec![false; cands.len()];
    for c in names.iter().flatten() {
        taken[*c] = true;
    }
    let mut offsets = Small::new();
    for i in ctx.layout.right_corner() + 1..n {
        if names[i].is_some() && !lost[i] {
            continue;
        }
        let window = depth_window(&ctx.tracks[i], head, ctx.config.lip_depth_gate_m);
        let reach_px = reach * score::spacing_px(ctx, &preds, ctx.tracks[i].depth);
        let nearest = cands
            .iter()
            .enumerate()
            .filter(|&(j, c)| !taken[j] && c.role != DotRole::Forehead)
            .filter(|(_, c)| (window[0]..=window[1]).contains(&c.point.z))
            .map(|(_, c)| [c.pixel[0] - preds[i][0], c.pixel[1] - preds[i][1]])
            .filter(|d| d[0].hypot(d[1]) <= reach_px)
            .min_by(|a, b| a[0].hypot(a[1]).total_cmp(&b[0].hypot(b[1])));
        offsets.extend(nearest);
    }
    offsets
}

/// The dot spacing in pixels at the lower lip's mean last depth (`preds`: the lips'
/// predictions, for the spacing before the neutral pose).
fn lower_lip_spacing_px(ctx: &Context, preds: &[[f64; 2]]) -> f64 {
    let lower = &ctx.tracks[ctx.layout.right_corner() + 1..ctx.layout.lip_dots];
    let z = lower.iter().map(|t| t.depth).sum::<f64>() / lower.len().max(1) as f64;
    score::spacing_px(ctx, preds, z)
}

/// The median of each coordinate of `offsets` (not empty).
fn median_offset(offsets: Small<[f64; 2]>) -> [f64; 2] {
    let median = |mut v: Small<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    [
        median(offsets.iter().map(|d| d[0]).collect()),
        median(offsets.iter().map(|d| d[1]).collect()),
    ]
}

/// How far the whole lower lip jumped beyond its prediction, in pixels (named heuristic
/// *whole-lip jump*): the median, over the lower-lip dots between the corners, of the offset
/// from each dot's prediction to the nearest free lip candidate within
/// [`WHOLE_LIP_JUMP_SPACINGS`] and its depth window, named or not. A jaw that jumps leaves every lower-lip dot's ghost
/// where the lip was, and a dot named on its ghost shows no miss; its paint is then a free
/// blob just beyond. `None` unless most of the lower lip (more than half its dots) has such
/// a candidate: the lip moves as one.
fn whole_lip_shift(
    ctx: &Context,
    names: &[Option<usize>],
    cands: &[Candidate],
    head: &RigidTransform,
) -> Option<[f64; 2]> {
    let all_lost: Small<bool> = smallvec::smallvec![true; ctx.layout.lip_dots];
    let lower = ctx.layout.lip_dots - ctx.layout.right_corner() - 1;
    let offsets = jump_offsets(ctx, names, &all_lost, cands, head, WHOLE_LIP_JUMP_SPACINGS);
    (offsets.len() > lower / 2).then(|| median_offset(offsets))
}

/// Whether `shift` (pixels) runs along the lip: its component along the line through the
/// predicted corners (`preds`, layout order) is more than [`ALONG_LIP_SHARE`] of the lip
/// dots' spacing. Corners too close to give a line: no.
fn runs_along_the_lip(ctx: &Context, preds: &[[f64; 2]], shift: [f64; 2]) -> bool {
    let spacing = score::spacing_px(ctx, preds, lips_depth(ctx));
    CornerLine::measurable(preds, &ctx.layout, spacing)
        .is_some_and(|line| line.runs_along(&shift, ctx.layout.lip_dots, ALONG_LIP_SHARE))
}

/// `names` with the lower lip between the corners (after `right_corner`, before `lip_dots`)
/// named as in `jumped` (named heuristic *the jaw moves the lower lip only*). The jaw's pass
/// names the whole mouth again from the steady prediction, but the jaw carries the lower lip
/// alone: the upper lip and the corners keep the names the frame has, which may come from a
/// better pass (stopped lips). Compared whole, a jaw that found the lower lip on its paint
/// can lose to names on ghosts only because its upper lip was named worse.
/// Tried only when the frame has two or more lower-lip dots on ghosts
/// ([`GHOSTS_FOR_A_JUMP`]: the lower lip was left behind, not lost along the lip), before the
/// jaw's names whole, and its lower lip must land on free paint. `None` when the two would
/// share a blob.
fn with_the_upper_lip_of(
    names: &NameSet,
    jumped: &NameSet,
    right_corner: usize,
    lip_dots: usize,
) -> Option<NameSet> {
    let lower = right_corner + 1..lip_dots;
    let merged = NameSet::of(
        (0..names.as_slice().len()).map(|i| {
            if lower.contains(&i) {
                jumped.get(i)
            } else {
                names.get(i)
            }
        }),
        jumped.taken().len().max(names.taken().len()),
    );
    let named = merged.as_slice().iter().flatten().count();
    let distinct = merged.taken().iter().filter(|t| **t).count();
    (named == distinct).then_some(merged)
}

/// Whether every dot named in `jumped` keeps its blob from `names` or takes one no dot had
/// (named heuristic *lands on free paint*). A lower lip that jumped past its ghosts lands on
/// paint nobody was named on; names that move onto a neighbour's blob have slipped along the
/// lip (a head turned far, a corner's large merged blob taken by the dot beside it).
fn lands_on_free_blobs(names: &[Option<usize>], jumped: &[Option<usize>]) -> bool {
    jumped.iter().zip(names).all(|(after, before)| match after {
        Some(c) => Some(*c) == *before || !names.contains(&Some(*c)),
        None => true,
    })
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
                    blob_and_paint_area(ctx, cands, c)
                        .is_some_and(|(blob, paint)| blob < GHOST_AREA_SHARE * paint)
                })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;

    /// The jaw's naming step on a lower lip that jumped `by_px` down within a frame, leaving
    /// faint ghosts (0.3 of the paint) of D9..D11 where it was, its predictions still there.
    fn lower_lip_jumped_past_faint_ghosts(by_px: f64) -> HypothesisRun {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let truth = lower_lip_moved(&rest, [0.0, by_px]);
        let mut cands = scene.candidates_at(&truth);
        let face = neutral_face();
        for (px, p) in rest.iter().zip(&face).take(11).skip(8) {
            scene.push(&mut cands, *px, p.z, DotRole::Lip, 0.3);
        }
        scene.run_as_hypothesis(&JawJump, &rest, &mut cands)
    }

    /// The jaw drops 9 px within a frame: the lower lip between the corners lands beyond every
    /// gate and leaves faint ghosts where it was; D9..D11 are named on their ghosts, D8 and
    /// D12 are missing. The jaw's jump, measured from the missing dots to the free blobs,
    /// names the whole lower lip on its paint.
    #[test]
    fn a_lower_lip_on_its_ghosts_is_named_from_the_jaws_jump() {
        let run = lower_lip_jumped_past_faint_ghosts(9.0);
        assert_eq!(
            (
                run.first.get(7),
                run.first.get(8),
                run.first.get(9),
                run.first.get(11)
            ),
            (None, Some(15), Some(16), None),
            "{:?}",
            named(&run.first)
        );
        assert!(run.fired);
        assert_eq!(named(&run.names), identity());
    }

    /// The jaw snaps shut 14 px beyond the lower lip's predictions (a frame's jaw motion and
    /// the lag of the ghosts the predictions were made from) and leaves faint ghosts where
    /// it was; D9..D11 are named on them, D8 and D12 are missing. Too far for the missing
    /// dots' own jump; the whole lip's jump finds the paint.
    #[test]
    fn a_lower_lip_a_jump_and_a_ghosts_lag_away_is_found() {
        let run = lower_lip_jumped_past_faint_ghosts(14.0);
        assert!(run.fired, "{:?}", named(&run.first));
        assert_eq!(named(&run.names), identity());
    }

    /// The jaw drops 9 px within a frame; D8..D11 leave ghosts of 0.7 of their paint where
    /// they were (too large to pass for ghosts by their area) and are named on them with no
    /// miss, D12 is hidden. No dot is on a ghost by area, and no free blob lies near the
    /// hidden dot: only the whole lower lip's jump finds the paint.
    #[test]
    fn a_lower_lip_on_large_ghosts_is_named_from_the_whole_lips_jump() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let truth = lower_lip_moved(&rest, [0.0, 9.0]);
        let face = neutral_face();
        let mut cands = scene.candidates_hiding(&truth, 11);
        let ghosts: Vec<usize> = (7..11)
            .map(|i| scene.push(&mut cands, rest[i], face[i].z, DotRole::Lip, 0.7))
            .collect();
        let run = scene.run_as_hypothesis(&JawJump, &rest, &mut cands);
        let on_ghosts: Vec<_> = (7..11).map(|i| run.first.get(i)).collect();
        assert_eq!(
            on_ghosts,
            ghosts.iter().map(|g| Some(*g)).collect::<Vec<_>>()
        );
        assert!(run.fired, "{:?}", named(&run.names));
        let lower: Vec<_> = (7..12).map(|i| run.names.get(i)).collect();
        assert_eq!(lower, vec![Some(7), Some(8), Some(9), Some(10), None]);
    }

    /// As above with every dot seen and named: the whole lower lip on ghosts of 0.7 of its
    /// paint, 3 mm deeper than the lip (the surface behind the ghost), nothing missing, no
    /// ghost small enough to count. The whole lip's jump is looked for all the same, and its
    /// names on the paint score better by area and depth together.
    #[test]
    fn a_fully_named_lower_lip_on_large_ghosts_moves_to_its_paint() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let truth = lower_lip_moved(&rest, [0.0, 9.0]);
        let mut cands = scene.candidates_at(&truth);
        let face = neutral_face();
        for i in 7..12 {
            scene.push(&mut cands, rest[i], face[i].z + 0.003, DotRole::Lip, 0.7);
        }
        let run = scene.run_as_hypothesis(&JawJump, &rest, &mut cands);
        let first: Vec<_> = (7..12).map(|i| run.first.get(i)).collect();
        assert_eq!(first, (15..20).map(Some).collect::<Vec<_>>());
        assert!(run.fired, "{:?}", named(&run.names));
        assert_eq!(named(&run.names), identity());
    }

    /// The lower lip is named on its paint and its ghosts are left free above it, one dot
    /// hidden: the whole lip's jump points at the ghosts, and naming them would cover less
    /// paint, so the names stay.
    #[test]
    fn a_lower_lip_on_its_paint_keeps_its_names_beside_its_ghosts() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let face = neutral_face();
        let mut cands = scene.candidates_hiding(&rest, 11);
        let above = lower_lip_moved(&rest, [0.0, -5.0]);
        for i in 7..11 {
            scene.push(&mut cands, above[i], face[i].z, DotRole::Lip, 0.6);
        }
        let run = scene.run_as_hypothesis(&JawJump, &rest, &mut cands);
        let before = named(&run.first);
        assert_eq!(before[7..11], [Some(7), Some(8), Some(9), Some(10)]);
        assert!(whole_lip_shift(
            &scene.ctx(),
            run.first.as_slice(),
            &cands.list,
            &run.pass.head
        )
        .is_some_and(|s| s[1] < -4.0));
        assert!(!run.fired);
        assert_eq!(named(&run.names), before);
    }

    /// The face at rest is level: its corners 0.05 m apart at 0.6 m, the lip dots about 7 px
    /// apart. A jaw's jump across the mouth, even a long one, does not run along the lip; one
    /// of most of a dot's spacing sideways does.
    #[test]
    fn a_jump_runs_along_the_lip_by_its_component_along_the_corners() {
        let scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let spacing = 2.0 * (rest[0][0] - rest[6][0]).abs() / 12.0;
        assert!((6.0..9.0).contains(&spacing), "{spacing}");
        let ctx = scene.ctx();
        assert!(!runs_along_the_lip(&ctx, &rest, [0.0, 12.0]));
        assert!(!runs_along_the_lip(&ctx, &rest, [0.4 * spacing, 9.0]));
        assert!(runs_along_the_lip(&ctx, &rest, [0.6 * spacing, 0.0]));
        assert!(runs_along_the_lip(&ctx, &rest, [-8.6, 3.2]));
        // Corners on top of each other give no line.
        let mut folded = rest.clone();
        folded[6] = folded[0];
        assert!(!runs_along_the_lip(&ctx, &folded, [8.6, 3.2]));
    }

    #[test]
    fn landing_on_free_paint_keeps_blobs_or_takes_unnamed_ones() {
        let names = [Some(0), Some(1), Some(2), None];
        // Keeps two, takes the unnamed 5, loses one: on free paint.
        assert!(lands_on_free_blobs(
            &names,
            &[Some(0), Some(1), Some(5), None]
        ));
        assert!(lands_on_free_blobs(
            &names,
            &[None, Some(1), Some(2), Some(7)]
        ));
        // Slipped one place along the lip: dot 1 on dot 0's blob, dot 2 on dot 1's.
        assert!(!lands_on_free_blobs(
            &names,
            &[None, Some(0), Some(1), Some(2)]
        ));
        // One swap is enough.
        assert!(!lands_on_free_blobs(
            &names,
            &[Some(1), Some(0), Some(2), None]
        ));
    }

    /// The frame's names have the upper lip where it went (raised 6 px, named by a pass that
    /// predicted it there) and the lower lip on the faint ghosts the jaw left 9 px above its
    /// paint; both lips left faint ghosts where they were. The jaw's own pass predicts the
    /// upper lip steady, on its ghosts; the jaw moves the lower lip only, so its lower lip is
    /// taken with the frame's upper lip.
    #[test]
    fn the_jaw_moves_the_lower_lip_only() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let mut truth = lower_lip_moved(&rest, [0.0, 9.0]);
        for p in &mut truth[1..6] {
            p[1] -= 6.0;
        }
        let mut cands = scene.candidates_at(&truth);
        let face = neutral_face();
        for i in (1..6).chain(7..12) {
            scene.push(&mut cands, rest[i], face[i].z, DotRole::Lip, 0.3);
        }
        // Predicted where the frame's names are: the upper lip raised, the lower lip at rest.
        let mut preds = truth.clone();
        preds[7..12].copy_from_slice(&rest[7..12]);
        let pass = scene.pass(&preds, &cands);
        let ctx = scene.ctx();
        let (_, jaws_own) = checked_pass(
            &ctx,
            &pass.forehead,
            pass.head,
            LipMotion::JawJumped([0.0, 9.0]),
            &mut cands,
            &mut Scratch::default(),
        );
        let upper: Vec<_> = (1..6).map(|i| jaws_own.get(i)).collect();
        assert_eq!(
            upper,
            (15..20).map(Some).collect::<Vec<_>>(),
            "{:?}",
            named(&jaws_own)
        );
        let (first, names) = scene.run_after_first_pass(&JawJump, &pass, &mut cands);
        let on_ghosts: Vec<_> = (7..12).map(|i| first.get(i)).collect();
        assert_eq!(on_ghosts, (20..25).map(Some).collect::<Vec<_>>());
        assert_eq!(named(&names), identity());
    }

    /// Dots 0 and 1 the corner and upper lip, 2 and 3 the lower lip, 4 a forehead dot: the
    /// lower lip comes from the jaw's names, the rest from the frame's, unless a blob would
    /// then name two dots.
    #[test]
    fn the_jaws_lower_lip_joins_the_frames_upper_lip_unless_they_share_a_blob() {
        let names = NameSet::of([Some(0), Some(1), Some(2), Some(7), Some(8)], 10);
        let jumped = NameSet::of([Some(0), Some(5), Some(6), Some(3), Some(9)], 10);
        let merged = with_the_upper_lip_of(&names, &jumped, 1, 4).expect("no blob shared");
        assert_eq!(
            merged.as_slice(),
            &[Some(0), Some(1), Some(6), Some(3), Some(8)]
        );
        assert!(merged.taken()[6] && !merged.taken()[2] && !merged.taken()[7]);
        let onto_the_upper_lip = NameSet::of([Some(0), Some(5), Some(6), Some(1), Some(9)], 10);
        assert!(with_the_upper_lip_of(&names, &onto_the_upper_lip, 1, 4).is_none());
    }

    /// The jaw drops 6 px within a frame and leaves ghosts of the lower lip where it was, at
    /// `ghost_area` of a dot's paint and `ghost_dz` metres deeper than the dots' last depths;
    /// the frame names the lower lip on them. The lower lip's paint is at its last depths,
    /// on `paint_area` of a dot's paint. The names after the jaw's step.
    fn lower_lip_left_on_ghosts(ghost_area: f64, ghost_dz: f64, paint_area: f64) -> NameSet {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let truth = lower_lip_moved(&rest, [0.0, 6.0]);
        let face = neutral_face();
        let mut cands = scene.candidates_at(&truth[..7]);
        for i in 7..12 {
            scene.push(&mut cands, truth[i], face[i].z, DotRole::Lip, paint_area);
        }
        for i in 12..15 {
            scene.push(&mut cands, truth[i], face[i].z, DotRole::Forehead, 1.0);
        }
        for i in 7..12 {
            scene.push(
                &mut cands,
                rest[i],
                face[i].z + ghost_dz,
                DotRole::Lip,
                ghost_area,
            );
        }
        let run = scene.run_as_hypothesis(&JawJump, &rest, &mut cands);
        let first: Vec<_> = (7..12).map(|i| run.first.get(i)).collect();
        assert_eq!(first, (15..20).map(Some).collect::<Vec<_>>());
        run.names
    }

    /// Ghosts nearly as large as the paint (0.9 against 1.0: no ghost by its area, and not
    /// 1.3 times the paint) but 6 mm deeper than the lip was: the jaw's names, on the paint
    /// at the lip's depths, win by their depth.
    #[test]
    fn the_jaws_lip_keeps_its_depth() {
        assert_eq!(
            named(&lower_lip_left_on_ghosts(0.9, 0.006, 1.0)),
            identity()
        );
        // The ghosts at the lip's depths: nothing tells them from the paint.
        let at_depth = lower_lip_left_on_ghosts(0.9, 0.0, 1.0);
        assert_eq!(at_depth.get(9), Some(17), "{:?}", named(&at_depth));
    }

    /// The jaw's lower lip at the lip's depths but on less paint than the frame's (0.6
    /// against 0.9): its depth does not outweigh the paint.
    #[test]
    fn the_jaws_depth_does_not_outweigh_less_paint() {
        let names = lower_lip_left_on_ghosts(0.9, 0.006, 0.6);
        assert_eq!(names.get(9), Some(17), "{:?}", named(&names));
    }
}
