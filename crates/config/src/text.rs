//! One configuration file's text and where it came from: the loader every command shares.
//! The daemon keeps one inside its [`crate::Config`]; `process`, `evaluate`, `tune-colours`
//! and `lipsync poses` read their `--config` through it. Each part of mouthpiece takes the
//! tables it owns ([`ConfigText::extract`]) and reports a check that fails at the key it is
//! about ([`ConfigText::locate`]), so every error names the file, the line and the key.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::de::DeserializeOwned;

use crate::{invalid, line_col, read_bounded, span_of_key, ConfigError, Location};

/// The text of a configuration file (read with the size bound of
/// [`crate::MAX_CONFIG_FILE_BYTES`]) and its path. `Debug` leaves the text out: it may hold a
/// token.
#[derive(Clone, PartialEq)]
pub struct ConfigText {
    path: PathBuf,
    text: Arc<str>,
}

impl std::fmt::Debug for ConfigText {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("File")
            .field("path", &self.path)
            .finish_non_exhaustive()
    }
}

impl ConfigText {
    /// Reads `path`, refusing a file longer than [`crate::MAX_CONFIG_FILE_BYTES`].
    pub fn read(path: &Path) -> Result<ConfigText, ConfigError> {
        let text = read_bounded(path, crate::MAX_CONFIG_FILE_BYTES).map_err(|source| {
            ConfigError::Read {
                path: path.to_owned(),
                source,
            }
        })?;
        Ok(ConfigText::new(path, text))
    }

    /// Text already in memory, named `path` in errors.
    pub fn new(path: &Path, text: impl Into<Arc<str>>) -> ConfigText {
        ConfigText {
            path: path.to_owned(),
            text: text.into(),
        }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn text(&self) -> &str {
        &self.text
    }

    /// Deserializes the text into `T`: a struct of the caller's that reads only the tables
    /// it owns and ignores the others; syntax and type errors with the file's line, column
    /// and key.
    pub fn extract<T: DeserializeOwned>(&self) -> Result<T, ConfigError> {
        toml::from_str::<T>(&self.text).map_err(|err| {
            invalid(
                &self.text,
                &self.path.display().to_string(),
                err.span(),
                err.message().trim_end().to_owned(),
            )
        })
    }

    /// File, line and column of `key` (dotted path, `detect.class[0].hue`), for errors
    /// found by later checks.
    pub fn locate(&self, key: &str) -> Location {
        let (line, column) =
            span_of_key(&self.text, key).map_or((0, 0), |span| line_col(&self.text, span.start));
        Location {
            file: self.path.display().to_string(),
            line,
            column,
            key: Some(key.to_owned()),
        }
    }

    /// An error about `key`: its place in the file and `message`.
    pub fn invalid(&self, key: &str, message: impl Into<String>) -> ConfigError {
        ConfigError::Invalid {
            location: self.locate(key),
            message: message.into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_name_the_file_line_and_key() {
        #[derive(serde::Deserialize, Default)]
        #[serde(default)]
        struct Mine {
            detect: Option<toml::Value>,
        }
        let text = ConfigText::new(
            Path::new("booth.toml"),
            "[server]\nlisten = \"127.0.0.1:9870\"\n\n[detect]\ndot_radius_m = 0.002\n",
        );
        let mine: Mine = text.extract().unwrap();
        assert!(mine.detect.is_some());
        let e = text.invalid("detect.dot_radius_m", "too small").to_string();
        assert_eq!(e, "booth.toml:5:1: key `detect.dot_radius_m`: too small");
        let bad = ConfigText::new(Path::new("booth.toml"), "[detect]\ndot_radius_m = \"x\"\n");
        #[derive(serde::Deserialize, Debug)]
        #[allow(dead_code)]
        struct Typed {
            detect: Detect,
        }
        #[derive(serde::Deserialize, Debug)]
        #[allow(dead_code)]
        struct Detect {
            dot_radius_m: f64,
        }
        let e = bad.extract::<Typed>().unwrap_err().to_string();
        assert!(e.starts_with("booth.toml:2:"), "{e}");
    }

    #[test]
    fn debug_never_shows_the_text() {
        let text = ConfigText::new(
            Path::new("booth.toml"),
            "[server]\nread_token = { value = \"s3cr3t\" }\n",
        );
        let shown = format!("{text:?}");
        assert!(
            shown.contains("booth.toml") && !shown.contains("s3cr3t"),
            "{shown}"
        );
    }

    #[test]
    fn a_file_that_never_ends_is_refused() {
        let e = ConfigText::read(Path::new("/dev/zero")).unwrap_err();
        assert!(matches!(e, ConfigError::Read { .. }), "{e}");
    }
}
