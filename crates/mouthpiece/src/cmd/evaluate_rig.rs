//! The rig's accuracy (docs/rig.md), measured inside `mouthpiece evaluate`: the jaw against the
//! synthetic performer's own mouth state, and every named curve against its definition
//! applied to the ground-truth dots.
//!
//! Per session, over the frames after calibration from the evaluation's `--skip` on:
//! - *jaw RMS*: the rig's jaw angle against the synthetic jaw's rotation (degrees);
//! - *slide RMS*: the rig's jaw slide against the synthetic jaw's, which does not slide (mm);
//! - *curve RMS*: each curve against the same curve computed from the ground-truth dots
//!   (stabilised by the retarget core from the true dots, the same neutral frames), with the
//!   tracked rig's ranges; the worst curve is reported with its name;
//! - *correlations*: `jawOpen` with the synthetic jaw angle, `mouthFunnel` with its rounding.

use mouthpiece_retarget::rig::{curves_from, Rig, RigModel, RigSettings, CURVES, CURVE_NAMES};
use mouthpiece_retarget::{NeutralPose, StabilisedFrame};
use mouthpiece_synth::MouthTruth;

/// Pearson correlation accumulator.
#[derive(Debug, Clone, Copy, Default)]
pub struct Correlation {
    n: f64,
    sx: f64,
    sy: f64,
    sxx: f64,
    syy: f64,
    sxy: f64,
}

impl Correlation {
    pub fn push(&mut self, x: f64, y: f64) {
        self.n += 1.0;
        self.sx += x;
        self.sy += y;
        self.sxx += x * x;
        self.syy += y * y;
        self.sxy += x * y;
    }

    pub fn value(&self) -> f64 {
        let n = self.n.max(1.0);
        let cov = self.sxy / n - self.sx * self.sy / (n * n);
        let vx = self.sxx / n - self.sx * self.sx / (n * n);
        let vy = self.syy / n - self.sy * self.sy / (n * n);
        if vx <= 0.0 || vy <= 0.0 {
            return f64::NAN;
        }
        cov / (vx * vy).sqrt()
    }
}

/// One session's rig figures.
#[derive(Debug, Clone, Default)]
pub struct RigMetrics {
    pub frames: usize,
    pub jaw_sq: f64,
    pub slide_sq: f64,
    pub curve_sq: [f64; CURVES],
    pub jaw_open: Correlation,
    pub funnel: Correlation,
}

impl RigMetrics {
    pub fn jaw_rms_deg(&self) -> f64 {
        (self.jaw_sq / self.frames.max(1) as f64).sqrt()
    }
    pub fn slide_rms_mm(&self) -> f64 {
        1e3 * (self.slide_sq / self.frames.max(1) as f64).sqrt()
    }
    pub fn curve_rms(&self, i: usize) -> f64 {
        (self.curve_sq[i] / self.frames.max(1) as f64).sqrt()
    }
    /// The worst curve: (name, RMS).
    pub fn worst_curve(&self) -> (&'static str, f64) {
        (0..CURVES)
            .map(|i| (CURVE_NAMES[i], self.curve_rms(i)))
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .expect("curves")
    }
}

/// The measurement in progress: the tracked rig and the ground truth's.
#[derive(Debug, Default)]
pub struct RigAccuracy {
    settings: RigSettings,
    tracked: Option<Rig>,
    truth: Option<RigModel>,
    pub metrics: RigMetrics,
}

impl RigAccuracy {
    pub fn new(settings: RigSettings) -> Self {
        Self {
            settings,
            ..Self::default()
        }
    }

    /// A neutral pose was taken: the tracker's and the one from the true dots.
    pub fn calibrated(&mut self, tracked: &NeutralPose, truth: &NeutralPose) -> anyhow::Result<()> {
        self.tracked = Some(Rig::new(tracked, self.settings.clone())?);
        self.truth = Some(RigModel::new(truth, &self.settings)?);
        Ok(())
    }

    /// Every stabilised frame (keeps the tracked rig's learning in step); `measured` says
    /// whether it counts.
    pub fn frame(
        &mut self,
        tracked: &StabilisedFrame,
        truth: &StabilisedFrame,
        mouth: Option<&MouthTruth>,
        measured: bool,
    ) {
        let (Some(rig), Some(model)) = (&mut self.tracked, &self.truth) else {
            return;
        };
        rig.step(tracked);
        if !measured {
            return;
        }
        let Some(mouth) = mouth else {
            return;
        };
        let ours = *rig.measures();
        let theirs = model.measure(&truth.lip);
        let (mut a, mut b) = ([0.0; CURVES], [0.0; CURVES]);
        curves_from(&ours, rig.ranges(), &mut a);
        curves_from(&theirs, rig.ranges(), &mut b);
        let m = &mut self.metrics;
        m.frames += 1;
        m.jaw_sq += (ours.jaw_angle - mouth.jaw).to_degrees().powi(2);
        m.slide_sq += ours.jaw_slide.powi(2);
        for ((sq, x), y) in m.curve_sq.iter_mut().zip(a).zip(b) {
            *sq += (x - y).powi(2);
        }
        m.jaw_open.push(a[0], mouth.jaw);
        m.funnel.push(a[2], mouth.round);
    }
}

/// The table's header.
pub fn print_header() {
    println!();
    println!(
        "| seed | noise | head motion | frames | jaw RMS (°) | slide RMS (mm) | worst curve | its RMS | jawOpen r (jaw) | mouthFunnel r (round) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
}

/// One session's row.
pub fn print_row(label: &str, m: &RigMetrics) {
    let (worst, rms) = m.worst_curve();
    println!(
        "| {label} | {} | {:.2} | {:.2} | {worst} | {:.3} | {:.3} | {:.3} |",
        m.frames,
        m.jaw_rms_deg(),
        m.slide_rms_mm(),
        rms,
        m.jaw_open.value(),
        m.funnel.value()
    );
}

/// Every curve's RMS (for `--per-curve`).
pub fn print_curves(m: &RigMetrics) {
    let cells: Vec<String> = (0..CURVES)
        .map(|i| format!("{} {:.3}", CURVE_NAMES[i], m.curve_rms(i)))
        .collect();
    println!("curve RMS: {}", cells.join(", "));
}
