//! The character's head and eyes (`docs/head.md`): the performer's head rotation carried over
//! within the character's reach, or a turn towards a viewpoint.
//!
//! Frames. Everything here works in the character's *head frame*: the axes of its mouth frame
//! (x towards the character's left, y up, z forward, out of the mouth) with the origin at the
//! head pivot. Rotations leave this module in the character's model frame (the head, rest =
//! identity) and in the head's own frame (the eyes, relative to the head, rest = identity).
//!
//! - [`Reach`]: which directions the head can face (the reach test) and the nearest one it
//!   can face when a direction is out of reach.
//! - [`slerp`]: spherical interpolation of unit quaternions along the shortest path.
//! - [`HeadConfig`]: a character's `[head]` table.
//! - [`HeadDriver`]: the per-character state machine, one step per frame, no allocation.

use nalgebra::{Matrix3, Rotation3, Unit, UnitQuaternion};

use crate::{Error, Vec3};

/// Quaternion type of this module.
pub type Quat = UnitQuaternion<f64>;

/// The directions a head can face, as components of a unit direction in the head frame:
/// `left` (x), `up` (y), `forward` (z).
///
/// A direction is in reach when it is not behind the head (`forward >= 0`), not far out on
/// both side axes at once (`|left| > diagonal` and `|up| > diagonal`), and then, when it is
/// more to the side than up or down (`|left| > |up|`), `|left| <= side`; otherwise
/// `-down <= up <= up_limit`. Defaults: side 0.8, up 0.6, down 0.8, diagonal 0.5, so looking
/// down is easier than looking up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reach {
    /// Largest `|left|` component.
    pub side: f64,
    /// Largest `up` component.
    pub up: f64,
    /// Largest `-up` component (looking down).
    pub down: f64,
    /// `|left|` and `|up|` may not both exceed this.
    pub diagonal: f64,
}

impl Default for Reach {
    fn default() -> Self {
        Self {
            side: 0.8,
            up: 0.6,
            down: 0.8,
            diagonal: 0.5,
        }
    }
}

/// The head frame's forward axis.
pub const FORWARD: Vec3 = Vec3::new(0.0, 0.0, 1.0);
/// The head frame's up axis.
pub const UP: Vec3 = Vec3::new(0.0, 1.0, 0.0);

impl Reach {
    /// Whether the head can face direction `d` (any non-zero length; head frame).
    pub fn contains(&self, d: &Vec3) -> bool {
        self.contains_within(d, 0.0)
    }

    /// [`Reach::contains`] with every limit widened by `eps` (for points on the boundary).
    pub fn contains_within(&self, d: &Vec3, eps: f64) -> bool {
        let n = d.norm();
        if !(n > 0.0 && n.is_finite()) {
            return false;
        }
        let (l, u, f) = (d.x / n, d.y / n, d.z / n);
        if f < -eps {
            return false;
        }
        let (al, au) = (l.abs(), u.abs());
        if al > self.diagonal + eps && au > self.diagonal + eps {
            return false;
        }
        let sideways = al <= self.side + eps;
        let vertical = u <= self.up + eps && u >= -self.down - eps;
        if al > au + eps {
            sideways
        } else if au > al + eps {
            vertical
        } else {
            sideways || vertical
        }
    }

