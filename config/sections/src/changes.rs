//! How the simulated arm changes while it runs: a scenario's steps (the arm becomes another at
//! a given time, as when a tool is swapped) and drifts (actuators creeping, stiffness cycling),
//! as a function of the plant's own time. Plain data with its validation and its value at a
//! time: the config checks that the arm stays valid at every time with the very
//! [`Changes::arm_at`] the plant (`softarm_sim::plant`) runs. [`Changes::arm_at`] allocates
//! nothing, so the plant evaluates it every step.

use serde::{Deserialize, Serialize};

use crate::arm::{ACTUATORS, ArmGeometry};
use softarm_space::MAX_ACTUATORS;

/// Most steps a scenario may hold (fixed, so [`Changes`] is `Copy` and allocation-free).
pub const MAX_STEPS: usize = 16;
/// Fastest creep (mm per minute), either way.
pub const MAX_CREEP_MM_PER_MIN: f64 = 10.0;
/// Latest step and longest cycle (s): about eleven days.
pub const MAX_TIME_S: f64 = 1e6;

/// The arm from `at_s` on (s of plant time): the arm before it with the step's keys changed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Step {
    pub at_s: f64,
    pub arm: ArmGeometry,
}

/// A scenario's `[drift]`: slow changes that go on all the time, on whatever arm the steps
/// have made. Zero turns each off.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Drift {
    /// How fast each actuator lengthens (mm per minute; negative: shortens), from time 0, added
    /// to the arm's `actuator_offset_m`: one per actuator of the arm, or none. The sum stops at ±[`ArmGeometry::MAX_OFFSET_M`]
    /// (100 minutes at 0.5 mm/min): the arm stays valid however long the sim runs.
    #[schemars(with = "Vec<f64>")]
    pub creep_mm_per_min: Rates,
    /// Amplitude of the actuator radius's cycle (m): r(t) = r + A sin(2π t / P) for every
    /// tendon, as a module stiffening and softening with temperature or pressure.
    pub actuator_radius_amplitude_m: f64,
    /// Period P of that cycle (s).
    pub actuator_radius_period_s: f64,
}

impl Drift {
    pub fn is_off(&self) -> bool {
        *self == Self::default()
    }

    /// Checks every value; the error is `drift.KEY: message`.
    pub fn validate(&self) -> Result<(), String> {
        let c = MAX_CREEP_MM_PER_MIN;
        for (i, v) in self.creep_mm_per_min.as_slice().iter().enumerate() {
            if !(v.is_finite() && (-c..=c).contains(v)) {
                return Err(format!(
                    "drift.creep_mm_per_min: actuator {} is {v:?}; each must be in [-{c}, {c}] mm/min",
                    i + 1
                ));
            }
        }
        let (a, p) = (
            self.actuator_radius_amplitude_m,
            self.actuator_radius_period_s,
        );
        let r = ArmGeometry::MAX_RADIUS_M;
        if !(a.is_finite() && (0.0..=r).contains(&a)) {
            return Err(format!(
                "drift.actuator_radius_amplitude_m: must be in [0, {r}] m (0 turns it off), got {a:?}"
            ));
        }
        if !(p.is_finite() && (0.0..=MAX_TIME_S).contains(&p)) {
            return Err(format!(
                "drift.actuator_radius_period_s: must be in [0, {MAX_TIME_S}] s, got {p:?}"
            ));
        }
        if a > 0.0 && p == 0.0 {
            return Err(
                "drift.actuator_radius_period_s: must be > 0 when actuator_radius_amplitude_m is set"
                    .into(),
            );
        }
        Ok(())
    }

    /// The length each actuator has crept by at time `t` (m), before the bound; 0 past the
    /// rates given.
    pub fn creep_m(&self, t: f64) -> [f64; MAX_ACTUATORS] {
        self.creep_mm_per_min.values.map(|v| v * 1e-3 * t / 60.0)
    }

