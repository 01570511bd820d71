//! `mouthpiece lipsync`: speech → a take. Phones with times (from a phone file, or from a WAV
//! file through PocketSphinx, aligned to a transcript or recognised) → viseme classes →
//! stitched basic-pose weight curves (`mouthpiece-lipsync`) → the performer's lip dots
//! `D⁰ + Σ wᵢ · poseᵢ` in the mouth frame → the retarget core onto the character → one take
//! line per sample, the format of `mouthpiece process` (so `export` reads it). Method and
//! figures: `docs/lipsync.md`.
//!
//! Every input is checked before anything is written; the weights are computed in memory
//! (a few dozen bytes a sample), the take and the CSV are streamed to temporary files beside
//! their destinations and renamed into place at the end, so bad input leaves no file and a
//! long take costs no more memory than a short one.

use std::fmt::Write as _;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context as _;
use mouthpiece_lipsync::phones::{self, PhoneFormat};
use mouthpiece_lipsync::take::{phones_jsonl, Source, TakeWriter};
pub use mouthpiece_lipsync::take::{Tables, DEFAULT_POSES};
use mouthpiece_lipsync::{BasicPoses, PhoneSpan, Weights};
#[cfg(test)]
use mouthpiece_retarget::{NeutralPose, PerformerLayout, Vec3};
use mouthpiece_speech::{ModelPaths, Task, TimedPhone};
#[cfg(test)]
use mouthpiece_synth::DotLayout;
use mouthpiece_synth::MouthState;

use crate::cmd::process::{load_character, smoothing};
use crate::cmd::retarget::Smooth;
use crate::exit::bad_input;
use mouthpiece_lipsync::input::cut;

#[derive(Debug, clap::Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct Args {
    #[command(subcommand)]
    pub action: Option<Action>,
    /// Character file (TOML).
    #[arg(long, required = true)]
    pub character: Option<PathBuf>,
    /// Phone timing file: TIMIT `.phn`, Praat `.TextGrid`, HTK/Festival `.lab` (or `.segs`),
    /// or `.jsonl` of `{start, end, phone}`.
    #[arg(long, conflicts_with = "audio", required_unless_present = "audio")]
    pub phonemes: Option<PathBuf>,
    /// Speech as a WAV file (any rate; the first channel): phones from PocketSphinx.
    #[arg(long)]
    pub audio: Option<PathBuf>,
    /// What the audio says: the text, or `@FILE` to read it from a file. With it the phones
    /// are aligned to the transcript; without it they are recognised.
    #[arg(long, requires = "audio")]
    pub transcript: Option<String>,
    /// Samples per second of the take.
    #[arg(long, default_value_t = 60.0)]
    pub fps: f64,
    /// Length T of the change stage, seconds (0.03–0.05).
    #[arg(long, default_value_t = mouthpiece_lipsync::DEFAULT_T_CHANGE)]
    pub t_change: f64,
    /// Output take (JSONL).
    #[arg(long, required = true)]
    pub out: Option<PathBuf>,
    /// Also write the basic-pose weight curves as CSV (`t,phone,class,<pose>…`).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Also write the phones used (recognised, aligned or read) as JSONL `{start, end, phone}`.
    #[arg(long)]
    pub phones_out: Option<PathBuf>,
    /// Class table (TOML); default: the shipped one (config/lipsync/classes.toml).
    #[arg(long)]
    pub classes: Option<PathBuf>,
    /// Basic poses (TOML); default: the shipped ones (config/lipsync/poses.toml).
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// Segment overrides (TOML, control points per class pair and pose).
    #[arg(long)]
    pub segments: Option<PathBuf>,
    /// PocketSphinx model directory (Debian's pocketsphinx-en-us layout).
    #[arg(long, default_value = "/usr/share/pocketsphinx/model/en-us")]
    pub model: PathBuf,
    /// Shape smoothing that makes each line's `curve`.
    #[arg(long, value_parser = crate::cmd::retarget::smooth_arg(), default_value = "bspline")]
    pub smooth: Smooth,
}