    /// The unit direction in reach nearest to `d` (largest cosine), `d` itself (normalised)
    /// when it is in reach. A zero or non-finite `d` gives forward.
    pub fn nearest(&self, d: &Vec3) -> Vec3 {
        let n = d.norm();
        if !(n > 0.0 && n.is_finite()) {
            return FORWARD;
        }
        let a = d / n;
        if self.contains(&a) {
            return a;
        }
        // The region's boundary lies on the planes where one of the tests changes its
        // answer; the nearest point is the best point of a boundary circle or a corner where
        // two circles meet. Candidates from all of them, kept when in reach.
        let s2 = std::f64::consts::FRAC_1_SQRT_2;
        let planes: [(Vec3, f64); 11] = [
            (Vec3::x(), self.side),
            (Vec3::x(), -self.side),
            (Vec3::x(), self.diagonal),
            (Vec3::x(), -self.diagonal),
            (Vec3::y(), self.diagonal),
            (Vec3::y(), -self.diagonal),
            (Vec3::y(), self.up),
            (Vec3::y(), -self.down),
            (Vec3::new(s2, -s2, 0.0), 0.0),
            (Vec3::new(s2, s2, 0.0), 0.0),
            (Vec3::z(), 0.0),
        ];
        let mut best = FORWARD;
        let mut best_dot = a.dot(&FORWARD);
        let mut consider = |p: Vec3| {
            let dot = a.dot(&p);
            if dot > best_dot && self.contains_within(&p, 1e-9) {
                best = p;
                best_dot = dot;
            }
        };
        for (i, (n1, c1)) in planes.iter().enumerate() {
            // Best point of the circle {p : n1·p = c1, |p| = 1}.
            let r2 = 1.0 - c1 * c1;
            if r2 >= 0.0 {
                let tangent = a - n1 * a.dot(n1);
                if tangent.norm() > 1e-12 {
                    consider(n1 * *c1 + tangent.normalize() * r2.sqrt());
                }
            }
            for (n2, c2) in &planes[i + 1..] {
                for p in circle_corners(n1, *c1, n2, *c2).into_iter().flatten() {
                    consider(p);
                }
            }
        }
        best.normalize()
    }
}

/// Where the circles `{n1·p = c1}` and `{n2·p = c2}` on the unit sphere meet (0–2 points).
fn circle_corners(n1: &Vec3, c1: f64, n2: &Vec3, c2: f64) -> [Option<Vec3>; 2] {
    let dir = n1.cross(n2);
    let d2 = dir.norm_squared();
    if d2 < 1e-18 {
        return [None, None];
    }
    let n12 = n1.dot(n2);
    let p0 =
        (n1 * (c1 * n2.norm_squared() - c2 * n12) + n2 * (c2 * n1.norm_squared() - c1 * n12)) / d2;
    // |p0 + s dir|² = 1, p0 ⟂ dir.
    let rest = 1.0 - p0.norm_squared();
    if rest < 0.0 {
        return [None, None];
    }
    let s = (rest / d2).sqrt();
    [Some(p0 + dir * s), Some(p0 - dir * s)]
}

/// Spherical linear interpolation from `q0` (s = 0) to `q1` (s = 1) along the shorter arc,
/// unit quaternions in, unit quaternion out.
pub fn slerp(q0: &Quat, q1: &Quat, s: f64) -> Quat {
    let a = q0.quaternion();
    let mut b = *q1.quaternion();
    if a.dot(&b) < 0.0 {
        b = -b;
    }
    // Angle between the quaternions (half the rotation angle between them), computed without
    // acos's loss of precision near 1.
    let theta = (a - b).norm().atan2((a + b).norm()) * 2.0;
    let q = if theta < 1e-9 {
        a * (1.0 - s) + b * s
    } else {
        let sin = theta.sin();
        a * (((1.0 - s) * theta).sin() / sin) + b * ((s * theta).sin() / sin)
    };
    Quat::new_normalize(q)
}

/// The rotation (no roll: a turn about the up axis, then a nod about the turned left axis)
/// that carries the head's forward axis onto the unit direction `d`.
pub fn facing(d: &Vec3) -> Quat {
    let d = d.normalize();
    let left = UP.cross(&d);
    let left = if left.norm() < 1e-9 {
        Vec3::x()
    } else {
        left.normalize()
    };
    let up = d.cross(&left);
    Quat::from_rotation_matrix(&Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[
        left, up, d,
    ])))
}

