//! Naming dots: from geometry (at calibration and re-acquisition) and by optimal assignment
//! to predicted positions (every other frame).

use mouthpiece_detect::DotRole;
use mouthpiece_retarget::PerformerLayout;
use smallvec::SmallVec;

use crate::Vec3;

/// A short per-frame list kept on the stack (dots, candidates: a few dozen at most), so that
/// tracking a frame needs no heap allocation; longer lists spill to the heap and still work.
pub type Small<T> = SmallVec<[T; 32]>;

/// Corners nearer each other than this (metres), or a forehead this close to the line
/// through them, give no mouth frame: the geometry cannot say left from right.
pub const DEGENERATE_MOUTH_M: f64 = 1e-6;

/// Assignment costs are whole numbers: squared pixel distances in this many units per px²
/// (hundredths, finer than the detector's sub-pixel precision; a gate of a thousand pixels
/// still costs far less than `FORBIDDEN`).
pub const COST_UNITS_PER_PX2: f64 = 100.0;

/// The cost of a gated-out pair (a candidate outside the dot's gate or of the wrong role):
/// above any "missing" cost, so such a pair is never chosen.
const FORBIDDEN: i64 = 1_000_000_000_000;

/// A dot's "missing" column costs its gate squared plus this (cost units): a candidate just
/// inside the gate rounds to at most the gate squared, and must still beat "missing".
const MISSING_TIE_BREAK: i64 = 1;

/// A detected dot with its 3D position, not yet named.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    /// Sub-pixel centre in the colour image.
    pub pixel: [f64; 2],
    /// Camera frame, metres.
    pub point: Vec3,
    /// What its colour class may hold.
    pub role: DotRole,
}

impl Candidate {
    fn can_be_lip(&self) -> bool {
        matches!(self.role, DotRole::Lip | DotRole::Any)
    }
    fn can_be_forehead(&self) -> bool {
        matches!(self.role, DotRole::Forehead | DotRole::Any)
    }
}

/// Why the geometry did not give a full set of names.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum GeometryFailure {
    /// Not the expected number of lip / forehead candidates.
    Count { lip: usize, forehead: usize },
    /// Walking around the mouth met `upper` dots between the corners on the forehead side and
    /// `lower` on the other, not the layout's halves.
    LipSplit { upper: usize, lower: usize },
    /// Degenerate geometry (coincident corners, forehead on the lip line).
    Degenerate,
}

