//! mouthpiece's configuration: one TOML file.
//!
//! `config/mouthpiece.toml` in the repository is the documented example with every key and its
//! default; a system install reads [`SYSTEM_CONFIG_PATH`]. With no file at all the daemon runs
//! on [`Config::default`] (the embedded default: the demo recording, human and wolf, the server
//! on 127.0.0.1:9870).
//!
//! Validation is strict and happens once, at start (and on every reload): unknown keys, wrong
//! types and out-of-range values are rejected with an error that names the file, the line and
//! column, the key (dotted path such as `server.listen`) and what was expected.
//!
//! Paths inside a config file (characters, takes folder, token files, TLS files, a `replay:`
//! source's file) are resolved against the directory that holds the config file, so a config
//! means the same thing whatever the working directory. The embedded default has no file: its
//! relative paths are relative to the working directory (the repository root for
//! `scripts/run`).
//!
//! Tokens come from the environment or a file (or, discouraged, the file itself) and are held
//! as [`Secret`], whose `Debug` and `Display` never show the value.
//!
//! The `[detect]` section belongs to the detector; it is kept as written and parsed
//! into the detector's own config type with [`Config::extract`], which keeps the file's
//! line numbers in its errors; so is `[track]` (labels, neutral calibration seconds).

use std::fmt;
use std::net::SocketAddr;
use std::ops::Range;
use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::Deserialize;

mod audio;
mod ifacialmocap;
mod livelink;
mod locate;
mod nats;
mod sections;
mod text;
mod tokens;

pub use audio::*;
pub use ifacialmocap::IfacialmocapConfig;
pub use livelink::*;
pub(crate) use locate::{invalid, key_location, line_col, span_of_key, state_directory};
pub use locate::{key_segment, read_bounded, MAX_CONFIG_FILE_BYTES, MAX_TOKEN_FILE_BYTES};
pub use nats::{subject_safe, NatsConfig, NatsSecrets, MAX_NATS_QUEUE_FRAMES, MAX_NATS_SERVERS};
pub use sections::*;
pub use text::ConfigText;
pub(crate) use tokens::redact_token_error;
pub use tokens::{Secret, TokenRef, Tokens};

/// Where a system install keeps its configuration.
pub const SYSTEM_CONFIG_PATH: &str = "/etc/mouthpiece/mouthpiece.toml";

/// The source of the embedded default: the committed demo session, looped at real-time pace.
pub const DEFAULT_SOURCE_SPEC: &str = "replay:recordings/demo.mcap?loop=1&speed=1.0";

/// The server's default address: loopback only, so no token is required.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:9870";

/// Hard cap of `[takes] queue_frames`: two minutes at 30 fps (each frame holds its images).
pub const MAX_QUEUE_FRAMES: u32 = 3600;

/// Hard cap of `[server] max_clients`: the server's TCP connection cap.
pub const MAX_CLIENTS: u32 = 512;

/// Longest `.creds` or TLS file of `[nats]` read.
pub const MAX_NATS_FILE_BYTES: u64 = 1 << 20;

/// What a PEM file named in `[nats]` must hold.
#[derive(Debug, Clone, Copy)]
enum PemHolds {
    Certificate,
    PrivateKey,
}

impl PemHolds {
    fn what(self) -> &'static str {
        match self {
            PemHolds::Certificate => "certificate",
            PemHolds::PrivateKey => "private key",
        }
    }

    fn label(self) -> &'static str {
        match self {
            PemHolds::Certificate => "CERTIFICATE",
            PemHolds::PrivateKey => "PRIVATE KEY",
        }
    }

    /// Whether `pem` has a block of this kind (`PRIVATE KEY`, `RSA PRIVATE KEY`, `EC
    /// PRIVATE KEY` for a key).
    fn found_in(self, pem: &str) -> bool {
        pem.lines().any(|line| {
            let Some(label) = line
                .trim()
                .strip_prefix("-----BEGIN ")
                .and_then(|l| l.strip_suffix("-----"))
            else {
                return false;
            };
            match self {
                PemHolds::Certificate => label == "CERTIFICATE",
                PemHolds::PrivateKey => label.ends_with("PRIVATE KEY"),
            }
        })
    }
}

/// Why a configuration was rejected.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config file {path}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file is not valid TOML, has an unknown key, or a value of the wrong type or range.
    #[error("{location}: {message}")]
    Invalid { location: Location, message: String },
    /// A token's environment variable is unset or its file cannot be read.
    #[error("{location}: cannot read token for `{key}`")]
    Token {
        location: Location,
        key: String,
        #[source]
        source: TokenError,
    },
}

