//! `[nats]`: the booth on a NATS server (docs/nats.md). Off while `servers` is empty.
//!
//! Credentials (a password, a token, an NKey seed) come from the environment or a file like
//! the server's tokens ([`TokenRef`]), are read when the file is loaded and held as
//! [`Secret`]s; a `.creds` file is named, not read here. None of them is ever printed.

use super::*;

/// `[nats]` as written.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NatsConfig {
    /// `nats://host:port` (or `tls://`) each; several for a cluster. Empty: NATS is off.
    pub servers: Vec<String>,
    /// This booth's name, the second token of its subjects (`mouthpiece.<booth>.frame`).
    pub booth: Option<String>,
    /// The studio: takes go to the object store bucket `mouthpiece-takes-<studio>` and their
    /// metadata to the key-value bucket `mouthpiece-takes-<studio>-meta`.
    pub studio: String,
    /// Upload each closed take (and the folder's backlog) to the studio's object store.
    pub upload_takes: bool,
    /// User name for user/password authentication (with `password`).
    pub user: Option<String>,
    /// The password, from `env`, `file` or `value`.
    pub password: Option<TokenRef>,
    /// A token (the server's `authorization { token }`), from `env`, `file` or `value`.
    pub token: Option<TokenRef>,
    /// An NKey seed (`SU...`), from `env`, `file` or `value`.
    pub nkey: Option<TokenRef>,
    /// A `.creds` file (JWT and NKey seed) for decentralised authentication.
    pub credentials_file: Option<PathBuf>,
    /// CA certificate(s) (PEM) to verify the server with; also turns TLS on.
    pub tls_ca: Option<PathBuf>,
    /// Client certificate (PEM) for mutual TLS, with `tls_key`.
    pub tls_cert: Option<PathBuf>,
    /// The client certificate's private key (PEM).
    pub tls_key: Option<PathBuf>,
    /// Frames waiting for the connection before the oldest is dropped.
    pub queue_frames: u32,
    /// Publish the binary frame layout on `.frame.bin` too.
    pub binary: bool,
    /// Publish each character's rig on `.rig.<character>`.
    pub rig: bool,
    /// Longest wait between reconnection attempts, seconds.
    pub reconnect_max_s: PositiveSeconds,
    /// Credentials read at load time (never printed).
    #[serde(skip)]
    pub secrets: NatsSecrets,
}

impl Default for NatsConfig {
    fn default() -> Self {
        NatsConfig {
            servers: Vec::new(),
            booth: None,
            studio: "studio".to_owned(),
            upload_takes: true,
            user: None,
            password: None,
            token: None,
            nkey: None,
            credentials_file: None,
            tls_ca: None,
            tls_cert: None,
            tls_key: None,
            queue_frames: 256,
            binary: true,
            rig: true,
            reconnect_max_s: PositiveSeconds(5.0),
            secrets: NatsSecrets::default(),
        }
    }
}

/// The `[nats]` credentials as read at load time. `Debug` shows only which are set.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct NatsSecrets {
    pub password: Option<Secret>,
    pub token: Option<Secret>,
    pub nkey: Option<Secret>,
}

/// Most entries of `[nats] servers`.
pub const MAX_NATS_SERVERS: usize = 32;
/// Most frames in `[nats] queue_frames`.
pub const MAX_NATS_QUEUE_FRAMES: u32 = 4096;

/// Whether `name` may be one token of a NATS subject and a bucket or object name: ASCII
/// letters, digits, `-` and `_`, 1 to 64 characters (no `.`, `*`, `>` or spaces).
pub fn subject_safe(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= 64
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
}

impl NatsConfig {
    /// Whether the booth goes on NATS.
    pub fn enabled(&self) -> bool {
        !self.servers.is_empty()
    }

