//! From frames to named 3D dots: the tracker.
//!
//! Per frame ([`Tracker::process`]):
//! 1. depth onto the colour grid when the source did not register it ([`camera::register_depth`]);
//! 2. the detector (`mouthpiece-detect`) searches the region around the predicted dots
//!    (`prediction`), or the full frame when dots were lost;
//! 3. each blob's depth (lip dots: `lip_depth`, a robust plane over a few millimetres of
//!    lip; forehead dots: `head`, a plane over a wide patch of skin), undistorted and
//!    deprojected into the camera frame;
//! 4. names (`naming`): from 3D geometry when there are none yet, otherwise by optimal
//!    assignment to predictions and the recovery steps listed in one place
//!    (`naming::recovery`), every name held to the checks (`naming::checks`);
//! 5. once named, lip dots take their depth again from a patch stretched along the lip
//!    (`lip_depth`), and, once calibrated, the head motion is refined on the whole forehead
//!    surface (`forehead`, `head`) and the forehead dots placed by it;
//! 6. neutral calibration (`calibration`, docs/method.md) once the mouth has been still for
//!    [`TrackConfig::calibration_s`] (again on [`Tracker::calibrate`]), then head pose and
//!    stabilised lip dots every frame through the retarget core's [`Stabiliser`].
//!
//! Everything is on the caller's thread; no queues. A frame allocates nothing once the
//! buffers kept between frames have grown.

// The tracker's internals stay private: callers see the `Tracker`, its frame
// (`TrackedFrame`), its settings and the camera helpers; the one frame pipeline around it is
// `mouthpiece-pipeline`.
mod calibration;
pub mod camera;
mod clock;
mod config;
mod depth;
mod forehead;
mod head;
mod head_filter;
mod labels;
mod lip_depth;
mod naming;
mod output;
mod prediction;

use std::sync::Arc;

use mouthpiece_detect::{DetectConfig, DetectError, Detections, Detector, DotRole};
use mouthpiece_frame::{Calibration, DepthImage, Frame, Intrinsics};
use mouthpiece_retarget::{
    MissingDots, NeutralPose, OneEuroGroup, OneEuroParams, PerformerDots, PerformerLayout,
    RigidTransform, Stabiliser,
};

pub use calibration::{same_performer, SAME_PERFORMER_TOLERANCE_M};
pub use config::TrackConfig;
pub use lip_depth::LIP_PATCH_NEIGHBOUR_FRACTION;
pub use output::{DotName, Status, StepEvent, TrackedFrame};
pub use prediction::mean_neighbour_distance;

use labels::{Candidate, Small};

/// The retarget core's vector type (metres, camera frame unless said otherwise).
pub type Vec3 = nalgebra::Vector3<f64>;

/// A blob without a depth reading is taken to be this far away (metres) when sizing the
/// patch its depth is measured over: the distance the performer sits from the camera.
pub const DEFAULT_DEPTH_M: f64 = 0.6;

/// Fewest forehead dots that give a head pose (a rigid motion needs three points off one
/// line); with fewer seen and no forehead surface the head is lost.
pub const MIN_POSE_DOTS: usize = 3;

/// The One Euro filters' cut-off for the derivative of the filtered value, Hz: the filter's
/// authors' suggested value, left untuned.
pub const ONE_EURO_DERIVATIVE_CUTOFF_HZ: f64 = 1.0;

/// A lip blob between two named neighbours counts (*slipped names*) when it is at least this
/// many paint radii from each of them: a dot of its own, not a fragment of theirs.
const BLOB_BETWEEN_SEPARATION_RADII: f64 = 1.5;

/// The recovery steps' names, in the order they run (`mouthpiece evaluate --steps`).
pub fn recovery_steps() -> Vec<&'static str> {
    naming::recovery::step_names()
}

