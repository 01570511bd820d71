//! `mouthpiece synth`: render a synthetic performer session to an MCAP file, or to an
//! OpenNI2 `.oni` (by the output's extension; frames and timestamps only, see
//! `docs/capture.md`).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use mouthpiece_capture::oni_write::{OniFrameWriter, OniWriteError};
use mouthpiece_recording::{ColorEncoding, SessionWriter, WriterOptions};
use mouthpiece_synth::{DotLayout, HeadMotion, NoiseModel, Synth, SynthConfig};

use crate::exit::{bad_input, bad_input_if};

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum MotionArg {
    None,
    Mild,
    Strong,
    /// The strong motion at 1.5 times its speed.
    Fast,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum NoiseArg {
    None,
    Kinect,
    Realsense,
}

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output session: MCAP (with ground truth), or OpenNI2 `.oni` when the name ends in
    /// `.oni` (frames only: uncompressed depth and RGB888, no ground truth, no distortion or
    /// depth baseline).
    #[arg(long)]
    pub out: PathBuf,
    /// Length of the session in seconds.
    #[arg(long)]
    pub seconds: f64,
    /// Seed: the same seed gives the same session.
    #[arg(long)]
    pub seed: u64,
    /// Frames per second.
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// Image size WIDTHxHEIGHT (colour and depth; focal length 525 px at 640 wide, scaled).
    #[arg(long, default_value = "640x480", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Camera to the mouth, metres.
    #[arg(long, default_value_t = 0.6)]
    pub distance: f64,
    /// Head motion: none, mild (±10° yaw) or strong (yaw ±30°, pitch ±15°, roll ±10°, ±5 cm).
    #[arg(long, value_enum, default_value = "mild")]
    pub head_motion: MotionArg,
    /// Depth sensor noise model.
    #[arg(long, value_enum, default_value = "kinect")]
    pub noise: NoiseArg,
    /// Dot layout (TOML: lip_dots, radius_mm, lip_color, forehead_color, `[[forehead]]`).
    #[arg(long)]
    pub layout: Option<PathBuf>,
    /// Lens distortion of the colour camera, OpenCV plumb_bob: K1,K2,P1,P2,K3.
    #[arg(long, value_parser = parse_distortion)]
    pub distortion: Option<[f64; 5]>,
    /// Render depth from a separate depth camera this many millimetres to the colour
    /// camera's right (a baseline along x) instead of registered to the colour grid.
    #[arg(long)]
    pub depth_baseline_mm: Option<f64>,
    /// Store colour losslessly (bgr8 RawImage, ≈ 20× larger) instead of JPEG. (`.oni`
    /// colour is always lossless.)
    #[arg(long)]
    pub raw_color: bool,
    /// JPEG quality of colour frames (1–100).
    #[arg(long, default_value_t = 90, value_parser = clap::value_parser!(u8).range(1..=100))]
    pub jpeg_quality: u8,
    /// Turn off colour sensor effects (noise, exposure drift, motion blur, uneven light).
    #[arg(long)]
    pub no_colour_effects: bool,
    /// Drive the mouth from a lip-sync weights CSV (`mouthpiece lipsync --weights`) instead
    /// of the seed's speech: each sample's mouth is Σ wᵢ · (pose i's mouth state), after the
    /// neutral lead-in.
    #[arg(long, group = "speech_source")]
    pub speech: Option<PathBuf>,
    /// Festival says this line: its sound goes on `/audio` and its own phone timing drives
    /// the mouth (through the shipped lip-sync classes and the basic poses), both after the
    /// neutral lead-in. Needs Festival (`festival`, `festvox-kallpc16k`). MCAP output only.
    #[arg(long, group = "speech_source", value_name = "LINE")]
    pub speech_text: Option<String>,
    /// The basic poses whose mouth states `--speech`/`--speech-text` blend (default: the
    /// shipped ones).
    #[arg(long, requires = "speech_source")]
    pub poses: Option<PathBuf>,
    /// The lips' own colour under the paint, R,G,B (0–255), e.g. 200,102,102 for saturated
    /// red lips (OpenCV saturation ≈ 125). Default: a muted red. Overrides the layout file's
    /// `lip_skin_color`.
    #[arg(long, value_name = "R,G,B", value_parser = parse_rgb)]
    pub lip_skin_colour: Option<[u8; 3]>,
    /// The sound the `--speech` weights were made from (a 16-bit PCM WAV, e.g. Festival's
    /// `text2wave`): written on `/audio` with its true timing, sample 0 at the time the
    /// weights' 0 s is (after the neutral lead-in), so sound and mouth share one timeline.
    /// MCAP output only.
    #[arg(long, requires = "speech", value_name = "WAV")]
    pub speech_audio: Option<PathBuf>,
    #[command(flatten)]
    pub jaw: JawArgs,
}

