//! Neutral calibration: the window of fully named frames, whether the mouth in it is still
//! and closed, the neutral pose from it, and whether the performer after a source restart
//! is the calibrated one.

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
        let interval = if self.frames.len() > 1 {
            self.span() / (self.frames.len() - 1) as f64
        } else {
            0.0
        };
        // 1 ns: the frames' times are sums of intervals; rounding must not cost a frame.
        self.span() + interval >= seconds - 1e-9
    }

    /// Whether the lips, with head motion removed, stayed within `still_tolerance_m` (RMS
    /// wobble at the 75th percentile over the lip dots) over the window, and the mouth is
    /// closed (middle of the upper to middle of the lower lip within `max_opening_ratio` of
    /// the mouth's width).
    pub(crate) fn is_still(
        &self,
        layout: PerformerLayout,
        still_tolerance_m: f64,
        max_opening_ratio: f64,
    ) -> bool {
        let n = layout.lip_dots;
        let first = &self.frames[0].1;
        let reference: Vec<Vec3> = first
            .forehead
            .iter()
            .map(|p| p.expect("complete"))
            .collect();
        let mut sum = vec![Vec3::zeros(); n];
        let mut sum_sq = vec![0.0; n];
        for (_, d) in &self.frames {
            let cur: Vec<Vec3> = d.forehead.iter().map(|p| p.expect("complete")).collect();
            let Some(h) = kabsch(&cur, &reference) else {
                return false;
            };
            for (i, p) in d.lip.iter().enumerate() {
                let q = h.apply(&p.expect("complete"));
                sum[i] += q;
                sum_sq[i] += q.norm_squared();
            }
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
        tracing::trace!(worst_rms_mm = worst * 1e3, opening, "calibration window");
        worst <= still_tolerance_m && opening <= max_opening_ratio
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