#[derive(Debug, clap::Subcommand)]
pub enum Action {
    /// Capture a booth's own basic poses from a recorded session in which the actor holds
    /// each pose (marked by time ranges).
    Poses(crate::cmd::lipsync_poses::PosesArgs),
    /// Learn live lip-sync profiles from the booth's own recordings with known phone timing
    /// (for the daemon's `[audio] speech_profiles`).
    Learn(crate::cmd::lipsync_learn::LearnArgs),
}

pub use mouthpiece_lipsync::input::{
    MAX_PHONE_FILE_BYTES, MAX_TABLE_FILE_BYTES, MAX_TRANSCRIPT_BYTES, MAX_WEIGHTS_CSV_BYTES,
};

/// [`mouthpiece_lipsync::input::read_text`]: every error is the caller's file (exit code 2).
pub fn read_text(path: &Path, what: &str, limit: u64) -> anyhow::Result<String> {
    mouthpiece_lipsync::input::read_text(path, what, limit).map_err(bad_input)
}

/// The method's tables from `--classes`, `--poses` and `--segments` (the shipped ones when
/// absent).
pub fn load_tables(
    classes: Option<&Path>,
    poses: Option<&Path>,
    segments: Option<&Path>,
) -> anyhow::Result<Tables> {
    use mouthpiece_lipsync::take::{DEFAULT_CLASSES, DEFAULT_CLASSES_NAME, DEFAULT_POSES_NAME};
    let read = |path: Option<&Path>, what: &str| -> anyhow::Result<Option<(String, String)>> {
        path.map(|p| {
            Ok((
                read_text(p, what, MAX_TABLE_FILE_BYTES)?,
                p.display().to_string(),
            ))
        })
        .transpose()
    };
    let classes = read(classes, "class table")?;
    let poses = read(poses, "pose file")?;
    let segments = read(segments, "segment overrides")?;
    fn source<'a>(file: &'a Option<(String, String)>, text: &'a str, name: &'a str) -> Source<'a> {
        match file {
            Some((text, name)) => Source { text, name },
            None => Source { text, name },
        }
    }
    Tables::parse(
        source(&classes, DEFAULT_CLASSES, DEFAULT_CLASSES_NAME),
        source(&poses, DEFAULT_POSES, DEFAULT_POSES_NAME),
        segments.as_ref().map(|(text, name)| Source { text, name }),
    )
    .map_err(bad_input)
}

/// Recogniser names that are not speech sounds: silence and fillers.
fn is_filler(name: &str) -> bool {
    name.eq_ignore_ascii_case("sil")
        || name.starts_with(['<', '+', '[', '('])
        || name.eq_ignore_ascii_case("</s>")
}

/// Recognised or aligned phones → checked phone spans (fillers become silence).
pub fn spans_from_decoder(
    phones: &[TimedPhone],
    source_name: &str,
) -> anyhow::Result<Vec<PhoneSpan>> {
    let raw: Vec<PhoneSpan> = phones
        .iter()
        .enumerate()
        .filter(|(_, p)| p.end > p.start)
        .map(|(i, p)| PhoneSpan {
            start: p.start,
            end: p.end,
            phone: if is_filler(&p.phone) {
                "sil".into()
            } else {
                phones::normalise(&p.phone)
            },
            line: i + 1,
        })
        .collect();
    Ok(phones::check(raw, source_name)?)
}

/// Reads the phones from `--phonemes` or `--audio` (+ `--transcript`).
fn input_phones(args: &Args) -> anyhow::Result<(Vec<PhoneSpan>, String)> {
    if let Some(path) = &args.phonemes {
        let name = path.display().to_string();
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        let format = PhoneFormat::from_extension(ext).ok_or_else(|| {
            bad_input(anyhow::anyhow!(
                "{name}: unknown phone file type (expected .phn, .TextGrid, .lab, .segs or .jsonl)"
            ))
        })?;
        let text = read_text(path, "phone file", MAX_PHONE_FILE_BYTES)?;
        let spans = phones::read(&text, format, &name).map_err(bad_input)?;
        return Ok((spans, name));
    }
    let path = args
        .audio
        .as_ref()
        .expect("clap requires --phonemes or --audio");
    let name = path.display().to_string();
    let transcript = match &args.transcript {
        None => None,
        Some(t) => Some(match t.strip_prefix('@') {
            Some(file) => (
                read_text(Path::new(file), "transcript", MAX_TRANSCRIPT_BYTES)?,
                file.to_string(),
            ),
            None => (t.clone(), "--transcript".to_string()),
        }),
    };
    let file = std::fs::File::open(path)
        .with_context(|| format!("cannot open audio {name}"))
        .map_err(bad_input)?;
    let samples = mouthpiece_speech::wav::read_16k(std::io::BufReader::new(file), &name)
        .map_err(bad_input)?;
    let model = ModelPaths::en_us(&args.model);
    let task = match &transcript {
        Some((text, source)) => Task::Align {
            transcript: text,
            source_name: source,
        },
        None => Task::Recognise,
    };
    // In a child process: a damaged model file that crashes the library is an error.
    let decoded = mouthpiece_speech::decode(&model, &samples, &name, task)
        .map_err(|e| crate::exit::bad_input_if(e.is_bad_input(), e))?;
    let source = format!("{name} (PocketSphinx)");
    let spans = spans_from_decoder(&decoded, &source)?;
    Ok((spans, source))
}

