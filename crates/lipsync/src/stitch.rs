//! Stitching: one pass over the placed segments builds one weight curve per key pose, sampled
//! at `fps` (samples at t = k / fps from 0 to the last phone's end).
//!
//! The curve so far, c, covers [0, c_end]. Segment i's placed curve cᵢ covers [sᵢ, eᵢ]. Where
//! they overlap (sᵢ ≤ t < c_end) the result is c′ = (1 − r) c + r cᵢ with r rising linearly
//! from 0 at sᵢ to 1 at c_end; from c_end on it is cᵢ; before sᵢ c is kept. Phones do not
//! overlap, so overlaps come only from short phones (see [`crate::mapping`]).
//!
//! Continuity, as measured by the tests (`docs/lipsync.md`): C⁰ everywhere; C¹ wherever phones
//! last at least T (flat-ended stage curves join with zero slope); across a blend the slope
//! has the extra term r′ (cᵢ − c), which is not zero where the two curves differ at the
//! overlap's start, so the stitched curve is C⁰ but not G¹ there.

use crate::mapping::Placed;
use crate::segments::SegmentTable;

/// Weight curves sampled at a fixed rate: `values[k * poses + p]` is pose p at t = k / fps.
#[derive(Debug, Clone, PartialEq)]
pub struct Weights {
    pub fps: f64,
    pub poses: usize,
    pub values: Vec<f64>,
    /// Per sample: the placed segment (= phone index) that dominates it: the one stitched
    /// last, or inside a blend the one with the larger share (r ≥ ½ → the newer).
    pub owner: Vec<usize>,
}

impl Weights {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.values.len() / self.poses.max(1)
    }

    /// No samples.
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// Time of sample `k`.
    pub fn time(&self, k: usize) -> f64 {
        k as f64 / self.fps
    }

    /// The weights of sample `k`.
    pub fn sample(&self, k: usize) -> &[f64] {
        &self.values[k * self.poses..(k + 1) * self.poses]
    }
}

/// Samples covering [0, end]: t_k = k / fps ≤ end.
pub fn sample_count(end: f64, fps: f64) -> usize {
    let mut n = (end * fps).floor().max(0.0) as usize + 1;
    while n > 1 && (n - 1) as f64 / fps > end {
        n -= 1;
    }
    while (n as f64) / fps <= end {
        n += 1;
    }
    n
}

/// Stitches the placed segments (in phone order) into sampled curves.
pub fn stitch(placed: &[Placed], segments: &SegmentTable, fps: f64) -> Weights {
    let k = segments.poses();
    let end = placed.iter().map(|p| p.end).fold(0.0, f64::max);
    let n = sample_count(end, fps);
    let mut values = vec![0.0; n * k];
    let mut owner = vec![0; n];
    let mut here = vec![0.0; k];
    let mut c_end = f64::NEG_INFINITY;
    for (index, p) in placed.iter().enumerate() {
        let segment = segments.get(p.from, p.to);
        let mut i = (p.start * fps).floor().max(0.0) as usize;
        while i < n && (i as f64 / fps) < p.start {
            i += 1;
        }
        while i < n {
            let t = i as f64 / fps;
            if t > p.end {
                break;
            }
            p.eval(segment, t, &mut here);
            let row = &mut values[i * k..(i + 1) * k];
            if t < c_end {
                let r = (t - p.start) / (c_end - p.start);
                for (v, h) in row.iter_mut().zip(&here) {
                    *v = (1.0 - r) * *v + r * h;
                }
                if r >= 0.5 {
                    owner[i] = index;
                }
            } else {
                row.copy_from_slice(&here);
                owner[i] = index;
            }
            i += 1;
        }
        c_end = c_end.max(p.end);
    }
    Weights {
        fps,
        poses: k,
        values,
        owner,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::curve::StageCurve;
    use crate::segments::Segment;
    use crate::ClassTable;

    #[test]
    fn sample_count_covers_the_end() {
        assert_eq!(sample_count(1.0, 60.0), 61);
        assert_eq!(sample_count(0.999, 60.0), 60);
        assert_eq!(sample_count(0.0, 60.0), 1);
    }

    /// Stitching a constant 0 with a constant 1 over [a, b] gives (t − a) / (b − a).
    #[test]
    fn constant_zero_then_one_blend_linearly() {
        let table = ClassTable::from_toml_str(
            "poses = [\"open\"]\n[[class]]\nname = \"sil\"\nphones = [\"sil\"]\n[[class]]\nname = \"aa\"\nphones = [\"aa\"]\ntarget = { open = 1.0 }\n",
            "t",
        )
        .unwrap();
        let mut segs = SegmentTable::generate(&table);
        // Constant segments: A(sil, aa) all 0, A(aa, sil) all 1 (the conventions do not hold
        // for these, so they are put in place directly).
        let zero = Segment {
            stable: vec![StageCurve::constant(0.0)],
            change: vec![StageCurve::constant(0.0)],
        };
        let one = Segment {
            stable: vec![StageCurve::constant(1.0)],
            change: vec![StageCurve::constant(1.0)],
        };
        segs.force(0, 1, zero);
        segs.force(1, 0, one);
        let (a, b) = (0.5, 0.75);
        let placed = [
            Placed {
                from: 0,
                to: 1,
                start: 0.0,
                end: b,
                t1: 0.0,
                change_start: b - 0.04,
                t_change: 0.04,
            },
            Placed {
                from: 1,
                to: 0,
                start: a,
                end: 1.0,
                t1: a,
                change_start: 0.96,
                t_change: 0.04,
            },
        ];
        let fps = 1000.0;
        let w = stitch(&placed, &segs, fps);
        assert_eq!(w.len(), 1001);
        for k in 0..w.len() {
            let t = w.time(k);
            let expect = if t < a {
                0.0
            } else if t < b {
                (t - a) / (b - a)
            } else {
                1.0
            };
            assert!((w.sample(k)[0] - expect).abs() < 1e-12, "t {t}");
        }
    }
}
