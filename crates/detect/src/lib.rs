//! The dot detector: finds painted dots in a colour image with OpenCV.
//!
//! Per colour class ([`ColorClass`], HSV ranges, several hue ranges OR-ed so red can wrap):
//! threshold (the HSV ranges, as OpenCV's `inRange` would, for every class in one pass of
//! table lookups), a small morphology step, connected components with statistics,
//! filters (area for the distance measured in the registered depth image, fill ratio,
//! aspect, a valid depth reading nearby), and a sub-pixel centre: the image moments of a
//! per-pixel colour weight (how close the pixel's hue and saturation are to the paint) over
//! the component grown by one pixel, so rim pixels that mix paint and skin count in
//! proportion instead of all-or-nothing.
//!
//! Speed comes from the search region: [`Detector::detect`] takes a rectangle (the tracker
//! passes the box around where the dots are predicted) and does all image work inside it;
//! `None` searches the full frame (start-up and re-acquisition). Within it, connected
//! components run only over the box holding the class's mask pixels, and the colour weight
//! and the grown component are computed per component in Rust from the HSV bytes (one table
//! lookup per pixel, the table made by OpenCV's own `LUT` and `multiply`), so a frame's cost
//! follows the dots, not the region (docs/performance.md).
//!
//! The detector does not name dots; that is the tracker's job (`mouthpiece-track`).

mod config;
pub mod tune;

use opencv::core::{
    self, Mat, MatTrait, MatTraitConst, MatTraitConstManual, MatTraitManual, Rect, Scalar, Size,
    Vec3b,
};
use opencv::imgproc;

use mouthpiece_frame::{ColorImage, DepthImage};

pub use config::{default_classes, ColorClass, DetectConfig, DotRole, Morphology};

/// Sets how many threads OpenCV may use for its image operations (process-wide). The
/// benchmarks use 1 to measure one core; the daemon leaves OpenCV's default.
pub fn set_opencv_threads(threads: i32) -> Result<(), DetectError> {
    core::set_num_threads(threads)?;
    Ok(())
}

/// What can go wrong in the detector.
#[derive(Debug, thiserror::Error)]
pub enum DetectError {
    /// A configuration value is wrong; `key` is how it is written in the file.
    #[error("invalid configuration {key}: {message}")]
    Config { key: String, message: String },
    /// The colour and depth images do not fit together (the depth must be on the colour grid).
    #[error("image size mismatch: {0}")]
    ImageSize(String),
    #[error("OpenCV failed")]
    OpenCv(#[from] opencv::Error),
}

/// A pixel rectangle (`x`, `y` of the top-left corner, size), in full-frame coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixelRect {
    pub x: i32,
    pub y: i32,
    pub width: i32,
    pub height: i32,
}

impl PixelRect {
    pub fn full(width: u32, height: u32) -> Self {
        Self {
            x: 0,
            y: 0,
            width: width as i32,
            height: height as i32,
        }
    }

