//! `mouthpiece evaluate`: the measuring instrument measured. Renders synthetic sessions
//! (`mouthpiece-synth`, exact ground truth) in memory, runs the whole pipeline on them and
//! prints, per session, how well the dots were found, named and placed, the head rotation
//! error, and how far the character output is from the retarget core fed with the ground
//! truth itself.
//!
//! Definitions (frames from `--skip` seconds on, the neutral second excluded):
//! - *found & named*: over visible ground-truth dots, the share the tracker reports under
//!   their own name, at a pixel whose nearest projected true dot is their own (within 8 px);
//! - *wrong*: dots the tracker reports at a pixel whose nearest projected true dot is another
//!   one (or none within 8 px); hidden dots reported are counted apart (*named hidden*);
//! - *3D RMS*: over correctly named visible dots, distance to the true centre;
//! - *head RMS*: angle between the tracked head rotation and the true one (both relative to
//!   the pose at calibration);
//! - *character RMS*: the character points against those the retarget core gives from the
//!   true dots with the same neutral frames, as a share of the character's mouth width; over
//!   the points whose driving lip dot is visible (the accuracy targets are on visible dots),
//!   and over all points (a dot the camera cannot see holds its last value, docs/method.md §6,
//!   while the truth moves on).

use std::path::PathBuf;

use anyhow::Context as _;
use mouthpiece_retarget::{
    Character, CharacterSettings, NeutralAccumulator, PerformerDots, PerformerLayout,
    RetargetConfig, Retargeter, ShapeSmoothing,
};
use mouthpiece_synth::{GroundTruth, HeadMotion, NoiseModel, Synth, SynthConfig};
use mouthpiece_track::pipeline::{Pipeline, PipelineConfig};
use nalgebra::{Matrix3, Vector3};

use crate::cmd::process::{load_character, load_config};
use crate::exit::bad_input;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Motion {
    None,
    Mild,
    Strong,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Noise {
    None,
    Kinect,
    Realsense,
}

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Seeds of the synthetic sessions.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    pub seeds: Vec<u64>,
    /// Depth noise models.
    #[arg(long, value_delimiter = ',', default_value = "kinect,realsense")]
    pub noise: Vec<Noise>,
    /// Head motions.
    #[arg(
        long = "head-motion",
        value_delimiter = ',',
        default_value = "mild,strong"
    )]
    pub head_motion: Vec<Motion>,
    /// Length of each session, seconds.
    #[arg(long, default_value_t = 6.0)]
    pub seconds: f64,
    /// Character the output is measured on.
    #[arg(long, default_value = "config/characters/wolf.toml")]
    pub character: PathBuf,
    /// Configuration file (`[detect]`, `[track]`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Dot layout of the synthetic performer (TOML, as `mouthpiece synth --layout`): where
    /// the forehead dots are painted, paint colours, dot size.
    #[arg(long)]
    pub layout: Option<PathBuf>,
    /// After each session, a table per dot: found, wrong, bias and RMS per camera axis.
    #[arg(long)]
    pub per_dot: bool,
    /// After the rig table, every named curve's RMS per session.
    #[arg(long)]
    pub per_curve: bool,
}

/// One session's figures.
#[derive(Debug, Clone, Default)]
pub struct Metrics {
    pub frames: usize,
    pub visible: usize,
    pub found_named: usize,
    pub wrong: usize,
    pub named_hidden: usize,
    pub err_sq_sum: f64,
    pub head_sq_sum: f64,
    pub head_frames: usize,
    pub char_sq_sum: f64,
    pub char_count: usize,
    /// Over the points whose driving lip dot is visible.
    pub char_visible_sq_sum: f64,
    pub char_visible_count: usize,
    pub char_width: f64,
    pub calibrated_at: Option<f64>,
    /// Per dot (`D1..`, then `F1..`), for `--per-dot`.
    pub per_dot: Vec<DotStats>,
    /// The rig's accuracy (`evaluate_rig`).
    pub rig: crate::cmd::evaluate_rig::RigMetrics,
}

