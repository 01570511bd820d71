//! The one frame pipeline: detect + track + retarget onto one or several characters. Every
//! caller runs it: `mouthpiece process` (the line it writes, [`Pipeline::process`]),
//! `mouthpiece evaluate`, the benchmark and the daemon (which streams every character,
//! [`Pipeline::step`]). Its settings come from one place, [`PipelineConfig`]: the `[detect]`,
//! `[track]` and `[retarget]` tables of a configuration file.
//!
//! - [`live`]: the daemon's step: [`Pipeline::step`] and the mouths from speech filling the
//!   published frame (`mouthpiece_output::StreamFrame`) for every character;
//! - [`quality`]: how good a neutral pose is (the lip wobble of the console's calibration
//!   report);
//! - [`setup`]: the live pipeline's set-up from a daemon configuration (characters, speech);
//! - [`speech`], [`handover`]: the mouths from speech and the handover camera ↔ speech;
//! - [`tune`]: the paint check's proposal from frames, written into a configuration file;
//! - [`wire`]: the retarget core's rig and heads in the output vocabulary (the one
//!   conversion).

pub mod handover;
pub mod live;
pub mod quality;
pub mod setup;
pub mod speech;
pub mod tune;
pub mod wire;

use mouthpiece_config::{ConfigError, ConfigText};
use mouthpiece_detect::DetectConfig;
use mouthpiece_frame::Frame;
use mouthpiece_retarget::jsonl::OutputLine;
use mouthpiece_retarget::{
    Character, CharacterRetarget, CharacterSettings, MovingAverageKind, Named, OneEuroParams,
    RetargetOutput, Rig, RigSettings, ShapeSmoothing,
};
use serde::{Deserialize, Serialize};

use mouthpiece_track::{Status, TrackConfig, TrackError, TrackedFrame, Tracker};

/// The detector's, the tracker's and the retarget's settings: the `[detect]`, `[track]` and
/// `[retarget]` tables of a configuration file (other tables belong to other parts of
/// mouthpiece and are ignored here).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PipelineConfig {
    #[serde(default)]
    pub detect: DetectConfig,
    #[serde(default)]
    pub track: TrackConfig,
    #[serde(default)]
    pub retarget: RetargetSettings,
    /// The rig (`[rig]`, docs/rig.md): hinge placement, range learning and ranges.
    #[serde(default)]
    pub rig: RigSettings,
}

/// Which shape smoothing makes each character's `curve` (`[retarget] smooth`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Smooth {
    /// No curve.
    None,
    /// Plain moving average over `ma_radius` neighbours each side.
    Ma,
    /// Triangular-weighted moving average.
    MaWeighted,
    /// Exponentially weighted moving average (`ma_alpha` per step).
    MaExp,
    /// Savitzky–Golay, 5 points, quadratic.
    Sg5,
    /// Closed uniform cubic B-spline, `samples_per_span` samples per point.
    #[default]
    Bspline,
}

impl Smooth {
    /// Every shape smoothing by the name the configuration file (`[retarget] smooth`) and
    /// the command line (`--smooth`) both use.
    pub const ALL: [(&'static str, Smooth); 6] = [
        ("none", Smooth::None),
        ("ma", Smooth::Ma),
        ("ma-weighted", Smooth::MaWeighted),
        ("ma-exp", Smooth::MaExp),
        ("sg5", Smooth::Sg5),
        ("bspline", Smooth::Bspline),
    ];

    /// The smoothing a name gives, `None` for an unknown name.
    pub fn from_name(name: &str) -> Option<Smooth> {
        Self::ALL.iter().find(|(n, _)| *n == name).map(|&(_, s)| s)
    }
}

/// How the characters' outputs are made (`[retarget]`): the shape smoothing that makes the
/// curve and the optional temporal filter on the points. The same for every character and
/// every caller; `mouthpiece process --smooth` overrides `smooth`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RetargetSettings {
    pub smooth: Smooth,
    /// Moving averages: neighbours on each side.
    pub ma_radius: usize,
    /// Exponential moving average: weight factor per step along the loop, in (0, 1].
    pub ma_alpha: f64,
    /// B-spline: curve samples per span (per character point).
    pub samples_per_span: usize,
    /// One Euro filter on the output points: `[min_cutoff_hz, beta]`; absent: off.
    pub one_euro: Option<[f64; 2]>,
}

