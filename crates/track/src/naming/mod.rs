//! Naming the frame's candidates: which blob is which dot.
//!
//! Without names from earlier frames, from geometry alone ([`labels::label_by_geometry`]).
//! With them, by prediction and optimal assignment, then the recovery steps
//! ([`recovery::STEPS`], in the order listed there):
//! 1. the forehead by constant pixel velocity, the head motion from it;
//! 2. the lips by prediction under a motion hypothesis (steady velocity first), the
//!    in-pass recovery steps, then the checks ([`checks::order_and_neighbours`]);
//! 3. the hypothesis steps: other lip motions propose names, and one score
//!    ([`score::score`]) keeps the best;
//! 4. the corner check: names slipped around the mouth are named afresh from geometry, or
//!    the lips go missing for the frame;
//! 5. the steps on the chosen names (geometry filling in, merged blobs split, faint corners).
//!
//! The names live in a [`NameSet`]: a step proposes names, the checks drop some, and a step
//! whose result fails the checks rolls back as one transaction.

pub mod checks;
pub mod recovery;
pub mod score;

use mouthpiece_detect::{Blob, DotRole};
use mouthpiece_retarget::kabsch::kabsch;
use mouthpiece_retarget::{NeutralPose, PerformerLayout, RigidTransform};

use crate::config::TrackConfig;
use crate::depth::DepthScratch;
use crate::head::HeadReference;
use crate::labels::{self, Candidate, Slot, Small};
use crate::output::StepEvent;
use crate::prediction::{self, DotTrack, LipMotion};
use crate::Sensor;
use recovery::Stage;

/// What naming reads of the tracker and the frame. Built once per frame; steps and checks
/// read it and change nothing in it.
#[derive(Clone, Copy)]
pub(crate) struct Context<'a> {
    pub(crate) layout: PerformerLayout,
    pub(crate) config: &'a TrackConfig,
    /// Per dot (lip dots, then forehead); empty before the first full naming.
    pub(crate) tracks: &'a [DotTrack],
    /// The neutral pose, once calibrated (the checks need its mouth frame).
    pub(crate) neutral: Option<&'a NeutralPose>,
    pub(crate) head: HeadReference<'a>,
    /// This frame's interval over the one the velocities were measured over.
    pub(crate) step_ratio: f64,
    /// Per colour class: what it may hold.
    pub(crate) roles: &'a [DotRole],
    /// The detector's blobs (candidates point into them) and its faint specks.
    pub(crate) blobs: &'a [Blob],
    pub(crate) faint: &'a [Blob],
    pub(crate) sensor: Sensor<'a>,
}

impl Context<'_> {
    /// Whether there are names from earlier frames to predict from.
    pub(crate) fn tracking(&self) -> bool {
        !self.tracks.is_empty()
    }

    /// A dot's paint radius in pixels at depth `z` (metres).
    pub(crate) fn dot_radius_px(&self, z: f64) -> f64 {
        self.sensor.dot_radius_px(z)
    }

    /// The dot spacing of the lips at rest ([`prediction::DotSpacing`]); `None` before any
    /// names.
    pub(crate) fn spacing(&self) -> Option<prediction::DotSpacing> {
        prediction::DotSpacing::of_rest(self.head.rest, self.sensor.k.fx)
    }

    /// The smallest gate around a prediction at depth `z`, pixels
    /// ([`TrackConfig::min_gate_spacings`]; 0 without a spacing).
    pub(crate) fn min_gate_px(&self, z: f64) -> f64 {
        self.spacing()
            .map_or(0.0, |s| self.config.min_gate_spacings * s.px(z))
    }
}

/// The frame's candidates: the detector's blobs with a depth, then those a step made (split
/// halves, faint corners).
#[derive(Debug, Default)]
pub(crate) struct Candidates {
    pub(crate) list: Vec<Candidate>,
    /// Per candidate: its blob in the detections (split halves: the blob split; faint
    /// corners: none, `usize::MAX`).
    pub(crate) blob: Vec<usize>,
    /// `list[..real]` are the detector's.
    pub(crate) real: usize,
}

impl Candidates {
    pub(crate) fn clear(&mut self) {
        self.list.clear();
        self.blob.clear();
        self.real = 0;
    }

    /// A candidate the detector found (before any a step makes).
    pub(crate) fn push_detected(&mut self, cand: Candidate, blob: usize) {
        debug_assert_eq!(self.real, self.list.len());
        self.list.push(cand);
        self.blob.push(blob);
        self.real = self.list.len();
    }