/// The shortest-arc rotation carrying forward onto `d`, limited to `max` radians.
fn aim(d: &Vec3, max: f64) -> Quat {
    let n = d.norm();
    if !(n > 0.0 && n.is_finite()) {
        return Quat::identity();
    }
    let d = d / n;
    let axis = FORWARD.cross(&d);
    let angle = axis.norm().atan2(FORWARD.dot(&d));
    let axis = if axis.norm() < 1e-12 {
        if angle < 1.0 {
            return Quat::identity();
        }
        Vec3::y_axis()
    } else {
        Unit::new_normalize(axis)
    };
    Quat::from_axis_angle(&axis, angle.min(max))
}

/// Angle of a rotation, radians in [0, π].
pub fn angle(q: &Quat) -> f64 {
    q.angle()
}

/// A character's head (`[head]` in its file): where its head pivots and its eyes sit, what
/// it can reach, how fast it turns and how it follows the performer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadConfig {
    /// The head's pivot, model frame.
    pub pivot: Vec3,
    /// Centre of the character's left eye, model frame.
    pub eye_left: Vec3,
    /// Centre of the character's right eye, model frame.
    pub eye_right: Vec3,
    /// The reach limits.
    pub reach: Reach,
    /// Seconds a turn to a new viewpoint (or back to following) takes; 0 = at once.
    pub turn_time: f64,
    /// How much of the performer's head rotation the head carries over (angle factor).
    pub follow_gain: f64,
    /// Largest rotation, radians, the head takes from the performer.
    pub follow_max: f64,
    /// Largest angle, radians, an eye turns from the head's forward axis.
    pub eye_max: f64,
}

/// Defaults of `[head]` that do not depend on the character's size.
pub const DEFAULT_TURN_TIME_S: f64 = 0.5;
/// Default `follow_gain`.
pub const DEFAULT_FOLLOW_GAIN: f64 = 1.0;
/// Default `follow_max_deg`.
pub const DEFAULT_FOLLOW_MAX_DEG: f64 = 90.0;
/// Default `eye_max_deg`.
pub const DEFAULT_EYE_MAX_DEG: f64 = 30.0;

impl HeadConfig {
    /// A head for a mouth frame when the file has no `[head]`: pivot 1.6 mouth widths behind
    /// and 0.5 above the mouth, eyes 1.3 widths apart, 1.4 above the mouth, 0.2 behind it.
    pub fn default_for(frame: &crate::MouthFrame) -> Self {
        let w = frame.width;
        let at = |x: f64, y: f64, z: f64| frame.to_parent(&(Vec3::new(x, y, z) * w));
        Self {
            pivot: at(0.0, 0.5, -1.6),
            eye_left: at(0.65, 1.4, -0.2),
            eye_right: at(-0.65, 1.4, -0.2),
            reach: Reach::default(),
            turn_time: DEFAULT_TURN_TIME_S,
            follow_gain: DEFAULT_FOLLOW_GAIN,
            follow_max: DEFAULT_FOLLOW_MAX_DEG.to_radians(),
            eye_max: DEFAULT_EYE_MAX_DEG.to_radians(),
        }
    }
}

/// What drives the head: the output vocabulary's one enum (`follow` or `look_at`).
pub use mouthpiece_output::LookMode;

/// One step of a character's head and eyes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadFrame {
    /// The head's rotation about its pivot, model frame (identity at rest).
    pub rotation: Quat,
    /// The left eye's rotation relative to the head (identity: along the head's forward).
    pub eye_left: Quat,
    /// The right eye's rotation relative to the head.
    pub eye_right: Quat,
    /// What drives the head.
    pub mode: LookMode,
    /// With a viewpoint: whether the head can face it. `None` while following.
    pub in_reach: Option<bool>,
    /// How far the current turn has come, 0..=1 (1 when no turn is under way).
    pub progress: f64,
    /// The head's rotation was limited (reach or `follow_max`) this step.
    pub limited: bool,
}

impl Default for HeadFrame {
    fn default() -> Self {
        Self {
            rotation: Quat::identity(),
            eye_left: Quat::identity(),
            eye_right: Quat::identity(),
            mode: LookMode::Follow,
            in_reach: None,
            progress: 1.0,
            limited: false,
        }
    }
}

