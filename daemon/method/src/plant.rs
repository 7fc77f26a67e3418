//! The simulated plant: PCC kinematics behind a configurable, seeded realism layer.
//!
//! Per actuator, a command passes backlash (play operator) → rate limit → first-order lag, then
//! gets actuation noise; the kinematics use a slowly drifting geometry, and the tracker adds
//! noise to the end-effector position. With every effect off it is the kinematic model exactly.

use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::pcc::{ACTUATORS, ArmGeometry};

/// The `[sim]` section: the sim driver's rate and start, and the plant's realism.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimConfig {
    /// Rate of `tracker` and `motor_state` (Hz).
    pub rate_hz: f64,
    /// Where the actuators rest at start.
    pub initial_actuation: [f64; ACTUATORS],
    pub realism: Realism,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            rate_hz: 200.0,
            initial_actuation: [0.5; ACTUATORS],
            realism: Realism::default(),
        }
    }
}

impl SimConfig {
    /// Checks every field; the error is `sim.KEY: message` (`sim.realism.KEY` for the realism).
    pub fn validate(&self) -> Result<(), String> {
        if !(self.rate_hz.is_finite() && (1.0..=5000.0).contains(&self.rate_hz)) {
            return Err(format!(
                "sim.rate_hz: must be in [1, 5000] Hz, got {:?}",
                self.rate_hz
            ));
        }
        if let Some(i) = self
            .initial_actuation
            .iter()
            .position(|a| !(0.0..=1.0).contains(a))
        {
            return Err(format!(
                "sim.initial_actuation: actuator {} is {:?}; each must be in [0, 1]",
                i + 1,
                self.initial_actuation[i]
            ));
        }
        self.realism.validate()
    }
}

/// The `[sim]` realism settings. Zero turns an effect off.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Realism {
    pub seed: u64,
    /// Time constant of each actuator's first-order lag (s).
    pub lag_s: f64,
    /// Fastest an actuator moves (normalised units per s).
    pub rate_limit_per_s: f64,
    /// Width of the play band (normalised units): a reversal moves nothing until it is crossed.
    pub backlash: f64,
    /// Standard deviation of the actuation noise (normalised units), fresh every step.
    pub actuation_noise: f64,
    /// Standard deviation of the tracker noise per axis (m).
    pub tracker_noise_m: f64,
    /// Amplitude of the slow drift of each actuator's length (m).
    pub drift_m: f64,
    /// Period of that drift (s).
    pub drift_period_s: f64,
}

impl Default for Realism {
    /// The simulation default of `config/softarm.toml`.
    fn default() -> Self {
        Self {
            seed: 1,
            lag_s: 0.02,
            rate_limit_per_s: 2.0,
            backlash: 0.003,
            actuation_noise: 0.001,
            tracker_noise_m: 0.0005,
            drift_m: 0.0001,
            drift_period_s: 600.0,
        }
    }
}

impl Realism {
    /// No effect at all: the plant is the kinematic model.
    pub fn ideal() -> Self {
        Self {
            seed: 0,
            lag_s: 0.0,
            rate_limit_per_s: 0.0,
            backlash: 0.0,
            actuation_noise: 0.0,
            tracker_noise_m: 0.0,
            drift_m: 0.0,
            drift_period_s: 0.0,
        }
    }

    /// Checks every field; the error is `sim.realism.KEY: message`.
    pub fn validate(&self) -> Result<(), String> {
        let fields = [
            ("lag_s", self.lag_s, 10.0, " s"),
            ("rate_limit_per_s", self.rate_limit_per_s, 1000.0, " /s"),
            ("backlash", self.backlash, 1.0, ""),
            ("actuation_noise", self.actuation_noise, 1.0, ""),
            ("tracker_noise_m", self.tracker_noise_m, 1.0, " m"),
            ("drift_m", self.drift_m, 0.1, " m"),
            ("drift_period_s", self.drift_period_s, 1e6, " s"),
        ];
        for (key, v, max, unit) in fields {
            if !(v.is_finite() && (0.0..=max).contains(&v)) {
                return Err(format!(
                    "sim.realism.{key}: must be in [0, {max}]{unit} (0 turns it off), got {v:?}"
                ));
            }
        }
        if self.drift_m > 0.0 && self.drift_period_s == 0.0 {
            return Err("sim.realism.drift_period_s: must be > 0 when drift_m is set".into());
        }
        Ok(())
    }
}

/// What the plant measures after a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measurement {
    /// Normalised actuation the actuators actually reached (motor state).
    pub actuation: [f64; ACTUATORS],
    /// Tracked end-effector position (m), with tracker noise.
    pub position: [f64; 3],
}

/// The simulated arm.
pub struct Plant {
    geometry: ArmGeometry,
    realism: Realism,
    rng: StdRng,
    noise: Option<Normal<f64>>,
    tracker_noise: Option<Normal<f64>>,
    /// Output of the play operator.
    played: [f64; ACTUATORS],
    /// Actuator state after rate limit and lag.
    state: [f64; ACTUATORS],
    time: f64,
}

