//! The real pipeline behind `mouthpiece run`: capture's sources, the tracker (detect + track:
//! 3D dots, labels, head pose, neutral calibration), and the retarget core binding each
//! configured character to the performer's neutral pose.

use std::time::{Duration, Instant};

use mouthpiece_config::Config;
use mouthpiece_detect::DetectConfig;
use mouthpiece_frame::Frame;
use mouthpiece_retarget::retarget::{CharacterRetarget, CharacterSettings, StabilisedFrame};
use mouthpiece_retarget::{Character, PerformerLayout, ShapeSmoothing};
use mouthpiece_server::{CharacterFrame, CharacterInfo, PerformerFrame, StreamInfo};
use mouthpiece_track::{TrackConfig, TrackedFrame, Tracker};
use serde::Deserialize;

use crate::check::CheckError;
use crate::daemon::Factory;
use crate::pipeline::{Output, Processor};
use crate::source::Opener;
use crate::throttle::Throttle;

/// The sections of the config file this pipeline owns besides the daemon's.
#[derive(Debug, Default, Deserialize)]
struct Sections {
    #[serde(default)]
    detect: DetectConfig,
    #[serde(default)]
    track: TrackConfig,
}

/// Everything a (re)load produces.
pub struct Setup {
    pub characters: Vec<Character>,
    pub detect: DetectConfig,
    pub track: TrackConfig,
}

/// Loads and validates characters, `[detect]` and `[track]`.
pub fn setup(config: &Config) -> Result<Setup, CheckError> {
    let sections: Sections = config.extract()?;
    let invalid = |key: &str, message: String| CheckError::Invalid {
        location: config.locate(key),
        message,
    };
    sections
        .detect
        .validate()
        .map_err(|e| invalid("detect", crate::source::error_chain(&e)))?;
    sections
        .track
        .validate()
        .map_err(|e| invalid("track", crate::source::error_chain(&e)))?;
    let characters = crate::characters::load(config)?;
    let layout = sections.track.layout();
    for (i, c) in characters.iter().enumerate() {
        if c.len() != layout.lip_dots {
            return Err(invalid(
                &format!("characters.files[{i}]"),
                format!(
                    "character {} has {} points but the performer wears {} lip dots",
                    c.name,
                    c.len(),
                    layout.lip_dots
                ),
            ));
        }
    }
    Ok(Setup {
        characters,
        detect: sections.detect,
        track: sections.track,
    })
}

/// Builds the live pipeline.
#[derive(Debug, Clone, Copy, Default)]
pub struct LiveFactory;

impl Factory for LiveFactory {
    type Processor = LiveProcessor;

    fn processor(&self, config: &Config) -> Result<LiveProcessor, CheckError> {
        LiveProcessor::new(setup(config)?).map_err(|message| CheckError::Invalid {
            location: config.locate("detect"),
            message,
        })
    }

    fn reload(&self, config: &Config) -> Result<Box<dyn std::any::Any + Send>, CheckError> {
        let setup = setup(config)?;
        // Build the tracker here so a bad colour range is rejected before anything changes.
        Tracker::new(setup.detect.clone(), setup.track.clone()).map_err(|e| {
            CheckError::Invalid {
                location: config.locate("detect"),
                message: crate::source::error_chain(&e),
            }
        })?;
        Ok(Box::new(setup))
    }

    fn opener(&self, spec: &str, stall_timeout: Duration) -> Opener {
        crate::capture::opener(spec, stall_timeout)
    }
}

/// Detect + track + retarget for one or several characters.
pub struct LiveProcessor {
    tracker: Tracker,
    detect: DetectConfig,
    track: TrackConfig,
    characters: Vec<Character>,
    /// Characters bound to the tracker's current neutral pose (empty until calibrated).
    bound: Vec<CharacterRetarget>,
    dot_names: Vec<String>,
    /// The tracker's last stabilised frame, copied out of its borrow.
    stabilised: Option<StabilisedFrame>,
    info_changed: bool,
    errors: Throttle,
    /// Where the dots are in the image (for the console's preview).
    places: crate::console::DotPlaces,
    /// The last frames' dots, to judge a new neutral pose on.
    history: crate::console::DotHistory,
    /// How good the neutral pose taken on the last frame was, until collected.
    calibration_report: Option<mouthpiece_server::CalibrationReport>,
}

