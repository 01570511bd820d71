//! The crate's one error type.

/// Everything that can go wrong in the retarget core. Messages name the key, dot or line
/// involved so that a user can fix their file.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The character file is not valid TOML, or a key has the wrong type or is unknown.
    #[error("{}{}", line_prefix(*.line), .source.message())]
    CharacterToml {
        /// 1-based line of the problem, when the parser knows it.
        line: Option<usize>,
        #[source]
        source: toml::de::Error,
    },
    /// The character file parses but a value is not acceptable.
    #[error("{}`{key}`: {reason}", line_prefix(*.line))]
    CharacterInvalid {
        /// The key at fault, dotted (`points.P3`, `contour.upper`).
        key: String,
        /// 1-based line of the key's value, when known.
        line: Option<usize>,
        /// What is wrong and what was expected.
        reason: String,
    },
    /// Two points that must differ (the mouth corners) are at the same place.
    #[error("the mouth corners {left} and {right} coincide")]
    CoincidentCorners {
        /// Name of the left corner.
        left: String,
        /// Name of the right corner.
        right: String,
    },
    /// The `up` direction is parallel to the corner line, so no mouth frame can be built.
    #[error("`up` is parallel to the line through the mouth corners")]
    UpParallelToCorners,
    /// No neutral samples at all.
    #[error("the neutral pose has no frames")]
    NeutralEmpty,
    /// A lip dot was never seen during the neutral pose.
    #[error("dot {dot} is never seen in the neutral pose")]
    NeutralMissingDot {
        /// Name of the dot (`D1`, …).
        dot: String,
    },
    /// Fewer than three forehead dots, or collinear ones, in the neutral pose.
    #[error(
        "the neutral pose needs at least 3 non-collinear forehead dots; it has {seen} seen{}",
        if *.collinear { " and they are collinear" } else { "" }
    )]
    NeutralForehead {
        /// Forehead dots seen at least once.
        seen: usize,
        /// Whether the seen ones are (nearly) collinear.
        collinear: bool,
    },
    /// A dot position is NaN or infinite.
    #[error("dot {dot} has a non-finite coordinate")]
    NonFinite {
        /// Name of the dot.
        dot: String,
    },
    /// A dot position is further from the camera than any face can be.
    #[error("dot {dot} has a coordinate beyond {limit} (metres)")]
    CoordinateOutOfRange {
        /// Name of the dot.
        dot: String,
        /// [`crate::layout::MAX_COORDINATE`].
        limit: f64,
    },
    /// A timestamp is NaN or infinite.
    #[error("timestamp {t} is not finite")]
    NonFiniteTime {
        /// The bad timestamp.
        t: f64,
    },
    /// Time went backwards between two steps.
    #[error("timestamp goes backwards: {t} after {previous}")]
    TimeBackwards {
        /// The previous step's timestamp.
        previous: f64,
        /// This step's timestamp.
        t: f64,
    },
    /// The dots handed to a step do not match the performer layout.
    #[error("expected {expected_lip} lip and {expected_forehead} forehead dots, got {lip} and {forehead}")]
    DotCount {
        /// Lip dots the layout has.
        expected_lip: usize,
        /// Forehead dots the layout has.
        expected_forehead: usize,
        /// Lip dots given.
        lip: usize,
        /// Forehead dots given.
        forehead: usize,
    },
    /// The character and the performer do not fit together.
    #[error(
        "character `{character}` has {points} points but the performer has {lip_dots} lip dots"
    )]
    LayoutMismatch {
        /// Character name.
        character: String,
        /// Number of character points.
        points: usize,
        /// Number of performer lip dots.
        lip_dots: usize,
    },
    /// A JSONL line is not valid JSON or not of the expected shape.
    #[error("not a valid input line")]
    Json {
        #[source]
        source: serde_json::Error,
    },
    /// A JSONL line names a dot that the performer layout does not have.
    #[error("unknown dot name `{name}` (expected D1..D{lip_dots} or F1..F<k>)")]
    UnknownDot {
        /// The name as given.
        name: String,
        /// Lip dots in the layout.
        lip_dots: usize,
    },
    /// A JSONL line gives the same dot twice.
    #[error("dot {name} is given twice")]
    DuplicateDot {
        /// The dot's name.
        name: String,
    },
    /// A configuration value is out of range.
    #[error("invalid setting `{key}`: {reason}")]
    InvalidConfig {
        /// Setting name.
        key: &'static str,
        /// What was expected.
        reason: String,
    },
    /// A setting of a table (`rig.ranges.jawOpen`) is wrong; the key names it in full.
    #[error("invalid setting `{key}`: {reason}")]
    InvalidSetting { key: String, reason: String },
}

fn line_prefix(line: Option<usize>) -> String {
    match line {
        Some(l) => format!("line {l}: "),
        None => String::new(),
    }
}

/// 1-based line number of a byte offset into `src`.
pub(crate) fn line_of(src: &str, offset: usize) -> usize {
    let end = offset.min(src.len());
    src.as_bytes()[..end]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}
