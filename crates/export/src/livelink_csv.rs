//! Live Link Face's CSV take layout (`export --format livelink-csv`, docs/export.md): the file
//! the iPhone app writes for each take, which importers of its takes read unchanged.
//!
//! Header: `Timecode,BlendShapeCount,` then the 61 value names as the app writes them
//! ([`LIVELINK_CSV_COLUMNS`]); one row per frame: the frame's timecode (`HH:MM:SS:FF.fff`,
//! the sub-frame in thousandths after the point), `61`, then the values, each under the column
//! its name says. The values are the character's ARKit face ([`ArkitFace`]: the rig's curves,
//! the head and eye angles in radians), the same as the Live Link stream sends.

use std::io::{self, Write};
use std::path::{Path, PathBuf};

use mouthpiece_output::{
    ArkitFace, CharacterFrame, CharacterHead, HeadAxes, RigState, LIVELINK_NAMES, LIVELINK_VALUES,
};

use crate::csv::CsvSummary;
use crate::output::PendingFile;
use crate::{ExportError, MouthRig, TakeFrame};

/// The value columns in the order the app writes them: [`LIVELINK_NAMES`] (the datagram's
/// order) except that its CSV header lists `JawRight` before `JawLeft` and `MouthRight` before
/// `MouthLeft`. Importers read the columns by name; each column holds the value its name says.
pub const LIVELINK_CSV_COLUMNS: [&str; LIVELINK_VALUES] = csv_columns();

const fn csv_columns() -> [&'static str; LIVELINK_VALUES] {
    let mut out = LIVELINK_NAMES;
    // JawLeft 15, JawRight 16; MouthLeft 21, MouthRight 22 (checked by a test).
    out.swap(15, 16);
    out.swap(21, 22);
    out
}

/// Streaming writer of a Live Link Face CSV take.
pub struct LiveLinkCsvWriter {
    out: PendingFile,
    path: PathBuf,
    rows: u64,
    row: String,
    axes: HeadAxes,
    /// For each CSV column, its index in [`LIVELINK_NAMES`].
    order: [usize; LIVELINK_VALUES],
    source_name: String,
}

impl LiveLinkCsvWriter {
    /// Starts `path` (written under a temporary name until [`finish`](Self::finish)). The
    /// rig's placement gives the character's head-frame axes (its mouth frame's) in which the
    /// head and eye angles are taken.
    pub fn create(rig: &MouthRig, path: &Path) -> Result<Self, ExportError> {
        let err = |cause| ExportError::write(path, cause);
        let m = rig.placement().rotation.to_rotation_matrix();
        let m = m.matrix();
        let axes = HeadAxes::from_columns([
            [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
            [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
            [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
        ]);
        let order = LIVELINK_CSV_COLUMNS.map(|c| {
            LIVELINK_NAMES
                .iter()
                .position(|n| *n == c)
                .expect("a Live Link name")
        });
        let mut out = PendingFile::create(path).map_err(err)?;
        let mut header = String::from("Timecode,BlendShapeCount");
        for c in LIVELINK_CSV_COLUMNS {
            header.push(',');
            header.push_str(c);
        }
        header.push('\n');
        out.write_all(header.as_bytes()).map_err(err)?;
        Ok(Self {
            out,
            path: path.to_path_buf(),
            rows: 0,
            row: String::new(),
            axes,
            order,
            source_name: "take".into(),
        })
    }

    /// Names the take in error messages (its file).
    pub fn named(mut self, source_name: impl Into<String>) -> Self {
        self.source_name = source_name.into();
        self
    }

    /// The frame's ARKit face: its rig's curves and its head as the stream carries them.
    pub fn face(&self, frame: &TakeFrame) -> ArkitFace {
        let f32s = |q: [f64; 4]| q.map(|v| v as f32);
        let character = CharacterFrame {
            rig: frame.rig.map(|r| {
                let mut rig = RigState::default();
                for (c, v) in rig.curves.0.iter_mut().zip(&r.curves) {
                    *c = *v as f32;
                }
                rig
            }),
            head: frame.head.map(|h| CharacterHead {
                rotation: f32s(h.head),
                eye_left: f32s(h.eye_left),
                eye_right: f32s(h.eye_right),
                ..CharacterHead::default()
            }),
            ..CharacterFrame::default()
        };
        ArkitFace::from_character(&character, &self.axes)
    }

    /// Appends one frame as a row at `timecode` (`HH:MM:SS:FF.fff`).
    pub fn push(&mut self, frame: &TakeFrame, timecode: &str) -> Result<(), ExportError> {
        use std::fmt::Write as _;
        let values = self.face(frame).livelink_values();
        self.row.clear();
        let _ = write!(self.row, "{timecode},{LIVELINK_VALUES}");
        for &i in &self.order {
            let _ = write!(self.row, ",{:.10}", values[i]);
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
        Ok(CsvSummary {
            rows: self.rows,
            file: path,
        })
    }
}

/// A timecode label and the sub-frame (0..1) as the app's CSV writes them:
/// `HH:MM:SS:FF.fff` (`;` before the frames at a drop-frame rate), the sub-frame truncated to
/// thousandths.
pub fn livelink_timecode(label: &str, sub_frame: f64) -> String {
    let thousandths = if sub_frame.is_finite() {
        (sub_frame.clamp(0.0, 0.999_999) * 1000.0).floor() as u32
    } else {
        0
    };
    format!("{label}.{thousandths:03}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_are_the_apps_header() {
        // The header Live Link Face writes, as published takes show it.
        let app = "EyeBlinkLeft,EyeLookDownLeft,EyeLookInLeft,EyeLookOutLeft,EyeLookUpLeft,\
EyeSquintLeft,EyeWideLeft,EyeBlinkRight,EyeLookDownRight,EyeLookInRight,EyeLookOutRight,\
EyeLookUpRight,EyeSquintRight,EyeWideRight,JawForward,JawRight,JawLeft,JawOpen,MouthClose,\
MouthFunnel,MouthPucker,MouthRight,MouthLeft,MouthSmileLeft,MouthSmileRight,MouthFrownLeft,\
MouthFrownRight,MouthDimpleLeft,MouthDimpleRight,MouthStretchLeft,MouthStretchRight,\
MouthRollLower,MouthRollUpper,MouthShrugLower,MouthShrugUpper,MouthPressLeft,MouthPressRight,\
MouthLowerDownLeft,MouthLowerDownRight,MouthUpperUpLeft,MouthUpperUpRight,BrowDownLeft,\
BrowDownRight,BrowInnerUp,BrowOuterUpLeft,BrowOuterUpRight,CheekPuff,CheekSquintLeft,\
CheekSquintRight,NoseSneerLeft,NoseSneerRight,TongueOut,HeadYaw,HeadPitch,HeadRoll,\
LeftEyeYaw,LeftEyePitch,LeftEyeRoll,RightEyeYaw,RightEyePitch,RightEyeRoll";
        assert_eq!(LIVELINK_CSV_COLUMNS.join(","), app);
    }

    #[test]
    fn timecodes_carry_the_sub_frame_in_thousandths() {
        assert_eq!(livelink_timecode("12:27:47:47", 0.1695), "12:27:47:47.169");
        assert_eq!(livelink_timecode("00:00:00:00", 0.0), "00:00:00:00.000");
        assert_eq!(
            livelink_timecode("00:00:00:00", 0.99999999),
            "00:00:00:00.999"
        );
    }
}
