//! The synthetic performer's options as written on a command line (`synth --size 640x480
//! --hinge back=+25% --jaw-slide 2 --lip-skin-colour 200,102,102 --distortion K1,…`), each
//! checked against the performer's own ranges.

use crate::{JawError, JawOptions};

/// Why an option's text is refused; the text is quoted (cut to 80 characters).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ArgError {
    #[error("expected {expected}, got {text:?}")]
    Expected {
        expected: &'static str,
        text: String,
    },
    #[error("unknown direction {key:?} (back or down) in {text:?}")]
    Direction { key: String, text: String },
    #[error("expected a percentage such as +25% in {text:?}")]
    Percentage { text: String },
    #[error("{key} given twice in {text:?}")]
    Twice { key: String, text: String },
    #[error("bad {what} in {text:?}")]
    Bad { what: &'static str, text: String },
    #[error("bad colour component {part:?} in {text:?}: expected 0–255")]
    Component { part: String, text: String },
    #[error("bad number {part:?} in {text:?}")]
    Number { part: String, text: String },
    #[error("expected {count} values {names}, got {got}")]
    Count {
        count: usize,
        names: &'static str,
        got: usize,
    },
    #[error(transparent)]
    Jaw(#[from] JawError),
}

fn short(s: &str, n: usize) -> String {
    s.chars().take(n).collect()
}

/// `back=P%,down=Q%` → (back, down) as fractions, within the synthetic performer's range.
pub fn parse_hinge(s: &str) -> Result<(f64, f64), ArgError> {
    let text = short(s, 80);
    let (mut back, mut down) = (None, None);
    for part in s.split(',') {
        let (key, value) = part.split_once('=').ok_or_else(|| ArgError::Expected {
            expected: "back=P%,down=Q%",
            text: text.clone(),
        })?;
        let slot = match key.trim() {
            "back" => &mut back,
            "down" => &mut down,
            _ => {
                return Err(ArgError::Direction {
                    key: short(key.trim(), 20),
                    text,
                })
            }
        };
        let pct: f64 = value
            .trim()
            .strip_suffix('%')
            .and_then(|v| v.trim().parse().ok())
            .ok_or_else(|| ArgError::Percentage { text: text.clone() })?;
        if slot.replace(pct / 100.0).is_some() {
            return Err(ArgError::Twice {
                key: key.trim().to_string(),
                text,
            });
        }
    }
    let jaw = JawOptions {
        hinge_back: back.unwrap_or(0.0),
        hinge_down: down.unwrap_or(0.0),
        ..Default::default()
    };
    jaw.validate_hinge()?;
    Ok((jaw.hinge_back, jaw.hinge_down))
}

/// Jaw slide in millimetres, within the synthetic performer's range.
pub fn parse_jaw_slide(s: &str) -> Result<f64, ArgError> {
    let mm: f64 = s.trim().parse().map_err(|_| ArgError::Expected {
        expected: "millimetres",
        text: short(s, 80),
    })?;
    JawOptions {
        slide_m: mm / 1e3,
        ..Default::default()
    }
    .validate_slide()?;
    Ok(mm)
}

/// `WIDTHxHEIGHT`.
pub fn parse_size(s: &str) -> Result<(u32, u32), ArgError> {
    let text = || short(s, 80);
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| ArgError::Expected {
        expected: "WIDTHxHEIGHT",
        text: text(),
    })?;
    let w: u32 = w.trim().parse().map_err(|_| ArgError::Bad {
        what: "width",
        text: text(),
    })?;
    let h: u32 = h.trim().parse().map_err(|_| ArgError::Bad {
        what: "height",
        text: text(),
    })?;
    Ok((w, h))
}

/// `R,G,B`, each 0–255.
pub fn parse_rgb(s: &str) -> Result<[u8; 3], ArgError> {
    let v: Vec<u8> = s
        .split(',')
        .map(|x| {
            x.trim().parse::<u8>().map_err(|_| ArgError::Component {
                part: short(x, 20),
                text: short(s, 80),
            })
        })
        .collect::<Result<_, _>>()?;
    v.try_into().map_err(|v: Vec<u8>| ArgError::Count {
        count: 3,
        names: "R,G,B",
        got: v.len(),
    })
}

/// OpenCV's plumb_bob lens distortion `K1,K2,P1,P2,K3`.
pub fn parse_distortion(s: &str) -> Result<[f64; 5], ArgError> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| {
            x.trim().parse::<f64>().map_err(|_| ArgError::Number {
                part: short(x, 20),
                text: short(s, 80),
            })
        })
        .collect::<Result<_, _>>()?;
    v.try_into().map_err(|v: Vec<f64>| ArgError::Count {
        count: 5,
        names: "K1,K2,P1,P2,K3",
        got: v.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hinge_moves_parse_as_fractions_and_bad_ones_say_why() {
        assert_eq!(parse_hinge("back=+25%,down=-25%"), Ok((0.25, -0.25)));
        assert_eq!(parse_hinge("down=10%"), Ok((0.0, 0.1)));
        assert_eq!(parse_hinge(" back = -50 % "), Ok((-0.5, 0.0)));
        for (bad, says) in [
            ("back=+60%", "within ±50 %"),
            ("down=NaN%", "within ±50 %"),
            ("back=25", "percentage"),
            ("up=25%", "unknown direction"),
            ("back=1%,back=2%", "twice"),
            ("back", "expected back=P%"),
        ] {
            let e = parse_hinge(bad).unwrap_err().to_string();
            assert!(e.contains(says), "{bad}: {e}");
        }
        assert_eq!(parse_jaw_slide("2.5"), Ok(2.5));
        for bad in ["-1", "6", "inf", "NaN", "two"] {
            assert!(parse_jaw_slide(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn sizes_colours_and_distortions_parse_and_bad_ones_name_the_part() {
        assert_eq!(parse_size("640x480"), Ok((640, 480)));
        assert!(parse_size("640")
            .unwrap_err()
            .to_string()
            .contains("WIDTHxHEIGHT"));
        assert!(parse_size("ax480")
            .unwrap_err()
            .to_string()
            .contains("width"));
        assert_eq!(parse_rgb("200, 102,102"), Ok([200, 102, 102]));
        assert!(parse_rgb("300,1,1")
            .unwrap_err()
            .to_string()
            .contains("0–255"));
        assert!(parse_rgb("1,1").unwrap_err().to_string().contains("got 2"));
        assert_eq!(
            parse_distortion("0,0,0,0,0.1"),
            Ok([0.0, 0.0, 0.0, 0.0, 0.1])
        );
        assert!(parse_distortion("0,0,0,0")
            .unwrap_err()
            .to_string()
            .contains("K1"));
    }
}
