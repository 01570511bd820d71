//! Where the dots are expected in this frame: each dot's track (last pixel and pixel
//! velocity, last place and velocity in the reference head pose, last depth), the
//! predictions and gates the naming assigns against, the detector's search region, and the
//! tracks' update once a frame is named.

use mouthpiece_detect::PixelRect;
use mouthpiece_frame::Intrinsics;
use mouthpiece_retarget::kabsch::kabsch;
use mouthpiece_retarget::{NeutralPose, PerformerLayout, RigidTransform};

use crate::camera;
use crate::config::TrackConfig;
use crate::head;
use crate::labels::{self, Candidate, Slot, Small};
use crate::naming::checks::depth_window;
use crate::naming::Context;
use crate::Vec3;

/// Past this many skipped frames constant velocity says little: a prediction extrapolates
/// at most this many frame intervals (the interval the velocity was measured over).
pub const MAX_STEP_RATIO: f64 = 4.0;

/// A dot missing for longer than this many frames widens its gates no further.
const GATE_WIDENING_MAX_FRAMES: u32 = 10;
/// Per frame a dot has been missing, its pixel gate widens by this share of itself ...
const PIXEL_GATE_WIDENING_PER_FRAME: f64 = 0.05;
/// ... and its depth gate by this share (lips move in depth faster than the gate's
/// 8 mm would follow over several frames).
const DEPTH_GATE_WIDENING_PER_FRAME: f64 = 0.2;

/// Where to look on a frame ([`Tracks::search_region`]): the box round every predicted dot
/// with the margin, and the same round the lips and round the forehead apart.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SearchRegions {
    pub(crate) all: PixelRect,
    pub(crate) lips: Option<PixelRect>,
    pub(crate) forehead: Option<PixelRect>,
    /// The lips' and the forehead's boxes are searched apart only when at least this many
    /// pixels lie between them: a dot's diameter at the lips' depth, so no dot's paint can
    /// straddle the gap and be found as two halves.
    pub(crate) min_gap_px: i32,
}

impl SearchRegions {
    /// The regions the detector searches: the forehead's box and the lips' box when at least
    /// [`Self::min_gap_px`] apart (the face between them holds no dot), top one first; else
    /// the box round all.
    pub(crate) fn searched(&self) -> smallvec::SmallVec<[PixelRect; 2]> {
        match (self.forehead, self.lips) {
            (Some(a), Some(b)) if a.gap(&b) >= self.min_gap_px => {
                if a.y <= b.y {
                    smallvec::smallvec![a, b]
                } else {
                    smallvec::smallvec![b, a]
                }
            }
            _ => smallvec::smallvec![self.all],
        }
    }
}

/// A search region covering 1/this of the image or more costs about as much as the full
/// frame, which is searched instead.
const FULL_FRAME_DIVISOR: i64 = 2;

/// The search region's margin doubles per frame with dots missing, up to 2^this times.
const SEARCH_GROWTH_MAX_DOUBLINGS: u32 = 4;

/// *Search margin from the prediction's uncertainty*: over the last this many frames with
/// every dot seen in them and in the two before (the prediction's miss measured) ...
pub(crate) const SEARCH_MOTION_FRAMES: usize = 8;
/// ... the head's largest miss of the constant-velocity prediction (the forehead dots' largest
/// distance from where their own velocity put them: the head's change of velocity in a frame,
/// its acceleration, with the sensor's noise in the centroids and in the measured velocity) is
/// the prediction's measured uncertainty; a head may accelerate past what the window saw (its
/// acceleration grows while it turns into a move), so the region allows this many times it ...
pub(crate) const SEARCH_HEAD_MISS_FACTOR: f64 = 2.0;
/// ... carried `r` frame intervals on as `r (r + 1) / 2` (a velocity measured over the last
/// interval lags the motion by half of it, and a change of velocity adds up over the step) ...
fn miss_over_steps(miss: f64, step_ratio: f64) -> f64 {
    let r = step_ratio.max(1.0);
    miss * r * (r + 1.0) / 2.0
}
/// ... on top of what no measured motion predicts: a lip starting from rest moves up to this
/// many dot spacings in a frame relative to the head (a jaw dropping), and its paint reaches
/// [`SEARCH_PAINT_SPACINGS`] round its centre. The margin is never below
/// [`TrackConfig::roi_margin_spacings`] (those two and the prediction's own error at rest),
/// which is also the margin until the window is full and while dots are missing.
pub(crate) const SEARCH_LIP_JUMP_SPACINGS: f64 = 1.4;
/// The reach of a dot's paint round its centre, dot spacings.
pub(crate) const SEARCH_PAINT_SPACINGS: f64 = 0.2;

