//! The learned binder: a graph network from per-vertex features to skin weights.
//!
//! ```text
//! features X (N×18: position and normal in the mouth frame, distance to each of the 12 points,
//!             all in mouth widths)
//!   MLP ─────────────────────────────── F1 (N×64)
//!   graph conv (self ‖ neighbour mean → linear, ReLU) H (N×256)
//!   graph max-pool over each vertex's neighbourhood   P (N×256)
//!   concatenate F1 ‖ H ‖ P ──────────── F2 (N×576)
//!   global: MLP (N×64) → max over vertices → replicated to every vertex  G (N×64)
//!   local:  graph conv (N×64) → graph conv (N×64)                        L (N×64)
//!   G ‖ L → MLP (N×64) → linear (N×13) → softmax over joints → weights
//! ```
//!
//! A graph convolution maps `[x_v ‖ mean(x_u : u ∈ N(v) ∪ {v})]` through a linear layer
//! and a ReLU; the pool takes the element-wise maximum over `N(v) ∪ {v}`. Training minimises
//! the mean over vertices of `KL(reference ‖ predicted)` with Adam (Kingma & Ba 2015).
//!
//! It is written by hand (forward and backward passes below, checked against finite
//! differences in the tests) on nalgebra's matrices, whose products go through the
//! `matrixmultiply` kernels: ARCHITECTURE.md says why no ML framework.

use std::path::Path;

use nalgebra::DMatrix;
use rand::{Rng, SeedableRng};

use crate::mesh::Mesh;
use crate::procedural::POINTS;
use crate::weights::{Weights, JOINTS};
use crate::BindError;

/// Per-vertex input features: position (3), normal (3), distance to each point (12).
pub const FEATURES: usize = 6 + POINTS;

type Mat = DMatrix<f32>;

/// Layer widths. [`Widths::PAPER`] has the 64 and 576 (= 64 + 2·256) of the architecture.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Widths {
    pub first: usize,
    pub conv: usize,
    pub global: usize,
    pub local: usize,
    pub head: usize,
}

impl Widths {
    pub const PAPER: Self = Self {
        first: 64,
        conv: 256,
        global: 64,
        local: 64,
        head: 64,
    };
    /// The shipped network: the same graph at half the first width and a quarter of the
    /// convolution's (F2 is N×160), about 7× cheaper to train on a shared two-core machine.
    pub const SMALL: Self = Self {
        first: 32,
        conv: 64,
        global: 32,
        local: 32,
        head: 32,
    };
    /// For tests: the same graph, narrow.
    pub const TINY: Self = Self {
        first: 8,
        conv: 8,
        global: 8,
        local: 8,
        head: 8,
    };
    fn second(&self) -> usize {
        self.first + 2 * self.conv
    }

    /// (inputs, outputs) of each linear layer, in order.
    fn layer_shapes(&self) -> [(usize, usize); 7] {
        [
            (FEATURES, self.first),
            (2 * self.first, self.conv),
            (self.second(), self.global),
            (2 * self.second(), self.local),
            (2 * self.local, self.local),
            (self.global + self.local, self.head),
            (self.head, JOINTS),
        ]
    }

    /// Parameters of a network of these widths, computed without building it.
    pub fn parameter_count(&self) -> usize {
        self.layer_shapes().iter().map(|(i, o)| i * o + o).sum()
    }
}

/// A linear layer: `Y = X W + b`.
#[derive(Clone, Debug)]
struct Linear {
    w: Mat,
    b: Vec<f32>,
}

impl Linear {
    fn new(input: usize, output: usize, rng: &mut impl Rng) -> Self {
        // He initialisation for the ReLU layers.
        let bound = (6.0 / input as f32).sqrt();
        Self {
            w: Mat::from_fn(input, output, |_, _| rng.random_range(-bound..bound)),
            b: vec![0.0; output],
        }
    }

    fn forward(&self, x: &Mat) -> Mat {
        let mut y = x * &self.w;
        for (c, b) in self.b.iter().enumerate() {
            y.column_mut(c).add_scalar_mut(*b);
        }
        y
    }

    /// Accumulates the gradients into `grad` and returns dX.
    fn backward(&self, x: &Mat, dy: &Mat, grad: &mut Linear) -> Mat {
        grad.w += x.transpose() * dy;
        for c in 0..dy.ncols() {
            grad.b[c] += dy.column(c).sum();
        }
        dy * self.w.transpose()
    }

