//! The mouth from speech for every character: the live analyser fed with sound blocks as
//! they come, and per character the speech-driven points and the handover that mixes them
//! into the camera's step (docs/daemon.md, "Speech"). The caller steps it with each output
//! step's time and the host time of that step (both injected: no clock is read here).

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use mouthpiece_frame::audio::AudioBlock;
use mouthpiece_lipsync::live::{LiveAnalyser, LiveMouth, LiveSettings, LiveStep, Profiles};
use mouthpiece_lipsync::take::{Source, Tables, TakeError, DEFAULT_CLASSES, DEFAULT_CLASSES_NAME};
use mouthpiece_lipsync::take::{DEFAULT_POSES, DEFAULT_POSES_NAME};
use mouthpiece_output::MouthSource;
use mouthpiece_retarget::rig::{Rig, RigSettings};
use mouthpiece_retarget::smooth::smooth_closed;
use mouthpiece_retarget::{Character, CharacterSettings, CharacterStep, Vec3};

use crate::handover::{mix_points, Handover, HandoverSettings, SpeechMode};

/// Live lip-sync profiles (the analyser's per-class statistics).
pub use mouthpiece_lipsync::live::Profiles as LiveProfiles;

/// Speech counts as coming in while its newest step is at most this old.
pub const SPEECH_STALE: Duration = Duration::from_millis(250);

/// Steps per second of sound when speech alone drives every character (no camera timing
/// the steps): the analyser's steps taken at this rate by the sound's own sample clock.
pub const SPEECH_ALONE_RATE_HZ: f64 = 50.0;

/// Speech-alone steps held until the caller takes them (2 s at the rate above); beyond
/// this the oldest is dropped.
const ALONE_QUEUE: usize = 100;

/// One step of sound for a booth driven by speech alone.
#[derive(Debug, Clone)]
pub struct AloneStep {
    /// Stream time of the sound, seconds since the sound stream's first sample.
    pub t: f64,
    /// Host time at which that sound was captured.
    pub heard_at: Instant,
    /// The mouth's key-pose weights.
    pub weights: Vec<f64>,
}

struct Mouth {
    mouth: LiveMouth,
    handover: Handover,
    mixed: Vec<Vec3>,
    /// The rig measured on the speech-driven performer dots, as `mouthpiece lipsync` does:
    /// jaw, curves and visemes for a step speech alone drives; `None` for a layout the rig
    /// cannot measure.
    rig: Option<Rig>,
    /// The share of speech in the last [`SpeechDriver::drive`]n step (0: the camera alone).
    share: f64,
}

impl Mouth {
    /// The speech-driven mouth at time `t` for `weights`, and the rig measured on its dots.
    fn step(&mut self, tables: &Tables, t: f64, weights: &[f64]) {
        self.mouth.step(tables, t, weights);
        if let Some(rig) = &mut self.rig {
            rig.step(self.mouth.performer());
        }
    }
}

/// The analyser and one mouth and handover per character.
pub struct SpeechDriver {
    analyser: LiveAnalyser,
    tables: Tables,
    mouths: Vec<Mouth>,
    steps: Vec<LiveStep>,
    /// The newest step's weights and the host time of its sound.
    latest: Option<(Vec<f64>, Instant)>,
    /// Every character is `always`: steps are also queued at [`SPEECH_ALONE_RATE_HZ`].
    alone: bool,
    queued: VecDeque<AloneStep>,
    /// Stream time of the next speech-alone step.
    next_alone: f64,
}

