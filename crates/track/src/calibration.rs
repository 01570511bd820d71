//! Neutral calibration: the window of fully named frames, whether the mouth in it is still
//! and closed, the neutral pose from it, the check that the pose is the performer's typical
//! closed mouth ([`NeutralCheck`]), and whether the performer after a source restart is the
//! calibrated one.

use std::collections::VecDeque;

use mouthpiece_retarget::kabsch::kabsch;
use mouthpiece_retarget::{NeutralAccumulator, NeutralPose, PerformerDots, PerformerLayout};

use crate::forehead::DepthCrop;
use crate::{TrackError, Vec3};

/// The most frames the calibration window holds (each with a crop of the forehead's depth,
/// about 12 kB at 640x480): beyond it every second frame is dropped, so a long calibration
/// at a high frame rate (or a clock creeping forward by microseconds) stays within a few
/// megabytes. 512 frames are 8.5 s at 60 frames/s.
pub const CALIBRATION_WINDOW_MAX_FRAMES: usize = 512;

/// Share of the lip dots whose wobble must be within the stillness tolerance: the wobble is
/// judged at this quantile over the lip dots (one noisy dot, a mouth corner on a steep
/// surface, must not block calibration; speech moves most dots).
const STILL_QUANTILE: usize = 3; // of 4: the 75th percentile

/// Largest change of any side of the forehead triangle (all pairwise distances between
/// forehead dots; rigid, so the head's pose does not change them) for the performer to
/// count as the calibrated one after a source restart, metres. The sides measured frame to
/// frame vary by 1–2 mm with Kinect-like depth noise on the synthetic performer; dots painted
/// again by hand, or another performer, land several millimetres to centimetres apart.
pub const SAME_PERFORMER_TOLERANCE_M: f64 = 0.005;

/// How much still, closed mouth the neutral-face check surveys before judging the neutral
/// pose, in calibration windows (`calibration_s` each): three, so that a single held
/// expression (a stretched or pursed closed mouth held for a second) is a minority of what
/// the median sees.
pub const NEUTRAL_SURVEY_WINDOWS: f64 = 3.0;

/// How far a neutral pose's mouth width may be from the typical width of the performer's
/// still, closed mouth, as a fraction of it: 0.4 %, so that two neutral poses judged against
/// the same typical width are at most 0.8 % apart (0.45 mm on a 55 mm mouth), and a mouth
/// stretched or pursed by a millimetre or more is refused.
pub const NEUTRAL_WIDTH_TOLERANCE: f64 = 0.004;

/// Most width samples the survey keeps (beyond it every second is dropped): three seconds at
/// 500 frames/s.
const SURVEY_MAX_SAMPLES: usize = 1500;

/// What the neutral-face check concluded ([`NeutralCheck::verdict`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Verdict {
    /// The neutral pose's width is within [`NEUTRAL_WIDTH_TOLERANCE`] of the typical width.
    Typical { typical_m: f64 },
    /// It is not: a new pose is to be taken from a window of about the typical width.
    Atypical { typical_m: f64, neutral_m: f64 },
}

/// The neutral-face criterion, *the typical still, closed mouth*. Stillness and a closed
/// mouth alone do not tell a relaxed mouth from one held stretched or pursed, so the first
/// still, closed window is taken at once (as before) and then checked: every still, closed
/// window from the calibration request on adds its mouth width (weighted by the time it
/// covers), and once they cover [`NEUTRAL_SURVEY_WINDOWS`] windows their weighted median is
/// the performer's typical closed-mouth width. A relaxed mouth is what the closed mouth
/// returns to between expressions, so the median lands on it whatever expressions came
/// first; a pose more than [`NEUTRAL_WIDTH_TOLERANCE`] from it is taken again from the first
/// still, closed window within that tolerance of the typical width.
#[derive(Debug, Default)]
pub(crate) struct NeutralCheck {
    /// (seconds covered, mouth width in metres) of each still, closed window seen.
    samples: Vec<(f64, f64)>,
    covered_s: f64,
    /// The width of the neutral pose being checked.
    neutral_m: Option<f64>,
    /// While a pose is being taken again: the typical width it must be near.
    typical_m: Option<f64>,
}

