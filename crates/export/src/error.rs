//! The one error type of this crate.

use std::io;
use std::path::PathBuf;

/// Everything that can go wrong while reading a take or writing an export.
///
/// [`ExportError::is_bad_input`] tells the user's mistakes (a malformed take, a bad
/// tolerance, a character that does not match the take) from the machine's (disk full).
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// A take line that is not JSON of the expected shape.
    #[error("{source_name}: line {line}: not a take line")]
    Json {
        source_name: String,
        line: u64,
        #[source]
        cause: serde_json::Error,
    },
    /// A take line that parses but is wrong (times, names, numbers).
    #[error("{source_name}: line {line}: {problem}")]
    BadLine {
        source_name: String,
        line: u64,
        problem: String,
    },
    /// The take has no frames at all.
    #[error("{source_name}: the take has no frames")]
    EmptyTake { source_name: String },
    /// `--curve` was asked for and no line of the take has a `curve` with points.
    #[error("{source_name}: no line has a `curve` with points (export without --curve)")]
    NoCurve { source_name: String },
    /// Reading the take failed (including bytes that are not UTF-8).
    #[error("{source_name}: reading line {line}")]
    Read {
        source_name: String,
        line: u64,
        #[source]
        cause: io::Error,
    },
    /// The character file cannot be read.
    #[error("reading the character file {}", path.display())]
    CharacterRead {
        path: PathBuf,
        #[source]
        cause: io::Error,
    },
    /// The character file is not a valid character (the retarget core says why).
    #[error("character file {}", path.display())]
    Character {
        path: PathBuf,
        /// Boxed: the retarget error is large and this one is rare.
        #[source]
        cause: Box<mouthpiece_retarget::Error>,
    },
    /// The take names another character than the character file.
    #[error(
        "{source_name}: the take was made for character `{take}`, the character file is `{file}`"
    )]
    CharacterMismatch {
        /// The take, as its reader names it.
        source_name: String,
        /// The take's character, as shown (escaped, cut).
        take: String,
        file: String,
    },
    /// The description of the character's mouth (names, rest pose, placement) is unusable.
    #[error("character: {0}")]
    BadRig(String),
    /// A playback speed outside the range `play` keeps its waits finite in.
    #[error("--speed must be from {min} to {max}, got {0}", min = crate::play::MIN_SPEED, max = crate::play::MAX_SPEED)]
    BadSpeed(f64),
    /// `--reduce` needs a finite tolerance ≥ 0.
    #[error("reduce tolerance {0} is not a finite number ≥ 0")]
    BadTolerance(f64),
    /// GLB stores lengths in 32 bits.
    #[error("the take needs {bytes} bytes of key data, more than GLB's 4 GiB limit: export .gltf instead")]
    TooLargeForGlb { bytes: u64 },
    /// Writing the output or the spool files next to it failed.
    #[error("writing {}", path.display())]
    Write {
        path: PathBuf,
        #[source]
        cause: io::Error,
    },
    /// A rigged glTF (`export --rig`) that the take cannot be written onto.
    #[error("rig {}: {problem}", path.display())]
    Rig { path: PathBuf, problem: String },
    /// The rigged glTF cannot be read.
    #[error("reading the rig {}", path.display())]
    RigRead {
        path: PathBuf,
        #[source]
        cause: io::Error,
    },
    /// An avatar (`export --onto`) that is malformed or has nothing the take can drive.
    #[error("avatar {}: {problem}", path.display())]
    Avatar { path: PathBuf, problem: String },
    /// The avatar file cannot be read.
    #[error("reading the avatar {}", path.display())]
    AvatarRead {
        path: PathBuf,
        #[source]
        cause: io::Error,
    },
    /// Serialising the glTF JSON failed (does not happen for well-formed documents).
    #[error("serialising the glTF document")]
    Serialize(#[source] serde_json::Error),
}

impl ExportError {
    /// True when the user's input or options are at fault (exit code 2 in the binary).
    pub fn is_bad_input(&self) -> bool {
        matches!(
            self,
            Self::Json { .. }
                | Self::BadLine { .. }
                | Self::CharacterRead { .. }
                | Self::Character { .. }
                | Self::CharacterMismatch { .. }
                | Self::EmptyTake { .. }
                | Self::NoCurve { .. }
                | Self::BadRig(_)
                | Self::BadTolerance(_)
                | Self::BadSpeed(_)
                | Self::TooLargeForGlb { .. }
                | Self::Rig { .. }
                | Self::RigRead { .. }
                | Self::Avatar { .. }
                | Self::AvatarRead { .. }
        ) || matches!(self, Self::Read { cause, .. } if cause.kind() == io::ErrorKind::InvalidData)
    }

    pub(crate) fn write(path: impl Into<PathBuf>, cause: io::Error) -> Self {
        Self::Write {
            path: path.into(),
            cause,
        }
    }
}
