//! `mouthpiece export`: a take (retarget/process JSONL) → glTF 2.0 / GLB / CSV keyframes. A
//! daemon's take (`.mcap`) is read as it was recorded live (`mouthpiece_takes::read`); a plain
//! recording (`.mcap`, `.oni`), or a take with `--reprocess`, is first processed into a
//! temporary take by the same code as `mouthpiece process`.

use std::fs::File;
use std::io::{self, BufRead, BufReader, BufWriter, Seek, SeekFrom, Write as _};
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{anyhow, Context as _};
use mouthpiece_export::{
    livelink_timecode, CsvWriter, ExportError, GltfLayout, GltfOptions, GltfWriter,
    LiveLinkCsvWriter, ModelUp, MouthRig, RigPoint, TakeFrame, TakeReader,
};
use mouthpiece_server::{Timecode, TimecodeRate};
use mouthpiece_takes::read::{self as take_file, ReadError};

use crate::cmd::process::{process_recording, ProcessSetup};
use crate::cmd::retarget::Smooth;
use crate::exit::{bad_input, bad_input_if};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The take: a daemon's take (.mcap: what went out live, as recorded), JSONL from
    /// `mouthpiece retarget` or `mouthpiece process` (`-` for stdin), or a recording (.mcap,
    /// .oni) to process first.
    pub input: PathBuf,
    /// Output format; by default from --out's extension (.gltf, .glb, .csv).
    #[arg(long, value_enum)]
    pub format: Option<Format>,
    /// Output file. For `gltf` the buffer goes to the same name with `.bin` (see --embed).
    #[arg(long)]
    pub out: PathBuf,
    /// Character file (TOML): point names and order, rest pose, and where the mouth sits in
    /// the model. Without it the names come from the take and the mouth node is the origin.
    /// Required for a recording (it is processed for this character).
    #[arg(long)]
    pub character: Option<PathBuf>,
    /// Recordings only: configuration file (TOML) whose `[detect]` and `[track]` tables the
    /// processing uses (as `mouthpiece process --config`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// A daemon's take: track its camera images again (with --config, or the built-in
    /// configuration) instead of using the steps it recorded live.
    #[arg(long)]
    pub reprocess: bool,
    /// Drop glTF keys that linear interpolation reproduces within TOLERANCE (character units,
    /// per axis).
    #[arg(long, value_name = "TOLERANCE", allow_negative_numbers = true)]
    pub reduce: Option<f64>,
    /// `gltf` only: embed the buffer in the .gltf as base64 instead of writing a .bin.
    #[arg(long)]
    pub embed: bool,
    /// Up axis of the character's model frame: `y` (glTF's convention, +Y up, front +Z) or
    /// `z` (Blender's, +Z up, front -Y; converted to glTF's axes on export).
    #[arg(long, value_enum, default_value = "y")]
    pub model_up: ModelUpArg,
    /// glTF only: also animate the take's smoothed mouth outline (`curve`, from `retarget
    /// --smooth`) as nodes C0, C1, … under a `curve` node.
    #[arg(long)]
    pub curve: bool,
    /// Leave the point nodes empty (no small marker mesh).
    #[arg(long)]
    pub no_markers: bool,
    /// GLB only: write the take onto this rigged mesh (from `mouthpiece bind`) instead of
    /// onto bare point nodes: the output is the rig with the take's animation on its joints.
    #[arg(long, value_name = "RIGGED_GLB")]
    pub rig: Option<PathBuf>,
    /// Write the take's curves onto this avatar (glTF/GLB) as morph-target weight animation:
    /// targets named like the curves (ARKit names, case ignored) follow the take; everything
    /// else in the file is kept. The output has the avatar's format (.glb or .gltf).
    #[arg(long, value_name = "AVATAR")]
    pub onto: Option<PathBuf>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ModelUpArg {
    Y,
    Z,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// glTF 2.0 JSON (+ .bin, or embedded with --embed).
    Gltf,
    /// Binary glTF: one file.
    Glb,
    /// One row per frame: t, x, y, z per point, then the head's and eyes' quaternions (when
    /// the take has a head), the jaw's angle and slide and one column per rig curve.
    Csv,
    /// Live Link Face's CSV take: `Timecode,BlendShapeCount,` then the 52 ARKit blend shapes
    /// and the head and eye angles, one row per frame at its timecode (docs/export.md).
    LivelinkCsv,
}

