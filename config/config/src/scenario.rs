//! Scenario files: the simulated arm is not the one the model was trained on. A scenario
//! overrides keys of `[arm]` and `[sim.realism]` for the sim process only; the controller, the
//! learner and the model keep the nominal arm of the config. It may also change the arm while
//! the sim runs: steps at given times of the sim's clock (each `[[step]]` with its own
//! `[step.arm]` keys, on the arm before it) and a `[drift]` (actuators creeping, the actuator
//! radius cycling), run inside the plant ([`crate::changes`]).
//!
//! ```toml
//! # A longer tool from the start, swapped back 90 s in, two tendons creeping all along
//! # (comments say what the scenario models).
//! [arm]
//! tool_m = 0.05
//!
//! [[step]]
//! at_s = 90.0
//! [step.arm]
//! tool_m = 0.03
//!
//! [drift]
//! creep_mm_per_min = [0.0, 0.5, 0.0, 0.0, 0.0, 0.5]
//! ```
//!
//! Unknown sections and keys are refused, every value is checked as the config checks it (the
//! arm at every time: each step's, with a radius cycle that keeps every tendon off the
//! backbone; the creep is bounded by its rule), and errors name the key and its line in the scenario file.

use std::path::Path;

use crate::arm::{ArmConfig, MAX_OFFSET_M};
use crate::changes::Drift;
use crate::mujoco::MujocoConfig;
use crate::sim::SimConfig;

/// What a scenario may change of a MuJoCo plant: its gravity and a load at the tip.
const MUJOCO_KEYS: [&str; 2] = ["gravity_m_s2", "load"];
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use softarm_arm::Kind;

use crate::{ConfigError, key_line, line_at};

/// The scenarios shipped in `config/scenarios/`, embedded so `--scenario NAME` works anywhere.
pub const SHIPPED: [(&str, &str); 16] = [
    (
        "nominal",
        include_str!("../../../config/scenarios/nominal.toml"),
    ),
    (
        "tool-change",
        include_str!("../../../config/scenarios/tool-change.toml"),
    ),
    (
        "creep",
        include_str!("../../../config/scenarios/creep.toml"),
    ),
    (
        "twist",
        include_str!("../../../config/scenarios/twist.toml"),
    ),
    (
        "stiffer",
        include_str!("../../../config/scenarios/stiffer.toml"),
    ),
    (
        "tool-swap",
        include_str!("../../../config/scenarios/tool-swap.toml"),
    ),
    (
        "creeping",
        include_str!("../../../config/scenarios/creeping.toml"),
    ),
    (
        "stiffness-cycle",
        include_str!("../../../config/scenarios/stiffness-cycle.toml"),
    ),
    (
        "combined",
        include_str!("../../../config/scenarios/combined.toml"),
    ),
    (
        "not-pcc",
        include_str!("../../../config/scenarios/not-pcc.toml"),
    ),
    (
        "sequence",
        include_str!("../../../config/scenarios/sequence.toml"),
    ),
    (
        "tendon-steps",
        include_str!("../../../config/scenarios/tendon-steps.toml"),
    ),
    (
        "tdcr-creep",
        include_str!("../../../config/scenarios/tdcr-creep.toml"),
    ),
    (
        "tdcr-sequence",
        include_str!("../../../config/scenarios/tdcr-sequence.toml"),
    ),
    (
        "tdcr-creeping",
        include_str!("../../../config/scenarios/tdcr-creeping.toml"),
    ),
    (
        "hybrid-weak-chamber",
        include_str!("../../../config/scenarios/hybrid-weak-chamber.toml"),
    ),
];

/// A scenario on an arm of any layout ([`Scenario::apply_to`]).
#[derive(Debug, Clone, PartialEq)]
pub struct OnArm {
    /// The sim's arm from the start.
    pub arm: ArmConfig,
    pub sim: SimConfig,
    /// Each step's time (s of the sim's clock) and the arm from then on.
    pub steps: Vec<(f64, ArmConfig)>,
}

/// The `[arm]` keys every arm has, which a scenario without `for_arm` may set on any arm.
const EVERY_ARMS: [&str; 2] = ["tool_m", "connector_m"];

/// What a scenario file may hold.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    /// The arm the scenario changes: a shipped arm's name or an arm file; the paper's arm
    /// when absent.
    #[serde(default)]
    for_arm: Option<String>,
    #[serde(default)]
    arm: toml::Table,
    #[serde(default)]
    sim: SimPart,
    #[serde(default)]
    step: Vec<StepPart>,
    #[serde(default)]
    drift: Drift,
}

/// A `[[step]]`: from `at_s` on, the arm before it with these `[step.arm]` keys.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct StepPart {
    at_s: f64,
    #[serde(default)]
    arm: toml::Table,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct SimPart {
    #[serde(default)]
    realism: toml::Table,
    #[serde(default)]
    mujoco: toml::Table,
}

