//! The forehead fit's per-sample terms four samples at a time, in 256-bit lanes (x86-64 with
//! AVX, checked at run time).
//!
//! Each lane does exactly what the per-sample code does, operation for operation and in the
//! same order (the products and sums of nalgebra's matrix–vector product, `dot` and
//! `cross`; no fused multiply–add), so the terms are the same numbers to the bit; the normal
//! equations are still summed sample by sample, in order, by the caller. A unit test compares
//! the two on thousands of samples.

use std::arch::x86_64::*;

use nalgebra::Matrix3;

use super::{HUBER_M, OUTLIER_M};
use crate::Vec3;

/// The surface samples and normals as columns (x, y and z apart), for loading four at once.
#[derive(Debug, Clone, Default)]
pub(super) struct SampleColumns {
    p: [Vec<f64>; 3],
    n: [Vec<f64>; 3],
}

impl SampleColumns {
    pub(super) fn new(points: &[Vec3], normals: &[Vec3]) -> Self {
        let column = |v: &[Vec3], k: usize| v.iter().map(|p| p[k]).collect::<Vec<_>>();
        Self {
            p: [column(points, 0), column(points, 1), column(points, 2)],
            n: [column(normals, 0), column(normals, 1), column(normals, 2)],
        }
    }

    /// Samples in whole groups of four.
    pub(super) fn grouped_len(&self) -> usize {
        self.p[0].len() / 4 * 4
    }
}

/// What one step's per-sample terms read: the pose, an ideal camera with its ray tables, the
/// depth image.
pub(super) struct StepInputs<'a> {
    pub rotation: &'a Matrix3<f64>,
    pub translation: &'a Vec3,
    /// `fx, fy, cx, cy`.
    pub camera: [f64; 4],
    pub width: i64,
    pub height: i64,
    pub depth: &'a [u16],
    pub scale: f64,
    pub columns: &'a [f64],
    pub rows: &'a [f64],
    pub w_depth: f64,
}

/// One sample's terms: its weight, residual and Jacobian row (`None`: the sample is not used).
pub(super) type Terms = Option<(f64, f64, [f64; 6])>;

/// Whether this CPU runs [`four_samples`].
pub(super) fn available() -> bool {
    is_x86_feature_detected!("avx")
}

