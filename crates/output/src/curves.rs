//! The rig's curve names: ARKit's blend-shape names for the lower face that the lip dots and
//! the jaw measure (docs/rig.md), in the order every output carries them.

/// The curves, in order: the rig computes them in this order, the WebSocket and Foxglove
/// name them, OSC/VMC sends them, takes and exports write them.
pub const CURVE_NAMES: [&str; 18] = [
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
];

/// How many curves there are.
pub const CURVES: usize = CURVE_NAMES.len();

/// Index of a curve name in [`CURVE_NAMES`] (exact, case-sensitive).
pub fn curve_index(name: &str) -> Option<usize> {
    CURVE_NAMES.iter().position(|n| *n == name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_distinct_and_found_by_index() {
        for (i, name) in CURVE_NAMES.iter().enumerate() {
            assert_eq!(curve_index(name), Some(i));
        }
        assert_eq!(curve_index("JawOpen"), None);
        assert_eq!(curve_index("tongueOut"), None);
    }
}
