//! The rig's curve names: ARKit's blend-shape names for the lower face that the lip dots and
//! the jaw measure (docs/rig.md), in the order every output carries them, and the VRM mouth
//! expressions (visemes) derived from them.

/// The curves, in order: the rig computes them in this order, the WebSocket and Foxglove
/// name them, OSC/VMC sends them, takes and exports write them.
pub const CURVE_NAMES: [&str; 27] = [
    "jawOpen",
    "mouthClose",
    "mouthFunnel",
    "mouthPucker",
    "mouthLeft",
    "mouthRight",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthStretchLeft",
    "mouthStretchRight",
    "mouthRollUpper",
    "mouthRollLower",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "mouthPressLeft",
    "mouthPressRight",
    "jawForward",
    "jawLeft",
    "jawRight",
    "mouthFrownLeft",
    "mouthFrownRight",
    "mouthShrugUpper",
    "mouthShrugLower",
    "mouthDimpleLeft",
    "mouthDimpleRight",
];

/// How many curves there are.
pub const CURVES: usize = CURVE_NAMES.len();

/// Index of a curve name in [`CURVE_NAMES`] (exact, case-sensitive).
pub fn curve_index(name: &str) -> Option<usize> {
    CURVE_NAMES.iter().position(|n| *n == name)
}

/// ARKit's name of curve `i` in PascalCase, as perfect-sync avatars name their blend-shape
/// clips (`JawOpen`, `MouthClose`); `None` past the last curve.
pub fn pascal_name(i: usize) -> Option<&'static str> {
    PASCAL_NAMES.get(i).copied()
}

/// [`CURVE_NAMES`] in PascalCase (perfect-sync clip names), same order.
pub const PASCAL_NAMES: [&str; CURVES] = [
    "JawOpen",
    "MouthClose",
    "MouthFunnel",
    "MouthPucker",
    "MouthLeft",
    "MouthRight",
    "MouthSmileLeft",
    "MouthSmileRight",
    "MouthStretchLeft",
    "MouthStretchRight",
    "MouthRollUpper",
    "MouthRollLower",
    "MouthUpperUpLeft",
    "MouthUpperUpRight",
    "MouthLowerDownLeft",
    "MouthLowerDownRight",
    "MouthPressLeft",
    "MouthPressRight",
    "JawForward",
    "JawLeft",
    "JawRight",
    "MouthFrownLeft",
    "MouthFrownRight",
    "MouthShrugUpper",
    "MouthShrugLower",
    "MouthDimpleLeft",
    "MouthDimpleRight",
];

/// The VRM 1.0 mouth expressions (visemes), in the order the rig carries them.
pub const VISEME_NAMES: [&str; 5] = ["aa", "ih", "ou", "ee", "oh"];

/// The same visemes as VRM 0.x names its blend-shape clips (`A I U E O`), same order.
pub const VISEME_NAMES_VRM0: [&str; 5] = ["A", "I", "U", "E", "O"];

/// How many visemes there are.
pub const VISEMES: usize = VISEME_NAMES.len();

/// The visemes from the curves (docs/rig.md, *Visemes*), each 0..1: from the lips' opening
/// `o = jawOpen − mouthClose`, the rounding `ρ = mouthFunnel + mouthPucker` and the spread
/// `σ` (the mean of the two stretches), each clamped to 0..1:
///
/// - `aa` = o · (1 − ρ): open, unrounded;
/// - `ih` = σ · (1 − ρ) · slight(o): spread and slightly open, `slight(o)` rising to 1 at
///   o = 0.3 and falling to 0 at o = 1;
/// - `ou` = ρ · (1 − o): rounded, nearly closed;
/// - `ee` = σ · (1 − ρ) · (1 − o): spread, closed;
/// - `oh` = ρ · o: rounded, open.
///
/// Curves that are not numbers count as 0.
pub fn visemes_from(curves: &[f64; CURVES]) -> [f64; VISEMES] {
    let c = |name: &str| {
        let v = curves[curve_index(name).expect("a curve name")];
        if v.is_finite() {
            v.clamp(0.0, 1.0)
        } else {
            0.0
        }
    };
    let open = (c("jawOpen") - c("mouthClose")).clamp(0.0, 1.0);
    let round = (c("mouthFunnel") + c("mouthPucker")).clamp(0.0, 1.0);
    let spread = 0.5 * (c("mouthStretchLeft") + c("mouthStretchRight"));
    let slight = (open / SLIGHT_OPEN).min((1.0 - open) / (1.0 - SLIGHT_OPEN));
    [
        open * (1.0 - round),
        spread * (1.0 - round) * slight.clamp(0.0, 1.0),
        round * (1.0 - open),
        spread * (1.0 - round) * (1.0 - open),
        round * open,
    ]
}