impl Default for RetargetSettings {
    fn default() -> Self {
        Self {
            smooth: Smooth::Bspline,
            ma_radius: 1,
            ma_alpha: 0.5,
            samples_per_span: 8,
            one_euro: None,
        }
    }
}

impl RetargetSettings {
    /// The shape smoothing these settings name.
    pub fn smoothing(&self) -> ShapeSmoothing {
        match self.smooth {
            Smooth::None => ShapeSmoothing::None,
            Smooth::Ma => ShapeSmoothing::MovingAverage {
                kind: MovingAverageKind::Plain,
                radius: self.ma_radius,
            },
            Smooth::MaWeighted => ShapeSmoothing::MovingAverage {
                kind: MovingAverageKind::Weighted,
                radius: self.ma_radius,
            },
            Smooth::MaExp => ShapeSmoothing::MovingAverage {
                kind: MovingAverageKind::Exponential {
                    alpha: self.ma_alpha,
                },
                radius: self.ma_radius,
            },
            Smooth::Sg5 => ShapeSmoothing::SavitzkyGolay5,
            Smooth::Bspline => ShapeSmoothing::BSpline {
                samples_per_span: self.samples_per_span,
            },
        }
    }

    /// The retarget core's per-character settings.
    pub fn character_settings(&self) -> CharacterSettings {
        CharacterSettings {
            smoothing: self.smoothing(),
            one_euro: self.one_euro.map(|[min_cutoff, beta]| OneEuroParams {
                min_cutoff,
                beta,
                d_cutoff: mouthpiece_track::ONE_EURO_DERIVATIVE_CUTOFF_HZ,
            }),
        }
    }

    /// Errors name the key (`retarget.ma_alpha`).
    pub fn validate(&self) -> Result<(), TrackError> {
        let bad = |key: &str, message: String| {
            Err(TrackError::Config {
                key: format!("retarget.{key}"),
                message,
            })
        };
        if let Some([min_cutoff, beta]) = self.one_euro {
            // The retarget core's one rule for the filter's parameters.
            if let Err(e) = OneEuroParams::new(min_cutoff, beta) {
                return bad("one_euro", format!("[{min_cutoff}, {beta}]: {e}"));
            }
        }
        if let Err(e) = self.smoothing().validate() {
            let key = match self.smooth {
                Smooth::MaExp if !(self.ma_alpha > 0.0 && self.ma_alpha <= 1.0) => "ma_alpha",
                Smooth::Ma | Smooth::MaWeighted | Smooth::MaExp => "ma_radius",
                Smooth::Bspline => "samples_per_span",
                _ => "smooth",
            };
            return bad(key, e.to_string());
        }
        Ok(())
    }
}

impl PipelineConfig {
    /// The `[detect]`, `[track]`, `[retarget]` and `[rig]` tables of a configuration file,
    /// read by the one configuration loader (`mouthpiece_config::ConfigText`, which the
    /// daemon's configuration holds too) and checked: every error names the file, the line
    /// and the key (``booth.toml:12:1: key `detect.class[0].hue[0]`: …``).
    pub fn from_text(text: &ConfigText) -> Result<Self, ConfigError> {
        #[derive(Deserialize)]
        struct Sections {
            #[serde(default)]
            detect: DetectConfig,
            #[serde(default)]
            track: TrackConfig,
            #[serde(default)]
            retarget: RetargetSettings,
            #[serde(default)]
            rig: RigSettings,
        }
        let sections: Sections = text.extract()?;
        let config = Self {
            detect: sections.detect,
            track: sections.track,
            retarget: sections.retarget,
            rig: sections.rig,
        };
        config.validate().map_err(|e| match e {
            TrackError::Config { key, message } => text.invalid(&key, message),
            other => text.invalid("detect", other.to_string()),
        })?;
        Ok(config)
    }

    /// Reads a configuration file with [`Self::from_text`]; no file: the defaults.
    pub fn load(path: Option<&std::path::Path>) -> Result<Self, ConfigError> {
        match path {
            Some(path) => Self::from_text(&ConfigText::read(path)?),
            None => Ok(Self::default()),
        }
    }