/// What can go wrong in the tracker.
#[derive(Debug, thiserror::Error)]
pub enum TrackError {
    #[error("invalid configuration {key}: {message}")]
    Config { key: String, message: String },
    #[error("dot detection failed")]
    Detect(#[source] DetectError),
    #[error("neutral calibration failed")]
    Neutral(#[source] mouthpiece_retarget::Error),
    #[error("head stabilisation failed")]
    Stabilise(#[source] mouthpiece_retarget::Error),
    #[error("frame {seq}: {message}")]
    Frame { seq: u64, message: String },
}

impl From<DetectError> for TrackError {
    /// A bad detector setting is a configuration error like any other (the key says where).
    fn from(e: DetectError) -> Self {
        match e {
            DetectError::Config { key, message } => TrackError::Config { key, message },
            other => TrackError::Detect(other),
        }
    }
}

/// This frame's depth image (on the colour grid, `scale` metres per unit), the colour
/// intrinsics, the detector's depth range and the paint's radius: what measuring a dot
/// needs.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Sensor<'a> {
    pub(crate) depth: &'a DepthImage,
    pub(crate) scale: f64,
    pub(crate) k: &'a Intrinsics,
    pub(crate) depth_range: [f64; 2],
    pub(crate) dot_radius_m: f64,
}

impl Sensor<'_> {
    /// A dot's paint radius in pixels at depth `z` (metres).
    pub(crate) fn dot_radius_px(&self, z: f64) -> f64 {
        self.dot_radius_m * self.k.fx / z
    }
}

/// The tracker: owns the detector, the names, and the calibration.
pub struct Tracker {
    config: TrackConfig,
    layout: PerformerLayout,
    detector: Detector,
    dot_radius_m: f64,
    depth_range: [f64; 2],
    roles: Vec<DotRole>,
    /// Session time from the frames' device timestamps, running on across source restarts.
    clock: clock::SessionClock,
    /// The source restarted while calibrated: on the first full naming, check that the
    /// performer in view is the calibrated one ([`same_performer`]).
    check_performer: bool,
    /// The previous frame's time (seconds) and the interval the tracks' velocities were
    /// measured over: a live source may skip frames, so predictions scale the velocities by
    /// this frame's interval over that one.
    prev_t: Option<f64>,
    velocity_dt: f64,
    /// This frame's interval over `velocity_dt` (1 at a steady frame rate).
    step_ratio: f64,
    tracks: prediction::Tracks,
    calibrating: bool,
    /// How long the running calibration wants the mouth still, seconds
    /// ([`TrackConfig::calibration_s`] unless [`Tracker::calibrate_for`] said otherwise).
    calibration_s: f64,
    pub(crate) window: calibration::Window,
    /// The neutral forehead surface the head motion is refined on, once calibrated.
    forehead_surface: Option<forehead::ForeheadSurface>,
    stabiliser: Option<Stabiliser>,
    registered: DepthImage,
    /// Per-frame buffers kept between frames (a frame allocates nothing once they have grown).
    found: Detections,
    cands: naming::Candidates,
    scratch: naming::Scratch,
    /// The forehead dots' depth filter, one cutoff for all (`None` when switched off).
    forehead_depth: Option<OneEuroGroup>,
    /// The head motion's filter, once there is a forehead surface to fit it on.
    head_filter: Option<head_filter::HeadFilter>,
    pub(crate) out: TrackedFrame,
}

impl std::fmt::Debug for Tracker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tracker")
            .field("config", &self.config)
            .finish_non_exhaustive()
    }
}

