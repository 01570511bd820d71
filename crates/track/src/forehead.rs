//! Head motion from the whole forehead, not just its three dots.
//!
//! Three dots' depths tilt the head by the depth noise over their spacing: 0.4 mm over 4 cm
//! is 0.6°, and the mouth sits 11 cm below. The forehead's skin around and between the dots
//! holds thousands of depth readings. At calibration their mean over the still second becomes
//! a surface (camera frame, neutral pose); each frame afterwards the head motion is refined so
//! that this surface meets the depth image (point-to-plane, projective association as in
//! KinectFusion) while the dots' neutral places project onto the dots' pixels (their pixels
//! are precise to a tenth of a pixel; their depth is what is noisy). Gauss–Newton on the
//! six parameters, Huber weights on the depth residuals (eyebrows, hair and hands are not
//! the surface).

use mouthpiece_frame::{DepthImage, Intrinsics};
use mouthpiece_retarget::RigidTransform;
use nalgebra::{Matrix3, Matrix6, Rotation3, Vector6};

use crate::{camera, Vec3};

#[cfg(target_arch = "x86_64")]
mod lanes;

/// A rectangle of one frame's depth image, kept while calibrating.
#[derive(Debug, Clone)]
pub struct DepthCrop {
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
    data: Vec<u16>,
    /// The forehead's box, pixels `[x0, y0, x1, y1)`: what is surface besides the nose.
    forehead: [usize; 4],
    /// The nose bridge below it, when the mouth's place is known.
    nose: Option<NoseStrip>,
}

/// A strip of pixels down the middle of the face, from the forehead dots towards the mouth:
/// the nose bridge, which is skull like the forehead (*the nose bridge is skull*). It sits
/// 5–9 cm below the forehead's middle, so it sets the head's pitch by a longer lever than
/// the forehead alone, and it lies between the forehead and the mouth the pose is used on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoseStrip {
    /// Where distances along the strip start (the forehead dots' centroid), pixels.
    pub origin: [f64; 2],
    /// Unit direction from the forehead dots' centroid to the mouth's centre.
    pub dir: [f64; 2],
    /// The strip's extent along `dir`, pixels from `origin`.
    pub along: [f64; 2],
    /// Half its width across `dir`, pixels.
    pub half_width: f64,
}

impl NoseStrip {
    /// The strip for forehead dots at `forehead` pixels and the mouth centred at `mouth`:
    /// from the lowest forehead dot (along the line to the mouth) down `reach` of the way
    /// from it to the mouth, `half_width_px` either side of that line. `None` when the
    /// mouth is not below the forehead dots, or there are none.
    pub fn between(
        forehead: &[[f64; 2]],
        mouth: [f64; 2],
        reach: f64,
        half_width_px: f64,
    ) -> Option<Self> {
        let origin = camera::pixel_mean(forehead)?;
        let (dx, dy) = (mouth[0] - origin[0], mouth[1] - origin[1]);
        let len = dx.hypot(dy);
        let positive = |v: f64| v > 0.0; // false for NaN too
        if !positive(len) || !positive(half_width_px) || !positive(reach) {
            return None;
        }
        let dir = [dx / len, dy / len];
        let lowest = forehead
            .iter()
            .map(|p| (p[0] - origin[0]) * dir[0] + (p[1] - origin[1]) * dir[1])
            .fold(f64::NEG_INFINITY, f64::max);
        if lowest >= len {
            return None;
        }
        Some(Self {
            origin,
            dir,
            along: [lowest, lowest + reach.min(1.0) * (len - lowest)],
            half_width: half_width_px,
        })
    }

    /// Whether pixel (x, y) lies on the strip.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        let (dx, dy) = (x - self.origin[0], y - self.origin[1]);
        let a = dx * self.dir[0] + dy * self.dir[1];
        let c = -dx * self.dir[1] + dy * self.dir[0];
        a >= self.along[0] && a <= self.along[1] && c.abs() <= self.half_width
    }

    /// The strip's four corners, pixels.
    fn corners(&self) -> [[f64; 2]; 4] {
        let [ux, uy] = self.dir;
        let (nx, ny) = (-uy, ux);
        let mut out = [[0.0; 2]; 4];
        for (i, (a, c)) in [
            (self.along[0], -self.half_width),
            (self.along[0], self.half_width),
            (self.along[1], -self.half_width),
            (self.along[1], self.half_width),
        ]
        .into_iter()
        .enumerate()
        {
            out[i] = [
                self.origin[0] + a * ux + c * nx,
                self.origin[1] + a * uy + c * ny,
            ];
        }
        out
    }
}

