//! `mouthpiece record`: any source to an MCAP session or an `.oni`: an OpenNI2 source
//! (camera, Dummy or `.oni` replay) through OpenNI2's own recorder, any other through the
//! plain-Rust `.oni` writer.
//!
//! Both run on the caller's thread: pull a pair from the source, write it (MCAP) or let
//! OpenNI2's recorder take it from the stream (`.oni`), until the time limit (device time),
//! the end of a replay, or the stop flag (Ctrl-C). A lost source ends the recording with a
//! readable file and the error.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use mouthpiece_frame::{Frame, FrameSource, SourceError};

use crate::spec::SourceSpec;
use crate::CaptureConfig;

/// Why a recording failed.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error(transparent)]
    Source(#[from] SourceError),
    #[error("cannot write {path}")]
    Write {
        path: PathBuf,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("{path}: unknown output format (expected a .mcap or .oni file name)")]
    UnknownFormat { path: PathBuf },
    /// The source's frames hold what an `.oni` cannot (distortion, unregistered depth, …).
    #[error(transparent)]
    OniUnsupported(crate::oni_write::OniWriteError),
    #[error("{what} support is not built in")]
    NotBuilt { what: &'static str },
}

/// When to stop.
#[derive(Debug, Clone, Default)]
pub struct RecordLimits {
    /// Stop after this much device time.
    pub seconds: Option<f64>,
    /// Stop when set (Ctrl-C).
    pub stop: Arc<AtomicBool>,
}

/// What was recorded.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordSummary {
    pub frames: u64,
    /// Device time between the first and last frame, seconds.
    pub duration_s: f64,
    pub skipped: u64,
    /// `.oni` only: nodes that needed the cropping-record fix.
    pub oni_fixed_nodes: usize,
    /// The source was lost mid-recording; the file holds what came before.
    pub lost: Option<String>,
    /// The sound (`--audio`) stopped before the end: why (the file says where).
    pub sound_lost: Option<String>,
}

/// Output formats, from the file name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputFormat {
    Mcap,
    Oni,
}

impl OutputFormat {
    pub fn from_path(path: &Path) -> Result<OutputFormat, RecordError> {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("mcap") => Ok(OutputFormat::Mcap),
            Some("oni") => Ok(OutputFormat::Oni),
            _ => Err(RecordError::UnknownFormat {
                path: path.to_path_buf(),
            }),
        }
    }
}

/// Pulls frames until a limit; `write` gets each one. Returns frames, duration, lost.
fn pump(
    source: &mut dyn FrameSource,
    limits: &RecordLimits,
    mut write: impl FnMut(&mut Frame) -> Result<(), RecordError>,
) -> Result<(u64, f64, Option<String>), RecordError> {
    let mut frames = 0u64;
    let mut first_ts = None;
    let mut last_ts = 0u64;
    loop {
        if limits.stop.load(Ordering::Relaxed) {
            tracing::info!("stop requested; closing the recording");
            break;
        }
        let mut frame = match source.next_frame() {
            Ok(Some(f)) => f,
            Ok(None) => break,
            Err(err @ SourceError::Disconnected { .. }) => {
                tracing::error!(%err, "source lost; the file keeps what was recorded");
                let duration = first_ts.map_or(0.0, |f| (last_ts - f) as f64 / 1e6);
                return Ok((frames, duration, Some(err.to_string())));
            }
            Err(err) => return Err(err.into()),
        };
        let first = *first_ts.get_or_insert(frame.device_ts_us);
        if let Some(limit) = limits.seconds {
            if frame.device_ts_us.saturating_sub(first) as f64 / 1e6 >= limit {
                break;
            }
        }
        last_ts = frame.device_ts_us;
        write(&mut frame)?;
        frames += 1;
    }
    Ok((
        frames,
        first_ts.map_or(0.0, |f| (last_ts - f) as f64 / 1e6),
        None,
    ))
}

/// Records `spec` to an MCAP session at `out`. `on_frame` sees every frame written.
#[cfg(feature = "mcap")]
pub fn record_mcap(
    spec: &SourceSpec,
    config: &CaptureConfig,
    out: &Path,
    options: mouthpiece_recording::WriterOptions,
    limits: &RecordLimits,
    on_frame: impl FnMut(&Frame),
) -> Result<RecordSummary, RecordError> {
    record_mcap_with_audio(spec, config, out, options, limits, None, on_frame)
}

/// [`record_mcap`] with the sound of `audio` (already open) read on its own thread and
/// written to `/audio`; frames and sound are then both stamped on the host's wall clock
/// (see [`crate::record_audio`]).
#[cfg(feature = "mcap")]
pub fn record_mcap_with_audio(
    spec: &SourceSpec,
    config: &CaptureConfig,
    out: &Path,
    options: mouthpiece_recording::WriterOptions,
    limits: &RecordLimits,
    audio: Option<Box<dyn mouthpiece_frame::AudioSource>>,
    on_frame: impl FnMut(&Frame),
) -> Result<RecordSummary, RecordError> {
    use crate::record_audio::AudioRecorder;
    let failed = |e: mouthpiece_recording::RecordingError| RecordError::Write {
        path: out.to_path_buf(),
        source: Box::new(e),
    };
    let source = crate::open_parsed(spec, config)?;
    let mut writer = mouthpiece_recording::SessionWriter::create(out, options).map_err(failed)?;
    let recorder = match audio {
        None => None,
        Some(audio) => {
            let mut recorder = AudioRecorder::start(audio).map_err(|e| RecordError::Write {
                path: out.to_path_buf(),
                source: Box::new(e),
            })?;
            recorder.begin(&mut writer).map_err(failed)?;
            Some(recorder)
        }
    };
    let with_sound = recorder.is_some();
    tracing::info!(source = %spec, file = %out.display(), with_sound, "recording MCAP session");
    let mut sound_lost = None;
    let mut summary = record_with(
        source,
        limits,
        (writer, recorder),
        |(writer, recorder), f| {
            if let Some(recorder) = recorder {
                // One clock for frames and sound: the wall clock at the frame's receipt.
                f.wall_clock = Some(std::time::SystemTime::now() - f.host_rx.elapsed());
                recorder.drain(writer).map_err(failed)?;
            }
            writer.write_frame(f).map(drop).map_err(failed)
        },
        |(mut writer, recorder)| {
            if let Some(recorder) = recorder {
                let written = recorder.finish(&mut writer);
                if let Ok(lost) = &written {
                    sound_lost.clone_from(lost);
                }
                written.map(drop).map_err(failed)?;
            }
            writer.finish().map(drop).map_err(failed)
        },
        on_frame,
    )?;
    summary.sound_lost = sound_lost;
    Ok(summary)
}

