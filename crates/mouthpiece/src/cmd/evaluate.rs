//! `mouthpiece evaluate`: renders synthetic sessions and measures the pipeline on them
//! against their ground truth (the sweep, the figures and their definitions:
//! `mouthpiece_evaluate::sweep`), printing one table row per session.

use anyhow::Context as _;
use std::path::PathBuf;

use mouthpiece_evaluate::sweep::{self, SweepOptions};
use mouthpiece_synth::{HeadMotion, NoiseModel};

use crate::cmd::process::{load_character, load_config};
use crate::exit::{bad_input, bad_input_if};

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

/// The built-in wolf the daemon drives by default.
fn builtin_wolf() -> anyhow::Result<mouthpiece_retarget::Character> {
    let (name, text) = mouthpiece_pipeline::setup::BUILTIN
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
    let character = match &args.character {
        Some(path) => load_character(path)?,
        None => builtin_wolf()?,
    };
    let options = SweepOptions {
        config,
        character,
        layout,
        seeds: args.seeds,
        noises: args
            .noise
            .iter()
            .map(|n| match n {
                Noise::None => NoiseModel::None,
                Noise::Kinect => NoiseModel::Kinect,
                Noise::Realsense => NoiseModel::Realsense,
            })
            .collect(),
        motions: args
            .head_motion
            .iter()
            .map(|m| match m {
                Motion::None => HeadMotion::None,
                Motion::Mild => HeadMotion::Mild,
                Motion::Strong => HeadMotion::Strong,
                Motion::Fast => HeadMotion::Fast,
            })
            .collect(),
        seconds: args.seconds,
        size: args.size,
        distance: args.distance,
        jaw: args.jaw.options(),
        per_dot: args.per_dot,
        steps: args.steps,
        per_curve: args.per_curve,
        rig_frames: args.rig_frames,
    };
    sweep::run(&options, &mut std::io::stdout().lock())
        .map_err(|e| bad_input_if(e.is_bad_input(), e))
}
