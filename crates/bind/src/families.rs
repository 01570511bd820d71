//! Meshes the generator did not make, and a reference motion to score the binders on them.
//!
//! The procedural motion ([`crate::procedural::field`]) is defined on a head's ring parametrisation
//! (each vertex's angle round the mouth and distance from the lip line), which only the
//! generator's own meshes have. [`LipField`] makes it a function of position alone: the
//! angle and the distance are those of the nearest point of the lip line (the closed
//! Catmull–Rom curve through P1…P12), so any surface near the mouth — decimated,
//! subdivided, welded, or modelled elsewhere — gets a motion that none of the three binders
//! computes. Separate shells get a motion of their own ([`Part`]): eyes and upper teeth stay
//! with the head, lower teeth and the tongue turn with the jaw.
//!
//! Everything is in the mouth frame, in mouth widths.

use std::path::Path;

use nalgebra::{Rotation3, Vector3};

use crate::mesh::Mesh;
use crate::network::{Graph, Network};
use crate::procedural::{catmull_rom_loop, field, jaw_member, Head, MouthState, POINTS};
use crate::reference::fit_weights;
use crate::weights::{distance_weights, heat_weights, joint_distances, Weights};

/// Samples of the lip line searched for a point's nearest before refining.
const CURVE_SAMPLES: usize = 1440;
/// A vertex is in the chin/lips region when it is this close to the lip line (the lips'
/// own scale in the motion) or at least half on the jaw.
pub const REGION_LIPS: f64 = 0.35;

/// The procedural motion as a function of position (see the module's documentation).
#[derive(Clone, Debug)]
pub struct LipField {
    points: [[f64; 3]; POINTS],
    pub hinge: Vector3<f64>,
    samples: Vec<Vector3<f64>>,
}

impl LipField {
    pub fn new(points: &[[f64; 3]; POINTS], hinge: [f64; 3]) -> Self {
        let samples = (0..CURVE_SAMPLES)
            .map(|i| Vector3::from(catmull_rom_loop(points, Self::alpha(i as f64))))
            .collect();
        Self {
            points: *points,
            hinge: Vector3::from(hinge),
            samples,
        }
    }

    fn alpha(i: f64) -> f64 {
        2.0 * std::f64::consts::PI * i / CURVE_SAMPLES as f64
    }

    /// The angle round the mouth and the distance of the lip line's nearest point to `p`.
    pub fn nearest(&self, p: &Vector3<f64>) -> (f64, f64) {
        let (best, _) = self
            .samples
            .iter()
            .enumerate()
            .map(|(i, q)| (i, (q - p).norm_squared()))
            .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
        // golden-section search between the neighbouring samples
        let at = |a: f64| (Vector3::from(catmull_rom_loop(&self.points, a)) - p).norm();
        let (mut lo, mut hi) = (
            Self::alpha(best as f64 - 1.0),
            Self::alpha(best as f64 + 1.0),
        );
        let g = 0.5 * (5f64.sqrt() - 1.0);
        for _ in 0..40 {
            let (x1, x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
            if at(x1) < at(x2) {
                hi = x2;
            } else {
                lo = x1;
            }
        }
        let a = 0.5 * (lo + hi);
        (a.rem_euclid(2.0 * std::f64::consts::PI), at(a))
    }

    /// The motion at `p` in state `s`.
    pub fn displacement(&self, p: &Vector3<f64>, s: &MouthState) -> Vector3<f64> {
        let (a, d) = self.nearest(p);
        field(p, a, d, &self.hinge, s)
    }
}

/// What a vertex belongs to, for its reference motion.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Part {
    /// The face's skin: the [`LipField`].
    Skin,
    /// Still with the head (eyes, upper teeth).
    Head,
    /// Turns with the jaw (lower teeth, tongue).
    Jaw,
}

/// A mesh to score, in the mouth frame, mouth widths.
#[derive(Clone, Debug)]
pub struct Subject {
    pub name: String,
    pub mesh: Mesh,
    pub points: [[f64; 3]; POINTS],
    pub hinge: [f64; 3],
    pub parts: Vec<Part>,
}

