//! Splitting merged blobs: two lip dots close together (lips pressed shut, a corner and its
//! neighbour in a pursed mouth) merge into one blob; one of them is missing, or both, or
//! the blob went to the wrong one. A missing lip dot (seen within the last
//! [`SPLIT_MISSING_FRAMES`]) whose prediction, or the place it was last seen, lies within a
//! dot's diameter plus its gate of a blob of at least [`MERGED_AREA_DOTS`] dots' area
//! splits that blob with the dot holding it (or another missing dot predicted there): the
//! blob's colour weight spreads along its long axis by the dots' own spread plus a quarter
//! of their separation squared, which gives the two centres, each with its own depth and
//! depth gate. The split is one transaction: kept only if the mouth's order and corner
//! checks hold, rolled back (halves and all) otherwise.

use mouthpiece_detect::DotRole;

use super::{Candidates, Context, NameSet, Pass, Scratch, Step};
use crate::camera;
use crate::labels::{Candidate, Small};
use crate::lip_depth::lip_depth;
use crate::naming::checks::{self, depth_window, disc_area};
use crate::prediction::{lip_predictions, LipMotion};

/// A lip dot unseen for longer than this many frames is not looked for in a merged blob: a
/// corner often comes back out of the mouth's fold merged with its neighbour after several
/// frames hidden, while a dot gone longer has no prediction worth splitting a blob for (the
/// measurement: docs/lab/detection-log.md).
pub const SPLIT_MISSING_FRAMES: u32 = 10;

/// A blob of at least this many dots' area may hold two: a corner half folded away adds
/// less than a whole dot to its neighbour's blob, and one dot's paint at a slant reaches
/// little over its own area (the values tried: docs/lab/detection-log.md).
pub const MERGED_AREA_DOTS: f64 = 1.2;

/// Halves less than this many paint radii apart are one dot, not two.
pub const MIN_HALF_SEPARATION_RADII: f64 = 0.5;

/// A merged blob, and the partner dot predicted on it, lie within a dot's diameter (this many
/// paint radii: two dots side by side have their centres that far apart) plus the smallest
/// gate of a prediction.
pub const MERGED_REACH_RADII: f64 = 2.0;

/// Below this (px²) the blob's spread has no cross term: its axes are the image's.
const ROUND_SPREAD_PX2: f64 = 1e-12;

pub(crate) struct SplitMergedBlobs;

