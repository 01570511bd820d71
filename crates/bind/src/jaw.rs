//! The jaw: a joint at the rig's hinge that carries the chin and the lower lip, with the
//! lower lip's joints riding on it (the face rig engines and Blender expect).
//!
//! Which vertices follow the jaw is geometric, the same for every binder: the lower face in
//! front of the hinge, fading out towards the mouth's corners and the cheeks. A vertex's
//! share of the head (the root's weight) goes to the jaw in proportion; its weights on the
//! mouth points stay. Points and vertices are in the mouth frame, in mouth widths.

use nalgebra::{Rotation3, Vector3};

use crate::mesh::Mesh;
use crate::procedural::{Head, MouthState, POINTS};
use crate::weights::{Weights, ROOT};

/// The lower lip's points (0-based: P8 … P12), whose joints ride on the jaw; the corners
/// (P1, P7) and the upper lip stay on the mouth.
pub const LOWER_LIP: [usize; 5] = [7, 8, 9, 10, 11];

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// How much a vertex at `p` belongs to the jaw (0…1): below the corners' line (by its angle
/// round the mouth's centre), in front of the hinge, within about a mouth width of the middle.
pub fn jaw_mask(p: &Vector3<f64>, hinge: &Vector3<f64>) -> f64 {
    let r = (p.x * p.x + p.y * p.y).sqrt();
    if r == 0.0 {
        return 0.0;
    }
    let lower = smoothstep(0.0, 0.35, -p.y / r);
    let in_front = smoothstep(hinge.z - 0.1, hinge.z + 0.4, p.z);
    let side = (-(((p.x.abs() - 0.6).max(0.0)) / 0.3).powi(2)).exp();
    lower * in_front * side
}

/// Each vertex's weight on the jaw: its root weight times [`jaw_mask`].
pub fn jaw_shares(positions: &[Vector3<f64>], weights: &Weights, hinge: &Vector3<f64>) -> Vec<f64> {
    positions
        .iter()
        .zip(&weights.rows)
        .map(|(p, row)| row[ROOT] * jaw_mask(p, hinge))
        .collect()
}

/// Where the jaw hinges, read from the face (mouth frame, mouth widths), for a character that
/// gives no hinge: at the mouth's level, `0.42 + 0.6 D` mouth widths behind the mouth, where
/// `D` is the lower face's depth: how far behind the mouth the surface below it reaches (the
/// back-most vertex with `|x| ≤ 0.25`, `y ≤ −0.25`: the chin, the jaw's underside, a muzzle).
/// The constants are the procedural heads' own hinge (0.6 behind the face plus 0.6 of the
/// muzzle's length, with the face 0.3 deep). None when the lower face reaches less than 0.2
/// mouth widths back (a mask cut off at the chin: no depth to read); the result is kept
/// between 0.6 and 4 mouth widths behind the mouth.
pub fn hinge_from_mesh(mesh: &Mesh) -> Option<Vector3<f64>> {
    let depth = mesh
        .positions
        .iter()
        .filter(|p| p[0].abs() <= 0.25 && p[1] <= -0.25)
        .map(|p| -p[2])
        .fold(f64::NEG_INFINITY, f64::max);
    (depth >= 0.2).then(|| Vector3::new(0.0, 0.0, -(0.42 + 0.6 * depth).clamp(0.6, 4.0)))
}

/// The jaw's angle in a mouth state of the procedural motion (radians; 0.35 at full opening,
/// as [`Head::displacement`] turns the lower face).
pub fn jaw_angle(s: &MouthState) -> f64 {
    0.35 * s.jaw
}

/// A vertex skinned with a jaw: `v' = Σ_j w_j T_j(v)`, where the root stays, an upper point
/// translates by its motion d_j, the jaw turns by its angle about the hinge, and a lower-lip
/// point's joint (a child of the jaw) turns with it and lands on its point: `p_j + R (v − p_j⁰)`.
#[allow(clippy::too_many_arguments)]
pub fn skin_vertex(
    v: &Vector3<f64>,
    row: &[f64],
    jaw: f64,
    rest_points: &[Vector3<f64>; POINTS],
    motion: &[Vector3<f64>; POINTS],
    hinge: &Vector3<f64>,
    rotation: &Rotation3<f64>,
) -> Vector3<f64> {
    let mut out = (row[ROOT] - jaw) * v;
    out += jaw * (hinge + rotation * (v - hinge));
    for j in 0..POINTS {
        if row[j] == 0.0 {
            continue;
        }
        out += row[j]
            * if LOWER_LIP.contains(&j) {
                rest_points[j] + motion[j] + rotation * (v - rest_points[j])
            } else {
                v + motion[j]
            };
    }
    out
}

/// The deformation error of a skin with and without the jaw, over all vertices and over
/// the chin's (those [`jaw_mask`] gives at least one half at the head's own hinge and farther
/// than 0.3 mouth widths from every point): `(all without, all with, chin without, chin
/// with)`, each RMS in % of the mouth width.
pub fn jaw_errors(head: &Head, weights: &Weights, states: &[MouthState]) -> [f64; 4] {
    jaw_errors_at(head, weights, states, &Vector3::from(head.hinge))
}

