//! `[sim.mujoco]`: the sim's plant as a MuJoCo model instead of its own PCC kinematics, as
//! plain data with its validation. Either generated from `[arm]` (`generated`'s physical
//! values) or a lab's own MJCF (`model`) with a map onto the arm. The plant that runs it is
//! crate `softarm-mujoco`.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// The `[sim.mujoco]` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct MujocoConfig {
    /// A lab's MJCF file (relative paths start at the config file's folder); absent, the
    /// model is generated from `[arm]` with `generated`'s values.
    pub model: Option<PathBuf>,
    /// The site the tracker follows: the model's tip. A generated model's is `tip`, at the
    /// end of `[arm]`'s tool.
    pub tip_site: String,
    /// The tracked marker in the tip site's frame (m): where the tracker sees it.
    pub marker_m: [f64; 3],
    /// The keyframe the model starts from (a lab's model); absent, the model's first
    /// keyframe if it has one, else its rest.
    pub keyframe: Option<String>,
    /// Gravity in the model's world frame (m/s²); absent, the model's own (a generated model:
    /// 9.81 down, the world being the arm's base frame, `[arm] mount` deciding which way the
    /// arm points). `[0, 0, 0]` turns it off.
    pub gravity_m_s2: Option<[f64; 3]>,
    /// Where the model's world origin is in the arm's base frame (m), when the two differ.
    pub base_position_m: [f64; 3],
    /// The rotation that turns the model's world directions into the arm's base frame: about
    /// x, then y, then z of the base frame (degrees).
    pub base_rotation_deg: [f64; 3],
    /// Which actuator of the model is which of the arm, in the arm's order; empty: the model's
    /// actuators in its own order, one per actuator of the arm.
    pub actuators: Vec<MujocoActuator>,
    /// A load on the tip from a time of the plant's clock; none by default.
    pub load: Option<TipLoad>,
    /// The physical values of a model generated from `[arm]`.
    pub generated: Generated,
}

impl Default for MujocoConfig {
    fn default() -> Self {
        Self {
            model: None,
            tip_site: "tip".into(),
            marker_m: [0.0; 3],
            keyframe: None,
            gravity_m_s2: None,
            base_position_m: [0.0; 3],
            base_rotation_deg: [0.0; 3],
            actuators: Vec::new(),
            load: None,
            generated: Generated::default(),
        }
    }
}

/// One actuator of a lab's model, mapped onto the arm's actuator of the same place.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct MujocoActuator {
    /// The MJCF actuator's name.
    pub name: String,
    /// Its `ctrl` at normalised actuation 0 and 1; absent, the arm's actuator's length at 0
    /// and 1 (m), as for a position actuator on a tendon's length that the arm describes.
    #[serde(default)]
    pub ctrl: Option<[f64; 2]>,
}

/// A load at the tip: a force and a mass's weight, applied from `from_s` of the plant's time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TipLoad {
    /// When it is applied (s of the plant's clock, from the sim's start).
    #[serde(default)]
    pub from_s: f64,
    /// A force at the tip site (N, in the model's world frame).
    #[serde(default)]
    pub force_n: [f64; 3],
    /// A mass hung at the tip (kg): its weight under the model's gravity.
    #[serde(default)]
    pub mass_kg: f64,
}

/// What a model generated from `[arm]` is made of. The defaults make a plausible small arm:
/// a silicone-like soft module or a thin rod (EI as the OpenCR lab's identified model of its
/// TDCR), a few tens of grams per module, tendons as stiff as a short braided line (PCC's
/// lengths held: the servo some 25 times stiffer than a module's bending, per tendon).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Generated {
    /// Rigid links each module is cut into.
    pub links_per_module: usize,
    /// Bending stiffness EI of a soft module (N·m²).
    pub soft_bending_nm2: f64,
    /// Axial stiffness EA of a soft module (N): how hard it is to shorten or stretch.
    pub soft_axial_n: f64,
    /// Bending stiffness EI of a module with a fixed backbone (N·m²).
    pub backbone_bending_nm2: f64,
    /// Mass of each soft module (kg), spread over its links.
    pub module_mass_kg: f64,
    /// Mass of each module with a fixed backbone (kg): a thin rod and its discs, a few grams
    /// (the OpenCR lab's whole three-segment TDCR weighs 7 g).
    pub backbone_module_mass_kg: f64,
    /// Mass of the tool at the tip (kg).
    pub tool_mass_kg: f64,
    /// Damping of every joint, as a fraction of critical for the module's first mode.
    pub damping_ratio: f64,
    /// How stiffly an actuator holds its length (N/m): a position servo on the tendon's or
    /// chamber's length.
    pub actuator_stiffness_n_per_m: f64,
    /// The most a tendon pulls or a chamber pushes (N).
    pub max_force_n: f64,
}

impl Default for Generated {
    fn default() -> Self {
        Self {
            links_per_module: 10,
            soft_bending_nm2: 0.05,
            soft_axial_n: 200.0,
            backbone_bending_nm2: 0.0005,
            module_mass_kg: 0.05,
            backbone_module_mass_kg: 0.003,
            tool_mass_kg: 0.01,
            damping_ratio: 0.5,
            actuator_stiffness_n_per_m: 10000.0,
            max_force_n: 100.0,
        }
    }
}

fn finite(key: &str, v: &[f64]) -> Result<(), String> {
    match v.iter().find(|x| !x.is_finite()) {
        Some(x) => Err(format!("{key}: must be a number, got {x:?}")),
        None => Ok(()),
    }
}

