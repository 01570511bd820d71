//! Leaving blur ghosts: a lip dot that stayed where it was predicted while a neighbour
//! jumped has probably taken the motion blur's ghost of itself (the exposure also saw where
//! the lip just was). When a free candidate lies where the neighbour's motion puts the dot,
//! within its gate (or, when the neighbour moved less than its gate but the two misses
//! differ by more than half of it, within a quarter of the gate), the dot takes that one
//! and the ghost is left. Judged twice: against the predictions, and against where each dot
//! was last frame (a dot seen again only last frame has no velocity, so its prediction sits
//! on its own ghost and shows no miss while its neighbour's step since last frame points to
//! it). Corners neither move nor lead: a corner moves about half as far as the lip beside
//! it, and a corner name is the one most often on the wrong blob.

use mouthpiece_detect::DotRole;
use mouthpiece_retarget::PerformerLayout;

use super::{Candidates, Context, NameSet, Pass, Scratch, Step};
use crate::labels::Small;
use crate::naming::checks::blob_and_paint_area;

/// A neighbour that moved less than its gate pulls a dot only to a blob within this share
/// of the gate of where its motion points ...
pub const NEAR_REACH_SHARE: f64 = 0.25;
/// ... and only when the two misses differ by more than this share of the gate: a ghost
/// nearer the prediction than the dot wins the assignment, and a neighbour's motion that
/// differs from the dot's by less is the lip's own bend (the measurement:
/// docs/lab/detection-log.md).
pub const NEAR_APART_SHARE: f64 = 0.5;

/// A neighbour named on a blob of at least this many dots' area leads no one (named
/// heuristic *a merged blob leads no one*): its centre lies between two dots' paint (a
/// corner merged with the dot beside it), so its miss is the merge's, not the lip's motion.
/// Lent on, it pulls the neighbours it leads back from their paint onto their ghosts one
/// after the other (the measurement: docs/lab/detection-log.md).
pub const MERGED_LEADS_NO_ONE_DOTS: f64 = 2.0;

pub(crate) struct LeaveGhosts;

impl Step for LeaveGhosts {
    fn name(&self) -> &'static str {
        "leave-ghosts"
    }

    fn run(
        &self,
        ctx: &Context,
        pass: &Pass,
        names: &mut NameSet,
        cands: &mut Candidates,
        _scratch: &mut Scratch,
    ) -> bool {
        let n = ctx.layout.lip_dots;
        let preds: Small<Option<[f64; 2]>> = pass.preds.iter().map(|p| Some(*p)).collect();
        let a = leave_ghosts_from(ctx, pass, names, cands, &preds);
        let last: Small<Option<[f64; 2]>> = ctx.tracks[..n]
            .iter()
            .map(|t| (t.missing == 0).then_some(t.pixel))
            .collect();
        let b = leave_ghosts_from(ctx, pass, names, cands, &last);
        a || b
    }
}

/// [`LeaveGhosts`] with each dot's miss measured from `from` (a dot without one is left as
/// it is). True when a dot changed blobs.
fn leave_ghosts_from(
    ctx: &Context,
    pass: &Pass,
    names: &mut NameSet,
    cands: &Candidates,
    from: &[Option<[f64; 2]>],
) -> bool {
    let n = ctx.layout.lip_dots;
    let list = &cands.list;
    let gates = &pass.gates;
    let miss = |names: &NameSet, i: usize| {
        let from = from[i]?;
        names.get(i).map(|c| {
            let p = list[c].pixel;
            [p[0] - from[0], p[1] - from[1]]
        })
    };
    let norm = |v: [f64; 2]| (v[0] * v[0] + v[1] * v[1]).sqrt();
    let layout = ctx.layout;
    let is_corner = |i: usize| i == layout.left_corner() || i == layout.right_corner();
    let mut changed = false;
    for i in (0..n).filter(|&i| !is_corner(i)) {
        let Some(own) = miss(names, i) else { continue };
        let g = gates[i];
        // The neighbour that moved most beyond its prediction.
        let Some(moved) = [(i + n - 1) % n, (i + 1) % n]
            .iter()
            .filter(|&&j| !is_corner(j))
            .filter(|&&j| !names.get(j).is_some_and(|c| on_merged_blob(ctx, cands, c)))
            .filter_map(|&j| miss(names, j))
            .max_by(|a, b| norm(*a).total_cmp(&norm(*b)))
        else {
            continue;
        };
        let apart = norm([own[0] - moved[0], own[1] - moved[1]]);
        // A neighbour that jumped beyond its gate pulls from anywhere within the gate; one
        // that moved less only to a blob right where its motion points.
        let reach = if norm(moved) > g.gate_px && apart > g.gate_px {
            g.gate_px
        } else if apart > NEAR_APART_SHARE * g.gate_px {
            NEAR_REACH_SHARE * g.gate_px
        } else {
            continue;
        };
        let base = from[i].expect("a dot with a miss has a place it is measured from");
        let target = [base[0] + moved[0], base[1] + moved[1]];
        let better = (0..list.len())
            .filter(|&j| !names.taken()[j] && list[j].role != DotRole::Forehead)
            .filter(|&j| (list[j].point.z - g.z).abs() <= g.z_gate)
            .map(|j| {
                let p = list[j].pixel;
                (j, norm([p[0] - target[0], p[1] - target[1]]))
            })
            .filter(|&(_, d)| d < reach)
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((j, _)) = better {
            names.set(i, Some(j));
            changed = true;
            tracing::debug!(dot = %PerformerLayout::lip_name(i), "stayed while its neighbour moved: took the blob the neighbour's motion points to");
        }
    }
    changed
}

