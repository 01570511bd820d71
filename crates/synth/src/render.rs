//! Rendering one frame: deform and pose the mesh, rasterise it with a z-buffer (per-pixel
//! depth, shading, albedo, material coordinates), paint the dots in material space, compose
//! colour with lighting and sensor effects, and derive depth with a sensor noise model.
//!
//! Speed: the mesh is ≈ 50k triangles, nearly all of a pixel or less; buffers are allocated
//! once; noise uses a precomputed Gaussian table indexed by a per-frame xorshift stream.

mod raster;
mod sensor;

use mouthpiece_frame::{ColorImage, DepthImage, Extrinsics};
use mouthpiece_recording::{GroundTruth, HeadPose};

use crate::head::{self, Attrs, Geometry};
use crate::motion::{HeadState, MouthState};
use crate::rng::{GaussTable, Rng};
use crate::{NoiseModel, SynthConfig};

use raster::{Buffers, ScreenVert, View};
use sensor::depth_image;

/// The booth behind the performer: a wall 1.8 m away lined with dark acoustic foam, which
/// absorbs the sensor's infrared: no depth reading there unless the noise model is `None`.
const WALL_Z: f32 = 1.8;
const WALL_RGB: [f32; 3] = [0.22, 0.23, 0.25];
/// Material coordinates given to surfaces that carry no paint (teeth).
const NO_MATERIAL: [f32; 2] = [100.0, 100.0];

pub(crate) struct RenderOutput {
    pub color: ColorImage,
    pub depth: DepthImage,
    pub ground_truth: GroundTruth,
}

struct Dot {
    name: String,
    attrs: Attrs,
    material: [f32; 2],
    /// Metres per unit of material a and v at the dot.
    metric: [f32; 2],
    /// Linear RGB paint.
    paint: [f32; 3],
    /// Paint radius, metres.
    radius_m: f64,
    is_lip: bool,
}

pub(crate) struct Renderer {
    geo: Geometry,
    dots: Vec<Dot>,
    distance: f64,
    noise: NoiseModel,
    effects: bool,
    color_view: View,
    depth_view: Option<View>,
    pos: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
    screen: Vec<ScreenVert>,
    color_buf: Buffers,
    depth_buf: Option<Buffers>,
    light_map: Vec<f32>,
    gauss: GaussTable,
    seed: u64,
    exposure_phase: [f64; 2],
    clean: Vec<u8>,
    prev_clean: Vec<u8>,
    prev_lip_px: Vec<Option<[f64; 2]>>,
}

fn mul3(m: &[[f64; 3]; 3], p: [f64; 3]) -> [f64; 3] {
    [
        m[0][0] * p[0] + m[0][1] * p[1] + m[0][2] * p[2],
        m[1][0] * p[0] + m[1][1] * p[1] + m[1][2] * p[2],
        m[2][0] * p[0] + m[2][1] * p[1] + m[2][2] * p[2],
    ]
}

fn matmul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    m
}

/// Head rotation: yaw about y, then pitch about x, then roll about z (camera axes).
fn head_rotation(h: &HeadState) -> [[f64; 3]; 3] {
    let (sy, cy) = h.yaw.sin_cos();
    let (sp, cp) = h.pitch.sin_cos();
    let (sr, cr) = h.roll.sin_cos();
    let ry = [[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]];
    let rx = [[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]];
    let rz = [[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]];
    matmul(&ry, &matmul(&rx, &rz))
}