/// A viewpoint being looked at.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Viewpoint {
    /// Head frame, relative to the pivot.
    at: Vec3,
    in_reach: bool,
    /// Head-frame rotation facing it (or the nearest direction in reach).
    target: Quat,
}

/// A turn under way: from `from` at time `start` (set on the first step after it began).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Turn {
    from: Quat,
    start: Option<f64>,
}

/// Drives one character's head and eyes, one step per frame.
#[derive(Debug, Clone, PartialEq)]
pub struct HeadDriver {
    config: HeadConfig,
    /// Head frame axes (columns) in model coordinates.
    axes: Matrix3<f64>,
    /// Eye centres relative to the pivot, head frame.
    eyes: [Vec3; 2],
    viewpoint: Option<Viewpoint>,
    turn: Option<Turn>,
    last_t: Option<f64>,
    /// Current head rotation, head frame.
    current: Quat,
    out: HeadFrame,
}

impl HeadDriver {
    /// A driver for a head whose frame has `axes` (columns x left, y up, z forward, in model
    /// coordinates: the character's mouth frame axes).
    pub fn new(config: HeadConfig, axes: Matrix3<f64>) -> Self {
        let to_head = |p: &Vec3| axes.tr_mul(&(p - config.pivot));
        Self {
            eyes: [to_head(&config.eye_left), to_head(&config.eye_right)],
            config,
            axes,
            viewpoint: None,
            turn: None,
            last_t: None,
            current: Quat::identity(),
            out: HeadFrame::default(),
        }
    }

    /// The configuration.
    pub fn config(&self) -> &HeadConfig {
        &self.config
    }

    /// The last step's result.
    pub fn output(&self) -> &HeadFrame {
        &self.out
    }

    /// Looks at `point` (model frame) from the next step on, or goes back to following the
    /// performer (`None`). A turn starts from wherever the head is. Returns whether the point
    /// is in reach (`None` when following).
    pub fn look_at(&mut self, point: Option<Vec3>) -> Result<Option<bool>, Error> {
        let viewpoint = match point {
            None => None,
            Some(p) => {
                if !(p.iter().all(|c| c.is_finite())
                    && crate::layout::coordinates_in_range(&[p.x, p.y, p.z]))
                {
                    return Err(Error::InvalidConfig {
                        key: "look_at",
                        reason: format!("the point must be finite numbers, got {p:?}"),
                    });
                }
                let at = self.axes.tr_mul(&(p - self.config.pivot));
                let scale = self.eyes[0].norm().max(self.eyes[1].norm()).max(1e-9);
                if at.norm() <= 1e-6 * scale {
                    return Err(Error::InvalidConfig {
                        key: "look_at",
                        reason: "the point is the head's pivot: there is no direction to face"
                            .into(),
                    });
                }
                let in_reach = self.config.reach.contains(&at);
                let direction = self.config.reach.nearest(&at);
                Some(Viewpoint {
                    at,
                    in_reach,
                    target: facing(&direction),
                })
            }
        };
        self.viewpoint = viewpoint;
        self.turn = Some(Turn {
            from: self.current,
            start: self.last_t,
        });
        Ok(viewpoint.map(|v| v.in_reach))
    }

    /// Where the driver looks: the viewpoint (model frame), or `None` when following.
    pub fn viewpoint(&self) -> Option<Vec3> {
        self.viewpoint.map(|v| self.axes * v.at + self.config.pivot)
    }

    /// The head rotation (head frame) that follows the performer's head rotation `r` (given
    /// in the same axes: the performer's mouth frame), scaled by the gain, limited to
    /// `follow_max` and to the reach. Also says whether it was limited.
    pub fn follow_target(&self, r: &Quat) -> (Quat, bool) {
        let v = r.scaled_axis() * self.config.follow_gain;
        let mut limited = false;
        let v = if v.norm() > self.config.follow_max {
            limited = true;
            v * (self.config.follow_max / v.norm())
        } else {
            v
        };
        let q = Quat::from_scaled_axis(v);
        let f = q * FORWARD;
        if self.config.reach.contains(&f) {
            return (q, limited);
        }
        let n = self.config.reach.nearest(&f);
        let fix = Quat::rotation_between(&f, &n).unwrap_or_else(Quat::identity);
        (fix * q, true)
    }

