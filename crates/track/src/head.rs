//! The head: the head motion the naming uses (from the named forehead dots, or with one of
//! them hidden from the two seen and the upper lip at rest), the forehead dots' depths (a
//! plane over a wide patch of skin, then one temporal filter for them all), and once
//! calibrated the head motion refined on the whole forehead surface ([`crate::forehead`]).

use mouthpiece_frame::Intrinsics;
use mouthpiece_retarget::kabsch::kabsch;
use mouthpiece_retarget::{OneEuroGroup, PerformerLayout, RigidTransform};

use crate::depth::{self, DepthScratch};
use crate::forehead::{self, DepthCrop, ForeheadSurface};
use crate::head_filter::HeadFilter;
use crate::labels::{Candidate, Small};
use crate::{camera, Sensor, Vec3};

/// Largest RMS misfit (metres) of the upper lip and forehead dots to their rest shape for
/// the head motion fitted to them to be used while a forehead dot is hidden: the upper lip
/// moves a millimetre or two with speech, wrong or deformed lip names misfit by more.
pub const HEAD_FALLBACK_RMS_M: f64 = 0.003;

/// Largest change the forehead surface fit may make to the dots' head motion: rotation
/// (radians, 5°) and the forehead dots' places (metres). The dots' own fit is off by a
/// degree or two at worst on the synthetic performer; beyond these the fit took something
/// else for the forehead (a hand over most of it).
pub const SURFACE_FIT_MAX_TURN_RAD: f64 = 0.087;
pub const SURFACE_FIT_MAX_SHIFT_M: f64 = 0.01;

/// The forehead surface is sampled this far apart, metres (2 px at 0.6 m in VGA; the
/// sensor's noise is correlated over about four pixels, and the samples' count is what the
/// fit costs).
pub const FOREHEAD_SAMPLE_SPACING_M: f64 = 0.002;

/// The smallest forehead depth patch: this many paint radii, and this many pixels (a patch
/// of fewer readings fits a plane poorly).
const FOREHEAD_PATCH_MIN_RADII: f64 = 2.0;
const FOREHEAD_PATCH_MIN_PX: f64 = 3.0;

/// Depths below this (metres) are taken as this when converting sizes in metres to pixels
/// (a forehead nearer than 10 cm is not a performer in front of a depth camera).
const NEAREST_FOREHEAD_M: f64 = 0.1;

/// What a frame's head motion is measured against.
#[derive(Debug, Clone, Copy)]
pub(crate) struct HeadReference<'a> {
    pub(crate) layout: PerformerLayout,
    /// The forehead dots in the reference head pose (camera frame).
    pub(crate) forehead: &'a [Vec3],
    /// The lip dots at rest in the reference head pose.
    pub(crate) rest: &'a [Vec3],
    /// The last frame's head motion (reference → then).
    pub(crate) last: RigidTransform,
}

impl HeadReference<'_> {
    /// This frame's head motion (reference → now) from the named forehead dots, or the last
    /// one.
    ///
    /// For naming only (the reported head pose follows docs/method.md): with fewer than 3
    /// forehead dots the motion is fitted to the two forehead dots seen plus the upper lip
    /// and corners at rest. The upper lip moves little with speech; a head turning fast
    /// while a forehead dot is hidden moves far more, and a stale head pose would bend every
    /// lip prediction.
    pub(crate) fn now(&self, names: &[Option<usize>], cands: &[Candidate]) -> RigidTransform {
        let n = self.layout.lip_dots;
        let (mut from, mut to): (Small<Vec3>, Small<Vec3>) = names[n..]
            .iter()
            .enumerate()
            .filter_map(|(j, c)| c.map(|c| (self.forehead[j], cands[c].point)))
            .unzip();
        if let Some(head) = kabsch(&from, &to) {
            return head;
        }
        if self.rest.len() == n && from.len() == 2 {
            let upper = 0..=self.layout.right_corner();
            for (rest, c) in self.rest[upper.clone()].iter().zip(&names[upper]) {
                if let Some(c) = c {
                    from.push(*rest);
                    to.push(cands[*c].point);
                }
            }
        }
        // Only a fit the upper lip follows rigidly (wrong or deformed lip names fit badly).
        match kabsch(&from, &to) {
            Some(head)
                if from
                    .iter()
                    .zip(&to)
                    .map(|(f, t)| (head.apply(f) - t).norm_squared())
                    .sum::<f64>()
                    <= from.len() as f64 * HEAD_FALLBACK_RMS_M.powi(2) =>
            {
                head
            }
            _ => self.last,
        }
    }
}

/// Sizes in metres at depth `z` in pixels, rounded to 1/64 px: calibrations that differ only
/// in their last digits (an .oni's field of view is a 32-bit float) must pick the same
/// pixels.
pub(crate) fn patch_px(size_m: f64, fx: f64, z: f64) -> f64 {
    quantise_px(size_m * fx / z)
}