impl Subject {
    /// A procedural head as it is (the control family).
    pub fn from_head(name: &str, head: &Head) -> Self {
        Self {
            name: name.to_owned(),
            mesh: head.mesh.clone(),
            points: head.params.points,
            hinge: head.hinge,
            parts: vec![Part::Skin; head.mesh.len()],
        }
    }
}

/// The reference motion of a subject over states: each vertex's displacement per state,
/// the joints' motions, and which vertices are in the chin/lips region.
pub struct Truth {
    pub moves: Vec<Vec<Vector3<f64>>>,
    pub joints: Vec<[Vector3<f64>; POINTS]>,
    pub region: Vec<bool>,
}

pub fn truth(subject: &Subject, states: &[MouthState]) -> Truth {
    let lip = LipField::new(&subject.points, subject.hinge);
    let near: Vec<(f64, f64)> = (0..subject.mesh.len())
        .map(|v| lip.nearest(&subject.mesh.vertex(v)))
        .collect();
    let moves = states
        .iter()
        .map(|s| {
            let rotation = Rotation3::from_axis_angle(&Vector3::x_axis(), 0.35 * s.jaw);
            (0..subject.mesh.len())
                .map(|v| {
                    let p = subject.mesh.vertex(v);
                    match subject.parts[v] {
                        Part::Skin => field(&p, near[v].0, near[v].1, &lip.hinge, s),
                        Part::Head => Vector3::zeros(),
                        Part::Jaw => rotation * (p - lip.hinge) + lip.hinge - p,
                    }
                })
                .collect()
        })
        .collect();
    let joints = states
        .iter()
        .map(|s| std::array::from_fn(|k| lip.displacement(&subject.points[k].into(), s)))
        .collect();
    let region = (0..subject.mesh.len())
        .map(|v| match subject.parts[v] {
            Part::Skin => {
                let p = subject.mesh.vertex(v);
                near[v].1 < REGION_LIPS || jaw_member(&p, near[v].0, &lip.hinge) >= 0.5
            }
            Part::Jaw => true,
            Part::Head => false,
        })
        .collect();
    Truth {
        moves,
        joints,
        region,
    }
}

/// The three binders' weights on a subject, as `bind` computes them (four influences).
pub fn method_weights(subject: &Subject, network: &Network) -> [(&'static str, Weights); 3] {
    let points = subject.points.map(Vector3::from);
    let d = joint_distances(&subject.mesh, &points);
    let mut out = [
        (
            "network",
            network.predict(&Graph::new(&subject.mesh, &subject.points)),
        ),
        ("heat", heat_weights(&subject.mesh, &d, 1.0)),
        ("distance", distance_weights(&d, 1.0)),
    ];
    for (_, w) in &mut out {
        w.limit_influences();
    }
    out
}

/// The best four-influence skin against the subject's reference motion (the floor).
pub fn reference(truth: &Truth, vertices: usize) -> Weights {
    fit_weights(&truth.joints, vertices, |v, s| truth.moves[s][v])
}

/// The skinned deformation's RMS error against the reference motion, % of the mouth
/// width: over all vertices and over the chin/lips region.
pub fn errors(subject: &Subject, weights: &Weights, truth: &Truth) -> (f64, f64) {
    let rest: Vec<Vector3<f64>> = (0..subject.mesh.len())
        .map(|v| subject.mesh.vertex(v))
        .collect();
    let (mut all, mut region, mut n_all, mut n_region) = (0.0, 0.0, 0usize, 0usize);
    for (s, motion) in truth.joints.iter().enumerate() {
        let skinned = weights.skin(&rest, motion);
        for v in 0..rest.len() {
            let e = (skinned[v] - rest[v] - truth.moves[s][v]).norm_squared();
            all += e;
            n_all += 1;
            if truth.region[v] {
                region += e;
                n_region += 1;
            }
        }
    }
    (
        100.0 * (all / n_all.max(1) as f64).sqrt(),
        100.0 * (region / n_region.max(1) as f64).sqrt(),
    )
}

/// Each triangle split into four at its edges' midpoints (the same surface, four times the
/// triangles); `parts` extended with the midpoints' (an edge within one part).
pub fn subdivide(mesh: &Mesh, parts: &[Part]) -> (Mesh, Vec<Part>) {
    let mut positions = mesh.positions.clone();
    let mut parts = parts.to_vec();
    let mut mid = std::collections::HashMap::new();
    let mut triangles = Vec::with_capacity(4 * mesh.triangles.len());
    for t in &mesh.triangles {
        let mut m = [0u32; 3];
        for k in 0..3 {
            let (a, b) = (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]));
            m[k] = *mid.entry((a, b)).or_insert_with(|| {
                let (pa, pb) = (positions[a as usize], positions[b as usize]);
                positions.push(std::array::from_fn(|c| 0.5 * (pa[c] + pb[c])));
                parts.push(parts[a as usize]);
                (positions.len() - 1) as u32
            });
        }
        triangles.push([t[0], m[0], m[2]]);
        triangles.push([m[0], t[1], m[1]]);
        triangles.push([m[2], m[1], t[2]]);
        triangles.push([m[0], m[1], m[2]]);
    }
    (
        Mesh {
            positions,
            triangles,
        },
        parts,
    )
}

