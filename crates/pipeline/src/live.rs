//! The live step: the frame pipeline and the mouths from speech for every configured
//! character, filling the output vocabulary's published frame ([`StreamFrame`]) directly:
//! the performer, every character's points, curve, rig (jaw, curves, visemes), head and eyes,
//! and what drove each mouth. The daemon publishes, records and sends to every output what
//! this fills; nothing else assembles a step.
//!
//! A camera frame steps it with [`LivePipeline::step`]; a booth that speech alone drives
//! (no calibrated camera timing the steps) steps it with [`LivePipeline::speech_step`], timed
//! by the sound's own clock. Both refill one [`Output`] in place, so the steady-state path
//! does not allocate.

use std::time::Instant;

use mouthpiece_frame::audio::AudioBlock;
use mouthpiece_frame::Frame;
use mouthpiece_output::{CharacterFrame, MouthSource, PerformerFrame, StreamFrame};
use mouthpiece_retarget::{Character, CharacterStep, Vec3};
use mouthpiece_track::{TrackError, TrackedFrame};

use crate::handover::{HandoverSettings, SpeechMode};
use crate::quality::{lip_wobble, DotHistory};
use crate::setup::Setup;
use crate::speech::{LiveProfiles, SpeechDriver, SpeechError, SPEECH_STALE};
use crate::wire::{head, point, rig_state_for};
use crate::{Pipeline, PipelineConfig};

/// Per-frame flags besides the stream frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Flags {
    /// No neutral pose yet, or a requested calibration is collecting frames.
    pub calibrating: bool,
    /// Fewer than three forehead dots: the head pose is the last good one.
    pub head_lost: bool,
    /// Dots not seen in this frame.
    pub dots_missing: usize,
    /// No dot of any colour found at all.
    pub no_dots: bool,
    /// This frame completed a neutral calibration (answers waiting `calibrate` requests).
    pub neutral_taken: bool,
}

/// One step of the live pipeline; reused from step to step.
#[derive(Debug, Default)]
pub struct Output {
    /// Sent to clients (`t`, `capture_us`, `wall_us` and `processing` are the caller's: the
    /// times of the frame or sound it stepped on).
    pub stream: StreamFrame,
    /// Tracked dots `D1..`, `F1..` in the camera frame (metres), for takes.
    pub performer_camera: Vec<Option<[f64; 3]>>,
    pub flags: Flags,
}

/// Why the live pipeline cannot be built or reloaded.
#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    #[error(transparent)]
    Pipeline(#[from] TrackError),
    #[error(transparent)]
    Speech(#[from] SpeechError),
}

/// The frame pipeline for every character, and the mouths from speech where a character's
/// `speech` is not `off`.
pub struct LivePipeline {
    pipeline: Pipeline,
    config: PipelineConfig,
    dot_names: Vec<String>,
    info_changed: bool,
    /// The mouths from speech, when a character's `speech` is not `off`.
    speech: Option<SpeechDriver>,
    /// A character step mixed with speech (reused).
    mixed: Option<CharacterStep>,
    /// Host time of the last camera frame that stepped the characters (calibrated).
    camera_at: Option<Instant>,
    /// The last frames' dots, to judge a new neutral pose on.
    history: DotHistory,
}

impl std::fmt::Debug for LivePipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LivePipeline")
            .field("pipeline", &self.pipeline)
            .field("speech", &self.speech.is_some())
            .finish_non_exhaustive()
    }
}

/// The speech driver for the characters whose `speech` is not `off` (`None` when none is).
fn speech_driver(
    config: &PipelineConfig,
    characters: &[Character],
    speech: &[HandoverSettings],
    profiles: Option<&LiveProfiles>,
) -> Result<Option<SpeechDriver>, SpeechError> {
    if speech.iter().all(|s| s.mode == SpeechMode::Off) {
        return Ok(None);
    }
    let pairs: Vec<(Character, HandoverSettings)> = characters
        .iter()
        .cloned()
        .zip(speech.iter().copied())
        .collect();
    let settings = config.retarget.character_settings();
    SpeechDriver::with_profiles(&pairs, settings, profiles).map(Some)
}

/// The lip dots count as lost when fewer than half of them are seen.
fn lips_lost(confidence: &[f64]) -> bool {
    2 * confidence.iter().filter(|&&c| c > 0.0).count() < confidence.len()
}

