//! The TOML files softarm reads on its own, told apart by their top-level keys: what
//! `softarm config check FILE` takes a file for before it checks it as that.

use std::collections::BTreeSet;

use crate::ConfigError;
use crate::arm::ArmConfig;

/// A kind of file softarm reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileKind {
    /// A whole config (`softarm.toml`, `hardware.toml`).
    Config,
    /// An `[arm]` section on its own (`config/arms/*.toml`, `--arm FILE`).
    Arm,
    /// A way-point set (`softarm submit FILE`).
    WaypointSet,
    /// A scenario (`--scenario FILE`).
    Scenario,
    /// A recording's column map (`softarm train --from REC --columns FILE`).
    ColumnMap,
    /// A MuJoCo model of an arm for the sim (`softarm demo --mujoco FILE`):
    /// `crate::plant::Plant`.
    Plant,
}

impl FileKind {
    /// What the kind is called where it is said which one a file was taken for.
    pub fn name(self) -> &'static str {
        match self {
            Self::Config => "a config",
            Self::Arm => "an [arm] file",
            Self::WaypointSet => "a way-point set",
            Self::Scenario => "a scenario",
            Self::ColumnMap => "a recording's column map",
            Self::Plant => "a plant file",
        }
    }

    /// The kind of file `text` is, by its top-level keys; an error naming them when they fit
    /// none (or the text is not TOML), so that the user can say with `--as`.
    pub fn of(text: &str, origin: &str) -> Result<Self, ConfigError> {
        let table: toml::Table = toml::from_str(text).map_err(|e| ConfigError {
            origin: origin.into(),
            line: e.span().map(|s| crate::line_at(text, s.start)),
            message: e.message().to_string(),
        })?;
        let keys: BTreeSet<&str> = table.keys().map(String::as_str).collect();
        let any = |of: &[&str]| of.iter().any(|k| keys.contains(k));
        let sections = properties(schemars::schema_for!(crate::Config));
        // `[arm]` and `[sim]` are a scenario's too: only the config's other sections say config.
        let config_only = sections
            .iter()
            .any(|k| !matches!(k.as_str(), "arm" | "sim") && keys.contains(k.as_str()));
        let arm_keys = properties(schemars::schema_for!(ArmConfig));
        let kind = if config_only {
            Self::Config
        } else if keys.contains("mujoco") && keys.iter().all(|k| ["arm", "mujoco"].contains(k)) {
            Self::Plant
        } else if any(&["actuators", "tip", "time"]) {
            Self::ColumnMap
        } else if any(&["point", "duration_s"]) {
            Self::WaypointSet
        } else if arm_keys.iter().any(|k| keys.contains(k.as_str())) {
            Self::Arm
        } else if keys
            .iter()
            .all(|k| ["for_arm", "arm", "sim", "step", "drift"].contains(k))
        {
            // An empty file too: the scenario that changes nothing (`nominal`).
            Self::Scenario
        } else {
            let found: Vec<&str> = keys.into_iter().collect();
            return Err(ConfigError {
                origin: origin.into(),
                line: None,
                message: format!(
                    "cannot tell what this file is from its top-level keys ({}): give `--as \
                     config|arm|waypoints|scenario|columns|plant`",
                    found.join(", ")
                ),
            });
        };
        Ok(kind)
    }
}

