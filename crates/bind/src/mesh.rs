//! A triangle mesh and the geometry the binders need: checks, neighbours, normals and the
//! cotangent Laplacian.

use std::collections::HashMap;

use nalgebra::Vector3;

use crate::BindError;

/// Largest vertex count the binder accepts (a head for a mouth needs far fewer).
pub const MAX_VERTICES: usize = 1_000_000;

/// An indexed triangle mesh (positions in the character's model frame and units).
#[derive(Clone, Debug, PartialEq)]
pub struct Mesh {
    pub positions: Vec<[f64; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// Checks that the mesh can be bound: at least one triangle, indices in range, finite
    /// positions, no degenerate (repeated-index) triangles, at most [`MAX_VERTICES`].
    /// Non-manifold edges, holes and separate shells are no error: the binders work on the
    /// vertex graph and on a Laplacian that need no manifold ([`Mesh::topology`] reports them).
    pub fn validate(&self) -> Result<(), BindError> {
        self.check()
            .map_err(|(_, problem)| BindError::Geometry(problem))
    }

    /// [`validate`](Self::validate)'s checks; an error says what is wrong and, when one
    /// triangle is at fault, which.
    pub fn check(&self) -> Result<(), (Option<usize>, String)> {
        let n = self.positions.len();
        if self.triangles.is_empty() {
            return Err((None, "the mesh has no triangles".into()));
        }
        if n > MAX_VERTICES {
            return Err((
                None,
                format!("{n} vertices is more than the {MAX_VERTICES} the binder accepts"),
            ));
        }
        if let Some(i) = self
            .positions
            .iter()
            .position(|p| p.iter().any(|c| !c.is_finite()))
        {
            return Err((None, format!("vertex {i} has a non-finite coordinate")));
        }
        for (t, tri) in self.triangles.iter().enumerate() {
            if let Some(&bad) = tri.iter().find(|&&i| i as usize >= n) {
                return Err((
                    Some(t),
                    format!("triangle {t} names vertex {bad}, but there are {n} vertices"),
                ));
            }
            if tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2] {
                return Err((Some(t), format!("triangle {t} repeats a vertex ({tri:?})")));
            }
        }
        if self.extent() <= 0.0 {
            return Err((None, "all its vertices are at one point".into()));
        }
        Ok(())
    }

    /// What the surface is made of: separate shells, edges shared by more than two
    /// triangles (welded seams, fins), and holes (loops of edges with one triangle).
    pub fn topology(&self) -> Topology {
        let n = self.len();
        let mut edges: HashMap<(u32, u32), u32> = HashMap::with_capacity(self.triangles.len() * 2);
        let mut shells = UnionFind::new(n);
        for tri in &self.triangles {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
                shells.union(a as usize, b as usize);
            }
        }
        let mut used = vec![false; n];
        for tri in &self.triangles {
            for &v in tri {
                used[v as usize] = true;
            }
        }
        let mut roots = std::collections::HashSet::new();
        for v in 0..n {
            if used[v] {
                roots.insert(shells.find(v));
            }
        }
        let mut holes = UnionFind::new(n);
        let mut boundary = 0;
        let mut non_manifold = 0;
        for (&(a, b), &count) in &edges {
            if count == 1 {
                boundary += 1;
                holes.union(a as usize, b as usize);
            } else if count > 2 {
                non_manifold += 1;
            }
        }
        let mut loops = std::collections::HashSet::new();
        for (&(a, _), &count) in &edges {
            if count == 1 {
                loops.insert(holes.find(a as usize));
            }
        }
        Topology {
            shells: roots.len(),
            non_manifold_edges: non_manifold,
            boundary_edges: boundary,
            holes: loops.len(),
        }
    }

    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    pub fn vertex(&self, i: usize) -> Vector3<f64> {
        Vector3::from(self.positions[i])
    }

    /// Each vertex's neighbours along triangle edges, sorted, without itself.
    pub fn neighbours(&self) -> Vec<Vec<u32>> {
        let mut nb = vec![Vec::new(); self.len()];
        for tri in &self.triangles {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                nb[a as usize].push(b);
                nb[b as usize].push(a);
            }
        }
        for list in &mut nb {
            list.sort_unstable();
            list.dedup();
        }
        nb
    }

    /// Area-weighted vertex normals (unit; zero for a vertex in no triangle).
    pub fn normals(&self) -> Vec<Vector3<f64>> {
        let mut normals = vec![Vector3::zeros(); self.len()];
        for tri in &self.triangles {
            let [a, b, c] = tri.map(|i| self.vertex(i as usize));
            let n = (b - a).cross(&(c - a));
            for &i in tri {
                normals[i as usize] += n;
            }
        }
        for n in &mut normals {
            let len = n.norm();
            if len > 0.0 {
                *n /= len;
            }
        }
        normals
    }

    /// The cotangent Laplacian as a symmetric sparse matrix (positive semi-definite: edge
    /// weights `(cot α + cot β)/2`, negative ones clamped to zero so the matrix stays an
    /// M-matrix and the heat solution stays in [0, 1]), and the lumped (barycentric) vertex
    /// areas.
    pub fn cotangent_laplacian(&self) -> (SparseSym, Vec<f64>) {
        let n = self.len();
        let mut weights: HashMap<(u32, u32), f64> =
            HashMap::with_capacity(self.triangles.len() * 3);
        let mut area = vec![0.0; n];
        for tri in &self.triangles {
            let p = tri.map(|i| self.vertex(i as usize));
            let double_area = (p[1] - p[0]).cross(&(p[2] - p[0])).norm();
            for &i in tri {
                area[i as usize] += double_area / 6.0;
            }
            if double_area <= 0.0 {
                continue;
            }
            for k in 0..3 {
                // the angle at corner k faces the edge (k+1, k+2)
                let (i, j) = (tri[(k + 1) % 3], tri[(k + 2) % 3]);
                let u = p[(k + 1) % 3] - p[k];
                let v = p[(k + 2) % 3] - p[k];
                let cot = u.dot(&v) / double_area;
                *weights.entry((i.min(j), i.max(j))).or_insert(0.0) += 0.5 * cot;
            }
        }
        let mut rows: Vec<Vec<(u32, f64)>> = vec![Vec::new(); n];
        let mut diag = vec![0.0; n];
        for (&(i, j), &w) in &weights {
            let w = w.max(0.0);
            if w == 0.0 {
                continue;
            }
            rows[i as usize].push((j, -w));
            rows[j as usize].push((i, -w));
            diag[i as usize] += w;
            diag[j as usize] += w;
        }
        for r in &mut rows {
            r.sort_unstable_by_key(|e| e.0);
        }
        (SparseSym { diag, off: rows }, area)
    }

    /// The mesh with every position mapped by `f`.
    pub fn map_positions(&self, f: impl Fn([f64; 3]) -> [f64; 3]) -> Mesh {
        Mesh {
            positions: self.positions.iter().map(|&p| f(p)).collect(),
            triangles: self.triangles.clone(),
        }
    }

    /// Length of the longest edge of the bounding box.
    pub fn extent(&self) -> f64 {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in &self.positions {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        (0..3).map(|k| hi[k] - lo[k]).fold(0.0, f64::max)
    }
}

