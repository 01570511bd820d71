//! The server's and the timecode's settings from a configuration: leaf functions the checks
//! and the daemon both use.

use mouthpiece_config::Config;
use mouthpiece_server::{Limits, ServerConfig, TimecodeRate, TlsFiles, Token};

use crate::error::CheckError;

/// The server's settings from the config (tokens checked for the server's rules).
pub fn server_config(config: &Config) -> Result<ServerConfig, CheckError> {
    let token = |key: &str,
                 secret: Option<&mouthpiece_config::Secret>|
     -> Result<Option<Token>, CheckError> {
        secret
            .map(|s| Token::new(s.expose()))
            .transpose()
            .map_err(|e| CheckError::Invalid {
                location: config.locate(key),
                message: e.to_string(),
            })
    };
    Ok(ServerConfig {
        name: "mouthpiece".into(),
        read_token: token("server.read_token", config.server.tokens.read.as_ref())?,
        control_token: token(
            "server.control_token",
            config.server.tokens.control.as_ref(),
        )?,
        allowed_origins: config.server.allowed_origins.clone(),
        allowed_hosts: config.server.allowed_hosts.clone(),
        limits: Limits {
            max_clients: config.server.max_clients as usize,
            ..Limits::default()
        },
        tls: match (&config.server.tls_cert, &config.server.tls_key) {
            (Some(cert), Some(key)) => Some(TlsFiles {
                cert: cert.clone(),
                key: key.clone(),
            }),
            _ => None,
        },
    })
}

pub fn timecode_rate(config: &Config) -> Result<TimecodeRate, CheckError> {
    config
        .timecode
        .rate
        .0
        .parse::<TimecodeRate>()
        .map_err(|e| CheckError::Invalid {
            location: config.locate("timecode.rate"),
            message: e.to_string(),
        })
}