impl Format {
    fn from_extension(path: &Path) -> Option<Self> {
        match path.extension()?.to_str()?.to_ascii_lowercase().as_str() {
            "gltf" => Some(Self::Gltf),
            "glb" => Some(Self::Glb),
            "csv" => Some(Self::Csv),
            _ => None,
        }
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // A recording's sound goes beside the animation as a Broadcast WAV, moved into place
    // only once the animation is written.
    let is_mcap = args
        .input
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"));
    // Without --character the animation's own checks refuse the recording first.
    let wav = if is_mcap && args.onto.is_none() && args.rig.is_none() && args.character.is_some() {
        crate::cmd::export_audio::prepare(&args.input, &args.out)?
    } else {
        None
    };
    export_animation(args)?;
    if let Some(wav) = wav {
        wav.commit()?;
    }
    Ok(())
}

fn export_animation(args: Args) -> anyhow::Result<()> {
    let format = match args.format {
        Some(f) => f,
        None => Format::from_extension(&args.out).ok_or_else(|| {
            bad_input(anyhow!(
                "--format not given and --out {} does not end in .gltf, .glb or .csv",
                args.out.display()
            ))
        })?,
    };
    let csv = matches!(format, Format::Csv | Format::LivelinkCsv);
    if let Some(tolerance) = args.reduce {
        if csv {
            return Err(bad_input(anyhow!(
                "--reduce applies to glTF keys; CSV keeps one row per frame"
            )));
        }
        if !tolerance.is_finite() || tolerance < 0.0 {
            return Err(bad_input(ExportError::BadTolerance(tolerance)));
        }
    }
    if args.curve && csv {
        return Err(bad_input(anyhow!(
            "--curve applies to glTF; CSV has the points only"
        )));
    }
    if args.rig.is_some() && format != Format::Glb {
        return Err(bad_input(anyhow!(
            "--rig writes a GLB: give --out NAME.glb"
        )));
    }
    if let Some(avatar) = &args.onto {
        if csv {
            return Err(bad_input(anyhow!(
                "--onto writes the avatar with the animation: give --out NAME.glb or NAME.gltf"
            )));
        }
        for (given, flag) in [
            (args.rig.is_some(), "--rig"),
            (args.curve, "--curve"),
            (args.reduce.is_some(), "--reduce"),
            (args.embed, "--embed"),
            (args.no_markers, "--no-markers"),
        ] {
            if given {
                return Err(bad_input(anyhow!(
                    "{flag} does not apply with --onto (only the morph-target weights are written)"
                )));
            }
        }
        return export_onto(&args, avatar, format == Format::Glb);
    }
    if args.embed && format != Format::Gltf {
        return Err(bad_input(anyhow!("--embed applies to --format gltf only")));
    }

    let character = args.character.as_deref().map(load_character).transpose()?;
    let input = open_take(&args)?;
    let total_bytes = input.len;
    let mut reader = match &character {
        Some(rig) => TakeReader::with_points(input.reader, input.name, rig.names()),
        None => TakeReader::new(input.reader, input.name),
    };
    let first = reader.next_frame().map_err(export_error)?.ok_or_else(|| {
        bad_input(ExportError::EmptyTake {
            source_name: reader.source_name().to_owned(),
        })
    })?;
    let rig = match character {
        Some(rig) => {
            if let Some(file) = rig.character() {
                reader.check_character(file).map_err(bad_input)?;
            }
            rig
        }
        None => rig_from_take(&reader, &first)?,
    };

    let source_name = reader.source_name().to_owned();
    // The rows' timecodes: the take's own clock (read before the progress bar shows).
    let clock = match format {
        Format::LivelinkCsv => Some(take_clock(&args.input)?),
        _ => None,
    };
    let progress = progress_bar(total_bytes);
    let mut frames = Frames {
        first: Some(first),
        reader,
        progress: &progress,
    };
    match format {
        Format::Csv => {
            let mut writer = CsvWriter::create(&rig, &args.out)
                .map_err(export_error)?
                .named(source_name);
            while let Some(frame) = frames.next()? {
                writer.push(&frame).map_err(export_error)?;
            }
            progress.set_message("finishing");
            let summary = writer.finish().map_err(export_error)?;
            progress.finish_and_clear();
            eprintln!("wrote {}: {} rows", summary.file.display(), summary.rows);
        }
        Format::LivelinkCsv => {
            let (start_us, rate) = clock.unwrap_or((0, TimecodeRate::Fps30));
            // A daemon's take as recorded: each row at the timecode its step went out with.
            let recorded = recorded_labels(&args, &rig)?;
            let mut writer = LiveLinkCsvWriter::create(&rig, &args.out)
                .map_err(export_error)?
                .named(source_name);
            let mut t0 = None;
            let mut row = 0;
            while let Some(frame) = frames.next()? {
                let t0 = *t0.get_or_insert(frame.t);
                let timecode = match recorded.get(row) {
                    Some(label) => livelink_timecode(label, 0.0),
                    None => row_timecode(start_us + ((frame.t - t0) * 1e6).round() as i64, rate),
                };
                writer.push(&frame, &timecode).map_err(export_error)?;
                row += 1;
            }
            progress.set_message("finishing");
            let summary = writer.finish().map_err(export_error)?;
            progress.finish_and_clear();
            eprintln!(
                "wrote {}: {} rows (Live Link Face CSV, {} fps)",
                summary.file.display(),
                summary.rows,
                rate.name()
            );
        }
        Format::Gltf | Format::Glb => {
            let options = GltfOptions {
                layout: match format {
                    Format::Glb => GltfLayout::Glb,
                    _ if args.embed => GltfLayout::Embedded,
                    _ => GltfLayout::SeparateBin,
                },
                model_up: match args.model_up {
                    ModelUpArg::Y => ModelUp::Y,
                    ModelUpArg::Z => ModelUp::Z,
                },
                reduce: args.reduce,
                curve: args.curve,
                markers: !args.no_markers && args.rig.is_none(),
                // A bound mesh has no head joints to carry the head's keys; its `jaw` joint
                // takes the rig's jaw keys (the blend shapes and lips are left out there).
                head: args.rig.is_none(),
                rig: true,
            };
            let dir = spool_dir(&args.out);
            // With --rig the take goes to a temporary GLB first, then onto the rig.
            let rig_stage = match &args.rig {
                Some(_) => {
                    Some(tempfile::tempdir_in(&dir).context("creating a temporary directory")?)
                }
                None => None,
            };
            let take_out = match &rig_stage {
                Some(stage) => stage.path().join("take.glb"),
                None => args.out.clone(),
            };
            let mut writer = GltfWriter::new(rig, options, &dir)
                .map_err(export_error)?
                .named(source_name);
            while let Some(frame) = frames.next()? {
                writer.push(&frame).map_err(export_error)?;
            }
            progress.set_message("writing the buffer");
            let mut summary = writer.finish(&take_out).map_err(export_error)?;
            if let Some(rigged) = &args.rig {
                let onto = mouthpiece_export::animate_rig(rigged, &take_out, &args.out)
                    .map_err(export_error)?;
                summary.files = vec![args.out.clone()];
                eprintln!(
                    "{} animation channels on the joints of {}",
                    onto.channels,
                    rigged.display()
                );
            }
            progress.finish_and_clear();
            let files: Vec<String> = summary
                .files
                .iter()
                .map(|f| f.display().to_string())
                .collect();
            eprintln!(
                "wrote {}: {} frames, {} keys{}",
                files.join(" + "),
                summary.frames,
                summary.keys,
                match args.reduce {
                    Some(tol) => format!(
                        ", {} of {} dropped by --reduce {tol} ({:.1} %)",
                        summary.dropped,
                        summary.samples,
                        100.0 * summary.dropped as f64 / summary.samples.max(1) as f64
                    ),
                    None => String::new(),
                }
            );
            if summary.rotation_keys > 0 {
                eprintln!(
                    "head, eye_L, eye_R: {} rotation keys",
                    summary.rotation_keys
                );
            }
            if summary.rig_keys > 0 {
                eprintln!(
                    "jaw, blendshapes: {} frames of the rig (jaw rotation and slide, {} curve weights each)",
                    summary.rig_keys,
                    mouthpiece_retarget::rig::CURVES
                );
            }
        }
    }
    Ok(())
}

/// `--onto`: the avatar is read and matched first (a bad avatar fails before the take is
/// read), then the take's curves are collected (4 bytes per curve and frame) and appended to
/// the avatar as one weight animation.
fn export_onto(args: &Args, avatar_path: &Path, glb_out: bool) -> anyhow::Result<()> {
    use mouthpiece_export::onto::{Avatar, CurveTable};
    use mouthpiece_output::{visemes_from, VISEMES, VISEME_NAMES};
    use mouthpiece_retarget::rig::{CURVES, CURVE_NAMES};
    let avatar = Avatar::read(avatar_path).map_err(export_error)?;
    // The curves, then the VRM visemes (VRM avatars' `aa ih ou ee oh`, `A I U E O`).
    let names: Vec<&str> = CURVE_NAMES.iter().chain(&VISEME_NAMES).copied().collect();
    let per_frame = CURVES + VISEMES;
    let table = CurveTable::new(&names);
    let plan = avatar.plan(&table).map_err(export_error)?;
    let character = args.character.as_deref().map(load_character).transpose()?;
    let input = open_take(args)?;
    let progress = progress_bar(input.len);
    let mut reader = match &character {
        Some(rig) => TakeReader::with_points(input.reader, input.name, rig.names()),
        None => TakeReader::new(input.reader, input.name),
    };
    let mut times = Vec::new();
    let mut values = Vec::new();
    while let Some(frame) = reader.next_frame().map_err(export_error)? {
        progress.set_position(reader.bytes_read());
        times.push(frame.t as f32);
        let curves = frame.rig.map_or([0.0; CURVES], |r| r.curves);
        // As the rig computes them: a take stores the visemes its curves give.
        let visemes = frame
            .rig
            .map_or([0.0; VISEMES], |r| visemes_from(&r.curves));
        values.extend(curves.iter().chain(&visemes).map(|&c| c as f32));
    }
    if times.is_empty() {
        return Err(bad_input(ExportError::EmptyTake {
            source_name: reader.source_name().to_owned(),
        }));
    }
    progress.set_message("writing");
    let summary = avatar
        .write_onto(&plan, &times, &values, per_frame, &args.out, glb_out)
        .map_err(export_error)?;
    progress.finish_and_clear();
    eprint!("{}", plan.report);
    eprintln!(
        "wrote {}: {} frames, {} weights channel(s) on {}, {} bytes of animation added",
        args.out.display(),
        summary.frames,
        summary.channels,
        avatar_path.display(),
        summary.bytes
    );
    Ok(())
}

/// The first frame (read early to learn the point names), then the rest of the reader.
struct Frames<'a, R> {
    first: Option<TakeFrame>,
    reader: TakeReader<R>,
    progress: &'a indicatif::ProgressBar,
}

