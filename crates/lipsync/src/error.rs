/// Everything that can go wrong in lip sync. `source_name` is the file (or other source) the
/// text came from; `line` is 1-based.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A line of a phone file or of a text format that does not parse.
    #[error("{source_name}:{line}: {what}")]
    Parse {
        source_name: String,
        line: usize,
        what: String,
    },
    /// A value at a line and column (1-based, characters) that is not acceptable.
    #[error("{source_name}:{line}:{column}: {what}")]
    ParseAt {
        source_name: String,
        line: usize,
        column: usize,
        what: String,
    },
    /// A phone the class table does not know.
    #[error("{source_name}:{line}: unknown phone {phone:?} (not in the class table)")]
    UnknownPhone {
        source_name: String,
        line: usize,
        phone: String,
    },
    /// A phone that ends before it starts.
    #[error("{source_name}:{line}: phone {phone:?} ends ({end} s) before it starts ({start} s)")]
    Backwards {
        source_name: String,
        line: usize,
        phone: String,
        start: f64,
        end: f64,
    },
    /// A phone that starts before the previous one ended.
    #[error(
        "{source_name}:{line}: phone {phone:?} starts at {start} s, before the previous phone \
         (line {previous_line}) ends at {previous_end} s"
    )]
    Overlap {
        source_name: String,
        line: usize,
        phone: String,
        start: f64,
        previous_line: usize,
        previous_end: f64,
    },
    /// A phone file without phones.
    #[error("{source_name}: no phones")]
    Empty { source_name: String },
    /// A TOML file that does not parse.
    #[error("{source_name}: invalid TOML")]
    Toml {
        source_name: String,
        #[source]
        source: Box<toml::de::Error>,
    },
    /// A TOML file that parses but says something invalid.
    #[error("{source_name}: {key}: {what}")]
    Config {
        source_name: String,
        key: String,
        what: String,
    },
    /// A setting out of range (change-stage length, sample rate).
    #[error("{what}")]
    Setting { what: String },
}