impl NeutralCheck {
    /// Starts over (a calibration request, another performer).
    pub(crate) fn restart(&mut self) {
        *self = Self::default();
    }

    /// Whether windows are still being surveyed (a pose taken, not yet judged).
    pub(crate) fn surveying(&self) -> bool {
        self.neutral_m.is_some() && self.typical_m.is_none()
    }

    /// A still, closed window of mouth width `width_m`, covering `seconds` more of the
    /// survey (one frame interval).
    pub(crate) fn observe(&mut self, seconds: f64, width_m: f64) {
        if self.typical_m.is_some() {
            return;
        }
        self.samples.push((seconds, width_m));
        self.covered_s += seconds;
        if self.samples.len() > SURVEY_MAX_SAMPLES {
            let mut kept: VecDeque<_> = self.samples.drain(..).collect();
            thin_out(&mut kept);
            // The dropped samples' time goes to their neighbours: the total stays.
            let scale = self.covered_s / kept.iter().map(|s| s.0).sum::<f64>();
            self.samples = kept.into_iter().map(|(w, x)| (w * scale, x)).collect();
        }
    }

    /// Whether a still, closed window of width `width_m` may become the neutral pose: any
    /// may, unless a pose is being taken again, then only one near the typical width.
    pub(crate) fn admits(&self, width_m: f64) -> bool {
        self.typical_m
            .is_none_or(|typical| (width_m - typical).abs() <= NEUTRAL_WIDTH_TOLERANCE * typical)
    }

    /// The neutral pose of width `width_m` was taken. Taken again near the typical width, it
    /// is final; otherwise it is checked.
    pub(crate) fn taken(&mut self, width_m: f64) {
        if self.typical_m.is_some() {
            self.restart();
        } else {
            self.neutral_m = Some(width_m);
        }
    }

    /// Once the survey covers `survey_s`: whether the pose taken is typical. Typical, the
    /// check ends; atypical, [`Self::admits`] from then on only lets windows near the typical
    /// width through.
    pub(crate) fn verdict(&mut self, survey_s: f64) -> Option<Verdict> {
        let neutral_m = self.neutral_m.filter(|_| self.surveying())?;
        // 1 ns: the frame intervals' sum must not miss the survey's end by rounding.
        if self.covered_s < survey_s - 1e-9 {
            return None;
        }
        let typical_m = weighted_median(&self.samples)?;
        if (neutral_m - typical_m).abs() <= NEUTRAL_WIDTH_TOLERANCE * typical_m {
            self.restart();
            Some(Verdict::Typical { typical_m })
        } else {
            self.samples.clear();
            self.typical_m = Some(typical_m);
            Some(Verdict::Atypical {
                typical_m,
                neutral_m,
            })
        }
    }
}

/// The median of `(weight, value)` pairs: the smallest value with at least half the total
/// weight at or below it. `None` for no weight.
pub(crate) fn weighted_median(samples: &[(f64, f64)]) -> Option<f64> {
    let total: f64 = samples.iter().map(|s| s.0).sum();
    // NaN weights count as none.
    if total.is_nan() || total <= 0.0 {
        return None;
    }
    let mut sorted = samples.to_vec();
    sorted.sort_by(|a, b| a.1.total_cmp(&b.1));
    let mut below = 0.0;
    for (w, x) in sorted {
        below += w;
        if below >= 0.5 * total {
            return Some(x);
        }
    }
    None
}

/// Whether the forehead dots `now` (camera frame, all seen) are the neutral pose's
/// (`neutral`, camera frame; a dot unseen at calibration is not compared): every side of
/// the triangle within [`SAME_PERFORMER_TOLERANCE_M`].
pub fn same_performer(neutral: &[Option<Vec3>], now: &[Vec3]) -> bool {
    let n = neutral.len().min(now.len());
    (0..n).all(|a| {
        (a + 1..n).all(|b| match (neutral[a], neutral[b]) {
            (Some(p), Some(q)) => {
                let then = (p - q).norm();
                let here = (now[a] - now[b]).norm();
                (then - here).abs() <= SAME_PERFORMER_TOLERANCE_M
            }
            _ => true,
        })
    })
}

