//! Sampling frames: the saturated, compact, one-hue blobs of each frame (after the depth
//! cut and the face's saturation threshold), their pixels, and the face's hue x saturation
//! histogram.

use std::f64::consts::PI;

use opencv::core::{self, Mat, MatTraitConst, MatTraitConstManual, Vec3b};
use opencv::imgproc;

use mouthpiece_frame::{ColorImage, DepthImage};

use super::hue::{circular_mean, circular_stats, hue_diff, median_u8, percentile_u8};
use super::TuneOptions;
use crate::{DetectError, PixelRect};

/// One blob of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct SampledBlob {
    /// Index of the frame among those added.
    pub frame: u32,
    pub center: [f64; 2],
    pub area: u32,
    pub bbox: PixelRect,
    /// Circular mean hue of its pixels (0–180, OpenCV scale).
    pub hue: f64,
    /// Where its pixels start in the sampler's pixel store.
    pub(super) pixels: std::ops::Range<usize>,
}

/// What one frame gave.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameSample {
    pub blobs: usize,
    /// The performer's nearest surface (metres), when the frame had usable depth.
    pub performer_m: Option<f64>,
    /// The saturation threshold used for this frame.
    pub saturation_threshold: u8,
}

/// Collects blobs frame by frame.
pub struct ColourSampler {
    pub(super) options: TuneOptions,
    pub(super) frames: u32,
    pub(super) blobs: Vec<SampledBlob>,
    /// (hue, saturation, value) of every blob pixel.
    pub(super) pixels: Vec<[u8; 3]>,
    pub(super) performer_m: Vec<f64>,
    pub(super) thresholds: Vec<u8>,
    /// Hue x saturation histogram (180 x 256) of the foreground away from the blobs: the
    /// skin, lips and mouth a class's ranges must leave out.
    pub(super) face_hist: Vec<u64>,
    pub(super) face_pixels: u64,
    /// Frames kept to check a proposal on (`propose_checked`).
    pub(super) kept: super::check::KeptFrames,
    hsv: Mat,
    labels: Mat,
    stats: Mat,
    centroids: Mat,
}

impl std::fmt::Debug for ColourSampler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ColourSampler")
            .field("frames", &self.frames)
            .field("blobs", &self.blobs.len())
            .finish_non_exhaustive()
    }
}

impl ColourSampler {
    pub fn new(options: TuneOptions) -> Self {
        Self {
            options,
            frames: 0,
            blobs: Vec::new(),
            pixels: Vec::new(),
            performer_m: Vec::new(),
            thresholds: Vec::new(),
            face_hist: vec![0; 180 * 256],
            face_pixels: 0,
            kept: Default::default(),
            hsv: Mat::default(),
            labels: Mat::default(),
            stats: Mat::default(),
            centroids: Mat::default(),
        }
    }

    pub fn frames(&self) -> u32 {
        self.frames
    }

    pub fn blobs(&self) -> &[SampledBlob] {
        &self.blobs
    }

    /// (hue, saturation, value) of a blob's pixels.
    pub fn pixels(&self, blob: &SampledBlob) -> &[[u8; 3]] {
        &self.pixels[blob.pixels.clone()]
    }