/// Names every dot from 3D geometry alone: the forehead dots are the forehead class (or, for
/// a single paint, the `K` highest dots in the image); the mouth corners are the two lip dots
/// furthest apart; the left corner is the one that makes the mouth frame face the camera;
/// the lip dots are then named in the order met walking around the mouth from the left
/// corner over the upper lip (the side towards the forehead), which must reach the right
/// corner at `D⌊N/2⌋+1`. Forehead dots are ordered from the performer's left to right.
///
/// Returns, per dot (lip dots `D1..DN` then forehead `F1..FK`), the candidate index.
pub fn label_by_geometry(
    cands: &[Candidate],
    layout: PerformerLayout,
) -> Result<Small<usize>, GeometryFailure> {
    let (n, k) = (layout.lip_dots, layout.forehead_dots);
    let mut forehead: Small<usize> = (0..cands.len())
        .filter(|&i| cands[i].role == DotRole::Forehead)
        .collect();
    let mut any: Small<usize> = (0..cands.len())
        .filter(|&i| cands[i].role == DotRole::Any)
        .collect();
    if forehead.len() < k && !any.is_empty() {
        // One paint for lips and forehead: the forehead dots are the highest in the image.
        any.sort_by(|&a, &b| cands[a].pixel[1].total_cmp(&cands[b].pixel[1]));
        let take = (k - forehead.len()).min(any.len());
        forehead.extend(any.drain(..take));
    }
    let mut lip: Small<usize> = (0..cands.len())
        .filter(|&i| cands[i].role == DotRole::Lip)
        .collect();
    lip.extend(any);
    if lip.len() != n || forehead.len() != k {
        return Err(GeometryFailure::Count {
            lip: lip.len(),
            forehead: forehead.len(),
        });
    }

    // Corners: the lip pair furthest apart.
    let mut best = (0, 0, -1.0);
    for (ai, &a) in lip.iter().enumerate() {
        for &b in &lip[ai + 1..] {
            let d = (cands[a].point - cands[b].point).norm_squared();
            if d > best.2 {
                best = (a, b, d);
            }
        }
    }
    let (a, b) = (best.0, best.1);
    let forehead_centroid = forehead.iter().map(|&i| cands[i].point).sum::<Vec3>() / k as f64;
    let mid = (cands[a].point + cands[b].point) / 2.0;
    let up = forehead_centroid - mid;
    let ab = cands[a].point - cands[b].point;
    // x points to the performer's left; z = x × up must face the camera (towards -mid).
    let (left, right) = if ab.cross(&up).dot(&-mid) > 0.0 {
        (a, b)
    } else {
        (b, a)
    };
    let x = cands[left].point - cands[right].point;
    if x.norm() < DEGENERATE_MOUTH_M {
        return Err(GeometryFailure::Degenerate);
    }
    let x = x.normalize();
    let y = up - x * up.dot(&x);
    if y.norm() < DEGENERATE_MOUTH_M {
        return Err(GeometryFailure::Degenerate);
    }
    let y = y.normalize();

    let along = |i: usize| (cands[i].point - mid).dot(&x);
    // Walk around the mouth: angle about the lip centroid in the mouth plane, starting at the
    // left corner and turning towards the forehead. Unlike a split by the corner line this
    // holds when a smile lifts the corners above the middle of the upper lip.
    let centroid = lip.iter().map(|&i| cands[i].point).sum::<Vec3>() / n as f64;
    let angle = |i: usize| {
        let d = cands[i].point - centroid;
        d.dot(&y).atan2(d.dot(&x))
    };
    let start = angle(left);
    let tau = std::f64::consts::TAU;
    let mut around: Small<(f64, usize)> = lip
        .iter()
        .map(|&i| ((angle(i) - start).rem_euclid(tau), i))
        .collect();
    around.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Rounding can put the left corner at ~2π: it starts the walk by definition.
    if let Some(pos) = around.iter().position(|&(_, i)| i == left) {
        let item = around.remove(pos);
        around.insert(0, item);
    }
    let rc = layout.right_corner();
    if around[rc].1 != right {
        let upper = around
            .iter()
            .position(|&(_, i)| i == right)
            .unwrap_or(0)
            .saturating_sub(1);
        return Err(GeometryFailure::LipSplit {
            upper,
            // The rest, less the two corners.
            lower: n.saturating_sub(upper + 2),
        });
    }
    forehead.sort_by(|&p, &q| along(q).total_cmp(&along(p)));

    let mut out: Small<usize> = around.into_iter().map(|(_, i)| i).collect();
    out.extend(forehead);
    Ok(out)
}

/// Which candidates a dot may take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Slot {
    Lip,
    Forehead,
}

/// Where a dot is expected in this frame, and how far from it a candidate may be.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prediction {
    pub pixel: [f64; 2],
    /// Largest pixel distance.
    pub gate_px: f64,
    pub slot: Slot,
    /// Expected depth (metres) and the largest difference from it (infinite: no depth gate).
    /// A lip dot's colour can show where the paint is not: motion blur leaves a ghost of the
    /// dot where the lip just was, over the open mouth, a centimetre or more behind the lip.
    pub z: f64,
    pub z_gate: f64,
}

impl Prediction {
    /// A prediction gated in the image only.
    pub fn in_image(pixel: [f64; 2], gate_px: f64, slot: Slot) -> Self {
        Prediction {
            pixel,
            gate_px,
            slot,
            z: 0.0,
            z_gate: f64::INFINITY,
        }
    }
}

