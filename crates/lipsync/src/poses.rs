//! The basic lip poses: the performer's neutral dots and, per key pose, each lip dot's
//! displacement from neutral, all in the performer's mouth frame (metres; x towards the
//! performer's left corner, y up, z out of the mouth). The mouth at a sample is
//! `neutral + Σ wᵢ · poseᵢ`.
//!
//! ```toml
//! [neutral]
//! lip = [[0.026, 0.0, 0.0], …]        # D⁰, one per lip dot (D1..Dn)
//! forehead = [[0.035, 0.095, 0.01], …] # the forehead dots (at least 3), for the mouth frame
//! [[pose]]
//! name = "open"
//! displacement = [[0.0, -0.001, 0.0], …]  # one per lip dot
//! mouth = { jaw = 0.2, raise = 0.3 }      # optional: the synthetic performer's state
//! ```

use std::collections::BTreeMap;
use std::fmt::Write as _;

use serde::Deserialize;

use crate::classes::ClassTable;
use crate::Error;

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    neutral: NeutralFile,
    pose: Vec<Pose>,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct NeutralFile {
    lip: Vec<[f64; 3]>,
    forehead: Vec<[f64; 3]>,
}

/// One key pose.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Pose {
    pub name: String,
    /// Per lip dot, metres, mouth frame.
    pub displacement: Vec<[f64; 3]>,
    /// The synthetic performer's mouth state that shows this pose (`jaw`, `spread`, `round`,
    /// `raise`, `roll_in`), when the pose came from it.
    #[serde(default)]
    pub mouth: BTreeMap<String, f64>,
}

/// The basic poses.
#[derive(Debug, Clone, PartialEq)]
pub struct BasicPoses {
    /// D⁰ per lip dot, mouth frame.
    pub neutral_lip: Vec<[f64; 3]>,
    /// Forehead dots, mouth frame.
    pub forehead: Vec<[f64; 3]>,
    pub poses: Vec<Pose>,
}

/// Largest plausible displacement of a lip dot, metres (a sanity bound on pose files).
pub const MAX_DISPLACEMENT_M: f64 = 0.1;
/// Most lip dots a pose file may have (every sample blends each of them).
pub const MAX_LIP_DOTS: usize = 64;
/// Most forehead dots a pose file may have.
pub const MAX_FOREHEAD_DOTS: usize = 16;
/// Most poses a pose file may have.
pub const MAX_POSES: usize = 64;

impl BasicPoses {
    /// Parses and checks a pose file: ≥ 4 lip dots (even), ≥ 3 forehead dots, every pose with
    /// one finite displacement per lip dot within 10 cm, unique names.
    pub fn from_toml_str(text: &str, source_name: &str) -> Result<Self, Error> {
        let file: File = toml::from_str(text).map_err(|e| Error::Toml {
            source_name: source_name.to_string(),
            source: Box::new(e),
        })?;
        let poses = Self {
            neutral_lip: file.neutral.lip,
            forehead: file.neutral.forehead,
            poses: file.pose,
        };
        poses.check().map_err(|(key, what)| Error::Config {
            source_name: source_name.to_string(),
            key,
            what,
        })?;
        Ok(poses)
    }