/// Appends a closed ellipsoid (a UV sphere scaled by `radii`) at `centre`.
fn add_ellipsoid(
    mesh: &mut Mesh,
    parts: &mut Vec<Part>,
    centre: [f64; 3],
    radii: [f64; 3],
    part: Part,
) {
    use std::f64::consts::PI;
    let (around, rings) = (16u32, 8u32);
    let base = mesh.positions.len() as u32;
    let pole = |sign: f64| [centre[0], centre[1] + sign * radii[1], centre[2]];
    mesh.positions.push(pole(1.0));
    for r in 1..rings {
        let theta = PI * r as f64 / rings as f64;
        for i in 0..around {
            let phi = 2.0 * PI * i as f64 / around as f64;
            mesh.positions.push([
                centre[0] + radii[0] * theta.sin() * phi.cos(),
                centre[1] + radii[1] * theta.cos(),
                centre[2] + radii[2] * theta.sin() * phi.sin(),
            ]);
        }
    }
    mesh.positions.push(pole(-1.0));
    let bottom = mesh.positions.len() as u32 - 1;
    let at = |r: u32, i: u32| base + 1 + (r - 1) * around + i % around;
    for i in 0..around {
        mesh.triangles.push([base, at(1, i + 1), at(1, i)]);
        mesh.triangles
            .push([bottom, at(rings - 1, i), at(rings - 1, i + 1)]);
        for r in 1..rings - 1 {
            let (a, b, c, d) = (at(r, i), at(r, i + 1), at(r + 1, i), at(r + 1, i + 1));
            mesh.triangles.push([a, b, c]);
            mesh.triangles.push([b, d, c]);
        }
    }
    parts.resize(mesh.positions.len(), part);
}

/// Family (b): a procedural head with two eyes, upper and lower teeth and a tongue as
/// separate closed shells in the same mesh (the eyes in front of the face above the mouth,
/// the teeth and the tongue behind the lips).
pub fn with_shells(name: &str, head: &Head) -> Subject {
    let mut s = Subject::from_head(name, head);
    let z = head
        .params
        .points
        .iter()
        .map(|p| p[2])
        .fold(f64::INFINITY, f64::min);
    let eye_y = 0.75 * head.params.aspect;
    for x in [-0.55, 0.55] {
        // the face's front at the eye: the nearest vertex in x, y
        let front = (0..head.mesh.len())
            .map(|v| head.mesh.vertex(v))
            .min_by(|a, b| {
                let da = (a.x - x).powi(2) + (a.y - eye_y).powi(2) - 1e-3 * a.z;
                let db = (b.x - x).powi(2) + (b.y - eye_y).powi(2) - 1e-3 * b.z;
                da.total_cmp(&db)
            })
            .unwrap_or_default();
        add_ellipsoid(
            &mut s.mesh,
            &mut s.parts,
            [x, eye_y, front.z - 0.1],
            [0.16, 0.16, 0.16],
            Part::Head,
        );
    }
    add_ellipsoid(
        &mut s.mesh,
        &mut s.parts,
        [0.0, 0.06, z - 0.2],
        [0.38, 0.05, 0.12],
        Part::Head,
    );
    add_ellipsoid(
        &mut s.mesh,
        &mut s.parts,
        [0.0, -0.06, z - 0.2],
        [0.36, 0.05, 0.12],
        Part::Jaw,
    );
    add_ellipsoid(
        &mut s.mesh,
        &mut s.parts,
        [0.0, -0.1, z - 0.5],
        [0.28, 0.07, 0.3],
        Part::Jaw,
    );
    s
}