#[cfg(not(feature = "mcap"))]
pub fn record_mcap(
    _: &SourceSpec,
    _: &CaptureConfig,
    _: &Path,
    _: (),
    _: &RecordLimits,
    _: impl FnMut(&Frame),
) -> Result<RecordSummary, RecordError> {
    Err(RecordError::NotBuilt { what: "MCAP" })
}

/// Records an OpenNI2 source to `.oni` with OpenNI2's recorder, then adds the cropping and
/// field-of-view records OpenNI2's player needs where the source lacked them.
#[cfg(feature = "openni2")]
pub fn record_oni(
    spec: &SourceSpec,
    config: &CaptureConfig,
    out: &Path,
    limits: &RecordLimits,
    mut on_frame: impl FnMut(&Frame),
) -> Result<RecordSummary, RecordError> {
    let is_openni = match spec {
        SourceSpec::OpenNi2 { .. } => true,
        SourceSpec::Replay(r) => r
            .path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("oni")),
        SourceSpec::V4l2 { .. } => false,
    };
    if !is_openni {
        return record_oni_written(spec, config, out, limits, on_frame);
    }
    let (mut source, recording) = crate::openni::OpenNiSource::open_recording(spec, config, out)?;
    let result = pump(&mut source, limits, |f| {
        on_frame(f);
        Ok(())
    });
    let skipped = source.skipped();
    // The recorder first (it holds the streams), then the source's streams and device.
    let fixed = recording.finish();
    drop(source);
    let (frames, duration_s, lost) = result?;
    let fix = fixed?;
    Ok(RecordSummary {
        frames,
        duration_s,
        skipped,
        oni_fixed_nodes: fix.cropping_added.len().max(fix.fov_added.len()),
        lost,
        sound_lost: None,
    })
}

/// Any other source to `.oni`: its frames through the plain-Rust writer
/// ([`crate::oni_write`]), which refuses calibrations an `.oni` cannot hold.
#[cfg(feature = "openni2")]
fn record_oni_written(
    spec: &SourceSpec,
    config: &CaptureConfig,
    out: &Path,
    limits: &RecordLimits,
    on_frame: impl FnMut(&Frame),
) -> Result<RecordSummary, RecordError> {
    use crate::oni_write::{OniFrameWriter, OniWriteError};
    let source = crate::open_parsed(spec, config)?;
    // A replay reports no rate: the player paces by the frames' timestamps anyway.
    let fps = match source.info().fps {
        f if f > 0.0 => f,
        _ => 30.0,
    };
    tracing::info!(source = %spec, file = %out.display(), "recording .oni (plain-Rust writer)");
    let fail = |e: OniWriteError| {
        if e.is_bad_input() {
            RecordError::OniUnsupported(e)
        } else {
            RecordError::Write {
                path: out.to_path_buf(),
                source: Box::new(e),
            }
        }
    };
    record_with(
        source,
        limits,
        None::<OniFrameWriter>,
        |writer, f| {
            let w = match writer {
                Some(w) => w,
                None => {
                    writer.insert(OniFrameWriter::create(out, &f.calibration, fps).map_err(fail)?)
                }
            };
            w.write_frame(f).map_err(fail)
        },
        |writer| writer.map_or(Ok(()), |w| w.finish().map(drop).map_err(fail)),
        on_frame,
    )
}

/// Pulls frames from `source` into `sink` (`write`) until the limits, then closes the file
/// (`finish`) whatever happened, so it stays readable, and sums up.
#[cfg(any(feature = "mcap", feature = "openni2"))]
fn record_with<W>(
    mut source: Box<dyn FrameSource>,
    limits: &RecordLimits,
    mut sink: W,
    mut write: impl FnMut(&mut W, &mut Frame) -> Result<(), RecordError>,
    finish: impl FnOnce(W) -> Result<(), RecordError>,
    mut on_frame: impl FnMut(&Frame),
) -> Result<RecordSummary, RecordError> {
    let result = pump(source.as_mut(), limits, |f| {
        write(&mut sink, f)?;
        on_frame(f);
        Ok(())
    });
    let skipped = source.skipped();
    drop(source);
    let finished = finish(sink);
    let (frames, duration_s, lost) = result?;
    finished?;
    Ok(RecordSummary {
        frames,
        duration_s,
        skipped,
        oni_fixed_nodes: 0,
        lost,
        sound_lost: None,
    })
}

#[cfg(not(feature = "openni2"))]
pub fn record_oni(
    _: &SourceSpec,
    _: &CaptureConfig,
    _: &Path,
    _: &RecordLimits,
    _: impl FnMut(&Frame),
) -> Result<RecordSummary, RecordError> {
    Err(RecordError::NotBuilt { what: "OpenNI2" })
}
