//! Input text as the readers see it: a file's bytes decoded (UTF-8, or UTF-16 with a byte
//! order mark, as Praat writes TextGrids whose labels are not ASCII), and what errors may
//! quote of it cut short.

use crate::Error;

/// Longest piece of input an error quotes, in characters.
pub const QUOTE_CHARS: usize = 80;

/// `s` cut to [`QUOTE_CHARS`] characters (an ellipsis marks the cut) with its control
/// characters escaped ([`mouthpiece_output::shown()`]): errors never echo megabytes of input,
/// nor an escape sequence or a newline to the terminal.
pub fn cut(s: &str) -> String {
    match s.char_indices().nth(QUOTE_CHARS) {
        Some((i, _)) => format!("{}…", mouthpiece_output::shown(&s[..i])),
        None => mouthpiece_output::shown(s).into_owned(),
    }
}

/// The rule for the names a lip-sync file gives (key poses, classes, pose marks), in words.
pub const NAME_RULE: &str = "1 to 64 ASCII letters, digits, '_' or '-'";

/// Whether `name` may name a key pose, a class or a pose mark: it becomes a column of the
/// weights CSV and a key of the TOML files written, so nothing that separates either
/// (`,`, `.`, quotes, spaces, control characters) ([`NAME_RULE`]).
pub fn valid_name(name: &str) -> bool {
    (1..=64).contains(&name.len())
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
}

/// Largest phone file read (a phone file of hours is a few MB).
pub const MAX_PHONE_FILE_BYTES: u64 = 64 << 20;
/// Largest class, pose or segment table read.
pub const MAX_TABLE_FILE_BYTES: u64 = 4 << 20;
/// Largest transcript read.
pub const MAX_TRANSCRIPT_BYTES: u64 = 1 << 20;
/// Largest weights CSV `synth --speech` reads (a CSV of an hour at 60 fps is 25 MB).
pub const MAX_WEIGHTS_CSV_BYTES: u64 = 64 << 20;

