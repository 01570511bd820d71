//! One connected component's work: the box the components are searched in, the component's
//! colour weight over its pixels grown by one (for the sub-pixel centre), and the depth
//! around it.

use opencv::core::{self, Mat, MatTrait, MatTraitConst, MatTraitConstManual, MatTraitManual};

use mouthpiece_frame::DepthImage;

use crate::{DetectError, PixelRect};

/// The box holding `mask`'s non-zero pixels grown by one pixel, its corner moved to even
/// coordinates, cut to the mask; `None` for an empty mask.
pub(crate) fn mask_box(mask: &Mat) -> Result<Option<PixelRect>, DetectError> {
    let (w, h) = (mask.cols() as usize, mask.rows() as usize);
    if w == 0 || h == 0 {
        return Ok(None);
    }
    let data = mask.data_bytes()?;
    let (mut x_lo, mut x_hi, mut y_lo, mut y_hi) = (usize::MAX, 0, usize::MAX, 0);
    for (y, row) in data.chunks_exact(w).enumerate().take(h) {
        // Most rows are empty: test eight bytes at a time.
        let (words, rest) = row.split_at(w - w % 8);
        let empty = words
            .chunks_exact(8)
            .all(|c| u64::from_ne_bytes(c.try_into().expect("8 bytes")) == 0)
            && rest.iter().all(|&b| b == 0);
        if empty {
            continue;
        }
        let first = row.iter().position(|&b| b != 0).expect("a non-zero byte");
        let last = row.iter().rposition(|&b| b != 0).expect("a non-zero byte");
        x_lo = x_lo.min(first);
        x_hi = x_hi.max(last);
        y_lo = y_lo.min(y);
        y_hi = y_hi.max(y);
    }
    if y_lo == usize::MAX {
        return Ok(None);
    }
    let even = |v: usize| v.saturating_sub(1) & !1;
    let (x0, y0) = (even(x_lo), even(y_lo));
    let (x1, y1) = ((x_hi + 2).min(w), (y_hi + 2).min(h));
    Ok(Some(PixelRect {
        x: x0 as i32,
        y: y0 as i32,
        width: (x1 - x0) as i32,
        height: (y1 - y0) as i32,
    }))
}

/// The images one component's weight is read from.
pub(crate) struct ComponentImages<'a> {
    /// Connected-component labels over `crop` (region coordinates).
    pub(crate) labels: &'a Mat,
    pub(crate) crop: PixelRect,
    /// The region in HSV.
    pub(crate) hsv: &'a Mat,
    /// The opened mask over the region, when the class mask is opened.
    pub(crate) opened: Option<&'a Mat>,
    /// The class's weight table ([`crate::tables::weight_table`]).
    pub(crate) weights: &'a [u8],
}

/// Component `label`'s colour weight over `local` (region coordinates): the weight of each
/// pixel of the component grown by one pixel (a 3x3 dilation within `local`), 0 elsewhere,
/// into `out` (`local`'s size). Returns the sums of the component's own pixels' coordinates
/// in the region, or `None` when the opened mask keeps none of its pixels.
pub(crate) fn component_weight(
    images: ComponentImages,
    label: i32,
    local: PixelRect,
    grown: &mut Vec<bool>,
    out: &mut Mat,
) -> Result<Option<[u64; 2]>, DetectError> {
    let ComponentImages {
        labels,
        crop,
        hsv,
        opened,
        weights,
    } = images;
    let (w, h) = (local.width as usize, local.height as usize);
    let labels_w = labels.cols() as usize;
    let labels = labels.data_typed::<i32>()?;
    let hsv_w = hsv.cols() as usize;
    let hsv = hsv.data_bytes()?;
    let opened = opened.map(|m| m.data_bytes()).transpose()?;
    let (lx, ly) = ((local.x - crop.x) as usize, (local.y - crop.y) as usize);
    let is_label = |x: usize, y: usize| labels[(ly + y) * labels_w + lx + x] == label;
    grown.clear();
    grown.resize(w * h, false);
    let (mut sums, mut kept) = ([0u64; 2], false);
    for y in 0..h {
        for x in 0..w {
            if !is_label(x, y) {
                continue;
            }
            let (rx, ry) = (local.x as usize + x, local.y as usize + y);
            sums[0] += rx as u64;
            sums[1] += ry as u64;
            kept |= opened.is_none_or(|o| o[ry * hsv_w + rx] != 0);
            for gy in y.saturating_sub(1)..(y + 2).min(h) {
                for gx in x.saturating_sub(1)..(x + 2).min(w) {
                    grown[gy * w + gx] = true;
                }
            }
        }
    }
    if !kept {
        return Ok(None);
    }
    // SAFETY: every byte of the new matrix is written below before it is read.
    unsafe { out.create_rows_cols(h as i32, w as i32, core::CV_8UC1)? };
    let dst = out.data_bytes_mut()?;
    for y in 0..h {
        let row = (local.y as usize + y) * hsv_w + local.x as usize;
        for x in 0..w {
            dst[y * w + x] = if grown[y * w + x] {
                let p = 3 * (row + x);
                weights[hsv[p] as usize * 256 + hsv[p + 1] as usize]
            } else {
                0
            };
        }
    }
    Ok(Some(sums))
}

/// Median of the valid depth readings (metres, inside `range`) in `bbox` grown by `grow`.
pub(crate) fn median_depth_near(
    depth: &DepthImage,
    scale: f64,
    bbox: PixelRect,
    grow: i32,
    range: [f64; 2],
    buf: &mut Vec<u16>,
) -> Option<f64> {
    let r = PixelRect {
        x: bbox.x - grow,
        y: bbox.y - grow,
        width: bbox.width + 2 * grow,
        height: bbox.height + 2 * grow,
    }
    .clip(depth.width, depth.height)?;
    let lo = (range[0] / scale).floor().max(1.0) as u32;
    let hi = (range[1] / scale).ceil().min(u16::MAX as f64) as u32;
    buf.clear();
    let w = depth.width as usize;
    for y in r.y..r.y + r.height {
        let row =
            &depth.data[y as usize * w + r.x as usize..y as usize * w + (r.x + r.width) as usize];
        buf.extend(
            row.iter()
                .copied()
                .filter(|&v| (lo..=hi).contains(&(v as u32))),
        );
    }
    if buf.is_empty() {
        return None;
    }
    let mid = buf.len() / 2;
    let (_, m, _) = buf.select_nth_unstable(mid);
    Some(*m as f64 * scale)
}