    fn zeros_like(&self) -> Self {
        Self {
            w: Mat::zeros(self.w.nrows(), self.w.ncols()),
            b: vec![0.0; self.b.len()],
        }
    }

    fn params(&mut self) -> impl Iterator<Item = &mut f32> {
        self.w.as_mut_slice().iter_mut().chain(self.b.iter_mut())
    }
}

/// The network's parameters.
#[derive(Clone, Debug)]
pub struct Network {
    pub widths: Widths,
    layers: Vec<Linear>,
}

/// A mesh prepared for the network: features and neighbourhoods.
#[derive(Clone, Debug)]
pub struct Graph {
    pub features: Mat,
    /// Each vertex's neighbourhood including itself.
    pub neighbourhood: Vec<Vec<u32>>,
}

impl Graph {
    /// Features of a mesh given in the mouth frame in mouth-width units, with the points
    /// (same frame and units).
    pub fn new(mesh: &Mesh, points: &[[f64; 3]; POINTS]) -> Self {
        let normals = mesh.normals();
        let features = Mat::from_fn(mesh.len(), FEATURES, |v, k| {
            let p = mesh.positions[v];
            (match k {
                0..3 => p[k],
                3..6 => normals[v][k - 3],
                _ => {
                    let q = points[k - 6];
                    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
                }
            }) as f32
        });
        let neighbourhood = mesh
            .neighbours()
            .into_iter()
            .enumerate()
            .map(|(v, mut nb)| {
                nb.push(v as u32);
                nb
            })
            .collect();
        Self {
            features,
            neighbourhood,
        }
    }
}

fn relu(mut x: Mat) -> Mat {
    x.apply(|v| *v = v.max(0.0));
    x
}

fn relu_backward(y: &Mat, mut dy: Mat) -> Mat {
    dy.zip_apply(y, |d, y| {
        if y <= 0.0 {
            *d = 0.0
        }
    });
    dy
}

fn mean_aggregate(x: &Mat, nb: &[Vec<u32>]) -> Mat {
    let mut out = Mat::zeros(x.nrows(), x.ncols());
    for c in 0..x.ncols() {
        let col = x.column(c);
        let mut o = out.column_mut(c);
        for (v, list) in nb.iter().enumerate() {
            let s: f32 = list.iter().map(|&u| col[u as usize]).sum();
            o[v] = s / list.len() as f32;
        }
    }
    out
}

fn mean_aggregate_backward(d: &Mat, nb: &[Vec<u32>]) -> Mat {
    let mut out = Mat::zeros(d.nrows(), d.ncols());
    for c in 0..d.ncols() {
        let col = d.column(c);
        let mut o = out.column_mut(c);
        for (v, list) in nb.iter().enumerate() {
            let share = col[v] / list.len() as f32;
            for &u in list {
                o[u as usize] += share;
            }
        }
    }
    out
}

/// Element-wise max over each neighbourhood; also where each maximum came from.
fn max_pool(x: &Mat, nb: &[Vec<u32>]) -> (Mat, Vec<u32>) {
    let mut out = Mat::zeros(x.nrows(), x.ncols());
    let mut arg = vec![0u32; x.nrows() * x.ncols()];
    for c in 0..x.ncols() {
        let col = x.column(c);
        for (v, list) in nb.iter().enumerate() {
            let mut best = list[0];
            for &u in list {
                if col[u as usize] > col[best as usize] {
                    best = u;
                }
            }
            out[(v, c)] = col[best as usize];
            arg[c * x.nrows() + v] = best;
        }
    }
    (out, arg)
}

fn hcat(parts: &[&Mat]) -> Mat {
    let rows = parts[0].nrows();
    let cols = parts.iter().map(|p| p.ncols()).sum();
    let mut out = Mat::zeros(rows, cols);
    let mut at = 0;
    for p in parts {
        out.columns_mut(at, p.ncols()).copy_from(*p);
        at += p.ncols();
    }
    out
}

fn conv_input(x: &Mat, nb: &[Vec<u32>]) -> Mat {
    hcat(&[x, &mean_aggregate(x, nb)])
}

