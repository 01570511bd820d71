//! The mouth from speech, live: a causal analyser that takes sound blocks as they come and
//! gives, every 10 ms, the lip-sync class heard and the key-pose weights of the mouth
//! (docs/lipsync.md, "Live").
//!
//! Per hop: MFCC features of the last 25 ms ([`features`]); silence when the window is
//! quiet (absolute or relative to the loudest so far); otherwise the class whose learned
//! profile ([`profiles`]) gives the highest likelihood, after a short leaky average of the
//! likelihoods that steadies single-frame flips. The weights move toward the class's target
//! with a time constant, as the offline change stage does. Nothing looks ahead: a step
//! describes the window that ends with the newest sample.

pub mod features;
pub mod learn;
pub mod learn_files;
pub mod mouth;
pub mod profiles;

use mouthpiece_frame::audio::AudioBlock;

pub use features::{Feature, FeatureExtractor, FEATURES, HOP_S, SAMPLE_RATES, WINDOW_S};
pub use learn::{learn_from_recordings, Recording};
pub use mouth::LiveMouth;
pub use profiles::{Bound, Profiles};

use crate::{ClassTable, Error};

/// The shipped profiles (learned from Festival's `kal_diphone` voice, see the file header).
pub const SHIPPED_PROFILES: &str = include_str!("../../../../config/lipsync/live_profiles.toml");

/// Tunables of the analyser.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LiveSettings {
    /// A window below this level (dB full scale) is silence.
    pub gate_db: f64,
    /// A window this many dB below the loudest so far is silence.
    pub relative_gate_db: f64,
    /// Time constant of the leaky average of the class likelihoods, seconds (0: none).
    pub score_tau_s: f64,
    /// Time constant of the weights' move toward the class target, seconds.
    pub mouth_tau_s: f64,
}

impl Default for LiveSettings {
    fn default() -> Self {
        Self {
            gate_db: -50.0,
            relative_gate_db: -35.0,
            score_tau_s: 0.0,
            mouth_tau_s: 0.005,
        }
    }
}

/// One step of the analyser.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveStep {
    /// Stream time of the newest sample of the window, seconds since the stream's first
    /// sample frame (the step describes the 25 ms up to it).
    pub t: f64,
    /// Index of that sample frame in the stream.
    pub frame: u64,
    /// Host monotonic time at which that sample was captured.
    pub heard_at: std::time::Instant,
    /// The class heard.
    pub class: usize,
    /// Key-pose weights of the mouth, in the class table's pose order.
    pub weights: Vec<f64>,
    /// Window level, dB full scale.
    pub level_db: f64,
}

/// The live analyser.
pub struct LiveAnalyser {
    table: ClassTable,
    profiles: Bound,
    settings: LiveSettings,
    extractor: Option<FeatureExtractor>,
    /// The stream frame the next sample should have (a jump is a gap: the window restarts).
    next_frame: Option<u64>,
    smoothed: Vec<f64>,
    scores: Vec<f64>,
    weights: Vec<f64>,
    class: usize,
}

impl LiveAnalyser {
    /// An analyser for a class table and profiles bound to it.
    pub fn new(
        table: ClassTable,
        profiles: &Profiles,
        settings: LiveSettings,
    ) -> Result<Self, Error> {
        let bound = profiles.bind(&table, "live profiles")?;
        let k = table.len();
        let p = table.poses.len();
        let class = table.silence();
        Ok(Self {
            table,
            profiles: bound,
            settings,
            extractor: None,
            next_frame: None,
            smoothed: vec![0.0; k],
            scores: vec![0.0; k],
            weights: vec![0.0; p],
            class,
        })
    }

    /// The class table.
    pub fn table(&self) -> &ClassTable {
        &self.table
    }

    /// Analyses one block; appends a step for every hop it completes.
    ///
    /// The block's first channel is analysed. A sample rate outside [`SAMPLE_RATES`] or a
    /// block without channels is an error.
    pub fn push(&mut self, block: &AudioBlock, out: &mut Vec<LiveStep>) -> Result<(), Error> {
        let format = block.format;
        if !(SAMPLE_RATES.0..=SAMPLE_RATES.1).contains(&format.sample_rate) || format.channels == 0
        {
            return Err(Error::Setting {
                what: format!(
                    "live lip sync: {} Hz with {} channels; the analyser needs {} to {} Hz and at \
                     least one channel",
                    format.sample_rate, format.channels, SAMPLE_RATES.0, SAMPLE_RATES.1
                ),
            });
        }
        if self
            .extractor
            .as_ref()
            .is_none_or(|e| e.sample_rate() != format.sample_rate)
            || self.next_frame != Some(block.first_frame)
        {
            self.extractor = Some(FeatureExtractor::new(format.sample_rate));
        }
        let channels = format.channels as usize;
        let first_at = block.first_sample_at();
        let rate = f64::from(format.sample_rate);
        let mut frame = block.first_frame;
        for s in block.samples.iter().step_by(channels) {
            let feature = self.extractor.as_mut().and_then(|e| e.push(*s));
            if let Some(f) = feature {
                let class = self.classify(&f);
                let a = 1.0 - (-HOP_S / self.settings.mouth_tau_s.max(1e-6)).exp();
                for (w, target) in self
                    .weights
                    .iter_mut()
                    .zip(&self.table.classes[class].target)
                {
                    *w += (target - *w) * a;
                }
                let offset = format.duration_of(frame - block.first_frame);
                out.push(LiveStep {
                    t: frame as f64 / rate,
                    frame,
                    heard_at: first_at + offset,
                    class,
                    weights: self.weights.clone(),
                    level_db: f.level_db,
                });
            }
            frame += 1;
        }
        self.next_frame = Some(frame);
        Ok(())
    }