/// Patch sizes in pixels are rounded to whole multiples of 1/this px (a binary fraction, exact
/// in floating point), so that calibrations differing by a 32-bit float's rounding pick the
/// same pixels.
pub const PATCH_PX_STEPS: f64 = 64.0;

/// A pixel length rounded to 1/[`PATCH_PX_STEPS`] px (see [`patch_px`]).
pub(crate) fn quantise_px(px: f64) -> f64 {
    (px * PATCH_PX_STEPS).round() / PATCH_PX_STEPS
}

/// A forehead dot's depth: the forehead is smooth, so a plane over a wide patch of skin
/// (`patch_m` radius) around the dot averages the sensor's (spatially correlated) noise
/// down; the head pose needs it.
pub(crate) fn forehead_dot_depth(
    sensor: &Sensor,
    patch_m: f64,
    center: [f64; 2],
    z_hint: f64,
    scratch: &mut DepthScratch,
) -> Option<(f64, depth::DepthMethod)> {
    let radius_px = sensor.dot_radius_px(z_hint);
    let patch = patch_px(patch_m, sensor.k.fx, z_hint);
    depth::depth_by_plane(
        sensor.depth,
        sensor.scale,
        center,
        patch
            .max(FOREHEAD_PATCH_MIN_RADII * radius_px)
            .max(FOREHEAD_PATCH_MIN_PX),
        sensor.depth_range,
        scratch,
    )
}

/// The forehead's depth in one calibration frame: the box round the forehead dots' pixels
/// grown by `margin_m` (see [`DepthCrop::around_forehead`]), and the nose bridge's strip
/// `nose_reach` of the way to the mouth centred at `mouth_px` (0: none).
pub(crate) fn forehead_crop(
    sensor: &Sensor,
    margin_m: f64,
    pixels: &[[f64; 2]],
    dots: &[Option<Vec3>],
    mouth_px: Option<[f64; 2]>,
    nose_reach: f64,
) -> DepthCrop {
    let z = dots.iter().flatten().map(|p| p.z).sum::<f64>() / dots.len() as f64;
    let px_per_m = sensor.k.fx / z.max(NEAREST_FOREHEAD_M);
    // `NoseStrip::between` gives none for a reach of 0.
    let nose = mouth_px.and_then(|mouth| {
        forehead::NoseStrip::between(
            pixels,
            mouth,
            nose_reach,
            NOSE_BRIDGE_HALF_WIDTH_M * px_per_m,
        )
    });
    DepthCrop::around_forehead(sensor.depth, pixels, margin_m * px_per_m, nose)
}

/// Half the nose bridge strip's width, metres: the bridge is 15–20 mm wide, and the eyes'
/// inner corners lie 15 mm or more either side of the midline.
pub const NOSE_BRIDGE_HALF_WIDTH_M: f64 = 0.010;

/// The neutral forehead surface from the calibration window's crops (see [`forehead`]).
pub(crate) fn build_forehead_surface(
    crops: Option<Vec<&DepthCrop>>,
    scale: f64,
    depth_range: [f64; 2],
    k: &Intrinsics,
    reference_forehead: &[Vec3],
) -> Option<ForeheadSurface> {
    let crops = crops?;
    let z = reference_forehead.iter().map(|p| p.z).sum::<f64>()
        / reference_forehead.len().max(1) as f64;
    let step_px = (FOREHEAD_SAMPLE_SPACING_M * k.fx / z.max(NEAREST_FOREHEAD_M))
        .round()
        .max(1.0) as usize;
    let surface = ForeheadSurface::build(
        &crops,
        scale,
        depth_range,
        k,
        reference_forehead.to_vec(),
        step_px,
    );
    match &surface {
        Some(s) => tracing::info!(samples = s.samples(), "forehead surface taken"),
        None => tracing::warn!(
            "too little forehead surface with depth: the head motion comes from the forehead dots alone"
        ),
    }
    surface
}

/// With every forehead dot named and a neutral surface, the forehead dots become the
/// neutral ones (`reference`) carried by the head motion fitted to the surface and their
/// pixels. `last`: the last frame's head motion.
pub(crate) fn fit_forehead_surface(
    surface: &ForeheadSurface,
    reference: &[Vec3],
    last: &RigidTransform,
    forehead: &[Option<usize>],
    cands: &mut [Candidate],
    sensor: &Sensor,
    filter: Option<(&mut HeadFilter, f64)>,
) -> Option<RigidTransform> {
    let rays: Small<Option<Vec3>> = forehead.iter().map(|c| c.map(|c| cands[c].point)).collect();
    let (from, to): (Small<Vec3>, Small<Vec3>) = reference
        .iter()
        .zip(&rays)
        .filter_map(|(f, r)| r.map(|r| (*f, r)))
        .unzip();
    if from.len() < forehead.len() {
        return None;
    }
    let start = kabsch(&from, &to)?;
    let fitted = surface.refine(
        &start,
        &rays,
        sensor.depth,
        sensor.scale,
        sensor.k,
        forehead::SurfaceFit::default(),
    );
    // A refinement that turned or moved the forehead far from both the dots' own fit and
    // the last frame's head fitted something else (a hand over most of the forehead). Near
    // either is the head: the dots' fit is off by a degree or two at worst, but one dot's
    // depth gone astray for a frame (a few millimetres over their 4 cm) turns it by more,
    // while the head turns little between frames (*either anchor*).
    let fitted = fitted.filter(|head| {
        let usable = surface_fit_usable(head, &start, last, reference);
        if !usable {
            tracing::debug!(
                "forehead surface fit far from the dots' fit and the last head; not used"
            );
        }
        usable
    });
    let Some(fitted) = fitted else {
        // No head motion measured on the surface this frame (a hand over the forehead):
        // the dots stay as seen, and the filter starts again.
        if let Some((filter, _)) = filter {
            filter.reset();
        }
        return None;
    };
    // The naming goes on from the fitted motion (a filter lags a head that changes speed,
    // and the lips' predictions would lag with it); the output takes the filtered one.
    for (c, reference) in forehead.iter().zip(reference) {
        if let Some(c) = c {
            cands[*c].point = fitted.apply(reference);
        }
    }
    filter.map(|(filter, t)| filter.update(t, &fitted))
}