/// dX of a graph convolution's input `[x ‖ mean(x)]` given d of that input.
fn conv_input_backward(d: &Mat, nb: &[Vec<u32>]) -> Mat {
    let half = d.ncols() / 2;
    let own = d.columns(0, half).into_owned();
    own + mean_aggregate_backward(&d.columns(half, half).into_owned(), nb)
}

/// Everything the backward pass needs.
struct Trace {
    x: Mat,
    f1: Mat,
    c1_in: Mat,
    h: Mat,
    pool_arg: Vec<u32>,
    f2: Mat,
    g1: Mat,
    g_arg: Vec<usize>,
    l1_in: Mat,
    l1: Mat,
    l2_in: Mat,
    l2: Mat,
    z: Mat,
    z1: Mat,
    q: Mat,
}

impl Network {
    /// A freshly initialised network (reproducible from `seed`).
    pub fn new(widths: Widths, seed: u64) -> Self {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let layers = widths
            .layer_shapes()
            .iter()
            .map(|&(i, o)| Linear::new(i, o, &mut rng))
            .collect();
        Self { widths, layers }
    }

    pub fn parameter_count(&self) -> usize {
        self.layers.iter().map(|l| l.w.len() + l.b.len()).sum()
    }

    fn forward(&self, g: &Graph) -> Trace {
        let nb = &g.neighbourhood;
        let l = &self.layers;
        let x = g.features.clone();
        let f1 = relu(l[0].forward(&x));
        let c1_in = conv_input(&f1, nb);
        let h = relu(l[1].forward(&c1_in));
        let (p, pool_arg) = max_pool(&h, nb);
        let f2 = hcat(&[&f1, &h, &p]);
        let g1 = relu(l[2].forward(&f2));
        let n = f2.nrows();
        let mut g_arg = vec![0usize; g1.ncols()];
        let mut grep = Mat::zeros(n, g1.ncols());
        for c in 0..g1.ncols() {
            let col = g1.column(c);
            let arg = col.iamax_full().0;
            // iamax is by absolute value; ReLU outputs are ≥ 0 so it is the maximum
            g_arg[c] = arg;
            grep.column_mut(c).fill(col[arg]);
        }
        let l1_in = conv_input(&f2, nb);
        let l1 = relu(l[3].forward(&l1_in));
        let l2_in = conv_input(&l1, nb);
        let l2 = relu(l[4].forward(&l2_in));
        let z = hcat(&[&grep, &l2]);
        let z1 = relu(l[5].forward(&z));
        let mut q = l[6].forward(&z1);
        for mut row in q.row_iter_mut() {
            let max = row.max();
            row.apply(|v| *v = (*v - max).exp());
            let s = row.sum();
            row /= s;
        }
        Trace {
            x,
            f1,
            c1_in,
            h,
            pool_arg,
            f2,
            g1,
            g_arg,
            l1_in,
            l1,
            l2_in,
            l2,
            z,
            z1,
            q,
        }
    }

    /// Skin weights for a graph (full rows; the binder limits them to four influences).
    pub fn predict(&self, g: &Graph) -> Weights {
        let q = self.forward(g).q;
        Weights {
            rows: (0..q.nrows())
                .map(|v| std::array::from_fn(|j| q[(v, j)] as f64))
                .collect(),
        }
    }

