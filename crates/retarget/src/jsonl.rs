//! Line formats of `mouthpiece retarget` (one JSON object per line; `docs/retarget.md`).
//!
//! [`InputLine`]: raw 3D dots in the camera frame. [`OutputLine`]: one character's mouth per
//! time step; `process` extends it (flatten it into a larger struct) and `export` reads it.

use std::io::{self, BufRead};

use serde::{Deserialize, Serialize};

use crate::layout::{parse_dot_name, DotId, PerformerDots, PerformerLayout};
use crate::retarget::RetargetOutput;
use crate::smooth::ShapeSmoothing;
use crate::{Character, Error, Named, Vec3};

/// One input line: `{"t": 0.033, "points": {"D1": [x, y, z], …, "F3": null}, "neutral": true}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InputLine {
    /// Seconds since the start of the stream.
    pub t: f64,
    /// Dot name → camera-frame position (metres), `null` when not seen. A dot left out is
    /// not seen either.
    pub points: Named<Option<[f64; 3]>>,
    /// Whether this line belongs to the neutral pose.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub neutral: bool,
}

impl InputLine {
    /// Parses one line.
    pub fn parse(line: &str) -> Result<Self, Error> {
        serde_json::from_str(line).map_err(|source| Error::Json { source })
    }

    /// The highest forehead dot index named (1-based count), to size a layout.
    pub fn forehead_count(&self) -> usize {
        self.points
            .iter()
            .filter_map(|(name, _)| match parse_dot_name(name) {
                Some(DotId::Forehead(i)) => Some(i + 1),
                _ => None,
            })
            .max()
            .unwrap_or(0)
    }

    /// Writes the line's dots into `dots` (resized to the layout). Errors on a name that is not
    /// a dot name, a lip dot the layout does not have, a dot given twice, or a non-finite
    /// coordinate or timestamp. Forehead dots beyond the layout are checked and then ignored:
    /// they have no neutral reference to align with.
    pub fn dots_into(
        &self,
        layout: PerformerLayout,
        dots: &mut PerformerDots,
    ) -> Result<(), Error> {
        if !self.t.is_finite() {
            return Err(Error::NonFiniteTime { t: self.t });
        }
        dots.lip.resize(layout.lip_dots, None);
        dots.forehead.resize(layout.forehead_dots, None);
        dots.clear();
        let mut given = [0u64; 4];
        for (name, value) in self.points.iter() {
            let unknown = || Error::UnknownDot {
                name: name.to_string(),
                lip_dots: layout.lip_dots,
            };
            let id = parse_dot_name(name).ok_or_else(unknown)?;
            let bit = match id {
                DotId::Lip(i) if i < layout.lip_dots => i,
                DotId::Forehead(i) if i < layout.forehead_dots => layout.lip_dots + i,
                DotId::Forehead(_) => {
                    if value.is_some_and(|a| !a.iter().all(|c| c.is_finite())) {
                        return Err(Error::NonFinite {
                            dot: name.to_string(),
                        });
                    }
                    continue;
                }
                DotId::Lip(_) => return Err(unknown()),
            };
            if bit < 256 {
                if given[bit / 64] & (1 << (bit % 64)) != 0 {
                    return Err(Error::DuplicateDot {
                        name: name.to_string(),
                    });
                }
                given[bit / 64] |= 1 << (bit % 64);
            }
            let slot = dots.slot_mut(id).ok_or_else(unknown)?;
            if let Some(a) = value {
                if !a.iter().all(|c| c.is_finite()) {
                    return Err(Error::NonFinite {
                        dot: name.to_string(),
                    });
                }
                if !crate::layout::coordinates_in_range(a) {
                    return Err(Error::CoordinateOutOfRange {
                        dot: name.to_string(),
                        limit: crate::layout::MAX_COORDINATE,
                    });
                }
                *slot = Some(Vec3::new(a[0], a[1], a[2]));
            }
        }
        Ok(())
    }
}

/// Head pose on the wire (docs/method.md §10): `current = R · neutral + t`, camera frame;
/// the rotation with `w ≥ 0`. The one rigid pose of every output.
pub type HeadPose = mouthpiece_output::RigidPose;

/// The smoothed mouth outline of one step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Curve {
    /// How it was made: `ma`, `ma-weighted`, `ma-exp`, `sg5`, `bspline`.
    pub method: String,
    /// Always true: the last point joins the first.
    pub closed: bool,
    /// Curve points, character mouth frame and units.
    pub points: Vec<[f64; 3]>,
}

