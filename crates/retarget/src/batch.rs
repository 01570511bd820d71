//! Batch retargeting: 3D dots as JSON lines in, the character's mouth points (and its rig) as
//! JSON lines out, one output line per input line (`mouthpiece retarget`, docs/retarget.md).
//!
//! The neutral pose is the lines flagged `"neutral": true`, else the first line.
//! - [`retarget_file`]: input that can be read twice. The first pass ([`scan`]) checks every
//!   line (JSON, dot names, finite numbers, time order) and collects the neutral lines
//!   wherever they are; the second writes the output. A bad line is reported before anything
//!   is written.
//! - [`retarget_stream`]: input read once (stdin, a pipe). The neutral lines must come first
//!   (they are the only lines held in memory); output streams line by line. A bad line stops
//!   the run after the lines before it were written, each of them complete.
//!
//! Where the lines go is the caller's: a [`LineSink`] takes each output line.

use std::io::{self, BufRead};

use crate::jsonl::{InputLine, OutputLine};
use crate::{
    Character, NeutralAccumulator, PerformerDots, PerformerLayout, RetargetConfig, Retargeter, Rig,
    RigSettings,
};

/// A viewpoint for the character's head, set from a given time on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LookAt {
    /// Character model frame.
    pub point: [f64; 3],
    /// Set before the first line whose `t` is at least this.
    pub from_t: f64,
}

/// Latest look-at time, seconds either side of 0 (about 32 years).
pub const MAX_LOOK_AT_T: f64 = 1e9;

/// Why a batch stopped.
#[derive(Debug, thiserror::Error)]
pub enum BatchError {
    /// The input is wrong: a line, the neutral pose, or a request on a line. `at` names the
    /// input and the line.
    #[error("{at}")]
    Input {
        at: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// The input has no lines at all.
    #[error("{0} has no lines")]
    Empty(String),
    /// Writing an output line failed (a full disk; a reader that went away).
    #[error("writing output")]
    Output(#[source] io::Error),
}

impl BatchError {
    /// Whether the user's input is at fault (the command's exit code 2), not the output.
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, Self::Output(_))
    }

    /// The reader downstream went away (`| head`): callers stop quietly, like other Unix tools.
    pub fn is_broken_pipe(&self) -> bool {
        matches!(self, Self::Output(e) if e.kind() == io::ErrorKind::BrokenPipe)
    }

    fn input(
        at: impl Into<String>,
        source: impl Into<Box<dyn std::error::Error + Send + Sync>>,
    ) -> Self {
        Self::Input {
            at: at.into(),
            source: source.into(),
        }
    }
}

/// Where output lines go.
pub trait LineSink {
    fn write_line(&mut self, line: &OutputLine) -> io::Result<()>;
}

impl<F: FnMut(&OutputLine) -> io::Result<()>> LineSink for F {
    fn write_line(&mut self, line: &OutputLine) -> io::Result<()> {
        self(line)
    }
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
        at_line(self.input_name, line_no)
    }

    /// The parsed line, or `None` for a blank line.
    fn check(&mut self, line_no: usize, text: &str) -> Result<Option<InputLine>, BatchError> {
        if text.trim().is_empty() {
            return Ok(None);
        }
        let line = InputLine::parse(text).map_err(|e| BatchError::input(self.at(line_no), e))?;
        let layout = PerformerLayout {
            lip_dots: self.lip_dots,
            forehead_dots: line.forehead_count(),
        };
        line.dots_into(layout, &mut self.scratch)
            .map_err(|e| BatchError::input(self.at(line_no), e))?;
        if let Some(previous) = self.previous_t {
            if line.t < previous {
                return Err(BatchError::input(
                    self.at(line_no),
                    crate::Error::TimeBackwards {
                        previous,
                        t: line.t,
                    },
                ));
            }
        }
        self.previous_t = Some(line.t);
        Ok(Some(line))
    }
}

fn at_line(input_name: &str, line_no: usize) -> String {
    format!("{input_name} line {line_no}")
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

    fn next_line(&mut self, input_name: &str) -> Result<Option<(usize, &str)>, BatchError> {
        self.buf.clear();
        let n = crate::jsonl::read_line_limited(
            &mut self.reader,
            &mut self.buf,
            crate::jsonl::MAX_LINE_BYTES,
        )
        .map_err(|e| BatchError::input(at_line(input_name, self.line_no + 1), e))?;
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

/// The neutral lines found in the input.
pub struct NeutralLines {
    lines: Vec<InputLine>,
    /// Line numbers, for messages.
    first: usize,
    last: usize,
    flagged: bool,
}

impl NeutralLines {
    fn flagged_block() -> Self {
        Self {
            lines: Vec::new(),
            first: 0,
            last: 0,
            flagged: true,
        }
    }

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
    ) -> Result<(Retargeter, PerformerLayout), BatchError> {
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
        let context = || self.describe(input_name);
        let mut acc = NeutralAccumulator::new(layout);
        let mut dots = PerformerDots::new(layout);
        for line in &self.lines {
            line.dots_into(layout, &mut dots)
                .map_err(|e| BatchError::input(context(), e))?;
            acc.push(&dots)
                .map_err(|e| BatchError::input(context(), e))?;
        }
        let neutral = acc.finish().map_err(|e| BatchError::input(context(), e))?;
        tracing::info!(
            frames = neutral.frames,
            width_m = neutral.mouth_width(),
            "neutral pose"
        );
        let retargeter = Retargeter::new(character, neutral, config)
            .map_err(|e| BatchError::input(context(), e))?;
        Ok((retargeter, layout))
    }
}

/// First pass over input that can be read again: checks every line, collects the neutral
/// ones.
pub fn scan<R: BufRead>(
    reader: R,
    input_name: &str,
    lip_dots: usize,
) -> Result<NeutralLines, BatchError> {
    let mut checker = LineChecker::new(input_name, lip_dots);
    let mut lines = Lines::new(reader);
    let mut flagged = NeutralLines::flagged_block();
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
        None => Err(BatchError::Empty(input_name.to_string())),
    }
}

