//! The console's paint check (`tune_colours`): propose colour ranges from a few seconds of
//! live frames, count what the ranges in use and the proposed ones find on the same frames,
//! show both (`tune` in `status`), and on request write the proposal into the configuration
//! file and reload it as SIGHUP does.
//!
//! The processing thread only hands frames over (a copy into a bounded queue of
//! [`QUEUE_FRAMES`], dropped when full) while a check samples; the sampling, proposing and
//! checking run on a thread of their own. A proposal that finds fewer dots than the ranges in
//! use is never offered, so it cannot be applied.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender, TrySendError};
use mouthpiece_detect::tune::{CheckedProposal, ColourSampler, DotsFound, TuneOptions};
use mouthpiece_detect::{ColorClass, DetectConfig, DotRole};
use mouthpiece_frame::{DepthImage, Frame};
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
        let report = match sample_and_check(&in_use, frames) {
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
            Err(message) => TuneReport {
                state: "failed".into(),
                message,
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
        write_classes(path, &classes)?;
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

fn sample_and_check(in_use: &InUse, frames: Receiver<Frame>) -> Result<CheckedProposal, String> {
    let options = TuneOptions::from_config(&in_use.detect, in_use.lip_dots, in_use.forehead_dots);
    let mut sampler = ColourSampler::new(options);
    let mut registered = DepthImage::new(0, 0);
    for frame in frames {
        let calib = &frame.calibration;
        let depth = if calib.depth_registered {
            &frame.depth
        } else {
            mouthpiece_track::camera::register_depth(&frame.depth, calib, &mut registered);
            &registered
        };
        let has_depth = depth.width == frame.color.width
            && depth.height == frame.color.height
            && depth.data.iter().any(|&d| d != 0);
        sampler
            .add_frame(
                &frame.color,
                has_depth.then_some((depth, calib.depth_scale_m)),
                calib.color.fx,
            )
            .map_err(|e| format!("frame {}: {e}", frame.seq))?;
    }
    if sampler.frames() == 0 {
        return Err("no frames arrived while sampling (is the camera up?)".into());
    }
    sampler
        .propose_checked(&in_use.detect)
        .map_err(|e| format!("checking the proposal: {e}"))
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
                role: match c.role {
                    DotRole::Lip => "lip",
                    DotRole::Forehead => "forehead",
                    DotRole::Any => "any",
                }
                .into(),
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

/// Replaces the file's `[[detect.class]]` entries with `classes`, keeping everything else as
/// written; checks the result loads before writing it (atomically: a new file renamed over).
pub fn write_classes(path: &Path, classes: &[ColorClass]) -> Result<(), String> {
    let shown = path.display();
    let text = std::fs::read_to_string(path).map_err(|e| format!("reading {shown}: {e}"))?;
    let mut doc: toml_edit::DocumentMut = text
        .parse()
        .map_err(|e| format!("{shown} does not parse: {e}"))?;
    let detect = doc
        .entry("detect")
        .or_insert_with(|| toml_edit::Item::Table(toml_edit::Table::new()));
    let Some(detect) = detect.as_table_like_mut() else {
        return Err(format!("{shown}: detect is not a table"));
    };
    let mut array = toml_edit::ArrayOfTables::new();
    for c in classes {
        let mut t = toml_edit::Table::new();
        t["name"] = toml_edit::value(c.name.as_str());
        t["role"] = toml_edit::value(match c.role {
            DotRole::Lip => "lip",
            DotRole::Forehead => "forehead",
            DotRole::Any => "any",
        });
        let mut hue = toml_edit::Array::new();
        for [lo, hi] in &c.hue {
            hue.push(toml_edit::Array::from_iter([
                i64::from(*lo),
                i64::from(*hi),
            ]));
        }
        t["hue"] = toml_edit::value(hue);
        let pair = |p: [u8; 2]| toml_edit::Array::from_iter([i64::from(p[0]), i64::from(p[1])]);
        t["saturation"] = toml_edit::value(pair(c.saturation));
        t["value"] = toml_edit::value(pair(c.value));
        array.push(t);
    }
    detect.insert("class", toml_edit::Item::ArrayOfTables(array));
    let new_text = doc.to_string();
    // What is written must load and pass the checks the reload makes.
    let config = mouthpiece_config::Config::parse(&new_text, path)
        .map_err(|e| format!("the new ranges do not load (nothing written): {e}"))?;
    crate::live::setup(&config)
        .map_err(|e| format!("the new ranges do not pass the checks (nothing written): {e}"))?;
    // A link stays a link: the file written is the link's final target (what a technician
    // who linked a shared booth file into place expects to change), replaced by a rename in
    // its own folder.
    let target = std::fs::canonicalize(path).map_err(|e| format!("resolving {shown}: {e}"))?;
    let dir = target.parent().unwrap_or(Path::new("/"));
    let tmp = dir.join(format!(
        ".{}.tune-{}",
        target.file_name().unwrap_or_default().to_string_lossy(),
        std::process::id()
    ));
    let written = || -> std::io::Result<()> {
        use std::io::Write as _;
        use std::os::unix::fs::OpenOptionsExt as _;
        let mut file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .custom_flags(libc::O_NOFOLLOW)
            .open(&tmp)?;
        if let Ok(meta) = std::fs::metadata(&target) {
            file.set_permissions(meta.permissions())?;
        }
        file.write_all(new_text.as_bytes())?;
        file.sync_all()?;
        drop(file);
        std::fs::rename(&tmp, &target)
    };
    written().map_err(|e| {
        // Only a file this call created (it is created new).
        if e.kind() != std::io::ErrorKind::AlreadyExists {
            let _ = std::fs::remove_file(&tmp);
        }
        if target == path {
            format!("writing {shown}: {e}")
        } else {
            format!("writing {} (the target of {shown}): {e}", target.display())
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A configuration file that is a symbolic link stays one: the new ranges go to its
    /// target, written beside the target, and nothing is left in either folder.
    #[test]
    fn writing_classes_through_a_symbolic_link_writes_its_target() {
        let shared = tempfile::tempdir().unwrap();
        let etc = tempfile::tempdir().unwrap();
        let target = shared.path().join("booth-a.toml");
        std::fs::write(
            &target,
            "# booth A\n[source]\nspec = \"replay:x.mcap\"\n\n[detect]\nmin_area_px = 3\n",
        )
        .unwrap();
        let link = etc.path().join("mouthpiece.toml");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let classes = vec![ColorClass {
            name: "lip".into(),
            role: DotRole::Lip,
            hue: vec![[0, 8]],
            saturation: [100, 255],
            value: [50, 255],
        }];
        write_classes(&link, &classes).unwrap();
        assert!(
            std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink(),
            "the link was replaced by a file"
        );
        assert_eq!(std::fs::read_link(&link).unwrap(), target);
        let written = std::fs::read_to_string(&target).unwrap();
        assert!(
            written.contains("# booth A") && written.contains("\"lip\""),
            "{written}"
        );
        assert_eq!(std::fs::read_dir(shared.path()).unwrap().count(), 1);
        assert_eq!(std::fs::read_dir(etc.path()).unwrap().count(), 1);
    }

    #[test]
    fn writing_classes_keeps_the_rest_of_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("mouthpiece.toml");
        let text = "# booth A\n[source]\nspec = \"replay:x.mcap\" # the rehearsal\n\n\
                    [detect]\nmin_area_px = 3\n\n[[detect.class]]\nname = \"old\"\nrole = \"any\"\n\
                    hue = [[40, 80]]\nsaturation = [90, 255]\nvalue = [40, 255]\n";
        std::fs::write(&path, text).unwrap();
        let classes = vec![ColorClass {
            name: "lip".into(),
            role: DotRole::Lip,
            hue: vec![[0, 8], [172, 179]],
            saturation: [100, 255],
            value: [50, 255],
        }];
        write_classes(&path, &classes).unwrap();
        let written = std::fs::read_to_string(&path).unwrap();
        assert!(
            written.contains("# booth A") && written.contains("# the rehearsal"),
            "{written}"
        );
        assert!(written.contains("min_area_px = 3"), "{written}");
        assert!(!written.contains("\"old\""), "{written}");
        let config = mouthpiece_config::Config::parse(&written, &path).unwrap();
        let pipeline =
            mouthpiece_pipeline::PipelineConfig::from_text(config.text().unwrap()).unwrap();
        assert_eq!(pipeline.detect.classes, classes);
        // Ranges the detector refuses are not written.
        let bad = vec![ColorClass {
            hue: vec![[170, 10]],
            ..classes[0].clone()
        }];
        let err = write_classes(&path, &bad).unwrap_err();
        assert!(err.contains("nothing written"), "{err}");
        assert_eq!(std::fs::read_to_string(&path).unwrap(), written);
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            1,
            "no file left behind"
        );
    }
}
