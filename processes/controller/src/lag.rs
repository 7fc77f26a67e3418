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
//! The estimate: per actuator, between two measured samples, the shortfall
//! e = setpoint − measured at their midpoint against the measured velocity ṁ there,
//! e ≈ c + τ ṁ (c: any steady offset, a sagged motor); τ by least squares over all the
//! actuators, the sums forgotten with a time constant of [`MEMORY_S`] so a changing arm is
//! followed. A first-order lag T gives exactly e = T ṁ, in a slew's start and end too, so the
//! slew of a set's first rest already tells it; a dead time d gives about d on smooth paths.
//! Fixed size: the tick allocates nothing.

/// Published setpoints kept: 256 ticks (0.5 s at 500 Hz), more than the lag and the measured
/// samples' age at any supported rate.
const RING: usize = 256;
/// What the measurement remembers (s): about a minute of motion.
const MEMORY_S: f64 = 60.0;
/// Two measured samples further apart than this (ns) tell no velocity: the driver was away.
const MAX_GAP_NS: u64 = 100_000_000;
/// Motion needed before τ is trusted: Σ (ṁ − mean ṁ)² over the sample pairs, (units/s)². 10 is
/// 40 pairs of one actuator slewing at 0.5 per s (0.2 s at 200 Hz), or a set's first rest
/// slewing three actuators by 0.05: less, and noise would set it.
const MIN_EXCITATION: f64 = 10.0;
/// The lead changes only when the lag measured is this far (ticks) from it: a set's lead is
/// what its points' corrections were learnt under, and a lead that flips by a tick between
/// sets moves a visited target by about a millimetre.
const HYSTERESIS_TICKS: f64 = 0.75;

/// The actuators' lag as measured, and the lead it asks for.
#[derive(Debug, Clone)]
pub struct ActuatorLag<const N: usize> {
    /// (time published, setpoint), oldest overwritten.
    published: [(u64, [f64; N]); RING],
    len: usize,
    next: usize,
    /// The newest measured sample taken in: (stamp ns, actuation).
    last_measured: Option<(u64, [f64; N])>,
    /// Exponentially forgotten sums: weight, per actuator Σe, Σṁ, Σeṁ, Σṁ².
    weight: f64,
    e: [f64; N],
    v: [f64; N],
    ev: [f64; N],
    vv: [f64; N],
    period_ns: u64,
    max_lead_ticks: i64,
    /// The lead in force (ticks).
    lead_ticks: i64,
}

impl<const N: usize> ActuatorLag<N> {
    /// For a tick of `rate_hz`, leads of at most `max_lead_s` (0: none).
    pub fn new(rate_hz: f64, max_lead_s: f64) -> Self {
        let period_ns = (1e9 / rate_hz).round().max(1.0) as u64;
        Self {
            published: [(0, [0.0; N]); RING],
            len: 0,
            next: 0,
            last_measured: None,
            weight: 0.0,
            e: [0.0; N],
            v: [0.0; N],
            ev: [0.0; N],
            vv: [0.0; N],
            period_ns,
            max_lead_ticks: (max_lead_s.max(0.0) * 1e9 / period_ns as f64).floor() as i64,
            lead_ticks: 0,
        }
    }

    /// The setpoint published at `now`, and the actuators' newest measured state (stamp, value)
    /// if any: a measured sample not taken in before is compared with what was published.
    /// Pass none while the setpoint is not the tick's own (held, stopped): the arm's state
    /// then says nothing of the lag.
    pub fn published(&mut self, now: u64, setpoint: &[f64; N], measured: Option<(u64, &[f64; N])>) {
        if self.newest().is_some_and(|(t, _)| now <= t) {
            return;
        }
        self.published[self.next] = (now, *setpoint);
        self.next = (self.next + 1) % RING;
        self.len = (self.len + 1).min(RING);
        let Some((stamp, m)) = measured else {
            return;
        };
        match self.last_measured {
            Some((t, _)) if stamp <= t => {}
            Some((t, before)) if stamp - t <= MAX_GAP_NS => {
                self.take_in(t, &before, stamp, m);
                self.last_measured = Some((stamp, *m));
            }
            _ => self.last_measured = Some((stamp, *m)),
        }
    }

    /// One pair of measured samples: the shortfall at their midpoint against their velocity.
    fn take_in(&mut self, t0: u64, m0: &[f64; N], t1: u64, m1: &[f64; N]) {
        let mid = t0 + (t1 - t0) / 2;
        let Some(at) = self.setpoint_at(mid) else {
            return;
        };
        let dt = (t1 - t0) as f64 * 1e-9;
        let forget = (-dt / MEMORY_S).exp();
        self.weight = self.weight * forget + 1.0;
        for i in 0..N {
            let e = at[i] - 0.5 * (m0[i] + m1[i]);
            let v = (m1[i] - m0[i]) / dt;
            self.e[i] = self.e[i] * forget + e;
            self.v[i] = self.v[i] * forget + v;
            self.ev[i] = self.ev[i] * forget + e * v;
            self.vv[i] = self.vv[i] * forget + v * v;
        }
        if let Some(s) = self.lag_s() {
            let x = s * 1e9 / self.period_ns as f64;
            if (x - self.lead_ticks as f64).abs() > HYSTERESIS_TICKS {
                self.lead_ticks = x.round() as i64;
            }
        }
    }

