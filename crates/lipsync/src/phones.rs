//! Phone timing files.
//!
//! | format | times | layout |
//! |---|---|---|
//! | TIMIT `.phn` | sample offsets at 16 kHz | `start end phone` per line |
//! | Praat TextGrid (long or short text format) | seconds | the interval tier named `phones`/`phone`/`phonemes`, or the only interval tier; empty labels are silence |
//! | HTK label (`.lab`) | 100 ns units | `start end phone [score…]` per line |
//! | Festival / xwaves label (`.lab`, `.segs`) | seconds | header, a line `#`, then `end colour phone` per line (a phone starts where the previous one ended) |
//! | JSONL | seconds | `{"start": s, "end": s, "phone": "sh"}` per line |
//!
//! Phone names are lowercased and ARPAbet stress digits dropped (`AH0` → `ah`). After reading,
//! [`check`] orders nothing: phones must come in time order, each ending after it starts and
//! none starting before the previous one ends (a rounding slack of 1 µs is allowed). Gaps
//! between phones, and the time before the first, become silence (`sil`).

use serde::Deserialize;

use crate::input::cut;
use crate::Error;

/// One phone on the timeline.
#[derive(Debug, Clone, PartialEq)]
pub struct PhoneSpan {
    /// Start, seconds.
    pub start: f64,
    /// End, seconds.
    pub end: f64,
    /// Normalised phone name (lowercase, no stress digits).
    pub phone: String,
    /// 1-based line of the source it came from (0 for silence filled in by [`check`]).
    pub line: usize,
}

/// The formats [`read`] understands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PhoneFormat {
    /// TIMIT `.phn`.
    Timit,
    /// Praat TextGrid.
    TextGrid,
    /// HTK or Festival label file (told apart by Festival's `#` header line).
    Label,
    /// JSON lines `{start, end, phone}`.
    Jsonl,
}

impl PhoneFormat {
    /// The format for a file name's extension: `.phn`, `.textgrid`, `.lab`/`.segs`,
    /// `.jsonl`/`.json` (case-insensitive).
    pub fn from_extension(ext: &str) -> Option<Self> {
        match ext.to_ascii_lowercase().as_str() {
            "phn" => Some(Self::Timit),
            "textgrid" => Some(Self::TextGrid),
            "lab" | "segs" => Some(Self::Label),
            "jsonl" | "json" => Some(Self::Jsonl),
            _ => None,
        }
    }
}

/// TIMIT's sample rate.
pub const TIMIT_RATE: f64 = 16_000.0;
/// HTK label time unit, seconds (100 ns).
pub const HTK_UNIT: f64 = 1e-7;
/// Slack for rounding in time checks, seconds.
pub const TIME_SLACK: f64 = 1e-6;
/// Latest time, seconds (a day), of the lip-sync inputs that are timelines of a session
/// (pose marks, a `synth --speech` CSV).
pub const MAX_TIME: f64 = 86_400.0;

/// Latest time a phone may end, seconds (ten minutes): as long as the longest audio the
/// speech recogniser reads (a line of dialogue is seconds, a scene minutes). A later end is
/// an error naming its line, not minutes of weights written for one phone.
pub const MAX_PHONE_SECONDS: f64 = 600.0;

/// Lowercases and drops ARPAbet stress digits (`AH0` → `ah`; TIMIT names have no digits).
pub fn normalise(phone: &str) -> String {
    phone
        .trim()
        .trim_end_matches(|c: char| c.is_ascii_digit())
        .to_ascii_lowercase()
}

/// Reads a phone file's text, then [`check`]s it.
pub fn read(text: &str, format: PhoneFormat, source_name: &str) -> Result<Vec<PhoneSpan>, Error> {
    let raw = match format {
        PhoneFormat::Timit => read_columns(text, source_name, TIMIT_RATE, "TIMIT")?,
        PhoneFormat::TextGrid => read_textgrid(text, source_name)?,
        PhoneFormat::Label => {
            if text.lines().any(|l| l.trim() == "#") {
                read_festival(text, source_name)?
            } else {
                read_columns(text, source_name, 1.0 / HTK_UNIT, "HTK")?
            }
        }
        PhoneFormat::Jsonl => read_jsonl(text, source_name)?,
    };
    check(raw, source_name)
}

