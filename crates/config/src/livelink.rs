//! `[livelink]`: characters streamed as Live Link Face datagrams to Unreal, and Live Link
//! Face's OSC remote control (docs/livelink.md).

use std::collections::BTreeMap;
use std::net::{IpAddr, SocketAddr};

use serde::Deserialize;

use crate::{quote_excerpt, ConfigError, OscTarget};

/// Unreal's Live Link Face source listens on this UDP port by default.
pub const LIVELINK_DEFAULT_PORT: u16 = 11111;

/// Most Live Link targets over all characters (each costs one datagram per frame).
pub const MAX_LIVELINK_TARGETS: usize = 16;

/// Most addresses in `[livelink] allow`.
pub const MAX_LIVELINK_ALLOW: usize = 64;

/// The longest subject name in bytes: Unreal's receiver reads names of at most 255
/// characters.
pub const MAX_SUBJECT_BYTES: usize = 255;

/// `[livelink]`: Live Link Face's UDP stream and its OSC remote control.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LiveLinkConfig {
    /// Send the stream (the targets stay configured when off).
    pub enabled: bool,
    /// The remote control's UDP address (`ip:port`); `None`: no remote control.
    pub control: Option<String>,
    /// Source addresses whose control packets are taken; every other sender is refused
    /// (counted, never answered). Loopback only by default.
    pub allow: Vec<String>,
    /// `[livelink.characters.NAME]`: the characters streamed, by configured name.
    pub characters: BTreeMap<String, LiveLinkCharacter>,
}

impl Default for LiveLinkConfig {
    fn default() -> Self {
        LiveLinkConfig {
            enabled: true,
            control: None,
            allow: vec!["127.0.0.1".to_owned(), "::1".to_owned()],
            characters: BTreeMap::new(),
        }
    }
}

/// `[livelink.characters.NAME]`: one character's subject and where it goes.
#[derive(Debug, Clone, PartialEq, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct LiveLinkCharacter {
    /// The Live Link subject name; `None`: the character's name.
    pub subject: Option<String>,
    /// Where to send, `host:port` each ([`OscTarget`]; Unreal listens on
    /// [`LIVELINK_DEFAULT_PORT`]).
    pub targets: Vec<String>,
    /// The device id sent (a UUID, `8-4-4-4-12` hex digits); `None`:
    /// [`default_device_id`] of the subject.
    pub device_id: Option<String>,
}

impl LiveLinkCharacter {
    /// The subject name for character `name`.
    pub fn subject_or<'a>(&'a self, name: &'a str) -> &'a str {
        self.subject.as_deref().unwrap_or(name)
    }

    /// The device id sent for character `name`: as configured (upper case), else derived
    /// from the subject.
    pub fn device_id_or(&self, name: &str) -> String {
        match &self.device_id {
            Some(id) => id.to_ascii_uppercase(),
            None => default_device_id(self.subject_or(name)),
        }
    }
}

/// The device id of a subject with none configured: a UUID (version 8, RFC 9562's
/// custom layout) whose 122 free bits are the FNV-1a 128-bit hash of
/// `mouthpiece livelink ` and the subject name, in upper case as iOS writes UUIDs. The same
/// subject gets the same id on every start and every booth.
pub fn default_device_id(subject: &str) -> String {
    const OFFSET: u128 = 0x6c62_272e_07bb_0142_62b8_2175_6295_c58d;
    const PRIME: u128 = 0x0000_0000_0100_0000_0000_0000_0000_013b;
    let mut hash = OFFSET;
    for byte in b"mouthpiece livelink ".iter().chain(subject.as_bytes()) {
        hash ^= u128::from(*byte);
        hash = hash.wrapping_mul(PRIME);
    }
    // Version 8 in bits 48..52, variant 0b10 in bits 64..66 (counted from the left).
    let mut bytes = hash.to_be_bytes();
    bytes[6] = (bytes[6] & 0x0f) | 0x80;
    bytes[8] = (bytes[8] & 0x3f) | 0x80;
    let hex: String = bytes.iter().map(|b| format!("{b:02X}")).collect();
    format!(
        "{}-{}-{}-{}-{}",
        &hex[0..8],
        &hex[8..12],
        &hex[12..16],
        &hex[16..20],
        &hex[20..32]
    )
}

/// Whether `s` is a UUID in its text form: 36 characters, hex digits in groups of 8, 4, 4,
/// 4 and 12 separated by `-`.
pub fn is_uuid(s: &str) -> bool {
    s.len() == 36
        && s.char_indices().all(|(i, c)| match i {
            8 | 13 | 18 | 23 => c == '-',
            _ => c.is_ascii_hexdigit(),
        })
}

impl LiveLinkConfig {
    /// The control address, parsed (a loaded config's parses).
    pub fn control_addr(&self) -> Option<SocketAddr> {
        self.control.as_deref().and_then(|c| c.parse().ok())
    }

    /// The allowed source addresses, parsed (a loaded config's all parse). An IPv4 address
    /// also allows its IPv4-mapped IPv6 form.
    pub fn allowed(&self) -> Vec<IpAddr> {
        self.allow.iter().filter_map(|a| a.parse().ok()).collect()
    }

