//! The actuators' lag behind the setpoints, measured while the arm moves, and the lead it asks
//! of Eq. 11.
//!
//! An actuator follows its setpoint late (a motor's position loop, a tendon's give, the bus and
//! the driver's cycle; the sim's first-order `lag_s`), so on a trajectory moving at v it stands
//! about τ v short of where Eq. 11 says it should be at T_cond: a few millimetres at the tip.
//! The tick measures τ from what it published and what the actuators reported, and an
//! execution evaluates Eq. 11 τ ahead of the clock, so the arm is where the blend says when it
//! says. τ is measured, never configured: a config value would be the sim's own `lag_s`
//! passing for adaptation.
//!
//! The estimate: per actuator, the shortfall e = setpoint(t) − measured(t) at each measured
//! sample's time t against the setpoint's velocity v there, e ≈ c + τ v (c: any steady offset,
//! a sagged motor, backlash at rest); τ by least squares over all six, the sums forgotten with
//! a time constant of [`MEMORY_S`] so a changing arm is followed. A first-order lag T gives
//! τ = T on a ramp; a dead time d gives d. Fixed size: the tick allocates nothing.

use softarm_ipc::{ACTUATORS, Actuation};

/// Published setpoints kept: 256 ticks (0.5 s at 500 Hz), more than the lag and the measured
/// samples' age at any supported rate.
const RING: usize = 256;
/// What the measurement remembers (s): about a minute of motion.
pub const MEMORY_S: f64 = 60.0;
/// The setpoint's velocity is taken over this (ns): long enough to average the limiter's
/// steps, short against the trajectories' changes.
const VELOCITY_WINDOW_NS: u64 = 10_000_000;
/// Motion needed before τ is trusted: Σ (v − v̄)² over the samples, (units/s)². 10 is 250
/// samples of one actuator at 0.2 per s (1.25 s at 200 Hz): less and an execution's first
/// second of rest would set it from noise.
const MIN_EXCITATION: f64 = 10.0;

/// The actuators' lag as measured, and the lead it asks for.
#[derive(Debug, Clone)]
pub struct ActuatorLag {
    /// (time published, setpoint), oldest overwritten.
    published: [(u64, Actuation); RING],
    len: usize,
    next: usize,
    /// The newest measured sample taken in (ns).
    last_measured_ns: Option<u64>,
    /// Exponentially forgotten sums: weight, per actuator Σe, Σv, Σev, Σv².
    weight: f64,
    e: Actuation,
    v: Actuation,
    ev: Actuation,
    vv: Actuation,
    max_lead_ns: u64,
}

impl ActuatorLag {
    /// Leads of at most `max_lead_s` (0: none).
    pub fn new(max_lead_s: f64) -> Self {
        Self {
            published: [(0, [0.0; ACTUATORS]); RING],
            len: 0,
            next: 0,
            last_measured_ns: None,
            weight: 0.0,
            e: [0.0; ACTUATORS],
            v: [0.0; ACTUATORS],
            ev: [0.0; ACTUATORS],
            vv: [0.0; ACTUATORS],
            max_lead_ns: (max_lead_s.max(0.0) * 1e9) as u64,
        }
    }

    /// The setpoint published at `now`, and the actuators' newest measured state (stamp, value)
    /// if any: a measured sample not taken in before is compared with what was published then.
    /// Only while the setpoint is the tick's own (the arm safe and driven): held, the arm's
    /// state says nothing of the lag.
    pub fn published(
        &mut self,
        now: u64,
        setpoint: &Actuation,
        measured: Option<(u64, &Actuation)>,
    ) {
        if self.newest().is_some_and(|(t, _)| now <= t) {
            return;
        }
        self.published[self.next] = (now, *setpoint);
        self.next = (self.next + 1) % RING;
        self.len = (self.len + 1).min(RING);
        let Some((stamp, m)) = measured else {
            return;
        };
        if self.last_measured_ns.is_some_and(|t| stamp <= t) {
            return;
        }
        let (Some(at), Some(before)) = (
            self.setpoint_at(stamp),
            self.setpoint_at(stamp.saturating_sub(VELOCITY_WINDOW_NS)),
        ) else {
            return;
        };
        let forget = self
            .last_measured_ns
            .map_or(1.0, |t| (-((stamp - t) as f64 * 1e-9) / MEMORY_S).exp());
        self.last_measured_ns = Some(stamp);
        let window_s = VELOCITY_WINDOW_NS as f64 * 1e-9;
        self.weight = self.weight * forget + 1.0;
        for i in 0..ACTUATORS {
            let e = at[i] - m[i];
            let v = (at[i] - before[i]) / window_s;
            self.e[i] = self.e[i] * forget + e;
            self.v[i] = self.v[i] * forget + v;
            self.ev[i] = self.ev[i] * forget + e * v;
            self.vv[i] = self.vv[i] * forget + v * v;
        }
    }

    /// The lag measured (s), once the arm has moved enough to tell; never negative.
    pub fn lag_s(&self) -> Option<f64> {
        let w = self.weight;
        if w <= 0.0 {
            return None;
        }
        let (mut cov, mut var) = (0.0, 0.0);
        for i in 0..ACTUATORS {
            cov += self.ev[i] - self.e[i] * self.v[i] / w;
            var += self.vv[i] - self.v[i] * self.v[i] / w;
        }
        (var >= MIN_EXCITATION).then(|| (cov / var).max(0.0))
    }

    /// How far ahead Eq. 11 is evaluated (ns): the lag measured, at most the configured lead;
    /// 0 until it is measured.
    pub fn lead_ns(&self) -> u64 {
        self.lag_s()
            .map_or(0, |s| ((s * 1e9) as u64).min(self.max_lead_ns))
    }

