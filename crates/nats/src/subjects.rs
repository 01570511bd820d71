//! The booth's subjects and bucket names.

/// `mouthpiece.<booth>.*`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Subjects {
    prefix: String,
}

impl Subjects {
    /// `booth` must be subject-safe (the configuration checks it).
    pub fn new(booth: &str) -> Subjects {
        Subjects {
            prefix: format!("mouthpiece.{booth}"),
        }
    }

    /// The WebSocket `frame` message, JSON, with every optional field.
    pub fn frame(&self) -> String {
        format!("{}.frame", self.prefix)
    }

    /// The binary frame layout (docs/protocol.md, *Binary frames*).
    pub fn frame_bin(&self) -> String {
        format!("{}.frame.bin", self.prefix)
    }

    /// One character's rig; a name that is not one subject token is escaped ([`escape`]).
    pub fn rig(&self, character: &str) -> String {
        format!("{}.rig.{}", self.prefix, escape(character))
    }

    /// The WebSocket `status` message, on change and every few seconds.
    pub fn status(&self) -> String {
        format!("{}.status", self.prefix)
    }

    /// The WebSocket `hello` message: published on connection and on change, and the
    /// answer to a request on this subject.
    pub fn hello(&self) -> String {
        format!("{}.hello", self.prefix)
    }

    /// Control requests (request/reply).
    pub fn control(&self) -> String {
        format!("{}.control", self.prefix)
    }
}

/// The object store bucket of a studio's takes.
pub fn takes_bucket(studio: &str) -> String {
    format!("mouthpiece-takes-{studio}")
}

/// The key-value bucket of a studio's take metadata.
pub fn meta_bucket(studio: &str) -> String {
    format!("mouthpiece-takes-{studio}-meta")
}

/// `name` as one subject token or key-value key token: letters, digits, `-` and `_` stay,
/// every other byte becomes `=XX` (hex), `=` included, so that distinct names stay distinct.
pub fn escape(name: &str) -> String {
    let mut out = String::with_capacity(name.len());
    for b in name.bytes() {
        if b.is_ascii_alphanumeric() || b == b'-' || b == b'_' {
            out.push(b as char);
        } else {
            out.push_str(&format!("={b:02X}"));
        }
    }
    if out.is_empty() {
        out.push_str("=00");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subjects_and_escapes() {
        let s = Subjects::new("booth-a");
        assert_eq!(s.frame(), "mouthpiece.booth-a.frame");
        assert_eq!(s.frame_bin(), "mouthpiece.booth-a.frame.bin");
        assert_eq!(s.rig("wolf"), "mouthpiece.booth-a.rig.wolf");
        assert_eq!(
            s.rig("big wolf.v2"),
            "mouthpiece.booth-a.rig.big=20wolf=2Ev2"
        );
        assert_ne!(escape("a b"), escape("a_b"));
        assert_ne!(escape("a=20b"), escape("a b"));
    }
}