/// *Either anchor*: the surface fit is the head when it agrees with the dots' own fit or with
/// the last frame's head motion (see [`near_enough`]).
fn surface_fit_usable(
    fit: &RigidTransform,
    dots: &RigidTransform,
    last: &RigidTransform,
    reference: &[Vec3],
) -> bool {
    near_enough(fit, dots, reference) || near_enough(fit, last, reference)
}

/// Whether two head motions agree within [`SURFACE_FIT_MAX_TURN_RAD`] and, on every
/// forehead dot (`reference`), [`SURFACE_FIT_MAX_SHIFT_M`].
fn near_enough(a: &RigidTransform, b: &RigidTransform, reference: &[Vec3]) -> bool {
    let turned = ((a.rotation.transpose() * b.rotation).trace() - 1.0) / 2.0;
    let moved = reference
        .iter()
        .map(|p| (a.apply(p) - b.apply(p)).norm())
        .fold(0.0, f64::max);
    turned.clamp(-1.0, 1.0).acos() <= SURFACE_FIT_MAX_TURN_RAD && moved <= SURFACE_FIT_MAX_SHIFT_M
}

/// The forehead dots' depths through their temporal filter, one cutoff for all of them
/// ([`OneEuroGroup`]: a rigid forehead's dots lag alike, so the lag does not turn the head).
/// The pixels stay; each dot is deprojected again at its filtered depth. A dot unseen starts
/// afresh when it returns, rather than from a stale depth.
pub(crate) fn filter_forehead_depths(
    filter: &mut OneEuroGroup,
    forehead: &[Option<usize>],
    cands: &mut [Candidate],
    t: f64,
    k: &Intrinsics,
) {
    let mut depths: Small<Option<f64>> = forehead
        .iter()
        .map(|c| c.map(|c| cands[c].point.z))
        .collect();
    filter.filter(t, &mut depths);
    for (name, z) in forehead.iter().zip(&depths) {
        if let (Some(c), Some(z)) = (name, z) {
            let c = &mut cands[*c];
            c.point = camera::deproject(k, c.pixel, *z);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    /// The head turned about the middle of the forehead by `deg` and shifted sideways.
    fn turned(deg: f64, shift_m: f64) -> RigidTransform {
        let rotation = Rotation3::from_axis_angle(&Vec3::y_axis(), deg.to_radians()).into_inner();
        let middle = Vec3::new(0.0, -0.085, 0.6);
        RigidTransform {
            rotation,
            translation: middle - rotation * middle + Vec3::new(shift_m, 0.0, 0.0),
        }
    }

    /// *Either anchor*: a fit 6° from the dots' own fit (one dot's depth astray) is still the
    /// head when it is 1° from the last frame's; 6° from both, or 12 mm off both, it is
    /// something else (a hand over the forehead).
    #[test]
    fn the_surface_fit_is_used_near_the_dots_fit_or_the_last_head() {
        let forehead = [
            Vec3::new(-0.02, -0.08, 0.6),
            Vec3::new(0.0, -0.09, 0.6),
            Vec3::new(0.02, -0.08, 0.6),
        ];
        let fit = turned(10.0, 0.0);
        assert!(surface_fit_usable(
            &fit,
            &turned(9.0, 0.0),
            &turned(0.0, 0.0),
            &forehead
        ));
        assert!(surface_fit_usable(
            &fit,
            &turned(4.0, 0.0),
            &turned(9.0, 0.0),
            &forehead
        ));
        assert!(!surface_fit_usable(
            &fit,
            &turned(4.0, 0.0),
            &turned(16.0, 0.0),
            &forehead
        ));
        let moved = turned(10.0, 0.012);
        assert!(!surface_fit_usable(&moved, &fit, &fit, &forehead));
        assert!(surface_fit_usable(
            &moved,
            &turned(10.0, 0.004),
            &fit,
            &forehead
        ));
    }
}