impl Tracker {
    /// Validates both configurations.
    pub fn new(detect: DetectConfig, config: TrackConfig) -> Result<Self, TrackError> {
        config.validate()?;
        let layout = config.layout();
        let dot_radius_m = detect.dot_radius_m;
        let depth_range = detect.depth_range_m;
        let roles = detect.classes.iter().map(|c| c.role).collect();
        let detector = Detector::new(detect)?;
        let n = layout.lip_dots + layout.forehead_dots;
        let forehead_depth = (config.forehead_depth_min_cutoff_hz > 0.0).then(|| {
            let params = OneEuroParams {
                min_cutoff: config.forehead_depth_min_cutoff_hz,
                beta: config.forehead_depth_beta,
                d_cutoff: ONE_EURO_DERIVATIVE_CUTOFF_HZ,
            };
            OneEuroGroup::new(params, layout.forehead_dots)
        });
        Ok(Self {
            forehead_depth,
            head_filter: None,
            layout,
            detector,
            dot_radius_m,
            depth_range,
            roles,
            clock: clock::SessionClock::default(),
            check_performer: false,
            prev_t: None,
            velocity_dt: 0.0,
            step_ratio: 1.0,
            tracks: prediction::Tracks::default(),
            calibrating: true,
            calibration_s: config.calibration_s,
            window: calibration::Window::default(),
            forehead_surface: None,
            stabiliser: None,
            registered: DepthImage::new(0, 0),
            found: Detections::default(),
            cands: naming::Candidates::default(),
            scratch: {
                let mut scratch = naming::Scratch::default();
                scratch.log.reserve_for(n);
                scratch
            },
            out: TrackedFrame {
                seq: 0,
                device_ts_us: 0,
                t: 0.0,
                dots: PerformerDots::new(layout),
                pixels: vec![None; n],
                confidence: vec![0.0; n],
                stabilised: None,
                status: Status::default(),
                steps: Vec::new(),
                searched: Vec::new(),
            },
            config,
        })
    }

    pub fn layout(&self) -> PerformerLayout {
        self.layout
    }

    pub fn config(&self) -> &TrackConfig {
        &self.config
    }

    /// The neutral pose, once calibrated.
    pub fn neutral(&self) -> Option<&NeutralPose> {
        self.stabiliser.as_ref().map(|s| s.neutral())
    }

    /// Asks for a new neutral calibration: the next [`TrackConfig::calibration_s`] of still,
    /// closed mouth become the neutral pose. The old one stays in use until then.
    pub fn calibrate(&mut self) {
        self.calibrate_for(None);
    }

    /// [`Tracker::calibrate`] over `seconds` of still, closed mouth instead of
    /// [`TrackConfig::calibration_s`] (`None`: that). The frame that takes the pose says
    /// so in [`Status::neutral_taken`].
    pub fn calibrate_for(&mut self, seconds: Option<f64>) {
        let seconds = seconds
            .filter(|s| s.is_finite() && *s > 0.0)
            .unwrap_or(self.config.calibration_s);
        tracing::info!(seconds, "neutral calibration requested");
        self.calibrating = true;
        self.calibration_s = seconds;
        self.window.clear();
    }

    /// The source was reopened (a replay from its beginning, a camera plugged back in): the
    /// next frame starts a new segment of the session clock, whatever its timestamp. A clock
    /// that goes backwards is taken as a restart without being told.
    pub fn source_restarted(&mut self) {
        self.clock.restart();
    }

    /// After a restart: the names are found again from geometry, the calibration window
    /// starts afresh, and the first full naming checks the performer ([`same_performer`]):
    /// the neutral pose is kept for the same performer, a new one is taken otherwise.
    fn restart_tracks(&mut self) {
        tracing::info!("source restarted; re-acquiring the dots");
        self.tracks.forget();
        self.window.clear();
        self.velocity_dt = 0.0;
        if let Some(filter) = &mut self.forehead_depth {
            filter.reset();
        }
        if let Some(filter) = &mut self.head_filter {
            filter.reset();
        }
        self.check_performer = self.stabiliser.is_some();
    }

    /// The last frame [`Self::process`] made.
    pub fn last(&self) -> &TrackedFrame {
        &self.out
    }

