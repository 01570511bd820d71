//! The real processor behind `mouthpiece run`: capture's sources and the live pipeline
//! (`mouthpiece_pipeline::live::LivePipeline`: detect + track + retarget + rig, and the mouths
//! from speech) for every configured character, configured from the `[detect]`, `[track]`,
//! `[retarget]` and `[rig]` tables as `mouthpiece process` is. The pipeline fills the published
//! step; this adds what the console needs (the preview's dots, the calibration report) and
//! feeds it the booth's sound.

use std::time::{Duration, Instant};

use mouthpiece_config::Config;
use mouthpiece_frame::{AudioSubscription, Frame};
use mouthpiece_output::Throttle;
use mouthpiece_pipeline::live::LivePipeline;
use mouthpiece_pipeline::wire::point;
use mouthpiece_retarget::PerformerLayout;
use mouthpiece_server::{CharacterInfo, StreamInfo};

use crate::error::CheckError;
use crate::factory::Factory;
use crate::pipeline::{Output, Processor};
use crate::source::{error_chain, Opener};

/// The live pipeline's set-up from a configuration: characters, `[detect]`, `[track]`,
/// `[retarget]`, `[rig]` and the characters' speech settings.
pub use mouthpiece_pipeline::setup::{setup, Setup};

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
        LivePipeline::check(&setup).map_err(|e| CheckError::Invalid {
            location: config.locate("detect"),
            message: error_chain(&e),
        })?;
        Ok(setup)
    }

    fn opener(&self, spec: &str, stall_timeout: Duration) -> Opener {
        crate::capture::opener(spec, stall_timeout)
    }
}

/// The live pipeline, fed the booth's sound, with the console's view of the dots.
pub struct LiveProcessor {
    live: LivePipeline,
    errors: Throttle,
    /// Where the dots are in the image (for the console's preview).
    places: crate::console::DotPlaces,
    /// How good the neutral pose taken on the last frame was, until collected.
    calibration_report: Option<mouthpiece_server::CalibrationReport>,
    /// The audio thread's bus, when the daemon captures sound.
    bus: Option<std::sync::Arc<mouthpiece_frame::AudioBus>>,
    /// The audio thread's blocks, drained before each step (while some mouth hears).
    audio: Option<AudioSubscription>,
}

impl LiveProcessor {
    pub fn new(setup: Setup) -> Result<Self, String> {
        Ok(LiveProcessor {
            live: LivePipeline::new(setup).map_err(|e| error_chain(&e))?,
            errors: Throttle::new(Duration::from_secs(10)),
            places: Default::default(),
            calibration_report: None,
            bus: None,
            audio: None,
        })
    }

    /// Listens to the audio bus while some character's mouth may follow speech.
    fn subscribe_audio(&mut self) {
        self.audio = match (&self.bus, self.live.hears()) {
            // 64 blocks: 0.6 s of 10 ms periods; older sound is of no use to a live mouth.
            (Some(bus), true) => Some(self.audio.take().unwrap_or_else(|| bus.subscribe(64))),
            _ => None,
        };
    }

    /// Feeds the sound that came since the last call to the mouths from speech.
    fn drain_audio(&mut self) {
        let Some(audio) = &self.audio else {
            return;
        };
        while let Ok(event) = audio.events.try_recv() {
            if let mouthpiece_frame::AudioEvent::Block(block) = event {
                if let Err(e) = self.live.push_audio(&block) {
                    if let Some(held_back) = self.errors.allow(Instant::now()) {
                        tracing::warn!(held_back, "live lip sync: {e}");
                    }
                }
            }
        }
    }
}

impl Processor for LiveProcessor {
    type Reload = Setup;

    fn set_audio(&mut self, bus: &std::sync::Arc<mouthpiece_frame::AudioBus>) {
        self.bus = Some(bus.clone());
        self.subscribe_audio();
    }