fn positive(key: &str, v: f64, max: f64) -> Result<(), String> {
    if v.is_finite() && v > 0.0 && v <= max {
        Ok(())
    } else {
        Err(format!("{key}: must be in (0, {max}], got {v:?}"))
    }
}

impl MujocoConfig {
    /// Checks every field for an arm of `actuators`; the error is `sim.mujoco.KEY: message`.
    pub fn validate(&self, actuators: usize) -> Result<(), String> {
        let k = |key: &str| format!("sim.mujoco.{key}");
        if self.tip_site.trim().is_empty() {
            return Err(format!("{}: must name a site of the model", k("tip_site")));
        }
        finite(&k("marker_m"), &self.marker_m)?;
        finite(&k("base_position_m"), &self.base_position_m)?;
        finite(&k("base_rotation_deg"), &self.base_rotation_deg)?;
        if let Some(g) = self.gravity_m_s2 {
            finite(&k("gravity_m_s2"), &g)?;
        }
        if self.model.is_none() && !self.actuators.is_empty() {
            return Err(format!(
                "{}: a generated model's actuators are the arm's own; map actuators only with \
                 sim.mujoco.model",
                k("actuators")
            ));
        }
        if !self.actuators.is_empty() && self.actuators.len() != actuators {
            return Err(format!(
                "{}: {} actuators mapped for an arm of {actuators}; map each of the arm's, in \
                 its order",
                k("actuators"),
                self.actuators.len()
            ));
        }
        for (i, a) in self.actuators.iter().enumerate() {
            if a.name.trim().is_empty() {
                return Err(format!(
                    "{}[{i}].name: must name an actuator",
                    k("actuators")
                ));
            }
            if let Some(c) = a.ctrl {
                finite(&format!("{}[{i}].ctrl", k("actuators")), &c)?;
                if c[0] == c[1] {
                    return Err(format!(
                        "{}[{i}].ctrl: the same at 0 and 1 ({}): the actuator would not move",
                        k("actuators"),
                        c[0]
                    ));
                }
            }
        }
        if let Some(load) = &self.load {
            finite(&k("load.force_n"), &load.force_n)?;
            if !(load.from_s.is_finite() && load.from_s >= 0.0) {
                return Err(format!(
                    "{}: must be ≥ 0 s, got {:?}",
                    k("load.from_s"),
                    load.from_s
                ));
            }
            if !(load.mass_kg.is_finite() && (0.0..=10.0).contains(&load.mass_kg)) {
                return Err(format!(
                    "{}: must be in [0, 10] kg, got {:?}",
                    k("load.mass_kg"),
                    load.mass_kg
                ));
            }
        }
        self.generated.validate()
    }
}

impl Generated {
    pub fn validate(&self) -> Result<(), String> {
        let k = |key: &str| format!("sim.mujoco.generated.{key}");
        if !(2..=100).contains(&self.links_per_module) {
            return Err(format!(
                "{}: must be in [2, 100], got {}",
                k("links_per_module"),
                self.links_per_module
            ));
        }
        positive(&k("soft_bending_nm2"), self.soft_bending_nm2, 1e3)?;
        positive(&k("soft_axial_n"), self.soft_axial_n, 1e7)?;
        positive(&k("backbone_bending_nm2"), self.backbone_bending_nm2, 1e3)?;
        positive(&k("module_mass_kg"), self.module_mass_kg, 100.0)?;
        positive(
            &k("backbone_module_mass_kg"),
            self.backbone_module_mass_kg,
            100.0,
        )?;
        positive(&k("damping_ratio"), self.damping_ratio, 10.0)?;
        positive(
            &k("actuator_stiffness_n_per_m"),
            self.actuator_stiffness_n_per_m,
            1e7,
        )?;
        positive(&k("max_force_n"), self.max_force_n, 1e5)?;
        if !(self.tool_mass_kg.is_finite() && (0.0..=100.0).contains(&self.tool_mass_kg)) {
            return Err(format!(
                "{}: must be in [0, 100] kg, got {:?}",
                k("tool_mass_kg"),
                self.tool_mass_kg
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_defaults_are_valid_and_errors_name_the_full_key() {
        MujocoConfig::default().validate(6).unwrap();
        let mut c = MujocoConfig::default();
        c.generated.links_per_module = 1;
        assert!(
            c.validate(6)
                .unwrap_err()
                .starts_with("sim.mujoco.generated.links_per_module:")
        );
        let mut c = MujocoConfig {
            model: Some("arm.xml".into()),
            ..MujocoConfig::default()
        };
        c.actuators = vec![MujocoActuator {
            name: "t".into(),
            ctrl: None,
        }];
        let e = c.validate(6).unwrap_err();
        assert!(
            e.starts_with("sim.mujoco.actuators:") && e.contains("1 actuators mapped"),
            "{e}"
        );
        c.model = None;
        assert!(
            c.validate(1)
                .unwrap_err()
                .contains("only with sim.mujoco.model")
        );
        let c = MujocoConfig {
            load: Some(TipLoad {
                from_s: -1.0,
                force_n: [0.0; 3],
                mass_kg: 0.0,
            }),
            ..MujocoConfig::default()
        };
        assert!(
            c.validate(6)
                .unwrap_err()
                .starts_with("sim.mujoco.load.from_s:")
        );
    }
}
