//! `mouthpiece lipsync poses SESSION --marks FILE`: a booth's own basic poses, captured from a
//! recorded session in which the actor holds each pose. The whole camera pipeline (detect,
//! track, calibrate, head-motion removal) runs over the session; for each pose, the lip dots
//! in the neutral mouth frame are averaged over the frames inside its marked time range (every
//! lip dot seen), and the pose is that mean minus the neutral `D⁰`. The neutral is the
//! tracker's calibration (the still, closed mouth at the start of the session).
//!
//! Marks (TOML): one `name = [start_s, end_s]` per pose, session seconds:
//! ```toml
//! closed = [2.0, 2.6]
//! open = [3.0, 3.6]
//! ```

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context as _;
use mouthpiece_lipsync::poses::Pose;
use mouthpiece_lipsync::BasicPoses;
use mouthpiece_retarget::{Character, CharacterSettings, Vec3};
use mouthpiece_track::pipeline::Pipeline;

use crate::cmd::process::{load_config, Input};
use crate::exit::bad_input;

/// The shipped human character: the pipeline needs one; its output is not used here.
const HUMAN: &str = include_str!("../../../../config/characters/human.toml");

#[derive(Debug, clap::Args)]
pub struct PosesArgs {
    /// Recorded session (`.mcap` or `.oni`) with the actor holding each pose.
    pub session: PathBuf,
    /// Marks (TOML): `name = [start_s, end_s]` per pose.
    #[arg(long)]
    pub marks: PathBuf,
    /// Output pose file (TOML, the format of config/lipsync/poses.toml).
    #[arg(long)]
    pub out: PathBuf,
    /// Configuration file (TOML): its `[detect]` and `[track]` tables.
    #[arg(long)]
    pub config: Option<PathBuf>,
}

/// Parses marks: `name = [start, end]`, start < end, finite.
pub fn parse_marks(text: &str, source_name: &str) -> anyhow::Result<Vec<(String, f64, f64)>> {
    let table: BTreeMap<String, [f64; 2]> = toml::from_str(text)
        .with_context(|| format!("{source_name}: expected `name = [start_s, end_s]` per pose"))
        .map_err(bad_input)?;
    if table.is_empty() {
        return Err(bad_input(anyhow::anyhow!("{source_name}: no poses marked")));
    }
    table
        .into_iter()
        .map(|(name, [a, b])| {
            if !(a.is_finite() && b.is_finite() && a < b) {
                return Err(bad_input(anyhow::anyhow!(
                    "{source_name}: {name}: the range must be [start, end] with start < end, got [{a}, {b}]"
                )));
            }
            Ok((name, a, b))
        })
        .collect()
}

/// Captures the poses (see the module docs).
pub fn capture(
    session: &Path,
    marks: &[(String, f64, f64)],
    config: Option<&Path>,
) -> anyhow::Result<BasicPoses> {
    let config = load_config(config)?;
    let character = Character::from_toml_str(HUMAN).context("the built-in human character")?;
    let mut pipeline =
        Pipeline::new(config, character, CharacterSettings::default()).map_err(bad_input)?;
    let mut input = Input::open(session)?;
    let mut sums: Vec<(Vec<Vec3>, usize)> = Vec::new();
    while let Some(frame) = input
        .next_frame()
        .with_context(|| format!("reading {}", session.display()))?
    {
        let (_, tracked) = pipeline
            .process(&frame)
            .with_context(|| format!("frame {}", frame.seq))?;
        let Some(stabilised) = &tracked.stabilised else {
            continue;
        };
        if stabilised.confidence.iter().any(|&c| c < 1.0) {
            continue;
        }
        if sums.is_empty() {
            sums = vec![(vec![Vec3::zeros(); stabilised.lip.len()], 0); marks.len()];
        }
        for (k, (_, a, b)) in marks.iter().enumerate() {
            if (*a..=*b).contains(&tracked.t) {
                for (s, d) in sums[k].0.iter_mut().zip(&stabilised.lip) {
                    *s += d;
                }
                sums[k].1 += 1;
            }
        }
    }
    let neutral = pipeline.tracker().neutral().ok_or_else(|| {
        bad_input(anyhow::anyhow!(
            "{}: no neutral pose was taken (the session must start with a still, closed mouth)",
            session.display()
        ))
    })?;
    let arr = |p: &Vec3| [p.x, p.y, p.z];
    let mut poses = Vec::with_capacity(marks.len());
    for (k, (name, a, b)) in marks.iter().enumerate() {
        let (sum, n) = sums.get(k).cloned().unwrap_or_default();
        if n == 0 {
            return Err(bad_input(anyhow::anyhow!(
                "{}: pose {name:?}: no frame within [{a}, {b}] s with every lip dot seen",
                session.display()
            )));
        }
        poses.push(Pose {
            name: name.clone(),
            displacement: sum
                .iter()
                .zip(&neutral.lip)
                .map(|(s, d0)| arr(&(s / n as f64 - d0)))
                .collect(),
            mouth: BTreeMap::new(),
        });
        tracing::info!(pose = %name, frames = n, "pose captured");
    }
    let forehead: Vec<[f64; 3]> = neutral
        .forehead_camera
        .iter()
        .flatten()
        .map(|p| arr(&neutral.frame.to_mouth(p)))
        .collect();
    Ok(BasicPoses {
        neutral_lip: neutral.lip.iter().map(arr).collect(),
        forehead,
        poses,
    })
}

pub fn run(args: PosesArgs) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(&args.marks)
        .with_context(|| format!("cannot read marks {}", args.marks.display()))
        .map_err(bad_input)?;
    let marks = parse_marks(&text, &args.marks.display().to_string())?;
    let poses = capture(&args.session, &marks, args.config.as_deref())?;
    let text = poses.to_toml_string(&format!(
        "Basic lip poses captured from {} (marks {}): performer mouth frame, metres.",
        args.session.display(),
        args.marks.display()
    ));
    let mut f = mouthpiece_export::PendingFile::create(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))
        .map_err(bad_input)?;
    f.write_all(text.as_bytes())
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    f.commit()
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    Ok(())
}
