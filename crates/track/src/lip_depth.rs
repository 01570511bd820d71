//! A lip dot's depth: a robust plane over a few millimetres of lip around it when it is a
//! candidate, and once named, again from a patch stretched along the lip.

use crate::depth::{self, DepthScratch};
use crate::head::{patch_px, quantise_px};
use crate::labels::Candidate;
use crate::{camera, Sensor};

/// How far towards its nearer neighbour a lip dot's stretched depth patch may reach (the
/// lip bends away towards a corner; measured with no cap: 3D RMS 0.86–1.28 mm over the 12
/// sessions of docs/lab/accuracy-tables.md against 0.78–1.22 mm with 0.8).
pub const LIP_PATCH_NEIGHBOUR_FRACTION: f64 = 0.8;

/// A lip dot's depth from the stretched patch replaces its own only within this distance
/// (metres) of it (*the stretched patch agrees with the paint*). The two readings of one dot
/// differ by 0.7–0.8 mm RMS (synthetic sessions, both noise models); where they differ by
/// several millimetres the long patch has reached past the lip, into the open mouth behind
/// a lip rolling out of it, and the paint's own patch is the better reading.
pub const LIP_PATCH_AGREEMENT_M: f64 = 0.005;

/// Neighbours nearer than this (pixels) give no direction along the lip.
const MIN_LIP_LINE_PX: f64 = 1.0;

/// Depth at a lip dot: a robust plane over `patch_m` of lip around it (the sensor's noise is
/// correlated over a few pixels, so the paint's own pixels share one error; the plane's
/// outlier rejection drops the open mouth behind the lip), else (`patch_m` 0, or too few
/// readings) the median of the paint's readings.
pub(crate) fn lip_depth(
    sensor: &Sensor,
    patch_m: f64,
    center: [f64; 2],
    z_hint: f64,
    scratch: &mut DepthScratch,
) -> Option<(f64, depth::DepthMethod)> {
    let radius_px = sensor.dot_radius_px(z_hint);
    let patch = patch_px(patch_m, sensor.k.fx, z_hint);
    (patch_m > 0.0)
        .then(|| {
            depth::depth_by_plane(
                sensor.depth,
                sensor.scale,
                center,
                patch.max(radius_px),
                sensor.depth_range,
                scratch,
            )
        })
        .flatten()
        .or_else(|| {
            depth::depth_at_dot(
                sensor.depth,
                sensor.scale,
                center,
                radius_px,
                sensor.depth_range,
                scratch,
            )
        })
}

