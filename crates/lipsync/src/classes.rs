//! The class table: every phone → one viseme class, each class with its target weights on the
//! key poses (`config/lipsync/classes.toml`).
//!
//! ```toml
//! poses = ["closed", "open", "spread", "round", "bite"]   # the key poses targets weigh
//! [[class]]
//! name = "sil"                                 # the silence class: all targets 0
//! phones = ["sil", "h#", "pau"]
//! [[class]]
//! name = "bilabial"
//! phones = ["p", "b", "m", "em", "pcl", "bcl"]
//! target = { closed = 1.0 }                    # poses left out weigh 0
//! ```

use std::collections::HashMap;

use serde::Deserialize;

use crate::input::cut;
use crate::phones::{normalise, PhoneSpan};
use crate::Error;

/// The name of the silence class; its targets are all 0 (the neutral mouth).
pub const SILENCE: &str = "sil";

/// Most classes a table may have: the segment table holds one segment per ordered pair
/// (16 classes: 256 segments; 64: 4096), each a curve per key pose and stage.
pub const MAX_CLASSES: usize = 64;
/// Most key poses a table may weigh (every sample holds one weight per key pose).
pub const MAX_POSES: usize = 16;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    poses: Vec<String>,
    class: Vec<ClassFile>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ClassFile {
    name: String,
    phones: Vec<toml::Spanned<String>>,
    #[serde(default)]
    target: HashMap<String, f64>,
}

/// One class.
#[derive(Debug, Clone, PartialEq)]
pub struct Class {
    pub name: String,
    pub phones: Vec<String>,
    /// Target weight per key pose, in [`ClassTable::poses`] order.
    pub target: Vec<f64>,
}

/// The class table.
#[derive(Debug, Clone, PartialEq)]
pub struct ClassTable {
    /// Key pose names, the order of every target vector.
    pub poses: Vec<String>,
    pub classes: Vec<Class>,
    by_phone: HashMap<String, usize>,
    silence: usize,
}

