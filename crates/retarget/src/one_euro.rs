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
    pub fn new(min_cutoff: f64, beta: f64) -> Result<Self, Error> {
        if !(min_cutoff.is_finite() && min_cutoff > 0.0) {
            return Err(Error::InvalidConfig {
                key: "one_euro.min_cutoff",
                reason: format!("must be a positive number of Hz, got {min_cutoff}"),
            });
        }
        if !(beta.is_finite() && beta >= 0.0) {
            return Err(Error::InvalidConfig {
                key: "one_euro.beta",
                reason: format!("must be finite and not negative, got {beta}"),
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
        let dx_raw = (x - s.x) / dt;
        let a_d = alpha(self.params.d_cutoff, dt);
        let dx = s.dx + a_d * (dx_raw - s.dx);
        let cutoff = self.params.min_cutoff + self.params.beta * dx.abs();
        let a = alpha(cutoff, dt);
        let x_hat = s.x + a * (x - s.x);
        self.state = Some(State { t, x: x_hat, dx });
        x_hat
    }
}

#[cfg(test)]
mod tests {
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
}
