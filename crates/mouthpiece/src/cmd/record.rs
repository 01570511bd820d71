//! `mouthpiece record`: any source to an MCAP session, an OpenNI2 source also to `.oni`.

use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::time::Instant;

use anyhow::Context;
use mouthpiece_capture::record::{self, OutputFormat, RecordError, RecordLimits};
use mouthpiece_capture::{CaptureConfig, SourceError, SourceSpec};
use mouthpiece_recording::{ColorEncoding, WriterOptions};

use crate::exit::bad_input;

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

/// Opens the `--audio` device before anything is recorded: a device that cannot be opened is
/// bad input (exit 2) and no file is written.
fn open_audio(args: &Args) -> anyhow::Result<Option<Box<dyn mouthpiece_frame::AudioSource>>> {
    let Some(device) = &args.audio else {
        return Ok(None);
    };
    if !(8_000..=192_000).contains(&args.audio_rate) {
        return Err(bad_input(anyhow::anyhow!(
            "--audio-rate {}: expected 8000 to 192000 Hz",
            args.audio_rate
        )));
    }
    if !(1..=32).contains(&args.audio_channels) {
        return Err(bad_input(anyhow::anyhow!(
            "--audio-channels {}: expected 1 to 32",
            args.audio_channels
        )));
    }
    // The string reaches alsa-lib, whose `file` plugin can write a file or run a command.
    mouthpiece_config::check_alsa_device(device, false)
        .map_err(|e| bad_input(anyhow::anyhow!("--audio: {e}")))?;
    let request = mouthpiece_capture::alsa::AlsaRequest {
        device: device.clone(),
        sample_rate: args.audio_rate,
        channels: args.audio_channels,
        // 10 ms periods, 200 ms of buffer, as the daemon's defaults.
        period_frames: (args.audio_rate / 100).max(1),
        buffer_frames: (args.audio_rate / 5).max(2),
        stall_timeout: std::time::Duration::from_secs(2),
    };
    let source = mouthpiece_capture::alsa::AlsaSource::open(&request).map_err(|e| {
        bad_input(anyhow::Error::new(e).context(format!(
            "--audio {}: cannot record from this ALSA device",
            cut(device)
        )))
    })?;
    Ok(Some(Box::new(source)))
}

/// `s` cut to about 80 characters for an error message.
fn cut(s: &str) -> String {
    if s.chars().count() <= 80 {
        s.to_owned()
    } else {
        format!("{}…", s.chars().take(80).collect::<String>())
    }
}

fn parse_color(s: &str) -> anyhow::Result<ColorEncoding> {
    match s.split_once(':') {
        None if s == "raw" => Ok(ColorEncoding::Raw),
        None if s == "jpeg" => Ok(ColorEncoding::Jpeg { quality: 90 }),
        Some(("jpeg", q)) => match q.parse::<u8>() {
            Ok(quality @ 1..=100) => Ok(ColorEncoding::Jpeg { quality }),
            _ => anyhow::bail!("--color jpeg:{q}: quality must be 1 to 100"),
        },
        _ => anyhow::bail!("--color {s:?}: expected raw, jpeg or jpeg:QUALITY"),
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let spec = SourceSpec::parse(&args.source).map_err(bad_input)?;
    let format = OutputFormat::from_path(&args.out).map_err(bad_input)?;
    let color = parse_color(&args.color).map_err(bad_input)?;
    if let Some(s) = args.seconds {
        if !(s > 0.0 && s.is_finite()) {
            return Err(bad_input(anyhow::anyhow!(
                "--seconds {s}: expected a positive number"
            )));
        }
    }
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        if !dir.is_dir() {
            return Err(bad_input(anyhow::anyhow!(
                "--out {}: directory {} does not exist",
                args.out.display(),
                dir.display()
            )));
        }
    }
    if args.audio.is_some() && format != OutputFormat::Mcap {
        return Err(bad_input(anyhow::anyhow!(
            "--audio needs an .mcap --out ({} cannot hold sound)",
            args.out.display()
        )));
    }
    let audio = open_audio(&args)?;
    let limits = RecordLimits {
        seconds: args.seconds,
        ..Default::default()
    };
    let stop = limits.stop.clone();
    ctrlc::set_handler(move || stop.store(true, Ordering::Relaxed))
        .context("cannot install the Ctrl-C handler")?;

    let config = CaptureConfig::default();
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
    let result = match format {
        OutputFormat::Mcap => {
            let options = WriterOptions {
                color,
                ..Default::default()
            };
            record::record_mcap_with_audio(
                &spec, &config, &args.out, options, &limits, audio, progress,
            )
        }
        OutputFormat::Oni => record::record_oni(&spec, &config, &args.out, &limits, progress),
    };
    let summary = result.map_err(|err| match err {
        // The user named something that cannot work: exit code 2.
        RecordError::OniUnsupported(_) | RecordError::UnknownFormat { .. } => bad_input(err),
        RecordError::Source(SourceError::Open { .. } | SourceError::Format { .. })
            if matches!(spec, SourceSpec::Replay(_)) =>
        {
            bad_input(err)
        }
        other => anyhow::Error::new(other),
    })?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colour_encodings_parse() {
        assert_eq!(parse_color("raw").unwrap(), ColorEncoding::Raw);
        assert_eq!(
            parse_color("jpeg").unwrap(),
            ColorEncoding::Jpeg { quality: 90 }
        );
        assert_eq!(
            parse_color("jpeg:75").unwrap(),
            ColorEncoding::Jpeg { quality: 75 }
        );
        assert!(parse_color("jpeg:0").is_err());
        assert!(parse_color("png").is_err());
    }
}