    /// The smallest rectangle holding every point, grown by `margin` pixels on each side.
    /// `None` for no points.
    pub fn around(points: impl IntoIterator<Item = [f64; 2]>, margin: f64) -> Option<Self> {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for p in points {
            for k in 0..2 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        if !lo[0].is_finite() || !hi[0].is_finite() {
            return None;
        }
        let x0 = (lo[0] - margin).floor() as i32;
        let y0 = (lo[1] - margin).floor() as i32;
        let x1 = (hi[0] + margin).ceil() as i32;
        let y1 = (hi[1] + margin).ceil() as i32;
        Some(Self {
            x: x0,
            y: y0,
            width: x1 - x0 + 1,
            height: y1 - y0 + 1,
        })
    }

    /// This rectangle cut to the image; `None` when nothing is left.
    pub fn clip(&self, width: u32, height: u32) -> Option<Self> {
        let x0 = self.x.max(0);
        let y0 = self.y.max(0);
        let x1 = (self.x + self.width).min(width as i32);
        let y1 = (self.y + self.height).min(height as i32);
        (x1 > x0 && y1 > y0).then_some(Self {
            x: x0,
            y: y0,
            width: x1 - x0,
            height: y1 - y0,
        })
    }

    pub fn area(&self) -> i64 {
        self.width as i64 * self.height as i64
    }

    fn to_cv(self) -> Rect {
        Rect::new(self.x, self.y, self.width, self.height)
    }
}

/// One dot candidate.
#[derive(Debug, Clone, PartialEq)]
pub struct Blob {
    /// Index into [`DetectConfig::classes`].
    pub class: usize,
    /// Sub-pixel centre, full-frame pixel coordinates (pixel centres at integers).
    pub center: [f64; 2],
    /// Pixels in the component.
    pub area: u32,
    pub bbox: PixelRect,
    /// Median valid depth (metres) around the blob; `None` when no depth image was given.
    pub depth_m: Option<f64>,
    /// Spread of the colour weight about the centre (second central moments over the
    /// weight, px²): `[xx, xy, yy]`. Two dots merged into one blob spread along the line
    /// between them; the tracker splits such a blob when it misses a dot there.
    pub spread: [f64; 3],
}

/// What one call found.
#[derive(Debug, Clone, Default)]
pub struct Detections {
    pub blobs: Vec<Blob>,
    /// The rectangle actually searched (clipped to the image).
    pub searched: Option<PixelRect>,
    /// Components that failed a filter (size, shape, depth); for diagnostics.
    pub rejected: u32,
    /// Components of a dot's shape and depth but smaller than a dot at that distance
    /// (`area_ratio`), down to `min_area_px`: paint mostly hidden (a mouth corner folding
    /// in) or a speck. Not in `blobs` (nor counted as rejected); the tracker may take one
    /// for a dot it would otherwise miss, right where that dot is predicted.
    pub faint: Vec<Blob>,
}

/// Why a component was not accepted (counted, logged at TRACE).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Reject {
    Small,
    Area,
    Shape,
    NoDepth,
}

/// The detector, with its scratch images kept between frames so a frame allocates nothing
/// once sizes settle.
pub struct Detector {
    config: DetectConfig,
    /// Per class: the colour weight (0–255) of each hue and saturation, `[hue * 256 +
    /// saturation]` ([`weight_table`]).
    weights: Vec<Vec<u8>>,
    kernel: Mat,
    hsv: Mat,
    /// The colour thresholds of every class as bit tables ([`RangeBits`]).
    range_bits: RangeBits,
    /// Per pixel of the region, the bits of the (class, hue range) pairs it falls in.
    pixel_bits: Vec<u32>,
    mask: Mat,
    morphed: Mat,
    labels: Mat,
    stats: Mat,
    centroids: Mat,
    comp_weight: Mat,
    /// One component's pixels grown by one (the 3x3 dilation), over its local rectangle.
    grown: Vec<bool>,
    depth_buf: Vec<u16>,
}

impl std::fmt::Debug for Detector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Detector")
            .field("config", &self.config)
            .finish_non_exhaustive()
    }
}

impl Detector {
    /// Validates the configuration and prepares the per-class lookup tables.
    pub fn new(config: DetectConfig) -> Result<Self, DetectError> {
        config.validate()?;
        let weights = config
            .classes
            .iter()
            .map(|class| {
                weight_table(
                    &hue_weight_table(&class.hue, config.weight_hue_margin),
                    &saturation_weight_table(class.saturation),
                )
            })
            .collect::<Result<_, _>>()?;
        let rect = |n| imgproc::get_structuring_element_def(imgproc::MORPH_RECT, Size::new(n, n));
        let kernel = match config.morphology {
            Morphology::Close => {
                imgproc::get_structuring_element_def(imgproc::MORPH_CROSS, Size::new(3, 3))?
            }
            _ => rect(2)?,
        };
        let range_bits = RangeBits::new(&config.classes);
        Ok(Self {
            kernel,
            config,
            weights,
            hsv: Mat::default(),
            range_bits,
            pixel_bits: Vec::new(),
            mask: Mat::default(),
            morphed: Mat::default(),
            labels: Mat::default(),
            stats: Mat::default(),
            centroids: Mat::default(),
            comp_weight: Mat::default(),
            grown: Vec::new(),
            depth_buf: Vec::new(),
        })
    }

    pub fn config(&self) -> &DetectConfig {
        &self.config
    }

