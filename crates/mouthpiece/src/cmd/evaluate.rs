//! `mouthpiece evaluate`: renders synthetic sessions and measures the pipeline on them
//! against their ground truth (the figures and their definitions: `mouthpiece-evaluate`),
//! printing one table row per session.

use anyhow::Context as _;
use std::path::PathBuf;

use mouthpiece_evaluate::rig::RigAccuracy;
use mouthpiece_evaluate::{EvaluateError, Measure, Metrics, StepStats, TABLE_HEADER};
use mouthpiece_retarget::PerformerLayout;
use mouthpiece_synth::{HeadMotion, NoiseModel, SynthConfig};

use crate::cmd::process::{load_character, load_config};
use crate::exit::bad_input;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Motion {
    None,
    Mild,
    Strong,
    /// The strong motion at 1.5 times its speed.
    Fast,
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
    /// Character the output is measured on (a character file; default: the built-in wolf,
    /// the repository's `config/characters/wolf.toml` embedded at build time, so the default
    /// works from any working directory).
    #[arg(long)]
    pub character: Option<PathBuf>,
    /// Configuration file (`[detect]`, `[track]`, `[retarget]`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Dot layout of the synthetic performer (TOML, as `mouthpiece synth --layout`): where
    /// the forehead dots are painted, paint colours, dot size.
    #[arg(long)]
    pub layout: Option<PathBuf>,
    /// After each session, a table per dot: found, wrong, bias and RMS per camera axis.
    #[arg(long)]
    pub per_dot: bool,
    /// After each session, a table per naming step: the frames and runs it changed names
    /// on, and the found and wrong names it added and took away; at the end, the sums.
    #[arg(long)]
    pub steps: bool,
    /// After the rig table, every named curve's RMS per session.
    #[arg(long)]
    pub per_curve: bool,
    /// Writes every counted frame's rig to this CSV file: the synthetic mouth's state (jaw,
    /// rounding, spread, raise, roll-in), every curve from the tracked and from the true
    /// dots, the lip dots both rigs measured, and the tracked ones as the stabiliser gave
    /// them (`scripts/rig-error-split.py` reads it).
    #[arg(long, value_name = "FILE")]
    pub rig_frames: Option<PathBuf>,
    /// Image size WIDTHxHEIGHT of the rendered sessions (focal length 525 px at 640 wide,
    /// scaled), as `synth --size`.
    #[arg(long, default_value = "640x480", value_parser = crate::cmd::synth::parse_size)]
    pub size: (u32, u32),
    /// Camera to the mouth, metres, as `synth --distance`.
    #[arg(long, default_value_t = 0.6)]
    pub distance: f64,
    /// The synthetic jaw's hinge and slide, as `synth --hinge` and `--jaw-slide`: the rig's
    /// jaw is measured against the synthetic jaw's own rotation and slide.
    #[command(flatten)]
    pub jaw: crate::cmd::synth::JawArgs,
}

/// The sessions' camera and distance from `--size` and `--distance`, checked by the synthetic
/// performer's own rules before any session is rendered: a bad value is the caller's input
/// (exit code 2), named by its flags.
fn session_view(size: (u32, u32), distance: f64) -> anyhow::Result<SynthConfig> {
    let view = SynthConfig {
        camera: SynthConfig::camera_for_size(size.0, size.1),
        distance_m: distance,
        ..SynthConfig::default()
    };
    view.validate()
        .map_err(|e| bad_input(anyhow::Error::new(e).context("--size / --distance")))?;
    Ok(view)
}

/// A bad `--layout` is the caller's input (exit code 2); anything else is not.
fn to_anyhow(e: EvaluateError) -> anyhow::Error {
    match e {
        EvaluateError::Layout { .. } => bad_input(anyhow::Error::new(e).context("--layout")),
        other => anyhow::Error::new(other),
    }
}