    /// Mean KL(reference ‖ predicted) over vertices, and its gradient.
    fn loss_and_gradient(&self, g: &Graph, reference: &Mat) -> (f64, Vec<Linear>) {
        let t = self.forward(g);
        let nb = &g.neighbourhood;
        let n = t.q.nrows();
        let mut loss = 0.0f64;
        for v in 0..n {
            for j in 0..JOINTS {
                let p = reference[(v, j)] as f64;
                if p > 0.0 {
                    loss += p * (p / (t.q[(v, j)] as f64).max(1e-30)).ln();
                }
            }
        }
        loss /= n as f64;
        let mut grads: Vec<Linear> = self.layers.iter().map(Linear::zeros_like).collect();
        let l = &self.layers;
        let w = self.widths;
        // softmax + KL: d score = (q − p) / N
        let ds = (&t.q - reference) / n as f32;
        let dz1 = l[6].backward(&t.z1, &ds, &mut grads[6]);
        let dz = l[5].backward(&t.z, &relu_backward(&t.z1, dz1), &mut grads[5]);
        let dgrep = dz.columns(0, w.global).into_owned();
        let dl2 = dz.columns(w.global, w.local).into_owned();
        // local branch
        let dl2_in = l[4].backward(&t.l2_in, &relu_backward(&t.l2, dl2), &mut grads[4]);
        let dl1 = conv_input_backward(&dl2_in, nb);
        let dl1_in = l[3].backward(&t.l1_in, &relu_backward(&t.l1, dl1), &mut grads[3]);
        let mut df2 = conv_input_backward(&dl1_in, nb);
        // global branch: the max's gradient goes to the vertex that held it
        let mut dg1 = Mat::zeros(n, w.global);
        for c in 0..w.global {
            dg1[(t.g_arg[c], c)] = dgrep.column(c).sum();
        }
        df2 += l[2].backward(&t.f2, &relu_backward(&t.g1, dg1), &mut grads[2]);
        // F2 = F1 ‖ H ‖ P
        let mut df1 = df2.columns(0, w.first).into_owned();
        let mut dh = df2.columns(w.first, w.conv).into_owned();
        let dp = df2.columns(w.first + w.conv, w.conv);
        for c in 0..w.conv {
            for v in 0..n {
                let from = t.pool_arg[c * n + v] as usize;
                dh[(from, c)] += dp[(v, c)];
            }
        }
        let dc1_in = l[1].backward(&t.c1_in, &relu_backward(&t.h, dh), &mut grads[1]);
        df1 += conv_input_backward(&dc1_in, nb);
        l[0].backward(&t.x, &relu_backward(&t.f1, df1), &mut grads[0]);
        (loss, grads)
    }

    /// Writes the parameters: a header line, then little-endian f32s.
    pub fn save(&self, path: &Path) -> Result<(), BindError> {
        let w = self.widths;
        let mut bytes = format!(
            "mouthpiece-bind-network 1 {} {} {} {} {} {}\n",
            w.first,
            w.conv,
            w.global,
            w.local,
            w.head,
            self.parameter_count()
        )
        .into_bytes();
        let mut me = self.clone();
        for layer in &mut me.layers {
            for p in layer.params() {
                bytes.extend_from_slice(&p.to_le_bytes());
            }
        }
        std::fs::write(path, bytes).map_err(|cause| BindError::Write {
            path: path.to_path_buf(),
            cause,
        })
    }

    /// Reads parameters written by [`save`](Self::save).
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, BindError> {
        let bad = |problem: &str| BindError::BadModel {
            path: path.to_path_buf(),
            problem: problem.to_owned(),
        };
        let end = bytes
            .iter()
            .position(|&b| b == b'\n')
            .ok_or_else(|| bad("no header line"))?;
        let header = std::str::from_utf8(&bytes[..end]).map_err(|_| bad("header is not text"))?;
        let fields: Vec<&str> = header.split(' ').collect();
        if fields.len() != 8 || fields[0] != "mouthpiece-bind-network" || fields[1] != "1" {
            return Err(bad("header is not `mouthpiece-bind-network 1 …`"));
        }
        let num: Vec<usize> = fields[2..]
            .iter()
            .map(|f| f.parse().map_err(|_| bad("a width is not a number")))
            .collect::<Result<_, _>>()?;
        if num[..5].iter().any(|&v| v == 0 || v > 4096) {
            return Err(bad("a layer width is 0 or above 4096"));
        }
        let widths = Widths {
            first: num[0],
            conv: num[1],
            global: num[2],
            local: num[3],
            head: num[4],
        };
        // Checked against the header and the file's size before any layer is allocated.
        if widths.parameter_count() != num[5] || bytes.len() - end - 1 != 4 * num[5] {
            return Err(bad(
                "the parameter count does not match the widths or the file size",
            ));
        }
        let mut net = Self::new(widths, 0);
        let mut values = bytes[end + 1..]
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]));
        for layer in &mut net.layers {
            for p in layer.params() {
                *p = values.next().unwrap_or(f32::NAN);
                if !p.is_finite() {
                    return Err(bad("a parameter is not a finite number"));
                }
            }
        }
        Ok(net)
    }
}

