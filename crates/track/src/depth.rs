//! Depth at a dot: the median of the valid readings in a small disc around the centre (away
//! from the paint's rim, where colour and depth edges disagree), or, when the centre has too
//! few readings, a least-squares plane through the valid readings around it, evaluated at the
//! centre.

use mouthpiece_frame::DepthImage;
use nalgebra::{Matrix3, Vector3};

/// The median is taken over a disc of this share of the paint's radius: the paint's rim,
/// where the colour and depth edges disagree by a pixel or so, is left out (a round figure
/// from the first depth lookup, never retuned: the disc must still hold a few pixels for
/// paint 2 px across).
pub const INNER_DISC_SHARE: f64 = 0.6;
/// ... and never less than this radius, pixels: the centre pixel and its four neighbours.
pub const MIN_INNER_DISC_PX: f64 = 1.0;
/// The median needs at least this many readings (fewer is one pixel's word) ...
pub const MIN_MEDIAN_READINGS: usize = 3;
/// ... covering at least this share of the inner disc; below it the centre is mostly a hole
/// (the sensor's shadow or a flying edge), and a plane over the skin around the dot is fitted
/// instead.
pub const MIN_DISC_COVERAGE: f64 = 0.5;
/// That plane's radius, in paint radii: reaching past the paint onto the skin around it ...
pub const FALLBACK_PLANE_RADII: f64 = 2.5;
/// ... and at least this many pixels, so a small dot's fallback still spans a few rows.
pub const FALLBACK_PLANE_MIN_PX: f64 = 4.0;
/// Fewest readings a plane is fitted to: three parameters, each pinned by two readings, so
/// one flying pixel cannot tilt it alone.
pub const MIN_PLANE_READINGS: usize = 6;
/// Readings farther than this from the patch's median are another surface, metres: a lip's
/// curvature across a few pixels is far less, the step to the mouth's interior or the
/// background more (15 mm from the first lookup; unchanged since).
pub const OTHER_SURFACE_M: f64 = 0.015;
/// The second plane keeps readings within this many standard deviations of the first plane's
/// residuals (the usual three-sigma cut: 0.3 % of normal noise is dropped) ...
pub const RESIDUAL_SIGMAS: f64 = 3.0;
/// ... the standard deviation estimated as this many median absolute deviations (the
/// normal distribution's constant, 1 / Φ⁻¹(3/4)) ...
pub const SIGMA_PER_MAD: f64 = 1.4826;
/// ... and the cut never nearer than this, metres: the sensor's depth quantisation at face
/// distance, where a MAD of zero would otherwise keep only exact readings.
pub const MIN_RESIDUAL_CUT_M: f64 = 0.001;
/// Smallest valid raw depth reading: a raw 0 is the sensor's "no reading".
const MIN_VALID_RAW: f64 = 1.0;

/// Buffers the depth estimates work in, kept by the caller between dots and frames.
#[derive(Debug, Default)]
pub struct DepthScratch {
    samples: Vec<(f64, f64, f64)>,
    /// Values a median is selected from, as integer keys in the values' own order (raw
    /// readings; the bits of non-negative residuals): the selection then compares integers,
    /// not floats by `total_cmp`, and picks the same value.
    keys: Vec<u64>,
}

/// The upper median of `keys`, the `len / 2`-th smallest (reordered: those before it are the
/// smaller half).
fn upper_median(keys: &mut [u64]) -> u64 {
    let mid = keys.len() / 2;
    *keys.select_nth_unstable(mid).1
}

/// An order-keeping integer key of a raw reading (a whole number of depth units, as the
/// samples hold them).
fn raw_key(z: f64) -> u64 {
    z as u64
}

/// An order-keeping integer key of a non-negative float: for those, the IEEE bits order as
/// the values do.
fn magnitude_key(x: f64) -> u64 {
    debug_assert!(x >= 0.0);
    x.to_bits()
}

/// How a depth value was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DepthMethod {
    Median,
    PlaneFit,
}