/// What every output line is made with: the retargeter, the rig of its neutral pose, the
/// pending viewpoint, and the reused buffers.
struct Emitter<'a> {
    retargeter: Retargeter,
    layout: PerformerLayout,
    dots: PerformerDots,
    rig: Option<Rig>,
    line_out: OutputLine,
    seq: u64,
    look_at: Option<LookAt>,
    sink: &'a mut dyn LineSink,
}

impl<'a> Emitter<'a> {
    fn new(
        retargeter: Retargeter,
        layout: PerformerLayout,
        line_out: OutputLine,
        look_at: Option<LookAt>,
        sink: &'a mut dyn LineSink,
    ) -> Self {
        Self {
            retargeter,
            layout,
            dots: PerformerDots::new(layout),
            rig: None,
            line_out,
            seq: 0,
            look_at,
            sink,
        }
    }

    fn emit(&mut self, line: &InputLine, at: impl Fn() -> String) -> Result<(), BatchError> {
        line.dots_into(self.layout, &mut self.dots)
            .map_err(|e| BatchError::input(at(), e))?;
        if self.rig.is_none() {
            // The rig of this neutral pose (docs/rig.md); a layout it cannot rig has no `rig`.
            self.rig = Rig::new(
                self.retargeter.stabiliser().neutral(),
                RigSettings::default(),
            )
            .ok();
        }
        if let Some(look) = self.look_at.take_if(|l| line.t >= l.from_t) {
            self.retargeter
                .character_mut()
                .look_at(Some(look.point.into()))
                .map_err(|e| BatchError::input(at(), e))?;
        }
        let result = self
            .retargeter
            .step(line.t, &self.dots)
            .map_err(|e| BatchError::input(at(), e))?;
        self.line_out.update(self.seq, &result);
        if let Some(r) = &mut self.rig {
            r.step(result.performer);
            // With the character's own ranges where it has them (docs/rig.md).
            r.output_for(
                &self.retargeter.character().character().rig_ranges,
                self.line_out.rig.get_or_insert_with(Default::default),
            );
        }
        self.sink
            .write_line(&self.line_out)
            .map_err(BatchError::Output)?;
        self.seq += 1;
        Ok(())
    }
}

/// Second pass over input that [`scan`] checked: one output line per input line. Returns
/// how many lines were written.
pub fn retarget_file<R: BufRead>(
    reader: R,
    input_name: &str,
    character: Character,
    config: RetargetConfig,
    neutral: NeutralLines,
    look_at: Option<LookAt>,
    sink: &mut dyn LineSink,
) -> Result<u64, BatchError> {
    let line_out = OutputLine::for_character(&character, &config.character.smoothing);
    let (retargeter, layout) = neutral.build(input_name, character, config)?;
    drop(neutral);
    let mut checker = LineChecker::new(input_name, layout.lip_dots);
    let mut out = Emitter::new(retargeter, layout, line_out, look_at, sink);
    let mut lines = Lines::new(reader);
    while let Some((line_no, text)) = lines.next_line(input_name)? {
        let Some(line) = checker.check(line_no, text)? else {
            continue;
        };
        out.emit(&line, || at_line(input_name, line_no))?;
    }
    Ok(out.seq)
}