/// Optimal assignment of dots to candidates by pixel distance to each dot's prediction, with
/// a gate per dot: a dot whose best candidate is outside its gate (in the image, or in depth)
/// is missing, never given a neighbour's candidate. `taken` marks candidates already used
/// (they are skipped).
///
/// Returns, per dot, the candidate index.
pub fn assign(
    predictions: &[Prediction],
    cands: &[Candidate],
    taken: &[bool],
    solver: &mut Assignment,
) -> Small<Option<usize>> {
    let rows = predictions.len();
    if rows == 0 {
        return Small::new();
    }
    let cols: Small<usize> = (0..cands.len()).filter(|&j| !taken[j]).collect();
    let scale = COST_UNITS_PER_PX2;
    let width = cols.len() + rows;
    solver.reset(rows, width, FORBIDDEN);
    for (r, p) in predictions.iter().enumerate() {
        let (pred, gate) = (p.pixel, p.gate_px);
        for (c, &j) in cols.iter().enumerate() {
            let cand = &cands[j];
            let ok = match p.slot {
                Slot::Lip => cand.can_be_lip(),
                Slot::Forehead => cand.can_be_forehead(),
            };
            let d2 = (cand.pixel[0] - pred[0]).powi(2) + (cand.pixel[1] - pred[1]).powi(2);
            if ok && d2 < gate * gate && (cand.point.z - p.z).abs() <= p.z_gate {
                solver.set(r, c, (d2 * scale).round() as i64);
            }
        }
        // This dot's own "missing" column costs its gate squared.
        solver.set(
            r,
            cols.len() + r,
            (gate * gate * scale).round() as i64 + MISSING_TIE_BREAK,
        );
    }
    solver.solve();
    (0..rows)
        .map(|r| {
            let c = solver.column_of(r);
            (c < cols.len() && solver.cost(r, c) != FORBIDDEN).then(|| cols[c])
        })
        .collect()
}

/// Minimum-cost assignment of `rows` ≤ `cols` (the Hungarian method with potentials,
/// O(rows² · cols)), on buffers kept between calls so that a frame allocates nothing once
/// they have grown to the frame's size.
#[derive(Debug, Default)]
pub struct Assignment {
    rows: usize,
    cols: usize,
    cost: Vec<i64>,
    u: Vec<i64>,
    v: Vec<i64>,
    /// `owner[j]`: the row (1-based, 0 = none) holding column `j` (1-based).
    owner: Vec<usize>,
    way: Vec<usize>,
    min_slack: Vec<i64>,
    used: Vec<bool>,
    column: Vec<usize>,
}

impl Assignment {
    fn reset(&mut self, rows: usize, cols: usize, fill: i64) {
        assert!(rows <= cols, "more rows than columns");
        self.rows = rows;
        self.cols = cols;
        self.cost.clear();
        self.cost.resize(rows * cols, fill);
    }

    fn set(&mut self, r: usize, c: usize, cost: i64) {
        self.cost[r * self.cols + c] = cost;
    }

    fn cost(&self, r: usize, c: usize) -> i64 {
        self.cost[r * self.cols + c]
    }

    /// The column assigned to row `r` after [`Self::solve`].
    fn column_of(&self, r: usize) -> usize {
        self.column[r]
    }