/// [`jaw_errors`] with the skin's jaw at `hinge` (its mask and its turn; a binding that
/// guessed the hinge), the motion still turning about the head's own; the chin is the same
/// vertices as in [`jaw_errors`].
pub fn jaw_errors_at(
    head: &Head,
    weights: &Weights,
    states: &[MouthState],
    hinge: &Vector3<f64>,
) -> [f64; 4] {
    let own = Vector3::from(head.hinge);
    let hinge = *hinge;
    let rest: Vec<Vector3<f64>> = (0..head.mesh.len()).map(|v| head.mesh.vertex(v)).collect();
    let points: [Vector3<f64>; POINTS] =
        std::array::from_fn(|k| head.mesh.vertex(head.point_vertices[k]));
    let shares = jaw_shares(&rest, weights, &hinge);
    let chin: Vec<bool> = rest
        .iter()
        .map(|p| jaw_mask(p, &own) >= 0.5 && points.iter().all(|q| (p - q).norm() > 0.3))
        .collect();
    let mut sums = [0.0; 4];
    let mut counts = [0usize; 4];
    for s in states {
        let motion = head.joint_motion(s);
        let rotation = Rotation3::from_axis_angle(&Vector3::x_axis(), jaw_angle(s));
        for (v, p) in rest.iter().enumerate() {
            let truth = p + head.displacement(v, s);
            let row = &weights.rows[v];
            let mut plain = *p;
            for j in 0..POINTS {
                plain += row[j] * motion[j];
            }
            let jawed = skin_vertex(p, row, shares[v], &points, &motion, &hinge, &rotation);
            let e = [
                (plain - truth).norm_squared(),
                (jawed - truth).norm_squared(),
            ];
            for k in 0..2 {
                sums[k] += e[k];
                counts[k] += 1;
                if chin[v] {
                    sums[2 + k] += e[k];
                    counts[2 + k] += 1;
                }
            }
        }
    }
    std::array::from_fn(|k| 100.0 * (sums[k] / counts[k].max(1) as f64).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::HeadParams;

    #[test]
    fn the_jaw_takes_the_chin_not_the_upper_face() {
        let hinge = Vector3::new(0.0, 0.0, -0.8);
        assert!(jaw_mask(&Vector3::new(0.0, -0.6, 0.0), &hinge) > 0.9);
        assert_eq!(jaw_mask(&Vector3::new(0.0, 0.6, 0.0), &hinge), 0.0);
        assert!(jaw_mask(&Vector3::new(0.0, -0.6, -1.5), &hinge) < 1e-9);
        assert!(jaw_mask(&Vector3::new(2.0, -0.6, 0.0), &hinge) < 1e-3);
    }

    #[test]
    fn at_rest_the_jaw_skin_is_the_input() {
        let head =
            HeadParams::around_points(HeadParams::mouth_points(0.2, 0.2, 0.2), 0.0, 2).build();
        let points = std::array::from_fn(|k| head.mesh.vertex(head.point_vertices[k]));
        let zero = [Vector3::zeros(); POINTS];
        let id = Rotation3::identity();
        let mut row = [0.0; POINTS + 1];
        row[9] = 0.3;
        row[2] = 0.2;
        row[ROOT] = 0.5;
        let v = Vector3::new(0.1, -0.4, 0.2);
        let out = skin_vertex(
            &v,
            &row,
            0.4,
            &points,
            &zero,
            &Vector3::new(0.0, 0.0, -1.0),
            &id,
        );
        assert!((out - v).norm() < 1e-12);
    }

    #[test]
    fn the_hinge_read_from_the_mesh_is_near_the_generators_own() {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x6a77);
        let mut heads: Vec<HeadParams> = (0..12).map(|_| HeadParams::random(&mut rng)).collect();
        // the two ends of the family: a flat human face and a long muzzle
        for snout in [0.0, 1.0] {
            heads.push(HeadParams::around_points(
                HeadParams::mouth_points(0.2, 0.2, 0.3),
                snout,
                3,
            ));
        }
        let mut depths = Vec::new();
        for params in &heads {
            let head = params.build();
            let own = Vector3::from(head.hinge);
            let found = hinge_from_mesh(&head.mesh).expect("a procedural head has an underside");
            assert!(
                (found - own).norm() <= 0.15,
                "snout {:.2}, face depth {:.2}: found {found:?}, own {own:?}",
                params.snout,
                params.face_depth
            );
            depths.push(found.z);
        }
        // it follows the head: short faces and long muzzles get different hinges
        let (lo, hi) = depths
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &z| {
                (a.min(z), b.max(z))
            });
        assert!(hi - lo > 0.8, "hinges from {lo} to {hi}");
    }

    #[test]
    fn a_face_without_an_underside_has_no_hinge_read_from_it() {
        // a flat mask facing +z, cut off at the chin
        let mut positions = Vec::new();
        for i in 0..5 {
            for j in 0..5 {
                positions.push([i as f64 * 0.5 - 1.0, j as f64 * 0.5 - 1.0, 0.0]);
            }
        }
        let mut triangles = Vec::new();
        for i in 0..4u32 {
            for j in 0..4u32 {
                let a = i * 5 + j;
                triangles.push([a, a + 5, a + 1]);
                triangles.push([a + 1, a + 5, a + 6]);
            }
        }
        let mask = Mesh {
            positions,
            triangles,
        };
        assert_eq!(hinge_from_mesh(&mask), None);
    }
}