impl DepthCrop {
    /// The forehead's skin: the box round the forehead dots' pixels grown by `margin_px` to
    /// the sides and above, and by a third of it below (towards the brows, which move), and
    /// the nose bridge's strip when given.
    pub fn around_forehead(
        depth: &DepthImage,
        dots: &[[f64; 2]],
        margin_px: f64,
        nose: Option<NoseStrip>,
    ) -> Self {
        let (mut x_lo, mut y_lo) = (f64::INFINITY, f64::INFINITY);
        let (mut x_hi, mut y_hi) = (f64::NEG_INFINITY, f64::NEG_INFINITY);
        for p in dots {
            x_lo = x_lo.min(p[0]);
            x_hi = x_hi.max(p[0]);
            y_lo = y_lo.min(p[1]);
            y_hi = y_hi.max(p[1]);
        }
        let (w_img, h_img) = (depth.width as f64, depth.height as f64);
        let fx0 = (x_lo - margin_px).floor().clamp(0.0, w_img) as usize;
        let fx1 = (x_hi + margin_px).ceil().clamp(0.0, w_img) as usize;
        let fy0 = (y_lo - margin_px).floor().clamp(0.0, h_img) as usize;
        let fy1 = (y_hi + margin_px / BROW_MARGIN_DIVISOR)
            .ceil()
            .clamp(0.0, h_img) as usize;
        let (mut x0, mut x1, mut y0, mut y1) = (fx0, fx1, fy0, fy1);
        if let Some(strip) = &nose {
            for c in strip.corners() {
                x0 = x0.min(c[0].floor().clamp(0.0, w_img) as usize);
                x1 = x1.max(c[0].ceil().clamp(0.0, w_img) as usize);
                y0 = y0.min(c[1].floor().clamp(0.0, h_img) as usize);
                y1 = y1.max(c[1].ceil().clamp(0.0, h_img) as usize);
            }
        }
        let (w, h) = (x1.saturating_sub(x0), y1.saturating_sub(y0));
        let mut data = Vec::with_capacity(w * h);
        for y in y0..y0 + h {
            let row = y * depth.width as usize;
            data.extend_from_slice(&depth.data[row + x0..row + x0 + w]);
        }
        Self {
            x0,
            y0,
            w,
            h,
            data,
            forehead: [fx0, fy0, fx1, fy1],
            nose,
        }
    }

    /// Whether pixel (x, y) is on the forehead's box or the nose's strip.
    fn is_skin(&self, x: usize, y: usize) -> bool {
        let [fx0, fy0, fx1, fy1] = self.forehead;
        (x >= fx0 && x < fx1 && y >= fy0 && y < fy1)
            || self.nose.is_some_and(|s| s.contains(x as f64, y as f64))
    }

    fn get(&self, x: usize, y: usize) -> Option<u16> {
        (x >= self.x0 && y >= self.y0 && x < self.x0 + self.w && y < self.y0 + self.h)
            .then(|| self.data[(y - self.y0) * self.w + x - self.x0])
    }
}

/// Below the forehead dots the crop reaches the margin divided by this: the brows lie a few
/// centimetres below and move with the face, not the head.
pub const BROW_MARGIN_DIVISOR: f64 = 3.0;

/// A dot's pixel error, pixels (1 σ): the detector's sub-pixel centres scatter by about a
/// tenth of a pixel on still frames; twice that leaves room for blur.
pub const DOT_SIGMA_PX: f64 = 0.2;
/// One forehead sample's depth error, metres (1 σ): above the per-pixel noise, because the
/// structured-light noise is correlated over a few pixels and neighbouring samples do not
/// average it away.
pub const DEPTH_SIGMA_M: f64 = 0.004;

/// A pixel is forehead surface only if it has a valid reading in at least this share of the
/// calibration window's frames (numerator, denominator): a pixel that flickers in and out is
/// on an edge or under hair.
pub const VALID_FRAMES_SHARE: (usize, usize) = (2, 3);

/// Between the samples either side of a surface sample, a depth difference beyond this
/// share of their distance ...
pub const MAX_SURFACE_SLOPE: f64 = 0.6;
/// ... plus this much, metres (about twice the sensor's noise at 0.6 m), is a step in depth
/// (the head's edge, a dot's paint without readings beside it), not skin.
pub const SURFACE_STEP_SLACK_M: f64 = 0.004;

/// Fewest surface samples for a surface, and fewest used in a refinement step: below this a
/// hand or the image's edge hides most of the forehead and the three dots do better alone.
pub const MIN_SURFACE_SAMPLES: usize = 30;

