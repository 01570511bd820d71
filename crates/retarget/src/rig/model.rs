//! The rig's measures: the jaw and the lips' rigid motions from the lip dots, and the
//! named curves' measures and their scaling into 0..1.

use super::*;

/// Dot roles in the layout (indices into the lip dots).
#[derive(Debug, Clone)]
pub(super) struct Roles {
    pub(super) left: usize,
    pub(super) right: usize,
    pub(super) upper: Vec<usize>,
    pub(super) lower: Vec<usize>,
}

impl Roles {
    /// Which unseen dots the fill moves (docs/rig.md, *a lip with no dot seen stays held*):
    /// the corners, and a lip's dots when one of that lip's dots or a corner is seen. A lip
    /// with nothing seen is mostly a lip rolled into the mouth, a shape the complete frames
    /// the fill learns from seldom show; its held dots are nearer.
    pub(super) fn fill_wanted(&self, seen: &[bool], out: &mut Vec<bool>) {
        let corner_seen = seen[self.left] || seen[self.right];
        let upper = corner_seen || self.upper.iter().any(|&i| seen[i]);
        let lower = corner_seen || self.lower.iter().any(|&i| seen[i]);
        out.clear();
        out.extend((0..seen.len()).map(|i| {
            if self.upper.contains(&i) {
                upper
            } else if self.lower.contains(&i) {
                lower
            } else {
                true
            }
        }));
    }

    fn new(n: usize) -> Self {
        let right = n / 2;
        Self {
            left: 0,
            right,
            upper: (1..right).collect(),
            lower: (right + 1..n).collect(),
        }
    }
}

/// The rig geometry fixed at calibration, and the measures of any stabilised step.
///
/// Use [`Rig`] for the streaming estimator; [`RigModel::measure`] alone gives the measures of
/// any set of mouth-frame dots (the evaluation applies it to ground truth).
#[derive(Debug, Clone)]
pub struct RigModel {
    pub(super) roles: Roles,
    /// Neutral lip dots, mouth frame.
    pub(super) neutral: Vec<Vec3>,
    pub(super) width: f64,
    /// Hinge pivot (y, z) in the mouth frame; the axis is x.
    pub(super) pivot: [f64; 2],
    /// Per upper / lower non-corner dot: weight of the performer's left side (right = 1 − it).
    pub(super) upper_left: Vec<f64>,
    pub(super) lower_left: Vec<f64>,
    /// Σ x0² over all dots (the horizontal scale fit's denominator).
    pub(super) sxx: f64,
    /// Per dot: its weight in the mouth centre's sideways shift ([`midline_weights`]).
    pub(super) mid_weight: Vec<f64>,
    /// The neutral mouth frame in the camera frame: where the camera is seen from the mouth.
    pub(super) frame: MouthFrame,
}

pub(super) fn mean_over(idx: &[usize], f: impl Fn(usize) -> f64) -> f64 {
    idx.iter().map(|&i| f(i)).sum::<f64>() / idx.len().max(1) as f64
}

pub(super) fn weighted(idx: &[usize], w: &[f64], f: impl Fn(usize) -> f64) -> f64 {
    let (mut s, mut ws) = (0.0, 0.0);
    for (k, &i) in idx.iter().enumerate() {
        s += w[k] * f(i);
        ws += w[k];
    }
    if ws > 0.0 {
        s / ws
    } else {
        0.0
    }
}

impl RigModel {
    /// The model for a neutral pose (at least 6 lip dots: two corners and two per lip).
    pub fn new(neutral: &NeutralPose, settings: &RigSettings) -> Result<Self, Error> {
        settings.validate("rig")?;
        let n = neutral.lip.len();
        if n < 6 {
            return Err(Error::InvalidSetting {
                key: "track.lip_dots".into(),
                reason: format!("the rig needs at least 6 lip dots, the layout has {n}"),
            });
        }
        let roles = Roles::new(n);
        let width = neutral.mouth_width();
        let side = |i: usize| (0.5 + neutral.lip[i].x / (0.5 * width)).clamp(0.0, 1.0);
        let upper_left = roles.upper.iter().map(|&i| side(i)).collect();
        let lower_left = roles.lower.iter().map(|&i| side(i)).collect();
        let sxx = neutral.lip.iter().map(|p| p.x * p.x).sum::<f64>();
        Ok(Self {
            mid_weight: midline_weights(&neutral.lip, width),
            frame: neutral.frame,
            pivot: [settings.hinge_up * width, -settings.hinge_back * width],
            neutral: neutral.lip.clone(),
            roles,
            width,
            upper_left,
            lower_left,
            sxx,
        })
    }

