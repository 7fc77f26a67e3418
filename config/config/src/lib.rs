//! The one configuration file every softarm process reads: TOML, unknown keys
//! refused, every value checked at start; errors name the key and its line.
//!
//! - [`Config`] (this file): every section, the embedded defaults, `--set`-style overrides.
//! - [`hardware`]: the real arm's drivers' sections, motor ticks ↔ actuation, tracker ↔ base
//!   frame.
//! - [`waypoints`]: way-point files and the checks a set must pass.
//! - [`scenario`]: scenario files, the sim's arm when it is not the one the model knows.
//! - [`load`]: the config a command finds (`--config`, `--namespace`) and joining its stack.
//! - The sections the math reads, plain data with their validation, from `softarm-sections`
//!   (re-exported here): [`arm`], [`sim`], [`changes`], [`learner`], [`forward_model`],
//!   [`kinematics`], [`activation`], [`demonstrations`].
//!
//! Every process links this crate to read its section; none of it trains or loads a model, and
//! it links none of the math (`softarm-method`, `softarm-kinematics`, `softarm-learning`, the
//! sim's plant): the drivers read their config without them.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use softarm_space::{Position, Workspace};

use crate::activation::ActivationConfig;
use crate::arm::ArmConfig;
use crate::demonstrations::DemoRecipe;
use crate::forward_model::NetworkConfig;
use crate::kinematics::PolynomialConfig;
use crate::learner::{LearnerConfig, PretrainConfig};
use crate::per_actuator::PerActuator;
use crate::sim::SimConfig;

/// Exit code of a process whose config is refused (EX_CONFIG of sysexits.h): starting it again
/// cannot help, so the systemd units list it in `RestartPreventExitStatus=` and the supervisor
/// of `softarm up` gives it up.
pub const EXIT_CONFIG: u8 = 78;

pub mod arms;
pub mod files;
pub mod hardware;
pub mod host;
pub mod load;
pub mod plant;
pub mod reference;
pub mod ros2;
pub mod scenario;
pub mod view;
pub mod waypoints;

pub use softarm_sections::{
    activation, arm, changes, demonstrations, forward_model, kinematics, learner, mujoco,
    per_actuator, sim,
};

use softarm_ipc::drivers::{DRIVERS, Driver};
use softarm_sections::bounds::{self, Lower, Lower::Closed, Lower::Open};

use crate::hardware::{TendonConfig, TrackerConfig};
use crate::host::HostConfig;
use crate::ros2::Ros2Config;
use crate::view::ViewConfig;

/// The config of an installed stack (`softarm install` writes it): what a command uses when
/// it is given none and [`CONFIG_ENV`] is not set.
pub const INSTALLED: &str = "/etc/softarm/softarm.toml";
/// The environment variable that names the config for commands given no `--config`.
pub const CONFIG_ENV: &str = "SOFTARM_CONFIG";

/// The config file a command uses: `explicit` (`--config`), else `env` ([`CONFIG_ENV`]'s value),
/// else `installed` if it exists; `None`: the embedded simulation config.
pub fn locate(
    explicit: Option<&Path>,
    env: Option<std::ffi::OsString>,
    installed: &Path,
) -> Option<PathBuf> {
    explicit
        .map(Path::to_path_buf)
        .or_else(|| env.filter(|v| !v.is_empty()).map(PathBuf::from))
        .or_else(|| installed.exists().then(|| installed.to_path_buf()))
}

/// Where the embedded config keeps its state (the e-stop latch, checkpoints): the user's own
/// state folder (`$XDG_STATE_HOME/softarm`, else `~/.local/state/softarm`), never the folder a
/// command happens to run in.
pub fn user_state_dir() -> PathBuf {
    let home = |v: &str| std::env::var_os(v).filter(|p| Path::new(p).is_absolute());
    match (home("XDG_STATE_HOME"), home("HOME")) {
        (Some(state), _) => PathBuf::from(state).join("softarm"),
        (None, Some(h)) => PathBuf::from(h).join(".local/state/softarm"),
        // No home at all (a bare service account): a folder of this user's own name.
        (None, None) => {
            let uid = std::fs::metadata("/proc/self")
                .map(|m| std::os::unix::fs::MetadataExt::uid(&m))
                .unwrap_or(0);
            std::env::temp_dir().join(format!("softarm-{uid}/state"))
        }
    }
}

/// The simulation default, embedded so `softarm demo` needs no file.
pub const DEFAULT: &str = include_str!("../../../config/softarm.toml");

/// Longest a way-point set may last (s): the ceiling of `waypoints.max_duration_s`.
pub const MAX_DURATION_S: f64 = 3600.0;
/// Most ticks in one execution (`waypoints.max_duration_s` × `controller.rate_hz`): the planner
/// keeps a table of marginals per tick for every primitive and conditioning point.
pub const MAX_TICKS: f64 = 120_000.0;
/// CPUs a Linux CPU set can name (`CPU_SETSIZE`): the ceiling of `controller.cpu`.
pub const MAX_CPUS: usize = 1024;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
    pub kinematics: PolynomialConfig,
    #[serde(default)]
    pub learner: LearnerConfig,
    #[serde(default)]
    pub pretrain: PretrainConfig,
    pub state: StateConfig,
    #[serde(default)]
    pub arm: ArmConfig,
    #[serde(default)]
    pub sim: SimConfig,
    /// The tendon motor driver; required when `robot.drivers` has "tendon".
    #[serde(default)]
    pub tendon: Option<TendonConfig>,
    /// The tracker driver; required when `robot.drivers` has "tracker".
    #[serde(default)]
    pub tracker: Option<TrackerConfig>,
    /// `softarm view`, the live view; off unless `view.enabled`.
    #[serde(default)]
    pub view: ViewConfig,
    /// `softarm ros2`, the bridge to ROS 2; off unless `ros2.enabled`.
    #[serde(default)]
    pub ros2: Ros2Config,
    /// An installed stack's user, operators' group and iceoryx2 folder.
    #[serde(default)]
    pub host: HostConfig,
    /// Where relative paths start: the config file's folder.
    #[serde(skip)]
    pub base_dir: PathBuf,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Robot {
    /// The robot's name: the namespace is `softarm/<id>` unless `namespace` is given.
    pub id: String,
    /// Service namespace; `softarm/<id>` when absent.
    #[serde(default)]
    pub namespace: Option<String>,
    /// The drivers `softarm up` starts: "sim", or the hardware drivers.
    pub drivers: Vec<String>,
}

