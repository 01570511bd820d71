//! Hue-circle arithmetic (differences, circular mean and spread, hue ranges and sets) and
//! the small percentile and median helpers.

use std::f64::consts::PI;

pub(super) fn percentile_u8(hist: &[u64; 256], q: f64) -> u8 {
    let total: u64 = hist.iter().sum();
    if total == 0 {
        return 0;
    }
    let target = (total as f64 * q).ceil().max(1.0) as u64;
    let mut acc = 0;
    for (v, &c) in hist.iter().enumerate() {
        acc += c;
        if acc >= target {
            return v as u8;
        }
    }
    255
}

pub(super) fn median_u8(values: &[u8]) -> Option<u8> {
    let mut v = values.to_vec();
    v.sort_unstable();
    v.get(v.len() / 2).copied()
}

/// Signed hue difference `a - b` on the 180-unit circle, in (-90, 90].
pub(super) fn hue_diff(a: f64, b: f64) -> f64 {
    let mut d = (a - b) % 180.0;
    if d > 90.0 {
        d -= 180.0;
    } else if d <= -90.0 {
        d += 180.0;
    }
    d
}

/// Circular mean of hues (0–180 scale).
pub(super) fn circular_mean(hues: impl Iterator<Item = f64>) -> f64 {
    circular_stats(hues).0
}

/// Circular mean and standard deviation of hues (0–180 scale, hue units).
pub(super) fn circular_stats(hues: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut s, mut c, mut n) = (0.0f64, 0.0f64, 0.0f64);
    for h in hues {
        let a = h * PI / 90.0;
        s += a.sin();
        c += a.cos();
        n += 1.0;
    }
    let r = (s.hypot(c) / n.max(1.0)).clamp(1e-12, 1.0);
    (
        (s.atan2(c) * 90.0 / PI).rem_euclid(180.0),
        (-2.0 * r.ln()).sqrt() * 90.0 / PI,
    )
}

pub(super) fn median_f64(v: &[f64]) -> Option<f64> {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied()
}

/// `[lo, hi]` on the hue circle (may run below 0 or above 179) as OpenCV ranges: one, or
/// two when it wraps around red (`[[0, hi], [lo, 179]]`).
pub fn hue_ranges(lo: i32, hi: i32) -> Vec<[u8; 2]> {
    if hi - lo >= 179 {
        return vec![[0, 179]];
    }
    let (lo, hi) = if hi > 179 {
        (lo - 180, hi - 180)
    } else {
        (lo, hi)
    };
    if lo < 0 {
        vec![[0, hi as u8], [(lo + 180) as u8, 179]]
    } else {
        vec![[lo as u8, hi as u8]]
    }
}

/// Hue units of `ranges` (a set on the circle).
pub(super) fn hue_set(ranges: &[[u8; 2]]) -> [bool; 180] {
    let mut set = [false; 180];
    for [lo, hi] in ranges {
        for h in *lo..=(*hi).min(179) {
            set[h as usize] = true;
        }
    }
    set
}

/// A hue set back to ranges (a run through 179→0 becomes two).
pub(super) fn set_to_ranges(set: &[bool; 180]) -> Vec<[u8; 2]> {
    let mut out = Vec::new();
    let mut h = 0;
    while h < 180 {
        if set[h] {
            let start = h;
            while h + 1 < 180 && set[h + 1] {
                h += 1;
            }
            out.push([start as u8, h as u8]);
        }
        h += 1;
    }
    out
}
