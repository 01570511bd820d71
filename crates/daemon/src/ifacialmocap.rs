//! The daemon's side of the iFacialMocap output (`mouthpiece-ifacialmocap`): `[ifacialmocap]`
//! checked against the configured characters, at start and on every reload.

use mouthpiece_config::Config;
pub use mouthpiece_ifacialmocap::{IfmOutput, IfmSettings};
use mouthpiece_output::HeadAxes;

use crate::error::CheckError;

/// `[ifacialmocap]` resolved: `None` when it is off. The character must be configured (the
/// first configured one by default); errors name the key and its line.
pub fn settings(config: &Config) -> Result<Option<IfmSettings>, CheckError> {
    let section = &config.ifacialmocap;
    if !section.enabled {
        return Ok(None);
    }
    let invalid = |key: &str, message: String| CheckError::Invalid {
        location: config.locate(key),
        message,
    };
    let listen = section
        .listen()
        .map_err(|e| invalid("ifacialmocap.address", e))?;
    let characters = mouthpiece_pipeline::setup::characters(config)?;
    let character = match &section.character {
        Some(name) => characters.iter().find(|c| &c.name == name).ok_or_else(|| {
            let known: Vec<&str> = characters.iter().map(|c| c.name.as_str()).collect();
            invalid(
                "ifacialmocap.character",
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
    let m = character.frame.axes;
    let axes = HeadAxes::from_columns([
        [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
        [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
        [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
    ]);
    Ok(Some(IfmSettings {
        listen,
        // Checked to fit a port by the config crate.
        reply_port: u16::try_from(section.reply_port).unwrap_or(0),
        character: character.name.clone(),
        axes,
    }))
}

/// The output's counters in `/metrics` (the output's crate does not know the server's).
#[derive(Debug)]
pub struct IfmMetrics(pub std::sync::Arc<mouthpiece_ifacialmocap::IfmCounters>);

impl mouthpiece_server::MetricsSource for IfmMetrics {
    fn render_metrics(&self, out: &mut String) {
        self.0.render_metrics(out);
    }
}
