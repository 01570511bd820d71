//! Sources come from the capture crate (`replay:`, `openni2:`, `v4l2:`).

use std::time::Duration;

use mouthpiece_capture::{open_source, CaptureConfig, SourceSpec};
use mouthpiece_config::Config;

use crate::error::CheckError;
use crate::source::Opener;

/// Opens `spec` again on every call (the source thread calls it after each loss).
pub fn opener(spec: &str, stall_timeout: Duration) -> Opener {
    let spec = spec.to_owned();
    let config = CaptureConfig {
        stall_timeout,
        ..CaptureConfig::default()
    };
    Box::new(move || open_source(&spec, &config))
}

/// The source spec parses (the file or device may still be absent: that is retried).
pub fn check_spec(config: &Config) -> Result<(), CheckError> {
    SourceSpec::parse(config.source.spec.as_str())
        .map(|_| ())
        .map_err(|e| CheckError::Invalid {
            location: config.locate("source.spec"),
            message: crate::source::error_chain(&e),
        })
}
