//! A plant file: a MuJoCo model of an arm for the sim (`softarm demo --mujoco FILE`), as a lab
//! ships one: `[mujoco]` (the keys of `[sim.mujoco]`: the model file, relative to the plant
//! file's folder, and its map onto the arm) and, optionally, the `[arm]` it is a model of.
//! `generated` in place of a file: a model generated from the arm.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::ConfigError;
use crate::arm::ArmConfig;
use crate::mujoco::MujocoConfig;

/// A plant file, read.
#[derive(Debug, Clone, PartialEq)]
pub struct Plant {
    /// The arm it is a model of, as written (an `[arm]` file's text), if it says.
    pub arm: Option<String>,
    /// Its `[sim.mujoco]`, the model's path absolute.
    pub mujoco: MujocoConfig,
    origin: String,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    #[serde(default)]
    arm: Option<toml::Table>,
    mujoco: MujocoConfig,
}

/// What `--mujoco` takes for a model generated from the arm.
pub const GENERATED: &str = "generated";

impl Plant {
    /// `generated`, or the plant file at `name_or_path`.
    pub fn resolve(name_or_path: &str) -> Result<Self, ConfigError> {
        if name_or_path == GENERATED && !Path::new(GENERATED).exists() {
            return Ok(Self {
                arm: None,
                mujoco: MujocoConfig::default(),
                origin: GENERATED.into(),
            });
        }
        let path = Path::new(name_or_path);
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError {
            origin: name_or_path.into(),
            line: None,
            message: format!(
                "cannot read the plant file: {e} (`{GENERATED}` runs a model generated from \
                 the arm)"
            ),
        })?;
        let dir = path.parent().unwrap_or(Path::new("."));
        Self::parse(&text, name_or_path, &absolute(dir))
    }

    /// Reads a plant file's `text`; its model's path starts at `dir`.
    pub fn parse(text: &str, origin: &str, dir: &Path) -> Result<Self, ConfigError> {
        let error = |line, message: String| ConfigError {
            origin: origin.into(),
            line,
            message,
        };
        let file: File = toml::from_str(text).map_err(|e| {
            error(
                e.span().map(|s| crate::line_at(text, s.start)),
                e.message().into(),
            )
        })?;
        let arm = match file.arm {
            None => None,
            Some(table) => {
                // As an arm file has it: the section's keys at the top.
                let text = toml::to_string(&table).map_err(|e| error(None, e.to_string()))?;
                let arm: ArmConfig = crate::arms::check(&text, origin)?;
                Some((text, arm))
            }
        };
        let mut mujoco = file.mujoco;
        mujoco.model = mujoco.model.map(|m| dir.join(m));
        let actuators = match &arm {
            Some((_, a)) => Some(a.layout().map_err(|m| error(None, m))?.actuators().len()),
            None => None,
        };
        // The map's count is checked against the arm the plant runs on, when it is known.
        mujoco
            .validate(actuators.unwrap_or(mujoco.actuators.len()))
            .map_err(|m| error(None, m.replacen("sim.mujoco.", "mujoco.", 1)))?;
        if let Some(model) = &mujoco.model
            && let Err(e) = std::fs::metadata(model)
        {
            let line = crate::key_line(text, "model");
            return Err(error(
                line,
                format!("mujoco.model: cannot read {}: {e}", model.display()),
            ));
        }
        Ok(Self {
            arm: arm.map(|(text, _)| text),
            mujoco,
            origin: origin.into(),
        })
    }

    /// Where it came from: its file, or `generated`.
    pub fn origin(&self) -> &str {
        &self.origin
    }

    /// `config` (a config's text) with this plant as its sim's: its `[arm]` in place of the
    /// config's (with the boxes its reach bounds), its `[sim.mujoco]`.
    pub fn into_config(&self, config: &str) -> Result<String, ConfigError> {
        let config = match &self.arm {
            Some(arm) => crate::arms::with_arm(config, arm, &self.origin)?,
            None => config.to_string(),
        };
        let mut doc: toml_edit::DocumentMut =
            config
                .parse()
                .map_err(|e: toml_edit::TomlError| ConfigError {
                    origin: "the config".into(),
                    line: None,
                    message: e.message().to_string(),
                })?;
        let table = toml::to_string(&self.mujoco).map_err(|e| ConfigError {
            origin: self.origin.clone(),
            line: None,
            message: e.to_string(),
        })?;
        let table: toml_edit::DocumentMut = table.parse().expect("toml writes toml");
        if doc.get("sim").is_none() {
            doc.insert("sim", toml_edit::table());
        }
        let mut table = table.as_table().clone();
        table.set_implicit(false);
        doc["sim"]["mujoco"] = toml_edit::Item::Table(table);
        Ok(doc.to_string())
    }
}

fn absolute(dir: &Path) -> PathBuf {
    std::path::absolute(dir).unwrap_or_else(|_| dir.to_path_buf())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plant_goes_into_a_config_with_its_arm_and_its_model_found_from_its_folder() {
        let dir = std::env::temp_dir().join(format!("softarm-plant-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("arm.xml"), "<mujoco/>").unwrap();
        let text = "[arm]\nmodules = [{ tendons = { count = 3, radius_m = 0.01, length_m = \
                    [0.09, 0.11] } }]\n[mujoco]\nmodel = \"arm.xml\"\ntip_site = \"tip\"\n";
        let plant = Plant::parse(text, "p.toml", &dir).unwrap();
        assert_eq!(
            plant.mujoco.model.as_deref(),
            Some(dir.join("arm.xml").as_path())
        );
        let config = plant.into_config(crate::DEFAULT).unwrap();
        let c = crate::Config::parse(&config, "test", dir.clone()).unwrap();
        assert_eq!(c.sim.mujoco.as_ref().unwrap().model, plant.mujoco.model);
        assert_eq!(c.layout().actuators().len(), 3);
        // A model that is not there is refused naming the key and the file.
        let e = Plant::parse(&text.replace("arm.xml", "gone.xml"), "p.toml", &dir).unwrap_err();
        assert!(
            e.message.starts_with("mujoco.model: cannot read") && e.message.contains("gone.xml"),
            "{e}"
        );
        // A map of another count than the arm's.
        let two = text.replace(
            "tip_site",
            "actuators = [{ name = \"a\" }, { name = \"b\" }]\ntip_site",
        );
        let e = Plant::parse(&two, "p.toml", &dir).unwrap_err();
        assert!(
            e.message.contains("2 actuators mapped for an arm of 3"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn generated_runs_the_configs_arm() {
        let plant = Plant::resolve(GENERATED).unwrap();
        assert!(plant.arm.is_none() && plant.mujoco.model.is_none());
        let config = plant.into_config(crate::DEFAULT).unwrap();
        let c = crate::Config::parse(&config, "test", ".".into()).unwrap();
        assert_eq!(c.sim.mujoco, Some(MujocoConfig::default()));
    }
}
