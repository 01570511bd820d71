//! The path a head takes through a turn (`docs/head.md`, "Turning to a viewpoint"): the
//! reach region is not convex (a cross, seen from the front), so a plain slerp between two
//! directions in reach can cut through a corner out of reach. The route goes through
//! waypoints pulled into the region where the straight turn would leave it, and every step is
//! held in the region.

use crate::head::{slerp, Quat, Reach, FORWARD};
use crate::Vec3;

/// Waypoints a route may insert (each where the turn so far leaves the reach the most).
const MAX_WAYPOINTS: usize = 4;
/// Points checked inside each leg of a route.
const SAMPLES: usize = 16;
/// Tolerance of the reach test along a route (points on the boundary count as in reach).
const EPS: f64 = 1e-9;

/// The head's rotation at fraction `s` (0..=1) of a turn from `from` to `to` (head frame):
/// spherical interpolation, through waypoints where the straight turn would leave the reach,
/// at constant angular speed over the whole route, and each result held in the reach. `to`
/// is reached exactly at `s = 1`. Fixed-size state: no allocation.
pub(crate) fn turn_point(reach: &Reach, from: &Quat, to: &Quat, s: f64) -> Quat {
    if s >= 1.0 {
        // The target is in reach already (the nearest direction, or the clamped follow).
        return *to;
    }
    let mut points = [Quat::identity(); MAX_WAYPOINTS + 2];
    points[0] = *from;
    points[1] = *to;
    let mut n = 2;
    while n < points.len() {
        // The sample of the route furthest out of reach (by how much a limit is exceeded).
        let mut worst: Option<(usize, Quat, f64)> = None;
        for leg in 0..n - 1 {
            for i in 1..SAMPLES {
                let q = slerp(&points[leg], &points[leg + 1], i as f64 / SAMPLES as f64);
                let f = q * FORWARD;
                if reach.contains_within(&f, EPS) {
                    continue;
                }
                let out = f.angle(&reach.nearest(&f));
                if worst.is_none_or(|(_, _, w)| out > w) {
                    worst = Some((leg, q, out));
                }
            }
        }
        let Some((leg, q, _)) = worst else { break };
        let f = q * FORWARD;
        let into = pulled_in(reach, &f);
        let fix = Quat::rotation_between(&f, &into).unwrap_or_else(Quat::identity);
        points.copy_within(leg + 1..n, leg + 2);
        points[leg + 1] = fix * q;
        n += 1;
    }
    hold_in(reach, &along(&points[..n], s))
}

/// The point at fraction `s` of the path through `points`, by angle travelled.
fn along(points: &[Quat], s: f64) -> Quat {
    let last = points.len() - 1;
    if s >= 1.0 {
        return points[last];
    }
    let total: f64 = points.windows(2).map(|w| w[0].angle_to(&w[1])).sum();
    if total <= 1e-12 || total.is_nan() {
        return slerp(&points[0], &points[last], s);
    }
    let mut left = s.max(0.0) * total;
    for w in points.windows(2) {
        let a = w[0].angle_to(&w[1]);
        if left <= a {
            return slerp(&w[0], &w[1], if a > 0.0 { left / a } else { 1.0 });
        }
        left -= a;
    }
    points[last]
}

/// A unit direction in reach near `f`: moved towards forward (the (left, up) components
/// shrunk together, which keeps the reach test's comparisons) until a little inside the
/// reach. The region is star-shaped about forward, so the move ends inside it.
fn pulled_in(reach: &Reach, f: &Vec3) -> Vec3 {
    let lu = nalgebra::Vector2::new(f.x, f.y);
    let r = lu.norm();
    let lu = if r > 1.0 { lu / r } else { lu };
    let at = |k: f64| {
        let p = lu * k;
        Vec3::new(p.x, p.y, (1.0 - p.norm_squared()).max(0.0).sqrt())
    };
    // Largest k in [0, 1] with at(k) in reach, by bisection.
    let (mut lo, mut hi) = (0.0, 1.0);
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if reach.contains(&at(mid)) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    at(lo * 0.95)
}

