//! A family of procedural heads and muzzles, each with a known analytic mouth motion.
//!
//! Everything here is in the mouth frame (origin between the corners, x towards the
//! character's left corner, y up, z out of the mouth) in units of the mouth width, so one
//! family spans a human face and a long animal snout.
//!
//! # The surface
//! The mesh is a stack of rings around the mouth. Ring 1 is the lip line: a closed
//! Catmull–Rom loop through the twelve mouth points P1 (left corner), P2…P6 (upper lip), P7
//! (right corner), P8…P12 (lower lip), the points at parameters α = kπ/6, so each point is a
//! vertex. Ring 0 lies inside the lips (the mouth's slit: the upper and lower lips meet only at
//! the corners). Rings 2… spread outwards over the face to `face_radius` and then run back
//! along −z as a tube of length `snout` (a human face: a wide face and a short tube; a wolf:
//! a narrow face and a long one).
//!
//! # The motion
//! A mouth state is four numbers: jaw opening, smile (corners out and up; negative: in and
//! down), pucker (lips in and forward) and upper-lip raise. The jaw rotates the lower half
//! of the muzzle about a hinge behind the mouth; the others are smooth fields around the
//! lips. A rotation is not a sum of translations, and the fields overlap, so no skin
//! weights reproduce the motion exactly: the reference weights are the best fit.

use std::f64::consts::PI;

use nalgebra::{Rotation3, Vector3};
use rand::Rng;

use crate::mesh::Mesh;

/// Number of mouth points (P1…P12).
pub const POINTS: usize = 12;

/// Shape parameters of one procedural head (mouth-width units).
#[derive(Clone, Debug, PartialEq)]
pub struct HeadParams {
    /// Mouth points P1…P12 in the mouth frame, mouth-width units (corners at x = ±0.5).
    pub points: [[f64; 3]; POINTS],
    /// How far the slit ring lies inside the lips (lip thickness).
    pub lip_thickness: f64,
    /// Radius of the face around the mouth before the tube starts.
    pub face_radius: f64,
    /// Depth the face recedes over its radius.
    pub face_depth: f64,
    /// Length of the tube behind the face (the muzzle; short for a human).
    pub snout: f64,
    /// Vertical over horizontal size of the face rings.
    pub aspect: f64,
    /// Vertices around each ring (a multiple of 12).
    pub around: usize,
    /// Rings over the face (after the lip ring).
    pub face_rings: usize,
    /// Rings along the tube.
    pub tube_rings: usize,
}

/// A mouth state of the analytic motion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MouthState {
    /// Jaw opening, 0…1 (1 = 20 degrees about the hinge).
    pub jaw: f64,
    /// Smile, −1…1.
    pub smile: f64,
    /// Pucker, 0…1.
    pub pucker: f64,
    /// Upper-lip raise, 0…1.
    pub raise: f64,
}

impl MouthState {
    pub const NEUTRAL: Self = Self {
        jaw: 0.0,
        smile: 0.0,
        pucker: 0.0,
        raise: 0.0,
    };

    /// A random state, each component uniform over its range.
    pub fn random(rng: &mut impl Rng) -> Self {
        Self {
            jaw: rng.random_range(0.0..1.0),
            smile: rng.random_range(-1.0..1.0),
            pucker: rng.random_range(0.0..1.0),
            raise: rng.random_range(0.0..1.0),
        }
    }

    /// The pure states (each motion alone at full strength) and `random` more.
    pub fn set(random: usize, rng: &mut impl Rng) -> Vec<Self> {
        let n = Self::NEUTRAL;
        let mut states = vec![
            Self { jaw: 1.0, ..n },
            Self { smile: 1.0, ..n },
            Self { smile: -1.0, ..n },
            Self { pucker: 1.0, ..n },
            Self { raise: 1.0, ..n },
        ];
        states.extend((0..random).map(|_| Self::random(rng)));
        states
    }
}

/// A generated head: its mesh (mouth frame, mouth-width units) and each vertex's place in
/// the ring parametrisation, which the analytic motion is defined on.
#[derive(Clone, Debug)]
pub struct Head {
    pub params: HeadParams,
    pub mesh: Mesh,
    /// Each vertex's angle around the mouth (0 at P1, π/2 mid upper lip, π at P7).
    pub alpha: Vec<f64>,
    /// Each vertex's distance from the lip line over the surface, roughly (mouth widths).
    pub from_lips: Vec<f64>,
    /// Vertex index of each mouth point.
    pub point_vertices: [usize; POINTS],
    /// Hinge of the jaw (a point on the x-parallel axis it turns about).
    pub hinge: [f64; 3],
}

impl HeadParams {
    /// A human mouth's points of a given shape: upper and lower lip heights, and how far
    /// the middle of the lips stands out of the corners' plane.
    pub fn mouth_points(upper: f64, lower: f64, protrusion: f64) -> [[f64; 3]; POINTS] {
        let mut points = [[0.0; 3]; POINTS];
        for (k, p) in points.iter_mut().enumerate() {
            let a = k as f64 * PI / 6.0;
            let s = a.sin();
            let height = if s >= 0.0 { upper } else { lower };
            *p = [
                0.5 * a.cos(),
                height * s.signum() * s.abs().powf(0.8),
                protrusion * s.abs(),
            ];
        }
        points
    }

