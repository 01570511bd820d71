//! Sensor models: the colour image composed from the z-buffer with lighting, exposure drift,
//! motion blur and sensor noise, and the depth image through the configured noise model
//! (Kinect-like correlated disparity noise and dropouts, RealSense-like noise and holes).

use mouthpiece_frame::{ColorImage, DepthImage};

use super::raster::Buffers;
use super::{Renderer, WALL_RGB, WALL_Z};
use crate::rng::{FastRng, GaussTable};
use crate::NoiseModel;

impl Renderer {
    pub(super) fn compose_color(
        &mut self,
        index: u64,
        t: f64,
        lip_px: &[Option<[f64; 2]>],
    ) -> ColorImage {
        let buf = &self.color_buf;
        let exposure = if self.effects {
            let tau = std::f64::consts::TAU;
            (1.0 + 0.05 * (tau * t / 11.0 + self.exposure_phase[0]).sin()
                + 0.025 * (tau * t / 3.7 + self.exposure_phase[1]).sin()) as f32
        } else {
            1.0
        };
        for i in 0..buf.w * buf.h {
            let (rgb, gain) = if buf.z[i].is_finite() {
                (buf.albedo[i], buf.shade[i])
            } else {
                (WALL_RGB, 0.9)
            };
            let g = gain * self.light_map[i] * exposure * 255.0;
            let o = i * 3;
            self.clean[o] = (rgb[2] * g).clamp(0.0, 255.0) as u8;
            self.clean[o + 1] = (rgb[1] * g).clamp(0.0, 255.0) as u8;
            self.clean[o + 2] = (rgb[0] * g).clamp(0.0, 255.0) as u8;
        }
        // Motion blur where the lips move fast: the exposure also saw where they just were.
        if self.effects && self.prev_clean.len() == self.clean.len() {
            let mut speed: f64 = 0.0;
            let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
            for (now, before) in lip_px.iter().zip(&self.prev_lip_px) {
                if let (Some(a), Some(b)) = (now, before) {
                    speed = speed.max(((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt());
                    x0 = x0.min(a[0]).min(b[0]);
                    y0 = y0.min(a[1]).min(b[1]);
                    x1 = x1.max(a[0]).max(b[0]);
                    y1 = y1.max(a[1]).max(b[1]);
                }
            }
            let alpha = ((speed - 1.5) / 10.0).clamp(0.0, 0.4) as f32;
            if alpha > 0.0 {
                let margin = 12.0;
                let xa = (x0 - margin).max(0.0) as usize;
                let xb = ((x1 + margin) as usize).min(buf.w - 1);
                let ya = (y0 - margin).max(0.0) as usize;
                let yb = ((y1 + margin) as usize).min(buf.h - 1);
                for y in ya..=yb {
                    for o in (y * buf.w + xa) * 3..(y * buf.w + xb + 1) * 3 {
                        let v = self.clean[o] as f32 * (1.0 - alpha)
                            + self.prev_clean[o] as f32 * alpha;
                        self.clean[o] = v.round() as u8;
                    }
                }
            }
        }
        let mut out = ColorImage {
            width: buf.w as u32,
            height: buf.h as u32,
            data: self.clean.clone(),
        };
        if self.effects {
            // Sensor noise: read noise plus a shot-noise-like part growing with the signal.
            let mut rng = FastRng::new(self.seed ^ index.wrapping_mul(0x9e37_79b9) ^ 0xc010);
            for v in out.data.iter_mut() {
                let sigma = 1.5 + 0.012 * *v as f32;
                let n = self.gauss.get(rng.next() >> 20) * sigma;
                *v = (*v as f32 + n).round().clamp(0.0, 255.0) as u8;
            }
        }
        std::mem::swap(&mut self.prev_clean, &mut self.clean);
        if self.clean.len() != self.prev_clean.len() {
            self.clean = vec![0; self.prev_clean.len()];
        }
        out
    }
}

/// Depth in millimetres from a z-buffer, through a sensor model.
pub(super) fn depth_image(
    buf: &Buffers,
    noise: NoiseModel,
    gauss: &GaussTable,
    seed: u64,
    index: u64,
    fx: f64,
) -> DepthImage {
    let (w, h) = (buf.w, buf.h);
    let mut out = DepthImage::new(w as u32, h as u32);
    let mut rng = FastRng::new(seed ^ index.wrapping_mul(0x51_7cc1_b727_220a) ^ 0xde97);
    let z_at = |i: usize| {
        if buf.z[i].is_finite() {
            buf.z[i]
        } else {
            WALL_Z
        }
    };
    match noise {
        NoiseModel::None => {
            for i in 0..w * h {
                out.data[i] = (z_at(i) * 1000.0).round() as u16;
            }
        }
        NoiseModel::Kinect => {
            // Disparity in 1/8 px for a 75 mm baseline at this focal length; σ chosen for
            // 1.5 mm at 0.6 m.
            let fb8 = (8.0 * 0.075 * fx) as f32;
            let sigma_d = 0.0015 * fb8 / (0.6 * 0.6);
            // The sensor matches correlation windows, so its disparity error is spatially
            // correlated: a smooth field (Gaussian nodes every 4 px, bilinear between them; the
            // 1.5 factor restores the per-pixel σ that interpolation averages away) plus a
            // small independent part.
            let (gw, gh) = (w / 4 + 2, h / 4 + 2);
            let field: Vec<f32> = (0..gw * gh)
                .map(|_| gauss.get(rng.next() >> 20) * sigma_d * 1.5)
                .collect();
            for y in 0..h {
                for x in 0..w {
                    let i = y * w + x;
                    let z = z_at(i);
                    let head = buf.z[i].is_finite();
                    if !head {
                        out.data[i] = 0;
                        continue;
                    }
                    let mut drop_p: f32 = 0.0;
                    {
                        let f = buf.facing[i];
                        if f < 0.25 {
                            drop_p = drop_p.max(0.9 * (1.0 - f / 0.25));
                        }
                        let a = buf.albedo[i];
                        let lum = 0.3 * a[0] + 0.59 * a[1] + 0.11 * a[2];
                        if lum < 0.2 {
                            drop_p = drop_p.max(0.85);
                        }
                    }
                    // Silhouette edges: a neighbour much nearer or farther.
                    let edge = [
                        (x > 0, i.wrapping_sub(1)),
                        (x + 1 < w, i + 1),
                        (y > 0, i.wrapping_sub(w)),
                        (y + 1 < h, i + w),
                    ]
                    .iter()
                    .any(|&(ok, j)| ok && (z_at(j) - z).abs() > 0.03);
                    if edge {
                        drop_p = drop_p.max(0.75);
                    }
                    if drop_p > 0.0 && rng.unit() < drop_p {
                        out.data[i] = 0;
                        continue;
                    }
                    let (gx, fx_) = (x / 4, (x % 4) as f32 / 4.0);
                    let (gy, fy_) = (y / 4, (y % 4) as f32 / 4.0);
                    let n00 = field[gy * gw + gx];
                    let n10 = field[gy * gw + gx + 1];
                    let n01 = field[(gy + 1) * gw + gx];
                    let n11 = field[(gy + 1) * gw + gx + 1];
                    let smooth = (n00 * (1.0 - fx_) + n10 * fx_) * (1.0 - fy_)
                        + (n01 * (1.0 - fx_) + n11 * fx_) * fy_;
                    let d = fb8 / z + smooth + gauss.get(rng.next() >> 20) * sigma_d * 0.25;
                    let q = d.round().max(1.0);
                    out.data[i] = ((fb8 / q) * 1000.0).round().min(65535.0) as u16;
                }
            }
        }
        NoiseModel::Realsense => {
            for i in 0..w * h {
                if !buf.z[i].is_finite() {
                    out.data[i] = 0;
                    continue;
                }
                let z = z_at(i);
                let noisy = z * (1.0 + 0.005 * gauss.get(rng.next() >> 20));
                out.data[i] = (noisy * 1000.0).round().clamp(0.0, 65535.0) as u16;
                if buf.facing[i] < 0.15 && rng.unit() < 0.7 {
                    out.data[i] = 0;
                }
            }
            // Speckle holes: small blobs where stereo matching failed.
            let holes = (w * h) / 700;
            for _ in 0..holes {
                let cx = (rng.next() % w as u64) as i64;
                let cy = (rng.next() % h as u64) as i64;
                let r = 1 + (rng.next() % 2) as i64;
                for y in (cy - r).max(0)..=(cy + r).min(h as i64 - 1) {
                    for x in (cx - r).max(0)..=(cx + r).min(w as i64 - 1) {
                        if (x - cx).pow(2) + (y - cy).pow(2) <= r * r {
                            out.data[y as usize * w + x as usize] = 0;
                        }
                    }
                }
            }
        }
    }
    out
}
