//! CSV writer: one row per frame, `t` then x, y, z per point, for spreadsheets and DCC
//! import scripts. Streams straight to the output (through a temporary file renamed at the
//! end), so memory does not grow with the take.

use std::io::{self, Write};
use std::path::{Path, PathBuf};

use crate::output::PendingFile;
use crate::{ExportError, MouthRig, TakeFrame};

/// What [`CsvWriter::finish`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct CsvSummary {
    pub rows: u64,
    pub file: PathBuf,
}

/// Streaming CSV writer.
///
/// Header: `t,P1_x,P1_y,P1_z,…` (names quoted per RFC 4180 when they need it). Numbers are
/// written in full (shortest text that reads back to the same f64); a point that is `null`
/// in the take leaves its three cells empty. Lines end in `\n`.
pub struct CsvWriter {
    out: PendingFile,
    path: PathBuf,
    points: usize,
    rows: u64,
    row: String,
}

impl CsvWriter {
    /// Starts `path` (written under a temporary name until [`finish`](Self::finish)).
    pub fn create(rig: &MouthRig, path: &Path) -> Result<Self, ExportError> {
        let err = |cause| ExportError::write(path, cause);
        let mut out = PendingFile::create(path).map_err(err)?;
        let mut header = String::from("t");
        for p in rig.points() {
            for axis in ["x", "y", "z"] {
                header.push(',');
                header.push_str(&quote(&format!("{}_{axis}", p.name)));
            }
        }
        header.push('\n');
        out.write_all(header.as_bytes()).map_err(err)?;
        Ok(Self {
            out,
            path: path.to_path_buf(),
            points: rig.points().len(),
            rows: 0,
            row: String::new(),
        })
    }

    /// Appends one frame as a row.
    pub fn push(&mut self, frame: &TakeFrame) -> Result<(), ExportError> {
        use std::fmt::Write as _;
        if frame.points.len() != self.points {
            return Err(ExportError::BadRig(format!(
                "line {}: the frame has {} points, the rig {}",
                frame.line,
                frame.points.len(),
                self.points
            )));
        }
        self.row.clear();
        let _ = write!(self.row, "{}", frame.t);
        for p in &frame.points {
            match p {
                Some([x, y, z]) => {
                    let _ = write!(self.row, ",{x},{y},{z}");
                }
                None => self.row.push_str(",,,"),
            }
        }
        self.row.push('\n');
        self.out
            .write_all(self.row.as_bytes())
            .map_err(|cause| ExportError::write(&self.path, cause))?;
        self.rows += 1;
        Ok(())
    }

    /// Completes the file (renames it into place).
    pub fn finish(self) -> Result<CsvSummary, ExportError> {
        let path = self.path;
        let err = |cause: io::Error| ExportError::write(&path, cause);
        if self.rows == 0 {
            return Err(ExportError::EmptyTake {
                source_name: "take".into(),
            });
        }
        self.out.commit().map_err(err)?;
        tracing::debug!(rows = self.rows, out = %path.display(), "CSV written");
        Ok(CsvSummary {
            rows: self.rows,
            file: path,
        })
    }
}

/// RFC 4180 quoting for a field that holds a comma, quote or line break.
fn quote(field: &str) -> String {
    if field.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", field.replace('"', "\"\""))
    } else {
        field.to_owned()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::RigPoint;

    #[test]
    fn writes_header_rows_and_gaps() {
        let dir = tempfile::tempdir().unwrap();
        let rig = MouthRig::new(
            None,
            vec![
                RigPoint {
                    name: "P1".into(),
                    rest: [0.0; 3],
                },
                RigPoint {
                    name: "odd,name".into(),
                    rest: [0.0; 3],
                },
            ],
            nalgebra::Isometry3::identity(),
        )
        .unwrap();
        let path = dir.path().join("take.csv");
        let mut w = CsvWriter::create(&rig, &path).unwrap();
        assert!(!path.exists(), "nothing appears before finish");
        w.push(&TakeFrame {
            line: 1,
            t: 0.0,
            points: vec![Some([0.1, -2.5, 3.0]), None],
            curve: None,
        })
        .unwrap();
        w.push(&TakeFrame {
            line: 2,
            t: 1.0 / 3.0,
            points: vec![Some([1e-9, 0.0, 1.0]), Some([1.0, 2.0, 3.0])],
            curve: None,
        })
        .unwrap();
        let summary = w.finish().unwrap();
        assert_eq!(summary.rows, 2);
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(
            text,
            "t,P1_x,P1_y,P1_z,\"odd,name_x\",\"odd,name_y\",\"odd,name_z\"\n\
             0,0.1,-2.5,3,,,\n\
             0.3333333333333333,0.000000001,0,1,1,2,3\n"
        );
    }
}
