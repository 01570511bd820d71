//! Acoustic features of the live analyser, one vector per 10 ms hop: 12 mel-frequency
//! cepstral coefficients of the last 25 ms, their change over 20 ms, and the frame's level
//! below the loudest so far.
//!
//! The spectrum is read on the 16 kHz scale at any sample rate: the mel bands span 100 to
//! 7600 Hz, and the 16 kHz pre-emphasis filter (`1 − 0.97 z⁻¹`) is applied to the power
//! spectrum at the same frequencies, so profiles learned at 16 kHz match a 48 kHz microphone.

use std::collections::VecDeque;
use std::sync::Arc;

use realfft::{RealFftPlanner, RealToComplex};

/// Cepstral coefficients kept (c1..c12; c0, the level, is carried separately).
pub const CEPSTRA: usize = 12;
/// Length of a feature vector: cepstra, their deltas, the relative level.
pub const FEATURES: usize = 2 * CEPSTRA + 1;
/// Hop between feature vectors, seconds.
pub const HOP_S: f64 = 0.010;
/// Analysis window, seconds.
pub const WINDOW_S: f64 = 0.025;
/// Lowest and highest sample rates the analyser accepts.
pub const SAMPLE_RATES: (u32, u32) = (16_000, 192_000);

const MEL_BANDS: usize = 26;
const MEL_LOW_HZ: f64 = 100.0;
const MEL_HIGH_HZ: f64 = 7600.0;
/// Hops between a cepstrum and the one its delta is taken against.
const DELTA_HOPS: usize = 2;
/// The level feature is clamped to this many dB below the loudest frame.
const LEVEL_FLOOR_DB: f64 = -60.0;
/// The loudest-frame reference falls this many dB a second, so a quieter talker is
/// followed after a shout.
const PEAK_DECAY_DB_S: f64 = 3.0;

/// One hop's analysis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Feature {
    /// The feature vector.
    pub x: [f64; FEATURES],
    /// The window's level, dB full scale.
    pub level_db: f64,
    /// The window's level below the (decaying) loudest level so far, dB (≤ 0).
    pub relative_db: f64,
}

/// Turns mono samples into feature vectors as they come.
pub struct FeatureExtractor {
    sample_rate: u32,
    window: Vec<f64>,
    hop: usize,
    fft: Arc<dyn RealToComplex<f64>>,
    /// Per mel band: (first bin, weights), pre-emphasis folded in.
    bands: Vec<(usize, Vec<f64>)>,
    dct: Vec<[f64; MEL_BANDS]>,
    /// The last `window.len()` samples, scaled to [-1, 1).
    ring: VecDeque<f64>,
    /// Samples since the last feature.
    since_hop: usize,
    history: VecDeque<[f64; CEPSTRA]>,
    peak_db: f64,
    input: Vec<f64>,
    spectrum: Vec<realfft::num_complex::Complex<f64>>,
    scratch: Vec<realfft::num_complex::Complex<f64>>,
}

fn mel(hz: f64) -> f64 {
    2595.0 * (1.0 + hz / 700.0).log10()
}

fn hz(mel: f64) -> f64 {
    700.0 * (10f64.powf(mel / 2595.0) - 1.0)
}

