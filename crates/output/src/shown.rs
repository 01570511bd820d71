//! How a name that came from a file or the network is printed: control characters (an
//! escape sequence that repaints the terminal, a newline that forges a line or a table row,
//! a NUL), the invisible characters that reorder text (bidirectional overrides) and the
//! backslash are written as Rust escapes (`\n`, `\u{1b}`, `\\`), so what is shown is what
//! the file holds, on one line. Every printer of such a name goes through [`shown`].

use std::borrow::Cow;
use std::fmt;

/// `name` as it may be printed: unchanged when it holds nothing to escape.
pub fn shown(name: &str) -> Cow<'_, str> {
    if !name.chars().any(needs_escape) {
        return Cow::Borrowed(name);
    }
    let mut out = String::with_capacity(name.len() + 8);
    for c in name.chars() {
        push_shown(&mut out, c);
    }
    Cow::Owned(out)
}

/// [`shown`] as a `Display` value, for `format!` without an allocation when nothing needs
/// escaping.
#[derive(Debug, Clone, Copy)]
pub struct Shown<'a>(pub &'a str);

impl fmt::Display for Shown<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&shown(self.0))
    }
}

/// Whether `c` is written as an escape: C0 and C1 controls (and DEL), the backslash (so an
/// escape in the output is never ambiguous), and the bidirectional formatting characters.
pub fn needs_escape(c: char) -> bool {
    c.is_control()
        || c == '\\'
        || matches!(c, '\u{200e}' | '\u{200f}' | '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}')
}

fn push_shown(out: &mut String, c: char) {
    use fmt::Write as _;
    match c {
        '\n' => out.push_str("\\n"),
        '\r' => out.push_str("\\r"),
        '\t' => out.push_str("\\t"),
        '\0' => out.push_str("\\0"),
        '\\' => out.push_str("\\\\"),
        c if needs_escape(c) => {
            let _ = write!(out, "\\u{{{:x}}}", c as u32);
        }
        c => out.push(c),
    }
}

/// A message made of trusted text and names already shown: escapes the control characters
/// that move the cursor or repaint (everything of [`needs_escape`] but the newline and the
/// tab, which a message may use for its layout; the backslash is kept as it is). The last
/// line of defence where every error is printed.
pub fn shown_message(message: &str) -> Cow<'_, str> {
    let escape = |c: char| c != '\n' && c != '\t' && c != '\\' && needs_escape(c);
    if !message.chars().any(escape) {
        return Cow::Borrowed(message);
    }
    let mut out = String::with_capacity(message.len() + 8);
    for c in message.chars() {
        if escape(c) {
            push_shown(&mut out, c);
        } else {
            out.push(c);
        }
    }
    Cow::Owned(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_names_are_unchanged_and_borrowed() {
        for name in ["wolf", "scene.1_T003", "naïve Ωmega", "a b", ""] {
            assert!(
                matches!(shown(name), Cow::Borrowed(n) if n == name),
                "{name}"
            );
        }
    }

    #[test]
    fn controls_become_escapes_on_one_line() {
        assert_eq!(shown("a\nb"), "a\\nb");
        assert_eq!(shown("\u{1b}[2J"), "\\u{1b}[2J");
        assert_eq!(shown("x\ty\r\0"), "x\\ty\\r\\0");
        assert_eq!(shown("back\\slash"), "back\\\\slash");
        assert_eq!(shown("\u{7f}\u{9b}"), "\\u{7f}\\u{9b}");
        assert_eq!(shown("evil\u{202e}txt"), "evil\\u{202e}txt");
        assert_eq!(Shown("r\nw").to_string(), "r\\nw");
        for name in ["\u{1b}]0;title\u{7}", "row\n\tforged", "a\u{2066}b"] {
            let s = shown(name);
            assert!(!s.chars().any(needs_escape_but_backslash), "{s:?}");
        }
    }

    fn needs_escape_but_backslash(c: char) -> bool {
        c != '\\' && needs_escape(c)
    }

    #[test]
    fn messages_keep_their_lines_but_lose_escape_sequences() {
        assert_eq!(shown_message("a\n\tb"), "a\n\tb");
        assert_eq!(shown_message("C:\\x \u{1b}[31m"), "C:\\x \\u{1b}[31m");
    }
}