impl ConfigError {
    /// The dotted key the error is about, when it is about one.
    pub fn key(&self) -> Option<&str> {
        match self {
            ConfigError::Read { .. } => None,
            ConfigError::Invalid { location, .. } => location.key.as_deref(),
            ConfigError::Token { key, .. } => Some(key),
        }
    }
}

/// Why a token could not be read.
#[derive(Debug, thiserror::Error)]
pub enum TokenError {
    #[error("environment variable {0} is not set (or not UTF-8)")]
    EnvMissing(String),
    #[error("cannot read token file {path}")]
    File {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("the token is empty")]
    Empty,
}

/// File, line, column and key of a configuration error.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    /// The config file, or `<embedded default>` / `<command line>`.
    pub file: String,
    /// 1-based; 0 when unknown.
    pub line: usize,
    /// 1-based; 0 when unknown.
    pub column: usize,
    /// Dotted path of the key, e.g. `server.listen`.
    pub key: Option<String>,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", mouthpiece_output::shown(&self.file))?;
        if self.line > 0 {
            write!(f, ":{}:{}", self.line, self.column)?;
        }
        if let Some(key) = &self.key {
            // Names in keys are quoted and escaped already ([`key_segment`]).
            write!(f, ": key `{}`", mouthpiece_output::shown_message(key))?;
        }
        Ok(())
    }
}

/// The whole configuration. Every section has a default; see `config/mouthpiece.toml`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    pub source: SourceConfig,
    pub server: ServerConfig,
    pub characters: CharactersConfig,
    pub takes: TakesConfig,
    pub timecode: TimecodeConfig,
    pub logging: LoggingConfig,
    /// The detector's section, parsed by [`Config::extract`].
    pub detect: toml::Table,
    /// The tracker's section (labels, calibration seconds), parsed by
    /// [`Config::extract`].
    pub track: toml::Table,
    /// How the characters' outputs are made (shape smoothing, temporal filter), parsed by
    /// [`Config::extract`] like `[detect]` and `[track]`.
    pub retarget: toml::Table,
    /// The rig (jaw hinge, curve ranges; docs/rig.md), parsed by [`Config::extract`].
    pub rig: toml::Table,
    /// OSC / VMC protocol output to avatar apps and engines (docs/osc.md).
    pub osc: OscConfig,
    /// Live Link Face's UDP stream to Unreal and its OSC remote control (docs/livelink.md).
    pub livelink: LiveLinkConfig,
    /// The booth's microphone (`[audio]`, docs/daemon.md); `None` (no table): no audio.
    pub audio: Option<AudioConfig>,
    /// The booth on a NATS server (docs/nats.md); off by default.
    pub nats: NatsConfig,
    /// The iFacialMocap output (docs/ifacialmocap.md); off by default.
    pub ifacialmocap: IfacialmocapConfig,
    /// Where this configuration came from, with its text (for [`Config::extract`]).
    #[serde(skip)]
    pub origin: Origin,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            source: SourceConfig::default(),
            server: ServerConfig::default(),
            characters: CharactersConfig::default(),
            takes: TakesConfig::default(),
            timecode: TimecodeConfig::default(),
            logging: LoggingConfig::default(),
            detect: toml::Table::new(),
            track: toml::Table::new(),
            retarget: toml::Table::new(),
            rig: toml::Table::new(),
            osc: OscConfig::default(),
            livelink: LiveLinkConfig::default(),
            audio: None,
            nats: NatsConfig::default(),
            ifacialmocap: IfacialmocapConfig::default(),
            origin: Origin::Embedded,
        }
    }
}

/// Where a configuration came from. `Debug` leaves the text out: it may hold a token.
#[derive(Clone, PartialEq, Default)]
pub enum Origin {
    /// No file: [`Config::default`].
    #[default]
    Embedded,
    /// A file: its path and text.
    File(ConfigText),
}

impl fmt::Debug for Origin {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Origin::Embedded => f.write_str("Embedded"),
            Origin::File(text) => text.fmt(f),
        }
    }
}

impl Origin {
    pub fn describe(&self) -> String {
        match self {
            Origin::Embedded => "<embedded default>".to_owned(),
            Origin::File(text) => text.path().display().to_string(),
        }
    }
}

