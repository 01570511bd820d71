//! The characters a configuration drives: its `[characters] files`, or the built-in human
//! and wolf (embedded in the binary with `include_str!`, so the embedded default works from
//! any working directory).

use mouthpiece_config::Config;
use mouthpiece_retarget::Character;

use crate::error::CheckError;

/// The built-in characters: the repository's `config/characters/` at build time.
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

/// Loads and validates every character, each error naming the config key and the file.
pub fn load(config: &Config) -> Result<Vec<Character>, CheckError> {
    let invalid = |key: &str, message: String| CheckError::Invalid {
        location: config.locate(key),
        message,
    };
    let mut characters = Vec::new();
    if config.characters.files.is_empty() {
        for (name, text) in BUILTIN {
            let character = Character::from_toml_str(text).map_err(|e| {
                invalid(
                    "characters.files",
                    format!("built-in {name}: {}", crate::source::error_chain(&e)),
                )
            })?;
            characters.push(character);
        }
    } else {
        for (i, path) in config.characters.files.iter().enumerate() {
            let key = format!("characters.files[{i}]");
            let text =
                mouthpiece_config::read_bounded(path, mouthpiece_config::MAX_CONFIG_FILE_BYTES)
                    .map_err(|e| {
                        invalid(
                            &key,
                            format!("cannot read character file {}: {e}", path.display()),
                        )
                    })?;
            let character = Character::from_toml_str(&text).map_err(|e| {
                invalid(
                    &key,
                    format!("{}: {}", path.display(), crate::source::error_chain(&e)),
                )
            })?;
            characters.push(character);
        }
    }
    let mut names: Vec<&str> = characters.iter().map(|c| c.name.as_str()).collect();
    names.sort_unstable();
    if let Some(w) = names.windows(2).find(|w| w[0] == w[1]) {
        return Err(invalid(
            "characters.files",
            format!("two characters are named {:?}", w[0]),
        ));
    }
    Ok(characters)
}
