//! How a take is named: one rule for the slate, whether it comes from a client's `record`
//! request, the configuration's `[takes] slate` or the command line.

/// The rule in words, for error messages.
pub const SLATE_RULE: &str =
    "1-64 letters, digits, '-', '_' or '.', starting with a letter or digit";

/// Whether `slate` may name a take: it becomes the start of a file name, so 1-64 of
/// `A-Z a-z 0-9 - _ .`, starting with a letter or digit (not `.`: hidden, `..`; not `-`:
/// read as an option by command-line tools).
pub fn valid_slate(slate: &str) -> bool {
    slate.len() <= 64
        && slate
            .chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphanumeric())
        && slate
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_name_hazards_are_refused() {
        for good in ["take", "A-1_b.2", &"x".repeat(64)] {
            assert!(valid_slate(good), "{good}");
        }
        for bad in [
            "",
            ".hidden",
            "..",
            "-rf",
            "a/b",
            "a b",
            "naïve",
            &"x".repeat(65),
        ] {
            assert!(!valid_slate(bad), "{bad:?}");
        }
    }
}
