//! The One Euro filter (Casiez, Roussel, Vogel, "1€ Filter: A Simple Speed-based Low-pass
//! Filter for Noisy Input in Interactive Systems", CHI 2012): a low-pass whose cutoff rises
//! with speed, so slow motion is smoothed and fast motion keeps little lag.

use std::f64::consts::PI;

use crate::Error;

/// Parameters of the filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OneEuroParams {
    /// Cutoff at rest, Hz (`fcmin`). Lower: smoother, more lag at low speed.
    pub min_cutoff: f64,
    /// Speed coefficient (`β`). Higher: less lag when moving fast.
    pub beta: f64,
    /// Cutoff for the derivative, Hz (the paper uses 1 Hz).
    pub d_cutoff: f64,
}

impl OneEuroParams {
    /// Parameters with the paper's derivative cutoff (1 Hz); checked.
    /// Highest minimum cut-off, Hz: a kilohertz camera's Nyquist frequency is 500 Hz.
    pub const MAX_MIN_CUTOFF_HZ: f64 = 1000.0;
    /// Highest speed coefficient (s per unit of the signal).
    pub const MAX_BETA: f64 = 1000.0;

    /// Refuses what no camera's frame rate can use: a cut-off above
    /// [`Self::MAX_MIN_CUTOFF_HZ`] passes every frame unfiltered, and a speed coefficient above
    /// [`Self::MAX_BETA`] does the same at any motion.
    pub fn new(min_cutoff: f64, beta: f64) -> Result<Self, Error> {
        if !(min_cutoff.is_finite() && min_cutoff > 0.0 && min_cutoff <= Self::MAX_MIN_CUTOFF_HZ) {
            return Err(Error::InvalidConfig {
                key: "one_euro.min_cutoff",
                reason: format!(
                    "must be a number of Hz above 0 and at most {}, got {min_cutoff}",
                    Self::MAX_MIN_CUTOFF_HZ
                ),
            });
        }
        if !(beta.is_finite() && (0.0..=Self::MAX_BETA).contains(&beta)) {
            return Err(Error::InvalidConfig {
                key: "one_euro.beta",
                reason: format!("must be within 0 to {}, got {beta}", Self::MAX_BETA),
            });
        }
        Ok(Self {
            min_cutoff,
            beta,
            d_cutoff: 1.0,
        })
    }
}

/// Smoothing factor of an exponential low-pass with cutoff `cutoff` Hz at sampling step `dt`.
fn alpha(cutoff: f64, dt: f64) -> f64 {
    let tau = 1.0 / (2.0 * PI * cutoff);
    1.0 / (1.0 + tau / dt)
}

/// One scalar signal's filter state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OneEuro {
    params: OneEuroParams,
    state: Option<State>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct State {
    t: f64,
    x: f64,
    dx: f64,
}

impl State {
    /// The filtered derivative after sample `x` at `t` (later than this state's time).
    fn speed(&self, params: &OneEuroParams, t: f64, x: f64) -> f64 {
        let dt = t - self.t;
        let dx_raw = (x - self.x) / dt;
        self.dx + alpha(params.d_cutoff, dt) * (dx_raw - self.dx)
    }

    /// The state after sample `x` at `t`, smoothed at `cutoff` Hz, with derivative `dx`.
    fn step(&self, cutoff: f64, t: f64, x: f64, dx: f64) -> State {
        let x_hat = self.x + alpha(cutoff, t - self.t) * (x - self.x);
        State { t, x: x_hat, dx }
    }
}

impl OneEuro {
    /// A filter that has seen nothing yet.
    pub fn new(params: OneEuroParams) -> Self {
        Self {
            params,
            state: None,
        }
    }

    /// Forgets the history.
    pub fn reset(&mut self) {
        self.state = None;
    }

    /// Filters sample `x` taken at time `t` (seconds). The first sample passes unchanged. A
    /// sample at the same time as the previous one (or earlier) returns the previous output.
    pub fn filter(&mut self, t: f64, x: f64) -> f64 {
        let Some(s) = self.state else {
            self.state = Some(State { t, x, dx: 0.0 });
            return x;
        };
        let dt = t - s.t;
        if dt.is_nan() || dt <= 0.0 {
            return s.x;
        }
        let dx = s.speed(&self.params, t, x);
        let next = s.step(
            self.params.min_cutoff + self.params.beta * dx.abs(),
            t,
            x,
            dx,
        );
        self.state = Some(next);
        next.x
    }
}