/// The weight curves as CSV: `t,phone,class,<pose>…` (the dominant phone and its class),
/// written to `out` as it goes.
pub fn write_weights_csv(
    weights: &Weights,
    phones: &[PhoneSpan],
    tables: &Tables,
    out: &mut dyn Write,
) -> anyhow::Result<()> {
    let classes = tables.classes.classify(phones, "phones")?;
    // Names come from the user's files: quoted per RFC 4180 and guarded against spreadsheet
    // formulas, as the export's CSV does.
    use mouthpiece_export::csv::quote;
    let mut s = String::from("t,phone,class");
    for p in &tables.classes.poses {
        let _ = write!(s, ",{}", quote(p));
    }
    s.push('\n');
    for k in 0..weights.len() {
        let owner = weights.owner[k];
        let _ = write!(
            s,
            "{:.6},{},{}",
            weights.time(k),
            quote(&phones[owner].phone),
            quote(&tables.classes.classes[classes[owner]].name)
        );
        for w in weights.sample(k) {
            let _ = write!(s, ",{w:.9}");
        }
        s.push('\n');
        if s.len() > 1 << 16 {
            out.write_all(s.as_bytes())
                .context("cannot write the weights")?;
            s.clear();
        }
    }
    out.write_all(s.as_bytes())
        .context("cannot write the weights")?;
    Ok(())
}

fn create_file(path: &Path) -> anyhow::Result<mouthpiece_export::PendingFile> {
    mouthpiece_export::PendingFile::create(path)
        .with_context(|| format!("cannot create {}", path.display()))
        .map_err(bad_input)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.action {
        Some(Action::Poses(poses)) => return crate::cmd::lipsync_poses::run(poses),
        Some(Action::Learn(learn)) => return crate::cmd::lipsync_learn::run(learn),
        None => {}
    }
    let (Some(character), Some(out)) = (&args.character, &args.out) else {
        return Err(bad_input(anyhow::anyhow!(
            "--character and --out are required"
        )));
    };
    // Flags first: nothing is read or decoded for a take that cannot be made.
    let (lo, hi) = (mouthpiece_lipsync::MIN_FPS, mouthpiece_lipsync::MAX_FPS);
    if !(lo..=hi).contains(&args.fps) {
        return Err(bad_input(anyhow::anyhow!(
            "--fps must be within {lo} to {hi} samples per second, got {:?}",
            args.fps
        )));
    }
    mouthpiece_lipsync::mapping::check_t_change(args.t_change).map_err(bad_input)?;
    let tables = load_tables(
        args.classes.as_deref(),
        args.poses.as_deref(),
        args.segments.as_deref(),
    )?;
    let character_name = character.display().to_string();
    let character = load_character(character)?;
    let (phones, source) = input_phones(&args)?;
    let weights = mouthpiece_lipsync::weights_for_phones(
        &phones,
        &source,
        &tables.classes,
        &tables.segments,
        args.t_change,
        args.fps,
    )
    .map_err(bad_input)?;
    let take = TakeWriter::new(&tables, character, &character_name, smoothing(args.smooth))
        .map_err(bad_input)?;
    // Streamed to temporary files beside the outputs, renamed into place at the end.
    let mut pending = vec![create_file(out)?];
    take.write(&weights, &tables, &mut pending[0])
        .with_context(|| format!("cannot write {}", out.display()))?;
    if let Some(path) = &args.weights {
        let mut f = create_file(path)?;
        write_weights_csv(&weights, &phones, &tables, &mut f)
            .with_context(|| format!("cannot write {}", path.display()))?;
        pending.push(f);
    }
    if let Some(path) = &args.phones_out {
        let mut f = create_file(path)?;
        f.write_all(phones_jsonl(&phones).as_bytes())
            .with_context(|| format!("cannot write {}", path.display()))?;
        pending.push(f);
    }
    for f in pending {
        f.commit().context("cannot write the outputs")?;
    }
    tracing::info!(
        phones = phones.len(),
        samples = weights.len(),
        seconds = format!("{:.2}", weights.time(weights.len().saturating_sub(1))),
        "lipsync take written"
    );
    Ok(())
}

