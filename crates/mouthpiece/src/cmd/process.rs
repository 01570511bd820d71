//! `mouthpiece process`: a recorded session → character mouth points (JSONL), offline.
//!
//! The whole pipeline (detect, track, calibrate, retarget) on every frame of the input, as
//! fast as the machine goes (unpaced). One output line per input frame: the `retarget` output
//! fields, plus `performer` (tracked dots, camera frame, metres, `null` when not seen),
//! `status` (calibrating, head_lost, dots_missing, no_dots, too_few_dots, …) and
//! `frame {seq, device_ts_us}`. A progress line on stderr when stderr is a terminal.

use std::io::{self, BufWriter, IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context as _;
use mouthpiece_capture::session_file::{SessionFile, SessionFileError};
use mouthpiece_frame::Frame;
use mouthpiece_pipeline::{Pipeline, PipelineConfig, RetargetSettings};
use mouthpiece_retarget::head::HeadLine;
use mouthpiece_retarget::{Character, ShapeSmoothing};
use mouthpiece_takes::read::RecordedHeads;

use crate::cmd::export::take_error;
use crate::cmd::retarget::Smooth;
use crate::exit::{bad_input, bad_input_if};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Recorded session: `.mcap` (mouthpiece's format) or `.oni` (OpenNI2).
    pub input: PathBuf,
    /// Character file (TOML).
    #[arg(long)]
    pub character: PathBuf,
    /// Configuration file (TOML): its `[detect]`, `[track]` and `[retarget]` tables are used.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Output JSONL, `-` for stdout.
    #[arg(long)]
    pub out: PathBuf,
    /// Shape smoothing that makes each line's `curve` (default: the configuration's
    /// `[retarget] smooth`, `bspline` without one).
    #[arg(long, value_parser = crate::cmd::retarget::smooth_arg())]
    pub smooth: Option<Smooth>,
    /// Threads OpenCV may use (0: its default). 1 measures one core.
    #[arg(long, default_value_t = 0)]
    pub opencv_threads: i32,
}

/// Loads the `[detect]`/`[track]`/`[retarget]` configuration (defaults without a file).
/// The daemon's loader: errors name the file, line and key.
pub fn load_config(path: Option<&Path>) -> anyhow::Result<PipelineConfig> {
    PipelineConfig::load(path).map_err(bad_input)
}

/// Loads a character file.
pub fn load_character(path: &Path) -> anyhow::Result<Character> {
    let text = mouthpiece_config::read_bounded(path, mouthpiece_config::MAX_CONFIG_FILE_BYTES)
        .with_context(|| format!("cannot read character file {}", path.display()))
        .map_err(bad_input)?;
    Character::from_toml_str(&text)
        .with_context(|| format!("character file {}", path.display()))
        .map_err(bad_input)
}

/// The shape smoothing `--smooth` names, with the configuration's default parameters
/// (`[retarget]`: moving averages over 1 neighbour, alpha 0.5, 8 B-spline samples a span).
pub(crate) fn smoothing(smooth: Smooth) -> ShapeSmoothing {
    RetargetSettings {
        smooth,
        ..RetargetSettings::default()
    }
    .smoothing()
}

/// A finite stream of frames from a recorded session (errors marked for the exit code).
pub struct Input(SessionFile);

fn session_error(e: SessionFileError) -> anyhow::Error {
    bad_input_if(e.is_bad_input(), e)
}

impl Input {
    /// Opens a session by its file extension.
    pub fn open(path: &Path) -> anyhow::Result<Self> {
        SessionFile::open(path).map(Input).map_err(session_error)
    }

    pub fn next_frame(&mut self) -> anyhow::Result<Option<Frame>> {
        self.0.next_frame().map_err(session_error)
    }

    /// The next frame and, from an MCAP file, its log time (ns).
    pub fn next_logged(&mut self) -> anyhow::Result<Option<(Frame, Option<u64>)>> {
        self.0.next_logged().map_err(session_error)
    }
}

/// What to process: a recording, the character, the `[detect]`/`[track]`/`[retarget]`
/// configuration, the shape smoothing (`None`: the configuration's) and OpenCV's thread count
/// (0: its default).
pub struct ProcessSetup<'a> {
    pub input: &'a Path,
    pub character: &'a Path,
    pub config: Option<&'a Path>,
    pub smooth: Option<Smooth>,
    pub opencv_threads: i32,
    /// A take's character head as the daemon recorded it (`/character/<name>`'s `head`, with
    /// the `look_at` turns made live) instead of the re-run's, where the take has one.
    pub recorded_heads: bool,
}

/// What one pass over a recording did.
#[derive(Debug, Clone, PartialEq)]
pub struct ProcessSummary {
    pub frames: u64,
    /// Wall-clock seconds of the pass (reading, pipeline, writing).
    pub seconds: f64,
    /// Session time at which the neutral pose was taken.
    pub calibrated_at: Option<f64>,
    pub frames_with_missing_dots: u64,
    pub pipeline_median_ms: f64,
    pub pipeline_p99_ms: f64,
    /// Frames whose character head is the one the take recorded (`recorded_heads`).
    pub recorded_heads: u64,
}

impl ProcessSummary {
    pub fn fps(&self) -> f64 {
        self.frames as f64 / self.seconds.max(1e-9)
    }

    /// Logs the summary (INFO) and a warning when no neutral pose was taken.
    pub fn log(&self) {
        tracing::info!(
            frames = self.frames,
            fps = format!("{:.1}", self.fps()),
            pipeline_median_ms = format!("{:.3}", self.pipeline_median_ms),
            pipeline_p99_ms = format!("{:.3}", self.pipeline_p99_ms),
            calibrated_at_s = ?self.calibrated_at,
            frames_with_missing_dots = self.frames_with_missing_dots,
            recorded_heads = self.recorded_heads,
            "process done"
        );
        if self.calibrated_at.is_none() && self.frames > 0 {
            tracing::warn!(
                "no neutral pose was taken: the session never showed every dot with a still, closed mouth \
                 for a second (see each line's status)"
            );
        }
    }
}

