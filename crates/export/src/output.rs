//! Output files that appear complete or not at all.

use std::fs::{self, File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// A file written under a hidden temporary name in its final directory and renamed into
/// place by [`commit`](Self::commit); dropped uncommitted, the temporary file is removed.
/// Unlike `tempfile`'s files it is created with the usual permissions (0666 less umask).
///
/// A destination that exists and is not a regular file (`/dev/null`, a FIFO, a terminal) is
/// written directly: renaming over it would replace the device node or pipe with a file.
/// Used by `export`, `process` and `retarget`.
pub struct PendingFile {
    path: PathBuf,
    /// `None` when writing straight to a non-regular destination.
    tmp: Option<PathBuf>,
    writer: Option<BufWriter<File>>,
}

impl PendingFile {
    pub fn create(path: &Path) -> io::Result<Self> {
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        if fs::metadata(path).is_ok_and(|m| !m.is_file()) {
            let file = OpenOptions::new().write(true).open(path)?;
            return Ok(Self {
                path: path.to_path_buf(),
                tmp: None,
                writer: Some(BufWriter::with_capacity(64 * 1024, file)),
            });
        }
        let dir = parent_dir(path);
        let name = path.file_name().unwrap_or_default().to_string_lossy();
        let tmp = dir.join(format!(
            ".{name}.{}-{}.partial",
            std::process::id(),
            COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        let file = OpenOptions::new().write(true).create_new(true).open(&tmp)?;
        Ok(Self {
            path: path.to_path_buf(),
            tmp: Some(tmp),
            writer: Some(BufWriter::with_capacity(64 * 1024, file)),
        })
    }

    pub(crate) fn writer(&mut self) -> &mut BufWriter<File> {
        self.writer.as_mut().expect("writer present until commit")
    }

    /// Flushes and moves the file into place.
    pub fn commit(mut self) -> io::Result<()> {
        let writer = self.writer.take().expect("writer present until commit");
        writer.into_inner().map_err(|e| e.into_error())?;
        match &self.tmp {
            Some(tmp) => fs::rename(tmp, &self.path),
            None => Ok(()),
        }
    }
}

impl Drop for PendingFile {
    fn drop(&mut self) {
        if let (Some(_), Some(tmp)) = (self.writer.take(), &self.tmp) {
            let _ = fs::remove_file(tmp);
        }
    }
}

impl Write for PendingFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.writer().write(buf)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.writer().flush()
    }
}

/// The directory a path's file lives in (`.` for a bare name).
pub(crate) fn parent_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}
