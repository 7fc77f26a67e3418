//! The simulated plant: PCC kinematics behind a configurable, seeded realism layer, for any
//! arm.
//!
//! Per actuator, a command passes backlash (play operator) → rate limit → first-order lag, and
//! a coloured disturbance moves the actuator from there; the kinematics use the arm (as a
//! scenario's steps change it at the plant's time, [`Body::Stepped`], and its [`Drift`]) with a
//! slow drift of
//! the actuator lengths, optionally bent not quite at constant curvature, and the tracker adds
//! noise to the end-effector position. With every effect off it is the kinematic model exactly.
//! Per-actuator state has room for every arm ([`MAX_ACTUATORS`]), so a step allocates nothing.

use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use softarm_arm::{Layout, MAX_ACTUATORS, MAX_MODULES};
use softarm_kinematics::pcc;
use softarm_sections::arm::{ArmConfig, MAX_OFFSET_M};
use softarm_sections::changes::{Drift, MAX_STEPS};
use softarm_sections::sim::{Realism, SimConfig};

/// The arm a plant simulates. Made once, where a plant is, and copied by value: the
/// variants' sizes do not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Body {
    /// Any arm, from its layout (`pcc::Arm`).
    Any(pcc::Arm),
    /// Any arm that a scenario's steps change: `start` until the first step's time, then each
    /// step's arm from its time (s of plant time) on.
    Stepped {
        start: pcc::Arm,
        steps: [Option<(f64, pcc::Arm)>; MAX_STEPS],
    },
}

impl Body {
    /// Any arm of `layout`, each actuator's length changed by `offset_m` (empty: none).
    pub fn of_layout(layout: &Layout, offset_m: &[f64]) -> Self {
        Self::Any(pcc::Arm::new(layout, offset_m))
    }

    /// The arm of `[arm]` `arm` (its offsets included), becoming each of `steps` (time in s of
    /// plant time, the arm from then on) at its time.
    pub fn of_arm(arm: &ArmConfig, steps: &[(f64, ArmConfig)]) -> Result<Self, String> {
        let start = pcc::Arm::of_config(arm)?;
        if steps.is_empty() {
            return Ok(Self::Any(start));
        }
        let steps = (steps.iter())
            .map(|(at_s, arm)| Ok((*at_s, pcc::Arm::of_config(arm)?)))
            .collect::<Result<Vec<_>, String>>()?;
        Self::stepped(start, &steps)
    }

    /// `start`, becoming each of `steps` (time in s of plant time, the arm) at its time: in
    /// order of time, at most [`MAX_STEPS`], each of `start`'s actuator count.
    pub fn stepped(start: pcc::Arm, steps: &[(f64, pcc::Arm)]) -> Result<Self, String> {
        if steps.len() > MAX_STEPS {
            return Err(format!("step[{MAX_STEPS}]: at most {MAX_STEPS} steps"));
        }
        let mut after = 0.0;
        for (k, (at_s, arm)) in steps.iter().enumerate() {
            if !(at_s.is_finite() && *at_s > after) {
                return Err(format!(
                    "step[{k}].at_s: must be after {after} s, got {at_s:?}"
                ));
            }
            if arm.actuators() != start.actuators() {
                return Err(format!(
                    "step[{k}]: an arm of {} actuators; the arm has {}",
                    arm.actuators(),
                    start.actuators()
                ));
            }
            after = *at_s;
        }
        let mut all = [None; MAX_STEPS];
        for (slot, s) in all.iter_mut().zip(steps) {
            *slot = Some(*s);
        }
        Ok(Self::Stepped { start, steps: all })
    }

    /// The arm at time 0.
    pub fn start(&self) -> &pcc::Arm {
        match self {
            Body::Any(a) | Body::Stepped { start: a, .. } => a,
        }
    }

    /// The step in force at plant time `t` (its index from 0), if any.
    pub fn step_at(&self, t: f64) -> Option<usize> {
        match self {
            Body::Any(_) => None,
            Body::Stepped { steps, .. } => steps
                .iter()
                .map_while(Option::as_ref)
                .take_while(|(at_s, _)| *at_s <= t)
                .count()
                .checked_sub(1),
        }
    }