    /// Samples one frame. `depth` must be on the colour grid (registered), in units of the
    /// given metres; without it (or when it shows no performer) the whole image is searched
    /// and the blob size bound assumes the nearest plausible distance.
    pub fn add_frame(
        &mut self,
        color: &ColorImage,
        depth: Option<(&DepthImage, f64)>,
        fx: f64,
    ) -> Result<FrameSample, DetectError> {
        let (w, h) = (color.width as usize, color.height as usize);
        if color.data.len() != w * h * 3 {
            return Err(DetectError::ImageSize(format!(
                "colour image {}x{} holds {} bytes, expected {}",
                color.width,
                color.height,
                color.data.len(),
                w * h * 3
            )));
        }
        if let Some((d, _)) = depth {
            if d.width != color.width || d.height != color.height {
                return Err(DetectError::ImageSize(format!(
                    "depth {}x{} is not on the colour grid {}x{}",
                    d.width, d.height, color.width, color.height
                )));
            }
        }
        self.kept.offer(color, depth, fx);
        let opts = &self.options;
        let frame_idx = self.frames;
        self.frames += 1;

        let image = Mat::new_rows_cols_with_bytes::<Vec3b>(h as i32, w as i32, &color.data)?;
        imgproc::cvt_color_def(&image, &mut self.hsv, imgproc::COLOR_BGR2HSV)?;
        let hsv = self.hsv.data_bytes()?;

        // Foreground: the performer's surface and what is up to `depth_window_m` behind it.
        let performer = depth.and_then(|(d, scale)| {
            performer_distance(d, scale, opts.depth_range_m, 0.015).map(|z| (d, scale, z))
        });
        let foreground = |i: usize| match performer {
            Some((d, scale, z)) => {
                let v = d.data[i];
                v != 0 && (v as f64 * scale) <= z + opts.depth_window_m
            }
            None => true,
        };
        if let Some((_, _, z)) = performer {
            self.performer_m.push(z);
        }

        let fg: Vec<bool> = (0..w * h)
            .map(|i| hsv[3 * i + 2] >= opts.min_value && foreground(i))
            .collect();
        let z_blob = performer
            .map(|(_, _, z)| z)
            .unwrap_or(opts.depth_range_m[0]);
        // Nothing painted as a dot is wider than a 15 mm radius disc.
        let max_area = PI * (0.015 * fx / z_blob.max(0.05)).powi(2);

        // The face's own saturation (skin, lips, mouth) must stay below the blob threshold.
        // Two passes: blobs found above the face's 95th percentile are left out of the
        // face's histogram, so paint covering more than a few per mille of the face (a
        // close-up) does not lift the threshold above itself.
        let face_hist = |exclude: &[bool]| {
            let mut hist = [0u64; 256];
            for i in 0..w * h {
                if fg[i] && !exclude[i] {
                    hist[hsv[3 * i + 1] as usize] += 1;
                }
            }
            hist
        };
        let threshold_above = |level: u8| {
            opts.min_saturation
                .max(level.saturating_add(opts.saturation_above_face))
        };
        let mut excluded = vec![false; w * h];
        let first = threshold_above(percentile_u8(&face_hist(&excluded), 0.95));
        let blobs = compact_blobs(
            hsv,
            &fg,
            (w, h),
            first,
            max_area,
            opts,
            &mut self.labels,
            &mut self.stats,
            &mut self.centroids,
        )?;
        for b in &blobs {
            mark_box(&mut excluded, (w, h), b.bbox, 1);
        }
        let threshold = threshold_above(percentile_u8(&face_hist(&excluded), 0.995));
        self.thresholds.push(threshold);
        let blobs = compact_blobs(
            hsv,
            &fg,
            (w, h),
            threshold,
            max_area,
            opts,
            &mut self.labels,
            &mut self.stats,
            &mut self.centroids,
        )?;
        let labels = self.labels.data_typed::<i32>()?;
        let mut found = 0;
        // What is not paint: the foreground outside every candidate's box grown by 1 px
        // (paint mixed into the rim; candidates dropped below for mixed hue are paint too).
        // Not more: lip dots sit a few pixels apart, and the lips between them are what a
        // red paint's range must leave out.
        let mut near_blob = vec![false; w * h];
        for b in &blobs {
            mark_box(&mut near_blob, (w, h), b.bbox, 1);
        }
        for blob in blobs {
            let (label, area) = (blob.label, blob.area);
            let PixelRect {
                x: bx,
                y: by,
                width: bw,
                height: bh,
            } = blob.bbox;
            let start = self.pixels.len();
            let (mut sx, mut sy) = (0.0, 0.0);
            for y in by..by + bh {
                for x in bx..bx + bw {
                    let i = y as usize * w + x as usize;
                    if labels[i] == label {
                        self.pixels
                            .push([hsv[3 * i], hsv[3 * i + 1], hsv[3 * i + 2]]);
                        sx += x as f64;
                        sy += y as f64;
                    }
                }
            }
            // The blob's own colour: pixels within 15 hue units of its trimmed mean (a dot run
            // into the mouth's dark red keeps only its paint pixels).
            let all = self.pixels.len() - start;
            let mean = circular_mean(self.pixels[start..].iter().map(|p| p[0] as f64));
            let mean = circular_mean(
                self.pixels[start..]
                    .iter()
                    .map(|p| p[0] as f64)
                    .filter(|h| hue_diff(*h, mean).abs() <= 15.0),
            );
            let mut kept = start;
            for j in start..self.pixels.len() {
                if hue_diff(self.pixels[j][0] as f64, mean).abs() <= 15.0 {
                    self.pixels[kept] = self.pixels[j];
                    kept += 1;
                }
            }
            self.pixels.truncate(kept);
            let px = &self.pixels[start..];
            let (hue, spread) = circular_stats(px.iter().map(|p| p[0] as f64));
            if px.len() * 3 < all * 2 || spread > opts.max_hue_spread {
                // Not one paint.
                self.pixels.truncate(start);
                continue;
            }
            let k = all as f64;
            self.blobs.push(SampledBlob {
                frame: frame_idx,
                center: [sx / k, sy / k],
                area,
                bbox: PixelRect {
                    x: bx,
                    y: by,
                    width: bw,
                    height: bh,
                },
                hue,
                pixels: start..self.pixels.len(),
            });
            found += 1;
        }
        for i in 0..w * h {
            if !near_blob[i] && fg[i] {
                let hue = (hsv[3 * i] as usize).min(179);
                self.face_hist[hue * 256 + hsv[3 * i + 1] as usize] += 1;
                self.face_pixels += 1;
            }
        }
        Ok(FrameSample {
            blobs: found,
            performer_m: performer.map(|(_, _, z)| z),
            saturation_threshold: threshold,
        })
    }
}

