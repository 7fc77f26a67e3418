//! How the simulated arm changes while it runs, besides a scenario's steps (the arm becoming
//! another at a given time, which `softarm-config`'s scenario makes and the sim's plant
//! steps through): a drift (actuators creeping, the tendons' radius cycling) as a function of
//! the plant's own time. Plain data with its validation and its value at a time, which
//! allocates nothing, so the plant evaluates it every step.

use serde::{Deserialize, Serialize};

use softarm_arm::MAX_RADIUS_M;
use softarm_space::MAX_ACTUATORS;

/// Most steps a scenario may hold (fixed, so the plant's arm is `Copy` and allocation-free).
pub const MAX_STEPS: usize = 16;
/// Fastest creep (mm per minute), either way.
pub const MAX_CREEP_MM_PER_MIN: f64 = 10.0;
/// Latest step and longest cycle (s): about eleven days.
pub const MAX_TIME_S: f64 = 1e6;

/// A scenario's `[drift]`: slow changes that go on all the time, on whatever arm the steps
/// have made. Zero turns each off.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Drift {
    /// How fast each actuator lengthens (mm per minute; negative: shortens), from time 0, added
    /// to the arm's `actuator_offset_m`: one per actuator of the arm, or none. The creep stops
    /// at ±0.05 m (100 minutes at 0.5 mm/min): the arm stays valid however long the sim runs.
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
        let r = MAX_RADIUS_M;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn creep_is_its_rate() {
        let drift = Drift {
            creep_mm_per_min: Rates::new(&[0.0, 0.5, 0.0, 0.0, 0.0, -0.5]).unwrap(),
            ..Drift::default()
        };
        drift.check_for(6, Some(0.025)).unwrap();
        let at_20_min = drift.creep_m(1200.0);
        assert!((at_20_min[1] - 0.010).abs() < 1e-12, "{at_20_min:?}");
        assert!((at_20_min[5] + 0.010).abs() < 1e-12, "{at_20_min:?}");
        assert_eq!(at_20_min[0], 0.0);
        assert!(!drift.is_off() && Drift::default().is_off());
    }

    #[test]
    fn the_radius_cycles_with_its_amplitude_and_period() {
        let drift = Drift {
            actuator_radius_amplitude_m: 0.003,
            actuator_radius_period_s: 120.0,
            ..Drift::default()
        };
        drift.check_for(6, Some(0.025)).unwrap();
        let r = |t| 0.025 + drift.radius_change_m(t);
        assert!((r(30.0) - 0.028).abs() < 1e-12);
        assert!((r(90.0) - 0.022).abs() < 1e-12);
        assert!((r(120.0) - 0.025).abs() < 1e-12);
    }

    #[test]
    fn bad_drifts_name_the_key() {
        let check = |r: Result<(), String>, want: &str| {
            let e = r.unwrap_err();
            assert!(e.starts_with(want), "{e} (wanted {want:?})");
        };
        let off = Drift::default();
        let mut creep = off;
        creep.creep_mm_per_min = Rates::new(&[0.0, 0.0, f64::INFINITY, 0.0, 0.0, 0.0]).unwrap();
        check(
            creep.validate(),
            "drift.creep_mm_per_min: actuator 3 is inf",
        );
        creep.creep_mm_per_min = Rates::new(&[0.1; 4]).unwrap();
        check(
            creep.check_for(6, None),
            "drift.creep_mm_per_min: 4 values for an arm of 6 actuators",
        );
        let cycle = Drift {
            actuator_radius_amplitude_m: 0.01,
            ..off
        };
        check(
            cycle.validate(),
            "drift.actuator_radius_period_s: must be > 0 when",
        );
        // A cycle that takes the thinnest tendon's radius through zero is refused.
        let cycle = Drift {
            actuator_radius_period_s: 60.0,
            ..cycle
        };
        check(
            cycle.check_for(6, Some(0.008)),
            "drift.actuator_radius_amplitude_m: 0.01 m takes the smallest tendon radius",
        );
        check(
            cycle.check_for(6, None),
            "drift.actuator_radius_amplitude_m: 0.01 m, but this arm has no tendon",
        );
        assert!(Rates::new(&[0.0; MAX_ACTUATORS + 1]).is_err());
    }
}