    /// Tracks one frame.
    pub fn process(&mut self, frame: &Frame) -> Result<&TrackedFrame, TrackError> {
        let tick = self.clock.tick(frame.device_ts_us);
        if tick.restarted {
            self.restart_tracks();
        }
        let t = tick.t;
        let dt = self.prev_t.map_or(0.0, |p| t - p);
        self.step_ratio = if self.velocity_dt > 0.0 && dt > 0.0 {
            (dt / self.velocity_dt).min(prediction::MAX_STEP_RATIO)
        } else {
            1.0
        };
        let calib: &Arc<Calibration> = &frame.calibration;
        let k = calib.color;
        if frame.color.width != k.width || frame.color.height != k.height {
            return Err(TrackError::Frame {
                seq: frame.seq,
                message: format!(
                    "colour image is {}x{} but its calibration says {}x{}",
                    frame.color.width, frame.color.height, k.width, k.height
                ),
            });
        }
        let mut registered = std::mem::replace(&mut self.registered, DepthImage::new(0, 0));
        let depth = if calib.depth_registered {
            &frame.depth
        } else {
            camera::register_depth(&frame.depth, calib, &mut registered);
            &registered
        };
        let sensor = Sensor {
            depth,
            scale: calib.depth_scale_m,
            k: &k,
            depth_range: self.depth_range,
            dot_radius_m: self.dot_radius_m,
        };
        let mut found = std::mem::take(&mut self.found);
        let result = self.detect_and_name(frame, &sensor, t, &mut found);
        self.found = found;
        let result = result.and_then(|()| {
            if dt > 0.0 {
                self.velocity_dt = dt;
            }
            self.prev_t = Some(t);
            self.update_calibration(t, &sensor)
        });
        self.registered = registered;
        result?;
        let out = &mut self.out;
        match (&mut self.stabiliser, &mut out.stabilised) {
            (Some(stab), stabilised) => {
                let s = stab.step(t, &out.dots).map_err(TrackError::Stabilise)?;
                out.status.head_lost = s.head_lost;
                // Into the kept frame, reusing its vectors.
                match stabilised {
                    Some(mine) => mine.clone_from(s),
                    none => *none = Some(s.clone()),
                }
            }
            (None, stabilised) => {
                *stabilised = None;
                out.status.head_lost = out.dots.forehead.iter().flatten().count() < MIN_POSE_DOTS;
            }
        }
        out.status.calibrating = self.calibrating;
        tracing::trace!(seq = frame.seq, candidates = self.cands.len(), "tracked");
        Ok(&self.out)
    }