fn parse_err(source_name: &str, line: usize, what: impl Into<String>) -> Error {
    Error::Parse {
        source_name: source_name.to_string(),
        line,
        what: what.into(),
    }
}

fn number(word: &str, source_name: &str, line: usize, what: &str) -> Result<f64, Error> {
    word.parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .ok_or_else(|| {
            parse_err(
                source_name,
                line,
                format!("{what} {:?} is not a finite number", cut(word)),
            )
        })
}

/// `start end phone [more…]` per line, times in units of `1 / per_second` seconds.
fn read_columns(
    text: &str,
    source_name: &str,
    per_second: f64,
    kind: &str,
) -> Result<Vec<PhoneSpan>, Error> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let words: Vec<&str> = line.split_whitespace().collect();
        if words.is_empty() {
            continue;
        }
        if words.len() < 3 {
            return Err(parse_err(
                source_name,
                n,
                format!(
                    "expected `start end phone` ({kind} label), got {:?}",
                    cut(line)
                ),
            ));
        }
        let start = number(words[0], source_name, n, "start")? / per_second;
        let end = number(words[1], source_name, n, "end")? / per_second;
        out.push(PhoneSpan {
            start,
            end,
            phone: normalise(words[2]),
            line: n,
        });
    }
    Ok(out)
}

/// Festival / xwaves: header up to a line `#`, then `end colour phone`.
fn read_festival(text: &str, source_name: &str) -> Result<Vec<PhoneSpan>, Error> {
    let mut out: Vec<PhoneSpan> = Vec::new();
    let mut in_body = false;
    let mut previous_end = 0.0;
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        if !in_body {
            in_body = line.trim() == "#";
            continue;
        }
        let words: Vec<&str> = line.split_whitespace().collect();
        if words.is_empty() {
            continue;
        }
        if words.len() < 3 {
            return Err(parse_err(
                source_name,
                n,
                format!(
                    "expected `end colour phone` (Festival label), got {:?}",
                    cut(line)
                ),
            ));
        }
        let end = number(words[0], source_name, n, "end")?;
        out.push(PhoneSpan {
            start: previous_end,
            end,
            phone: normalise(words[2]),
            line: n,
        });
        previous_end = end;
    }
    Ok(out)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct JsonPhone {
    start: f64,
    end: f64,
    phone: String,
}

fn read_jsonl(text: &str, source_name: &str) -> Result<Vec<PhoneSpan>, Error> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        if line.trim().is_empty() {
            continue;
        }
        let p: JsonPhone = serde_json::from_str(line).map_err(|e| {
            parse_err(
                source_name,
                n,
                format!("expected {{start, end, phone}}: {e}"),
            )
        })?;
        if !(p.start.is_finite() && p.end.is_finite()) {
            return Err(parse_err(source_name, n, "times must be finite numbers"));
        }
        out.push(PhoneSpan {
            start: p.start,
            end: p.end,
            phone: normalise(&p.phone),
            line: n,
        });
    }
    Ok(out)
}

/// A TextGrid token: a quoted string or a number.
#[derive(Debug, Clone, PartialEq)]
enum Token {
    Text(String),
    Number(f64),
}