fn print_per_dot(m: &Metrics, layout: PerformerLayout) {
    println!("|  dot | visible | found | wrong | bias x, y, z (mm) | RMS x, y, z (mm) |");
    for (i, d) in m.naming.per_dot.iter().enumerate() {
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

/// The built-in wolf the daemon drives by default.
fn builtin_wolf() -> anyhow::Result<mouthpiece_retarget::Character> {
    let (name, text) = mouthpiece_daemon::characters::BUILTIN
        .iter()
        .find(|(name, _)| name.ends_with("/wolf.toml"))
        .expect("the built-in characters include the wolf");
    mouthpiece_retarget::Character::from_toml_str(text)
        .with_context(|| format!("built-in character {name}"))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let config = load_config(args.config.as_deref())?;
    let layout = match &args.layout {
        Some(path) => mouthpiece_synth::DotLayout::from_file(path).map_err(bad_input)?,
        None => mouthpiece_synth::DotLayout::default(),
    };
    mouthpiece_evaluate::check_layout(&layout, &config).map_err(to_anyhow)?;
    let character = match &args.character {
        Some(path) => load_character(path)?,
        None => builtin_wolf()?,
    };
    if !(args.seconds > 2.0 && args.seconds.is_finite()) {
        return Err(bad_input(anyhow::anyhow!(
            "--seconds must be more than 2 (the neutral pose takes the first 1.5 s)"
        )));
    }
    let view = session_view(args.size, args.distance)?;
    let mut frames_csv = match &args.rig_frames {
        Some(path) => Some(crate::cmd::evaluate_rig::FramesCsv::create(
            path,
            config.track.layout().lip_dots,
        )?),
        None => None,
    };
    println!("{TABLE_HEADER}");
    let mut steps = StepStats::default();
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
                        Motion::Fast => HeadMotion::Fast,
                    },
                    noise: match noise {
                        Noise::None => NoiseModel::None,
                        Noise::Kinect => NoiseModel::Kinect,
                        Noise::Realsense => NoiseModel::Realsense,
                    },
                    layout: layout.clone(),
                    camera: view.camera,
                    distance_m: view.distance_m,
                    jaw: args.jaw.options(),
                    ..SynthConfig::default()
                };
                let mut rig = RigAccuracy::new(
                    config.rig.clone(),
                    character.clone(),
                    config.track.layout(),
                    config.track.calibration_s,
                );
                if frames_csv.is_some() {
                    rig = rig.keep_frames();
                }
                let m = mouthpiece_evaluate::evaluate_with(
                    synth,
                    &config,
                    &character,
                    1.0,
                    &mut [&mut rig as &mut dyn Measure],
                )
                .map_err(to_anyhow)?;
                println!(
                    "| {seed} | {noise:?} | {motion:?} | {}",
                    mouthpiece_evaluate::table_cells(&m)
                );
                if args.per_dot {
                    print_per_dot(&m, config.track.layout());
                }
                if args.steps {
                    println!("\n{}", m.steps.table());
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
    if args.steps {
        println!("All sessions:\n\n{}", steps.table());
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
            assert!(
                err.chain().any(|e| e.is::<crate::exit::BadInput>()),
                "{err:#}"
            );
            assert!(
                format!("{err:#}").contains("--size / --distance"),
                "{err:#}"
            );
        }
    }

    /// A `--layout` that does not match the configuration's dots is a bad input (exit code
    /// 2), not a panic.
    #[test]
    fn a_layout_that_does_not_match_the_configuration_is_refused() {
        let layout = mouthpiece_synth::DotLayout {
            lip_dots: 8,
            ..Default::default()
        };
        let config = mouthpiece_pipeline::PipelineConfig::default();
        let err = mouthpiece_evaluate::check_layout(&layout, &config)
            .map_err(to_anyhow)
            .unwrap_err();
        assert!(
            err.chain().any(|e| e.is::<crate::exit::BadInput>()),
            "{err:#}"
        );
        assert!(format!("{err:#}").contains("track.lip_dots"), "{err:#}");
    }
}
