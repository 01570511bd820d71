//! The analytic head: a smooth surface given by material coordinates (azimuth `a` around a
//! vertical axis, height `v`), its deformation by the mouth state, and the mesh it is
//! rendered from.
//!
//! Head frame `H`: origin at the mouth centre (midpoint of the corners, neutral), axes those of
//! the camera when the head is neutral (x = performer's left, y down, z into the head), metres.
//!
//! Everything is Lagrangian: a material point (a dot, a vertex) has attributes computed once
//! ([`Attrs`]) and its position in a frame is [`deform`]`(attrs, mouth)`. Dots are painted on the
//! material, so their exact centres come from the same function as the mesh, and they are
//! hidden exactly when the rendered surface in front of them is other material.

use crate::motion::{smoothstep, MouthState};

/// Half the mouth width (corner to corner ≈ 50 mm).
pub const HALF_MOUTH: f64 = 0.025;
/// Arc radius used to turn azimuth into a lateral distance for the facial features.
const E0: f64 = 0.09;
/// Vertical centre and semi-axis of the skull (H frame).
const VC: f64 = -0.06;
const VH: f64 = 0.14;
/// Half the gap between the two material rows at the lip seam.
pub const SEAM_EPS: f64 = 0.0002;
/// Jaw hinge (temporomandibular axis), parallel to x, at this (y, z): 25 mm above and 80 mm
/// behind the mouth centre. `JawPose` can place it elsewhere.
pub const HINGE: [f64; 2] = [-0.025, 0.08];
/// Head rotation pivot (H frame): roughly the centre of the head.
pub const PIVOT: [f64; 3] = [0.0, -0.04, 0.09];

/// Surface kinds, for colour.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Part {
    Skin,
    Teeth,
}

/// What a material point needs to be placed and coloured in any frame.
#[derive(Debug, Clone, Copy)]
pub struct Attrs {
    /// Neutral (closed mouth) position.
    pub p0: [f64; 3],
    /// Displacement when the mouth is fully open (the seam groove deepening into the mouth).
    pub groove: [f64; 3],
    pub w_jaw: f64,
    /// Lip region weight, and its upper / lower parts.
    pub w_lip: f64,
    pub w_upper: f64,
    pub w_lower: f64,
    /// Linear RGB albedo, 0..1.
    pub albedo: [f32; 3],
    /// Lateral position of the material (neutral x), for spreading and rounding.
    pub x0: f64,
    pub part: Part,
}

const SKIN: [f32; 3] = [0.80, 0.60, 0.50];
const LIP: [f32; 3] = [0.70, 0.34, 0.34];
const INTERIOR: [f32; 3] = [0.16, 0.04, 0.06];
const BROW: [f32; 3] = [0.26, 0.18, 0.14];
const TEETH: [f32; 3] = [0.90, 0.88, 0.82];

fn gauss2(x: f64, v: f64, cx: f64, cv: f64, sx: f64, sv: f64) -> f64 {
    let dx = (x - cx) / sx;
    let dv = (v - cv) / sv;
    (-(dx * dx + dv * dv)).exp()
}

/// 1 in the middle of the mouth, 0 at and beyond the corners.
fn lip_taper(x: f64) -> f64 {
    let q = x / HALF_MOUTH;
    (1.0 - q * q).max(0.0).sqrt()
}

fn upper_lip_bump(x: f64, v: f64) -> f64 {
    // Cupid's bow: the upper lip is fuller either side of the centre.
    let bow = 1.0 + 0.15 * gauss2(x, 0.0, 0.008, 0.0, 0.005, 1.0)
        - 0.1 * gauss2(x, 0.0, 0.0, 0.0, 0.003, 1.0);
    0.0045 * lip_taper(x) * bow * gauss2(0.0, v, 0.0, -0.0045, 1.0, 0.0033)
}

fn lower_lip_bump(x: f64, v: f64) -> f64 {
    0.0050 * lip_taper(x) * gauss2(0.0, v, 0.0, 0.0058, 1.0, 0.0042)
}

fn seam_profile(v: f64) -> f64 {
    (-(v / 0.0012) * (v / 0.0012)).exp()
}

