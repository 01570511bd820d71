//! `mouthpiece retarget`'s files: 3D dots (JSONL, a file or stdin) → character mouth points
//! (JSONL, a file or stdout); the lines are [`mouthpiece_retarget::batch`]'s. A regular input
//! file is read twice (the neutral pose first); stdin, a pipe or a device is streamed. Output
//! to a file goes to a temporary file beside it, renamed into place only on success.

use std::fs::File;
use std::io::{self, BufReader, BufWriter, Seek, Write};
use std::path::{Path, PathBuf};

use mouthpiece_retarget::batch::{self, BatchError, LookAt};
use mouthpiece_retarget::jsonl::OutputLine;
use mouthpiece_retarget::{Character, RetargetConfig};

use crate::PendingFile;

/// Why the files could not be retargeted.
#[derive(Debug, thiserror::Error)]
pub enum RetargetFilesError {
    #[error("cannot open input {}", path.display())]
    Open {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error("cannot rewind {name}")]
    Rewind {
        name: String,
        #[source]
        source: io::Error,
    },
    #[error("cannot create output {}", path.display())]
    Create {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error(transparent)]
    Batch(#[from] BatchError),
}

impl RetargetFilesError {
    /// The caller's files, not the machine, are at fault (exit code 2).
    pub fn is_bad_input(&self) -> bool {
        match self {
            Self::Open { .. } | Self::Create { .. } => true,
            Self::Rewind { .. } => false,
            Self::Batch(e) => e.is_bad_input(),
        }
    }
}

fn is_dash(p: &Path) -> bool {
    p.as_os_str() == "-"
}

/// Retargets `input` (`-`: stdin) to `out` (`-`: stdout); the number of lines written, or
/// none when the reader went away (a closed pipe on stdout), which ends it quietly.
pub fn retarget_files(
    input: &Path,
    out: &Path,
    character: Character,
    config: RetargetConfig,
    look_at: Option<LookAt>,
) -> Result<Option<u64>, RetargetFilesError> {
    let input_name = if is_dash(input) {
        "stdin".to_string()
    } else {
        input.display().to_string()
    };
    let result = if is_dash(input) {
        let mut out = Output::open(out, true)?;
        let stdin = io::stdin().lock();
        let written =
            batch::retarget_stream(stdin, &input_name, character, config, look_at, &mut out);
        written.and_then(|n| out.finish().map(|()| n))
    } else {
        let file = File::open(input).map_err(|source| RetargetFilesError::Open {
            path: input.to_path_buf(),
            source,
        })?;
        let regular = file.metadata().is_ok_and(|m| m.is_file());
        let mut reader = BufReader::new(file);
        if regular {
            let neutral = batch::scan(&mut reader, &input_name, character.len())?;
            reader
                .rewind()
                .map_err(|source| RetargetFilesError::Rewind {
                    name: input_name.clone(),
                    source,
                })?;
            let mut out = Output::open(out, false)?;
            let written = batch::retarget_file(
                reader,
                &input_name,
                character,
                config,
                neutral,
                look_at,
                &mut out,
            );
            written.and_then(|n| out.finish().map(|()| n))
        } else {
            // A pipe or device given by path: it cannot be read twice, so stream it like stdin.
            let mut out = Output::open(out, true)?;
            let written =
                batch::retarget_stream(reader, &input_name, character, config, look_at, &mut out);
            written.and_then(|n| out.finish().map(|()| n))
        }
    };
    match result {
        Ok(lines) => Ok(Some(lines)),
        Err(e) if e.is_broken_pipe() => Ok(None),
        Err(e) => Err(e.into()),
    }
}

/// Where the output goes: stdout, or a file written under a temporary name and moved into
/// place by `finish` ([`PendingFile`]).
struct Output {
    sink: Sink,
    flush_each_line: bool,
}

enum Sink {
    Stdout(BufWriter<io::Stdout>),
    File(PendingFile),
}

impl Output {
    fn open(path: &Path, streaming: bool) -> Result<Self, RetargetFilesError> {
        let sink = if is_dash(path) {
            Sink::Stdout(BufWriter::new(io::stdout()))
        } else {
            Sink::File(
                PendingFile::create(path).map_err(|source| RetargetFilesError::Create {
                    path: path.to_path_buf(),
                    source,
                })?,
            )
        };
        Ok(Self {
            flush_each_line: streaming && matches!(sink, Sink::Stdout(_)),
            sink,
        })
    }

    /// Flushes stdout, or moves the file into place.
    fn finish(self) -> Result<(), BatchError> {
        match self.sink {
            Sink::Stdout(mut w) => w.flush().map_err(BatchError::Output),
            Sink::File(f) => f.commit().map_err(BatchError::Output),
        }
    }
}

impl batch::LineSink for Output {
    fn write_line(&mut self, line: &OutputLine) -> io::Result<()> {
        let writer: &mut dyn Write = match &mut self.sink {
            Sink::Stdout(w) => w,
            Sink::File(f) => f,
        };
        serde_json::to_writer(&mut *writer, line)?;
        writer.write_all(b"\n")?;
        if self.flush_each_line {
            writer.flush()?;
        }
        Ok(())
    }
}