/// Drops every second entry (the first and the last stay): the span is kept, the number of
/// entries halved.
pub(crate) fn thin_out<T>(window: &mut VecDeque<T>) {
    let last = window.len().saturating_sub(1);
    let mut i = 0;
    window.retain(|_| {
        let keep = i % 2 == 0 || i == last;
        i += 1;
        keep
    });
}

/// What a full calibration window shows ([`Window::shape`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct WindowShape {
    /// RMS motion of the lip dots over the window, head motion removed, at the 75th
    /// percentile over the lip dots, metres.
    pub(crate) wobble_m: f64,
    /// Middle of the upper to middle of the lower lip over the mouth's width, in the
    /// window's first frame.
    pub(crate) opening: f64,
    /// Corner to corner, the median over the window's frames, metres.
    pub(crate) width_m: f64,
}

impl WindowShape {
    /// The mouth is still (wobble within `still_tolerance_m`) and closed (opening within
    /// `max_opening_ratio`).
    pub(crate) fn still_and_closed(&self, still_tolerance_m: f64, max_opening_ratio: f64) -> bool {
        self.wobble_m <= still_tolerance_m && self.opening <= max_opening_ratio
    }
}

/// The calibration window: consecutive fully named frames (session time, dots) and, when
/// the forehead surface fit is on, the forehead's depth in each.
#[derive(Debug, Default)]
pub(crate) struct Window {
    pub(crate) frames: VecDeque<(f64, PerformerDots)>,
    pub(crate) crops: VecDeque<DepthCrop>,
}

impl Window {
    pub(crate) fn clear(&mut self) {
        self.frames.clear();
        self.crops.clear();
    }

    fn span(&self) -> f64 {
        self.frames.back().map_or(0.0, |b| b.0) - self.frames.front().map_or(0.0, |f| f.0)
    }

    /// The mean frame interval over the window, seconds (0 for fewer than two frames).
    pub(crate) fn interval(&self) -> f64 {
        if self.frames.len() > 1 {
            self.span() / (self.frames.len() - 1) as f64
        } else {
            0.0
        }
    }

    /// Adds a fully named frame at session time `t` (with the forehead's depth, when the
    /// surface fit is on), keeping just over `seconds` of frames; true once the window spans
    /// `seconds`.
    pub(crate) fn push(
        &mut self,
        t: f64,
        dots: &PerformerDots,
        crop: Option<DepthCrop>,
        seconds: f64,
    ) -> bool {
        // A frame at the window's last moment (a clock standing still) replaces it: the
        // window spans time, not frames.
        if self.frames.back().is_some_and(|(last, _)| *last >= t) {
            self.frames.pop_back();
            self.crops.pop_back();
        }
        self.frames.push_back((t, dots.clone()));
        self.crops.extend(crop);
        // Keep just over the calibration span.
        while self.frames.len() > 2
            && self.span() - (self.frames[1].0 - self.frames[0].0) >= seconds
        {
            self.frames.pop_front();
            self.crops.pop_front();
        }
        if self.frames.len() > CALIBRATION_WINDOW_MAX_FRAMES {
            thin_out(&mut self.frames);
            thin_out(&mut self.crops);
        }
        // One frame interval short of the span is a full second of frames at any rate.
        let interval = self.interval();
        // 1 ns: the frames' times are sums of intervals; rounding must not cost a frame.
        self.span() + interval >= seconds - 1e-9
    }

