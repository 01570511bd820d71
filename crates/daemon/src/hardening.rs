//! Checks that make `check-config` and a reload refuse what serving would refuse.

use std::net::SocketAddr;

use mouthpiece_config::Config;

use crate::check::CheckError;

/// The server's settings from `config`, checked as the server will check them when it serves
/// on `config`'s listen address: limits within the hard caps, tokens where they are needed,
/// TLS files that load.
pub fn check_server(config: &Config) -> Result<mouthpiece_server::ServerConfig, CheckError> {
    let server = crate::settings::server_config(config)?;
    check_against(config, &server, config.server.listen.0)?;
    if let Some(files) = &server.tls {
        mouthpiece_server::check_tls(files).map_err(|e| CheckError::Invalid {
            location: config.locate("server.tls_cert"),
            message: crate::source::error_chain(&e),
        })?;
    }
    Ok(server)
}

/// `server` validated for the address it is (or will be) bound to.
pub fn check_against(
    config: &Config,
    server: &mouthpiece_server::ServerConfig,
    bound: SocketAddr,
) -> Result<(), CheckError> {
    server.validate(bound).map_err(|e| {
        let key = match &e {
            mouthpiece_server::ServerError::Config { key, .. } => format!("server.{key}"),
            _ => "server.listen".to_owned(),
        };
        let message = if bound == config.server.listen.0 {
            e.to_string()
        } else {
            format!("the running server is bound to {bound} (listen changes need a restart): {e}")
        };
        CheckError::Invalid {
            location: config.locate(&key),
            message,
        }
    })
}