impl Step for SplitMergedBlobs {
    fn name(&self) -> &'static str {
        "split-merged-blobs"
    }

    fn run(
        &self,
        ctx: &Context,
        _pass: &Pass,
        names: &mut NameSet,
        cands: &mut Candidates,
        scratch: &mut Scratch,
    ) -> bool {
        let n = ctx.layout.lip_dots;
        if !ctx.tracking() || ctx.neutral.is_none() {
            return false;
        }
        if (0..n).all(|i| names.get(i).is_some()) {
            return false;
        }
        let tracks = ctx.tracks;
        let head = ctx.head.now(names.as_slice(), &cands.list);
        let preds = lip_predictions(ctx, &head, LipMotion::Steady);
        let missing: Small<u32> = tracks[..n].iter().map(|t| t.missing).collect();
        let last_seen: Small<[f64; 2]> = tracks[..n].iter().map(|t| t.pixel).collect();
        // Depth windows as the assignment's: last depth to carried depth.
        let depth_window: Small<[f64; 2]> = tracks[..n]
            .iter()
            .map(|t| depth_window(t, &head, ctx.config.lip_depth_gate_m))
            .collect();
        let real = cands.len();
        names.begin();
        let mut split_any = false;
        for i in 0..n {
            if names.get(i).is_some() || missing[i] > SPLIT_MISSING_FRAMES {
                continue;
            }
            let p = preds[i];
            let min_gate = ctx.min_gate_px(tracks[i].depth);
            // From its prediction or, if that overshot (a velocity measured on merged blobs
            // is poor), from where it was last seen.
            let last = last_seen[i];
            let dist = |q: [f64; 2]| {
                ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2))
                    .sqrt()
                    .min(((q[0] - last[0]).powi(2) + (q[1] - last[1]).powi(2)).sqrt())
            };
            // The merged blob: the nearest big lip blob within reach.
            let merged = (0..real)
                .filter(|&c| cands.list[c].role != DotRole::Forehead)
                .filter_map(|c| {
                    let blob = &ctx.blobs[cands.blob[c]];
                    let r = ctx.dot_radius_px(cands.list[c].point.z);
                    let big = blob.area as f64 >= MERGED_AREA_DOTS * disc_area(r);
                    let d = dist(cands.list[c].pixel);
                    (big && d <= MERGED_REACH_RADII * r + min_gate).then_some((d, c, r))
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let Some((_, c, r)) = merged else { continue };
            // Its other dot: the lip dot named on it, else another missing one predicted
            // nearest to it.
            let holder = (0..n).find(|&j| names.get(j) == Some(c));
            let partner = holder.or_else(|| {
                (0..n)
                    .filter(|&j| {
                        j != i && names.get(j).is_none() && missing[j] <= SPLIT_MISSING_FRAMES
                    })
                    .map(|j| {
                        let q = preds[j];
                        let e = cands.list[c].pixel;
                        (((q[0] - e[0]).powi(2) + (q[1] - e[1]).powi(2)).sqrt(), j)
                    })
                    .filter(|&(d, _)| d <= MERGED_REACH_RADII * r + min_gate)
                    .min_by(|a, b| a.0.total_cmp(&b.0))
                    .map(|(_, j)| j)
            });
            let Some(j) = partner else { continue };
            let d = [preds[i][0] - preds[j][0], preds[i][1] - preds[j][1]];
            let [xx, xy, yy] = ctx.blobs[cands.blob[c]].spread;
            // The blob's long axis, pointing from dot j's side to dot i's: the two dots lie
            // along it (their predictions give only the side; a mouth narrowing fast turns
            // the line between a corner and its neighbour within a frame). Two equal dots
            // 2h apart spread h² more along that line than across it.
            let mean = 0.5 * (xx + yy);
            let root = (0.25 * (xx - yy).powi(2) + xy * xy).sqrt();
            let (long, short) = (mean + root, mean - root);
            let axis = if xy.abs() > ROUND_SPREAD_PX2 {
                [xy, long - xx]
            } else if xx >= yy {
                [1.0, 0.0]
            } else {
                [0.0, 1.0]
            };
            let norm = axis[0].hypot(axis[1]);
            if !(norm.is_finite() && norm > 0.0) {
                continue;
            }
            let sign = if axis[0] * d[0] + axis[1] * d[1] >= 0.0 {
                1.0
            } else {
                -1.0
            };
            let u = [sign * axis[0] / norm, sign * axis[1] / norm];
            let half = (long - short).max(0.0).sqrt();
            if half < MIN_HALF_SEPARATION_RADII * r {
                continue;
            }
            let centre = cands.list[c].pixel;
            let at = |sign: f64| {
                [
                    centre[0] + sign * half * u[0],
                    centre[1] + sign * half * u[1],
                ]
            };
            let z_hint = cands.list[c].point.z;
            let mut half_at = |dot: usize, px: [f64; 2]| {
                lip_depth(
                    &ctx.sensor,
                    ctx.config.lip_depth_patch_m,
                    px,
                    z_hint,
                    &mut scratch.depth,
                )
                .filter(|(z, _)| (depth_window[dot][0]..=depth_window[dot][1]).contains(z))
                .map(|(z, _)| (dot, px, z))
            };
            let Some(a) = half_at(i, at(1.0)) else {
                continue;
            };
            let Some(b) = half_at(j, at(-1.0)) else {
                continue;
            };
            let (role, blob) = (cands.list[c].role, cands.blob[c]);
            for (dot, px, z) in [a, b] {
                let made = cands.push_made(
                    Candidate {
                        pixel: px,
                        point: camera::deproject(ctx.sensor.k, px, z),
                        role,
                    },
                    blob,
                );
                names.set(dot, Some(made));
            }
            split_any = true;
        }
        if !split_any {
            names.commit();
            return false;
        }
        names.apply(
            |names| checks::order_and_neighbours(ctx, names, &cands.list),
            cands.len(),
        );
        let kept = checks::corners_are_extremes(ctx, names.as_slice(), &cands.list);
        if kept {
            names.commit();
        } else {
            names.rollback(cands.len());
        }
        // Halves no name kept (the split rolled back, or a half out of order) are not blobs.
        names.drop_unnamed_extras(cands);
        tracing::debug!(dots = cands.len() - real, kept, "merged lip blobs split");
        true
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;

    /// The middles of the lips, D4 and D10, pressed together 6 px apart: their paint makes
    /// one blob of two dots' area, spread along the line between them. The first pass gives
    /// it to D4 and leaves D10 missing; the split names each on its half.
    #[test]
    fn a_blob_of_two_merged_lip_dots_is_split_between_them() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let centre = [
            0.5 * (rest[3][0] + rest[9][0]),
            0.5 * (rest[3][1] + rest[9][1]),
        ];
        let (upper, lower) = ([centre[0], centre[1] - 3.0], [centre[0], centre[1] + 3.0]);
        let z = 0.596;
        for (dot, px) in [(3, upper), (9, lower)] {
            let t = &mut scene.tracks[dot];
            t.pixel = px;
            t.stab = crate::camera::deproject(&scene.k, px, z);
            t.depth = z;
        }
        let mut truth = rest.clone();
        truth[3] = upper;
        truth[9] = lower;
        let mut cands = Candidates::default();
        scene.blobs.clear();
        let face = neutral_face();
        let mut merged = 0;
        for (i, px) in rest.iter().enumerate() {
            let role = if i < 12 {
                DotRole::Lip
            } else {
                DotRole::Forehead
            };
            match i {
                3 => merged = scene.push(&mut cands, centre, z, role, 2.0),
                9 => {}
                _ => {
                    scene.push(&mut cands, *px, face[i].z, role, 1.0);
                }
            }
        }
        let r2 = (crate::naming::checks::disc_area(scene.ctx().dot_radius_px(z))
            / std::f64::consts::PI)
            / 4.0;
        scene.blobs[merged].spread = [r2, 0.0, r2 + 9.0];
        let mut preds: Vec<[f64; 2]> = truth.clone();
        preds[3] = [centre[0], centre[1] - 1.0];
        preds[9] = [centre[0], centre[1] + 5.0];
        let pass = scene.pass(&preds, &cands);
        let real = cands.len();
        let (first, names) = scene.run_after_first_pass(&SplitMergedBlobs, &pass, &mut cands);
        assert_eq!(
            (first.get(3), first.get(9)),
            (Some(merged), None),
            "{:?}",
            named(&first)
        );
        for (dot, want) in [(3, upper), (9, lower)] {
            let c = names.get(dot).expect("named on a half");
            let got = cands.list[c].pixel;
            assert!(
                (got[0] - want[0]).hypot(got[1] - want[1]) < 0.5,
                "D{} at {got:?}, want {want:?}",
                dot + 1
            );
        }
        assert_eq!(cands.len(), real + 2);
    }
}
