//! A small seeded generator (SplitMix64): deterministic across platforms and versions, which
//! is what "deterministic for a seed" needs; statistical quality is ample for noise.

#[derive(Debug, Clone)]
pub(crate) struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed ^ 0x9e37_79b9_7f4a_7c15)
    }

    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    #[inline]
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.unit().max(1e-300);
        let u2 = self.unit();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// Many standard-normal samples, drawn once; per-pixel noise indexes it with a fast hash.
pub(crate) struct GaussTable {
    values: Vec<f32>,
}

impl GaussTable {
    pub const SIZE: usize = 1 << 16;

    pub fn new(seed: u64) -> Self {
        let mut rng = Rng::new(seed ^ 0x6a55);
        Self {
            values: (0..Self::SIZE).map(|_| rng.normal() as f32).collect(),
        }
    }

    #[inline]
    pub fn get(&self, key: u64) -> f32 {
        self.values[(key as usize) & (Self::SIZE - 1)]
    }
}

/// Cheap per-pixel random stream (xorshift64*), seeded per frame.
pub(crate) struct FastRng(u64);

impl FastRng {
    pub fn new(seed: u64) -> Self {
        Self(Rng::new(seed).next_u64() | 1)
    }

    #[inline]
    pub fn next(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// Uniform in [0, 1) from the high bits.
    #[inline]
    pub fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
}
