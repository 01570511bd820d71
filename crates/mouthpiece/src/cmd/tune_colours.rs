//! `mouthpiece tune-colours SOURCE`: propose the detector's colour classes from the first
//! seconds of a session and print them as a `[detect]` TOML snippet on stdout.
//!
//! The work is `mouthpiece_detect::tune` (blobs, hue clustering, roles, ranges); this command
//! opens the source (`mouthpiece_capture::open_source`: a recording path or any capture
//! spec), registers depth to the colour grid when the source does not, and prints.

use std::path::Path;

use anyhow::Context as _;
use mouthpiece_capture::{CaptureConfig, SourceSpec};
use mouthpiece_detect::tune::{ColourSampler, TuneOptions};
use mouthpiece_frame::DepthImage;

use crate::cmd::process::load_config;
use crate::exit::bad_input;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// A recording (`.mcap`, `.oni`) or a capture spec: replay:FILE, `openni2:[URI]`,
    /// v4l2:COLOUR[+DEPTH]. Replays are read unpaced, once.
    pub source: String,
    /// Seconds of frames to sample, from the first frame's device time.
    #[arg(long, default_value_t = 2.0)]
    pub seconds: f64,
    /// Paint colours expected (1: one paint on every dot; 2: lips and forehead). Default: as
    /// many as found, at most lips + forehead.
    #[arg(long)]
    pub classes: Option<usize>,
    /// Configuration file (TOML): blob filters from `[detect]`, dot counts from `[track]`.
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
}

/// The spec to open: a plain path is a replay; replays run unpaced and once.
fn source_spec(source: &str) -> anyhow::Result<SourceSpec> {
    let looks_like_spec = ["replay:", "openni2:", "v4l2:"]
        .iter()
        .any(|s| source.starts_with(s));
    let mut spec = if looks_like_spec {
        SourceSpec::parse(source).map_err(bad_input)?
    } else {
        SourceSpec::Replay(mouthpiece_capture::ReplaySpec::unpaced(Path::new(source)))
    };
    if let SourceSpec::Replay(r) = &mut spec {
        r.speed = None;
        r.looping = false;
    }
    Ok(spec)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if !(args.seconds > 0.0 && args.seconds.is_finite()) {
        return Err(bad_input(anyhow::anyhow!(
            "--seconds {}: expected a positive number",
            args.seconds
        )));
    }
    if matches!(args.classes, Some(n) if !(1..=2).contains(&n)) {
        return Err(bad_input(anyhow::anyhow!(
            "--classes {}: expected 1 (one paint for every dot) or 2 (lips and forehead)",
            args.classes.unwrap_or_default()
        )));
    }
    let config = load_config(args.config.as_deref())?;
    let spec = source_spec(&args.source)?;
    let is_replay = matches!(spec, SourceSpec::Replay(_));
    let mut source = mouthpiece_capture::open_parsed(&spec, &CaptureConfig::default())
        .with_context(|| format!("cannot open {}", args.source))
        .map_err(|e| if is_replay { bad_input(e) } else { e })?;

    let mut options = TuneOptions::from_config(
        &config.detect,
        config.track.lip_dots,
        config.track.forehead_dots,
    );
    options.classes = args.classes;
    let mut sampler = ColourSampler::new(options);
    let mut registered = DepthImage::new(0, 0);
    let mut first_ts = None;
    let mut with_depth = 0u32;
    while let Some(frame) = source
        .next_frame()
        .with_context(|| format!("reading {}", args.source))
        .map_err(|e| if is_replay { bad_input(e) } else { e })?
    {
        let t0 = *first_ts.get_or_insert(frame.device_ts_us);
        if frame.device_ts_us.saturating_sub(t0) as f64 * 1e-6 >= args.seconds {
            break;
        }
        let sample = sampler
            .add_frame(
                &frame.color,
                mouthpiece_pipeline::tune::sampling_depth(&frame, &mut registered),
                frame.calibration.color.fx,
            )
            .with_context(|| format!("frame {}", frame.seq))
            .map_err(bad_input)?;
        with_depth += sample.performer_m.is_some() as u32;
        tracing::debug!(seq = frame.seq, ?sample, "sampled");
    }
    if sampler.frames() == 0 {
        return Err(bad_input(anyhow::anyhow!(
            "{}: no frames to sample",
            args.source
        )));
    }
    if with_depth == 0 {
        tracing::warn!("no depth showed a performer: the background is not masked");
    }
    let checked = sampler
        .propose_checked(&config.detect)
        .context("checking the proposal with the detector")?;
    let proposal = &checked.proposal;
    for w in &proposal.warnings {
        tracing::warn!("{w}");
    }
    if proposal.classes.is_empty() {
        return Err(bad_input(anyhow::anyhow!(
            "{}: {}; nothing to propose (are the dots painted, lit and in view in the first {} s?)",
            args.source,
            proposal
                .warnings
                .last()
                .map(String::as_str)
                .unwrap_or("no paint colours found"),
            args.seconds
        )));
    }
    // What is printed must be a configuration the detector takes.
    let detect = proposal.detect_config(&config.detect);
    detect
        .validate()
        .context("the proposed classes do not validate (a bug)")?;
    let (lip, forehead) = (config.track.lip_dots, config.track.forehead_dots);
    let report = checked.report(lip, forehead);
    for line in &report {
        tracing::info!("{line}");
    }
    // Never offer ranges that find fewer dots than those in use on the same frames.
    if !checked.offered() {
        return Err(bad_input(anyhow::anyhow!(
            "{}: no proposal: the proposed ranges find fewer dots than the ranges in use on the \
             same frames ({}; {}); keep the ranges in use",
            args.source,
            report[0],
            report[1]
        )));
    }
    print!("{}", proposal.to_toml(&args.source));
    println!();
    for line in &report {
        println!("# {line}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_become_unpaced_replays() {
        let SourceSpec::Replay(r) = source_spec("recordings/demo.mcap").unwrap() else {
            panic!("not a replay");
        };
        assert_eq!(r.speed, None);
        assert!(!r.looping);
        let SourceSpec::Replay(r) = source_spec("replay:x.oni?loop=1&speed=1.0").unwrap() else {
            panic!("not a replay");
        };
        assert_eq!((r.speed, r.looping), (None, false));
        assert!(matches!(
            source_spec("openni2:").unwrap(),
            SourceSpec::OpenNi2 { uri: None }
        ));
        assert!(source_spec("replay:").is_err());
    }
}