impl ClassTable {
    /// Parses and checks a class table: at most [`MAX_CLASSES`] classes and [`MAX_POSES`]
    /// key poses, unique class names, each phone listed once (after [`normalise`]: `F1` and
    /// `f` are the same phone; a second listing is an error naming its line), a `sil` class
    /// with all-zero targets, targets finite in [0, 1] on known poses.
    pub fn from_toml_str(text: &str, source_name: &str) -> Result<Self, Error> {
        let file: File = toml::from_str(text).map_err(|e| Error::Toml {
            source_name: source_name.to_string(),
            source: Box::new(e),
        })?;
        let config = |key: String, what: String| Error::Config {
            source_name: source_name.to_string(),
            key,
            what,
        };
        if file.poses.is_empty() {
            return Err(config("poses".into(), "at least one key pose".into()));
        }
        if file.poses.len() > MAX_POSES {
            return Err(config(
                "poses".into(),
                format!("{} key poses, at most {MAX_POSES}", file.poses.len()),
            ));
        }
        if file.class.len() > MAX_CLASSES {
            return Err(config(
                "class".into(),
                format!(
                    "{} classes, at most {MAX_CLASSES} (the segment table holds one segment \
                     per ordered pair of classes)",
                    file.class.len()
                ),
            ));
        }
        for (i, p) in file.poses.iter().enumerate() {
            if !crate::input::valid_name(p) {
                return Err(config(
                    format!("poses[{i}]"),
                    format!(
                        "pose name {} must be {} (it names a column of the weights CSV)",
                        cut(p),
                        crate::input::NAME_RULE
                    ),
                ));
            }
            if file.poses[..i].contains(p) {
                return Err(config(
                    "poses".into(),
                    format!("pose {:?} listed twice", cut(p)),
                ));
            }
        }
        let mut by_phone: HashMap<String, usize> = HashMap::new();
        let mut classes: Vec<Class> = Vec::with_capacity(file.class.len());
        for (ci, c) in file.class.into_iter().enumerate() {
            let key = |k: &str| format!("class[{ci}] ({}).{k}", cut(&c.name));
            if !crate::input::valid_name(&c.name) {
                return Err(config(
                    key("name"),
                    format!("a class name must be {}", crate::input::NAME_RULE),
                ));
            }
            if classes.iter().any(|o: &Class| o.name == c.name) {
                return Err(config(key("name"), "class name used twice".into()));
            }
            let mut target = vec![0.0; file.poses.len()];
            for (pose, &w) in &c.target {
                let i = file.poses.iter().position(|p| p == pose).ok_or_else(|| {
                    config(
                        key("target"),
                        format!("unknown pose {:?} (poses: {:?})", cut(pose), file.poses),
                    )
                })?;
                if !(w.is_finite() && (0.0..=1.0).contains(&w)) {
                    return Err(config(
                        key("target"),
                        format!("weight of {:?} must be within 0..1, got {w}", cut(pose)),
                    ));
                }
                target[i] = w;
            }
            let mut phones = Vec::with_capacity(c.phones.len());
            for listed in &c.phones {
                let p = normalise(listed.get_ref());
                let line = || {
                    text[..listed.span().start.min(text.len())]
                        .bytes()
                        .filter(|&b| b == b'\n')
                        .count()
                        + 1
                };
                // No phone file can hold an empty phone, nor one with a space or a control
                // character: such an entry is a mistake in the table.
                if p.is_empty() || p.chars().any(|c| c.is_whitespace() || c.is_control()) {
                    return Err(Error::Parse {
                        source_name: source_name.to_string(),
                        line: line(),
                        what: format!(
                            "{}: phone {:?} is empty or holds a space or control character",
                            key("phones"),
                            cut(listed.get_ref())
                        ),
                    });
                }
                if let Some(&other) = by_phone.get(&p) {
                    // The class being read is not in `classes` yet.
                    let other = if other == ci {
                        "this class".to_string()
                    } else {
                        format!("class {:?}", cut(&classes[other].name))
                    };
                    return Err(Error::Parse {
                        source_name: source_name.to_string(),
                        line: line(),
                        what: format!(
                            "{}: phone {:?} (read as {:?}) is already in {other}",
                            key("phones"),
                            cut(listed.get_ref()),
                            cut(&p)
                        ),
                    });
                }
                by_phone.insert(p.clone(), ci);
                phones.push(p);
            }
            classes.push(Class {
                name: c.name,
                phones,
                target,
            });
        }
        let silence = classes
            .iter()
            .position(|c| c.name == SILENCE)
            .ok_or_else(|| config("class".into(), format!("no class named {SILENCE:?}")))?;
        if classes[silence].target.iter().any(|&w| w != 0.0) {
            return Err(config(
                format!("class[{silence}] (sil).target"),
                "silence is the neutral mouth: all targets 0".into(),
            ));
        }
        if !by_phone.contains_key(SILENCE) {
            return Err(config(
                format!("class[{silence}] (sil).phones"),
                "must list \"sil\" (gaps between phones are filled with it)".into(),
            ));
        }
        Ok(Self {
            poses: file.poses,
            classes,
            by_phone,
            silence,
        })
    }

    /// The class of a (normalised) phone.
    pub fn class_of(&self, phone: &str) -> Option<usize> {
        self.by_phone.get(phone).copied()
    }

    /// The silence class's index.
    pub fn silence(&self) -> usize {
        self.silence
    }

    /// Number of classes.
    pub fn len(&self) -> usize {
        self.classes.len()
    }

    /// Never true for a parsed table (it has the silence class).
    pub fn is_empty(&self) -> bool {
        self.classes.is_empty()
    }