/// One output line (field order as written):
/// `{"t", "seq", "character", "points", "confidence", "head", "head_lost", "curve",
/// "character_head"}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OutputLine {
    /// The input line's timestamp.
    pub t: f64,
    /// 0-based index of the line in the stream.
    pub seq: u64,
    /// Character name.
    pub character: String,
    /// Point name → position in the character's mouth frame and units, in point order.
    pub points: Named<[f64; 3]>,
    /// Point name → confidence (1 seen, 0 held or decaying).
    pub confidence: Named<f64>,
    /// Head pose of the performer.
    pub head: HeadPose,
    /// The head pose is the last good one (fewer than 3 forehead dots usable).
    #[serde(default)]
    pub head_lost: bool,
    /// The smoothed curve, `null` without shape smoothing.
    #[serde(default)]
    pub curve: Option<Curve>,
    /// The rig of the step (docs/rig.md): jaw, lip motions, named curves. Absent before the
    /// neutral pose is taken.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rig: Option<crate::rig::RigFrame>,
    /// The character's head and eyes (docs/head.md); absent in takes made before heads.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub character_head: Option<crate::head::HeadLine>,
}

fn arr(v: &Vec3) -> [f64; 3] {
    [v.x, v.y, v.z]
}

impl OutputLine {
    /// A line for `character`, with its point names allocated once; fill it with
    /// [`OutputLine::update`] every step.
    pub fn for_character(character: &Character, smoothing: &ShapeSmoothing) -> Self {
        let names = &character.point_names;
        Self {
            t: 0.0,
            seq: 0,
            character: character.name.clone(),
            points: Named(names.iter().map(|n| (n.clone(), [0.0; 3])).collect()),
            confidence: Named(names.iter().map(|n| (n.clone(), 0.0)).collect()),
            head: HeadPose {
                rotation: [1.0, 0.0, 0.0, 0.0],
                translation: [0.0; 3],
            },
            head_lost: false,
            curve: match smoothing {
                ShapeSmoothing::None => None,
                s => Some(Curve {
                    method: s.name().to_string(),
                    closed: true,
                    points: Vec::with_capacity(s.curve_len(names.len())),
                }),
            },
            rig: None,
            character_head: Some(Default::default()),
        }
    }

    /// Overwrites the values with one step's output (no allocation once the curve buffer has
    /// grown).
    pub fn update(&mut self, seq: u64, out: &RetargetOutput<'_>) {
        let c = out.character;
        self.t = c.t;
        self.seq = seq;
        for ((_, dst), p) in self.points.0.iter_mut().zip(&c.points) {
            *dst = arr(p);
        }
        for ((_, dst), &w) in self.confidence.0.iter_mut().zip(&c.confidence) {
            *dst = w;
        }
        let head = &out.performer.head;
        self.head = HeadPose {
            rotation: head.quaternion_wxyz(),
            translation: arr(&head.translation),
        };
        self.head_lost = out.performer.head_lost;
        if let Some(curve) = &mut self.curve {
            curve.points.clear();
            curve.points.extend(c.curve.iter().map(arr));
        }
        self.character_head = Some((&c.head).into());
    }
}

/// Longest line read from a line-per-record input (take JSONL, `retarget`'s dots): a frame
/// line of a character with many points is a few kilobytes, so a longer one is not a take
/// (`/dev/zero`, a binary file) and is refused before it fills memory.
pub const MAX_LINE_BYTES: usize = 1 << 20;

