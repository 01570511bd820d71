//! Rasterising: the cameras the mesh is projected into, projected vertices, and the
//! z-buffer of per-pixel surface attributes (depth, shading, facing, albedo, material
//! coordinates) filled from front-facing triangles.

use mouthpiece_frame::{Extrinsics, Intrinsics};

use super::NO_MATERIAL;

#[derive(Clone, Copy, Default)]
pub(super) struct ScreenVert {
    pub(super) x: f32,
    pub(super) y: f32,
    pub(super) z: f32,
    pub(super) shade: f32,
    pub(super) facing: f32,
    pub(super) albedo: [f32; 3],
    pub(super) material: [f32; 2],
    pub(super) valid: bool,
}

/// Per-pixel surface attributes of one camera.
pub(super) struct Buffers {
    pub(super) w: usize,
    pub(super) h: usize,
    pub(super) z: Vec<f32>,
    pub(super) shade: Vec<f32>,
    pub(super) facing: Vec<f32>,
    pub(super) albedo: Vec<[f32; 3]>,
    pub(super) material: Vec<[f32; 2]>,
}

impl Buffers {
    pub(super) fn new(w: usize, h: usize) -> Self {
        let n = w * h;
        Self {
            w,
            h,
            z: vec![f32::INFINITY; n],
            shade: vec![0.0; n],
            facing: vec![0.0; n],
            albedo: vec![[0.0; 3]; n],
            material: vec![NO_MATERIAL; n],
        }
    }

    pub(super) fn clear(&mut self) {
        self.z.fill(f32::INFINITY);
    }

    /// Rasterises front-facing triangles; pixel (i, j) samples the image point (i, j).
    pub(super) fn raster(&mut self, verts: &[ScreenVert], tris: &[[u32; 3]]) {
        let (w, h) = (self.w as i32, self.h as i32);
        for t in tris {
            let (a, b, c) = (
                &verts[t[0] as usize],
                &verts[t[1] as usize],
                &verts[t[2] as usize],
            );
            if !(a.valid && b.valid && c.valid) {
                continue;
            }
            let area = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
            if area <= 1e-12 {
                continue; // back face or degenerate
            }
            let x0 = a.x.min(b.x).min(c.x).ceil().max(0.0) as i32;
            let x1 = (a.x.max(b.x).max(c.x).floor() as i32).min(w - 1);
            let y0 = a.y.min(b.y).min(c.y).ceil().max(0.0) as i32;
            let y1 = (a.y.max(b.y).max(c.y).floor() as i32).min(h - 1);
            if x0 > x1 || y0 > y1 {
                continue;
            }
            let inv = 1.0 / area;
            for py in y0..=y1 {
                let fy = py as f32;
                for px in x0..=x1 {
                    let fx = px as f32;
                    let w0 = ((c.x - b.x) * (fy - b.y) - (c.y - b.y) * (fx - b.x)) * inv;
                    let w1 = ((a.x - c.x) * (fy - c.y) - (a.y - c.y) * (fx - c.x)) * inv;
                    let w2 = 1.0 - w0 - w1;
                    if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                        continue;
                    }
                    let z = w0 * a.z + w1 * b.z + w2 * c.z;
                    let i = py as usize * self.w + px as usize;
                    if z >= self.z[i] {
                        continue;
                    }
                    self.z[i] = z;
                    self.shade[i] = w0 * a.shade + w1 * b.shade + w2 * c.shade;
                    self.facing[i] = w0 * a.facing + w1 * b.facing + w2 * c.facing;
                    self.albedo[i] = [
                        w0 * a.albedo[0] + w1 * b.albedo[0] + w2 * c.albedo[0],
                        w0 * a.albedo[1] + w1 * b.albedo[1] + w2 * c.albedo[1],
                        w0 * a.albedo[2] + w1 * b.albedo[2] + w2 * c.albedo[2],
                    ];
                    self.material[i] = [
                        w0 * a.material[0] + w1 * b.material[0] + w2 * c.material[0],
                        w0 * a.material[1] + w1 * b.material[1] + w2 * c.material[1],
                    ];
                }
            }
        }
    }
}

/// A camera the mesh is projected into.
pub(super) struct View {
    pub(super) k: Intrinsics,
    /// Colour camera frame → this camera's frame (identity for the colour camera).
    pub(super) from_color: Extrinsics,
}

impl View {
    pub(super) fn project(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        let p = self.from_color.apply(p);
        if p[2] <= 0.01 {
            return None;
        }
        self.k.project(p)
    }
}