/// One dot's track.
#[derive(Debug, Clone)]
pub(crate) struct DotTrack {
    pub(crate) pixel: [f64; 2],
    pub(crate) pixel_vel: [f64; 2],
    /// Last position carried back into the reference head pose (`H⁻¹ p`).
    pub(crate) stab: Vec3,
    pub(crate) stab_vel: Vec3,
    /// Depth when last seen (camera frame, metres): one end of the depth gate's window (the
    /// other, the stabilised position carried by the head motion, carries the head pose's
    /// noise about the lever from the forehead).
    pub(crate) depth: f64,
    /// Frames since last seen (0 = seen in the last frame).
    pub(crate) missing: u32,
}

impl DotTrack {
    /// A dot seen for the first time at `c`.
    pub(crate) fn new(c: &Candidate) -> Self {
        DotTrack {
            pixel: c.pixel,
            pixel_vel: [0.0; 2],
            stab: c.point,
            stab_vel: Vec3::zeros(),
            depth: c.point.z,
            missing: 0,
        }
    }

    /// Where constant pixel velocity puts the dot `ratio` frame intervals on.
    pub(crate) fn predicted_pixel(&self, ratio: f64) -> [f64; 2] {
        [
            self.pixel[0] + self.pixel_vel[0] * ratio,
            self.pixel[1] + self.pixel_vel[1] * ratio,
        ]
    }
}

/// How the lip dots are predicted to have moved since the last frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum LipMotion {
    /// On at the velocity they had (in the head's frame).
    Steady,
    /// Not at all: where they were last (in the head's frame).
    Stopped,
    /// As `Steady`, the lower lip between the corners shifted by these pixels besides (the
    /// jaw dropping or snapping shut within one frame).
    JawJumped([f64; 2]),
    /// As `Steady`, each side of the mouth stretched along the corner line about the
    /// predicted corners' midpoint by these shares (the performer's left side, then the
    /// right; 0.1: 10 % further out, -0.1: drawn in): the lips drawn in, spread or shifted
    /// within one frame.
    SidesStretched([f64; 2]),
}

/// Where each lip dot is predicted in the image: its stabilised position (moved on by its
/// velocity when it was seen last frame and `lip_motion` is steady) carried by this
/// frame's head motion and projected.
pub(crate) fn lip_predictions(
    ctx: &Context,
    head: &RigidTransform,
    lip_motion: LipMotion,
) -> Small<[f64; 2]> {
    let k = ctx.sensor.k;
    let mut preds: Small<[f64; 2]> = ctx.tracks[..ctx.layout.lip_dots]
        .iter()
        .map(|t| {
            let q = if t.missing == 0 && lip_motion != LipMotion::Stopped {
                t.stab + t.stab_vel * ctx.step_ratio
            } else {
                t.stab
            };
            camera::project(k, &head.apply(&q)).unwrap_or(t.pixel)
        })
        .enumerate()
        .map(|(i, p)| match lip_motion {
            LipMotion::JawJumped(shift) if i > ctx.layout.right_corner() => {
                [p[0] + shift[0], p[1] + shift[1]]
            }
            _ => p,
        })
        .collect();
    if let LipMotion::SidesStretched(stretch) = lip_motion {
        stretch_sides(&mut preds, &ctx.layout, stretch);
    }
    preds
}

/// Stretches each side of the mouth along the line through the two corners (`pixels` in
/// layout order) about the corners' midpoint: a pixel on the left corner's side moves
/// `stretch[0]` times its distance from the midpoint along that line, one on the right
/// corner's side `stretch[1]` times; across the line nothing moves. The same share on both
/// sides scales the width; opposite shares shift the mouth. Coincident corners leave the
/// pixels as they are.
pub(crate) fn stretch_sides(pixels: &mut [[f64; 2]], layout: &PerformerLayout, stretch: [f64; 2]) {
    let Some(line) = CornerLine::of(pixels, layout) else {
        return;
    };
    for p in pixels.iter_mut() {
        let along = line.along(p);
        let share = if along >= 0.0 { stretch[0] } else { stretch[1] };
        *p = line.moved(p, share * along);
    }
}

/// *Corners a line apart*: corners nearer than this many dot spacings ([`DotSpacing`]) give
/// no line to measure a shift along. A mouth wears half its lip dots' spacings between its
/// corners (six for twelve dots) and a pucker draws them in by a third at most: corners
/// within one spacing are predictions gone wrong, and the direction between them is noise.
pub(crate) const MIN_CORNER_LINE_SPACINGS: f64 = 1.0;

/// Depths nearer than this (metres) are taken as this for a pixel length: no division by a
/// depth of zero.
const MIN_SPACING_DEPTH_M: f64 = 0.05;

/// The tracker's unit of length in the image, the *dot spacing*: the mean distance between
/// neighbouring lip dots of the mouth at rest (the neutral pose once taken, else the first
/// full naming), in pixels at a given depth. The gates' floor, the search region's margin
/// and the corner line's least length are set in it, so they mean the same on the face at
/// any camera resolution and any distance from the camera (the score's motion term uses the
/// same unit: [`crate::naming::score::spacing_px`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct DotSpacing {
    /// The spacing in metres times the focal length in pixels: its pixels at 1 m.
    px_at_1m: f64,
}