    /// Checks the section; `fail(key, message)` makes the error with the key's line.
    pub(crate) fn validate(
        &self,
        fail: &dyn Fn(&str, String) -> ConfigError,
    ) -> Result<(), ConfigError> {
        if self.servers.len() > MAX_NATS_SERVERS {
            return Err(fail(
                "nats.servers",
                format!(
                    "expected at most {MAX_NATS_SERVERS} servers, got {}",
                    self.servers.len()
                ),
            ));
        }
        for (i, server) in self.servers.iter().enumerate() {
            check_server_url(server).map_err(|m| fail(&format!("nats.servers[{i}]"), m))?;
        }
        if let Some(booth) = &self.booth {
            if !subject_safe(booth) {
                return Err(fail(
                    "nats.booth",
                    format!(
                        "expected 1 to 64 letters, digits, '-' or '_' (it is a subject token), got {}",
                        quote_excerpt(booth)
                    ),
                ));
            }
        } else if self.enabled() {
            return Err(fail(
                "nats.servers",
                "expected nats.booth too: every booth on a NATS server needs its own name".into(),
            ));
        }
        if !subject_safe(&self.studio) {
            return Err(fail(
                "nats.studio",
                format!(
                    "expected 1 to 64 letters, digits, '-' or '_' (it names buckets), got {}",
                    quote_excerpt(&self.studio)
                ),
            ));
        }
        if self.queue_frames == 0 || self.queue_frames > MAX_NATS_QUEUE_FRAMES {
            return Err(fail(
                "nats.queue_frames",
                format!(
                    "expected 1 to {MAX_NATS_QUEUE_FRAMES} frames, got {}",
                    self.queue_frames
                ),
            ));
        }
        if self.reconnect_max_s.0 > 600.0 {
            return Err(fail(
                "nats.reconnect_max_s",
                format!(
                    "expected at most 600 seconds, got {}",
                    self.reconnect_max_s.0
                ),
            ));
        }
        for (key, token) in [
            ("nats.password", &self.password),
            ("nats.token", &self.token),
            ("nats.nkey", &self.nkey),
        ] {
            if let Some(token) = token {
                let set = [
                    token.env.is_some(),
                    token.file.is_some(),
                    token.value.is_some(),
                ];
                if set.iter().filter(|s| **s).count() != 1 {
                    return Err(fail(
                        key,
                        "expected exactly one of env, file or value".into(),
                    ));
                }
            }
        }
        if self.user.is_some() != self.password.is_some() {
            let (present, missing) = if self.user.is_some() {
                ("nats.user", "nats.password")
            } else {
                ("nats.password", "nats.user")
            };
            return Err(fail(
                present,
                format!("expected {missing} too: user/password authentication needs both"),
            ));
        }
        let kinds = [
            ("nats.user", self.user.is_some()),
            ("nats.token", self.token.is_some()),
            ("nats.nkey", self.nkey.is_some()),
            ("nats.credentials_file", self.credentials_file.is_some()),
        ];
        let set: Vec<&str> = kinds.iter().filter(|k| k.1).map(|k| k.0).collect();
        if set.len() > 1 {
            return Err(fail(
                set[1],
                format!(
                    "expected one way to authenticate, got {}",
                    set.join(" and ")
                ),
            ));
        }
        if self.tls_cert.is_some() != self.tls_key.is_some() {
            let (present, missing) = if self.tls_cert.is_some() {
                ("nats.tls_cert", "nats.tls_key")
            } else {
                ("nats.tls_key", "nats.tls_cert")
            };
            return Err(fail(
                present,
                format!("expected {missing} too: a client certificate needs its key"),
            ));
        }
        Ok(())
    }

    /// Resolves file paths against the config file's folder.
    pub(crate) fn resolve_paths(&mut self, join: &dyn Fn(&mut PathBuf)) {
        for path in [
            &mut self.credentials_file,
            &mut self.tls_ca,
            &mut self.tls_cert,
            &mut self.tls_key,
        ]
        .into_iter()
        .flatten()
        {
            join(path);
        }
        for token in [&mut self.password, &mut self.token, &mut self.nkey]
            .into_iter()
            .flatten()
        {
            if let Some(file) = &mut token.file {
                join(file);
            }
        }
    }

    /// One line for the config summary; never the credentials.
    pub fn summary(&self) -> String {
        if !self.enabled() {
            return "off".to_owned();
        }
        let auth = if self.user.is_some() {
            "user/password"
        } else if self.token.is_some() {
            "token"
        } else if self.nkey.is_some() {
            "nkey"
        } else if self.credentials_file.is_some() {
            "creds file"
        } else {
            "none"
        };
        format!(
            "booth {} on {} (studio {}, auth {auth}, tls {})",
            self.booth.as_deref().unwrap_or(""),
            self.servers.join(" "),
            self.studio,
            if self.tls_ca.is_some() || self.servers.iter().any(|s| s.starts_with("tls://")) {
                "on"
            } else {
                "off"
            }
        )
    }
}

/// `nats://host:port`, `tls://host:port` or `host:port`; credentials in the URL are refused
/// (they would show wherever the URL is logged: use `user`/`password` or `token`).
fn check_server_url(url: &str) -> Result<(), String> {
    // A NUL would cut the address short in the C-level resolver; other controls and spaces
    // are no part of a host name either.
    if url.chars().any(|c| c.is_control() || c.is_whitespace()) {
        return Err(format!(
            "expected a server URL without control characters or spaces, got {}",
            quote_excerpt(url)
        ));
    }
    let rest = match url.split_once("://") {
        Some(("nats" | "tls", rest)) => rest,
        Some((scheme, _)) => {
            return Err(format!(
                "expected nats:// or tls://, got {}://",
                quote_excerpt(scheme)
            ))
        }
        None => url,
    };
    if rest.contains('@') {
        return Err(
            "credentials in a server URL are refused (they would be logged): use nats.user and nats.password, or nats.token"
                .into(),
        );
    }
    let (host, port) = rest.rsplit_once(':').ok_or_else(|| {
        format!(
            "expected host:port (e.g. nats://127.0.0.1:4222), got {}",
            quote_excerpt(url)
        )
    })?;
    if host.is_empty() || host.contains(['/', ' ']) {
        return Err(format!("expected a host name, got {}", quote_excerpt(url)));
    }
    match port.parse::<u16>() {
        Ok(p) if p > 0 => Ok(()),
        _ => Err(format!(
            "expected a port from 1 to 65535, got {}",
            quote_excerpt(port)
        )),
    }
}
