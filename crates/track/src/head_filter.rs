//! A constant-velocity Kalman filter on the head motion.
//!
//! The head motion fitted each frame (forehead surface and dots) carries the depth camera's
//! noise: a fifth of a degree of pitch and yaw a frame, which the mouth, 11 cm below the
//! forehead, feels as a third of a millimetre. A head is a heavy body: its turn and its
//! shift change smoothly, so each is followed as a position and a velocity (*a head keeps
//! its speed*). Unlike a low-pass filter on the dots, a head turning at a steady speed is not
//! lagged; only a change of speed is smoothed, by as much as the measurement's noise against
//! the head's plausible accelerations asks.
//!
//! The rotation is filtered on its own axes (the innovation is the small rotation from the
//! predicted to the measured one, in the camera frame) and the shift as the motion of the
//! forehead's middle (a point on the head, so that turning and shifting do not trade
//! against each other as they would about the camera's origin). Each axis is an independent
//! two-state filter: position and velocity.

use mouthpiece_retarget::RigidTransform;
use nalgebra::{Matrix3, Rotation3};

use crate::Vec3;

/// How much the filter trusts each frame's fitted head motion against its prediction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadFilterParams {
    /// The fitted rotation's noise per axis, radians (1 σ).
    pub rotation_sigma_rad: f64,
    /// The head's angular acceleration as white noise: its spectral density, rad²/s³.
    pub rotation_accel: f64,
    /// The fitted forehead middle's noise per axis, metres (1 σ).
    pub shift_sigma_m: f64,
    /// The head's linear acceleration as white noise: its spectral density, m²/s³.
    pub shift_accel: f64,
}

/// The fitted rotation's noise per axis, radians (0.2°): the forehead surface fit's pitch
/// and yaw scatter by about that frame to frame with a Kinect-like camera at 0.6 m.
pub const FITTED_TURN_SIGMA_RAD: f64 = 0.2 * std::f64::consts::PI / 180.0;
/// The fitted forehead middle's noise per axis, metres.
pub const FITTED_SHIFT_SIGMA_M: f64 = 2e-4;

/// A gap longer than this (seconds) between measurements starts the filter afresh: the head
/// may have done anything while unseen.
pub const MAX_GAP_S: f64 = 0.25;

/// One axis: position and velocity with their 2x2 covariance.
#[derive(Debug, Clone, Copy)]
struct Axis {
    p: [[f64; 2]; 2],
}

impl Axis {
    fn new(sigma: f64) -> Self {
        // The velocity is unknown at first: a wide prior (1 unit/s) lets the first frames set it.
        Self {
            p: [[sigma * sigma, 0.0], [0.0, 1.0]],
        }
    }

    fn predict(&mut self, dt: f64, q: f64) {
        let [[a, b], [_, d]] = self.p;
        // F P Fᵀ + Q for F = [[1, dt], [0, 1]], Q = q [[dt³/3, dt²/2], [dt²/2, dt]].
        let a2 = a + 2.0 * dt * b + dt * dt * d + q * dt.powi(3) / 3.0;
        let b2 = b + dt * d + q * dt * dt / 2.0;
        let d2 = d + q * dt;
        self.p = [[a2, b2], [b2, d2]];
    }

    /// The gains (position, velocity) for a measurement of the position with variance `r`,
    /// and the covariance updated.
    fn update(&mut self, r: f64) -> (f64, f64) {
        let [[a, b], [_, d]] = self.p;
        let s = a + r;
        let (k0, k1) = (a / s, b / s);
        self.p = [
            [(1.0 - k0) * a, (1.0 - k0) * b],
            [(1.0 - k0) * b, d - k1 * b],
        ];
        (k0, k1)
    }
}

#[derive(Debug, Clone)]
struct State {
    t: f64,
    rotation: Matrix3<f64>,
    /// Angular velocity, camera frame, rad/s.
    spin: Vec3,
    /// The forehead's middle, camera frame.
    middle: Vec3,
    velocity: Vec3,
    /// One covariance serves the three axes of the turn, one those of the shift: the axes
    /// share their noise, their acceleration and their times, so theirs stay equal.
    rotation_axis: Axis,
    shift_axis: Axis,
}

/// The filter (see the module's text).
#[derive(Debug, Clone)]
pub struct HeadFilter {
    params: HeadFilterParams,
    /// The point on the head whose motion is filtered, at neutral (camera frame).
    anchor: Vec3,
    state: Option<State>,
}