    /// A random member of the family: mouths from thin human lips to long animal ones,
    /// faces from flat to snouts, and several resolutions.
    pub fn random(rng: &mut impl Rng) -> Self {
        let points = Self::mouth_points(
            rng.random_range(0.08..0.3),
            rng.random_range(0.1..0.35),
            rng.random_range(0.05..1.0),
        );
        let snouty: f64 = rng.random_range(0.0..1.0);
        Self {
            points,
            lip_thickness: rng.random_range(0.04..0.12),
            face_radius: 1.5 - 1.0 * snouty + rng.random_range(-0.1..0.1),
            face_depth: rng.random_range(0.1..0.5),
            snout: 0.2 + 1.8 * snouty,
            aspect: rng.random_range(0.7..1.2),
            around: 12 * rng.random_range(3..6),
            face_rings: rng.random_range(8..14),
            tube_rings: rng.random_range(4..10),
        }
    }

    /// A head around given mouth points (mouth frame, mouth-width units) with the default
    /// human proportions (`snout` = 0) up to a long muzzle (`snout` = 1).
    pub fn around_points(points: [[f64; 3]; POINTS], snout: f64, resolution: usize) -> Self {
        Self {
            points,
            lip_thickness: 0.08,
            face_radius: 1.5 - snout,
            face_depth: 0.3,
            snout: 0.2 + 1.8 * snout,
            aspect: 0.9,
            around: 12 * resolution.max(1),
            face_rings: 3 * resolution.max(1),
            tube_rings: 2 * resolution.max(1),
        }
    }

    /// Builds the head.
    pub fn build(&self) -> Head {
        let m = self.around;
        let lip = |alpha: f64| catmull_rom_loop(&self.points, alpha);
        // The slit ring sits inside the lips by at most 0.4 of the lips' opening, so the
        // upper and lower slit never cross.
        let gap = (1..6)
            .map(|k| self.points[k][1] - self.points[12 - k][1])
            .fold(f64::INFINITY, f64::min)
            .max(0.0);
        let inset = self.lip_thickness.min(0.4 * gap);
        let mut positions = Vec::new();
        let mut alpha = Vec::new();
        let mut from_lips = Vec::new();
        let mut push_ring = |f: &dyn Fn(f64, [f64; 3]) -> [f64; 3], s: f64| {
            for i in 0..m {
                let a = 2.0 * PI * i as f64 / m as f64;
                positions.push(f(a, lip(a)));
                alpha.push(a);
                from_lips.push(s);
            }
        };
        // ring 0: the slit, inside the lips and a little into the mouth
        push_ring(
            &|a, l| {
                [
                    l[0] - inset * a.cos(),
                    l[1] - inset * a.sin(),
                    l[2] - 0.5 * inset,
                ]
            },
            0.0,
        );
        // ring 1: the lip line (the points are vertices)
        push_ring(&|_, l| l, 0.0);
        let r = self.face_radius;
        let nf = self.face_rings.max(1);
        let edge_z = -self.face_depth;
        for k in 1..=nf {
            let t = k as f64 / nf as f64;
            let rho = r * t.powf(1.3);
            let s = rho;
            let aspect = self.aspect;
            push_ring(
                &|a, l| {
                    let blend = t.powf(0.7);
                    [
                        l[0] + rho * a.cos(),
                        l[1] + rho * aspect * a.sin(),
                        l[2] * (1.0 - blend) + edge_z * blend,
                    ]
                },
                s,
            );
        }
        let nt = self.tube_rings.max(1);
        for k in 1..=nt {
            let t = k as f64 / nt as f64;
            let back = self.snout * t;
            let flare = 1.0 + 0.4 * t * t;
            let aspect = self.aspect;
            push_ring(
                &|a, l| {
                    [
                        (l[0] + r * a.cos()) * flare,
                        (l[1] + r * aspect * a.sin()) * flare,
                        edge_z - back,
                    ]
                },
                r + back,
            );
        }
        let rings = positions.len() / m;
        let mut triangles = Vec::with_capacity(2 * m * (rings - 1));
        for k in 0..rings - 1 {
            for i in 0..m {
                let a = (k * m + i) as u32;
                let b = (k * m + (i + 1) % m) as u32;
                let c = a + m as u32;
                let d = b + m as u32;
                triangles.push([a, c, b]);
                triangles.push([b, c, d]);
            }
        }
        let step = m / POINTS;
        let point_vertices = std::array::from_fn(|k| m + k * step);
        Head {
            params: self.clone(),
            mesh: Mesh {
                positions,
                triangles,
            },
            alpha,
            from_lips,
            point_vertices,
            hinge: [0.0, 0.0, -(0.6 + 0.6 * self.snout)],
        }
    }
}