/// Distance from `p` to the triangle `t` (its closest point: inside, on an edge or a corner;
/// Ericson, Real-Time Collision Detection, 5.1.5).
pub fn point_triangle_distance(p: &Vector3<f64>, t: &[Vector3<f64>; 3]) -> f64 {
    let [a, b, c] = *t;
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return ap.norm();
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return bp.norm();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (p - (a + ab * v)).norm();
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return cp.norm();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (p - (a + ac * w)).norm();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (p - (b + (c - b) * w)).norm();
    }
    let denom = va + vb + vc;
    if denom.abs() < f64::MIN_POSITIVE {
        return ap.norm().min(bp.norm()).min(cp.norm());
    }
    let (v, w) = (vb / denom, vc / denom);
    (p - (a + ab * v + ac * w)).norm()
}

/// What a mesh's surface is made of ([`Mesh::topology`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Topology {
    /// Connected pieces (a head with separate eyes and teeth has several).
    pub shells: usize,
    /// Edges shared by more than two triangles.
    pub non_manifold_edges: usize,
    /// Edges with one triangle.
    pub boundary_edges: usize,
    /// Connected loops of boundary edges (the neck's opening counts as one).
    pub holes: usize,
}

impl std::fmt::Display for Topology {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(
            f,
            "{} shell(s), {} non-manifold edge(s), {} hole(s) ({} open edges)",
            self.shells, self.non_manifold_edges, self.holes, self.boundary_edges
        )
    }
}

/// Disjoint sets over 0..n (path halving, union by size).
struct UnionFind {
    parent: Vec<u32>,
    size: Vec<u32>,
}

impl UnionFind {
    fn new(n: usize) -> Self {
        Self {
            parent: (0..n as u32).collect(),
            size: vec![1; n],
        }
    }

    fn find(&mut self, mut v: usize) -> usize {
        while self.parent[v] as usize != v {
            let up = self.parent[self.parent[v] as usize];
            self.parent[v] = up;
            v = up as usize;
        }
        v
    }

    fn union(&mut self, a: usize, b: usize) {
        let (mut a, mut b) = (self.find(a), self.find(b));
        if a == b {
            return;
        }
        if self.size[a] < self.size[b] {
            std::mem::swap(&mut a, &mut b);
        }
        self.parent[b] = a as u32;
        self.size[a] += self.size[b];
    }
}

/// A symmetric sparse matrix: the diagonal and each row's off-diagonal entries.
#[derive(Clone, Debug)]
pub struct SparseSym {
    pub diag: Vec<f64>,
    pub off: Vec<Vec<(u32, f64)>>,
}

impl SparseSym {
    /// y = (self + diag(extra)) x
    pub fn mul(&self, extra: &[f64], x: &[f64], y: &mut [f64]) {
        for i in 0..x.len() {
            let mut s = (self.diag[i] + extra[i]) * x[i];
            for &(j, w) in &self.off[i] {
                s += w * x[j as usize];
            }
            y[i] = s;
        }
    }

