//! The real processor behind `mouthpiece run`: capture's sources and the one frame pipeline
//! (`mouthpiece_pipeline::Pipeline`: detect + track + retarget) for every configured
//! character, configured from the `[detect]`, `[track]` and `[retarget]` tables as
//! `mouthpiece process` is.

use std::time::{Duration, Instant};

use mouthpiece_config::{Config, SpeechSetting};
use mouthpiece_frame::AudioSubscription;
use mouthpiece_frame::Frame;
use mouthpiece_output::MouthSource;
use mouthpiece_pipeline::handover::{HandoverSettings, SpeechMode};
use mouthpiece_pipeline::speech::SpeechDriver;
use mouthpiece_pipeline::{Pipeline, PipelineConfig};
use mouthpiece_retarget::{Character, PerformerLayout};
use mouthpiece_server::{CharacterFrame, CharacterInfo, PerformerFrame, StreamInfo};
use mouthpiece_track::TrackedFrame;

use crate::error::CheckError;
use crate::factory::Factory;
use crate::pipeline::{Output, Processor};
use crate::source::Opener;
use mouthpiece_output::Throttle;

/// Everything a (re)load produces.
#[derive(Debug, Clone)]
pub struct Setup {
    pub characters: Vec<Character>,
    pub config: PipelineConfig,
    /// Per character (same order): whether speech may drive its mouth.
    pub speech: Vec<HandoverSettings>,
    /// `[audio] speech_profiles`: the booth's own live lip-sync profiles (else the shipped).
    pub speech_profiles: Option<mouthpiece_pipeline::speech::LiveProfiles>,
}

