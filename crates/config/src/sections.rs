//! The configuration's tables, each with its defaults and the checks serde runs while
//! reading it: `[source]`, `[server]`, `[characters]`, `[takes]`, `[timecode]`, `[logging]`,
//! `[osc]`.

use super::*;

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

    /// `none`: no camera at all (a booth driven by speech alone; docs/daemon.md).
    pub const NONE: &'static str = "none";

    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// True for `none`: the daemon opens no camera.
    pub fn is_none(&self) -> bool {
        self.0 == Self::NONE
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
        if s == Self::NONE {
            return Ok(SourceSpec(s));
        }
        if !Self::SCHEMES.iter().any(|scheme| s.starts_with(scheme)) {
            return Err(format!(
                "expected none or a source spec starting with replay:, openni2: or v4l2:, got {s:?}"
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

/// `[characters]`: which characters are driven, all at once.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CharactersConfig {
    /// Character files (TOML). Empty = the built-in human and wolf.
    pub files: Vec<PathBuf>,
    /// `[characters.settings.NAME]`: per character, by name (docs/daemon.md, "Speech").
    pub settings: std::collections::BTreeMap<String, CharacterOptions>,
}

#[allow(clippy::derivable_impls)] // spelled out: the default is part of the documented config
impl Default for CharactersConfig {
    fn default() -> Self {
        CharactersConfig {
            files: Vec::new(),
            settings: std::collections::BTreeMap::new(),
        }
    }
}

/// Whether the microphone may drive a character's mouth.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SpeechSetting {
    /// The camera alone.
    #[default]
    Off,
    /// Speech when the lip dots are lost for longer than `speech_hold_ms`.
    Fallback,
    /// Speech alone (a booth without a camera).
    Always,
}

/// Longest `speech_hold_ms`.
pub const MAX_SPEECH_HOLD_MS: u32 = 10_000;
/// Longest `speech_blend_ms`.
pub const MAX_SPEECH_BLEND_MS: u32 = 2_000;

/// `[characters.settings.NAME]`: one character's options.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CharacterOptions {
    /// `"off"` (default), `"fallback"` or `"always"`.
    pub speech: SpeechSetting,
    /// How long the lip dots must be lost before speech takes over, ms (0 to 10 000).
    pub speech_hold_ms: u32,
    /// How long each handover blends, ms (0 to 2 000).
    pub speech_blend_ms: u32,
}

impl Default for CharacterOptions {
    fn default() -> Self {
        CharacterOptions {
            speech: SpeechSetting::Off,
            speech_hold_ms: 300,
            speech_blend_ms: 150,
        }
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
    /// 29.97 and 59.94 are drop-frame, as recorders count them). Time of day, UTC. With
    /// `source = "ltc"`: the rate of the studio's LTC, one of [`LTC_RATES`].
    pub rate: TimecodeRateName,
    /// Where the timecode comes from: the host's time of day, or LTC on the booth's audio.
    pub source: TimecodeSource,
    /// With `source = "ltc"`: the channel of the `[audio]` device that carries the LTC,
    /// counted from 1 (channel 1 is the booth's microphone, so 2 or above).
    pub channel: Option<u32>,
}

impl Default for TimecodeConfig {
    fn default() -> Self {
        TimecodeConfig {
            rate: TimecodeRateName("30".to_owned()),
            source: TimecodeSource::System,
            channel: None,
        }
    }
}

/// The rates LTC is read at (`[timecode] rate` with `source = "ltc"`).
pub const LTC_RATES: [&str; 5] = ["23.976", "24", "25", "29.97df", "30"];

/// `[timecode] source`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TimecodeSource {
    /// The host's time of day (UTC).
    #[default]
    System,
    /// Linear timecode decoded from a channel of the `[audio]` device.
    Ltc,
}

impl TimecodeConfig {
    /// The checks serde cannot express, against the `[audio]` table LTC is read from:
    /// `(key, message)` of the first that fails.
    pub fn check(&self, audio: Option<&AudioConfig>) -> Result<(), (&'static str, String)> {
        match self.source {
            TimecodeSource::System => {
                if let Some(channel) = self.channel {
                    return Err((
                        "timecode.channel",
                        format!(
                            "channel {channel} is read only with source = \"ltc\"; remove it or set timecode.source = \"ltc\""
                        ),
                    ));
                }
            }
            TimecodeSource::Ltc => {
                if !LTC_RATES.contains(&self.rate.0.as_str()) {
                    return Err((
                        "timecode.rate",
                        format!(
                            "expected one of the LTC rates {} with source = \"ltc\", got {:?}",
                            LTC_RATES.join(", "),
                            self.rate.0
                        ),
                    ));
                }
                let Some(audio) = audio else {
                    return Err((
                        "timecode.source",
                        "expected an [audio] table: LTC is read from a channel of the booth's audio input".into(),
                    ));
                };
                let Some(channel) = self.channel else {
                    return Err((
                        "timecode.source",
                        format!(
                            "expected timecode.channel too: the [audio] channel (2 to {}) that carries the LTC",
                            audio.channels.max(2)
                        ),
                    ));
                };
                if channel < 2 || channel > audio.channels {
                    return Err((
                        "timecode.channel",
                        if audio.channels < 2 {
                            format!(
                                "expected a channel of [audio] other than the microphone's (1), but audio.channels is {}: set audio.channels = 2 and wire the LTC into input 2",
                                audio.channels
                            )
                        } else {
                            format!(
                                "expected 2 to {} (audio.channels; channel 1 is the microphone), got {channel}",
                                audio.channels
                            )
                        },
                    ));
                }
            }
        }
        Ok(())
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
    /// The curves' names: `"arkit"` (`jawOpen`) or `"arkit-pascal"` (`JawOpen`).
    pub names: mouthpiece_output::CurveNaming,
    /// The visemes sent: `"vrm0"` (`A I U E O`), `"vrm1"` (`aa ih ou ee oh`) or `"none"`.
    pub visemes: mouthpiece_output::VisemeNaming,
    /// `[osc.characters]`: more characters, each with its own targets (`name = ["host:port"]`),
    /// besides `character`'s `targets`.
    pub characters: std::collections::BTreeMap<String, Vec<String>>,
}

impl Default for OscConfig {
    fn default() -> Self {
        OscConfig {
            targets: Vec::new(),
            character: None,
            head: true,
            eyes: true,
            names: mouthpiece_output::CurveNaming::Arkit,
            visemes: mouthpiece_output::VisemeNaming::Vrm0,
            characters: std::collections::BTreeMap::new(),
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

/// Most OSC targets in `[osc] targets` and `[osc.characters]` together (each costs one or two
/// datagrams per frame).
pub const MAX_OSC_TARGETS: usize = 16;

impl OscConfig {
    /// The targets, parsed (a loaded config's targets all parse).
    pub fn parsed_targets(&self) -> Result<Vec<OscTarget>, String> {
        self.targets.iter().map(|t| t.parse()).collect()
    }

    /// Every target as its key in the file and its text, with the character it is for
    /// (`None`: `character`, the first configured by default): `targets` first, then
    /// `[osc.characters]` by name.
    pub fn all_targets(&self) -> Vec<(String, &str, Option<&str>)> {
        let plain = self
            .targets
            .iter()
            .enumerate()
            .map(|(i, t)| (format!("osc.targets[{i}]"), t.as_str(), None));
        let named = self.characters.iter().flat_map(|(name, targets)| {
            targets.iter().enumerate().map(move |(i, t)| {
                (
                    format!("osc.characters.{}[{i}]", key_segment(name)),
                    t.as_str(),
                    Some(name.as_str()),
                )
            })
        });
        plain.chain(named).collect()
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

impl OscTarget {
    /// The address datagrams go to: the host resolved now (an IPv4 address is taken when a
    /// name has both kinds). The error says why, naming the host.
    pub fn resolve(&self) -> Result<std::net::SocketAddr, String> {
        use std::net::ToSocketAddrs as _;
        let addrs: Vec<std::net::SocketAddr> = (self.host.as_str(), self.port)
            .to_socket_addrs()
            .map_err(|e| format!("cannot resolve {}: {e}", self.host))?
            .collect();
        addrs
            .iter()
            .find(|a| a.is_ipv4())
            .or(addrs.first())
            .copied()
            .ok_or_else(|| format!("{} resolves to no address", self.host))
    }
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
