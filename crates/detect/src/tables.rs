//! The colour lookup tables: every class's HSV thresholds as bit tables (the mask), and each
//! class's colour weight per hue and saturation (the sub-pixel centre's weights).

use opencv::core::{self, Mat, MatTraitConst, MatTraitConstManual, MatTraitManual, Scalar};

use crate::{config, ColorClass, DetectError};

/// Every class's colour thresholds as bit tables: one bit per (class, hue range) pair, set in
/// `hue[h]` when `h` is within that hue range, in `saturation[s]` and `value[v]` when they are
/// within the class's. A pixel is in a class's hue range exactly when the three entries of its
/// H, S and V share that bit: OpenCV's `inRange` (bounds included) of every range of every
/// class, ORed per class, in one pass over the region instead of one `inRange` per range, and
/// three table reads per pixel instead of six comparisons per range.
#[derive(Debug, Clone)]
pub(crate) struct RangeBits {
    hue: [u32; 256],
    saturation: [u32; 256],
    value: [u32; 256],
    /// Per class, the bits of its hue ranges.
    class: Vec<u32>,
}

impl RangeBits {
    /// `classes` as validated ([`config::MAX_HUE_RANGES`] ranges at most).
    pub(crate) fn new(classes: &[ColorClass]) -> Self {
        const _: () = assert!(config::MAX_HUE_RANGES <= u32::BITS as usize);
        let mut bits = Self {
            hue: [0; 256],
            saturation: [0; 256],
            value: [0; 256],
            class: Vec::with_capacity(classes.len()),
        };
        // Bounds included, as `inRange`'s; an inverted range marks nothing.
        let mark = |table: &mut [u32; 256], [lo, hi]: [u8; 2], bit: u32| {
            for entry in &mut table[lo as usize..=hi as usize] {
                *entry |= bit;
            }
        };
        let mut next = 0;
        for class in classes {
            let mut class_bits = 0;
            for &hue in &class.hue {
                let bit = 1u32 << next;
                next += 1;
                class_bits |= bit;
                mark(&mut bits.hue, hue, bit);
                mark(&mut bits.saturation, class.saturation, bit);
                mark(&mut bits.value, class.value, bit);
            }
            bits.class.push(class_bits);
        }
        bits
    }

    /// Each pixel's bits, from the region's HSV bytes.
    pub(crate) fn classify(&self, hsv: &[u8], out: &mut Vec<u32>) {
        out.clear();
        out.extend(hsv.chunks_exact(3).map(|p| {
            self.hue[p[0] as usize] & self.saturation[p[1] as usize] & self.value[p[2] as usize]
        }));
    }

    /// Class `class_idx`'s mask (255 inside, 0 outside) from the pixels' bits.
    pub(crate) fn class_mask(&self, class_idx: usize, pixel_bits: &[u32], mask: &mut [u8]) {
        let class = self.class[class_idx];
        for (m, &b) in mask.iter_mut().zip(pixel_bits) {
            *m = if b & class != 0 { 255 } else { 0 };
        }
    }
}

/// A class's colour weight per hue and saturation, `[hue * 256 + saturation]`: the hue
/// weight times the saturation weight over 255, computed by OpenCV's `LUT` and `multiply`
/// (as the per-pixel weight image once was), so each value is OpenCV's to the bit.
pub(crate) fn weight_table(hue: &[u8; 256], sat: &[u8; 256]) -> Result<Vec<u8>, DetectError> {
    let mut hues = Mat::new_rows_cols_with_default(256, 256, core::CV_8UC1, Scalar::all(0.0))?;
    let mut sats = hues.try_clone()?;
    for (i, (h_row, s_row)) in hues
        .data_bytes_mut()?
        .chunks_exact_mut(256)
        .zip(sats.data_bytes_mut()?.chunks_exact_mut(256))
        .enumerate()
    {
        h_row.fill(i as u8);
        for (j, s) in s_row.iter_mut().enumerate() {
            *s = j as u8;
        }
    }
    let (mut hue_w, mut sat_w, mut weight) = (Mat::default(), Mat::default(), Mat::default());
    core::lut(&hues, &Mat::from_slice(hue)?, &mut hue_w)?;
    core::lut(&sats, &Mat::from_slice(sat)?, &mut sat_w)?;
    core::multiply(&hue_w, &sat_w, &mut weight, 1.0 / 255.0, -1)?;
    Ok(weight.data_bytes()?.to_vec())
}

/// Hue → weight: 255 over the inner half of each range, falling linearly to 0 at `margin`
/// hue units beyond its ends (the hue circle wraps at 180).
pub(crate) fn hue_weight_table(ranges: &[[u8; 2]], margin: u8) -> [u8; 256] {
    let mut table = [0u8; 256];
    for (h, slot) in table.iter_mut().enumerate().take(180) {
        let mut best = 0.0f64;
        for &[lo, hi] in ranges {
            let (lo, hi) = (lo as f64, hi.min(179) as f64);
            let centre = (lo + hi) / 2.0;
            let core_half = (hi - lo) / 4.0;
            let outer_half = (hi - lo) / 2.0 + margin as f64;
            let d = {
                let d = (h as f64 - centre).abs();
                d.min(180.0 - d)
            };
            let w = if d <= core_half {
                1.0
            } else if d >= outer_half {
                0.0
            } else {
                1.0 - (d - core_half) / (outer_half - core_half)
            };
            best = best.max(w);
        }
        *slot = (best * 255.0).round() as u8;
    }
    table
}

/// Saturation → weight: 0 at half the class's minimum, 255 at the minimum and above (a paint
/// pixel mixed with skin loses saturation).
pub(crate) fn saturation_weight_table([lo, _hi]: [u8; 2]) -> [u8; 256] {
    let mut table = [0u8; 256];
    let start = lo as f64 / 2.0;
    let end = (lo as f64).max(start + 1.0);
    for (s, slot) in table.iter_mut().enumerate() {
        let w = ((s as f64 - start) / (end - start)).clamp(0.0, 1.0);
        *slot = (w * 255.0).round() as u8;
    }
    table
}
