//! Scenario files: the simulated arm is not the one the model was trained on. A scenario
//! overrides keys of `[arm]` and `[sim.realism]` for the sim process only; the controller, the
//! learner and the model keep the nominal arm of the config.
//!
//! ```toml
//! # A longer tool (comments say what the scenario models).
//! [arm]
//! tool_m = 0.05
//! ```
//!
//! Unknown sections and keys are refused, every value is checked as the config checks it, and
//! errors name the key and its line in the scenario file.

use std::path::Path;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use softarm_method::pcc::ArmGeometry;
use softarm_method::plant::SimConfig;

use crate::{ConfigError, key_line, line_at};

/// The scenarios shipped in `config/scenarios/`, embedded so `--scenario NAME` works anywhere.
pub const SHIPPED: [(&str, &str); 5] = [
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
];

/// What a scenario file may hold.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    #[serde(default)]
    arm: toml::Table,
    #[serde(default)]
    sim: SimPart,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct SimPart {
    #[serde(default)]
    realism: toml::Table,
}

/// A parsed scenario: its name (file stem or shipped name) and the keys it overrides.
#[derive(Debug, Clone)]
pub struct Scenario {
    pub name: String,
    origin: String,
    text: String,
    arm: toml::Table,
    realism: toml::Table,
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

    /// Parses a scenario and checks it against the defaults; [`Scenario::apply`] checks it
    /// against the arm it changes.
    pub fn parse(text: &str, name: &str, origin: &str) -> Result<Self, ConfigError> {
        let file: File = toml::from_str(text).map_err(|e| ConfigError {
            origin: origin.into(),
            line: e.span().map(|s| line_at(text, s.start)),
            message: e.message().to_string(),
        })?;
        let s = Self {
            name: name.into(),
            origin: origin.into(),
            text: text.into(),
            arm: file.arm,
            realism: file.sim.realism,
        };
        s.apply(&ArmGeometry::default(), &SimConfig::default())?;
        Ok(s)
    }

    /// Whether it changes nothing.
    pub fn is_nominal(&self) -> bool {
        self.arm.is_empty() && self.realism.is_empty()
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
        if all.is_empty() {
            "nothing overridden".into()
        } else {
            all.join(", ")
        }
    }

    /// The sim's arm and settings with the scenario's keys in place of the config's.
    pub fn apply(
        &self,
        arm: &ArmGeometry,
        sim: &SimConfig,
    ) -> Result<(ArmGeometry, SimConfig), ConfigError> {
        let arm: ArmGeometry = self.overlay("arm", arm, &self.arm)?;
        arm.validate().map_err(|m| self.error(&m))?;
        let realism = self.overlay("sim.realism", &sim.realism, &self.realism)?;
        let sim = SimConfig { realism, ..*sim };
        sim.validate().map_err(|m| self.error(&m))?;
        Ok((arm, sim))
    }

    /// `base` with each of `keys` set; an unknown key or a value of the wrong type is blamed on
    /// its own line.
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

    fn arm_of(name: &str) -> ArmGeometry {
        let s = Scenario::resolve(name).unwrap();
        s.apply(&ArmGeometry::default(), &SimConfig::default())
            .unwrap()
            .0
    }

    #[test]
    fn the_shipped_scenarios_change_what_they_say() {
        let nominal = ArmGeometry::default();
        assert!(Scenario::resolve("nominal").unwrap().is_nominal());
        assert_eq!(arm_of("nominal"), nominal);
        assert_eq!(
            arm_of("tool-change"),
            ArmGeometry {
                tool_m: nominal.tool_m + 0.02,
                ..nominal
            }
        );
        let creep = arm_of("creep");
        let longer: Vec<f64> = creep
            .actuator_offset_m
            .into_iter()
            .filter(|o| *o != 0.0)
            .collect();
        assert_eq!(longer, [0.003, 0.004]);
        assert_eq!(
            arm_of("twist").module_rotation_deg[1],
            nominal.module_rotation_deg[1] + 10.0
        );
        assert_eq!(arm_of("stiffer").actuator_radius_m, 0.028);
        for (name, text) in SHIPPED {
            assert!(
                text.trim_start().starts_with('#'),
                "{name}: say what it models"
            );
        }
    }

    #[test]
    fn a_scenario_overrides_only_its_keys() {
        let text = "[arm]\ntool_m = 0.06\n[sim.realism]\nlag_s = 0.05\n";
        let s = Scenario::parse(text, "t", "t.toml").unwrap();
        let sim = SimConfig {
            rate_hz: 100.0,
            ..Default::default()
        };
        let arm = ArmGeometry {
            connector_m: 0.04,
            ..Default::default()
        };
        let (a, c) = s.apply(&arm, &sim).unwrap();
        assert_eq!((a.tool_m, a.connector_m), (0.06, 0.04));
        assert_eq!((c.realism.lag_s, c.rate_hz), (0.05, 100.0));
        assert_eq!(c.realism.backlash, sim.realism.backlash);
        assert!(
            s.describe().contains("arm.tool_m = 0.06"),
            "{}",
            s.describe()
        );
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
