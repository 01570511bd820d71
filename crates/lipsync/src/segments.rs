//! The designed segments A(a, b), one per ordered pair of classes: per key pose, a weight
//! curve over a *stable stage* (the mouth holding class a) then a *change stage* (moving
//! towards class b). Both stages are [`StageCurve`]s on normalised time; the mapping gives the
//! stable stage the phone's time minus T and the change stage exactly T.
//!
//! Conventions every segment keeps (checked for overrides), which make the stitched curves
//! continuous wherever phones are at least T long:
//! 1. the stable stage of A(a, ·) starts at class a's target weights;
//! 2. the change stage of A(·, b) ends at class b's target weights;
//! 3. the stable stage ends where the change stage starts.
//!
//! Stage curves are flat at their ends, so the joins are C¹ as well.
//!
//! Generated defaults (the designer's step): the stable stage holds class a's target; the
//! change stage eases from a's target to b's with a smoothstep (the two-point stage curve).
//!
//! Overrides (TOML), any number of `[[segment]]`s; poses not given keep the default:
//! ```toml
//! [[segment]]
//! from = "bilabial"
//! to = "open"
//! stable.open = [[0.0, 0.0], [0.6, 0.05], [1.0, 0.1]]
//! change.open = [[0.0, 0.1], [1.0, 1.0]]
//! ```

use std::collections::BTreeMap;

use serde::Deserialize;

use crate::classes::ClassTable;
use crate::curve::StageCurve;
use crate::Error;

/// Tolerance of the join conventions, in weight.
pub const JOIN_TOLERANCE: f64 = 1e-9;

/// One designed segment: per key pose, the stable and the change stage.
#[derive(Debug, Clone, PartialEq)]
pub struct Segment {
    pub stable: Vec<StageCurve>,
    pub change: Vec<StageCurve>,
}