/// The whole pipeline over every frame of a recording, one JSONL line per frame to `out`
/// (flushed at the end). Used by `mouthpiece process` and by `mouthpiece export` of a
/// recording.
pub fn process_recording(
    setup: &ProcessSetup<'_>,
    out: &mut dyn Write,
) -> anyhow::Result<ProcessSummary> {
    let mut config = load_config(setup.config)?;
    let character = load_character(setup.character)?;
    if let Some(smooth) = setup.smooth {
        config.retarget.smooth = smooth;
    }
    let character_name = character.name.clone();
    let mut pipeline = Pipeline::for_characters(config, vec![character]).map_err(bad_input)?;
    if setup.opencv_threads > 0 {
        mouthpiece_detect::set_opencv_threads(setup.opencv_threads)?;
    }
    let mut input = Input::open(setup.input)?;
    let mut recorded = match (&input, setup.recorded_heads) {
        (Input(SessionFile::Mcap(_)), true) => Some(
            RecordedHeads::<HeadLine>::open(setup.input, &character_name).map_err(take_error)?,
        ),
        _ => None,
    };

    let progress = io::stderr().is_terminal().then(|| {
        let bar = indicatif::ProgressBar::new_spinner();
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{spinner} {pos} frames  {per_sec}  {elapsed}  {msg}",
            )
            .expect("valid template"),
        );
        bar
    });

    let started = Instant::now();
    let mut frames = 0u64;
    let mut calibrated_at = None;
    let mut frames_with_missing = 0u64;
    let mut pipeline_ms: Vec<f64> = Vec::new();
    let mut recorded_frames = 0u64;
    while let Some((frame, log_time)) = input
        .next_logged()
        .with_context(|| format!("reading {}", setup.input.display()))?
    {
        let tick = Instant::now();
        let (line, tracked) = pipeline
            .process(&frame)
            .with_context(|| format!("frame {}", frame.seq))?;
        pipeline_ms.push(tick.elapsed().as_secs_f64() * 1e3);
        let head = match (&mut recorded, log_time) {
            (Some(r), Some(t)) => r.at(t, checked_head).map_err(take_error)?,
            _ => None,
        };
        if let Some(head) = head {
            let mut value = serde_json::to_value(&line).context("cannot write output")?;
            value["character_head"] = serde_json::to_value(head).context("cannot write output")?;
            serde_json::to_writer(&mut *out, &value).context("cannot write output")?;
            recorded_frames += 1;
        } else {
            serde_json::to_writer(&mut *out, &line).context("cannot write output")?;
        }
        out.write_all(b"\n").context("cannot write output")?;
        if tracked.status.neutral_taken && calibrated_at.is_none() {
            calibrated_at = Some(tracked.t);
        }
        frames_with_missing += !tracked.status.dots_missing.is_empty() as u64;
        frames += 1;
        if let Some(bar) = &progress {
            bar.set_position(frames);
            if frames.is_multiple_of(15) {
                bar.set_message(if tracked.status.calibrating {
                    "calibrating"
                } else {
                    "tracking"
                });
            }
        }
    }
    out.flush().context("cannot write output")?;
    if frames == 0 {
        return Err(bad_input(anyhow::anyhow!(
            "{}: no frames (an empty recording, or one cut before its first frame)",
            setup.input.display()
        )));
    }
    if let Some(bar) = progress {
        bar.finish_and_clear();
    }
    let seconds = started.elapsed().as_secs_f64();
    pipeline_ms.sort_by(f64::total_cmp);
    let pct = |q: f64| {
        pipeline_ms
            .get(((pipeline_ms.len().max(1) - 1) as f64 * q).round() as usize)
            .copied()
            .unwrap_or(0.0)
    };
    Ok(ProcessSummary {
        frames,
        seconds,
        calibrated_at,
        frames_with_missing_dots: frames_with_missing,
        pipeline_median_ms: pct(0.5),
        pipeline_p99_ms: pct(0.99),
        recorded_heads: recorded_frames,
    })
}

/// A daemon's take's recorded head (`export` of a take: the re-run tracker knows nothing of
/// the `look_at` requests made live over the WebSocket, the recorded head has their turns),
/// its rotations finite, made unit again in 64 bits (they were recorded as 32-bit floats).
fn checked_head(mut h: HeadLine) -> Result<HeadLine, &'static str> {
    for q in [&mut h.rotation, &mut h.eye_left, &mut h.eye_right] {
        if !q.iter().all(|c| c.is_finite()) {
            return Err("the head's rotations are not finite");
        }
        let n = q.iter().map(|c| c * c).sum::<f64>().sqrt();
        if n > 0.0 {
            q.iter_mut().for_each(|c| *c /= n);
        }
    }
    Ok(h)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let setup = ProcessSetup {
        input: &args.input,
        character: &args.character,
        config: args.config.as_deref(),
        smooth: args.smooth,
        opencv_threads: args.opencv_threads,
        recorded_heads: false,
    };
    if args.out.as_os_str() == "-" {
        let mut out = BufWriter::new(io::stdout().lock());
        let summary = process_recording(&setup, &mut out)?;
        summary.log();
        return Ok(());
    }
    // A file is written beside its destination and renamed into place only when complete.
    let mut out = mouthpiece_export::PendingFile::create(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))
        .map_err(bad_input)?;
    let summary = process_recording(&setup, &mut out)?;
    out.commit()
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    summary.log();
    Ok(())
}