impl DotSpacing {
    /// The spacing of `rest` (lip dots in layout order, around the mouth, metres) seen with
    /// a focal length of `fx` pixels; `None` with fewer than two dots, all in one place, or
    /// no focal length.
    pub(crate) fn of_rest(rest: &[Vec3], fx: f64) -> Option<Self> {
        let metres = mean_neighbour_distance(rest)?;
        let px_at_1m = metres * fx;
        (px_at_1m.is_finite() && px_at_1m > 0.0).then_some(Self { px_at_1m })
    }

    /// The spacing in pixels at depth `z` (metres).
    pub(crate) fn px(&self, z: f64) -> f64 {
        self.px_at_1m / z.max(MIN_SPACING_DEPTH_M)
    }
}

/// The lip dots' mean last depth (metres; 0 before any names).
pub(crate) fn lips_depth(ctx: &Context) -> f64 {
    let lips = &ctx.tracks[..ctx.layout.lip_dots.min(ctx.tracks.len())];
    lips.iter().map(|t| t.depth).sum::<f64>() / lips.len().max(1) as f64
}

/// The mean distance between neighbouring points of a closed loop (the lip dots around the
/// mouth); `None` with fewer than two points.
pub fn mean_neighbour_distance(points: &[Vec3]) -> Option<f64> {
    let n = points.len();
    (n >= 2).then(|| {
        (0..n)
            .map(|i| (points[(i + 1) % n] - points[i]).norm())
            .sum::<f64>()
            / n as f64
    })
}

/// The line through the two mouth corners' pixels: its midpoint, the unit direction from
/// the right corner to the left one, and the corners' distance.
#[derive(Debug, Clone, Copy)]
pub(crate) struct CornerLine {
    mid: [f64; 2],
    dir: [f64; 2],
    len: f64,
}

impl CornerLine {
    /// The line of `pixels`' corners (layout order); `None` when they coincide.
    pub(crate) fn of(pixels: &[[f64; 2]], layout: &PerformerLayout) -> Option<Self> {
        let (l, r) = (pixels[layout.left_corner()], pixels[layout.right_corner()]);
        let (dx, dy) = (l[0] - r[0], l[1] - r[1]);
        let len = dx.hypot(dy);
        (len > 1e-9).then(|| Self {
            mid: [0.5 * (l[0] + r[0]), 0.5 * (l[1] + r[1])],
            dir: [dx / len, dy / len],
            len,
        })
    }

    /// The line of `pixels`' corners when they are at least [`MIN_CORNER_LINE_SPACINGS`]
    /// dot spacings (`spacing_px` pixels each) apart.
    pub(crate) fn measurable(
        pixels: &[[f64; 2]],
        layout: &PerformerLayout,
        spacing_px: f64,
    ) -> Option<Self> {
        Self::of(pixels, layout).filter(|line| line.len >= MIN_CORNER_LINE_SPACINGS * spacing_px)
    }

    /// Whether `shift` (pixels) has a component along the line of more than `share` of the
    /// lip dots' spacing (half the corners' distance over half of `lip_dots`).
    pub(crate) fn runs_along(&self, shift: &[f64; 2], lip_dots: usize, share: f64) -> bool {
        let along = shift[0] * self.dir[0] + shift[1] * self.dir[1];
        let spacing = 2.0 * self.len / lip_dots as f64;
        along.abs() > share * spacing
    }

    /// Where `p` lies along the line from the midpoint, pixels (> 0 on the left corner's side).
    pub(crate) fn along(&self, p: &[f64; 2]) -> f64 {
        (p[0] - self.mid[0]) * self.dir[0] + (p[1] - self.mid[1]) * self.dir[1]
    }

    /// `p` moved `by` pixels along the line.
    pub(crate) fn moved(&self, p: &[f64; 2], by: f64) -> [f64; 2] {
        [p[0] + by * self.dir[0], p[1] + by * self.dir[1]]
    }
}

/// Where each forehead dot is predicted: on at constant pixel velocity when seen last frame,
/// else its last place carried by the last head motion.
pub(crate) fn forehead_predictions(ctx: &Context, k: &Intrinsics) -> Small<[f64; 2]> {
    ctx.tracks[ctx.layout.lip_dots..]
        .iter()
        .map(|t| {
            if t.missing == 0 {
                t.predicted_pixel(ctx.step_ratio)
            } else {
                camera::project(k, &ctx.head.last.apply(&t.stab)).unwrap_or(t.pixel)
            }
        })
        .collect()
}