/// Radial distance of the neutral surface from the head's vertical axis.
fn radius(a: f64, v: f64) -> f64 {
    let (rx, rz) = (0.078, 0.10);
    let e = 1.0 / ((a.sin() / rx).powi(2) + (a.cos() / rz).powi(2)).sqrt();
    // Superellipse over height: a flatter face than an ellipsoid's.
    let q = ((v - VC) / VH).abs().min(1.0);
    let ell = e * (1.0 - q.powi(3)).max(0.0).cbrt();
    // Neck: a cylinder of radius 55 mm, 25 mm behind the head axis, below the chin.
    let (rn, d) = (0.055, 0.025);
    let neck =
        (-d * a.cos() + (rn * rn - d * d * a.sin().powi(2)).sqrt()) * smoothstep(0.03, 0.11, v);
    let k = 0.012;
    let mut r = 0.5 * (ell + neck + ((ell - neck).powi(2) + k * k).sqrt());
    // Facial features live on the front half only.
    if a.cos() > 0.0 {
        let x = a * E0;
        let features = 0.020 * gauss2(x, v, 0.0, -0.030, 0.010, 0.009) // nose tip
            + 0.011 * gauss2(x, v, 0.0, -0.055, 0.007, 0.018) // nose bridge
            + 0.006 * (gauss2(x, v, 0.014, -0.024, 0.006, 0.006) + gauss2(x, v, -0.014, -0.024, 0.006, 0.006))
            + 0.008 * (gauss2(x, v, 0.040, -0.030, 0.022, 0.022) + gauss2(x, v, -0.040, -0.030, 0.022, 0.022))
            - 0.009 * (gauss2(x, v, 0.032, -0.066, 0.014, 0.010) + gauss2(x, v, -0.032, -0.066, 0.014, 0.010))
            + 0.004 * (gauss2(x, v, 0.030, -0.080, 0.022, 0.007) + gauss2(x, v, -0.030, -0.080, 0.022, 0.007))
            + 0.008 * gauss2(x, v, 0.0, 0.045, 0.016, 0.012) // chin
            + 0.006 * gauss2(x, v, 0.0, 0.030, 0.030, 0.025) // lower face fullness
            - 0.003 * gauss2(x, v, 0.0, 0.022, 0.015, 0.004) // groove under the lower lip
            + upper_lip_bump(x, v)
            + lower_lip_bump(x, v)
            - 0.0025 * lip_taper(x) * seam_profile(v);
        r += features;
    }
    r
}

/// The axis position `zc` that puts the lip seam at z = 0 (what [`Geometry::new`] uses).
pub fn seam_zc() -> f64 {
    -surface(0.0, 0.0, 0.0)[2]
}

/// Axis position: chosen so the lips meet at z ≈ 0 (see [`Geometry::new`]).
fn surface(a: f64, v: f64, zc: f64) -> [f64; 3] {
    let r = radius(a, v);
    [r * a.sin(), v, zc - r * a.cos()]
}

/// The attributes of the head's material point (a, v).
pub fn attrs_at(a: f64, v: f64, zc: f64) -> Attrs {
    attrs_coloured(a, v, zc, LIP)
}

/// [`attrs_at`] with the lips' own colour `lip` (linear RGB, 0..1).
fn attrs_coloured(a: f64, v: f64, zc: f64, lip: [f32; 3]) -> Attrs {
    let p0 = surface(a, v, zc);
    let front = a.cos() > 0.0;
    let x = if front { a * E0 } else { 1.0 };
    let ax = x.abs();
    // Groove: inwards along the radial direction, only inside the mouth.
    let g = if front {
        0.022 * lip_taper(x).powi(2) * seam_profile(v)
    } else {
        0.0
    };
    let groove = [-g * a.sin(), 0.0, g * a.cos()];
    // Jaw weight: a sharp step across the seam inside the mouth, smooth on the cheeks.
    let tau = SEAM_EPS * 0.5 + 0.02 * smoothstep(0.021, 0.045, ax);
    let below = smoothstep(-tau, tau, v);
    let lateral = (1.0 - smoothstep(0.035, 0.085, ax)) * (1.0 - smoothstep(0.08, 0.13, v));
    let w_jaw = if front { below * lateral } else { 0.0 };
    let w_lip = if front {
        (-(x / 0.034).powi(4)).exp() * (-(v / 0.016).powi(2)).exp()
    } else {
        0.0
    };
    // Colour.
    let lipness = if front {
        let bump = (upper_lip_bump(x, v) / 0.0045).max(lower_lip_bump(x, v) / 0.0050);
        smoothstep(0.22, 0.45, bump)
    } else {
        0.0
    };
    let interior = if front {
        smoothstep(0.35, 0.8, seam_profile(v)) * smoothstep(0.0, 0.3, lip_taper(x))
    } else {
        0.0
    };
    let brow = if front {
        smoothstep(0.5, 0.8, gauss2(ax, v, 0.032, -0.083, 0.016, 0.0035))
    } else {
        0.0
    };
    let mut albedo = [0.0f32; 3];
    for c in 0..3 {
        let mut col = SKIN[c] + (lip[c] - SKIN[c]) * lipness as f32;
        col += (BROW[c] - col) * brow as f32;
        col += (INTERIOR[c] - col) * interior as f32;
        albedo[c] = col;
    }
    Attrs {
        p0,
        groove,
        w_jaw,
        w_lip,
        w_upper: w_lip * (1.0 - below),
        w_lower: w_lip * below,
        albedo,
        x0: p0[0],
        part: Part::Skin,
    }
}