/// Praat's text formats reduced to their values: quoted strings and bare numbers, in order;
/// labels (`xmin =`, `intervals [3]:`, `<exists>`) dropped. The long and the short format give
/// the same sequence. A number that is not finite (`NaN`, `inf`) is an error at its line and
/// column.
fn textgrid_tokens(text: &str) -> Result<Vec<(Token, usize)>, (usize, usize, String)> {
    let mut out = Vec::new();
    // A byte order mark left at the start (the file was decoded elsewhere) is not a token.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let mut chars = line.char_indices().peekable();
        while let Some(&(pos, c)) = chars.peek() {
            if c.is_whitespace() {
                chars.next();
            } else if c == '"' {
                chars.next();
                let mut s = String::new();
                let mut closed = false;
                while let Some((_, c)) = chars.next() {
                    if c == '"' {
                        if chars.peek().map(|&(_, c)| c) == Some('"') {
                            chars.next();
                            s.push('"');
                        } else {
                            closed = true;
                            break;
                        }
                    } else {
                        s.push(c);
                    }
                }
                if !closed {
                    let column = line[..pos].chars().count() + 1;
                    return Err((
                        n,
                        column,
                        "unterminated string (labels must fit on one line)".into(),
                    ));
                }
                out.push((Token::Text(s), n));
            } else if c == '!' {
                break; // comment to the end of the line
            } else {
                let rest = &line[pos..];
                let end = rest.find(char::is_whitespace).unwrap_or(rest.len());
                let word = &rest[..end];
                if let Ok(v) = word.parse::<f64>() {
                    if !v.is_finite() {
                        let column = line[..pos].chars().count() + 1;
                        return Err((n, column, format!("{:?} is not a finite number", cut(word))));
                    }
                    out.push((Token::Number(v), n));
                }
                for _ in 0..word.chars().count() {
                    chars.next();
                }
            }
        }
    }
    Ok(out)
}

fn read_textgrid(text: &str, source_name: &str) -> Result<Vec<PhoneSpan>, Error> {
    let tokens = textgrid_tokens(text).map_err(|(line, column, what)| Error::ParseAt {
        source_name: source_name.to_string(),
        line,
        column,
        what,
    })?;
    let mut it = tokens.into_iter().peekable();
    let last_line = text.lines().count().max(1);
    let mut next = |what: &str| -> Result<(Token, usize), Error> {
        it.next().ok_or_else(|| {
            parse_err(
                source_name,
                last_line,
                format!("TextGrid ends early (expected {what})"),
            )
        })
    };
    let text_of = |(t, n): (Token, usize), what: &str| -> Result<(String, usize), Error> {
        match t {
            Token::Text(s) => Ok((s, n)),
            Token::Number(v) => Err(parse_err(
                source_name,
                n,
                format!("expected {what} (a quoted string), got {v}"),
            )),
        }
    };
    let num_of = |(t, n): (Token, usize), what: &str| -> Result<(f64, usize), Error> {
        match t {
            Token::Number(v) => Ok((v, n)),
            Token::Text(s) => Err(parse_err(
                source_name,
                n,
                format!("expected {what} (a number), got {:?}", cut(&s)),
            )),
        }
    };
    let (kind, n) = text_of(next("file type")?, "file type")?;
    if kind != "ooTextFile" {
        return Err(parse_err(
            source_name,
            n,
            format!(
                "not a Praat text file (file type {:?}, expected \"ooTextFile\")",
                cut(&kind)
            ),
        ));
    }
    let (class, n) = text_of(next("object class")?, "object class")?;
    if class != "TextGrid" {
        return Err(parse_err(
            source_name,
            n,
            format!("object class {:?} is not \"TextGrid\"", cut(&class)),
        ));
    }
    num_of(next("xmin")?, "xmin")?;
    num_of(next("xmax")?, "xmax")?;
    let (tiers, n) = num_of(next("tier count")?, "tier count")?;
    if tiers < 0.0 || tiers.fract() != 0.0 {
        return Err(parse_err(source_name, n, format!("bad tier count {tiers}")));
    }
    let mut interval_tiers: Vec<(String, usize, Vec<PhoneSpan>)> = Vec::new();
    for _ in 0..tiers as usize {
        let (tier_class, tier_line) = text_of(next("tier class")?, "tier class")?;
        let (name, _) = text_of(next("tier name")?, "tier name")?;
        num_of(next("tier xmin")?, "tier xmin")?;
        num_of(next("tier xmax")?, "tier xmax")?;
        let (count, n) = num_of(next("item count")?, "item count")?;
        if count < 0.0 || count.fract() != 0.0 {
            return Err(parse_err(source_name, n, format!("bad item count {count}")));
        }
        match tier_class.as_str() {
            "IntervalTier" => {
                // The count comes from the file: it sizes nothing (each interval read is
                // three tokens that are there, or an error).
                let mut spans = Vec::new();
                for _ in 0..count as usize {
                    let (start, line) = num_of(next("interval xmin")?, "interval xmin")?;
                    let (end, _) = num_of(next("interval xmax")?, "interval xmax")?;
                    let (label, _) = text_of(next("interval text")?, "interval text")?;
                    let phone = normalise(&label);
                    spans.push(PhoneSpan {
                        start,
                        end,
                        phone: if phone.is_empty() {
                            "sil".into()
                        } else {
                            phone
                        },
                        line,
                    });
                }
                interval_tiers.push((name, tier_line, spans));
            }
            "TextTier" => {
                for _ in 0..count as usize {
                    num_of(next("point time")?, "point time")?;
                    text_of(next("point mark")?, "point mark")?;
                }
            }
            other => {
                return Err(parse_err(
                    source_name,
                    tier_line,
                    format!("unknown tier class {:?}", cut(other)),
                ))
            }
        }
    }
    let is_phone_tier = |name: &str| {
        matches!(
            name.to_ascii_lowercase().as_str(),
            "phones" | "phone" | "phonemes" | "phoneme"
        )
    };
    let chosen = match interval_tiers
        .iter()
        .position(|(name, ..)| is_phone_tier(name))
    {
        Some(i) => i,
        None if interval_tiers.len() == 1 => 0,
        None => {
            let names: Vec<String> = interval_tiers
                .iter()
                .take(8)
                .map(|(n, ..)| cut(n))
                .collect();
            return Err(parse_err(
                source_name,
                1,
                format!(
                    "no interval tier named \"phones\" and not exactly one interval tier \
                     (tiers: {names:?})"
                ),
            ));
        }
    };
    Ok(interval_tiers.swap_remove(chosen).2)
}