/// The synthetic performer's mouth state for each default key pose (the shipped pose file
/// is these states' dot displacements, [`poses_from_synth`]).
#[cfg(test)]
pub fn synth_pose_states() -> Vec<(&'static str, MouthState)> {
    let s = |jaw, spread, round, raise, roll_in| MouthState {
        jaw,
        spread,
        round,
        raise,
        roll_in,
    };
    vec![
        // Lips pressed, the lower lip rolled in a little: m, b, p.
        ("closed", s(0.0, 0.0, 0.0, 0.0, 1.0)),
        // Jaw open, upper lip raised: "ah".
        ("open", s(0.2, 0.0, 0.0, 0.3, 0.0)),
        // Corners out, upper lip raised, teeth nearly together: "ee".
        ("spread", s(0.06, 1.0, 0.0, 0.5, 0.0)),
        // Corners in, lips forward: "oo", "w".
        ("round", s(0.05, 0.0, 1.0, 0.0, 0.0)),
        // Lower lip up under the upper teeth, upper lip raised: f, v.
        ("bite", s(0.03, 0.0, 0.0, 0.3, 0.6)),
    ]
}

/// The default basic poses from the synthetic performer's mouth model: its dots for each
/// state in [`synth_pose_states`], in the mouth frame of its neutral pose.
#[cfg(test)]
pub fn poses_from_synth() -> anyhow::Result<BasicPoses> {
    let layout = DotLayout::default();
    let v = |p: &[f64; 3]| Vec3::new(p[0], p[1], p[2]);
    let (lip, forehead) = mouthpiece_synth::dot_positions(&layout, &MouthState::default());
    let neutral = NeutralPose::from_positions(
        PerformerLayout {
            lip_dots: lip.len(),
            forehead_dots: forehead.len(),
        },
        lip.iter().map(|p| Some(v(p))).collect(),
        forehead.iter().map(|p| Some(v(p))).collect(),
        1,
    )?;
    let frame = neutral.frame;
    let arr = |p: Vec3| [p.x, p.y, p.z];
    let poses = synth_pose_states()
        .into_iter()
        .map(|(name, state)| {
            let (moved, _) = mouthpiece_synth::dot_positions(&layout, &state);
            let displacement = moved
                .iter()
                .zip(&lip)
                .map(|(m, l)| arr(frame.to_mouth(&v(m)) - frame.to_mouth(&v(l))))
                .collect();
            let mouth = [
                ("jaw", state.jaw),
                ("spread", state.spread),
                ("round", state.round),
                ("raise", state.raise),
                ("roll_in", state.roll_in),
            ]
            .into_iter()
            .filter(|(_, x)| *x != 0.0)
            .map(|(k, x)| (k.to_string(), x))
            .collect();
            mouthpiece_lipsync::poses::Pose {
                name: name.to_string(),
                displacement,
                mouth,
            }
        })
        .collect();
    Ok(BasicPoses {
        neutral_lip: neutral.lip.iter().map(|p| arr(*p)).collect(),
        forehead: forehead
            .iter()
            .map(|p| arr(frame.to_mouth(&v(p))))
            .collect(),
        poses,
    })
}