impl Robot {
    /// The service namespace: `namespace`, else `softarm/<id>`.
    pub fn namespace(&self) -> String {
        self.namespace
            .clone()
            .unwrap_or_else(|| format!("softarm/{}", self.id))
    }

    /// Checks the namespace (or the id it is made of) and the drivers: each known and listed
    /// once, "sim" alone or the hardware drivers, each of these with its section
    /// (`has_section`: [`Config::has_section`]).
    fn validate(&self, has_section: impl Fn(&str) -> bool) -> Result<(), Invalid> {
        softarm_ipc::Namespace::new(&self.namespace()).map_err(|m| {
            let key = if self.namespace.is_some() {
                "robot.namespace"
            } else {
                "robot.id"
            };
            (key.to_string(), m.to_string())
        })?;
        for (i, d) in self.drivers.iter().enumerate() {
            if Driver::named(d).is_none() {
                return invalid(
                    "robot.drivers",
                    format!("unknown driver {d:?}; this build has {:?}", Driver::names()),
                );
            }
            if self.drivers[..i].contains(d) {
                return invalid("robot.drivers", format!("driver {d:?} is listed twice"));
            }
        }
        let listed = || {
            DRIVERS
                .iter()
                .filter(|d| self.drivers.iter().any(|x| x == d.name))
        };
        if let Some(whole) = listed().find(|d| !d.hardware)
            && listed().any(|d| d.hardware)
        {
            return invalid(
                "robot.drivers",
                format!(
                    "\"{}\" is the whole arm: list it alone, or the hardware drivers",
                    whole.name
                ),
            );
        }
        for driver in listed().filter(|d| d.hardware).map(|d| d.name) {
            if !has_section(driver) {
                return invalid(
                    "robot.drivers",
                    format!("lists \"{driver}\" but the config has no [{driver}] section"),
                );
            }
        }
        Ok(())
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Controller {
    pub rate_hz: f64,
    /// Tracker or motor data older than this puts the controller in HOLD (ms): it times both
    /// `tracker` and `motor_state`.
    pub tracker_timeout_ms: f64,
    /// Fastest a setpoint may change (normalised units per s).
    pub slew_per_s: f64,
    /// Actuator limits in normalised units, one number for all or one per actuator in the
    /// arm's order; setpoints are clamped to them.
    pub actuator_min: PerActuator,
    /// The upper limits, as `actuator_min`.
    pub actuator_max: PerActuator,
    /// Time between executions to slew to the next start (s).
    pub rest_s: f64,
    /// Variance floor of the Eq. 11 marginals.
    pub variance_floor: f64,
    /// How long to wait for the learner's first estimates of a new set (s).
    pub estimate_timeout_s: f64,
    /// Eq. 11 is evaluated ahead of the clock by the actuators' lag as the controller measures
    /// it, at most this far (s; 0: not at all).
    #[serde(default = "default_max_lead_s")]
    pub max_lead_s: f64,
    /// SCHED_FIFO priority of the tick thread; 0 leaves the scheduler alone.
    #[serde(default)]
    pub realtime_priority: i32,
    /// CPU to pin the tick thread to; absent leaves it free.
    #[serde(default)]
    pub cpu: Option<usize>,
    /// Locks the memory of the controller and of the drivers (`mlockall`), so a page the kernel
    /// reclaimed never stalls a tick or a driver's cycle on a disk read.
    #[serde(default = "locked")]
    pub mlockall: bool,
}

fn locked() -> bool {
    true
}

impl Controller {
    /// Checks `rate_hz`, `tracker_timeout_ms` and `slew_per_s`: what needs nothing of the
    /// arm ([`Controller::validate`] the rest).
    fn validate_rates(&self) -> Result<(), Invalid> {
        within(
            "controller.rate_hz",
            self.rate_hz,
            Closed(10.0),
            1000.0,
            " Hz",
        )?;
        within(
            "controller.tracker_timeout_ms",
            self.tracker_timeout_ms,
            Open(0.0),
            10_000.0,
            " ms",
        )?;
        within(
            "controller.slew_per_s",
            self.slew_per_s,
            Open(0.0),
            1000.0,
            " /s",
        )
    }

    /// Checks the rest ([`Controller::validate_rates`] the rates) for an arm of `n` actuators:
    /// the limits, one number or one per actuator, each minimum below its maximum; the times,
    /// the variance floor, the real-time priority and the CPU.
    fn validate(&self, n: usize) -> Result<(), Invalid> {
        (self.actuator_min)
            .check("controller.actuator_min", n, 0.0..=1.0)
            .map_err(|e| keyed("controller.actuator_min", e))?;
        (self.actuator_max)
            .check("controller.actuator_max", n, 0.0..=1.0)
            .map_err(|e| keyed("controller.actuator_max", e))?;
        for i in 0..n {
            let (lo, hi) = (self.actuator_min.get(i), self.actuator_max.get(i));
            if lo >= hi {
                return invalid(
                    "controller.actuator_max",
                    format!("actuator {}: {hi} must exceed its actuator_min {lo}", i + 1),
                );
            }
        }
        within("controller.rest_s", self.rest_s, Closed(0.0), 60.0, " s")?;
        within(
            "controller.variance_floor",
            self.variance_floor,
            Open(0.0),
            1.0,
            "",
        )?;
        within(
            "controller.estimate_timeout_s",
            self.estimate_timeout_s,
            Open(0.0),
            60.0,
            " s",
        )?;
        within(
            "controller.max_lead_s",
            self.max_lead_s,
            Closed(0.0),
            1.0,
            " s",
        )?;
        if !(0..=99).contains(&self.realtime_priority) {
            return invalid(
                "controller.realtime_priority",
                format!("must be 0 (off) to 99, got {}", self.realtime_priority),
            );
        }
        if let Some(cpu) = self.cpu
            && cpu >= MAX_CPUS
        {
            return invalid(
                "controller.cpu",
                format!(
                    "must be 0 to {}, the CPUs a CPU set can name, got {cpu}",
                    MAX_CPUS - 1
                ),
            );
        }
        Ok(())
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct WaypointLimits {
    /// Way-points must lie in this box (m, tracker frame).
    pub workspace_min_m: Position,
    /// The box's upper corner (m), as `workspace_min_m`.
    pub workspace_max_m: Position,
    /// Farthest a way-point may be from the base (the frame's origin, where the arm is
    /// mounted): the box's corners lie beyond any arm's reach (m).
    #[serde(default = "default_reach_m")]
    pub reach_m: f64,
    /// Shortest a way-point set may last (s).
    pub min_duration_s: f64,
    /// Longest a way-point set may last (s).
    pub max_duration_s: f64,
    /// Most executions one submitted set may ask for.
    pub max_executions: u32,
}

/// Room for a slow arm's lag (a tendon's give, a slow bus) without the lead reaching into
/// what a way-point set's timing means.
fn default_max_lead_s() -> f64 {
    0.1
}

/// The default arm's longest backbone (two modules at full length, connector and tool: 0.56 m)
/// with room for a longer tool.
fn default_reach_m() -> f64 {
    0.6
}

impl WaypointLimits {
    /// The box way-points must lie in; `Config` has checked it with [`Workspace::new`].
    pub fn workspace(&self) -> Workspace {
        Workspace {
            min_m: self.workspace_min_m,
            max_m: self.workspace_max_m,
        }
    }

    /// Checks the box, the reach, the durations and the executions. The longest set at
    /// `controller_rate_hz` (checked) must fit the planner's tables: at most [`MAX_TICKS`].
    fn validate(&self, controller_rate_hz: f64) -> Result<(), Invalid> {
        workspace("waypoints", self.workspace_min_m, self.workspace_max_m)?;
        within("waypoints.reach_m", self.reach_m, Open(0.0), 10.0, " m")?;
        within(
            "waypoints.min_duration_s",
            self.min_duration_s,
            Open(0.0),
            MAX_DURATION_S,
            " s",
        )?;
        if !(self.max_duration_s >= self.min_duration_s && self.max_duration_s <= MAX_DURATION_S) {
            return invalid(
                "waypoints.max_duration_s",
                format!(
                    "must be in [min_duration_s, {MAX_DURATION_S}] = [{}, {MAX_DURATION_S}] s, \
                     got {:?}",
                    self.min_duration_s, self.max_duration_s
                ),
            );
        }
        let ticks = self.max_duration_s * controller_rate_hz;
        if ticks > MAX_TICKS {
            return invalid(
                "waypoints.max_duration_s",
                format!(
                    "{} s at controller.rate_hz = {} Hz is {ticks:.0} ticks; the planner keeps \
                     tables per tick, so at most {MAX_TICKS} ({:.0} s at this rate)",
                    self.max_duration_s,
                    controller_rate_hz,
                    MAX_TICKS / controller_rate_hz
                ),
            );
        }
        count(
            "waypoints.max_executions",
            self.max_executions as usize,
            1,
            1_000_000,
        )
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ModelConfig {
    /// The model bundle's folder.
    pub dir: PathBuf,
    pub basis_functions: usize,
}

impl ModelConfig {
    fn validate(&self) -> Result<(), Invalid> {
        if self.dir.as_os_str().is_empty() {
            return invalid("model.dir", "must name a folder".into());
        }
        count("model.basis_functions", self.basis_functions, 2, 40)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct StateConfig {
    /// Learner checkpoints live here.
    pub dir: PathBuf,
}

impl StateConfig {
    fn validate(&self) -> Result<(), Invalid> {
        if self.dir.as_os_str().is_empty() {
            return invalid("state.dir", "must name a folder".into());
        }
        Ok(())
    }
}

/// A config key (`section.key`, sections nested with dots) and the value it is set to.
pub type Override<'a> = (&'a str, toml::Value);

/// `text` (a config) with each `(dotted key, value)` set, e.g. `("sim.realism.seed", 3)` or
/// `("tendon.extra_bus[0].port", ..)` (the first `[[tendon.extra_bus]]`); the
/// key's section must exist. For the tools that write or run a config of their own (`softarm
/// demo`, `softarm install`, the tests). Comments and layout survive; a replaced value loses
/// the comment after it.
pub fn with_overrides(text: &str, overrides: &[Override]) -> Result<String, String> {
    let mut doc: toml_edit::DocumentMut = text
        .parse()
        .map_err(|e: toml_edit::TomlError| e.message().to_string())?;
    for (key, value) in overrides {
        let (path, leaf) = key
            .rsplit_once('.')
            .ok_or_else(|| format!("{key:?}: need section.key"))?;
        let mut table: &mut dyn toml_edit::TableLike = doc.as_table_mut();
        for section in path.split('.') {
            // `name[k]`: the k-th table of an array of tables (`[[name]]`).
            let indexed = (section.strip_suffix(']'))
                .and_then(|s| s.split_once('['))
                .and_then(|(name, k)| Some((name, k.parse::<usize>().ok()?)));
            let next = match indexed {
                Some((name, k)) => table
                    .get_mut(name)
                    .and_then(toml_edit::Item::as_array_of_tables_mut)
                    .and_then(|a| a.get_mut(k))
                    .map(|t| t as &mut dyn toml_edit::TableLike),
                None => table
                    .get_mut(section)
                    .and_then(toml_edit::Item::as_table_like_mut),
            };
            table = next.ok_or_else(|| format!("{key:?}: no section [{path}] in the config"))?;
        }
        let value: toml_edit::Value = value
            .to_string()
            .parse()
            .map_err(|e: toml_edit::TomlError| format!("{key:?}: {}", e.message()))?;
        table.insert(leaf, toml_edit::Item::Value(value));
    }
    Ok(doc.to_string())
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
    /// Whether the config has the section of hardware driver `driver` ([`Driver::hardware`]:
    /// `[tendon]`, `[tracker]`), which that driver needs.
    pub fn has_section(&self, driver: &str) -> bool {
        match driver {
            "tendon" => self.tendon.is_some(),
            "tracker" => self.tracker.is_some(),
            _ => false,
        }
    }

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
            line: e.span().map(|s| line_at(text, s.start)),
            message: e.message().to_string(),
        })?;
        c.base_dir = base_dir;
        c.validate().map_err(|(key, message)| ConfigError {
            origin: origin.into(),
            line: key_line(text, &key),
            message: format!("{key}: {message}"),
        })?;
        // Logged here, so every process that reads the file says it, and no caller can forget.
        for w in deprecations(text, origin) {
            tracing::warn!("{w}");
        }
        Ok(c)
    }

    /// The service namespace.
    pub fn namespace(&self) -> String {
        self.robot.namespace()
    }

    /// Who the arm this config describes is to the stack's processes, its bundles and its
    /// services (`softarm_arm::Layout::identity`).
    pub fn arm_identity(&self) -> String {
        self.layout().identity()
    }

    /// The arm this config describes, checked (a loaded config's arm is valid).
    pub fn layout(&self) -> softarm_arm::Layout {
        self.arm
            .layout()
            .expect("a loaded config's arm passed its check")
    }

    /// This stack on this host: its namespace under its iceoryx2 root folder, for the arm
    /// this config describes (a process of another arm's stack cannot join it).
    pub fn bus(&self) -> Result<softarm_ipc::Namespace, softarm_ipc::Error> {
        let ns = softarm_ipc::Namespace::new(&self.namespace())?.with_arm(&self.arm_identity())?;
        match &self.host.ipc_root {
            Some(root) => ns.under(root),
            None => Ok(ns),
        }
    }

    pub fn model_dir(&self) -> PathBuf {
        self.base_dir.join(&self.model.dir)
    }

    pub fn state_dir(&self) -> PathBuf {
        self.base_dir.join(&self.state.dir)
    }

    /// The e-stop latch of this stack: in the state folder, so it outlives every process.
    pub fn estop_latch(&self) -> softarm_runtime::EstopLatch {
        softarm_runtime::EstopLatch::new(self.state_dir().join("estop"))
    }

    /// Checks every value of every section, each by its own `validate`, in this order (a
    /// config with several errors is refused for the first). The error is the exact dotted
    /// key (array elements as `[i]`) and a message that does not repeat it.
    fn validate(&self) -> Result<(), Invalid> {
        let c = &self.controller;
        self.robot.validate(|driver| self.has_section(driver))?;
        // The controller's rates need nothing of the arm; its limits, one per actuator, do.
        c.validate_rates()?;
        self.arm.validate().map_err(|e| keyed("arm", e))?;
        let arm = self.layout();
        let n = arm.actuators().len();
        c.validate(n)?;
        self.waypoints.validate(c.rate_hz)?;
        (self.activation.validate()).map_err(|e| keyed("activation", e))?;
        self.model.validate()?;
        (self.demonstrations.validate_for(&arm, c.rate_hz))
            .map_err(|e| keyed("demonstrations", e))?;
        (self.forward_model.validate()).map_err(|e| keyed("forward_model", e))?;
        (self.kinematics.validate()).map_err(|e| keyed("kinematics", e))?;
        self.learner.validate().map_err(|e| keyed("learner", e))?;
        self.pretrain.validate().map_err(|e| keyed("pretrain", e))?;
        self.state.validate()?;
        self.sim.validate(n).map_err(|e| keyed("sim", e))?;
        if let Some(t) = &self.tendon {
            let (lo, hi) = (c.actuator_min.values(n), c.actuator_max.values(n));
            t.validate(&arm, &lo, &hi, c.rate_hz)?;
        }
        if let Some(t) = &self.tracker {
            t.validate()?;
        }
        self.view.validate()?;
        self.ros2.validate()?;
        self.host.validate_for(self.bus())
    }
}

/// Former spellings that still load as their new names: (dotted key, its old value or `None`
/// for any value, the message).
const DEPRECATED: [(&str, Option<&str>, &str); 2] = [
    (
        "learner.correction",
        None,
        "[learner.correction] is deprecated: rename it [learner.gauss_newton]",
    ),
    (
        "learner.algorithm",
        Some("softarm"),
        "learner.algorithm = \"softarm\" is deprecated: use \"gauss-newton\"",
    ),
];

/// One line per deprecated spelling in the TOML `text`, each naming the new one, as
/// `origin:line: message`. [`Config::parse`] logs them.
pub fn deprecations(text: &str, origin: &str) -> Vec<String> {
    let Ok(doc) = text.parse::<toml::Table>() else {
        return Vec::new();
    };
    DEPRECATED
        .iter()
        .filter(|(key, old, _)| {
            let mut parts = key.split('.');
            let first = parts.next().and_then(|k| doc.get(k));
            let value = parts.fold(first, |v, k| v.and_then(|v| v.get(k)));
            value.is_some_and(|v| old.is_none_or(|old| v.as_str() == Some(old)))
        })
        .map(|(key, _, message)| match key_line(text, key) {
            Some(line) => format!("{origin}:{line}: {message}"),
            None => format!("{origin}: {message}"),
        })
        .collect()
}

/// A failed check: the dotted key and a message that does not repeat it.
type Invalid = (String, String);

fn invalid(key: &str, message: String) -> Result<(), Invalid> {
    Err((key.to_string(), message))
}

/// Splits a section's `KEY: message` (KEY a dotted path in `section`) into key and message; a
/// message without such a key stays whole, under the section.
fn keyed(section: &str, e: String) -> Invalid {
    match e.split_once(": ") {
        Some((key, message))
            if !key.contains(' ')
                && (key == section || key.starts_with(&format!("{section}."))) =>
        {
            (key.to_string(), message.to_string())
        }
        _ => (section.to_string(), e),
    }
}

/// A finite `v` within the range, or an error that names the range ([`bounds::within`]).
fn within(key: &str, v: f64, lower: Lower, upper: f64, unit: &str) -> Result<(), Invalid> {
    bounds::within(key, v, lower, upper, unit).map_err(|e| keyed(key, e))
}

/// `v` in `lo..=hi`, or an error that names the range ([`bounds::count`]).
fn count(key: &str, v: usize, lo: usize, hi: usize) -> Result<(), Invalid> {
    bounds::count(key, v, lo, hi).map_err(|e| keyed(key, e))
}

/// A box checked by [`Workspace::new`]; the key is the bound that is not finite, else the upper.
fn workspace(section: &str, min_m: Position, max_m: Position) -> Result<(), Invalid> {
    Workspace::new(min_m, max_m).map(|_| ()).map_err(|m| {
        let bound = if min_m.iter().all(|v| v.is_finite()) {
            "workspace_max_m"
        } else {
            "workspace_min_m"
        };
        (format!("{section}.{bound}"), m)
    })
}

/// The line (1-based) of byte `offset` of `text`.
pub(crate) fn line_at(text: &str, offset: usize) -> usize {
    let end = offset.min(text.len());
    text.as_bytes()[..end]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// The line where the dotted key `path` stands in the TOML `text` (`sim.realism.lag_s`,
/// `demonstrations.classes[1].start`, `point[2].t_s`), from the parser's spans: dotted keys,
/// inline tables, arrays and arrays of tables included. A key that is absent (left to its
/// default) gives the line of its nearest present parent; `None` when no part of it is there.
pub(crate) fn key_line(text: &str, path: &str) -> Option<usize> {
    let doc = toml_edit::Document::parse(text).ok()?;
    let mut node = Node::Item(doc.as_item());
    let mut at = None;
    'walk: for part in path.split('.') {
        let (name, indices) = part.split_once('[').unwrap_or((part, ""));
        let Some((span, next)) = node.field(name) else {
            break;
        };
        at = span.map(|s| s.start).or(at);
        node = next;
        for index in indices.split('[') {
            let Ok(i) = index.trim_end_matches(']').parse::<usize>() else {
                continue;
            };
            let Some((span, next)) = node.element(i) else {
                break 'walk;
            };
            at = span.map(|s| s.start).or(at);
            node = next;
        }
    }
    at.map(|offset| line_at(text, offset))
}

/// A place in a parsed TOML document.
enum Node<'a> {
    Item(&'a toml_edit::Item),
    Value(&'a toml_edit::Value),
    Table(&'a toml_edit::Table),
}

type Span = Option<std::ops::Range<usize>>;

impl<'a> Node<'a> {
    /// Key `name` of a table, inline table or dotted key: where the key stands, and its value.
    fn field(&self, name: &str) -> Option<(Span, Node<'a>)> {
        let table: &'a dyn toml_edit::TableLike = match *self {
            Node::Item(i) => i.as_table_like()?,
            Node::Value(v) => v.as_inline_table()?,
            Node::Table(t) => t,
        };
        let (key, item) = table.get_key_value(name)?;
        Some((key.span().or_else(|| item.span()), Node::Item(item)))
    }

    /// Element `i` of an array or an array of tables.
    fn element(&self, i: usize) -> Option<(Span, Node<'a>)> {
        match *self {
            Node::Item(toml_edit::Item::ArrayOfTables(a)) => {
                let t = a.get(i)?;
                Some((t.span(), Node::Table(t)))
            }
            Node::Item(toml_edit::Item::Value(v)) | Node::Value(v) => {
                let e = v.as_array()?.get(i)?;
                Some((e.span(), Node::Value(e)))
            }
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overrides_set_nested_keys_or_say_what_is_missing() {
        let text = with_overrides(DEFAULT, &[("sim.realism.seed", 7.into())]).unwrap();
        let c = Config::parse(&text, "o.toml", ".".into()).unwrap();
        assert_eq!(c.sim.realism.seed, 7);
        let e = with_overrides(DEFAULT, &[("nowhere.key", 1.into())]).unwrap_err();
        assert!(e.contains("no section [nowhere]"), "{e}");
        assert!(with_overrides(DEFAULT, &[("flat", 1.into())]).is_err());
        assert!(with_overrides("[robot", &[]).is_err());
    }

    #[test]
    fn the_embedded_default_is_valid() {
        let c = Config::default_sim(PathBuf::from("/tmp/x"));
        assert_eq!(c.namespace(), "softarm/sim");
        assert_eq!(c.model_dir(), PathBuf::from("/tmp/x/model"));
        // The file spells out the structs' defaults (the learner's online rates excepted).
        assert_eq!(c.sim, SimConfig::default());
        assert_eq!(c.arm.shorthand(), ArmConfig::default().shorthand());
        assert_eq!(c.activation, ActivationConfig::default());
        assert_eq!(c.forward_model, NetworkConfig::default());
    }

    const HARDWARE: &str = include_str!("../../../config/hardware.toml");

    /// `text` with `new` spelt `old`, parsed, and the deprecation lines it gives.
    fn formerly(text: &str, new: &str, old: &str) -> (Config, Vec<String>) {
        assert!(text.contains(new), "{new}");
        let old = text.replace(new, old);
        let c = Config::parse(&old, "c.toml", ".".into()).unwrap();
        (c, deprecations(&old, "c.toml"))
    }

    #[test]
    fn the_former_learner_correction_section_loads_and_names_gauss_newton() {
        let new = Config::parse(DEFAULT, "c.toml", ".".into()).unwrap();
        assert!(deprecations(DEFAULT, "c.toml").is_empty());
        assert!(deprecations(HARDWARE, "h.toml").is_empty());
        let (old, warnings) = formerly(DEFAULT, "[learner.gauss_newton]", "[learner.correction]");
        assert_eq!(old, new);
        let line = DEFAULT
            .lines()
            .position(|l| l.starts_with("[learner.gauss_newton]"))
            .unwrap()
            + 1;
        assert_eq!(
            warnings,
            [format!(
                "c.toml:{line}: [learner.correction] is deprecated: rename it [learner.gauss_newton]"
            )]
        );
        // A value out of range there still names its key (and the section's line).
        let bad = DEFAULT
            .replace("[learner.gauss_newton]", "[learner.correction]")
            .replace("gain = 1.0 ", "gain = 8.0 ");
        let e = Config::parse(&bad, "c.toml", ".".into()).unwrap_err();
        assert!(e.message.starts_with("learner.gauss_newton.gain: "), "{e}");
    }

    #[test]
    fn the_former_algorithm_softarm_loads_and_names_gauss_newton() {
        let new = Config::parse(DEFAULT, "c.toml", ".".into()).unwrap();
        assert_eq!(
            new.learner.algorithm,
            crate::learner::Algorithm::GaussNewton
        );
        let (old, warnings) = formerly(
            DEFAULT,
            "algorithm = \"gauss-newton\"",
            "algorithm = \"softarm\"",
        );
        assert_eq!(old, new);
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(
            warnings[0]
                .ends_with(": learner.algorithm = \"softarm\" is deprecated: use \"gauss-newton\""),
            "{warnings:?}"
        );
        // "paper" is no former name.
        let (paper, warnings) = formerly(
            DEFAULT,
            "algorithm = \"gauss-newton\"",
            "algorithm = \"paper\"",
        );
        assert_ne!(paper, new);
        assert!(warnings.is_empty(), "{warnings:?}");
    }

    #[test]
    fn the_hardware_config_is_valid_and_differs_only_in_the_drivers() {
        let c = Config::parse(HARDWARE, "hardware.toml", ".".into()).unwrap();
        let d = Config::default_sim(".".into());
        assert_eq!(c.robot.drivers, ["tendon", "tracker"]);
        assert!(c.tendon.is_some() && c.tracker.is_some());
        // The same arm and method: a model trained on either config fits the other.
        assert_eq!(
            (&c.arm, &c.learner, &c.controller),
            (&d.arm, &d.learner, &d.controller)
        );
    }

    #[test]
    fn every_driver_of_the_registry_is_checked() {
        // Each hardware driver's section is one the config knows.
        let hardware = Config::parse(HARDWARE, "hardware.toml", ".".into()).unwrap();
        let sim = Config::default_sim(".".into());
        for d in DRIVERS.iter().filter(|d| d.hardware) {
            assert!(
                hardware.has_section(d.name) && !sim.has_section(d.name),
                "{}",
                d.name
            );
        }
        let unknown = DEFAULT.replace(r#"drivers = ["sim"]"#, r#"drivers = ["arm"]"#);
        assert_ne!(unknown, DEFAULT);
        let e = Config::parse(&unknown, "c.toml", ".".into()).unwrap_err();
        assert_eq!(
            e.message,
            r#"robot.drivers: unknown driver "arm"; this build has ["sim", "tendon", "tracker"]"#
        );
        let mixed = HARDWARE.replace(
            r#"drivers = ["tendon", "tracker"]"#,
            r#"drivers = ["tracker", "sim"]"#,
        );
        let e = Config::parse(&mixed, "h.toml", ".".into()).unwrap_err();
        assert_eq!(
            e.message,
            r#"robot.drivers: "sim" is the whole arm: list it alone, or the hardware drivers"#
        );
    }

    #[test]
    fn hardware_drivers_need_their_sections_and_consistent_limits() {
        let no_tendon = HARDWARE.replace("[tendon]", "[tendon_unused]");
        assert!(Config::parse(&no_tendon, "h.toml", ".".into()).is_err());
        let (start, end) = (
            HARDWARE.find("[tendon]").unwrap(),
            HARDWARE.find("[tracker]").unwrap(),
        );
        let without = format!("{}{}", &HARDWARE[..start], &HARDWARE[end..]);
        let e = Config::parse(&without, "h.toml", ".".into()).unwrap_err();
        assert!(e.message.contains("no [tendon] section"), "{e}");
        let mixed = HARDWARE.replace(
            r#"drivers = ["tendon", "tracker"]"#,
            r#"drivers = ["sim", "tracker"]"#,
        );
        assert!(Config::parse(&mixed, "h.toml", ".".into()).is_err());
        // A motor turned the wrong way would be driven past its limit: refused, at its line.
        let wrong = HARDWARE.replace(
            "direction = [1, 1, 1, -1, -1, -1]",
            "direction = [1, 1, 1, -1, 1, -1]",
        );
        let e = Config::parse(&wrong, "h.toml", ".".into()).unwrap_err();
        let line = HARDWARE
            .lines()
            .position(|l| l.starts_with("zero_ticks"))
            .unwrap()
            + 1;
        assert_eq!(e.line, Some(line), "{e}");
        assert!(
            e.message
                .starts_with("tendon.zero_ticks[4]: motor 5 (actuator 5)"),
            "{e}"
        );
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
        // The key's own line, not the one before it (a span at a line's start).
        let line = unknown.lines().position(|l| l == "rate = 3").unwrap() + 1;
        assert_eq!(e.line, Some(line), "{e}");

        let e = Config::parse("[robot\n", "c.toml", ".".into()).unwrap_err();
        assert_eq!(e.line, Some(1));

        let bad = DEFAULT.replace("gamma = 0.5", "gamma = 2.0");
        let e = Config::parse(&bad, "c.toml", ".".into()).unwrap_err();
        assert!(e.to_string().contains("learner.gamma"), "{e}");
    }

    /// DEFAULT with the first line starting `from` after the `[section]` header replaced by
    /// `to`, and that line's number.
    fn edit(section: &str, from: &str, to: &str) -> (String, usize) {
        let lines: Vec<&str> = DEFAULT.lines().collect();
        let header = format!("[{section}]");
        let start = lines.iter().position(|l| l.starts_with(&header)).unwrap();
        let at = start
            + lines[start..]
                .iter()
                .position(|l| l.starts_with(from))
                .unwrap_or_else(|| panic!("no {from:?} in [{section}]"));
        let mut out: Vec<&str> = lines.clone();
        out[at] = to;
        (out.join("\n") + "\n", at + 1)
    }

    fn refused(text: &str) -> ConfigError {
        Config::parse(text, "c.toml", ".".into()).unwrap_err()
    }

    /// The message starts with the full key and names it only there.
    fn names_key_once(e: &ConfigError, key: &str) {
        assert!(
            e.message.starts_with(&format!("{key}: ")),
            "{e} (wanted {key})"
        );
        assert_eq!(e.message.matches(key).count(), 1, "{e}");
        assert!(e.to_string().starts_with("c.toml:"), "{e}");
    }

    #[test]
    fn nested_keys_point_at_their_own_line_and_are_named_once() {
        let cases = [
            ("sim.realism", "lag_s", "lag_s = -1.0", "sim.realism.lag_s"),
            (
                "sim.realism",
                "drift_period_s",
                "drift_period_s = 0.0",
                "sim.realism.drift_period_s",
            ),
            ("sim", "rate_hz", "rate_hz = 0.5", "sim.rate_hz"),
            (
                "sim",
                "initial_actuation",
                "initial_actuation = [0.5, 0.5, 0.5, 2.0, 0.5, 0.5]",
                "sim.initial_actuation",
            ),
            (
                "learner",
                "critic_span",
                "critic_span = 1",
                "learner.critic_span",
            ),
            (
                "learner",
                "actor_span",
                "actor_span = 10",
                "learner.actor_span",
            ),
            ("learner", "gamma", "gamma = 2.0", "learner.gamma"),
            (
                "learner",
                "workspace_min_m",
                "workspace_min_m = [nan, 0.0, 0.0]",
                "learner.workspace_min_m",
            ),
            (
                "arm",
                "module_rotation_deg",
                "module_rotation_deg = [0.0, nan]",
                "arm.module_rotation_deg",
            ),
            (
                "arm",
                "actuator_max_m",
                "actuator_max_m = 0.1",
                "arm.actuator_max_m",
            ),
            (
                "activation",
                "window_s",
                "window_s = -0.1",
                "activation.window_s",
            ),
            (
                "activation",
                "crossfade_s",
                "crossfade_s = 0.01",
                "activation.crossfade_s",
            ),
            (
                "demonstrations",
                "spread",
                "spread = 0.9",
                "demonstrations.spread",
            ),
            (
                "waypoints",
                "workspace_max_m",
                "workspace_max_m = [0.45, -0.5, 0.05]",
                "waypoints.workspace_max_m",
            ),
            (
                "controller",
                "actuator_max",
                "actuator_max = [1.0, 1.0, 0.0, 1.0, 1.0, 1.0]",
                "controller.actuator_max",
            ),
        ];
        for (section, from, to, key) in cases {
            let (text, line) = edit(section, from, to);
            let e = refused(&text);
            assert_eq!(e.line, Some(line), "{to}: {e}");
            names_key_once(&e, key);
        }
    }

    #[test]
    fn inline_table_elements_point_at_their_own_line() {
        let at = DEFAULT.find("intermediate_points = 2\n").unwrap() + 24;
        let text = format!(
            "{}classes = [\n  {{ start = [0.2, 0.8, 0.8, 0.5, 0.5, 0.5], end = [0.8, 0.3, 0.3, 0.5, \
             0.5, 0.5] }},\n  {{ start = [0.8, 0.2, 0.7, 0.7, 1.2, 0.6], end = [0.6, 0.8, 0.2, \
             0.5, 0.8, 0.2] }},\n]\n{}",
            &DEFAULT[..at],
            &DEFAULT[at..]
        );
        let line = text[..at].lines().count() + 3;
        let e = refused(&text);
        assert_eq!(e.line, Some(line), "{e}");
        names_key_once(&e, "demonstrations.classes[1].start");
        assert!(e.message.contains("actuator 5 is 1.2"), "{e}");
    }

    #[test]
    fn dotted_keys_point_at_their_own_line() {
        let cut = DEFAULT.find("[sim.realism]").unwrap();
        let text = format!(
            "{}realism.seed = 1\nrealism.lag_s = -0.5\nrealism.backlash = 0.0\n",
            &DEFAULT[..cut]
        );
        let line = text
            .lines()
            .position(|l| l.starts_with("realism.lag_s"))
            .unwrap()
            + 1;
        let e = refused(&text);
        assert_eq!(e.line, Some(line), "{e}");
        names_key_once(&e, "sim.realism.lag_s");
    }

    #[test]
    fn absent_keys_point_at_their_nearest_parent() {
        let text = "[sim]\nrate_hz = 1.0\n\n[sim.realism]\nseed = 1\n";
        assert_eq!(key_line(text, "sim.rate_hz"), Some(2));
        assert_eq!(key_line(text, "sim.realism.lag_s"), Some(4));
        assert_eq!(key_line(text, "sim.initial_actuation"), Some(1));
        assert_eq!(key_line(text, "learner.gamma"), None);
        let points = "duration_s = 2\n[[point]]\nt_s = 1\n\n[[point]]\nt_s = 2\n";
        assert_eq!(key_line(points, "point[1].t_s"), Some(6));
        assert_eq!(key_line(points, "point[1].position_m"), Some(5));
        assert_eq!(key_line(points, "point[7].t_s"), Some(2));
        let array = "a = [\n  1,\n  [2, 3],\n]\n";
        assert_eq!(key_line(array, "a[1]"), Some(3));
        assert_eq!(key_line(array, "a[1][1]"), Some(3));
        assert_eq!(key_line(array, "a[9]"), Some(1));
        assert_eq!(key_line("a = [", "a"), None);
        assert_eq!(line_at("a\nb\n", 2), 2);
    }

    /// Checks no other test reaches: the namespace, a driver twice, the real-time priority,
    /// and the longest set at the controller's rate.
    #[test]
    fn the_robot_the_priority_and_the_longest_set_are_checked() {
        let (text, line) = edit("robot", "id", "id = \"a b\"");
        let e = refused(&text);
        assert_eq!(e.line, Some(line), "{e}");
        names_key_once(&e, "robot.id");
        assert!(e.message.contains("\"softarm/a b\" is not valid"), "{e}");
        let text = with_overrides(DEFAULT, &[("robot.namespace", "/x".into())]).unwrap();
        names_key_once(&refused(&text), "robot.namespace");

        let (text, _) = edit("robot", "drivers", r#"drivers = ["sim", "sim"]"#);
        let e = refused(&text);
        names_key_once(&e, "robot.drivers");
        assert!(
            e.message.ends_with(r#"driver "sim" is listed twice"#),
            "{e}"
        );

        let (text, line) = edit("controller", "realtime_priority", "realtime_priority = 100");
        let e = refused(&text);
        assert_eq!(e.line, Some(line), "{e}");
        names_key_once(&e, "controller.realtime_priority");
        assert!(e.message.ends_with("must be 0 (off) to 99, got 100"), "{e}");

        let (text, line) = edit("waypoints", "max_duration_s", "max_duration_s = 3600.0");
        let e = refused(&text);
        assert_eq!(e.line, Some(line), "{e}");
        names_key_once(&e, "waypoints.max_duration_s");
        assert!(
            e.message.ends_with(
                "3600 s at controller.rate_hz = 500 Hz is 1800000 ticks; the planner keeps \
                 tables per tick, so at most 120000 (240 s at this rate)"
            ),
            "{e}"
        );
    }

    #[test]
    fn durations_counts_and_sizes_are_bounded() {
        let cases = [
            (
                "controller",
                "estimate_timeout_s",
                "estimate_timeout_s = 1e300",
                "(0, 60] s",
            ),
            ("controller", "rest_s", "rest_s = inf", "[0, 60] s"),
            ("controller", "max_lead_s", "max_lead_s = 2", "[0, 1] s"),
            (
                "controller",
                "tracker_timeout_ms",
                "tracker_timeout_ms = 1e20",
                "(0, 10000] ms",
            ),
            (
                "controller",
                "slew_per_s",
                "slew_per_s = inf",
                "(0, 1000] /s",
            ),
            (
                "controller",
                "variance_floor",
                "variance_floor = nan",
                "(0, 1]",
            ),
            ("controller", "# cpu", "cpu = 4096", "0 to 1023"),
            (
                "waypoints",
                "max_duration_s",
                "max_duration_s = 1e300",
                "3600] s",
            ),
            (
                "waypoints",
                "min_duration_s",
                "min_duration_s = 0.0",
                "(0, 3600] s",
            ),
            (
                "waypoints",
                "max_executions",
                "max_executions = 0",
                "1 to 1000000",
            ),
            (
                "model",
                "basis_functions",
                "basis_functions = 1000000",
                "2 to 40",
            ),
            ("model", "dir", "dir = \"\"", "folder"),
            (
                "demonstrations",
                "duration_s",
                "duration_s = 1e9",
                "(0, 600] s",
            ),
            (
                "demonstrations",
                "demos_per_class",
                "demos_per_class = 1000000000",
                "2 to 1000",
            ),
            (
                "demonstrations",
                "sample_rate_hz",
                "sample_rate_hz = 1e300",
                "(0, 1000] Hz",
            ),
            (
                "demonstrations",
                "sample_rate_hz",
                "sample_rate_hz = 1000.0",
                "controller.rate_hz",
            ),
            (
                "demonstrations",
                "intermediate_points",
                "intermediate_points = 100000000",
                "0 to 100",
            ),
            (
                "forward_model",
                "centres",
                "centres = 100000000",
                "1 to 2000",
            ),
            (
                "forward_model",
                "width_factor",
                "width_factor = inf",
                "(0, 100]",
            ),
            ("forward_model", "ridge", "ridge = nan", "[0, 1]"),
            ("forward_model", "widths", "widths = 0", "1 to 4"),
            (
                "learner",
                "critic_spacing_m",
                "critic_spacing_m = 1e-9",
                "[0.001, 1] m",
            ),
            ("learner", "sigma_max", "sigma_max = inf", "(0, 1]"),
            ("pretrain", "budget_s", "budget_s = 1e12", "[0, 86400] s"),
            (
                "pretrain",
                "targets_per_epoch",
                "targets_per_epoch = 100000000",
                "0 to 1000",
            ),
            (
                "pretrain",
                "visits_per_epoch",
                "visits_per_epoch = 0",
                "1 to 100000",
            ),
            ("pretrain", "threshold_m", "threshold_m = 0.0", "(0, 1] m"),
            ("state", "dir", "dir = \"\"", "folder"),
            (
                "arm",
                "actuator_max_m",
                "actuator_max_m = 1e300",
                "(0, 10] m",
            ),
            ("sim.realism", "lag_s", "lag_s = 1e300", "[0, 10] s"),
        ];
        for (section, from, to, range) in cases {
            let (text, line) = edit(section, from, to);
            let e = refused(&text);
            assert_eq!(e.line, Some(line), "{to}: {e}");
            let key = e.message.split(": ").next().unwrap().to_string();
            let leaf = to.split(' ').next().unwrap();
            assert!(key.ends_with(&format!(".{leaf}")), "{to}: {e}");
            names_key_once(&e, &key);
            assert!(e.message.contains(range), "{to}: {e} (wanted {range:?})");
        }
    }
}