    /// The class of one feature (silence by level, else the most likely profile).
    pub fn classify(&mut self, f: &Feature) -> usize {
        self.profiles.scores(&f.x, &mut self.scores);
        let a = if self.settings.score_tau_s > 0.0 {
            (-HOP_S / self.settings.score_tau_s).exp()
        } else {
            0.0
        };
        for (s, x) in self.smoothed.iter_mut().zip(&self.scores) {
            // Unprofiled classes stay at -inf and are never picked.
            *s = if x.is_finite() && s.is_finite() {
                a * *s + (1.0 - a) * x
            } else {
                *x
            };
        }
        let quiet =
            f.level_db < self.settings.gate_db || f.relative_db < self.settings.relative_gate_db;
        self.class = if quiet {
            self.table.silence()
        } else {
            let best = self
                .smoothed
                .iter()
                .enumerate()
                .filter(|(k, _)| self.profiles.has(*k))
                .max_by(|a, b| a.1.total_cmp(b.1))
                .map(|(k, _)| k);
            best.unwrap_or(self.table.silence())
        };
        self.class
    }

    /// The current key-pose weights.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }
}

#[cfg(test)]
mod tests {
    use std::time::Instant;

    use mouthpiece_frame::audio::AudioFormat;

    use super::*;
    use crate::take::{DEFAULT_CLASSES, DEFAULT_CLASSES_NAME};

    fn analyser() -> LiveAnalyser {
        let table = ClassTable::from_toml_str(DEFAULT_CLASSES, DEFAULT_CLASSES_NAME).unwrap();
        let profiles = Profiles::from_toml_str(SHIPPED_PROFILES, "shipped").unwrap();
        LiveAnalyser::new(table, &profiles, LiveSettings::default()).unwrap()
    }

    fn block(first_frame: u64, rate: u32, samples: Vec<i16>) -> AudioBlock {
        AudioBlock {
            seq: 0,
            first_frame,
            format: AudioFormat {
                sample_rate: rate,
                channels: 1,
            },
            samples,
            host_rx: Instant::now(),
            wall_clock: None,
        }
    }

    #[test]
    fn silence_is_the_silence_class_with_a_neutral_mouth_every_10_ms() {
        let mut a = analyser();
        let mut steps = Vec::new();
        for k in 0..10 {
            a.push(&block(k * 4800, 48_000, vec![0; 4800]), &mut steps)
                .unwrap();
        }
        // 1 s of sound: a step every 10 ms once the first 25 ms window is full.
        assert_eq!(steps.len(), 98);
        assert!(steps.iter().all(|s| s.class == a.table().silence()));
        assert!(steps.iter().all(|s| s.weights.iter().all(|w| *w == 0.0)));
        assert!((steps[1].t - steps[0].t - 0.010).abs() < 1e-9);
    }

    #[test]
    fn a_gap_in_the_stream_restarts_the_window() {
        let mut a = analyser();
        let mut steps = Vec::new();
        a.push(&block(0, 16_000, vec![0; 1600]), &mut steps)
            .unwrap();
        let before = steps.len();
        // 1 s missing: the next window needs 25 ms of new sound before its first step.
        a.push(&block(17_600, 16_000, vec![0; 400]), &mut steps)
            .unwrap();
        assert_eq!(steps.len(), before + 1);
        assert_eq!(steps.last().unwrap().frame, 17_999);
    }

    #[test]
    fn a_sample_rate_outside_the_range_is_an_error_naming_it() {
        let mut a = analyser();
        let e = a
            .push(&block(0, 8_000, vec![0; 80]), &mut Vec::new())
            .unwrap_err()
            .to_string();
        assert!(e.contains("8000 Hz"), "{e}");
    }

    #[test]
    fn profiles_with_wrong_lengths_or_nan_are_refused() {
        let bad_len = "version = 1\nlearned_on = \"x\"\n[[class]]\nname = \"open\"\nframes = 3\nmean = [0.0]\nvar = [1.0]\n";
        let e = Profiles::from_toml_str(bad_len, "p.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("p.toml") && e.contains("class open"), "{e}");
        let nan = SHIPPED_PROFILES.replacen("mean = [", "mean = [nan, ", 1);
        let nan = nan.replacen(", ", "", 0);
        assert!(Profiles::from_toml_str(&nan, "p.toml").is_err());
        let unknown = "version = 1\nlearned_on = \"x\"\n[[class]]\nname = \"zz\"\nframes = 3\nmean = [0.0]\nvar = [1.0]\n";
        assert!(Profiles::from_toml_str(unknown, "p.toml").is_err());
    }

    /// A class name from a profile file reaches the terminal escaped, whichever check
    /// refuses it.
    #[test]
    fn class_names_in_profile_errors_are_escaped() {
        let hostile = "op\\u001b[2J\\nen";
        let bad_len = format!("version = 1\nlearned_on = \"x\"\n[[class]]\nname = \"{hostile}\"\nframes = 3\nmean = [0.0]\nvar = [1.0]\n");
        let e = Profiles::from_toml_str(&bad_len, "p.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("class op\\u{1b}[2J\\nen:"), "{e}");
        let shipped = Profiles::from_toml_str(SHIPPED_PROFILES, "shipped").unwrap();
        let mut renamed = shipped.clone();
        renamed.classes[0].name = "x\u{1b}]0;t\u{7}".into();
        let table = ClassTable::from_toml_str(DEFAULT_CLASSES, "classes").unwrap();
        let e = renamed.bind(&table, "p.toml").unwrap_err().to_string();
        assert!(e.contains("class x\\u{1b}]0;t\\u{7} is not in"), "{e}");
        assert!(!e.contains(['\u{1b}', '\u{7}', '\n']), "{e:?}");
    }
}
