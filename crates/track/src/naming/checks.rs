//! Pure checks on a set of names: the depth gate, the order along the lips, the corners out
//! beyond their neighbours, the corners at the extremes of the mouth. Each reads the frame's
//! [`Context`] and the candidates and changes nothing but the names it is given (a name that
//! breaks a check is dropped: missing beats wrong).

use mouthpiece_detect::DotRole;
use mouthpiece_retarget::{PerformerLayout, RigidTransform};

use super::{Candidates, Context};
use crate::labels::{Candidate, Small};
use crate::prediction::DotTrack;
use crate::Vec3;

/// In the neutral mouth frame a corner stays out beyond its two neighbours, and each
/// upper-lip dot above the lower-lip dot opposite it, by at least this share of their gap at
/// rest: speech narrows those gaps but never turns them over, so a name that does is on
/// another dot's blob (the check's measurement: docs/lab/detection-log.md).
pub const NEIGHBOUR_MARGIN: f64 = 0.4;

/// A dot unseen for at most this many frames is taken to be where it was last seen.
pub const RECENT_FRAMES: u32 = 2;

/// A dot unseen for longer than this many frames is not taken to be anywhere.
pub const STALE_FRAMES: u32 = 30;

/// The named corners must be the lip dots furthest out along the mouth's x axis, to within
/// this share of the mouth's width.
pub const CORNER_EXTREME_TOLERANCE: f64 = 0.03;

/// The depths (metres, low and high) a lip candidate may have to be this dot: within `gate`
/// of its last depth or of its last place carried by this frame's head motion (`head`).
pub(crate) fn depth_window(track: &DotTrack, head: &RigidTransform, gate: f64) -> [f64; 2] {
    let (last, carried) = (track.depth, head.apply(&track.stab).z);
    [last.min(carried) - gate, last.max(carried) + gate]
}

/// Area (pixels) of a disc of radius `r` pixels: what a dot's paint covers.
pub(crate) fn disc_area(r: f64) -> f64 {
    std::f64::consts::PI * r * r
}

/// The area (pixels) of the detector blob candidate `c` stands on, and of one dot's paint
/// at the candidate's depth; `None` for a candidate no blob stands for (a faint corner).
pub(crate) fn blob_and_paint_area(
    ctx: &Context,
    cands: &Candidates,
    c: usize,
) -> Option<(f64, f64)> {
    let blob = ctx.blobs.get(*cands.blob.get(c)?)?;
    let paint = disc_area(ctx.dot_radius_px(cands.list[c].point.z));
    Some((blob.area as f64, paint))
}

/// Names that break the walk around the mouth are dropped: in the neutral mouth frame (head
/// motion removed), the named lip dots must meet in label order going round the mouth's
/// origin from the left corner over the upper lip. The longest run of names in order is
/// kept, the others become missing.
pub(crate) fn enforce_lip_order(ctx: &Context, names: &mut [Option<usize>], cands: &[Candidate]) {
    let Some(neutral) = ctx.neutral else { return };
    let frame = &neutral.frame;
    let n = ctx.layout.lip_dots;
    let inverse = ctx.head.now(names, cands).inverse();
    // Angle about the mouth origin, the walk starting at the left corner (or, when it is
    // not seen, half-way between it and the last lower-lip dot at rest).
    let tau = std::f64::consts::TAU;
    let raw = |c: usize| {
        let q = frame.to_mouth(&inverse.apply(&cands[c].point));
        q.y.atan2(q.x)
    };
    let start = match names[0] {
        // Just before the corner itself, so that it is first.
        Some(c) => raw(c) - 1e-9,
        None => {
            let rest = |i: usize| neutral.lip[i].y.atan2(neutral.lip[i].x);
            let (last, first) = (rest(n - 1), rest(0));
            let last = if last > first { last - tau } else { last };
            (last + first) / 2.0
        }
    };
    let angle = |c: usize| (raw(c) - start).rem_euclid(tau);
    let found: Small<(usize, f64)> = (0..n)
        .filter_map(|i| names[i].map(|c| (i, angle(c))))
        .collect();
    if found.len() < 2 {
        return;
    }
    // Longest increasing subsequence of the angles in label order (n is small: O(n²)).
    let mut best_len: Small<usize> = smallvec::smallvec![1; found.len()];
    let mut prev: Small<usize> = smallvec::smallvec![usize::MAX; found.len()];
    for a in 0..found.len() {
        for b in 0..a {
            if found[b].1 < found[a].1 && best_len[b] + 1 > best_len[a] {
                best_len[a] = best_len[b] + 1;
                prev[a] = b;
            }
        }
    }
    let mut end = (0..found.len())
        .max_by_key(|&a| best_len[a])
        .expect("non-empty");
    let mut keep: Small<bool> = smallvec::smallvec![false; found.len()];
    loop {
        keep[end] = true;
        if prev[end] == usize::MAX {
            break;
        }
        end = prev[end];
    }
    for (a, &(i, _)) in found.iter().enumerate() {
        if !keep[a] {
            tracing::debug!(dot = %PerformerLayout::lip_name(i), "name breaks the order around the mouth; dropped");
            names[i] = None;
        }
    }
}