    /// The body of [`Self::process`]: detect, measure, name, then sharpen the named dots and
    /// fill the output.
    fn detect_and_name(
        &mut self,
        frame: &Frame,
        sensor: &Sensor,
        t: f64,
        found: &mut Detections,
    ) -> Result<(), TrackError> {
        let k = sensor.k;
        let search = self.tracks.search_region(
            &self.config,
            self.step_ratio,
            [frame.color.width as usize, frame.color.height as usize],
            k.fx,
            sensor.dot_radius_m,
        );
        self.out.searched.clear();
        let regions = search.map(|s| s.searched());
        self.detector.detect_into(
            &frame.color,
            Some((sensor.depth, sensor.scale)),
            k.fx,
            regions.as_deref(),
            found,
        )?;
        self.out.searched.clone_from(&found.searched);
        self.cands.clear();
        for (blob_index, blob) in found.blobs.iter().enumerate() {
            let z_hint = blob.depth_m.unwrap_or(DEFAULT_DEPTH_M);
            let role = self.roles[blob.class];
            let z = if role == DotRole::Forehead {
                head::forehead_dot_depth(
                    sensor,
                    self.config.forehead_depth_patch_m,
                    blob.center,
                    z_hint,
                    &mut self.scratch.depth,
                )
            } else {
                lip_depth::lip_depth(
                    sensor,
                    self.config.lip_depth_patch_m,
                    blob.center,
                    z_hint,
                    &mut self.scratch.depth,
                )
            };
            if let Some((z, _)) = z {
                self.cands.push_detected(
                    Candidate {
                        pixel: blob.center,
                        point: camera::deproject(k, blob.center, z),
                        role,
                    },
                    blob_index,
                );
            }
        }

        let n = self.layout.lip_dots;
        let ctx = naming::Context {
            layout: self.layout,
            config: &self.config,
            tracks: self.tracks.dots.as_deref().unwrap_or(&[]),
            neutral: self.stabiliser.as_ref().map(|s| s.neutral()),
            head: self.tracks.reference(self.layout),
            step_ratio: self.step_ratio,
            roles: &self.roles,
            blobs: &found.blobs,
            faint: &found.faint,
            sensor: *sensor,
        };
        let names = naming::name_frame(&ctx, &mut self.cands, &mut self.scratch);
        let names: Small<Option<usize>> = names.as_slice().iter().copied().collect();
        // After a restart, on the first full naming and before the forehead surface fit
        // (which places the forehead dots on the neutral triangle): the same performer?
        if self.check_performer && self.tracks.dots.is_none() && names.iter().all(Option::is_some) {
            self.check_performer = false;
            let now: Small<Vec3> = names[n..]
                .iter()
                .map(|c| self.cands.list[c.expect("all named")].point)
                .collect();
            let same = self
                .neutral()
                .is_none_or(|neutral| same_performer(&neutral.forehead_camera, &now));
            if !same {
                tracing::info!(
                    "the forehead dots are not where the neutral pose had them: another performer; recalibrating"
                );
                self.calibrate();
            }
        }
        let cands = &mut self.cands.list;
        let mut filtered_head = None;
        // While a new neutral pose is taken the old surface is not the reference: the new
        // pose is measured from the dots as they are seen (another performer's, after a
        // restart, are not where the old neutral has them).
        if let Some(surface) = self.forehead_surface.as_ref().filter(|_| !self.calibrating) {
            filtered_head = head::fit_forehead_surface(
                surface,
                &self.tracks.reference_forehead,
                &self.tracks.head,
                &names[n..],
                cands,
                sensor,
                self.head_filter.as_mut().map(|f| (f, t)),
            );
        }
        lip_depth::along_the_lips(
            sensor,
            [
                self.config.lip_depth_along_m,
                self.config.lip_depth_across_m,
            ],
            [self.layout.left_corner(), self.layout.right_corner()],
            &names[..n],
            cands,
            &mut self.scratch.depth,
        );
        // The depth filter stands in for the head filter where that did not run (before the
        // neutral pose, a forehead dot unseen, a surface fit not used).
        if let Some(filter) = &mut self.forehead_depth {
            if filtered_head.is_none() {
                head::filter_forehead_depths(filter, &names[n..], cands, t, k);
            }
        }
        // Fill the output.
        let out = &mut self.out;
        out.seq = frame.seq;
        out.device_ts_us = frame.device_ts_us;
        out.t = t;
        out.dots.clear();
        let mut used: Small<bool> = smallvec::smallvec![false; cands.len()];
        for (dot, name) in names.iter().enumerate() {
            let p = name.map(|c| {
                used[c] = true;
                &cands[c]
            });
            out.pixels[dot] = p.map(|c| c.pixel);
            out.confidence[dot] = if p.is_some() { 1.0 } else { 0.0 };
            let slot = if dot < n {
                &mut out.dots.lip[dot]
            } else {
                &mut out.dots.forehead[dot - n]
            };
            *slot = p.map(|c| c.point);
        }
        if let Some(head) = &filtered_head {
            let reference = &self.tracks.reference_forehead;
            for (slot, reference) in out.dots.forehead.iter_mut().zip(reference) {
                if let Some(p) = slot {
                    *p = head.apply(reference);
                }
            }
        }
        out.status.calibrating = false;
        out.status.head_lost = false;
        out.status.dots_missing.clear();
        out.status.dots_missing.extend(
            (0..names.len())
                .filter(|&i| names[i].is_none())
                .map(|i| DotName::of(self.layout, i)),
        );
        out.status.no_dots = found.blobs.is_empty();
        out.status.too_few_dots = self.tracks.dots.is_none() && cands.len() < names.len();
        out.status.unassigned_blobs = used.iter().filter(|u| !**u).count();
        let lip_z = names[..n]
            .iter()
            .flatten()
            .map(|&c| cands[c].point.z)
            .next();
        let blob_between = naming::checks::blob_between_neighbours(
            &names[..n],
            cands,
            &used,
            BLOB_BETWEEN_SEPARATION_RADII * sensor.dot_radius_px(lip_z.unwrap_or(DEFAULT_DEPTH_M)),
        )
        .is_some();
        out.status.neutral_taken = false;
        out.steps.clear();
        // As much room as the log has, so that copying it never grows the frame's list.
        out.steps.reserve(self.scratch.log.events.capacity());
        out.steps.extend_from_slice(&self.scratch.log.events);
        self.tracks.count(&names);
        let neutral = self.stabiliser.as_ref().map(|s| s.neutral());
        self.tracks.update(
            &self.config,
            self.layout,
            &names,
            &self.cands.list,
            neutral,
            self.step_ratio,
        );
        // After the frame's tracks are kept, so that the next frame names from geometry and
        // not from these names; only when geometry can name this frame, so that a lasting
        // extra blob (a smear of paint the size of a dot) never leaves the dots unnamed.
        if self.tracks.dots.is_some()
            && self.tracks.names_slipped(blob_between)
            && labels::label_by_geometry(&self.cands.list, self.layout).is_ok()
        {
            tracing::info!(
                frames = prediction::SLIPPED_NAMES_FRAMES,
                "a lip blob left between two named neighbours: the names slipped; re-acquiring from geometry"
            );
            self.tracks.forget();
        }
        Ok(())
    }

