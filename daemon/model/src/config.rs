//! The one configuration file every softarm process reads (DESIGN §7): TOML, unknown keys
//! refused, every value checked at start; errors name the key and its line.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use softarm_method::pcc::ArmGeometry;
use softarm_method::plant::Realism;

use softarm_method::activation::ActivationConfig;
use softarm_method::cacla::{LearnerConfig, PretrainConfig};
use softarm_method::rbf::NetworkConfig;
use softarm_method::skill::DemoRecipe;

/// The simulation default, embedded so `softarm demo` needs no file.
pub const DEFAULT: &str = include_str!("../../../config/softarm.toml");

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    pub robot: Robot,
    pub controller: Controller,
    pub waypoints: WaypointLimits,
    #[serde(default)]
    pub activation: ActivationConfig,
    pub model: ModelConfig,
    #[serde(default)]
    pub demonstrations: DemoRecipe,
    #[serde(default)]
    pub forward_model: NetworkConfig,
    #[serde(default)]
    pub learner: LearnerConfig,
    #[serde(default)]
    pub pretrain: PretrainConfig,
    pub state: StateConfig,
    #[serde(default)]
    pub arm: ArmGeometry,
    #[serde(default)]
    pub sim: SimConfig,
    /// Where relative paths start: the config file's folder.
    #[serde(skip)]
    pub base_dir: PathBuf,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Robot {
    pub id: String,
    /// Service namespace; `softarm/<id>` when absent.
    #[serde(default)]
    pub namespace: Option<String>,
    /// The drivers `softarm up` starts: "sim", or the hardware drivers.
    pub drivers: Vec<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Controller {
    pub rate_hz: f64,
    /// Tracker data older than this puts the controller in HOLD (ms).
    pub tracker_timeout_ms: f64,
    /// Fastest a setpoint may change (normalised units per s).
    pub slew_per_s: f64,
    /// Actuator limits in normalised units; setpoints are clamped to them.
    pub actuator_min: [f64; 6],
    pub actuator_max: [f64; 6],
    /// Time between executions to slew to the next start (s).
    pub rest_s: f64,
    /// Variance floor of the Eq. 11 marginals.
    pub variance_floor: f64,
    /// How long to wait for the learner's first estimates of a new set (s).
    pub estimate_timeout_s: f64,
    /// SCHED_FIFO priority of the tick thread; 0 leaves the scheduler alone.
    #[serde(default)]
    pub realtime_priority: i32,
    /// CPU to pin the tick thread to; absent leaves it free.
    #[serde(default)]
    pub cpu: Option<usize>,
    #[serde(default)]
    pub mlockall: bool,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WaypointLimits {
    /// Way-points must lie in this box (m, tracker frame).
    pub workspace_min_m: [f64; 3],
    pub workspace_max_m: [f64; 3],
    pub min_duration_s: f64,
    pub max_duration_s: f64,
    pub max_executions: u32,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelConfig {
    /// The model bundle's folder.
    pub dir: PathBuf,
    pub basis_functions: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StateConfig {
    /// Learner checkpoints live here.
    pub dir: PathBuf,
}

/// The `[sim]` section.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimConfig {
    /// Rate of `tracker` and `motor_state` (Hz).
    pub rate_hz: f64,
    /// Where the actuators rest at start.
    pub initial_actuation: [f64; 6],
    pub realism: Realism,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            rate_hz: 200.0,
            initial_actuation: [0.5; 6],
            realism: Realism::default(),
        }
    }
}

impl SimConfig {
    pub fn validate(&self) -> Result<(), String> {
        if !(self.rate_hz.is_finite() && (1.0..=5000.0).contains(&self.rate_hz)) {
            return Err(format!(
                "sim.rate_hz must be 1 to 5000, got {}",
                self.rate_hz
            ));
        }
        if self
            .initial_actuation
            .iter()
            .any(|a| !(0.0..=1.0).contains(a))
        {
            return Err("sim.initial_actuation must be in [0, 1]".into());
        }
        self.realism.validate()
    }
}

/// A config error: the message names the key; `line` is where that key stands, if found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{origin}{}: {message}", line.map(|l| format!(":{l}")).unwrap_or_default())]
pub struct ConfigError {
    pub origin: String,
    pub line: Option<usize>,
    pub message: String,
}

impl Config {
    /// Reads and checks a config file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError {
            origin: path.display().to_string(),
            line: None,
            message: format!("cannot read the config: {e}"),
        })?;
        let base = path
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_else(|| PathBuf::from("."));
        Self::parse(&text, &path.display().to_string(), base)
    }

    /// The embedded simulation default, with relative paths under `base_dir`.
    pub fn default_sim(base_dir: PathBuf) -> Self {
        Self::parse(DEFAULT, "embedded default config", base_dir)
            .expect("the embedded config is valid")
    }

    pub fn parse(text: &str, origin: &str, base_dir: PathBuf) -> Result<Self, ConfigError> {
        let mut c: Config = toml::from_str(text).map_err(|e| ConfigError {
            origin: origin.into(),
            line: e.span().map(|s| text[..s.start].lines().count().max(1)),
            message: e.message().to_string(),
        })?;
        c.base_dir = base_dir;
        c.validate().map_err(|(key, message)| ConfigError {
            origin: origin.into(),
            line: line_of(text, &key),
            message: format!("{key}: {message}"),
        })?;
        Ok(c)
    }

    /// The service namespace.
    pub fn namespace(&self) -> String {
        self.robot
            .namespace
            .clone()
            .unwrap_or_else(|| format!("softarm/{}", self.robot.id))
    }

    pub fn model_dir(&self) -> PathBuf {
        self.base_dir.join(&self.model.dir)
    }

    pub fn state_dir(&self) -> PathBuf {
        self.base_dir.join(&self.state.dir)
    }

    fn validate(&self) -> Result<(), (String, String)> {
        let key = |k: &str, m: String| Err((k.to_string(), m));
        softarm_ipc::Namespace::new(&self.namespace())
            .map_err(|m| ("robot.namespace".to_string(), m.to_string()))?;
        for d in &self.robot.drivers {
            if !["sim"].contains(&d.as_str()) {
                return key(
                    "robot.drivers",
                    format!("unknown driver {d:?}; this build has \"sim\""),
                );
            }
        }
        let c = &self.controller;
        if !(c.rate_hz.is_finite() && (10.0..=1000.0).contains(&c.rate_hz)) {
            return key(
                "controller.rate_hz",
                format!("must be 10 to 1000 Hz, got {}", c.rate_hz),
            );
        }
        if !(c.tracker_timeout_ms.is_finite() && c.tracker_timeout_ms > 0.0) {
            return key("controller.tracker_timeout_ms", "must be > 0".into());
        }
        if !(c.slew_per_s.is_finite() && c.slew_per_s > 0.0) {
            return key("controller.slew_per_s", "must be > 0".into());
        }
        for i in 0..6 {
            let (lo, hi) = (c.actuator_min[i], c.actuator_max[i]);
            if !(0.0..=1.0).contains(&lo) || !(0.0..=1.0).contains(&hi) || lo >= hi {
                return key(
                    "controller.actuator_min",
                    format!(
                        "actuator {}: limits [{lo}, {hi}] must satisfy 0 <= min < max <= 1",
                        i + 1
                    ),
                );
            }
        }
        if !(c.rest_s.is_finite() && c.rest_s >= 0.0) {
            return key("controller.rest_s", "must be >= 0".into());
        }
        if !(c.variance_floor.is_finite() && c.variance_floor > 0.0) {
            return key("controller.variance_floor", "must be > 0".into());
        }
        if !(c.estimate_timeout_s.is_finite() && c.estimate_timeout_s > 0.0) {
            return key("controller.estimate_timeout_s", "must be > 0".into());
        }
        if !(0..=99).contains(&c.realtime_priority) {
            return key(
                "controller.realtime_priority",
                "must be 0 (off) to 99".into(),
            );
        }
        let w = &self.waypoints;
        for d in 0..3 {
            if !(w.workspace_min_m[d].is_finite()
                && w.workspace_max_m[d].is_finite()
                && w.workspace_min_m[d] < w.workspace_max_m[d])
            {
                return key(
                    "waypoints.workspace_min_m",
                    format!("axis {d}: the box is empty"),
                );
            }
        }
        if !(w.min_duration_s > 0.0
            && w.min_duration_s <= w.max_duration_s
            && w.max_duration_s.is_finite())
        {
            return key(
                "waypoints.min_duration_s",
                "need 0 < min_duration_s <= max_duration_s".into(),
            );
        }
        if w.max_executions == 0 {
            return key("waypoints.max_executions", "must be >= 1".into());
        }
        softarm_method::activation::Schedule::new(&[0.5], &[0], 1, 1.0, self.activation)
            .map_err(|e| ("activation".to_string(), e.to_string()))?;
        if !(2..=40).contains(&self.model.basis_functions) {
            return key("model.basis_functions", "must be 2 to 40".into());
        }
        self.demonstrations
            .validate()
            .map_err(|m| ("demonstrations".to_string(), m))?;
        if self.forward_model.centres == 0 {
            return key("forward_model.centres", "must be >= 1".into());
        }
        self.learner
            .validate()
            .map_err(|m| ("learner".to_string(), m))?;
        if !(self.pretrain.budget_s.is_finite() && self.pretrain.budget_s >= 0.0) {
            return key("pretrain.budget_s", "must be >= 0".into());
        }
        self.arm.validate().map_err(|m| ("arm".to_string(), m))?;
        self.sim.validate().map_err(|m| ("sim".to_string(), m))?;
        Ok(())
    }
}