/// One dot's figures over a session.
#[derive(Debug, Clone, Default)]
pub struct DotStats {
    pub visible: usize,
    pub found_named: usize,
    pub wrong: usize,
    /// Sum of (tracked − true), camera frame, metres: the bias.
    pub err_sum: Vector3<f64>,
    /// Sum of squared error components.
    pub err_sq: Vector3<f64>,
}

impl Metrics {
    pub fn found_pct(&self) -> f64 {
        100.0 * self.found_named as f64 / self.visible.max(1) as f64
    }
    pub fn rms_mm(&self) -> f64 {
        1e3 * (self.err_sq_sum / self.found_named.max(1) as f64).sqrt()
    }
    pub fn head_rms_deg(&self) -> f64 {
        (self.head_sq_sum / self.head_frames.max(1) as f64)
            .sqrt()
            .to_degrees()
    }
    /// Over every character point.
    pub fn char_rms_pct(&self) -> f64 {
        100.0 * (self.char_sq_sum / self.char_count.max(1) as f64).sqrt() / self.char_width
    }
    /// Over the character points whose driving lip dot is visible.
    pub fn char_visible_rms_pct(&self) -> f64 {
        100.0 * (self.char_visible_sq_sum / self.char_visible_count.max(1) as f64).sqrt()
            / self.char_width
    }
}

fn v3(a: [f64; 3]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}

fn rot(gt: &GroundTruth) -> Matrix3<f64> {
    let m = gt.head.rotation_matrix();
    Matrix3::new(
        m[0][0], m[0][1], m[0][2], m[1][0], m[1][1], m[1][2], m[2][0], m[2][1], m[2][2],
    )
}

fn gt_dots(gt: &GroundTruth, layout: PerformerLayout) -> PerformerDots {
    let mut d = PerformerDots::new(layout);
    for (i, slot) in d.lip.iter_mut().enumerate() {
        *slot = gt.point(&PerformerLayout::lip_name(i)).map(v3);
    }
    for (i, slot) in d.forehead.iter_mut().enumerate() {
        *slot = gt.point(&PerformerLayout::forehead_name(i)).map(v3);
    }
    d
}

/// The synthetic performer must wear the dots the configuration's `[track]` expects (a bad
/// input, exit code 2).
fn check_layout(
    layout: &mouthpiece_synth::DotLayout,
    config: &PipelineConfig,
) -> anyhow::Result<()> {
    let (lip, forehead) = (config.track.lip_dots, config.track.forehead_dots);
    if layout.lip_dots != lip || layout.forehead.len() != forehead {
        return Err(bad_input(anyhow::anyhow!(
            "--layout: the synthetic performer wears {} lip dots and {} forehead dots, but the \
             configuration expects {lip} and {forehead} (track.lip_dots, track.forehead_dots)",
            layout.lip_dots,
            layout.forehead.len()
        )));
    }
    Ok(())
}