    fn solve(&mut self) {
        let (n, m) = (self.rows, self.cols);
        const INF: i64 = i64::MAX / 4;
        for buf in [&mut self.u, &mut self.v, &mut self.min_slack] {
            buf.clear();
        }
        self.u.resize(n + 1, 0);
        self.v.resize(m + 1, 0);
        self.owner.clear();
        self.owner.resize(m + 1, 0);
        self.way.clear();
        self.way.resize(m + 1, 0);
        for i in 1..=n {
            self.owner[0] = i;
            let mut j0 = 0;
            self.min_slack.clear();
            self.min_slack.resize(m + 1, INF);
            self.used.clear();
            self.used.resize(m + 1, false);
            loop {
                self.used[j0] = true;
                let i0 = self.owner[j0];
                let mut delta = INF;
                let mut j1 = 0;
                for j in 1..=m {
                    if self.used[j] {
                        continue;
                    }
                    let slack = self.cost[(i0 - 1) * m + (j - 1)] - self.u[i0] - self.v[j];
                    if slack < self.min_slack[j] {
                        self.min_slack[j] = slack;
                        self.way[j] = j0;
                    }
                    if self.min_slack[j] < delta {
                        delta = self.min_slack[j];
                        j1 = j;
                    }
                }
                for j in 0..=m {
                    if self.used[j] {
                        self.u[self.owner[j]] += delta;
                        self.v[j] -= delta;
                    } else {
                        self.min_slack[j] -= delta;
                    }
                }
                j0 = j1;
                if self.owner[j0] == 0 {
                    break;
                }
            }
            loop {
                let j1 = self.way[j0];
                self.owner[j0] = self.owner[j1];
                j0 = j1;
                if j0 == 0 {
                    break;
                }
            }
        }
        self.column.clear();
        self.column.resize(n, usize::MAX);
        for j in 1..=m {
            if self.owner[j] > 0 {
                self.column[self.owner[j] - 1] = j - 1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A mouth 50 mm wide at 0.6 m, facing the camera, with the forehead 80 mm above.
    pub(crate) fn face(layout: PerformerLayout) -> Vec<(String, Vec3)> {
        let n = layout.lip_dots;
        let half = n / 2;
        let mut out = Vec::new();
        let centre = Vec3::new(0.01, 0.03, 0.6);
        // Performer's left is +x in the camera; up is -y.
        let lip_point = |angle: f64, open: f64| {
            centre
                + Vec3::new(
                    0.025 * angle.cos(),
                    -(0.008 + open) * angle.sin(),
                    -0.004 * angle.sin().abs(),
                )
        };
        for i in 0..n {
            // D1 at angle 0 (left corner), upper lip angles in (0, π), right corner π, lower (π, 2π).
            let angle = std::f64::consts::PI * i as f64 / half as f64;
            out.push((format!("D{}", i + 1), lip_point(angle, 0.0)));
        }
        for j in 0..layout.forehead_dots {
            let x = 0.03 - 0.06 * j as f64 / (layout.forehead_dots - 1) as f64;
            out.push((
                format!("F{}", j + 1),
                centre + Vec3::new(x, -0.09 - 0.005 * j as f64, 0.01),
            ));
        }
        out
    }

    fn to_candidates(
        dots: &[(String, Vec3)],
        forehead_role: DotRole,
        lip_role: DotRole,
    ) -> Vec<Candidate> {
        let k = mouthpiece_frame::Intrinsics::default_vga();
        dots.iter()
            .map(|(name, p)| Candidate {
                pixel: crate::camera::project(&k, p).unwrap(),
                point: *p,
                role: if name.starts_with('F') {
                    forehead_role
                } else {
                    lip_role
                },
            })
            .collect()
    }

    #[test]
    fn geometry_names_every_dot_in_any_order() {
        let layout = PerformerLayout::default();
        let dots = face(layout);
        for (forehead_role, lip_role) in [
            (DotRole::Forehead, DotRole::Lip),
            (DotRole::Any, DotRole::Any),
        ] {
            let mut cands = to_candidates(&dots, forehead_role, lip_role);
            // Shuffle deterministically.
            cands.reverse();
            cands.rotate_left(5);
            let names: Vec<&str> = {
                let order: Vec<usize> = (0..dots.len()).collect();
                let shuffled: Vec<usize> = {
                    let mut o = order.clone();
                    o.reverse();
                    o.rotate_left(5);
                    o
                };
                shuffled.iter().map(|&i| dots[i].0.as_str()).collect()
            };
            let labels = label_by_geometry(&cands, layout).unwrap();
            for (dot, &cand) in labels.iter().enumerate() {
                let expected = if dot < 12 {
                    format!("D{}", dot + 1)
                } else {
                    format!("F{}", dot - 11)
                };
                assert_eq!(
                    names[cand], expected,
                    "roles {forehead_role:?}/{lip_role:?}"
                );
            }
        }
    }

    #[test]
    fn geometry_survives_head_roll_and_refuses_wrong_counts() {
        let layout = PerformerLayout::default();
        let roll = nalgebra::Rotation3::from_axis_angle(&Vec3::z_axis(), 0.5);
        let centre = Vec3::new(0.0, 0.0, 0.6);
        let dots: Vec<(String, Vec3)> = face(layout)
            .into_iter()
            .map(|(n, p)| (n, roll * (p - centre) + centre))
            .collect();
        let cands = to_candidates(&dots, DotRole::Forehead, DotRole::Lip);
        let labels = label_by_geometry(&cands, layout).unwrap();
        assert_eq!(labels.to_vec(), (0..15).collect::<Vec<_>>());
        assert_eq!(
            label_by_geometry(&cands[1..], layout),
            Err(GeometryFailure::Count {
                lip: 11,
                forehead: 3
            })
        );
    }

    #[test]
    fn assignment_leaves_a_missing_dot_missing() {
        let cands: Vec<Candidate> = [[10.0, 10.0], [30.0, 10.0]]
            .iter()
            .map(|&p| Candidate {
                pixel: p,
                point: Vec3::zeros(),
                role: DotRole::Lip,
            })
            .collect();
        // Three dots predicted 20 px apart; the middle one is not seen. The two seen dots moved
        // 4 px towards the middle: still theirs, and the middle dot stays missing.
        let preds = [
            Prediction::in_image([6.0, 10.0], 8.0, Slot::Lip),
            Prediction::in_image([20.0, 10.0], 8.0, Slot::Lip),
            Prediction::in_image([34.0, 10.0], 8.0, Slot::Lip),
        ];
        let got = assign(&preds, &cands, &[false, false], &mut Assignment::default()).to_vec();
        assert_eq!(got, vec![Some(0), None, Some(1)]);
    }

    #[test]
    fn assignment_respects_roles_gates_and_taken() {
        let cands = vec![
            Candidate {
                pixel: [0.0, 0.0],
                point: Vec3::zeros(),
                role: DotRole::Forehead,
            },
            Candidate {
                pixel: [1.0, 0.0],
                point: Vec3::zeros(),
                role: DotRole::Lip,
            },
            Candidate {
                pixel: [50.0, 0.0],
                point: Vec3::zeros(),
                role: DotRole::Lip,
            },
        ];
        let preds = [
            Prediction::in_image([0.0, 0.0], 5.0, Slot::Lip),
            Prediction::in_image([50.0, 30.0], 5.0, Slot::Lip),
        ];
        assert_eq!(
            assign(&preds, &cands, &[false; 3], &mut Assignment::default()).to_vec(),
            vec![Some(1), None]
        );
        assert_eq!(
            assign(
                &preds,
                &cands,
                &[false, true, false],
                &mut Assignment::default()
            )
            .to_vec(),
            vec![None, None]
        );
        let preds = [Prediction::in_image([0.0, 0.0], 5.0, Slot::Forehead)];
        assert_eq!(
            assign(&preds, &cands, &[false; 3], &mut Assignment::default()).to_vec(),
            vec![Some(0)]
        );
    }

    #[test]
    fn assignment_is_globally_optimal() {
        // Greedy nearest would give dot 0 the candidate at 5 and leave dot 1 far off.
        let cands: Vec<Candidate> = [[5.0, 0.0], [-1.0, 0.0]]
            .iter()
            .map(|&p| Candidate {
                pixel: p,
                point: Vec3::zeros(),
                role: DotRole::Lip,
            })
            .collect();
        let preds = [
            Prediction::in_image([4.0, 0.0], 10.0, Slot::Lip),
            Prediction::in_image([8.0, 0.0], 10.0, Slot::Lip),
        ];
        assert_eq!(
            assign(&preds, &cands, &[false, false], &mut Assignment::default()).to_vec(),
            vec![Some(1), Some(0)]
        );
    }

    #[test]
    fn a_candidate_at_the_wrong_depth_is_not_the_dot() {
        // The paint's ghost over the open mouth (nearer the prediction in the image, 2 cm
        // deeper) against the dot itself.
        let cand = |x: f64, z: f64| Candidate {
            pixel: [x, 0.0],
            point: Vec3::new(0.0, 0.0, z),
            role: DotRole::Lip,
        };
        let cands = [cand(1.0, 0.62), cand(3.0, 0.60)];
        let mut pred = Prediction::in_image([0.0, 0.0], 5.0, Slot::Lip);
        let solve = |p: Prediction| assign(&[p], &cands, &[false; 2], &mut Assignment::default());
        assert_eq!(solve(pred).to_vec(), vec![Some(0)]);
        pred.z = 0.601;
        pred.z_gate = 0.008;
        assert_eq!(solve(pred).to_vec(), vec![Some(1)]);
        pred.z = 0.64;
        assert_eq!(solve(pred).to_vec(), vec![None]);
    }
}