/// Adam (β₁ 0.9, β₂ 0.999, ε 1e-8).
pub struct Adam {
    rate: f32,
    m: Vec<Linear>,
    v: Vec<Linear>,
    step: i32,
}

impl Adam {
    pub fn new(net: &Network, rate: f32) -> Self {
        Self {
            rate,
            m: net.layers.iter().map(Linear::zeros_like).collect(),
            v: net.layers.iter().map(Linear::zeros_like).collect(),
            step: 0,
        }
    }

    /// One step on one graph; returns the loss before the step.
    pub fn step(&mut self, net: &mut Network, graph: &Graph, reference: &Mat) -> f64 {
        let (loss, mut grads) = net.loss_and_gradient(graph, reference);
        self.step += 1;
        let (b1, b2) = (0.9f32, 0.999f32);
        let c1 = 1.0 - b1.powi(self.step);
        let c2 = 1.0 - b2.powi(self.step);
        for (((layer, g), m), v) in net
            .layers
            .iter_mut()
            .zip(&mut grads)
            .zip(&mut self.m)
            .zip(&mut self.v)
        {
            for (((p, g), m), v) in layer
                .params()
                .zip(g.params())
                .zip(m.params())
                .zip(v.params())
            {
                *m = b1 * *m + (1.0 - b1) * *g;
                *v = b2 * *v + (1.0 - b2) * *g * *g;
                *p -= self.rate * (*m / c1) / ((*v / c2).sqrt() + 1e-8);
            }
        }
        loss
    }
}

/// Reference weights as the training target matrix.
pub fn target(reference: &Weights) -> Mat {
    Mat::from_fn(reference.len(), JOINTS, |v, j| reference.rows[v][j] as f32)
}

/// Mean KL(reference ‖ network) on a graph (the training loss).
pub fn loss(net: &Network, graph: &Graph, reference: &Mat) -> f64 {
    net.loss_and_gradient(graph, reference).0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::HeadParams;

    fn small_case() -> (Graph, Mat) {
        let head =
            HeadParams::around_points(HeadParams::mouth_points(0.2, 0.2, 0.2), 0.0, 1).build();
        let g = Graph::new(&head.mesh, &head.params.points);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let mut p = Mat::from_fn(head.mesh.len(), JOINTS, |_, _| {
            rng.random_range(0.0f32..1.0)
        });
        for mut row in p.row_iter_mut() {
            let s = row.sum();
            row /= s;
        }
        (g, p)
    }

    #[test]
    fn gradients_match_finite_differences() {
        let (g, p) = small_case();
        let net = Network::new(Widths::TINY, 5);
        let (_, grads) = net.loss_and_gradient(&g, &p);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        for layer in 0..net.layers.len() {
            for _ in 0..4 {
                let (r, c) = (
                    rng.random_range(0..net.layers[layer].w.nrows()),
                    rng.random_range(0..net.layers[layer].w.ncols()),
                );
                let h = 2e-3f32;
                let mut plus = net.clone();
                plus.layers[layer].w[(r, c)] += h;
                let mut minus = net.clone();
                minus.layers[layer].w[(r, c)] -= h;
                let numeric = (loss(&plus, &g, &p) - loss(&minus, &g, &p)) / (2.0 * h as f64);
                let analytic = grads[layer].w[(r, c)] as f64;
                assert!(
                    (numeric - analytic).abs() <= 2e-2 * numeric.abs().max(analytic.abs()) + 1e-4,
                    "layer {layer} ({r},{c}): numeric {numeric} analytic {analytic}"
                );
            }
        }
    }

    #[test]
    fn training_lowers_the_loss_and_save_load_round_trips() {
        let (g, p) = small_case();
        let mut net = Network::new(Widths::TINY, 3);
        let before = loss(&net, &g, &p);
        let mut adam = Adam::new(&net, 1e-2);
        for _ in 0..30 {
            adam.step(&mut net, &g, &p);
        }
        assert!(loss(&net, &g, &p) < 0.8 * before);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("net.bin");
        net.save(&path).unwrap();
        let back = Network::from_bytes(&std::fs::read(&path).unwrap(), &path).unwrap();
        assert_eq!(back.predict(&g), net.predict(&g));
        let err = Network::from_bytes(b"garbage\n", &path)
            .unwrap_err()
            .to_string();
        assert!(err.contains("header"), "{err}");
    }
}