/// The synthetic jaw's hinge and slide (`mouthpiece synth` and `mouthpiece evaluate`).
#[derive(Debug, Clone, Copy, Default, clap::Args)]
pub struct JawArgs {
    /// Move the synthetic jaw's hinge: `back=P%,down=Q%` (either or both), percentages of
    /// its default distance behind (80 mm) and above (25 mm) the mouth centre, each within
    /// ±50 % (negative: forward, up).
    #[arg(long, value_name = "back=P%,down=Q%", value_parser = parse_hinge)]
    pub hinge: Option<(f64, f64)>,
    /// Slide the synthetic jaw: sideways within ±MM (a smooth seeded motion) and forward by
    /// MM on the widest openings; 0 to 5.
    #[arg(long, value_name = "MM", value_parser = parse_jaw_slide)]
    pub jaw_slide: Option<f64>,
}

impl JawArgs {
    /// The synthetic performer's jaw options (checked when the flags were parsed).
    pub fn options(&self) -> mouthpiece_synth::JawOptions {
        let (back, down) = self.hinge.unwrap_or((0.0, 0.0));
        mouthpiece_synth::JawOptions {
            hinge_back: back,
            hinge_down: down,
            slide_m: self.jaw_slide.unwrap_or(0.0) / 1e3,
        }
    }
}

/// `--hinge back=P%,down=Q%` → (back, down) as fractions, within the synthetic performer's
/// range.
pub(crate) fn parse_hinge(s: &str) -> Result<(f64, f64), String> {
    let short: String = s.chars().take(80).collect();
    let (mut back, mut down) = (None, None);
    for part in s.split(',') {
        let (key, value) = part
            .split_once('=')
            .ok_or_else(|| format!("expected back=P%,down=Q%, got {short:?}"))?;
        let slot = match key.trim() {
            "back" => &mut back,
            "down" => &mut down,
            _ => {
                return Err(format!(
                    "unknown direction {:?} (back or down) in {short:?}",
                    key.trim().chars().take(20).collect::<String>()
                ))
            }
        };
        let pct: f64 = value
            .trim()
            .strip_suffix('%')
            .and_then(|v| v.trim().parse().ok())
            .ok_or_else(|| format!("expected a percentage such as +25% in {short:?}"))?;
        if slot.replace(pct / 100.0).is_some() {
            return Err(format!("{} given twice in {short:?}", key.trim()));
        }
    }
    let jaw = mouthpiece_synth::JawOptions {
        hinge_back: back.unwrap_or(0.0),
        hinge_down: down.unwrap_or(0.0),
        ..Default::default()
    };
    jaw.validate_hinge()?;
    Ok((jaw.hinge_back, jaw.hinge_down))
}

/// `--jaw-slide MM`, within the synthetic performer's range.
pub(crate) fn parse_jaw_slide(s: &str) -> Result<f64, String> {
    let mm: f64 = s.trim().parse().map_err(|_| {
        format!(
            "expected millimetres, got {:?}",
            s.chars().take(80).collect::<String>()
        )
    })?;
    mouthpiece_synth::JawOptions {
        slide_m: mm / 1e3,
        ..Default::default()
    }
    .validate_slide()?;
    Ok(mm)
}

