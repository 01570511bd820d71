//! Which take curve drives which avatar morph target: the name table of `export --onto`.
//!
//! A target matches a curve when its name equals the curve's name ignoring ASCII case
//! (`JawOpen`, `jawopen`, `jawOpen` → `jawOpen`). VRM's viseme names are accepted too:
//! VRM 1.0's `aa ih ou ee oh` are plain names (they match a take curve of that name when the
//! take carries visemes), and VRM 0.x's `A I U E O` are aliases of them.

/// VRM 0.x viseme presets (lower-cased) and the VRM 1.0 names they stand for.
pub const VISEME_ALIASES: [(&str, &str); 5] = [
    ("a", "aa"),
    ("i", "ih"),
    ("u", "ou"),
    ("e", "ee"),
    ("o", "oh"),
];

/// The take's curve names (in the order of its per-frame values) looked up by avatar target
/// name.
#[derive(Clone, Debug)]
pub struct CurveTable {
    names: Vec<String>,
}

impl CurveTable {
    /// A table over `names`, the take's curves in the order of its per-frame values.
    pub fn new<S: AsRef<str>>(names: &[S]) -> Self {
        Self {
            names: names.iter().map(|n| n.as_ref().to_owned()).collect(),
        }
    }

    /// The take's curve names, in order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The index of the curve that drives a target named `target`, if any.
    pub fn lookup(&self, target: &str) -> Option<usize> {
        let direct = |name: &str| self.names.iter().position(|n| n.eq_ignore_ascii_case(name));
        direct(target).or_else(|| {
            VISEME_ALIASES
                .iter()
                .find(|(alias, _)| alias.eq_ignore_ascii_case(target))
                .and_then(|(_, viseme)| direct(viseme))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arkit_names_match_ignoring_case() {
        let table = CurveTable::new(&["jawOpen", "mouthSmileLeft"]);
        for name in ["jawOpen", "JawOpen", "jawopen", "JAWOPEN"] {
            assert_eq!(table.lookup(name), Some(0), "{name}");
        }
        assert_eq!(table.lookup("MouthSmileLeft"), Some(1));
        assert_eq!(table.lookup("mouthSmile"), None);
        assert_eq!(table.lookup("jawOpen "), None);
        assert_eq!(table.lookup("eyeBlinkLeft"), None);
    }

    #[test]
    fn visemes_map_only_when_the_take_has_them() {
        let without = CurveTable::new(&["jawOpen", "mouthClose", "mouthFunnel", "mouthPucker"]);
        for name in ["aa", "A", "oh", "O", "ih"] {
            assert_eq!(without.lookup(name), None, "{name}");
        }
        let with = CurveTable::new(&["jawOpen", "aa", "ih", "ou", "ee", "oh"]);
        for (names, index) in [
            (["aa", "A", "AA"], 1),
            (["ih", "I", "i"], 2),
            (["ou", "U", "u"], 3),
            (["ee", "E", "e"], 4),
            (["oh", "O", "o"], 5),
        ] {
            for name in names {
                assert_eq!(with.lookup(name), Some(index), "{name}");
            }
        }
    }
}