/// Gate per prediction: a fraction of the distance to the nearest other prediction of the
/// group, at least [`TrackConfig::min_gate_spacings`] dot spacings at the dot's last depth
/// (no floor without a `spacing`), widened a little for dots missing for a while. Lip dots
/// are gated in depth too: a candidate further than [`TrackConfig::lip_depth_gate_m`]
/// from the dot's expected depth is not this dot (widened for dots missing for a while).
/// The window spans the dot's last depth and its last place carried by this frame's head
/// motion (`head`, reference → now): a head moving fast in depth moved the lips 8 mm
/// between two frames, out of a gate around their last depth, while the head pose's own
/// noise makes the carried depth alone the worse guess in some sessions.
pub(crate) fn gated(
    config: &TrackConfig,
    preds: &[[f64; 2]],
    tracks: &[DotTrack],
    slot: Slot,
    head: &RigidTransform,
    spacing: Option<DotSpacing>,
) -> Small<labels::Prediction> {
    preds
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let nearest = preds
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, q)| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt())
                .fold(f64::INFINITY, f64::min);
            let floor = spacing.map_or(0.0, |s| config.min_gate_spacings * s.px(tracks[i].depth));
            let base = (config.gate_fraction * nearest).max(floor);
            let missing = tracks[i].missing.min(GATE_WIDENING_MAX_FRAMES) as f64;
            let mut gate = labels::Prediction::in_image(
                *p,
                base * (1.0 + PIXEL_GATE_WIDENING_PER_FRAME * missing),
                slot,
            );
            if slot == Slot::Lip {
                let gate_m =
                    config.lip_depth_gate_m * (1.0 + DEPTH_GATE_WIDENING_PER_FRAME * missing);
                let [low, high] = depth_window(&tracks[i], head, gate_m);
                gate.z = 0.5 * (low + high);
                gate.z_gate = 0.5 * (high - low);
            }
            gate
        })
        .collect()
}

/// What the tracker knows of the dots between frames: each dot's track once all were named,
/// the reference forehead the head motion is measured against, the last head motion, and
/// the lips' rest shape.
#[derive(Debug, Default)]
pub(crate) struct Tracks {
    /// Per dot (lip dots, then forehead); `None` until a full naming from geometry.
    pub(crate) dots: Option<Vec<DotTrack>>,
    /// Forehead positions the head motion is measured against (camera frame).
    pub(crate) reference_forehead: Vec<Vec3>,
    /// The last head motion (reference → then).
    pub(crate) head: RigidTransform,
    /// Lip dots at rest in the reference head pose (first naming, then the neutral pose):
    /// the shape the neighbour-based prediction keeps offsets from.
    pub(crate) rest: Vec<Vec3>,
    pub(crate) frames_without_names: u32,
    pub(crate) frames_with_missing: u32,
    /// Frames in a row with a lip blob left unnamed between two named neighbours.
    pub(crate) frames_with_blob_between: u32,
    /// The forehead dots' largest miss of the constant-velocity prediction (pixels) in each
    /// of the last frames with every dot seen in it and the two before, a ring indexed by
    /// `motion_frames` (*search margin from the prediction's uncertainty*).
    pub(crate) recent_head_miss_px: [f64; SEARCH_MOTION_FRAMES],
    /// Frames measured into `recent_head_miss_px` since the names began or a dot went missing.
    pub(crate) motion_frames: usize,
    /// Whether every dot's velocity was measured last frame (every dot seen in it and the one
    /// before): this frame's misses measure the prediction.
    pub(crate) velocities_known: bool,
}

/// *Slipped names*: after this many frames in a row with a lip blob left unnamed between two
/// named neighbours (`naming::checks::blob_between_neighbours`), the names are taken to have
/// slipped along the lip and are forgotten, to be found again from geometry (when geometry
/// can name the frame: a lasting extra blob must not lose the names). A passing extra blob
/// (a motion-blur ghost, a corner's fold) lasts a few frames; a lip slipped as one piece
/// keeps one for seconds, so twice the longest passing one tells them apart (the
/// measurement: docs/lab/detection-log.md).
pub(crate) const SLIPPED_NAMES_FRAMES: u32 = 8;

impl Tracks {
    /// Forgets the names (they are found again from geometry).
    pub(crate) fn forget(&mut self) {
        self.dots = None;
        self.frames_without_names = 0;
        self.frames_with_missing = 0;
        self.frames_with_blob_between = 0;
        self.motion_frames = 0;
        self.velocities_known = false;
    }

    /// Counts the frames in a row with a lip blob left between two named neighbours; true
    /// once they reach [`SLIPPED_NAMES_FRAMES`] (*slipped names*).
    pub(crate) fn names_slipped(&mut self, blob_between: bool) -> bool {
        self.frames_with_blob_between = if blob_between {
            self.frames_with_blob_between + 1
        } else {
            0
        };
        self.frames_with_blob_between >= SLIPPED_NAMES_FRAMES
    }

    /// The dot spacing of the lips at rest seen with focal length `fx` (pixels).
    pub(crate) fn spacing(&self, fx: f64) -> Option<DotSpacing> {
        DotSpacing::of_rest(&self.rest, fx)
    }