/// Where the jaw hinges and how far it has slid, for one frame (H frame, metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JawPose {
    /// The hinge axis (parallel to x) at this (y, z).
    pub hinge: [f64; 2],
    /// The jaw's slide after its turn: sideways (x, > 0 towards the performer's left) and
    /// forward (out of the face, > 0; the H frame's −z).
    pub slide: [f64; 2],
}

impl Default for JawPose {
    fn default() -> Self {
        Self {
            hinge: HINGE,
            slide: [0.0; 2],
        }
    }
}

/// Where a material point is for a mouth state (H frame), the jaw on the default hinge and not
/// sliding.
pub fn deform(at: &Attrs, m: &MouthState) -> [f64; 3] {
    deform_with(at, m, &JawPose::default())
}

/// [`deform`] with the jaw turning about `jaw.hinge` and then sliding by `jaw.slide` (each
/// point carried by its jaw weight).
pub fn deform_with(at: &Attrs, m: &MouthState, jaw: &JawPose) -> [f64; 3] {
    let open = smoothstep(0.0, 0.05, m.jaw);
    let mut p = [
        at.p0[0] + at.groove[0] * open,
        at.p0[1] + at.groove[1] * open,
        at.p0[2] + at.groove[2] * open,
    ];
    if at.part == Part::Teeth {
        return move_jaw(p, m.jaw, at.w_jaw, jaw);
    }
    let l = at.w_lip;
    if l > 1e-6 {
        // Spread: corners outwards, lips thinner.
        p[0] += 0.006 * m.spread * (at.x0 / HALF_MOUTH).clamp(-1.4, 1.4) * l;
        p[1] -= 0.15 * m.spread * p[1] * l;
        // Round / pucker: corners inwards, lips forwards.
        p[0] -= 0.3 * m.round * at.x0 * l;
        p[2] -= 0.008 * m.round * l;
        // Upper-lip raise.
        p[1] -= 0.004 * m.raise * at.w_upper;
        // Roll-in: the lower lip curls up and back under the upper lip, which comes down.
        let lower = at.w_lower * (-(at.p0[1] / 0.012).powi(2)).exp();
        p[1] -= 0.007 * m.roll_in * lower;
        p[2] += 0.009 * m.roll_in * lower;
        let upper = at.w_upper * (-(at.p0[1] / 0.01).powi(2)).exp();
        p[1] += 0.003 * m.roll_in * upper;
        p[2] -= 0.002 * m.roll_in * upper;
    }
    move_jaw(p, m.jaw, at.w_jaw, jaw)
}

/// The jaw's motion of a point of jaw weight `w`: turned by `w · angle` about the hinge, then
/// slid by `w · slide`.
fn move_jaw(p: [f64; 3], angle: f64, w: f64, jaw: &JawPose) -> [f64; 3] {
    let mut q = rotate_jaw(p, angle * w, jaw.hinge);
    if jaw.slide != [0.0; 2] {
        q[0] += w * jaw.slide[0];
        q[2] -= w * jaw.slide[1];
    }
    q
}

fn rotate_jaw(p: [f64; 3], angle: f64, hinge: [f64; 2]) -> [f64; 3] {
    if angle == 0.0 {
        return p;
    }
    let (s, c) = angle.sin_cos();
    let dy = p[1] - hinge[0];
    let dz = p[2] - hinge[1];
    [p[0], hinge[0] + dy * c - dz * s, hinge[1] + dy * s + dz * c]
}

/// A rectangular patch of the mesh: `cols × rows` vertices from `start`, columns across
/// (increasing x on a frontal view), rows downwards; `wrap` closes the columns into a ring.
#[derive(Debug, Clone, Copy)]
pub struct Grid {
    pub start: usize,
    pub cols: usize,
    pub rows: usize,
    pub wrap: bool,
}

