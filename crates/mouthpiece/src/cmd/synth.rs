//! `mouthpiece synth`: render a synthetic performer session to an MCAP file, or to an
//! OpenNI2 `.oni` (by the output's extension; frames and timestamps only, see
//! `docs/capture.md`).

use std::path::PathBuf;
use std::time::Instant;

use mouthpiece_recording::ColorEncoding;
pub use mouthpiece_synth::args::parse_size;
use mouthpiece_synth::args::{parse_distortion, parse_hinge, parse_jaw_slide, parse_rgb};
use mouthpiece_synth::session::{self, SessionOptions};
use mouthpiece_synth::{DotLayout, HeadMotion, NoiseModel, SynthConfig};

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

pub fn run(args: Args) -> anyhow::Result<()> {
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
        config.set_depth_baseline_mm(mm).map_err(bad_input)?;
    }
    if let Some(path) = &args.layout {
        config.layout = DotLayout::from_file(path).map_err(bad_input)?;
    }
    if let Some(rgb) = args.lip_skin_colour {
        config.layout.lip_skin_color = Some(rgb);
    }
    // Checked before Festival speaks or a weights file is read.
    config.validate().map_err(bad_input)?;
    let with_sound = args.speech_audio.is_some() || args.speech_text.is_some();
    session::refuse_sound_in_oni(&args.out, with_sound).map_err(bad_input)?;
    let neutral_seconds = config.neutral_seconds;
    let mut speech = match &args.speech {
        Some(path) => Some(speech_keys(path, args.poses.as_deref(), neutral_seconds)?),
        None => None,
    };
    // Festival's line: its mouth keys, and its WAV written as `--speech-audio`'s.
    let spoken = match &args.speech_text {
        Some(text) => Some(crate::cmd::synth_speech::speak(
            text,
            args.poses.as_deref(),
            neutral_seconds,
            std::path::Path::new("festival"),
        )?),
        None => None,
    };
    if let Some(line) = &spoken {
        speech = Some(line.keys.clone());
    }
    let sound = args
        .speech_audio
        .clone()
        .or(spoken.as_ref().map(|l| l.wav.clone()));
    let started = Instant::now();
    let summary = session::write_session(SessionOptions {
        config,
        out: args.out.clone(),
        color: if args.raw_color {
            ColorEncoding::Raw
        } else {
            ColorEncoding::Jpeg {
                quality: args.jpeg_quality,
            }
        },
        speech,
        sound,
    })
    .map_err(|e| bad_input_if(e.is_bad_input(), e))?;
    tracing::info!(
        out = %args.out.display(),
        format = if summary.oni { "oni" } else { "mcap" },
        frames = summary.frames,
        seconds = args.seconds,
        bytes = summary.bytes,
        elapsed_s = format!("{:.2}", started.elapsed().as_secs_f64()),
        "synthetic session written"
    );
    Ok(())
}
