//! Proposing colour classes from frames (`mouthpiece tune-colours`).
//!
//! [`ColourSampler::add_frame`] finds saturated, compact colour blobs in one frame: OpenCV
//! converts to HSV; the performer's distance (a depth histogram: the nearest surface covering
//! 1.5 % of the image) masks out what is more than 35 cm behind it; the face's saturation is
//! measured (99.5th percentile of the foreground, with the blobs of a first, lower-threshold
//! pass left out so a close-up's paint does not lift it) and pixels 20 above it form connected
//! components; a component is kept when it is dot-sized and shaped, at least 60 more
//! saturated than the ring around it (paint stands out, a fold of the lips does not) and of
//! one hue (pixels more than 15 hue units off its trimmed mean are dropped; a blob losing a
//! third is dropped). Everything else in the foreground goes into a hue x saturation
//! histogram of "face".
//!
//! [`ColourSampler::propose`] clusters the blobs of every frame by hue (a circular histogram,
//! smoothed, split at its valleys), keeps the clusters seen in two frames out of three, picks
//! the lip cluster (about `lip_dots` blobs per frame) and the forehead cluster (about
//! `forehead_dots`, above the lips), and turns each into a [`ColorClass`]: hue from the 2nd to
//! the 98th percentile of its pixels plus a margin (a red across hue 0 written as two ranges,
//! hue shared with another class split between them), saturation from the lowest level at
//! which the face shows (almost) no pixel of that hue, value from the paint's low tail.
//! [`Proposal::to_toml`] prints it as a `[detect]` snippet.

use std::f64::consts::PI;
use std::fmt::Write as _;

use opencv::core::{self, Mat, MatTraitConst, MatTraitConstManual, Vec3b};
use opencv::imgproc;

use mouthpiece_frame::{ColorImage, DepthImage};

use crate::{ColorClass, DetectConfig, DetectError, DotRole, PixelRect};

/// How the sampler looks for blobs and how much room the proposed ranges get.
#[derive(Debug, Clone, PartialEq)]
pub struct TuneOptions {
    /// Dots expected on the lips and on the forehead (the tracker's `lip_dots`,
    /// `forehead_dots`).
    pub lip_dots: usize,
    pub forehead_dots: usize,
    /// Paint colours to propose: `Some(1)` one class (role `any`) for every dot, `Some(2)`
    /// lips and forehead, `None` as many as found (at most two).
    pub classes: Option<usize>,
    /// Lowest saturation (0–255) a blob pixel may have, whatever the face's saturation is.
    pub min_saturation: u8,
    /// How far above the face's 99.5th-percentile saturation the blob threshold sits.
    pub saturation_above_face: u8,
    /// How much more saturated (median) a blob must be than the skin around it (the ring
    /// 2–3 px outside its box): paint stands out, a saturated fold of the lips does not.
    pub min_contrast: u8,
    /// Largest circular standard deviation of hue inside one blob (hue units): a paint dot
    /// is one colour.
    pub max_hue_spread: f64,
    /// Darkest pixel (value, 0–255) considered: hue is noise in the dark.
    pub min_value: u8,
    /// Margins added outside the paint's percentiles, hue and value units (the saturation
    /// floor comes from the face: as low as it allows in the class's hues).
    pub hue_margin: u8,
    pub value_margin: u8,
    /// Smallest blob (pixels); larger blobs are bounded by a 15 mm disc at their distance.
    pub min_area_px: u32,
    pub min_fill_ratio: f64,
    pub max_aspect: f64,
    /// Plausible performer distance (metres).
    pub depth_range_m: [f64; 2],
    /// Background cut: pixels farther than the performer's nearest surface plus this are
    /// ignored (metres).
    pub depth_window_m: f64,
}

impl TuneOptions {
    /// Blob filters from a detector configuration (the user's `[detect]`), dot counts from
    /// the tracker's layout.
    pub fn from_config(detect: &DetectConfig, lip_dots: usize, forehead_dots: usize) -> Self {
        Self {
            lip_dots,
            forehead_dots,
            classes: None,
            min_saturation: 60,
            saturation_above_face: 20,
            min_contrast: 60,
            max_hue_spread: 6.0,
            min_value: 60,
            hue_margin: 12,
            value_margin: 25,
            min_area_px: detect.min_area_px.max(2),
            min_fill_ratio: detect.min_fill_ratio,
            max_aspect: detect.max_aspect,
            depth_range_m: detect.depth_range_m,
            depth_window_m: 0.35,
        }
    }
}