/// Whether candidate `c` is on a detector blob of at least [`MERGED_LEADS_NO_ONE_DOTS`]
/// dots' area at its depth.
fn on_merged_blob(ctx: &Context, cands: &Candidates, c: usize) -> bool {
    blob_and_paint_area(ctx, cands, c)
        .is_some_and(|(blob, paint)| blob >= MERGED_LEADS_NO_ONE_DOTS * paint)
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;

    /// The lower lip drops 4 px (within the gates); D10's motion blur leaves a ghost of its
    /// paint where it was, right at its prediction, which the assignment gives it. Its
    /// neighbours' motion points to its own blob: it leaves the ghost.
    #[test]
    fn a_dot_on_its_ghost_takes_the_blob_its_neighbours_motion_points_to() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let mut truth = rest.clone();
        for p in &mut truth[8..11] {
            p[1] += 4.0;
        }
        let mut cands = scene.candidates_at(&truth);
        let ghost = scene.push(&mut cands, rest[9], 0.596, DotRole::Lip, 0.4);
        let pass = scene.pass(&rest, &cands);
        let (first, names) = scene.run_after_first_pass(&LeaveGhosts, &pass, &mut cands);
        assert_eq!(first.get(9), Some(ghost), "the first pass takes the ghost");
        assert_eq!(named(&names), identity());
    }

    /// A merged blob leads no one: D8 sits 2.8 px above its prediction on a blob of three
    /// dots' area (merged with paint beside it); D9 is on its paint at its prediction, and a
    /// faint ghost lies where D8's miss points from there. D9 keeps its paint. With D8 on a
    /// blob of one dot's area, the same miss leads D9 onto the blob (the step as before).
    #[test]
    fn a_dot_on_a_merged_blob_leads_no_one() {
        for (d8_area, d9_leaves) in [(3.0, false), (1.0, true)] {
            let mut scene = Scene::calibrated();
            let rest = scene.rest_pixels();
            let mut truth = rest.clone();
            truth[7][1] -= 2.8;
            let mut cands = scene.candidates_hiding(&truth, 7);
            let face = neutral_face();
            let d8 = scene.push(&mut cands, truth[7], face[7].z, DotRole::Lip, d8_area);
            let ghost_px = [rest[8][0], rest[8][1] - 2.8];
            let ghost = scene.push(&mut cands, ghost_px, 0.596, DotRole::Lip, 0.3);
            let paint = (0..cands.len()).find(|&c| cands.list[c].pixel == truth[8]);
            let pass = scene.pass(&rest, &cands);
            let (first, names) = scene.run_after_first_pass(&LeaveGhosts, &pass, &mut cands);
            assert_eq!(first.get(7), Some(d8), "D8 named on its blob");
            assert_eq!(first.get(8), paint, "D9 named on its paint");
            let expected = if d9_leaves { Some(ghost) } else { paint };
            assert_eq!(names.get(8), expected, "D8 of {d8_area} dots' area");
        }
    }
}