fn quaternion(m: &[[f64; 3]; 3]) -> [f64; 4] {
    let tr = m[0][0] + m[1][1] + m[2][2];
    let q = if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [
            0.25 * s,
            (m[2][1] - m[1][2]) / s,
            (m[0][2] - m[2][0]) / s,
            (m[1][0] - m[0][1]) / s,
        ]
    } else if m[0][0] > m[1][1] && m[0][0] > m[2][2] {
        let s = (1.0 + m[0][0] - m[1][1] - m[2][2]).sqrt() * 2.0;
        [
            (m[2][1] - m[1][2]) / s,
            0.25 * s,
            (m[0][1] + m[1][0]) / s,
            (m[0][2] + m[2][0]) / s,
        ]
    } else if m[1][1] > m[2][2] {
        let s = (1.0 + m[1][1] - m[0][0] - m[2][2]).sqrt() * 2.0;
        [
            (m[0][2] - m[2][0]) / s,
            (m[0][1] + m[1][0]) / s,
            0.25 * s,
            (m[1][2] + m[2][1]) / s,
        ]
    } else {
        let s = (1.0 + m[2][2] - m[0][0] - m[1][1]).sqrt() * 2.0;
        [
            (m[1][0] - m[0][1]) / s,
            (m[0][2] + m[2][0]) / s,
            (m[1][2] + m[2][1]) / s,
            0.25 * s,
        ]
    };
    // Canonical sign: w ≥ 0.
    if q[0] < 0.0 {
        [-q[0], -q[1], -q[2], -q[3]]
    } else {
        q
    }
}

fn invert(e: &Extrinsics) -> Extrinsics {
    let r = e.rotation;
    let rt = [
        [r[0][0], r[1][0], r[2][0]],
        [r[0][1], r[1][1], r[2][1]],
        [r[0][2], r[1][2], r[2][2]],
    ];
    let t = mul3(&rt, e.translation);
    Extrinsics {
        rotation: rt,
        translation: [-t[0], -t[1], -t[2]],
    }
}

impl Renderer {
    pub fn new(cfg: &SynthConfig) -> Self {
        let layout = &cfg.layout;
        let lin = |c: [u8; 3]| {
            [
                c[0] as f32 / 255.0,
                c[1] as f32 / 255.0,
                c[2] as f32 / 255.0,
            ]
        };
        let geo = match layout.lip_skin_color {
            Some(c) => Geometry::with_lip_colour(lin(c)),
            None => Geometry::new(),
        };
        let mut dots = Vec::new();
        let names = layout.names();
        let mut materials = head::lip_dot_material(layout.lip_dots, geo.zc);
        materials.extend(
            layout
                .forehead
                .iter()
                .map(|f| head::front_material(f.x_mm / 1000.0, f.y_mm / 1000.0)),
        );
        for (k, (name, (a, v))) in names.into_iter().zip(materials).enumerate() {
            let is_lip = k < layout.lip_dots;
            let (ma, mv) = head::material_metric(a, v, geo.zc);
            dots.push(Dot {
                name,
                attrs: head::attrs_at(a, v, geo.zc),
                material: [a as f32, v as f32],
                metric: [ma as f32, mv as f32],
                paint: lin(if is_lip {
                    layout.lip_color
                } else {
                    layout.forehead_color
                }),
                radius_m: if is_lip {
                    layout.radius_mm
                } else {
                    layout.forehead_radius_mm
                } / 1000.0,
                is_lip,
            });
        }
        let (w, h) = (cfg.camera.width as usize, cfg.camera.height as usize);
        let light_map = (0..w * h)
            .map(|i| {
                if !cfg.colour_effects {
                    return 1.0;
                }
                let (x, y) = (
                    (i % w) as f32 / w as f32 - 0.5,
                    (i / w) as f32 / h as f32 - 0.5,
                );
                // Vignetting and a brighter left side (a key light off to one side).
                (1.0 - 0.35 * (x * x + y * y)) * (1.0 - 0.16 * x)
            })
            .collect();
        let depth_view = cfg.depth_camera.as_ref().map(|(k, depth_to_color)| View {
            k: *k,
            from_color: invert(depth_to_color),
        });
        let depth_buf = cfg
            .depth_camera
            .as_ref()
            .map(|(k, _)| Buffers::new(k.width as usize, k.height as usize));
        let mut rng = Rng::new(cfg.seed ^ 0xe4905);
        let n = geo.attrs.len();
        Self {
            dots,
            distance: cfg.distance_m,
            noise: cfg.noise,
            effects: cfg.colour_effects,
            color_view: View {
                k: cfg.camera,
                from_color: Extrinsics::IDENTITY,
            },
            depth_view,
            pos: Vec::with_capacity(n),
            normals: Vec::with_capacity(n),
            screen: vec![ScreenVert::default(); n],
            color_buf: Buffers::new(w, h),
            depth_buf,
            light_map,
            gauss: GaussTable::new(cfg.seed),
            seed: cfg.seed,
            exposure_phase: [
                rng.range(0.0, std::f64::consts::TAU),
                rng.range(0.0, std::f64::consts::TAU),
            ],
            clean: vec![0; w * h * 3],
            prev_clean: Vec::new(),
            prev_lip_px: Vec::new(),
            geo,
        }
    }