impl HeadFilter {
    /// A filter for a head whose forehead middle is at `anchor` at neutral.
    pub fn new(params: HeadFilterParams, anchor: Vec3) -> Self {
        Self {
            params,
            anchor,
            state: None,
        }
    }

    /// Forgets the head's motion: the next measurement is taken as it is.
    pub fn reset(&mut self) {
        self.state = None;
    }

    /// The head motion at `t` given this frame's fitted one.
    pub fn update(&mut self, t: f64, measured: &RigidTransform) -> RigidTransform {
        let p = self.params;
        let middle = measured.apply(&self.anchor);
        let fresh = |t| State {
            t,
            rotation: measured.rotation,
            spin: Vec3::zeros(),
            middle,
            velocity: Vec3::zeros(),
            rotation_axis: Axis::new(p.rotation_sigma_rad),
            shift_axis: Axis::new(p.shift_sigma_m),
        };
        let s = match &mut self.state {
            Some(s) if t > s.t && t - s.t <= MAX_GAP_S => s,
            _ => {
                self.state = Some(fresh(t));
                return *measured;
            }
        };
        let dt = t - s.t;
        s.t = t;
        // Predict: keep turning and moving at the same speed.
        let predicted = Rotation3::new(s.spin * dt).into_inner() * s.rotation;
        let predicted_middle = s.middle + s.velocity * dt;
        // Innovation: from the prediction to the measurement.
        let turn = Rotation3::from_matrix_unchecked(measured.rotation * predicted.transpose())
            .scaled_axis();
        let shift = middle - predicted_middle;
        s.rotation_axis.predict(dt, p.rotation_accel);
        let (turn_gain, spin_gain) = s.rotation_axis.update(p.rotation_sigma_rad.powi(2));
        s.shift_axis.predict(dt, p.shift_accel);
        let (shift_gain, velocity_gain) = s.shift_axis.update(p.shift_sigma_m.powi(2));
        s.spin += spin_gain * turn;
        s.velocity += velocity_gain * shift;
        s.rotation = Rotation3::new(turn_gain * turn).into_inner() * predicted;
        s.middle = predicted_middle + shift_gain * shift;
        RigidTransform {
            rotation: s.rotation,
            translation: s.middle - s.rotation * self.anchor,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tracker's defaults.
    fn params() -> HeadFilterParams {
        let [rotation_accel, shift_accel] = crate::config::TrackConfig::default().head_filter_accel;
        HeadFilterParams {
            rotation_sigma_rad: FITTED_TURN_SIGMA_RAD,
            rotation_accel,
            shift_sigma_m: FITTED_SHIFT_SIGMA_M,
            shift_accel,
        }
    }

    fn turned(yaw_rad: f64, anchor: Vec3, shift: Vec3) -> RigidTransform {
        let rotation = Rotation3::from_axis_angle(&Vec3::y_axis(), yaw_rad).into_inner();
        RigidTransform {
            rotation,
            translation: anchor - rotation * anchor + shift,
        }
    }

    fn angle(a: &RigidTransform, b: &RigidTransform) -> f64 {
        (((a.rotation.transpose() * b.rotation).trace() - 1.0) / 2.0)
            .clamp(-1.0, 1.0)
            .acos()
    }

    /// *A head keeps its speed*: a head turning at a steady 20°/s and sliding at 30 mm/s is
    /// followed without lag once the filter has its speed.
    #[test]
    fn a_steady_turn_is_not_lagged() {
        let anchor = Vec3::new(0.0, -0.1, 0.6);
        let mut f = HeadFilter::new(params(), anchor);
        let (spin, slide) = (20f64.to_radians(), Vec3::new(0.03, 0.0, 0.0));
        let mut last = (0.0, 0.0);
        for i in 0..90 {
            let t = i as f64 / 30.0;
            let truth = turned(spin * t, anchor, slide * t);
            let out = f.update(t, &truth);
            last = (
                angle(&out, &truth),
                (out.apply(&anchor) - truth.apply(&anchor)).norm(),
            );
        }
        assert!(last.0.to_degrees() < 0.01, "lag {}°", last.0.to_degrees());
        assert!(last.1 < 1e-5, "lag {} m", last.1);
    }

    /// Noise on a still head is cut: 0.2° of white jitter per axis comes out at under
    /// three quarters (the filter keeps what a head accelerating as the defaults allow
    /// could do within a few frames).
    #[test]
    fn jitter_on_a_still_head_is_cut() {
        let anchor = Vec3::new(0.0, -0.1, 0.6);
        let mut f = HeadFilter::new(params(), anchor);
        let mut seed = 7u64;
        let mut noise = || {
            // A deterministic uniform in [-1, 1) scaled to 0.2° RMS (√3 · 0.2°).
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) * 3f64.sqrt() * 0.2
        };
        let (mut raw_sq, mut out_sq, mut n) = (0.0, 0.0, 0);
        for i in 0..300 {
            let t = i as f64 / 30.0;
            let v = Vec3::new(noise(), noise(), noise()).map(f64::to_radians);
            let measured = RigidTransform {
                rotation: Rotation3::new(v).into_inner(),
                translation: Vec3::zeros(),
            };
            let out = f.update(t, &measured);
            if i >= 30 {
                raw_sq += v.norm_squared();
                out_sq += Rotation3::from_matrix_unchecked(out.rotation)
                    .scaled_axis()
                    .norm_squared();
                n += 1;
            }
        }
        let (raw, out) = ((raw_sq / n as f64).sqrt(), (out_sq / n as f64).sqrt());
        assert!(
            out < 0.75 * raw,
            "{}° → {}°",
            raw.to_degrees(),
            out.to_degrees()
        );
    }

    /// After a gap the filter starts again from the measurement, not a stale speed.
    #[test]
    fn a_gap_starts_afresh() {
        let anchor = Vec3::new(0.0, -0.1, 0.6);
        let mut f = HeadFilter::new(params(), anchor);
        for i in 0..30 {
            let t = i as f64 / 30.0;
            f.update(t, &turned(0.5 * t, anchor, Vec3::zeros()));
        }
        let back = turned(-0.2, anchor, Vec3::new(0.01, 0.0, 0.0));
        let out = f.update(1.0 + MAX_GAP_S + 0.1, &back);
        assert_eq!(out, back);
    }

    /// The filter against filterpy's Kalman filter (tests/reference/head_filter_fixtures.py):
    /// a head turning about one fixed axis and its forehead middle moving, measured with
    /// noise at uneven frame times; the filtered angle and middle agree to 1e-9.
    #[test]
    fn agrees_with_filterpy() {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../tests/reference/head_filter_fixtures.json"
        );
        let fixtures: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        let floats = |v: &serde_json::Value| -> Vec<f64> {
            v.as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect()
        };
        let triples = |v: &serde_json::Value| -> Vec<Vec3> {
            v.as_array()
                .unwrap()
                .iter()
                .map(|p| {
                    let a = floats(p);
                    Vec3::new(a[0], a[1], a[2])
                })
                .collect()
        };
        assert_eq!(
            fixtures["rotation_sigma_rad"].as_f64(),
            Some(FITTED_TURN_SIGMA_RAD)
        );
        assert_eq!(
            fixtures["shift_sigma_m"].as_f64(),
            Some(FITTED_SHIFT_SIGMA_M)
        );
        let cases = fixtures["cases"].as_array().unwrap();
        assert_eq!(cases.len(), 2);
        for case in cases {
            let params = HeadFilterParams {
                rotation_sigma_rad: FITTED_TURN_SIGMA_RAD,
                rotation_accel: case["rotation_accel"].as_f64().unwrap(),
                shift_sigma_m: FITTED_SHIFT_SIGMA_M,
                shift_accel: case["shift_accel"].as_f64().unwrap(),
            };
            let anchor = Vec3::new(0.01, -0.1, 0.62);
            let mut f = HeadFilter::new(params, anchor);
            let a = floats(&case["axis"]);
            let axis = nalgebra::Unit::new_normalize(Vec3::new(a[0], a[1], a[2]));
            let (t, angle) = (floats(&case["t"]), floats(&case["angle"]));
            let middle = triples(&case["middle"]);
            let (want_angle, want_middle) = (
                floats(&case["filtered_angle"]),
                triples(&case["filtered_middle"]),
            );
            for k in 0..t.len() {
                let rotation = Rotation3::from_axis_angle(&axis, angle[k]).into_inner();
                let measured = RigidTransform {
                    rotation,
                    translation: middle[k] - rotation * anchor,
                };
                let out = f.update(t[k], &measured);
                let turned = Rotation3::from_matrix_unchecked(out.rotation).scaled_axis();
                assert!(
                    (turned.dot(&axis) - want_angle[k]).abs() < 1e-9
                        && (turned - axis.into_inner() * turned.dot(&axis)).norm() < 1e-9,
                    "frame {k}: {turned:?} against {} about {axis:?}",
                    want_angle[k]
                );
                let got = out.apply(&anchor);
                assert!(
                    (got - want_middle[k]).norm() < 1e-9,
                    "frame {k}: middle {got:?} against {:?}",
                    want_middle[k]
                );
            }
        }
    }
}