    /// The lag measured (s), once the arm has moved enough to tell; never negative.
    pub fn lag_s(&self) -> Option<f64> {
        let w = self.weight;
        if w <= 0.0 {
            return None;
        }
        let (mut cov, mut var) = (0.0, 0.0);
        for i in 0..N {
            cov += self.ev[i] - self.e[i] * self.v[i] / w;
            var += self.vv[i] - self.v[i] * self.v[i] / w;
        }
        (var >= MIN_EXCITATION).then(|| (cov / var).max(0.0))
    }

    /// How far ahead Eq. 11 is to be evaluated (ticks): the lag measured, rounded, changed only
    /// when the lag has moved by more than [`HYSTERESIS_TICKS`], at most the configured lead;
    /// 0 until measured.
    pub fn lead_ticks(&self) -> i64 {
        self.lead_ticks.min(self.max_lead_ticks)
    }

    /// [`ActuatorLag::lead_ticks`] in ns.
    pub fn lead_ns(&self) -> u64 {
        self.lead_ticks() as u64 * self.period_ns
    }

    /// The lead's cap (ticks).
    pub fn max_lead_ticks(&self) -> i64 {
        self.max_lead_ticks
    }

    /// The setpoint the actuators were following at `now` under a lead of `lead` ticks: the
    /// one published that long before (Eq. 11 at `now`, limited); none if no longer kept.
    pub fn followed(&self, now: u64, lead: i64) -> Option<[f64; N]> {
        let back = u64::try_from(lead).ok()?.saturating_mul(self.period_ns);
        self.setpoint_at(now.checked_sub(back)?)
    }

    fn newest(&self) -> Option<(u64, [f64; N])> {
        (self.len > 0).then(|| self.published[(self.next + RING - 1) % RING])
    }