impl LiveProcessor {
    pub fn new(setup: Setup) -> Result<Self, String> {
        let tracker = Tracker::new(setup.detect.clone(), setup.track.clone())
            .map_err(|e| crate::source::error_chain(&e))?;
        let dot_names = TrackedFrame::names(tracker.layout());
        Ok(LiveProcessor {
            tracker,
            detect: setup.detect,
            track: setup.track,
            characters: setup.characters,
            bound: Vec::new(),
            dot_names,
            stabilised: None,
            info_changed: true,
            errors: Throttle::new(Duration::from_secs(10)),
            places: Default::default(),
            history: Default::default(),
            calibration_report: None,
        })
    }

    fn bind_characters(&mut self) {
        let Some(neutral) = self.tracker.neutral() else {
            self.bound.clear();
            return;
        };
        let settings = CharacterSettings {
            smoothing: ShapeSmoothing::default(),
            one_euro: None,
        };
        self.bound = self
            .characters
            .iter()
            .filter_map(
                |c| match CharacterRetarget::new(c.clone(), neutral, settings) {
                    Ok(bound) => Some(bound),
                    Err(e) => {
                        tracing::error!(character = %c.name, "cannot bind character: {e}");
                        None
                    }
                },
            )
            .collect();
        self.info_changed = true;
    }
}

fn to_f32(v: &nalgebra::Vector3<f64>) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

impl Processor for LiveProcessor {
    fn process(&mut self, frame: &Frame, out: &mut Output) {
        let tracked = match self.tracker.process(frame) {
            Ok(tracked) => tracked,
            Err(e) => {
                if let Some(held_back) = self.errors.allow(Instant::now()) {
                    tracing::warn!(
                        held_back,
                        seq = frame.seq,
                        "tracking failed: {}",
                        crate::source::error_chain(&e)
                    );
                }
                out.flags.no_dots = true;
                return;
            }
        };
        let neutral_taken = tracked.status.neutral_taken;
        out.flags.calibrating = tracked.status.calibrating;
        out.flags.head_lost = tracked.status.head_lost;
        out.flags.dots_missing = tracked.status.dots_missing.len();
        out.flags.no_dots = tracked.status.no_dots;
        let dots = &tracked.dots;
        out.performer_camera.clear();
        out.performer_camera.extend(
            dots.lip
                .iter()
                .chain(dots.forehead.iter())
                .map(|d| d.map(|p| [p.x, p.y, p.z])),
        );
        self.places.update(&tracked.pixels);
        self.history.push(
            tracked.t,
            dots.lip.iter().chain(dots.forehead.iter()).copied(),
            self.track.calibration_s + 0.5,
        );
        // Copied into a kept buffer, reusing its vectors, to end the tracker's borrow.
        self.stabilised.clone_from(&tracked.stabilised);
        if neutral_taken {
            if let Some(neutral) = self.tracker.neutral() {
                let wobble = crate::console::lip_wobble(neutral, self.history.last(neutral.frames));
                self.calibration_report = Some(mouthpiece_server::CalibrationReport {
                    wall_us: 0,
                    frames: neutral.frames,
                    mouth_width_mm: neutral.mouth_width() * 1e3,
                    lip_wobble_mm: wobble.map_or(f64::NAN, |w| w * 1e3),
                });
            }
        }
        if neutral_taken || (self.bound.is_empty() && self.tracker.neutral().is_some()) {
            self.bind_characters();
        }
        let stream = &mut out.stream;
        match &self.stabilised {
            Some(stab) => {
                stream.head.rotation = stab.head.quaternion_wxyz();
                stream.head.translation = [
                    stab.head.translation.x,
                    stab.head.translation.y,
                    stab.head.translation.z,
                ];
                stream.head.lost = stab.head_lost;
                let performer = stream.performer.get_or_insert_with(PerformerFrame::default);
                performer.points.clear();
                performer.points.extend(stab.lip.iter().map(to_f32));
                performer.confidence.clear();
                performer
                    .confidence
                    .extend(stab.confidence.iter().map(|&c| c as f32));
                stream
                    .characters
                    .resize_with(self.bound.len(), CharacterFrame::default);
                for (bound, slot) in self.bound.iter_mut().zip(stream.characters.iter_mut()) {
                    if slot.name != bound.character().name {
                        slot.name.clone_from(&bound.character().name);
                    }
                    let result = bound.apply(stab);
                    slot.points.clear();
                    slot.points.extend(result.points.iter().map(to_f32));
                    slot.confidence.clear();
                    slot.confidence
                        .extend(result.confidence.iter().map(|&c| c as f32));
                    if result.curve.is_empty() {
                        slot.curve = None;
                    } else {
                        let curve = slot.curve.get_or_insert_with(Vec::new);
                        curve.clear();
                        curve.extend(result.curve.iter().map(to_f32));
                    }
                }
            }
            None => {
                // Not calibrated yet: every character at rest, confidence 0.
                stream.head = Default::default();
                stream.performer = None;
                stream
                    .characters
                    .resize_with(self.characters.len(), CharacterFrame::default);
                for (c, slot) in self.characters.iter().zip(stream.characters.iter_mut()) {
                    if slot.name != c.name {
                        slot.name.clone_from(&c.name);
                    }
                    slot.points.clear();
                    slot.points.extend(c.neutral.iter().map(to_f32));
                    slot.confidence.clear();
                    slot.confidence.resize(c.len(), 0.0);
                    slot.curve = None;
                }
            }
        }
    }

