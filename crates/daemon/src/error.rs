//! Why a configuration that parsed is still unusable. A leaf module: the checks, the live
//! pipeline's set-up and the daemon all report through it.

use mouthpiece_config::{ConfigError, Location};

/// Why a config that parsed is still unusable.
#[derive(Debug, thiserror::Error)]
pub enum CheckError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The characters, the pipeline's tables or the speech settings.
    #[error(transparent)]
    Setup(Box<mouthpiece_pipeline::setup::SetupError>),
    #[error("{location}: {message}")]
    Invalid { location: Location, message: String },
}

impl From<mouthpiece_pipeline::setup::SetupError> for CheckError {
    fn from(e: mouthpiece_pipeline::setup::SetupError) -> Self {
        CheckError::Setup(Box::new(e))
    }
}
