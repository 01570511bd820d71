//! Deformation parameters `M_n` (docs/method.md §5): how far each character point moves per unit
//! of its performer dot's motion, per axis.

use serde::Deserialize;

use crate::Vec3;

/// How the deformation parameters `M` are chosen (docs/method.md §5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MMode {
    /// Per point and axis `P/D` where that is safe, the axis extent ratio otherwise.
    #[default]
    PerPoint,
    /// Every point uses the axis extent ratios.
    PerAxis,
    /// Values given in the file's `[m]` table.
    Manual,
}

impl MMode {
    /// The spelling of a character file's `m_mode` (kebab-case), which `hello` repeats.
    pub fn name(self) -> &'static str {
        match self {
            MMode::PerPoint => "per-point",
            MMode::PerAxis => "per-axis",
            MMode::Manual => "manual",
        }
    }
}

/// Bounds for a per-point ratio `P/D`.
pub const M_MIN: f64 = 0.05;
/// Upper bound for a per-point ratio `P/D`.
pub const M_MAX: f64 = 20.0;

/// Max − min along each axis.
pub fn extent(points: &[Vec3]) -> Vec3 {
    let mut lo = Vec3::repeat(f64::INFINITY);
    let mut hi = Vec3::repeat(f64::NEG_INFINITY);
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    hi - lo
}

/// The per-axis fallback ratios `f_k = E_char_k / E_perf_k`, with the width ratio where the
/// performer barely extends along an axis (`E_perf_k < eps`) or the character not at all.
pub fn fallback(perf_neutral: &[Vec3], char_neutral: &[Vec3], eps: f64) -> Vec3 {
    let e_perf = extent(perf_neutral);
    let e_char = extent(char_neutral);
    let width_ratio = e_char.x / e_perf.x;
    Vec3::from_fn(|k, _| {
        if e_perf[k] < eps || e_char[k] == 0.0 {
            width_ratio
        } else {
            e_char[k] / e_perf[k]
        }
    })
}

/// `M` for every character point, in point order.
///
/// * `perf_neutral`: `D⁰` per performer lip dot, performer mouth frame (metres).
/// * `char_neutral`: `P⁰` per character point, character mouth frame.
/// * `driver[n]`: the lip dot that drives point `n`.
/// * `perf_width`: the performer's neutral mouth width (corner to corner).
/// * `manual`: the values for `MMode::Manual` (ignored otherwise).
pub fn deformation(
    mode: MMode,
    perf_neutral: &[Vec3],
    char_neutral: &[Vec3],
    driver: &[usize],
    perf_width: f64,
    manual: Option<&[Vec3]>,
) -> Vec<Vec3> {
    if mode == MMode::Manual {
        if let Some(m) = manual {
            return m.to_vec();
        }
    }
    let eps = 0.02 * perf_width;
    let f = fallback(perf_neutral, char_neutral, eps);
    char_neutral
        .iter()
        .zip(driver)
        .map(|(p, &d)| match mode {
            MMode::PerAxis | MMode::Manual => f,
            MMode::PerPoint => {
                let dn = perf_neutral[d];
                Vec3::from_fn(|k, _| {
                    let (dk, pk) = (dn[k], p[k]);
                    if dk.abs() >= eps && pk != 0.0 && pk.signum() == dk.signum() {
                        (pk / dk).clamp(M_MIN, M_MAX)
                    } else {
                        f[k]
                    }
                })
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// A performer mouth 50 mm wide, 20 mm tall, 10 mm deep; a character twice as wide, three
    /// times as tall, four times as deep.
    fn mouths() -> (Vec<Vec3>, Vec<Vec3>) {
        let perf = vec![
            Vec3::new(0.025, 0.0, 0.0),  // left corner
            Vec3::new(0.0, 0.01, 0.01),  // upper middle
            Vec3::new(-0.025, 0.0, 0.0), // right corner
            Vec3::new(0.0, -0.01, 0.0),  // lower middle
        ];
        let chr = vec![
            Vec3::new(0.05, 0.0, 0.0),
            Vec3::new(0.0, 0.03, 0.04),
            Vec3::new(-0.05, 0.0, 0.0),
            Vec3::new(0.0, -0.03, 0.0),
        ];
        (perf, chr)
    }

    #[test]
    fn corners_use_the_fallback_on_y_and_z() {
        let (perf, chr) = mouths();
        let m = deformation(MMode::PerPoint, &perf, &chr, &[0, 1, 2, 3], 0.05, None);
        // Corner x: same sign, |D| ≥ eps → ratio 0.05/0.025 = 2.
        assert_relative_eq!(m[0].x, 2.0);
        // Corner y, z: D = 0 → fallback E_char/E_perf: y 0.06/0.02 = 3, z 0.04/0.01 = 4.
        assert_relative_eq!(m[0].y, 3.0, epsilon = 1e-12);
        assert_relative_eq!(m[0].z, 4.0, epsilon = 1e-12);
        // Upper middle: x = 0 → fallback x = 2; y ratio 3; z ratio 4.
        assert_relative_eq!(m[1], Vec3::new(2.0, 3.0, 4.0), epsilon = 1e-12);
    }

    #[test]
    fn opposite_signs_use_the_fallback() {
        let (perf, mut chr) = mouths();
        chr[1].y = -0.03; // the character's "upper" point sits below the corner line
        chr[3].y = 0.03;
        let m = deformation(MMode::PerPoint, &perf, &chr, &[0, 1, 2, 3], 0.05, None);
        assert_relative_eq!(m[1].y, 3.0, epsilon = 1e-12);
        assert_relative_eq!(m[3].y, 3.0, epsilon = 1e-12);
    }

    #[test]
    fn ratios_are_clamped() {
        let (perf, mut chr) = mouths();
        chr[1].y = 0.5; // ratio 50 → 20
        chr[3].y = -0.0001; // ratio 0.01 → 0.05
        let m = deformation(MMode::PerPoint, &perf, &chr, &[0, 1, 2, 3], 0.05, None);
        assert_relative_eq!(m[1].y, M_MAX);
        assert_relative_eq!(m[3].y, M_MIN);
    }

    #[test]
    fn flat_performer_axis_falls_back_to_width_ratio() {
        let (mut perf, chr) = mouths();
        perf[1].z = 0.0005; // E_perf_z = 0.5 mm < eps = 1 mm
        let m = deformation(MMode::PerAxis, &perf, &chr, &[0, 1, 2, 3], 0.05, None);
        assert_relative_eq!(m[2].z, 2.0, epsilon = 1e-12);
        // A point whose |D_z| < eps also falls back, to the width ratio now.
        let m = deformation(MMode::PerPoint, &perf, &chr, &[0, 1, 2, 3], 0.05, None);
        assert_relative_eq!(m[1].z, 2.0, epsilon = 1e-12);
    }

    #[test]
    fn driver_permutes_the_performer_dots() {
        let (perf, chr) = mouths();
        // Point 0 driven by dot 2 (the right corner): x signs differ → fallback 2 anyway,
        // point 1 driven by dot 3 (lower middle, y < 0) while P_y > 0 → fallback 3.
        let m = deformation(MMode::PerPoint, &perf, &chr, &[2, 3, 0, 1], 0.05, None);
        assert_relative_eq!(m[1].y, 3.0, epsilon = 1e-12);
        assert_relative_eq!(m[0].x, 2.0, epsilon = 1e-12);
    }
}