    /// The arm at plant time `t`, for an arm that its steps or `drift` change: the step's arm
    /// in force, crept (each actuator's creep within [`MAX_OFFSET_M`]) and its tendons' radius
    /// cycled. `None` for an arm that nothing changes.
    fn drifted_at(&self, t: f64, drift: &Drift) -> Option<pcc::Arm> {
        let now = match self {
            Body::Any(_) if drift.is_off() => return None,
            Body::Any(arm) => *arm,
            Body::Stepped { start, steps } => {
                let now = steps
                    .iter()
                    .map_while(Option::as_ref)
                    .take_while(|(at_s, _)| *at_s <= t);
                now.last().map_or(*start, |(_, arm)| *arm)
            }
        };
        if drift.is_off() {
            return Some(now);
        }
        let o = MAX_OFFSET_M;
        let creep = drift.creep_m(t).map(|c| c.clamp(-o, o));
        let crept = now.changed(0.0, 0.0, &creep, &[0.0; MAX_MODULES]);
        Some(crept.widened(drift.radius_change_m(t)))
    }
}

/// A body simulated by physics of its own (a MuJoCo model, crate `softarm-mujoco`) in place of
/// the PCC kinematics: the realism layer's actuators drive it, and it says where the tracked
/// point is. It keeps its own time, stepped to the plant's.
pub trait Physics: Send {
    /// The arm's actuators it takes.
    fn actuators(&self) -> usize;
    /// Advances to `t` (s of the plant's clock) with `actuation` held (one per actuator, in
    /// [0, 1]), each actuator's length changed by `offset_m` (m); where the tracked point is
    /// then, in the arm's base frame (m). Allocates nothing.
    fn advance(&mut self, t: f64, actuation: &[f64], offset_m: &[f64]) -> [f64; 3];
    /// What it is, for logs and errors (a model's file, or what it was generated from).
    fn describe(&self) -> String;
}

/// What the plant measures after a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measurement {
    /// Normalised actuation the actuators actually reached (motor state), one per actuator;
    /// the rest of the array 0.
    pub actuation: [f64; MAX_ACTUATORS],
    /// Tracked end-effector position (m), with tracker noise.
    pub position: [f64; 3],
}

impl Measurement {
    /// The actuation as `N` values, for an arm of `N` actuators.
    pub fn actuation_of<const N: usize>(&self) -> [f64; N] {
        std::array::from_fn(|i| self.actuation[i])
    }
}

/// The simulated arm.
pub struct Plant {
    /// The arm at time 0, and its steps.
    body: Body,
    drift: Drift,
    /// The arm's kinematics at `time`.
    kinematics: pcc::Arm,
    /// Actuators.
    n: usize,
    realism: Realism,
    rng: StdRng,
    /// Output of the play operator.
    played: [f64; MAX_ACTUATORS],
    /// Actuator state after rate limit and lag.
    state: [f64; MAX_ACTUATORS],
    /// The disturbance on each actuator (normalised units).
    disturbance: [f64; MAX_ACTUATORS],
    /// Where the tip was last: kept while an actuation the arcs cannot tell lasts.
    position: [f64; 3],
    time: f64,
    /// Physics in place of the kinematics, if the plant has it.
    physics: Option<Box<dyn Physics>>,
}

