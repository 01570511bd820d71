//! `mouthpiece play`: a take (a daemon's `.mcap` take as recorded live, or JSONL from
//! `process`, `retarget` or `lipsync`) sent over the VMC
//! protocol as the daemon sends a live character (docs/osc.md): the rig's curves, the VRM
//! visemes, the head and the eyes, each frame at its time. A speech-driven take and a camera
//! take drive an avatar app alike.

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{anyhow, Context as _};
use mouthpiece_export::{ExportError, PlayClock, TakeReader};
use mouthpiece_osc::{VmcFrame, VmcSender};
use mouthpiece_output::{CurveNaming, VisemeNaming};

use crate::cmd::export::{export_error, recording_as_take};
use crate::cmd::process::load_character;
use crate::exit::bad_input;

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
    PlayClock::check_speed(args.speed).map_err(bad_input)?;
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
    let mut clock = PlayClock::new(args.speed, name.clone()).map_err(bad_input)?;
    let mut start: Option<Instant> = None;
    let mut frames = 0u64;
    while let Some(frame) = reader.next_frame().map_err(export_error)? {
        if frames == 0 {
            reader.check_character(&character.name).map_err(bad_input)?;
        }
        // A late frame goes at once (the receiver sees the take's times in /VMC/Ext/T either
        // way); the clock has bounded every wait.
        let due = clock.due(&frame).map_err(bad_input)?;
        let t0_wall = *start.get_or_insert_with(Instant::now);
        if let Some(wait) = (t0_wall + due).checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        sender.send(&VmcFrame::from(&frame));
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