pub(crate) fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, got {s:?}"))?;
    let w: u32 = w
        .trim()
        .parse()
        .map_err(|_| format!("bad width in {s:?}"))?;
    let h: u32 = h
        .trim()
        .parse()
        .map_err(|_| format!("bad height in {s:?}"))?;
    Ok((w, h))
}

fn parse_rgb(s: &str) -> Result<[u8; 3], String> {
    let v: Vec<u8> = s
        .split(',')
        .map(|x| {
            x.trim()
                .parse::<u8>()
                .map_err(|_| format!("bad colour component {x:?} in {s:?}: expected 0–255"))
        })
        .collect::<Result<_, _>>()?;
    v.try_into()
        .map_err(|v: Vec<u8>| format!("expected 3 values R,G,B, got {}", v.len()))
}

fn parse_distortion(s: &str) -> Result<[f64; 5], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| {
            x.trim()
                .parse::<f64>()
                .map_err(|_| format!("bad number {x:?} in {s:?}"))
        })
        .collect::<Result<_, _>>()?;
    v.try_into()
        .map_err(|v: Vec<f64>| format!("expected 5 values K1,K2,P1,P2,K3, got {}", v.len()))
}

/// `--speech`: a weights CSV → mouth keys after the neutral lead-in.
fn speech_keys(
    path: &std::path::Path,
    poses: Option<&std::path::Path>,
    neutral_seconds: f64,
) -> anyhow::Result<Vec<(f64, mouthpiece_synth::MouthState)>> {
    use crate::cmd::lipsync::{mouth_keys_from_weights, DEFAULT_POSES};
    use crate::cmd::lipsync::{read_text, MAX_TABLE_FILE_BYTES, MAX_WEIGHTS_CSV_BYTES};
    let (text, name) = match poses {
        Some(p) => (
            read_text(p, "pose file", MAX_TABLE_FILE_BYTES)?,
            p.display().to_string(),
        ),
        None => (
            DEFAULT_POSES.to_string(),
            "config/lipsync/poses.toml".to_string(),
        ),
    };
    let poses = mouthpiece_lipsync::BasicPoses::from_toml_str(&text, &name).map_err(bad_input)?;
    let csv = read_text(path, "weights CSV", MAX_WEIGHTS_CSV_BYTES)?;
    let mut keys = vec![(0.0, mouthpiece_synth::MouthState::default())];
    keys.extend(mouth_keys_from_weights(
        &csv,
        &path.display().to_string(),
        &poses,
        neutral_seconds,
    )?);
    Ok(keys)
}

/// `--speech-audio`: the WAV's samples, written in 10 ms blocks at their true times.
struct SpeechAudio {
    format: mouthpiece_frame::AudioFormat,
    samples: Vec<i16>,
    /// Log time of sample 0, ns (the session's clock: 0 at the first frame).
    start_ns: u64,
    /// Next sample frame to write.
    next: usize,
}

impl SpeechAudio {
    fn read(path: &std::path::Path, start_s: f64) -> anyhow::Result<SpeechAudio> {
        let reader = hound::WavReader::open(path)
            .with_context(|| format!("--speech-audio {}: not a readable WAV file", path.display()))
            .map_err(bad_input)?;
        let spec = reader.spec();
        if spec.sample_format != hound::SampleFormat::Int
            || spec.bits_per_sample != 16
            || !(8_000..=192_000).contains(&spec.sample_rate)
            || !(1..=32).contains(&spec.channels)
        {
            return Err(bad_input(anyhow::anyhow!(
                "--speech-audio {}: expected 16-bit PCM, 8000 to 192000 Hz, 1 to 32 channels; got {}-bit {:?}, {} Hz, {} channels",
                path.display(),
                spec.bits_per_sample,
                spec.sample_format,
                spec.sample_rate,
                spec.channels
            )));
        }
        // Checked against a day of sound before anything is allocated.
        let len = u64::from(reader.len());
        if len > MAX_SECONDS as u64 * u64::from(spec.sample_rate) * u64::from(spec.channels) {
            return Err(bad_input(anyhow::anyhow!(
                "--speech-audio {}: {len} samples is more than a day of sound",
                path.display()
            )));
        }
        let samples = reader
            .into_samples::<i16>()
            .collect::<Result<Vec<_>, _>>()
            .with_context(|| format!("--speech-audio {}: cut short", path.display()))
            .map_err(bad_input)?;
        Ok(SpeechAudio {
            format: mouthpiece_frame::AudioFormat {
                sample_rate: spec.sample_rate,
                channels: spec.channels,
            },
            samples,
            start_ns: (start_s * 1e9).round() as u64,
            next: 0,
        })
    }