/// Why a text file cannot be read; every case is the caller's file.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error("cannot read {what} {path}")]
    Io {
        what: String,
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {what} longer than {limit} bytes")]
    TooLong {
        what: String,
        path: String,
        limit: u64,
    },
    #[error(transparent)]
    Decode(#[from] Error),
    #[error("{path} line {line}: {what}: {cause}")]
    Line {
        what: String,
        path: String,
        line: usize,
        cause: std::io::Error,
    },
}

/// Reads a text file of at most `limit` bytes (UTF-8, or UTF-16 with a byte order mark):
/// a longer one (a device such as `/dev/zero`, a wrong path) is an error naming the file, and
/// so is a line longer than [`MAX_LINE_BYTES`](mouthpiece_retarget::jsonl::MAX_LINE_BYTES),
/// naming its line. `what` says what the file is in errors (`phone file`).
pub fn read_text(path: &std::path::Path, what: &str, limit: u64) -> Result<String, ReadError> {
    use mouthpiece_retarget::jsonl::{read_line_limited, MAX_LINE_BYTES};
    use std::io::Read;
    let name = path.display().to_string();
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .and_then(|f| f.take(limit + 1).read_to_end(&mut bytes))
        .map_err(|source| ReadError::Io {
            what: what.to_string(),
            path: name.clone(),
            source,
        })?;
    if bytes.len() as u64 > limit {
        return Err(ReadError::TooLong {
            what: what.to_string(),
            path: name,
            limit,
        });
    }
    let text = decode_text(&bytes, &name)?;
    // Line by line as the take readers read, with their limit: a line of megabytes is not a
    // phone file, table or transcript, and the error says where it is.
    let (mut rest, mut line) = (text.as_bytes(), String::new());
    for n in 1.. {
        match read_line_limited(&mut rest, &mut line, MAX_LINE_BYTES) {
            Ok(0) => break,
            Ok(_) => {}
            Err(cause) => {
                return Err(ReadError::Line {
                    what: what.to_string(),
                    path: name,
                    line: n,
                    cause,
                })
            }
        }
    }
    Ok(text)
}

/// A text file's bytes → text: UTF-8 (a leading byte order mark dropped), or UTF-16 little-
/// or big-endian when the file starts with that byte order mark. `source_name` names the
/// file in errors.
pub fn decode_text(bytes: &[u8], source_name: &str) -> Result<String, Error> {
    let not_text = |what: String| Error::Parse {
        source_name: source_name.to_string(),
        line: 1,
        what,
    };
    let utf16 = |body: &[u8], unit: fn([u8; 2]) -> u16, order: &str| {
        if !body.len().is_multiple_of(2) {
            return Err(not_text(format!(
                "UTF-16 ({order}) text with an odd number of bytes"
            )));
        }
        let units = body.chunks_exact(2).map(|c| unit([c[0], c[1]]));
        char::decode_utf16(units)
            .enumerate()
            .map(|(i, c)| {
                c.map_err(|_| {
                    not_text(format!(
                        "not UTF-16 ({order}) text: unpaired surrogate at byte {}",
                        2 + 2 * i
                    ))
                })
            })
            .collect()
    };
    match bytes {
        [0xFF, 0xFE, body @ ..] => utf16(body, u16::from_le_bytes, "little-endian"),
        [0xFE, 0xFF, body @ ..] => utf16(body, u16::from_be_bytes, "big-endian"),
        _ => {
            let body = bytes.strip_prefix(&[0xEF, 0xBB, 0xBF]).unwrap_or(bytes);
            String::from_utf8(body.to_vec()).map_err(|e| {
                let at = e.utf8_error().valid_up_to();
                let line = body[..at].iter().filter(|&&b| b == b'\n').count() + 1;
                Error::Parse {
                    source_name: source_name.to_string(),
                    line,
                    what: format!("not UTF-8 text (byte {at}), nor UTF-16 with a byte order mark"),
                }
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utf16_with_either_byte_order_and_utf8_with_a_mark() {
        let text = "\"ooTextFile\"\n\"ʃiː\"\n";
        let mut le = vec![0xFF, 0xFE];
        let mut be = vec![0xFE, 0xFF];
        for u in text.encode_utf16() {
            le.extend(u.to_le_bytes());
            be.extend(u.to_be_bytes());
        }
        assert_eq!(decode_text(&le, "le").unwrap(), text);
        assert_eq!(decode_text(&be, "be").unwrap(), text);
        let mut bom = vec![0xEF, 0xBB, 0xBF];
        bom.extend(text.as_bytes());
        assert_eq!(decode_text(&bom, "u8").unwrap(), text);
        let err = decode_text(b"ok\n\xff\xfe", "bad.lab").unwrap_err();
        assert!(err.to_string().starts_with("bad.lab:2: not UTF-8"), "{err}");
        let err = decode_text(&le[..le.len() - 1], "odd").unwrap_err();
        assert!(err.to_string().contains("odd number of bytes"), "{err}");
    }

    #[test]
    fn quotes_are_cut() {
        let long = "é".repeat(1000);
        let q = cut(&long);
        assert_eq!(q.chars().count(), QUOTE_CHARS + 1);
        assert_eq!(cut("short"), "short");
        assert_eq!(cut("a\u{1b}[2J\nb"), "a\\u{1b}[2J\\nb");
    }

    #[test]
    fn names_are_single_csv_columns_and_toml_keys() {
        for good in ["open", "mid_front", "lip-roll", "A1"] {
            assert!(valid_name(good), "{good}");
        }
        for bad in [
            "",
            "a,b",
            "a.b",
            "a b",
            "a\"b",
            "a\nb",
            "é",
            &"x".repeat(65),
        ] {
            assert!(!valid_name(bad), "{bad:?}");
        }
    }
}
