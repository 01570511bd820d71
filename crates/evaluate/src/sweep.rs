//! `mouthpiece evaluate`: synthetic sessions over seeds × noise models × head motions, each
//! measured against its ground truth, printed as Markdown tables: one row per session, the
//! rig's table after them, and optionally per dot, per naming step and per curve; the rig's
//! frames optionally to a CSV (`scripts/rig-error-split.py` reads it).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use mouthpiece_pipeline::PipelineConfig;
use mouthpiece_retarget::rig::{CURVES, CURVE_NAMES};
use mouthpiece_retarget::{Character, PerformerLayout};
use mouthpiece_synth::{DotLayout, HeadMotion, JawOptions, NoiseModel, SynthConfig};

use crate::rig::{RigAccuracy, RigFrameRecord, RigMetrics};
use crate::{EvaluateError, Measure, Metrics, StepStats, TABLE_HEADER};

/// The sessions to render and what to print about them.
pub struct SweepOptions {
    pub config: PipelineConfig,
    pub character: Character,
    /// The synthetic performer's dots (must match the configuration's `[track]`).
    pub layout: DotLayout,
    pub seeds: Vec<u64>,
    pub noises: Vec<NoiseModel>,
    pub motions: Vec<HeadMotion>,
    /// Length of each session, seconds (more than 2: the neutral pose takes 1.5 s).
    pub seconds: f64,
    /// Image size of the rendered sessions.
    pub size: (u32, u32),
    /// Camera to the mouth, metres.
    pub distance: f64,
    pub jaw: JawOptions,
    /// A table per dot after each session.
    pub per_dot: bool,
    /// A table per naming step after each session, and their sums at the end.
    pub steps: bool,
    /// Every curve's RMS after each rig row.
    pub per_curve: bool,
    /// Every counted frame's rig to this CSV.
    pub rig_frames: Option<PathBuf>,
}