/// Several signals that move together (the depths of dots on one rigid forehead), each with
/// its own state but one cutoff for all: the one the fastest of them asks for. With a cutoff
/// per signal, a head turning fast moves some depths fast and others slowly, the slow ones
/// lag more, and the lag turns the head; with one cutoff every signal lags alike.
#[derive(Debug, Clone, PartialEq)]
pub struct OneEuroGroup {
    params: OneEuroParams,
    members: Vec<Option<State>>,
    /// Per signal, this call's filtered derivative (kept to allocate once).
    speeds: Vec<f64>,
}

impl OneEuroGroup {
    /// `n` signals that have seen nothing yet.
    pub fn new(params: OneEuroParams, n: usize) -> Self {
        Self {
            params,
            members: vec![None; n],
            speeds: Vec::with_capacity(n),
        }
    }

    /// Forgets every signal's history.
    pub fn reset(&mut self) {
        self.members.iter_mut().for_each(|m| *m = None);
    }

    /// Filters the samples `xs` taken at time `t` in place, one per signal. A `None` sample
    /// (the signal unseen) forgets that signal's history; a signal seen again, like a new
    /// one, passes its first sample unchanged. A call at the same time as the previous one
    /// (or earlier) returns the previous outputs.
    pub fn filter(&mut self, t: f64, xs: &mut [Option<f64>]) {
        debug_assert_eq!(xs.len(), self.members.len());
        let mut fastest: f64 = 0.0;
        let speeds = &mut self.speeds;
        speeds.clear();
        for (m, x) in self.members.iter().zip(xs.iter()) {
            let dx = match (m, x) {
                (Some(s), Some(x)) if t > s.t => s.speed(&self.params, t, *x),
                _ => 0.0,
            };
            fastest = fastest.max(dx.abs());
            speeds.push(dx);
        }
        let cutoff = self.params.min_cutoff + self.params.beta * fastest;
        for ((m, x), &dx) in self
            .members
            .iter_mut()
            .zip(xs.iter_mut())
            .zip(speeds.iter())
        {
            match (m.as_mut(), x.as_mut()) {
                (_, None) => *m = None,
                (None, Some(x)) => *m = Some(State { t, x: *x, dx: 0.0 }),
                (Some(s), Some(x)) if t > s.t => {
                    *s = s.step(cutoff, t, *x, dx);
                    *x = s.x;
                }
                (Some(s), Some(x)) => *x = s.x,
            }
        }
    }
}

#[cfg(test)]
mod tests {

    #[test]
    fn parameters_no_frame_rate_can_use_are_refused() {
        assert!(OneEuroParams::new(1.0, 0.007).is_ok());
        assert!(
            OneEuroParams::new(OneEuroParams::MAX_MIN_CUTOFF_HZ, OneEuroParams::MAX_BETA).is_ok()
        );
        for (min_cutoff, beta) in [
            (1e300, 0.0),
            (1.0, 1e300),
            (0.0, 0.0),
            (1.0, -0.1),
            (f64::NAN, 0.0),
        ] {
            assert!(
                OneEuroParams::new(min_cutoff, beta).is_err(),
                "{min_cutoff} {beta}"
            );
        }
    }
    use super::*;

    #[test]
    fn constant_signal_passes() {
        let mut f = OneEuro::new(OneEuroParams::new(1.0, 0.0).unwrap());
        for i in 0..100 {
            assert_eq!(f.filter(i as f64 / 60.0, 3.5), 3.5);
        }
    }

    #[test]
    fn matches_hand_computed_steps() {
        // Paper's formulas by hand: fcmin 1 Hz, β 0.5, dcutoff 1 Hz, dt 0.1 s.
        let mut f = OneEuro::new(OneEuroParams::new(1.0, 0.5).unwrap());
        assert_eq!(f.filter(0.0, 0.0), 0.0);
        let a_d = alpha(1.0, 0.1);
        let dx = a_d * 10.0; // raw derivative (1 - 0) / 0.1
        let a = alpha(1.0 + 0.5 * dx, 0.1);
        let expect = a * 1.0;
        assert!((f.filter(0.1, 1.0) - expect).abs() < 1e-15);
        // alpha = 1 / (1 + tau/dt) with tau = 1/(2π·fc)
        assert!((alpha(1.0, 0.1) - 1.0 / (1.0 + 1.0 / (2.0 * PI) / 0.1)).abs() < 1e-15);
    }