    fn check(&self) -> Result<(), (String, String)> {
        let n = self.neutral_lip.len();
        if n < 4 || !n.is_multiple_of(2) || n > MAX_LIP_DOTS {
            return Err((
                "neutral.lip".into(),
                format!("needs an even number of lip dots from 4 to {MAX_LIP_DOTS}, got {n}"),
            ));
        }
        if !(3..=MAX_FOREHEAD_DOTS).contains(&self.forehead.len()) {
            return Err((
                "neutral.forehead".into(),
                format!(
                    "needs 3 to {MAX_FOREHEAD_DOTS} dots, got {}",
                    self.forehead.len()
                ),
            ));
        }
        if self.poses.len() > MAX_POSES {
            return Err((
                "pose".into(),
                format!("{} poses, at most {MAX_POSES}", self.poses.len()),
            ));
        }
        let finite = |v: &[[f64; 3]]| v.iter().flatten().all(|x| x.is_finite());
        if !finite(&self.neutral_lip) || !finite(&self.forehead) {
            return Err(("neutral".into(), "coordinates must be finite".into()));
        }
        for (i, p) in self.poses.iter().enumerate() {
            let key = format!("pose[{i}] ({})", crate::input::cut(&p.name));
            if !crate::input::valid_name(&p.name) {
                return Err((
                    format!("{key}.name"),
                    format!("a pose name must be {}", crate::input::NAME_RULE),
                ));
            }
            if let Some((k, v)) = p.mouth.iter().find(|(_, v)| !v.is_finite()) {
                return Err((
                    format!("{key}.mouth.{}", crate::input::cut(k)),
                    format!("must be a finite number, got {v}"),
                ));
            }
            if self.poses[..i].iter().any(|o| o.name == p.name) {
                return Err((key, "pose name used twice".into()));
            }
            if p.displacement.len() != n {
                return Err((
                    format!("{key}.displacement"),
                    format!(
                        "needs {n} entries (one per lip dot), got {}",
                        p.displacement.len()
                    ),
                ));
            }
            if !p
                .displacement
                .iter()
                .flatten()
                .all(|x| x.is_finite() && x.abs() <= MAX_DISPLACEMENT_M)
            {
                return Err((
                    format!("{key}.displacement"),
                    format!("entries must be finite and within ±{MAX_DISPLACEMENT_M} m"),
                ));
            }
        }
        Ok(())
    }

    /// Number of lip dots.
    pub fn lip_dots(&self) -> usize {
        self.neutral_lip.len()
    }

    /// Indices of the class table's key poses in this file (every one must be here).
    pub fn order_for(&self, table: &ClassTable, source_name: &str) -> Result<Vec<usize>, Error> {
        table
            .poses
            .iter()
            .map(|name| {
                self.poses
                    .iter()
                    .position(|p| &p.name == name)
                    .ok_or_else(|| Error::Config {
                        source_name: source_name.to_string(),
                        key: "pose".into(),
                        what: format!(
                            "the class table weighs pose {name:?}, which this file does not have"
                        ),
                    })
            })
            .collect()
    }

    /// The mouth for one sample: `out[d] = neutral[d] + Σ weights[i] · pose[order[i]][d]`.
    pub fn blend(&self, weights: &[f64], order: &[usize], out: &mut [[f64; 3]]) {
        out.copy_from_slice(&self.neutral_lip);
        for (&w, &p) in weights.iter().zip(order) {
            if w == 0.0 {
                continue;
            }
            for (o, d) in out.iter_mut().zip(&self.poses[p].displacement) {
                for k in 0..3 {
                    o[k] += w * d[k];
                }
            }
        }
    }

    /// The displacement from neutral for one sample: `out[d] = Σ weights[i] · pose[order[i]][d]`.
    pub fn displacement(&self, weights: &[f64], order: &[usize], out: &mut [[f64; 3]]) {
        out.iter_mut().for_each(|o| *o = [0.0; 3]);
        for (&w, &p) in weights.iter().zip(order) {
            if w == 0.0 {
                continue;
            }
            for (o, d) in out.iter_mut().zip(&self.poses[p].displacement) {
                for k in 0..3 {
                    o[k] += w * d[k];
                }
            }
        }
    }

