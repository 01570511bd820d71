//! Where the dots are painted and in which colours (`--layout FILE`, TOML).
//!
//! ```toml
//! lip_dots = 12                 # even, ≥ 4: two corners + the same count on each lip
//! radius_mm = 2.25              # lip dots: 2–2.5 mm paint dots
//! forehead_radius_mm = 4.0      # forehead dots: larger (skin there does not move)
//! lip_color = [40, 200, 70]     # RGB
//! forehead_color = [40, 90, 230]
//! lip_skin_color = [200, 102, 102]  # optional: the lips' own colour (default a muted red)
//! [[forehead]]                  # optional; default F1..F3 below
//! name = "F1"
//! x_mm = 35.0                   # performer's left is +x
//! y_mm = -95.0                  # above the mouth is negative (camera y points down)
//! ```

use std::path::Path;

use serde::Deserialize;

use crate::SynthError;

/// A forehead dot, placed on the head surface at (x, y) relative to the mouth centre.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForeheadDot {
    pub name: String,
    pub x_mm: f64,
    pub y_mm: f64,
}

/// The dot layout.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DotLayout {
    pub lip_dots: usize,
    pub radius_mm: f64,
    /// Forehead dots' radius: they can be larger than the lip dots (the forehead does not
    /// move with speech), and a larger dot gives the head pose a steadier centre and depth.
    pub forehead_radius_mm: f64,
    pub lip_color: [u8; 3],
    pub forehead_color: [u8; 3],
    /// The lips' own colour (RGB, under the paint); `None`: the built-in muted red.
    pub lip_skin_color: Option<[u8; 3]>,
    pub forehead: Vec<ForeheadDot>,
}

impl Default for DotLayout {
    fn default() -> Self {
        let dot = |name: &str, x_mm: f64, y_mm: f64| ForeheadDot {
            name: name.into(),
            x_mm,
            y_mm,
        };
        Self {
            lip_dots: 12,
            radius_mm: crate::DEFAULT_DOT_RADIUS_M * 1000.0,
            forehead_radius_mm: 4.0,
            lip_color: crate::LIP_DOT_RGB,
            forehead_color: crate::FOREHEAD_DOT_RGB,
            lip_skin_color: None,
            // A wide, tall triangle (70 × 40 mm): the head pose rests on depth and pixel
            // differences across it, so its size sets the head pose's precision (docs/detection.md,
            // "Painting the dots").
            forehead: vec![
                dot("F1", 35.0, -95.0),
                dot("F2", 0.0, -135.0),
                dot("F3", -35.0, -95.0),
            ],
        }
    }
}

impl DotLayout {
    /// Reads a TOML layout; missing keys take the defaults.
    pub fn from_file(path: &Path) -> Result<Self, SynthError> {
        let text = std::fs::read_to_string(path).map_err(|source| SynthError::LayoutRead {
            path: path.to_path_buf(),
            source,
        })?;
        let layout: DotLayout = toml::from_str(&text).map_err(|e| SynthError::LayoutParse {
            path: path.to_path_buf(),
            source: Box::new(e),
        })?;
        layout
            .validate()
            .map_err(|problem| SynthError::LayoutInvalid {
                path: path.to_path_buf(),
                problem,
            })?;
        Ok(layout)
    }

    pub(crate) fn validate(&self) -> Result<(), LayoutError> {
        use LayoutError as E;
        if self.lip_dots < 4 || !self.lip_dots.is_multiple_of(2) || self.lip_dots > 40 {
            return Err(E::LipDots(self.lip_dots));
        }
        if !(1.0..=4.0).contains(&self.radius_mm) {
            return Err(E::Radius(self.radius_mm));
        }
        if !(1.0..=6.0).contains(&self.forehead_radius_mm) {
            return Err(E::ForeheadRadius(self.forehead_radius_mm));
        }
        if self.forehead.len() < 3 {
            return Err(E::TooFewForehead(self.forehead.len()));
        }
        for (i, f) in self.forehead.iter().enumerate() {
            if !(-60.0..=60.0).contains(&f.x_mm) || !(-150.0..=-70.0).contains(&f.y_mm) {
                return Err(E::ForeheadPlace {
                    index: i,
                    name: f.name.clone(),
                    x_mm: f.x_mm,
                    y_mm: f.y_mm,
                });
            }
            if f.name.starts_with('D') || self.forehead[..i].iter().any(|g| g.name == f.name) {
                return Err(E::NameTaken {
                    index: i,
                    name: f.name.clone(),
                });
            }
        }
        // Not collinear: the head pose needs a plane.
        let p: Vec<[f64; 2]> = self.forehead.iter().map(|f| [f.x_mm, f.y_mm]).collect();
        let area = p
            .windows(3)
            .chain(std::iter::once(&p[..3]))
            .fold(0.0f64, |m, w| {
                m.max(
                    ((w[1][0] - w[0][0]) * (w[2][1] - w[0][1])
                        - (w[1][1] - w[0][1]) * (w[2][0] - w[0][0]))
                        .abs(),
                )
            });
        if area < 50.0 {
            return Err(E::Collinear);
        }
        Ok(())
    }

    /// Names in order: D1..Dn, then the forehead dots.
    pub fn names(&self) -> Vec<String> {
        (1..=self.lip_dots)
            .map(|k| format!("D{k}"))
            .chain(self.forehead.iter().map(|f| f.name.clone()))
            .collect()
    }
}

/// A dot layout the synthetic performer cannot wear; the message names the key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LayoutError {
    #[error("lip_dots must be even and within 4–40, got {0}")]
    LipDots(usize),
    #[error("radius_mm must be within 1–4 mm, got {0}")]
    Radius(f64),
    #[error("forehead_radius_mm must be within 1–6 mm, got {0}")]
    ForeheadRadius(f64),
    #[error("at least 3 forehead dots are needed, got {0}")]
    TooFewForehead(usize),
    #[error("forehead[{index}] ({name}): x_mm must be within ±60 and y_mm within -150..-70 (the forehead), got ({x_mm}, {y_mm})")]
    ForeheadPlace {
        index: usize,
        name: String,
        x_mm: f64,
        y_mm: f64,
    },
    #[error("forehead[{index}]: name {name:?} is taken")]
    NameTaken { index: usize, name: String },
    #[error("forehead dots are (nearly) collinear; the head pose needs them spread")]
    Collinear,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_layout_is_valid_and_named_as_in_the_method() {
        let l = DotLayout::default();
        l.validate().unwrap();
        let names = l.names();
        assert_eq!(names.first().unwrap(), "D1");
        assert_eq!(names[11], "D12");
        assert_eq!(&names[12..], ["F1", "F2", "F3"]);
    }

    #[test]
    fn bad_layout_files_name_the_problem() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("l.toml");
        std::fs::write(&p, "lip_dots = 7\n").unwrap();
        let e = DotLayout::from_file(&p).unwrap_err().to_string();
        assert!(e.contains("l.toml") && e.contains("lip_dots"), "{e}");
        std::fs::write(&p, "lip_dot = 8\n").unwrap();
        let e = DotLayout::from_file(&p).unwrap_err();
        let chain = format!("{e}: {}", std::error::Error::source(&e).unwrap());
        assert!(chain.contains("lip_dot"), "{chain}");
        std::fs::write(&p, "lip_dots = 8\nradius_mm = 2.0\n").unwrap();
        assert_eq!(DotLayout::from_file(&p).unwrap().lip_dots, 8);
    }
}