    /// [`Self::from_text`] on text in memory (errors name it `<configuration>`).
    pub fn from_toml_str(src: &str) -> Result<Self, ConfigError> {
        Self::from_text(&ConfigText::new(
            std::path::Path::new("<configuration>"),
            src,
        ))
    }

    pub fn validate(&self) -> Result<(), TrackError> {
        self.detect.validate()?;
        self.track.validate()?;
        self.retarget.validate()?;
        self.rig.validate("rig").map_err(rig_config_error)
    }

    /// A character fits when it has one point per lip dot; the error names the character.
    pub fn check_character(&self, character: &Character) -> Result<(), TrackError> {
        let layout = self.track.layout();
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
        Ok(())
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
    /// The performer's rig (docs/rig.md), once the neutral pose is taken; its figures are in
    /// `retarget.rig`.
    #[serde(skip)]
    pub rig: Option<&'a Rig>,
}

fn no_character() -> TrackError {
    TrackError::Config {
        key: "characters".into(),
        message: "the pipeline needs at least one character".into(),
    }
}

/// Detect + track + retarget, frame by frame, for one or several characters.
pub struct Pipeline {
    tracker: Tracker,
    characters: Vec<Character>,
    settings: CharacterSettings,
    /// One per character once the neutral pose is taken (`None`: it could not be bound);
    /// empty before.
    bound: Vec<Option<CharacterRetarget>>,
    /// The characters were bound to a new neutral pose since [`Pipeline::take_rebound`].
    rebound: bool,
    /// The first character's output line ([`Pipeline::process`]).
    line: OutputLine,
    performer: Named<Option<[f64; 3]>>,
    /// The performer's rig (docs/rig.md), once the neutral pose is taken.
    rig_settings: RigSettings,
    rig: Option<Rig>,
    /// Viewpoints set with [`Pipeline::look_at`], by character name: kept across new
    /// neutral poses and reloads.
    viewpoints: Vec<(String, mouthpiece_retarget::Vec3)>,
}

impl std::fmt::Debug for Pipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let names: Vec<&str> = self.characters.iter().map(|c| c.name.as_str()).collect();
        f.debug_struct("Pipeline")
            .field("characters", &names)
            .finish_non_exhaustive()
    }
}

impl Pipeline {
    /// One character with these retarget settings (`config.retarget` is not used).
    pub fn new(
        config: PipelineConfig,
        character: Character,
        settings: CharacterSettings,
    ) -> Result<Self, TrackError> {
        Self::build(config, vec![character], settings)
    }

    /// Every character, with `config.retarget`'s settings (the daemon).
    pub fn for_characters(
        config: PipelineConfig,
        characters: Vec<Character>,
    ) -> Result<Self, TrackError> {
        config.retarget.validate()?;
        let settings = config.retarget.character_settings();
        Self::build(config, characters, settings)
    }

    fn build(
        config: PipelineConfig,
        characters: Vec<Character>,
        settings: CharacterSettings,
    ) -> Result<Self, TrackError> {
        let layout = config.track.layout();
        for character in &characters {
            config.check_character(character)?;
        }
        settings
            .smoothing
            .validate()
            .map_err(|e| TrackError::Config {
                key: "retarget.smooth".into(),
                message: e.to_string(),
            })?;
        let rig_settings = config.rig;
        let tracker = Tracker::new(config.detect, config.track)?;
        let Some(first) = characters.first() else {
            return Err(no_character());
        };
        let line = OutputLine::for_character(first, &settings.smoothing);
        let performer = Named(
            TrackedFrame::names(layout)
                .into_iter()
                .map(|n| (n, None))
                .collect(),
        );
        Ok(Self {
            tracker,
            characters,
            settings,
            bound: Vec::new(),
            rebound: false,
            line,
            performer,
            rig_settings,
            rig: None,
            viewpoints: Vec::new(),
        })
    }

    /// The performer's rig (after calibration).
    pub fn rig(&self) -> Option<&Rig> {
        self.rig.as_ref()
    }

    /// New rig settings (a reload of `[rig]`): the rig is rebuilt on the current neutral pose
    /// at once, so a new hinge or a set range applies from the next frame; ranges not set are
    /// learned again over `learn_s` from then on.
    pub fn set_rig_settings(&mut self, settings: RigSettings) -> Result<(), TrackError> {
        settings.validate("rig").map_err(rig_config_error)?;
        if let Some(neutral) = self.tracker.neutral() {
            self.rig = match Rig::new(neutral, settings.clone()) {
                Ok(rig) => Some(rig),
                Err(e) => {
                    tracing::error!("no rig for this neutral pose: {e}");
                    None
                }
            };
        }
        self.rig_settings = settings;
        Ok(())
    }

