//! `mouthpiece retarget`: 3D dots (JSONL) → character mouth points (JSONL).
//!
//! Neutral pose: the lines flagged `"neutral": true`, else the first line.
//! - Input from a file: two passes. The first validates every line (JSON, dot names, finite
//!   numbers, time order) and collects the neutral lines wherever they are; the second writes
//!   the output. A bad line is reported before anything is written.
//! - Input from stdin (or a pipe given by path): one pass. The neutral lines must come first (they are the only lines
//!   held in memory); output streams line by line, flushed per line. A bad line stops the run
//!   with exit code 2 after the lines before it were written, each of them complete.
//!
//! Output to a file goes to a temporary file beside it, renamed into place only on success.

use std::fs::File;
use std::io::{self, BufRead, BufReader, BufWriter, Seek, Write};
use std::path::{Path, PathBuf};

use anyhow::Context as _;
use mouthpiece_pipeline::RetargetSettings;
use mouthpiece_retarget::jsonl::{InputLine, OutputLine};
use mouthpiece_retarget::{
    Character, CharacterSettings, MissingDots, NeutralAccumulator, OneEuroParams, PerformerDots,
    PerformerLayout, RetargetConfig, Retargeter, Rig, RigSettings,
};

use crate::exit::bad_input;
use mouthpiece_export::PendingFile;

/// The shape smoothing: one enum for the configuration's `[retarget] smooth` and `--smooth`.
pub use mouthpiece_pipeline::Smooth;

/// `--smooth`: the names of [`Smooth::ALL`], listed in `--help`.
pub fn smooth_arg() -> impl clap::builder::TypedValueParser<Value = Smooth> {
    use clap::builder::TypedValueParser as _;
    clap::builder::PossibleValuesParser::new(Smooth::ALL.map(|(name, _)| name))
        .map(|name| Smooth::from_name(&name).expect("a listed name"))
}

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Character file (TOML).
    #[arg(long)]
    pub character: PathBuf,
    /// Input JSONL, `-` for stdin.
    #[arg(long)]
    pub input: PathBuf,
    /// Output JSONL, `-` for stdout.
    #[arg(long)]
    pub out: PathBuf,
    /// Shape smoothing that makes each line's `curve`.
    #[arg(long, value_parser = smooth_arg(), default_value = "bspline")]
    pub smooth: Smooth,
    /// Moving average: neighbours on each side.
    #[arg(long, default_value_t = 1)]
    pub ma_radius: usize,
    /// Exponential moving average: weight factor per step along the loop, in (0, 1].
    #[arg(long, default_value_t = 0.5)]
    pub ma_alpha: f64,
    /// B-spline: curve samples per span (per character point).
    #[arg(long, default_value_t = 8)]
    pub samples_per_span: usize,
    /// Temporal One Euro filter on the output points: `MINCUTOFF,BETA` (Hz, s/unit).
    /// Off unless given.
    #[arg(long, value_name = "MINCUTOFF,BETA", value_parser = parse_one_euro)]
    pub one_euro: Option<OneEuroParams>,
    /// Seconds a missing lip dot keeps its last value (confidence 0).
    #[arg(long, default_value_t = 0.5, value_parser = parse_seconds)]
    pub hold: f64,
    /// Seconds over which a missing dot then returns to neutral.
    #[arg(long, default_value_t = 0.5, value_parser = parse_seconds)]
    pub decay: f64,
    /// Turn the character's head to a viewpoint `X,Y,Z` (character model frame) from the
    /// first line at time `T` on (`X,Y,Z@T`; from the start without `@T`). Without it the
    /// head follows the performer's (docs/head.md).
    #[arg(long, value_name = "X,Y,Z[@T]", value_parser = parse_look_at)]
    pub look_at: Option<LookAt>,
}

/// `--look-at`: a viewpoint and when it is set.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LookAt {
    /// Character model frame.
    pub point: [f64; 3],
    /// Set before the first line whose `t` is at least this.
    pub from_t: f64,
}

/// Latest `--look-at` time `@T`, seconds either side of 0 (about 32 years).
pub const MAX_LOOK_AT_T: f64 = 1e9;