    /// The neutral lip dots (mouth frame).
    pub fn neutral(&self) -> &[Vec3] {
        &self.neutral
    }

    /// The camera's centre in the neutral mouth frame for a head pose (the rigid motion carrying
    /// the neutral head onto the current one in the camera frame): each dot's depth error lies
    /// along the line from it to this point.
    pub fn camera_in_mouth(&self, head: &crate::RigidTransform) -> Vec3 {
        self.frame
            .to_mouth(&head.rotation.tr_mul(&(-head.translation)))
    }

    /// Neutral mouth width, metres.
    pub fn width(&self) -> f64 {
        self.width
    }

    /// The hinge pivot in the mouth frame (the hinge axis is the frame's x axis).
    pub fn pivot(&self) -> Vec3 {
        Vec3::new(0.0, self.pivot[0], self.pivot[1])
    }

    /// The jaw's rigid motion (mouth frame) for an angle (radians) and slide (metres).
    pub fn jaw_transform(&self, angle: f64, slide: f64) -> crate::RigidTransform {
        let r = Rotation3::from_axis_angle(&Vec3::x_axis(), angle).into_inner();
        let h = self.pivot();
        crate::RigidTransform {
            rotation: r,
            translation: h - r * h + Vec3::new(slide, 0.0, 0.0),
        }
    }