/// A step without the performer: no head pose, no performer points, one entry per character
/// under its name (buffers reused); the caller fills each character's mouth.
fn without_performer(stream: &mut StreamFrame, characters: &[Character]) {
    stream.head = Default::default();
    stream.performer = None;
    stream
        .characters
        .resize_with(characters.len(), CharacterFrame::default);
    for (c, slot) in characters.iter().zip(stream.characters.iter_mut()) {
        if slot.name != c.name {
            slot.name.clone_from(&c.name);
        }
    }
}

/// A character's points and curve into its published entry (buffers reused).
fn fill_points(slot: &mut CharacterFrame, points: &[Vec3], curve: &[Vec3]) {
    slot.points.clear();
    slot.points.extend(points.iter().map(point));
    if curve.is_empty() {
        slot.curve = None;
    } else {
        let c = slot.curve.get_or_insert_with(Vec::new);
        c.clear();
        c.extend(curve.iter().map(point));
    }
}

impl LivePipeline {
    pub fn new(setup: Setup) -> Result<Self, LiveError> {
        let pipeline = Pipeline::for_characters(setup.config.clone(), setup.characters)?;
        let dot_names = TrackedFrame::names(pipeline.tracker().layout());
        let speech = speech_driver(
            &setup.config,
            pipeline.characters(),
            &setup.speech,
            setup.speech_profiles.as_ref(),
        )?;
        Ok(Self {
            pipeline,
            config: setup.config,
            dot_names,
            info_changed: true,
            speech,
            mixed: None,
            camera_at: None,
            history: DotHistory::default(),
        })
    }

    /// The frame pipeline (tracker, characters, bindings, rig), read-only.
    pub fn pipeline(&self) -> &Pipeline {
        &self.pipeline
    }

    /// The configuration it runs with.
    pub fn config(&self) -> &PipelineConfig {
        &self.config
    }

    /// Names of [`Output::performer_camera`]'s entries.
    pub fn performer_names(&self) -> &[String] {
        &self.dot_names
    }

    /// True once after the stream's description changed (characters bound to a new neutral
    /// pose, or a reload).
    pub fn take_info_changed(&mut self) -> bool {
        std::mem::take(&mut self.info_changed)
    }

    /// Whether some character's mouth may follow speech (then feed it sound).
    pub fn hears(&self) -> bool {
        self.speech.is_some()
    }

    /// Analyses a block of sound for the mouths from speech (nothing when none listens).
    pub fn push_audio(&mut self, block: &AudioBlock) -> Result<(), mouthpiece_lipsync::Error> {
        match &mut self.speech {
            Some(driver) => driver.push_audio(block),
            None => Ok(()),
        }
    }

    /// Starts a new neutral calibration over `seconds` (`None`: the configured length).
    pub fn calibrate(&mut self, seconds: Option<f64>) {
        self.pipeline.tracker_mut().calibrate_for(seconds);
    }

    /// The source was reopened (its clock may have started again).
    pub fn source_restarted(&mut self) {
        self.pipeline.tracker_mut().source_restarted();
    }

    /// Turns `character`'s head to `point` or back to following ([`Pipeline::look_at`]).
    pub fn look_at(
        &mut self,
        character: &str,
        point: Option<Vec3>,
    ) -> Result<Option<bool>, TrackError> {
        self.pipeline.look_at(character, point)
    }

    /// The lip wobble (metres) of the current neutral pose over the frames it was averaged
    /// from ([`lip_wobble`]); `None` before calibration or when no frame could be fitted.
    pub fn neutral_wobble(&self) -> Option<f64> {
        let neutral = self.pipeline.tracker().neutral()?;
        lip_wobble(neutral, self.history.last(neutral.frames))
    }

    /// Every character at rest, confidence 0, no performer: before calibration, and when a
    /// frame could not be tracked (the last points are not repeated as if they were new).
    fn at_rest(&self, out: &mut Output) {
        let characters = self.pipeline.characters();
        without_performer(&mut out.stream, characters);
        for (c, slot) in characters.iter().zip(out.stream.characters.iter_mut()) {
            slot.points.clear();
            slot.points.extend(c.neutral.iter().map(point));
            slot.confidence.clear();
            slot.confidence.resize(c.len(), 0.0);
            slot.curve = None;
            slot.rig = None;
            slot.head = Some(Default::default());
        }
    }