/// The closed Catmull–Rom curve through the points at parameters kπ/6 (the lip line).
pub fn catmull_rom_loop(points: &[[f64; 3]; POINTS], alpha: f64) -> [f64; 3] {
    let u = alpha.rem_euclid(2.0 * PI) / (2.0 * PI) * POINTS as f64;
    let i = (u.floor() as usize) % POINTS;
    let t = u - u.floor();
    let p = |k: isize| points[(i as isize + k).rem_euclid(POINTS as isize) as usize];
    let (p0, p1, p2, p3) = (p(-1), p(0), p(1), p(2));
    let t2 = t * t;
    let t3 = t2 * t;
    std::array::from_fn(|c| {
        0.5 * (2.0 * p1[c]
            + (-p0[c] + p2[c]) * t
            + (2.0 * p0[c] - 5.0 * p1[c] + 4.0 * p2[c] - p3[c]) * t2
            + (-p0[c] + 3.0 * p1[c] - 3.0 * p2[c] + p3[c]) * t3)
    })
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

impl Head {
    /// Displacement of vertex `v` in mouth state `s` (mouth-width units).
    pub fn displacement(&self, v: usize, s: &MouthState) -> Vector3<f64> {
        field(
            &self.mesh.vertex(v),
            self.alpha[v],
            self.from_lips[v],
            &Vector3::from(self.hinge),
            s,
        )
    }

    /// The motions of the mouth points (the joints) in state `s`.
    pub fn joint_motion(&self, s: &MouthState) -> [Vector3<f64>; POINTS] {
        std::array::from_fn(|k| self.displacement(self.point_vertices[k], s))
    }
}

/// How much the jaw turns the point at `p` at angle `a` round the mouth (0…1): the lower
/// half, in front of the hinge, within about a mouth width of the middle.
pub fn jaw_member(p: &Vector3<f64>, a: f64, hinge: &Vector3<f64>) -> f64 {
    let lower = smoothstep(0.0, 0.35, -a.sin());
    let in_front = smoothstep(hinge.z - 0.1, hinge.z + 0.4, p.z);
    let side = (-(((p.x.abs() - 0.6).max(0.0)) / 0.3).powi(2)).exp();
    lower * in_front * side
}

/// The analytic motion at `p` in state `s`, given its angle round the mouth `a` (0 at P1,
/// π/2 mid upper lip) and its distance from the lip line `d` (mouth widths), with the jaw
/// turning about an x-parallel axis through `hinge`.
pub fn field(
    p: &Vector3<f64>,
    a: f64,
    d: f64,
    hinge: &Vector3<f64>,
    s: &MouthState,
) -> Vector3<f64> {
    let p = *p;
    let hinge = *hinge;
    let lips = (-(d / 0.35).powi(2)).exp();
    let mut out = Vector3::zeros();
    // jaw: the lower half turns about the hinge; the corners and the cheeks stay
    let member = jaw_member(&p, a, &hinge);
    if s.jaw != 0.0 && member > 0.0 {
        let rot = Rotation3::from_axis_angle(&Vector3::x_axis(), 0.35 * s.jaw * member);
        out += rot * (p - hinge) + hinge - p;
    }
    // smile: the corners out, up and back
    let to_corner = a.sin().abs().asin().abs();
    let corner = (-(to_corner / 0.5).powi(2)).exp() * lips;
    let sign = a.cos().signum();
    out += s.smile * corner * Vector3::new(0.12 * sign, 0.06, -0.04);
    // pucker: the lips in towards the middle and forward
    out += s.pucker * lips * Vector3::new(-0.3 * p.x, 0.0, 0.12);
    // raise: the upper lip up
    let upper = smoothstep(0.0, 0.3, a.sin()) * (-(d / 0.25).powi(2)).exp();
    out += s.raise * upper * (1.0 - 0.5 * corner) * Vector3::new(0.0, 0.08, 0.0);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn heads_are_valid_meshes_with_the_points_as_vertices() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for _ in 0..20 {
            let params = HeadParams::random(&mut rng);
            let head = params.build();
            head.mesh.validate().unwrap();
            for (k, &v) in head.point_vertices.iter().enumerate() {
                let d = (head.mesh.vertex(v) - Vector3::from(params.points[k])).norm();
                assert!(d < 1e-12, "point {k} off its vertex by {d}");
            }
        }
    }

    #[test]
    fn neutral_state_does_not_move_and_the_jaw_moves_only_the_lower_lip() {
        let head =
            HeadParams::around_points(HeadParams::mouth_points(0.2, 0.2, 0.2), 0.0, 2).build();
        for v in 0..head.mesh.len() {
            assert_eq!(head.displacement(v, &MouthState::NEUTRAL), Vector3::zeros());
        }
        let jaw = MouthState {
            jaw: 1.0,
            ..MouthState::NEUTRAL
        };
        let m = head.joint_motion(&jaw);
        assert!(
            m[3].norm() < 1e-12,
            "upper lip moved with the jaw: {:?}",
            m[3]
        );
        assert!(m[9].y < -0.05, "lower lip did not drop: {:?}", m[9]);
    }
}