    /// A candidate a step made; returns its index.
    pub(crate) fn push_made(&mut self, cand: Candidate, blob: usize) -> usize {
        self.list.push(cand);
        self.blob.push(blob);
        self.list.len() - 1
    }

    pub(crate) fn len(&self) -> usize {
        self.list.len()
    }

    /// Candidates a step made that no name refers to are removed and the names re-pointed:
    /// the frame's unassigned candidates are then blobs the detector found, never a step's
    /// leftovers.
    pub(crate) fn drop_unnamed_extras(&mut self, names: &mut [Option<usize>]) {
        let real = self.real;
        let mut next = real;
        for c in real..self.list.len() {
            if !names.contains(&Some(c)) {
                continue;
            }
            if c != next {
                self.list.swap(next, c);
                self.blob.swap(next, c);
                for name in names.iter_mut().filter(|n| **n == Some(c)) {
                    *name = Some(next);
                }
            }
            next += 1;
        }
        self.list.truncate(next);
        self.blob.truncate(next);
    }
}

/// The frame's names, per dot (lip dots, then forehead): the candidate each has, and which
/// candidates are taken. A step that must keep or undo all its names at once opens a
/// transaction ([`NameSet::begin`]) and commits or rolls it back.
#[derive(Debug, Clone)]
pub(crate) struct NameSet {
    names: Small<Option<usize>>,
    taken: Small<bool>,
    saved: Option<Small<Option<usize>>>,
}

impl NameSet {
    /// Every dot missing, `cands` candidates free.
    pub(crate) fn missing(dots: usize, cands: usize) -> Self {
        NameSet {
            names: smallvec::smallvec![None; dots],
            taken: smallvec::smallvec![false; cands],
            saved: None,
        }
    }

    /// These names over `cands` candidates.
    pub(crate) fn of(names: impl IntoIterator<Item = Option<usize>>, cands: usize) -> Self {
        let mut set = NameSet {
            names: names.into_iter().collect(),
            taken: Small::new(),
            saved: None,
        };
        set.retake(cands);
        set
    }

    fn retake(&mut self, cands: usize) {
        self.taken.clear();
        self.taken.resize(cands, false);
        for c in self.names.iter().flatten() {
            self.taken[*c] = true;
        }
    }

    pub(crate) fn get(&self, dot: usize) -> Option<usize> {
        self.names[dot]
    }

    pub(crate) fn as_slice(&self) -> &[Option<usize>] {
        &self.names
    }

    /// Per candidate: whether a dot has it.
    pub(crate) fn taken(&self) -> &[bool] {
        &self.taken
    }

    /// Names dot `dot` on candidate `cand` (`None`: missing); the candidate it had is free.
    pub(crate) fn set(&mut self, dot: usize, cand: Option<usize>) {
        if let Some(old) = self.names[dot] {
            self.taken[old] = false;
        }
        if let Some(c) = cand {
            if c >= self.taken.len() {
                self.taken.resize(c + 1, false);
            }
            self.taken[c] = true;
        }
        self.names[dot] = cand;
    }

    /// Dots named.
    pub(crate) fn count(&self) -> usize {
        self.names.iter().filter(|c| c.is_some()).count()
    }

    /// Lip dots (the first `lip_dots`) named.
    pub(crate) fn lips_named(&self, lip_dots: usize) -> usize {
        self.names[..lip_dots]
            .iter()
            .filter(|c| c.is_some())
            .count()
    }

    pub(crate) fn all_named(&self) -> bool {
        self.names.iter().all(Option::is_some)
    }

    /// Runs a check (or anything else that only drops or moves names) on the names.
    pub(crate) fn apply(&mut self, check: impl FnOnce(&mut [Option<usize>]), cands: usize) {
        check(&mut self.names);
        self.retake(cands);
    }

    /// Opens a transaction: what follows is kept by [`NameSet::commit`] or undone by
    /// [`NameSet::rollback`].
    pub(crate) fn begin(&mut self) {
        debug_assert!(self.saved.is_none(), "transactions do not nest");
        self.saved = Some(self.names.clone());
    }

    pub(crate) fn commit(&mut self) {
        self.saved = None;
    }

    /// Back to the names at [`NameSet::begin`].
    pub(crate) fn rollback(&mut self, cands: usize) {
        if let Some(saved) = self.saved.take() {
            self.names = saved;
            self.retake(cands);
        }
    }

