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
    /// positions, no degenerate (repeated-index) triangles, at most [`MAX_VERTICES`], and
    /// every edge shared by at most two triangles (a non-manifold edge has no well-defined
    /// surface around it, so neither heat diffusion nor graph neighbours are meaningful).
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
        let mut edges: HashMap<(u32, u32), u32> = HashMap::with_capacity(self.triangles.len() * 2);
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
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                let count = edges.entry((a.min(b), a.max(b))).or_insert(0);
                *count += 1;
                if *count > 2 {
                    let (a, b) = (a.min(b), a.max(b));
                    return Err((
                        Some(t),
                        format!(
                            "non-manifold: the edge between vertices {a} and {b} (at {:?} and \
                             {:?}) belongs to more than two triangles (triangle {t} is the third)",
                            self.positions[a as usize], self.positions[b as usize]
                        ),
                    ));
                }
            }
        }
        Ok(())
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
    fn no_triangles_and_non_manifold_edges_are_refused() {
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
        let err = m.validate().unwrap_err().to_string();
        assert!(
            err.contains("non-manifold") && err.contains("vertices 0 and 2"),
            "{err}"
        );
        let mut m = quad();
        m.triangles.push([0, 1, 9]);
        assert!(m.validate().unwrap_err().to_string().contains("vertex 9"));
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