/// `q`, or when its forward axis is out of reach the smallest extra rotation that brings it
/// onto the nearest direction in reach (roll kept).
pub(crate) fn hold_in(reach: &Reach, q: &Quat) -> Quat {
    let f = q * FORWARD;
    if reach.contains_within(&f, EPS) {
        return *q;
    }
    let n = reach.nearest(&f);
    Quat::rotation_between(&f, &n).unwrap_or_else(Quat::identity) * q
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::head::{facing, HeadConfig, HeadDriver};
    use nalgebra::Matrix3;
    use rand::{Rng, SeedableRng};

    fn random_direction(rng: &mut rand::rngs::StdRng) -> Vec3 {
        loop {
            let v = Vec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            let n = v.norm();
            if n > 0.1 && n <= 1.0 {
                return v / n;
            }
        }
    }

    fn random_in_reach(rng: &mut rand::rngs::StdRng, reach: &Reach) -> Vec3 {
        loop {
            let d = random_direction(rng);
            if reach.contains(&d) {
                return d;
            }
        }
    }

    /// Many random turns (start and end in reach, a fifth of the ends out of reach, a
    /// quarter of the viewpoints changed mid-turn, a third under other reach tables), stepped
    /// at 60 Hz: every step's forward axis is in reach, `progress` is the time since the
    /// request over `turn_time_s`, the head ends facing the viewpoint (or the nearest
    /// direction in reach) when `progress` reaches 1 and not before, and it moves at an even
    /// pace (no step more than 3 times the turn's mean step: no jump).
    #[test]
    fn every_step_of_a_turn_stays_in_reach() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(2026);
        let frame = crate::MouthFrame::from_corners(Vec3::x(), -Vec3::x(), Vec3::y()).unwrap();
        assert_eq!(frame.axes, Matrix3::identity());
        let dt = 1.0 / 60.0;
        let (mut out_of_reach, mut worst) = (0, 0.0f64);
        let mut steps_taken = Vec::new();
        for case in 0..3000 {
            let mut config = HeadConfig::default_for(&frame);
            if case % 3 == 1 {
                config.reach = Reach {
                    side: rng.random_range(0.3..1.0),
                    up: rng.random_range(0.3..1.0),
                    down: rng.random_range(0.3..1.0),
                    diagonal: rng.random_range(0.2..0.7),
                };
            }
            let reach = config.reach;
            config.turn_time = rng.random_range(0.2..1.5);
            let mut head = HeadDriver::new(config, Matrix3::identity());
            let still = Quat::identity();
            head.step(0.0, &still);
            let start = random_in_reach(&mut rng, &reach);
            head.look_at(Some(config.pivot + start * 3.0)).unwrap();
            head.step(100.0, &still);
            assert!((head.output().rotation * FORWARD - start).norm() < 1e-9);
            let view = |rng: &mut rand::rngs::StdRng| {
                if rng.random_bool(0.8) {
                    random_in_reach(rng, &reach)
                } else {
                    random_direction(rng)
                }
            };
            let mut end = view(&mut rng);
            let change = (case % 4 == 3).then(|| rng.random_range(1..40));
            head.look_at(Some(config.pivot + end * 3.0)).unwrap();
            let mut t0 = 100.0;
            steps_taken.clear();
            for k in 1..=(config.turn_time / dt).ceil() as usize + 45 {
                let t = 100.0 + k as f64 * dt;
                if change == Some(k) {
                    end = view(&mut rng);
                    head.look_at(Some(config.pivot + end * 3.0)).unwrap();
                    t0 = t - dt;
                    steps_taken.clear();
                }
                let before = head.output().rotation;
                let out = *head.step(t, &still);
                let f = out.rotation * FORWARD;
                if !reach.contains_within(&f, 1e-7) {
                    out_of_reach += 1;
                    worst = worst.max(f.angle(&reach.nearest(&f)).to_degrees());
                }
                let s = ((t - t0) / config.turn_time).clamp(0.0, 1.0);
                assert!((out.progress - s).abs() < 1e-9, "case {case} step {k}");
                let goal = reach.nearest(&end);
                let to_goal = out.rotation.angle_to(&facing(&goal));
                if s >= 1.0 {
                    assert!(
                        (f - goal).norm() < 1e-9 && to_goal < 1e-9,
                        "case {case}: ends at {f:?}, not {goal:?}"
                    );
                } else {
                    assert!(
                        to_goal > 1e-9,
                        "case {case}: at the goal at step {k}, s = {s}"
                    );
                    steps_taken.push(before.angle_to(&out.rotation));
                }
            }
            // The last step before the end may be a partial one: left out of the pace.
            steps_taken.pop();
            if steps_taken.len() > 2 {
                let mean = steps_taken.iter().sum::<f64>() / steps_taken.len() as f64;
                let most = steps_taken.iter().copied().fold(0.0, f64::max);
                assert!(
                    most <= 3.0 * mean + 1e-9,
                    "case {case}: a step of {:.2}° in a turn of mean {:.2}° steps",
                    most.to_degrees(),
                    mean.to_degrees()
                );
            }
        }
        assert!(
            out_of_reach == 0,
            "{out_of_reach} steps out of reach, the worst {worst:.2}° out"
        );
    }
}