impl Plant {
    /// A plant of `body` at rest at `initial` actuation (one per actuator).
    pub fn of_body(body: Body, realism: Realism, initial: &[f64]) -> Result<Self, String> {
        realism.validate()?;
        let kinematics = *body.start();
        let n = kinematics.actuators();
        if initial.len() != n {
            return Err(format!(
                "sim.initial_actuation: {} values for an arm of {n} actuators",
                initial.len()
            ));
        }
        if let Some(i) = initial.iter().position(|a| !(0.0..=1.0).contains(a)) {
            return Err(format!(
                "sim.initial_actuation: actuator {} is {:?}; each must be in [0, 1]",
                i + 1,
                initial[i]
            ));
        }
        let mut rng = StdRng::seed_from_u64(realism.seed);
        // Drawn from its stationary distribution: the disturbance is as large from the start.
        let mut disturbance = [0.0; MAX_ACTUATORS];
        for d in &mut disturbance[..n] {
            *d = realism.actuation_noise * rng.sample::<f64, _>(StandardNormal);
        }
        let mut start = [0.0; MAX_ACTUATORS];
        start[..n].copy_from_slice(initial);
        Ok(Self {
            body,
            drift: Drift::default(),
            kinematics,
            n,
            realism,
            rng,
            played: start,
            state: start,
            disturbance,
            position: [0.0; 3],
            time: 0.0,
            physics: None,
        })
    }

    /// This plant with `physics` in place of its kinematics: the same actuators, lag, rate
    /// limit, backlash, disturbance, length drift and tracker noise in front of physics of
    /// its own. A scenario's creep moves the actuators' lengths as on the kinematics; what
    /// else its steps change is the physics' to take (`softarm-mujoco`).
    pub fn with_physics(mut self, physics: Box<dyn Physics>) -> Result<Self, String> {
        if physics.actuators() != self.n {
            return Err(format!(
                "the physics ({}) has {} actuators; the arm has {}",
                physics.describe(),
                physics.actuators(),
                self.n
            ));
        }
        self.physics = Some(physics);
        Ok(self)
    }

    /// What physics the plant runs, if not its kinematics.
    pub fn physics(&self) -> Option<String> {
        self.physics.as_ref().map(|p| p.describe())
    }

    /// This plant with `drift` on its arm. `drift` is checked against the arm by whoever
    /// made it (`Scenario::apply_to`).
    pub fn drifting(mut self, drift: Drift) -> Self {
        self.drift = drift;
        self
    }

    /// The sim's plant: `body` (its steps included), drifting as `sim.drift` says, under
    /// `sim.realism`, at rest at `initial` (one per actuator). The sim driver and the
    /// rehearsal build theirs here, so a scenario runs the same in both.
    pub fn of_sim(body: Body, sim: &SimConfig, initial: &[f64]) -> Result<Self, String> {
        Ok(Self::of_body(body, sim.realism, initial)?.drifting(sim.drift))
    }

    /// The arm's kinematics now: its step in force at [`Plant::time`], drifted.
    pub fn arm(&self) -> &pcc::Arm {
        &self.kinematics
    }

    /// The arm at time 0, and its steps.
    pub fn body(&self) -> &Body {
        &self.body
    }

    /// The arm's actuators.
    pub fn actuators(&self) -> usize {
        self.n
    }

    /// Seconds since the plant started: the clock of its scenario's changes.
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Where the actuators are (before the disturbance), one per actuator.
    pub fn state(&self) -> &[f64] {
        &self.state[..self.n]
    }

    /// Advances by `dt` seconds with `command` applied (one per actuator), and measures. A
    /// command outside [0, 1] is clamped to it; a non-finite one holds that actuator's input
    /// where it was.
    pub fn step(&mut self, command: &[f64], dt: f64) -> Measurement {
        let r = self.realism;
        self.time += dt;
        // Physics of its own takes its changes itself (softarm-mujoco): no kinematics to move.
        if self.physics.is_none()
            && let Some(now) = self.body.drifted_at(self.time, &self.drift)
        {
            self.kinematics = now;
        }
        self.actuate(command, dt);
        self.disturb(dt);
        let mut actuation = [0.0; MAX_ACTUATORS];
        for i in 0..self.n {
            actuation[i] = (self.state[i] + self.disturbance[i]).clamp(0.0, 1.0);
        }
        let drift = self.length_drift();
        if let Some(physics) = &mut self.physics {
            let mut offset = drift;
            if !self.drift.is_off() {
                let o = MAX_OFFSET_M;
                for (d, c) in offset.iter_mut().zip(self.drift.creep_m(self.time)) {
                    *d += c.clamp(-o, o);
                }
            }
            self.position = physics.advance(self.time, &actuation[..self.n], &offset[..self.n]);
        } else {
            let mut lengths = self.kinematics.lengths(&actuation[..self.n]);
            for (l, d) in lengths[..self.n].iter_mut().zip(drift) {
                *l += d;
            }
            // An actuation whose arcs the model cannot tell (none of a valid arm's strokes)
            // keeps the tip where it was.
            if let Ok(p) = self
                .kinematics
                .pose_of_lengths(&lengths[..self.n], r.curvature_taper)
            {
                self.position = [p.position.x, p.position.y, p.position.z];
            }
        }
        let mut position = self.position;
        if r.tracker_noise_m > 0.0 {
            for x in &mut position {
                *x += r.tracker_noise_m * self.rng.sample::<f64, _>(StandardNormal);
            }
        }
        Measurement {
            actuation,
            position,
        }
    }

