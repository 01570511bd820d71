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
use std::sync::Arc;

use serde::de::DeserializeOwned;
use serde::Deserialize;

mod text;
pub use text::ConfigText;

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
        write!(f, "{}", self.file)?;
        if self.line > 0 {
            write!(f, ":{}:{}", self.line, self.column)?;
        }
        if let Some(key) = &self.key {
            write!(f, ": key `{key}`")?;
        }
        Ok(())
    }
}

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
    File {
        path: PathBuf,
        text: Arc<str>,
    },
}

impl fmt::Debug for Origin {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Origin::Embedded => f.write_str("Embedded"),
            Origin::File { path, .. } => f
                .debug_struct("File")
                .field("path", path)
                .finish_non_exhaustive(),
        }
    }
}

impl Origin {
    pub fn describe(&self) -> String {
        match self {
            Origin::Embedded => "<embedded default>".to_owned(),
            Origin::File { path, .. } => path.display().to_string(),
        }
    }
}

/// `[source]`: where frames come from, and how a lost source is retried.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SourceConfig {
    /// `replay:PATH[?loop=1&speed=1.0]`, `openni2:` / `openni2:URI`, `v4l2:COLOUR[+DEPTH]`.
    pub spec: SourceSpec,
    /// First wait before reopening a lost source, seconds; doubles up to `retry_max_s`.
    pub retry_initial_s: PositiveSeconds,
    pub retry_max_s: PositiveSeconds,
    /// No frame for this long from an open source: report `source down` to clients.
    pub stall_timeout_s: PositiveSeconds,
}

impl Default for SourceConfig {
    fn default() -> Self {
        SourceConfig {
            spec: SourceSpec(DEFAULT_SOURCE_SPEC.to_owned()),
            retry_initial_s: PositiveSeconds(0.5),
            retry_max_s: PositiveSeconds(10.0),
            stall_timeout_s: PositiveSeconds(2.0),
        }
    }
}

/// A source spec string; the scheme is checked here, the rest by the capture crate.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(try_from = "String")]
pub struct SourceSpec(pub String);

impl SourceSpec {
    pub const SCHEMES: [&'static str; 3] = ["replay:", "openni2:", "v4l2:"];

    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// The file of a `replay:` spec, without its query.
    pub fn replay_path(&self) -> Option<&str> {
        let rest = self.0.strip_prefix("replay:")?;
        Some(rest.split_once('?').map_or(rest, |(path, _)| path))
    }
}

impl TryFrom<String> for SourceSpec {
    type Error = String;
    fn try_from(s: String) -> Result<Self, String> {
        if !Self::SCHEMES.iter().any(|scheme| s.starts_with(scheme)) {
            return Err(format!(
                "expected a source spec starting with replay:, openni2: or v4l2:, got {s:?}"
            ));
        }
        if s.starts_with("replay:") && SourceSpec(s.clone()).replay_path() == Some("") {
            return Err(format!("expected replay:PATH, got {s:?} (no path)"));
        }
        Ok(SourceSpec(s))
    }
}

impl std::str::FromStr for SourceSpec {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        SourceSpec::try_from(s.to_owned())
    }
}

/// A finite number of seconds greater than zero.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(try_from = "f64")]
pub struct PositiveSeconds(pub f64);

impl PositiveSeconds {
    pub fn duration(self) -> std::time::Duration {
        std::time::Duration::from_secs_f64(self.0)
    }
}

impl TryFrom<f64> for PositiveSeconds {
    type Error = String;
    fn try_from(v: f64) -> Result<Self, String> {
        if v.is_finite() && v > 0.0 && v <= 86_400.0 {
            Ok(PositiveSeconds(v))
        } else {
            Err(format!(
                "expected a number of seconds > 0 and <= 86400, got {v}"
            ))
        }
    }
}

/// `[server]`: the WebSocket/HTTP server.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServerConfig {
    /// Address and port. Anything but loopback requires both tokens.
    pub listen: ListenAddr,
    /// Browser origins allowed to connect (`Origin` header); empty = same host only.
    pub allowed_origins: Vec<String>,
    /// Host names the server answers to besides `localhost`, the loopback addresses and
    /// the listen address (`Host` header; anything else is refused: DNS rebinding).
    pub allowed_hosts: Vec<String>,
    pub max_clients: u32,
    /// Token to subscribe (read) and to send control requests (calibrate, record).
    pub read_token: Option<TokenRef>,
    pub control_token: Option<TokenRef>,
    /// PEM certificate chain and key; both set = wss/https.
    pub tls_cert: Option<PathBuf>,
    pub tls_key: Option<PathBuf>,
    /// The tokens, read from where `read_token` / `control_token` say.
    #[serde(skip)]
    pub tokens: Tokens,
}

