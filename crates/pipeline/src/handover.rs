//! Which source drives a character's mouth, camera or speech, and the blend between them
//! (docs/daemon.md, "Speech"): a state machine stepped with the time of each output step
//! (injected, never read from a clock), so it is tested without sleeping.
//!
//! - `off`: the camera alone.
//! - `fallback`: when the lip dots have been lost for longer than `hold`, and speech steps
//!   are coming in, the share of speech rises to 1 over `blend`; when the dots return (or
//!   speech stops) it falls back to 0 over `blend`. The share moves at a bounded rate and
//!   turns around mid-blend, so a handover never jumps; the mix uses a smoothstep of the
//!   share so it starts and ends without a kink.
//! - `always`: speech alone (a booth without a camera).

use serde::{Deserialize, Serialize};

/// How a character's mouth may be driven by speech (`[characters.settings.NAME] speech`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SpeechMode {
    #[default]
    Off,
    Fallback,
    Always,
}

pub use mouthpiece_output::MouthSource;

/// Settings of one character's handover.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandoverSettings {
    pub mode: SpeechMode,
    /// How long the lip dots must be lost before speech takes over, seconds.
    pub hold_s: f64,
    /// How long a handover blends, seconds (0: at once).
    pub blend_s: f64,
}

impl Default for HandoverSettings {
    fn default() -> Self {
        Self {
            mode: SpeechMode::Off,
            hold_s: 0.3,
            blend_s: 0.15,
        }
    }
}

/// The handover of one character.
#[derive(Debug, Clone)]
pub struct Handover {
    settings: HandoverSettings,
    /// When the lip dots were last seen lost from (None: seen).
    lost_since: Option<f64>,
    /// Share of speech, 0 to 1, moving at 1/blend a second.
    share: f64,
    last_t: Option<f64>,
}

/// One step's decision.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mix {
    /// Weight of the speech-driven points (smoothstep of the share): 0 camera, 1 speech.
    pub speech: f64,
    pub source: MouthSource,
}

impl Handover {
    pub fn new(settings: HandoverSettings) -> Self {
        let share = if settings.mode == SpeechMode::Always {
            1.0
        } else {
            0.0
        };
        Self {
            settings,
            lost_since: None,
            share,
            last_t: None,
        }
    }

    pub fn settings(&self) -> &HandoverSettings {
        &self.settings
    }

    /// Steps to time `t` (seconds, non-decreasing; a step back counts as no time passed).
    /// `lips_lost`: the camera does not see the lip dots this step; `speech_live`: speech
    /// steps are arriving (a microphone with recent blocks).
    pub fn step(&mut self, t: f64, lips_lost: bool, speech_live: bool) -> Mix {
        if !t.is_finite() {
            return self.mix();
        }
        let dt = match self.last_t {
            Some(last) if t > last => t - last,
            _ => 0.0,
        };
        self.last_t = Some(self.last_t.map_or(t, |l| l.max(t)));
        let target = match self.settings.mode {
            SpeechMode::Off => 0.0,
            SpeechMode::Always => 1.0,
            SpeechMode::Fallback => {
                if lips_lost {
                    let since = *self.lost_since.get_or_insert(t);
                    if speech_live && t - since >= self.settings.hold_s {
                        1.0
                    } else {
                        0.0
                    }
                } else {
                    self.lost_since = None;
                    0.0
                }
            }
        };
        if self.settings.mode != SpeechMode::Fallback || self.settings.blend_s <= 0.0 {
            self.share = target;
        } else {
            let rate = dt / self.settings.blend_s;
            self.share = if target > self.share {
                (self.share + rate).min(target)
            } else {
                (self.share - rate).max(target)
            };
        }
        self.mix()
    }

    /// The current mix.
    pub fn mix(&self) -> Mix {
        let s = self.share;
        let speech = s * s * (3.0 - 2.0 * s);
        let source = if s <= 0.0 {
            MouthSource::Camera
        } else if s >= 1.0 {
            MouthSource::Speech
        } else {
            MouthSource::Blend
        };
        Mix { speech, source }
    }
}