    /// The setpoint in force at `t`: the last published at or before it, linearly toward the
    /// next (the arm's drivers take setpoints as they come); none before the oldest kept.
    fn setpoint_at(&self, t: u64) -> Option<[f64; N]> {
        let at = |k: usize| self.published[(self.next + RING - self.len + k) % RING];
        if self.len == 0 || t < at(0).0 {
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

    /// The default `[arm]`'s actuators.
    const N: usize = 6;

    const RATE_HZ: f64 = 500.0;
    const PERIOD: u64 = 2_000_000;
    /// The sim's motor_state period.
    const SAMPLE: u64 = 5_000_000;

    /// How the actuators follow: a first-order lag after a dead time, and a steady offset.
    #[derive(Clone, Copy)]
    struct Actuators {
        lag_s: f64,
        dead_ns: u64,
        offset: f64,
    }

    /// The actuators take each setpoint as it comes and hold it to the next (half a tick, 1 ms,
    /// behind the path on average), then lag it by 19 ms: 20 ms in all, which the lead is to
    /// make up.
    const SIM: Actuators = Actuators {
        lag_s: 0.019,
        dead_ns: 0,
        offset: 0.0,
    };
    const HALF_TICK_S: f64 = 0.001;

    /// Setpoints at 500 Hz along `path` for `seconds` from `lag`'s newest, the actuators
    /// following as `how` (from on the path), sampled every 5 ms, into `lag`.
    fn measure_into(
        lag: &mut ActuatorLag<N>,
        path: impl Fn(f64) -> [f64; N],
        how: Actuators,
        seconds: f64,
    ) {
        let start = lag.newest().map_or(0, |(t, _)| t + PERIOD);
        let mut actuators = path(start as f64 * 1e-9);
        let mut history: Vec<(u64, [f64; N])> = Vec::new();
        let mut measured = None;
        for k in 0..(seconds * 1e9) as u64 / PERIOD {
            let now = start + k * PERIOD;
            if now.is_multiple_of(SAMPLE) {
                measured = Some((now, actuators.map(|a| a + how.offset)));
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
                    .find(|(s, _)| *s + how.dead_ns <= t)
                    .map_or(path(start as f64 * 1e-9), |(_, a)| *a);
                let dt = PERIOD as f64 * 1e-10;
                for i in 0..N {
                    actuators[i] += (driving[i] - actuators[i]) * dt / how.lag_s;
                }
            }
            lag.published(now, &sp, measured.as_ref().map(|(t, m)| (*t, m)));
        }
    }

    fn measure(
        path: impl Fn(f64) -> [f64; N],
        how: Actuators,
        seconds: f64,
        max_lead_s: f64,
    ) -> ActuatorLag<N> {
        let mut lag = ActuatorLag::new(RATE_HZ, max_lead_s);
        measure_into(&mut lag, path, how, seconds);
        lag
    }

    fn swinging(t: f64) -> [f64; N] {
        std::array::from_fn(|i| 0.5 + 0.3 * (1.3 * t + i as f64).sin())
    }

    /// A set's first rest: three actuators slewed by 0.05 at the limiter's 1.5 per s, then
    /// held.
    fn slew(t: f64) -> [f64; N] {
        let x = 0.5 + (1.5 * t).min(0.05);
        [x, x, x, 0.5, 0.5, 0.5]
    }

    #[test]
    fn a_first_order_lag_is_measured_as_its_time_constant() {
        let lag = measure(swinging, SIM, 20.0, 0.1);
        let s = lag.lag_s().expect("measured");
        assert!((s - 0.02).abs() < 0.0005, "{s} s for 20 ms");
        assert_eq!((lag.lead_ticks(), lag.lead_ns()), (10, 20_000_000));
    }

    #[test]
    fn one_slew_tells_the_lag() {
        let lag = measure(slew, SIM, 0.8, 0.1);
        let s = lag.lag_s().expect("measured");
        assert!((s - 0.02).abs() < 0.001, "{s} s for 20 ms");
        assert_eq!(lag.lead_ticks(), 10);
    }

    #[test]
    fn a_dead_time_and_a_steady_offset_are_measured_as_the_lag_alone() {
        let how = Actuators {
            lag_s: 0.01,
            dead_ns: 30_000_000,
            offset: -0.02,
        };
        let s = measure(swinging, how, 20.0, 0.1).lag_s().expect("measured");
        let want = 0.04 + HALF_TICK_S;
        assert!((s - want).abs() < 0.001, "{s} s for 10 ms + 30 ms dead");
    }

    #[test]
    fn the_lead_is_capped_and_none_until_the_arm_has_moved() {
        let still = measure(|_| [0.5; N], SIM, 10.0, 0.1);
        assert_eq!((still.lag_s(), still.lead_ns()), (None, 0));
        let slow = Actuators { lag_s: 0.3, ..SIM };
        assert_eq!(
            measure(swinging, slow, 20.0, 0.1).lead_ns(),
            100_000_000,
            "capped at the configured 0.1 s"
        );
        let off = measure(swinging, SIM, 20.0, 0.0);
        assert!(off.lag_s().is_some());
        assert_eq!(off.lead_ticks(), 0, "0: no lead");
    }

    /// A lag measured a little off the lead leaves it; one that has moved by more than the
    /// hysteresis takes it along.
    #[test]
    fn the_lead_follows_the_lag_with_hysteresis() {
        let mut lag = measure(swinging, SIM, 20.0, 0.1);
        assert_eq!(lag.lead_ticks(), 10);
        let near = Actuators {
            lag_s: 0.0202,
            ..SIM
        };
        measure_into(&mut lag, swinging, near, 200.0);
        let s = lag.lag_s().unwrap();
        assert!((s - 0.0212).abs() < 0.0005, "{s}");
        assert_eq!(lag.lead_ticks(), 10, "10.6 ticks measured: 10 kept");
        let slower = Actuators {
            lag_s: 0.029,
            ..SIM
        };
        measure_into(&mut lag, swinging, slower, 200.0);
        assert_eq!(lag.lead_ticks(), 15);
    }

    #[test]
    fn setpoints_between_ticks_are_interpolated_and_old_samples_not_taken_twice() {
        let mut lag = ActuatorLag::new(RATE_HZ, 0.1);
        lag.published(0, &[0.0; N], None);
        lag.published(PERIOD, &[1.0; N], None);
        assert_eq!(lag.setpoint_at(PERIOD / 4), Some([0.25; N]));
        assert_eq!(lag.setpoint_at(5 * PERIOD), Some([1.0; N]));
        assert_eq!(lag.followed(PERIOD, 1), Some([0.0; N]));
        assert_eq!(lag.followed(PERIOD, 0), Some([1.0; N]));
        assert_eq!(lag.followed(PERIOD, 2), None, "before the oldest kept");
        // A tick at the same time again is not kept.
        lag.published(PERIOD, &[9.0; N], None);
        assert_eq!(lag.setpoint_at(PERIOD), Some([1.0; N]));
        // The same measured sample read on many ticks counts once; a first sample only starts
        // a pair.
        lag.published(2 * PERIOD, &[1.0; N], Some((PERIOD, &[0.1; N])));
        assert_eq!(lag.weight, 0.0);
        for k in 3..20 {
            lag.published(k * PERIOD, &[1.0; N], Some((3 * PERIOD, &[0.2; N])));
        }
        assert_eq!(lag.weight, 1.0);
        // After a gap the driver was away for, a sample starts a pair again.
        let late = 3 * PERIOD + MAX_GAP_NS + 1;
        lag.published(late, &[1.0; N], Some((late, &[0.3; N])));
        assert_eq!(lag.weight, 1.0);
    }
}