    /// Where to look ([`SearchRegions`]): around the predicted dots plus a margin at the
    /// lips' mean last depth (camera focal length `fx`, pixels; dots of `dot_radius_m`):
    /// [`Self::margin_spacings`] dot spacings, growing from
    /// [`TrackConfig::roi_margin_spacings`] while some are missing; the full frame (`None`)
    /// when nothing is named, every few frames while dots are missing, or without a spacing.
    pub(crate) fn search_region(
        &self,
        config: &TrackConfig,
        step_ratio: f64,
        image: [usize; 2],
        fx: f64,
        dot_radius_m: f64,
    ) -> Option<SearchRegions> {
        let tracks = self.dots.as_ref()?;
        let spacing = self.spacing(fx)?;
        if self.frames_with_missing > 0
            && self
                .frames_with_missing
                .is_multiple_of(config.full_search_every)
        {
            return None;
        }
        let grow = (1u32 << self.frames_with_missing.min(SEARCH_GROWTH_MAX_DOUBLINGS)) as f64;
        let lips = &tracks[..self.rest.len().min(tracks.len())];
        let z = lips.iter().map(|t| t.depth).sum::<f64>() / lips.len().max(1) as f64;
        let spacing_px = spacing.px(z);
        let margin = self.margin_spacings(config, step_ratio, spacing_px) * spacing_px * grow;
        let around = |group: &[DotTrack]| {
            PixelRect::around(group.iter().map(|t| t.predicted_pixel(step_ratio)), margin)
        };
        let (lips, forehead) = (around(lips), around(&tracks[lips.len()..]));
        // The box round all is the two boxes' union (the rounding outwards is monotone).
        let all = match (lips, forehead) {
            (Some(a), Some(b)) => a.union(&b),
            (a, b) => a.or(b)?,
        };
        let full = image[0] as i64 * image[1] as i64;
        let min_gap_px = (2.0 * dot_radius_m * fx / z.max(f64::MIN_POSITIVE)).ceil() as i32;
        (all.area() < full / FULL_FRAME_DIVISOR).then_some(SearchRegions {
            all,
            lips,
            forehead,
            min_gap_px,
        })
    }

    /// *Search margin from the prediction's uncertainty*, in dot spacings (`spacing_px`
    /// pixels each): a lip's jump from rest ([`SEARCH_LIP_JUMP_SPACINGS`]) and its paint
    /// ([`SEARCH_PAINT_SPACINGS`]), plus [`SEARCH_HEAD_MISS_FACTOR`] times the head's largest
    /// miss over the last [`SEARCH_MOTION_FRAMES`] frames carried `step_ratio` frame
    /// intervals on; at least [`TrackConfig::roi_margin_spacings`], which is the margin
    /// while dots are missing or fewer frames have been measured since (the region then
    /// grows from it: [`Self::search_region`]).
    pub(crate) fn margin_spacings(
        &self,
        config: &TrackConfig,
        step_ratio: f64,
        spacing_px: f64,
    ) -> f64 {
        let least = config.roi_margin_spacings;
        if self.frames_with_missing > 0 || self.motion_frames < SEARCH_MOTION_FRAMES {
            return least;
        }
        let miss_px = self.recent_head_miss_px.iter().copied().fold(0.0, f64::max);
        let wanted = SEARCH_LIP_JUMP_SPACINGS
            + SEARCH_PAINT_SPACINGS
            + SEARCH_HEAD_MISS_FACTOR * miss_over_steps(miss_px, step_ratio) / spacing_px;
        if wanted.is_finite() {
            wanted.max(least)
        } else {
            least
        }
    }

    /// Counts the frame's names (for the search region and for losing the names).
    pub(crate) fn count(&mut self, names: &[Option<usize>]) {
        let seen = names.iter().filter(|c| c.is_some()).count();
        if seen == 0 {
            self.frames_without_names += 1;
        } else {
            self.frames_without_names = 0;
        }
        if seen < names.len() {
            self.frames_with_missing += 1;
        } else {
            self.frames_with_missing = 0;
        }
    }