impl<R: BufRead> Frames<'_, R> {
    fn next(&mut self) -> anyhow::Result<Option<TakeFrame>> {
        if let Some(first) = self.first.take() {
            return Ok(Some(first));
        }
        let frame = self.reader.next_frame().map_err(export_error)?;
        self.progress.set_position(self.reader.bytes_read());
        Ok(frame)
    }
}

/// The user's mistakes exit 2, the machine's exit 1.
pub(crate) fn export_error(err: ExportError) -> anyhow::Error {
    bad_input_if(err.is_bad_input(), err)
}

/// A take file's fault exits 2, the machine's 1.
pub(crate) fn take_error(err: ReadError) -> anyhow::Error {
    bad_input_if(err.is_bad_input(), err)
}

pub(crate) struct TakeInput {
    pub(crate) name: String,
    pub(crate) reader: Box<dyn BufRead>,
    pub(crate) len: Option<u64>,
}

/// The timecode labels of a daemon's take read as recorded (empty for anything else: its rows
/// are placed on the take's clock instead).
fn recorded_labels(args: &Args, rig: &MouthRig) -> anyhow::Result<Vec<String>> {
    let is_mcap = args
        .input
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"));
    if !is_mcap || args.reprocess || !take_file::is_daemon_take(&args.input).map_err(take_error)? {
        return Ok(Vec::new());
    }
    match rig.character() {
        Some(name) => take_file::timecodes(&args.input, name).map_err(take_error),
        None => Ok(Vec::new()),
    }
}