/// Loads and validates characters, `[detect]`, `[track]` and `[retarget]`.
pub fn setup(config: &Config) -> Result<Setup, CheckError> {
    let pipeline = match config.text() {
        Some(text) => PipelineConfig::from_text(text)?,
        None => PipelineConfig::default(),
    };
    let invalid = |key: &str, message: String| CheckError::Invalid {
        location: config.locate(key),
        message,
    };
    let characters = crate::characters::load(config)?;
    let layout = pipeline.track.layout();
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
    for name in config.characters.settings.keys() {
        if !characters.iter().any(|c| &c.name == name) {
            return Err(invalid(
                &format!(
                    "characters.settings.{}",
                    mouthpiece_config::key_segment(name)
                ),
                format!("no configured character is named {name:?}"),
            ));
        }
    }
    let speech = characters
        .iter()
        .map(|c| {
            let o = config
                .characters
                .settings
                .get(&c.name)
                .copied()
                .unwrap_or_default();
            HandoverSettings {
                mode: match o.speech {
                    SpeechSetting::Off => SpeechMode::Off,
                    SpeechSetting::Fallback => SpeechMode::Fallback,
                    SpeechSetting::Always => SpeechMode::Always,
                },
                hold_s: f64::from(o.speech_hold_ms) / 1e3,
                blend_s: f64::from(o.speech_blend_ms) / 1e3,
            }
        })
        .collect::<Vec<HandoverSettings>>();
    // No camera: speech is the only thing that can move a mouth.
    if config.source.spec.is_none() {
        if config.audio.is_none() {
            return Err(invalid(
                "source.spec",
                "spec = \"none\" (no camera) needs an [audio] table: speech is all that drives the characters".into(),
            ));
        }
        if let Some(c) = characters
            .iter()
            .zip(&speech)
            .find(|(_, s)| s.mode != SpeechMode::Always)
        {
            return Err(invalid(
                "source.spec",
                format!(
                    "spec = \"none\" (no camera) needs speech = \"always\" for every character; {:?} has not",
                    c.0.name
                ),
            ));
        }
    }
    let speech_profiles = match config
        .audio
        .as_ref()
        .and_then(|a| a.speech_profiles.as_ref())
    {
        Some(path) => Some(
            mouthpiece_pipeline::speech::load_profiles(path)
                .map_err(|e| invalid("audio.speech_profiles", e))?,
        ),
        None => None,
    };
    Ok(Setup {
        characters,
        config: pipeline,
        speech,
        speech_profiles,
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

    fn reload(&self, config: &Config) -> Result<Setup, CheckError> {
        let setup = setup(config)?;
        // Build the pipeline here so a bad colour range is rejected before anything changes.
        Pipeline::for_characters(setup.config.clone(), setup.characters.clone()).map_err(|e| {
            CheckError::Invalid {
                location: config.locate("detect"),
                message: crate::source::error_chain(&e),
            }
        })?;
        Ok(setup)
    }

    fn opener(&self, spec: &str, stall_timeout: Duration) -> Opener {
        crate::capture::opener(spec, stall_timeout)
    }
}

/// The frame pipeline for one or several characters, filling the stream's frame.
pub struct LiveProcessor {
    pipeline: Pipeline,
    config: PipelineConfig,
    dot_names: Vec<String>,
    info_changed: bool,
    errors: Throttle,
    /// Where the dots are in the image (for the console's preview).
    places: crate::console::DotPlaces,
    /// The last frames' dots, to judge a new neutral pose on.
    history: crate::console::DotHistory,
    /// How good the neutral pose taken on the last frame was, until collected.
    calibration_report: Option<mouthpiece_server::CalibrationReport>,
    /// The mouths from speech, when a character's `speech` is not `off`.
    speech: Option<SpeechDriver>,
    /// The audio thread's bus, when the daemon captures sound.
    bus: Option<std::sync::Arc<mouthpiece_frame::AudioBus>>,
    /// The audio thread's blocks, drained before each frame (while `speech` is on).
    audio: Option<AudioSubscription>,
    /// A character step mixed with speech (reused).
    mixed: Option<mouthpiece_retarget::CharacterStep>,
    /// Host time of the last camera frame that stepped the characters (calibrated).
    camera_at: Option<Instant>,
}

impl LiveProcessor {
    pub fn new(setup: Setup) -> Result<Self, String> {
        let pipeline = Pipeline::for_characters(setup.config.clone(), setup.characters)
            .map_err(|e| crate::source::error_chain(&e))?;
        let dot_names = TrackedFrame::names(pipeline.tracker().layout());
        let speech = speech_driver(
            &setup.config,
            pipeline.characters(),
            &setup.speech,
            setup.speech_profiles.as_ref(),
        )?;
        Ok(LiveProcessor {
            speech,
            bus: None,
            audio: None,
            mixed: None,
            camera_at: None,
            pipeline,
            config: setup.config,
            dot_names,
            info_changed: true,
            errors: Throttle::new(Duration::from_secs(10)),
            places: Default::default(),
            history: Default::default(),
            calibration_report: None,
        })
    }

    /// Listens to the audio bus while some character's mouth may follow speech.
    fn subscribe_audio(&mut self) {
        self.audio = match (&self.bus, &self.speech) {
            // 64 blocks: 0.6 s of 10 ms periods; older sound is of no use to a live mouth.
            (Some(bus), Some(_)) => Some(self.audio.take().unwrap_or_else(|| bus.subscribe(64))),
            _ => None,
        };
    }

    /// Every character at rest, confidence 0, no performer: before calibration, and when a
    /// frame could not be tracked (the last points are not repeated as if they were new).
    fn at_rest(&self, out: &mut Output) {
        let stream = &mut out.stream;
        stream.head = Default::default();
        stream.performer = None;
        let characters = self.pipeline.characters();
        stream
            .characters
            .resize_with(characters.len(), CharacterFrame::default);
        for (c, slot) in characters.iter().zip(stream.characters.iter_mut()) {
            if slot.name != c.name {
                slot.name.clone_from(&c.name);
            }
            slot.points.clear();
            slot.points.extend(c.neutral.iter().map(to_f32));
            slot.confidence.clear();
            slot.confidence.resize(c.len(), 0.0);
            slot.curve = None;
            slot.rig = None;
            slot.head = Some(Default::default());
        }
    }
}

impl LiveProcessor {
    /// Feeds the sound that came since the last call to the speech driver.
    fn drain_audio(&mut self) {
        if let (Some(driver), Some(audio)) = (&mut self.speech, &self.audio) {
            while let Ok(event) = audio.events.try_recv() {
                if let mouthpiece_frame::AudioEvent::Block(block) = event {
                    if let Err(e) = driver.push_audio(&block) {
                        if let Some(held_back) = self.errors.allow(Instant::now()) {
                            tracing::warn!(held_back, "live lip sync: {e}");
                        }
                    }
                }
            }
        }
    }
}

/// The speech driver for the characters whose `speech` is not `off` (`None` when none is).
fn speech_driver(
    config: &PipelineConfig,
    characters: &[Character],
    speech: &[HandoverSettings],
    profiles: Option<&mouthpiece_pipeline::speech::LiveProfiles>,
) -> Result<Option<SpeechDriver>, String> {
    if speech.iter().all(|s| s.mode == SpeechMode::Off) {
        return Ok(None);
    }
    let pairs: Vec<(Character, HandoverSettings)> = characters
        .iter()
        .cloned()
        .zip(speech.iter().copied())
        .collect();
    let settings = config.retarget.character_settings();
    SpeechDriver::with_profiles(&pairs, settings, profiles)
        .map(Some)
        .map_err(|e| crate::source::error_chain(&e))
}

/// The lip dots count as lost when fewer than half of them are seen.
fn lips_lost(confidence: &[f64]) -> bool {
    2 * confidence.iter().filter(|&&c| c > 0.0).count() < confidence.len()
}

fn to_f32(v: &nalgebra::Vector3<f64>) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

impl Processor for LiveProcessor {
    type Reload = Setup;

    fn set_audio(&mut self, bus: &std::sync::Arc<mouthpiece_frame::AudioBus>) {
        self.bus = Some(bus.clone());
        self.subscribe_audio();
    }

    fn process(&mut self, frame: &Frame, out: &mut Output) {
        self.drain_audio();
        if let Err(e) = self.pipeline.step(frame) {
            if let Some(held_back) = self.errors.allow(Instant::now()) {
                tracing::warn!(
                    held_back,
                    seq = frame.seq,
                    "tracking failed: {}",
                    crate::source::error_chain(&e)
                );
            }
            out.flags.no_dots = true;
            out.performer_camera.clear();
            self.at_rest(out);
            return;
        }
        if self.pipeline.take_rebound() {
            self.info_changed = true;
        }
        let tracked = self.pipeline.tracked();
        out.flags.calibrating = tracked.status.calibrating;
        out.flags.neutral_taken = tracked.status.neutral_taken;
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
            self.config.track.calibration_s + 0.5,
        );
        if tracked.status.neutral_taken {
            if let Some(neutral) = self.pipeline.tracker().neutral() {
                let wobble = crate::console::lip_wobble(neutral, self.history.last(neutral.frames));
                self.calibration_report = Some(mouthpiece_server::CalibrationReport {
                    wall_us: 0,
                    frames: neutral.frames,
                    mouth_width_mm: neutral.mouth_width() * 1e3,
                    lip_wobble_mm: wobble.map_or(f64::NAN, |w| w * 1e3),
                });
            }
        }
        let Some(stab) = &tracked.stabilised else {
            // Not calibrated yet: every character at rest, confidence 0.
            self.at_rest(out);
            return;
        };
        self.camera_at = Some(frame.host_rx);
        let stream = &mut out.stream;
        stream.head.pose.rotation = stab.head.quaternion_wxyz();
        stream.head.pose.translation = [
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
        // Characters that could not be bound are left out of the frame.
        let bound = (0..self.pipeline.characters().len())
            .filter_map(|i| self.pipeline.bound(i).map(|b| (i, b)));
        let count = bound.clone().count();
        let rig = self.pipeline.rig();
        let lost = lips_lost(&stab.confidence);
        let smoothing = self.config.retarget.smoothing();
        stream
            .characters
            .resize_with(count, CharacterFrame::default);
        for ((index, bound), slot) in bound.zip(stream.characters.iter_mut()) {
            if slot.name != bound.character().name {
                slot.name.clone_from(&bound.character().name);
            }
            let mut result = bound.output();
            slot.source = MouthSource::Camera;
            if let Some(driver) = &mut self.speech {
                let mixed = self.mixed.get_or_insert_with(|| result.clone());
                mixed.clone_from(result);
                slot.source =
                    driver.drive(index, tracked.t, frame.host_rx, lost, &smoothing, mixed);
                result = mixed;
            }
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
            // The performer's rig, with the character's own ranges where it has them; while
            // speech has a share in the mouth, moved towards the speech-driven dots' rig by
            // that share, as the points are.
            let ranges = &bound.character().rig_ranges;
            slot.rig = rig.map(|r| crate::rig::rig_state_for(r, ranges));
            if let Some((speech_rig, share)) =
                self.speech.as_ref().and_then(|d| d.speech_rig(index))
            {
                let speech_state = crate::rig::rig_state_for(speech_rig, ranges);
                slot.rig = Some(match slot.rig {
                    Some(camera) => camera.blend(&speech_state, share as f32),
                    None => speech_state,
                });
            }
            slot.head = Some(crate::head::wire(&result.head));
        }
    }

    fn speech_step(&mut self, out: &mut Output) -> Option<Instant> {
        self.drain_audio();
        let driver = self.speech.as_mut()?;
        let step = loop {
            let step = driver.pop_alone()?;
            // A calibrated camera is timing the steps: the sound mixes into those.
            let camera = self.camera_at.is_some_and(|c| {
                step.heard_at.saturating_duration_since(c)
                    <= mouthpiece_pipeline::speech::SPEECH_STALE
            });
            if !camera {
                break step;
            }
        };
        out.flags = Default::default();
        out.performer_camera.clear();
        let stream = &mut out.stream;
        stream.head = Default::default();
        stream.performer = None;
        let characters = self.pipeline.characters();
        stream
            .characters
            .resize_with(characters.len(), CharacterFrame::default);
        for (k, (c, slot)) in characters
            .iter()
            .zip(stream.characters.iter_mut())
            .enumerate()
        {
            if slot.name != c.name {
                slot.name.clone_from(&c.name);
            }
            let Some((result, rig)) = driver.mouth_alone(k, step.t, &step.weights) else {
                continue;
            };
            slot.source = MouthSource::Speech;
            slot.points.clear();
            slot.points.extend(result.points.iter().map(to_f32));
            slot.confidence.clear();
            slot.confidence.resize(result.points.len(), 1.0);
            if result.curve.is_empty() {
                slot.curve = None;
            } else {
                let curve = slot.curve.get_or_insert_with(Vec::new);
                curve.clear();
                curve.extend(result.curve.iter().map(to_f32));
            }
            // The rig on the speech-driven dots, with the character's own ranges.
            slot.rig = rig.map(|r| crate::rig::rig_state_for(r, &c.rig_ranges));
            slot.head = Some(crate::head::wire(&result.head));
        }
        Some(step.heard_at)
    }

    fn calibrate(&mut self, duration: Option<Duration>) {
        self.pipeline
            .tracker_mut()
            .calibrate_for(duration.map(|d| d.as_secs_f64()));
    }

    fn source_restarted(&mut self) {
        self.pipeline.tracker_mut().source_restarted();
    }

    fn take_info_changed(&mut self) -> bool {
        std::mem::take(&mut self.info_changed)
    }

    fn stream_info(&self, frame_rate: f64, source: &str) -> StreamInfo {
        let layout: PerformerLayout = self.pipeline.tracker().layout();
        let characters = self
            .pipeline
            .characters()
            .iter()
            .enumerate()
            .map(|(i, c)| CharacterInfo {
                name: c.name.clone(),
                points: c.point_names.clone(),
                neutral: c.neutral.iter().map(to_f32).collect(),
                m: self
                    .pipeline
                    .bound(i)
                    .map(|b| b.m().iter().map(to_f32).collect())
                    .unwrap_or_default(),
                m_mode: c.m_mode.name().to_owned(),
                units: c.units.map(|u| u.symbol().to_owned()).unwrap_or_default(),
            })
            .collect();
        StreamInfo {
            characters,
            performer_points: (0..layout.lip_dots)
                .map(PerformerLayout::lip_name)
                .collect(),
            frame_rate,
            source: source.to_owned(),
            mouth_frame: self.pipeline.tracker().neutral().map(|n| {
                let rotation = nalgebra::UnitQuaternion::from_matrix(&n.frame.axes);
                mouthpiece_server::RigidPose {
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
        let n = self.pipeline.tracker().layout().lip_dots;
        // A missing dot is placed where the stream carries it: its held place in the neutral
        // mouth frame (lip) or its neutral place (forehead), moved with the head.
        let predicted = |i: usize| -> Option<[f64; 2]> {
            let neutral = self.pipeline.tracker().neutral()?;
            let stab = self.pipeline.tracked().stabilised.as_ref()?;
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
            &self.pipeline.tracked().searched,
        )
    }

    fn look_at(
        &mut self,
        character: &str,
        point: Option<[f64; 3]>,
    ) -> Result<serde_json::Value, String> {
        let in_reach = self
            .pipeline
            .look_at(character, point.map(Into::into))
            .map_err(|e| crate::source::error_chain(&e))?;
        Ok(serde_json::json!({
            "character": character,
            "point": point,
            "mode": if point.is_some() { "look_at" } else { "follow" },
            "in_reach": in_reach,
        }))
    }

    fn take_calibration_report(&mut self) -> Option<mouthpiece_server::CalibrationReport> {
        self.calibration_report.take()
    }

    fn detect_in_use(&self) -> Option<crate::tune::InUse> {
        let layout = self.config.track.layout();
        Some(crate::tune::InUse {
            detect: self.config.detect.clone(),
            lip_dots: layout.lip_dots,
            forehead_dots: layout.forehead_dots,
        })
    }

    fn reload(&mut self, setup: Setup) -> Result<(), String> {
        let speech = speech_driver(
            &setup.config,
            &setup.characters,
            &setup.speech,
            setup.speech_profiles.as_ref(),
        )?;
        if setup.config.detect != self.config.detect || setup.config.track != self.config.track {
            // New colour ranges or tracking settings: a new pipeline, which calibrates afresh.
            self.pipeline = Pipeline::for_characters(setup.config.clone(), setup.characters)
                .map_err(|e| crate::source::error_chain(&e))?;
            self.dot_names = TrackedFrame::names(self.pipeline.tracker().layout());
        } else {
            if setup.config.rig != self.config.rig {
                // New hinge or ranges: the rig is rebuilt on the neutral pose already taken.
                self.pipeline
                    .set_rig_settings(setup.config.rig.clone())
                    .map_err(|e| crate::source::error_chain(&e))?;
            }
            self.pipeline
                .set_characters(setup.characters, setup.config.retarget.character_settings())
                .map_err(|e| crate::source::error_chain(&e))?;
        }
        self.config = setup.config;
        self.speech = speech;
        self.subscribe_audio();
        self.info_changed = true;
        Ok(())
    }
}
