//! Reading a configuration file with a size limit, and finding a key's line and column in
//! its text for error messages.

use super::*;

/// Longest config file read (a config is a few kilobytes).
pub const MAX_CONFIG_FILE_BYTES: u64 = 1 << 20;

/// Longest token file read; a longer one (or `/dev/zero`) is refused without reading on.
pub const MAX_TOKEN_FILE_BYTES: u64 = 4096;

/// Reads a UTF-8 text file of at most `limit` bytes; a longer one (a device such as
/// `/dev/zero`, a wrong path) is an error instead of unbounded memory.
pub fn read_bounded(path: &Path, limit: u64) -> std::io::Result<String> {
    use std::io::Read;
    let file = std::fs::File::open(path)?;
    let mut bytes = Vec::new();
    file.take(limit + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("longer than {limit} bytes"),
        ));
    }
    String::from_utf8(bytes)
        .map_err(|_| std::io::Error::new(std::io::ErrorKind::InvalidData, "not UTF-8 text"))
}

/// The first of systemd's `$STATE_DIRECTORY` entries (colon-separated), if set.
pub(crate) fn state_directory() -> Option<PathBuf> {
    let dirs = std::env::var_os("STATE_DIRECTORY")?;
    let first = dirs.to_str()?.split(':').next()?.to_owned();
    (!first.is_empty()).then(|| PathBuf::from(first))
}

pub(crate) fn invalid(
    text: &str,
    file: &str,
    span: Option<Range<usize>>,
    message: String,
) -> ConfigError {
    let (line, column) = span.clone().map_or((0, 0), |s| line_col(text, s.start));
    let key = span.and_then(|s| key_path_at(text, s));
    ConfigError::Invalid {
        location: Location {
            file: file.to_owned(),
            line,
            column,
            key,
        },
        message,
    }
}

/// Where a dotted key stands in the file, for errors about the value it names (line 0 when
/// the key is not written in the file).
pub(crate) fn key_location(text: &str, file: &str, key: &str) -> Location {
    let (line, column) = span_of_key(text, key).map_or((0, 0), |s| line_col(text, s.start));
    Location {
        file: file.to_owned(),
        line,
        column,
        key: Some(key.to_owned()),
    }
}

/// 1-based line and column of a byte offset.
pub(crate) fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, column)
}

/// The dotted path of the deepest key whose key or value covers `span.start`.
fn key_path_at(text: &str, span: Range<usize>) -> Option<String> {
    let doc = toml_edit::ImDocument::parse(text).ok()?;
    let mut best: Option<(String, usize)> = None;
    visit_table(doc.as_table(), "", &mut |path, key_span, item_span| {
        let covers = |s: &Option<Range<usize>>| {
            s.as_ref()
                .is_some_and(|s| s.start <= span.start && span.start < s.end.max(s.start + 1))
        };
        if covers(&key_span) || covers(&item_span) {
            let width = item_span
                .as_ref()
                .or(key_span.as_ref())
                .map_or(usize::MAX, |s| s.len());
            if best.as_ref().is_none_or(|(_, w)| width <= *w) {
                best = Some((path.to_owned(), width));
            }
        }
    });
    best.map(|(path, _)| path)
}

/// One key of a dotted path as TOML writes it: bare when it is made of letters, digits, `-`
/// and `_`, else a basic string whose quote, backslash, control and bidirectional characters
/// are escapes (`"wolf.v2"`, `"a\u001B[2J"`). Names from the file go into error keys this
/// way, so that the key both reads as one line and finds its place in the file again.
pub fn key_segment(name: &str) -> String {
    use std::fmt::Write as _;
    let bare = !name.is_empty()
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_');
    if bare {
        return name.to_owned();
    }
    let mut out = String::with_capacity(name.len() + 2);
    out.push('"');
    for c in name.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\t' => out.push_str("\\t"),
            c if mouthpiece_output::shown::needs_escape(c) => {
                let _ = write!(out, "\\u{:04X}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// A dotted path up to its first index, and that index when it ends the path:
/// `osc.characters."a[1]"[0]` → (`osc.characters."a[1]"`, `Some(0)`); `detect.class[0].hue`
/// → (`detect.class`, `None`). Brackets inside a quoted key are part of the name.
fn split_index(key: &str) -> (&str, Option<usize>) {
    let mut quoted = false;
    let mut escaped = false;
    let mut open = None;
    for (i, c) in key.char_indices() {
        match c {
            _ if escaped => escaped = false,
            '\\' if quoted => escaped = true,
            '"' => quoted = !quoted,
            '[' if !quoted => {
                open = Some(i);
                break;
            }
            _ => {}
        }
    }
    let Some(open) = open else {
        return (key, None);
    };
    let index = key[open + 1..]
        .strip_suffix(']')
        .and_then(|i| i.parse::<usize>().ok());
    (&key[..open], index)
}

/// The span of the key at a dotted path; with an array index (`osc.targets[1]`), of that
/// element when the array is there, else of the key.
pub(crate) fn span_of_key(text: &str, key: &str) -> Option<Range<usize>> {
    let doc = toml_edit::ImDocument::parse(text).ok()?;
    let (wanted, index) = split_index(key);
    if let (Some(index), Ok(segments)) = (index, toml_edit::Key::parse(wanted)) {
        let mut segments = segments.iter();
        let mut item = doc.as_table().get(segments.next()?.get());
        for segment in segments {
            item = item.and_then(|i| i.get(segment.get()));
        }
        if let Some(span) = item
            .and_then(|i| i.as_array())
            .and_then(|a| a.get(index))
            .and_then(|v| v.span())
        {
            return Some(span);
        }
    }
    let mut found = None;
    visit_table(doc.as_table(), "", &mut |path, key_span, item_span| {
        if path == wanted && found.is_none() {
            found = key_span.or(item_span);
        }
    });
    found
}

/// Called with a key's dotted path, the key's span and its value's span.
type KeyVisitor<'a> = dyn FnMut(&str, Option<Range<usize>>, Option<Range<usize>>) + 'a;

fn visit_table(table: &toml_edit::Table, prefix: &str, f: &mut KeyVisitor<'_>) {
    for (key, item) in table.iter() {
        let path = if prefix.is_empty() {
            key_segment(key)
        } else {
            format!("{prefix}.{}", key_segment(key))
        };
        let key_span = table.key(key).and_then(|k| k.span());
        f(&path, key_span, item.span());
        match item {
            toml_edit::Item::Table(t) => visit_table(t, &path, f),
            toml_edit::Item::Value(toml_edit::Value::InlineTable(t)) => {
                for (k, v) in t.iter() {
                    let sub = format!("{path}.{}", key_segment(k));
                    f(&sub, t.key(k).and_then(|k| k.span()), v.span());
                }
            }
            toml_edit::Item::ArrayOfTables(tables) => {
                for t in tables.iter() {
                    visit_table(t, &path, f);
                }
            }
            _ => {}
        }
    }
}
