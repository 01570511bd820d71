//! The score that chooses among naming hypotheses: one number per set of lip names, a sum of
//! log-likelihoods (natural logarithms, "nats") with named terms ([`Score`]). The hypothesis
//! steps ([`super::recovery::Stage::Hypotheses`]) only propose names; the names with the
//! highest score are kept, the steady hypothesis's on a tie.
//!
//! Per lip dot, named on a candidate:
//! - **paint** ([`paint_term`]): is the blob the size of one dot's paint at the candidate's
//!   depth? A Gaussian in the log of blob area over paint area ([`AREA_LOG_SIGMA`]), so a
//!   motion-blur ghost (a share of the paint) and a merged blob (two dots' paint) cost alike.
//!   The detector keeps only blobs of a dot's colour, so the colour is in the candidates.
//! - **depth** ([`depth_term`]): how far the candidate's depth lies outside the dot's depth
//!   window (its last depth and its last place carried by the head's motion), in units of the
//!   sensor's depth noise at that depth ([`depth_noise_m`]) widened for the lip's own motion
//!   ([`DEPTH_SIGMA_NOISES`]).
//! - **shape** ([`shape_term`]): the learned mouth shape (the neutral pose): each pair of lip
//!   dots named next to each other keeps its distance at rest, up to how far speech stretches
//!   or squeezes a lip ([`SHAPE_LOG_SIGMA`], in the log of the ratio; rigid motion leaves it
//!   alone). Only with a neutral pose.
//! - **motion** ([`motion_term`]): the distance from the dot's constant-velocity
//!   (steady) prediction in units of the dot spacing ([`MOTION_SIGMA_SPACINGS`]). Every
//!   hypothesis is scored against the steady prediction: the other motions are ways of finding
//!   candidates, not more likely motions.
//!
//! Per lip dot missing, **miss** ([`MISS`]): a fixed log-likelihood, the price of a dot the
//! names leave out. It is what makes more names win, when the names cost no more than it.
//!
//! A proposal from another lip motion than the steady one also carries that motion's prior
//! ([`OTHER_MOTION_PRIOR`]) against the steady names.
//!
//! Each per-dot term is bounded below ([`OUTLIER_FLOOR`]): a candidate that fits a dot badly
//! on one count is an outlier of that count, not an impossibility (a robust likelihood).

use mouthpiece_retarget::RigidTransform;

use super::checks::depth_window;
use super::{Candidates, Context, NameSet};

/// Log-likelihood of a lip dot left missing, nats. A name costs at most about as much on each
/// term, so a set with a dot more wins unless its names fit worse on two counts or more:
/// two lower-lip dots on small ghosts ([`AREA_LOG_SIGMA`]: under half the paint costs 3.8
/// each) lose to one dot missing and the rest on their paint.
pub const MISS: f64 = -8.0;

/// Spread of the log of a blob's area over one dot's paint at its depth. 0.25: a blob of 70 %
/// or 140 % of the paint (a dot at a slant, rim pixels counted) costs about 1 nat; half or
/// twice the paint (a faint ghost, two dots merged) 3.8.
pub const AREA_LOG_SIGMA: f64 = 0.25;

/// The sensor's depth noise (one standard deviation) at 1 m, metres; it grows with the square
/// of the depth (structured light and stereo alike: depth from disparity). 1.5 mm at 0.6 m,
/// the Kinect-like noise of the synthetic sensor.
pub const DEPTH_NOISE_AT_1M: f64 = 0.0015 / (0.6 * 0.6);

/// The depth term's spread in units of the sensor's noise: the noise of the last depth and
/// of this one, and the lip's own motion in depth within a frame (a lip protruding moves a
/// few millimetres). A ghost over the mouth's rim misses by several millimetres.
pub const DEPTH_SIGMA_NOISES: f64 = 2.0;

/// Spread of the log of a named pair's distance over its distance at rest: speech stretches
/// a lip by half (ln 1.5).
pub const SHAPE_LOG_SIGMA: f64 = 0.405;

/// Spread of a dot's distance from its steady prediction, in dot spacings: a jaw jumping
/// within a frame moves the lower lip about one spacing past it.
pub const MOTION_SIGMA_SPACINGS: f64 = 1.0;

/// The prior log-odds of a lip motion other than steady (stopped dead, the width or the jaw
/// jumping within a frame) against the steady one, nats: those are rarer than constant
/// velocity, so their names must fit better by this much to replace the steady ones (less
/// than a dot's worth: a dot more still wins).
pub const OTHER_MOTION_PRIOR: f64 = -2.0;