/// One pass over a stream: the leading neutral block is held, the rest streams. Returns how
/// many lines were written.
pub fn retarget_stream<R: BufRead>(
    reader: R,
    input_name: &str,
    character: Character,
    config: RetargetConfig,
    look_at: Option<LookAt>,
    sink: &mut dyn LineSink,
) -> Result<u64, BatchError> {
    let line_out = OutputLine::for_character(&character, &config.character.smoothing);
    let mut checker = LineChecker::new(input_name, character.len());
    let mut lines = Lines::new(reader);
    let mut pending = NeutralLines::flagged_block();
    let mut pending_numbers = Vec::new();
    let mut start = Some((character, config, line_out, look_at, sink));
    let mut out: Option<Emitter> = None;
    loop {
        let line = match lines.next_line(input_name)? {
            Some((line_no, text)) => match checker.check(line_no, text)? {
                Some(line) => Some((line_no, line)),
                None => continue,
            },
            None => None,
        };
        if out.is_none() {
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
                    return Err(BatchError::Empty(input_name.to_string()));
                };
                pending = NeutralLines {
                    lines: vec![l.clone()],
                    first: *line_no,
                    last: *line_no,
                    flagged: false,
                };
            }
            let (character, config, line_out, look_at, sink) = start.take().expect("started once");
            let (retargeter, layout) = pending.build(input_name, character, config)?;
            let mut emitter = Emitter::new(retargeter, layout, line_out, look_at, sink);
            if pending.flagged {
                for (l, &line_no) in pending.lines.iter().zip(&pending_numbers) {
                    emitter.emit(l, || at_line(input_name, line_no))?;
                }
            }
            pending = NeutralLines::flagged_block();
            pending_numbers = Vec::new();
            out = Some(emitter);
        }
        let Some((line_no, l)) = line else { break };
        if l.neutral {
            return Err(BatchError::input(
                at_line(input_name, line_no),
                "a \"neutral\" line after the neutral block; on stdin the neutral lines must \
                 come first (give the input as a file to allow neutral lines anywhere)",
            ));
        }
        let emitter = out.as_mut().expect("set above");
        emitter.emit(&l, || at_line(input_name, line_no))?;
    }
    Ok(out.map_or(0, |o| o.seq))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    /// A small performer: `n` lines, the first `neutral` of them flagged.
    fn performer(n: usize, neutral: usize) -> String {
        let mut text = String::new();
        for i in 0..n {
            let open = if i >= neutral {
                0.004 * (i as f64 * 0.7).sin()
            } else {
                0.0
            };
            let mut points = serde_json::Map::new();
            for k in 0..12 {
                let a = k as f64 / 12.0 * std::f64::consts::TAU;
                let y = -0.01 * a.sin() + if a.sin() < 0.0 { open } else { 0.0 };
                let v = [0.025 * a.cos(), y, 0.6 - 0.005 * a.sin().abs()];
                points.insert(format!("D{}", k + 1), serde_json::json!(v));
            }
            for (k, v) in [[-0.03, -0.1, 0.62], [0.03, -0.1, 0.62], [0.0, -0.12, 0.625]]
                .iter()
                .enumerate()
            {
                points.insert(format!("F{}", k + 1), serde_json::json!(v));
            }
            let mut line = serde_json::json!({"t": i as f64 / 30.0, "points": points});
            if i < neutral {
                line["neutral"] = serde_json::Value::Bool(true);
            }
            text.push_str(&line.to_string());
            text.push('\n');
        }
        text
    }

    fn human() -> Character {
        Character::from_toml_str(include_str!("../../../config/characters/human.toml")).unwrap()
    }

    fn collect(lines: &mut Vec<String>) -> impl FnMut(&OutputLine) -> io::Result<()> + '_ {
        |line| {
            lines.push(serde_json::to_string(line)?);
            Ok(())
        }
    }

    /// `input` retargeted onto the human as a stream named `name`.
    fn stream(input: &str, name: &str, sink: &mut dyn LineSink) -> Result<u64, BatchError> {
        retarget_stream(
            Cursor::new(input),
            name,
            human(),
            RetargetConfig::default(),
            None,
            sink,
        )
    }

    #[test]
    fn a_file_and_a_stream_give_the_same_lines() {
        let input = performer(20, 3);
        let mut from_file = Vec::new();
        let neutral = scan(Cursor::new(&input), "in", 12).unwrap();
        let n = retarget_file(
            Cursor::new(&input),
            "in",
            human(),
            RetargetConfig::default(),
            neutral,
            None,
            &mut collect(&mut from_file),
        )
        .unwrap();
        let mut from_stream = Vec::new();
        let m = stream(&input, "in", &mut collect(&mut from_stream)).unwrap();
        assert_eq!((n, m), (20, 20));
        assert_eq!(from_file, from_stream);
        assert!(from_file[10].contains("\"rig\""), "{}", from_file[10]);
    }

    #[test]
    fn a_late_neutral_line_is_bad_input_on_a_stream_and_names_its_line() {
        let mut input = performer(6, 2);
        input.push_str(&performer(1, 1));
        let mut out = Vec::new();
        let e = stream(&input, "stdin", &mut collect(&mut out)).unwrap_err();
        assert!(e.is_bad_input());
        assert_eq!(e.to_string(), "stdin line 7");
        assert_eq!(out.len(), 6, "the lines before it were written");
    }

    #[test]
    fn a_failing_sink_is_not_bad_input() {
        let input = performer(4, 1);
        let mut broken =
            |_: &OutputLine| -> io::Result<()> { Err(io::ErrorKind::BrokenPipe.into()) };
        let e = stream(&input, "stdin", &mut broken).unwrap_err();
        assert!(!e.is_bad_input() && e.is_broken_pipe(), "{e:?}");
        let e = stream("", "stdin", &mut broken).unwrap_err();
        assert!(e.is_bad_input() && e.to_string().contains("no lines"));
    }
}