/// A cross product (of sample differences, metres²) shorter than this gives no normal: the
/// points are on one line.
const DEGENERATE_CROSS: f64 = 1e-12;

/// The refinement has converged once a step turns the head by less than this, radians
/// (0.03°) ...
pub const CONVERGED_TURN_RAD: f64 = 5e-4;
/// ... and moves the forehead's middle by less than this, metres: each Gauss–Newton step
/// cuts the last about tenfold, so what is left is below the sensor's say.
pub const CONVERGED_SHIFT_M: f64 = 5e-5;

/// How the refinement weighs its two kinds of evidence.
#[derive(Debug, Clone, Copy)]
pub struct SurfaceFit {
    /// A dot's pixel error, pixels (1 σ).
    pub dot_sigma_px: f64,
    /// One surface sample's depth error, metres (1 σ; the sensor's noise is correlated over
    /// a few pixels, so this is above the per-pixel noise).
    pub depth_sigma_m: f64,
}

impl Default for SurfaceFit {
    fn default() -> Self {
        Self {
            dot_sigma_px: DOT_SIGMA_PX,
            depth_sigma_m: DEPTH_SIGMA_M,
        }
    }
}

/// Samples farther than this from the measured surface are something else (hair, a hand,
/// the brows), and not used.
const OUTLIER_M: f64 = 0.010;
/// Residuals beyond this are weighed down (Huber): about the sensor's noise at face distance.
const HUBER_M: f64 = 0.002;
/// Most Gauss–Newton steps per frame, a cap on the frame's time: the fit starts from the
/// three dots' pose, close by, and most frames stop earlier (see [`CONVERGED_TURN_RAD`]).
const ITERATIONS: usize = 4;

/// Skin farther than this from the plane through the forehead dots is not the forehead.
const OFF_PLANE_M: f64 = 0.025;

/// `x.round() as i64` without the library call `f64::round` becomes on baseline x86-64 (no
/// SSE4.1 rounding instruction): the projective association rounds two coordinates per
/// forehead sample and step. Below 2^52 the fraction `x - trunc(x)` is exact, so this is the
/// same rounding (half away from zero).
fn round_to_i64(x: f64) -> i64 {
    if x.abs() < 4.0e15 {
        let t = x as i64;
        let frac = x - t as f64;
        if frac >= 0.5 {
            t + 1
        } else if frac <= -0.5 {
            t - 1
        } else {
            t
        }
    } else {
        x.round() as i64
    }
}

/// `h += w j jᵀ` on the lower triangle only (with the rounding of nalgebra's `ger`:
/// `(w j[col]) j[row] + h`): the Cholesky factorisation the normal equations go to reads
/// nothing else, and the upper triangle is 15 of the 36 products.
fn add_outer_lower(h: &mut Matrix6<f64>, w: f64, j: &Vector6<f64>) {
    for col in 0..6 {
        let s = w * j[col];
        for row in col..6 {
            h[(row, col)] += s * j[row];
        }
    }
}

/// A point on the plane through the first three of `dots` and its unit normal.
fn plane_through(dots: &[Vec3]) -> Option<(Vec3, Vec3)> {
    let [a, b, c] = dots.get(..3)? else {
        return None;
    };
    let n = (b - a).cross(&(c - a));
    let len = n.norm();
    (len > DEGENERATE_CROSS).then(|| ((a + b + c) / 3.0, n / len))
}

/// The forehead at neutral: surface samples with their normals, and the dots.
#[derive(Debug, Clone)]
pub struct ForeheadSurface {
    points: Vec<Vec3>,
    normals: Vec<Vec3>,
    dots: Vec<Vec3>,
    /// The samples' mean.
    centre: Vec3,
    /// The rays through every column and row of the camera it was built with, when that
    /// camera has no lens distortion.
    rays: Option<PixelRays>,
    /// The samples as columns, for four at a time.
    #[cfg(target_arch = "x86_64")]
    columns: lanes::SampleColumns,
}

/// For a camera without lens distortion, the normalised image coordinate of every pixel
/// column, `(x − cx) / fx`, and row, `(y − cy) / fy`: deprojecting a whole pixel is then a
/// table lookup and a product instead of a division per sample and refinement step (the
/// same numbers, computed once).
#[derive(Debug, Clone)]
struct PixelRays {
    camera: Intrinsics,
    columns: Vec<f64>,
    rows: Vec<f64>,
}