/// A lip-sync weights CSV (`t,…,<pose>…`) → the synthetic performer's mouth states, keyed
/// at `t + offset`: Σ wᵢ · stateᵢ over the poses that carry a `mouth` state. Times must be
/// within 0 to a day and increase; weights within 0 to 1 (what `lipsync` writes); anything
/// else is an error naming the line and column.
pub fn mouth_keys_from_weights(
    csv: &str,
    source_name: &str,
    poses: &BasicPoses,
    offset: f64,
) -> anyhow::Result<Vec<(f64, MouthState)>> {
    // RFC 4180, as `write_weights_csv` writes it (names may hold commas, quotes, line breaks).
    let mut reader = ::csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .from_reader(csv.as_bytes());
    let mut records = reader.records();
    let cell_error = |e: ::csv::Error| {
        let line = e.position().map_or(0, |p| p.line());
        bad_input(anyhow::anyhow!(
            "{source_name}:{line}: not a CSV file: {}",
            cut(&e.to_string())
        ))
    };
    let header = match records.next() {
        Some(record) => record.map_err(cell_error)?,
        None => {
            return Err(bad_input(anyhow::anyhow!(
                "{source_name}: empty weights file"
            )))
        }
    };
    let columns: Vec<String> = header
        .iter()
        .map(|c| mouthpiece_export::csv::unguard(c.trim()).to_owned())
        .collect();
    if columns.first().map(String::as_str) != Some("t") {
        return Err(bad_input(anyhow::anyhow!(
            "{source_name}:1: the first column must be `t`"
        )));
    }
    // (column, pose state) for every column naming a pose with a mouth state.
    let mut used = Vec::new();
    for (c, name) in columns.iter().enumerate().skip(1) {
        if let Some(p) = poses.poses.iter().find(|p| &p.name == name) {
            let get = |k: &str| p.mouth.get(k).copied().unwrap_or(0.0);
            used.push((
                c,
                MouthState {
                    jaw: get("jaw"),
                    spread: get("spread"),
                    round: get("round"),
                    raise: get("raise"),
                    roll_in: get("roll_in"),
                },
            ));
        }
    }
    if used.is_empty() {
        return Err(bad_input(anyhow::anyhow!(
            "{source_name}:1: no column names a pose with a mouth state (poses: {:?})",
            poses.poses.iter().map(|p| cut(&p.name)).collect::<Vec<_>>()
        )));
    }
    let mut keys: Vec<(f64, MouthState)> = Vec::new();
    for record in records {
        let record = record.map_err(cell_error)?;
        let i = record.position().map_or(0, |p| p.line() as usize - 1);
        if record.iter().all(|c| c.trim().is_empty()) {
            continue;
        }
        let num = |c: usize, lo: f64, hi: f64| -> anyhow::Result<f64> {
            let cell = record.get(c).map_or("", |s| s.trim());
            cell.parse::<f64>()
                .ok()
                .filter(|x| (lo..=hi).contains(x))
                .ok_or_else(|| {
                    bad_input(anyhow::anyhow!(
                        "{source_name}:{}: column {} ({:?}): {:?} is not a number within {lo} to {hi}",
                        i + 1,
                        c + 1,
                        cut(&columns[c]),
                        cut(cell)
                    ))
                })
        };
        let t = num(0, 0.0, mouthpiece_lipsync::phones::MAX_TIME)? + offset;
        if keys.last().is_some_and(|(prev, _)| t <= *prev) {
            return Err(bad_input(anyhow::anyhow!(
                "{source_name}:{}: times must increase",
                i + 1
            )));
        }
        let mut m = MouthState::default();
        for (c, state) in &used {
            let w = num(*c, 0.0, 1.0)?;
            m.jaw += w * state.jaw;
            m.spread += w * state.spread;
            m.round += w * state.round;
            m.raise += w * state.raise;
            m.roll_in += w * state.roll_in;
        }
        keys.push((t, m));
    }
    if keys.is_empty() {
        return Err(bad_input(anyhow::anyhow!("{source_name}: no samples")));
    }
    Ok(keys)
}

#[cfg(test)]
mod tests {
    use super::*;
    use mouthpiece_lipsync::take::DEFAULT_CLASSES;
    use mouthpiece_lipsync::{ClassTable, SegmentTable};