    /// What the window shows: the lips' wobble with the head's motion removed, how far the
    /// mouth is open and how wide it is; `None` when the head's motion cannot be removed.
    pub(crate) fn shape(&self, layout: PerformerLayout) -> Option<WindowShape> {
        let n = layout.lip_dots;
        let first = &self.frames[0].1;
        let reference: Vec<Vec3> = first
            .forehead
            .iter()
            .map(|p| p.expect("complete"))
            .collect();
        let mut sum = vec![Vec3::zeros(); n];
        let mut sum_sq = vec![0.0; n];
        let mut widths = Vec::with_capacity(self.frames.len());
        for (_, d) in &self.frames {
            let cur: Vec<Vec3> = d.forehead.iter().map(|p| p.expect("complete")).collect();
            let h = kabsch(&cur, &reference)?;
            for (i, p) in d.lip.iter().enumerate() {
                let q = h.apply(&p.expect("complete"));
                sum[i] += q;
                sum_sq[i] += q.norm_squared();
            }
            let corner = |i: usize| d.lip[i].expect("complete");
            widths.push((corner(layout.left_corner()) - corner(layout.right_corner())).norm());
        }
        let m = self.frames.len() as f64;
        let mut wobble: Vec<f64> = (0..n)
            .map(|i| {
                let mean = sum[i] / m;
                (sum_sq[i] / m - mean.norm_squared()).max(0.0).sqrt()
            })
            .collect();
        wobble.sort_by(f64::total_cmp);
        let worst = wobble[(STILL_QUANTILE * (n - 1)) / 4];
        let lip = |i: usize| first.lip[i].expect("complete");
        let width = (lip(layout.left_corner()) - lip(layout.right_corner())).norm();
        let upper_mid = lip(layout.right_corner() / 2);
        let lower_mid = lip((n + layout.right_corner()) / 2);
        // 1 nm: a degenerate mouth must not divide by zero.
        let opening = (upper_mid - lower_mid).norm() / width.max(1e-9);
        widths.sort_by(f64::total_cmp);
        let shape = WindowShape {
            wobble_m: worst,
            opening,
            width_m: widths[widths.len() / 2],
        };
        tracing::trace!(
            worst_rms_mm = worst * 1e3,
            opening,
            width_mm = shape.width_m * 1e3,
            "calibration window"
        );
        Some(shape)
    }

    /// The neutral pose from the window's frames.
    pub(crate) fn neutral(&self, layout: PerformerLayout) -> Result<NeutralPose, TrackError> {
        let mut acc = NeutralAccumulator::new(layout);
        for (_, d) in &self.frames {
            acc.push(d).map_err(TrackError::Neutral)?;
        }
        acc.finish().map_err(TrackError::Neutral)
    }

