//! The recovery steps: second chances for dots the first naming pass left missing or named
//! wrongly, each in a file of its own behind [`Step`], run in the order of [`STEPS`].
//!
//! Every step reads the frame ([`Context`]) and the naming hypothesis it runs in ([`Pass`]),
//! and changes the names ([`NameSet`]); the frame's [`crate::TrackedFrame::steps`] records
//! what each changed (`mouthpiece evaluate --steps` sums it over a session).

mod faint_corners;
mod follow_neighbours;
mod geometry_fill;
mod jaw_jump;
mod leave_ghosts;
mod rest_offsets;
mod shift_across_lip;
mod split_merged_blobs;
mod stopped_lips;
mod width_jump;

#[cfg(test)]
pub(crate) mod test_support;

pub(crate) use faint_corners::FaintCorners;
pub(crate) use follow_neighbours::FollowNeighbours;
pub(crate) use geometry_fill::GeometryFill;
pub(crate) use jaw_jump::JawJump;
pub(crate) use leave_ghosts::LeaveGhosts;
pub(crate) use rest_offsets::RestOffsets;
pub(crate) use shift_across_lip::ShiftAcrossLip;
pub(crate) use split_merged_blobs::SplitMergedBlobs;
pub(crate) use stopped_lips::StoppedLips;
pub(crate) use width_jump::WidthJump;

use super::{checked_pass, checks, pixels, score, Candidates, Context, NameSet, Pass, Scratch};
use crate::labels::{self, Slot, Small};
use crate::prediction::{self, LipMotion};

/// One recovery step.
pub(crate) trait Step: Sync {
    /// Its name, as `mouthpiece evaluate --steps` prints it.
    fn name(&self) -> &'static str;

    /// Runs the step on the names; true when it changed them (a step listed
    /// [`When::AfterPrevious`] runs only then).
    fn run(
        &self,
        ctx: &Context,
        pass: &Pass,
        names: &mut NameSet,
        cands: &mut Candidates,
        scratch: &mut Scratch,
    ) -> bool;
}

/// When in the naming of a frame a step runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Stage {
    /// Inside every naming hypothesis, after the assignment to predictions and before the
    /// order and neighbour checks; the lips only, on the detector's candidates.
    InPass,
    /// After the steady hypothesis: other lip motions propose names, and the names that
    /// score best are kept ([`take_if_better`]).
    Hypotheses,
    /// On the names chosen (after the corner check); may make candidates.
    Named,
}

/// Whether a step runs always or only after the step before it changed names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum When {
    Always,
    AfterPrevious,
}

pub(crate) struct Entry {
    pub(crate) stage: Stage,
    pub(crate) when: When,
    pub(crate) step: &'static dyn Step,
}

const fn entry(stage: Stage, when: When, step: &'static dyn Step) -> Entry {
    Entry { stage, when, step }
}

/// Every recovery step, in the order they run (within a stage; the stages run in the order
/// of [`Stage`], see [`super::name_frame`]).
pub(crate) static STEPS: [Entry; 12] = [
    // Speech moves neighbouring dots together: a missing dot is looked for where its
    // prediction lands moved as its found neighbours moved.
    entry(Stage::InPass, When::Always, &FollowNeighbours),
    // The jaw moves the lower lip across the lip line all at once: one common shift.
    entry(Stage::InPass, When::Always, &ShiftAcrossLip),
    entry(Stage::InPass, When::AfterPrevious, &FollowNeighbours),
    // A dot that stayed at its prediction while its neighbour jumped took its blur ghost.
    entry(Stage::InPass, When::Always, &LeaveGhosts),
    // Last in the pass: found neighbours' places plus the rest offsets.
    entry(Stage::InPass, When::Always, &RestOffsets),
    // Dots found from their neighbours show a jump the dots beside them stayed behind for.
    entry(Stage::InPass, When::AfterPrevious, &LeaveGhosts),
    // The hypotheses: each proposes names, the score keeps the best (the order does not
    // choose). Lips that stopped dead: named from where they were.
    entry(Stage::Hypotheses, When::Always, &StoppedLips),
    // Lips drawn in or spread within a frame: every dot named from its stretched place.
    entry(Stage::Hypotheses, When::Always, &WidthJump),
    // A jaw that jumped within a frame: the lower lip named from its shifted places. Last:
    // it also proposes its lower lip with the upper lip of the best names so far.
    entry(Stage::Hypotheses, When::Always, &JawJump),
    // As many candidates as dots: geometry fills in the missing, if it agrees.
    entry(Stage::Named, When::Always, &GeometryFill),
    // Two lip dots merged into one blob: split along its long axis.
    entry(Stage::Named, When::Always, &SplitMergedBlobs),
    // A mouth corner folded over its paint: named on a faint speck.
    entry(Stage::Named, When::Always, &FaintCorners),
];