impl PixelRays {
    fn new(k: &Intrinsics) -> Option<Self> {
        if k.has_distortion() {
            return None;
        }
        Some(Self {
            camera: *k,
            columns: (0..k.width).map(|x| (x as f64 - k.cx) / k.fx).collect(),
            rows: (0..k.height).map(|y| (y as f64 - k.cy) / k.fy).collect(),
        })
    }

    /// The tables, if they were made for `k` and cover a `width` x `height` image.
    fn for_camera(&self, k: &Intrinsics, width: usize, height: usize) -> Option<&Self> {
        (self.camera == *k && self.columns.len() >= width && self.rows.len() >= height)
            .then_some(self)
    }
}

impl ForeheadSurface {
    /// The surface from the still calibration window's crops: per pixel, the mean of its
    /// valid readings (at least two thirds of the frames), sampled every `step` pixels, with
    /// normals from the neighbouring samples. `dots`: the forehead dots at neutral (the
    /// neutral pose the head motion is measured from). `None` with too little surface.
    pub fn build(
        crops: &[&DepthCrop],
        scale: f64,
        range: [f64; 2],
        k: &Intrinsics,
        dots: Vec<Vec3>,
        step: usize,
    ) -> Option<Self> {
        let last = crops.last()?;
        let (lo, hi) = ((range[0] / scale).max(1.0), range[1] / scale);
        let (num, den) = VALID_FRAMES_SHARE;
        let need = (num * crops.len()).div_ceil(den);
        let mean = |x: usize, y: usize| -> Option<f64> {
            let (mut sum, mut n) = (0.0, 0usize);
            for c in crops {
                if let Some(v) = c.get(x, y) {
                    let v = v as f64;
                    if v >= lo && v <= hi {
                        sum += v;
                        n += 1;
                    }
                }
            }
            (n >= need).then(|| sum / n as f64 * scale)
        };
        let point =
            |x: usize, y: usize| mean(x, y).map(|z| camera::deproject(k, [x as f64, y as f64], z));
        // The skin lies near the plane through the dots; what lies far behind it (the wall,
        // the room) or before it is not the head, and must not hold the fit still.
        let plane = plane_through(&dots)?;
        let mut points = Vec::new();
        let mut normals = Vec::new();
        let step = step.max(1);
        for y in (last.y0 + step..last.y0 + last.h.saturating_sub(step)).step_by(step) {
            for x in (last.x0 + step..last.x0 + last.w.saturating_sub(step)).step_by(step) {
                if !last.is_skin(x, y) {
                    continue;
                }
                let Some(p) = point(x, y) else { continue };
                if (p - plane.0).dot(&plane.1).abs() > OFF_PLANE_M {
                    continue;
                }
                let (Some(l), Some(r), Some(u), Some(d)) = (
                    point(x - step, y),
                    point(x + step, y),
                    point(x, y - step),
                    point(x, y + step),
                ) else {
                    continue;
                };
                // A step in depth (the edge of the head, a dot's paint without readings
                // beside it) makes no surface.
                let (dx, dy) = (r - l, d - u);
                if (r.z - l.z).abs() > MAX_SURFACE_SLOPE * dx.norm() + SURFACE_STEP_SLACK_M
                    || (d.z - u.z).abs() > MAX_SURFACE_SLOPE * dy.norm() + SURFACE_STEP_SLACK_M
                {
                    continue;
                }
                let mut n = dx.cross(&dy);
                if n.norm() < DEGENERATE_CROSS {
                    continue;
                }
                n.normalize_mut();
                // Facing the camera.
                if n.dot(&p) > 0.0 {
                    n = -n;
                }
                points.push(p);
                normals.push(n);
            }
        }
        let centre = points.iter().sum::<Vec3>() / points.len().max(1) as f64;
        (points.len() >= MIN_SURFACE_SAMPLES).then_some(Self {
            dots,
            centre,
            rays: PixelRays::new(k),
            #[cfg(target_arch = "x86_64")]
            columns: lanes::SampleColumns::new(&points, &normals),
            points,
            normals,
        })
    }

    /// The samples' mean, camera frame at neutral: the forehead's middle.
    pub fn centre(&self) -> Vec3 {
        self.centre
    }

    pub fn samples(&self) -> usize {
        self.points.len()
    }

    /// The head motion (neutral → now) that best fits the depth image and the dots seen at
    /// `dot_rays` (their undistorted rays, any length; `None` for a dot not seen), starting
    /// from `start`. `None` if the fit breaks down (too few samples, a singular system).
    pub fn refine(
        &self,
        start: &RigidTransform,
        dot_rays: &[Option<Vec3>],
        depth: &DepthImage,
        scale: f64,
        k: &Intrinsics,
        fit: SurfaceFit,
    ) -> Option<RigidTransform> {
        self.refine_with(start, dot_rays, depth, scale, k, fit, true)
    }