    /// Solves (self + diag(extra)) x = b by conjugate gradients with a Jacobi
    /// preconditioner, from `x` as the first guess, to a relative residual of `tol`.
    /// Returns the iterations used.
    pub fn solve_cg(
        &self,
        extra: &[f64],
        b: &[f64],
        x: &mut [f64],
        tol: f64,
        max_iter: usize,
    ) -> usize {
        let n = b.len();
        let inv: Vec<f64> = (0..n)
            .map(|i| {
                let d = self.diag[i] + extra[i];
                if d > 0.0 {
                    1.0 / d
                } else {
                    1.0
                }
            })
            .collect();
        let mut ax = vec![0.0; n];
        self.mul(extra, x, &mut ax);
        let mut r: Vec<f64> = (0..n).map(|i| b[i] - ax[i]).collect();
        let b_norm = b.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
        let mut z: Vec<f64> = (0..n).map(|i| inv[i] * r[i]).collect();
        let mut p = z.clone();
        let mut rz: f64 = (0..n).map(|i| r[i] * z[i]).sum();
        let mut ap = vec![0.0; n];
        for iter in 0..max_iter {
            let r_norm = r.iter().map(|v| v * v).sum::<f64>().sqrt();
            if r_norm <= tol * b_norm {
                return iter;
            }
            self.mul(extra, &p, &mut ap);
            let pap: f64 = (0..n).map(|i| p[i] * ap[i]).sum();
            if pap <= 0.0 {
                return iter;
            }
            let alpha = rz / pap;
            for i in 0..n {
                x[i] += alpha * p[i];
                r[i] -= alpha * ap[i];
                z[i] = inv[i] * r[i];
            }
            let rz_new: f64 = (0..n).map(|i| r[i] * z[i]).sum();
            let beta = rz_new / rz;
            rz = rz_new;
            for i in 0..n {
                p[i] = z[i] + beta * p[i];
            }
        }
        max_iter
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad() -> Mesh {
        Mesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        }
    }

    #[test]
    fn a_quad_is_valid_and_its_normals_point_up() {
        let m = quad();
        m.validate().unwrap();
        for n in m.normals() {
            assert!((n - Vector3::z()).norm() < 1e-12);
        }
        assert_eq!(m.neighbours()[0], vec![1, 2, 3]);
    }

    #[test]
    fn no_triangles_are_refused_and_non_manifold_edges_reported() {
        let mut m = quad();
        m.triangles.clear();
        assert!(m
            .validate()
            .unwrap_err()
            .to_string()
            .contains("no triangles"));
        let mut m = quad();
        m.positions.push([0.5, 0.5, 1.0]);
        m.triangles.push([0, 2, 4]);
        m.validate().unwrap();
        let t = m.topology();
        assert_eq!(t.non_manifold_edges, 1, "{t}");
        assert_eq!(t.shells, 1);
        // a second, separate shell with a hole
        let base = m.positions.len() as u32;
        m.positions
            .extend([[5.0, 0.0, 0.0], [6.0, 0.0, 0.0], [5.0, 1.0, 0.0]]);
        m.triangles.push([base, base + 1, base + 2]);
        let t = m.topology();
        assert_eq!((t.shells, t.holes), (2, 2), "{t}");
        let flat = Mesh {
            positions: vec![[1.0; 3]; 3],
            triangles: vec![[0, 1, 2]],
        };
        assert!(flat
            .validate()
            .unwrap_err()
            .to_string()
            .contains("one point"));
        let mut m = quad();
        m.triangles.push([0, 1, 9]);
        assert!(m.validate().unwrap_err().to_string().contains("vertex 9"));
    }

    #[test]
    fn point_triangle_distance_inside_on_edges_and_corners() {
        let t = [Vector3::zeros(), Vector3::x(), Vector3::y()];
        let d = |x: f64, y: f64, z: f64| point_triangle_distance(&Vector3::new(x, y, z), &t);
        assert!((d(0.2, 0.2, 0.5) - 0.5).abs() < 1e-12);
        assert!((d(0.5, -1.0, 0.0) - 1.0).abs() < 1e-12);
        assert!((d(-3.0, -4.0, 0.0) - 5.0).abs() < 1e-12);
        assert!((d(1.0, 1.0, 0.0) - 0.5f64.sqrt()).abs() < 1e-12);
        assert!((d(2.0, 0.0, 0.0) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_laplacian_annihilates_constants_and_cg_solves() {
        let m = quad();
        let (l, area) = m.cotangent_laplacian();
        assert!((area.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        let ones = vec![1.0; 4];
        let mut y = vec![0.0; 4];
        l.mul(&[0.0; 4], &ones, &mut y);
        assert!(y.iter().all(|v| v.abs() < 1e-12));
        let extra = vec![1.0, 0.0, 0.0, 2.0];
        let b = vec![1.0, 2.0, 3.0, 4.0];
        let mut x = vec![0.0; 4];
        l.solve_cg(&extra, &b, &mut x, 1e-12, 100);
        l.mul(&extra, &x, &mut y);
        for i in 0..4 {
            assert!((y[i] - b[i]).abs() < 1e-9);
        }
    }
}