/// The steps' names, each once, in the order they first run.
pub fn step_names() -> Vec<&'static str> {
    let mut names: Vec<&'static str> = Vec::new();
    for stage in [Stage::InPass, Stage::Hypotheses, Stage::Named] {
        for e in STEPS.iter().filter(|e| e.stage == stage) {
            if !names.contains(&e.step.name()) {
                names.push(e.step.name());
            }
        }
    }
    names
}

/// Runs the steps of `stage` in order, recording what each changed.
pub(crate) fn run_stage(
    stage: Stage,
    ctx: &Context,
    pass: &Pass,
    names: &mut NameSet,
    cands: &mut Candidates,
    scratch: &mut Scratch,
) {
    let mut previous = false;
    for e in STEPS.iter().filter(|e| e.stage == stage) {
        if e.when == When::AfterPrevious && !previous {
            continue;
        }
        let before = pixels(names, cands);
        // A step's own record is its net change: what it ran inside (another hypothesis's
        // steps) is not recorded apart.
        let mark = scratch.log.events.len();
        previous = e.step.run(ctx, pass, names, cands, scratch);
        scratch.log.events.truncate(mark);
        scratch.log.record(e.step.name(), &before, names, cands);
    }
}

/// Names missing lip dots at moved predictions (`moved`: dot, pixel), with the pass's
/// gates recomputed for this frame's positions (found or predicted). True when any dot was
/// found. Same gates (pixel and depth) as the first pass, candidates nobody took.
pub(crate) fn name_moved(
    ctx: &Context,
    pass: &Pass,
    names: &mut NameSet,
    cands: &Candidates,
    solver: &mut labels::Assignment,
    moved: &[(usize, [f64; 2])],
) -> bool {
    if moved.is_empty() {
        return false;
    }
    let n = ctx.layout.lip_dots;
    let mut all: Small<[f64; 2]> = (0..n)
        .map(|i| names.get(i).map_or(pass.preds[i], |c| cands.list[c].pixel))
        .collect();
    for &(i, p) in moved {
        all[i] = p;
    }
    let gates = prediction::gated(
        ctx.config,
        &all,
        &ctx.tracks[..n],
        Slot::Lip,
        &pass.head,
        ctx.spacing(),
    );
    let these: Small<labels::Prediction> = moved.iter().map(|&(i, _)| gates[i]).collect();
    let mut found = false;
    let assigned = labels::assign(&these, &cands.list, names.taken(), solver);
    for (&(i, _), c) in moved.iter().zip(assigned) {
        if let Some(c) = c {
            names.set(i, Some(c));
            found = true;
        }
    }
    found
}

/// Whether lip dots are missing while the steady hypothesis left candidates nobody took:
/// when the hypothesis steps look for another lip motion.
pub(crate) fn lips_missing_with_candidates_left(
    ctx: &Context,
    pass: &Pass,
    names: &NameSet,
    cands: &Candidates,
) -> bool {
    let n = ctx.layout.lip_dots;
    names.lips_named(n) < n && pass.steady_named < cands.len()
}

