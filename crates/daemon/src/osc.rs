//! The daemon's side of the OSC/VMC output (`mouthpiece-osc`): `[osc]` checked against the
//! configured characters and its targets resolved, at start and on every reload. `targets` get
//! `character` (the first configured by default); `[osc.characters]` names more characters,
//! each with its own targets.

use mouthpiece_config::Config;
pub use mouthpiece_osc::{OscCharacter, OscOutput, OscSettings, Target, VmcFrame};

use crate::error::CheckError;

/// Checks `[osc]` against the configured characters and resolves every target (a name is
/// resolved here, at start and on each reload; an IPv4 address is preferred when a name has
/// both kinds). Errors name the key and its line.
pub fn settings(config: &Config) -> Result<OscSettings, CheckError> {
    let invalid = |key: &str, message: String| CheckError::Invalid {
        location: config.locate(key),
        message,
    };
    let characters = mouthpiece_pipeline::setup::characters(config)?;
    let find = |name: &str, key: &str| {
        characters.iter().find(|c| c.name == name).ok_or_else(|| {
            let known: Vec<&str> = characters.iter().map(|c| c.name.as_str()).collect();
            invalid(
                key,
                format!(
                    "no configured character is named {} (configured: {})",
                    mouthpiece_config::quote_excerpt(name),
                    known.join(", ")
                ),
            )
        })
    };
    let default = match &config.osc.character {
        Some(name) => find(name, "osc.character")?,
        None => characters
            .first()
            .ok_or_else(|| invalid("characters.files", "no character configured".into()))?,
    };
    let mut sent: Vec<OscCharacter> = Vec::new();
    let mut targets = Vec::new();
    for (key, text, character) in config.osc.all_targets() {
        let character = match character {
            Some(name) => find(name, &key)?,
            None => default,
        };
        let index = match sent.iter().position(|c| c.name == character.name) {
            Some(i) => i,
            None if sent.len() < mouthpiece_osc::MAX_CHARACTERS => {
                sent.push(OscCharacter {
                    name: character.name.clone(),
                    axes: character.frame.axes,
                });
                sent.len() - 1
            }
            None => {
                return Err(invalid(
                    &key,
                    format!(
                        "at most {} characters go out over OSC",
                        mouthpiece_osc::MAX_CHARACTERS
                    ),
                ))
            }
        };
        let target: mouthpiece_config::OscTarget = text.parse().map_err(|e| invalid(&key, e))?;
        let addr = target.resolve().map_err(|e| invalid(&key, e))?;
        targets.push(Target {
            label: text.to_owned(),
            addr,
            character: index,
        });
    }
    Ok(OscSettings {
        targets,
        characters: sent,
        head: config.osc.head,
        eyes: config.osc.eyes,
        names: config.osc.names,
        visemes: config.osc.visemes,
    })
}