/// Family (c): the lips' inner edges welded (the slit ring's upper and lower vertices merged
/// at their midpoint, so the mouth is closed by one seam), as a rigger's closed-mouth mesh.
pub fn lips_welded(name: &str, head: &Head) -> Subject {
    let mut s = Subject::from_head(name, head);
    s.mesh = weld_lips(&head.mesh, head.params.around);
    s
}

/// A generator head's mesh (its first ring the slit, `around` vertices) with the slit's
/// upper and lower vertices merged at their midpoints: the mouth closed by one seam.
pub fn weld_lips(mesh: &Mesh, around: usize) -> Mesh {
    let m = around;
    let mut mesh = mesh.clone();
    let mut map: Vec<u32> = (0..mesh.len() as u32).collect();
    for i in m / 2 + 1..m {
        let partner = m - i;
        let (a, b) = (mesh.positions[i], mesh.positions[partner]);
        mesh.positions[partner] = std::array::from_fn(|c| 0.5 * (a[c] + b[c]));
        map[i] = partner as u32;
    }
    for t in &mut mesh.triangles {
        *t = t.map(|v| map[v as usize]);
    }
    mesh.triangles
        .retain(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2]);
    mesh
}

/// Family (c): fins (extra triangles on existing edges of the chin and the cheeks, so those
/// edges have three) and holes (the triangles within 0.12 mouth widths of a cheek point and
/// of a point 0.6 mouth widths above the mouth removed).
pub fn fins_and_holes(name: &str, head: &Head) -> Subject {
    let mut s = Subject::from_head(name, head);
    let mesh = &mut s.mesh;
    let centroid = |m: &Mesh, t: &[u32; 3]| {
        (m.vertex(t[0] as usize) + m.vertex(t[1] as usize) + m.vertex(t[2] as usize)) / 3.0
    };
    // the face's vertex nearest to (x, y) seen from the front
    let nearest_vertex = |m: &Mesh, at: Vector3<f64>| {
        let score = |v: usize| {
            let p = m.vertex(v);
            (p.x - at.x).powi(2) + (p.y - at.y).powi(2) - 1e-3 * p.z
        };
        (0..m.len())
            .min_by(|&a, &b| score(a).total_cmp(&score(b)))
            .unwrap_or(0)
    };
    let holes: Vec<Vector3<f64>> = [[0.9, 0.25], [0.0, 0.6]]
        .iter()
        .map(|&[x, y]| mesh.vertex(nearest_vertex(mesh, Vector3::new(x, y, 1.0))))
        .collect();
    // each hole: the triangle nearest its point, and any within 0.12 of it
    let nearest_triangles: Vec<usize> = holes
        .iter()
        .map(|h| {
            (0..mesh.triangles.len())
                .min_by(|&a, &b| {
                    (centroid(mesh, &mesh.triangles[a]) - h)
                        .norm()
                        .total_cmp(&(centroid(mesh, &mesh.triangles[b]) - h).norm())
                })
                .unwrap_or(0)
        })
        .collect();
    let kept: Vec<[u32; 3]> = (0..mesh.triangles.len())
        .filter(|t| {
            !nearest_triangles.contains(t)
                && holes
                    .iter()
                    .all(|h| (centroid(mesh, &mesh.triangles[*t]) - h).norm() > 0.12)
        })
        .map(|t| mesh.triangles[t])
        .collect();
    mesh.triangles = kept;
    let normals = mesh.normals();
    for [x, y] in [[0.0, -0.6], [-0.8, -0.1], [0.8, -0.1]] {
        let v = nearest_vertex(mesh, Vector3::new(x, y, 1.0));
        let Some(t) = mesh
            .triangles
            .iter()
            .find(|t| t.contains(&(v as u32)))
            .copied()
        else {
            continue;
        };
        let (a, b) = (t[0] as usize, t[1] as usize);
        let tip = 0.5 * (mesh.vertex(a) + mesh.vertex(b)) + 0.1 * normals[a];
        mesh.positions.push([tip.x, tip.y, tip.z]);
        s.parts.push(Part::Skin);
        let n = mesh.positions.len() as u32 - 1;
        mesh.triangles.push([a as u32, b as u32, n]);
    }
    s
}