impl Default for TuneOptions {
    fn default() -> Self {
        Self::from_config(&DetectConfig::default(), 12, 3)
    }
}

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
    pixels: std::ops::Range<usize>,
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
    options: TuneOptions,
    frames: u32,
    blobs: Vec<SampledBlob>,
    /// (hue, saturation, value) of every blob pixel.
    pixels: Vec<[u8; 3]>,
    performer_m: Vec<f64>,
    thresholds: Vec<u8>,
    /// Hue x saturation histogram (180 x 256) of the foreground away from the blobs: the
    /// skin, lips and mouth a class's ranges must leave out.
    face_hist: Vec<u64>,
    face_pixels: u64,
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

fn percentile_u8(hist: &[u64; 256], q: f64) -> u8 {
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

fn median_u8(values: &[u8]) -> Option<u8> {
    let mut v = values.to_vec();
    v.sort_unstable();
    v.get(v.len() / 2).copied()
}

/// Signed hue difference `a - b` on the 180-unit circle, in (-90, 90].
fn hue_diff(a: f64, b: f64) -> f64 {
    let mut d = (a - b) % 180.0;
    if d > 90.0 {
        d -= 180.0;
    } else if d <= -90.0 {
        d += 180.0;
    }
    d
}

/// Circular mean of hues (0–180 scale).
fn circular_mean(hues: impl Iterator<Item = f64>) -> f64 {
    circular_stats(hues).0
}

/// Circular mean and standard deviation of hues (0–180 scale, hue units).
fn circular_stats(hues: impl Iterator<Item = f64>) -> (f64, f64) {
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

    /// Clusters the blobs into paints and proposes a class for each dot role found.
    pub fn propose(&self) -> Proposal {
        let opts = &self.options;
        let frames = self.frames.max(1);
        let clusters = self.clusters();
        let mut warnings = Vec::new();

        // Persistent clusters: seen in at least two frames out of three.
        let (cands, others): (Vec<Cluster>, Vec<Cluster>) = clusters
            .into_iter()
            .partition(|c| c.frames_present * 3 >= frames * 2 && c.per_frame >= 1.0);
        let (l, f) = (opts.lip_dots as f64, opts.forehead_dots as f64);
        let mut chosen: Vec<(Cluster, DotRole)> = Vec::new();
        let mut unused = others;
        if opts.classes == Some(2) && cands.len() == 1 {
            warnings.push("two paint colours were asked for but only one was found".into());
        }
        match cands.len() {
            0 => {}
            n if opts.classes == Some(1) => {
                // The most persistent colour paints every dot.
                let mut cands = cands;
                cands.sort_by_key(|c| std::cmp::Reverse(c.blobs.len()));
                if n > 1 {
                    warnings.push(format!(
                        "one paint colour was asked for but {n} were seen; the most frequent is proposed"
                    ));
                }
                let mut it = cands.into_iter();
                chosen.push((it.next().expect("one"), DotRole::Any));
                unused.extend(it);
            }
            1 => {
                let c = cands.into_iter().next().expect("one");
                let n = c.per_frame;
                if (n - (l + f)).abs() <= (n - l).abs() {
                    warnings.push(format!(
                        "one paint colour only ({n:.0} blobs per frame): proposed as role \"any\"; the tracker tells lips from forehead by geometry"
                    ));
                    chosen.push((c, DotRole::Any));
                } else {
                    warnings.push(format!(
                        "one paint colour only ({n:.0} blobs per frame, {} lip and {} forehead dots expected): no forehead colour found",
                        opts.lip_dots, opts.forehead_dots
                    ));
                    chosen.push((c, DotRole::Lip));
                }
            }
            _ => {
                // Best (lip, forehead) pair: counts near the layout, forehead above the lips.
                let score = |lip: &Cluster, fh: &Cluster| {
                    (lip.per_frame - l).abs() / l
                        + (fh.per_frame - f).abs() / f
                        + if fh.mean_y < lip.mean_y { 0.0 } else { 1.0 }
                };
                let mut pairs = Vec::new();
                for (i, a) in cands.iter().enumerate() {
                    for (j, b) in cands.iter().enumerate() {
                        if i != j {
                            pairs.push((score(a, b), i, j));
                        }
                    }
                }
                pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
                let (best, li, fi) = pairs[0];
                let lip = &cands[li];
                let fh = &cands[fi];
                if best > 0.5 {
                    warnings.push(format!(
                        "ambiguous: the best lip/forehead pair has {:.0} and {:.0} blobs per frame (expected {} and {}){}",
                        lip.per_frame,
                        fh.per_frame,
                        opts.lip_dots,
                        opts.forehead_dots,
                        if fh.mean_y < lip.mean_y { "" } else { ", and the forehead colour is not above the lip colour" }
                    ));
                }
                if let Some(&(second, _, _)) = pairs.iter().find(|p| (p.1, p.2) != (li, fi)) {
                    if cands.len() > 2 && second - best < 0.25 {
                        warnings.push(format!(
                            "ambiguous: {} persistent colours fit the layout almost equally well; check the hues below",
                            cands.len()
                        ));
                    }
                }
                for (k, c) in cands.into_iter().enumerate() {
                    if k == li {
                        chosen.push((c, DotRole::Lip));
                    } else if k == fi {
                        chosen.push((c, DotRole::Forehead));
                    } else {
                        unused.push(c);
                    }
                }
                chosen.sort_by_key(|(_, r)| *r != DotRole::Lip);
            }
        }
        if chosen.is_empty() {
            warnings.push(if self.blobs.is_empty() {
                format!(
                    "no saturated, compact colour blobs in {} frames: no paint colours found",
                    self.frames
                )
            } else {
                format!(
                    "no paint colour seen in at least two thirds of {} frames ({} blobs in all)",
                    self.frames,
                    self.blobs.len()
                )
            });
        }

        let mut classes: Vec<ProposedClass> = chosen
            .iter()
            .map(|(c, role)| self.class_from(c, *role, &mut warnings))
            .collect();
        // Neighbouring paints: no hue shared between two classes.
        separate_hues(&mut classes);
        unused.sort_by_key(|c| std::cmp::Reverse(c.blobs.len()));
        Proposal {
            classes,
            unused: unused
                .iter()
                .map(|c| ClusterSummary {
                    hue: c.centre,
                    blobs: c.blobs.len(),
                    frames_present: c.frames_present,
                    per_frame: c.per_frame,
                })
                .collect(),
            warnings,
            frames: self.frames,
            blobs: self.blobs.len(),
            performer_m: median_f64(&self.performer_m),
            saturation_threshold: median_u8(&self.thresholds),
        }
    }

    /// Blob clusters by hue: a circular histogram of blob hues, smoothed, split at valleys.
    fn clusters(&self) -> Vec<Cluster> {
        const SIGMA: f64 = 2.0;
        let mut hist = [0.0f64; 180];
        for b in &self.blobs {
            hist[(b.hue.round() as usize) % 180] += 1.0;
        }
        let mut smooth = [0.0f64; 180];
        for (i, s) in smooth.iter_mut().enumerate() {
            for k in -6i32..=6 {
                let j = (i as i32 + k).rem_euclid(180) as usize;
                *s += hist[j] * (-(k * k) as f64 / (2.0 * SIGMA * SIGMA)).exp();
            }
        }
        let at = |i: i32| smooth[i.rem_euclid(180) as usize];
        // Local maxima (plateaus: first bin), then merge neighbours without a real valley.
        let mut peaks: Vec<usize> = (0..180)
            .filter(|&i| {
                let i = i as i32;
                at(i) > 0.0 && at(i) > at(i - 1) && at(i) >= at(i + 1)
            })
            .collect();
        loop {
            if peaks.len() < 2 {
                break;
            }
            let mut merged = false;
            for k in 0..peaks.len() {
                let (a, b) = (peaks[k], peaks[(k + 1) % peaks.len()]);
                let span = (b + 180 - a) % 180;
                let valley = (0..=span)
                    .map(|d| smooth[(a + d) % 180])
                    .fold(f64::INFINITY, f64::min);
                if valley > 0.5 * smooth[a].min(smooth[b]) {
                    let drop = if smooth[a] >= smooth[b] { b } else { a };
                    peaks.retain(|&p| p != drop);
                    merged = true;
                    break;
                }
            }
            if !merged {
                break;
            }
        }
        if peaks.is_empty() {
            return Vec::new();
        }
        peaks.sort_unstable();
        // Each bin belongs to the peak whose region holds it: boundaries at the valleys.
        let mut owner = [usize::MAX; 180];
        for k in 0..peaks.len() {
            let a = peaks[k];
            let b = if peaks.len() == 1 {
                a + 180
            } else {
                let nb = peaks[(k + 1) % peaks.len()];
                if nb > a {
                    nb
                } else {
                    nb + 180
                }
            };
            let valley = (a..b)
                .min_by(|&x, &y| smooth[x % 180].total_cmp(&smooth[y % 180]))
                .unwrap_or(a);
            let next = (k + 1) % peaks.len();
            for d in a..b {
                owner[d % 180] = if d <= valley || peaks.len() == 1 {
                    k
                } else {
                    next
                };
            }
        }
        let frames = self.frames.max(1) as usize;
        let mut clusters = Vec::new();
        for (k, &peak) in peaks.iter().enumerate() {
            // Outliers far down the peak's flank belong to no paint.
            let members: Vec<(usize, &SampledBlob)> = self
                .blobs
                .iter()
                .enumerate()
                .filter(|(_, b)| {
                    let bin = (b.hue.round() as usize) % 180;
                    owner[bin] == k && smooth[bin] >= 0.05 * smooth[peak]
                })
                .collect();
            if members.is_empty() {
                continue;
            }
            let mut per_frame = vec![0u32; frames];
            for (_, b) in &members {
                per_frame[b.frame as usize] += 1;
            }
            let frames_present = per_frame.iter().filter(|&&n| n > 0).count() as u32;
            per_frame.sort_unstable();
            let centre = circular_mean(members.iter().map(|(_, b)| b.hue));
            let mean_y =
                members.iter().map(|(_, b)| b.center[1]).sum::<f64>() / members.len() as f64;
            clusters.push(Cluster {
                centre,
                per_frame: per_frame[frames / 2] as f64,
                frames_present,
                mean_y,
                blobs: members.iter().map(|(i, _)| *i).collect(),
            });
        }
        clusters.sort_by_key(|c| std::cmp::Reverse(c.blobs.len()));
        clusters
    }

    /// Lowest saturation at which the face (away from the blobs) shows at most one pixel in
    /// 5000 inside `hue`.
    fn face_saturation_limit(&self, hue: &[[u8; 2]]) -> u8 {
        let set = hue_set(hue);
        let budget = self.face_pixels / 5000;
        let mut count = 0;
        for s in (0..256).rev() {
            count += (0..180)
                .filter(|&h| set[h])
                .map(|h| self.face_hist[h * 256 + s])
                .sum::<u64>();
            if count > budget {
                return (s + 1).min(255) as u8;
            }
        }
        0
    }

    fn class_from(&self, c: &Cluster, role: DotRole, warnings: &mut Vec<String>) -> ProposedClass {
        let opts = &self.options;
        let mut dh: Vec<f64> = Vec::new();
        let mut sat = [0u64; 256];
        let mut val = [0u64; 256];
        for &i in &c.blobs {
            for p in &self.pixels[self.blobs[i].pixels.clone()] {
                dh.push(hue_diff(p[0] as f64, c.centre));
                sat[p[1] as usize] += 1;
                val[p[2] as usize] += 1;
            }
        }
        dh.sort_by(f64::total_cmp);
        let q = |v: &[f64], q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
        // 2nd to 98th percentile, at most 20 hue units from the centre, plus the margin.
        let margin = opts.hue_margin as f64;
        let lo = (c.centre + q(&dh, 0.02).max(-20.0) - margin).floor() as i32;
        let hi = (c.centre + q(&dh, 0.98).min(20.0) + margin).ceil() as i32;
        let hue = hue_ranges(lo, hi);
        // Saturation: as low as the face allows in this hue (rim pixels count in the
        // detector's centre), but no lower than half the paint's low tail.
        let paint_lo = percentile_u8(&sat, 0.02);
        let face = self.face_saturation_limit(&hue).saturating_add(10);
        let s_lo = face.max(paint_lo / 2).max(opts.min_saturation);
        if s_lo > percentile_u8(&sat, 0.25) {
            warnings.push(format!(
                "hue {:.0}: the face is nearly as saturated as the paint in this hue (saturation floor {s_lo}, paint's lower quartile {}); dots may break up",
                c.centre,
                percentile_u8(&sat, 0.25)
            ));
        }
        let v_lo = percentile_u8(&val, 0.02)
            .saturating_sub(opts.value_margin)
            .max(opts.min_value);
        let name = match role {
            DotRole::Lip => "lip",
            DotRole::Forehead => "forehead",
            DotRole::Any => "dots",
        };
        ProposedClass {
            class: ColorClass {
                name: name.into(),
                role,
                hue,
                saturation: [s_lo, 255],
                value: [v_lo, 255],
            },
            hue_centre: c.centre,
            blobs: c.blobs.len(),
            frames_present: c.frames_present,
            per_frame: c.per_frame,
        }
    }
}

fn median_f64(v: &[f64]) -> Option<f64> {
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
fn hue_set(ranges: &[[u8; 2]]) -> [bool; 180] {
    let mut set = [false; 180];
    for [lo, hi] in ranges {
        for h in *lo..=(*hi).min(179) {
            set[h as usize] = true;
        }
    }
    set
}

/// Removes hue shared by two classes, giving each side the half nearer its own centre.
fn separate_hues(classes: &mut [ProposedClass]) {
    for a in 0..classes.len() {
        for b in a + 1..classes.len() {
            let sa = hue_set(&classes[a].class.hue);
            let sb = hue_set(&classes[b].class.hue);
            if !(0..180).any(|h| sa[h] && sb[h]) {
                continue;
            }
            let (ca, cb) = (classes[a].hue_centre, classes[b].hue_centre);
            let keep = |set: &[bool; 180], own: f64, other: f64| {
                let mut out = *set;
                for (h, slot) in out.iter_mut().enumerate() {
                    if sa[h] && sb[h] {
                        *slot = hue_diff(h as f64, own).abs() < hue_diff(h as f64, other).abs();
                    }
                }
                out
            };
            let na = keep(&sa, ca, cb);
            let nb = keep(&sb, cb, ca);
            classes[a].class.hue = set_to_ranges(&na);
            classes[b].class.hue = set_to_ranges(&nb);
        }
    }
}

/// A hue set back to ranges (a run through 179→0 becomes two).
fn set_to_ranges(set: &[bool; 180]) -> Vec<[u8; 2]> {
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

#[derive(Debug, Clone)]
struct Cluster {
    centre: f64,
    /// Median blobs per frame (frames without any counted as 0).
    per_frame: f64,
    frames_present: u32,
    mean_y: f64,
    blobs: Vec<usize>,
}

/// A proposed colour class and where it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct ProposedClass {
    pub class: ColorClass,
    pub hue_centre: f64,
    pub blobs: usize,
    pub frames_present: u32,
    pub per_frame: f64,
}

/// A colour seen but not proposed.
#[derive(Debug, Clone, PartialEq)]
pub struct ClusterSummary {
    pub hue: f64,
    pub blobs: usize,
    pub frames_present: u32,
    pub per_frame: f64,
}

/// What [`ColourSampler::propose`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct Proposal {
    /// Lip class first, then forehead; empty when nothing usable was found.
    pub classes: Vec<ProposedClass>,
    pub unused: Vec<ClusterSummary>,
    /// No or ambiguous colours; also printed as comments.
    pub warnings: Vec<String>,
    pub frames: u32,
    pub blobs: usize,
    pub performer_m: Option<f64>,
    pub saturation_threshold: Option<u8>,
}

impl Proposal {
    /// The proposal as a detector configuration: `base` with its classes replaced.
    pub fn detect_config(&self, base: &DetectConfig) -> DetectConfig {
        DetectConfig {
            classes: self.classes.iter().map(|c| c.class.clone()).collect(),
            ..base.clone()
        }
    }

    /// The `[detect]` snippet: `[[detect.class]]` entries with the keys a configuration file
    /// takes (valid TOML on its own and anywhere in a configuration file whose `[detect]`
    /// table has no classes), comments saying where each came from, `# warning:` lines.
    pub fn to_toml(&self, source: &str) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "# Proposed by `mouthpiece tune-colours` from {} frames of {source}",
            self.frames
        );
        let _ = writeln!(
            s,
            "# ({} colour blobs{}{}).",
            self.blobs,
            match self.performer_m {
                Some(z) => format!(", performer at {z:.2} m"),
                None => ", no depth: background not masked".into(),
            },
            match self.saturation_threshold {
                Some(t) => format!(", blob saturation >= {t}"),
                None => String::new(),
            }
        );
        for w in &self.warnings {
            let _ = writeln!(s, "# warning: {w}");
        }
        for c in &self.unused {
            let _ = writeln!(
                s,
                "# not used: hue {:.0}, {} blobs in {} of {} frames ({:.0} per frame)",
                c.hue, c.blobs, c.frames_present, self.frames, c.per_frame
            );
        }
        // No `[detect]` line: the entries create the table on their own, and can be pasted
        // into a file that has one (TOML refuses a table defined twice).
        for p in &self.classes {
            let c = &p.class;
            let _ = writeln!(s);
            let _ = writeln!(
                s,
                "# hue {:.0}: {} blobs in {} of {} frames ({:.0} per frame)",
                p.hue_centre, p.blobs, p.frames_present, self.frames, p.per_frame
            );
            let _ = writeln!(s, "[[detect.class]]");
            let _ = writeln!(s, "name = \"{}\"", c.name);
            let role = match c.role {
                DotRole::Lip => "lip",
                DotRole::Forehead => "forehead",
                DotRole::Any => "any",
            };
            let _ = writeln!(s, "role = \"{role}\"");
            let hue: Vec<String> = c.hue.iter().map(|[a, b]| format!("[{a}, {b}]")).collect();
            let _ = writeln!(s, "hue = [{}]", hue.join(", "));
            let _ = writeln!(s, "saturation = [{}, {}]", c.saturation[0], c.saturation[1]);
            let _ = writeln!(s, "value = [{}, {}]", c.value[0], c.value[1]);
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 160x120 BGR image of skin with depth: the face at 0.6 m in the middle, a wall at
    /// 1.8 m around it.
    struct Scene {
        color: ColorImage,
        depth: DepthImage,
    }

    const W: u32 = 160;
    const H: u32 = 120;

    impl Scene {
        fn new() -> Self {
            let mut color = ColorImage::new(W, H);
            let mut depth = DepthImage::new(W, H);
            for y in 0..H {
                for x in 0..W {
                    let i = (y * W + x) as usize;
                    let face = (40..120).contains(&x) && (10..110).contains(&y);
                    // BGR: skin (hue ≈ 10, saturation ≈ 100) or a grey wall.
                    let bgr = if face { [120, 150, 205] } else { [60, 62, 64] };
                    color.data[3 * i..3 * i + 3].copy_from_slice(&bgr);
                    depth.data[i] = if face { 600 } else { 1800 };
                }
            }
            Self { color, depth }
        }

        fn square(&mut self, x0: u32, y0: u32, bgr: [u8; 3]) {
            for y in y0..y0 + 3 {
                for x in x0..x0 + 3 {
                    let i = (y * W + x) as usize;
                    self.color.data[3 * i..3 * i + 3].copy_from_slice(&bgr);
                }
            }
        }
    }

    const GREEN: [u8; 3] = [70, 200, 40]; // BGR, hue ≈ 66
    const BLUE: [u8; 3] = [230, 90, 40]; // hue ≈ 112
    const MAGENTA: [u8; 3] = [200, 30, 210]; // hue ≈ 152

    /// Twelve green dots on a lip line, three blue ones above, and magenta dots on the wall
    /// (a poster behind the performer).
    fn scene() -> Scene {
        let mut s = Scene::new();
        for k in 0..12 {
            s.square(50 + 5 * k, 80 + (k % 2) * 6, GREEN);
        }
        for k in 0..3 {
            s.square(60 + 20 * k, 30, BLUE);
        }
        for k in 0..6 {
            s.square(5 + 5 * k, 5, MAGENTA);
            s.square(130, 20 + 6 * k, MAGENTA);
        }
        s
    }

    fn sample(with_depth: bool) -> Proposal {
        let s = scene();
        let mut sampler = ColourSampler::new(TuneOptions::default());
        for _ in 0..10 {
            let depth = with_depth.then_some((&s.depth, 0.001));
            let got = sampler.add_frame(&s.color, depth, 140.0).unwrap();
            assert_eq!(got.performer_m.is_some(), with_depth);
        }
        sampler.propose()
    }

    #[test]
    fn depth_masks_the_background_and_roles_follow_count_and_height() {
        let p = sample(true);
        assert!(p.warnings.is_empty(), "{:?}", p.warnings);
        assert!(
            p.unused.is_empty(),
            "the wall's magenta was sampled: {:?}",
            p.unused
        );
        let performer = p.performer_m.unwrap();
        assert!((performer - 0.6).abs() < 0.011, "{performer}");
        assert_eq!(p.classes.len(), 2);
        let (lip, forehead) = (&p.classes[0], &p.classes[1]);
        assert_eq!(lip.class.role, DotRole::Lip);
        assert_eq!(lip.per_frame, 12.0);
        assert_eq!((lip.blobs, lip.frames_present), (120, 10));
        assert_eq!(forehead.class.role, DotRole::Forehead);
        assert_eq!(forehead.per_frame, 3.0);
        let hue_of = |c: &ProposedClass| hue_set(&c.class.hue);
        assert!(hue_of(lip)[66] && !hue_of(lip)[112] && !hue_of(lip)[10]);
        assert!(hue_of(forehead)[112] && !hue_of(forehead)[66]);
        let config = p.detect_config(&DetectConfig::default());
        config.validate().unwrap();
        // The snippet parses back to the same classes.
        let text = p.to_toml("scene");
        #[derive(serde::Deserialize)]
        struct File {
            detect: DetectConfig,
        }
        let back: File = toml::from_str(&text).unwrap();
        assert_eq!(back.detect.classes, config.classes, "{text}");
        assert!(
            text.contains("# hue 66: 120 blobs in 10 of 10 frames (12 per frame)"),
            "{text}"
        );
    }

    #[test]
    fn without_depth_the_background_colour_is_seen() {
        let p = sample(false);
        assert!(p.performer_m.is_none());
        // Magenta: 12 wall dots per frame compete with the green lip dots.
        let seen: Vec<f64> = p
            .classes
            .iter()
            .map(|c| c.hue_centre)
            .chain(p.unused.iter().map(|c| c.hue))
            .collect();
        assert!(seen.iter().any(|h| (h - 152.0).abs() < 3.0), "{seen:?}");
        assert!(p.to_toml("scene").contains("no depth"));
    }

    #[test]
    fn nothing_saturated_gives_no_class_and_a_warning() {
        let s = Scene::new();
        let mut sampler = ColourSampler::new(TuneOptions::default());
        sampler
            .add_frame(&s.color, Some((&s.depth, 0.001)), 140.0)
            .unwrap();
        let p = sampler.propose();
        assert!(p.classes.is_empty());
        assert!(
            p.warnings[0].contains("no saturated, compact colour blobs"),
            "{:?}",
            p.warnings
        );
    }

    #[test]
    fn hue_ranges_wrap_around_red() {
        assert_eq!(hue_ranges(55, 76), vec![[55, 76]]);
        assert_eq!(hue_ranges(-8, 9), vec![[0, 9], [172, 179]]);
        assert_eq!(hue_ranges(170, 185), vec![[0, 5], [170, 179]]);
        assert_eq!(hue_ranges(-100, 100), vec![[0, 179]]);
        assert!((hue_diff(2.0, 178.0) - 4.0).abs() < 1e-9);
        assert!((circular_mean([178.0, 2.0].into_iter()) % 180.0).abs() < 1e-6);
    }

    #[test]
    fn overlapping_classes_split_the_shared_hues() {
        let class = |hue: Vec<[u8; 2]>, centre: f64| ProposedClass {
            class: ColorClass {
                name: "x".into(),
                role: DotRole::Any,
                hue,
                saturation: [100, 255],
                value: [50, 255],
            },
            hue_centre: centre,
            blobs: 1,
            frames_present: 1,
            per_frame: 1.0,
        };
        let mut v = vec![
            class(vec![[0, 20], [170, 179]], 5.0),
            class(vec![[15, 40]], 28.0),
        ];
        separate_hues(&mut v);
        assert_eq!(v[0].class.hue, vec![[0, 16], [170, 179]]);
        assert_eq!(v[1].class.hue, vec![[17, 40]]);
    }

    #[test]
    fn performer_distance_ignores_specks() {
        let mut d = DepthImage::new(100, 100);
        d.data.iter_mut().for_each(|v| *v = 2000);
        d.data[0] = 300; // one near pixel: a speck, not the performer
        for v in &mut d.data[5000..6000] {
            *v = 750;
        }
        let z = performer_distance(&d, 0.001, [0.2, 2.5], 0.015).unwrap();
        assert!((z - 0.75).abs() < 0.011, "{z}");
    }
}