impl Default for ServerConfig {
    fn default() -> Self {
        ServerConfig {
            listen: ListenAddr(DEFAULT_LISTEN.parse().expect("valid default address")),
            allowed_origins: Vec::new(),
            allowed_hosts: Vec::new(),
            max_clients: 64,
            read_token: None,
            control_token: None,
            tls_cert: None,
            tls_key: None,
            tokens: Tokens::default(),
        }
    }
}

/// A socket address `IP:PORT`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(try_from = "String")]
pub struct ListenAddr(pub SocketAddr);

impl TryFrom<String> for ListenAddr {
    type Error = String;
    fn try_from(s: String) -> Result<Self, String> {
        s.parse::<SocketAddr>().map(ListenAddr).map_err(|_| {
            format!("expected an address like 127.0.0.1:9870 or [::1]:9870, got {s:?}")
        })
    }
}

impl std::str::FromStr for ListenAddr {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        ListenAddr::try_from(s.to_owned())
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

/// `[characters]`: which characters are driven, all at once.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CharactersConfig {
    /// Character files (TOML). Empty = the built-in human and wolf.
    pub files: Vec<PathBuf>,
}

#[allow(clippy::derivable_impls)] // spelled out: the default is part of the documented config
impl Default for CharactersConfig {
    fn default() -> Self {
        CharactersConfig { files: Vec::new() }
    }
}

/// `[takes]`: recording while live.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TakesConfig {
    /// Folder for take files; created if missing. Under systemd, `$STATE_DIRECTORY/takes`
    /// is used when this is left relative and a state directory is given.
    pub folder: PathBuf,
    /// Start a take as soon as the daemon runs.
    pub record_at_start: bool,
    /// Slate of takes not named by a control message or the command line.
    pub slate: Slate,
    /// At most this many seconds of a take are lost on a crash (chunk flush interval).
    pub flush_s: PositiveSeconds,
    /// Stop a take when the folder's file system has less free space than this.
    pub min_free_mb: u64,
    /// Frames buffered between processing and the take writer before frames are dropped.
    pub queue_frames: u32,
    /// Caps the take writer's disk throughput, MB (10^6 bytes) per second; 0: no cap. For a
    /// takes folder on a disk shared with other recorders; frames beyond the queue are
    /// dropped from the take as when the disk itself is slow.
    pub max_write_mb_s: f64,
}

impl Default for TakesConfig {
    fn default() -> Self {
        TakesConfig {
            folder: PathBuf::from("takes"),
            record_at_start: false,
            slate: Slate("take".to_owned()),
            flush_s: PositiveSeconds(1.0),
            min_free_mb: 200,
            queue_frames: 120,
            max_write_mb_s: 0.0,
        }
    }
}

/// A slate name: letters, digits, `-`, `_`, `.`, 1 to 64 characters (it becomes a file name).
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(try_from = "String")]
pub struct Slate(pub String);

impl TryFrom<String> for Slate {
    type Error = String;
    fn try_from(s: String) -> Result<Self, String> {
        // The one rule for takes' names (client requests and the command line use it too).
        if mouthpiece_output::valid_slate(&s) {
            Ok(Slate(s))
        } else {
            Err(format!(
                "expected a slate of {}, got {s:?}",
                mouthpiece_output::SLATE_RULE
            ))
        }
    }
}

impl std::str::FromStr for Slate {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Slate::try_from(s.to_owned())
    }
}

/// `[timecode]`: SMPTE timecode stamped on every frame.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TimecodeConfig {
    /// `23.976`, `24`, `25`, `29.97df`, `30`, `48`, `50`, `59.94df`, `60` (the server's rates:
    /// 29.97 and 59.94 are drop-frame, as recorders count them). Time of day, UTC.
    pub rate: TimecodeRateName,
}

impl Default for TimecodeConfig {
    fn default() -> Self {
        TimecodeConfig {
            rate: TimecodeRateName("30".to_owned()),
        }
    }
}