    pub fn dot_names(&self) -> Vec<String> {
        self.dots.iter().map(|d| d.name.clone()).collect()
    }

    pub fn render(
        &mut self,
        index: u64,
        t: f64,
        mouth: &MouthState,
        head_state: &HeadState,
        jaw: &head::JawPose,
    ) -> RenderOutput {
        let rot = head_rotation(head_state);
        let base = [0.0, 0.0, self.distance];
        let pivot = [
            head::PIVOT[0] + base[0],
            head::PIVOT[1] + base[1],
            head::PIVOT[2] + base[2],
        ];
        let tr = head_state.translation;
        // H frame → camera: p_cam = R (p + base - pivot) + pivot + tr.
        let to_camera = |p: [f64; 3]| {
            let q = mul3(
                &rot,
                [
                    p[0] + base[0] - pivot[0],
                    p[1] + base[1] - pivot[1],
                    p[2] + base[2] - pivot[2],
                ],
            );
            [
                q[0] + pivot[0] + tr[0],
                q[1] + pivot[1] + tr[1],
                q[2] + pivot[2] + tr[2],
            ]
        };

        // Mesh.
        self.pos.clear();
        self.pos.extend(
            self.geo
                .attrs
                .iter()
                .map(|a| head::deform_with(a, mouth, jaw)),
        );
        let mut normals = std::mem::take(&mut self.normals);
        self.geo.normals(&self.pos, &mut normals);
        self.normals = normals;
        let light = {
            let l = [-0.35f64, -0.45, -0.8];
            let n = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
            [l[0] / n, l[1] / n, l[2] / n]
        };
        let cam_pos: Vec<[f64; 3]> = self.pos.iter().map(|&p| to_camera(p)).collect();
        for (i, sv) in self.screen.iter_mut().enumerate() {
            let p = cam_pos[i];
            let n = mul3(&rot, self.normals[i]);
            let dist = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            let facing = -(n[0] * p[0] + n[1] * p[1] + n[2] * p[2]) / dist;
            let diffuse = (n[0] * light[0] + n[1] * light[1] + n[2] * light[2]).max(0.0);
            let at = &self.geo.attrs[i];
            *sv = match self.color_view.project(p) {
                Some([x, y]) => ScreenVert {
                    x: x as f32,
                    y: y as f32,
                    z: p[2] as f32,
                    shade: (0.3 + 0.7 * diffuse) as f32,
                    facing: facing.max(0.0) as f32,
                    albedo: at.albedo,
                    material: self.geo.material[i],
                    valid: true,
                },
                None => ScreenVert::default(),
            };
        }
        self.color_buf.clear();
        self.color_buf.raster(&self.screen, &self.geo.tris);

        // Dots: exact centres, visibility, paint.
        let mut points = std::collections::BTreeMap::new();
        let mut visible = std::collections::BTreeMap::new();
        let mut lip_px = Vec::with_capacity(self.dots.len());
        for dot in &self.dots {
            let r2 = (dot.radius_m * dot.radius_m) as f32;
            let centre = to_camera(head::deform_with(&dot.attrs, mouth, jaw));
            points.insert(dot.name.clone(), centre);
            let px = self.color_view.project(centre);
            let mut seen = false;
            if let Some([u, v]) = px {
                let buf = &mut self.color_buf;
                let (cu, cv) = (u.round() as i64, v.round() as i64);
                if cu >= 0 && cv >= 0 && (cu as usize) < buf.w && (cv as usize) < buf.h {
                    let i = cv as usize * buf.w + cu as usize;
                    let m = buf.material[i];
                    let d = ((m[0] - dot.material[0]) * dot.metric[0]).powi(2)
                        + ((m[1] - dot.material[1]) * dot.metric[1]).powi(2);
                    // Visible exactly when the surface the camera sees at the centre's pixel
                    // is this dot's paint: a hidden dot never shows there.
                    seen = buf.z[i].is_finite() && d <= r2;
                }
                // Paint every pixel whose surface is this dot's material.
                let reach =
                    (dot.radius_m * self.color_view.k.fx / centre[2] * 2.0 + 3.0).ceil() as i64;
                let (xa, xb) = ((cu - reach).max(0), (cu + reach).min(buf.w as i64 - 1));
                let (ya, yb) = ((cv - reach).max(0), (cv + reach).min(buf.h as i64 - 1));
                for y in ya..=yb {
                    for x in xa..=xb {
                        let i = y as usize * buf.w + x as usize;
                        if !buf.z[i].is_finite() {
                            continue;
                        }
                        let m = buf.material[i];
                        let d = ((m[0] - dot.material[0]) * dot.metric[0]).powi(2)
                            + ((m[1] - dot.material[1]) * dot.metric[1]).powi(2);
                        if d <= r2 {
                            buf.albedo[i] = dot.paint;
                        }
                    }
                }
            }
            visible.insert(dot.name.clone(), seen);
            if dot.is_lip {
                lip_px.push(px);
            }
        }

        let color = self.compose_color(index, t, &lip_px);
        self.prev_lip_px = lip_px;

        // Depth from the colour camera (registered) or from the depth camera.
        let depth = match (&self.depth_view, &mut self.depth_buf) {
            (Some(view), Some(buf)) => {
                for (i, sv) in self.screen.iter_mut().enumerate() {
                    let p = view.from_color.apply(cam_pos[i]);
                    sv.valid = false;
                    if let Some([x, y]) = view.project(cam_pos[i]) {
                        sv.x = x as f32;
                        sv.y = y as f32;
                        sv.z = p[2] as f32;
                        let n = view.from_color.rotation;
                        let nn = mul3(&n, mul3(&rot, self.normals[i]));
                        let dist = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                        sv.facing =
                            (-(nn[0] * p[0] + nn[1] * p[1] + nn[2] * p[2]) / dist).max(0.0) as f32;
                        sv.valid = true;
                    }
                }
                buf.clear();
                buf.raster(&self.screen, &self.geo.tris);
                depth_image(buf, self.noise, &self.gauss, self.seed, index, view.k.fx)
            }
            _ => depth_image(
                &self.color_buf,
                self.noise,
                &self.gauss,
                self.seed,
                index,
                self.color_view.k.fx,
            ),
        };

        let neutral_pivot = pivot;
        let rp = mul3(&rot, neutral_pivot);
        let translation = [
            neutral_pivot[0] + tr[0] - rp[0],
            neutral_pivot[1] + tr[1] - rp[1],
            neutral_pivot[2] + tr[2] - rp[2],
        ];
        let ground_truth = GroundTruth {
            t,
            points,
            visible,
            head: HeadPose {
                rotation: quaternion(&rot),
                translation,
            },
            mouth: Some(mouthpiece_recording::MouthTruth {
                jaw: mouth.jaw,
                spread: mouth.spread,
                round: mouth.round,
                raise: mouth.raise,
                roll_in: mouth.roll_in,
                slide: jaw.slide[0],
                glide: jaw.slide[1],
            }),
        };
        RenderOutput {
            color,
            depth,
            ground_truth,
        }
    }
}
