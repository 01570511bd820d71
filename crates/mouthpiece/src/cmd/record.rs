//! `mouthpiece record`: any source to an MCAP session, an OpenNI2 source also to `.oni`.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use anyhow::Context;
use mouthpiece_capture::record_job::{self, AudioRequest, RecordJob};

use crate::exit::{bad_input, bad_input_if};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// What to record: replay:FILE[?loop=1&speed=1.0&start=S], `openni2:[URI]`,
    /// v4l2:COLOUR[+DEPTH].
    #[arg(long)]
    pub source: String,
    /// Output file: .mcap or .oni (OpenNI2 sources through OpenNI2's recorder, others through
    /// mouthpiece's writer: registered, undistorted, centred cameras only).
    #[arg(long)]
    pub out: PathBuf,
    /// Stop after this many seconds of device time (default: until Ctrl-C or the end of a replay).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Colour in MCAP: raw (lossless BGR, the default: the detector sees what the camera saw)
    /// or `jpeg[:QUALITY]`.
    #[arg(long, default_value = "raw")]
    pub color: String,
    /// Also record the sound of this ALSA capture device (PCM name, e.g. `default` or
    /// `hw:1,0`) to `/audio` (MCAP only); frames and sound are then stamped on the host clock.
    #[arg(long)]
    pub audio: Option<String>,
    /// The sample rate to ask the --audio device for (it may agree to another: the file
    /// holds what it delivered).
    #[arg(long, default_value_t = 48_000, requires = "audio")]
    pub audio_rate: u32,
    /// The channels to ask the --audio device for, 1 to 32.
    #[arg(long, default_value_t = 1, requires = "audio")]
    pub audio_channels: u16,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let audio = match &args.audio {
        Some(device) => {
            // The string reaches alsa-lib, whose `file` plugin can write a file or run a command.
            mouthpiece_config::check_alsa_device(device, false)
                .map_err(|e| bad_input(anyhow::anyhow!("--audio: {e}")))?;
            Some(AudioRequest {
                device: device.clone(),
                rate: args.audio_rate,
                channels: args.audio_channels,
            })
        }
        None => None,
    };
    let job = RecordJob {
        source: args.source,
        out: args.out.clone(),
        seconds: args.seconds,
        color: args.color,
        audio,
    };
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed))
        .context("cannot install the Ctrl-C handler")?;
    let started = Instant::now();
    let mut last_report = Instant::now();
    let mut count = 0u64;
    let progress = |_: &mouthpiece_capture::Frame| {
        count += 1;
        if last_report.elapsed().as_secs() >= 5 {
            last_report = Instant::now();
            tracing::info!(frames = count, "recording");
        }
    };
    let summary =
        record_job::record(&job, stop, progress).map_err(|e| bad_input_if(e.is_bad_input(), e))?;
    eprintln!(
        "recorded {} frames ({:.1} s of device time, {} skipped) to {} in {:.1} s{}",
        summary.frames,
        summary.duration_s,
        summary.skipped,
        args.out.display(),
        started.elapsed().as_secs_f64(),
        if summary.oni_fixed_nodes > 0 {
            format!(
                "; added the cropping records OpenNI2's player needs to {} streams",
                summary.oni_fixed_nodes
            )
        } else {
            String::new()
        }
    );
    if let Some(reason) = &summary.sound_lost {
        eprintln!(
            "the sound stopped before the end (the file keeps the video and says where, on /audio/events): {reason}"
        );
    }
    if let Some(lost) = summary.lost {
        anyhow::bail!(
            "the source was lost while recording (the file keeps what came before): {lost}"
        );
    }
    Ok(())
}