/// Parses `X,Y,Z` or `X,Y,Z@T`.
pub fn parse_look_at(s: &str) -> Result<LookAt, String> {
    let (xyz, from_t) = match s.split_once('@') {
        Some((xyz, t)) => {
            let t: f64 = t.trim().parse().map_err(|e| format!("time `{t}`: {e}"))?;
            if !(t.is_finite() && t.abs() <= MAX_LOOK_AT_T) {
                return Err(format!(
                    "time `{t}` is not a number of seconds within ±{MAX_LOOK_AT_T:e}"
                ));
            }
            (xyz, t)
        }
        None => (s, f64::NEG_INFINITY),
    };
    let parts: Vec<&str> = xyz.split(',').collect();
    if parts.len() != 3 {
        return Err("expected X,Y,Z or X,Y,Z@T, e.g. 0,0.1,2@1.5".into());
    }
    let mut point = [0.0; 3];
    for (dst, part) in point.iter_mut().zip(&parts) {
        let v: f64 = part
            .trim()
            .parse()
            .map_err(|e| format!("coordinate `{part}`: {e}"))?;
        if !v.is_finite() {
            return Err(format!("coordinate `{part}` is not finite"));
        }
        *dst = v;
    }
    Ok(LookAt { point, from_t })
}

/// A duration flag: a finite number of seconds, 0 or more (checked with the other flags,
/// before any input is read).
fn parse_seconds(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if MissingDots::valid_seconds(v) => Ok(v),
        _ => Err(format!(
            "`{s}` is not a number of seconds within 0 to {}",
            MissingDots::MAX_SECONDS
        )),
    }
}

fn parse_one_euro(s: &str) -> Result<OneEuroParams, String> {
    let (a, b) = s
        .split_once(',')
        .ok_or("expected MINCUTOFF,BETA, e.g. 1.0,0.007")?;
    let min_cutoff: f64 = a
        .trim()
        .parse()
        .map_err(|e| format!("MINCUTOFF `{a}`: {e}"))?;
    let beta: f64 = b.trim().parse().map_err(|e| format!("BETA `{b}`: {e}"))?;
    OneEuroParams::new(min_cutoff, beta).map_err(|e| e.to_string())
}

impl Args {
    fn config(&self) -> anyhow::Result<RetargetConfig> {
        // The one mapping from the option to the shape smoothing: the configuration's.
        let smoothing = RetargetSettings {
            smooth: self.smooth,
            ma_radius: self.ma_radius,
            ma_alpha: self.ma_alpha,
            samples_per_span: self.samples_per_span,
            one_euro: None,
        }
        .smoothing();
        smoothing.validate().map_err(bad_input)?;
        Ok(RetargetConfig {
            missing: MissingDots {
                hold: self.hold,
                decay: self.decay,
            },
            character: CharacterSettings {
                smoothing,
                one_euro: self.one_euro,
            },
        })
    }
}

fn is_dash(p: &Path) -> bool {
    p.as_os_str() == "-"
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let config = args.config()?;
    let character_src =
        mouthpiece_config::read_bounded(&args.character, mouthpiece_config::MAX_CONFIG_FILE_BYTES)
            .with_context(|| format!("cannot read character file {}", args.character.display()))
            .map_err(bad_input)?;
    let character = Character::from_toml_str(&character_src)
        .with_context(|| format!("character file {}", args.character.display()))
        .map_err(bad_input)?;
    tracing::info!(character = %character.name, points = character.len(), "character loaded");
    if let Some(look) = &args.look_at {
        let in_reach = character
            .head_driver()
            .look_at(Some(look.point.into()))
            .with_context(|| format!("--look-at for character {}", character.name))
            .map_err(bad_input)?;
        tracing::info!(point = ?look.point, in_reach, "viewpoint");
    }
    let mut look_at = args.look_at;

    let input_name = if is_dash(&args.input) {
        "stdin".to_string()
    } else {
        args.input.display().to_string()
    };
    let result = if is_dash(&args.input) {
        let stdin = io::stdin().lock();
        let mut out = Output::open(&args.out, true)?;
        let written = retarget_stream(
            stdin,
            &input_name,
            character,
            config,
            &mut look_at,
            &mut out,
        );
        written.and_then(|n| out.finish().map(|()| n))
    } else {
        let file = File::open(&args.input)
            .with_context(|| format!("cannot open input {}", args.input.display()))
            .map_err(bad_input)?;
        let regular = file.metadata().is_ok_and(|m| m.is_file());
        let mut reader = BufReader::new(file);
        if regular {
            let neutral = scan(&mut reader, &input_name, character.len())?;
            reader
                .rewind()
                .with_context(|| format!("cannot rewind {input_name}"))?;
            let mut out = Output::open(&args.out, false)?;
            let written = retarget_file(
                reader,
                &input_name,
                character,
                config,
                neutral,
                &mut look_at,
                &mut out,
            );
            written.and_then(|n| out.finish().map(|()| n))
        } else {
            // A pipe or device given by path: it cannot be read twice, so stream it like stdin.
            let mut out = Output::open(&args.out, true)?;
            let written = retarget_stream(
                reader,
                &input_name,
                character,
                config,
                &mut look_at,
                &mut out,
            );
            written.and_then(|n| out.finish().map(|()| n))
        }
    };
    match result {
        Ok(lines) => {
            tracing::info!(lines, "retarget done");
            Ok(())
        }
        Err(e) if is_broken_pipe(&e) => Ok(()),
        Err(e) => Err(e),
    }
}

