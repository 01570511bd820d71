//! A recorded session read to its end as fast as it decodes (`process`, `lipsync poses`):
//! an MCAP session (with each frame's log time) or an `.oni` through OpenNI2's player,
//! unpaced; the type by the file's extension.

use std::path::{Path, PathBuf};

use mouthpiece_recording::{RecordingError, SessionReader};

use crate::{CaptureConfig, Frame, FrameSource, SourceError};

/// A finite stream of frames from a recorded session.
pub enum SessionFile {
    Mcap(Box<SessionReader>),
    Oni(Box<dyn FrameSource>),
}

/// Why a session cannot be opened or read.
#[derive(Debug, thiserror::Error)]
pub enum SessionFileError {
    #[error("cannot open session {}", path.display())]
    OpenMcap {
        path: PathBuf,
        #[source]
        source: RecordingError,
    },
    #[error("cannot open session {}", path.display())]
    OpenOni {
        path: PathBuf,
        #[source]
        source: SourceError,
    },
    #[error("{}: unknown session type (expected .mcap or .oni)", .0.display())]
    UnknownType(PathBuf),
    #[error(transparent)]
    Mcap(#[from] RecordingError),
    #[error(transparent)]
    Oni(#[from] SourceError),
}

impl SessionFileError {
    /// The caller's file, not the machine, is at fault (exit code 2).
    pub fn is_bad_input(&self) -> bool {
        match self {
            Self::OpenMcap { .. } | Self::OpenOni { .. } | Self::UnknownType(_) => true,
            Self::Mcap(e) => e.is_bad_input(),
            Self::Oni(_) => false,
        }
    }
}

impl SessionFile {
    /// Opens a session by its file extension.
    pub fn open(path: &Path) -> Result<Self, SessionFileError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("mcap") => {
                let reader =
                    SessionReader::open(path).map_err(|source| SessionFileError::OpenMcap {
                        path: path.to_path_buf(),
                        source,
                    })?;
                Ok(Self::Mcap(Box::new(reader)))
            }
            Some("oni") => {
                // OpenNI2 playback, unpaced (`speed=0`).
                let spec = format!("replay:{}?speed=0", path.display());
                let source =
                    crate::open_source(&spec, &CaptureConfig::default()).map_err(|source| {
                        SessionFileError::OpenOni {
                            path: path.to_path_buf(),
                            source,
                        }
                    })?;
                Ok(Self::Oni(source))
            }
            _ => Err(SessionFileError::UnknownType(path.to_path_buf())),
        }
    }

    pub fn next_frame(&mut self) -> Result<Option<Frame>, SessionFileError> {
        Ok(self.next_logged()?.map(|(f, _)| f))
    }

    /// The next frame and, from an MCAP file, its log time (ns).
    pub fn next_logged(&mut self) -> Result<Option<(Frame, Option<u64>)>, SessionFileError> {
        match self {
            Self::Mcap(r) => Ok(r.next_frame()?.map(|f| (f.frame, Some(f.log_time)))),
            Self::Oni(s) => Ok(s.next_frame()?.map(|f| (f, None))),
        }
    }
}