/// A Live Link CSV row's timecode at `unix_us` (time of day, UTC, as the takes' timecode):
/// the label and the sub-frame in thousandths (`HH:MM:SS:FF.fff`).
fn row_timecode(unix_us: i64, rate: TimecodeRate) -> String {
    const DAY_US: i64 = 86_400 * 1_000_000;
    let (num, den) = rate.fraction();
    let of_day = unix_us.rem_euclid(DAY_US) as u128;
    let scaled = of_day * u128::from(num);
    let per_frame = u128::from(den) * 1_000_000;
    let frame = (scaled / per_frame) as u64;
    let sub = (scaled % per_frame) as f64 / per_frame as f64;
    livelink_timecode(&Timecode::from_frame_count(frame, rate).to_string(), sub)
}

/// Where a take's rows sit on the clock: a daemon's take (`.mcap`) at its first frame's time
/// of day and its recorded timecode rate; any other take (JSONL: no clock) at 00:00:00:00,
/// 30 fps.
fn take_clock(input: &Path) -> anyhow::Result<(i64, TimecodeRate)> {
    let is_mcap = input
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"));
    if !is_mcap {
        return Ok((0, TimecodeRate::Fps30));
    }
    let (span, take) = take_file::frame_span(input).map_err(take_error)?;
    let start_ns = span.map_or(0, |s| s.first_ns);
    let rate = take.and_then(|t| t.rate()).unwrap_or(TimecodeRate::Fps30);
    Ok(((start_ns / 1000) as i64, rate))
}