/// Runs the pipeline over one synthetic session and measures it against its ground truth.
pub fn evaluate(
    synth: SynthConfig,
    config: &PipelineConfig,
    character: &Character,
    skip_s: f64,
) -> anyhow::Result<Metrics> {
    let settings = CharacterSettings {
        smoothing: ShapeSmoothing::None,
        one_euro: None,
    };
    check_layout(&synth.layout, config)?;
    let mut pipeline = Pipeline::new(config.clone(), character.clone(), settings)?;
    let layout = config.track.layout();
    let names: Vec<String> = (0..layout.lip_dots)
        .map(PerformerLayout::lip_name)
        .chain((0..layout.forehead_dots).map(PerformerLayout::forehead_name))
        .collect();
    let mut synth = Synth::new(synth).context("synthetic performer")?;
    let mut m = Metrics {
        char_width: character.mouth_width(),
        per_dot: vec![DotStats::default(); names.len()],
        ..Metrics::default()
    };

    // Ground truth kept for the calibration window (to build the reference retarget from the
    // same frames the tracker used).
    let mut history: Vec<(f64, GroundTruth)> = Vec::new();
    let mut reference: Option<Retargeter> = None;
    let mut head_at_calibration = Matrix3::identity();
    let mut rig = crate::cmd::evaluate_rig::RigAccuracy::new(config.rig.clone());
    let mut rig_pending = false;
    while let Some((frame, gt)) = synth.render_next() {
        if let (true, Some(n), Some(r)) = (rig_pending, pipeline.tracker().neutral(), &reference) {
            rig.calibrated(n, r.stabiliser().neutral())?;
            rig_pending = false;
        }
        let (line, tracked) = pipeline.process(&frame)?;
        let t = tracked.t;
        history.push((t, gt.clone()));
        if tracked.status.neutral_taken {
            m.calibrated_at = Some(t);
            let neutral_s = config.track.calibration_s;
            let mut acc = NeutralAccumulator::new(layout);
            let mut rotations = Vec::new();
            for (ht, g) in history.iter().filter(|(ht, _)| *ht >= t - neutral_s - 1e-6) {
                let _ = ht;
                acc.push(&gt_dots(g, layout))?;
                rotations.push(rot(g));
            }
            // The neutral pose averages the window: compare against the window's mean rotation.
            let mean = rotations.iter().sum::<Matrix3<f64>>() / rotations.len().max(1) as f64;
            head_at_calibration = nalgebra::Rotation3::from_matrix(&mean).into_inner();
            let cfg = RetargetConfig {
                missing: Default::default(),
                character: settings,
            };
            let mut r = Retargeter::new(character.clone(), acc.finish()?, cfg)?;
            // Bring the reference's clock to now.
            r.step(t, &gt_dots(&gt, layout))?;
            reference = Some(r);
            rig_pending = true;
        }
        if t < skip_s {
            continue;
        }
        m.frames += 1;
        let points: Vec<Option<Vector3<f64>>> = tracked
            .dots
            .lip
            .iter()
            .chain(&tracked.dots.forehead)
            .copied()
            .collect();
        let truth: Vec<Vector3<f64>> = names
            .iter()
            .map(|n| v3(gt.point(n).expect("every dot has truth")))
            .collect();
        let truth_px: Vec<Option<[f64; 2]>> = truth
            .iter()
            .map(|q| mouthpiece_track::camera::project(&frame.calibration.color, q))
            .collect();
        for (i, name) in names.iter().enumerate() {
            let visible = gt.is_visible(name);
            if visible {
                m.visible += 1;
                m.per_dot[i].visible += 1;
            }
            let Some(p) = points[i] else {
                if visible {
                    tracing::debug!(t, dot = %name, "visible dot not found");
                }
                continue;
            };
            // Naming is judged in the image (which blob got the name); how far the 3D point
            // is from the truth is the 3D error, reported apart.
            let px = tracked.pixels[i].expect("a named dot has a pixel");
            let (nearest, dist_px) = truth_px
                .iter()
                .enumerate()
                .filter_map(|(j, q)| {
                    q.map(|q| (j, ((px[0] - q[0]).powi(2) + (px[1] - q[1]).powi(2)).sqrt()))
                })
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .expect("dots");
            if nearest != i || dist_px > 8.0 {
                m.wrong += 1;
                m.per_dot[i].wrong += 1;
                tracing::debug!(t, dot = %name, nearest = %names[nearest], dist_px, "wrongly named");
            } else if visible {
                let dist = (p - truth[i]).norm();
                m.found_named += 1;
                m.err_sq_sum += dist * dist;
                let d = &mut m.per_dot[i];
                let e = p - truth[i];
                d.found_named += 1;
                d.err_sum += e;
                d.err_sq += e.component_mul(&e);
                if dist > 0.006 {
                    tracing::debug!(t, dot = %name, dist_mm = dist * 1e3, "far from its true position");
                }
            } else {
                m.named_hidden += 1;
            }
        }
        if let Some(s) = &tracked.stabilised {
            let truth_rel = rot(&gt) * head_at_calibration.transpose();
            let diff = s.head.rotation.transpose() * truth_rel;
            let angle = ((diff.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos();
            m.head_sq_sum += angle * angle;
            m.head_frames += 1;
        }
        if let Some(r) = &mut reference {
            let ours: Vec<[f64; 3]> = line.retarget.points.0.iter().map(|(_, p)| *p).collect();
            let out = r.step(t, &gt_dots(&gt, layout))?;
            if let Some(s) = &tracked.stabilised {
                rig.frame(s, out.performer, gt.mouth.as_ref(), true);
            }
            for (k, (a, b)) in ours.iter().zip(&out.character.points).enumerate() {
                let d2 = (v3(*a) - b).norm_squared();
                tracing::trace!(
                    t,
                    point = k,
                    diff = d2.sqrt(),
                    "character point against reference"
                );
                m.char_sq_sum += d2;
                m.char_count += 1;
                if gt.is_visible(&names[character.driver[k]]) {
                    m.char_visible_sq_sum += d2;
                    m.char_visible_count += 1;
                }
            }
        }
    }
    m.rig = rig.metrics;
    Ok(m)
}

fn print_per_dot(m: &Metrics, layout: PerformerLayout) {
    println!("|  dot | visible | found | wrong | bias x, y, z (mm) | RMS x, y, z (mm) |");
    for (i, d) in m.per_dot.iter().enumerate() {
        let name = if i < layout.lip_dots {
            PerformerLayout::lip_name(i)
        } else {
            PerformerLayout::forehead_name(i - layout.lip_dots)
        };
        let n = d.found_named.max(1) as f64;
        let bias = d.err_sum * 1e3 / n;
        let rms = (d.err_sq / n).map(f64::sqrt) * 1e3;
        println!(
            "| {name:>4} | {} | {} | {} | {:+.2}, {:+.2}, {:+.2} | {:.2}, {:.2}, {:.2} |",
            d.visible, d.found_named, d.wrong, bias.x, bias.y, bias.z, rms.x, rms.y, rms.z
        );
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let config = load_config(args.config.as_deref())?;
    let layout = match &args.layout {
        Some(path) => mouthpiece_synth::DotLayout::from_file(path).map_err(bad_input)?,
        None => mouthpiece_synth::DotLayout::default(),
    };
    let character = load_character(&args.character)?;
    if !(args.seconds > 2.0 && args.seconds.is_finite()) {
        return Err(bad_input(anyhow::anyhow!(
            "--seconds must be more than 2 (the neutral pose takes the first 1.5 s)"
        )));
    }
    println!(
        "| seed | noise | head motion | frames | calibrated at (s) | visible dots | found & named | wrong | named hidden | 3D RMS (mm) | head RMS (°) | character RMS, visible dots (% width) | character RMS, all dots (% width) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut rig_rows = Vec::new();
    for &motion in &args.head_motion {
        for &noise in &args.noise {
            for &seed in &args.seeds {
                let synth = SynthConfig {
                    seed,
                    seconds: args.seconds,
                    head_motion: match motion {
                        Motion::None => HeadMotion::None,
                        Motion::Mild => HeadMotion::Mild,
                        Motion::Strong => HeadMotion::Strong,
                    },
                    noise: match noise {
                        Noise::None => NoiseModel::None,
                        Noise::Kinect => NoiseModel::Kinect,
                        Noise::Realsense => NoiseModel::Realsense,
                    },
                    layout: layout.clone(),
                    ..SynthConfig::default()
                };
                let m = evaluate(synth, &config, &character, 1.0)?;
                println!(
                    "| {seed} | {noise:?} | {motion:?} | {} | {} | {} | {:.2} % | {} | {} | {:.2} | {:.2} | {:.2} | {:.2} |",
                    m.frames,
                    m.calibrated_at.map_or("never".to_string(), |t| format!("{t:.2}")),
                    m.visible,
                    m.found_pct(),
                    m.wrong,
                    m.named_hidden,
                    m.rms_mm(),
                    m.head_rms_deg(),
                    m.char_visible_rms_pct(),
                    m.char_rms_pct()
                );
                if args.per_dot {
                    print_per_dot(&m, config.track.layout());
                }
                rig_rows.push((format!("{seed} | {noise:?} | {motion:?}"), m.rig));
            }
        }
    }
    crate::cmd::evaluate_rig::print_header();
    for (label, r) in &rig_rows {
        crate::cmd::evaluate_rig::print_row(label, r);
        if args.per_curve {
            crate::cmd::evaluate_rig::print_curves(r);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Figures a short session must reach (README's table is the 12-session measurement).
    struct Guard {
        found_pct: f64,
        wrong: usize,
        rms_mm: f64,
        head_deg: f64,
        /// Character RMS over the points whose dot is visible, and over all points.
        char_visible_pct: f64,
        char_pct: f64,
    }

    /// Renders a short session now, measures it against its ground truth and holds it to the
    /// figures the pipeline reached when this was written (regression guards, a little
    /// looser than measured; the accuracy targets are in docs/detection.md).
    fn session_holds(synth: SynthConfig, guard: Guard) {
        let character =
            Character::from_toml_str(include_str!("../../../../config/characters/human.toml"))
                .unwrap();
        let m = evaluate(synth, &PipelineConfig::default(), &character, 1.0).unwrap();
        let calibrated = m.calibrated_at.expect("neutral pose taken");
        assert!(
            (0.9..1.6).contains(&calibrated),
            "calibrated at {calibrated} s"
        );
        assert!(m.frames >= 89 && m.visible > 1000, "{m:?}");
        let figures = format!(
            "found and named {:.2} %, {} wrong of {}, 3D RMS {:.2} mm, head RMS {:.2}°, character RMS {:.2} % of its width on visible dots, {:.2} % on all",
            m.found_pct(),
            m.wrong,
            m.visible,
            m.rms_mm(),
            m.head_rms_deg(),
            m.char_visible_rms_pct(),
            m.char_rms_pct()
        );
        assert!(m.found_pct() >= guard.found_pct, "{figures}");
        assert!(m.wrong <= guard.wrong, "{figures}");
        assert!(m.rms_mm() <= guard.rms_mm, "{figures}");
        assert!(m.head_rms_deg() <= guard.head_deg, "{figures}");
        assert!(
            m.char_visible_rms_pct() <= guard.char_visible_pct,
            "{figures}"
        );
        assert!(m.char_rms_pct() <= guard.char_pct, "{figures}");
    }

    #[test]
    fn synthetic_session_is_tracked_against_ground_truth() {
        // Measured: 100 % found and named, none wrong, 1.01 mm, 0.31°, character 1.93 % on
        // visible dots, 2.14 % on all.
        session_holds(
            SynthConfig {
                seed: 3,
                seconds: 4.0,
                ..SynthConfig::default()
            },
            Guard {
                found_pct: 99.5,
                wrong: 0,
                rms_mm: 1.3,
                head_deg: 0.5,
                char_visible_pct: 2.4,
                char_pct: 2.6,
            },
        );
    }

    #[test]
    fn lips_pressed_shut_stay_named() {
        // At 2.9 s the lips press shut and stop dead: their constant-velocity predictions
        // overshoot past each other, and every lip dot went missing for a frame (99.18 %
        // found) until the names from "the lips stopped" were tried (99.70 %). At 2.53 s the
        // jaw drops within a frame: the lower lip left ghosts where it was, three of its dots
        // took them and two went missing (1 wrong name, 99.78 %) until the names from "the
        // lower lip jumped together" were tried. Measured now: 100 %, none wrong, 1.08 mm,
        // 0.23°, character 2.15 % on visible dots, 2.38 % on all.
        session_holds(
            SynthConfig {
                seed: 1,
                seconds: 4.0,
                ..SynthConfig::default()
            },
            Guard {
                found_pct: 99.6,
                wrong: 0,
                rms_mm: 1.3,
                head_deg: 0.4,
                char_visible_pct: 2.5,
                char_pct: 2.7,
            },
        );
    }

    #[test]
    fn a_corner_folding_into_the_mouth_is_not_named_on_its_neighbour() {
        // At 5.0 s D7 (a corner) half folds away and its paint merges with D6's; with blobs
        // split only from 1.5 dots' area, D6 was named on the merged blob, nearer D7 (2 wrong
        // names, 99.50 % found). Lip dots found from their neighbours' places are checked for
        // a ghost left beside them again (character 3.11 % on all points without, 2.79 with).
        // Measured: 99.82 %, none wrong, 1.22 mm, 0.44°, character 2.57 % on visible dots,
        // 2.79 % on all.
        session_holds(
            SynthConfig {
                seed: 1,
                seconds: 6.0,
                head_motion: HeadMotion::Strong,
                ..SynthConfig::default()
            },
            Guard {
                found_pct: 99.6,
                wrong: 0,
                rms_mm: 1.4,
                head_deg: 0.6,
                char_visible_pct: 2.8,
                char_pct: 3.0,
            },
        );
    }

    #[test]
    fn strong_head_motion_is_tracked_against_ground_truth() {
        // Measured: 99.77 % found and named, none wrong of 1327, 1.07 mm, 0.39°, character
        // 2.78 % on visible dots, 2.94 % on all.
        session_holds(
            SynthConfig {
                seed: 2,
                seconds: 4.0,
                head_motion: HeadMotion::Strong,
                ..SynthConfig::default()
            },
            Guard {
                found_pct: 99.5,
                wrong: 0,
                rms_mm: 1.3,
                head_deg: 0.6,
                char_visible_pct: 3.0,
                char_pct: 3.2,
            },
        );
    }

    #[test]
    fn lip_dots_near_the_corners_leave_their_ghosts_when_the_jaw_drops() {
        // At 1.87 s the jaw drops 6 px within a frame. D8 and D12 had been seen again only
        // the frame before (no velocity yet): their predictions stayed put, right on their
        // motion-blur ghosts, so they showed no miss while D9..D11 jumped. Judged against
        // where they were last frame they are (2 wrong names without). Measured: 99.92 %,
        // none wrong, 1.12 mm, 0.42°, character 2.33 % on visible dots, 2.52 % on all.
        session_holds(
            SynthConfig {
                seed: 3,
                seconds: 4.0,
                head_motion: HeadMotion::Strong,
                ..SynthConfig::default()
            },
            Guard {
                found_pct: 99.7,
                wrong: 0,
                rms_mm: 1.3,
                head_deg: 0.6,
                char_visible_pct: 2.6,
                char_pct: 2.8,
            },
        );
    }

    #[test]
    fn a_lower_lip_on_its_ghosts_is_named_from_the_jaws_jump() {
        // At 2.83 s the jaw snaps shut 7 px within a frame and the whole lower lip sat on its
        // faint motion-blur ghosts, none missing; the names from the jaw's jump lost the
        // corner D7 (merged with D6) to the corner check, and were refused for naming one
        // dot fewer (1 wrong name, 99.40 %, character 3.17 % on visible dots). Measured:
        // 99.62 %, none wrong, 0.94 mm, 0.41°, character 2.43 % on visible dots, 2.93 % on
        // all.
        session_holds(
            SynthConfig {
                seed: 6,
                seconds: 4.0,
                head_motion: HeadMotion::Strong,
                noise: NoiseModel::Realsense,
                ..SynthConfig::default()
            },
            Guard {
                found_pct: 99.5,
                wrong: 0,
                rms_mm: 1.1,
                head_deg: 0.6,
                char_visible_pct: 2.7,
                char_pct: 3.2,
            },
        );
    }

    #[test]
    fn a_corner_merged_with_its_neighbour_is_split_from_where_the_neighbour_was() {
        // At 2.0-2.1 s the mouth narrows fast and D7 (a corner) merges with D6; D6's velocity,
        // measured on the merged blob, overshoots by 4 px, so its prediction lay too far from
        // the merged blob to split it, and D7 then held D6's blob (2 wrong names without the
        // merged blob looked for from D6's last place; 3 with the split along the line
        // between the two predictions instead of the blob's long axis). Measured: 99.85 %,
        // none wrong, 1.29 mm, 0.34°, character 3.09 % on visible dots, 3.40 % on all (a
        // hard session: a pursed mouth a few pixels across).
        session_holds(
            SynthConfig {
                seed: 6,
                seconds: 4.0,
                ..SynthConfig::default()
            },
            Guard {
                found_pct: 99.7,
                wrong: 0,
                rms_mm: 1.45,
                head_deg: 0.5,
                char_visible_pct: 3.4,
                char_pct: 3.7,
            },
        );
    }

    #[test]
    fn a_session_without_paint_says_so_on_every_frame() {
        // Dots painted in skin colour: nothing to find; the pipeline must not fail.
        let character =
            Character::from_toml_str(include_str!("../../../../config/characters/human.toml"))
                .unwrap();
        let layout = mouthpiece_synth::DotLayout {
            lip_color: [205, 150, 120],
            forehead_color: [205, 150, 120],
            ..Default::default()
        };
        let mut synth = Synth::new(SynthConfig {
            seed: 1,
            seconds: 1.5,
            layout,
            ..SynthConfig::default()
        })
        .unwrap();
        let settings = CharacterSettings {
            smoothing: ShapeSmoothing::None,
            one_euro: None,
        };
        let mut pipeline = Pipeline::new(PipelineConfig::default(), character, settings).unwrap();
        while let Some((frame, _)) = synth.render_next() {
            let (line, tracked) = pipeline.process(&frame).unwrap();
            assert!(tracked.status.calibrating && tracked.status.too_few_dots);
            assert_eq!(tracked.status.dots_missing.len(), 15);
            let json = serde_json::to_string(&line).unwrap();
            assert!(
                json.contains("\"calibrating\":true") && json.contains("\"D1\":null"),
                "{json}"
            );
        }
    }

    /// A `--layout` that does not match the configuration's dots is a bad input, not a
    /// panic.
    #[test]
    fn a_layout_that_does_not_match_the_configuration_is_refused() {
        let character =
            Character::from_toml_str(include_str!("../../../../config/characters/human.toml"))
                .unwrap();
        for layout in [
            mouthpiece_synth::DotLayout {
                lip_dots: 8,
                ..Default::default()
            },
            mouthpiece_synth::DotLayout {
                forehead: mouthpiece_synth::DotLayout::default().forehead[..2].to_vec(),
                ..Default::default()
            },
        ] {
            let synth = SynthConfig {
                seed: 1,
                seconds: 2.5,
                layout,
                ..SynthConfig::default()
            };
            let err = evaluate(synth, &PipelineConfig::default(), &character, 1.0).unwrap_err();
            assert!(
                err.chain().any(|e| e.is::<crate::exit::BadInput>()),
                "{err:#}"
            );
            assert!(format!("{err:#}").contains("track.lip_dots"), "{err:#}");
        }
    }
}