/// With one of two neighbouring dots unseen, names can slip by one place without breaking
/// the order around the mouth: the dot next to a corner named on the corner's blob, the
/// corner on its neighbour's, a lower-lip dot on the upper-lip blob above it. In the
/// neutral mouth frame (head motion removed) a corner stays out beyond its two
/// neighbours, and each upper-lip dot above the lower-lip dot opposite it, by at least
/// [`NEIGHBOUR_MARGIN`] of their gap at rest; with one of the two unseen, the seen one is
/// held to that against where the unseen one is taken to be. A name that breaks it is
/// dropped.
pub(crate) fn keep_corner_neighbours_in_place(
    ctx: &Context,
    names: &mut [Option<usize>],
    cands: &[Candidate],
) {
    let Some(neutral) = ctx.neutral else {
        return;
    };
    let tracks = ctx.tracks;
    let frame = &neutral.frame;
    let n = ctx.layout.lip_dots;
    let inverse = ctx.head.now(names, cands).inverse();
    let now = |names: &[Option<usize>], i: usize| {
        names[i].map(|c| frame.to_mouth(&inverse.apply(&cands[c].point)))
    };
    let (left, right) = (ctx.layout.left_corner(), ctx.layout.right_corner());
    let is_corner = |i: usize| i == left || i == right;
    // Where an unseen dot is taken to be: where it was, if lately; a lip dot unseen for
    // longer, from a seen lip neighbour (not a corner) plus their offset at rest (the
    // mouth moves on while a dot is unseen); else where it was, up to STALE_FRAMES back.
    let last = |names: &[Option<usize>], i: usize| {
        let track = &tracks[i];
        if track.missing > RECENT_FRAMES && !is_corner(i) {
            let seen = [(i + n - 1) % n, (i + 1) % n]
                .into_iter()
                .filter(|&k| !is_corner(k))
                .find_map(|k| now(names, k).map(|q| (k, q)));
            if let Some((k, q)) = seen {
                return Some(q + (neutral.lip[i] - neutral.lip[k]));
            }
        }
        (track.missing <= STALE_FRAMES).then(|| frame.to_mouth(&track.stab))
    };
    // (outer or upper dot, inner or lower dot, axis): `outer` stays beyond `inner` along
    // the axis (x for the left corner, -x for the right one, y for upper over lower).
    let x = Vec3::x();
    let y = Vec3::y();
    let corners = [
        (left, (left + 1) % n, x),
        (left, (left + n - 1) % n, x),
        (right, right - 1, -x),
        (right, right + 1, -x),
    ];
    // Each upper-lip dot over the lower-lip dot opposite it (D2 over D12, … D6 over D8).
    let lips = (1..right).map(|u| (u, n - u, y));
    // Along each lip, each dot beyond its neighbour towards the right corner (D2 beyond
    // D3, …; D12 beyond D11, …): a name slipped one place along a lip with the dot it
    // slipped onto unseen keeps every other order, and held on for 1.5 s in one session.
    let upper = (1..right - 1).map(|i| (i, i + 1, x));
    let lower = (right + 1..n - 1).map(|i| (i + 1, i, x));
    let pairs = corners.into_iter().chain(lips).chain(upper).chain(lower);
    // A corner unseen for a while, checked against one neighbour, from its other
    // neighbour as seen now plus their rest offset (a mouth pursing moves the corners in).
    let corner_ref = |names: &[Option<usize>], corner: usize, against: usize| {
        let other = [(corner + n - 1) % n, (corner + 1) % n]
            .into_iter()
            .find(|&k| k != against)
            .expect("a corner has two neighbours");
        match now(names, other) {
            Some(q) if tracks[corner].missing > RECENT_FRAMES => {
                Some(q + (neutral.lip[corner] - neutral.lip[other]))
            }
            _ => last(names, corner),
        }
    };
    for (outer, inner, axis) in pairs {
        let gap = (neutral.lip[outer] - neutral.lip[inner]).dot(&axis);
        if gap <= 0.0 {
            continue;
        }
        let margin = NEIGHBOUR_MARGIN * gap;
        let outer_ref = |names: &[Option<usize>]| {
            if is_corner(outer) {
                corner_ref(names, outer, inner)
            } else {
                last(names, outer)
            }
        };
        match (now(names, outer), now(names, inner)) {
            (None, Some(q)) if outer_ref(names).is_some_and(|o| (o - q).dot(&axis) < margin) => {
                tracing::debug!(dot = %PerformerLayout::lip_name(inner), "where an unseen neighbour was; name dropped");
                names[inner] = None;
            }
            (Some(q), None) if last(names, inner).is_some_and(|i| (q - i).dot(&axis) < margin) => {
                tracing::debug!(dot = %PerformerLayout::lip_name(outer), "where an unseen neighbour was; name dropped");
                names[outer] = None;
            }
            _ => {}
        }
    }
}