/// Depth (metres) at sub-pixel `center` of a dot of `radius_px`; readings outside `range`
/// (metres) are ignored. `None` when there are too few readings to say.
pub fn depth_at_dot(
    depth: &DepthImage,
    scale: f64,
    center: [f64; 2],
    radius_px: f64,
    range: [f64; 2],
    scratch: &mut DepthScratch,
) -> Option<(f64, DepthMethod)> {
    let lo = (range[0] / scale).max(MIN_VALID_RAW);
    let hi = range[1] / scale;
    let inner = (INNER_DISC_SHARE * radius_px).max(MIN_INNER_DISC_PX);
    let DepthScratch { samples: buf, keys } = scratch;
    collect(depth, center, inner, lo, hi, buf);
    let disc_pixels = std::f64::consts::PI * inner * inner;
    if buf.len() >= MIN_MEDIAN_READINGS && buf.len() as f64 >= MIN_DISC_COVERAGE * disc_pixels {
        keys.clear();
        keys.extend(buf.iter().map(|s| raw_key(s.2)));
        let mid = keys.len() / 2;
        let upper = upper_median(keys) as f64;
        let median = if keys.len() % 2 == 1 {
            upper
        } else {
            let below = keys[..mid].iter().copied().max().expect("mid ≥ 1") as f64;
            (below + upper) / 2.0
        };
        return Some((median * scale, DepthMethod::Median));
    }
    depth_by_plane(
        depth,
        scale,
        center,
        (FALLBACK_PLANE_RADII * radius_px).max(FALLBACK_PLANE_MIN_PX),
        range,
        scratch,
    )
}

/// Depth (metres) at `center` from a least-squares plane through the valid readings within
/// `radius` pixels, after dropping readings far from their median (another surface behind or
/// in front, e.g. the mouth interior next to a lip dot). For smooth skin (the forehead) over
/// a wide radius this averages the sensor noise down far better than a median.
pub fn depth_by_plane(
    depth: &DepthImage,
    scale: f64,
    center: [f64; 2],
    radius: f64,
    range: [f64; 2],
    scratch: &mut DepthScratch,
) -> Option<(f64, DepthMethod)> {
    plane_over(depth, scale, center, radius, range, scratch, |_, _| true)
}

/// An elliptic patch: `half_len` pixels each way along the unit direction `along`,
/// `half_width` across it.
#[derive(Debug, Clone, Copy)]
pub struct Ellipse {
    pub along: [f64; 2],
    pub half_len: f64,
    pub half_width: f64,
}

/// As [`depth_by_plane`] over an ellipse instead of a disc. A lip is curved across and
/// nearly straight along its line, so a patch stretched along the lip averages more of the
/// sensor's noise for the same curvature bias.
pub fn depth_by_plane_along(
    depth: &DepthImage,
    scale: f64,
    center: [f64; 2],
    patch: Ellipse,
    range: [f64; 2],
    scratch: &mut DepthScratch,
) -> Option<(f64, DepthMethod)> {
    let Ellipse {
        along,
        half_len,
        half_width,
    } = patch;
    plane_over(depth, scale, center, half_len, range, scratch, |dx, dy| {
        let u = dx * along[0] + dy * along[1];
        let v = -dx * along[1] + dy * along[0];
        (u / half_len).powi(2) + (v / half_width).powi(2) <= 1.0
    })
}

/// The two-pass robust plane through the valid readings within `radius` of `center` that
/// `inside(dx, dy)` keeps, evaluated at the centre.
fn plane_over(
    depth: &DepthImage,
    scale: f64,
    center: [f64; 2],
    radius: f64,
    range: [f64; 2],
    scratch: &mut DepthScratch,
    inside: impl Fn(f64, f64) -> bool,
) -> Option<(f64, DepthMethod)> {
    let lo = (range[0] / scale).max(MIN_VALID_RAW);
    let hi = range[1] / scale;
    let DepthScratch { samples: buf, keys } = scratch;
    collect(depth, center, radius, lo, hi, buf);
    buf.retain(|&(dx, dy, _)| inside(dx, dy));
    if buf.len() < MIN_PLANE_READINGS {
        return None;
    }
    keys.clear();
    keys.extend(buf.iter().map(|s| raw_key(s.2)));
    let median = upper_median(keys) as f64;
    let tol = OTHER_SURFACE_M / scale;
    buf.retain(|s| (s.2 - median).abs() <= tol);
    if buf.len() < MIN_PLANE_READINGS {
        return None;
    }
    // Two passes: the plane through every kept reading, then again without the readings far
    // off that plane (the rim of the mouth opening, flying pixels at an edge).
    let first = fit_plane(buf)?;
    keys.clear();
    keys.extend(
        buf.iter()
            .map(|&s| magnitude_key((s.2 - first.dot(&lift(&s))).abs())),
    );
    let mad = f64::from_bits(upper_median(keys));
    let keep = (RESIDUAL_SIGMAS * SIGMA_PER_MAD * mad).max(MIN_RESIDUAL_CUT_M / scale);
    buf.retain(|&s| (s.2 - first.dot(&lift(&s))).abs() <= keep);
    if buf.len() < MIN_PLANE_READINGS {
        return None;
    }
    let z = fit_plane(buf)?[0];
    (z >= lo && z <= hi).then_some((z * scale, DepthMethod::PlaneFit))
}

