//! The console's paint check (`tune_colours`): propose colour ranges from a few seconds of
//! live frames, count what the ranges in use and the proposed ones find on the same frames
//! (`mouthpiece_pipeline::tune`), show both (`tune` in `status`), and on request write the
//! proposal into the configuration file and reload it as SIGHUP does.
//!
//! The processing thread only hands frames over (a copy into a bounded queue of
//! [`QUEUE_FRAMES`], dropped when full) while a check samples; the sampling, proposing and
//! checking run on a thread of their own. A proposal that finds fewer dots than the ranges in
//! use is never offered, so it cannot be applied.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender, TrySendError};
use mouthpiece_detect::tune::{CheckedProposal, DotsFound};
use mouthpiece_detect::{ColorClass, DetectConfig};
use mouthpiece_frame::Frame;
use mouthpiece_pipeline::tune::{role_name, sample_and_check, write_classes};
use mouthpiece_server::{Hub, TuneClass, TuneFound, TuneReport};

/// Frames waiting for the sampler.
pub const QUEUE_FRAMES: usize = 4;
/// Sampling time when the request names none.
pub const DEFAULT_SECONDS: f64 = 2.0;

/// The ranges the tracker runs with and its dot counts.
#[derive(Debug, Clone)]
pub struct InUse {
    pub detect: DetectConfig,
    pub lip_dots: usize,
    pub forehead_dots: usize,
}

#[derive(Default)]
struct Shared {
    /// Frames go here while a check samples, until the instant.
    feed: Mutex<Option<(Sender<Frame>, Instant)>>,
    sampling: AtomicBool,
    /// The last proposal offered (it found at least as many dots as the ranges in use).
    offered: Mutex<Option<Vec<ColorClass>>>,
}

/// The paint check; cheap to clone.
#[derive(Clone)]
pub struct Tuner {
    hub: Hub,
    config_path: Option<PathBuf>,
    shared: Arc<Shared>,
}

impl std::fmt::Debug for Tuner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tuner")
            .field("config_path", &self.config_path)
            .finish_non_exhaustive()
    }
}

impl Tuner {
    /// `config_path`: the file `apply` writes (`None`: the embedded default, nothing to
    /// write).
    pub fn new(hub: Hub, config_path: Option<PathBuf>) -> Self {
        Self {
            hub,
            config_path,
            shared: Arc::default(),
        }
    }

    /// Called by the processing thread with every frame: copied to the sampler while a check
    /// samples, never blocking.
    pub fn offer(&self, frame: &Frame) {
        if !self.shared.sampling.load(Ordering::Relaxed) {
            return;
        }
        let mut feed = self.shared.feed.lock().unwrap_or_else(|e| e.into_inner());
        let Some((tx, until)) = feed.as_ref() else {
            return;
        };
        if Instant::now() >= *until {
            // Dropping the sender ends the sampling.
            *feed = None;
            self.shared.sampling.store(false, Ordering::Relaxed);
            return;
        }
        if let Err(TrySendError::Disconnected(_)) = tx.try_send(frame.clone()) {
            *feed = None;
            self.shared.sampling.store(false, Ordering::Relaxed);
        }
    }

    /// Starts a check over `seconds` of frames against the ranges `in_use`.
    pub fn run(
        &self,
        in_use: InUse,
        seconds: Option<Duration>,
    ) -> Result<serde_json::Value, String> {
        let seconds = seconds.map_or(DEFAULT_SECONDS, |d| d.as_secs_f64());
        let mut feed = self.shared.feed.lock().unwrap_or_else(|e| e.into_inner());
        if feed.is_some() || self.shared.sampling.load(Ordering::Relaxed) {
            return Err("a paint check is already sampling".into());
        }
        let (tx, rx) = crossbeam_channel::bounded(QUEUE_FRAMES);
        let worker = self.clone();
        std::thread::Builder::new()
            .name("mouthpiece-tune".into())
            .spawn(move || worker.check(in_use, rx))
            .map_err(|e| format!("cannot start the paint check: {e}"))?;
        *feed = Some((tx, Instant::now() + Duration::from_secs_f64(seconds)));
        self.shared.sampling.store(true, Ordering::Relaxed);
        *self
            .shared
            .offered
            .lock()
            .unwrap_or_else(|e| e.into_inner()) = None;
        self.hub.set_tune(Some(TuneReport {
            state: "sampling".into(),
            message: format!("sampling {seconds:.1} s of frames: hold still, mouth closed"),
            ..TuneReport::default()
        }));
        Ok(serde_json::json!({ "sampling_s": seconds }))
    }