    /// Each actuator's slow length drift now (m): its own phase, as ageing material would.
    fn length_drift(&self) -> [f64; MAX_ACTUATORS] {
        let r = self.realism;
        let mut d = [0.0; MAX_ACTUATORS];
        if r.drift_m > 0.0 {
            let w = 2.0 * std::f64::consts::PI * self.time / r.drift_period_s;
            for (i, d) in d[..self.n].iter_mut().enumerate() {
                *d = r.drift_m * (w + 1.1 * i as f64).sin();
            }
        }
        d
    }

    /// Backlash, lag and rate limit: where each actuator goes under `command`.
    fn actuate(&mut self, command: &[f64], dt: f64) {
        let r = self.realism;
        for i in 0..self.n {
            let c = match command.get(i) {
                Some(c) if c.is_finite() => c.clamp(0.0, 1.0),
                _ => self.played[i],
            };
            // Play operator: the output follows once the input leaves the band around it.
            let half = 0.5 * r.backlash;
            self.played[i] = self.played[i].clamp(c - half, c + half);
            let mut target = self.played[i];
            if r.lag_s > 0.0 {
                let alpha = 1.0 - (-dt / r.lag_s).exp();
                target = self.state[i] + alpha * (target - self.state[i]);
            }
            if r.rate_limit_per_s > 0.0 {
                let step = r.rate_limit_per_s * dt;
                target = self.state[i] + (target - self.state[i]).clamp(-step, step);
            }
            self.state[i] = target;
        }
    }