/// A timecode rate name, checked against [`TimecodeRateName::ALLOWED`].
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(try_from = "String")]
pub struct TimecodeRateName(pub String);

impl TimecodeRateName {
    pub const ALLOWED: [&'static str; 9] = [
        "23.976", "24", "25", "29.97df", "30", "48", "50", "59.94df", "60",
    ];
}

impl TryFrom<String> for TimecodeRateName {
    type Error = String;
    fn try_from(s: String) -> Result<Self, String> {
        if Self::ALLOWED.contains(&s.as_str()) {
            Ok(TimecodeRateName(s))
        } else {
            Err(format!(
                "expected one of {}, got {s:?}",
                Self::ALLOWED.join(", ")
            ))
        }
    }
}

/// `[logging]`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LoggingConfig {
    /// `tracing` filter (`RUST_LOG` syntax); the `RUST_LOG` variable wins when set.
    pub level: String,
    /// A repeated warning is logged at most once per this many seconds (with a count).
    pub throttle_s: PositiveSeconds,
}

impl Default for LoggingConfig {
    fn default() -> Self {
        LoggingConfig {
            level: "info".to_owned(),
            throttle_s: PositiveSeconds(10.0),
        }
    }
}

/// `[osc]`: the rig and the head sent as VMC protocol messages over OSC/UDP (docs/osc.md).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OscConfig {
    /// Where to send, `host:port` each (UDP; [`OscTarget`], checked when the file is
    /// loaded so that an error names the element's own line). Empty: no OSC output.
    pub targets: Vec<String>,
    /// The character whose rig and head go out; `None`: the first configured character.
    pub character: Option<String>,
    /// Send the head as `/VMC/Ext/Bone/Pos` `Head`.
    pub head: bool,
    /// Send the eyes as `/VMC/Ext/Bone/Pos` `LeftEye` and `RightEye`.
    pub eyes: bool,
}

impl Default for OscConfig {
    fn default() -> Self {
        OscConfig {
            targets: Vec::new(),
            character: None,
            head: true,
            eyes: true,
        }
    }
}

/// `s` quoted for an error message, cut to its first 80 characters (with its length): an
/// error never echoes a whole file's worth of one value.
pub fn quote_excerpt(s: &str) -> String {
    const MAX_CHARS: usize = 80;
    if s.chars().count() <= MAX_CHARS {
        format!("{s:?}")
    } else {
        let head: String = s.chars().take(MAX_CHARS).collect();
        format!("{head:?}… ({} bytes)", s.len())
    }
}

/// Most OSC targets in `[osc] targets` (each costs one datagram per frame).
pub const MAX_OSC_TARGETS: usize = 16;

impl OscConfig {
    /// The targets, parsed (a loaded config's targets all parse).
    pub fn parsed_targets(&self) -> Result<Vec<OscTarget>, String> {
        self.targets.iter().map(|t| t.parse()).collect()
    }
}

/// A UDP destination `host:port`: a name, an IPv4 address, or an IPv6 address in brackets,
/// then a port 1 to 65535. The host is resolved by the daemon (at start and on reload).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OscTarget {
    /// The host as written, without brackets.
    pub host: String,
    pub port: u16,
}

impl fmt::Display for OscTarget {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.host.contains(':') {
            write!(f, "[{}]:{}", self.host, self.port)
        } else {
            write!(f, "{}:{}", self.host, self.port)
        }
    }
}

impl TryFrom<String> for OscTarget {
    type Error = String;
    fn try_from(s: String) -> Result<Self, String> {
        let shown = quote_excerpt(&s);
        let shape = || {
            format!("expected host:port (e.g. \"127.0.0.1:39539\", \"[::1]:39539\"), got {shown}")
        };
        let Some((host, port)) = s.rsplit_once(':') else {
            return Err(shape());
        };
        let host = match host.strip_prefix('[') {
            Some(inner) => {
                let inner = inner.strip_suffix(']').ok_or_else(shape)?;
                inner
                    .parse::<std::net::Ipv6Addr>()
                    .map_err(|_| format!("expected an IPv6 address between [ and ], got {shown}"))?;
                inner
            }
            None if host.contains(':') => {
                return Err(format!(
                "expected host:port, got {shown} (an IPv6 address goes in brackets: \"[::1]:39539\")"
            ))
            }
            None => host,
        };
        let name_ok = !host.is_empty()
            && host.len() <= 253
            && host
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_' | ':'));
        if !name_ok {
            return Err(shape());
        }
        if port.is_empty() || !port.chars().all(|c| c.is_ascii_digit()) {
            return Err(shape());
        }
        let port = match port.parse::<u32>() {
            Ok(p) if (1..=65535).contains(&p) => p as u16,
            _ => return Err(format!("port out of range in {shown}: expected 1 to 65535")),
        };
        Ok(OscTarget {
            host: host.to_owned(),
            port,
        })
    }
}

