//! A character's mouth points: their names and order, and points read as a contour
//! resampled along its length.

use super::*;

/// Largest `points_per_lip`: the two lips then hold [`crate::layout::MAX_DOT_NUMBER`] points.
pub const MAX_POINTS_PER_LIP: usize = crate::layout::MAX_DOT_NUMBER.div_ceil(2);
/// `k - 1` for a point named `Pk` with `1 <= k <= n`.
pub(super) fn point_number(name: &str, n: usize) -> Option<usize> {
    let digits = name.strip_prefix('P')?;
    if digits.starts_with('0') || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let k: usize = digits.parse().ok()?;
    (1..=n).contains(&k).then(|| k - 1)
}

/// When the names are exactly `P1..PN` (in any order), the file's indices in name order: the
/// points' order around the mouth (and with it the corners and the default map `Dk -> Pk`)
/// follows the names, never the file's order. `None` when the names are anything else.
pub(super) fn order_by_name(names: &[String]) -> Option<Vec<usize>> {
    let n = names.len();
    let mut order = vec![usize::MAX; n];
    for (i, name) in names.iter().enumerate() {
        let k = point_number(name, n)?;
        if order[k] != usize::MAX {
            return None;
        }
        order[k] = i;
    }
    Some(order)
}

/// Places `points_per_lip` points (corners included) at equal arc length along each contour
/// and orders them like the performer's dots: left corner, upper lip left to right, right
/// corner, lower lip right to left.
pub(super) fn contour_points(
    c: &Checker<'_>,
    contour: &Spanned<RawContour>,
) -> Result<Vec<Vec3>, Error> {
    let contour = contour.get_ref();
    let k = *contour.points_per_lip.get_ref();
    if k < 3 {
        return Err(c.err(
            "contour.points_per_lip",
            Some(contour.points_per_lip.span()),
            format!("must be at least 3 (two corners and one lip point), got {k}"),
        ));
    }
    if k > MAX_POINTS_PER_LIP {
        return Err(c.err(
            "contour.points_per_lip",
            Some(contour.points_per_lip.span()),
            format!(
                "must be at most {MAX_POINTS_PER_LIP} (dots are named up to D{}), got {k}",
                crate::layout::MAX_DOT_NUMBER
            ),
        ));
    }
    let polyline = |key: &str, line: &Spanned<Vec<[f64; 3]>>| -> Result<Vec<Vec3>, Error> {
        let pts = line.get_ref();
        if pts.len() < 2 {
            return Err(c.err(
                key,
                Some(line.span()),
                "needs at least 2 points, corner to corner",
            ));
        }
        let mut out = Vec::with_capacity(pts.len());
        for a in pts {
            if !a.iter().all(|v| v.is_finite()) {
                return Err(c.err(
                    key,
                    Some(line.span()),
                    format!("non-finite number in {a:?}"),
                ));
            }
            if !crate::layout::coordinates_in_range(a) {
                return Err(c.err(
                    key,
                    Some(line.span()),
                    format!(
                        "coordinate beyond {} in {a:?}",
                        crate::layout::MAX_COORDINATE
                    ),
                ));
            }
            out.push(Vec3::new(a[0], a[1], a[2]));
        }
        Ok(out)
    };
    let upper = polyline("contour.upper", &contour.upper)?;
    let lower = polyline("contour.lower", &contour.lower)?;
    let scale = upper
        .iter()
        .chain(&lower)
        .map(|p| p.norm())
        .fold(1.0, f64::max);
    let same = |a: &Vec3, b: &Vec3| (a - b).norm() <= 1e-9 * scale;
    if !same(&upper[0], &lower[0]) || !same(upper.last().unwrap(), lower.last().unwrap()) {
        return Err(c.err(
            "contour.lower",
            Some(contour.lower.span()),
            "must start and end where contour.upper does (left corner first, right corner last)",
        ));
    }
    let up = resample(&upper, k).ok_or_else(|| {
        c.err(
            "contour.upper",
            Some(contour.upper.span()),
            "has zero length",
        )
    })?;
    let low = resample(&lower, k).ok_or_else(|| {
        c.err(
            "contour.lower",
            Some(contour.lower.span()),
            "has zero length",
        )
    })?;
    let mut out = up;
    out.extend(low[1..k - 1].iter().rev());
    Ok(out)
}

/// `count` points at equal arc-length intervals along a polyline, both ends included.
/// `None` for a polyline of zero length.
pub fn resample(polyline: &[Vec3], count: usize) -> Option<Vec<Vec3>> {
    let mut cumulative = Vec::with_capacity(polyline.len());
    cumulative.push(0.0);
    for w in polyline.windows(2) {
        cumulative.push(cumulative.last().unwrap() + (w[1] - w[0]).norm());
    }
    let total = *cumulative.last().unwrap();
    if total.is_nan() || total <= 0.0 || count < 2 {
        return None;
    }
    let mut out = Vec::with_capacity(count);
    let mut seg = 0;
    for i in 0..count {
        let s = total * i as f64 / (count - 1) as f64;
        while seg + 2 < cumulative.len() && cumulative[seg + 1] < s {
            seg += 1;
        }
        let len = cumulative[seg + 1] - cumulative[seg];
        let u = if len > 0.0 {
            ((s - cumulative[seg]) / len).clamp(0.0, 1.0)
        } else {
            0.0
        };
        out.push(polyline[seg] + (polyline[seg + 1] - polyline[seg]) * u);
    }
    *out.last_mut().unwrap() = *polyline.last().unwrap();
    Some(out)
}