    /// The measures of one step's lip dots (mouth frame, in layout order).
    pub fn measure(&self, lip: &[Vec3]) -> Measures {
        let r = &self.roles;
        let n0 = &self.neutral;
        let w = self.width;
        let d = |i: usize| lip[i] - n0[i];
        // Lip centroids and their motion.
        let du = Vec3::new(
            mean_over(&r.upper, |i| d(i).x),
            mean_over(&r.upper, |i| d(i).y),
            mean_over(&r.upper, |i| d(i).z),
        );
        let c0 = Vec3::new(
            mean_over(&r.lower, |i| n0[i].x),
            mean_over(&r.lower, |i| n0[i].y),
            mean_over(&r.lower, |i| n0[i].z),
        );
        let dl = Vec3::new(
            mean_over(&r.lower, |i| d(i).x),
            mean_over(&r.lower, |i| d(i).y),
            mean_over(&r.lower, |i| d(i).z),
        );
        // Jaw: the angle the lower-lip centroid turned about the pivot, with the forward motion
        // both lips share taken off.
        let (hy, hz) = (self.pivot[0], self.pivot[1]);
        let (r0y, r0z) = (c0.y - hy, c0.z - hz);
        let (py, pz) = (r0y + dl.y, r0z + dl.z - du.z);
        let angle = (r0y * pz - r0z * py).atan2(r0y * py + r0z * pz);
        let slide = dl.x - du.x;
        // The lower lip with the jaw's motion taken off.
        let (s, c) = angle.sin_cos();
        let unjaw = |i: usize| -> Vec3 {
            let p = lip[i];
            let (y, z) = (p.y - hy, p.z - hz);
            // Rotate back by −angle about x through the pivot, and undo the slide.
            Vec3::new(p.x - slide, hy + y * c + z * s, hz - y * s + z * c) - n0[i]
        };
        let free_y = |i: usize| unjaw(i).y;
        let free_z = |i: usize| unjaw(i).z;
        // The drop the jaw gives the lower-lip centroid.
        let jaw_drop = -((r0y * c - r0z * s + hy) - c0.y);
        let mut v = [0.0; CURVES];
        v[0] = angle.to_degrees();
        // The growth of the gap between the lip centroids: the lips parting.
        let gap = du.y - dl.y;
        // mouthClose: the part of the jaw's opening the lips do not show as parting (lips
        // sealed while the jaw is open), in degrees of the jaw like jawOpen.
        v[1] = close_measure(angle.to_degrees(), jaw_drop, gap);
        // Horizontal scale of the whole mouth (least squares over every dot, the lower lip
        // without the slide), and of each side about the mouth's own centre.
        let x_of = |i: usize| lip[i].x - if r.lower.contains(&i) { slide } else { 0.0 };
        let centre_shift = centre_shift(&self.mid_weight, |i| x_of(i) - n0[i].x);
        let (mut sx_all, mut sxl, mut sxr, mut xxl, mut xxr) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (i, q) in n0.iter().enumerate() {
            let x = x_of(i);
            sx_all += x * q.x;
            let xc = x - centre_shift;
            if q.x >= 0.0 {
                sxl += xc * q.x;
                xxl += q.x * q.x;
            } else {
                sxr += xc * q.x;
                xxr += q.x * q.x;
            }
        }
        let sx = sx_all / self.sxx;
        // The rounding, lips pushed out and drawn in (the upper lip's push: the lower lip's
        // depends on the jaw's estimate), split by the lips' opening: mouthFunnel rounded and
        // open, mouthPucker rounded and closed.
        let rounding = funnel_measure(du.z / w, sx);
        let open = open_fraction(gap / w);
        v[2] = rounding * open;
        v[3] = rounding * (1.0 - open);
        // mouthLeft / Right: the whole mouth shifted sideways (mean over every dot).
        let shift = lip.iter().zip(n0).map(|(p, q)| p.x - q.x).sum::<f64>() / lip.len() as f64 / w;
        v[4] = shift;
        v[5] = -shift;
        // Corners with their two neighbours (the lower neighbour without the jaw).
        let (ul, ll) = (r.upper[0], *r.lower.last().expect("lower lip"));
        let (ur, lr) = (*r.upper.last().expect("upper lip"), r.lower[0]);
        let corner_up = |c: usize, up: usize, low: usize| -> f64 {
            // A corner moves with half the jaw (it joins both lips).
            let cy = 0.5 * (d(c).y + unjaw(c).y);
            (cy + d(up).y + free_y(low)) / 3.0
        };
        let ly = corner_up(r.left, ul, ll);
        let ry = corner_up(r.right, ur, lr);
        v[6] = ly / w;
        v[7] = ry / w;
        // Stretch: each side's horizontal scale about the mouth's centre, as the corner's
        // outward motion (a whole-mouth shift is mouthLeft/Right, not one side stretching).
        v[8] = 0.5 * (sxl / xxl.max(f64::MIN_POSITIVE) - 1.0);
        v[9] = 0.5 * (sxr / xxr.max(f64::MIN_POSITIVE) - 1.0);
        // Rolls: the upper lip's edge down and back; the lower lip's (without the jaw) up and
        // back.
        // (Depth is the noisiest axis: the backward part counts at depth weight.)
        v[10] = mean_over(&r.upper, |i| -d(i).y - DEPTH_WEIGHT * d(i).z) / w;
        v[11] = mean_over(&r.lower, |i| free_y(i) - DEPTH_WEIGHT * free_z(i)) / w;
        // Upper lip up / lower lip down, per side.
        let up_l = weighted(&r.upper, &self.upper_left, |i| d(i).y);
        let up_r = weighted_right(&r.upper, &self.upper_left, |i| d(i).y);
        let lo_l = weighted(&r.lower, &self.lower_left, free_y);
        let lo_r = weighted_right(&r.lower, &self.lower_left, free_y);
        v[12] = up_l / w;
        v[13] = up_r / w;
        v[14] = -lo_l / w;
        v[15] = -lo_r / w;
        // Press: the lips squeezed together on a side (upper down, lower up, without the jaw).
        v[16] = (lo_l - up_l) / w;
        v[17] = (lo_r - up_r) / w;
        // jawForward: the lower-lip centroid's distance from the hinge grows (the jaw thrust
        // forward; the upper lip's forward motion taken off, as for the angle).
        v[18] = ((py * py + pz * pz).sqrt() - (r0y * r0y + r0z * r0z).sqrt()) / w;
        // jawLeft / Right: the slide along the hinge.
        v[19] = slide / w;
        v[20] = -slide / w;
        // mouthFrownLeft / Right: the corners down (the smile's measure, the other way).
        v[21] = -ly / w;
        v[22] = -ry / w;
        // Shrugs: each lip up and out. The upper lip's own motion (the roll's the other way);
        // the lower lip's as it is, against the upper lip's push: without the jaw it would
        // be nothing, since the jaw's estimate takes the lower lip's mean motion as a turn
        // (a closing) or a thrust of the jaw.
        v[23] = mean_over(&r.upper, |i| d(i).y + DEPTH_WEIGHT * d(i).z) / w;
        v[24] = (dl.y + DEPTH_WEIGHT * (dl.z - du.z)) / w;
        // Dimples: each corner drawn back into the cheek, with its two neighbours (the lower
        // one without the jaw; the corner with half the jaw), against the upper lip's mean
        // depth: the error the head pose leaves is common to every dot, and was most of
        // the corners' depth error.
        let corner_back = |c: usize, up: usize, low: usize| -> f64 {
            let cz = 0.5 * (d(c).z + unjaw(c).z);
            du.z - (cz + d(up).z + free_z(low)) / 3.0
        };
        v[25] = corner_back(r.left, ul, ll) / w;
        v[26] = corner_back(r.right, ur, lr) / w;
        Measures {
            values: v,
            jaw_angle: angle,
            jaw_slide: slide,
        }
    }
}