/// The mesh: every vertex's material attributes, the grids and the triangles.
pub struct Geometry {
    pub zc: f64,
    pub attrs: Vec<Attrs>,
    /// Material coordinates (a, v) per vertex; teeth carry (100, 100), where no paint is.
    pub material: Vec<[f32; 2]>,
    pub grids: Vec<Grid>,
    /// Triangles, wound so that front faces have positive area on screen (x right, y down).
    pub tris: Vec<[u32; 3]>,
}

fn steps(from: f64, to: f64, step: impl Fn(f64) -> f64) -> Vec<f64> {
    let mut out = vec![from];
    let mut x = from;
    let dir = (to - from).signum();
    loop {
        x += dir * step(x);
        if (to - x) * dir <= 0.0 {
            break;
        }
        out.push(x);
    }
    out.push(to);
    out
}

impl Geometry {
    pub fn new() -> Self {
        Self::with_lip_colour(LIP)
    }

    /// The head with the lips' own colour `lip` (linear RGB, 0..1).
    pub fn with_lip_colour(lip: [f32; 3]) -> Self {
        // The lips meet at z = 0: the seam point's neutral depth with zc = 0, negated.
        let zc = -surface(0.0, 0.0, 0.0)[2];
        // Columns: fine (0.6 mm) across the face, coarse at the back.
        let col_step = |a: f64| {
            let x = a * E0;
            (0.0006 + 0.0055 * (x / 0.06).powi(2).min(1.0)) / E0
        };
        let mut cols = steps(0.0, std::f64::consts::PI, col_step);
        cols.pop(); // π is -π: the ring closes.
        let mut left: Vec<f64> = steps(0.0, -std::f64::consts::PI, col_step)
            .into_iter()
            .skip(1)
            .collect();
        left.reverse();
        let cols: Vec<f64> = left.into_iter().chain(cols).collect();
        // Rows: fine (0.35 mm) around the lips, two rows at the seam.
        let row_step = |v: f64| 0.00035 + 0.0045 * (v / 0.03).powi(2).min(1.0);
        let mut up: Vec<f64> = steps(-SEAM_EPS, VC - VH, row_step);
        up.reverse();
        let down = steps(SEAM_EPS, 0.33, row_step);
        let rows: Vec<f64> = up.into_iter().chain(down).collect();

        let mut attrs = Vec::with_capacity(cols.len() * rows.len() + 2000);
        let mut material = Vec::with_capacity(attrs.capacity());
        for &v in &rows {
            for &a in &cols {
                attrs.push(attrs_coloured(a, v, zc, lip));
                material.push([a as f32, v as f32]);
            }
        }
        let mut grids = vec![Grid {
            start: 0,
            cols: cols.len(),
            rows: rows.len(),
            wrap: true,
        }];
        // Teeth: upper fixed to the skull, lower on the jaw, 6–9 mm behind the lip front.
        for (v0, v1, w_jaw) in [(-0.011, -0.0004, 0.0), (0.0004, 0.010, 1.0)] {
            let start = attrs.len();
            let (nc, nr) = (40, 12);
            for j in 0..nr {
                let v = v0 + (v1 - v0) * j as f64 / (nr - 1) as f64;
                for i in 0..nc {
                    let x = -0.02 + 0.04 * i as f64 / (nc - 1) as f64;
                    let z = 0.0065 + 0.012 * (x / 0.02).powi(2);
                    attrs.push(Attrs {
                        p0: [x, v, z],
                        groove: [0.0; 3],
                        w_jaw,
                        w_lip: 0.0,
                        w_upper: 0.0,
                        w_lower: 0.0,
                        albedo: TEETH,
                        x0: x,
                        part: Part::Teeth,
                    });
                    material.push([100.0, 100.0]);
                }
            }
            grids.push(Grid {
                start,
                cols: nc,
                rows: nr,
                wrap: false,
            });
        }
        let mut tris = Vec::new();
        for g in &grids {
            let ncols = if g.wrap { g.cols } else { g.cols - 1 };
            for j in 0..g.rows - 1 {
                for i in 0..ncols {
                    let i1 = (i + 1) % g.cols;
                    let v00 = (g.start + j * g.cols + i) as u32;
                    let v10 = (g.start + j * g.cols + i1) as u32;
                    let v01 = (g.start + (j + 1) * g.cols + i) as u32;
                    let v11 = (g.start + (j + 1) * g.cols + i1) as u32;
                    tris.push([v00, v10, v01]);
                    tris.push([v10, v11, v01]);
                }
            }
        }
        Self {
            zc,
            attrs,
            material,
            grids,
            tris,
        }
    }

