//! Tokens: where each comes from (`env`, `file` or `value`), read at load time, held as
//! [`Secret`]s that never print, and kept out of error messages.

use super::*;

/// A value that must never be printed (tokens). `Debug` and `Display` show `***`.
#[derive(Clone, PartialEq, Eq)]
pub struct Secret(String);

impl Secret {
    pub fn new(value: impl Into<String>) -> Self {
        Secret(value.into())
    }

    /// The secret itself, for comparison by the server. Never log it.
    pub fn expose(&self) -> &str {
        &self.0
    }
}

impl fmt::Debug for Secret {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Secret(***)")
    }
}

impl fmt::Display for Secret {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("***")
    }
}

/// Where a token comes from: exactly one of `env`, `file` or `value`.
#[derive(Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TokenRef {
    /// Name of an environment variable holding the token.
    pub env: Option<String>,
    /// A file holding the token (trailing newline ignored), e.g. a systemd credential.
    pub file: Option<PathBuf>,
    /// The token itself. Discouraged: config files get copied around.
    pub value: Option<Secret>,
}

impl fmt::Debug for TokenRef {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("TokenRef")
            .field("env", &self.env)
            .field("file", &self.file)
            .field("value", &self.value.as_ref().map(|_| "***"))
            .finish()
    }
}

impl<'de> Deserialize<'de> for Secret {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        String::deserialize(d).map(Secret)
    }
}

/// Tokens as read at load time.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Tokens {
    pub read: Option<Secret>,
    pub control: Option<Secret>,
}

impl TokenRef {
    /// Reads the token from where it is.
    pub fn read(&self) -> Result<Secret, TokenError> {
        let value = if let Some(name) = &self.env {
            std::env::var(name).map_err(|_| TokenError::EnvMissing(name.clone()))?
        } else if let Some(path) = &self.file {
            read_bounded(path, MAX_TOKEN_FILE_BYTES).map_err(|source| TokenError::File {
                path: path.clone(),
                source,
            })?
        } else if let Some(value) = &self.value {
            value.0.clone()
        } else {
            String::new()
        };
        let value = value.trim_end_matches(['\n', '\r']).to_owned();
        if value.is_empty() {
            return Err(TokenError::Empty);
        }
        Ok(Secret(value))
    }
}

/// Parser messages quote the offending value (`invalid type: string "..."`): under a token
/// key that value may be the secret, so the message is replaced by one that names the key
/// and the expected shape only.
pub(crate) fn redact_token_error(err: ConfigError) -> ConfigError {
    match err {
        ConfigError::Invalid { location, message }
            if location.key.as_deref().is_some_and(|k| {
                [
                    "server.read_token",
                    "server.control_token",
                    "nats.password",
                    "nats.token",
                    "nats.nkey",
                ]
                .iter()
                .any(|t| k == *t || k.starts_with(&format!("{t}.")))
            }) =>
        {
            let _ = message;
            ConfigError::Invalid {
                location,
                message: "expected a table with exactly one of env = \"VARIABLE\", file = \"PATH\" or value = \"TOKEN\" (the value found is not shown: it may be a secret)".into(),
            }
        }
        other => other,
    }
}