/// Checks `text` (the file `path`) as `kind`, as softarm reads such a file: a way-point set
/// against `config`'s limits, a scenario on the arm it names or else `config`'s, an arm file
/// put into the embedded config as `--arm` puts it. What it found, in a few words; the first error, naming its line. A
/// recording's column map is checked where it is read (`softarm-identify`), not here.
pub fn check(
    kind: FileKind,
    text: &str,
    path: &std::path::Path,
    config: &crate::Config,
) -> Result<String, ConfigError> {
    let origin = path.display().to_string();
    let refused = |message: String| ConfigError {
        origin: origin.clone(),
        line: None,
        message,
    };
    Ok(match kind {
        FileKind::Config => {
            let base = path
                .parent()
                .map(std::path::Path::to_path_buf)
                .unwrap_or_default();
            let c = crate::Config::parse(text, &origin, base)?;
            format!(
                "namespace {}, the arm of {}",
                c.namespace(),
                c.arm_identity()
            )
        }
        FileKind::Arm => {
            // As `--arm FILE` reads it: into a config, where what does not fit the rest shows.
            let with = crate::arms::with_arm(crate::DEFAULT, text, &origin)?;
            let c = crate::Config::parse(&with, &origin, config.base_dir.clone())?;
            c.arm_identity()
        }
        FileKind::WaypointSet => {
            let file = crate::waypoints::WaypointFile::parse(text).map_err(refused)?;
            file.to_set(1)
                .and_then(|set| {
                    crate::waypoints::validate(&set, &config.waypoints, &config.activation)
                })
                .map_err(|e| refused(format!("against the config's limits: {e}")))?;
            format!(
                "{} points over {} s, within the config's limits",
                file.point.len(),
                file.duration_s
            )
        }
        FileKind::Scenario => {
            let name = path
                .file_stem()
                .map_or_else(|| origin.clone(), |s| s.to_string_lossy().into_owned());
            // Parsing checks it on the arm it names; one that names none, on the config's (one
            // that changes a MuJoCo plant, on a model generated from it if the config has none).
            let scenario = crate::scenario::Scenario::parse(text, &name, &origin)?;
            let on = match scenario.for_arm() {
                Some(arm) => arm.layout().map(|l| l.identity()).unwrap_or_default(),
                None => {
                    let mut config = config.clone();
                    if scenario.changes_mujoco() && config.sim.mujoco.is_none() {
                        config.sim.mujoco = Some(Default::default());
                    }
                    scenario.check_on(&config)?;
                    config.arm_identity()
                }
            };
            format!("on the arm of {on}: {}", scenario.describe())
        }
        FileKind::Plant => {
            let dir = path.parent().unwrap_or(std::path::Path::new("."));
            let plant = crate::plant::Plant::parse(text, &origin, dir)?;
            let with = plant.into_config(crate::DEFAULT)?;
            let c = crate::Config::parse(&with, &origin, config.base_dir.clone())?;
            let model = match &plant.mujoco.model {
                Some(m) => format!("the model {}", m.display()),
                None => "a model generated from the arm".into(),
            };
            format!("{model} of the arm of {}", c.arm_identity())
        }
        FileKind::ColumnMap => {
            // Its reader is the recording's (softarm-identify), which this crate does not link.
            return Err(refused(
                "a recording's column map is read by softarm-identify (`Columns::parse`)".into(),
            ));
        }
    })
}

/// The property names of a struct's JSON schema: the keys its TOML table takes.
fn properties(schema: schemars::Schema) -> Vec<String> {
    schema
        .as_object()
        .and_then(|o| o.get("properties"))
        .and_then(|p| p.as_object())
        .map(|p| p.keys().cloned().collect())
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn of(text: &str) -> FileKind {
        FileKind::of(text, "test").unwrap()
    }

    #[test]
    fn every_shipped_file_is_taken_for_what_it_is() {
        assert_eq!(of(crate::DEFAULT), FileKind::Config);
        for (name, text) in crate::arms::SHIPPED {
            assert_eq!(of(text), FileKind::Arm, "{name}");
        }
        for (name, text) in crate::scenario::SHIPPED {
            assert_eq!(of(text), FileKind::Scenario, "{name}");
        }
        let set = include_str!("../../../config/waypoints/demo.toml");
        assert_eq!(of(set), FileKind::WaypointSet);
        let columns = include_str!("../../../config/recordings/opencr-tdcr/columns.toml");
        assert_eq!(of(columns), FileKind::ColumnMap);
        let plant = include_str!("../../../config/mujoco/opencr-ftdcr-v6.toml");
        assert_eq!(of(plant), FileKind::Plant);
        assert_eq!(of("[mujoco]\ntip_site = \"tip\"\n"), FileKind::Plant);
        let load = include_str!("../../../config/mujoco/tip-load.toml");
        assert_eq!(of(load), FileKind::Scenario);
        let hardware = include_str!("../../../config/hardware.toml");
        assert_eq!(of(hardware), FileKind::Config);
    }

    #[test]
    fn a_file_of_no_kind_is_refused_naming_its_keys() {
        let e = FileKind::of("colour = 3\n[shape]\nsides = 4\n", "f.toml").unwrap_err();
        assert!(e.message.contains("(colour, shape)"), "{}", e.message);
        assert!(e.message.contains("--as"), "{}", e.message);
        assert_eq!(
            of("# nothing\n"),
            FileKind::Scenario,
            "the nominal scenario"
        );
        let e = FileKind::of("a = [", "f.toml").unwrap_err();
        assert_eq!(e.line, Some(1));
    }
}