/// A reader downstream went away (`| head`): stop quietly, like other Unix tools.
fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        let kind = c
            .downcast_ref::<io::Error>()
            .map(io::Error::kind)
            .or_else(|| {
                c.downcast_ref::<serde_json::Error>()
                    .and_then(|j| j.io_error_kind())
            });
        kind == Some(io::ErrorKind::BrokenPipe)
    })
}

/// Checks each line as it is read: JSON shape, dot names, finite numbers, time order.
struct LineChecker<'a> {
    input_name: &'a str,
    lip_dots: usize,
    previous_t: Option<f64>,
    scratch: PerformerDots,
}

impl<'a> LineChecker<'a> {
    fn new(input_name: &'a str, lip_dots: usize) -> Self {
        Self {
            input_name,
            lip_dots,
            previous_t: None,
            scratch: PerformerDots::default(),
        }
    }

    fn at(&self, line_no: usize) -> String {
        format!("{} line {line_no}", self.input_name)
    }

    /// The parsed line, or `None` for a blank line.
    fn check(&mut self, line_no: usize, text: &str) -> anyhow::Result<Option<InputLine>> {
        if text.trim().is_empty() {
            return Ok(None);
        }
        let line = InputLine::parse(text)
            .with_context(|| self.at(line_no))
            .map_err(bad_input)?;
        let layout = PerformerLayout {
            lip_dots: self.lip_dots,
            forehead_dots: line.forehead_count(),
        };
        line.dots_into(layout, &mut self.scratch)
            .with_context(|| self.at(line_no))
            .map_err(bad_input)?;
        if let Some(previous) = self.previous_t {
            if line.t < previous {
                return Err(bad_input(
                    anyhow::Error::new(mouthpiece_retarget::Error::TimeBackwards {
                        previous,
                        t: line.t,
                    })
                    .context(self.at(line_no)),
                ));
            }
        }
        self.previous_t = Some(line.t);
        Ok(Some(line))
    }
}

/// Reads lines, counting them (1-based) and reusing one buffer.
struct Lines<R> {
    reader: R,
    buf: String,
    line_no: usize,
}

impl<R: BufRead> Lines<R> {
    fn new(reader: R) -> Self {
        Self {
            reader,
            buf: String::new(),
            line_no: 0,
        }
    }

    fn next_line(&mut self, input_name: &str) -> anyhow::Result<Option<(usize, &str)>> {
        self.buf.clear();
        let n = self
            .reader
            .read_line(&mut self.buf)
            .with_context(|| format!("{input_name} line {}", self.line_no + 1))
            .map_err(bad_input)?;
        if n == 0 {
            return Ok(None);
        }
        self.line_no += 1;
        Ok(Some((
            self.line_no,
            self.buf.trim_end_matches(['\n', '\r']),
        )))
    }
}

/// The neutral lines found by a pass over the input.
struct NeutralLines {
    lines: Vec<InputLine>,
    /// Line numbers, for messages.
    first: usize,
    last: usize,
    flagged: bool,
}

impl NeutralLines {
    fn describe(&self, input_name: &str) -> String {
        let how = if self.flagged {
            "flagged \"neutral\": true"
        } else {
            "the first line"
        };
        if self.first == self.last {
            format!("neutral pose from {input_name} line {} ({how})", self.first)
        } else {
            format!(
                "neutral pose from {input_name} lines {}..{} ({how})",
                self.first, self.last
            )
        }
    }

