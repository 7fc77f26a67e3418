//! `[sim]`: the sim driver's rate and start, and the plant's realism, as plain data with its
//! validation. The plant that runs them is `softarm_sim::plant`.

use serde::{Deserialize, Serialize};

use crate::changes::Drift;
use crate::mujoco::MujocoConfig;
use crate::per_actuator::PerActuator;

/// The `[sim]` section: the sim driver's rate and start, and the plant's realism.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SimConfig {
    /// Rate of `tracker` and `motor_state` (Hz).
    pub rate_hz: f64,
    /// Where the actuators rest at start: one number for every actuator, or one per actuator
    /// in the arm's order.
    pub initial_actuation: PerActuator,
    pub realism: Realism,
    /// The plant as a MuJoCo model (`softarm` built with its `mujoco` feature); absent, the
    /// sim's own PCC kinematics.
    pub mujoco: Option<MujocoConfig>,
    /// How the arm drifts while the sim runs: a scenario's `[drift]` (scenario files only, not
    /// a key of `[sim]`). None by default.
    #[serde(skip)]
    pub drift: Drift,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            rate_hz: 200.0,
            initial_actuation: PerActuator::All(0.5),
            realism: Realism::default(),
            mujoco: None,
            drift: Drift::default(),
        }
    }
}

impl SimConfig {
    /// Checks every field for an arm of `actuators`; the error is `sim.KEY: message`
    /// (`sim.realism.KEY` for the realism).
    pub fn validate(&self, actuators: usize) -> Result<(), String> {
        if !(self.rate_hz.is_finite() && (1.0..=5000.0).contains(&self.rate_hz)) {
            return Err(format!(
                "sim.rate_hz: must be in [1, 5000] Hz, got {:?}",
                self.rate_hz
            ));
        }
        self.initial_actuation
            .check("sim.initial_actuation", actuators, 0.0..=1.0)?;
        self.realism.validate()?;
        match &self.mujoco {
            Some(m) => m.validate(actuators),
            None => Ok(()),
        }
    }
}

/// The `[sim]` realism settings. Zero turns an effect off.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Realism {
    /// Seeds the sim's noise and drift.
    pub seed: u64,
    /// Time constant of each actuator's first-order lag (s).
    pub lag_s: f64,
    /// Fastest an actuator moves (normalised units per s).
    pub rate_limit_per_s: f64,
    /// Width of the play band (normalised units): a reversal moves nothing until it is crossed.
    pub backlash: f64,
    /// Standard deviation of the disturbance at each actuator (normalised units): what moves
    /// the actuators beside their command (pressure ripple, friction, a brush of air).
    pub actuation_noise: f64,
    /// Its correlation time τ (s): white noise through a first-order response of time
    /// constant τ (an Ornstein-Uhlenbeck process), so the arm moves smoothly rather than jumping
    /// every step; the autocorrelation after a lag Δ is exp(−Δ/τ). 0: fresh every step.
    pub actuation_noise_correlation_s: f64,
    /// Standard deviation of the tracker noise per axis (m).
    pub tracker_noise_m: f64,
    /// Amplitude of the slow drift of each actuator's length (m).
    pub drift_m: f64,
    /// Period of that drift (s).
    pub drift_period_s: f64,
    /// A departure from constant curvature, c in [0, 1]: each module's curvature falls
    /// linearly from (1 + c) κ̄ at its base to (1 − c) κ̄ at its tip, same bend θ; the
    /// model's family is PCC, the plant then is not. 0: exactly PCC.
    pub curvature_taper: f64,
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
            actuation_noise_correlation_s: 0.1,
            tracker_noise_m: 0.0005,
            drift_m: 0.0001,
            drift_period_s: 600.0,
            curvature_taper: 0.0,
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
            actuation_noise_correlation_s: 0.0,
            tracker_noise_m: 0.0,
            drift_m: 0.0,
            drift_period_s: 0.0,
            curvature_taper: 0.0,
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
            ("curvature_taper", self.curvature_taper, 1.0, ""),
        ];
        for (key, v, max, unit) in fields {
            if !(v.is_finite() && (0.0..=max).contains(&v)) {
                return Err(format!(
                    "sim.realism.{key}: must be in [0, {max}]{unit} (0 turns it off), got {v:?}"
                ));
            }
        }
        let tau = self.actuation_noise_correlation_s;
        if !(tau.is_finite() && (0.0..=100.0).contains(&tau)) {
            return Err(format!(
                "sim.realism.actuation_noise_correlation_s: must be in [0, 100] s (0: fresh \
                 every step), got {tau:?}"
            ));
        }
        if self.drift_m > 0.0 && self.drift_period_s == 0.0 {
            return Err("sim.realism.drift_period_s: must be > 0 when drift_m is set".into());
        }
        Ok(())
    }
}