    /// Finds dot candidates of every class inside `search` (the full frame when `None`).
    ///
    /// `depth` must be on the colour grid (registered), in units of `depth_scale_m` metres;
    /// without it the depth filter is skipped and the area filter spans the whole
    /// configured distance range. `fx` is the colour camera's focal length in pixels.
    pub fn detect(
        &mut self,
        color: &ColorImage,
        depth: Option<(&DepthImage, f64)>,
        fx: f64,
        search: Option<PixelRect>,
    ) -> Result<Detections, DetectError> {
        let mut out = Detections::default();
        self.detect_into(color, depth, fx, search, &mut out)?;
        Ok(out)
    }

    /// As [`Self::detect`], into `out` (its blob list is reused: no allocation once it has
    /// grown to a frame's count).
    pub fn detect_into(
        &mut self,
        color: &ColorImage,
        depth: Option<(&DepthImage, f64)>,
        fx: f64,
        search: Option<PixelRect>,
        out: &mut Detections,
    ) -> Result<(), DetectError> {
        out.blobs.clear();
        out.faint.clear();
        out.searched = None;
        out.rejected = 0;
        let expected_len = color.width as usize * color.height as usize * 3;
        if color.data.len() != expected_len {
            return Err(DetectError::ImageSize(format!(
                "colour image {}x{} holds {} bytes, expected {expected_len}",
                color.width,
                color.height,
                color.data.len()
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
        let full = PixelRect::full(color.width, color.height);
        let roi = match search {
            Some(r) => match r.clip(color.width, color.height) {
                Some(r) => r,
                None => return Ok(()),
            },
            None => full,
        };
        let image = Mat::new_rows_cols_with_bytes::<Vec3b>(
            color.height as i32,
            color.width as i32,
            &color.data,
        )?;
        let image_roi = Mat::roi(&image, roi.to_cv())?;
        imgproc::cvt_color_def(&image_roi, &mut self.hsv, imgproc::COLOR_BGR2HSV)?;
        self.range_bits
            .classify(self.hsv.data_bytes()?, &mut self.pixel_bits);

        out.searched = Some(roi);
        for class_idx in 0..self.config.classes.len() {
            self.detect_class(class_idx, roi, depth, fx, out)?;
        }
        tracing::trace!(
            roi = ?roi,
            found = out.blobs.len(),
            rejected = out.rejected,
            "detected"
        );
        Ok(())
    }

    fn detect_class(
        &mut self,
        class_idx: usize,
        roi: PixelRect,
        depth: Option<(&DepthImage, f64)>,
        fx: f64,
        out: &mut Detections,
    ) -> Result<(), DetectError> {
        // SAFETY: `class_mask` writes every byte of the new matrix.
        unsafe {
            self.mask
                .create_rows_cols(self.hsv.rows(), self.hsv.cols(), core::CV_8UC1)?
        };
        self.range_bits
            .class_mask(class_idx, &self.pixel_bits, self.mask.data_bytes_mut()?);
        // Opening only decides which components are real (it would shave a 2-px dot's rim,
        // biasing the centre): components come from the unopened mask and must keep a pixel
        // through the opening. Closing changes the components themselves.
        let binary = match self.config.morphology {
            Morphology::Close => {
                imgproc::morphology_ex_def(
                    &self.mask,
                    &mut self.morphed,
                    imgproc::MORPH_CLOSE,
                    &self.kernel,
                )?;
                &self.morphed
            }
            Morphology::Open => {
                imgproc::morphology_ex_def(
                    &self.mask,
                    &mut self.morphed,
                    imgproc::MORPH_OPEN,
                    &self.kernel,
                )?;
                &self.mask
            }
            Morphology::None => &self.mask,
        };
        // Connected components over the box holding the mask's pixels (and one more pixel
        // round them, where the grown components reach), its corner at even offsets in the
        // region: OpenCV labels 2x2 blocks in raster order, so the labels and their order are
        // those of the whole region.
        let Some(crop) = mask_box(binary)? else {
            return Ok(());
        };
        let n = imgproc::connected_components_with_stats(
            &Mat::roi(binary, crop.to_cv())?,
            &mut self.labels,
            &mut self.stats,
            &mut self.centroids,
            8,
            core::CV_32S,
        )?;
        if n <= 1 {
            return Ok(());
        }

        let cfg = &self.config;
        let (r0, r1) = (cfg.depth_range_m[0], cfg.depth_range_m[1]);
        for label in 1..n {
            let area = *self.stats.at_2d::<i32>(label, imgproc::CC_STAT_AREA)? as u32;
            let bx = *self.stats.at_2d::<i32>(label, imgproc::CC_STAT_LEFT)?;
            let by = *self.stats.at_2d::<i32>(label, imgproc::CC_STAT_TOP)?;
            let bw = *self.stats.at_2d::<i32>(label, imgproc::CC_STAT_WIDTH)?;
            let bh = *self.stats.at_2d::<i32>(label, imgproc::CC_STAT_HEIGHT)?;
            // In the region's coordinates.
            let (bx, by) = (bx + crop.x, by + crop.y);
            let bbox = PixelRect {
                x: bx + roi.x,
                y: by + roi.y,
                width: bw,
                height: bh,
            };

            let verdict = (|| {
                if area < cfg.min_area_px {
                    return Err(Reject::Small);
                }
                let fill = area as f64 / (bw as f64 * bh as f64);
                let aspect = bw.max(bh) as f64 / bw.min(bh) as f64;
                if fill < cfg.min_fill_ratio || aspect > cfg.max_aspect {
                    return Err(Reject::Shape);
                }
                let depth_m = match depth {
                    Some((d, scale)) => {
                        let z = median_depth_near(
                            d,
                            scale,
                            bbox,
                            cfg.depth_search_px as i32,
                            [r0, r1],
                            &mut self.depth_buf,
                        );
                        Some(z.ok_or(Reject::NoDepth)?)
                    }
                    None => None,
                };
                // Expected area of a disc of the paint's radius at that distance (or anywhere
                // in the plausible range when the distance is unknown).
                let disc = |z: f64| std::f64::consts::PI * (cfg.dot_radius_m * fx / z).powi(2);
                let (lo, hi) = match depth_m {
                    Some(z) => (disc(z) * cfg.area_ratio[0], disc(z) * cfg.area_ratio[1]),
                    None => (disc(r1) * cfg.area_ratio[0], disc(r0) * cfg.area_ratio[1]),
                };
                let area_f = area as f64;
                if area_f > hi.max(4.0) {
                    return Err(Reject::Area);
                }
                // Tiny discs are quantised: never ask for more than the minimum pixel count.
                let faint = area_f
                    < lo.min(cfg.min_area_px as f64 * 2.0)
                        .max(cfg.min_area_px as f64);
                Ok((depth_m, faint))
            })();
            let (depth_m, faint) = match verdict {
                Ok(v) => v,
                Err(why) => {
                    tracing::trace!(class = class_idx, ?bbox, area, ?why, "component rejected");
                    out.rejected += 1;
                    continue;
                }
            };

            // Sub-pixel centre: colour-weight moments over the component grown by a pixel.
            let local = PixelRect {
                x: bx - 1,
                y: by - 1,
                width: bw + 2,
                height: bh + 2,
            }
            .clip(roi.width as u32, roi.height as u32)
            .unwrap_or(PixelRect {
                x: bx,
                y: by,
                width: bw,
                height: bh,
            });
            let open = (self.config.morphology == Morphology::Open).then_some(&self.morphed);
            let weighed = component_weight(
                ComponentImages {
                    labels: &self.labels,
                    crop,
                    hsv: &self.hsv,
                    opened: open,
                    weights: &self.weights[class_idx],
                },
                label,
                local,
                &mut self.grown,
                &mut self.comp_weight,
            )?;
            let Some(sums) = weighed else {
                tracing::trace!(
                    class = class_idx,
                    ?bbox,
                    area,
                    "speckle: nothing left after opening"
                );
                out.rejected += 1;
                continue;
            };
            let m = imgproc::moments(&self.comp_weight, false)?;
            let (center, spread) = if m.m00 > 0.0 {
                (
                    [
                        m.m10 / m.m00 + (local.x + roi.x) as f64,
                        m.m01 / m.m00 + (local.y + roi.y) as f64,
                    ],
                    [m.mu20 / m.m00, m.mu11 / m.m00, m.mu02 / m.m00],
                )
            } else {
                // The component's centroid in the region, as OpenCV's statistics give it
                // (the sums of the pixels' coordinates over their count).
                let count = area as f64;
                (
                    [
                        sums[0] as f64 / count + roi.x as f64,
                        sums[1] as f64 / count + roi.y as f64,
                    ],
                    [0.0; 3],
                )
            };
            let blob = Blob {
                class: class_idx,
                center,
                area,
                bbox,
                depth_m,
                spread,
            };
            if faint {
                out.faint.push(blob);
            } else {
                out.blobs.push(blob);
            }
        }
        Ok(())
    }
}

/// Every class's colour thresholds as bit tables: one bit per (class, hue range) pair, set in
/// `hue[h]` when `h` is within that hue range, in `saturation[s]` and `value[v]` when they are
/// within the class's. A pixel is in a class's hue range exactly when the three entries of its
/// H, S and V share that bit: OpenCV's `inRange` (bounds included) of every range of every
/// class, ORed per class, in one pass over the region instead of one `inRange` per range, and
/// three table reads per pixel instead of six comparisons per range.
#[derive(Debug, Clone)]
struct RangeBits {
    hue: [u32; 256],
    saturation: [u32; 256],
    value: [u32; 256],
    /// Per class, the bits of its hue ranges.
    class: Vec<u32>,
}

impl RangeBits {
    /// `classes` as validated ([`config::MAX_HUE_RANGES`] ranges at most).
    fn new(classes: &[ColorClass]) -> Self {
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
    fn classify(&self, hsv: &[u8], out: &mut Vec<u32>) {
        out.clear();
        out.extend(hsv.chunks_exact(3).map(|p| {
            self.hue[p[0] as usize] & self.saturation[p[1] as usize] & self.value[p[2] as usize]
        }));
    }

    /// Class `class_idx`'s mask (255 inside, 0 outside) from the pixels' bits.
    fn class_mask(&self, class_idx: usize, pixel_bits: &[u32], mask: &mut [u8]) {
        let class = self.class[class_idx];
        for (m, &b) in mask.iter_mut().zip(pixel_bits) {
            *m = if b & class != 0 { 255 } else { 0 };
        }
    }
}

/// The box holding `mask`'s non-zero pixels grown by one pixel, its corner moved to even
/// coordinates, cut to the mask; `None` for an empty mask.
fn mask_box(mask: &Mat) -> Result<Option<PixelRect>, DetectError> {
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
struct ComponentImages<'a> {
    /// Connected-component labels over `crop` (region coordinates).
    labels: &'a Mat,
    crop: PixelRect,
    /// The region in HSV.
    hsv: &'a Mat,
    /// The opened mask over the region, when the class mask is opened.
    opened: Option<&'a Mat>,
    /// The class's weight table ([`weight_table`]).
    weights: &'a [u8],
}

/// Component `label`'s colour weight over `local` (region coordinates): the weight of each
/// pixel of the component grown by one pixel (a 3x3 dilation within `local`), 0 elsewhere,
/// into `out` (`local`'s size). Returns the sums of the component's own pixels' coordinates
/// in the region, or `None` when the opened mask keeps none of its pixels.
fn component_weight(
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

/// A class's colour weight per hue and saturation, `[hue * 256 + saturation]`: the hue
/// weight times the saturation weight over 255, computed by OpenCV's `LUT` and `multiply`
/// (as the per-pixel weight image once was), so each value is OpenCV's to the bit.
fn weight_table(hue: &[u8; 256], sat: &[u8; 256]) -> Result<Vec<u8>, DetectError> {
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

/// Median of the valid depth readings (metres, inside `range`) in `bbox` grown by `grow`.
fn median_depth_near(
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

/// Hue → weight: 255 over the inner half of each range, falling linearly to 0 at `margin`
/// hue units beyond its ends (the hue circle wraps at 180).
fn hue_weight_table(ranges: &[[u8; 2]], margin: u8) -> [u8; 256] {
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
fn saturation_weight_table([lo, _hi]: [u8; 2]) -> [u8; 256] {
    let mut table = [0u8; 256];
    let start = lo as f64 / 2.0;
    let end = (lo as f64).max(start + 1.0);
    for (s, slot) in table.iter_mut().enumerate() {
        let w = ((s as f64 - start) / (end - start)).clamp(0.0, 1.0);
        *slot = (w * 255.0).round() as u8;
    }
    table
}

#[cfg(test)]
mod tests;