    fn build(
        &self,
        input_name: &str,
        character: Character,
        config: RetargetConfig,
    ) -> anyhow::Result<(Retargeter, PerformerLayout)> {
        let lip_dots = character.len();
        let forehead_dots = self
            .lines
            .iter()
            .map(InputLine::forehead_count)
            .max()
            .unwrap_or(0);
        let layout = PerformerLayout {
            lip_dots,
            forehead_dots,
        };
        let mut acc = NeutralAccumulator::new(layout);
        let mut dots = PerformerDots::new(layout);
        for line in &self.lines {
            line.dots_into(layout, &mut dots).map_err(bad_input)?;
            acc.push(&dots).map_err(bad_input)?;
        }
        let context = || self.describe(input_name);
        let neutral = acc.finish().with_context(context).map_err(bad_input)?;
        tracing::info!(
            frames = neutral.frames,
            width_m = neutral.mouth_width(),
            "neutral pose"
        );
        let retargeter = Retargeter::new(character, neutral, config)
            .with_context(context)
            .map_err(bad_input)?;
        Ok((retargeter, layout))
    }
}

/// First pass over a file: validates every line, collects the neutral ones.
fn scan<R: BufRead>(reader: R, input_name: &str, lip_dots: usize) -> anyhow::Result<NeutralLines> {
    let mut checker = LineChecker::new(input_name, lip_dots);
    let mut lines = Lines::new(reader);
    let mut flagged = NeutralLines {
        lines: Vec::new(),
        first: 0,
        last: 0,
        flagged: true,
    };
    let mut first = None;
    while let Some((line_no, text)) = lines.next_line(input_name)? {
        let Some(line) = checker.check(line_no, text)? else {
            continue;
        };
        if line.neutral {
            if flagged.lines.is_empty() {
                flagged.first = line_no;
            }
            flagged.last = line_no;
            flagged.lines.push(line);
        } else if first.is_none() && flagged.lines.is_empty() {
            first = Some((line_no, line));
        }
    }
    if !flagged.lines.is_empty() {
        return Ok(flagged);
    }
    match first {
        Some((line_no, line)) => Ok(NeutralLines {
            lines: vec![line],
            first: line_no,
            last: line_no,
            flagged: false,
        }),
        None => Err(bad_input(anyhow::anyhow!("{input_name} has no lines"))),
    }
}

/// Second pass over a validated file: one output line per input line.
fn retarget_file<R: BufRead>(
    reader: R,
    input_name: &str,
    character: Character,
    config: RetargetConfig,
    neutral: NeutralLines,
    look_at: &mut Option<LookAt>,
    out: &mut Output,
) -> anyhow::Result<u64> {
    let mut line_out = OutputLine::for_character(&character, &config.character.smoothing);
    let (mut retargeter, layout) = neutral.build(input_name, character, config)?;
    drop(neutral);
    let mut checker = LineChecker::new(input_name, layout.lip_dots);
    let mut dots = PerformerDots::new(layout);
    let mut lines = Lines::new(reader);
    let mut seq = 0;
    let mut rig = None;
    while let Some((line_no, text)) = lines.next_line(input_name)? {
        let Some(line) = checker.check(line_no, text)? else {
            continue;
        };
        emit(
            &mut retargeter,
            &mut rig,
            &line,
            layout,
            &mut dots,
            &mut line_out,
            seq,
            look_at,
            out,
        )
        .with_context(|| format!("{input_name} line {line_no}"))?;
        seq += 1;
    }
    Ok(seq)
}

