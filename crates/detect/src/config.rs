//! Detector configuration: colour classes in HSV and the blob filters, validated once.

use serde::{Deserialize, Serialize};

use crate::DetectError;

/// Which dots a colour class can hold. Labels are given by geometry in the tracker; the role
/// only narrows which candidates may become lip or forehead dots.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DotRole {
    Lip,
    Forehead,
    /// Either: one paint for every dot (the tracker separates them by geometry).
    Any,
}

/// One paint colour, as ranges in OpenCV's 8-bit HSV (hue 0–179, saturation and value
/// 0–255). Several hue ranges are OR-ed, which is how a red that wraps around 0/180 is
/// written: `hue = [[0, 8], [172, 179]]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColorClass {
    pub name: String,
    pub role: DotRole,
    pub hue: Vec<[u8; 2]>,
    pub saturation: [u8; 2],
    pub value: [u8; 2],
}

/// What the morphology step does to each class mask before connected components.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Morphology {
    /// 2x2 opening as a filter: a component survives when some of it survives the opening,
    /// which removes speckle and thin lines but keeps dots 2–3 px across whole and never joins
    /// neighbouring dots. It also removes a dot seen at a grazing angle (a forehead dot on a
    /// head turned 30°, paint stretched thin at a mouth corner), so it is not the default.
    Open,
    /// 3x3 closing: fills pinholes that sensor noise punches into a dot, but joins dots that
    /// are less than a pixel apart (close-up sessions with large dots only).
    Close,
    /// Components straight from the threshold; speckle is left to the area filter (a blob
    /// must cover a fifth of the paint's expected area). The default.
    None,
}

/// The detector's settings (`[detect]` in a configuration file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectConfig {
    /// Painted dot radius in metres, for the expected blob area at the measured distance.
    pub dot_radius_m: f64,
    /// Accepted blob area as a multiple of the expected one, `[min, max]`.
    pub area_ratio: [f64; 2],
    /// Smallest blob accepted at any distance, pixels.
    pub min_area_px: u32,
    /// Smallest accepted `area / bounding-box area` (a disc fills 0.785).
    pub min_fill_ratio: f64,
    /// Largest accepted bounding-box aspect ratio (a dot seen at a grazing angle stretches).
    pub max_aspect: f64,
    /// How far around the blob (pixels) a valid depth reading must exist.
    pub depth_search_px: u32,
    /// Nearest and farthest plausible performer distance (metres); readings outside are
    /// ignored by the depth filter.
    pub depth_range_m: [f64; 2],
    pub morphology: Morphology,
    /// Soft margin (hue units) around each hue range over which a pixel's centre weight
    /// falls to zero: edge pixels that mix paint and skin count for less.
    pub weight_hue_margin: u8,
    /// The colour classes. Defaults match the synthetic performer's paints.
    #[serde(rename = "class")]
    pub classes: Vec<ColorClass>,
}

impl Default for DetectConfig {
    fn default() -> Self {
        Self {
            dot_radius_m: 0.00225,
            area_ratio: [0.2, 8.0],
            min_area_px: 2,
            min_fill_ratio: 0.3,
            max_aspect: 4.0,
            depth_search_px: 3,
            depth_range_m: [0.2, 2.5],
            morphology: Morphology::None,
            weight_hue_margin: 8,
            classes: default_classes(),
        }
    }
}

/// The synthetic performer's paints: green on the lips, blue on the forehead.
pub fn default_classes() -> Vec<ColorClass> {
    vec![
        ColorClass {
            name: "lip".into(),
            role: DotRole::Lip,
            hue: vec![[45, 85]],
            saturation: [90, 255],
            value: [40, 255],
        },
        ColorClass {
            name: "forehead".into(),
            role: DotRole::Forehead,
            hue: vec![[100, 130]],
            saturation: [90, 255],
            value: [40, 255],
        },
    ]
}

fn bad(key: impl Into<String>, message: impl Into<String>) -> DetectError {
    DetectError::Config {
        key: key.into(),
        message: message.into(),
    }
}

/// Most hue ranges over all colour classes together.
pub const MAX_HUE_RANGES: usize = 32;