    /// The lead in ticks of `period_ns`, rounded.
    pub fn lead_ticks(&self, period_ns: u64) -> i64 {
        ((self.lead_ns() + period_ns / 2) / period_ns.max(1)) as i64
    }

    fn newest(&self) -> Option<(u64, Actuation)> {
        (self.len > 0).then(|| self.published[(self.next + RING - 1) % RING])
    }

    /// The setpoint in force at `t`: the last published at or before it, linearly toward the
    /// next (the arm's drivers take setpoints as they come); none before the oldest kept.
    fn setpoint_at(&self, t: u64) -> Option<Actuation> {
        let at = |k: usize| self.published[(self.next + RING - self.len + k) % RING];
        let (oldest, _) = at(0);
        if self.len == 0 || t < oldest {
            return None;
        }
        // Newest first: the samples asked for are recent.
        let k = (0..self.len).rev().find(|&k| at(k).0 <= t)?;
        let (t0, a0) = at(k);
        if k + 1 == self.len {
            return Some(a0);
        }
        let (t1, a1) = at(k + 1);
        let f = (t - t0) as f64 / (t1 - t0) as f64;
        Some(std::array::from_fn(|i| a0[i] + f * (a1[i] - a0[i])))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PERIOD: u64 = 2_000_000;
    /// The sim's motor_state period.
    const SAMPLE: u64 = 5_000_000;

    /// Setpoints at 500 Hz along `path`, actuators following them as first-order lag `lag_s`
    /// after `dead_ns`, plus `offset`, sampled every 5 ms; the lag measured after `seconds`.
    fn measure(
        path: impl Fn(f64) -> Actuation,
        lag_s: f64,
        dead_ns: u64,
        offset: f64,
        seconds: f64,
        max_lead_s: f64,
    ) -> ActuatorLag {
        let mut lag = ActuatorLag::new(max_lead_s);
        let mut actuators = path(0.0);
        let mut history: Vec<(u64, Actuation)> = Vec::new();
        let mut measured = None;
        let ticks = (seconds * 1e9) as u64 / PERIOD;
        for k in 0..ticks {
            let now = k * PERIOD;
            if now.is_multiple_of(SAMPLE) {
                measured = Some((now, actuators.map(|a| a + offset)));
            }
            let sp = path(now as f64 * 1e-9);
            history.push((now, sp));
            // Up to the next tick the actuators integrate the setpoint in force dead_ns
            // before, finely.
            for sub in 0..10 {
                let t = now + sub * PERIOD / 10;
                let driving = history
                    .iter()
                    .rev()
                    .find(|(s, _)| *s + dead_ns <= t)
                    .map_or(path(0.0), |(_, a)| *a);
                let dt = PERIOD as f64 * 1e-10;
                for i in 0..ACTUATORS {
                    actuators[i] += (driving[i] - actuators[i]) * dt / lag_s;
                }
            }
            lag.published(now, &sp, measured.as_ref().map(|(t, m)| (*t, m)));
        }
        lag
    }

    fn swinging(t: f64) -> Actuation {
        std::array::from_fn(|i| 0.5 + 0.3 * (1.3 * t + i as f64).sin())
    }

    #[test]
    fn a_first_order_lag_is_measured_as_its_time_constant() {
        let lag = measure(swinging, 0.02, 0, 0.0, 20.0, 0.1);
        let s = lag.lag_s().expect("measured");
        assert!((s - 0.02).abs() < 0.001, "{s} s for 20 ms");
        assert_eq!(lag.lead_ticks(PERIOD), 10);
    }

    #[test]
    fn a_dead_time_and_a_steady_offset_are_measured_as_the_lag_alone() {
        let lag = measure(swinging, 0.01, 30_000_000, -0.02, 20.0, 0.1);
        let s = lag.lag_s().expect("measured");
        assert!((s - 0.04).abs() < 0.001, "{s} s for 10 ms + 30 ms dead");
    }

    #[test]
    fn the_lead_is_capped_and_none_until_the_arm_has_moved() {
        let still = measure(|_| [0.5; ACTUATORS], 0.02, 0, 0.0, 10.0, 0.1);
        assert_eq!((still.lag_s(), still.lead_ns()), (None, 0));
        let slow = measure(swinging, 0.3, 0, 0.0, 20.0, 0.1);
        assert_eq!(
            slow.lead_ns(),
            100_000_000,
            "capped at the configured 0.1 s"
        );
        let off = measure(swinging, 0.02, 0, 0.0, 20.0, 0.0);
        assert!(off.lag_s().is_some());
        assert_eq!(off.lead_ticks(PERIOD), 0, "0: no lead");
    }

    #[test]
    fn setpoints_between_ticks_are_interpolated_and_old_samples_not_taken_twice() {
        let mut lag = ActuatorLag::new(0.1);
        lag.published(0, &[0.0; ACTUATORS], None);
        lag.published(PERIOD, &[1.0; ACTUATORS], None);
        assert_eq!(lag.setpoint_at(PERIOD / 4), Some([0.25; ACTUATORS]));
        assert_eq!(lag.setpoint_at(5 * PERIOD), Some([1.0; ACTUATORS]));
        // A tick at the same time again is not kept.
        lag.published(PERIOD, &[9.0; ACTUATORS], None);
        assert_eq!(lag.setpoint_at(PERIOD), Some([1.0; ACTUATORS]));
        // The same measured sample read on two ticks counts once.
        let m = [0.5; ACTUATORS];
        for k in 2..20 {
            lag.published(k * PERIOD, &[1.0; ACTUATORS], Some((PERIOD * 15 / 2, &m)));
        }
        assert_eq!(lag.weight, 1.0);
    }
}