/// Reads one line (with its `\n`) into `buf`, as [`BufRead::read_line`] does, but at most
/// `limit` bytes: a longer line is an [`io::ErrorKind::InvalidData`] error ("line longer than
/// … bytes"), as are bytes that are not UTF-8. Returns the bytes read, 0 at the end. Every
/// reader of outside input line by line goes through this one function.
pub fn read_line_limited<R: BufRead + ?Sized>(
    reader: &mut R,
    buf: &mut String,
    limit: usize,
) -> io::Result<usize> {
    let mut bytes = std::mem::take(buf).into_bytes();
    bytes.clear();
    let n = std::io::Read::take(&mut *reader, limit as u64 + 1).read_until(b'\n', &mut bytes)?;
    if n > limit {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!("line longer than {limit} bytes"),
        ));
    }
    *buf = String::from_utf8(bytes).map_err(|_| {
        io::Error::new(
            io::ErrorKind::InvalidData,
            "stream did not contain valid UTF-8",
        )
    })?;
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_longer_than_the_limit_is_refused_before_it_is_held() {
        let mut buf = String::new();
        let mut input = io::Cursor::new(b"abc\nabcdefgh\nxy".to_vec());
        assert_eq!(read_line_limited(&mut input, &mut buf, 5).unwrap(), 4);
        assert_eq!(buf, "abc\n");
        let err = read_line_limited(&mut input, &mut buf, 5).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::InvalidData);
        assert!(err.to_string().contains("longer than 5 bytes"), "{err}");
        // An endless line (a device) ends with the error too.
        let mut zeros = io::BufReader::new(io::repeat(0));
        let err = read_line_limited(&mut zeros, &mut buf, MAX_LINE_BYTES).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::InvalidData);
        let mut last = io::Cursor::new(b"xy".to_vec());
        assert_eq!(read_line_limited(&mut last, &mut buf, 5).unwrap(), 2);
        assert_eq!(buf, "xy");
        assert_eq!(read_line_limited(&mut last, &mut buf, 5).unwrap(), 0);
        let mut bad = io::Cursor::new(vec![b'a', 0xff, b'\n']);
        let err = read_line_limited(&mut bad, &mut buf, 5).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::InvalidData);
    }

    fn layout() -> PerformerLayout {
        PerformerLayout {
            lip_dots: 4,
            forehead_dots: 3,
        }
    }

    #[test]
    fn input_line_fills_dots() {
        let line = InputLine::parse(
            r#"{"t": 0.5, "points": {"D2": [1, 2, 3], "D1": null, "F3": [0, 0, 1], "F7": [1, 1, 1]}, "frame": 9}"#,
        )
        .unwrap();
        assert!(!line.neutral);
        assert_eq!(line.forehead_count(), 7);
        let mut dots = PerformerDots::default();
        line.dots_into(layout(), &mut dots).unwrap();
        assert_eq!(dots.lip, [None, Some(Vec3::new(1.0, 2.0, 3.0)), None, None]);
        assert_eq!(dots.forehead, [None, None, Some(Vec3::z())]);
    }

    #[test]
    fn input_line_errors() {
        let mut dots = PerformerDots::default();
        let check = |s: &str, dots: &mut PerformerDots| {
            InputLine::parse(s)
                .and_then(|l| l.dots_into(layout(), dots))
                .unwrap_err()
        };
        assert!(matches!(
            check(r#"{"t": 0, "points": {"D5": [0, 0, 0]}}"#, &mut dots),
            Error::UnknownDot { .. }
        ));
        assert!(matches!(
            check(r#"{"t": 0, "points": {"nose": [0, 0, 0]}}"#, &mut dots),
            Error::UnknownDot { .. }
        ));
        assert!(matches!(
            check(
                r#"{"t": 0, "points": {"D1": [0, 0, 0], "D1": null}}"#,
                &mut dots
            ),
            Error::DuplicateDot { .. }
        ));
        assert!(matches!(
            check(r#"{"t": 0, "points": {"D1": [0, 0]}}"#, &mut dots),
            Error::Json { .. }
        ));
        assert!(matches!(
            check(r#"{"points": {}}"#, &mut dots),
            Error::Json { .. }
        ));
        assert!(matches!(check("[]", &mut dots), Error::Json { .. }));
    }

    #[test]
    fn output_line_round_trips_in_order() {
        let line = OutputLine {
            t: 0.25,
            seq: 7,
            character: "wolf".into(),
            points: Named(vec![
                ("P2".into(), [1.0, 2.0, 3.0]),
                ("P1".into(), [4.0, 5.0, 6.0]),
            ]),
            confidence: Named(vec![("P2".into(), 1.0), ("P1".into(), 0.0)]),
            head: HeadPose {
                rotation: [1.0, 0.0, 0.0, 0.0],
                translation: [0.0, 0.1, 0.0],
            },
            head_lost: true,
            curve: Some(Curve {
                method: "sg5".into(),
                closed: true,
                points: vec![[0.0; 3]],
            }),
            rig: Some(crate::rig::RigFrame::default()),
            character_head: Some(Default::default()),
        };
        let text = serde_json::to_string(&line).unwrap();
        assert!(
            text.starts_with(r#"{"t":0.25,"seq":7,"character":"wolf","points":{"P2":"#),
            "{text}"
        );
        let back: OutputLine = serde_json::from_str(&text).unwrap();
        assert_eq!(back, line);
        // A consumer can read lines that carry more fields (`process` adds some).
        let extended = text.replacen('{', r#"{"performer":{"D1":null},"#, 1);
        assert_eq!(serde_json::from_str::<OutputLine>(&extended).unwrap(), line);
    }
}