    pub fn tracker(&self) -> &Tracker {
        &self.tracker
    }

    pub fn tracker_mut(&mut self) -> &mut Tracker {
        &mut self.tracker
    }

    /// The characters, in the order they were given.
    pub fn characters(&self) -> &[Character] {
        &self.characters
    }

    /// Per character, its binding to the neutral pose (`None` before calibration).
    pub fn bound(&self, index: usize) -> Option<&CharacterRetarget> {
        self.bound.get(index).and_then(Option::as_ref)
    }

    /// The retarget settings every character uses.
    pub fn settings(&self) -> &CharacterSettings {
        &self.settings
    }

    /// The last frame the tracker made (after [`Pipeline::step`]).
    pub fn tracked(&self) -> &TrackedFrame {
        self.tracker.last()
    }

    /// Turns `character`'s head to `point` (its model frame), or back to following the
    /// performer (`None`). Returns whether the point is in reach (`None` when following).
    /// Kept when the characters are bound to a new neutral pose.
    pub fn look_at(
        &mut self,
        character: &str,
        point: Option<mouthpiece_retarget::Vec3>,
    ) -> Result<Option<bool>, TrackError> {
        let Some(index) = self.characters.iter().position(|c| c.name == character) else {
            let known: Vec<&str> = self.characters.iter().map(|c| c.name.as_str()).collect();
            return Err(TrackError::Config {
                key: "look_at.character".into(),
                message: format!(
                    "unknown character {character:?} (available: {})",
                    known.join(", ")
                ),
            });
        };
        let bad = |e: mouthpiece_retarget::Error| TrackError::Config {
            key: "look_at.point".into(),
            message: e.to_string(),
        };
        // Checked on a fresh driver first, so a refused point changes nothing.
        let in_reach = self.characters[index]
            .head_driver()
            .look_at(point)
            .map_err(bad)?;
        self.viewpoints.retain(|(name, _)| name != character);
        if let Some(p) = point {
            self.viewpoints.push((character.to_owned(), p));
        }
        if let Some(Some(bound)) = self.bound.get_mut(index) {
            bound.look_at(point).map_err(bad)?;
        }
        Ok(in_reach)
    }

    /// Whether the characters were bound to a new neutral pose since the last call.
    pub fn take_rebound(&mut self) -> bool {
        std::mem::take(&mut self.rebound)
    }

    /// New characters (a reload), bound to the current neutral pose if there is one.
    pub fn set_characters(
        &mut self,
        characters: Vec<Character>,
        settings: CharacterSettings,
    ) -> Result<(), TrackError> {
        let layout = self.tracker.layout();
        for c in &characters {
            if c.len() != layout.lip_dots {
                return Err(TrackError::Config {
                    key: "track.lip_dots".into(),
                    message: format!(
                        "the performer wears {} lip dots but character {:?} has {} points",
                        layout.lip_dots,
                        c.name,
                        c.len()
                    ),
                });
            }
        }
        let Some(first) = characters.first() else {
            return Err(no_character());
        };
        self.line = OutputLine::for_character(first, &settings.smoothing);
        self.characters = characters;
        self.settings = settings;
        self.bound.clear();
        // A character that cannot be bound is logged and left out; the others run.
        let _ = self.bind();
        Ok(())
    }