/// Single pass over a stream: the leading neutral block is buffered, the rest streams.
fn retarget_stream<R: BufRead>(
    reader: R,
    input_name: &str,
    character: Character,
    config: RetargetConfig,
    look_at: &mut Option<LookAt>,
    out: &mut Output,
) -> anyhow::Result<u64> {
    let mut line_out = OutputLine::for_character(&character, &config.character.smoothing);
    let mut checker = LineChecker::new(input_name, character.len());
    let mut lines = Lines::new(reader);
    let mut pending = NeutralLines {
        lines: Vec::new(),
        first: 0,
        last: 0,
        flagged: true,
    };
    let mut pending_numbers = Vec::new();
    let mut character = Some(character);
    let mut state: Option<(Retargeter, PerformerLayout, PerformerDots)> = None;
    let mut seq = 0;
    let mut rig = None;
    loop {
        let next = lines.next_line(input_name)?;
        let line = match next {
            Some((line_no, text)) => match checker.check(line_no, text)? {
                Some(line) => Some((line_no, line)),
                None => continue,
            },
            None => None,
        };
        if state.is_none() {
            // Still in the neutral block?
            if let Some((line_no, l)) = &line {
                if l.neutral {
                    if pending.lines.is_empty() {
                        pending.first = *line_no;
                    }
                    pending.last = *line_no;
                    pending.lines.push(l.clone());
                    pending_numbers.push(*line_no);
                    continue;
                }
            }
            if pending.lines.is_empty() {
                // No flagged block: the first line is the neutral pose (and is output too).
                let Some((line_no, l)) = &line else {
                    return Err(bad_input(anyhow::anyhow!("{input_name} has no lines")));
                };
                pending = NeutralLines {
                    lines: vec![l.clone()],
                    first: *line_no,
                    last: *line_no,
                    flagged: false,
                };
            }
            let (retargeter, layout) =
                pending.build(input_name, character.take().expect("built once"), config)?;
            let mut s = (retargeter, layout, PerformerDots::new(layout));
            if pending.flagged {
                for (l, &line_no) in pending.lines.iter().zip(&pending_numbers) {
                    emit(
                        &mut s.0,
                        &mut rig,
                        l,
                        s.1,
                        &mut s.2,
                        &mut line_out,
                        seq,
                        look_at,
                        out,
                    )
                    .with_context(|| format!("{input_name} line {line_no}"))?;
                    seq += 1;
                }
            }
            pending = NeutralLines {
                lines: Vec::new(),
                first: 0,
                last: 0,
                flagged: true,
            };
            pending_numbers = Vec::new();
            state = Some(s);
        }
        let Some((line_no, l)) = line else { break };
        if l.neutral {
            return Err(bad_input(anyhow::anyhow!(
                "{input_name} line {line_no}: a \"neutral\" line after the neutral block; on \
                 stdin the neutral lines must come first (give the input as a file to allow \
                 neutral lines anywhere)"
            )));
        }
        let (retargeter, layout, dots) = state.as_mut().expect("set above");
        emit(
            retargeter,
            &mut rig,
            &l,
            *layout,
            dots,
            &mut line_out,
            seq,
            look_at,
            out,
        )
        .with_context(|| format!("{input_name} line {line_no}"))?;
        seq += 1;
    }
    Ok(seq)
}

#[allow(clippy::too_many_arguments)]
fn emit(
    retargeter: &mut Retargeter,
    rig: &mut Option<Rig>,
    line: &InputLine,
    layout: PerformerLayout,
    dots: &mut PerformerDots,
    line_out: &mut OutputLine,
    seq: u64,
    look_at: &mut Option<LookAt>,
    out: &mut Output,
) -> anyhow::Result<()> {
    line.dots_into(layout, dots).map_err(bad_input)?;
    if rig.is_none() {
        // The rig of this neutral pose (docs/rig.md); a layout it cannot rig has no `rig`.
        *rig = Rig::new(retargeter.stabiliser().neutral(), RigSettings::default()).ok();
    }
    if let Some(look) = look_at.take_if(|l| line.t >= l.from_t) {
        retargeter
            .character_mut()
            .look_at(Some(look.point.into()))
            .map_err(bad_input)?;
    }
    let result = retargeter.step(line.t, dots).map_err(bad_input)?;
    line_out.update(seq, &result);
    if let Some(r) = rig {
        r.step(result.performer);
        // With the character's own ranges where it has them (docs/rig.md).
        r.output_for(
            &retargeter.character().character().rig_ranges,
            line_out.rig.get_or_insert_with(Default::default),
        );
    }
    out.write_line(line_out)
}

/// Where the output goes: stdout, or a file written under a temporary name and moved into
/// place by `finish` ([`PendingFile`]).
struct Output {
    sink: Sink,
    flush_each_line: bool,
}

enum Sink {
    Stdout(BufWriter<io::Stdout>),
    File(PendingFile),
}

impl Output {
    fn open(path: &Path, streaming: bool) -> anyhow::Result<Self> {
        let sink = if is_dash(path) {
            Sink::Stdout(BufWriter::new(io::stdout()))
        } else {
            Sink::File(
                PendingFile::create(path)
                    .with_context(|| format!("cannot create output {}", path.display()))
                    .map_err(bad_input)?,
            )
        };
        Ok(Self {
            flush_each_line: streaming && matches!(sink, Sink::Stdout(_)),
            sink,
        })
    }

    fn write_line(&mut self, line: &OutputLine) -> anyhow::Result<()> {
        let writer: &mut dyn Write = match &mut self.sink {
            Sink::Stdout(w) => w,
            Sink::File(f) => f,
        };
        serde_json::to_writer(&mut *writer, line).context("writing output")?;
        writer.write_all(b"\n").context("writing output")?;
        if self.flush_each_line {
            writer.flush().context("writing output")?;
        }
        Ok(())
    }

    fn finish(self) -> anyhow::Result<()> {
        match self.sink {
            Sink::Stdout(mut w) => w.flush().context("writing output"),
            Sink::File(f) => f.commit().context("cannot move the output into place"),
        }
    }
}