    /// Collects fully seen frames while calibrating; takes the neutral pose once the window
    /// spans `calibration_s` of a still, closed mouth.
    fn update_calibration(&mut self, t: f64, sensor: &Sensor) -> Result<(), TrackError> {
        if !self.calibrating {
            return Ok(());
        }
        let dots = &self.out.dots;
        let complete = dots.lip.iter().chain(&dots.forehead).all(|d| d.is_some());
        if !complete {
            // The window must be continuous.
            self.window.clear();
            return Ok(());
        }
        let n = self.layout.lip_dots;
        let margin_m = self.config.forehead_surface_margin_m;
        let crop = (margin_m > 0.0).then(|| {
            let pixels: Small<[f64; 2]> = self.out.pixels[n..].iter().flatten().copied().collect();
            let lips: Small<[f64; 2]> = self.out.pixels[..n].iter().flatten().copied().collect();
            let mouth = camera::pixel_mean(&lips);
            head::forehead_crop(
                sensor,
                margin_m,
                &pixels,
                &dots.forehead,
                mouth,
                self.config.nose_bridge_reach,
            )
        });
        if !self.window.push(t, dots, crop, self.calibration_s) {
            return Ok(());
        }
        if !self.window.is_still(
            self.layout,
            self.config.still_tolerance_m,
            self.config.max_opening_ratio,
        ) {
            return Ok(());
        }
        let neutral = self.window.neutral(self.layout)?;
        tracing::info!(
            frames = neutral.frames,
            mouth_width_mm = neutral.mouth_width() * 1e3,
            "neutral pose taken"
        );
        // Re-base the head motion on the neutral forehead.
        let tracks = &mut self.tracks;
        tracks.reference_forehead = neutral
            .forehead_camera
            .iter()
            .map(|p| p.expect("complete window"))
            .collect();
        if let Some(dots) = &mut tracks.dots {
            for (track, p) in dots
                .iter_mut()
                .zip(neutral.lip_camera.iter().chain(&tracks.reference_forehead))
            {
                track.stab = *p;
                track.stab_vel = Vec3::zeros();
            }
        }
        tracks.head = RigidTransform::IDENTITY;
        tracks.rest = neutral.lip_camera.clone();
        let missing = MissingDots {
            hold: self.config.missing_hold_s,
            decay: self.config.missing_decay_s,
        };
        self.stabiliser = Some(Stabiliser::new(neutral, missing).map_err(TrackError::Neutral)?);
        self.forehead_surface = head::build_forehead_surface(
            self.window.crops(),
            sensor.scale,
            self.depth_range,
            sensor.k,
            &self.tracks.reference_forehead,
        );
        let [rotation_accel, shift_accel] = self.config.head_filter_accel;
        self.head_filter = self
            .forehead_surface
            .as_ref()
            .filter(|_| rotation_accel > 0.0 && shift_accel > 0.0)
            .map(|surface| {
                head_filter::HeadFilter::new(
                    head_filter::HeadFilterParams {
                        rotation_sigma_rad: head_filter::FITTED_TURN_SIGMA_RAD,
                        rotation_accel,
                        shift_sigma_m: head_filter::FITTED_SHIFT_SIGMA_M,
                        shift_accel,
                    },
                    surface.centre(),
                )
            });
        self.calibrating = false;
        self.calibration_s = self.config.calibration_s;
        self.window.clear();
        self.out.status.neutral_taken = true;
        Ok(())
    }
}

#[cfg(test)]
mod tests;
