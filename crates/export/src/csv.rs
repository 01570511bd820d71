//! CSV writer: one row per frame, `t` then x, y, z per point (then the head's rotations,
//! then the rig's jaw and named curves), for spreadsheets and DCC import scripts. Streams straight to the output (through a temporary file renamed at the
//! end), so memory does not grow with the take.

use std::io::{self, Write};
use std::path::{Path, PathBuf};

use mouthpiece_retarget::rig::{CURVES, CURVE_NAMES};

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
/// Header: `t,P1_x,P1_y,P1_z,…` (names quoted per RFC 4180 when they need it), the head's
/// columns when the first line has `character_head`, then always the rig's
/// ([`RIG_COLUMNS`], then the curve names). Numbers are written in full (shortest text that
/// reads back to the same f64); a point that is `null` in the take leaves its three cells
/// empty, a line without `rig` (before the neutral pose, or a take made before the rig) its
/// rig cells. Lines end in `\n`.
pub struct CsvWriter {
    out: PendingFile,
    path: PathBuf,
    points: usize,
    rows: u64,
    row: String,
    /// The header, written with the first row (which says whether the take has a head).
    header: Option<String>,
    /// Whether the rows carry the head columns.
    head: bool,
    /// What error messages call the take (its file name; "take" until set).
    source_name: String,
    /// The character's mouth width (its units) and metres per unit, for the slide and the
    /// lips' translations ([`crate::RigKeys::to_character`]).
    width: f64,
    metres_per_unit: Option<f64>,
}

/// The head columns' prefixes, in order (docs/head.md).
pub const HEAD_COLUMNS: [&str; 3] = ["head", "eye_L", "eye_R"];

/// The rig's jaw and lip columns (docs/rig.md, docs/export.md), followed by one column per
/// curve name. The slide and the lips' translations are in the character's units.
pub const RIG_COLUMNS: [&str; 16] = [
    "jaw_angle_deg",
    "jaw_slide",
    "lip_upper_qw",
    "lip_upper_qx",
    "lip_upper_qy",
    "lip_upper_qz",
    "lip_upper_x",
    "lip_upper_y",
    "lip_upper_z",
    "lip_lower_qw",
    "lip_lower_qx",
    "lip_lower_qy",
    "lip_lower_qz",
    "lip_lower_x",
    "lip_lower_y",
    "lip_lower_z",
];

impl CsvWriter {
    /// Starts `path` (written under a temporary name until [`finish`](Self::finish)).
    pub fn create(rig: &MouthRig, path: &Path) -> Result<Self, ExportError> {
        let err = |cause| ExportError::write(path, cause);
        let mut header = String::from("t");
        for p in rig.points() {
            for axis in ["x", "y", "z"] {
                header.push(',');
                header.push_str(&quote(&format!("{}_{axis}", p.name)));
            }
        }
        let out = PendingFile::create(path).map_err(err)?;
        Ok(Self {
            out,
            path: path.to_path_buf(),
            points: rig.points().len(),
            rows: 0,
            row: String::new(),
            header: Some(header),
            head: false,
            source_name: "take".into(),
            width: rig.mouth_width(),
            metres_per_unit: rig.metres_per_unit(),
        })
    }