    /// The frame's names into the tracks: the first full naming starts them (its forehead the
    /// reference, its lips the rest shape); afterwards each seen dot's pixel, place in the
    /// reference head pose, depth and velocities, and each unseen dot's count of frames
    /// missing. After `lost_after_frames` without any name the names are forgotten.
    pub(crate) fn update(
        &mut self,
        config: &TrackConfig,
        layout: PerformerLayout,
        names: &[Option<usize>],
        cands: &[Candidate],
        neutral: Option<&NeutralPose>,
        step_ratio: f64,
    ) {
        let n = layout.lip_dots;
        let all_seen = names.iter().all(|c| c.is_some());
        if self.dots.is_none() {
            if !all_seen {
                return;
            }
            let point = |c: &Option<usize>| cands[c.expect("all seen")].point;
            let forehead: Small<Vec3> = names[n..].iter().map(point).collect();
            let rebased = neutral.and_then(|neutral| {
                let reference: Vec<Vec3> = neutral
                    .forehead_camera
                    .iter()
                    .copied()
                    .collect::<Option<_>>()?;
                let head = kabsch(&reference, &forehead)?;
                Some((reference, head, neutral.lip_camera.clone()))
            });
            if let Some((reference, head, rest)) = rebased {
                // Found again after the neutral pose was taken: the head motion and the rest
                // shape stay those of the neutral pose, as the forehead surface fit expects.
                self.reference_forehead = reference;
                self.head = head;
                self.rest = rest;
            } else {
                // First full naming: this forehead is the reference until calibrated.
                self.reference_forehead = forehead.to_vec();
                self.head = RigidTransform::IDENTITY;
                self.rest = names[..n].iter().map(point).collect();
            }
            let inverse = self.head.inverse();
            self.dots = Some(
                names
                    .iter()
                    .map(|c| {
                        let mut track = DotTrack::new(&cands[c.expect("all seen")]);
                        track.stab = inverse.apply(&track.stab);
                        track
                    })
                    .collect(),
            );
            self.motion_frames = 0;
            self.velocities_known = false;
            tracing::info!("all dots named from geometry; tracking");
            return;
        }
        if self.frames_without_names > config.lost_after_frames {
            tracing::info!(
                frames = self.frames_without_names,
                "dots lost; re-acquiring from geometry"
            );
            self.dots = None;
            return;
        }
        self.head = self.reference(layout).now(names, cands);
        let inverse = self.head.inverse();
        let tracks = self.dots.as_mut().expect("checked");
        // The forehead dots' largest miss of the prediction, when every dot was seen now and
        // its velocity measured (seen the two frames before).
        if all_seen && self.velocities_known {
            let miss = tracks[n..]
                .iter()
                .zip(&names[n..])
                .filter_map(|(track, name)| {
                    let p = track.predicted_pixel(step_ratio);
                    let c = &cands[(*name)?];
                    Some((c.pixel[0] - p[0]).hypot(c.pixel[1] - p[1]))
                })
                .fold(0.0f64, f64::max);
            self.recent_head_miss_px[self.motion_frames % SEARCH_MOTION_FRAMES] = miss;
            self.motion_frames = self.motion_frames.saturating_add(1);
        } else if !all_seen {
            self.motion_frames = 0;
        }
        // Velocities are measured this frame for every dot seen now and last frame.
        self.velocities_known = all_seen && tracks.iter().all(|t| t.missing == 0);
        for (track, name) in tracks.iter_mut().zip(names) {
            match name {
                Some(c) => {
                    let c = &cands[*c];
                    let stab = inverse.apply(&c.point);
                    if track.missing == 0 {
                        track.pixel_vel =
                            [c.pixel[0] - track.pixel[0], c.pixel[1] - track.pixel[1]];
                        track.stab_vel = stab - track.stab;
                    } else {
                        track.pixel_vel = [0.0; 2];
                        track.stab_vel = Vec3::zeros();
                    }
                    track.pixel = c.pixel;
                    track.depth = c.point.z;
                    track.stab = stab;
                    track.missing = 0;
                }
                None => track.missing = track.missing.saturating_add(1),
            }
        }
    }