    /// The forehead's depth in every frame, when the window kept it for each.
    pub(crate) fn crops(&self) -> Option<Vec<&DepthCrop>> {
        (!self.crops.is_empty() && self.crops.len() == self.frames.len())
            .then(|| self.crops.iter().collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FRAME_S: f64 = 1.0 / 30.0;
    const SURVEY_S: f64 = NEUTRAL_SURVEY_WINDOWS * 1.0;

    #[test]
    fn the_weighted_median_holds_half_the_weight() {
        assert_eq!(weighted_median(&[]), None);
        assert_eq!(weighted_median(&[(0.0, 1.0)]), None);
        assert_eq!(
            weighted_median(&[(1.0, 3.0), (1.0, 1.0), (1.0, 2.0)]),
            Some(2.0)
        );
        // One heavy sample outweighs two light ones.
        assert_eq!(
            weighted_median(&[(3.0, 9.0), (1.0, 1.0), (1.0, 2.0)]),
            Some(9.0)
        );
    }

    /// Feeds a calibration from `start` through a session of still, closed windows (`None`:
    /// none that frame), as the tracker does: the first admitted window is taken, checked once
    /// the survey is full and taken again when atypical. The width finally kept.
    fn calibrate_from(session: &[Option<f64>], start: usize) -> Option<f64> {
        let mut check = NeutralCheck::default();
        let (mut calibrating, mut neutral) = (true, None);
        for width in session.iter().cycle().skip(start).take(3 * session.len()) {
            if !calibrating && !check.surveying() {
                return neutral;
            }
            if let Some(w) = *width {
                check.observe(FRAME_S, w);
            }
            if !calibrating {
                if let Some(Verdict::Atypical { .. }) = check.verdict(SURVEY_S) {
                    calibrating = true;
                }
                continue;
            }
            if let Some(w) = width.filter(|w| check.admits(*w)) {
                check.taken(w);
                neutral = Some(w);
                calibrating = false;
            }
        }
        neutral.filter(|_| !calibrating && !check.surveying())
    }

    /// A performer whose closed mouth rests at 55.2 mm between expressions, holds it
    /// stretched (57.3 mm) and pursed (53.0 mm) for a second each, and speaks (no still,
    /// closed window) in between: 20 s at 30 frames/s.
    fn session() -> Vec<Option<f64>> {
        let mut s = Vec::new();
        let mut push = |seconds: f64, width: Option<f64>| {
            for i in 0..(seconds * 30.0) as usize {
                // ±0.1 mm of measurement noise on the width.
                s.push(width.map(|w| w + 1e-4 * ((i as f64) * 1.7).sin()));
            }
        };
        push(1.5, Some(0.0552));
        push(3.0, None);
        push(1.0, Some(0.0573));
        push(1.0, Some(0.0552));
        push(2.5, None);
        push(1.2, Some(0.0530));
        push(2.0, None);
        push(0.8, Some(0.0552));
        push(2.0, None);
        push(1.0, Some(0.0573));
        push(1.5, Some(0.0552));
        push(2.5, None);
        s
    }

    #[test]
    fn a_stretched_closed_mouth_is_taken_again_from_a_typical_one() {
        let session = session();
        // Starting on the stretched mouth (at 4.5 s) takes it first, then the relaxed one.
        let stretched_start = 135;
        let width = calibrate_from(&session, stretched_start).expect("calibrated");
        assert!((width - 0.0552).abs() < 2e-4, "{width}");
        // The neutral lead-in is kept: checked, not taken again.
        let mut check = NeutralCheck::default();
        check.taken(0.0552);
        for w in session.iter().flatten() {
            check.observe(FRAME_S, *w);
            if let Some(v) = check.verdict(SURVEY_S) {
                assert!(matches!(v, Verdict::Typical { .. }), "{v:?}");
                return;
            }
        }
        panic!("never judged");
    }

    /// The criterion's purpose: the same neutral width wherever the calibration starts.
    #[test]
    fn the_neutral_width_does_not_depend_on_where_calibration_starts() {
        let session = session();
        let widths: Vec<f64> = (0..session.len())
            .step_by(15)
            .map(|start| calibrate_from(&session, start).expect("calibrated"))
            .collect();
        let lo = widths.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = widths.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        assert!(hi - lo <= 0.0005, "{:.2} to {:.2} mm", lo * 1e3, hi * 1e3);
        // Without the check the first still, closed window would do: 53.0 to 57.3 mm.
        let first: Vec<f64> = (0..session.len())
            .step_by(15)
            .map(|start| {
                session
                    .iter()
                    .cycle()
                    .skip(start)
                    .flatten()
                    .copied()
                    .next()
                    .unwrap()
            })
            .collect();
        let spread = first.iter().copied().fold(f64::NEG_INFINITY, f64::max)
            - first.iter().copied().fold(f64::INFINITY, f64::min);
        assert!(spread > 0.004, "{spread}");
    }

    #[test]
    fn a_long_survey_is_thinned_keeping_its_time_and_median() {
        let mut check = NeutralCheck::default();
        check.taken(0.055);
        for i in 0..(3 * SURVEY_MAX_SAMPLES) {
            check.observe(1e-3, if i % 3 == 0 { 0.060 } else { 0.055 });
        }
        assert!(check.samples.len() <= SURVEY_MAX_SAMPLES);
        assert!((check.covered_s - 3.0 * SURVEY_MAX_SAMPLES as f64 * 1e-3).abs() < 1e-9);
        assert_eq!(weighted_median(&check.samples), Some(0.055));
    }
}