/// The `mouthFunnel` measure (mouth widths) from the upper lip's mean forward motion
/// (`forward`, mouth widths) and the horizontal scale `scale` of all dots about the centre:
/// lips pushed out and drawn into a rounded opening. Two named rules:
///
/// - *One weight per axis*: each corner's inward motion, `(1 − scale) · w/2`, counts in full
///   and the forward motion at [`DEPTH_WEIGHT`], as in the rolls: a millimetre is a
///   millimetre, depth weighted by its noise (the corners once counted half, giving the
///   noisy depth twice its share).
/// - *Drawn in only*: the corners count only when they come in. Spreading (corners pushed
///   out, `scale > 1`) is another shape (`mouthStretch`), not negative rounding: subtracted,
///   it cancelled the lips' push in a rounded vowel said with the corners apart.
pub fn funnel_measure(forward: f64, scale: f64) -> f64 {
    DEPTH_WEIGHT * forward + 0.5 * (1.0 - scale).max(0.0)
}

/// The lips' opening, in mouth widths of growth of the gap between the lip centroids, at
/// which the rounding counts wholly as `mouthFunnel` (open) and no longer as `mouthPucker`
/// (closed): 0.1, 5.5 mm for a 55 mm mouth.
pub const OPEN_WIDTHS: f64 = 0.1;

/// The share of the rounding that is open (`mouthFunnel`; the rest is `mouthPucker`), from
/// the growth of the gap between the lip centroids (`gap`, mouth widths): `clamp(gap /
/// OPEN_WIDTHS, 0, 1)`; 0 when it is not a number.
pub fn open_fraction(gap: f64) -> f64 {
    let f = gap / OPEN_WIDTHS;
    if f.is_finite() {
        f.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// The `mouthClose` measure, degrees: the part of the jaw's opening (`angle_deg`, which drops
/// the lower-lip centroid by `drop`, metres) that the lips do not show as parting (`gap`, the
/// growth of the gap between the lip centroids, metres): `angle_deg · clamp((drop −
/// max(gap, 0)) / drop, 0, 1)`, 0 when the jaw is not open. In degrees like `jawOpen` and with
/// its range, so that equal `jawOpen` and `mouthClose` mean sealed lips (ARKit's pairing);
/// lips pressed with the jaw shut read no `mouthClose`.
pub fn close_measure(angle_deg: f64, drop: f64, gap: f64) -> f64 {
    if !(angle_deg > 0.0 && drop > 0.0) {
        return 0.0;
    }
    let sealed = (drop - gap.max(0.0)) / drop;
    if sealed.is_finite() {
        angle_deg * sealed.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// The mouth centre's sideways shift: the mean of `dx` over the dots weighted by `weight`
/// (the midline weights of [`midline_weights`]). Named heuristic *centred stretch*: each
/// side's scale is fitted about the mouth centre moved by this shift, so that a shift of the
/// whole mouth, or the head-pose residue the stabiliser leaves (a common error of every dot),
/// does not read as one side stretching and the other narrowing.
pub(super) fn centre_shift(weight: &[f64], dx: impl Fn(usize) -> f64) -> f64 {
    let (mut s, mut ws) = (0.0, 0.0);
    for (i, w) in weight.iter().enumerate() {
        s += w * dx(i);
        ws += w;
    }
    if ws > 0.0 {
        s / ws
    } else {
        0.0
    }
}

/// Per dot, its weight in the mouth centre's shift: `clamp(1 − |x⁰| / (w/2), 0, 1)`, 1 on the
/// midline, 0 at the corners, so that one corner pulled out (a one-sided stretch) moves the
/// centre little and the other side does not read a stretch.
pub(super) fn midline_weights(neutral: &[Vec3], width: f64) -> Vec<f64> {
    neutral
        .iter()
        .map(|p| (1.0 - p.x.abs() / (0.5 * width)).clamp(0.0, 1.0))
        .collect()
}

pub(super) fn weighted_right(idx: &[usize], left: &[f64], f: impl Fn(usize) -> f64) -> f64 {
    let (mut s, mut ws) = (0.0, 0.0);
    for (k, &i) in idx.iter().enumerate() {
        let w = 1.0 - left[k];
        s += w * f(i);
        ws += w;
    }
    if ws > 0.0 {
        s / ws
    } else {
        0.0
    }
}

/// Turns measures into curves with ranges.
pub fn curves_from(measures: &Measures, ranges: &[f64; CURVES], out: &mut [f64; CURVES]) {
    for ((dst, m), r) in out.iter_mut().zip(&measures.values).zip(ranges) {
        let v = m / r;
        *dst = if v.is_finite() {
            v.clamp(0.0, 1.0)
        } else {
            0.0
        };
    }
}