    /// The shipped poses are the synthetic performer's (set `MOUTHPIECE_WRITE_POSES=1` to
    /// rewrite config/lipsync/poses.toml after changing the mouth model or the states).
    #[test]
    fn shipped_poses_are_derived_from_the_synthetic_mouth() {
        let derived = poses_from_synth().unwrap();
        if std::env::var_os("MOUTHPIECE_WRITE_POSES").is_some() {
            let path = concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../../config/lipsync/poses.toml"
            );
            let text = derived.to_toml_string(
                "Basic lip poses for lip sync: the neutral dots and each key pose's lip-dot\n\
                 displacements, performer mouth frame (x to the performer's left corner, y up,\n\
                 z out of the mouth), metres. Derived from the synthetic performer's mouth model\n\
                 (`mouth` = its state); regenerate with MOUTHPIECE_WRITE_POSES=1 cargo test -p\n\
                 mouthpiece shipped_poses. A booth can use its own (docs/lipsync.md).",
            );
            std::fs::write(path, text).unwrap();
        }
        let shipped = BasicPoses::from_toml_str(DEFAULT_POSES, "poses.toml").unwrap();
        assert_eq!(shipped.poses.len(), 5);
        let close = |a: &[[f64; 3]], b: &[[f64; 3]]| {
            a.len() == b.len()
                && a.iter()
                    .flatten()
                    .zip(b.iter().flatten())
                    .all(|(x, y)| (x - y).abs() < 1e-9)
        };
        assert!(close(&shipped.neutral_lip, &derived.neutral_lip));
        assert!(close(&shipped.forehead, &derived.forehead));
        for (s, d) in shipped.poses.iter().zip(&derived.poses) {
            assert_eq!(s.name, d.name);
            assert_eq!(s.mouth, d.mouth);
            assert!(close(&s.displacement, &d.displacement), "pose {}", s.name);
        }
        // The poses move the mouth the way their names say (mouth frame: y up, x left).
        let get = |n: &str| derived.poses.iter().find(|p| p.name == n).unwrap();
        assert!(
            get("open").displacement[9][1] < -0.005,
            "open: lower lip down"
        );
        assert!(
            get("spread").displacement[0][0] > 0.003,
            "spread: left corner out"
        );
        assert!(
            get("round").displacement[0][0] < -0.003,
            "round: left corner in"
        );
    }

    #[test]
    fn weights_csv_drives_the_synthetic_mouth() {
        let poses = BasicPoses::from_toml_str(DEFAULT_POSES, "poses.toml").unwrap();
        let csv = "t,phone,class,closed,open,spread,round,bite\n0.0,sil,sil,0,0,0,0,0\n0.5,aa,open,0,1,0,0,0\n";
        let keys = mouth_keys_from_weights(csv, "w.csv", &poses, 1.5).unwrap();
        assert_eq!(keys.len(), 2);
        assert_eq!(keys[0], (1.5, MouthState::default()));
        assert_eq!(keys[1].0, 2.0);
        assert!((keys[1].1.jaw - 0.2).abs() < 1e-12);
        let bad = csv.replace("0.5,aa", "0.5x,aa");
        let err = mouth_keys_from_weights(&bad, "w.csv", &poses, 0.0).unwrap_err();
        assert!(err.to_string().contains("w.csv:3"), "{err}");
    }

    #[test]
    fn absurd_weights_and_times_are_refused_naming_line_and_column() {
        // 1e308 and negative weights drove the synthetic mouth far outside its range.
        let poses = BasicPoses::from_toml_str(DEFAULT_POSES, "poses.toml").unwrap();
        let csv = "t,phone,class,closed,open,spread,round,bite\n0.0,sil,sil,0,0,0,0,0\n0.5,aa,open,0,1,0,0,0\n";
        for (from, to, column) in [
            (",0,1,0,0,0", ",0,1e308,0,0,0", "column 5 (\"open\")"),
            (",0,1,0,0,0", ",0,1,-0.5,0,0", "column 6 (\"spread\")"),
            ("0.5,aa", "NaN,aa", "column 1 (\"t\")"),
            ("0.5,aa", "1e300,aa", "column 1 (\"t\")"),
        ] {
            let bad = csv.replace(from, to);
            let err = mouth_keys_from_weights(&bad, "w.csv", &poses, 0.0).unwrap_err();
            let text = err.to_string();
            assert!(text.starts_with(&format!("w.csv:3: {column}")), "{text}");
        }
    }

    /// Names come from the user's files. A pose name holding a comma, a quote, a line break
    /// or a spreadsheet formula is refused where it is read (the name rule keeps every name
    /// one CSV column and one TOML key); text cells such as phones stay quoted and guarded,
    /// so a weights file keeps its header's columns and `synth --speech` reads it back.
    #[test]
    fn hostile_pose_names_are_refused_and_cells_keep_the_weights_csv_columns() {
        use mouthpiece_export::csv::quote;
        let hostile = "=HYPERLINK(\"x\"), open\nwide";
        let poses_text = DEFAULT_POSES.replace(
            "name = \"open\"",
            &format!("name = {}", toml::Value::String(hostile.into())),
        );
        let refused = BasicPoses::from_toml_str(&poses_text, "poses.toml").unwrap_err();
        assert!(
            format!("{refused:?}").contains("a pose name must be 1 to 64"),
            "{refused:?}"
        );
        let poses = BasicPoses::from_toml_str(DEFAULT_POSES, "poses.toml").unwrap();
        let names = ["closed", "open", "spread", "round", "bite"];
        let header: Vec<String> = names.iter().map(|n| quote(n)).collect();
        let csv = format!(
            "t,phone,class,{}\n0.0,sil,sil,0,0,0,0,0\n0.5,{},{},0,1,0,0,0\n",
            header.join(","),
            quote("a,\"a\""),
            quote("@open")
        );
        // Every record has the header's eight columns; no text cell starts a formula.
        let mut reader = ::csv::ReaderBuilder::new()
            .has_headers(false)
            .from_reader(csv.as_bytes());
        for record in reader.records() {
            let record = record.unwrap();
            assert_eq!(record.len(), 8, "{record:?}");
            assert!(
                record.iter().all(|c| !c.starts_with(['=', '+', '-', '@'])),
                "{record:?}"
            );
        }
        let keys = mouth_keys_from_weights(&csv, "w.csv", &poses, 0.0).unwrap();
        assert_eq!(keys.len(), 2);
        // Full weight on the open pose opens the jaw as the shipped open pose does.
        assert!((keys[1].1.jaw - 0.2).abs() < 1e-12, "{:?}", keys[1]);
    }

    /// A class named like a formula with a comma and a line break is refused where the class
    /// table is read; the writer's file reads back with its header's columns.
    #[test]
    fn hostile_class_names_are_refused_and_the_weights_keep_their_columns() {
        let hostile = "=cmd|' /C calc'!A0, \"x\"\ny";
        let hostile_classes = DEFAULT_CLASSES.replace(
            "name = \"bilabial\"",
            &format!("name = {}", toml::Value::String(hostile.into())),
        );
        let refused = ClassTable::from_toml_str(&hostile_classes, "classes.toml").unwrap_err();
        assert!(
            format!("{refused:?}").contains("a class name must be 1 to 64"),
            "{refused:?}"
        );
        let classes = ClassTable::from_toml_str(DEFAULT_CLASSES, "classes.toml").unwrap();
        let poses = BasicPoses::from_toml_str(DEFAULT_POSES, "poses.toml").unwrap();
        let order = poses.order_for(&classes, "poses.toml").unwrap();
        let tables = Tables {
            pose_name: "poses.toml".into(),
            segments: SegmentTable::generate(&classes),
            classes,
            poses,
            order,
        };
        let phones = vec![PhoneSpan {
            start: 0.0,
            end: 0.1,
            phone: "m".into(),
            line: 1,
        }];
        let k = tables.classes.poses.len();
        let weights = Weights {
            fps: 10.0,
            poses: k,
            values: vec![0.0; k],
            owner: vec![0],
        };
        let mut out = Vec::new();
        write_weights_csv(&weights, &phones, &tables, &mut out).unwrap();
        let text = String::from_utf8(out).unwrap();
        let mut reader = ::csv::ReaderBuilder::new()
            .has_headers(false)
            .from_reader(text.as_bytes());
        let records: Vec<_> = reader.records().map(Result::unwrap).collect();
        assert_eq!(records.len(), 2, "{text}");
        assert!(records.iter().all(|r| r.len() == 3 + k), "{text}");
        assert_eq!(&records[1][2], "bilabial", "{text}");
    }
}