/// The line (1-based) where a dotted key stands: its section header, then the key within it.
fn line_of(text: &str, dotted: &str) -> Option<usize> {
    let (section, leaf) = match dotted.rsplit_once('.') {
        Some((s, l)) => (s, l),
        None => (dotted, ""),
    };
    let mut in_section = false;
    let mut header = None;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.starts_with('[') {
            let name = line.trim_matches(|c| c == '[' || c == ']').trim();
            in_section = name == section || name == dotted;
            if in_section && header.is_none() {
                header = Some(i + 1);
            }
            continue;
        }
        if in_section && !leaf.is_empty() {
            let k = line.split('=').next().unwrap_or("").trim();
            if k == leaf {
                return Some(i + 1);
            }
        }
    }
    header
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_default_is_valid() {
        let c = Config::default_sim(PathBuf::from("/tmp/x"));
        assert_eq!(c.namespace(), "softarm/sim");
        assert_eq!(c.model_dir(), PathBuf::from("/tmp/x/model"));
        // The file spells out the structs' defaults (the learner's online rates excepted).
        assert_eq!(c.sim, SimConfig::default());
        assert_eq!(c.arm, ArmGeometry::default());
        assert_eq!(c.activation, ActivationConfig::default());
        assert_eq!(c.forward_model, NetworkConfig::default());
    }

    #[test]
    fn errors_name_the_key_and_line() {
        let bad = DEFAULT.replace("rate_hz = 500.0", "rate_hz = 5000.0");
        let e = Config::parse(&bad, "c.toml", ".".into()).unwrap_err();
        let line = DEFAULT
            .lines()
            .position(|l| l.starts_with("rate_hz = 500.0"))
            .unwrap()
            + 1;
        assert_eq!(e.line, Some(line), "{e}");
        assert!(
            e.to_string()
                .starts_with(&format!("c.toml:{line}: controller.rate_hz")),
            "{e}"
        );

        let unknown = DEFAULT.replace("[controller]\n", "[controller]\nrate = 3\n");
        let e = Config::parse(&unknown, "c.toml", ".".into()).unwrap_err();
        assert!(e.message.contains("unknown field `rate`"), "{e}");
        assert!(e.line.is_some(), "{e}");

        let e = Config::parse("[robot\n", "c.toml", ".".into()).unwrap_err();
        assert_eq!(e.line, Some(1));

        let bad = DEFAULT.replace("gamma = 0.5", "gamma = 2.0");
        let e = Config::parse(&bad, "c.toml", ".".into()).unwrap_err();
        assert!(e.to_string().contains("learner.gamma"), "{e}");
    }
}
