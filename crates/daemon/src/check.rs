//! Checks of a loaded [`Config`] that need more than the config crate knows: the log
//! filter's syntax, the character files, the `[detect]`, `[track]` and `[retarget]` sections. Run at start, on reload and
//! by `mouthpiece check-config`.

use mouthpiece_config::{Config, Location};

pub use crate::error::CheckError;

/// Everything a config must satisfy before the daemon uses it.
pub fn check(config: &Config) -> Result<(), CheckError> {
    if let Err(message) = crate::logging::check_level(&config.logging.level) {
        return Err(CheckError::Invalid {
            location: location(config, "logging.level"),
            message,
        });
    }
    // Characters, `[detect]` (colour ranges) and `[track]`, as the pipeline will load them.
    crate::live::setup(config)?;
    crate::capture::check_spec(config)?;
    crate::hardening::check_server(config)?;
    crate::settings::timecode_rate(config)?;
    // `[osc]`: the character exists, every target resolves.
    crate::osc::settings(config)?;
    // `[livelink]`: the characters exist, every target resolves.
    crate::livelink::settings(config, crate::settings::timecode_rate(config)?)?;
    // `[ifacialmocap]`: the character exists.
    crate::ifacialmocap::settings(config)?;
    let listen = config.server.listen.0;
    if !listen.ip().is_loopback()
        && (config.server.tokens.read.is_none() || config.server.tokens.control.is_none())
    {
        return Err(CheckError::Invalid {
            location: location(config, "server.listen"),
            message: format!(
                "{listen} is reachable from the network: set server.read_token and server.control_token"
            ),
        });
    }
    Ok(())
}

/// The file and key, for errors found after parsing (the line is looked up when the file
/// has one).
pub(crate) fn location(config: &Config, key: &str) -> Location {
    config.locate(key)
}