fn open_take(args: &Args) -> anyhow::Result<TakeInput> {
    let path = args.input.as_path();
    if path.as_os_str() == "-" {
        return Ok(TakeInput {
            name: "stdin".into(),
            reader: Box::new(BufReader::new(io::stdin())),
            len: None,
        });
    }
    let extension = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if matches!(extension.as_deref(), Some("mcap" | "oni")) {
        return take_from_recording(args);
    }
    let file = File::open(path)
        .with_context(|| format!("opening the take {}", path.display()))
        .map_err(bad_input)?;
    let len = file.metadata().ok().map(|m| m.len());
    Ok(TakeInput {
        name: path.display().to_string(),
        reader: Box::new(BufReader::with_capacity(256 * 1024, file)),
        len,
    })
}

fn take_from_recording(args: &Args) -> anyhow::Result<TakeInput> {
    let character = args.character.as_deref().ok_or_else(|| {
        bad_input(anyhow!(
            "{}: exporting a recording needs --character (its steps of that character are \
             exported, or it is processed for that character first)",
            args.input.display()
        ))
    })?;
    let spool = spool_dir(&args.out);
    recording_as_take(
        &args.input,
        character,
        args.config.as_deref(),
        args.reprocess,
        &spool,
    )
}

/// A recording as take lines for `character`: a daemon's take as it was recorded live
/// (unless `reprocess`); a plain recording, or a take with `reprocess`, through the
/// processing pipeline (`mouthpiece process`, same code). The lines go into an anonymous
/// temporary file in `spool`, read back from its start. Shared by `export` and `play`.
pub(crate) fn recording_as_take(
    path: &Path,
    character: &Path,
    config: Option<&Path>,
    reprocess: bool,
    spool: &Path,
) -> anyhow::Result<TakeInput> {
    let mut file = tempfile::tempfile_in(spool)
        .with_context(|| format!("cannot create a temporary take in {}", spool.display()))?;
    let is_mcap = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"));
    let is_take = is_mcap && take_file::is_daemon_take(path).map_err(take_error)?;
    if is_take && reprocess && take_file::has_no_images(path).map_err(take_error)? {
        return Err(bad_input(anyhow!(
            "{}: --reprocess needs camera images and this take has none (speech alone drove \
             it): leave --reprocess out to use its recorded steps",
            path.display()
        )));
    }
    let name = if is_take && !reprocess {
        let character = crate::cmd::process::load_character(character)?.name;
        let mut out = BufWriter::new(&mut file);
        let steps = take_file::write_lines(path, &character, &mut out).map_err(take_error)?;
        out.flush().context("cannot write the temporary take")?;
        drop(out);
        eprintln!(
            "{}: {steps} steps of {} as recorded live (--reprocess tracks the images again)",
            path.display(),
            mouthpiece_output::shown(&character)
        );
        format!("{} (as recorded)", path.display())
    } else {
        if !is_take && reprocess {
            eprintln!(
                "{}: not a daemon's take: processed, as without --reprocess",
                path.display()
            );
        }
        let setup = ProcessSetup {
            input: path,
            character,
            config,
            // `mouthpiece process`'s default, so that --curve has a curve to export.
            smooth: Some(Smooth::Bspline),
            opencv_threads: 0,
            // A daemon's take: the head as it turned live (`look_at` over the WebSocket).
            recorded_heads: true,
        };
        let summary = process_recording(&setup, &mut BufWriter::new(&mut file))?;
        summary.log();
        eprintln!(
            "{}: processed with {}; neutral pose {}",
            path.display(),
            match config {
                Some(c) => format!("the configuration {}", c.display()),
                None => "the built-in configuration".to_owned(),
            },
            match summary.calibrated_at {
                Some(t) => format!("taken from the images at {t:.2} s"),
                None => "never taken (no still, closed mouth with every dot seen)".to_owned(),
            }
        );
        format!("{} (processed)", path.display())
    };
    file.seek(SeekFrom::Start(0))
        .context("cannot read back the temporary take")?;
    let len = file.metadata().ok().map(|m| m.len());
    Ok(TakeInput {
        name,
        reader: Box::new(BufReader::with_capacity(256 * 1024, file)),
        len,
    })
}