/// Nearest depth (metres) at which valid readings covering at least `min_fraction` of the
/// image lie within 10 cm: the performer, not a stray pixel.
pub fn performer_distance(
    depth: &DepthImage,
    scale_m: f64,
    range_m: [f64; 2],
    min_fraction: f64,
) -> Option<f64> {
    const BIN_M: f64 = 0.01;
    let bins = ((range_m[1] - range_m[0]) / BIN_M).ceil().max(1.0) as usize;
    let mut hist = vec![0u32; bins];
    for &d in &depth.data {
        if d == 0 {
            continue;
        }
        let z = d as f64 * scale_m;
        if z < range_m[0] || z >= range_m[1] {
            continue;
        }
        hist[(((z - range_m[0]) / BIN_M) as usize).min(bins - 1)] += 1;
    }
    let need = (depth.data.len() as f64 * min_fraction).max(1.0) as u64;
    let window = 10;
    let mut sum: u64 = hist.iter().take(window).map(|&c| c as u64).sum();
    for start in 0..bins {
        if sum >= need {
            // The first occupied bin of the window: the surface's near side.
            let first = (start..(start + window).min(bins)).find(|&b| hist[b] > 0)?;
            return Some(range_m[0] + first as f64 * BIN_M);
        }
        sum -= hist[start] as u64;
        if start + window < bins {
            sum += hist[start + window] as u64;
        }
    }
    None
}

/// A connected component that passed the size, shape and contrast tests.
struct Candidate {
    label: i32,
    area: u32,
    bbox: PixelRect,
}

/// Marks `rect` grown by `grow` pixels.
fn mark_box(marks: &mut [bool], (w, h): (usize, usize), rect: PixelRect, grow: i32) {
    for y in (rect.y - grow).max(0)..(rect.y + rect.height + grow).min(h as i32) {
        for x in (rect.x - grow).max(0)..(rect.x + rect.width + grow).min(w as i32) {
            marks[y as usize * w + x as usize] = true;
        }
    }
}

/// Connected components of the foreground pixels at or above `threshold` saturation that
/// are dot-like: size, fill, aspect, and at least `min_contrast` more saturated (median) than
/// the ring 2–3 px outside their box; `labels` holds the components.
#[allow(clippy::too_many_arguments)]
fn compact_blobs(
    hsv: &[u8],
    fg: &[bool],
    (w, h): (usize, usize),
    threshold: u8,
    max_area: f64,
    opts: &TuneOptions,
    labels: &mut Mat,
    stats: &mut Mat,
    centroids: &mut Mat,
) -> Result<Vec<Candidate>, DetectError> {
    let mask: Vec<u8> = (0..w * h)
        .map(|i| {
            if fg[i] && hsv[3 * i + 1] >= threshold {
                255
            } else {
                0
            }
        })
        .collect();
    let mask_mat = Mat::new_rows_cols_with_data(h as i32, w as i32, &mask)?.try_clone()?;
    let n = imgproc::connected_components_with_stats(
        &mask_mat,
        labels,
        stats,
        centroids,
        8,
        core::CV_32S,
    )?;
    let label_of = labels.data_typed::<i32>()?;
    let mut out = Vec::new();
    for label in 1..n {
        let stat = |k| stats.at_2d::<i32>(label, k).copied();
        let area = stat(imgproc::CC_STAT_AREA)? as u32;
        let (bx, by) = (stat(imgproc::CC_STAT_LEFT)?, stat(imgproc::CC_STAT_TOP)?);
        let (bw, bh) = (
            stat(imgproc::CC_STAT_WIDTH)?,
            stat(imgproc::CC_STAT_HEIGHT)?,
        );
        let fill = area as f64 / (bw as f64 * bh as f64);
        let aspect = bw.max(bh) as f64 / bw.min(bh) as f64;
        if area < opts.min_area_px
            || area as f64 > max_area
            || fill < opts.min_fill_ratio
            || aspect > opts.max_aspect
        {
            continue;
        }
        // Contrast with the surroundings: the ring 2–3 px outside the box.
        let mut ring = Vec::with_capacity(64);
        for y in (by - 3).max(0)..(by + bh + 3).min(h as i32) {
            for x in (bx - 3).max(0)..(bx + bw + 3).min(w as i32) {
                let inner = x >= bx - 1 && x <= bx + bw && y >= by - 1 && y <= by + bh;
                let i = y as usize * w + x as usize;
                if !inner && mask[i] == 0 {
                    ring.push(hsv[3 * i + 1]);
                }
            }
        }
        let mut inside = Vec::with_capacity(area as usize);
        for y in by..by + bh {
            for x in bx..bx + bw {
                let i = y as usize * w + x as usize;
                if label_of[i] == label {
                    inside.push(hsv[3 * i + 1]);
                }
            }
        }
        let (Some(s_in), Some(s_ring)) = (median_u8(&inside), median_u8(&ring)) else {
            continue;
        };
        if s_in < s_ring.saturating_add(opts.min_contrast) {
            continue;
        }
        out.push(Candidate {
            label,
            area,
            bbox: PixelRect {
                x: bx,
                y: by,
                width: bw,
                height: bh,
            },
        });
    }
    Ok(out)
}