    /// The step's leftovers dropped ([`Candidates::drop_unnamed_extras`]) and the names
    /// re-pointed.
    pub(crate) fn drop_unnamed_extras(&mut self, cands: &mut Candidates) {
        cands.drop_unnamed_extras(&mut self.names);
        self.retake(cands.len());
    }
}

/// One naming hypothesis: the forehead names and head motion it starts from, the lip
/// motion it assumes, and the lips' predictions and gates under it.
#[derive(Debug, Clone)]
pub(crate) struct Pass {
    /// This frame's head motion (reference → now), from the named forehead.
    pub(crate) head: RigidTransform,
    pub(crate) forehead: Small<Option<usize>>,
    /// Per lip dot: its predicted pixel and gates.
    pub(crate) preds: Small<[f64; 2]>,
    pub(crate) gates: Small<labels::Prediction>,
    /// How many dots the steady hypothesis named (after its checks).
    pub(crate) steady_named: usize,
    /// The steady hypothesis's names (after its checks; empty until it has run).
    pub(crate) steady: Small<Option<usize>>,
}

/// Buffers kept between frames (a frame allocates nothing once they have grown), and the
/// frame's record of what the steps did.
#[derive(Debug, Default)]
pub(crate) struct Scratch {
    pub(crate) solver: labels::Assignment,
    pub(crate) depth: DepthScratch,
    pub(crate) log: StepLog,
}

/// What the naming steps changed on this frame ([`crate::TrackedFrame::steps`]).
#[derive(Debug, Default)]
pub(crate) struct StepLog {
    pub(crate) events: Vec<StepEvent>,
    runs: u16,
}

/// Room the step log takes up front, per dot: every entry of the step list renaming every
/// dot under four motion hypotheses. A frame that needs more grows the log (one allocation)
/// and loses nothing; reserving it keeps the per-frame path allocation-free in steady state.
const STEP_EVENTS_PER_DOT: usize = 4 * recovery::STEPS.len();

impl StepLog {
    /// Reserves the log for `dots` dots ([`STEP_EVENTS_PER_DOT`]).
    pub(crate) fn reserve_for(&mut self, dots: usize) {
        self.events.reserve(dots * STEP_EVENTS_PER_DOT);
    }

    pub(crate) fn clear(&mut self) {
        self.events.clear();
        self.runs = 0;
    }

    /// One run of `step`: every dot whose candidate's pixel differs from `before`.
    fn record(
        &mut self,
        step: &'static str,
        before: &[Option<[f64; 2]>],
        names: &NameSet,
        cands: &Candidates,
    ) {
        let mut any = false;
        for (dot, (b, name)) in before.iter().zip(names.as_slice()).enumerate() {
            let after = name.map(|c| cands.list[c].pixel);
            if *b != after {
                any = true;
                self.events.push(StepEvent {
                    step,
                    run: self.runs,
                    dot: dot as u16,
                    before: *b,
                    after,
                });
            }
        }
        self.runs += u16::from(any);
    }
}

/// Each dot's candidate pixel (`None`: missing).
fn pixels(names: &NameSet, cands: &Candidates) -> Small<Option<[f64; 2]>> {
    names
        .as_slice()
        .iter()
        .map(|c| c.map(|c| cands.list[c].pixel))
        .collect()
}

/// Names from geometry alone, or `None` (logged) when it cannot name every dot.
pub(crate) fn geometry(ctx: &Context, cands: &[Candidate]) -> Option<Small<usize>> {
    match labels::label_by_geometry(cands, ctx.layout) {
        Ok(names) => Some(names),
        Err(why) => {
            tracing::trace!(?why, candidates = cands.len(), "no names from geometry");
            None
        }
    }
}