    /// Checks it for an arm of `actuators` actuators whose tendons' smallest routing radius is
    /// `min_radius_m` (`None`: no tendon): a rate per actuator, and a radius cycle that leaves
    /// every tendon's radius above 0. The error is `drift.KEY: message`.
    pub fn check_for(&self, actuators: usize, min_radius_m: Option<f64>) -> Result<(), String> {
        self.validate()?;
        let given = self.creep_mm_per_min.len();
        if given != 0 && given != actuators {
            return Err(format!(
                "drift.creep_mm_per_min: {given} values for an arm of {actuators} actuators; \
                 give one per actuator in the arm's order"
            ));
        }
        let a = self.actuator_radius_amplitude_m;
        match min_radius_m {
            _ if a == 0.0 => Ok(()),
            None => Err(format!(
                "drift.actuator_radius_amplitude_m: {a} m, but this arm has no tendon whose \
                 radius could cycle"
            )),
            Some(r) if a >= r => Err(format!(
                "drift.actuator_radius_amplitude_m: {a} m takes the smallest tendon radius \
                 ({r} m) to 0 or below; it must be under {r} m"
            )),
            Some(_) => Ok(()),
        }
    }

    /// The actuator radius's change at time `t` (m).
    pub fn radius_change_m(&self, t: f64) -> f64 {
        if self.actuator_radius_amplitude_m == 0.0 {
            return 0.0;
        }
        let w = 2.0 * std::f64::consts::PI / self.actuator_radius_period_s;
        self.actuator_radius_amplitude_m * (w * t).sin()
    }
}

/// A rate per actuator, as many as given (up to [`MAX_ACTUATORS`]): fixed capacity, so a
/// [`Drift`] stays `Copy` and the plant reads it without allocating.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Rates {
    values: [f64; MAX_ACTUATORS],
    count: usize,
}

impl Rates {
    /// `values`, at most [`MAX_ACTUATORS`].
    pub fn new(values: &[f64]) -> Result<Self, String> {
        if values.len() > MAX_ACTUATORS {
            return Err(format!(
                "{} values; an arm has at most {MAX_ACTUATORS} actuators",
                values.len()
            ));
        }
        let mut r = Self::default();
        r.values[..values.len()].copy_from_slice(values);
        r.count = values.len();
        Ok(r)
    }

    pub fn as_slice(&self) -> &[f64] {
        &self.values[..self.count]
    }

    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Actuator `i`'s rate (0 past those given).
    pub fn set(&mut self, i: usize, v: f64) {
        self.values[i] = v;
        self.count = self.count.max(i + 1);
    }
}

impl Serialize for Rates {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        self.as_slice().serialize(s)
    }
}

impl<'de> Deserialize<'de> for Rates {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let v = Vec::<f64>::deserialize(d)?;
        Self::new(&v).map_err(serde::de::Error::custom)
    }
}

/// How the arm changes over the plant's time: steps in order of time, and a drift.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Changes {
    steps: [Option<Step>; MAX_STEPS],
    pub drift: Drift,
}

impl Changes {
    /// Steps in order of time and a drift; errors name `step[k].at_s` or `drift.KEY`. The arms
    /// are checked against the arm they start from by [`Changes::validate`].
    pub fn new(steps: &[Step], drift: Drift) -> Result<Self, String> {
        if steps.len() > MAX_STEPS {
            return Err(format!(
                "step[{MAX_STEPS}]: at most {MAX_STEPS} steps, got {}",
                steps.len()
            ));
        }
        let mut after = 0.0;
        for (k, s) in steps.iter().enumerate() {
            if !(s.at_s.is_finite() && s.at_s > after && s.at_s <= MAX_TIME_S) {
                return Err(format!(
                    "step[{k}].at_s: must be after {after} s (the steps in order of time, the \
                     first after 0) and at most {MAX_TIME_S} s, got {:?}",
                    s.at_s
                ));
            }
            after = s.at_s;
        }
        drift.validate()?;
        let mut all = [None; MAX_STEPS];
        for (slot, s) in all.iter_mut().zip(steps) {
            *slot = Some(*s);
        }
        Ok(Self { steps: all, drift })
    }