    /// The file text (round-trips through [`BasicPoses::from_toml_str`]): `header` as
    /// comment lines, then the tables. Pose names and mouth keys are written by the TOML
    /// serialiser (quoted and escaped: a name holding quotes, newlines or `]` stays one
    /// string); control characters in the header are replaced, a comment cannot hold them.
    pub fn to_toml_string(&self, header: &str) -> String {
        let mut s = String::new();
        for line in header.lines() {
            let clean: String = line
                .chars()
                .map(|c| if c.is_control() && c != '\t' { '?' } else { c })
                .collect();
            let _ = writeln!(s, "# {clean}");
        }
        let string = |v: &str| toml::Value::String(v.to_string()).to_string();
        let list = |s: &mut String, v: &[[f64; 3]]| {
            s.push_str("[\n");
            for p in v {
                let _ = writeln!(s, "  [{:?}, {:?}, {:?}],", p[0], p[1], p[2]);
            }
            s.push(']');
        };
        s.push_str("\n[neutral]\nlip = ");
        list(&mut s, &self.neutral_lip);
        s.push_str("\nforehead = ");
        list(&mut s, &self.forehead);
        s.push('\n');
        for p in &self.poses {
            let _ = write!(s, "\n[[pose]]\nname = {}\n", string(&p.name));
            if !p.mouth.is_empty() {
                let table: toml::Table = p
                    .mouth
                    .iter()
                    .map(|(k, v)| (k.clone(), toml::Value::Float(*v)))
                    .collect();
                let _ = writeln!(s, "mouth = {}", toml::Value::Table(table));
            }
            s.push_str("displacement = ");
            list(&mut s, &p.displacement);
            s.push('\n');
        }
        s
    }
}

/// Why pose marks (`name = [start_s, end_s]` per pose, for `lipsync poses`) are refused;
/// `source_name` names the file.
#[derive(Debug, thiserror::Error)]
pub enum MarksError {
    #[error("{source_name}: expected `name = [start_s, end_s]` per pose")]
    Toml {
        source_name: String,
        #[source]
        source: Box<toml::de::Error>,
    },
    #[error("{source_name}: no poses marked")]
    Empty { source_name: String },
    #[error(
        "{source_name}: pose name {name} must be {} (it becomes a column and a key)",
        crate::input::NAME_RULE
    )]
    Name { source_name: String, name: String },
    #[error("{source_name}: {name}: expected [start_s, end_s], got {count} values")]
    Count {
        source_name: String,
        name: String,
        count: usize,
    },
    #[error("{source_name}: {name}: the range must be [start, end] with 0 ≤ start < end ≤ {}, got [{start}, {end}]", crate::phones::MAX_TIME)]
    Range {
        source_name: String,
        name: String,
        start: f64,
        end: f64,
    },
}

/// Parses pose marks: `name = [start, end]` (session seconds), start < end, finite.
pub fn parse_marks(text: &str, source_name: &str) -> Result<Vec<(String, f64, f64)>, MarksError> {
    let source_name = source_name.to_string();
    // A list, its length checked here: a `[f64; 2]` would take `[1, 2, 3]` as `[1, 2]`.
    let table: BTreeMap<String, Vec<f64>> = toml::from_str(text).map_err(|e| MarksError::Toml {
        source_name: source_name.clone(),
        source: Box::new(e),
    })?;
    if table.is_empty() {
        return Err(MarksError::Empty { source_name });
    }
    table
        .into_iter()
        .map(|(name, range)| {
            if !crate::input::valid_name(&name) {
                return Err(MarksError::Name {
                    source_name: source_name.clone(),
                    name: crate::input::cut(&name),
                });
            }
            let &[start, end] = range.as_slice() else {
                return Err(MarksError::Count {
                    source_name: source_name.clone(),
                    name,
                    count: range.len(),
                });
            };
            let day = crate::phones::MAX_TIME;
            if !(start.is_finite() && end.is_finite() && 0.0 <= start && start < end && end <= day)
            {
                return Err(MarksError::Range {
                    source_name: source_name.clone(),
                    name: crate::input::cut(&name),
                    start,
                    end,
                });
            }
            Ok((name, start, end))
        })
        .collect()
}

#[cfg(test)]
mod marks_tests {
    use super::parse_marks;