/// The terms of samples `first..first + 4` (`first + 4 ≤ grouped_len`).
///
/// # Safety
/// The CPU must support AVX ([`available`]).
#[target_feature(enable = "avx")]
pub(super) unsafe fn four_samples(
    samples: &SampleColumns,
    first: usize,
    inputs: &StepInputs,
) -> [Terms; 4] {
    let load = |v: &[f64]| {
        let lanes: &[f64; 4] = v[first..first + 4].try_into().expect("four samples");
        // SAFETY: AVX is enabled for this function; the array is four f64.
        unsafe { _mm256_loadu_pd(lanes.as_ptr()) }
    };
    let splat = |x: f64| _mm256_set1_pd(x);
    let r = inputs.rotation;
    // nalgebra's `m * v`: `y = m[.,0] v0`, then `y = m[.,1] v1 + y`, then `y = m[.,2] v2 + y`.
    let rotate = |v: [__m256d; 3], row: usize| {
        let y = _mm256_mul_pd(splat(r[(row, 0)]), v[0]);
        let y = _mm256_add_pd(_mm256_mul_pd(splat(r[(row, 1)]), v[1]), y);
        _mm256_add_pd(_mm256_mul_pd(splat(r[(row, 2)]), v[2]), y)
    };
    let p = [
        load(&samples.p[0]),
        load(&samples.p[1]),
        load(&samples.p[2]),
    ];
    let t = inputs.translation;
    let q = [
        _mm256_add_pd(rotate(p, 0), splat(t.x)),
        _mm256_add_pd(rotate(p, 1), splat(t.y)),
        _mm256_add_pd(rotate(p, 2), splat(t.z)),
    ];
    // `project_ideal`: none behind the camera (`z <= 0`), else `f * x / z + c`.
    let [fx, fy, cx, cy] = inputs.camera;
    let in_front = _mm256_cmp_pd::<_CMP_NLE_UQ>(q[2], _mm256_setzero_pd());
    let u = _mm256_add_pd(
        _mm256_div_pd(_mm256_mul_pd(splat(fx), q[0]), q[2]),
        splat(cx),
    );
    let v = _mm256_add_pd(
        _mm256_div_pd(_mm256_mul_pd(splat(fy), q[1]), q[2]),
        splat(cy),
    );
    // `round_to_i64`: the truncation plus one where the fraction is ≥ ½, minus one where it
    // is ≤ −½ (half away from zero), as floats (whole numbers, exact).
    let round = |x: __m256d| {
        let t = _mm256_round_pd::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(x);
        let frac = _mm256_sub_pd(x, t);
        let one = splat(1.0);
        let up = _mm256_and_pd(_mm256_cmp_pd::<_CMP_GE_OQ>(frac, splat(0.5)), one);
        let down = _mm256_and_pd(_mm256_cmp_pd::<_CMP_LE_OQ>(frac, splat(-0.5)), one);
        _mm256_sub_pd(_mm256_add_pd(t, up), down)
    };
    let (x, y) = (round(u), round(v));
    let inside = _mm256_and_pd(
        _mm256_and_pd(
            _mm256_cmp_pd::<_CMP_GE_OQ>(x, _mm256_setzero_pd()),
            _mm256_cmp_pd::<_CMP_GE_OQ>(y, _mm256_setzero_pd()),
        ),
        _mm256_and_pd(
            _mm256_cmp_pd::<_CMP_LT_OQ>(x, splat(inputs.width as f64)),
            _mm256_cmp_pd::<_CMP_LT_OQ>(y, splat(inputs.height as f64)),
        ),
    );
    let seen = _mm256_movemask_pd(_mm256_and_pd(in_front, inside));
    let (mut xs, mut ys) = ([0.0f64; 4], [0.0f64; 4]);
    // SAFETY: AVX is enabled; the arrays are four f64.
    unsafe {
        _mm256_storeu_pd(xs.as_mut_ptr(), x);
        _mm256_storeu_pd(ys.as_mut_ptr(), y);
    }
    // The depth reads and ray tables, lane by lane.
    let mut valid = [false; 4];
    let (mut mx, mut my, mut mz) = ([0.0f64; 4], [0.0f64; 4], [0.0f64; 4]);
    for lane in 0..4 {
        if seen & (1 << lane) == 0 {
            continue;
        }
        let (xi, yi) = (xs[lane] as i64, ys[lane] as i64);
        let raw = inputs.depth[(yi * inputs.width + xi) as usize];
        if raw == 0 {
            continue;
        }
        let z = raw as f64 * inputs.scale;
        valid[lane] = true;
        mx[lane] = inputs.columns[xi as usize] * z;
        my[lane] = inputs.rows[yi as usize] * z;
        mz[lane] = z;
    }
    if !valid.iter().any(|&v| v) {
        return [None; 4];
    }
    // SAFETY: AVX is enabled; the arrays are four f64.
    let measured = unsafe {
        [
            _mm256_loadu_pd(mx.as_ptr()),
            _mm256_loadu_pd(my.as_ptr()),
            _mm256_loadu_pd(mz.as_ptr()),
        ]
    };
    let n0 = [
        load(&samples.n[0]),
        load(&samples.n[1]),
        load(&samples.n[2]),
    ];
    let n = [rotate(n0, 0), rotate(n0, 1), rotate(n0, 2)];
    // `n.dot(&(measured - q))`: for three components nalgebra sums `(a + b) + c`.
    let d = [
        _mm256_sub_pd(measured[0], q[0]),
        _mm256_sub_pd(measured[1], q[1]),
        _mm256_sub_pd(measured[2], q[2]),
    ];
    let res = _mm256_add_pd(
        _mm256_add_pd(_mm256_mul_pd(n[0], d[0]), _mm256_mul_pd(n[1], d[1])),
        _mm256_mul_pd(n[2], d[2]),
    );
    let abs = _mm256_andnot_pd(splat(-0.0), res);
    let near = _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_NGT_UQ>(abs, splat(OUTLIER_M)));
    let huber = _mm256_blendv_pd(
        _mm256_div_pd(splat(HUBER_M), abs),
        splat(1.0),
        _mm256_cmp_pd::<_CMP_LE_OQ>(abs, splat(HUBER_M)),
    );
    let w = _mm256_mul_pd(splat(inputs.w_depth), huber);
    // `q.cross(&n)`: (qy nz − qz ny, qz nx − qx nz, qx ny − qy nx).
    let qn = [
        _mm256_sub_pd(_mm256_mul_pd(q[1], n[2]), _mm256_mul_pd(q[2], n[1])),
        _mm256_sub_pd(_mm256_mul_pd(q[2], n[0]), _mm256_mul_pd(q[0], n[2])),
        _mm256_sub_pd(_mm256_mul_pd(q[0], n[1]), _mm256_mul_pd(q[1], n[0])),
    ];
    let negate = |x: __m256d| _mm256_xor_pd(x, splat(-0.0));
    let j = [
        negate(qn[0]),
        negate(qn[1]),
        negate(qn[2]),
        negate(n[0]),
        negate(n[1]),
        negate(n[2]),
    ];
    let mut ws = [0.0f64; 4];
    let mut rs = [0.0f64; 4];
    let mut js = [[0.0f64; 4]; 6];
    // SAFETY: AVX is enabled; the arrays are four f64.
    unsafe {
        _mm256_storeu_pd(ws.as_mut_ptr(), w);
        _mm256_storeu_pd(rs.as_mut_ptr(), res);
        for (out, j) in js.iter_mut().zip(j) {
            _mm256_storeu_pd(out.as_mut_ptr(), j);
        }
    }
    std::array::from_fn(|lane| {
        (valid[lane] && near & (1 << lane) != 0)
            .then(|| (ws[lane], rs[lane], std::array::from_fn(|k| js[k][lane])))
    })
}