    fn calibrate(&mut self, _duration: Option<Duration>) {
        // The tracker's calibration window is `[track] calibration_s`.
        self.tracker.calibrate();
    }

    fn take_info_changed(&mut self) -> bool {
        std::mem::take(&mut self.info_changed)
    }

    fn stream_info(&self, frame_rate: f64, source: &str) -> StreamInfo {
        let layout: PerformerLayout = self.tracker.layout();
        let characters = self
            .characters
            .iter()
            .map(|c| {
                let bound = self.bound.iter().find(|b| b.character().name == c.name);
                CharacterInfo {
                    name: c.name.clone(),
                    points: c.point_names.clone(),
                    neutral: c.neutral.iter().map(to_f32).collect(),
                    m: bound
                        .map(|b| b.m().iter().map(to_f32).collect())
                        .unwrap_or_default(),
                    m_mode: format!("{:?}", c.m_mode).to_lowercase(),
                    units: c
                        .units
                        .map(|u| format!("{u:?}").to_lowercase())
                        .unwrap_or_default(),
                }
            })
            .collect();
        StreamInfo {
            characters,
            performer_points: (0..layout.lip_dots)
                .map(PerformerLayout::lip_name)
                .collect(),
            frame_rate,
            source: source.to_owned(),
            mouth_frame: self.tracker.neutral().map(|n| {
                let rotation = nalgebra::UnitQuaternion::from_matrix(&n.frame.axes);
                mouthpiece_server::FramePose {
                    rotation: [rotation.w, rotation.i, rotation.j, rotation.k],
                    translation: [n.frame.origin.x, n.frame.origin.y, n.frame.origin.z],
                }
            }),
        }
    }

    fn performer_names(&self) -> &[String] {
        &self.dot_names
    }

    fn preview_overlay(&self, frame: &Frame) -> mouthpiece_server::Overlay {
        let k = frame.calibration.color;
        let n = self.tracker.layout().lip_dots;
        // A missing dot is placed where the stream carries it: its held place in the neutral
        // mouth frame (lip) or its neutral place (forehead), moved with the head.
        let predicted = |i: usize| -> Option<[f64; 2]> {
            let neutral = self.tracker.neutral()?;
            let stab = self.stabilised.as_ref()?;
            let rest = if i < n {
                neutral.frame.to_parent(stab.lip.get(i)?)
            } else {
                (*neutral.forehead_camera.get(i - n)?)?
            };
            let p = stab.head.apply(&rest);
            k.project([p.x, p.y, p.z])
        };
        self.places.overlay(
            &self.dot_names,
            predicted,
            self.track.roi_margin_px,
            [frame.color.width, frame.color.height],
        )
    }

    fn take_calibration_report(&mut self) -> Option<mouthpiece_server::CalibrationReport> {
        self.calibration_report.take()
    }

    fn reload(&mut self, update: Box<dyn std::any::Any + Send>) -> Result<(), String> {
        let setup = update
            .downcast::<Setup>()
            .map_err(|_| "internal: wrong reload payload".to_owned())?;
        if setup.detect != self.detect || setup.track != self.track {
            // New colour ranges or tracking settings: a new tracker, which calibrates afresh.
            self.tracker = Tracker::new(setup.detect.clone(), setup.track.clone())
                .map_err(|e| crate::source::error_chain(&e))?;
            self.dot_names = TrackedFrame::names(self.tracker.layout());
            self.detect = setup.detect;
            self.track = setup.track;
        }
        self.characters = setup.characters;
        self.bind_characters();
        self.info_changed = true;
        Ok(())
    }
}