fn lift(&(dx, dy, _): &(f64, f64, f64)) -> Vector3<f64> {
    Vector3::new(1.0, dx, dy)
}

/// Least-squares plane `z = c + a dx + b dy` as `(c, a, b)`; `None` for a degenerate spread
/// (all readings on one line).
fn fit_plane(samples: &[(f64, f64, f64)]) -> Option<Vector3<f64>> {
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for s in samples {
        let a = lift(s);
        ata += a * a.transpose();
        atb += a * s.2;
    }
    Some(ata.cholesky()?.solve(&atb))
}

/// Valid readings within `radius` of `center`, as (dx, dy, raw depth).
fn collect(
    depth: &DepthImage,
    center: [f64; 2],
    radius: f64,
    lo: f64,
    hi: f64,
    buf: &mut Vec<(f64, f64, f64)>,
) {
    buf.clear();
    let x0 = ((center[0] - radius).floor().max(0.0)) as i64;
    let y0 = ((center[1] - radius).floor().max(0.0)) as i64;
    let x1 = ((center[0] + radius).ceil() as i64).min(depth.width as i64 - 1);
    let y1 = ((center[1] + radius).ceil() as i64).min(depth.height as i64 - 1);
    let r2 = radius * radius;
    for y in y0..=y1 {
        let dy = y as f64 - center[1];
        let row = y as usize * depth.width as usize;
        for x in x0..=x1 {
            let dx = x as f64 - center[0];
            if dx * dx + dy * dy > r2 {
                continue;
            }
            let v = depth.data[row + x as usize] as f64;
            if v >= lo && v <= hi {
                buf.push((dx, dy, v));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(w: u32, h: u32, f: impl Fn(f64, f64) -> f64) -> DepthImage {
        let mut d = DepthImage::new(w, h);
        for y in 0..h {
            for x in 0..w {
                d.data[(y * w + x) as usize] = f(x as f64, y as f64).round() as u16;
            }
        }
        d
    }

    #[test]
    fn median_ignores_a_few_outliers() {
        let mut d = plane(40, 40, |_, _| 600.0);
        d.data[20 * 40 + 20] = 900; // a flying pixel at the centre
        let mut buf = DepthScratch::default();
        let (z, how) = depth_at_dot(&d, 0.001, [20.2, 19.8], 2.5, [0.2, 2.0], &mut buf).unwrap();
        assert_eq!(how, DepthMethod::Median);
        assert!((z - 0.6).abs() < 1e-9, "{z}");
    }

    #[test]
    fn plane_fit_fills_a_hole_at_the_centre() {
        // A tilted surface z = 600 + 2 (x - 20) + 1 (y - 20) mm with a hole over the dot.
        let mut d = plane(40, 40, |x, y| 600.0 + 2.0 * (x - 20.0) + (y - 20.0));
        for y in 17..=23 {
            for x in 17..=23 {
                if (x as f64 - 20.0).powi(2) + (y as f64 - 20.0).powi(2) <= 4.0 {
                    d.data[y * 40 + x] = 0;
                }
            }
        }
        let mut buf = DepthScratch::default();
        let (z, how) = depth_at_dot(&d, 0.001, [20.0, 20.0], 2.0, [0.2, 2.0], &mut buf).unwrap();
        assert_eq!(how, DepthMethod::PlaneFit);
        assert!((z - 0.6).abs() < 0.0005, "{z}");
    }

    #[test]
    fn plane_fit_on_a_lip_ignores_the_open_mouth_behind_it() {
        // A lower lip at 600 mm tilting 1 mm per pixel, the open mouth 25 mm behind it above
        // row 18: the dot at row 20 sits near the lip's edge.
        let d = plane(
            40,
            40,
            |_, y| {
                if y < 18.0 {
                    625.0
                } else {
                    600.0 + (y - 20.0)
                }
            },
        );
        let mut buf = DepthScratch::default();
        let (z, how) = depth_by_plane(&d, 0.001, [20.0, 20.0], 3.0, [0.2, 2.0], &mut buf).unwrap();
        assert_eq!(how, DepthMethod::PlaneFit);
        assert!((z - 0.6).abs() < 0.0005, "{z}");
    }

    #[test]
    fn a_patch_stretched_along_a_lip_averages_more_noise_than_a_disc() {
        // A lip along x at row 40: curved across (radius 6 mm, 1.14 mm per pixel), straight
        // along; sensor noise correlated over 4 px, as a structured-light sensor's
        // correlation windows.
        let node = |i: u64, j: u64| {
            // splitmix64 of the node's index: uniform in [-1, 1], σ ≈ 0.58.
            let mut z = (i * 1000 + j).wrapping_add(0x9e37_79b9_7f4a_7c15);
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            z ^= z >> 31;
            (z >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        // Nodes every 4 px, bilinear between them; about 1.5 mm RMS.
        let cell = |x: f64, y: f64| {
            let (i, j) = ((x / 4.0) as u64, (y / 4.0) as u64);
            let (fx, fy) = (x / 4.0 - i as f64, y / 4.0 - j as f64);
            let top = node(i, j) * (1.0 - fx) + node(i + 1, j) * fx;
            let bottom = node(i, j + 1) * (1.0 - fx) + node(i + 1, j + 1) * fx;
            3.0 * (top * (1.0 - fy) + bottom * fy)
        };
        let d = plane(200, 80, |x, y| {
            let across_mm = (y - 40.0) * 1.14;
            600.0 + across_mm * across_mm / 12.0 + cell(x, y)
        });
        let mut buf = DepthScratch::default();
        let (mut disc_sq, mut wide_sq, mut along_sq) = (0.0, 0.0, 0.0);
        let centres: Vec<f64> = (0..40)
            .map(|i| 20.0 + 4.0 * i as f64 + 0.37 * (i % 3) as f64)
            .collect();
        for &x in &centres {
            let (z, _) = depth_by_plane(&d, 0.001, [x, 40.0], 3.0, [0.2, 2.0], &mut buf).unwrap();
            disc_sq += (z - 0.6).powi(2);
            // A disc of the stretched patch's area: more noise averaged, but the lip's
            // curvature across puts its plane behind the lip.
            let (z, _) = depth_by_plane(&d, 0.001, [x, 40.0], 3.6, [0.2, 2.0], &mut buf).unwrap();
            wide_sq += (z - 0.6).powi(2);
            let patch = Ellipse {
                along: [1.0, 0.0],
                half_len: 8.0,
                half_width: 1.6,
            };
            let (z, _) =
                depth_by_plane_along(&d, 0.001, [x, 40.0], patch, [0.2, 2.0], &mut buf).unwrap();
            along_sq += (z - 0.6).powi(2);
        }
        let n = centres.len() as f64;
        let rms = |sq: f64| (sq / n).sqrt() * 1e3;
        let (disc, wide, along) = (rms(disc_sq), rms(wide_sq), rms(along_sq));
        let figures =
            format!("along the lip {along:.2} mm, disc {disc:.2} mm, wide disc {wide:.2} mm");
        assert!(along < 0.85 * disc && along < 0.9 * wide, "{figures}");
    }

    #[test]
    fn no_readings_no_depth() {
        let d = DepthImage::new(40, 40);
        let mut buf = DepthScratch::default();
        assert!(depth_at_dot(&d, 0.001, [20.0, 20.0], 2.0, [0.2, 2.0], &mut buf).is_none());
    }

    #[test]
    fn readings_at_the_image_edge_do_not_panic() {
        let d = plane(10, 10, |_, _| 500.0);
        let mut buf = DepthScratch::default();
        assert!(depth_at_dot(&d, 0.001, [0.0, 9.0], 3.0, [0.2, 2.0], &mut buf).is_some());
    }
}