/// Without a character file: the take's own names and order, the first frame as rest pose
/// (the origin for a point it lacks), the mouth at the origin.
fn rig_from_take<R: BufRead>(
    reader: &TakeReader<R>,
    first: &TakeFrame,
) -> anyhow::Result<MouthRig> {
    let names = reader.point_names().unwrap_or_default();
    let points = names
        .iter()
        .zip(&first.points)
        .map(|(name, p)| RigPoint {
            name: name.clone(),
            rest: p.unwrap_or([0.0; 3]),
        })
        .collect();
    MouthRig::new(
        reader.character().map(str::to_owned),
        points,
        nalgebra::Isometry3::identity(),
    )
    .map_err(bad_input)
}

fn load_character(path: &Path) -> anyhow::Result<MouthRig> {
    MouthRig::load_character(path).map_err(export_error)
}

/// Spool files live next to the output: same disk, not a RAM-backed /tmp.
pub(crate) fn spool_dir(out: &Path) -> PathBuf {
    match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// A byte-count bar on stderr when it is a terminal (indicatif draws nothing otherwise).
fn progress_bar(total: Option<u64>) -> indicatif::ProgressBar {
    let bar = match total {
        Some(len) => indicatif::ProgressBar::new(len).with_style(
            indicatif::ProgressStyle::with_template(
                "{msg:>12} [{bar:40}] {bytes}/{total_bytes} ({eta})",
            )
            .expect("valid template")
            .progress_chars("=> "),
        ),
        None => indicatif::ProgressBar::new_spinner(),
    };
    bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
    bar.set_message("reading");
    bar.enable_steady_tick(Duration::from_millis(200));
    bar
}