/// How far apart the upper and the lower lip are over the surface: the shortest path along
/// the mesh's edges from the vertex nearest the upper lip's middle (P4) to the one nearest
/// the lower lip's middle (P10), over their straight distance. An open mouth (the lips apart,
/// a slit or a mouth bag between them) makes the path go round the corners or through the
/// bag (about 2 and more); a closed one (the lips one surface, welded or a groove) lets it
/// cross (about 1). Infinite when no path joins them. Mouth frame, any units.
pub fn lip_path_ratio(mesh: &Mesh, points: &[[f64; 3]; POINTS]) -> f64 {
    use std::cmp::Reverse;
    use std::collections::BinaryHeap;
    let neighbours = mesh.neighbours();
    // vertices on some triangle only: an unused vertex joins nothing
    let nearest = |p: [f64; 3]| {
        let p = nalgebra::Vector3::from(p);
        (0..mesh.len())
            .filter(|&v| !neighbours[v].is_empty())
            .min_by(|&a, &b| {
                (mesh.vertex(a) - p)
                    .norm_squared()
                    .total_cmp(&(mesh.vertex(b) - p).norm_squared())
            })
            .unwrap_or(0)
    };
    let (from, to) = (nearest(points[3]), nearest(points[9]));
    let straight = (mesh.vertex(from) - mesh.vertex(to)).norm();
    if from == to || straight <= 0.0 {
        return 1.0;
    }
    let mut best = vec![f64::INFINITY; mesh.len()];
    let mut heap = BinaryHeap::new();
    best[from] = 0.0;
    // distances as ordered bits: non-negative finite f64s order like their bit patterns
    heap.push(Reverse((0u64, from)));
    while let Some(Reverse((bits, v))) = heap.pop() {
        let d = f64::from_bits(bits);
        if v == to {
            return d / straight;
        }
        if d > best[v] {
            continue;
        }
        for &u in &neighbours[v] {
            let u = u as usize;
            let next = d + (mesh.vertex(u) - mesh.vertex(v)).norm();
            if next < best[u] {
                best[u] = next;
                heap.push(Reverse((next.to_bits(), u)));
            }
        }
    }
    f64::INFINITY
}

/// A triangle mesh in Wavefront OBJ (`v x y z` and `f a b c …` lines, fans for polygons;
/// only what the bench's Blender script writes).
pub fn read_obj(path: &Path) -> Result<Mesh, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut mesh = Mesh {
        positions: Vec::new(),
        triangles: Vec::new(),
    };
    for (n, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        let bad = || format!("{}:{}: cannot read `{line:.80}`", path.display(), n + 1);
        match words.next() {
            Some("v") => {
                let c: Vec<f64> = words
                    .take(3)
                    .map(str::parse)
                    .collect::<Result<_, _>>()
                    .map_err(|_| bad())?;
                mesh.positions.push(c.try_into().map_err(|_| bad())?);
            }
            Some("f") => {
                let ids: Vec<u32> = words
                    .map(|w| {
                        w.split('/')
                            .next()
                            .unwrap_or("")
                            .parse::<u32>()
                            .map(|i| i - 1)
                    })
                    .collect::<Result<_, _>>()
                    .map_err(|_| bad())?;
                for k in 1..ids.len().saturating_sub(1) {
                    mesh.triangles.push([ids[0], ids[k], ids[k + 1]]);
                }
            }
            _ => {}
        }
    }
    mesh.check()
        .map_err(|(_, e)| format!("{}: {e}", path.display()))?;
    Ok(mesh)
}