    fn process(&mut self, frame: &Frame, out: &mut Output) {
        self.drain_audio();
        if let Err(e) = self.live.step(frame, out) {
            if let Some(held_back) = self.errors.allow(Instant::now()) {
                tracing::warn!(
                    held_back,
                    seq = frame.seq,
                    "tracking failed: {}",
                    error_chain(&e)
                );
            }
            return;
        }
        let pipeline = self.live.pipeline();
        let tracked = pipeline.tracked();
        self.places.update(&tracked.pixels);
        if tracked.status.neutral_taken {
            if let Some(neutral) = pipeline.tracker().neutral() {
                let wobble = self.live.neutral_wobble();
                self.calibration_report = Some(mouthpiece_server::CalibrationReport {
                    wall_us: 0,
                    frames: neutral.frames,
                    mouth_width_mm: neutral.mouth_width() * 1e3,
                    lip_wobble_mm: wobble.map_or(f64::NAN, |w| w * 1e3),
                });
            }
        }
    }

    fn speech_step(&mut self, out: &mut Output) -> Option<Instant> {
        self.drain_audio();
        self.live.speech_step(out)
    }

    fn calibrate(&mut self, duration: Option<Duration>) {
        self.live.calibrate(duration.map(|d| d.as_secs_f64()));
    }

    fn source_restarted(&mut self) {
        self.live.source_restarted();
    }

    fn take_info_changed(&mut self) -> bool {
        self.live.take_info_changed()
    }

    fn stream_info(&self, frame_rate: f64, source: &str) -> StreamInfo {
        let pipeline = self.live.pipeline();
        let layout: PerformerLayout = pipeline.tracker().layout();
        let characters = pipeline
            .characters()
            .iter()
            .enumerate()
            .map(|(i, c)| CharacterInfo {
                name: c.name.clone(),
                points: c.point_names.clone(),
                neutral: c.neutral.iter().map(point).collect(),
                m: pipeline
                    .bound(i)
                    .map(|b| b.m().iter().map(point).collect())
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
            mouth_frame: pipeline.tracker().neutral().map(|n| {
                let rotation = nalgebra::UnitQuaternion::from_matrix(&n.frame.axes);
                mouthpiece_server::RigidPose {
                    rotation: [rotation.w, rotation.i, rotation.j, rotation.k],
                    translation: [n.frame.origin.x, n.frame.origin.y, n.frame.origin.z],
                }
            }),
        }
    }

    fn performer_names(&self) -> &[String] {
        self.live.performer_names()
    }

    fn preview_overlay(&self, frame: &Frame) -> mouthpiece_server::Overlay {
        let k = frame.calibration.color;
        let pipeline = self.live.pipeline();
        let n = pipeline.tracker().layout().lip_dots;
        // A missing dot is placed where the stream carries it: its held place in the neutral
        // mouth frame (lip) or its neutral place (forehead), moved with the head.
        let predicted = |i: usize| -> Option<[f64; 2]> {
            let neutral = pipeline.tracker().neutral()?;
            let stab = pipeline.tracked().stabilised.as_ref()?;
            let rest = if i < n {
                neutral.frame.to_parent(stab.lip.get(i)?)
            } else {
                (*neutral.forehead_camera.get(i - n)?)?
            };
            let p = stab.head.apply(&rest);
            k.project([p.x, p.y, p.z])
        };
        self.places.overlay(
            self.live.performer_names(),
            predicted,
            &pipeline.tracked().searched,
        )
    }

    fn look_at(
        &mut self,
        character: &str,
        point: Option<[f64; 3]>,
    ) -> Result<serde_json::Value, String> {
        let in_reach = self
            .live
            .look_at(character, point.map(Into::into))
            .map_err(|e| error_chain(&e))?;
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
        let config = self.live.config();
        let layout = config.track.layout();
        Some(crate::tune::InUse {
            detect: config.detect.clone(),
            lip_dots: layout.lip_dots,
            forehead_dots: layout.forehead_dots,
        })
    }

    fn reload(&mut self, setup: Setup) -> Result<(), String> {
        self.live.reload(setup).map_err(|e| error_chain(&e))?;
        self.subscribe_audio();
        Ok(())
    }
}