    /// Every target as its key in the file, its text and its character: by character name,
    /// each character's in order.
    pub fn all_targets(&self) -> Vec<(String, &str, &str)> {
        self.characters
            .iter()
            .flat_map(|(name, c)| {
                c.targets.iter().enumerate().map(move |(i, t)| {
                    (
                        format!("livelink.characters.{name}.targets[{i}]"),
                        t.as_str(),
                        name.as_str(),
                    )
                })
            })
            .collect()
    }

    /// One line for the configuration summary.
    pub fn summary(&self) -> String {
        let mut parts = Vec::new();
        if self.characters.values().any(|c| !c.targets.is_empty()) {
            let each: Vec<String> = self
                .characters
                .iter()
                .filter(|(_, c)| !c.targets.is_empty())
                .map(|(name, c)| format!("{} -> {}", c.subject_or(name), c.targets.join(" ")))
                .collect();
            let state = if self.enabled { "" } else { " (off)" };
            parts.push(format!("{}{state}", each.join(", ")));
        } else {
            parts.push("no targets".to_owned());
        }
        if let Some(control) = &self.control {
            parts.push(format!("control on {control}"));
        }
        parts.join(", ")
    }

    pub(crate) fn validate(
        &self,
        fail: &dyn Fn(&str, String) -> ConfigError,
    ) -> Result<(), ConfigError> {
        if let Some(control) = &self.control {
            if control.parse::<SocketAddr>().is_err() {
                return Err(fail(
                    "livelink.control",
                    format!(
                        "expected an IP address and a port (e.g. \"127.0.0.1:8000\", \"[::1]:8000\"), got {}",
                        quote_excerpt(control)
                    ),
                ));
            }
        }
        if self.allow.len() > MAX_LIVELINK_ALLOW {
            return Err(fail(
                "livelink.allow",
                format!(
                    "expected at most {MAX_LIVELINK_ALLOW} addresses, got {}",
                    self.allow.len()
                ),
            ));
        }
        for (i, a) in self.allow.iter().enumerate() {
            if a.parse::<IpAddr>().is_err() {
                return Err(fail(
                    &format!("livelink.allow[{i}]"),
                    format!(
                        "expected an IP address (e.g. \"127.0.0.1\", \"::1\"), got {}",
                        quote_excerpt(a)
                    ),
                ));
            }
        }
        let all = self.all_targets();
        if all.len() > MAX_LIVELINK_TARGETS {
            return Err(fail(
                "livelink.characters",
                format!(
                    "expected at most {MAX_LIVELINK_TARGETS} targets over all characters, got {}",
                    all.len()
                ),
            ));
        }
        for (name, c) in &self.characters {
            let key = format!("livelink.characters.{name}");
            if name.is_empty() {
                return Err(fail(
                    "livelink.characters",
                    "expected a character's name, got \"\"".into(),
                ));
            }
            if let Some(subject) = &c.subject {
                if subject.is_empty() || subject.len() > MAX_SUBJECT_BYTES {
                    return Err(fail(
                        &format!("{key}.subject"),
                        format!(
                            "expected a name of 1 to {MAX_SUBJECT_BYTES} bytes, got {}",
                            quote_excerpt(subject)
                        ),
                    ));
                }
                if subject.chars().any(char::is_control) {
                    return Err(fail(
                        &format!("{key}.subject"),
                        format!(
                            "expected a name without control characters, got {}",
                            quote_excerpt(subject)
                        ),
                    ));
                }
            } else if name.len() > MAX_SUBJECT_BYTES {
                return Err(fail(
                    &format!("{key}.subject"),
                    format!("the character's name is longer than {MAX_SUBJECT_BYTES} bytes: set a shorter subject"),
                ));
            }
            if let Some(id) = &c.device_id {
                if !is_uuid(id) {
                    return Err(fail(
                        &format!("{key}.device_id"),
                        format!(
                            "expected a UUID (e.g. \"0B2C5E4F-6A7D-4E8F-9A0B-1C2D3E4F5A6B\"), got {}",
                            quote_excerpt(id)
                        ),
                    ));
                }
            }
            let mut seen: Vec<OscTarget> = Vec::new();
            for (i, text) in c.targets.iter().enumerate() {
                let key = format!("{key}.targets[{i}]");
                let target = text.parse::<OscTarget>().map_err(|e| fail(&key, e))?;
                if seen.contains(&target) {
                    return Err(fail(&key, format!("{target} is listed twice")));
                }
                seen.push(target);
            }
        }
        Ok(())
    }
}

/// Whether a control packet from `source` is taken: its address is in `allowed` (an IPv4
/// address also matches its IPv4-mapped IPv6 form, as a dual-stack socket reports it).
pub fn source_allowed(allowed: &[IpAddr], source: IpAddr) -> bool {
    let source = match source {
        IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or(source, IpAddr::V4),
        v4 => v4,
    };
    allowed.contains(&source)
}
