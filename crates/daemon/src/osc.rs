//! The daemon's side of the OSC/VMC output (`mouthpiece-osc`): `[osc]` checked against the
//! configured characters and its targets resolved, at start and on every reload.

use std::net::{SocketAddr, ToSocketAddrs};

use mouthpiece_config::Config;
pub use mouthpiece_osc::{OscOutput, OscSettings, Target, VmcFrame};

use crate::error::CheckError;

/// Checks `[osc]` against the configured characters and resolves every target (a name is
/// resolved here, at start and on each reload; an IPv4 address is preferred when a name has
/// both kinds). Errors name the key and its line.
pub fn settings(config: &Config) -> Result<OscSettings, CheckError> {
    let invalid = |key: &str, message: String| CheckError::Invalid {
        location: config.locate(key),
        message,
    };
    let characters = crate::characters::load(config)?;
    let character = match &config.osc.character {
        Some(name) => characters.iter().find(|c| &c.name == name).ok_or_else(|| {
            let known: Vec<&str> = characters.iter().map(|c| c.name.as_str()).collect();
            invalid(
                "osc.character",
                format!(
                    "no configured character is named {} (configured: {})",
                    mouthpiece_config::quote_excerpt(name),
                    known.join(", ")
                ),
            )
        })?,
        None => characters
            .first()
            .ok_or_else(|| invalid("characters.files", "no character configured".into()))?,
    };
    let mut targets = Vec::new();
    for (i, text) in config.osc.targets.iter().enumerate() {
        let key = format!("osc.targets[{i}]");
        let target: mouthpiece_config::OscTarget = text.parse().map_err(|e| invalid(&key, e))?;
        let addrs: Vec<SocketAddr> = (target.host.as_str(), target.port)
            .to_socket_addrs()
            .map_err(|e| invalid(&key, format!("cannot resolve {}: {e}", target.host)))?
            .collect();
        let addr = addrs
            .iter()
            .find(|a| a.is_ipv4())
            .or(addrs.first())
            .copied()
            .ok_or_else(|| invalid(&key, format!("{} resolves to no address", target.host)))?;
        targets.push(Target {
            label: text.clone(),
            addr,
        });
    }
    Ok(OscSettings {
        targets,
        character: character.name.clone(),
        head: config.osc.head,
        eyes: config.osc.eyes,
        names: config.osc.names,
        visemes: config.osc.visemes,
        axes: character.frame.axes,
    })
}