    /// Steps on a camera frame and fills `out` (its buffers reused). A frame that cannot be
    /// tracked leaves every character at rest and returns the error.
    pub fn step(&mut self, frame: &Frame, out: &mut Output) -> Result<(), TrackError> {
        if let Err(e) = self.pipeline.step(frame) {
            out.flags.no_dots = true;
            out.performer_camera.clear();
            self.at_rest(out);
            return Err(e);
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
        self.history.push(
            tracked.t,
            dots.lip.iter().chain(dots.forehead.iter()).copied(),
            self.config.track.calibration_s + 0.5,
        );
        let Some(stab) = &tracked.stabilised else {
            // Not calibrated yet: every character at rest, confidence 0.
            self.at_rest(out);
            return Ok(());
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
        performer.points.extend(stab.lip.iter().map(point));
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
            fill_points(slot, &result.points, &result.curve);
            slot.confidence.clear();
            slot.confidence
                .extend(result.confidence.iter().map(|&c| c as f32));
            // The performer's rig, with the character's own ranges where it has them; while
            // speech has a share in the mouth, moved towards the speech-driven dots' rig by
            // that share, as the points are.
            let ranges = &bound.character().rig_ranges;
            slot.rig = rig.map(|r| rig_state_for(r, ranges));
            if let Some((speech_rig, share)) =
                self.speech.as_ref().and_then(|d| d.speech_rig(index))
            {
                let speech_state = rig_state_for(speech_rig, ranges);
                slot.rig = Some(match slot.rig {
                    Some(camera) => camera.blend(&speech_state, share as f32),
                    None => speech_state,
                });
            }
            slot.head = Some(head(&result.head));
        }
        Ok(())
    }

    /// With speech alone driving every character and no calibrated camera timing the steps:
    /// fills `out` with the next step taken from the sound and returns the host time of that
    /// sound (`None`: no step due).
    pub fn speech_step(&mut self, out: &mut Output) -> Option<Instant> {
        let driver = self.speech.as_mut()?;
        let step = loop {
            let step = driver.pop_alone()?;
            // A calibrated camera is timing the steps: the sound mixes into those.
            let camera = self
                .camera_at
                .is_some_and(|c| step.heard_at.saturating_duration_since(c) <= SPEECH_STALE);
            if !camera {
                break step;
            }
        };
        out.flags = Default::default();
        out.performer_camera.clear();
        let characters = self.pipeline.characters();
        without_performer(&mut out.stream, characters);
        for (k, (c, slot)) in characters
            .iter()
            .zip(out.stream.characters.iter_mut())
            .enumerate()
        {
            let Some((result, rig)) = driver.mouth_alone(k, step.t, &step.weights) else {
                continue;
            };
            slot.source = MouthSource::Speech;
            fill_points(slot, &result.points, &result.curve);
            slot.confidence.clear();
            slot.confidence.resize(result.points.len(), 1.0);
            // The rig on the speech-driven dots, with the character's own ranges.
            slot.rig = rig.map(|r| rig_state_for(r, &c.rig_ranges));
            slot.head = Some(head(&result.head));
        }
        Some(step.heard_at)
    }

    /// Checks a new set-up without applying it: a bad colour range is refused before
    /// anything changes.
    pub fn check(setup: &Setup) -> Result<(), LiveError> {
        Pipeline::for_characters(setup.config.clone(), setup.characters.clone())?;
        Ok(())
    }

    /// Applies a reloaded set-up (characters, colour ranges, settings); the old one stays on
    /// error.
    pub fn reload(&mut self, setup: Setup) -> Result<(), LiveError> {
        let speech = speech_driver(
            &setup.config,
            &setup.characters,
            &setup.speech,
            setup.speech_profiles.as_ref(),
        )?;
        if setup.config.detect != self.config.detect || setup.config.track != self.config.track {
            // New colour ranges or tracking settings: a new pipeline, which calibrates afresh.
            self.pipeline = Pipeline::for_characters(setup.config.clone(), setup.characters)?;
            self.dot_names = TrackedFrame::names(self.pipeline.tracker().layout());
        } else {
            if setup.config.rig != self.config.rig {
                // New hinge or ranges: the rig is rebuilt on the neutral pose already taken.
                self.pipeline.set_rig_settings(setup.config.rig.clone())?;
            }
            self.pipeline
                .set_characters(setup.characters, setup.config.retarget.character_settings())?;
        }
        self.config = setup.config;
        self.speech = speech;
        self.info_changed = true;
        Ok(())
    }
}