    /// Binds every character to the tracker's neutral pose; a character that cannot be
    /// bound is left out (logged) and the first such error returned.
    fn bind(&mut self) -> Result<(), TrackError> {
        let Some(neutral) = self.tracker.neutral() else {
            self.bound.clear();
            self.rig = None;
            return Ok(());
        };
        self.rig = match Rig::new(neutral, self.rig_settings.clone()) {
            Ok(rig) => Some(rig),
            Err(e) => {
                tracing::error!("no rig for this neutral pose: {e}");
                None
            }
        };
        let mut first_error = None;
        self.bound = self
            .characters
            .iter()
            .map(
                |c| match CharacterRetarget::new(c.clone(), neutral, self.settings) {
                    Ok(bound) => Some(bound),
                    Err(e) => {
                        tracing::error!(character = %c.name, "cannot bind character: {e}");
                        first_error.get_or_insert(TrackError::Neutral(e));
                        None
                    }
                },
            )
            .collect();
        for (name, point) in &self.viewpoints {
            let at = self.characters.iter().position(|c| &c.name == name);
            if let Some(Some(bound)) = at.and_then(|i| self.bound.get_mut(i)) {
                // Checked when it was set; a reloaded character may refuse it.
                if let Err(e) = bound.look_at(Some(*point)) {
                    tracing::warn!(character = %name, "viewpoint dropped: {e}");
                }
            }
        }
        self.rebound = true;
        first_error.map_or(Ok(()), Err)
    }

    /// Detect, track, and move every character (bound once the neutral pose is taken).
    /// The results: [`Pipeline::tracked`] and each [`Pipeline::bound`]'s output.
    pub fn step(&mut self, frame: &Frame) -> Result<(), TrackError> {
        let tracked = self.tracker.process(frame)?;
        if tracked.status.neutral_taken
            || (self.bound.is_empty() && self.tracker.neutral().is_some())
        {
            self.bind()?;
        }
        if let Some(stabilised) = &self.tracker.last().stabilised {
            for bound in self.bound.iter_mut().flatten() {
                bound.apply(stabilised);
            }
            if let Some(rig) = &mut self.rig {
                rig.step(stabilised);
            }
        }
        Ok(())
    }

    /// The first character's output (valid after [`Pipeline::process`]).
    pub fn output(&self) -> &OutputLine {
        &self.line
    }