    /// Names the take in error messages (its file).
    pub fn named(mut self, source_name: impl Into<String>) -> Self {
        self.source_name = source_name.into();
        self
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
        if let Some(mut header) = self.header.take() {
            // The first row says whether the take has the character's head.
            self.head = frame.head.is_some();
            if self.head {
                for node in HEAD_COLUMNS {
                    for c in ["qw", "qx", "qy", "qz"] {
                        let _ = write!(header, ",{node}_{c}");
                    }
                }
            }
            for column in RIG_COLUMNS.iter().chain(&CURVE_NAMES) {
                let _ = write!(header, ",{column}");
            }
            header.push('\n');
            self.row.push_str(&header);
        }
        if frame.head.is_some() != self.head {
            return Err(ExportError::BadLine {
                source_name: self.source_name.clone(),
                line: frame.line,
                problem: "`character_head` on some lines and not on others".into(),
            });
        }
        let _ = write!(self.row, "{}", frame.t);
        for p in &frame.points {
            match p {
                Some([x, y, z]) => {
                    let _ = write!(self.row, ",{x},{y},{z}");
                }
                None => self.row.push_str(",,,"),
            }
        }
        for q in frame.head.iter().flat_map(|h| h.rotations()) {
            let [w, x, y, z] = q;
            let _ = write!(self.row, ",{w},{x},{y},{z}");
        }
        match &frame.rig {
            Some(rig) => {
                let k = rig.to_character(self.width, self.metres_per_unit);
                let _ = write!(self.row, ",{},{}", rig.jaw_angle_deg, rig.jaw_slide_m * k);
                for lip in &rig.lips {
                    let [w, x, y, z] = lip.rotation;
                    let [tx, ty, tz] = lip.translation_m.map(|c| c * k);
                    let _ = write!(self.row, ",{w},{x},{y},{z},{tx},{ty},{tz}");
                }
                for v in &rig.curves {
                    let _ = write!(self.row, ",{v}");
                }
            }
            None => self
                .row
                .extend(std::iter::repeat_n(',', RIG_COLUMNS.len() + CURVES)),
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
                source_name: self.source_name,
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

/// A text cell (the header's names; [`unguard`] undoes the guard): a leading `=`, `+`, `-`, `@`, tab or carriage return,
/// which a spreadsheet would run as a formula, gets a `'` in front (OWASP's advice against
/// CSV injection; the spreadsheet shows the text as written), then RFC 4180 quoting when the
/// cell holds a comma, quote or line break.
pub fn quote(field: &str) -> String {
    let field = if field.starts_with(['=', '+', '-', '@', '\t', '\r']) {
        format!("'{field}")
    } else {
        field.to_owned()
    };
    if field.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", field.replace('"', "\"\""))
    } else {
        field
    }
}

/// A text cell as [`quote`] wrote it, once a CSV reader has taken the RFC 4180 quoting
/// off: the `'` put before a formula character is dropped.
pub fn unguard(cell: &str) -> &str {
    match cell.strip_prefix('\'') {
        Some(rest) if rest.starts_with(['=', '+', '-', '@', '\t', '\r']) => rest,
        _ => cell,
    }
}

#[cfg(test)]
pub(crate) mod tests {
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
            head: None,
            rig: None,
        })
        .unwrap();
        w.push(&TakeFrame {
            line: 2,
            t: 1.0 / 3.0,
            points: vec![Some([1e-9, 0.0, 1.0]), Some([1.0, 2.0, 3.0])],
            curve: None,
            head: None,
            rig: None,
        })
        .unwrap();
        let summary = w.finish().unwrap();
        assert_eq!(summary.rows, 2);
        let text = std::fs::read_to_string(&path).unwrap();
        // A take without a rig: its columns are there, empty.
        let empty_rig = ",".repeat(RIG_COLUMNS.len() + CURVES);
        assert_eq!(
            text,
            format!(
                "t,P1_x,P1_y,P1_z,\"odd,name_x\",\"odd,name_y\",\"odd,name_z\",{}\n\
                 0,0.1,-2.5,3,,,{empty_rig}\n\
                 0.3333333333333333,0.000000001,0,1,1,2,3{empty_rig}\n",
                rig_header()
            )
        );
    }

    #[test]
    fn names_cannot_break_columns_or_run_as_formulas() {
        let dir = tempfile::tempdir().unwrap();
        let names = [
            "=HYPERLINK(\"http://x\",\"y\")",
            "a,b",
            "say \"hi\"",
            "two\nlines",
            "@SUM(A1)",
            "+1",
            "-2",
            "plain",
        ];
        let rig = MouthRig::new(
            None,
            names
                .iter()
                .map(|n| RigPoint {
                    name: (*n).into(),
                    rest: [0.0; 3],
                })
                .collect(),
            nalgebra::Isometry3::identity(),
        )
        .unwrap();
        let path = dir.path().join("take.csv");
        let mut w = CsvWriter::create(&rig, &path).unwrap();
        w.push(&TakeFrame {
            line: 1,
            t: 0.0,
            points: vec![Some([-1.0, 2.0, 3.0]); names.len()],
            curve: None,
            head: None,
            rig: None,
        })
        .unwrap();
        w.finish().unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let header = rfc4180_cells(&text);
        assert_eq!(header[0], "t");
        for (k, name) in names.iter().enumerate() {
            let cell = &header[1 + 3 * k];
            let expected = if name.starts_with(['=', '+', '-', '@']) {
                format!("'{name}_x")
            } else {
                format!("{name}_x")
            };
            assert_eq!(cell, &expected);
        }
        assert_eq!(
            header.len(),
            1 + 3 * names.len() + RIG_COLUMNS.len() + CURVES
        );
        // Numbers stay numbers: only text cells get the quote mark.
        let row = text.lines().last().unwrap();
        assert!(row.starts_with("0,-1,2,3,-1,2,3"), "{row}");
    }

    /// The first record of an RFC 4180 text, cell by cell (quotes undone).
    fn rfc4180_cells(text: &str) -> Vec<String> {
        let mut cells = vec![String::new()];
        let mut quoted = false;
        let mut chars = text.chars().peekable();
        while let Some(c) = chars.next() {
            match (quoted, c) {
                (true, '"') if chars.peek() == Some(&'"') => {
                    chars.next();
                    cells.last_mut().unwrap().push('"');
                }
                (_, '"') => quoted = !quoted,
                (false, ',') => cells.push(String::new()),
                (false, '\n') => break,
                (_, c) => cells.last_mut().unwrap().push(c),
            }
        }
        cells
    }

    #[test]
    fn head_columns_follow_the_points() {
        let dir = tempfile::tempdir().unwrap();
        let rig = one_point_rig();
        let path = dir.path().join("take.csv");
        let mut w = CsvWriter::create(&rig, &path).unwrap();
        let head = crate::HeadKeys {
            head: [0.5, 0.5, 0.5, 0.5],
            eye_left: [1.0, 0.0, 0.0, 0.0],
            eye_right: [0.0, 1.0, 0.0, 0.0],
        };
        let frame = |line, head| TakeFrame {
            line,
            t: line as f64,
            points: vec![Some([1.0, 2.0, 3.0])],
            curve: None,
            head,
            rig: None,
        };
        w.push(&frame(1, Some(head))).unwrap();
        let e = w.push(&frame(2, None)).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("character_head"), "{e}");
        w.finish().unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(
            text,
            format!(
                "t,P1_x,P1_y,P1_z,head_qw,head_qx,head_qy,head_qz,eye_L_qw,eye_L_qx,eye_L_qy,eye_L_qz,eye_R_qw,eye_R_qx,eye_R_qy,eye_R_qz,{}\n\
                 1,1,2,3,0.5,0.5,0.5,0.5,1,0,0,0,0,1,0,0{}\n",
                rig_header(),
                ",".repeat(RIG_COLUMNS.len() + CURVES)
            )
        );
    }

    fn one_point_rig() -> MouthRig {
        MouthRig::new(
            None,
            vec![RigPoint {
                name: "P1".into(),
                rest: [0.0; 3],
            }],
            nalgebra::Isometry3::identity(),
        )
        .unwrap()
    }

    fn rig_header() -> String {
        let mut columns = RIG_COLUMNS.to_vec();
        columns.extend(CURVE_NAMES);
        columns.join(",")
    }

    #[test]
    fn rig_columns_hold_the_jaw_and_every_curve() {
        let dir = tempfile::tempdir().unwrap();
        let rig = one_point_rig();
        let path = dir.path().join("take.csv");
        let mut w = CsvWriter::create(&rig, &path).unwrap();
        let mut keys = crate::RigKeys::REST;
        keys.jaw_angle_deg = 14.25;
        keys.jaw_slide_m = -0.0015;
        for (k, c) in keys.curves.iter_mut().enumerate() {
            *c = k as f64 / CURVES as f64;
        }
        for (line, rig) in [(1, None), (2, Some(keys))] {
            w.push(&TakeFrame {
                line,
                t: line as f64,
                points: vec![Some([1.0, 2.0, 3.0])],
                curve: None,
                head: None,
                rig,
            })
            .unwrap();
        }
        w.finish().unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let rows: Vec<Vec<&str>> = text.lines().map(|l| l.split(',').collect()).collect();
        assert_eq!(
            rows[0][4..],
            rig_header().split(',').collect::<Vec<_>>()[..]
        );
        assert!(rows[1][4..].iter().all(|c| c.is_empty()), "{:?}", rows[1]);
        // A take without the performer's width: the slide in metres (the rig's units).
        assert_eq!(rows[2][4..6], ["14.25", "-0.0015"]);
        assert_eq!(
            rows[2][6..20],
            ["1", "0", "0", "0", "0", "0", "0"].repeat(2)
        );
        for (k, cell) in rows[2][20..].iter().enumerate() {
            assert_eq!(cell.parse::<f64>().unwrap(), k as f64 / CURVES as f64);
        }
        assert!(rows.iter().all(|r| r.len() == 1 + 3 + 16 + CURVES));
    }

    /// A rig whose mouth (corner to corner along x) is `width` wide, in metres.
    pub(crate) fn rig_of_width(width: f64) -> MouthRig {
        let corner = |name: &str, x: f64| RigPoint {
            name: name.into(),
            rest: [x, 0.0, 0.0],
        };
        MouthRig::new(
            None,
            vec![corner("P1", width / 2.0), corner("P2", -width / 2.0)],
            nalgebra::Isometry3::identity(),
        )
        .unwrap()
    }

    /// A frame of a take whose performer has a 5 cm mouth, the jaw slid 1.5 mm and the lips
    /// moved.
    pub(crate) fn performer_frame() -> TakeFrame {
        let mut keys = crate::RigKeys::REST;
        keys.jaw_slide_m = -0.0015;
        keys.lips[0].translation_m = [0.001, 0.002, -0.0005];
        keys.lips[1].translation_m = [-0.0025, -0.004, 0.003];
        keys.lips[1].rotation = [0.6, 0.8, 0.0, 0.0];
        keys.performer_width_m = Some(0.05);
        TakeFrame {
            line: 1,
            t: 0.0,
            points: vec![Some([0.0; 3]); 2],
            curve: None,
            head: None,
            rig: Some(keys),
        }
    }

    /// The slide and the lips' translations are in the character's units, scaled by its
    /// mouth width over the performer's: a character twice the performer's width gets twice
    /// the slide; rotations are not scaled.
    #[test]
    fn the_slide_and_the_lips_are_scaled_to_the_characters_mouth() {
        let dir = tempfile::tempdir().unwrap();
        let row = |width: f64| {
            let path = dir.path().join(format!("{width}.csv"));
            let mut w = CsvWriter::create(&rig_of_width(width), &path).unwrap();
            w.push(&performer_frame()).unwrap();
            w.finish().unwrap();
            let text = std::fs::read_to_string(&path).unwrap();
            let rows: Vec<Vec<String>> = text
                .lines()
                .map(|l| l.split(',').map(String::from).collect())
                .collect();
            let cell = |name: &str| {
                let k = rows[0].iter().position(|c| c == name).unwrap();
                rows[1][k].parse::<f64>().unwrap()
            };
            [
                "jaw_slide",
                "lip_upper_x",
                "lip_upper_y",
                "lip_upper_z",
                "lip_lower_x",
                "lip_lower_y",
                "lip_lower_z",
                "lip_lower_qw",
                "lip_lower_qx",
            ]
            .map(cell)
        };
        let same = row(0.05);
        let twice = row(0.1);
        let want = [-0.0015, 0.001, 0.002, -0.0005, -0.0025, -0.004, 0.003];
        for k in 0..7 {
            assert!((same[k] - want[k]).abs() < 1e-15, "{same:?}");
            assert!((twice[k] - 2.0 * want[k]).abs() < 1e-15, "{twice:?}");
        }
        assert_eq!(same[7..], [0.6, 0.8]);
        assert_eq!(twice[7..], [0.6, 0.8]);
    }
}
