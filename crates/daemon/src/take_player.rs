//! The takes folder as the console's player reads it ([`TakeFolder`], served at `/take`): a
//! chunk of a take is read by [`mouthpiece_takes::read::read_chunk`].
//!
//! Only plain take file names are opened (what the daemon names takes: ASCII letters, digits,
//! `-`, `_`, `.`, ending in `.mcap`), and only when the file, symlinks resolved, lies directly
//! in the takes folder.

use std::path::PathBuf;

use mouthpiece_server::{TakeArchive, TakeChunk, TakeChunkError};
use mouthpiece_takes::read::{read_chunk, MAX_CHUNK_BYTES};

/// The daemon's takes folder, read for the console's player.
#[derive(Debug, Clone)]
pub struct TakeFolder {
    folder: PathBuf,
}

impl TakeFolder {
    pub fn new(folder: impl Into<PathBuf>) -> Self {
        Self {
            folder: folder.into(),
        }
    }

    /// The file of take `name`: a take file name, directly in the folder.
    pub fn path_of(&self, name: &str) -> Result<PathBuf, TakeChunkError> {
        let plain = name.len() <= 255
            && name.ends_with(".mcap")
            && name
                .chars()
                .next()
                .is_some_and(|c| c.is_ascii_alphanumeric())
            && name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
        if !plain {
            return Err(TakeChunkError::BadName(format!(
                "{:?} is not a take's file name (letters, digits, '-', '_', '.', ending in .mcap; no folders)",
                name.chars().take(80).collect::<String>()
            )));
        }
        let folder = std::fs::canonicalize(&self.folder)
            .map_err(|_| TakeChunkError::NotFound("there is no takes folder yet".into()))?;
        let real = std::fs::canonicalize(folder.join(name))
            .map_err(|_| TakeChunkError::NotFound(format!("no take {name} in the takes folder")))?;
        if real.parent() != Some(folder.as_path()) || !real.is_file() {
            return Err(TakeChunkError::BadName(format!(
                "{name} is not a take in the takes folder"
            )));
        }
        Ok(real)
    }
}

impl TakeArchive for TakeFolder {
    fn chunk(&self, file: &str, from_s: f64, seconds: f64) -> Result<TakeChunk, TakeChunkError> {
        let path = self.path_of(file)?;
        read_chunk(&path, from_s, seconds, MAX_CHUNK_BYTES)
    }
}

#[cfg(test)]
mod tests;