/// Checks order and times; drops zero-length phones; fills gaps (and the time before the
/// first phone) with silence.
pub fn check(raw: Vec<PhoneSpan>, source_name: &str) -> Result<Vec<PhoneSpan>, Error> {
    let mut out: Vec<PhoneSpan> = Vec::with_capacity(raw.len() + 2);
    let mut previous: Option<(f64, usize)> = None;
    for mut p in raw {
        p.phone = if p.phone.chars().count() > crate::input::QUOTE_CHARS {
            // Only errors would quote it; no phone name is this long.
            cut(&p.phone)
        } else {
            p.phone
        };
        if !(p.start.is_finite() && p.end.is_finite()) {
            return Err(parse_err(
                source_name,
                p.line,
                format!(
                    "phone {:?}: times must be finite numbers, got {} to {} s",
                    p.phone, p.start, p.end
                ),
            ));
        }
        if p.start < 0.0 {
            return Err(parse_err(
                source_name,
                p.line,
                format!(
                    "phone {:?} starts at a negative time {} s",
                    p.phone, p.start
                ),
            ));
        }
        if p.end > MAX_PHONE_SECONDS {
            return Err(parse_err(
                source_name,
                p.line,
                format!(
                    "phone {:?} ends at {} s, past the limit of {MAX_PHONE_SECONDS} s",
                    p.phone, p.end
                ),
            ));
        }
        if p.end < p.start {
            return Err(Error::Backwards {
                source_name: source_name.to_string(),
                line: p.line,
                phone: p.phone,
                start: p.start,
                end: p.end,
            });
        }
        let previous_end = previous.map_or(0.0, |(e, _)| e);
        if let Some((previous_end, previous_line)) = previous {
            if p.start < previous_end - TIME_SLACK {
                return Err(Error::Overlap {
                    source_name: source_name.to_string(),
                    line: p.line,
                    phone: p.phone,
                    start: p.start,
                    previous_line,
                    previous_end,
                });
            }
        }
        if p.end <= p.start {
            continue;
        }
        let start = p.start.max(previous_end);
        if start > previous_end + TIME_SLACK {
            out.push(PhoneSpan {
                start: previous_end,
                end: start,
                phone: "sil".into(),
                line: 0,
            });
        }
        previous = Some((p.end, p.line));
        if p.end <= start {
            continue;
        }
        out.push(PhoneSpan { start, ..p });
    }
    if out.is_empty() {
        return Err(Error::Empty {
            source_name: source_name.to_string(),
        });
    }
    // Consecutive phones touch exactly.
    for i in 1..out.len() {
        let e = out[i - 1].end;
        out[i].start = e;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn phones(v: &[PhoneSpan]) -> Vec<(f64, f64, &str)> {
        v.iter()
            .map(|p| (p.start, p.end, p.phone.as_str()))
            .collect()
    }

    #[test]
    fn timit_phn() {
        let v = read(
            "0 3050 h#\n3050 4559 sh\n4559 5723 ix\n",
            PhoneFormat::Timit,
            "a.phn",
        )
        .unwrap();
        assert_eq!(
            phones(&v),
            [
                (0.0, 3050.0 / 16000.0, "h#"),
                (3050.0 / 16000.0, 4559.0 / 16000.0, "sh"),
                (4559.0 / 16000.0, 5723.0 / 16000.0, "ix")
            ]
        );
        assert_eq!(v[1].line, 2);
    }

    #[test]
    fn htk_and_festival_labels() {
        let htk = "0 2000000 sil\n2000000 3500000 SH -12.5\n";
        let v = read(htk, PhoneFormat::Label, "a.lab").unwrap();
        assert_eq!(phones(&v), [(0.0, 0.2, "sil"), (0.2, 0.35, "sh")]);
        let fest =
            "separator ;\nnfields 1\n#\n    0.2100 100 pau\n    0.3499 100 sh\n 0.41 100 iy\n";
        let v = read(fest, PhoneFormat::Label, "a.segs").unwrap();
        assert_eq!(
            phones(&v),
            [
                (0.0, 0.21, "pau"),
                (0.21, 0.3499, "sh"),
                (0.3499, 0.41, "iy")
            ]
        );
        assert_eq!(v[2].line, 6);
    }

    #[test]
    fn jsonl_with_stress_digits() {
        let text = "{\"start\": 0.1, \"end\": 0.2, \"phone\": \"AH0\"}\n\n{\"start\": 0.2, \"end\": 0.3, \"phone\": \"M\"}\n";
        let v = read(text, PhoneFormat::Jsonl, "a.jsonl").unwrap();
        // The lead-in before the first phone is silence.
        assert_eq!(
            phones(&v),
            [(0.0, 0.1, "sil"), (0.1, 0.2, "ah"), (0.2, 0.3, "m")]
        );
        let err = read("{\"start\": 0.1}\n", PhoneFormat::Jsonl, "b.jsonl").unwrap_err();
        assert!(err.to_string().starts_with("b.jsonl:1:"), "{err}");
    }

    const LONG: &str = r#"File type = "ooTextFile"
Object class = "TextGrid"

xmin = 0
xmax = 0.5
tiers? <exists>
size = 2
item []:
    item [1]:
        class = "IntervalTier"
        name = "words"
        xmin = 0
        xmax = 0.5
        intervals: size = 1
        intervals [1]:
            xmin = 0
            xmax = 0.5
            text = "she"
    item [2]:
        class = "IntervalTier"
        name = "phones"
        xmin = 0
        xmax = 0.5
        intervals: size = 3
        intervals [1]:
            xmin = 0
            xmax = 0.1
            text = ""
        intervals [2]:
            xmin = 0.1
            xmax = 0.3
            text = "SH"
        intervals [3]:
            xmin = 0.3
            xmax = 0.5
            text = "IY1"
"#;

    const SHORT: &str = "\"ooTextFile\"\n\"TextGrid\"\n0\n0.5\n<exists>\n1\n\"IntervalTier\"\n\"phn\"\n0\n0.5\n3\n0\n0.1\n\"\"\n0.1\n0.3\n\"sh\"\n0.3\n0.5\n\"iy\"\n";

    #[test]
    fn textgrid_long_and_short() {
        let expect = [(0.0, 0.1, "sil"), (0.1, 0.3, "sh"), (0.3, 0.5, "iy")];
        let v = read(LONG, PhoneFormat::TextGrid, "a.TextGrid").unwrap();
        assert_eq!(phones(&v), expect);
        assert_eq!(v[1].line, 30);
        let v = read(SHORT, PhoneFormat::TextGrid, "b.TextGrid").unwrap();
        assert_eq!(phones(&v), expect);
        let two = LONG.replace("\"phones\"", "\"segments\"");
        let err = read(&two, PhoneFormat::TextGrid, "c.TextGrid").unwrap_err();
        assert!(err.to_string().contains("segments"), "{err}");
    }

    #[test]
    fn backwards_and_overlapping_times_name_the_line() {
        let err = read("0 100 sh\n300 200 iy\n", PhoneFormat::Timit, "x.phn").unwrap_err();
        assert!(matches!(err, Error::Backwards { line: 2, .. }), "{err}");
        assert!(err.to_string().starts_with("x.phn:2:"), "{err}");
        let err = read("0 100 sh\n50 200 iy\n", PhoneFormat::Timit, "x.phn").unwrap_err();
        assert!(
            matches!(
                err,
                Error::Overlap {
                    line: 2,
                    previous_line: 1,
                    ..
                }
            ),
            "{err}"
        );
        let err = read("0 1oo sh\n", PhoneFormat::Timit, "x.phn").unwrap_err();
        assert!(err.to_string().contains("x.phn:1: end \"1oo\""), "{err}");
        let err = read("\n", PhoneFormat::Timit, "x.phn").unwrap_err();
        assert!(matches!(err, Error::Empty { .. }));
    }

    #[test]
    fn an_interval_count_the_file_cannot_hold_is_an_error_not_an_allocation() {
        // 1e30 overflowed the capacity of the interval list; 1e9 asked for 50 GB.
        for count in ["1e30", "1000000000"] {
            let text = SHORT.replacen("\n3\n", &format!("\n{count}\n"), 1);
            let err = read(&text, PhoneFormat::TextGrid, "big.TextGrid").unwrap_err();
            assert!(err.to_string().starts_with("big.TextGrid:"), "{err}");
        }
    }

    #[test]
    fn times_past_the_limit_are_refused_naming_the_line() {
        // 1e300 samples used to reach the sampling as an endless timeline.
        for (text, format) in [
            ("0 100 sh\n100 1e300 iy\n", PhoneFormat::Timit),
            ("0 1000 sh\n1000 1e19 iy\n", PhoneFormat::Label),
            (
                "{\"start\": 0, \"end\": 0.1, \"phone\": \"sh\"}\n{\"start\": 0.1, \"end\": 600.5, \"phone\": \"iy\"}\n",
                PhoneFormat::Jsonl,
            ),
        ] {
            let err = read(text, format, "long").unwrap_err();
            assert!(err.to_string().starts_with("long:2: phone \"iy\" ends at"), "{err}");
        }
        assert!(read("0 100 sh\n100 9600000 iy\n", PhoneFormat::Timit, "600 s").is_ok());
        assert!(read("0 100 sh\n100 9600017 iy\n", PhoneFormat::Timit, "600 s").is_err());
    }

    #[test]
    fn non_finite_textgrid_times_are_refused_at_their_line_and_column() {
        // NaN compared false everywhere: the take came out with null points and exit 0.
        for bad in ["NaN", "nan", "inf", "-Infinity"] {
            let text = LONG.replace("xmax = 0.3", &format!("xmax = {bad}"));
            let err = read(&text, PhoneFormat::TextGrid, "n.TextGrid").unwrap_err();
            assert!(
                err.to_string()
                    .starts_with(&format!("n.TextGrid:31:20: \"{bad}\" is not a finite")),
                "{err}"
            );
            let text = SHORT.replacen("0.3\n", &format!("{bad}\n"), 1);
            let err = read(&text, PhoneFormat::TextGrid, "s.TextGrid").unwrap_err();
            assert!(err.to_string().starts_with("s.TextGrid:16:1: "), "{err}");
        }
        // Spans made elsewhere (the recogniser) are checked too.
        let nan = PhoneSpan {
            start: 0.0,
            end: f64::NAN,
            phone: "sh".into(),
            line: 4,
        };
        let err = check(vec![nan], "r").unwrap_err();
        assert!(
            err.to_string()
                .starts_with("r:4: phone \"sh\": times must be finite"),
            "{err}"
        );
    }

    #[test]
    fn praat_utf16_textgrids_read() {
        // Praat saves a TextGrid as UTF-16 with a byte order mark when a label is not ASCII.
        let text = LONG.replace("\"she\"", "\"ʃiː\"");
        let expect = [(0.0, 0.1, "sil"), (0.1, 0.3, "sh"), (0.3, 0.5, "iy")];
        for big_endian in [false, true] {
            let mut bytes = if big_endian {
                vec![0xFE, 0xFF]
            } else {
                vec![0xFF, 0xFE]
            };
            for u in text.encode_utf16() {
                bytes.extend(if big_endian {
                    u.to_be_bytes()
                } else {
                    u.to_le_bytes()
                });
            }
            let decoded = crate::input::decode_text(&bytes, "u.TextGrid").unwrap();
            let v = read(&decoded, PhoneFormat::TextGrid, "u.TextGrid").unwrap();
            assert_eq!(phones(&v), expect);
        }
    }

    #[test]
    fn errors_quote_at_most_a_line_of_input() {
        let huge = "x".repeat(5_000_000);
        let err = read(&format!("0 {huge}\n"), PhoneFormat::Timit, "h.phn").unwrap_err();
        assert!(
            err.to_string().len() < 300,
            "{} bytes",
            err.to_string().len()
        );
        let err = read(&format!("0 1{huge} sh\n"), PhoneFormat::Timit, "h.phn").unwrap_err();
        assert!(
            err.to_string().len() < 300,
            "{} bytes",
            err.to_string().len()
        );
        let text = LONG.replace("\"IY1\"", &format!("\"{huge}\""));
        let err = read(&text, PhoneFormat::TextGrid, "h.TextGrid").unwrap();
        let table = crate::ClassTable::from_toml_str(
            "poses = [\"open\"]\n[[class]]\nname = \"sil\"\nphones = [\"sil\", \"sh\"]\n",
            "c",
        )
        .unwrap();
        let err = table.classify(&err, "h.TextGrid").unwrap_err();
        assert!(
            err.to_string().len() < 300,
            "{} bytes",
            err.to_string().len()
        );
    }

    #[test]
    fn gaps_become_silence_and_zero_length_phones_go() {
        let v = read(
            "0 1600 sh\n1600 1600 t\n3200 4800 iy\n",
            PhoneFormat::Timit,
            "g.phn",
        )
        .unwrap();
        assert_eq!(
            phones(&v),
            [(0.0, 0.1, "sh"), (0.1, 0.2, "sil"), (0.2, 0.3, "iy")]
        );
    }
}