    /// One step at time `t` (seconds, not decreasing). `performer` is the performer's head
    /// rotation relative to the neutral pose, expressed in the performer's mouth frame
    /// axes (x the performer's left, y up, z forward), so it means the same to the character.
    pub fn step(&mut self, t: f64, performer: &Quat) -> &HeadFrame {
        self.last_t = Some(t);
        let (target, limited) = match &self.viewpoint {
            Some(v) => (v.target, !v.in_reach),
            None => self.follow_target(performer),
        };
        let mut progress = 1.0;
        if let Some(turn) = &mut self.turn {
            let start = *turn.start.get_or_insert(t);
            let s = if self.config.turn_time > 0.0 {
                ((t - start) / self.config.turn_time).clamp(0.0, 1.0)
            } else {
                1.0
            };
            progress = s;
            self.current =
                crate::head_route::turn_point(&self.config.reach, &turn.from, &target, s);
            if s >= 1.0 {
                self.turn = None;
            }
        } else {
            self.current = target;
        }
        // Eyes: on the viewpoint, or on the character's forward direction (far ahead).
        let inverse = self.current.inverse();
        let eye = |e: &Vec3| match &self.viewpoint {
            Some(v) => aim(&(inverse * (v.at - self.current * e)), self.config.eye_max),
            None => aim(&(inverse * FORWARD), self.config.eye_max),
        };
        let model = |q: &Quat| {
            let m = self.axes * q.to_rotation_matrix().matrix() * self.axes.transpose();
            Quat::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m))
        };
        let (eye_left, eye_right) = (eye(&self.eyes[0]), eye(&self.eyes[1]));
        self.out = HeadFrame {
            rotation: model(&self.current),
            eye_left: model(&eye_left),
            eye_right: model(&eye_right),
            mode: if self.viewpoint.is_some() {
                LookMode::LookAt
            } else {
                LookMode::Follow
            },
            in_reach: self.viewpoint.map(|v| v.in_reach),
            progress,
            limited,
        };
        &self.out
    }

    /// The head's current rotation in the head frame (rest = identity).
    pub fn head_frame_rotation(&self) -> Quat {
        self.current
    }
}

/// A character's head and eyes on the wire and in takes (`docs/head.md`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeadLine {
    /// The head's rotation about its pivot, model frame, unit quaternion `[w, x, y, z]`.
    pub rotation: [f64; 4],
    /// The left eye's rotation relative to the head, `[w, x, y, z]`.
    pub eye_left: [f64; 4],
    /// The right eye's rotation relative to the head, `[w, x, y, z]`.
    pub eye_right: [f64; 4],
    /// `follow` or `look_at`.
    pub mode: LookMode,
    /// With a viewpoint: whether it is in reach; `null` while following.
    pub in_reach: Option<bool>,
    /// How far the current turn has come, 0..=1.
    pub progress: f64,
}

impl Default for HeadLine {
    fn default() -> Self {
        (&HeadFrame::default()).into()
    }
}

impl From<&HeadFrame> for HeadLine {
    fn from(h: &HeadFrame) -> Self {
        Self {
            rotation: wxyz(&h.rotation),
            eye_left: wxyz(&h.eye_left),
            eye_right: wxyz(&h.eye_right),
            mode: h.mode,
            in_reach: h.in_reach,
            progress: h.progress,
        }
    }
}

/// `[w, x, y, z]` with `w >= 0`.
pub fn wxyz(q: &Quat) -> [f64; 4] {
    let c = q.quaternion();
    let s = if c.w < 0.0 { -1.0 } else { 1.0 };
    [s * c.w, s * c.i, s * c.j, s * c.k]
}

