//! `mouthpiece play`: a take (a daemon's `.mcap` take as recorded live, or JSONL from
//! `process`, `retarget` or `lipsync`) sent over the VMC
//! protocol as the daemon sends a live character (docs/osc.md): the rig's curves, the VRM
//! visemes, the head and the eyes, each frame at its time. A speech-driven take and a camera
//! take drive an avatar app alike.

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context as _};
use mouthpiece_export::{ExportError, TakeReader};
use mouthpiece_osc::{VmcFrame, VmcSender};
use mouthpiece_output::{visemes_from, CurveNaming, RigCurves, RigVisemes, VisemeNaming};

use crate::cmd::export::{export_error, recording_as_take};
use crate::cmd::process::load_character;
use crate::exit::bad_input;

/// Slowest `--speed` (a hundredth of the take's own pace).
pub const MIN_SPEED: f64 = 0.01;
/// Fastest `--speed`.
pub const MAX_SPEED: f64 = 1000.0;
/// Longest time between two lines of a take that `play` waits through, seconds of the take:
/// a live take has a line per frame, so a longer gap is a broken or hostile file, refused at
/// its line rather than waited on for years.
pub const MAX_GAP_S: f64 = 60.0;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The take: a daemon's take (.mcap: the steps as they went out live), JSONL from
    /// `mouthpiece process`, `retarget` or `lipsync`, or a recording (.mcap, .oni) to process
    /// first.
    pub take: PathBuf,
    /// A daemon's take: track its camera images again (built-in configuration) instead of
    /// sending the steps it recorded live.
    #[arg(long)]
    pub reprocess: bool,
    /// The take's character file (TOML): its head frame orients the head and eye bones.
    #[arg(long)]
    pub character: PathBuf,
    /// Where to send, `host:port` (UDP); repeat for several receivers.
    #[arg(long = "osc", value_name = "HOST:PORT", required = true)]
    pub targets: Vec<String>,
    /// Curve names: `arkit` (jawOpen) or `arkit-pascal` (JawOpen).
    #[arg(long, value_parser = naming::<CurveNaming>, default_value = "arkit")]
    pub names: CurveNaming,
    /// Visemes sent: `vrm0` (A I U E O), `vrm1` (aa ih ou ee oh) or `none`.
    #[arg(long, value_parser = naming::<VisemeNaming>, default_value = "vrm0")]
    pub visemes: VisemeNaming,
    /// Do not send the head bone.
    #[arg(long)]
    pub no_head: bool,
    /// Do not send the eye bones.
    #[arg(long)]
    pub no_eyes: bool,
    /// Playback speed: 1 is the take's own timing, 2 twice as fast (0.01 to 1000).
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
}

/// The configuration file's names for the naming options (`[osc] names`, `visemes`).
fn naming<T: serde::de::DeserializeOwned>(s: &str) -> Result<T, String> {
    T::deserialize(serde::de::value::StrDeserializer::<serde::de::value::Error>::new(s))
        .map_err(|e| e.to_string())
}

fn resolve(text: &str) -> anyhow::Result<SocketAddr> {
    let target: mouthpiece_config::OscTarget = text
        .parse()
        .map_err(|e: String| bad_input(anyhow!("--osc: {e}")))?;
    target
        .resolve()
        .map_err(|e| bad_input(anyhow!("--osc: {e}")))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if !(MIN_SPEED..=MAX_SPEED).contains(&args.speed) {
        return Err(bad_input(anyhow!(
            "--speed must be from {MIN_SPEED} to {MAX_SPEED}, got {}",
            args.speed
        )));
    }
    let targets = args
        .targets
        .iter()
        .map(|t| resolve(t))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let character = load_character(&args.character)?;
    let is_recording = args
        .take
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap") || e.eq_ignore_ascii_case("oni"));
    let (name, input): (String, Box<dyn BufRead>) = if is_recording {
        let take = recording_as_take(
            &args.take,
            &args.character,
            None,
            args.reprocess,
            &std::env::temp_dir(),
        )?;
        (take.name, take.reader)
    } else {
        let name = args.take.display().to_string();
        let file = File::open(&args.take)
            .with_context(|| format!("cannot open take {name}"))
            .map_err(bad_input)?;
        (name, Box::new(BufReader::new(file)))
    };
    let mut reader = TakeReader::with_points(input, name.clone(), character.point_names.clone());
    let mut sender = VmcSender::new(
        &targets,
        &character.frame.axes,
        !args.no_head,
        !args.no_eyes,
        args.names,
        args.visemes,
    )
    .context("cannot open a UDP socket")?;
    let mut start: Option<(Instant, f64)> = None;
    let mut previous_t = None;
    let mut frames = 0u64;
    while let Some(frame) = reader.next_frame().map_err(export_error)? {
        if frames == 0 {
            reader.check_character(&character.name).map_err(bad_input)?;
        }
        // The reader has checked that `t` is finite and increasing; the gap is bounded here,
        // so every wait below is a few hours at most.
        if let Some(previous) = previous_t.replace(frame.t) {
            if frame.t - previous > MAX_GAP_S {
                return Err(bad_input(anyhow!(
                    "{name} line {}: t is {} s after the previous line's, more than the {MAX_GAP_S} s \
                     play waits between two lines",
                    frame.line,
                    frame.t - previous
                )));
            }
        }
        // Each frame at its time from the first, divided by the speed; a late frame goes at
        // once (the receiver sees the take's times in /VMC/Ext/T either way).
        let (t0_wall, t0) = *start.get_or_insert((Instant::now(), frame.t));
        let due = Duration::try_from_secs_f64(((frame.t - t0) / args.speed).max(0.0))
            .ok()
            .and_then(|offset| t0_wall.checked_add(offset))
            .ok_or_else(|| {
                bad_input(anyhow!(
                    "{name} line {}: t = {} is too far from the first line's",
                    frame.line,
                    frame.t
                ))
            })?;
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        sender.send(&vmc_frame(&frame));
        frames += 1;
    }
    if frames == 0 {
        return Err(bad_input(ExportError::EmptyTake { source_name: name }));
    }
    eprintln!(
        "sent {frames} frames of {name} to {}: {} datagrams, {} refused",
        args.targets.join(", "),
        sender.sent,
        sender.errors
    );
    Ok(())
}

/// A take frame as the live output sends it: without a rig (before the neutral pose) every
/// curve and viseme at rest; without a head, identities.
fn vmc_frame(frame: &mouthpiece_export::TakeFrame) -> VmcFrame {
    let f32s = |q: [f64; 4]| q.map(|v| v as f32);
    let head = frame.head.unwrap_or(mouthpiece_export::HeadKeys::REST);
    VmcFrame {
        t: frame.t,
        curves: frame.rig.map(|r| RigCurves(r.curves.map(|v| v as f32))),
        visemes: frame
            .rig
            .map(|r| RigVisemes(visemes_from(&r.curves).map(|v| v as f32))),
        head: f32s(head.head),
        eye_left: f32s(head.eye_left),
        eye_right: f32s(head.eye_right),
        // A take line does not say what drove it live.
        source: mouthpiece_output::MouthSource::Camera,
    }
}