/// The least any one term gives one dot, nats: a fit that bad is an outlier of that count.
pub const OUTLIER_FLOOR: f64 = -6.0;

/// A set of lip names' score: each term summed over the lip dots, nats (0 is a perfect fit,
/// every term is at most 0).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Score {
    pub paint: f64,
    pub depth: f64,
    pub shape: f64,
    pub motion: f64,
    pub miss: f64,
}

impl Score {
    /// The log-likelihood: the sum of the terms.
    pub fn total(&self) -> f64 {
        self.paint + self.depth + self.shape + self.motion + self.miss
    }
}

/// A Gaussian's log-likelihood of `u` standard deviations (without its constant), bounded
/// below by [`OUTLIER_FLOOR`].
fn gaussian(u: f64) -> f64 {
    (-0.5 * u * u).max(OUTLIER_FLOOR)
}

/// The paint term of a dot named on a blob of `blob_area` pixels where one dot's paint
/// covers `paint_area`.
pub fn paint_term(blob_area: f64, paint_area: f64) -> f64 {
    if blob_area <= 0.0 || paint_area <= 0.0 {
        return OUTLIER_FLOOR;
    }
    gaussian((blob_area / paint_area).ln() / AREA_LOG_SIGMA)
}

/// The sensor's depth noise at depth `z`, metres.
pub fn depth_noise_m(z: f64) -> f64 {
    DEPTH_NOISE_AT_1M * z * z
}

/// The depth term of a candidate at depth `z` for a dot whose depth window (no gate) is
/// `window` (metres).
pub fn depth_term(z: f64, window: [f64; 2]) -> f64 {
    let miss = (window[0] - z).max(z - window[1]).max(0.0);
    gaussian(miss / (DEPTH_SIGMA_NOISES * depth_noise_m(z)))
}

/// The shape term of two neighbouring lip dots `now` metres apart, `rest` apart at rest.
pub fn shape_term(now: f64, rest: f64) -> f64 {
    if now <= 0.0 || rest <= 0.0 {
        return OUTLIER_FLOOR;
    }
    gaussian((now / rest).ln() / SHAPE_LOG_SIGMA)
}

/// The motion term of a dot named `distance_px` from its steady prediction where the dots
/// lie `spacing_px` apart.
pub fn motion_term(distance_px: f64, spacing_px: f64) -> f64 {
    gaussian(distance_px / (MOTION_SIGMA_SPACINGS * spacing_px.max(f64::MIN_POSITIVE)))
}

/// The neutral mouth's mean distance between neighbouring lip dots, metres; `None` before the
/// neutral pose is taken.
pub(crate) fn neutral_spacing_m(ctx: &Context) -> Option<f64> {
    crate::prediction::mean_neighbour_distance(&ctx.neutral?.lip)
}

/// The dot spacing in pixels at depth `z`: the neutral mouth's spacing projected there, or,
/// before the neutral pose, the mean distance between neighbouring `preds`.
pub(crate) fn spacing_px(ctx: &Context, preds: &[[f64; 2]], z: f64) -> f64 {
    match neutral_spacing_m(ctx) {
        Some(s) if z > 0.0 => s * ctx.sensor.k.fx / z,
        _ => {
            let n = preds.len();
            let d = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
            (0..n).map(|i| d(preds[i], preds[(i + 1) % n])).sum::<f64>() / n.max(1) as f64
        }
    }
}