    #[test]
    fn reduces_noise_on_a_slow_signal() {
        let mut f = OneEuro::new(OneEuroParams::new(1.0, 0.0).unwrap());
        let mut raw_err = 0.0;
        let mut filt_err = 0.0;
        for i in 0..600 {
            let t = i as f64 / 60.0;
            let noise = if i % 2 == 0 { 0.01 } else { -0.01 };
            let y = f.filter(t, t * 0.01 + noise);
            if i > 60 {
                raw_err += noise * noise;
                filt_err += (y - t * 0.01).powi(2);
            }
        }
        assert!(filt_err < raw_err * 0.1, "{filt_err} vs {raw_err}");
    }

    #[test]
    fn repeated_timestamp_holds() {
        let mut f = OneEuro::new(OneEuroParams::new(1.0, 0.0).unwrap());
        f.filter(0.0, 0.0);
        let y = f.filter(0.1, 1.0);
        assert_eq!(f.filter(0.1, 5.0), y);
    }

    #[test]
    fn bad_parameters_are_refused() {
        assert!(OneEuroParams::new(0.0, 0.0).is_err());
        assert!(OneEuroParams::new(1.0, -1.0).is_err());
        assert!(OneEuroParams::new(f64::NAN, 0.0).is_err());
    }

    /// One signal alone is filtered exactly as by [`OneEuro`].
    #[test]
    fn a_group_of_one_is_the_plain_filter() {
        let params = OneEuroParams::new(2.0, 200.0).unwrap();
        let mut plain = OneEuro::new(params);
        let mut group = OneEuroGroup::new(params, 1);
        for i in 0..200 {
            let t = i as f64 / 30.0;
            let x = 0.6 + 0.02 * (t * 7.0).sin() + if i % 3 == 0 { 0.001 } else { -0.0005 };
            let mut xs = [Some(x)];
            group.filter(t, &mut xs);
            assert_eq!(xs[0], Some(plain.filter(t, x)));
        }
    }

    /// Two depths of one rigid body turning (one moving five times as fast as the other)
    /// keep their ratio through the group, as the turn does; filtered apart, the slow one
    /// lags more and the ratio, the turn, is wrong.
    #[test]
    fn a_group_lags_alike_where_separate_filters_do_not() {
        let params = OneEuroParams::new(2.0, 200.0).unwrap();
        let mut group = OneEuroGroup::new(params, 2);
        let mut apart = [OneEuro::new(params), OneEuro::new(params)];
        let (mut worst_group, mut worst_apart) = (0.0f64, 0.0f64);
        for i in 0..60 {
            let t = i as f64 / 30.0;
            let fast = 0.01 * (t * 6.0).sin();
            let xs_true = [fast, 0.2 * fast];
            let mut xs = xs_true.map(Some);
            group.filter(t, &mut xs);
            let [a, b] = xs.map(Option::unwrap);
            let [c, d] = [
                apart[0].filter(t, xs_true[0]),
                apart[1].filter(t, xs_true[1]),
            ];
            if a.abs() > 1e-4 {
                worst_group = worst_group.max((b / a - 0.2).abs());
                worst_apart = worst_apart.max((d / c - 0.2).abs());
            }
        }
        assert!(worst_group < 1e-9, "{worst_group}");
        assert!(worst_apart > 0.02, "{worst_apart}");
    }

    /// An unseen signal forgets its history and passes its first sample when it returns;
    /// a repeated time returns the previous outputs.
    #[test]
    fn a_group_member_unseen_starts_afresh() {
        let params = OneEuroParams::new(1.0, 0.0).unwrap();
        let mut group = OneEuroGroup::new(params, 2);
        let mut xs = [Some(0.0), Some(0.0)];
        group.filter(0.0, &mut xs);
        let mut xs = [Some(1.0), None];
        group.filter(0.1, &mut xs);
        let smoothed = xs[0].unwrap();
        assert!(smoothed > 0.0 && smoothed < 1.0 && xs[1].is_none());
        let mut again = [Some(5.0), None];
        group.filter(0.1, &mut again);
        assert_eq!(again[0], Some(smoothed));
        let mut xs = [Some(1.0), Some(3.0)];
        group.filter(0.2, &mut xs);
        assert_eq!(xs[1], Some(3.0));
    }
}