    /// The disturbance `dt` later: the exact update of the Ornstein-Uhlenbeck process (any
    /// `dt`), which keeps its standard deviation at `actuation_noise`; fresh with τ = 0.
    fn disturb(&mut self, dt: f64) {
        let (sd, tau) = (
            self.realism.actuation_noise,
            self.realism.actuation_noise_correlation_s,
        );
        if sd == 0.0 {
            return;
        }
        let keep = if tau > 0.0 { (-dt / tau).exp() } else { 0.0 };
        let fresh = sd * (1.0 - keep * keep).sqrt();
        for d in &mut self.disturbance[..self.n] {
            *d = keep * *d + fresh * self.rng.sample::<f64, _>(StandardNormal);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use softarm_kinematics::forward::ForwardModel;

    /// The default `[arm]`'s actuators: the paper's arm.
    const N: usize = 6;

    /// The default `[arm]` (the paper's arm).
    fn default_arm() -> pcc::Arm {
        pcc::Arm::of_config(&ArmConfig::default()).unwrap()
    }

    /// A plant of the default `[arm]` at rest at `initial`.
    fn default_plant(realism: Realism, initial: [f64; N]) -> Result<Plant, String> {
        Plant::of_body(Body::Any(default_arm()), realism, &initial)
    }

    fn position(arm: &pcc::Arm, a: &[f64; N]) -> [f64; 3] {
        ForwardModel::<N>::position(arm, a)
    }

    #[test]
    fn a_command_that_is_not_a_number_holds_the_actuator() {
        let mut p = default_plant(Realism::default(), [0.5; N]).unwrap();
        for _ in 0..50 {
            p.step(&[0.6; N], 0.005);
        }
        let before = p.state().to_vec();
        let bad = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 0.6, 0.6, 0.6];
        let m = p.step(&bad, 0.005);
        assert!(m.position.iter().chain(&m.actuation).all(|v| v.is_finite()));
        // The three broken inputs hold where they were: those actuators only settle further.
        for i in 0..3 {
            assert!(
                (p.state()[i] - before[i]).abs() < 0.01,
                "{:?} -> {:?}",
                before,
                p.state()
            );
        }
    }

    #[test]
    fn with_every_effect_off_it_is_the_kinematic_model() {
        let arm = default_arm();
        let mut plant = default_plant(Realism::ideal(), [0.5; 6]).unwrap();
        for k in 0..200 {
            let c: [f64; 6] = std::array::from_fn(|i| {
                (0.5 + 0.4 * ((k + 7 * i) as f64 * 0.1).sin()).clamp(0.0, 1.0)
            });
            let m = plant.step(&c, 0.002);
            assert_eq!(m.actuation_of::<6>(), c);
            assert_eq!(m.position, position(&arm, &c));
        }
    }

    #[test]
    fn lag_and_rate_limit_slow_a_step() {
        let realism = Realism {
            lag_s: 0.1,
            rate_limit_per_s: 1.0,
            ..Realism::ideal()
        };
        let mut plant = default_plant(realism, [0.0; 6]).unwrap();
        let m = plant.step(&[1.0; 6], 0.01);
        assert!(
            (m.actuation[0] - 0.01).abs() < 1e-12,
            "rate limited: {}",
            m.actuation[0]
        );
        let mut last = m.actuation[0];
        for _ in 0..300 {
            last = plant.step(&[1.0; 6], 0.01).actuation[0];
        }
        assert!((last - 1.0).abs() < 1e-3, "settles: {last}");
    }

    /// What the sim driver relies on when it wakes late and steps by all the time that passed:
    /// one step of 5 dt goes as far as five of dt (lag exactly, the rate limit too).
    #[test]
    fn one_long_step_goes_as_far_as_the_short_ones_it_stands_for() {
        for realism in [
            Realism {
                lag_s: 0.02,
                ..Realism::ideal()
            },
            Realism {
                rate_limit_per_s: 2.0,
                ..Realism::ideal()
            },
        ] {
            let start = [0.2; N];
            let mut short = default_plant(realism, start).unwrap();
            let mut long = default_plant(realism, start).unwrap();
            let mut m = short.step(&[0.8; N], 0.005);
            for _ in 1..5 {
                m = short.step(&[0.8; N], 0.005);
            }
            let l = long.step(&[0.8; N], 0.025);
            for i in 0..N {
                assert!(
                    (m.actuation[i] - l.actuation[i]).abs() < 1e-12,
                    "{realism:?}"
                );
            }
        }
    }

    #[test]
    fn backlash_swallows_small_reversals() {
        let realism = Realism {
            backlash: 0.1,
            ..Realism::ideal()
        };
        let mut plant = default_plant(realism, [0.5; 6]).unwrap();
        assert!((plant.step(&[0.7; 6], 0.01).actuation[0] - 0.65).abs() < 1e-12);
        // Reversing by less than the band moves nothing.
        assert!((plant.step(&[0.62; 6], 0.01).actuation[0] - 0.65).abs() < 1e-12);
        assert!((plant.step(&[0.5; 6], 0.01).actuation[0] - 0.55).abs() < 1e-12);
    }

    #[test]
    fn noise_is_seeded_and_about_the_configured_size() {
        let realism = Realism {
            tracker_noise_m: 0.001,
            ..Realism::ideal()
        };
        let run = |seed| {
            let mut p = default_plant(Realism { seed, ..realism }, [0.5; 6]).unwrap();
            (0..2000)
                .map(|_| p.step(&[0.5; 6], 0.002).position[0])
                .collect::<Vec<_>>()
        };
        assert_eq!(run(3), run(3));
        assert_ne!(run(3), run(4));
        let xs = run(3);
        let sd = (xs.iter().map(|x| x * x).sum::<f64>() / xs.len() as f64).sqrt();
        assert!((sd - 0.001).abs() < 1e-4, "{sd}");
    }

    #[test]
    fn the_actuation_disturbance_has_the_configured_rms_and_is_coloured() {
        let realism = Realism {
            seed: 5,
            actuation_noise: 0.01,
            actuation_noise_correlation_s: 0.1,
            ..Realism::ideal()
        };
        let mut plant = default_plant(realism, [0.5; 6]).unwrap();
        // 1000 s at the sim's 200 Hz: 10 000 correlation times.
        let d: Vec<[f64; 6]> = (0..200_000)
            .map(|_| plant.step(&[0.5; 6], 0.005).actuation_of().map(|a| a - 0.5))
            .collect();
        for i in 0..6 {
            let x: Vec<f64> = d.iter().map(|a| a[i]).collect();
            let rms = (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt();
            assert!((rms / 0.01 - 1.0).abs() < 0.05, "actuator {i}: rms {rms}");
            let lag1 =
                x.windows(2).map(|w| w[0] * w[1]).sum::<f64>() / (rms * rms * x.len() as f64);
            // exp(-5 ms / 100 ms) = 0.951; white noise would give 0.
            assert!((lag1 - 0.951).abs() < 0.02, "actuator {i}: lag-1 {lag1}");
        }
        // The tip moves smoothly: consecutive positions 5 ms apart differ by a fraction of
        // what fresh noise of the same size makes.
        let step = |tau: f64| {
            let r = Realism {
                actuation_noise_correlation_s: tau,
                ..realism
            };
            let mut p = default_plant(r, [0.5; 6]).unwrap();
            let xs: Vec<[f64; 3]> = (0..2000)
                .map(|_| p.step(&[0.5; 6], 0.005).position)
                .collect();
            xs.windows(2)
                .map(|w| (w[1][0] - w[0][0]).abs())
                .sum::<f64>()
                / 1999.0
        };
        assert!(
            step(0.1) < 0.3 * step(0.0),
            "{} vs {}",
            step(0.1),
            step(0.0)
        );
    }

    #[test]
    fn a_scenario_changes_the_arm_at_the_plants_time() {
        use softarm_sections::changes::{Drift, Rates};
        let arm = default_arm();
        let drift = Drift {
            creep_mm_per_min: Rates::new(&[0.0, 6.0, 0.0, 0.0, 0.0, 0.0]).unwrap(),
            ..Drift::default()
        };
        let longer = ArmConfig {
            tool_m: Some(0.06),
            ..ArmConfig::default()
        };
        let body = Body::of_arm(&ArmConfig::default(), &[(1.0, longer.clone())]).unwrap();
        let sim = SimConfig {
            realism: Realism::ideal(),
            drift,
            ..SimConfig::default()
        };
        let mut plant = Plant::of_sim(body, &sim, &[0.5; 6]).unwrap();
        let run = |plant: &mut Plant, steps| {
            (0..steps)
                .map(|_| plant.step(&[0.5; 6], 0.005))
                .last()
                .unwrap()
        };
        let before = run(&mut plant, 199);
        assert_eq!(plant.body().step_at(plant.time()), None);
        let after = run(&mut plant, 2);
        assert_eq!(plant.body().step_at(plant.time()), Some(0));
        assert_eq!(before.actuation, after.actuation, "the actuation holds");
        // The tool 30 mm longer: the hanging, nearly straight arm's tip 30 mm lower.
        assert!(
            (before.position[2] - after.position[2] - 0.03).abs() < 1e-3,
            "{before:?} {after:?}"
        );
        // Creep at 6 mm/min: 0.1 mm a second, on the step's arm.
        let mut crept = [0.0; 6];
        crept[1] = 1.005e-4;
        let want =
            pcc::Arm::of_config(&longer)
                .unwrap()
                .changed(0.0, 0.0, &crept, &[0.0; MAX_MODULES]);
        let a = [0.3, 0.6, 0.5, 0.4, 0.5, 0.6];
        let (got, want) = (position(plant.arm(), &a), position(&want, &a));
        assert!(
            (0..3).all(|d| (got[d] - want[d]).abs() < 1e-9),
            "{got:?} {want:?}"
        );
        assert_ne!(position(&arm, &a), got);
    }

    #[test]
    fn a_curvature_taper_moves_the_tip_and_none_is_pcc() {
        let arm = default_arm();
        let a = [0.2, 0.8, 0.5, 0.9, 0.1, 0.4];
        let tapered = |c| {
            let r = Realism {
                curvature_taper: c,
                ..Realism::ideal()
            };
            default_plant(r, a).unwrap().step(&a, 0.005).position
        };
        assert_eq!(tapered(0.0), position(&arm, &a));
        let moved = (0..3)
            .map(|d| (tapered(0.5)[d] - position(&arm, &a)[d]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(moved > 2e-3, "{moved}");
    }

    /// A stepped arm is its start until the step's time, then the step's arm; steps out of
    /// order or of another count are refused naming the step.
    #[test]
    fn a_stepped_arm_becomes_each_step_at_its_time() {
        let text = include_str!("../../../contract/arm/testdata/tdcr.toml");
        let layout = Layout::new(&toml::from_str(text).unwrap()).unwrap();
        let start = pcc::Arm::new(&layout, &[]);
        let mut longer = [0.0; 9];
        longer[4] = 0.0005;
        let crept = pcc::Arm::new(&layout, &longer);
        let body = Body::stepped(start, &[(1.0, crept)]).unwrap();
        let mut plant = Plant::of_body(body, Realism::ideal(), &[0.5; 9]).unwrap();
        let at = |p: &mut Plant, steps: usize| {
            (0..steps)
                .map(|_| p.step(&[0.5; 9], 0.01))
                .last()
                .unwrap()
                .position
        };
        let distance = |a: &[f64; 3], b: &[f64; 3]| {
            ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
        };
        let before = at(&mut plant, 90);
        assert_eq!(before, at(&mut plant, 5));
        let after = at(&mut plant, 10);
        let want = crept.pose(&[0.5; 9]).unwrap().position;
        assert!((after[0] - want.x).abs() < 1e-9 && (after[2] - want.z).abs() < 1e-9);
        assert!(distance(&before, &after) > 0.001, "{before:?} {after:?}");
        let e = Body::stepped(start, &[(2.0, crept), (1.0, start)]).unwrap_err();
        assert!(e.starts_with("step[1].at_s"), "{e}");
        let six = default_arm();
        let e = Body::stepped(start, &[(2.0, six)]).unwrap_err();
        assert!(e.starts_with("step[0]: an arm of 6 actuators"), "{e}");
    }

    /// Any arm creeps as its drift says, within the bound on an offset; its tendons' radius
    /// cycles.
    #[test]
    fn any_arm_creeps_and_cycles_as_its_drift_says() {
        use softarm_sections::changes::Rates;
        let text = include_str!("../../../contract/arm/testdata/tdcr.toml");
        let layout = Layout::new(&toml::from_str(text).unwrap()).unwrap();
        let arm = pcc::Arm::new(&layout, &[]);
        let mut rates = [0.0; 9];
        rates[4] = 0.6;
        let drift = Drift {
            creep_mm_per_min: Rates::new(&rates).unwrap(),
            ..Drift::default()
        };
        let mut plant = Plant::of_body(Body::Any(arm), Realism::ideal(), &[0.5; 9])
            .unwrap()
            .drifting(drift);
        let a = [0.4, 0.6, 0.5, 0.55, 0.45, 0.5, 0.5, 0.6, 0.4];
        // Each step 10 s: 0.1 mm of tendon 5 a step.
        let at = |p: &mut Plant| p.step(&a, 10.0).position;
        let first = at(&mut plant);
        let mut offsets = [0.0; 9];
        offsets[4] = 0.0001;
        let want = pcc::Arm::new(&layout, &offsets).pose(&a).unwrap().position;
        assert!((first[0] - want.x).abs() < 1e-9 && (first[1] - want.y).abs() < 1e-9);
        // Past the bound (100 min at 0.6 mm/min is 60 mm): where the bound holds it.
        for _ in 0..2000 {
            at(&mut plant);
        }
        offsets[4] = MAX_OFFSET_M;
        let bound = pcc::Arm::new(&layout, &offsets).pose(&a).unwrap().position;
        let late = at(&mut plant);
        assert!((late[2] - bound.z).abs() < 1e-9, "{late:?} {bound:?}");
        // A radius cycle: a quarter period in, every tendon 1 mm further out.
        let cycle = Drift {
            actuator_radius_amplitude_m: 0.001,
            actuator_radius_period_s: 40.0,
            ..Drift::default()
        };
        let mut plant = Plant::of_body(Body::Any(arm), Realism::ideal(), &[0.5; 9])
            .unwrap()
            .drifting(cycle);
        let p = at(&mut plant);
        let want = arm.widened(0.001).pose(&a).unwrap().position;
        assert!((p[0] - want.x).abs() < 1e-9, "{p:?} {want:?}");
        assert!((p[0] - arm.pose(&a).unwrap().position.x).abs() > 1e-4);
    }

    #[test]
    fn drift_moves_the_arm_slowly() {
        let realism = Realism {
            drift_m: 0.001,
            drift_period_s: 10.0,
            ..Realism::ideal()
        };
        let mut plant = default_plant(realism, [0.5; 6]).unwrap();
        let first = plant.step(&[0.5; 6], 0.002).position;
        let mut later = first;
        for _ in 0..1250 {
            later = plant.step(&[0.5; 6], 0.002).position;
        }
        let moved = (0..3)
            .map(|d| (later[d] - first[d]).powi(2))
            .sum::<f64>()
            .sqrt();
        // 1 mm of uneven length change tilts a 25 mm-radius module by ~0.04 rad: ~2 cm at the tip.
        assert!(moved > 5e-3 && moved < 0.05, "{moved}");
        assert!(
            Plant::of_body(
                Body::Any(default_arm()),
                Realism {
                    drift_period_s: 0.0,
                    ..realism
                },
                &[0.5; 6]
            )
            .is_err()
        );
    }

    #[test]
    fn realism_errors_name_the_full_key_and_the_range() {
        let check = |r: Realism, want: &str| {
            let e = r.validate().unwrap_err();
            assert!(e.starts_with(want), "{e} (wanted {want:?})");
            let e = default_plant(r, [0.5; 6]).err().unwrap();
            assert!(e.starts_with(want), "{e}");
        };
        let ideal = Realism::ideal();
        check(
            Realism {
                lag_s: 1e300,
                ..ideal
            },
            "sim.realism.lag_s: must be in [0, 10] s",
        );
        check(
            Realism {
                tracker_noise_m: f64::INFINITY,
                ..ideal
            },
            "sim.realism.tracker_noise_m: must be in [0, 1] m",
        );
        check(
            Realism {
                actuation_noise: f64::NAN,
                ..ideal
            },
            "sim.realism.actuation_noise: must be in [0, 1]",
        );
        check(
            Realism {
                drift_m: 0.01,
                ..ideal
            },
            "sim.realism.drift_period_s: must be > 0 when drift_m is set",
        );
        check(
            Realism {
                actuation_noise_correlation_s: -0.1,
                ..ideal
            },
            "sim.realism.actuation_noise_correlation_s: must be in [0, 100] s",
        );
        check(
            Realism {
                curvature_taper: 1.5,
                ..ideal
            },
            "sim.realism.curvature_taper: must be in [0, 1]",
        );
        let e = default_plant(ideal, [0.5, 0.5, f64::NAN, 0.5, 0.5, 0.5]);
        assert!(
            e.err()
                .unwrap()
                .starts_with("sim.initial_actuation: actuator 3 is NaN")
        );
        Realism::default().validate().unwrap();
    }
}
