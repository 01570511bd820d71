//! `mouthpiece lipsync poses SESSION --marks FILE`: a booth's own basic poses, captured from a
//! recorded session in which the actor holds each pose. The whole camera pipeline (detect,
//! track, calibrate, head-motion removal) runs over the session; for each pose, each lip dot
//! in the neutral mouth frame is averaged over the frames inside the pose's marked time range
//! in which that dot is seen, and the pose is that mean minus the neutral `D⁰`. The neutral is
//! the tracker's calibration (the still, closed mouth at the start of the session). A dot
//! never seen during a pose (a lower lip rolled in hides its dots) is an error naming the pose
//! and the dot: such poses cannot be captured by the camera and are kept from the defaults.
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
use mouthpiece_pipeline::Pipeline;
use mouthpiece_retarget::{Character, CharacterSettings, Vec3};

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
    // Per pose: per dot (sum, frames seen).
    let mut sums: Vec<Vec<(Vec3, usize)>> = Vec::new();
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
        if sums.is_empty() {
            sums = vec![vec![(Vec3::zeros(), 0); stabilised.lip.len()]; marks.len()];
        }
        for (k, (_, a, b)) in marks.iter().enumerate() {
            if (*a..=*b).contains(&tracked.t) {
                for ((s, n), (d, &c)) in sums[k]
                    .iter_mut()
                    .zip(stabilised.lip.iter().zip(&stabilised.confidence))
                {
                    if c >= 1.0 {
                        *s += d;
                        *n += 1;
                    }
                }
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
        let dots = sums
            .get(k)
            .cloned()
            .unwrap_or_else(|| vec![(Vec3::zeros(), 0); neutral.lip.len()]);
        let mut displacement = Vec::with_capacity(dots.len());
        for (d, ((sum, n), d0)) in dots.iter().zip(&neutral.lip).enumerate() {
            if *n == 0 {
                return Err(bad_input(anyhow::anyhow!(
                    "{}: pose {name:?}: dot D{} is not seen within [{a}, {b}] s",
                    session.display(),
                    d + 1
                )));
            }
            displacement.push(arr(&(sum / *n as f64 - d0)));
        }
        let frames = dots.iter().map(|(_, n)| *n).min().unwrap_or(0);
        poses.push(Pose {
            name: name.clone(),
            displacement,
            mouth: BTreeMap::new(),
        });
        tracing::info!(pose = %name, frames, "pose captured");
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
    let text = crate::cmd::lipsync::read_text(
        &args.marks,
        "marks",
        crate::cmd::lipsync::MAX_TABLE_FILE_BYTES,
    )?;
    let marks = mouthpiece_lipsync::poses::parse_marks(&text, &args.marks.display().to_string())
        .map_err(bad_input)?;
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