/// Names for this frame's candidates, per dot (lip dots, then forehead).
pub(crate) fn name_frame(ctx: &Context, cands: &mut Candidates, scratch: &mut Scratch) -> NameSet {
    let total = ctx.layout.lip_dots + ctx.layout.forehead_dots;
    scratch.log.clear();
    if !ctx.tracking() {
        return match geometry(ctx, &cands.list) {
            Some(names) => NameSet::of(names.into_iter().map(Some), cands.len()),
            None => NameSet::missing(total, cands.len()),
        };
    }
    // The forehead is named once; the lips under each motion hypothesis.
    let (forehead, head) = assign_forehead(ctx, &cands.list, &mut scratch.solver);
    let (mut pass, mut names) =
        checked_pass(ctx, &forehead, head, LipMotion::Steady, cands, scratch);
    pass.steady_named = names.count();
    pass.steady = names.as_slice().iter().copied().collect();
    recovery::run_stage(Stage::Hypotheses, ctx, &pass, &mut names, cands, scratch);
    if !checks::corners_are_extremes(ctx, names.as_slice(), &cands.list) {
        // Names slipped by one or more places around the mouth (a slip keeps the order):
        // geometry names a full set afresh; without one the lips go missing for now
        // (missing beats wrong).
        tracing::debug!("lip names slipped around the mouth; renaming");
        match geometry(ctx, &cands.list) {
            Some(geo) => names = NameSet::of(geo.into_iter().map(Some), cands.len()),
            None => {
                for dot in 0..ctx.layout.lip_dots {
                    names.set(dot, None);
                }
            }
        }
    }
    recovery::run_stage(Stage::Named, ctx, &pass, &mut names, cands, scratch);
    names
}

/// Forehead names by prediction (constant pixel velocity), and the head motion
/// (reference → now) fitted to the named forehead dots (the last one without any).
fn assign_forehead(
    ctx: &Context,
    cands: &[Candidate],
    solver: &mut labels::Assignment,
) -> (Small<Option<usize>>, RigidTransform) {
    let n = ctx.layout.lip_dots;
    let preds = prediction::forehead_predictions(ctx, ctx.sensor.k);
    let taken: Small<bool> = smallvec::smallvec![false; cands.len()];
    let gates = prediction::gated(
        ctx.config,
        &preds,
        &ctx.tracks[n..],
        Slot::Forehead,
        &ctx.head.last,
        ctx.spacing(),
    );
    let forehead = labels::assign(&gates, cands, &taken, solver);
    let (from, to): (Small<crate::Vec3>, Small<crate::Vec3>) = forehead
        .iter()
        .enumerate()
        .filter_map(|(j, c)| c.map(|c| (ctx.head.forehead[j], cands[c].point)))
        .unzip();
    let head = kabsch(&from, &to).unwrap_or(ctx.head.last);
    (forehead, head)
}

/// One naming hypothesis: the lips named by prediction under `motion` on the candidates the
/// forehead left, the in-pass recovery steps, then the checks that drop names breaking the
/// mouth's shape. Returns the pass and every name (lip dots, then the given forehead ones).
pub(crate) fn checked_pass(
    ctx: &Context,
    forehead: &[Option<usize>],
    head: RigidTransform,
    motion: LipMotion,
    cands: &mut Candidates,
    scratch: &mut Scratch,
) -> (Pass, NameSet) {
    let n = ctx.layout.lip_dots;
    let preds = prediction::lip_predictions(ctx, &head, motion);
    let gates = prediction::gated(
        ctx.config,
        &preds,
        &ctx.tracks[..n],
        Slot::Lip,
        &head,
        ctx.spacing(),
    );
    let mut names = NameSet::of(
        std::iter::repeat_n(None, n).chain(forehead.iter().copied()),
        cands.len(),
    );
    let lips = labels::assign(&gates, &cands.list, names.taken(), &mut scratch.solver);
    for (dot, c) in lips.into_iter().enumerate() {
        if c.is_some() {
            names.set(dot, c);
        }
    }
    let pass = Pass {
        head,
        forehead: forehead.iter().copied().collect(),
        preds,
        gates,
        steady_named: 0,
        steady: Small::new(),
    };
    recovery::run_stage(Stage::InPass, ctx, &pass, &mut names, cands, scratch);
    names.apply(
        |names| checks::order_and_neighbours(ctx, names, &cands.list),
        cands.len(),
    );
    (pass, names)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A transaction keeps or undoes every name it changed, and the taken candidates follow.
    #[test]
    fn a_name_set_commits_or_rolls_back_as_one() {
        let mut names = NameSet::of([Some(0), None, Some(2)], 4);
        names.begin();
        names.set(1, Some(3));
        names.set(0, None);
        assert_eq!(names.taken(), [false, false, true, true]);
        names.rollback(4);
        assert_eq!(names.as_slice(), [Some(0), None, Some(2)]);
        assert_eq!(names.taken(), [true, false, true, false]);
        names.begin();
        names.set(1, Some(1));
        names.commit();
        assert_eq!(names.as_slice(), [Some(0), Some(1), Some(2)]);
        assert_eq!((names.count(), names.lips_named(2)), (3, 2));
    }
}