    /// What the head motion of a frame is measured against.
    pub(crate) fn reference(&self, layout: PerformerLayout) -> head::HeadReference<'_> {
        head::HeadReference {
            layout,
            forehead: &self.reference_forehead,
            rest: &self.rest,
            last: self.head,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::naming::recovery::test_support::{Scene, DOT_RADIUS_M};

    /// The calibrated scene's dot tracks and rest shape; everything else as a new tracker's.
    fn calibrated_tracks(scene: &Scene) -> Tracks {
        Tracks {
            dots: Some(scene.tracks.clone()),
            rest: scene.rest.clone(),
            ..Tracks::default()
        }
    }

    /// The scene's mouth at rest (lip dots about 10 mm apart at 0.6 m, fx 525): its dot
    /// spacing in pixels grows with the focal length and shrinks with the depth.
    #[test]
    fn the_dot_spacing_is_the_rest_mouths_spacing_projected() {
        let scene = Scene::calibrated();
        let vga = DotSpacing::of_rest(&scene.rest, 525.0).unwrap();
        let hd = DotSpacing::of_rest(&scene.rest, 1050.0).unwrap();
        let px = vga.px(0.6);
        assert!((7.0..11.0).contains(&px), "{px}");
        assert!((hd.px(0.6) - 2.0 * px).abs() < 1e-9);
        assert!((vga.px(1.2) - px / 2.0).abs() < 1e-9);
        assert!(DotSpacing::of_rest(&scene.rest[..1], 525.0).is_none());
        assert!(DotSpacing::of_rest(&scene.rest, 0.0).is_none());
    }

    /// Gates' floor: D1's and D2's predictions crowd (half a pixel apart), so their gates
    /// are the floor, [`TrackConfig::min_gate_spacings`] dot spacings at the dot's depth:
    /// twice the pixels with twice the focal length (1280x720 against 640x480), half at
    /// twice the depth; the same share of the mouth at any resolution and distance.
    #[test]
    fn the_gates_floor_is_a_share_of_the_dot_spacing() {
        let scene = Scene::calibrated();
        let mut preds = scene.rest_pixels()[..12].to_vec();
        preds[1] = [preds[0][0] + 0.5, preds[0][1]];
        let floor = |tracks: &[DotTrack], fx: f64| {
            let spacing = DotSpacing::of_rest(&scene.rest, fx);
            let gates = gated(
                &scene.config,
                &preds,
                tracks,
                Slot::Lip,
                &RigidTransform::IDENTITY,
                spacing,
            );
            (gates[0].gate_px, spacing.unwrap().px(tracks[0].depth))
        };
        let (vga, spacing) = floor(&scene.tracks[..12], 525.0);
        assert!((vga - scene.config.min_gate_spacings * spacing).abs() < 1e-9);
        assert!((2.5..4.0).contains(&vga), "{vga} px at 640x480, 0.6 m");
        let (hd, _) = floor(&scene.tracks[..12], 1050.0);
        assert!((hd - 2.0 * vga).abs() < 1e-9, "{hd} against {vga}");
        let mut far = scene.tracks[..12].to_vec();
        far.iter_mut().for_each(|t| t.depth *= 2.0);
        let (at_far, _) = floor(&far, 525.0);
        assert!((at_far - vga / 2.0).abs() < 1e-9, "{at_far} against {vga}");
    }

    #[test]
    fn the_forehead_and_the_lips_are_searched_apart_when_a_dot_apart_or_more() {
        let scene = Scene::calibrated();
        let tracks = calibrated_tracks(&scene);
        let regions = |fx: f64| {
            tracks
                .search_region(&scene.config, 1.0, [4000, 4000], fx, DOT_RADIUS_M)
                .unwrap()
        };
        // The calibrated face: the forehead's box above the lips', the two apart, each
        // inside the box round all, together smaller.
        let r = regions(scene.k.fx);
        let searched = r.searched();
        assert_eq!(searched.len(), 2, "{r:?}");
        let (forehead, lips) = (searched[0], searched[1]);
        assert_eq!((Some(forehead), Some(lips)), (r.forehead, r.lips));
        assert!(forehead.y + forehead.height <= lips.y, "{r:?}");
        for b in [forehead, lips] {
            assert!(b.x >= r.all.x && b.y >= r.all.y);
            assert!(b.x + b.width <= r.all.x + r.all.width);
            assert!(b.y + b.height <= r.all.y + r.all.height);
        }
        assert!(forehead.area() + lips.area() < r.all.area(), "{r:?}");
        // Boxes that meet, or lie less than a dot's diameter apart: one box round all (a
        // dot's paint could straddle the gap). A diameter apart: two boxes.
        let diameter = 2.0 * DOT_RADIUS_M * scene.k.fx / scene.tracks[0].depth;
        assert!(
            (r.min_gap_px as f64 - diameter).abs() < 1.0,
            "{} px against a diameter of {diameter} px",
            r.min_gap_px
        );
        let forehead_ending = |rows_between: i32| SearchRegions {
            forehead: Some(PixelRect {
                y: lips.y - forehead.height - rows_between,
                ..forehead
            }),
            ..r
        };
        for rows_between in [-1, 0, r.min_gap_px - 1] {
            let close = forehead_ending(rows_between);
            assert_eq!(
                &close.searched()[..],
                [r.all],
                "{rows_between} rows between"
            );
        }
        assert_eq!(forehead_ending(r.min_gap_px).searched().len(), 2);
        // The lips above the forehead (a head upside down): still the top one first.
        let flipped = SearchRegions {
            forehead: r.lips,
            lips: r.forehead,
            ..r
        };
        assert_eq!(&flipped.searched()[..], [forehead, lips]);
    }

    /// The search region's margin is [`TrackConfig::roi_margin_spacings`] dot spacings at
    /// the lips' depth: with twice the focal length (the same dots' pixels), twice the
    /// pixels around them.
    #[test]
    fn the_search_margin_is_in_dot_spacings() {
        let scene = Scene::calibrated();
        let tracks = calibrated_tracks(&scene);
        let config = &scene.config;
        let image = [4000, 4000];
        let rect = |fx: f64| {
            tracks
                .search_region(config, 1.0, image, fx, DOT_RADIUS_M)
                .unwrap()
                .all
        };
        let (vga, hd) = (rect(525.0), rect(1050.0));
        let spacing = DotSpacing::of_rest(&scene.rest, 525.0).unwrap().px(0.6);
        let margin = config.roi_margin_spacings * spacing;
        assert!(
            (15.0..25.0).contains(&margin),
            "{margin} px at 640x480, 0.6 m"
        );
        // The dots' box is the same; the margin on each side doubled (to the pixel).
        let grown = (hd.width - vga.width) as f64 / 2.0;
        assert!((grown - margin).abs() <= 1.0, "{grown} against {margin}");
    }

    /// *Search margin from the prediction's uncertainty*: the margin is the configured 2.2
    /// spacings until eight frames of misses are measured, and stays 2.2 while the lips move
    /// on a steady head (a lip's jump and its paint, 1.6, are below it); a head accelerating
    /// 0.5 spacings a frame per frame (the forehead missing its constant-velocity prediction
    /// by 0.5 spacings) widens it to 1.6 + 2 × 0.5 = 2.6, and to 1.6 + 2 × 0.5 × 3 = 4.6 over
    /// a step of two frame intervals; a dot going missing brings back 2.2, the region twice
    /// as wide a side on the very next frame, until eight frames are measured again.
    #[test]
    fn the_search_margin_follows_the_predictions_uncertainty() {
        let mut scene = Scene::calibrated();
        let config = scene.config.clone();
        let layout = scene.layout;
        let rest = scene.rest_pixels();
        let fx = scene.k.fx;
        let spacing = DotSpacing::of_rest(&scene.rest, fx).unwrap().px(0.6);
        let mut tracks = Tracks {
            reference_forehead: scene.forehead.clone(),
            ..calibrated_tracks(&scene)
        };
        // One frame: every dot `head` spacings right of rest, the lip dots `lip` more, dot
        // `hidden` unseen.
        let mut frame = |tracks: &mut Tracks, head: f64, lip: f64, hidden: Option<usize>| {
            let pixels: Vec<[f64; 2]> = rest
                .iter()
                .enumerate()
                .map(|(i, p)| match i < layout.lip_dots {
                    true => [p[0] + (head + lip) * spacing, p[1]],
                    false => [p[0] + head * spacing, p[1]],
                })
                .collect();
            let cands = match hidden {
                Some(h) => scene.candidates_hiding(&pixels, h),
                None => scene.candidates_at(&pixels),
            };
            let names: Vec<Option<usize>> = (0..pixels.len())
                .map(|i| match hidden {
                    Some(h) if i == h => None,
                    Some(h) if i > h => Some(i - 1),
                    _ => Some(i),
                })
                .collect();
            tracks.count(&names);
            tracks.update(&config, layout, &names, &cands.list, None, 1.0);
        };
        let margin = |tracks: &Tracks, r: f64| tracks.margin_spacings(&config, r, spacing);
        let least = config.roi_margin_spacings;
        assert_eq!(margin(&tracks, 1.0), least, "nothing measured yet");
        // The lips jump about on a still head: the misses are the lips', not the head's.
        for k in 0..SEARCH_MOTION_FRAMES + 2 {
            assert_eq!(margin(&tracks, 1.0), least, "{k} frames measured");
            frame(&mut tracks, 0.0, 1.2 * (k % 2) as f64, None);
        }
        assert_eq!(margin(&tracks, 1.0), least, "lips alone");
        // The head accelerates: 0.5 spacings more each frame than the frame before.
        let mut head = 0.0;
        for k in 1..=SEARCH_MOTION_FRAMES + 2 {
            head += 0.5 * k as f64;
            frame(&mut tracks, head, 0.0, None);
        }
        assert!(
            (margin(&tracks, 1.0) - 2.6).abs() < 1e-6,
            "{}",
            margin(&tracks, 1.0)
        );
        assert!(
            (margin(&tracks, 2.0) - 4.6).abs() < 1e-6,
            "{}",
            margin(&tracks, 2.0)
        );
        // The lips move sideways only: the dots' box is as tall each time.
        let height = |tracks: &Tracks| {
            let r = tracks.search_region(&config, 1.0, [4000, 4000], fx, DOT_RADIUS_M);
            r.unwrap().all.height as f64
        };
        let moving = height(&tracks);
        head += 0.5 * (SEARCH_MOTION_FRAMES + 3) as f64;
        frame(&mut tracks, head, 0.0, Some(3));
        assert_eq!(margin(&tracks, 1.0), least, "a dot missing");
        let missing = height(&tracks);
        // Twice the least margin a side on the frame after the loss, against 2.6 before.
        let side = |a: f64, b: f64| (a - b) / 2.0 / spacing;
        assert!(
            (side(missing, moving) - (2.0 * least - 2.6)).abs() < 0.15,
            "{missing} against {moving}"
        );
        frame(&mut tracks, head, 0.0, None);
        assert_eq!(margin(&tracks, 1.0), least, "the dot found again");
    }

    /// *Corners a line apart*: corners 5 px apart are a line where the dots are 4 px apart,
    /// and none where they are 8 px apart (the same predictions seen from twice as near).
    #[test]
    fn corners_a_line_apart_are_measured_in_dot_spacings() {
        let layout = PerformerLayout::default();
        let mut pixels = vec![[100.0, 100.0]; layout.lip_dots];
        pixels[layout.right_corner()] = [95.0, 100.0];
        assert!(CornerLine::measurable(&pixels, &layout, 4.0).is_some());
        assert!(CornerLine::measurable(&pixels, &layout, 8.0).is_none());
        assert!(CornerLine::of(&pixels, &layout).is_some());
    }
}