    /// Writes the blocks that start before `until_ns`.
    fn write_until(&mut self, writer: &mut SessionWriter, until_ns: u64) -> anyhow::Result<()> {
        let channels = usize::from(self.format.channels);
        let block = self.format.sample_rate as usize / 100;
        let total = self.samples.len() / channels;
        while self.next < total {
            let at = self.start_ns
                + (self.next as u128 * 1_000_000_000 / u128::from(self.format.sample_rate)) as u64;
            if at >= until_ns {
                break;
            }
            let end = (self.next + block).min(total);
            writer.write_audio(
                at,
                self.format,
                &self.samples[self.next * channels..end * channels],
            )?;
            self.next = end;
        }
        Ok(())
    }
}

/// Frame rates `--fps` accepts: below one a second a session has no frames to speak of.
pub const FPS_RANGE: (f64, f64) = (1.0, 1000.0);
/// Longest session `--seconds` accepts (a day).
pub const MAX_SECONDS: f64 = 86_400.0;

pub fn run(args: Args) -> anyhow::Result<()> {
    if !(FPS_RANGE.0..=FPS_RANGE.1).contains(&args.fps) {
        return Err(bad_input(anyhow::anyhow!(
            "--fps must be within {} to {} frames per second, got {:?}",
            FPS_RANGE.0,
            FPS_RANGE.1,
            args.fps
        )));
    }
    if !(0.0..=MAX_SECONDS).contains(&args.seconds) {
        return Err(bad_input(anyhow::anyhow!(
            "--seconds must be within 0 to {MAX_SECONDS}, got {:?}",
            args.seconds
        )));
    }
    let mut config = SynthConfig {
        seed: args.seed,
        fps: args.fps,
        seconds: args.seconds,
        camera: SynthConfig::camera_for_size(args.size.0, args.size.1),
        distance_m: args.distance,
        head_motion: match args.head_motion {
            MotionArg::None => HeadMotion::None,
            MotionArg::Mild => HeadMotion::Mild,
            MotionArg::Strong => HeadMotion::Strong,
            MotionArg::Fast => HeadMotion::Fast,
        },
        noise: match args.noise {
            NoiseArg::None => NoiseModel::None,
            NoiseArg::Kinect => NoiseModel::Kinect,
            NoiseArg::Realsense => NoiseModel::Realsense,
        },
        colour_effects: !args.no_colour_effects,
        jaw: args.jaw.options(),
        ..SynthConfig::default()
    };
    if let Some(d) = args.distortion {
        config.camera.distortion = d;
    }
    if let Some(mm) = args.depth_baseline_mm {
        if !(mm.is_finite() && mm.abs() <= 200.0) {
            return Err(bad_input(anyhow::anyhow!(
                "--depth-baseline-mm must be within ±200, got {mm}"
            )));
        }
        let mut depth_to_color = mouthpiece_frame::Extrinsics::IDENTITY;
        // The depth camera sits `mm` to the colour camera's right: a point at its origin is
        // at +x in the colour frame.
        depth_to_color.translation = [mm / 1000.0, 0.0, 0.0];
        let mut depth = config.camera;
        depth.distortion = [0.0; 5];
        config.depth_camera = Some((depth, depth_to_color));
    }
    if let Some(path) = &args.layout {
        config.layout = DotLayout::from_file(path).map_err(bad_input)?;
    }
    if let Some(rgb) = args.lip_skin_colour {
        config.layout.lip_skin_color = Some(rgb);
    }
    let calibration = config.calibration();
    let neutral_seconds = config.neutral_seconds;
    let mut synth = Synth::new(config).map_err(bad_input)?;
    let is_oni = args
        .out
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("oni"));
    if is_oni && (args.speech_audio.is_some() || args.speech_text.is_some()) {
        return Err(bad_input(anyhow::anyhow!(
            "--speech-audio and --speech-text need an MCAP session (--out NAME.mcap): .oni files hold no sound"
        )));
    }
    if let Some(path) = &args.speech {
        synth.set_speech(speech_keys(path, args.poses.as_deref(), neutral_seconds)?);
    }
    // Festival's line: its mouth keys now, its WAV read as `--speech-audio`'s below.
    let spoken = match &args.speech_text {
        Some(text) => {
            let line = crate::cmd::synth_speech::speak(
                text,
                args.poses.as_deref(),
                neutral_seconds,
                std::path::Path::new("festival"),
            )?;
            synth.set_speech(line.keys.clone());
            Some(line)
        }
        None => None,
    };
    let speech_wav = args
        .speech_audio
        .as_deref()
        .or(spoken.as_ref().map(|l| l.wav.as_path()));
    let started = Instant::now();
    let total = synth.frame_count();
    let frames = if is_oni {
        let oni_error = |e: OniWriteError| bad_input_if(e.is_bad_input(), e);
        let mut writer = OniFrameWriter::create(&args.out, &calibration, args.fps)
            .map_err(oni_error)
            .with_context(|| format!("cannot write the session {}", args.out.display()))?;
        while let Some((frame, _truth)) = synth.render_next() {
            writer.write_frame(&frame).map_err(oni_error)?;
        }
        let summary = writer.finish().map_err(oni_error)?;
        summary.depth_frames as u64
    } else {
        let options = WriterOptions {
            color: if args.raw_color {
                ColorEncoding::Raw
            } else {
                ColorEncoding::Jpeg {
                    quality: args.jpeg_quality,
                }
            },
            ..WriterOptions::default()
        };
        let mut sound = match speech_wav {
            Some(path) => Some(SpeechAudio::read(path, neutral_seconds)?),
            None => None,
        };
        let mut writer = SessionWriter::create(&args.out, options)
            .with_context(|| format!("cannot write the session {}", args.out.display()))?;
        while let Some((frame, truth)) = synth.render_next() {
            if let Some(sound) = &mut sound {
                sound.write_until(&mut writer, frame.device_ts_us * 1000)?;
            }
            writer.write_frame_with_ground_truth(&frame, Some(&truth))?;
        }
        if let Some(sound) = &mut sound {
            sound.write_until(&mut writer, u64::MAX)?;
        }
        writer.finish()?.frames
    };
    let size = std::fs::metadata(&args.out).map(|m| m.len()).unwrap_or(0);
    tracing::info!(
        out = %args.out.display(),
        format = if is_oni { "oni" } else { "mcap" },
        frames,
        seconds = args.seconds,
        bytes = size,
        elapsed_s = format!("{:.2}", started.elapsed().as_secs_f64()),
        "synthetic session written"
    );
    debug_assert_eq!(frames, total);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hinge_moves_parse_as_fractions_and_bad_ones_say_why() {
        assert_eq!(parse_hinge("back=+25%,down=-25%"), Ok((0.25, -0.25)));
        assert_eq!(parse_hinge("down=10%"), Ok((0.0, 0.1)));
        assert_eq!(parse_hinge(" back = -50 % "), Ok((-0.5, 0.0)));
        for (bad, says) in [
            ("back=+60%", "within ±50 %"),
            ("down=NaN%", "within ±50 %"),
            ("back=25", "percentage"),
            ("up=25%", "unknown direction"),
            ("back=1%,back=2%", "twice"),
            ("back", "expected back=P%"),
        ] {
            let e = parse_hinge(bad).unwrap_err();
            assert!(e.contains(says), "{bad}: {e}");
        }
        assert_eq!(parse_jaw_slide("2.5"), Ok(2.5));
        for bad in ["-1", "6", "inf", "NaN", "two"] {
            assert!(parse_jaw_slide(bad).is_err(), "{bad}");
        }
    }
}