/// How the curves are named where a receiver matches them by name (`[osc] names`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CurveNaming {
    /// ARKit's lowerCamelCase names, [`CURVE_NAMES`] (`jawOpen`).
    #[default]
    Arkit,
    /// ARKit's names in PascalCase, [`PASCAL_NAMES`] (`JawOpen`: perfect-sync clip names).
    ArkitPascal,
}

impl CurveNaming {
    /// The names, in [`CURVE_NAMES`] order.
    pub fn names(self) -> &'static [&'static str; CURVES] {
        match self {
            CurveNaming::Arkit => &CURVE_NAMES,
            CurveNaming::ArkitPascal => &PASCAL_NAMES,
        }
    }
}

/// Which visemes are sent, by which names (`[osc] visemes`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VisemeNaming {
    /// VRM 0.x's blend-shape clips, [`VISEME_NAMES_VRM0`] (`A I U E O`).
    #[default]
    Vrm0,
    /// VRM 1.0's expressions, [`VISEME_NAMES`] (`aa ih ou ee oh`).
    Vrm1,
    /// No visemes.
    None,
}

impl VisemeNaming {
    /// The names, in [`VISEME_NAMES`] order; `None` for [`VisemeNaming::None`].
    pub fn names(self) -> Option<&'static [&'static str; VISEMES]> {
        match self {
            VisemeNaming::Vrm0 => Some(&VISEME_NAMES_VRM0),
            VisemeNaming::Vrm1 => Some(&VISEME_NAMES),
            VisemeNaming::None => None,
        }
    }
}

/// The lips' opening (`jawOpen − mouthClose`, 0..1) at which `ih` peaks.
pub const SLIGHT_OPEN: f64 = 0.3;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pascal_names_are_the_curve_names_capitalised() {
        for (i, name) in CURVE_NAMES.iter().enumerate() {
            let p = pascal_name(i).unwrap();
            assert_eq!(p[..1], name[..1].to_uppercase());
            assert_eq!(p[1..], name[1..]);
        }
        assert_eq!(pascal_name(0), Some("JawOpen"));
        assert_eq!(pascal_name(1), Some("MouthClose"));
        assert_eq!(pascal_name(CURVES), None);
    }

    /// Each viseme reads the mouth it names: open unrounded `aa`, spread slightly open `ih`,
    /// rounded closed `ou`, spread closed `ee`, rounded open `oh`.
    #[test]
    fn each_viseme_reads_its_mouth() {
        let mouth = |pairs: &[(&str, f64)]| {
            let mut c = [0.0; CURVES];
            for (n, v) in pairs {
                c[curve_index(n).unwrap()] = *v;
            }
            visemes_from(&c)
        };
        let best = |v: [f64; VISEMES]| {
            let i = (0..VISEMES).max_by(|&a, &b| v[a].total_cmp(&v[b])).unwrap();
            VISEME_NAMES[i]
        };
        let aa = mouth(&[("jawOpen", 0.9)]);
        assert_eq!(best(aa), "aa");
        assert!((aa[0] - 0.9).abs() < 1e-12, "{aa:?}");
        assert_eq!(
            best(mouth(&[
                ("jawOpen", 0.3),
                ("mouthStretchLeft", 0.8),
                ("mouthStretchRight", 0.8)
            ])),
            "ih"
        );
        let ou = mouth(&[("mouthPucker", 0.8), ("mouthFunnel", 0.1), ("jawOpen", 0.1)]);
        assert_eq!(best(ou), "ou");
        assert!((ou[2] - 0.9 * 0.9).abs() < 1e-12, "{ou:?}");
        assert_eq!(
            best(mouth(&[
                ("mouthStretchLeft", 0.7),
                ("mouthStretchRight", 0.9)
            ])),
            "ee"
        );
        assert_eq!(best(mouth(&[("mouthFunnel", 0.8), ("jawOpen", 0.7)])), "oh");
        // A sealed jaw drop (jawOpen and mouthClose alike) is a closed mouth: no aa.
        assert_eq!(
            mouth(&[("jawOpen", 0.8), ("mouthClose", 0.8)]),
            [0.0; VISEMES]
        );
        // Rest: nothing; bad values count as 0 and every viseme stays in 0..1.
        assert_eq!(mouth(&[]), [0.0; VISEMES]);
        let v = mouth(&[
            ("jawOpen", f64::NAN),
            ("mouthFunnel", 7.0),
            ("mouthPucker", 3.0),
        ]);
        assert!(v.iter().all(|x| (0.0..=1.0).contains(x)), "{v:?}");
    }

    #[test]
    fn names_are_distinct_and_found_by_index() {
        for (i, name) in CURVE_NAMES.iter().enumerate() {
            assert_eq!(curve_index(name), Some(i));
        }
        assert_eq!(curve_index("JawOpen"), None);
        assert_eq!(curve_index("tongueOut"), None);
    }
}