    /// Whether the arm never changes.
    pub fn is_empty(&self) -> bool {
        self.steps[0].is_none() && self.drift.is_off()
    }

    pub fn steps(&self) -> impl Iterator<Item = &Step> {
        self.steps.iter().map_while(Option::as_ref)
    }

    /// Checks that the arm is valid at every time when it starts as `arm`: each arm the steps
    /// make, at both ends of the radius's cycle (the creep is bounded by its rule). The error
    /// names the step (`step[k].arm.KEY: ...`) or the drift that breaks it.
    pub fn validate(&self, arm: &ArmGeometry) -> Result<(), String> {
        self.drift.validate()?;
        let given = self.drift.creep_mm_per_min.len();
        if given != 0 && given != ACTUATORS {
            return Err(format!(
                "drift.creep_mm_per_min: {given} values for the paper's arm of {ACTUATORS} \
                 actuators; give one per actuator in the arm's order"
            ));
        }
        let a = self.drift.actuator_radius_amplitude_m;
        let states = std::iter::once((None, arm))
            .chain(self.steps().enumerate().map(|(k, s)| (Some(k), &s.arm)));
        for (step, state) in states {
            state
                .validate()
                .map_err(|e| step.map_or(e.clone(), |k| format!("step[{k}].{e}")))?;
            for r in [state.actuator_radius_m - a, state.actuator_radius_m + a] {
                let cycled = ArmGeometry {
                    actuator_radius_m: r,
                    ..*state
                };
                if cycled.validate().is_err() {
                    let whose = step.map_or("the arm".to_string(), |k| format!("step[{k}]'s arm"));
                    return Err(format!(
                        "drift.actuator_radius_amplitude_m: {a} m takes the actuator radius of \
                         {whose} ({} m) to {r} m; it must stay in (0, {}] m",
                        state.actuator_radius_m,
                        ArmGeometry::MAX_RADIUS_M
                    ));
                }
            }
        }
        Ok(())
    }

    /// The step in force at time `t` (its index and itself), if any.
    pub fn step_at(&self, t: f64) -> Option<(usize, &Step)> {
        self.steps().enumerate().filter(|(_, s)| s.at_s <= t).last()
    }

