//! The stand-in processor `mouthpiece run` uses until the detection crates (issue 5) land
//! in this branch: [`FramesOnly`] publishes every frame's timing with the characters at rest
//! and confidence 0; it finds no dots and no head pose. Sources are the capture crate's.

use std::time::Duration;

use mouthpiece_frame::Frame;
use mouthpiece_server::{CharacterFrame, CharacterInfo, StreamInfo};

use crate::pipeline::{Output, Processor};

/// Publishes frames with the characters at rest (confidence 0): no detector in this build.
pub struct FramesOnly {
    characters: Vec<mouthpiece_retarget::Character>,
    names: Vec<String>,
    info_changed: bool,
}

impl FramesOnly {
    pub fn new(characters: Vec<mouthpiece_retarget::Character>) -> Self {
        tracing::warn!("no dot detector in this build: characters stay at rest (confidence 0)");
        let names = (1..=12)
            .map(|i| format!("D{i}"))
            .chain((1..=3).map(|i| format!("F{i}")))
            .collect();
        FramesOnly {
            characters,
            names,
            info_changed: true,
        }
    }
}

fn to_f32(v: &nalgebra::Vector3<f64>) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

impl Processor for FramesOnly {
    fn process(&mut self, _frame: &Frame, out: &mut Output) {
        out.flags.calibrating = true;
        out.flags.no_dots = true;
        out.performer_camera.clear();
        out.performer_camera.resize(self.names.len(), None);
        out.stream.performer = None;
        out.stream
            .characters
            .resize_with(self.characters.len(), CharacterFrame::default);
        for (c, slot) in self.characters.iter().zip(out.stream.characters.iter_mut()) {
            if slot.name != c.name {
                slot.name.clone_from(&c.name);
            }
            slot.points.clear();
            slot.points.extend(c.neutral.iter().map(to_f32));
            slot.confidence.clear();
            slot.confidence.resize(c.len(), 0.0);
        }
    }

    fn calibrate(&mut self, _duration: Option<Duration>) {}

    fn stream_info(&self, frame_rate: f64, source: &str) -> StreamInfo {
        StreamInfo {
            characters: self
                .characters
                .iter()
                .map(|c| CharacterInfo {
                    name: c.name.clone(),
                    points: c.point_names.clone(),
                    neutral: c.neutral.iter().map(to_f32).collect(),
                    m: Vec::new(),
                    m_mode: format!("{:?}", c.m_mode).to_lowercase(),
                    units: c
                        .units
                        .map(|u| format!("{u:?}").to_lowercase())
                        .unwrap_or_default(),
                })
                .collect(),
            performer_points: self.names[..12].to_vec(),
            frame_rate,
            source: source.to_owned(),
        }
    }

    fn take_info_changed(&mut self) -> bool {
        std::mem::take(&mut self.info_changed)
    }

    fn performer_names(&self) -> &[String] {
        &self.names
    }

    fn reload(&mut self, update: Box<dyn std::any::Any + Send>) -> Result<(), String> {
        let characters = update
            .downcast::<Vec<mouthpiece_retarget::Character>>()
            .map_err(|_| "internal: wrong reload payload".to_owned())?;
        self.characters = *characters;
        self.info_changed = true;
        Ok(())
    }
}

/// The factory `mouthpiece run` uses until detection lands: the capture crate's sources and
/// [`FramesOnly`] with the configured characters.
#[derive(Debug, Clone, Copy, Default)]
pub struct InterimFactory;

impl crate::daemon::Factory for InterimFactory {
    type Processor = FramesOnly;

    fn processor(
        &self,
        config: &mouthpiece_config::Config,
    ) -> Result<FramesOnly, crate::check::CheckError> {
        Ok(FramesOnly::new(crate::characters::load(config)?))
    }

    fn reload(
        &self,
        config: &mouthpiece_config::Config,
    ) -> Result<Box<dyn std::any::Any + Send>, crate::check::CheckError> {
        Ok(Box::new(crate::characters::load(config)?))
    }

    fn opener(&self, spec: &str, stall_timeout: Duration) -> crate::source::Opener {
        crate::capture::opener(spec, stall_timeout)
    }
}