    /// [`Self::refine`], four samples at a time when `lanes` and the CPU and camera allow.
    #[allow(clippy::too_many_arguments)]
    fn refine_with(
        &self,
        start: &RigidTransform,
        dot_rays: &[Option<Vec3>],
        depth: &DepthImage,
        scale: f64,
        k: &Intrinsics,
        fit: SurfaceFit,
        lanes: bool,
    ) -> Option<RigidTransform> {
        let mut rotation = start.rotation;
        let mut translation = start.translation;
        let w_dot = (k.fx / fit.dot_sigma_px).powi(2);
        let w_depth = fit.depth_sigma_m.powi(-2);
        let (wd, hd) = (depth.width as i64, depth.height as i64);
        // Without lens distortion, projecting and deprojecting are a few multiplications;
        // the general functions run per sample and iteration otherwise.
        let ideal = !k.has_distortion();
        let project = |q: &Vec3| {
            if ideal {
                k.project_ideal([q.x, q.y, q.z])
            } else {
                camera::project(k, q)
            }
        };
        let rays = self
            .rays
            .as_ref()
            .and_then(|r| r.for_camera(k, wd as usize, hd as usize));
        let deproject = |x: i64, y: i64, z: f64| {
            if let Some(r) = rays {
                Vec3::new(r.columns[x as usize] * z, r.rows[y as usize] * z, z)
            } else if ideal {
                Vec3::from(k.deproject_ideal([x as f64, y as f64], z))
            } else {
                camera::deproject(k, [x as f64, y as f64], z)
            }
        };
        for _ in 0..ITERATIONS {
            let mut h = Matrix6::<f64>::zeros();
            let mut g = Vector6::<f64>::zeros();
            let mut used = 0usize;
            // One sample's weight, residual and Jacobian row; `None`: not used.
            let terms = |p: &Vec3, n: &Vec3| -> Option<(f64, f64, [f64; 6])> {
                let q = rotation * p + translation;
                let px = project(&q)?;
                let (x, y) = (round_to_i64(px[0]), round_to_i64(px[1]));
                if x < 0 || y < 0 || x >= wd || y >= hd {
                    return None;
                }
                let raw = depth.data[(y * wd + x) as usize];
                if raw == 0 {
                    return None;
                }
                let n = rotation * n;
                let measured = deproject(x, y, raw as f64 * scale);
                let r = n.dot(&(measured - q));
                if r.abs() > OUTLIER_M {
                    return None;
                }
                let huber = if r.abs() <= HUBER_M {
                    1.0
                } else {
                    HUBER_M / r.abs()
                };
                let qn = q.cross(&n);
                Some((w_depth * huber, r, [-qn.x, -qn.y, -qn.z, -n.x, -n.y, -n.z]))
            };
            let mut add = |(w, r, j): (f64, f64, [f64; 6])| {
                let j = Vector6::from(j);
                add_outer_lower(&mut h, w, &j);
                g += w * r * j;
                used += 1;
            };
            // Four samples at a time where the CPU can and the camera is ideal (the same
            // numbers, see `lanes`), then the rest one by one, all summed in order.
            #[cfg(target_arch = "x86_64")]
            let first_single = match (lanes && lanes::available(), rays) {
                (true, Some(rays)) => {
                    let inputs = lanes::StepInputs {
                        rotation: &rotation,
                        translation: &translation,
                        camera: [k.fx, k.fy, k.cx, k.cy],
                        width: wd,
                        height: hd,
                        depth: &depth.data,
                        scale,
                        columns: &rays.columns,
                        rows: &rays.rows,
                        w_depth,
                    };
                    let grouped = self.columns.grouped_len();
                    for first in (0..grouped).step_by(4) {
                        // SAFETY: `lanes::available` checked the CPU.
                        for t in unsafe { lanes::four_samples(&self.columns, first, &inputs) }
                            .into_iter()
                            .flatten()
                        {
                            add(t);
                        }
                    }
                    grouped
                }
                _ => 0,
            };
            #[cfg(not(target_arch = "x86_64"))]
            let first_single = {
                let _ = lanes;
                0
            };
            for (p, n) in self.points.iter().zip(&self.normals).skip(first_single) {
                if let Some(t) = terms(p, n) {
                    add(t);
                }
            }
            if used < MIN_SURFACE_SAMPLES {
                return None;
            }
            for (x, ray) in self.dots.iter().zip(dot_rays) {
                let Some(ray) = ray else { continue };
                let q = rotation * x + translation;
                if q.z <= 0.0 || ray.z <= 0.0 {
                    continue;
                }
                let (mx, my) = (ray.x / ray.z, ray.y / ray.z);
                let r = [q.x / q.z - mx, q.y / q.z - my];
                // d(normalised)/dq, then dq/d(ω, v) = [-[q]×, I].
                let dn = nalgebra::Matrix2x3::new(
                    1.0 / q.z,
                    0.0,
                    -q.x / (q.z * q.z),
                    0.0,
                    1.0 / q.z,
                    -q.y / (q.z * q.z),
                );
                let dq = {
                    let mut m = nalgebra::Matrix3x6::zeros();
                    m.fixed_view_mut::<3, 3>(0, 0)
                        .copy_from(&(-q.cross_matrix()));
                    m.fixed_view_mut::<3, 3>(0, 3)
                        .copy_from(&Matrix3::identity());
                    m
                };
                let j = dn * dq;
                for (row, r) in r.iter().enumerate() {
                    let jr = j.row(row).transpose();
                    add_outer_lower(&mut h, w_dot, &jr);
                    g += w_dot * r * jr;
                }
            }
            // Only the lower triangle of `h` is filled, all the factorisation reads.
            let delta = h.cholesky()?.solve(&(-g));
            let omega = delta.fixed_rows::<3>(0).into_owned();
            let v = delta.fixed_rows::<3>(3).into_owned();
            let step = Rotation3::new(omega).into_inner();
            // How far this step moves the middle of the forehead (a turn about the camera
            // also shifts: ω and v are coupled, so v alone says little).
            let centre = rotation * self.centre + translation;
            let shift = (omega.cross(&centre) + v).norm();
            rotation = step * rotation;
            translation = step * translation + v;
            if omega.norm() < CONVERGED_TURN_RAD && shift < CONVERGED_SHIFT_M {
                break;
            }
        }
        // Re-orthonormalise against drift over the small steps.
        let rotation = Rotation3::from_matrix(&rotation).into_inner();
        Some(RigidTransform {
            rotation,
            translation,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    /// A forehead: a sphere of radius 9 cm whose front is at 0.6 m, seen by the VGA camera
    /// over a wall at 1.2 m; depth in millimetres, plus an offset field per pixel (noise).
    fn render(
        head: &RigidTransform,
        k: &Intrinsics,
        noise_mm: impl Fn(usize, usize) -> f64,
    ) -> DepthImage {
        let centre = head.apply(&Vec3::new(0.0, -0.1, 0.69));
        let radius = 0.09;
        let mut d = DepthImage::new(k.width, k.height);
        for y in 0..k.height as usize {
            for x in 0..k.width as usize {
                let ray = camera::deproject(k, [x as f64, y as f64], 1.0).normalize();
                // Nearest hit of the ray with the sphere, else the wall.
                let b = ray.dot(&centre);
                let disc = b * b - (centre.norm_squared() - radius * radius);
                let z = if disc >= 0.0 {
                    (b - disc.sqrt()) * ray.z
                } else {
                    1.2
                };
                d.data[y * k.width as usize + x] = (z * 1000.0 + noise_mm(x, y)).round() as u16;
            }
        }
        d
    }

    /// Three dots on the sphere, in the neutral pose.
    fn dots() -> Vec<Vec3> {
        let centre = Vec3::new(0.0, -0.1, 0.69);
        [[0.035, 0.0], [0.0, -0.035], [-0.035, 0.0]]
            .iter()
            .map(|[x, y]| {
                let (x, y) = (*x, -0.1 + y);
                let z = centre.z - (0.09f64.powi(2) - x * x - (y - centre.y).powi(2)).sqrt();
                Vec3::new(x, y, z)
            })
            .collect()
    }

    fn surface(k: &Intrinsics, neutral: &DepthImage) -> ForeheadSurface {
        let pixels: Vec<[f64; 2]> = dots()
            .iter()
            .map(|p| camera::project(k, p).unwrap())
            .collect();
        let crop = DepthCrop::around_forehead(neutral, &pixels, 0.025 * k.fx / 0.6, None);
        ForeheadSurface::build(&[&crop], 0.001, [0.2, 2.0], k, dots(), 2).unwrap()
    }

    fn angle_deg(a: &RigidTransform, b: &RigidTransform) -> f64 {
        let r = a.rotation.transpose() * b.rotation;
        ((r.trace() - 1.0) / 2.0)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees()
    }

    fn moved(yaw_deg: f64, pitch_deg: f64) -> RigidTransform {
        let rotation =
            Rotation3::from_euler_angles(pitch_deg.to_radians(), yaw_deg.to_radians(), 0.0)
                .into_inner();
        // About the head's centre, and a little to the side.
        let pivot = Vec3::new(0.0, -0.1, 0.69);
        RigidTransform {
            rotation,
            translation: pivot - rotation * pivot + Vec3::new(0.01, 0.0, 0.005),
        }
    }

    /// *The nose bridge is skull*: the strip runs from the lowest forehead dot down the line
    /// to the mouth, `reach` of the way, and follows that line when the face is rolled.
    #[test]
    fn the_nose_strip_runs_from_the_forehead_dots_towards_the_mouth() {
        let forehead = [[300.0, 100.0], [320.0, 80.0], [340.0, 100.0]];
        let strip = NoseStrip::between(&forehead, [320.0, 300.0], 0.5, 10.0).unwrap();
        assert!(strip.contains(320.0, 150.0) && strip.contains(328.0, 195.0));
        assert!(!strip.contains(320.0, 250.0), "beyond its reach");
        assert!(!strip.contains(335.0, 150.0), "beside it");
        assert!(
            !strip.contains(320.0, 95.0),
            "above the lowest forehead dot"
        );
        // The same face rolled by 90°: the mouth to the right of the forehead.
        let rolled = [[200.0, 300.0], [180.0, 320.0], [200.0, 340.0]];
        let strip = NoseStrip::between(&rolled, [400.0, 320.0], 0.5, 10.0).unwrap();
        assert!(strip.contains(250.0, 320.0) && !strip.contains(250.0, 335.0));
        // No mouth below the forehead dots: no strip.
        assert!(NoseStrip::between(&forehead, [320.0, 90.0], 0.5, 10.0).is_none());
        // A reach of 0 (`nose_bridge_reach = 0`: the forehead alone): no strip.
        assert!(NoseStrip::between(&forehead, [320.0, 300.0], 0.0, 10.0).is_none());
        // No forehead dots: no strip.
        assert!(NoseStrip::between(&[], [320.0, 300.0], 0.5, 10.0).is_none());
    }

    /// The strip's samples join the forehead's, below its box.
    #[test]
    fn the_nose_strip_adds_surface_below_the_forehead() {
        let k = Intrinsics::default_vga();
        let neutral = render(&RigidTransform::IDENTITY, &k, |_, _| 0.0);
        let pixels: Vec<[f64; 2]> = dots()
            .iter()
            .map(|p| camera::project(&k, p).unwrap())
            .collect();
        let margin = 0.025 * k.fx / 0.6;
        let mouth = camera::project(&k, &Vec3::new(0.0, -0.01, 0.61)).unwrap();
        let strip = NoseStrip::between(&pixels, mouth, 0.5, 0.01 * k.fx / 0.6);
        let build = |nose| {
            let crop = DepthCrop::around_forehead(&neutral, &pixels, margin, nose);
            ForeheadSurface::build(&[&crop], 0.001, [0.2, 2.0], &k, dots(), 2).unwrap()
        };
        let (forehead, both) = (build(None), build(strip));
        assert!(
            both.samples() > forehead.samples() + 50,
            "{} → {}",
            forehead.samples(),
            both.samples()
        );
        let lowest = forehead.points.iter().map(|p| p.y).fold(f64::MIN, f64::max);
        assert!(both.points.iter().any(|p| p.y > lowest + 0.02));
    }

    #[test]
    fn the_wall_behind_is_not_surface() {
        let k = Intrinsics::default_vga();
        let neutral = render(&RigidTransform::IDENTITY, &k, |_, _| 0.0);
        let s = surface(&k, &neutral);
        assert!(s.samples() > 300, "{}", s.samples());
        assert!(s.points.iter().all(|p| p.z < 0.7), "a sample on the wall");
        // Normals face the camera.
        assert!(s.points.iter().zip(&s.normals).all(|(p, n)| n.dot(p) < 0.0));
    }

    #[test]
    fn the_head_motion_is_found_from_the_surface_when_the_dots_depth_is_wrong() {
        let k = Intrinsics::default_vga();
        let neutral = render(&RigidTransform::IDENTITY, &k, |_, _| 0.0);
        let s = surface(&k, &neutral);
        let truth = moved(12.0, -5.0);
        // Depth noise correlated over 4 px, as a structured-light sensor's.
        let noise = |x: usize, y: usize| {
            let (i, j) = (x / 4, y / 4);
            1.5 * (((i * 7919 + j * 104_729) % 1000) as f64 / 500.0 - 1.0)
        };
        let now = render(&truth, &k, noise);
        // The dots' rays as seen; the start: their true places with 1.5 mm of depth error
        // on one of them, which tilts the three-dot fit by about 2°.
        let seen: Vec<Vec3> = dots().iter().map(|p| truth.apply(p)).collect();
        let rays: Vec<Option<Vec3>> = seen.iter().map(|p| Some(*p)).collect();
        let mut bad = seen.clone();
        let stretch = 1.0 + 0.0015 / bad[0].z;
        bad[0] *= stretch;
        let start = mouthpiece_retarget::kabsch::kabsch(&dots(), &bad).unwrap();
        assert!(
            angle_deg(&start, &truth) > 1.0,
            "{}",
            angle_deg(&start, &truth)
        );
        let fitted = s
            .refine(&start, &rays, &now, 0.001, &k, SurfaceFit::default())
            .unwrap();
        let error = angle_deg(&fitted, &truth);
        assert!(error < 0.25, "{error}°");
        assert!((fitted.translation - truth.translation).norm() < 0.001);
    }

    /// Four samples at a time give the same pose to the bit as one at a time, noise, a
    /// hand's step and samples falling off the image included.
    #[test]
    fn four_samples_at_a_time_give_the_same_pose_to_the_bit() {
        let k = Intrinsics::default_vga();
        let neutral = render(&RigidTransform::IDENTITY, &k, |_, _| 0.0);
        let s = surface(&k, &neutral);
        assert_ne!(
            s.samples() % 4,
            0,
            "a tail of single samples is exercised too"
        );
        let noise = |x: usize, y: usize| {
            let (i, j) = (x / 3, y / 3);
            2.5 * (((i * 7919 + j * 104_729) % 1000) as f64 / 500.0 - 1.0)
        };
        for (yaw, pitch) in [(0.0, 0.0), (12.0, -5.0), (-20.0, 8.0), (3.0, 25.0)] {
            let truth = moved(yaw, pitch);
            let mut now = render(&truth, &k, noise);
            // A hand 3 cm in front of the left fifth of the image.
            for y in 0..k.height as usize {
                for x in 0..k.width as usize / 5 {
                    let v = &mut now.data[y * k.width as usize + x];
                    *v = v.saturating_sub(30);
                }
            }
            let rays: Vec<Option<Vec3>> = dots().iter().map(|p| Some(truth.apply(p))).collect();
            let start = moved(yaw + 0.7, pitch - 0.4);
            let fit = SurfaceFit::default();
            let single = s.refine_with(&start, &rays, &now, 0.001, &k, fit, false);
            let four = s.refine_with(&start, &rays, &now, 0.001, &k, fit, true);
            let bits = |t: Option<RigidTransform>| {
                t.map(|t| {
                    t.rotation
                        .iter()
                        .chain(t.translation.iter())
                        .map(|v| v.to_bits())
                        .collect::<Vec<_>>()
                })
            };
            assert!(single.is_some(), "yaw {yaw}, pitch {pitch}");
            assert_eq!(bits(single), bits(four), "yaw {yaw}, pitch {pitch}");
        }
    }

    #[test]
    fn a_hand_over_part_of_the_forehead_is_left_out() {
        let k = Intrinsics::default_vga();
        let neutral = render(&RigidTransform::IDENTITY, &k, |_, _| 0.0);
        let s = surface(&k, &neutral);
        let truth = moved(-8.0, 4.0);
        let mut now = render(&truth, &k, |_, _| 0.0);
        // A hand 5 cm in front of the left third of the forehead.
        let left = camera::project(&k, &truth.apply(&dots()[2])).unwrap();
        for y in 0..k.height as usize {
            for x in 0..(left[0] as usize + 10) {
                let v = &mut now.data[y * k.width as usize + x];
                if *v < 700 {
                    *v -= 50;
                }
            }
        }
        let rays: Vec<Option<Vec3>> = dots().iter().map(|p| Some(truth.apply(p))).collect();
        let fitted = s
            .refine(
                &moved(-7.0, 3.0),
                &rays,
                &now,
                0.001,
                &k,
                SurfaceFit::default(),
            )
            .unwrap();
        let error = angle_deg(&fitted, &truth);
        assert!(error < 0.1, "{error}°");
    }
}