impl DetectConfig {
    /// Checks every key; the error names the first bad one as it is written in a file
    /// (`detect.class[1].hue[0]`).
    pub fn validate(&self) -> Result<(), DetectError> {
        // (Each hue range is one bit of the detector's per-pixel class tables.)
        let finite_pos = |key: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(bad(key, format!("must be a positive number, got {v}")))
            }
        };
        finite_pos("detect.dot_radius_m", self.dot_radius_m)?;
        finite_pos("detect.area_ratio[0]", self.area_ratio[0])?;
        finite_pos("detect.area_ratio[1]", self.area_ratio[1])?;
        if self.area_ratio[0] > self.area_ratio[1] {
            return Err(bad("detect.area_ratio", "inverted range: min is above max"));
        }
        if !(self.min_fill_ratio.is_finite() && (0.0..=1.0).contains(&self.min_fill_ratio)) {
            return Err(bad("detect.min_fill_ratio", "must be between 0 and 1"));
        }
        if !(self.max_aspect.is_finite() && self.max_aspect >= 1.0) {
            return Err(bad("detect.max_aspect", "must be at least 1"));
        }
        finite_pos("detect.depth_range_m[0]", self.depth_range_m[0])?;
        finite_pos("detect.depth_range_m[1]", self.depth_range_m[1])?;
        if self.depth_range_m[0] >= self.depth_range_m[1] {
            return Err(bad("detect.depth_range_m", "inverted or empty range"));
        }
        if self.classes.is_empty() {
            return Err(bad("detect.class", "at least one colour class is needed"));
        }
        for (i, class) in self.classes.iter().enumerate() {
            let key = format!("detect.class[{i}]");
            if class.name.trim().is_empty() {
                return Err(bad(format!("{key}.name"), "empty name"));
            }
            if self.classes[..i].iter().any(|c| c.name == class.name) {
                return Err(bad(
                    format!("{key}.name"),
                    format!("duplicate class name {:?}", class.name),
                ));
            }
            if class.hue.is_empty() {
                return Err(bad(
                    format!("{key}.hue"),
                    "empty: give at least one [min, max] hue range",
                ));
            }
            for (j, [lo, hi]) in class.hue.iter().enumerate() {
                let key = format!("{key}.hue[{j}]");
                if lo > hi {
                    return Err(bad(
                        key,
                        format!("inverted range [{lo}, {hi}]: write a range that wraps around red as two ranges, e.g. [[0, {hi}], [{lo}, 179]]"),
                    ));
                }
                if *hi > 180 {
                    return Err(bad(
                        key,
                        format!("hue is 0–179 in OpenCV's 8-bit HSV, got {hi}"),
                    ));
                }
            }
            let ranges_so_far: usize = self.classes[..=i].iter().map(|c| c.hue.len()).sum();
            if ranges_so_far > MAX_HUE_RANGES {
                return Err(bad(
                    format!("{key}.hue"),
                    format!("more than {MAX_HUE_RANGES} hue ranges over all classes"),
                ));
            }
            for (name, [lo, hi]) in [("saturation", class.saturation), ("value", class.value)] {
                if lo > hi {
                    return Err(bad(
                        format!("{key}.{name}"),
                        format!("inverted range [{lo}, {hi}]"),
                    ));
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid() {
        DetectConfig::default().validate().unwrap();
    }

    #[test]
    fn inverted_hue_names_the_key() {
        let text = r#"
            [[class]]
            name = "lip"
            role = "lip"
            hue = [[40, 80], [170, 10]]
            saturation = [80, 255]
            value = [40, 255]
        "#;
        let cfg: DetectConfig = toml::from_str(text).unwrap();
        let err = cfg.validate().unwrap_err().to_string();
        assert!(err.contains("detect.class[0].hue[1]"), "{err}");
        assert!(err.contains("inverted"), "{err}");
    }

    #[test]
    fn too_many_hue_ranges_name_the_class_that_goes_over() {
        let ranges = (0..20)
            .map(|i| format!("[{i}, {i}]"))
            .collect::<Vec<_>>()
            .join(", ");
        let text = format!(
            r#"
            [[class]]
            name = "a"
            role = "lip"
            hue = [{ranges}]
            saturation = [80, 255]
            value = [40, 255]
            [[class]]
            name = "b"
            role = "forehead"
            hue = [{ranges}]
            saturation = [80, 255]
            value = [40, 255]
        "#
        );
        let cfg: DetectConfig = toml::from_str(&text).unwrap();
        let err = cfg.validate().unwrap_err().to_string();
        assert!(err.contains("detect.class[1].hue"), "{err}");
        assert!(err.contains("more than 32 hue ranges"), "{err}");
    }

    #[test]
    fn empty_hue_and_inverted_saturation_name_the_key() {
        let mut cfg = DetectConfig::default();
        cfg.classes[1].hue.clear();
        let err = cfg.validate().unwrap_err().to_string();
        assert!(
            err.contains("detect.class[1].hue") && err.contains("empty"),
            "{err}"
        );

        let mut cfg = DetectConfig::default();
        cfg.classes[0].saturation = [200, 100];
        let err = cfg.validate().unwrap_err().to_string();
        assert!(err.contains("detect.class[0].saturation"), "{err}");
    }

    #[test]
    fn unknown_keys_are_rejected() {
        let err = toml::from_str::<DetectConfig>("dot_radius = 0.002").unwrap_err();
        assert!(err.to_string().contains("dot_radius"), "{err}");
    }
}