/// All `n × n` segments of a class table.
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentTable {
    classes: usize,
    poses: usize,
    segments: Vec<Segment>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct OverrideFile {
    #[serde(default)]
    segment: Vec<OverrideSegment>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct OverrideSegment {
    from: String,
    to: String,
    #[serde(default)]
    stable: BTreeMap<String, Vec<[f64; 2]>>,
    #[serde(default)]
    change: BTreeMap<String, Vec<[f64; 2]>>,
}

impl SegmentTable {
    /// The generated defaults for a class table.
    pub fn generate(table: &ClassTable) -> Self {
        let n = table.len();
        let k = table.poses.len();
        let mut segments = Vec::with_capacity(n * n);
        for a in &table.classes {
            for b in &table.classes {
                let stable = (0..k).map(|p| StageCurve::constant(a.target[p])).collect();
                let change = (0..k)
                    .map(|p| {
                        StageCurve::from_points(&[(0.0, a.target[p]), (1.0, b.target[p])])
                            .expect("two ordered finite points")
                    })
                    .collect();
                segments.push(Segment { stable, change });
            }
        }
        Self {
            classes: n,
            poses: k,
            segments,
        }
    }

    /// Number of classes.
    pub fn classes(&self) -> usize {
        self.classes
    }

    /// Number of key poses.
    pub fn poses(&self) -> usize {
        self.poses
    }

    /// A(a, b).
    pub fn get(&self, a: usize, b: usize) -> &Segment {
        &self.segments[a * self.classes + b]
    }

    /// Replaces A(a, b) (checked against the conventions with the class targets).
    pub fn set(
        &mut self,
        table: &ClassTable,
        a: usize,
        b: usize,
        segment: Segment,
    ) -> Result<(), JoinError> {
        if segment.stable.len() != self.poses || segment.change.len() != self.poses {
            return Err(JoinError::Curves(self.poses));
        }
        for p in 0..self.poses {
            let name = &table.poses[p];
            let (s, c) = (&segment.stable[p], &segment.change[p]);
            let ta = table.classes[a].target[p];
            let tb = table.classes[b].target[p];
            if (s.first() - ta).abs() > JOIN_TOLERANCE {
                return Err(JoinError::Start {
                    pose: name.clone(),
                    class: table.classes[a].name.clone(),
                    target: ta,
                    starts: s.first(),
                });
            }
            if (c.last() - tb).abs() > JOIN_TOLERANCE {
                return Err(JoinError::End {
                    pose: name.clone(),
                    class: table.classes[b].name.clone(),
                    target: tb,
                    ends: c.last(),
                });
            }
            if (s.last() - c.first()).abs() > JOIN_TOLERANCE {
                return Err(JoinError::Gap {
                    pose: name.clone(),
                    stable_ends: s.last(),
                    starts: c.first(),
                });
            }
        }
        self.segments[a * self.classes + b] = segment;
        Ok(())
    }

    /// Replaces A(a, b) without checking the join conventions (special segments built in
    /// code; file overrides go through [`SegmentTable::set`]).
    pub fn force(&mut self, a: usize, b: usize, segment: Segment) {
        assert!(segment.stable.len() == self.poses && segment.change.len() == self.poses);
        self.segments[a * self.classes + b] = segment;
    }

    /// Applies an override file (format in the module docs).
    pub fn apply_overrides(
        &mut self,
        table: &ClassTable,
        text: &str,
        source_name: &str,
    ) -> Result<(), Error> {
        let file: OverrideFile = toml::from_str(text).map_err(|e| Error::Toml {
            source_name: source_name.to_string(),
            source: Box::new(e),
        })?;
        for (i, o) in file.segment.into_iter().enumerate() {
            let config = |key: &str, what: String| Error::Config {
                source_name: source_name.to_string(),
                key: format!("segment[{i}] ({} → {}){key}", o.from, o.to),
                what,
            };
            let class = |name: &str, key: &str| {
                table
                    .classes
                    .iter()
                    .position(|c| c.name == name)
                    .ok_or_else(|| config(key, format!("unknown class {name:?}")))
            };
            let a = class(&o.from, ".from")?;
            let b = class(&o.to, ".to")?;
            let mut segment = self.get(a, b).clone();
            for (stage, curves, out) in [
                ("stable", &o.stable, &mut segment.stable),
                ("change", &o.change, &mut segment.change),
            ] {
                for (pose, points) in curves {
                    let key = format!(".{stage}.{pose}");
                    let p = table
                        .poses
                        .iter()
                        .position(|n| n == pose)
                        .ok_or_else(|| config(&key, format!("unknown pose {pose:?}")))?;
                    // Weights, like the class targets they join: 0 to 1 (a point of 1e298
                    // would carry into the take's points).
                    if let Some((k, q)) = points
                        .iter()
                        .enumerate()
                        .find(|(_, q)| !(0.0..=1.0).contains(&q[1]))
                    {
                        return Err(config(
                            &key,
                            format!("control point {k}: weight {:?} is not within 0 to 1", q[1]),
                        ));
                    }
                    let pts: Vec<(f64, f64)> = points.iter().map(|q| (q[0], q[1])).collect();
                    out[p] =
                        StageCurve::from_points(&pts).map_err(|e| config(&key, e.to_string()))?;
                }
            }
            self.set(table, a, b, segment)
                .map_err(|e| config("", e.to_string()))?;
        }
        Ok(())
    }
}

/// A segment that does not join its classes' targets (the conventions of the module docs).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum JoinError {
    #[error("a segment needs {0} curves per stage")]
    Curves(usize),
    #[error("stable.{pose} must start at class {class:?}'s target {target}, starts at {starts}")]
    Start {
        pose: String,
        class: String,
        target: f64,
        starts: f64,
    },
    #[error("change.{pose} must end at class {class:?}'s target {target}, ends at {ends}")]
    End {
        pose: String,
        class: String,
        target: f64,
        ends: f64,
    },
    #[error(
        "change.{pose} must start where stable.{pose} ends ({stable_ends}), starts at {starts}"
    )]
    Gap {
        pose: String,
        stable_ends: f64,
        starts: f64,
    },
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) const TABLE: &str = r#"
poses = ["closed", "open"]
[[class]]
name = "sil"
phones = ["sil"]
[[class]]
name = "m"
phones = ["m"]
target = { closed = 1.0 }
[[class]]
name = "aa"
phones = ["aa"]
target = { open = 1.0, closed = 0.0 }
"#;

    #[test]
    fn every_pair_exists_and_joins_continuously() {
        let table = ClassTable::from_toml_str(TABLE, "t").unwrap();
        let segs = SegmentTable::generate(&table);
        for a in 0..3 {
            for b in 0..3 {
                let s = segs.get(a, b);
                for p in 0..2 {
                    assert_eq!(s.stable[p].first(), table.classes[a].target[p]);
                    assert_eq!(s.stable[p].last(), s.change[p].first());
                    assert_eq!(s.change[p].last(), table.classes[b].target[p]);
                }
            }
        }
    }

    #[test]
    fn overrides_replace_one_pose_and_are_checked() {
        let table = ClassTable::from_toml_str(TABLE, "t").unwrap();
        let mut segs = SegmentTable::generate(&table);
        let ok = "[[segment]]\nfrom = \"m\"\nto = \"aa\"\nstable.closed = [[0, 1], [0.5, 0.9], [1, 0.8]]\nchange.closed = [[0, 0.8], [1, 0]]\n";
        segs.apply_overrides(&table, ok, "o.toml").unwrap();
        assert!((segs.get(1, 2).stable[0].at(0.5) - 0.9).abs() < 1e-15);
        // The open pose kept its default.
        assert_eq!(segs.get(1, 2).change[1].last(), 1.0);
        let bad = ok.replace("[[0, 1], [0.5", "[[0, 0.5], [0.5");
        let err = segs.apply_overrides(&table, &bad, "o.toml").unwrap_err();
        assert!(
            err.to_string().contains("must start at class \"m\""),
            "{err}"
        );
        let bad = ok.replace("stable.closed = [[0, 1], [0.5, 0.9], [1, 0.8]]\n", "");
        let mut fresh = SegmentTable::generate(&table);
        let err = fresh.apply_overrides(&table, &bad, "o.toml").unwrap_err();
        assert!(
            err.to_string()
                .contains("must start where stable.closed ends"),
            "{err}"
        );
        // A weight of 1e298 inside a stage (the joins still hold) would carry into the take.
        let bad = ok.replace("[0.5, 0.9]", "[0.5, 1e298]");
        let err = segs.apply_overrides(&table, &bad, "o.toml").unwrap_err();
        assert!(
            err.to_string()
                .contains("stable.closed: control point 1: weight 1e298 is not within 0 to 1"),
            "{err}"
        );
        let bad = ok.replace("to = \"aa\"", "to = \"ee\"");
        let err = segs.apply_overrides(&table, &bad, "o.toml").unwrap_err();
        assert!(err.to_string().contains("unknown class \"ee\""), "{err}");
    }
}