/// A parsed scenario: its name (file stem or shipped name) and the keys it overrides.
#[derive(Debug, Clone)]
pub struct Scenario {
    pub name: String,
    /// The arm it changes (`for_arm`), `None` for the paper's.
    for_arm: Option<ArmConfig>,
    origin: String,
    text: String,
    arm: toml::Table,
    realism: toml::Table,
    /// Keys of `[sim.mujoco]` (gravity, a tip load): only on a config whose sim runs MuJoCo.
    mujoco: toml::Table,
    /// Each step's time and keys.
    steps: Vec<(f64, toml::Table)>,
    drift: Drift,
}

impl Scenario {
    /// A shipped scenario by name, or else a scenario file at `name_or_path`.
    pub fn resolve(name_or_path: &str) -> Result<Self, ConfigError> {
        let path = Path::new(name_or_path);
        if path.is_file() {
            return Self::load(path);
        }
        match SHIPPED.iter().find(|(name, _)| *name == name_or_path) {
            Some((name, text)) => Self::parse(text, name, &format!("shipped scenario {name}")),
            None => Err(ConfigError {
                origin: name_or_path.into(),
                line: None,
                message: format!(
                    "no such scenario file, nor a shipped scenario; the shipped ones are {}",
                    SHIPPED.map(|(n, _)| n).join(", ")
                ),
            }),
        }
    }

    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let origin = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError {
            origin: origin.clone(),
            line: None,
            message: format!("cannot read the scenario: {e}"),
        })?;
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| origin.clone());
        Self::parse(&text, &name, &origin)
    }

    /// Parses a scenario and checks it on the arm it is for (`for_arm`, else the default
    /// `[arm]`); [`Scenario::apply_to`] checks it on the arm it changes.
    pub fn parse(text: &str, name: &str, origin: &str) -> Result<Self, ConfigError> {
        let file: File = toml::from_str(text).map_err(|e| ConfigError {
            origin: origin.into(),
            line: e.span().map(|s| line_at(text, s.start)),
            message: e.message().to_string(),
        })?;
        let for_arm = match &file.for_arm {
            None => None,
            Some(arm) => {
                let text = crate::arms::resolve(arm).map_err(|e| ConfigError {
                    origin: origin.into(),
                    line: key_line(text, "for_arm"),
                    message: format!("for_arm: {}", e.message),
                })?;
                Some(crate::arms::check(&text, arm)?)
            }
        };
        let s = Self {
            name: name.into(),
            for_arm,
            origin: origin.into(),
            text: text.into(),
            arm: file.arm,
            realism: file.sim.realism,
            mujoco: file.sim.mujoco,
            steps: file.step.into_iter().map(|s| (s.at_s, s.arm)).collect(),
            drift: file.drift,
        };
        // A scenario of the MuJoCo plant is checked on one.
        let sim = SimConfig {
            mujoco: (!s.mujoco.is_empty()).then(MujocoConfig::default),
            ..SimConfig::default()
        };
        let arm = s.for_arm.clone().unwrap_or_default();
        s.apply_to(&arm, &sim)?;
        Ok(s)
    }

    /// The arm the scenario is for (`for_arm`), `None` for any arm it fits.
    pub fn for_arm(&self) -> Option<&ArmConfig> {
        self.for_arm.as_ref()
    }

    /// Checks the scenario on `config`'s arm, as the sim will apply it: what refuses it before
    /// anything starts.
    pub fn check_on(&self, config: &crate::Config) -> Result<(), ConfigError> {
        self.apply_to(&config.arm, &config.sim).map(drop)
    }

    /// Whether it changes the MuJoCo plant (`[sim.mujoco]` keys).
    pub fn changes_mujoco(&self) -> bool {
        !self.mujoco.is_empty()
    }

    /// The sim's arm and settings on an arm of any layout (`arm`, the config's `[arm]`): the
    /// scenario's `[arm]` keys in place of the config's, its `[sim.realism]` keys in place of
    /// the sim's, and each step's arm (its `[step.arm]` keys on the arm before it). A scenario
    /// for another arm than `arm` (by `for_arm`; the paper's when absent), one whose values do
    /// not fit `arm` (an offset per actuator of another count, a drift's rates) or that changes
    /// the arm's structure are refused naming the key. The drift goes into the sim's
    /// `changes` (steps come as `steps`).
    pub fn apply_to(&self, arm: &ArmConfig, sim: &SimConfig) -> Result<OnArm, ConfigError> {
        let layout = arm.layout().map_err(|m| self.error(&m))?;
        match &self.for_arm {
            Some(a) => {
                let mine = a.layout().map_err(|m| self.error(&m))?.identity();
                if mine != layout.identity() {
                    return Err(self.error(&format!(
                        "for_arm: the scenario changes the arm {mine}; this arm is {}",
                        layout.identity()
                    )));
                }
            }
            // Without `for_arm`: the paper's arm (any arm its shorthand keys can write), or the
            // keys every arm has.
            None if arm.shorthand().is_some() => {}
            None => {
                let mut keys = self.arm.keys().map(|k| format!("arm.{k}")).chain(
                    self.steps.iter().enumerate().flat_map(|(i, (_, t))| {
                        t.keys().map(move |k| format!("step[{i}].arm.{k}"))
                    }),
                );
                let every =
                    |key: &String| EVERY_ARMS.iter().any(|k| key.rsplit('.').next() == Some(k));
                if let Some(key) = keys.find(|k| !every(k)) {
                    return Err(self.error(&format!(
                        "{key}: a key of the paper's arm; a scenario for this arm ({}) says \
                         so with for_arm = \"NAME|FILE\", or sets only {}",
                        layout.identity(),
                        EVERY_ARMS.join(", ")
                    )));
                }
            }
        }
        let n = layout.actuators().len();
        // The paper's keys are set on the paper's arm as its shorthand writes it.
        let mut base = match &self.for_arm {
            None => arm.shorthand().unwrap_or_else(|| arm.clone()),
            Some(_) => arm.clone(),
        };
        base.tool_m.get_or_insert(layout.tool_m);
        base.connector_m.get_or_insert(layout.connector_m);
        base.actuator_offset_m.get_or_insert_with(|| vec![0.0; n]);
        let changed = self.arm_with("arm", &base, &self.arm, &layout)?;
        let mut steps = Vec::with_capacity(self.steps.len());
        let mut before = changed.clone();
        for (k, (at_s, keys)) in self.steps.iter().enumerate() {
            let after = steps.last().map_or(0.0, |(t, _)| *t);
            if !(at_s.is_finite() && *at_s > after && *at_s <= crate::changes::MAX_TIME_S) {
                return Err(self.error(&format!(
                    "step[{k}].at_s: must be after {after} s (the steps in order of time, the \
                     first after 0) and at most {} s, got {at_s:?}",
                    crate::changes::MAX_TIME_S
                )));
            }
            before = self.arm_with(&format!("step[{k}].arm"), &before, keys, &layout)?;
            steps.push((*at_s, before.clone()));
        }
        if steps.len() > crate::changes::MAX_STEPS {
            return Err(self.error(&format!(
                "step: at most {} steps, got {}",
                crate::changes::MAX_STEPS,
                steps.len()
            )));
        }
        // The drift on every arm it will be: the tendons' smallest radius over the steps.
        let mut min_radius = None::<f64>;
        for a in std::iter::once(&changed).chain(steps.iter().map(|(_, a)| a)) {
            let l = a.layout().map_err(|m| self.error(&m))?;
            for t in l.actuators().iter().filter(|t| t.kind == Kind::Tendon) {
                min_radius = Some(min_radius.map_or(t.radius_m, |r| r.min(t.radius_m)));
            }
        }
        (self.drift.check_for(n, min_radius)).map_err(|m| self.error(&m))?;
        let realism = self.overlay("sim.realism", &sim.realism, &self.realism)?;
        let sim = SimConfig {
            realism,
            mujoco: self.mujoco_of(sim)?,
            drift: self.drift,
            ..sim.clone()
        };
        sim.validate(n).map_err(|m| self.error(&m))?;
        Ok(OnArm {
            arm: changed,
            sim,
            steps,
        })
    }

    /// `base` with `keys` (of `section`) set, checked, and still an arm of `layout`'s
    /// actuators.
    fn arm_with(
        &self,
        section: &str,
        base: &ArmConfig,
        keys: &toml::Table,
        layout: &softarm_arm::Layout,
    ) -> Result<ArmConfig, ConfigError> {
        let changed: ArmConfig = self.overlay(section, base, keys)?;
        changed
            .validate()
            .map_err(|m| self.error(&m.replacen("arm.", &format!("{section}."), 1)))?;
        let after = changed.layout().map_err(|m| self.error(&m))?.identity();
        if after != layout.identity() {
            return Err(self.error(&format!(
                "{section}.modules: the scenario makes the arm {after}; a scenario changes an \
                 arm's lengths and offsets, not its actuators"
            )));
        }
        Ok(changed)
    }

    /// Whether it changes nothing.
    pub fn is_nominal(&self) -> bool {
        self.arm.is_empty()
            && self.realism.is_empty()
            && self.mujoco.is_empty()
            && !self.changes_over_time()
    }

    /// Whether the arm changes while the sim runs (steps or a drift).
    pub fn changes_over_time(&self) -> bool {
        // A MuJoCo plant's load comes on at its time.
        !self.steps.is_empty() || !self.drift.is_off() || self.mujoco.contains_key("load")
    }

    /// Each step's time (s of the sim's clock), in order.
    pub fn step_times(&self) -> Vec<f64> {
        self.steps.iter().map(|s| s.0).collect()
    }

    /// The overridden keys as `section.key = value`, for the sim's log.
    pub fn describe(&self) -> String {
        let keys = |section: &str, t: &toml::Table| {
            t.iter()
                .map(|(k, v)| format!("{section}.{k} = {v}"))
                .collect::<Vec<_>>()
        };
        let mut all = keys("arm", &self.arm);
        all.extend(keys("sim.realism", &self.realism));
        all.extend(keys("sim.mujoco", &self.mujoco));
        for (k, (at_s, arm)) in self.steps.iter().enumerate() {
            all.push(format!(
                "step {} at {at_s} s: {}",
                k + 1,
                keys("arm", arm).join(", ")
            ));
        }
        if let Some(drift) = self.drift_keys() {
            all.push(drift);
        }
        if all.is_empty() {
            "nothing overridden".into()
        } else {
            all.join(", ")
        }
    }

    /// The drift's keys that are set, as `drift.key = value`.
    fn drift_keys(&self) -> Option<String> {
        let set = toml::Table::try_from(self.drift).ok()?;
        let off = toml::Table::try_from(Drift::default()).ok()?;
        let keys: Vec<String> = set
            .iter()
            .filter(|(k, v)| off.get(*k) != Some(*v))
            .map(|(k, v)| format!("drift.{k} = {v}"))
            .collect();
        (!keys.is_empty()).then(|| keys.join(", "))
    }

    /// What the scenario has changed by time `t` (s of the sim's clock), in a few words for a
    /// table: the step in force, how far the creeping actuators have crept, the radius's
    /// change. Empty when nothing changes over time.
    pub fn changed_at(&self, t: f64) -> String {
        let mut parts = Vec::new();
        let done = self.steps.iter().filter(|s| s.0 <= t).count();
        if done > 0 {
            let (at_s, keys) = &self.steps[done - 1];
            let keys: Vec<String> = keys.iter().map(|(k, v)| format!("{k} = {v}")).collect();
            parts.push(format!("step {done} at {at_s} s ({})", keys.join(", ")));
        } else if !self.steps.is_empty() {
            parts.push("before step 1".into());
        }
        let max_mm = MAX_OFFSET_M * 1e3;
        let crept: Vec<String> = (self.drift.creep_m(t).iter().enumerate())
            .filter(|(_, c)| **c != 0.0)
            .map(|(i, c)| format!("{}: {:+.2}", i + 1, (c * 1e3).clamp(-max_mm, max_mm)))
            .collect();
        if !crept.is_empty() {
            parts.push(format!("crept mm {}", crept.join(", ")));
        }
        if self.drift.actuator_radius_amplitude_m > 0.0 {
            let dr = self.drift.radius_change_m(t) * 1e3;
            parts.push(format!("radius {dr:+.2} mm"));
        }
        parts.join("; ")
    }

    /// `base` with each of `keys` set; an unknown key or a value of the wrong type is blamed on
    /// its own line.
    /// The sim's `[sim.mujoco]` with the scenario's keys in place; refused when the sim has
    /// none to change.
    fn mujoco_of(&self, sim: &SimConfig) -> Result<Option<MujocoConfig>, ConfigError> {
        match &sim.mujoco {
            _ if self.mujoco.is_empty() => Ok(sim.mujoco.clone()),
            Some(m) => {
                if let Some(key) = self
                    .mujoco
                    .keys()
                    .find(|k| !MUJOCO_KEYS.contains(&k.as_str()))
                {
                    return Err(self.error(&format!(
                        "sim.mujoco.{key}: a scenario changes {} of the MuJoCo plant",
                        MUJOCO_KEYS.join(" and ")
                    )));
                }
                let mut merged =
                    toml::Table::try_from(m).map_err(|e| self.error(&e.to_string()))?;
                merged.extend(self.mujoco.clone());
                let m: MujocoConfig = MujocoConfig::deserialize(merged)
                    .map_err(|e| self.error(&format!("[sim.mujoco]: {}", e.message().trim())))?;
                Ok(Some(m))
            }
            None => Err(self.error(
                "[sim.mujoco]: changes the MuJoCo plant, and this config's sim runs its own \
                 kinematics: run it on a config with [sim.mujoco]",
            )),
        }
    }

    fn overlay<T: Serialize + DeserializeOwned>(
        &self,
        section: &str,
        base: &T,
        keys: &toml::Table,
    ) -> Result<T, ConfigError> {
        let base = toml::Table::try_from(base).map_err(|e| self.error(&e.to_string()))?;
        let mut merged = base.clone();
        for (key, value) in keys {
            if !base.contains_key(key) {
                let known: Vec<&str> = base.keys().map(String::as_str).collect();
                return Err(self.error(&format!(
                    "{section}.{key}: unknown key; [{section}] has {}",
                    known.join(", ")
                )));
            }
            // One key at a time on the base, so a value of the wrong type names its key.
            let mut one = base.clone();
            one.insert(key.clone(), value.clone());
            T::deserialize(one)
                .map_err(|e| self.error(&format!("{section}.{key}: {}", e.message().trim())))?;
            merged.insert(key.clone(), value.clone());
        }
        T::deserialize(merged).map_err(|e| self.error(&format!("[{section}]: {}", e.message())))
    }

    /// An error for `key: message`, at the key's line in the scenario.
    fn error(&self, keyed: &str) -> ConfigError {
        let key = keyed.split(':').next().unwrap_or("");
        ConfigError {
            origin: self.origin.clone(),
            line: key_line(&self.text, key),
            message: keyed.into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sim's arm and settings for scenario `name` on the default `[arm]` (the paper's).
    fn sim_of(name: &str) -> OnArm {
        Scenario::resolve(name)
            .unwrap()
            .apply_to(&ArmConfig::default(), &SimConfig::default())
            .unwrap()
    }

    fn arm_of(name: &str) -> ArmConfig {
        sim_of(name).arm
    }

    #[test]
    fn the_shipped_scenarios_change_what_they_say() {
        // The default [arm] as the shorthand writes it, every key set.
        let nominal = ArmConfig::default().shorthand().unwrap();
        assert_eq!(nominal.tool_m, Some(0.03));
        assert!(Scenario::resolve("nominal").unwrap().is_nominal());
        let zeros = ArmConfig {
            actuator_offset_m: Some(vec![0.0; 6]),
            ..nominal.clone()
        };
        assert_eq!(arm_of("nominal"), zeros);
        assert_eq!(
            arm_of("tool-change"),
            ArmConfig {
                tool_m: Some(0.05),
                ..zeros.clone()
            }
        );
        let creep = arm_of("creep");
        let longer: Vec<f64> = (creep.actuator_offset_m.unwrap().into_iter())
            .filter(|o| *o != 0.0)
            .collect();
        assert_eq!(longer, [0.003, 0.004]);
        assert_eq!(arm_of("twist").module_rotation_deg, Some([0.0, 70.0]));
        assert_eq!(arm_of("stiffer").actuator_radius_m, Some(0.028));
        // The paper's arm written by its modules takes the paper's scenarios as the shorthand's.
        let modules = ArmConfig {
            modules: Some(ArmConfig::default().description().modules),
            ..ArmConfig::default()
        };
        let on = Scenario::resolve("stiffer")
            .unwrap()
            .apply_to(&modules, &SimConfig::default())
            .unwrap();
        assert_eq!(on.arm, arm_of("stiffer"));
        let fixed = [
            "nominal",
            "tool-change",
            "creep",
            "twist",
            "stiffer",
            "not-pcc",
            "tdcr-creep",
            "hybrid-weak-chamber",
        ];
        for (name, _) in SHIPPED {
            let s = Scenario::resolve(name).unwrap();
            assert_eq!(s.changes_over_time(), !fixed.contains(&name), "{name}");
        }
        for (name, text) in SHIPPED {
            assert!(
                text.trim_start().starts_with('#'),
                "{name}: say what it models"
            );
        }
    }

    /// The sim's arm and settings on `name` at the defaults.
    /// A scenario changes a MuJoCo plant's gravity and tip load, only on a sim that runs one,
    /// and nothing else of it.
    #[test]
    fn a_scenario_changes_a_mujoco_plants_gravity_and_load_and_nothing_else() {
        let text = "[sim.mujoco]\ngravity_m_s2 = [0.0, 0.0, -9.81]\nload = { from_s = 60.0, \
                    force_n = [0.25, 0.0, 0.0] }\n";
        let s = Scenario::parse(text, "load", "test").unwrap();
        assert!(s.changes_mujoco() && s.changes_over_time() && !s.is_nominal());
        let arm = ArmConfig::default();
        let mujoco = SimConfig {
            mujoco: Some(MujocoConfig::default()),
            ..SimConfig::default()
        };
        let on = s.apply_to(&arm, &mujoco).unwrap();
        let m = on.sim.mujoco.unwrap();
        assert_eq!(m.gravity_m_s2, Some([0.0, 0.0, -9.81]));
        assert_eq!(m.load.unwrap().force_n, [0.25, 0.0, 0.0]);
        assert_eq!(m.tip_site, MujocoConfig::default().tip_site);
        let e = s.apply_to(&arm, &SimConfig::default()).unwrap_err();
        assert!(e.message.contains("runs its own kinematics"), "{e}");
        let e = Scenario::parse("[sim.mujoco]\nmodel = \"x.xml\"\n", "m", "test").unwrap_err();
        assert!(
            e.message
                .starts_with("sim.mujoco.model: a scenario changes"),
            "{e}"
        );
    }

    #[test]
    fn the_shipped_scenarios_that_change_over_time_do_so_at_their_times() {
        let swap = sim_of("tool-swap");
        assert_eq!(swap.arm.tool_m, Some(0.03));
        assert_eq!(swap.steps.len(), 1);
        assert_eq!(
            (swap.steps[0].0, swap.steps[0].1.tool_m),
            (90.0, Some(0.05))
        );
        // Creeping: 0.5 mm/min on actuators 2 and 6, 10 mm in 20 minutes.
        let o = sim_of("creeping").sim.drift.creep_m(1200.0);
        let want = [0.0, 0.01, 0.0, 0.0, 0.0, 0.01];
        assert!((0..6).all(|i| (o[i] - want[i]).abs() < 1e-12), "{o:?}");
        let drift = sim_of("stiffness-cycle").sim.drift;
        let r = |t| 0.025 + drift.radius_change_m(t);
        assert!((r(150.0) - 0.027).abs() < 1e-12 && (r(450.0) - 0.023).abs() < 1e-12);
        // Combined: each step on the arm before it, the drifts on top.
        let combined = sim_of("combined");
        let at = |t: f64| {
            let step = combined.steps.iter().rfind(|(at_s, _)| *at_s <= t);
            step.map_or(&combined.arm, |(_, arm)| arm)
        };
        let state = |t| (at(t).tool_m, at(t).module_rotation_deg.unwrap()[0]);
        assert_eq!(state(60.0), (Some(0.03), 0.0));
        assert_eq!(state(300.0), (Some(0.05), 5.0));
        assert_eq!(state(500.0), (Some(0.03), 5.0));
        assert!((combined.sim.drift.creep_m(120.0)[4] - 0.001).abs() < 1e-12);
        assert_eq!(sim_of("not-pcc").sim.realism.curvature_taper, 0.6);
        // The sim's default realism stays exact PCC.
        assert_eq!(sim_of("nominal").sim.realism.curvature_taper, 0.0);
        let s = Scenario::resolve("combined").unwrap();
        assert_eq!(s.step_times(), [90.0, 240.0, 420.0]);
        assert!(
            s.describe()
                .contains("step 2 at 240 s: arm.module_rotation_deg"),
            "{}",
            s.describe()
        );
        assert_eq!(
            s.changed_at(30.0),
            "before step 1; crept mm 1: +0.25, 5: +0.25; radius +0.57 mm"
        );
        assert!(
            s.changed_at(250.0)
                .starts_with("step 2 at 240 s (module_rotation_deg = [5.0, 60.0])"),
            "{}",
            s.changed_at(250.0)
        );
    }

    use softarm_kinematics::forward::ForwardModel;
    use softarm_kinematics::pcc;

    /// The actuation that puts the PCC arm's tip at `target`: damped Gauss-Newton from the
    /// middle, finite-difference Jacobian.
    fn reach(arm: &pcc::Arm, target: [f64; 3]) -> [f64; 6] {
        let mut a = [0.5; 6];
        for _ in 0..100 {
            let p = ForwardModel::<6>::position(arm, &a);
            let e: [f64; 3] = std::array::from_fn(|d| target[d] - p[d]);
            let j = nalgebra::SMatrix::<f64, 3, 6>::from_fn(|d, i| {
                let mut b = a;
                b[i] += 1e-6;
                (ForwardModel::<6>::position(arm, &b)[d] - p[d]) / 1e-6
            });
            let jt = j.transpose();
            let m = j * jt + nalgebra::Matrix3::identity() * 1e-8;
            let step = jt * m.try_inverse().unwrap() * nalgebra::Vector3::from(e);
            for i in 0..6 {
                a[i] = (a[i] + step[i]).clamp(0.0, 1.0);
            }
        }
        a
    }

    #[test]
    fn not_pcc_moves_the_tip_by_millimetres_at_the_demo_points() {
        let demo = crate::waypoints::WaypointFile::parse(include_str!(
            "../../../config/waypoints/demo.toml"
        ))
        .unwrap();
        let not_pcc = sim_of("not-pcc");
        let arm = pcc::Arm::of_config(&not_pcc.arm).unwrap();
        let taper = not_pcc.sim.realism.curvature_taper;
        let moved: Vec<f64> = demo
            .point
            .iter()
            .map(|p| {
                let a = reach(&arm, p.position_m);
                let pcc = ForwardModel::<6>::position(&arm, &a);
                assert!(
                    (0..3).all(|d| (pcc[d] - p.position_m[d]).abs() < 1e-6),
                    "reached"
                );
                let q = arm
                    .pose_of_lengths(&arm.lengths(&a), taper)
                    .unwrap()
                    .position;
                let d = [q.x - pcc[0], q.y - pcc[1], q.z - pcc[2]];
                d.iter().map(|v| v * v).sum::<f64>().sqrt() * 1e3
            })
            .collect();
        eprintln!("not-pcc moves the tip at the demo's points by (mm) {moved:.2?}");
        let mean = moved.iter().sum::<f64>() / moved.len() as f64;
        assert!(mean > 3.0 && mean < 30.0, "{moved:?}");
    }

    #[test]
    fn a_scenario_overrides_only_its_keys() {
        let text = "[arm]\ntool_m = 0.06\n[sim.realism]\nlag_s = 0.05\n";
        let s = Scenario::parse(text, "t", "t.toml").unwrap();
        let sim = SimConfig {
            rate_hz: 100.0,
            ..Default::default()
        };
        let arm = ArmConfig {
            connector_m: Some(0.04),
            ..Default::default()
        };
        let OnArm { arm: a, sim: c, .. } = s.apply_to(&arm, &sim).unwrap();
        assert_eq!((a.tool_m, a.connector_m), (Some(0.06), Some(0.04)));
        assert_eq!((c.realism.lag_s, c.rate_hz), (0.05, 100.0));
        assert_eq!(c.realism.backlash, sim.realism.backlash);
        assert!(
            s.describe().contains("arm.tool_m = 0.06"),
            "{}",
            s.describe()
        );
    }

    /// On another arm: the keys every arm has from any scenario, the arm's own scenarios with
    /// their per-actuator values, and nothing sized for another arm or changing over time.
    #[test]
    fn another_arm_takes_its_own_scenarios_and_those_of_every_arm() {
        let on = |arm: &str| {
            let text = crate::arms::resolve(arm).unwrap();
            let c = crate::Config::parse(
                &crate::arms::with_arm(crate::DEFAULT, &text, arm).unwrap(),
                arm,
                ".".into(),
            )
            .unwrap();
            (c.arm.clone(), c)
        };
        let (tdcr, c) = on("tdcr");
        let arm = Scenario::resolve("tool-change")
            .unwrap()
            .apply_to(&tdcr, &c.sim)
            .unwrap()
            .arm;
        assert_eq!(arm.tool_m, Some(0.05));
        assert_eq!(arm.layout().unwrap().identity(), c.arm_identity());
        let creep = Scenario::resolve("tdcr-creep").unwrap();
        let arm = creep.apply_to(&tdcr, &c.sim).unwrap().arm;
        // Steps of the keys every arm has step any arm.
        let swap = Scenario::resolve("tool-swap")
            .unwrap()
            .apply_to(&tdcr, &c.sim)
            .unwrap();
        assert_eq!(swap.arm.tool_m, Some(0.01));
        assert_eq!(swap.steps.len(), 1);
        assert_eq!(
            (swap.steps[0].0, swap.steps[0].1.tool_m),
            (90.0, Some(0.05))
        );
        assert_eq!(arm.actuator_offset_m.unwrap()[4], 0.0015);
        assert!(creep.check_on(&c).is_ok());
        let e = creep
            .check_on(&crate::Config::default_sim(".".into()))
            .unwrap_err();
        assert!(
            e.message
                .starts_with("for_arm: the scenario changes the arm 9 actuators"),
            "{e}"
        );
        let (hybrid, h) = on("hybrid");
        let e = creep.apply_to(&hybrid, &h.sim).unwrap_err();
        assert!(e.message.contains("this arm is 8 actuators"), "{e}");
        assert!(
            Scenario::resolve("hybrid-weak-chamber")
                .unwrap()
                .check_on(&h)
                .is_ok()
        );
        for (paper_only, says) in [
            ("creep", "arm.actuator_offset_m: a key of the paper's arm"),
            (
                "creeping",
                "drift.creep_mm_per_min: 6 values for an arm of 9 actuators",
            ),
            (
                "sequence",
                "step[0].arm.actuator_offset_m: a key of the paper's arm",
            ),
        ] {
            let e = Scenario::resolve(paper_only)
                .unwrap()
                .check_on(&c)
                .unwrap_err();
            assert!(e.message.starts_with(says), "{paper_only}: {e}");
        }
        // Drifts on any arm: the TDCR's own creep, sized to it, and a radius cycle (every arm's).
        let on_tdcr = Scenario::resolve("tdcr-creeping")
            .unwrap()
            .apply_to(&c.arm, &c.sim)
            .unwrap();
        assert_eq!(on_tdcr.sim.drift.creep_mm_per_min.len(), 9);
        assert!(on_tdcr.steps.is_empty());
        let cycle = Scenario::resolve("stiffness-cycle").unwrap();
        assert!(cycle.check_on(&c).is_ok());
        let wide = "[drift]\nactuator_radius_amplitude_m = 0.005\nactuator_radius_period_s = 60\n";
        let e = Scenario::parse(wide, "wide", "wide.toml")
            .unwrap()
            .check_on(&c)
            .unwrap_err();
        assert!(
            e.message.contains("smallest tendon radius (0.0045 m)"),
            "{e}"
        );
        let e = Scenario::resolve("tdcr-creeping")
            .unwrap()
            .check_on(&h)
            .unwrap_err();
        assert!(e.message.starts_with("for_arm:"), "{e}");
        let six = "for_arm = \"tdcr\"\n[arm]\nactuator_offset_m = [0, 0, 0, 0, 0, 0.001]\n";
        let e = Scenario::parse(six, "six", "six.toml").unwrap_err();
        assert_eq!(e.line, Some(3), "{e}");
        assert!(e.message.contains("6 values for an arm of 9"), "{e}");
        let e = Scenario::parse("for_arm = \"octopus\"\n", "x", "x.toml").unwrap_err();
        assert_eq!(e.line, Some(1), "{e}");
        assert!(e.message.starts_with("for_arm: no such arm file"), "{e}");
    }

    #[test]
    fn bad_scenarios_name_the_key_and_line() {
        let cases = [
            (
                "[arm]\ntool_m = 0.05\ntool_mm = 1\n",
                3,
                "arm.tool_mm: unknown key",
            ),
            ("# x\n[sim]\nrate_hz = 10\n", 3, "unknown field `rate_hz`"),
            ("[arm]\n\ntool_m = \"long\"\n", 3, "arm.tool_m:"),
            (
                "[arm]\nactuator_radius_m = -1.0\n",
                2,
                "arm.actuator_radius_m:",
            ),
            (
                "[sim.realism]\nseed = 2\nlag_s = 1e9\n",
                3,
                "sim.realism.lag_s:",
            ),
            (
                "[controller]\nrate_hz = 100\n",
                1,
                "unknown field `controller`",
            ),
            ("[arm\n", 1, ""),
            (
                "[[step]]\nat_s = 90\n[step.arm]\ntool_m = 0.05\n[[step]]\nat_s = 60\n",
                6,
                "step[1].at_s: must be after 90 s",
            ),
            (
                "[[step]]\nat_s = 9\n[step.arm]\n\ntool_mm = 0.05\n",
                5,
                "step[0].arm.tool_mm: unknown key",
            ),
            (
                "[[step]]\nat_s = 9\n[step.arm]\ntool_m = -0.05\n",
                4,
                "step[0].arm.tool_m: must be a length",
            ),
            (
                "[[step]]\n[step.arm]\ntool_m = 0.05\n",
                1,
                "missing field `at_s`",
            ),
            ("[[step]]\nat_s = \"soon\"\n", 2, "invalid type"),
            (
                "# x\n[drift]\ncreep_mm_per_min = [0, 0.5, 0, 0, 0, 90]\n",
                3,
                "drift.creep_mm_per_min: actuator 6 is 90.0",
            ),
            (
                "[drift]\ncreep_mm_per_hour = 1\n",
                2,
                "unknown field `creep_mm_per_hour`",
            ),
            (
                "[drift]\nactuator_radius_amplitude_m = 0.002\n",
                1,
                "drift.actuator_radius_period_s: must be > 0",
            ),
            (
                "[[step]]\nat_s = 9\n[step.arm]\nactuator_radius_m = 0.001\n\
                 [drift]\nactuator_radius_amplitude_m = 0.002\nactuator_radius_period_s = 60\n",
                6,
                "drift.actuator_radius_amplitude_m: 0.002 m takes the smallest tendon radius (0.001 m) to 0",
            ),
            (
                "[sim.realism]\ncurvature_taper = 2\n",
                2,
                "sim.realism.curvature_taper: must be in [0, 1]",
            ),
        ];
        for (text, line, says) in cases {
            let e = Scenario::parse(text, "bad", "bad.toml").unwrap_err();
            assert_eq!(e.line, Some(line), "{text:?}: {e}");
            assert!(e.message.contains(says), "{text:?}: {e}");
            assert!(e.to_string().starts_with("bad.toml:"), "{e}");
        }
        let e = Scenario::resolve("no-such-scenario").unwrap_err();
        assert!(e.message.contains("tool-change"), "{e}");
    }
}