/// `out = (1 − w) · camera + w · speech`, point by point.
pub fn mix_points(
    camera: &[mouthpiece_retarget::Vec3],
    speech: &[mouthpiece_retarget::Vec3],
    w: f64,
    out: &mut [mouthpiece_retarget::Vec3],
) {
    for ((o, c), s) in out.iter_mut().zip(camera).zip(speech) {
        *o = c * (1.0 - w) + s * w;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fallback() -> Handover {
        Handover::new(HandoverSettings {
            mode: SpeechMode::Fallback,
            hold_s: 0.3,
            blend_s: 0.15,
        })
    }

    /// Steps at 60 per second from `from` for `seconds`; returns (t, mix) per step.
    fn run(h: &mut Handover, from: f64, seconds: f64, lost: bool, live: bool) -> Vec<(f64, Mix)> {
        let n = (seconds * 60.0).round() as usize;
        (0..n)
            .map(|k| {
                let t = from + k as f64 / 60.0;
                (t, h.step(t, lost, live))
            })
            .collect()
    }

    #[test]
    fn off_is_always_the_camera() {
        let mut h = Handover::new(HandoverSettings::default());
        for (_, m) in run(&mut h, 0.0, 2.0, true, true) {
            assert_eq!(m.source, MouthSource::Camera);
            assert_eq!(m.speech, 0.0);
        }
    }

    #[test]
    fn always_is_speech_alone_with_or_without_dots() {
        let mut h = Handover::new(HandoverSettings {
            mode: SpeechMode::Always,
            ..HandoverSettings::default()
        });
        for lost in [false, true] {
            for (_, m) in run(&mut h, 0.0, 1.0, lost, true) {
                assert_eq!((m.source, m.speech), (MouthSource::Speech, 1.0));
            }
        }
    }

    #[test]
    fn fallback_waits_the_hold_then_blends_to_speech_and_back_without_a_jump() {
        let mut h = fallback();
        let seen = run(&mut h, 0.0, 1.0, false, true);
        assert!(seen.iter().all(|(_, m)| m.source == MouthSource::Camera));
        let lost = run(&mut h, 1.0, 1.0, true, true);
        // Camera until the hold has passed.
        for (t, m) in &lost {
            if *t < 1.3 - 1e-9 {
                assert_eq!(m.source, MouthSource::Camera, "t {t}");
            }
        }
        let first_blend = lost
            .iter()
            .find(|(_, m)| m.source != MouthSource::Camera)
            .unwrap();
        assert!(
            (first_blend.0 - 1.3).abs() < 1.0 / 60.0 + 1e-9,
            "{}",
            first_blend.0
        );
        let speech_from = lost
            .iter()
            .find(|(_, m)| m.source == MouthSource::Speech)
            .unwrap()
            .0;
        assert!(
            (speech_from - 1.45).abs() < 1.0 / 60.0 + 1e-9,
            "{speech_from}"
        );
        let back = run(&mut h, 2.0, 0.5, false, true);
        assert_eq!(back[0].1.source, MouthSource::Blend);
        let camera_from = back
            .iter()
            .find(|(_, m)| m.source == MouthSource::Camera)
            .unwrap()
            .0;
        assert!(
            (camera_from - 2.15).abs() < 1.0 / 60.0 + 1e-9,
            "{camera_from}"
        );
        // The weight never moves more than a smoothstep's steepest slope allows per step.
        let all: Vec<f64> = seen
            .iter()
            .chain(&lost)
            .chain(&back)
            .map(|(_, m)| m.speech)
            .collect();
        let bound = 1.5 / 0.15 / 60.0 + 1e-9;
        for w in all.windows(2) {
            assert!((w[1] - w[0]).abs() <= bound, "{} -> {}", w[0], w[1]);
        }
    }

    #[test]
    fn dots_back_mid_blend_turn_it_around_from_where_it_is() {
        let mut h = fallback();
        run(&mut h, 0.0, 0.4, true, true); // lost since 0, speech from 0.3
        let before = h.step(0.4, true, true).speech;
        assert!(before > 0.0 && before < 1.0);
        let after = h.step(0.4 + 1.0 / 60.0, false, true).speech;
        assert!(
            after < before && before - after < 0.2,
            "{before} -> {after}"
        );
    }

    #[test]
    fn no_speech_coming_in_keeps_the_camera() {
        let mut h = fallback();
        for (_, m) in run(&mut h, 0.0, 2.0, true, false) {
            assert_eq!(m.source, MouthSource::Camera);
        }
    }

    #[test]
    fn a_short_loss_shorter_than_the_hold_never_hands_over() {
        let mut h = fallback();
        for k in 0..10 {
            let t0 = k as f64 * 0.5;
            for (_, m) in run(&mut h, t0, 0.25, true, true).into_iter().chain(run(
                &mut h,
                t0 + 0.25,
                0.25,
                false,
                true,
            )) {
                assert_eq!(m.source, MouthSource::Camera);
            }
        }
    }

    #[test]
    fn time_going_back_or_nan_moves_nothing() {
        let mut h = fallback();
        run(&mut h, 0.0, 0.4, true, true);
        let w = h.step(0.4, true, true).speech;
        assert_eq!(h.step(0.1, true, true).speech, w);
        assert_eq!(h.step(f64::NAN, true, true).speech, w);
    }
}
