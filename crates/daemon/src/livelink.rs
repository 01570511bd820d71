//! The daemon's side of Live Link Face (`mouthpiece-osc`'s `livelink` and `remote`):
//! `[livelink]` checked against the configured characters and its targets resolved, at start
//! and on every reload. The characters named in `[livelink.characters]` are sent; the first of
//! them (by name) is the one the remote control steers, and with none named it steers the
//! first configured character (an `/AddLiveLinkAddress` then starts its stream).

use mouthpiece_config::Config;
pub use mouthpiece_osc::livelink::{
    LiveLinkCharacter, LiveLinkOutput, LiveLinkSettings, LiveLinkTarget,
};
pub use mouthpiece_osc::remote::{LiveLinkRemote, RemoteSettings};
use mouthpiece_output::HeadAxes;
use mouthpiece_server::TimecodeRate;

use crate::error::CheckError;

/// Checks `[livelink]` against the configured characters and resolves every target (a name
/// is resolved here, at start and on each reload). Errors name the key and its line.
pub fn settings(config: &Config, rate: TimecodeRate) -> Result<LiveLinkSettings, CheckError> {
    let invalid = |key: &str, message: String| CheckError::Invalid {
        location: config.locate(key),
        message,
    };
    let characters = mouthpiece_pipeline::setup::characters(config)?;
    let livelink = &config.livelink;
    let mut sent: Vec<LiveLinkCharacter> = Vec::new();
    let mut targets = Vec::new();
    for (name, entry) in &livelink.characters {
        let key = format!("livelink.characters.{name}");
        let Some(character) = characters.iter().find(|c| &c.name == name) else {
            let known: Vec<&str> = characters.iter().map(|c| c.name.as_str()).collect();
            return Err(invalid(
                &key,
                format!(
                    "no configured character is named {} (configured: {})",
                    mouthpiece_config::quote_excerpt(name),
                    known.join(", ")
                ),
            ));
        };
        if sent.len() == mouthpiece_osc::MAX_CHARACTERS {
            return Err(invalid(
                &key,
                format!(
                    "at most {} characters go out over Live Link",
                    mouthpiece_osc::MAX_CHARACTERS
                ),
            ));
        }
        let subject = entry.subject_or(name).to_owned();
        if sent.iter().any(|c| c.subject == subject) {
            return Err(invalid(
                &format!("{key}.subject"),
                format!("the subject {subject:?} is sent for another character too"),
            ));
        }
        let index = sent.len();
        sent.push(LiveLinkCharacter {
            name: name.clone(),
            subject,
            device_id: entry.device_id_or(name),
            axes: head_axes(&character.frame.axes),
        });
        for (i, text) in entry.targets.iter().enumerate() {
            let key = format!("{key}.targets[{i}]");
            let target: mouthpiece_config::OscTarget =
                text.parse().map_err(|e| invalid(&key, e))?;
            let addr = target.resolve().map_err(|e| invalid(&key, e))?;
            targets.push(LiveLinkTarget {
                label: text.clone(),
                addr,
                character: index,
            });
        }
    }
    if sent.is_empty() {
        // Nothing configured: the remote control may still add a target for the first
        // character, as it would for an iPhone.
        if let Some(first) = characters.first() {
            sent.push(LiveLinkCharacter {
                name: first.name.clone(),
                subject: first.name.clone(),
                device_id: mouthpiece_config::default_device_id(&first.name),
                axes: head_axes(&first.frame.axes),
            });
        }
    }
    Ok(LiveLinkSettings {
        enabled: livelink.enabled,
        characters: sent,
        targets,
        rate,
    })
}

/// The remote control's settings, `None` when `[livelink] control` is not set.
pub fn remote_settings(config: &Config, rate: TimecodeRate) -> Option<RemoteSettings> {
    config.livelink.control_addr().map(|listen| RemoteSettings {
        listen,
        allowed: config.livelink.allowed(),
        rate,
    })
}

/// A character's head-frame axes (columns: left, up, forward) as the ARKit face takes them.
fn head_axes(axes: &nalgebra::Matrix3<f64>) -> HeadAxes {
    HeadAxes::from_columns(std::array::from_fn(|r| {
        std::array::from_fn(|c| axes[(r, c)])
    }))
}