/// Each named lip dot but the corners (`corners`): its depth again, from a patch stretched
/// along the lip (the line through its neighbours' pixels), `along_m` each way along it (at
/// most [`LIP_PATCH_NEIGHBOUR_FRACTION`] of the way to the nearer neighbour) and
/// `across_m` each way across. A lip is curved across and nearly straight along its line,
/// so the long patch averages more of the sensor's correlated noise for the same
/// curvature. Names are settled by then: this only sharpens the depth, and a reading further
/// than [`LIP_PATCH_AGREEMENT_M`] from the dot's own is not used.
pub(crate) fn along_the_lips(
    sensor: &Sensor,
    [along_m, across_m]: [f64; 2],
    corners: [usize; 2],
    lip: &[Option<usize>],
    cands: &mut [Candidate],
    scratch: &mut DepthScratch,
) {
    if along_m <= 0.0 {
        return;
    }
    let n = lip.len();
    for i in 0..n {
        if corners.contains(&i) {
            continue;
        }
        let Some(c) = lip[i] else { continue };
        let here = cands[c].pixel;
        let prev = lip[(i + n - 1) % n].map(|p| cands[p].pixel);
        let next = lip[(i + 1) % n].map(|p| cands[p].pixel);
        let (a, b) = match (prev, next) {
            (Some(p), Some(q)) => (p, q),
            (Some(p), None) => (p, here),
            (None, Some(q)) => (here, q),
            (None, None) => continue,
        };
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let len = (dx * dx + dy * dy).sqrt();
        if len < MIN_LIP_LINE_PX {
            continue;
        }
        let gap = |p: Option<[f64; 2]>| {
            p.map_or(f64::INFINITY, |p| {
                ((p[0] - here[0]).powi(2) + (p[1] - here[1]).powi(2)).sqrt()
            })
        };
        let nearest_px = gap(prev).min(gap(next));
        let z_hint = cands[c].point.z;
        // Short of the neighbours: towards a corner the lip bends away.
        let along_px = patch_px(along_m, sensor.k.fx, z_hint)
            .min(quantise_px(LIP_PATCH_NEIGHBOUR_FRACTION * nearest_px));
        if let Some((z, _)) = depth::depth_by_plane_along(
            sensor.depth,
            sensor.scale,
            here,
            depth::Ellipse {
                along: [dx / len, dy / len],
                half_len: along_px,
                half_width: patch_px(across_m, sensor.k.fx, z_hint),
            },
            sensor.depth_range,
            scratch,
        ) {
            if (z - z_hint).abs() <= LIP_PATCH_AGREEMENT_M {
                cands[c].point = camera::deproject(sensor.k, here, z);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mouthpiece_detect::DotRole;
    use mouthpiece_frame::{DepthImage, Intrinsics};

    /// Four lip dots, the corners 0 and 2 either side of dot 1 at (50, 40), 10 px apart
    /// along a horizontal lip; dot 3 unseen. Every dot at `z` metres.
    fn lip_of_three(k: &Intrinsics, z: f64) -> Vec<Candidate> {
        [[40.0, 40.0], [50.0, 40.0], [60.0, 40.0]]
            .into_iter()
            .map(|pixel| Candidate {
                pixel,
                point: camera::deproject(k, pixel, z),
                role: DotRole::Lip,
            })
            .collect()
    }

    fn depth_of_dot_1(image: &DepthImage, hint_z: f64) -> f64 {
        let k = Intrinsics::ideal(100, 80, 525.0, 525.0, 49.5, 39.5);
        let sensor = Sensor {
            depth: image,
            scale: 0.001,
            k: &k,
            depth_range: [0.2, 2.0],
            dot_radius_m: 0.002,
        };
        let mut cands = lip_of_three(&k, hint_z);
        along_the_lips(
            &sensor,
            [0.009, 0.0018],
            [0, 2],
            &[Some(0), Some(1), Some(2), None],
            &mut cands,
            &mut DepthScratch::default(),
        );
        cands[1].point.z
    }

    fn image(f: impl Fn(u32, u32) -> u16) -> DepthImage {
        let mut d = DepthImage::new(100, 80);
        for y in 0..80 {
            for x in 0..100 {
                d.data[(y * 100 + x) as usize] = f(x, y);
            }
        }
        d
    }

    #[test]
    fn the_stretched_patch_sharpens_a_dot_on_a_whole_lip() {
        // The lip at 600 mm all along; the dot's own reading 2 mm off is replaced.
        let lip = image(|_, y| if (36..=44).contains(&y) { 600 } else { 625 });
        let z = depth_of_dot_1(&lip, 0.602);
        assert!((z - 0.600).abs() < 1e-4, "{z}");
    }

    #[test]
    fn the_stretched_patch_past_the_lip_is_not_used() {
        // Only the paint's few millimetres of lip show; along the line either side is the
        // open mouth, 25 mm behind. The long patch reads the mouth; the dot keeps its own.
        let spot = image(|x, y| {
            if x.abs_diff(50) <= 2 && y.abs_diff(40) <= 3 {
                600
            } else {
                625
            }
        });
        let z = depth_of_dot_1(&spot, 0.600);
        assert!((z - 0.600).abs() < 1e-9, "{z}");
    }
}