/// Whether the named mouth corners are the lip dots furthest out along the mouth's x axis
/// (neutral mouth frame, head motion removed), within [`CORNER_EXTREME_TOLERANCE`] of the
/// mouth width: names that slipped around the mouth still meet in order, but put a corner
/// name on a lip dot.
pub(crate) fn corners_are_extremes(
    ctx: &Context,
    names: &[Option<usize>],
    cands: &[Candidate],
) -> bool {
    let Some(neutral) = ctx.neutral else {
        return true;
    };
    let frame = &neutral.frame;
    let tolerance = CORNER_EXTREME_TOLERANCE * frame.width;
    let (n, left, right) = (
        ctx.layout.lip_dots,
        ctx.layout.left_corner(),
        ctx.layout.right_corner(),
    );
    let inverse = ctx.head.now(names, cands).inverse();
    let x = |i: usize| names[i].map(|c| frame.to_mouth(&inverse.apply(&cands[c].point)).x);
    let others = || (0..n).filter(|&i| i != left && i != right).filter_map(x);
    let left_ok = x(left).is_none_or(|l| others().all(|o| o <= l + tolerance));
    let right_ok = x(right).is_none_or(|r| others().all(|o| o >= r - tolerance));
    left_ok && right_ok
}

/// The checks a naming hypothesis's names go through: the order along the lips, then the
/// corners' neighbours.
pub(crate) fn order_and_neighbours(
    ctx: &Context,
    names: &mut [Option<usize>],
    cands: &[Candidate],
) {
    enforce_lip_order(ctx, names, cands);
    keep_corner_neighbours_in_place(ctx, names, cands);
}

/// An unnamed lip blob lies between two named neighbours when it projects onto the segment
/// joining them between these shares of the way from one to the other ...
pub const BETWEEN_NEIGHBOURS_SPAN: [f64; 2] = [0.2, 0.8];

/// ... and at most this share of the segment's length off it.
pub const BETWEEN_NEIGHBOURS_OFFSET: f64 = 0.3;