impl FeatureExtractor {
    /// An extractor for `sample_rate` (within [`SAMPLE_RATES`]; the caller checks).
    pub fn new(sample_rate: u32) -> Self {
        let sr = f64::from(sample_rate);
        let len = (WINDOW_S * sr).round() as usize;
        let hop = (HOP_S * sr).round() as usize;
        let n = len.next_power_of_two();
        let window = (0..len)
            .map(|i| 0.54 - 0.46 * (2.0 * std::f64::consts::PI * i as f64 / (len - 1) as f64).cos())
            .collect();
        let fft = RealFftPlanner::<f64>::new().plan_fft_forward(n);
        let bins = n / 2 + 1;
        let edges: Vec<f64> = (0..MEL_BANDS + 2)
            .map(|k| {
                hz(mel(MEL_LOW_HZ)
                    + (mel(MEL_HIGH_HZ) - mel(MEL_LOW_HZ)) * k as f64 / (MEL_BANDS + 1) as f64)
            })
            .collect();
        let bin_hz = sr / n as f64;
        let bands = (0..MEL_BANDS)
            .map(|b| {
                let (lo, mid, hi) = (edges[b], edges[b + 1], edges[b + 2]);
                let first = (lo / bin_hz).ceil() as usize;
                let last = ((hi / bin_hz).floor() as usize).min(bins - 1);
                let weights = (first..=last)
                    .map(|k| {
                        let f = k as f64 * bin_hz;
                        let tri = if f <= mid {
                            (f - lo) / (mid - lo)
                        } else {
                            (hi - f) / (hi - mid)
                        };
                        // |1 − 0.97 e^{−jω}|² with ω on the 16 kHz scale.
                        let w = 2.0 * std::f64::consts::PI * f / 16_000.0;
                        let emphasis = 1.0 + 0.97 * 0.97 - 2.0 * 0.97 * w.cos();
                        tri.max(0.0) * emphasis
                    })
                    .collect();
                (first, weights)
            })
            .collect();
        let dct = (1..=CEPSTRA)
            .map(|c| {
                let mut row = [0.0; MEL_BANDS];
                for (b, v) in row.iter_mut().enumerate() {
                    *v = (std::f64::consts::PI * c as f64 * (b as f64 + 0.5) / MEL_BANDS as f64)
                        .cos()
                        * (2.0 / MEL_BANDS as f64).sqrt();
                }
                row
            })
            .collect();
        let spectrum = fft.make_output_vec();
        let scratch = fft.make_scratch_vec();
        Self {
            sample_rate,
            window,
            hop,
            fft,
            bands,
            dct,
            ring: VecDeque::with_capacity(len + 1),
            since_hop: 0,
            history: VecDeque::with_capacity(DELTA_HOPS + 1),
            peak_db: LEVEL_FLOOR_DB * 2.0,
            input: vec![0.0; n],
            spectrum,
            scratch,
        }
    }

    /// The sample rate.
    pub fn sample_rate(&self) -> u32 {
        self.sample_rate
    }

    /// Samples between features.
    pub fn hop(&self) -> usize {
        self.hop
    }

    /// Samples in one analysis window.
    pub fn window_len(&self) -> usize {
        self.window.len()
    }

    /// Feeds one sample; returns a feature when a hop completes with a full window behind it.
    pub fn push(&mut self, sample: i16) -> Option<Feature> {
        if self.ring.len() == self.window.len() {
            self.ring.pop_front();
        }
        self.ring.push_back(f64::from(sample) / 32768.0);
        self.since_hop += 1;
        if self.since_hop < self.hop || self.ring.len() < self.window.len() {
            return None;
        }
        self.since_hop = 0;
        Some(self.analyse())
    }

    fn analyse(&mut self) -> Feature {
        let mut energy = 0.0;
        for (i, (x, w)) in self.ring.iter().zip(&self.window).enumerate() {
            self.input[i] = x * w;
            energy += x * x;
        }
        for v in &mut self.input[self.window.len()..] {
            *v = 0.0;
        }
        // The buffers are sized by the plan: processing cannot fail.
        let _ =
            self.fft
                .process_with_scratch(&mut self.input, &mut self.spectrum, &mut self.scratch);
        let mut logmel = [0.0; MEL_BANDS];
        for (b, (first, weights)) in self.bands.iter().enumerate() {
            let e: f64 = weights
                .iter()
                .zip(&self.spectrum[*first..])
                .map(|(w, c)| w * c.norm_sqr())
                .sum();
            logmel[b] = e.max(1e-10).ln();
        }
        let mut c = [0.0; CEPSTRA];
        for (ci, row) in c.iter_mut().zip(&self.dct) {
            *ci = row.iter().zip(&logmel).map(|(a, b)| a * b).sum();
        }
        let level_db = 10.0 * (energy / self.window.len() as f64).max(1e-12).log10();
        self.peak_db = (self.peak_db - PEAK_DECAY_DB_S * HOP_S).max(level_db);
        let relative_db = (level_db - self.peak_db).max(LEVEL_FLOOR_DB);
        let past = if self.history.len() == DELTA_HOPS {
            self.history.pop_front()
        } else {
            self.history.front().copied()
        };
        self.history.push_back(c);
        let past = past.unwrap_or(c);
        let mut x = [0.0; FEATURES];
        x[..CEPSTRA].copy_from_slice(&c);
        for k in 0..CEPSTRA {
            x[CEPSTRA + k] = c[k] - past[k];
        }
        x[2 * CEPSTRA] = relative_db / 10.0;
        Feature {
            x,
            level_db,
            relative_db,
        }
    }
}