    /// Processes one frame into the line `mouthpiece process` writes, for the first
    /// character. Before the first neutral calibration the character rests at its neutral
    /// pose with confidence 0 (and `status.calibrating`).
    pub fn process(
        &mut self,
        frame: &Frame,
    ) -> Result<(ProcessLine<'_>, &TrackedFrame), TrackError> {
        self.step(frame)?;
        let tracked = self.tracker.last();
        let first = self.bound.first().and_then(Option::as_ref);
        match (first, &tracked.stabilised) {
            (Some(bound), Some(stabilised)) => {
                self.line.update(
                    tracked.seq,
                    &RetargetOutput {
                        performer: stabilised,
                        character: bound.output(),
                    },
                );
                if let Some(rig) = &self.rig {
                    // With the character's own ranges where it has them (docs/rig.md).
                    rig.output_for(
                        &bound.character().rig_ranges,
                        self.line.rig.get_or_insert_with(Default::default),
                    );
                }
            }
            _ => {
                self.line.t = tracked.t;
                self.line.seq = tracked.seq;
                if let Some(character) = self.characters.first() {
                    for ((_, dst), p) in self.line.points.0.iter_mut().zip(&character.neutral) {
                        *dst = [p.x, p.y, p.z];
                    }
                }
                for (_, c) in self.line.confidence.0.iter_mut() {
                    *c = 0.0;
                }
                self.line.head_lost = tracked.status.head_lost;
                if let Some(curve) = &mut self.line.curve {
                    curve.points.clear();
                }
                self.line.rig = None;
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
            rig: self.rig.as_ref(),
        };
        Ok((line, tracked))
    }
}

/// A `[rig]` settings error as a configuration error naming its key.
fn rig_config_error(e: mouthpiece_retarget::Error) -> TrackError {
    match e {
        mouthpiece_retarget::Error::InvalidSetting { key, reason } => TrackError::Config {
            key,
            message: reason,
        },
        e => TrackError::Config {
            key: "rig".into(),
            message: e.to_string(),
        },
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
        for (text, key) in [
            ("nose_bridge_reach = 1.5", "track.nose_bridge_reach"),
            ("nose_bridge_reach = -0.1", "track.nose_bridge_reach"),
            ("head_filter_accel = [0.05, 0.0]", "track.head_filter_accel"),
            (
                "head_filter_accel = [-1.0, 0.003]",
                "track.head_filter_accel",
            ),
        ] {
            let err = PipelineConfig::from_toml_str(&format!("[track]\n{text}\n"))
                .unwrap_err()
                .to_string();
            assert!(err.contains(key), "{text}: {err}");
        }
        let off = PipelineConfig::from_toml_str("[track]\nhead_filter_accel = [0, 0]\n");
        assert_eq!(off.unwrap().track.head_filter_accel, [0.0, 0.0]);
    }

    /// A file of before the thresholds were in dot spacings still sets `min_gate_px` or
    /// `roi_margin_px`: refused, the error at that key's line and naming the key that
    /// replaced it; the new keys read.
    #[test]
    fn the_pixel_keys_are_refused_naming_the_keys_in_dot_spacings() {
        for (old, new) in [
            ("min_gate_px", "track.min_gate_spacings"),
            ("roi_margin_px", "track.roi_margin_spacings"),
        ] {
            let text = format!("[track]\ncalibration_s = 1.0\n{old} = 2.5\n");
            let err = PipelineConfig::from_toml_str(&text)
                .unwrap_err()
                .to_string();
            assert!(
                err.contains(&format!(":3:1: key `track.{old}`")) && err.contains(new),
                "{err}"
            );
        }
        let cfg = PipelineConfig::from_toml_str(
            "[track]\nmin_gate_spacings = 0.5\nroi_margin_spacings = 3.0\n",
        )
        .unwrap();
        assert_eq!(cfg.track.min_gate_spacings, 0.5);
        assert_eq!(cfg.track.roi_margin_spacings, 3.0);
        let err = PipelineConfig::from_toml_str("[track]\nmin_gate_spacings = 0\n")
            .unwrap_err()
            .to_string();
        assert!(err.contains("track.min_gate_spacings"), "{err}");
    }

    /// `[retarget]` configures every caller's smoothing; bad values name their key.
    #[test]
    fn retarget_settings_are_read_and_checked() {
        let cfg = PipelineConfig::from_toml_str(
            "[retarget]\nsmooth = \"ma-exp\"\nma_alpha = 0.25\none_euro = [1.0, 0.007]\n",
        )
        .unwrap();
        let settings = cfg.retarget.character_settings();
        assert_eq!(
            settings.smoothing,
            ShapeSmoothing::MovingAverage {
                kind: MovingAverageKind::Exponential { alpha: 0.25 },
                radius: 1
            }
        );
        assert_eq!(settings.one_euro.unwrap().min_cutoff, 1.0);
        assert_eq!(
            PipelineConfig::default()
                .retarget
                .character_settings()
                .smoothing,
            ShapeSmoothing::BSpline {
                samples_per_span: 8
            }
        );
        for (text, key) in [
            ("smooth = \"ma-exp\"\nma_alpha = 1.5", "retarget.ma_alpha"),
            ("one_euro = [0.0, 0.1]", "retarget.one_euro"),
            ("samples_per_span = 0", "retarget.samples_per_span"),
            (
                "samples_per_span = 1000000000000",
                "retarget.samples_per_span",
            ),
            (
                "smooth = \"ma\"\nma_radius = 1000000000",
                "retarget.ma_radius",
            ),
            ("smooth = \"spline\"", "retarget"),
        ] {
            let err = PipelineConfig::from_toml_str(&format!("[retarget]\n{text}\n"))
                .unwrap_err()
                .to_string();
            assert!(err.contains(key), "{text}: {err}");
        }
    }

    /// The command line's names are the file's: each parses as `[retarget] smooth`.
    #[test]
    fn smoothing_names_are_the_files() {
        for (name, smooth) in Smooth::ALL {
            let cfg = PipelineConfig::from_toml_str(&format!("[retarget]\nsmooth = \"{name}\"\n"))
                .unwrap();
            assert_eq!(cfg.retarget.smooth, smooth, "{name}");
            assert_eq!(Smooth::from_name(name), Some(smooth));
        }
        assert_eq!(Smooth::from_name("gaussian"), None);
    }

    #[test]
    fn the_example_config_lists_the_defaults() {
        // config/mouthpiece.toml documents every [detect], [track] and [retarget] key with its
        // default.
        let text = include_str!("../../../config/mouthpiece.toml");
        let config = PipelineConfig::from_toml_str(text).unwrap();
        assert_eq!(config.detect, DetectConfig::default());
        assert_eq!(config.track, TrackConfig::default());
        assert_eq!(config.retarget, RetargetSettings::default());
    }
}