/// Names the frame again with the lips moving as `motion` (the pass's forehead and head
/// motion), and takes those names when they score better ([`take_if_better`]). Returns the
/// scores (nats) of the names before and after, when taken.
pub(crate) fn take_if_better_under(
    ctx: &Context,
    pass: &Pass,
    names: &mut NameSet,
    cands: &mut Candidates,
    scratch: &mut Scratch,
    motion: LipMotion,
) -> Option<(f64, f64)> {
    let (_, other) = checked_pass(ctx, &pass.forehead, pass.head, motion, cands, scratch);
    take_if_better(ctx, pass, names, other, cands)
}

/// The one rule by which a hypothesis's names replace the frame's: they keep the corners at
/// the extremes of the mouth (names slipped around the mouth keep every other order), and
/// their [`score`] is higher, with [`score::OTHER_MOTION_PRIOR`] added to theirs when the
/// frame's names are the steady hypothesis's. Returns the two scores (nats), when taken.
pub(crate) fn take_if_better(
    ctx: &Context,
    pass: &Pass,
    names: &mut NameSet,
    proposal: NameSet,
    cands: &Candidates,
) -> Option<(f64, f64)> {
    if !checks::corners_are_extremes(ctx, proposal.as_slice(), &cands.list) {
        return None;
    }
    // The frame's names still the steady hypothesis's: the proposal's lip motion is the less
    // likely one a priori.
    let prior = if pass.steady[..] == *names.as_slice() {
        score::OTHER_MOTION_PRIOR
    } else {
        0.0
    };
    let before = score::score(ctx, &pass.preds, &pass.head, names, cands).total();
    let after = score::score(ctx, &pass.preds, &pass.head, &proposal, cands).total() + prior;
    if after > before {
        *names = proposal;
        return Some((before, after));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::test_support::*;
    use super::*;
    use mouthpiece_detect::DotRole;

    /// D10 named on a blob of 70 % of a dot's paint where a full one lies on the same place:
    /// names on the full blob fit better by about 1 nat. Against the steady names that is
    /// less than another motion's prior, and they stand; against names another hypothesis
    /// proposed, it wins. A proposal naming a dot more replaces the steady names.
    #[test]
    fn a_proposal_replaces_the_steady_names_when_it_scores_better_by_the_motions_prior() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let mut cands = scene.candidates_at(&rest);
        let faint = scene.push(&mut cands, rest[9], neutral_face()[9].z, DotRole::Lip, 0.7);
        let ctx = scene.ctx();
        let mut pass = scene.pass(&rest, &cands);
        let mut on_faint: Vec<Option<usize>> = (0..15).map(Some).collect();
        on_faint[9] = Some(faint);
        let steady = NameSet::of(on_faint.iter().copied(), cands.len());
        let full = NameSet::of((0..15).map(Some), cands.len());
        let gain = score::score(&ctx, &pass.preds, &pass.head, &full, &cands).total()
            - score::score(&ctx, &pass.preds, &pass.head, &steady, &cands).total();
        assert!(gain > 0.5 && gain < -score::OTHER_MOTION_PRIOR, "{gain}");

        pass.steady = steady.as_slice().iter().copied().collect();
        let mut names = steady.clone();
        assert!(take_if_better(&ctx, &pass, &mut names, full.clone(), &cands).is_none());
        assert_eq!(names.as_slice(), steady.as_slice());

        pass.steady = Small::new();
        assert!(take_if_better(&ctx, &pass, &mut names, full.clone(), &cands).is_some());
        assert_eq!(names.as_slice(), full.as_slice());

        let mut one_missing = steady.clone();
        one_missing.set(3, None);
        pass.steady = one_missing.as_slice().iter().copied().collect();
        let mut names = one_missing;
        assert!(take_if_better(&ctx, &pass, &mut names, steady.clone(), &cands).is_some());
    }
}