    /// The arm at time `t` (s of plant time) for an arm that starts as `arm`: the last step's
    /// arm at or before `t`, crept and with its radius cycled.
    pub fn arm_at(&self, arm: &ArmGeometry, t: f64) -> ArmGeometry {
        let mut now = self.step_at(t).map_or(*arm, |(_, s)| s.arm);
        let o = ArmGeometry::MAX_OFFSET_M;
        let creep = self.drift.creep_m(t);
        for (offset, c) in now.actuator_offset_m.iter_mut().zip(creep) {
            *offset = (*offset + c).clamp(-o, o);
        }
        now.actuator_radius_m += self.drift.radius_change_m(t);
        now
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn swap_at(at_s: f64, tool_m: f64) -> Step {
        Step {
            at_s,
            arm: ArmGeometry {
                tool_m,
                ..Default::default()
            },
        }
    }

    #[test]
    fn steps_take_effect_at_their_time() {
        let arm = ArmGeometry::default();
        let c = Changes::new(
            &[swap_at(90.0, 0.05), swap_at(300.0, 0.03)],
            Drift::default(),
        )
        .unwrap();
        c.validate(&arm).unwrap();
        assert_eq!(c.arm_at(&arm, 0.0), arm);
        assert_eq!(c.arm_at(&arm, 89.999).tool_m, 0.03);
        assert_eq!(c.arm_at(&arm, 90.0).tool_m, 0.05);
        assert_eq!(c.arm_at(&arm, 299.0).tool_m, 0.05);
        assert_eq!(c.arm_at(&arm, 1e5).tool_m, 0.03);
        assert!(!c.is_empty() && Changes::default().is_empty());
    }

    #[test]
    fn creep_is_its_rate_and_stops_at_the_bound() {
        let arm = ArmGeometry::default();
        let drift = Drift {
            creep_mm_per_min: Rates::new(&[0.0, 0.5, 0.0, 0.0, 0.0, -0.5]).unwrap(),
            ..Drift::default()
        };
        let c = Changes::new(&[], drift).unwrap();
        let at_20_min = c.arm_at(&arm, 1200.0).actuator_offset_m;
        assert!((at_20_min[1] - 0.010).abs() < 1e-12, "{at_20_min:?}");
        assert!((at_20_min[5] + 0.010).abs() < 1e-12, "{at_20_min:?}");
        assert_eq!(at_20_min[0], 0.0);
        // Ten days on: held at the bound, still a valid arm.
        let late = c.arm_at(&arm, 864_000.0);
        assert_eq!(late.actuator_offset_m[1], ArmGeometry::MAX_OFFSET_M);
        late.validate().unwrap();
    }

    #[test]
    fn the_radius_cycles_with_its_amplitude_and_period() {
        let arm = ArmGeometry::default();
        let drift = Drift {
            actuator_radius_amplitude_m: 0.003,
            actuator_radius_period_s: 120.0,
            ..Drift::default()
        };
        let c = Changes::new(&[], drift).unwrap();
        c.validate(&arm).unwrap();
        let r = |t| c.arm_at(&arm, t).actuator_radius_m;
        assert!((r(30.0) - 0.028).abs() < 1e-12);
        assert!((r(90.0) - 0.022).abs() < 1e-12);
        assert!((r(120.0) - 0.025).abs() < 1e-12);
    }

    #[test]
    fn bad_changes_name_the_key() {
        let check = |r: Result<(), String>, want: &str| {
            let e = r.unwrap_err();
            assert!(e.starts_with(want), "{e} (wanted {want:?})");
        };
        let arm = ArmGeometry::default();
        let off = Drift::default();
        check(
            Changes::new(&[swap_at(90.0, 0.05), swap_at(90.0, 0.03)], off).map(drop),
            "step[1].at_s: must be after 90 s",
        );
        check(
            Changes::new(&[swap_at(f64::NAN, 0.05)], off).map(drop),
            "step[0].at_s: must be after 0 s",
        );
        check(
            Changes::new(&[swap_at(1.0, 0.05); MAX_STEPS + 1], off).map(drop),
            "step[16]: at most 16 steps",
        );
        let mut creep = off;
        creep.creep_mm_per_min = Rates::new(&[0.0, 0.0, f64::INFINITY, 0.0, 0.0, 0.0]).unwrap();
        check(
            Changes::new(&[], creep).map(drop),
            "drift.creep_mm_per_min: actuator 3 is inf",
        );
        let cycle = Drift {
            actuator_radius_amplitude_m: 0.01,
            ..off
        };
        check(
            Changes::new(&[], cycle).map(drop),
            "drift.actuator_radius_period_s: must be > 0 when",
        );
        // A cycle that takes a step's arm's radius through zero is refused at that step.
        let cycle = Drift {
            actuator_radius_period_s: 60.0,
            ..cycle
        };
        let thin = Step {
            at_s: 10.0,
            arm: ArmGeometry {
                actuator_radius_m: 0.008,
                ..arm
            },
        };
        let c = Changes::new(&[thin], cycle).unwrap();
        check(
            c.validate(&arm),
            "drift.actuator_radius_amplitude_m: 0.01 m takes the actuator radius of step[0]'s arm",
        );
        let broken = Step {
            at_s: 20.0,
            arm: ArmGeometry {
                tool_m: -1.0,
                ..arm
            },
        };
        check(
            Changes::new(&[thin, broken], off).unwrap().validate(&arm),
            "step[1].arm.tool_m:",
        );
    }
}