impl std::str::FromStr for OscTarget {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        OscTarget::try_from(s.to_owned())
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
        config.origin = Origin::File {
            path: path.to_owned(),
            text: Arc::from(text),
        };
        config.validate(text, &file)?;
        let base = path.parent().map(Path::to_owned).unwrap_or_default();
        config.resolve_paths(&base, state_directory().as_deref());
        config.server.tokens = config.read_tokens(text, &file)?;
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
        if self.osc.targets.len() > MAX_OSC_TARGETS {
            return Err(fail(
                "osc.targets",
                format!(
                    "expected at most {MAX_OSC_TARGETS} targets, got {}",
                    self.osc.targets.len()
                ),
            ));
        }
        let mut targets: Vec<OscTarget> = Vec::new();
        for (i, text) in self.osc.targets.iter().enumerate() {
            let key = format!("osc.targets[{i}]");
            let target = text.parse::<OscTarget>().map_err(|e| fail(&key, e))?;
            if targets.contains(&target) {
                return Err(fail(&key, format!("{target} is listed twice")));
            }
            targets.push(target);
        }
        if self.osc.character.as_deref() == Some("") {
            return Err(fail(
                "osc.character",
                "expected a character's name, got \"\"".into(),
            ));
        }
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
        let read_one =
            |key: &str, token: &Option<TokenRef>| -> Result<Option<Secret>, ConfigError> {
                let Some(token) = token else { return Ok(None) };
                token.read().map(Some).map_err(|source| {
                    let span = span_of_key(text, key);
                    let (line, column) = span.map_or((0, 0), |s| line_col(text, s.start));
                    ConfigError::Token {
                        location: Location {
                            file: file.to_owned(),
                            line,
                            column,
                            key: Some(key.to_owned()),
                        },
                        key: key.to_owned(),
                        source,
                    }
                })
            };
        Ok(Tokens {
            read: read_one("server.read_token", &self.server.read_token)?,
            control: read_one("server.control_token", &self.server.control_token)?,
        })
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
    pub fn text(&self) -> Option<ConfigText> {
        match &self.origin {
            Origin::Embedded => None,
            Origin::File { path, text } => Some(ConfigText::new(path, Arc::clone(text))),
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
        let osc = if self.osc.targets.is_empty() {
            "off".to_owned()
        } else {
            self.osc.targets.join(", ")
        };
        format!(
            "config {}: source {}, listen {}, characters [{}], takes in {}, timecode {}, osc {}, tokens: read {}, control {}",
            self.origin.describe(),
            self.source.spec.0,
            self.server.listen.0,
            characters,
            self.takes.folder.display(),
            self.timecode.rate.0,
            osc,
            if self.server.tokens.read.is_some() { "set" } else { "none" },
            if self.server.tokens.control.is_some() { "set" } else { "none" },
        )
    }
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
fn redact_token_error(err: ConfigError) -> ConfigError {
    match err {
        ConfigError::Invalid { location, message }
            if location.key.as_deref().is_some_and(|k| {
                ["server.read_token", "server.control_token"]
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

/// Longest config file read (a config is a few kilobytes).
pub const MAX_CONFIG_FILE_BYTES: u64 = 1 << 20;

/// Longest token file read; a longer one (or `/dev/zero`) is refused without reading on.
pub const MAX_TOKEN_FILE_BYTES: u64 = 4096;

/// Reads a UTF-8 text file of at most `limit` bytes; a longer one (a device such as
/// `/dev/zero`, a wrong path) is an error instead of unbounded memory.
pub fn read_bounded(path: &Path, limit: u64) -> std::io::Result<String> {
    use std::io::Read;
    let file = std::fs::File::open(path)?;
    let mut bytes = Vec::new();
    file.take(limit + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("longer than {limit} bytes"),
        ));
    }
    String::from_utf8(bytes)
        .map_err(|_| std::io::Error::new(std::io::ErrorKind::InvalidData, "not UTF-8 text"))
}

/// The first of systemd's `$STATE_DIRECTORY` entries (colon-separated), if set.
fn state_directory() -> Option<PathBuf> {
    let dirs = std::env::var_os("STATE_DIRECTORY")?;
    let first = dirs.to_str()?.split(':').next()?.to_owned();
    (!first.is_empty()).then(|| PathBuf::from(first))
}

pub(crate) fn invalid(
    text: &str,
    file: &str,
    span: Option<Range<usize>>,
    message: String,
) -> ConfigError {
    let (line, column) = span.clone().map_or((0, 0), |s| line_col(text, s.start));
    let key = span.and_then(|s| key_path_at(text, s));
    ConfigError::Invalid {
        location: Location {
            file: file.to_owned(),
            line,
            column,
            key,
        },
        message,
    }
}

/// 1-based line and column of a byte offset.
pub(crate) fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, column)
}

/// The dotted path of the deepest key whose key or value covers `span.start`.
fn key_path_at(text: &str, span: Range<usize>) -> Option<String> {
    let doc = toml_edit::ImDocument::parse(text).ok()?;
    let mut best: Option<(String, usize)> = None;
    visit_table(doc.as_table(), "", &mut |path, key_span, item_span| {
        let covers = |s: &Option<Range<usize>>| {
            s.as_ref()
                .is_some_and(|s| s.start <= span.start && span.start < s.end.max(s.start + 1))
        };
        if covers(&key_span) || covers(&item_span) {
            let width = item_span
                .as_ref()
                .or(key_span.as_ref())
                .map_or(usize::MAX, |s| s.len());
            if best.as_ref().is_none_or(|(_, w)| width <= *w) {
                best = Some((path.to_owned(), width));
            }
        }
    });
    best.map(|(path, _)| path)
}

/// The span of the key at a dotted path; with an array index (`osc.targets[1]`), of that
/// element when the array is there, else of the key.
pub(crate) fn span_of_key(text: &str, key: &str) -> Option<Range<usize>> {
    let doc = toml_edit::ImDocument::parse(text).ok()?;
    let wanted = key.split('[').next().unwrap_or(key);
    if let Some(index) = key
        .strip_prefix(wanted)
        .and_then(|rest| rest.strip_prefix('['))
        .and_then(|rest| rest.strip_suffix(']'))
        .and_then(|i| i.parse::<usize>().ok())
    {
        let mut segments = wanted.split('.');
        let mut item = doc.as_table().get(segments.next()?);
        for segment in segments {
            item = item.and_then(|i| i.get(segment));
        }
        if let Some(span) = item
            .and_then(|i| i.as_array())
            .and_then(|a| a.get(index))
            .and_then(|v| v.span())
        {
            return Some(span);
        }
    }
    let mut found = None;
    visit_table(doc.as_table(), "", &mut |path, key_span, item_span| {
        if path == wanted && found.is_none() {
            found = key_span.or(item_span);
        }
    });
    found
}

/// Called with a key's dotted path, the key's span and its value's span.
type KeyVisitor<'a> = dyn FnMut(&str, Option<Range<usize>>, Option<Range<usize>>) + 'a;

fn visit_table(table: &toml_edit::Table, prefix: &str, f: &mut KeyVisitor<'_>) {
    for (key, item) in table.iter() {
        let path = if prefix.is_empty() {
            key.to_owned()
        } else {
            format!("{prefix}.{key}")
        };
        let key_span = table.key(key).and_then(|k| k.span());
        f(&path, key_span, item.span());
        match item {
            toml_edit::Item::Table(t) => visit_table(t, &path, f),
            toml_edit::Item::Value(toml_edit::Value::InlineTable(t)) => {
                for (k, v) in t.iter() {
                    let sub = format!("{path}.{k}");
                    f(&sub, t.key(k).and_then(|k| k.span()), v.span());
                }
            }
            toml_edit::Item::ArrayOfTables(tables) => {
                for t in tables.iter() {
                    visit_table(t, &path, f);
                }
            }
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests;
