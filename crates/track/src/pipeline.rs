//! The whole per-frame pipeline: detect + track + retarget onto a character, producing the
//! line `mouthpiece process` writes (and the daemon streams).

use mouthpiece_detect::DetectConfig;
use mouthpiece_frame::Frame;
use mouthpiece_retarget::jsonl::OutputLine;
use mouthpiece_retarget::{Character, CharacterRetarget, CharacterSettings, Named, RetargetOutput};
use serde::{Deserialize, Serialize};

use crate::{Status, TrackConfig, TrackError, TrackedFrame, Tracker};

/// The detector's and the tracker's settings: the `[detect]` and `[track]` tables of a
/// configuration file (other tables belong to other parts of mouthpiece and are ignored here).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PipelineConfig {
    #[serde(default)]
    pub detect: DetectConfig,
    #[serde(default)]
    pub track: TrackConfig,
}

impl PipelineConfig {
    /// Parses and validates; errors name the key (`detect.class[0].hue[1]`).
    pub fn from_toml_str(src: &str) -> Result<Self, TrackError> {
        #[derive(Deserialize)]
        struct Sections {
            detect: Option<toml::Value>,
            track: Option<toml::Value>,
        }
        let bad = |key: &str, e: toml::de::Error| TrackError::Config {
            key: key.into(),
            message: e.message().trim().to_string(),
        };
        let sections: Sections = toml::from_str(src).map_err(|e| bad("(file)", e))?;
        let detect = match sections.detect {
            Some(v) => v.try_into().map_err(|e| bad("detect", e))?,
            None => DetectConfig::default(),
        };
        let track = match sections.track {
            Some(v) => v.try_into().map_err(|e| bad("track", e))?,
            None => TrackConfig::default(),
        };
        let config = Self { detect, track };
        config.validate()?;
        Ok(config)
    }

    pub fn validate(&self) -> Result<(), TrackError> {
        self.detect.validate()?;
        self.track.validate()
    }
}

/// `{"seq", "device_ts_us"}` of the input frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrameRef {
    pub seq: u64,
    pub device_ts_us: u64,
}

/// One output line: the retarget output's fields, then `performer` (tracked dots, camera
/// frame, metres, `null` when not seen), `status` and `frame`.
#[derive(Debug, Serialize)]
pub struct ProcessLine<'a> {
    #[serde(flatten)]
    pub retarget: &'a OutputLine,
    pub performer: &'a Named<Option<[f64; 3]>>,
    pub status: &'a Status,
    pub frame: FrameRef,
}

/// Detect + track + retarget, frame by frame.
pub struct Pipeline {
    tracker: Tracker,
    character: Character,
    settings: CharacterSettings,
    retarget: Option<CharacterRetarget>,
    line: OutputLine,
    performer: Named<Option<[f64; 3]>>,
}

impl std::fmt::Debug for Pipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pipeline")
            .field("character", &self.character.name)
            .finish_non_exhaustive()
    }
}

impl Pipeline {
    pub fn new(
        config: PipelineConfig,
        character: Character,
        settings: CharacterSettings,
    ) -> Result<Self, TrackError> {
        let layout = config.track.layout();
        if character.len() != layout.lip_dots {
            return Err(TrackError::Config {
                key: "track.lip_dots".into(),
                message: format!(
                    "the performer wears {} lip dots but character {:?} has {} points",
                    layout.lip_dots,
                    character.name,
                    character.len()
                ),
            });
        }
        settings
            .smoothing
            .validate()
            .map_err(|e| TrackError::Config {
                key: "smoothing".into(),
                message: e.to_string(),
            })?;
        let tracker = Tracker::new(config.detect, config.track)?;
        let line = OutputLine::for_character(&character, &settings.smoothing);
        let performer = Named(
            TrackedFrame::names(layout)
                .into_iter()
                .map(|n| (n, None))
                .collect(),
        );
        Ok(Self {
            tracker,
            character,
            settings,
            retarget: None,
            line,
            performer,
        })
    }

    pub fn tracker(&self) -> &Tracker {
        &self.tracker
    }

    pub fn tracker_mut(&mut self) -> &mut Tracker {
        &mut self.tracker
    }

    /// The character's current output (valid after [`Pipeline::process`]).
    pub fn output(&self) -> &OutputLine {
        &self.line
    }

    /// Processes one frame. Before the first neutral calibration the character rests at its
    /// neutral pose with confidence 0 (and `status.calibrating`).
    pub fn process(
        &mut self,
        frame: &Frame,
    ) -> Result<(ProcessLine<'_>, &TrackedFrame), TrackError> {
        let tracked = self.tracker.process(frame)?;
        if tracked.status.neutral_taken
            || (self.retarget.is_none() && self.tracker.neutral().is_some())
        {
            let neutral = self.tracker.neutral().expect("neutral taken");
            self.retarget = Some(
                CharacterRetarget::new(self.character.clone(), neutral, self.settings)
                    .map_err(TrackError::Neutral)?,
            );
        }
        let tracked = &self.tracker.out;
        match (&mut self.retarget, &tracked.stabilised) {
            (Some(retarget), Some(stabilised)) => {
                let character = retarget.apply(stabilised);
                self.line.update(
                    tracked.seq,
                    &RetargetOutput {
                        performer: stabilised,
                        character,
                    },
                );
            }
            _ => {
                self.line.t = tracked.t;
                self.line.seq = tracked.seq;
                for ((_, dst), p) in self.line.points.0.iter_mut().zip(&self.character.neutral) {
                    *dst = [p.x, p.y, p.z];
                }
                for (_, c) in self.line.confidence.0.iter_mut() {
                    *c = 0.0;
                }
                self.line.head_lost = tracked.status.head_lost;
                if let Some(curve) = &mut self.line.curve {
                    curve.points.clear();
                }
            }
        }
        for ((_, dst), p) in self
            .performer
            .0
            .iter_mut()
            .zip(tracked.dots.lip.iter().chain(&tracked.dots.forehead))
        {
            *dst = p.map(|p| [p.x, p.y, p.z]);
        }
        let line = ProcessLine {
            retarget: &self.line,
            performer: &self.performer,
            status: &tracked.status,
            frame: FrameRef {
                seq: tracked.seq,
                device_ts_us: tracked.device_ts_us,
            },
        };
        Ok((line, tracked))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_sections_are_read_and_checked() {
        let cfg = PipelineConfig::from_toml_str(
            r#"
            [server]
            port = 9000          # someone else's table: ignored here

            [detect]
            dot_radius_m = 0.002

            [track]
            calibration_s = 0.5
            "#,
        )
        .unwrap();
        assert_eq!(cfg.detect.dot_radius_m, 0.002);
        assert_eq!(cfg.track.calibration_s, 0.5);

        let err = PipelineConfig::from_toml_str("[detect]\nradius = 2")
            .unwrap_err()
            .to_string();
        assert!(err.contains("detect") && err.contains("radius"), "{err}");
        let err = PipelineConfig::from_toml_str(
            "[[detect.class]]\nname = \"red\"\nrole = \"any\"\nhue = [[170, 10]]\nsaturation = [100, 255]\nvalue = [50, 255]\n",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("detect.class[0].hue[0]") && err.contains("inverted"),
            "{err}"
        );
        let err = PipelineConfig::from_toml_str("[track]\nforehead_dots = 2")
            .unwrap_err()
            .to_string();
        assert!(err.contains("track.forehead_dots"), "{err}");
    }
}