    /// The class of every phone; an unknown phone is an error naming its source and line.
    pub fn classify(&self, phones: &[PhoneSpan], source_name: &str) -> Result<Vec<usize>, Error> {
        phones
            .iter()
            .map(|p| {
                self.class_of(&p.phone).ok_or_else(|| Error::UnknownPhone {
                    source_name: source_name.to_string(),
                    line: p.line,
                    phone: p.phone.clone(),
                })
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SMALL: &str = r#"
poses = ["closed", "open"]
[[class]]
name = "sil"
phones = ["sil", "h#"]
[[class]]
name = "m"
phones = ["M", "b"]
target = { closed = 1.0 }
"#;

    #[test]
    fn parses_and_classifies() {
        let t = ClassTable::from_toml_str(SMALL, "c.toml").unwrap();
        assert_eq!(t.class_of("m"), Some(1));
        assert_eq!(t.class_of("h#"), Some(0));
        assert_eq!(t.classes[1].target, [1.0, 0.0]);
        let phones = [PhoneSpan {
            start: 0.0,
            end: 1.0,
            phone: "zz".into(),
            line: 7,
        }];
        let err = t.classify(&phones, "p.phn").unwrap_err();
        assert_eq!(
            err.to_string(),
            "p.phn:7: unknown phone \"zz\" (not in the class table)"
        );
    }

    #[test]
    fn rejects_bad_tables() {
        let bad = [
            (SMALL.replace("\"b\"", "\"h#\""), "already in class"),
            (SMALL.replace("closed = 1.0", "shut = 1.0"), "unknown pose"),
            (SMALL.replace("closed = 1.0", "closed = 1.5"), "within 0..1"),
            (
                SMALL.replace("name = \"sil\"", "name = \"quiet\""),
                "no class named",
            ),
            (
                SMALL.replace("\"sil\", \"h#\"", "\"h#\""),
                "must list \"sil\"",
            ),
            (
                SMALL.replace("name = \"m\"", "name = \"sil\""),
                "used twice",
            ),
        ];
        for (text, expect) in bad {
            let err = ClassTable::from_toml_str(&text, "c.toml").unwrap_err();
            assert!(err.to_string().contains(expect), "{err} / {expect}");
            assert!(err.to_string().starts_with("c.toml:"), "{err}");
        }
    }

    /// An empty phone (or one the normalisation empties, `1`), a phone with a space, and
    /// names that would split a CSV column or a TOML key are refused, not accepted silently.
    #[test]
    fn empty_phones_and_names_with_separators_are_refused() {
        for (listed, line) in [
            ("\"M\", \"\"", 8),
            ("\"M\",\n \"1\"", 9),
            ("\"M\", \"a b\"", 8),
        ] {
            let text = SMALL.replace("\"M\", \"b\"", listed);
            let err = ClassTable::from_toml_str(&text, "c.toml")
                .unwrap_err()
                .to_string();
            assert!(err.starts_with(&format!("c.toml:{line}: ")), "{err}");
            assert!(err.contains("is empty or holds a space"), "{err}");
        }
        for (text, key) in [
            (SMALL.replace("\"open\"]", "\"op,en\"]"), "poses[1]"),
            (SMALL.replace("\"open\"]", "\"a\\u001b[2J\"]"), "poses[1]"),
            (
                SMALL.replace("name = \"m\"", "name = \"m.x\""),
                "class[1] (m.x).name",
            ),
        ] {
            let err = ClassTable::from_toml_str(&text, "c.toml")
                .unwrap_err()
                .to_string();
            assert!(err.starts_with(&format!("c.toml: {key}: ")), "{err}");
            assert!(err.contains(crate::input::NAME_RULE), "{err}");
            assert!(!err.contains('\u{1b}'), "{err:?}");
        }
    }

    #[test]
    fn a_phone_listed_twice_in_one_class_is_an_error_naming_the_line() {
        // The second listing used to index the class being read: a panic.
        for twice in ["\"M\", \"b\", \"m\"", "\"M\", \"b\", \"b1\""] {
            let text = SMALL.replace("\"M\", \"b\"", twice);
            let err = ClassTable::from_toml_str(&text, "c.toml").unwrap_err();
            assert!(err.to_string().starts_with("c.toml:8: "), "{err}");
            assert!(err.to_string().contains("already in this class"), "{err}");
        }
        // Across classes, with the line too.
        let text = SMALL.replace("\"M\", \"b\"", "\"M\",\n  \"H#\"");
        let err = ClassTable::from_toml_str(&text, "c.toml").unwrap_err();
        assert!(err.to_string().starts_with("c.toml:9: "), "{err}");
        assert!(err.to_string().contains("class \"sil\""), "{err}");
    }

    #[test]
    fn a_table_of_thousands_of_classes_is_refused_before_its_segments() {
        let mut text = SMALL.to_string();
        for i in 0..8000 {
            text.push_str(&format!(
                "[[class]]\nname = \"c{i}\"\nphones = [\"x{i}x\"]\n"
            ));
        }
        let Err(err) = ClassTable::from_toml_str(&text, "c.toml") else {
            panic!("a table of 8002 classes (64 million segments) was accepted");
        };
        assert!(
            err.to_string().contains("8002 classes, at most 64"),
            "{err}"
        );
    }
}
