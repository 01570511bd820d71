//! What the daemon runs, built from a configuration: the processor at start, a validated
//! reload for it on every SIGHUP, and the source's opener. The daemon is generic over it; the
//! real one is [`crate::live::LiveFactory`].

use std::time::Duration;

use mouthpiece_config::Config;

use crate::error::CheckError;
use crate::pipeline::Processor;
use crate::source::Opener;

/// Builds what the daemon runs from a configuration; called at start and (for the reload
/// payload) on every SIGHUP.
pub trait Factory: Send + Sync + 'static {
    type Processor: Processor + 'static;
    /// The processor for `config`.
    fn processor(&self, config: &Config) -> Result<Self::Processor, CheckError>;
    /// A validated reload for a running processor (characters, colour ranges, settings).
    fn reload(&self, config: &Config)
        -> Result<<Self::Processor as Processor>::Reload, CheckError>;
    /// Opens the configured source (called again after every loss); a live source that
    /// delivers nothing for `stall_timeout` is reported lost.
    fn opener(&self, spec: &str, stall_timeout: Duration) -> Opener;
}