    #[test]
    fn marks_are_two_times_under_a_plain_name() {
        let marks = parse_marks("open = [1.0, 2.5]\nclosed = [3, 4]\n", "m.toml").unwrap();
        assert_eq!(
            marks,
            [
                ("closed".to_owned(), 3.0, 4.0),
                ("open".to_owned(), 1.0, 2.5)
            ]
        );
        for (text, says) in [
            (
                "open = [1.0, 2.0, 3.0]\n",
                "open: expected [start_s, end_s], got 3 values",
            ),
            ("open = [1.0]\n", "got 1 values"),
            ("\"a,b\" = [1.0, 2.0]\n", "pose name a,b must be"),
            ("\"a.b\" = [1.0, 2.0]\n", "pose name a.b must be"),
            (
                "\"a\\u001b[2J\" = [1.0, 2.0]\n",
                "pose name a\\u{1b}[2J must be",
            ),
        ] {
            let err = parse_marks(text, "m.toml").unwrap_err().to_string();
            assert!(err.starts_with("m.toml: "), "{err}");
            assert!(err.contains(says), "{text}: {err}");
            assert!(!err.contains('\u{1b}'), "{err:?}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn poses() -> BasicPoses {
        BasicPoses {
            neutral_lip: vec![
                [0.02, 0.0, 0.0],
                [0.0, 0.005, 0.0],
                [-0.02, 0.0, 0.0],
                [0.0, -0.006, 0.0],
            ],
            forehead: vec![[0.03, 0.1, 0.0], [-0.03, 0.1, 0.0], [0.0, 0.12, 0.0]],
            poses: vec![
                Pose {
                    name: "open".into(),
                    displacement: vec![[0.0; 3], [0.0, 0.001, 0.0], [0.0; 3], [0.0, -0.01, 0.0]],
                    mouth: [("jaw".to_string(), 0.2)].into_iter().collect(),
                },
                Pose {
                    name: "round".into(),
                    displacement: vec![
                        [-0.004, 0.0, 0.002],
                        [0.0; 3],
                        [0.004, 0.0, 0.002],
                        [0.0; 3],
                    ],
                    mouth: BTreeMap::new(),
                },
            ],
        }
    }

    #[test]
    fn round_trips_and_blends() {
        let p = poses();
        let text = p.to_toml_string("test");
        let back = BasicPoses::from_toml_str(&text, "p.toml").unwrap();
        assert_eq!(back, p);
        let mut out = [[0.0; 3]; 4];
        back.blend(&[0.0, 0.0], &[0, 1], &mut out);
        assert_eq!(out.to_vec(), p.neutral_lip, "zero weights: exactly neutral");
        back.blend(&[0.5, 1.0], &[0, 1], &mut out);
        assert!((out[3][1] - (-0.006 - 0.005)).abs() < 1e-15);
        assert!((out[0][0] - 0.016).abs() < 1e-15);
    }

    #[test]
    fn rejects_bad_files() {
        let text = poses().to_toml_string("");
        let bad = text.replacen("  [0.0, -0.01, 0.0],\n", "", 1);
        let err = BasicPoses::from_toml_str(&bad, "p.toml").unwrap_err();
        assert!(err.to_string().contains("needs 4 entries"), "{err}");
        let bad = text.replace("-0.01", "-0.5");
        let err = BasicPoses::from_toml_str(&bad, "p.toml").unwrap_err();
        assert!(err.to_string().contains("within"), "{err}");
    }

    #[test]
    fn hostile_names_never_break_the_file_and_pose_names_keep_to_the_rule() {
        for name in [
            "open\"\n[[pose]]\nname = \"x",
            "a]\n\n[[pose]]\nname = 'evil'\ndisplacement = []",
            "tab\there, back\\slash, \u{7f} and \r\n",
        ] {
            // A mouth key may hold anything TOML keys can: it stays one string.
            let mut p = poses();
            p.poses[1].mouth.insert(format!("{name}]"), 0.5);
            let text = p.to_toml_string(&format!("captured from {name}"));
            let back = BasicPoses::from_toml_str(&text, "p.toml")
                .unwrap_or_else(|e| panic!("{e:?}\n{text}"));
            assert_eq!(back, p, "{text}");
            // A pose name becomes a column and a key: the file still parses, and the name is
            // refused by the rule, shown escaped.
            p.poses[0].name = name.to_string();
            let text = p.to_toml_string("");
            let err = BasicPoses::from_toml_str(&text, "p.toml")
                .unwrap_err()
                .to_string();
            assert!(err.starts_with("p.toml: pose[0] ("), "{err}");
            assert!(err.contains(crate::input::NAME_RULE), "{err}");
            assert!(!err.contains(['\n', '\r', '\u{7f}']), "{err:?}");
        }
    }
}
