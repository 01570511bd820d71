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

mod component;
mod config;
mod tables;
pub mod tune;

use opencv::core::{
    self, Mat, MatTrait, MatTraitConst, MatTraitConstManual, MatTraitManual, Rect, Size, Vec3b,
};
use opencv::imgproc;

use mouthpiece_frame::{ColorImage, DepthImage};

use component::{component_weight, mask_box, median_depth_near, ComponentImages};
use tables::{hue_weight_table, saturation_weight_table, weight_table, RangeBits};

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

    /// The pixels between the two along the axis they lie furthest apart on: 0 when they
    /// share a pixel or touch.
    pub fn gap(&self, other: &PixelRect) -> i32 {
        let apart =
            |a0: i32, a_len: i32, b0: i32, b_len: i32| (b0 - (a0 + a_len)).max(a0 - (b0 + b_len));
        apart(self.x, self.width, other.x, other.width)
            .max(apart(self.y, self.height, other.y, other.height))
            .max(0)
    }

    /// The smallest rectangle holding both.
    pub fn union(&self, other: &PixelRect) -> PixelRect {
        let (x0, y0) = (self.x.min(other.x), self.y.min(other.y));
        let x1 = (self.x + self.width).max(other.x + other.width);
        let y1 = (self.y + self.height).max(other.y + other.height);
        PixelRect {
            x: x0,
            y: y0,
            width: x1 - x0,
            height: y1 - y0,
        }
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
    /// The rectangles actually searched (clipped to the image), in the order searched; empty
    /// when nothing was.
    pub searched: Vec<PixelRect>,
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

/// One search region's images, kept between frames.
#[derive(Default)]
struct RegionImages {
    /// The region in HSV.
    hsv: Mat,
    /// Per pixel of the region, the bits of the (class, hue range) pairs it falls in.
    pixel_bits: Vec<u32>,
}

/// The detector, with its scratch images kept between frames so a frame allocates nothing
/// once sizes settle.
pub struct Detector {
    config: DetectConfig,
    /// Per class: the colour weight (0–255) of each hue and saturation, `[hue * 256 +
    /// saturation]` ([`weight_table`]).
    weights: Vec<Vec<u8>>,
    kernel: Mat,
    /// Per region searched this frame: its HSV image and class bits (kept per region, so
    /// that regions of different sizes do not reallocate each other's every frame).
    regions: Vec<RegionImages>,
    /// The colour thresholds of every class as bit tables ([`RangeBits`]).
    range_bits: RangeBits,
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
            regions: Vec::new(),
            range_bits,
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

    /// Finds dot candidates of every class inside `search` (the full frame when `None`);
    /// [`Self::detect_into`] searches several regions.
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
        let regions = search.map(|r| [r]);
        self.detect_into(color, depth, fx, regions.as_ref().map(|r| &r[..]), &mut out)?;
        Ok(out)
    }

    /// As [`Self::detect`] over each of the regions `search` (the full frame when `None`),
    /// into `out` (its lists are reused: no allocation once they have grown to a frame's
    /// count). The regions should not overlap (a blob in two is found twice). Blobs come
    /// class by class, and within a class region by region in the order given.
    pub fn detect_into(
        &mut self,
        color: &ColorImage,
        depth: Option<(&DepthImage, f64)>,
        fx: f64,
        search: Option<&[PixelRect]>,
        out: &mut Detections,
    ) -> Result<(), DetectError> {
        out.blobs.clear();
        out.faint.clear();
        out.searched.clear();
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
        let full = [PixelRect::full(color.width, color.height)];
        let regions = search.unwrap_or(&full);
        let image = Mat::new_rows_cols_with_bytes::<Vec3b>(
            color.height as i32,
            color.width as i32,
            &color.data,
        )?;
        for roi in regions
            .iter()
            .filter_map(|r| r.clip(color.width, color.height))
        {
            let k = out.searched.len();
            if self.regions.len() <= k {
                self.regions.push(RegionImages::default());
            }
            let region = &mut self.regions[k];
            let image_roi = Mat::roi(&image, roi.to_cv())?;
            imgproc::cvt_color_def(&image_roi, &mut region.hsv, imgproc::COLOR_BGR2HSV)?;
            self.range_bits
                .classify(region.hsv.data_bytes()?, &mut region.pixel_bits);
            out.searched.push(roi);
        }
        for class_idx in 0..self.config.classes.len() {
            for region in 0..out.searched.len() {
                self.detect_class(class_idx, region, depth, fx, out)?;
            }
        }
        tracing::trace!(
            regions = ?out.searched,
            found = out.blobs.len(),
            rejected = out.rejected,
            "detected"
        );
        Ok(())
    }

    /// The blobs of colour class `class_idx` in the searched region `region` (an index into
    /// `out.searched` and [`Self::regions`]), appended to `out`.
    fn detect_class(
        &mut self,
        class_idx: usize,
        region: usize,
        depth: Option<(&DepthImage, f64)>,
        fx: f64,
        out: &mut Detections,
    ) -> Result<(), DetectError> {
        // The region as clipped to the image; its pixels' class bits are `regions[region]`.
        let roi = out.searched[region];
        let images = &self.regions[region];
        // SAFETY: `class_mask` writes every byte of the new matrix.
        unsafe {
            self.mask
                .create_rows_cols(images.hsv.rows(), images.hsv.cols(), core::CV_8UC1)?
        };
        self.range_bits
            .class_mask(class_idx, &images.pixel_bits, self.mask.data_bytes_mut()?);
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
                    hsv: &self.regions[region].hsv,
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

#[cfg(test)]
mod tests;