    /// Per-vertex normals (outwards) from grid neighbours of deformed positions.
    pub fn normals(&self, pos: &[[f64; 3]], out: &mut Vec<[f64; 3]>) {
        out.clear();
        out.resize(pos.len(), [0.0, 0.0, -1.0]);
        for g in &self.grids {
            for j in 0..g.rows {
                for i in 0..g.cols {
                    let idx = |ii: usize, jj: usize| g.start + jj * g.cols + ii;
                    let (il, ir) = if g.wrap {
                        ((i + g.cols - 1) % g.cols, (i + 1) % g.cols)
                    } else {
                        (i.saturating_sub(1), (i + 1).min(g.cols - 1))
                    };
                    let (ju, jd) = (j.saturating_sub(1), (j + 1).min(g.rows - 1));
                    let ta = sub(pos[idx(ir, j)], pos[idx(il, j)]);
                    let tv = sub(pos[idx(i, jd)], pos[idx(i, ju)]);
                    // Outward: ∂v × ∂a (columns go +x, rows go +y, the face looks at -z).
                    let n = cross(tv, ta);
                    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                    if len > 1e-18 {
                        out[idx(i, j)] = [n[0] / len, n[1] / len, n[2] / len];
                    }
                }
            }
        }
    }
}

impl Default for Geometry {
    fn default() -> Self {
        Self::new()
    }
}

pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// The material coordinates of the lip dots: corners at the seam ends, the others at equal
/// arc length (neutral, 3D) along the crest lines of the upper and lower lip. Order D1..Dn:
/// left corner, upper lip left→right, right corner, lower lip right→left (docs/method.md §1).
pub fn lip_dot_material(count: usize, zc: f64) -> Vec<(f64, f64)> {
    let per_lip = (count - 2) / 2;
    let upper_crest = |x: f64| -0.0047 * lip_taper(x).sqrt();
    let lower_crest = |x: f64| 0.0060 * lip_taper(x).sqrt();
    // Painted on the corner of the mouth, just outside the commissure.
    let corner = HALF_MOUTH + 0.001;
    // Samples from x = +corner to -corner (performer's left to right).
    let sample = |crest: &dyn Fn(f64) -> f64| -> Vec<(f64, f64, f64)> {
        let n = 800;
        let mut out = Vec::with_capacity(n + 1);
        let mut length = 0.0;
        let mut prev: Option<[f64; 3]> = None;
        for k in 0..=n {
            let x = corner - 2.0 * corner * k as f64 / n as f64;
            let (a, v) = (x / E0, crest(x));
            let p = surface(a, v, zc);
            if let Some(q) = prev {
                let d = sub(p, q);
                length += (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            }
            prev = Some(p);
            out.push((length, a, v));
        }
        out
    };
    let at_fraction = |samples: &[(f64, f64, f64)], f: f64| -> (f64, f64) {
        let total = samples[samples.len() - 1].0;
        let target = f * total;
        let i = samples
            .partition_point(|s| s.0 < target)
            .min(samples.len() - 1);
        (samples[i].1, samples[i].2)
    };
    let upper = sample(&upper_crest);
    let lower = sample(&lower_crest);
    let mut dots = vec![(corner / E0, 0.0)];
    for k in 1..=per_lip {
        dots.push(at_fraction(&upper, k as f64 / (per_lip + 1) as f64));
    }
    dots.push((-corner / E0, 0.0));
    for k in 1..=per_lip {
        // Lower lip from the performer's right to left: walk the left→right samples backwards.
        dots.push(at_fraction(&lower, 1.0 - k as f64 / (per_lip + 1) as f64));
    }
    dots
}

/// Material coordinates of a point given by its lateral (x) and vertical (v) position on the
/// front of the head.
pub fn front_material(x: f64, v: f64) -> (f64, f64) {
    (x / E0, v)
}

/// Lengths (m) of one unit of `a` and of `v` at a material point: the local metric used to
/// paint round dots in material space.
pub fn material_metric(a: f64, v: f64, zc: f64) -> (f64, f64) {
    // Differences over about a dot radius: the lip taper has infinite slope at the corners.
    let (ha, hv) = (0.001 / E0, 0.001);
    let da = sub(surface(a + ha, v, zc), surface(a - ha, v, zc));
    let dv = sub(surface(a, v + hv, zc), surface(a, v - hv, zc));
    let n = |d: [f64; 3]| (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    (n(da) / (2.0 * ha), n(dv) / (2.0 * hv))
}