    fn check(&self, in_use: InUse, frames: Receiver<Frame>) {
        let checked = sample_and_check(
            &in_use.detect,
            in_use.lip_dots,
            in_use.forehead_dots,
            frames,
        );
        let report = match checked {
            Ok(checked) => {
                let report = report_of(&checked, &in_use);
                *self
                    .shared
                    .offered
                    .lock()
                    .unwrap_or_else(|e| e.into_inner()) = checked.offered().then(|| {
                    checked
                        .proposal
                        .classes
                        .iter()
                        .map(|c| c.class.clone())
                        .collect()
                });
                report
            }
            Err(e) => TuneReport {
                state: "failed".into(),
                message: crate::source::error_chain(&e),
                ..TuneReport::default()
            },
        };
        tracing::info!(state = report.state, "paint check: {}", report.message);
        self.hub.set_tune(Some(report));
    }

    /// Writes the last offered proposal into the configuration file and reloads it.
    pub fn apply(&self) -> Result<serde_json::Value, String> {
        let Some(classes) = self
            .shared
            .offered
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
        else {
            return Err(
                "no proposal to apply: run the paint check first (a proposal that finds fewer dots than the ranges in use is never offered)"
                    .into(),
            );
        };
        let Some(path) = &self.config_path else {
            return Err(
                "the daemon runs on the built-in configuration: there is no file to write the ranges into"
                    .into(),
            );
        };
        write_classes(path, &classes).map_err(|e| crate::source::error_chain(&e))?;
        tracing::info!(path = %path.display(), "paint check applied: reloading the configuration");
        // SAFETY: kill(2) on our own process with SIGHUP, which the daemon handles as a reload.
        unsafe { libc::kill(libc::getpid(), libc::SIGHUP) };
        self.hub.update_status(|s| {
            if let Some(t) = &mut s.tune {
                t.state = "applied".into();
                t.offered = false;
                t.message = format!("written to {} and reloaded", path.display());
            }
        });
        *self
            .shared
            .offered
            .lock()
            .unwrap_or_else(|e| e.into_inner()) = None;
        Ok(serde_json::json!({ "written": path.display().to_string() }))
    }
}

fn found(f: &DotsFound, classes: &[ColorClass], dots: usize) -> TuneFound {
    let frames = f64::from(f.frames.max(1));
    TuneFound {
        share: f.share(),
        per_frame: f.total() as f64 / frames,
        dots,
        classes: classes
            .iter()
            .zip(&f.classes)
            .map(|(c, n)| TuneClass {
                name: c.name.clone(),
                role: role_name(c.role).into(),
                hue: c.hue.clone(),
                saturation: c.saturation,
                value: c.value,
                per_frame: n.found as f64 / frames,
            })
            .collect(),
    }
}

fn report_of(checked: &CheckedProposal, in_use: &InUse) -> TuneReport {
    let dots = in_use.lip_dots + in_use.forehead_dots;
    let proposed: Vec<ColorClass> = checked
        .proposal
        .classes
        .iter()
        .map(|c| c.class.clone())
        .collect();
    let offered = checked.offered();
    let lines = checked.report(in_use.lip_dots, in_use.forehead_dots);
    let message = if checked.proposal.classes.is_empty() {
        format!(
            "no paint colour found to propose ({})",
            checked.proposal.warnings.join("; ")
        )
    } else if offered {
        format!("{}; {}", lines[0], lines[1])
    } else {
        format!(
            "not offered: the proposed ranges find fewer dots than the ranges in use ({}; {})",
            lines[0], lines[1]
        )
    };
    TuneReport {
        state: "done".into(),
        message,
        frames: checked.in_use.frames,
        in_use: Some(found(&checked.in_use, &in_use.detect.classes, dots)),
        proposed: (!proposed.is_empty()).then(|| found(&checked.proposed, &proposed, dots)),
        offered,
        toml: (!proposed.is_empty()).then(|| checked.proposal.to_toml("the live camera")),
    }
}
