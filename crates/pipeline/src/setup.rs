//! The live pipeline's set-up from a daemon configuration: the characters (`[characters]
//! files`, or the built-in human and wolf), the `[detect]`, `[track]`, `[retarget]` and `[rig]`
//! tables, each character's speech settings (`[characters.settings.NAME]`) and the booth's
//! live lip-sync profiles (`[audio] speech_profiles`). Every error names the file, line and
//! key.

use mouthpiece_config::{Config, ConfigError, Location, SpeechSetting};
use mouthpiece_retarget::Character;

use crate::handover::{HandoverSettings, SpeechMode};
use crate::speech::{load_profiles, LiveProfiles, ProfilesError};
use crate::PipelineConfig;

/// The built-in characters: the repository's `config/characters/` at build time (embedded,
/// so the embedded default configuration works from any working directory).
pub const BUILTIN: [(&str, &str); 2] = [
    (
        "config/characters/human.toml",
        include_str!("../../../config/characters/human.toml"),
    ),
    (
        "config/characters/wolf.toml",
        include_str!("../../../config/characters/wolf.toml"),
    ),
];

/// Everything a (re)load produces.
#[derive(Debug, Clone)]
pub struct Setup {
    pub characters: Vec<Character>,
    pub config: PipelineConfig,
    /// Per character (same order): whether speech may drive its mouth.
    pub speech: Vec<HandoverSettings>,
    /// `[audio] speech_profiles`: the booth's own live lip-sync profiles (else the shipped).
    pub speech_profiles: Option<LiveProfiles>,
}

/// Why a configuration cannot set the live pipeline up.
#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("{location}: {message}")]
    Invalid { location: Location, message: String },
    /// A character file that cannot be read.
    #[error("{location}: cannot read character file {file}")]
    ReadCharacter {
        location: Location,
        file: String,
        #[source]
        source: std::io::Error,
    },
    /// A character file (or a built-in character) that is not a valid character.
    #[error("{location}: {file}")]
    Character {
        location: Location,
        file: String,
        #[source]
        source: Box<mouthpiece_retarget::Error>,
    },
    #[error("{location}")]
    Profiles {
        location: Location,
        #[source]
        source: Box<ProfilesError>,
    },
}

/// Loads and validates every character, each error naming the config key and the file.
pub fn characters(config: &Config) -> Result<Vec<Character>, SetupError> {
    let mut characters = Vec::new();
    if config.characters.files.is_empty() {
        for (name, text) in BUILTIN {
            let character =
                Character::from_toml_str(text).map_err(|source| SetupError::Character {
                    location: config.locate("characters.files"),
                    file: format!("built-in {name}"),
                    source: Box::new(source),
                })?;
            characters.push(character);
        }
    } else {
        for (i, path) in config.characters.files.iter().enumerate() {
            let location = || config.locate(&format!("characters.files[{i}]"));
            let file = path.display().to_string();
            let text =
                mouthpiece_config::read_bounded(path, mouthpiece_config::MAX_CONFIG_FILE_BYTES)
                    .map_err(|source| SetupError::ReadCharacter {
                        location: location(),
                        file: file.clone(),
                        source,
                    })?;
            let character =
                Character::from_toml_str(&text).map_err(|source| SetupError::Character {
                    location: location(),
                    file,
                    source: Box::new(source),
                })?;
            characters.push(character);
        }
    }
    let mut names: Vec<&str> = characters.iter().map(|c| c.name.as_str()).collect();
    names.sort_unstable();
    if let Some(w) = names.windows(2).find(|w| w[0] == w[1]) {
        return Err(SetupError::Invalid {
            location: config.locate("characters.files"),
            message: format!("two characters are named {:?}", w[0]),
        });
    }
    Ok(characters)
}

/// Loads and validates characters, `[detect]`, `[track]`, `[retarget]`, `[rig]` and the
/// characters' speech settings.
pub fn setup(config: &Config) -> Result<Setup, SetupError> {
    let pipeline = match config.text() {
        Some(text) => PipelineConfig::from_text(text)?,
        None => PipelineConfig::default(),
    };
    let invalid = |key: &str, message: String| SetupError::Invalid {
        location: config.locate(key),
        message,
    };
    let characters = characters(config)?;
    let layout = pipeline.track.layout();
    for (i, c) in characters.iter().enumerate() {
        if c.len() != layout.lip_dots {
            return Err(invalid(
                &format!("characters.files[{i}]"),
                format!(
                    "character {} has {} points but the performer wears {} lip dots",
                    c.name,
                    c.len(),
                    layout.lip_dots
                ),
            ));
        }
    }
    for name in config.characters.settings.keys() {
        if !characters.iter().any(|c| &c.name == name) {
            return Err(invalid(
                &format!(
                    "characters.settings.{}",
                    mouthpiece_config::key_segment(name)
                ),
                format!("no configured character is named {name:?}"),
            ));
        }
    }
    let speech = characters
        .iter()
        .map(|c| {
            let o = config
                .characters
                .settings
                .get(&c.name)
                .copied()
                .unwrap_or_default();
            HandoverSettings {
                mode: match o.speech {
                    SpeechSetting::Off => SpeechMode::Off,
                    SpeechSetting::Fallback => SpeechMode::Fallback,
                    SpeechSetting::Always => SpeechMode::Always,
                },
                hold_s: f64::from(o.speech_hold_ms) / 1e3,
                blend_s: f64::from(o.speech_blend_ms) / 1e3,
            }
        })
        .collect::<Vec<HandoverSettings>>();
    // No camera: speech is the only thing that can move a mouth.
    if config.source.spec.is_none() {
        if config.audio.is_none() {
            return Err(invalid(
                "source.spec",
                "spec = \"none\" (no camera) needs an [audio] table: speech is all that drives the characters".into(),
            ));
        }
        if let Some(c) = characters
            .iter()
            .zip(&speech)
            .find(|(_, s)| s.mode != SpeechMode::Always)
        {
            return Err(invalid(
                "source.spec",
                format!(
                    "spec = \"none\" (no camera) needs speech = \"always\" for every character; {:?} has not",
                    c.0.name
                ),
            ));
        }
    }
    let speech_profiles = match config
        .audio
        .as_ref()
        .and_then(|a| a.speech_profiles.as_ref())
    {
        Some(path) => Some(load_profiles(path).map_err(|source| SetupError::Profiles {
            location: config.locate("audio.speech_profiles"),
            source: Box::new(source),
        })?),
        None => None,
    };
    Ok(Setup {
        characters,
        config: pipeline,
        speech,
        speech_profiles,
    })
}
