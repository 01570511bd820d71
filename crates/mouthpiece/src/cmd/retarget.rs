//! `mouthpiece retarget`: 3D dots (JSONL) → character mouth points (JSONL). The flags are
//! here; the files are [`mouthpiece_export::retarget_files`]'s, the lines
//! [`mouthpiece_retarget::batch`]'s.

use std::path::PathBuf;

use anyhow::Context as _;
use mouthpiece_export::retarget_files::retarget_files;
use mouthpiece_pipeline::RetargetSettings;
use mouthpiece_retarget::{CharacterSettings, MissingDots, OneEuroParams, RetargetConfig};

use crate::exit::{bad_input, bad_input_if};

/// The shape smoothing: one enum for the configuration's `[retarget] smooth` and `--smooth`.
pub use mouthpiece_pipeline::Smooth;

/// `--smooth`: the names of [`Smooth::ALL`], listed in `--help`.
pub fn smooth_arg() -> impl clap::builder::TypedValueParser<Value = Smooth> {
    use clap::builder::TypedValueParser as _;
    clap::builder::PossibleValuesParser::new(Smooth::ALL.map(|(name, _)| name))
        .map(|name| Smooth::from_name(&name).expect("a listed name"))
}

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Character file (TOML).
    #[arg(long)]
    pub character: PathBuf,
    /// Input JSONL, `-` for stdin.
    #[arg(long)]
    pub input: PathBuf,
    /// Output JSONL, `-` for stdout.
    #[arg(long)]
    pub out: PathBuf,
    /// Shape smoothing that makes each line's `curve`.
    #[arg(long, value_parser = smooth_arg(), default_value = "bspline")]
    pub smooth: Smooth,
    /// Moving average: neighbours on each side.
    #[arg(long, default_value_t = 1)]
    pub ma_radius: usize,
    /// Exponential moving average: weight factor per step along the loop, in (0, 1].
    #[arg(long, default_value_t = 0.5)]
    pub ma_alpha: f64,
    /// B-spline: curve samples per span (per character point).
    #[arg(long, default_value_t = 8)]
    pub samples_per_span: usize,
    /// Temporal One Euro filter on the output points: `MINCUTOFF,BETA` (Hz, s/unit).
    /// Off unless given.
    #[arg(long, value_name = "MINCUTOFF,BETA", value_parser = parse_one_euro)]
    pub one_euro: Option<OneEuroParams>,
    /// Seconds a missing lip dot keeps its last value (confidence 0).
    #[arg(long, default_value_t = 0.5, value_parser = parse_seconds)]
    pub hold: f64,
    /// Seconds over which a missing dot then returns to neutral.
    #[arg(long, default_value_t = 0.5, value_parser = parse_seconds)]
    pub decay: f64,
    /// Turn the character's head to a viewpoint `X,Y,Z` (character model frame) from the
    /// first line at time `T` on (`X,Y,Z@T`; from the start without `@T`). Without it the
    /// head follows the performer's (docs/head.md).
    #[arg(long, value_name = "X,Y,Z[@T]", value_parser = parse_look_at)]
    pub look_at: Option<LookAt>,
}

/// `--look-at`: a viewpoint and when it is set.
pub use mouthpiece_retarget::batch::{LookAt, MAX_LOOK_AT_T};

/// Parses `X,Y,Z` or `X,Y,Z@T`.
pub fn parse_look_at(s: &str) -> Result<LookAt, String> {
    let (xyz, from_t) = match s.split_once('@') {
        Some((xyz, t)) => {
            let t: f64 = t.trim().parse().map_err(|e| format!("time `{t}`: {e}"))?;
            if !(t.is_finite() && t.abs() <= MAX_LOOK_AT_T) {
                return Err(format!(
                    "time `{t}` is not a number of seconds within ±{MAX_LOOK_AT_T:e}"
                ));
            }
            (xyz, t)
        }
        None => (s, f64::NEG_INFINITY),
    };
    let parts: Vec<&str> = xyz.split(',').collect();
    if parts.len() != 3 {
        return Err("expected X,Y,Z or X,Y,Z@T, e.g. 0,0.1,2@1.5".into());
    }
    let mut point = [0.0; 3];
    for (dst, part) in point.iter_mut().zip(&parts) {
        let v: f64 = part
            .trim()
            .parse()
            .map_err(|e| format!("coordinate `{part}`: {e}"))?;
        if !v.is_finite() {
            return Err(format!("coordinate `{part}` is not finite"));
        }
        *dst = v;
    }
    Ok(LookAt { point, from_t })
}

/// A duration flag: a finite number of seconds, 0 or more (checked with the other flags,
/// before any input is read).
fn parse_seconds(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if MissingDots::valid_seconds(v) => Ok(v),
        _ => Err(format!(
            "`{s}` is not a number of seconds within 0 to {}",
            MissingDots::MAX_SECONDS
        )),
    }
}

fn parse_one_euro(s: &str) -> Result<OneEuroParams, String> {
    let (a, b) = s
        .split_once(',')
        .ok_or("expected MINCUTOFF,BETA, e.g. 1.0,0.007")?;
    let min_cutoff: f64 = a
        .trim()
        .parse()
        .map_err(|e| format!("MINCUTOFF `{a}`: {e}"))?;
    let beta: f64 = b.trim().parse().map_err(|e| format!("BETA `{b}`: {e}"))?;
    OneEuroParams::new(min_cutoff, beta).map_err(|e| e.to_string())
}

impl Args {
    fn config(&self) -> anyhow::Result<RetargetConfig> {
        // The one mapping from the option to the shape smoothing: the configuration's.
        let smoothing = RetargetSettings {
            smooth: self.smooth,
            ma_radius: self.ma_radius,
            ma_alpha: self.ma_alpha,
            samples_per_span: self.samples_per_span,
            one_euro: None,
        }
        .smoothing();
        smoothing.validate().map_err(bad_input)?;
        Ok(RetargetConfig {
            missing: MissingDots {
                hold: self.hold,
                decay: self.decay,
            },
            character: CharacterSettings {
                smoothing,
                one_euro: self.one_euro,
            },
        })
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let config = args.config()?;
    let character = crate::cmd::process::load_character(&args.character)?;
    tracing::info!(character = %character.name, points = character.len(), "character loaded");
    if let Some(look) = &args.look_at {
        let in_reach = character
            .head_driver()
            .look_at(Some(look.point.into()))
            .with_context(|| format!("--look-at for character {}", character.name))
            .map_err(bad_input)?;
        tracing::info!(point = ?look.point, in_reach, "viewpoint");
    }
    let lines = retarget_files(&args.input, &args.out, character, config, args.look_at)
        .map_err(|e| bad_input_if(e.is_bad_input(), e))?;
    if let Some(lines) = lines {
        tracing::info!(lines, "retarget done");
    }
    Ok(())
}