/// A direction from yaw (degrees, positive to the character's left) and pitch (degrees,
/// positive up), head frame.
pub fn direction_deg(yaw: f64, pitch: f64) -> Vec3 {
    let (y, p) = (yaw.to_radians(), pitch.to_radians());
    Vec3::new(p.cos() * y.sin(), p.sin(), p.cos() * y.cos())
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// The other reading of the source's axes: its second component is "left" and the third
    /// "up" in the final limits step, so the 0.6 / 0.8 limits fall on left / right.
    fn other_reading(d: &Vec3) -> bool {
        let n = d.normalize();
        let (l, u, f) = (n.x, n.y, n.z);
        if f < 0.0 {
            return false;
        }
        let (absy, absz) = (l.abs(), u.abs());
        if absz > 0.5 && absy > 0.5 {
            return false;
        }
        if absz > absy {
            absz <= 0.8
        } else {
            (-0.8..=0.6).contains(&l)
        }
    }

    #[test]
    fn reach_table() {
        let reach = Reach::default();
        for (yaw, pitch) in [
            (0.0, 0.0),
            (45.0, 0.0),
            (0.0, 30.0),
            (0.0, -45.0),
            (35.0, 35.0),
            (20.0, -50.0),
        ] {
            assert!(
                reach.contains(&direction_deg(yaw, pitch)),
                "({yaw}, {pitch}) should be in reach"
            );
        }
        for (yaw, pitch) in [
            (60.0, 0.0),
            (-60.0, 0.0),
            (0.0, 40.0),
            (0.0, -55.0),
            (40.0, 40.0),
            (45.0, -40.0),
            (100.0, 0.0),
        ] {
            assert!(
                !reach.contains(&direction_deg(yaw, pitch)),
                "({yaw}, {pitch}) should be out of reach"
            );
        }
        // Anything behind the head, whatever its side and height.
        for yaw in [91.0, 120.0, 180.0, -135.0, -91.0] {
            for pitch in [-30.0, 0.0, 10.0, 30.0] {
                assert!(
                    !reach.contains(&direction_deg(yaw, pitch)),
                    "({yaw}, {pitch})"
                );
            }
        }
        assert!(!reach.contains(&Vec3::new(0.0, 0.0, -1.0)));
    }

    /// The cases where the two readings of the source's axes disagree: in ours looking down
    /// is easier than looking up and left equals right; in the other, up equals down and the
    /// head turns further to one side than to the other.
    #[test]
    fn the_chosen_axis_reading_is_told_apart() {
        let reach = Reach::default();
        let cases = [
            // (yaw, pitch, ours)
            (45.0, 0.0, true),
            (-45.0, 0.0, true),
            (0.0, 40.0, false),
            (0.0, -40.0, true),
            (0.0, 38.0, false),
        ];
        for (yaw, pitch, ours) in cases {
            let d = direction_deg(yaw, pitch);
            assert_eq!(reach.contains(&d), ours, "({yaw}, {pitch})");
        }
        // (45, 0) and (0, 40) are where the readings differ.
        assert!(other_reading(&direction_deg(0.0, 40.0)));
        assert!(!other_reading(&direction_deg(45.0, 0.0)));
        assert!(other_reading(&direction_deg(-45.0, 0.0)));
        // Ours: the largest pitch down exceeds the largest pitch up; sides are symmetric.
        let limit = |f: &dyn Fn(f64) -> Vec3| {
            (0..=900)
                .map(|i| f64::from(i) * 0.1)
                .take_while(|a| reach.contains(&f(*a)))
                .last()
                .unwrap()
        };
        let up = limit(&|a| direction_deg(0.0, a));
        let down = limit(&|a| direction_deg(0.0, -a));
        let left = limit(&|a| direction_deg(a, 0.0));
        let right = limit(&|a| direction_deg(-a, 0.0));
        assert!(down > up + 10.0, "down {down}°, up {up}°");
        assert_eq!(left, right);
        assert_relative_eq!(up, 0.6f64.asin().to_degrees(), epsilon = 0.1);
        assert_relative_eq!(down, 0.8f64.asin().to_degrees(), epsilon = 0.1);
    }

    #[test]
    fn nearest_direction_in_reach_beats_every_sampled_one() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(19);
        let reach = Reach::default();
        let sample = |rng: &mut rand::rngs::StdRng| {
            let v = Vec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            v.normalize()
        };
        let inside: Vec<Vec3> = (0..40_000)
            .map(|_| sample(&mut rng))
            .filter(|v| reach.contains(v))
            .collect();
        assert!(inside.len() > 3000);
        for _ in 0..300 {
            let a = sample(&mut rng);
            let n = reach.nearest(&a);
            assert_relative_eq!(n.norm(), 1.0, epsilon = 1e-12);
            assert!(reach.contains_within(&n, 1e-9), "{a:?} -> {n:?}");
            let best = inside.iter().map(|p| p.dot(&a)).fold(f64::MIN, f64::max);
            assert!(
                n.dot(&a) >= best - 1e-12,
                "{a:?}: {n:?} {} < {best}",
                n.dot(&a)
            );
            if reach.contains(&a) {
                assert_relative_eq!(n, a, epsilon = 1e-12);
            }
        }
        // 70° to the left, level: the side limit, level.
        let n = reach.nearest(&direction_deg(70.0, 0.0));
        assert_relative_eq!(n, Vec3::new(0.8, 0.0, 0.6), epsilon = 1e-12);
    }

    #[test]
    fn a_quarter_turn_over_three_frames_passes_30_60_90_degrees() {
        let mut config = HeadConfig::default_for(
            &crate::MouthFrame::from_corners(Vec3::x(), -Vec3::x(), Vec3::y()).unwrap(),
        );
        let dt = 1.0 / 30.0;
        config.turn_time = 3.0 * dt;
        // A reach that allows a quarter turn (straight left).
        config.reach.side = 1.0;
        let mut head = HeadDriver::new(config, Matrix3::identity());
        let still = Quat::identity();
        head.step(0.0, &still);
        let far_left = config.pivot + Vec3::new(10.0, 0.0, 0.0);
        assert_eq!(head.look_at(Some(far_left)).unwrap(), Some(true));
        for (k, want) in [(1, 30.0), (2, 60.0), (3, 90.0), (4, 90.0)] {
            let out = *head.step(f64::from(k) * dt, &still);
            assert_relative_eq!(out.rotation.angle().to_degrees(), want, epsilon = 1e-9);
            // About the up axis, to the left: forward turns towards +x.
            let f = out.rotation * FORWARD;
            assert_relative_eq!(f, direction_deg(want, 0.0), epsilon = 1e-9);
            assert_relative_eq!(out.progress, (f64::from(k) / 3.0).min(1.0), epsilon = 1e-9);
            assert_eq!(out.mode, LookMode::LookAt);
        }
    }

    #[test]
    fn eyes_aim_at_once_and_the_head_follows_within_reach() {
        // A human-sized mouth (5 cm), viewpoints metres away.
        let corner = Vec3::new(0.025, 0.0, 0.0);
        let frame = crate::MouthFrame::from_corners(corner, -corner, Vec3::y()).unwrap();
        let config = HeadConfig::default_for(&frame);
        let mut head = HeadDriver::new(config, frame.axes);
        head.step(0.0, &Quat::identity());
        // 20° to the left and 10° up, 5 m away from the pivot: in reach.
        let target = config.pivot + direction_deg(20.0, 10.0) * 5.0;
        assert_eq!(head.look_at(Some(target)).unwrap(), Some(true));
        let out = *head.step(0.01, &Quat::identity());
        // The eyes are on the target already while the head has hardly moved.
        for (eye, centre) in [
            (out.eye_left, config.eye_left),
            (out.eye_right, config.eye_right),
        ] {
            let world = out.rotation * eye * FORWARD;
            let pos = config.pivot + out.rotation * (centre - config.pivot);
            assert_relative_eq!(world, (target - pos).normalize(), epsilon = 1e-9);
        }
        assert!(out.progress < 0.1);
        let out = *head.step(1.0, &Quat::identity());
        assert_relative_eq!(
            out.rotation * FORWARD,
            direction_deg(20.0, 10.0),
            epsilon = 1e-9
        );
        assert_eq!(out.progress, 1.0);
        // Out of reach (straight up): the head stops at its limit, the eyes make up the rest
        // within their own 30°.
        assert_eq!(
            head.look_at(Some(config.pivot + Vec3::new(0.0, 5.0, 0.0)))
                .unwrap(),
            Some(false)
        );
        let out = *head.step(3.0, &Quat::identity());
        let f = out.rotation * FORWARD;
        assert_relative_eq!(f.y, 0.6, epsilon = 1e-9);
        assert!(out.eye_left.angle() <= config.eye_max + 1e-12);
        assert_relative_eq!(out.eye_left.angle(), config.eye_max, epsilon = 1e-9);
        // Back to following: a turn back to the performer's rotation.
        assert_eq!(head.look_at(None).unwrap(), None);
        let half = *head.step(3.25, &Quat::identity());
        assert_relative_eq!(half.progress, 0.5, epsilon = 1e-9);
        let done = *head.step(3.5, &Quat::identity());
        assert_relative_eq!(done.rotation.angle(), 0.0, epsilon = 1e-9);
        assert_eq!(done.mode, LookMode::Follow);
        // Non-finite points and the pivot itself are refused.
        assert!(head.look_at(Some(Vec3::new(f64::NAN, 0.0, 1.0))).is_err());
        assert!(head.look_at(Some(config.pivot)).is_err());
    }

    #[test]
    fn following_scales_and_clamps_the_performers_rotation() {
        let frame = crate::MouthFrame::from_corners(Vec3::x(), -Vec3::x(), Vec3::y()).unwrap();
        let mut config = HeadConfig::default_for(&frame);
        config.follow_gain = 2.0;
        let mut head = HeadDriver::new(config, frame.axes);
        // 10° yaw → 20°.
        let r = Quat::from_axis_angle(&Vec3::y_axis(), 10f64.to_radians());
        let out = *head.step(0.0, &r);
        assert_relative_eq!(out.rotation.angle().to_degrees(), 20.0, epsilon = 1e-9);
        assert!(!out.limited);
        // Eyes stay on the character's forward: they turn back against the head.
        assert_relative_eq!(
            out.rotation * out.eye_left * FORWARD,
            FORWARD,
            epsilon = 1e-9
        );
        // 40° yaw → 80°, past the side limit: clamped onto it.
        let r = Quat::from_axis_angle(&Vec3::y_axis(), 40f64.to_radians());
        let out = *head.step(0.1, &r);
        let f = out.rotation * FORWARD;
        assert!(out.limited);
        assert_relative_eq!(f.x, 0.8, epsilon = 1e-9);
        assert!(config.reach.contains_within(&f, 1e-9));
    }

    #[test]
    fn slerp_is_unit_and_takes_the_short_way() {
        let a = Quat::from_axis_angle(&Vec3::z_axis(), 0.2);
        let b = Quat::from_axis_angle(&Vec3::z_axis(), 0.8);
        let neg_b = Quat::new_unchecked(-*b.quaternion());
        let m = slerp(&a, &neg_b, 0.5);
        assert_relative_eq!(m.angle(), 0.5, epsilon = 1e-12);
        assert_relative_eq!(slerp(&a, &b, 0.0).angle_to(&a), 0.0, epsilon = 1e-7);
        assert_relative_eq!(slerp(&a, &a, 0.3).angle_to(&a), 0.0, epsilon = 1e-7);
    }
}
