//! The last word on every setpoint: clamped to the actuator limits, slewed at most a fixed step
//! per tick.

/// Clamps to the actuator limits and limits the change per tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limiter<const N: usize> {
    min: [f64; N],
    max: [f64; N],
    step: f64,
    last: [f64; N],
}

impl<const N: usize> Limiter<N> {
    pub fn new(
        min: [f64; N],
        max: [f64; N],
        slew_per_s: f64,
        rate_hz: f64,
        start: [f64; N],
    ) -> Self {
        let mut l = Self {
            min,
            max,
            step: slew_per_s / rate_hz,
            last: start,
        };
        l.reset(start);
        l
    }

    /// Starts again from a measured state, so resuming never jumps: the tick does this when it
    /// is safe again after an e-stop (after HOLD it goes on from the held setpoint, which the
    /// drivers kept applying).
    pub fn reset(&mut self, measured: [f64; N]) {
        self.last = std::array::from_fn(|i| measured[i].clamp(self.min[i], self.max[i]));
    }

    pub fn last(&self) -> [f64; N] {
        self.last
    }

    /// The setpoint for a target: at most `step` from the last, inside the limits. A non-finite
    /// target holds the last setpoint.
    pub fn apply(&mut self, target: &[f64; N]) -> [f64; N] {
        if target.iter().all(|v| v.is_finite()) {
            for i in 0..N {
                let t = target[i].clamp(self.min[i], self.max[i]);
                self.last[i] += (t - self.last[i]).clamp(-self.step, self.step);
            }
        }
        self.last
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default `[arm]`'s actuators.
    const N: usize = 6;

    #[test]
    fn the_limiter_clamps_and_slews() {
        let mut l = Limiter::new([0.1; N], [0.9; N], 1.0, 100.0, [0.5; N]);
        let out = l.apply(&[1.0; N]);
        assert!((out[0] - 0.51).abs() < 1e-12);
        for _ in 0..100 {
            l.apply(&[1.0; N]);
        }
        assert_eq!(l.last(), [0.9; N]);
        let held = l.apply(&[f64::NAN; N]);
        assert_eq!(held, [0.9; N]);
        l.reset([0.0; N]);
        assert_eq!(l.last(), [0.1; N]);
    }
}