/// *A blob between neighbours*: a lip blob no name took, lying between two lip dots named
/// next to each other around the mouth (pixels; at least `min_separation_px` from each, so it
/// is a dot of its own and not a fragment of theirs). A lip whose names slipped one place as
/// a piece passes every order and corner check, but leaves the first dot's own blob unnamed
/// between it and its neighbour. Returns the two dots and the blob.
pub(crate) fn blob_between_neighbours(
    lip_names: &[Option<usize>],
    cands: &[Candidate],
    taken: &[bool],
    min_separation_px: f64,
) -> Option<(usize, usize, usize)> {
    let n = lip_names.len();
    let free = || (0..cands.len()).filter(|&c| !taken[c] && cands[c].role != DotRole::Forehead);
    for a in 0..n {
        let b = (a + 1) % n;
        let (Some(ca), Some(cb)) = (lip_names[a], lip_names[b]) else {
            continue;
        };
        let (pa, pb) = (cands[ca].pixel, cands[cb].pixel);
        let along = [pb[0] - pa[0], pb[1] - pa[1]];
        let len2 = along[0] * along[0] + along[1] * along[1];
        if len2 <= 0.0 {
            continue;
        }
        let len = len2.sqrt();
        for c in free() {
            let p = cands[c].pixel;
            let rel = [p[0] - pa[0], p[1] - pa[1]];
            let s = (rel[0] * along[0] + rel[1] * along[1]) / len2;
            let off = (rel[0] * along[1] - rel[1] * along[0]).abs() / len;
            let apart = |q: [f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]) >= min_separation_px;
            if (BETWEEN_NEIGHBOURS_SPAN[0]..=BETWEEN_NEIGHBOURS_SPAN[1]).contains(&s)
                && off <= BETWEEN_NEIGHBOURS_OFFSET * len
                && apart(pa)
                && apart(pb)
            {
                return Some((a, b, c));
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use nalgebra::Rotation3;

    use super::*;
    use crate::naming::recovery::test_support::{neutral_face, Scene};
    use crate::naming::Candidates;

    /// A head turned by yaw and pitch (degrees) about a point behind the mouth, and shifted.
    fn head(yaw_deg: f64, pitch_deg: f64, shift: Vec3) -> RigidTransform {
        let pivot = Vec3::new(0.01, 0.0, 0.65);
        let r = Rotation3::from_euler_angles(pitch_deg.to_radians(), yaw_deg.to_radians(), 0.0)
            .into_inner();
        RigidTransform {
            rotation: r,
            translation: pivot - r * pivot + shift,
        }
    }

    /// The face with the jaw open by `open` metres, moved by `head`.
    fn posed(open: f64, head: &RigidTransform) -> Vec<Vec3> {
        neutral_face()
            .into_iter()
            .enumerate()
            .map(|(i, p)| {
                let lower = (7..12).contains(&i);
                head.apply(&if lower {
                    p + Vec3::new(0.0, open, 0.0)
                } else {
                    p
                })
            })
            .collect()
    }

    /// Candidates exactly at the given dots, in their order (D1..D12, F1..F3).
    fn candidates(scene: &Scene, truth: &[Vec3]) -> Candidates {
        let mut cands = Candidates::default();
        for (i, p) in truth.iter().enumerate() {
            let role = if i < 12 {
                mouthpiece_detect::DotRole::Lip
            } else {
                mouthpiece_detect::DotRole::Forehead
            };
            cands.push_detected(
                Candidate {
                    pixel: crate::camera::project(&scene.k, p).unwrap(),
                    point: *p,
                    role,
                },
                i,
            );
        }
        cands
    }

    #[test]
    fn names_slipped_around_the_mouth_are_caught_by_the_corners() {
        let scene = Scene::calibrated();
        let ctx = scene.ctx();
        // The head turned and the jaw open: candidates in truth order (D1..D12, F1..F3).
        let truth = posed(0.006, &head(10.0, 4.0, Vec3::new(0.005, 0.0, 0.0)));
        let cands = candidates(&scene, &truth).list;
        let right: Vec<Option<usize>> = (0..15).map(Some).collect();
        assert!(corners_are_extremes(&ctx, &right, &cands));
        // Every lip name one place on around the mouth: still in order, but D7 (the right
        // corner) now sits on D8's blob and D1 on D2's: the order check cannot see it, the
        // corners can.
        for shift in [1, 11] {
            let slipped: Vec<Option<usize>> = (0..12)
                .map(|i| Some((i + shift) % 12))
                .chain((12..15).map(Some))
                .collect();
            assert!(
                !corners_are_extremes(&ctx, &slipped, &cands),
                "slip by {shift}"
            );
        }
        // A corner missing is no evidence of a slip.
        let mut missing = right.clone();
        missing[6] = None;
        assert!(corners_are_extremes(&ctx, &missing, &cands));
    }

    #[test]
    fn a_name_slipped_onto_an_unseen_neighbours_place_is_dropped() {
        let scene = Scene::calibrated();
        let ctx = scene.ctx();
        let cands = candidates(&scene, &posed(0.0, &RigidTransform::IDENTITY)).list;
        let right: Vec<Option<usize>> = (0..15).map(Some).collect();
        let check = |names: &[Option<usize>]| {
            let mut names = names.to_vec();
            keep_corner_neighbours_in_place(&ctx, &mut names, &cands);
            names
        };
        assert_eq!(check(&right), right, "right names stay");
        // `dot` named on the blob of `unseen`, which is not seen: is the name dropped?
        let dropped = |unseen: usize, dot: usize| {
            let mut slipped = right.clone();
            slipped[unseen] = None;
            slipped[dot] = Some(unseen);
            check(&slipped)[dot].is_none()
        };
        // D1 (left corner) unseen, D2 on its blob: in order around the mouth, but out where
        // the corner is.
        assert!(dropped(0, 1));
        // D2 unseen, D1 on D2's blob: not out beyond where D2 is.
        assert!(dropped(1, 0));
        // D4 unseen, D10 on its blob: a lower-lip dot over the upper lip.
        assert!(dropped(3, 9));
        // Along a lip: D10 unseen, D9 on its blob; D4 unseen, D3 on its blob.
        assert!(dropped(9, 8));
        assert!(dropped(3, 2));
        // A corner unseen and its neighbours in place: nothing to drop.
        let mut missing = right.clone();
        missing[6] = None;
        assert_eq!(check(&missing), missing);
    }

    #[test]
    fn names_out_of_order_around_the_mouth_are_dropped() {
        let scene = Scene::calibrated();
        let ctx = scene.ctx();
        let cands = candidates(&scene, &posed(0.0, &RigidTransform::IDENTITY)).list;
        // D3 and D4 swapped: one of them breaks the walk round the mouth and goes.
        let mut names: Vec<Option<usize>> = (0..15).map(Some).collect();
        names.swap(2, 3);
        enforce_lip_order(&ctx, &mut names, &cands);
        assert_eq!(names.iter().take(12).filter(|c| c.is_none()).count(), 1);
        assert!(names
            .iter()
            .enumerate()
            .all(|(i, c)| c.is_none_or(|c| c == i || i == 2 || i == 3)));
    }

    /// Twelve lip blobs round a mouth 50 px wide (pixels; D1 at the right of the image).
    fn lip_blobs() -> Vec<Candidate> {
        (0..12)
            .map(|i| {
                let a = std::f64::consts::PI * i as f64 / 6.0;
                Candidate {
                    pixel: [320.0 + 25.0 * a.cos(), 250.0 - 12.0 * a.sin()],
                    point: Vec3::new(0.0, 0.0, 0.6),
                    role: DotRole::Lip,
                }
            })
            .collect()
    }

    /// *A blob between neighbours*: the lower lip slipped one place (D8 on D9's blob, …, D11
    /// on D12's, D12 missing) leaves D8's blob between the corner D7 and D8; right names, or
    /// a free fragment beside a named dot, leave none.
    #[test]
    fn a_slipped_lip_leaves_a_blob_between_neighbours() {
        let cands = lip_blobs();
        let right: Vec<Option<usize>> = (0..12).map(Some).collect();
        let taken = vec![true; 12];
        assert_eq!(blob_between_neighbours(&right, &cands, &taken, 3.0), None);

        let mut slipped = right.clone();
        for (dot, name) in slipped.iter_mut().enumerate().take(11).skip(7) {
            *name = Some(dot + 1);
        }
        slipped[11] = None;
        let mut taken = vec![true; 12];
        taken[7] = false;
        assert_eq!(
            blob_between_neighbours(&slipped, &cands, &taken, 3.0),
            Some((6, 7, 7))
        );

        // A free blob three quarters of the way from D3 to D4 (3.3 px from D4): a dot of its
        // own when dots are 3 px apart, a fragment of D4's when they must be 4 px apart.
        let mut with_fragment = cands.clone();
        let (d3, d4) = (cands[2].pixel, cands[3].pixel);
        with_fragment.push(Candidate {
            pixel: [
                d3[0] + 0.75 * (d4[0] - d3[0]),
                d3[1] + 0.75 * (d4[1] - d3[1]),
            ],
            ..cands[3]
        });
        let mut taken = vec![true; 13];
        taken[12] = false;
        assert_eq!(
            blob_between_neighbours(&right, &with_fragment, &taken, 3.0),
            Some((2, 3, 12))
        );
        assert_eq!(
            blob_between_neighbours(&right, &with_fragment, &taken, 4.0),
            None
        );
    }
}