/// The score of `names`' lip dots, the motion against the steady predictions `steady` under
/// this frame's head motion `head`.
pub(crate) fn score(
    ctx: &Context,
    steady: &[[f64; 2]],
    head: &RigidTransform,
    names: &NameSet,
    cands: &Candidates,
) -> Score {
    let n = ctx.layout.lip_dots;
    let list = &cands.list;
    let mut s = Score::default();
    for i in 0..n {
        let Some(c) = names.get(i) else {
            s.miss += MISS;
            continue;
        };
        let cand = &list[c];
        let z = cand.point.z;
        if let Some(blob) = cands.blob.get(c).and_then(|&b| ctx.blobs.get(b)) {
            let r = ctx.dot_radius_px(z);
            s.paint += paint_term(blob.area as f64, std::f64::consts::PI * r * r);
        }
        if let Some(track) = ctx.tracks.get(i) {
            s.depth += depth_term(z, depth_window(track, head, 0.0));
        }
        let p = steady[i];
        let d = (cand.pixel[0] - p[0]).hypot(cand.pixel[1] - p[1]);
        let z_track = ctx.tracks.get(i).map_or(z, |t| t.depth);
        s.motion += motion_term(d, spacing_px(ctx, steady, z_track));
    }
    if let Some(neutral) = ctx.neutral {
        for i in 0..n {
            let j = (i + 1) % n;
            if let (Some(a), Some(b)) = (names.get(i), names.get(j)) {
                let now = (list[a].point - list[b].point).norm();
                s.shape += shape_term(now, (neutral.lip[i] - neutral.lip[j]).norm());
            }
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::naming::recovery::test_support::*;

    /// A blob of one dot's paint costs nothing; half or twice it cost alike (the log); a
    /// sliver is an outlier, no worse than the floor.
    #[test]
    fn the_paint_term_is_the_log_of_the_blobs_area_over_the_paint() {
        assert_eq!(paint_term(20.0, 20.0), 0.0);
        let half = paint_term(10.0, 20.0);
        assert!((half - paint_term(40.0, 20.0)).abs() < 1e-12);
        assert!((half + 3.84).abs() < 0.01, "{half}");
        assert!(paint_term(14.0, 20.0) > -1.1 && paint_term(14.0, 20.0) < -1.0);
        assert_eq!(paint_term(0.5, 20.0), OUTLIER_FLOOR);
        assert_eq!(paint_term(0.0, 20.0), OUTLIER_FLOOR);
    }

    /// Inside the window nothing; outside, the miss in units of twice the sensor's noise at
    /// that depth, which grows with the square of the depth: 3 mm at 0.6 m is one unit, at
    /// 1.2 m a quarter.
    #[test]
    fn the_depth_term_is_the_miss_in_units_of_the_sensors_noise() {
        assert!((depth_noise_m(0.6) - 0.0015).abs() < 1e-12);
        assert_eq!(depth_term(0.601, [0.600, 0.602]), 0.0);
        assert!((depth_term(0.605, [0.600, 0.602]) + 0.5).abs() < 0.03);
        assert!((depth_term(0.597, [0.600, 0.602]) + 0.5).abs() < 0.03);
        let far = depth_term(1.203, [1.188, 1.2]);
        assert!((far + 0.5 * 0.25 * 0.25).abs() < 0.01, "{far}");
        assert_eq!(depth_term(0.63, [0.600, 0.602]), OUTLIER_FLOOR);
    }

    /// Neighbours at their distance at rest cost nothing; stretched by half, half a nat;
    /// on one blob (no distance), the floor.
    #[test]
    fn the_shape_term_is_the_log_of_a_pairs_distance_over_its_rest() {
        assert_eq!(shape_term(0.01, 0.01), 0.0);
        assert!((shape_term(0.015, 0.01) + 0.5).abs() < 0.01);
        assert!((shape_term(0.01 / 1.5, 0.01) + 0.5).abs() < 0.01);
        assert_eq!(shape_term(0.0, 0.01), OUTLIER_FLOOR);
    }

    /// On the prediction nothing; one dot spacing off, half a nat, whatever the spacing in
    /// pixels (a face near or far, a camera of any resolution).
    #[test]
    fn the_motion_term_is_the_distance_in_dot_spacings() {
        assert_eq!(motion_term(0.0, 7.0), 0.0);
        assert!((motion_term(7.0, 7.0) + 0.5).abs() < 1e-12);
        assert_eq!(motion_term(14.0, 14.0), motion_term(7.0, 7.0));
        assert_eq!(motion_term(1000.0, 7.0), OUTLIER_FLOOR);
    }

    /// The scene's face at rest, every dot on its paint at its prediction: the score is 0.
    /// One lip dot missing costs [`MISS`] and its pair's shape terms, nothing else; the
    /// spacing is the neutral mouth's, projected.
    #[test]
    fn a_missing_dot_costs_the_miss_and_full_names_on_paint_cost_nothing() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let cands = scene.candidates_at(&rest);
        let ctx = scene.ctx();
        let head = RigidTransform::IDENTITY;
        let all = NameSet::of((0..15).map(Some), cands.len());
        let full = score(&ctx, &rest[..12], &head, &all, &cands);
        assert!(full.total().abs() < 0.1, "{full:?}");
        let mut one_fewer = all.clone();
        one_fewer.set(9, None);
        let fewer = score(&ctx, &rest[..12], &head, &one_fewer, &cands);
        assert_eq!(fewer.miss, MISS);
        assert!((fewer.paint - full.paint).abs() < 0.05);
        assert!(fewer.total() < full.total() + MISS + 0.1);
        let spacing = spacing_px(&ctx, &rest[..12], 0.6);
        assert!((6.0..11.0).contains(&spacing), "{spacing}");
        assert!((spacing_px(&ctx, &rest[..12], 1.2) - spacing / 2.0).abs() < 1e-9);
    }
}