impl Config {
    /// Reads, parses and validates a config file, resolves its relative paths and reads its
    /// tokens.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let text =
            read_bounded(path, MAX_CONFIG_FILE_BYTES).map_err(|source| ConfigError::Read {
                path: path.to_owned(),
                source,
            })?;
        Config::parse(&text, path)
    }

    /// Parses and validates `text` as if read from `path` (relative paths resolve against
    /// `path`'s directory).
    pub fn parse(text: &str, path: &Path) -> Result<Config, ConfigError> {
        let file = path.display().to_string();
        let mut config: Config = toml::from_str(text).map_err(|err| {
            let span = err.span();
            redact_token_error(invalid(
                text,
                &file,
                span,
                err.message().trim_end().to_owned(),
            ))
        })?;
        config.origin = Origin::File(ConfigText::new(path, text));
        config.validate(text, &file)?;
        let base = path.parent().map(Path::to_owned).unwrap_or_default();
        config.resolve_paths(&base, state_directory().as_deref());
        config.server.tokens = config.read_tokens(text, &file)?;
        config.nats.secrets = config.read_nats_secrets(text, &file)?;
        config.check_nats_files(text, &file)?;
        Ok(config)
    }

    /// The embedded default, with tokens from the environment variables the default names
    /// (none).
    pub fn embedded() -> Config {
        Config::default()
    }

    /// Cross-key checks that serde cannot express.
    fn validate(&self, text: &str, file: &str) -> Result<(), ConfigError> {
        let fail = |key: &str, message: String| -> ConfigError {
            let span = span_of_key(text, key);
            let mut err = invalid(text, file, span, message);
            if let ConfigError::Invalid { location, .. } = &mut err {
                location.key = Some(key.to_owned());
            }
            err
        };
        if self.source.retry_max_s.0 < self.source.retry_initial_s.0 {
            return Err(fail(
                "source.retry_max_s",
                format!(
                    "expected a value >= source.retry_initial_s ({}), got {}",
                    self.source.retry_initial_s.0, self.source.retry_max_s.0
                ),
            ));
        }
        if self.server.max_clients == 0 {
            return Err(fail(
                "server.max_clients",
                "expected at least 1 client, got 0".into(),
            ));
        }
        if self.server.tls_cert.is_some() != self.server.tls_key.is_some() {
            // Point at the key that is there; say which one is missing.
            let (present, missing) = if self.server.tls_cert.is_some() {
                ("server.tls_cert", "server.tls_key")
            } else {
                ("server.tls_key", "server.tls_cert")
            };
            return Err(fail(
                present,
                format!("expected {missing} too: TLS needs both a certificate and a key"),
            ));
        }
        for (key, token) in [
            ("server.read_token", &self.server.read_token),
            ("server.control_token", &self.server.control_token),
        ] {
            if let Some(token) = token {
                let set = [
                    token.env.is_some(),
                    token.file.is_some(),
                    token.value.is_some(),
                ]
                .iter()
                .filter(|set| **set)
                .count();
                if set != 1 {
                    return Err(fail(
                        key,
                        "expected exactly one of env, file or value".into(),
                    ));
                }
            }
        }
        if !self.server.listen.0.ip().is_loopback()
            && (self.server.read_token.is_none() || self.server.control_token.is_none())
        {
            return Err(fail(
                "server.listen",
                format!(
                    "expected a loopback address, or server.read_token and server.control_token: {} is reachable from the network",
                    self.server.listen.0
                ),
            ));
        }
        if self.takes.queue_frames == 0 || self.takes.queue_frames > MAX_QUEUE_FRAMES {
            return Err(fail(
                "takes.queue_frames",
                format!(
                    "expected 1 to {MAX_QUEUE_FRAMES} frames, got {}",
                    self.takes.queue_frames
                ),
            ));
        }
        if !(self.takes.max_write_mb_s.is_finite()
            && (self.takes.max_write_mb_s == 0.0 || self.takes.max_write_mb_s >= 0.01))
        {
            return Err(fail(
                "takes.max_write_mb_s",
                format!(
                    "expected 0 (no cap) or at least 0.01 MB/s, got {}",
                    self.takes.max_write_mb_s
                ),
            ));
        }
        if self.server.max_clients > MAX_CLIENTS {
            return Err(fail(
                "server.max_clients",
                format!(
                    "expected at most {MAX_CLIENTS} clients (the server's connection cap), got {}",
                    self.server.max_clients
                ),
            ));
        }
        for (i, file) in self.characters.files.iter().enumerate() {
            if file.as_os_str().is_empty() {
                return Err(fail(
                    &format!("characters.files[{i}]"),
                    "expected a file path, got \"\"".into(),
                ));
            }
        }
        for (name, o) in &self.characters.settings {
            let key = format!("characters.settings.{}", key_segment(name));
            if name.is_empty() {
                return Err(fail(
                    "characters.settings",
                    format!("expected a character's name, got {name:?}"),
                ));
            }
            if o.speech_hold_ms > MAX_SPEECH_HOLD_MS {
                return Err(fail(
                    &format!("{key}.speech_hold_ms"),
                    format!(
                        "expected 0 to {MAX_SPEECH_HOLD_MS} ms, got {}",
                        o.speech_hold_ms
                    ),
                ));
            }
            if o.speech_blend_ms > MAX_SPEECH_BLEND_MS {
                return Err(fail(
                    &format!("{key}.speech_blend_ms"),
                    format!(
                        "expected 0 to {MAX_SPEECH_BLEND_MS} ms, got {}",
                        o.speech_blend_ms
                    ),
                ));
            }
        }
        let all = self.osc.all_targets();
        if all.len() > MAX_OSC_TARGETS {
            return Err(fail(
                "osc.targets",
                format!(
                    "expected at most {MAX_OSC_TARGETS} targets (with [osc.characters]), got {}",
                    all.len()
                ),
            ));
        }
        // One destination gets one character: VMC receivers take one avatar.
        let mut targets: Vec<OscTarget> = Vec::new();
        for (key, text, _) in &all {
            let target = text.parse::<OscTarget>().map_err(|e| fail(key, e))?;
            if targets.contains(&target) {
                return Err(fail(key, format!("{target} is listed twice")));
            }
            targets.push(target);
        }
        if let Some(audio) = &self.audio {
            audio.check().map_err(|(key, message)| fail(key, message))?;
        }
        self.timecode
            .check(self.audio.as_ref())
            .map_err(|(key, message)| fail(key, message))?;
        if let Some(name) = self.osc.characters.keys().find(|n| n.is_empty()) {
            return Err(fail(
                "osc.characters",
                format!("expected a character's name, got {name:?}"),
            ));
        }
        if self.osc.character.as_deref() == Some("") {
            return Err(fail(
                "osc.character",
                "expected a character's name, got \"\"".into(),
            ));
        }
        self.nats.validate(&fail)?;
        self.livelink.validate(&fail)?;
        self.ifacialmocap.validate(&fail)?;
        Ok(())
    }

    /// `state_dir`: systemd's `$STATE_DIRECTORY`, where a relative takes folder goes (the
    /// config directory is read-only under `ProtectSystem=strict`).
    fn resolve_paths(&mut self, base: &Path, state_dir: Option<&Path>) {
        if let (true, Some(state_dir)) = (self.takes.folder.is_relative(), state_dir) {
            self.takes.folder = state_dir.join(&self.takes.folder);
        }
        let join = |p: &mut PathBuf| {
            if p.is_relative() && !base.as_os_str().is_empty() {
                *p = base.join(&*p);
            }
        };
        self.characters.files.iter_mut().for_each(join);
        if let Some(p) = self.audio.as_mut().and_then(|a| a.speech_profiles.as_mut()) {
            join(p);
        }
        join(&mut self.takes.folder);
        for token in [&mut self.server.read_token, &mut self.server.control_token]
            .into_iter()
            .flatten()
        {
            if let Some(file) = &mut token.file {
                join(file);
            }
        }
        for path in [&mut self.server.tls_cert, &mut self.server.tls_key]
            .into_iter()
            .flatten()
        {
            join(path);
        }
        self.nats.resolve_paths(&join);
        if let Some(replay) = self.source.spec.replay_path() {
            let mut path = PathBuf::from(replay);
            if path.is_relative() && !base.as_os_str().is_empty() {
                join(&mut path);
                let query = self
                    .source
                    .spec
                    .0
                    .split_once('?')
                    .map(|(_, q)| format!("?{q}"))
                    .unwrap_or_default();
                self.source.spec = SourceSpec(format!("replay:{}{query}", path.display()));
            }
        }
    }

    fn read_tokens(&self, text: &str, file: &str) -> Result<Tokens, ConfigError> {
        Ok(Tokens {
            read: read_token(text, file, "server.read_token", &self.server.read_token)?,
            control: read_token(
                text,
                file,
                "server.control_token",
                &self.server.control_token,
            )?,
        })
    }

    fn read_nats_secrets(&self, text: &str, file: &str) -> Result<NatsSecrets, ConfigError> {
        let nats = &self.nats;
        Ok(NatsSecrets {
            password: read_token(text, file, "nats.password", &nats.password)?,
            token: read_token(text, file, "nats.token", &nats.token)?,
            nkey: read_token(text, file, "nats.nkey", &nats.nkey)?,
        })
    }

    /// A `.creds` file or a TLS file that cannot be read, or a TLS file without what its key
    /// promises (a certificate for `tls_ca` and `tls_cert`, a private key for `tls_key`), is
    /// a configuration error at load time, not a connection that never authenticates.
    fn check_nats_files(&self, text: &str, file: &str) -> Result<(), ConfigError> {
        let nats = &self.nats;
        let files = [
            ("nats.credentials_file", &nats.credentials_file, None),
            ("nats.tls_ca", &nats.tls_ca, Some(PemHolds::Certificate)),
            ("nats.tls_cert", &nats.tls_cert, Some(PemHolds::Certificate)),
            ("nats.tls_key", &nats.tls_key, Some(PemHolds::PrivateKey)),
        ];
        for (key, path, holds) in files {
            let Some(path) = path else { continue };
            let content =
                read_bounded(path, MAX_NATS_FILE_BYTES).map_err(|e| ConfigError::Invalid {
                    location: key_location(text, file, key),
                    message: format!("cannot read {}: {e}", path.display()),
                })?;
            if let Some(holds) = holds {
                if !holds.found_in(&content) {
                    return Err(ConfigError::Invalid {
                        location: key_location(text, file, key),
                        message: format!(
                            "{} holds no PEM {} (-----BEGIN {}-----)",
                            path.display(),
                            holds.what(),
                            holds.label()
                        ),
                    });
                }
            }
        }
        Ok(())
    }

    /// Deserializes the file's text once more into `T`: a struct of the caller's that reads
    /// only the sections it owns (`[detect]`, `[track]`) and ignores the others, with the
    /// file's own line numbers in errors ([`ConfigText::extract`]). The embedded default gives
    /// `T::default()`.
    pub fn extract<T: DeserializeOwned + Default>(&self) -> Result<T, ConfigError> {
        match self.text() {
            Some(text) => text.extract(),
            None => Ok(T::default()),
        }
    }

    /// File, line and column of `key` (dotted path), for errors found by later checks (a
    /// character file that does not load, a detector setting out of range).
    pub fn locate(&self, key: &str) -> Location {
        match self.text() {
            Some(text) => text.locate(key),
            None => Location {
                file: self.origin.describe(),
                line: 0,
                column: 0,
                key: Some(key.to_owned()),
            },
        }
    }

    /// The file's text, `None` for the embedded default.
    pub fn text(&self) -> Option<&ConfigText> {
        match &self.origin {
            Origin::Embedded => None,
            Origin::File(text) => Some(text),
        }
    }

    /// The config as the user would see it, tokens hidden: for `check-config` and the log.
    pub fn summary(&self) -> String {
        let characters = if self.characters.files.is_empty() {
            "built-in human, wolf".to_owned()
        } else {
            self.characters
                .files
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        };
        let all = self.osc.all_targets();
        let osc = if all.is_empty() {
            "off".to_owned()
        } else {
            let each: Vec<String> = all
                .iter()
                .map(|(_, t, c)| match c {
                    Some(c) => format!("{t} ({c})"),
                    None => (*t).to_owned(),
                })
                .collect();
            each.join(", ")
        };
        format!(
            "config {}: source {}, listen {}, characters [{}], takes in {}, timecode {}, osc {}, livelink {}, audio {}, nats {}, ifacialmocap {}, tokens: read {}, control {}",
            self.origin.describe(),
            self.source.spec.0,
            self.server.listen.0,
            characters,
            self.takes.folder.display(),
            match (self.timecode.source, self.timecode.channel) {
                (TimecodeSource::Ltc, Some(channel)) => {
                    format!("{} from LTC on audio channel {channel}", self.timecode.rate.0)
                }
                _ => self.timecode.rate.0.clone(),
            },
            osc,
            self.livelink.summary(),
            match &self.audio {
                Some(a) => format!("{} ({} Hz, {} ch)", a.device, a.sample_rate, a.channels),
                None => "off".to_owned(),
            },
            self.nats.summary(),
            self.ifacialmocap.summary(),
            if self.server.tokens.read.is_some() { "set" } else { "none" },
            if self.server.tokens.control.is_some() { "set" } else { "none" },
        )
    }
}

/// Reads one secret named at `key` (a token, a password), with the key's line in errors.
fn read_token(
    text: &str,
    file: &str,
    key: &str,
    token: &Option<TokenRef>,
) -> Result<Option<Secret>, ConfigError> {
    let Some(token) = token else { return Ok(None) };
    token.read().map(Some).map_err(|source| ConfigError::Token {
        location: key_location(text, file, key),
        key: key.to_owned(),
        source,
    })
}

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_ifacialmocap;
#[cfg(test)]
mod tests_livelink;
#[cfg(test)]
mod tests_nats;
#[cfg(test)]
mod tests_timecode;
