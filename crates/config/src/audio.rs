//! `[audio]`: the booth's microphone, captured through ALSA (docs/daemon.md). Off when the
//! table is absent.

use super::*;

/// Lowest and highest sample rate accepted, Hz.
pub const AUDIO_RATES: std::ops::RangeInclusive<u32> = 8_000..=192_000;
/// Most interleaved channels accepted.
pub const MAX_AUDIO_CHANNELS: u32 = 32;
/// Bounds of `period_frames` (samples per channel per block).
pub const AUDIO_PERIOD_FRAMES: std::ops::RangeInclusive<u32> = 16..=65_536;
/// Most blocks `queue_blocks` may hold.
pub const MAX_AUDIO_QUEUE_BLOCKS: u32 = 10_000;

/// `[audio]`: where the sound comes from and in what format it is asked for.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AudioConfig {
    /// An ALSA PCM name (`default`, `hw:1,0`, `plughw:CARD=USB,DEV=0`, or one from an
    /// asound.conf).
    pub device: String,
    /// Samples per second asked for; the device may agree to another (read back and shown).
    pub sample_rate: u32,
    /// Interleaved channels asked for.
    pub channels: u32,
    /// Sample frames per block (the ALSA period).
    pub period_frames: u32,
    /// Sample frames the device buffers (the ALSA buffer): how long the audio thread may be
    /// late before the device overruns.
    pub buffer_frames: u32,
    /// Blocks held for each consumer (takes, the live speech analyser); beyond this the
    /// oldest is dropped and counted.
    pub queue_blocks: u32,
    /// Let `device` use ALSA's `file` plugin (or `tee`, its alias in alsa.conf), a pipe to a
    /// command (`|`) or an inline definition (`{ … }`) written in the device string itself.
    /// Off: such a string, which can write any file or run any command as the daemon's user,
    /// is refused ([`check_alsa_device`]). A PCM of that kind named in an asound.conf is
    /// always allowed (the configuration files of ALSA are trusted like this one).
    pub allow_file_plugin: bool,
    /// Live lip-sync profiles learned from this booth's own voice (`mouthpiece lipsync
    /// learn`) instead of the shipped ones; relative to the config file.
    pub speech_profiles: Option<PathBuf>,
}

impl Default for AudioConfig {
    fn default() -> Self {
        AudioConfig {
            device: "default".to_owned(),
            sample_rate: 48_000,
            channels: 1,
            period_frames: 480,
            buffer_frames: 4_800,
            queue_blocks: 200,
            allow_file_plugin: false,
            speech_profiles: None,
        }
    }
}

/// The ALSA PCM types that write a file or run a command: `file` (its `file` may be
/// `|command`), and `tee`, alsa.conf's shorthand for it; `ladspa` loads a shared library
/// from a path.
pub const ALSA_WRITING_PLUGINS: [&str; 3] = ["file", "tee", "ladspa"];

/// Checks an ALSA PCM name (from `[audio] device` or `record --audio`) before alsa-lib sees
/// it: 1 to 256 bytes without control characters and, unless `allow_file_plugin`, without
/// what lets the string itself write a file or run a command: a pipe (`|`), an inline
/// definition (`{`), or one of [`ALSA_WRITING_PLUGINS`] as the PCM or inside its arguments
/// (`file:'|cmd'`, `plug:'tee:hw,/x'`). The device name is trusted configuration otherwise:
/// a PCM defined in an asound.conf is opened whatever its type.
pub fn check_alsa_device(device: &str, allow_file_plugin: bool) -> Result<(), String> {
    if device.is_empty() || device.len() > 256 || device.chars().any(char::is_control) {
        return Err(format!(
            "expected an ALSA PCM name (1 to 256 bytes without control characters, e.g. \"default\" or \"hw:1,0\"), got {}",
            quote_excerpt(device)
        ));
    }
    if allow_file_plugin {
        return Ok(());
    }
    let refused = |what: &str| {
        Err(format!(
            "{} {what}, which can write a file or run a command: refused (name a PCM defined in an asound.conf instead)",
            quote_excerpt(device)
        ))
    };
    if device.contains('|') {
        return refused("holds a pipe (`|`)");
    }
    if device.contains('{') {
        return refused("holds an inline definition (`{`)");
    }
    let separators = |c: char| matches!(c, ':' | '=' | ',' | '\'' | '"' | ' ' | ';');
    if let Some(plugin) = device
        .split(separators)
        .find(|token| ALSA_WRITING_PLUGINS.contains(token))
    {
        return refused(&format!("uses ALSA's `{plugin}` plugin"));
    }
    Ok(())
}

impl AudioConfig {
    /// The checks serde cannot express: `(key, message)` of the first value out of range.
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        check_alsa_device(&self.device, self.allow_file_plugin).map_err(|message| {
            let hint = if message.ends_with("instead)") {
                ", or set audio.allow_file_plugin = true"
            } else {
                ""
            };
            ("audio.device", format!("{message}{hint}"))
        })?;
        if !AUDIO_RATES.contains(&self.sample_rate) {
            return Err((
                "audio.sample_rate",
                format!(
                    "expected {} to {} Hz, got {}",
                    AUDIO_RATES.start(),
                    AUDIO_RATES.end(),
                    self.sample_rate
                ),
            ));
        }
        if self.channels == 0 || self.channels > MAX_AUDIO_CHANNELS {
            return Err((
                "audio.channels",
                format!(
                    "expected 1 to {MAX_AUDIO_CHANNELS} channels, got {}",
                    self.channels
                ),
            ));
        }
        if !AUDIO_PERIOD_FRAMES.contains(&self.period_frames) {
            return Err((
                "audio.period_frames",
                format!(
                    "expected {} to {} sample frames, got {}",
                    AUDIO_PERIOD_FRAMES.start(),
                    AUDIO_PERIOD_FRAMES.end(),
                    self.period_frames
                ),
            ));
        }
        let max_buffer = 16 * AUDIO_PERIOD_FRAMES.end();
        if self.buffer_frames < 2 * self.period_frames || self.buffer_frames > max_buffer {
            return Err((
                "audio.buffer_frames",
                format!(
                    "expected at least two periods (2 × audio.period_frames = {}) and at most {max_buffer} sample frames, got {}",
                    2 * self.period_frames,
                    self.buffer_frames
                ),
            ));
        }
        if self.queue_blocks == 0 || self.queue_blocks > MAX_AUDIO_QUEUE_BLOCKS {
            return Err((
                "audio.queue_blocks",
                format!(
                    "expected 1 to {MAX_AUDIO_QUEUE_BLOCKS} blocks, got {}",
                    self.queue_blocks
                ),
            ));
        }
        Ok(())
    }
}