/// Why a sweep stopped.
#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    #[error("--layout")]
    Layout(#[source] EvaluateError),
    #[error("--seconds must be more than 2 (the neutral pose takes the first 1.5 s)")]
    Seconds,
    #[error("--size / --distance")]
    View(#[source] mouthpiece_synth::SynthError),
    #[error("--rig-frames: cannot create {path}")]
    CreateFrames {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("writing {path}")]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("writing the tables")]
    Print(#[source] std::io::Error),
    #[error(transparent)]
    Evaluate(EvaluateError),
}

impl SweepError {
    /// The caller's flags or files, not the machine, are at fault (exit code 2).
    pub fn is_bad_input(&self) -> bool {
        matches!(
            self,
            Self::Layout(_) | Self::Seconds | Self::View(_) | Self::CreateFrames { .. }
        )
    }
}

fn evaluate_error(e: EvaluateError) -> SweepError {
    match e {
        EvaluateError::Layout { .. } => SweepError::Layout(e),
        other => SweepError::Evaluate(other),
    }
}

/// The sessions' camera and distance, checked by the synthetic performer's own rules before
/// any session is rendered.
pub fn session_view(size: (u32, u32), distance: f64) -> Result<SynthConfig, SweepError> {
    let view = SynthConfig {
        camera: SynthConfig::camera_for_size(size.0, size.1),
        distance_m: distance,
        ..SynthConfig::default()
    };
    view.validate().map_err(SweepError::View)?;
    Ok(view)
}

/// Renders and measures every session, printing the tables to `out` as it goes.
pub fn run(o: &SweepOptions, out: &mut dyn Write) -> Result<(), SweepError> {
    crate::check_layout(&o.layout, &o.config).map_err(evaluate_error)?;
    if !(o.seconds > 2.0 && o.seconds.is_finite()) {
        return Err(SweepError::Seconds);
    }
    let view = session_view(o.size, o.distance)?;
    let config = &o.config;
    let mut frames_csv = match &o.rig_frames {
        Some(path) => Some(FramesCsv::create(path, config.track.layout().lip_dots)?),
        None => None,
    };
    let p = SweepError::Print;
    writeln!(out, "{TABLE_HEADER}").map_err(p)?;
    let mut steps = StepStats::default();
    let mut rig_rows = Vec::new();
    for &motion in &o.motions {
        for &noise in &o.noises {
            for &seed in &o.seeds {
                let synth = SynthConfig {
                    seed,
                    seconds: o.seconds,
                    head_motion: motion,
                    noise,
                    layout: o.layout.clone(),
                    camera: view.camera,
                    distance_m: view.distance_m,
                    jaw: o.jaw,
                    ..SynthConfig::default()
                };
                let mut rig = RigAccuracy::new(
                    config.rig.clone(),
                    o.character.clone(),
                    config.track.layout(),
                    config.track.calibration_s,
                );
                if frames_csv.is_some() {
                    rig = rig.keep_frames();
                }
                let m = crate::evaluate_with(
                    synth,
                    config,
                    &o.character,
                    1.0,
                    &mut [&mut rig as &mut dyn Measure],
                )
                .map_err(evaluate_error)?;
                let cells = crate::table_cells(&m);
                writeln!(out, "| {seed} | {noise:?} | {motion:?} | {cells}").map_err(p)?;
                if o.per_dot {
                    write_per_dot(out, &m, config.track.layout()).map_err(p)?;
                }
                if o.steps {
                    writeln!(out, "\n{}", m.steps.table()).map_err(p)?;
                    steps.add(&m.steps);
                }
                if let (Some(csv), Some(frames)) = (&mut frames_csv, &rig.frames) {
                    csv.session(&format!("{seed},{noise:?},{motion:?}"), frames)?;
                }
                rig_rows.push((format!("{seed} | {noise:?} | {motion:?}"), rig.metrics));
            }
        }
    }
    if let Some(csv) = frames_csv {
        csv.finish()?;
    }
    if o.steps {
        writeln!(out, "All sessions:\n\n{}", steps.table()).map_err(p)?;
    }
    write_rig_header(out).map_err(p)?;
    for (label, r) in &rig_rows {
        write_rig_row(out, label, r).map_err(p)?;
        if o.per_curve {
            write_curves(out, r).map_err(p)?;
        }
    }
    Ok(())
}

fn write_per_dot(out: &mut dyn Write, m: &Metrics, layout: PerformerLayout) -> std::io::Result<()> {
    writeln!(
        out,
        "|  dot | visible | found | wrong | bias x, y, z (mm) | RMS x, y, z (mm) |"
    )?;
    for (i, d) in m.naming.per_dot.iter().enumerate() {
        let name = if i < layout.lip_dots {
            PerformerLayout::lip_name(i)
        } else {
            PerformerLayout::forehead_name(i - layout.lip_dots)
        };
        let n = d.found_named.max(1) as f64;
        let bias = d.err_sum * 1e3 / n;
        let rms = (d.err_sq / n).map(f64::sqrt) * 1e3;
        writeln!(
            out,
            "| {name:>4} | {} | {} | {} | {:+.2}, {:+.2}, {:+.2} | {:.2}, {:.2}, {:.2} |",
            d.visible, d.found_named, d.wrong, bias.x, bias.y, bias.z, rms.x, rms.y, rms.z
        )?;
    }
    Ok(())
}

/// The rig table's header.
fn write_rig_header(out: &mut dyn Write) -> std::io::Result<()> {
    writeln!(out)?;
    writeln!(
        out,
        "| seed | noise | head motion | frames | jaw RMS (°) | slide RMS (mm) | worst curve | its RMS | jawOpen r (jaw) | rounding r (mouthFunnel + mouthPucker, round) | rounding r, true dots | round SD |"
    )?;
    writeln!(out, "|---|---|---|---|---|---|---|---|---|---|---|---|")
}

/// One session's row of the rig table.
fn write_rig_row(out: &mut dyn Write, label: &str, m: &RigMetrics) -> std::io::Result<()> {
    let (worst, rms) = m.worst_curve();
    writeln!(
        out,
        "| {label} | {} | {:.2} | {:.2} | {worst} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} |",
        m.frames,
        m.jaw_rms_deg(),
        m.slide_rms_mm(),
        rms,
        m.jaw_open.value(),
        m.funnel.value(),
        m.funnel_true.value(),
        m.funnel.y_sd()
    )
}

/// Every curve's RMS (`--per-curve`).
fn write_curves(out: &mut dyn Write, m: &RigMetrics) -> std::io::Result<()> {
    let cells: Vec<String> = (0..CURVES)
        .map(|i| format!("{} {:.3}", CURVE_NAMES[i], m.curve_rms(i)))
        .collect();
    writeln!(out, "curve RMS: {}", cells.join(", "))
}

/// The `--rig-frames` CSV: one row per counted frame of every session.
struct FramesCsv {
    path: PathBuf,
    out: BufWriter<File>,
}

impl FramesCsv {
    /// Creates the file and writes the header: the session, the time, the synthetic mouth's
    /// state (jaw in degrees, rounding, spread, raise, roll-in), every curve from the tracked
    /// dots and from the true dots, every lip dot's stabilised position (metres, neutral mouth
    /// frame), tracked and true, each rig's neutral dots, the ranges both rigs' curves
    /// were computed with, whether each tracked dot was seen (1) or held (0), where the camera
    /// is in the tracked neutral mouth frame, and the tracked lip dots as the stabiliser gave
    /// them to the rig (before the rig's estimate).
    fn create(path: &Path, lip_dots: usize) -> Result<Self, SweepError> {
        let file = File::create(path).map_err(|source| SweepError::CreateFrames {
            path: path.to_path_buf(),
            source,
        })?;
        let mut header = vec![
            "seed,noise,head_motion,t,true_jaw_deg,true_round,true_spread,true_raise,true_roll_in"
                .to_string(),
        ];
        for side in ["tracked", "reference"] {
            header.extend(CURVE_NAMES.iter().map(|c| format!("{side}_{c}")));
        }
        for side in [
            "tracked",
            "reference",
            "tracked_neutral",
            "reference_neutral",
        ] {
            for i in 0..lip_dots {
                let dot = PerformerLayout::lip_name(i);
                header.extend(["x", "y", "z"].map(|a| format!("{side}_{dot}_{a}")));
            }
        }
        header.extend(CURVE_NAMES.iter().map(|c| format!("range_{c}")));
        header.extend((0..lip_dots).map(|i| format!("seen_{}", PerformerLayout::lip_name(i))));
        header.extend(["camera_x", "camera_y", "camera_z"].map(String::from));
        for i in 0..lip_dots {
            let dot = PerformerLayout::lip_name(i);
            header.extend(["x", "y", "z"].map(|a| format!("stabilised_{dot}_{a}")));
        }
        let mut csv = Self {
            path: path.to_path_buf(),
            out: BufWriter::new(file),
        };
        csv.line(&header.join(","))?;
        Ok(csv)
    }

    fn line(&mut self, text: &str) -> Result<(), SweepError> {
        writeln!(self.out, "{text}").map_err(|source| SweepError::Write {
            path: self.path.clone(),
            source,
        })
    }

    /// One session's frames; `session` is its first three cells, `seed,noise,head_motion`.
    fn session(&mut self, session: &str, frames: &[RigFrameRecord]) -> Result<(), SweepError> {
        for f in frames {
            let mut row = vec![session.to_string()];
            let m = &f.mouth;
            let truth = [
                f.t,
                m.jaw.to_degrees(),
                m.round,
                m.spread,
                m.raise,
                m.roll_in,
            ];
            row.extend(truth.map(|v| v.to_string()));
            row.extend(f.tracked.iter().chain(&f.reference).map(|v| v.to_string()));
            let dots = f.tracked_lip.iter().chain(&f.reference_lip);
            for p in dots.chain(&f.tracked_neutral).chain(&f.reference_neutral) {
                row.extend(p.map(|v| v.to_string()));
            }
            row.extend(f.ranges.iter().map(|v| v.to_string()));
            row.extend(f.tracked_seen.iter().map(|&s| u8::from(s).to_string()));
            row.extend(f.camera.map(|v| v.to_string()));
            for p in &f.stabilised_lip {
                row.extend(p.map(|v| v.to_string()));
            }
            debug_assert_eq!(row.len(), 10 + 3 * CURVES + 16 * f.tracked_lip.len());
            self.line(&row.join(","))?;
        }
        Ok(())
    }

    fn finish(mut self) -> Result<(), SweepError> {
        self.out.flush().map_err(|source| SweepError::Write {
            path: self.path.clone(),
            source,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--size` and `--distance` out of the synthetic performer's range, or NaN, are a bad
    /// input (exit code 2) naming the flags, before anything is rendered.
    #[test]
    fn sizes_and_distances_the_performer_cannot_render_are_bad_input() {
        assert!(session_view((640, 480), 0.6).is_ok());
        for (size, distance) in [
            ((640, 480), 10.0),
            ((640, 480), f64::NAN),
            ((100_000, 10), 0.6),
        ] {
            let err = session_view(size, distance).unwrap_err();
            assert!(err.is_bad_input(), "{err}");
            assert!(err.to_string().contains("--size / --distance"), "{err}");
        }
    }

    /// A `--layout` that does not match the configuration's dots is a bad input (exit code
    /// 2) naming the configuration's keys, not a panic.
    #[test]
    fn a_layout_that_does_not_match_the_configuration_is_refused() {
        let layout = DotLayout {
            lip_dots: 8,
            ..Default::default()
        };
        let config = PipelineConfig::default();
        let err = crate::check_layout(&layout, &config)
            .map_err(evaluate_error)
            .unwrap_err();
        assert!(err.is_bad_input(), "{err}");
        let source = std::error::Error::source(&err).unwrap().to_string();
        assert!(source.contains("track.lip_dots"), "{source}");
    }
}
