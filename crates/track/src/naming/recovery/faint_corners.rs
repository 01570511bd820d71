//! Faint corners: a mouth corner the names left missing may show only a speck of paint (the
//! corner of the mouth folds in over it). A faint blob (smaller than a dot, see
//! [`mouthpiece_detect::Detections::faint`]) within `min_gate_spacings` of where the corner is
//! predicted (moving on or stopped), at the corner's depth (`lip_depth_gate_m`), names it,
//! if the corner checks still hold with it (one transaction: otherwise nothing of it
//! stays). Only corners seen within the last [`FAINT_CORNER_MISSING_FRAMES`]: elsewhere on
//! the lips a speck is as likely a motion-blur ghost, and taking ghosts slipped whole lips.

use mouthpiece_detect::DotRole;

use super::{Candidates, Context, NameSet, Pass, Scratch, Step};
use crate::camera;
use crate::labels::{Candidate, Small};
use crate::lip_depth::lip_depth;
use crate::naming::checks::{self, depth_window};

/// A corner unseen for longer than this many frames is not looked for on a speck.
pub const FAINT_CORNER_MISSING_FRAMES: u32 = 2;

/// The blob index of a candidate made from a faint speck (it is no blob of the detector's).
pub const NO_BLOB: usize = usize::MAX;

pub(crate) struct FaintCorners;

impl Step for FaintCorners {
    fn name(&self) -> &'static str {
        "faint-corners"
    }

    fn run(
        &self,
        ctx: &Context,
        _pass: &Pass,
        names: &mut NameSet,
        cands: &mut Candidates,
        scratch: &mut Scratch,
    ) -> bool {
        let faint = ctx.faint;
        if faint.is_empty() || !ctx.tracking() || ctx.neutral.is_none() {
            return false;
        }
        let k = ctx.sensor.k;
        let head = ctx.head.now(names.as_slice(), &cands.list);
        let before = cands.len();
        names.begin();
        for corner in [ctx.layout.left_corner(), ctx.layout.right_corner()] {
            let track = &ctx.tracks[corner];
            if names.get(corner).is_some() || track.missing > FAINT_CORNER_MISSING_FRAMES {
                continue;
            }
            let (stab, moving, window) = (
                track.stab,
                track.stab + track.stab_vel * ctx.step_ratio,
                depth_window(track, &head, ctx.config.lip_depth_gate_m),
            );
            let preds: Small<[f64; 2]> = [stab, moving]
                .iter()
                .filter_map(|q| camera::project(k, &head.apply(q)))
                .collect();
            let gate = ctx.min_gate_px(track.depth);
            let nearest = faint
                .iter()
                .filter(|b| matches!(ctx.roles[b.class], DotRole::Lip | DotRole::Any))
                .filter_map(|b| {
                    let d = preds
                        .iter()
                        .map(|p| {
                            ((b.center[0] - p[0]).powi(2) + (b.center[1] - p[1]).powi(2)).sqrt()
                        })
                        .fold(f64::INFINITY, f64::min);
                    (d < gate).then_some((d, b))
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let Some((_, blob)) = nearest else { continue };
            let z_hint = blob.depth_m.unwrap_or(0.5 * (window[0] + window[1]));
            let Some((z, _)) = lip_depth(
                &ctx.sensor,
                ctx.config.lip_depth_patch_m,
                blob.center,
                z_hint,
                &mut scratch.depth,
            ) else {
                continue;
            };
            if !(window[0]..=window[1]).contains(&z) {
                continue;
            }
            let made = cands.push_made(
                Candidate {
                    pixel: blob.center,
                    point: camera::deproject(k, blob.center, z),
                    role: DotRole::Lip,
                },
                NO_BLOB,
            );
            names.set(corner, Some(made));
        }
        if cands.len() == before {
            names.commit();
            return false;
        }
        names.apply(
            |names| checks::keep_corner_neighbours_in_place(ctx, names, &cands.list),
            cands.len(),
        );
        let kept = checks::corners_are_extremes(ctx, names.as_slice(), &cands.list);
        if kept {
            names.commit();
        } else {
            names.rollback(cands.len());
        }
        // Specks no name kept are not blobs the frame left unassigned.
        names.drop_unnamed_extras(cands);
        tracing::debug!(
            named = cands.len() - before,
            kept,
            "mouth corners named on faint paint"
        );
        kept
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;

    /// The left corner D1 folded in over its paint: no blob, only a faint speck where it is
    /// predicted. The step names it there; a speck 5 px off is not the corner.
    #[test]
    fn a_mouth_corner_is_named_on_a_speck_of_paint() {
        for (offset, named_on_it) in [(0.0, true), (5.0, false)] {
            let mut scene = Scene::calibrated();
            let rest = scene.rest_pixels();
            let mut speck = scene.blob([rest[0][0] + offset, rest[0][1]], 0.6, 0);
            speck.area = 2;
            scene.faint.push(speck);
            let mut cands = Candidates::default();
            scene.blobs.clear();
            let face = neutral_face();
            for (i, px) in rest.iter().enumerate().skip(1) {
                let role = if i < 12 {
                    DotRole::Lip
                } else {
                    DotRole::Forehead
                };
                scene.push(&mut cands, *px, face[i].z, role, 1.0);
            }
            let pass = scene.pass(&rest, &cands);
            let real = cands.len();
            let (first, names) = scene.run_after_first_pass(&FaintCorners, &pass, &mut cands);
            assert_eq!(first.get(0), None);
            assert_eq!(names.get(0).is_some(), named_on_it, "speck {offset} px off");
            if named_on_it {
                assert_eq!(cands.list[names.get(0).unwrap()].pixel, rest[0]);
            }
            assert_eq!(cands.len(), real + usize::from(named_on_it));
        }
    }
}