/// Writes a mesh as OBJ (for the bench's Blender script).
pub fn write_obj(path: &Path, mesh: &Mesh) -> std::io::Result<()> {
    use std::fmt::Write as _;
    let mut out = String::new();
    for p in &mesh.positions {
        let _ = writeln!(out, "v {} {} {}", p[0], p[1], p[2]);
    }
    for t in &mesh.triangles {
        let _ = writeln!(out, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    std::fs::write(path, out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::HeadParams;

    #[test]
    fn the_position_field_agrees_with_the_generator_near_the_lips() {
        // On a generator head the nearest lip point stands in for the ring parametrisation:
        // the points themselves move exactly as the generator moves them.
        let head =
            HeadParams::around_points(HeadParams::mouth_points(0.2, 0.25, 0.3), 0.3, 3).build();
        let field = LipField::new(&head.params.points, head.hinge);
        let s = MouthState {
            jaw: 0.7,
            smile: 0.5,
            pucker: 0.3,
            raise: 0.4,
        };
        for &v in &head.point_vertices {
            let (_, d) = field.nearest(&head.mesh.vertex(v));
            assert!(d < 1e-4, "a point is {d} from the lip line");
            let e =
                (field.displacement(&head.mesh.vertex(v), &s) - head.displacement(v, &s)).norm();
            assert!(e < 1e-4, "vertex {v}: {e}");
        }
    }

    #[test]
    fn the_lip_path_ratio_tells_an_open_mouth_from_a_closed_one() {
        let head =
            HeadParams::around_points(HeadParams::mouth_points(0.2, 0.25, 0.3), 0.3, 3).build();
        let open = lip_path_ratio(&head.mesh, &head.params.points);
        let closed = lip_path_ratio(
            &weld_lips(&head.mesh, head.params.around),
            &head.params.points,
        );
        assert!(open > 2.0, "open mouth: ratio {open}");
        assert!(closed < 1.3, "closed mouth: ratio {closed}");
    }

    #[test]
    fn subdivision_keeps_the_surface_and_quadruples_the_triangles() {
        let head =
            HeadParams::around_points(HeadParams::mouth_points(0.2, 0.25, 0.3), 0.3, 1).build();
        let parts = vec![Part::Skin; head.mesh.len()];
        let (fine, p) = subdivide(&head.mesh, &parts);
        fine.validate().unwrap();
        assert_eq!(fine.triangles.len(), 4 * head.mesh.triangles.len());
        assert_eq!(p.len(), fine.len());
        let t = fine.topology();
        assert_eq!((t.shells, t.non_manifold_edges), (1, 0));
    }

    #[test]
    fn the_families_have_what_they_are_named_for() {
        let head =
            HeadParams::around_points(HeadParams::mouth_points(0.2, 0.25, 0.3), 0.3, 2).build();
        let base = head.mesh.topology();
        let shells = with_shells("s", &head);
        assert_eq!(shells.mesh.topology().shells, base.shells + 5);
        let welded = lips_welded("w", &head);
        welded.mesh.validate().unwrap();
        assert!(welded.mesh.topology().boundary_edges < base.boundary_edges);
        let fins = fins_and_holes("f", &head);
        fins.mesh.validate().unwrap();
        let t = fins.mesh.topology();
        assert!(
            t.non_manifold_edges >= 3 && t.holes >= base.holes + 2,
            "{t}"
        );
    }
}