/// Why a live lip-sync profile file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ProfilesError {
    #[error("cannot read live lip-sync profiles {file}")]
    Read {
        file: String,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    Invalid(#[from] mouthpiece_lipsync::Error),
    #[error("{file}: no class has a profile")]
    Empty { file: String },
}

/// Reads a profile file (`mouthpiece lipsync learn`) and checks it against the shipped class
/// table: a missing, oversized or malformed file, or a class the table lacks, is an error
/// naming the file.
pub fn load_profiles(path: &std::path::Path) -> Result<Profiles, ProfilesError> {
    use mouthpiece_lipsync::live::profiles::MAX_PROFILE_BYTES;
    use std::io::Read;
    let name = path.display().to_string();
    let mut text = String::new();
    std::fs::File::open(path)
        .and_then(|f| {
            f.take(MAX_PROFILE_BYTES as u64 + 1)
                .read_to_string(&mut text)
        })
        .map_err(|source| ProfilesError::Read {
            file: name.clone(),
            source,
        })?;
    let profiles = Profiles::from_toml_str(&text, &name)?;
    let table =
        mouthpiece_lipsync::ClassTable::from_toml_str(DEFAULT_CLASSES, DEFAULT_CLASSES_NAME)?;
    profiles.bind(&table, &name)?;
    if profiles.classes.is_empty() {
        return Err(ProfilesError::Empty { file: name });
    }
    Ok(profiles)
}

/// A character that cannot be driven by the shipped poses, or damaged shipped tables.
#[derive(Debug, thiserror::Error)]
pub enum SpeechError {
    #[error(transparent)]
    Take(#[from] TakeError),
    #[error(transparent)]
    Tables(#[from] mouthpiece_lipsync::Error),
}

impl SpeechDriver {
    /// The shipped class table, poses and profiles, and one mouth per character with its
    /// handover settings and output settings.
    pub fn new(
        characters: &[(Character, HandoverSettings)],
        output: CharacterSettings,
    ) -> Result<Self, SpeechError> {
        Self::with_profiles(characters, output, None)
    }

    /// As [`SpeechDriver::new`], with the analyser's profiles given (a booth's own, from
    /// [`load_profiles`]) instead of the shipped ones when `profiles` is `Some`.
    pub fn with_profiles(
        characters: &[(Character, HandoverSettings)],
        output: CharacterSettings,
        profiles: Option<&Profiles>,
    ) -> Result<Self, SpeechError> {
        let tables = Tables::parse(
            Source {
                text: DEFAULT_CLASSES,
                name: DEFAULT_CLASSES_NAME,
            },
            Source {
                text: DEFAULT_POSES,
                name: DEFAULT_POSES_NAME,
            },
            None,
        )?;
        let shipped;
        let profiles = match profiles {
            Some(p) => p,
            None => {
                shipped = Profiles::from_toml_str(
                    mouthpiece_lipsync::live::SHIPPED_PROFILES,
                    "config/lipsync/live_profiles.toml",
                )?;
                &shipped
            }
        };
        let analyser =
            LiveAnalyser::new(tables.classes.clone(), profiles, LiveSettings::default())?;
        let mouths = characters
            .iter()
            .map(|(c, h)| {
                let mouth = LiveMouth::new(&tables, c.clone(), &c.name, output)?;
                let rig = Rig::new(mouth.neutral(), RigSettings::default()).ok();
                Ok(Mouth {
                    mouth,
                    handover: Handover::new(*h),
                    mixed: Vec::with_capacity(c.len()),
                    rig,
                    share: 0.0,
                })
            })
            .collect::<Result<_, TakeError>>()?;
        Ok(Self {
            analyser,
            tables,
            mouths,
            steps: Vec::new(),
            latest: None,
            alone: !characters.is_empty()
                && characters.iter().all(|(_, h)| h.mode == SpeechMode::Always),
            queued: VecDeque::new(),
            next_alone: 0.0,
        })
    }

    /// Analyses a block; the newest step becomes the speech mouth.
    pub fn push_audio(&mut self, block: &AudioBlock) -> Result<(), mouthpiece_lipsync::Error> {
        self.steps.clear();
        self.analyser.push(block, &mut self.steps)?;
        if let Some(s) = self.steps.last() {
            match &mut self.latest {
                Some((w, at)) => {
                    w.clone_from(&s.weights);
                    *at = s.heard_at;
                }
                None => self.latest = Some((s.weights.clone(), s.heard_at)),
            }
        }
        if self.alone {
            for s in &self.steps {
                // A stream that started again (its clock back at zero) starts the ticks again.
                if s.t + 1.0 < self.next_alone {
                    self.next_alone = 0.0;
                }
                if s.t < self.next_alone {
                    continue;
                }
                self.next_alone =
                    ((s.t * SPEECH_ALONE_RATE_HZ).floor() + 1.0) / SPEECH_ALONE_RATE_HZ;
                if self.queued.len() == ALONE_QUEUE {
                    self.queued.pop_front();
                }
                self.queued.push_back(AloneStep {
                    t: s.t,
                    heard_at: s.heard_at,
                    weights: s.weights.clone(),
                });
            }
        }
        Ok(())
    }

    /// True when every character is `always` (speech alone may time the steps).
    pub fn is_alone(&self) -> bool {
        self.alone
    }

    /// The oldest speech-alone step not yet taken (only when [`Self::is_alone`]).
    pub fn pop_alone(&mut self) -> Option<AloneStep> {
        self.queued.pop_front()
    }

    /// The rig on character `k`'s speech-driven dots and the share of speech in its last
    /// [`SpeechDriver::drive`]n step, when speech had a share in it; `None` when the camera
    /// alone drove it (or the rig cannot measure the layout).
    pub fn speech_rig(&self, k: usize) -> Option<(&Rig, f64)> {
        let m = self.mouths.get(k)?;
        if m.share <= 0.0 {
            return None;
        }
        Some((m.rig.as_ref()?, m.share))
    }

    /// Character `k`'s mouth from speech alone at stream time `t` (no camera step to mix),
    /// and the rig measured on the speech-driven performer dots.
    pub fn mouth_alone(
        &mut self,
        k: usize,
        t: f64,
        weights: &[f64],
    ) -> Option<(&CharacterStep, Option<&Rig>)> {
        let m = self.mouths.get_mut(k)?;
        m.step(&self.tables, t, weights);
        Some((m.mouth.output(), m.rig.as_ref()))
    }

    /// The class heard last (the class table's index), if any sound came.
    pub fn latest_weights(&self) -> Option<&[f64]> {
        self.latest.as_ref().map(|(w, _)| w.as_slice())
    }

    /// Character `k`'s step at time `t` (seconds) and host time `now`: mixes the speech
    /// mouth into `step` as the handover says; returns what drove it. `lips_lost`: the camera
    /// does not see this step's lip dots. `smoothing` remakes the curve of a mixed step.
    pub fn drive(
        &mut self,
        k: usize,
        t: f64,
        now: Instant,
        lips_lost: bool,
        smoothing: &mouthpiece_retarget::ShapeSmoothing,
        step: &mut CharacterStep,
    ) -> MouthSource {
        let Some(m) = self.mouths.get_mut(k) else {
            return MouthSource::Camera;
        };
        let live = self
            .latest
            .as_ref()
            .is_some_and(|(_, at)| now.saturating_duration_since(*at) <= SPEECH_STALE);
        let mix = m.handover.step(t, lips_lost, live);
        m.share = mix.speech.max(0.0);
        if mix.speech <= 0.0 {
            return mix.source;
        }
        let neutral = vec![0.0; self.tables.classes.poses.len()];
        let weights = self.latest.as_ref().map_or(&neutral, |(w, _)| w);
        m.step(&self.tables, t, weights);
        let speech = m.mouth.output();
        m.mixed.clear();
        m.mixed.resize(step.points.len(), Vec3::zeros());
        mix_points(&step.points, &speech.points, mix.speech, &mut m.mixed);
        step.points.clone_from(&m.mixed);
        for c in &mut step.confidence {
            *c = *c * (1.0 - mix.speech) + mix.speech;
        }
        smooth_closed(&step.points, smoothing, &mut step.curve);
        mix.source
    }
}