impl Plant {
    /// A plant at rest at `initial` actuation.
    pub fn new(
        geometry: ArmGeometry,
        realism: Realism,
        initial: [f64; ACTUATORS],
    ) -> Result<Self, String> {
        geometry.validate()?;
        realism.validate()?;
        if let Some(i) = initial.iter().position(|a| !(0.0..=1.0).contains(a)) {
            return Err(format!(
                "sim.initial_actuation: actuator {} is {:?}; each must be in [0, 1]",
                i + 1,
                initial[i]
            ));
        }
        let normal = |key: &str, s: f64| -> Result<Option<Normal<f64>>, String> {
            if s > 0.0 {
                let n = Normal::new(0.0, s).map_err(|e| format!("sim.realism.{key}: {e}"))?;
                Ok(Some(n))
            } else {
                Ok(None)
            }
        };
        Ok(Self {
            geometry,
            realism,
            rng: StdRng::seed_from_u64(realism.seed),
            noise: normal("actuation_noise", realism.actuation_noise)?,
            tracker_noise: normal("tracker_noise_m", realism.tracker_noise_m)?,
            played: initial,
            state: initial,
            time: 0.0,
        })
    }

    pub fn geometry(&self) -> &ArmGeometry {
        &self.geometry
    }

    /// The arm changes under the plant (a tool swapped, an actuator crept); the actuators stay
    /// where they are.
    pub fn set_geometry(&mut self, geometry: ArmGeometry) -> Result<(), String> {
        geometry.validate()?;
        self.geometry = geometry;
        Ok(())
    }

    pub fn time(&self) -> f64 {
        self.time
    }

    /// Where the actuators are (before actuation noise).
    pub fn state(&self) -> [f64; ACTUATORS] {
        self.state
    }

    /// Advances by `dt` seconds with `command` applied, and measures. A command outside [0, 1]
    /// is clamped to it; a non-finite one holds that actuator's input where it was.
    pub fn step(&mut self, command: &[f64; ACTUATORS], dt: f64) -> Measurement {
        let r = self.realism;
        self.time += dt;
        for i in 0..ACTUATORS {
            let c = if command[i].is_finite() {
                command[i].clamp(0.0, 1.0)
            } else {
                self.played[i]
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
        let mut actuation = self.state;
        if let Some(n) = self.noise {
            for a in &mut actuation {
                *a = (*a + n.sample(&mut self.rng)).clamp(0.0, 1.0);
            }
        }
        let mut lengths = self.geometry.lengths(&actuation);
        if r.drift_m > 0.0 {
            let w = 2.0 * std::f64::consts::PI * self.time / r.drift_period_s;
            for (i, l) in lengths.iter_mut().enumerate() {
                // Each actuator drifts with its own phase, as ageing material would.
                *l += r.drift_m * (w + 1.1 * i as f64).sin();
            }
        }
        let p = self.geometry.pose_of_lengths(&lengths).position;
        let mut position = [p.x, p.y, p.z];
        if let Some(n) = self.tracker_noise {
            for x in &mut position {
                *x += n.sample(&mut self.rng);
            }
        }
        Measurement {
            actuation,
            position,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_command_that_is_not_a_number_holds_the_actuator() {
        let mut p =
            Plant::new(ArmGeometry::default(), Realism::default(), [0.5; ACTUATORS]).unwrap();
        for _ in 0..50 {
            p.step(&[0.6; ACTUATORS], 0.005);
        }
        let before = p.state();
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
        let arm = ArmGeometry::default();
        let mut plant = Plant::new(arm, Realism::ideal(), [0.5; 6]).unwrap();
        for k in 0..200 {
            let c: [f64; 6] = std::array::from_fn(|i| {
                (0.5 + 0.4 * ((k + 7 * i) as f64 * 0.1).sin()).clamp(0.0, 1.0)
            });
            let m = plant.step(&c, 0.002);
            assert_eq!(m.actuation, c);
            assert_eq!(m.position, arm.position(&c));
        }
    }

    #[test]
    fn lag_and_rate_limit_slow_a_step() {
        let realism = Realism {
            lag_s: 0.1,
            rate_limit_per_s: 1.0,
            ..Realism::ideal()
        };
        let mut plant = Plant::new(ArmGeometry::default(), realism, [0.0; 6]).unwrap();
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

    #[test]
    fn backlash_swallows_small_reversals() {
        let realism = Realism {
            backlash: 0.1,
            ..Realism::ideal()
        };
        let mut plant = Plant::new(ArmGeometry::default(), realism, [0.5; 6]).unwrap();
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
            let mut p = Plant::new(
                ArmGeometry::default(),
                Realism { seed, ..realism },
                [0.5; 6],
            )
            .unwrap();
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
    fn drift_moves_the_arm_slowly() {
        let realism = Realism {
            drift_m: 0.001,
            drift_period_s: 10.0,
            ..Realism::ideal()
        };
        let arm = ArmGeometry::default();
        let mut plant = Plant::new(arm, realism, [0.5; 6]).unwrap();
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
            Plant::new(
                arm,
                Realism {
                    drift_period_s: 0.0,
                    ..realism
                },
                [0.5; 6]
            )
            .is_err()
        );
    }

    #[test]
    fn realism_errors_name_the_full_key_and_the_range() {
        let check = |r: Realism, want: &str| {
            let e = r.validate().unwrap_err();
            assert!(e.starts_with(want), "{e} (wanted {want:?})");
            let e = Plant::new(ArmGeometry::default(), r, [0.5; 6])
                .err()
                .unwrap();
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
        let e = Plant::new(
            ArmGeometry::default(),
            ideal,
            [0.5, 0.5, f64::NAN, 0.5, 0.5, 0.5],
        );
        assert!(
            e.err()
                .unwrap()
                .starts_with("sim.initial_actuation: actuator 3 is NaN")
        );
        Realism::default().validate().unwrap();
    }
}
