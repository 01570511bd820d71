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
    if config.source.spec.is_none() {
        return Ok(());
    }
    SourceSpec::parse(config.source.spec.as_str())
        .map(|_| ())
        .map_err(|e| CheckError::Invalid {
            location: config.locate("source.spec"),
            message: crate::source::error_chain(&e),
        })
}

/// How the audio thread runs for `config`: the `[audio]` device when configured, else the
/// sound of a `replay:` recording that has some, else `None` (no audio thread; `status`
/// says `off`).
pub fn audio_plan(config: &Config) -> Option<crate::audio::AudioPlan> {
    let backoff = crate::backoff::Backoff::new(
        config.source.retry_initial_s.duration(),
        config.source.retry_max_s.duration(),
    );
    let throttle = config.logging.throttle_s.duration();
    let Some(audio) = config.audio.as_ref() else {
        return replay_audio_plan(config, backoff, throttle);
    };
    let request = mouthpiece_capture::alsa::AlsaRequest {
        device: audio.device.clone(),
        sample_rate: audio.sample_rate,
        // Checked in the config: 1 to 32.
        channels: audio.channels as u16,
        period_frames: audio.period_frames,
        buffer_frames: audio.buffer_frames,
        stall_timeout: config.source.stall_timeout_s.duration(),
    };
    Some(crate::audio::AudioPlan {
        opener: Box::new(move || {
            mouthpiece_capture::alsa::AlsaSource::open(&request)
                .map(|s| Box::new(s) as Box<dyn mouthpiece_frame::AudioSource>)
        }),
        device: audio.device.clone(),
        state_when_up: mouthpiece_server::AudioState::Live,
        backoff,
        throttle,
    })
}

/// The sound of a `replay:` recording that has some (`/audio`), played into the microphone's
/// path, paced with the recording's frames.
fn replay_audio_plan(
    config: &Config,
    backoff: crate::backoff::Backoff,
    throttle: Duration,
) -> Option<crate::audio::AudioPlan> {
    let Ok(SourceSpec::Replay(replay)) = SourceSpec::parse(config.source.spec.as_str()) else {
        return None;
    };
    let is_mcap = replay
        .path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"));
    if !is_mcap || !mouthpiece_recording::AudioReader::has_audio(&replay.path).unwrap_or(false) {
        return None;
    }
    let device = SourceSpec::Replay(replay.clone()).to_string();
    tracing::info!(%device, "the replayed recording has sound: it plays as the microphone");
    Some(crate::audio::AudioPlan {
        opener: Box::new(move || {
            mouthpiece_capture::mcap_audio::McapAudioReplay::open(&replay)
                .map(|s| Box::new(s) as Box<dyn mouthpiece_frame::AudioSource>)
        }),
        device,
        state_when_up: mouthpiece_server::AudioState::Replay,
        backoff,
        throttle,
    })
}
