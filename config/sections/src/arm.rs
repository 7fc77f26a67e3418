//! `[arm]`: the arm the config describes ([`ArmConfig`]: any arm, as modules from the base, or
//! the paper's arm by its shorthand keys) and the paper's arm's geometry ([`ArmGeometry`]), as
//! plain data with their validation. The kinematics on them are
//! `softarm_kinematics::pcc::Kinematics`.

use serde::{Deserialize, Serialize};

use softarm_arm::{Description, Group, Layout, ModuleDescription};
pub use softarm_arm::{Mount, Routing};
pub use softarm_space::ACTUATORS;

/// The `[arm]` section: the arm, either as `[[arm.modules]]` (any arm: modules from the base,
/// each with its tendons and chambers) or, without `modules`, the paper's two soft modules of
/// three tendons by the shorthand keys (`actuator_radius_m`, `actuator_min_m`,
/// `actuator_max_m`, `module_rotation_deg`). `connector_m`, `tool_m`, `mount` and
/// `actuator_offset_m` belong to both forms.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ArmConfig {
    /// The modules, from the base (absent: the paper's arm of the shorthand keys). Each has
    /// `rotation_deg`, an optional `backbone_m` (a fixed backbone, as a TDCR's rod), and
    /// `tendons` and/or `chambers`: `{ count, radius_m, angles_deg, length_m = [at 0, at 1],
    /// names }` (angles evenly spaced and names `a1`..`aN` when absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modules: Option<Vec<ModuleDescription>>,
    /// Where a distal module's tendons run: "independent" (each ends in its own module) or
    /// "coupled" (through every module before it). With `modules` only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub routing: Option<Routing>,
    /// Shorthand: distance of each actuator from the backbone (m); 0.025 when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub actuator_radius_m: Option<f64>,
    /// Shorthand: actuator length at normalised actuation 0 (m); 0.19 when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub actuator_min_m: Option<f64>,
    /// Shorthand: actuator length at normalised actuation 1 (m); 0.25 when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub actuator_max_m: Option<f64>,
    /// Shorthand: ψ of each module, the angle of its actuator 1 (degrees); [0, 60] when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub module_rotation_deg: Option<[f64; MODULES]>,
    /// Rigid connector between consecutive modules (m); 0.03 when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub connector_m: Option<f64>,
    /// Rigid tool after the last module, to the point the tracker sees (m); 0.03 when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool_m: Option<f64>,
    /// "hanging" (the arm points down, −Z) or "standing" (+Z); hanging when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mount: Option<Mount>,
    /// Added to each actuator's length (m), one per actuator in the arm's order: tendon
    /// creep, a module that is not quite the one the model was trained on. Zeros when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub actuator_offset_m: Option<Vec<f64>>,
}

/// The shorthand keys, which describe the paper's arm alone.
const SHORTHAND: [&str; 4] = [
    "actuator_radius_m",
    "actuator_min_m",
    "actuator_max_m",
    "module_rotation_deg",
];

impl ArmConfig {
    /// The arm as a description: `modules` as written, or the shorthand's two modules.
    pub fn description(&self) -> Description {
        let d = ArmGeometry::default();
        match &self.modules {
            Some(modules) => Description {
                mount: self.mount.unwrap_or(d.mount),
                routing: self.routing.unwrap_or_default(),
                connector_m: self.connector_m.unwrap_or(d.connector_m),
                tool_m: self.tool_m.unwrap_or(d.tool_m),
                modules: modules.clone(),
            },
            None => self.shorthand_geometry().description(),
        }
    }

    /// The shorthand keys over the paper's defaults (offsets left at zero).
    fn shorthand_geometry(&self) -> ArmGeometry {
        let d = ArmGeometry::default();
        ArmGeometry {
            actuator_radius_m: self.actuator_radius_m.unwrap_or(d.actuator_radius_m),
            actuator_min_m: self.actuator_min_m.unwrap_or(d.actuator_min_m),
            actuator_max_m: self.actuator_max_m.unwrap_or(d.actuator_max_m),
            module_rotation_deg: self.module_rotation_deg.unwrap_or(d.module_rotation_deg),
            connector_m: self.connector_m.unwrap_or(d.connector_m),
            tool_m: self.tool_m.unwrap_or(d.tool_m),
            mount: self.mount.unwrap_or(d.mount),
            actuator_offset_m: [0.0; ACTUATORS],
        }
    }

    /// The checked arm. Call after [`ArmConfig::validate`]; an arm it refused gives the error.
    pub fn layout(&self) -> Result<Layout, String> {
        Layout::new(&self.description()).map_err(|e| e.to_string())
    }

    /// The arm as the paper's geometry, if it is the paper's kind of arm: two soft modules
    /// (no fixed backbone) of three evenly spaced tendons each, of one radius and one length
    /// range, ending in their module, named by place. `None` for any other arm.
    pub fn geometry(&self) -> Option<ArmGeometry> {
        let offsets = self.offsets()?;
        let mut g = match &self.modules {
            None => self.shorthand_geometry(),
            Some(modules) => {
                let d = self.description();
                let first = modules.first()?.tendons.as_ref()?;
                let paper_kind = |m: &ModuleDescription| {
                    m.backbone_m.is_none()
                        && m.chambers.is_none()
                        && m.tendons.as_ref().is_some_and(|t| {
                            t.count == 3
                                && t.names.is_none()
                                && t.radius_m == first.radius_m
                                && t.length_m == first.length_m
                                && t.angles_deg
                                    .as_ref()
                                    .is_none_or(|a| a.as_slice() == [0.0, 120.0, 240.0])
                        })
                };
                let independent = self.routing.unwrap_or_default() == Routing::Independent;
                if modules.len() != MODULES || !independent || !modules.iter().all(paper_kind) {
                    return None;
                }
                ArmGeometry {
                    actuator_radius_m: first.radius_m,
                    actuator_min_m: first.length_m[0],
                    actuator_max_m: first.length_m[1],
                    module_rotation_deg: [modules[0].rotation_deg, modules[1].rotation_deg],
                    connector_m: d.connector_m,
                    tool_m: d.tool_m,
                    mount: d.mount,
                    actuator_offset_m: [0.0; ACTUATORS],
                }
            }
        };
        g.actuator_offset_m = offsets;
        Some(g)
    }

    /// `actuator_offset_m` as the paper's six, if it has six (or is absent).
    fn offsets(&self) -> Option<[f64; ACTUATORS]> {
        match &self.actuator_offset_m {
            None => Some([0.0; ACTUATORS]),
            Some(v) => v.as_slice().try_into().ok(),
        }
    }

    /// Checks the section; the error is `arm.KEY: message`, naming what would be valid.
    pub fn validate(&self) -> Result<(), String> {
        if self.modules.is_some() {
            let given = [
                self.actuator_radius_m.is_some(),
                self.actuator_min_m.is_some(),
                self.actuator_max_m.is_some(),
                self.module_rotation_deg.is_some(),
            ];
            if let Some(k) = given.iter().position(|g| *g) {
                return Err(format!(
                    "arm.{}: a shorthand key of the paper's arm, which `arm.modules` replaces: \
                     give each module's radius, lengths and rotation in its `tendons` and \
                     `rotation_deg`, or drop `modules`",
                    SHORTHAND[k]
                ));
            }
        } else if self.routing.is_some() {
            return Err(
                "arm.routing: with `arm.modules` only (the paper's arm of the shorthand keys \
                 has independent routing)"
                    .into(),
            );
        }
        if self.modules.is_none() {
            // Named by the keys written, not by the modules they make.
            self.shorthand_geometry().validate()?;
        }
        let layout = Layout::new(&self.description()).map_err(|e| e.to_string())?;
        if let Some(v) = &self.actuator_offset_m {
            let n = layout.actuators().len();
            if v.len() != n {
                return Err(format!(
                    "arm.actuator_offset_m: {} values for an arm of {n} actuators; give one \
                     per actuator, in the arm's order",
                    v.len()
                ));
            }
            let o = ArmGeometry::MAX_OFFSET_M;
            for (i, v) in v.iter().enumerate() {
                if !(v.is_finite() && (-o..=o).contains(v)) {
                    return Err(format!(
                        "arm.actuator_offset_m: actuator {} is {v:?}; each must be in \
                         [-{o}, {o}] m",
                        i + 1
                    ));
                }
            }
        }
        Ok(())
    }
}

/// Actuators per module and modules per arm.
pub const ACTUATORS_PER_MODULE: usize = 3;
pub const MODULES: usize = 2;
const _: () = assert!(ACTUATORS == ACTUATORS_PER_MODULE * MODULES);

/// The paper's arm's geometry: what `[arm]`'s shorthand keys describe ([`ArmConfig::geometry`]),
/// what the controller and the learner compute for, and what scenarios change. Defaults: two
/// modules, actuator radius 25 mm, actuator length 0.19–0.25 m, second module rotated 60°,
/// hanging base.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ArmGeometry {
    /// Distance of each actuator from the backbone (m).
    pub actuator_radius_m: f64,
    /// Actuator length at normalised actuation 0 (m).
    pub actuator_min_m: f64,
    /// Actuator length at normalised actuation 1 (m).
    pub actuator_max_m: f64,
    /// ψ of each module: the angle of its actuator 1 (degrees).
    pub module_rotation_deg: [f64; MODULES],
    /// Rigid connector between the modules (m).
    pub connector_m: f64,
    /// Rigid tool after the second module (m).
    pub tool_m: f64,
    pub mount: Mount,
    /// Added to each actuator's length (m): tendon creep, a module that is not quite the one
    /// the model was trained on. Zero on the nominal arm.
    pub actuator_offset_m: [f64; ACTUATORS],
}

impl Default for ArmGeometry {
    fn default() -> Self {
        Self {
            actuator_radius_m: 0.025,
            actuator_min_m: 0.19,
            actuator_max_m: 0.25,
            module_rotation_deg: [0.0, 60.0],
            connector_m: 0.03,
            tool_m: 0.03,
            mount: Mount::Hanging,
            actuator_offset_m: [0.0; ACTUATORS],
        }
    }
}

impl ArmGeometry {
    /// The arm as a layout: two soft modules of three tendons each, evenly spaced from the
    /// module's rotation, ending in their module, named `a1`..`a6`.
    pub fn layout(&self) -> Layout {
        Layout::new(&self.description())
            .expect("a valid geometry is two modules that bend every way")
    }

    /// The arm as a description: two modules of three tendons, evenly spaced.
    pub fn description(&self) -> Description {
        let module = |rotation_deg| ModuleDescription {
            rotation_deg,
            backbone_m: None,
            tendons: Some(Group {
                count: ACTUATORS_PER_MODULE,
                radius_m: self.actuator_radius_m,
                angles_deg: None,
                length_m: [self.actuator_min_m, self.actuator_max_m],
                names: None,
            }),
            chambers: None,
        };
        Description {
            mount: self.mount,
            routing: Routing::Independent,
            connector_m: self.connector_m,
            tool_m: self.tool_m,
            modules: self.module_rotation_deg.map(module).to_vec(),
        }
    }

    /// Longest length of the geometry (m): actuators, connector and tool.
    pub const MAX_LENGTH_M: f64 = 10.0;
    /// Largest actuator length offset (m), either way.
    pub const MAX_OFFSET_M: f64 = 0.05;
    /// Largest actuator radius (m).
    pub const MAX_RADIUS_M: f64 = 1.0;

    /// Checks the geometry; the error is `arm.KEY: message`.
    pub fn validate(&self) -> Result<(), String> {
        let max = Self::MAX_LENGTH_M;
        let r = Self::MAX_RADIUS_M;
        let positive = [
            ("actuator_radius_m", self.actuator_radius_m, r),
            ("actuator_min_m", self.actuator_min_m, max),
            ("actuator_max_m", self.actuator_max_m, max),
        ];
        for (key, v, max) in positive {
            if !(v.is_finite() && v > 0.0 && v <= max) {
                return Err(format!(
                    "arm.{key}: must be a length in (0, {max}] m, got {v:?}"
                ));
            }
        }
        for (key, v) in [("connector_m", self.connector_m), ("tool_m", self.tool_m)] {
            if !(v.is_finite() && (0.0..=max).contains(&v)) {
                return Err(format!(
                    "arm.{key}: must be a length in [0, {max}] m, got {v:?}"
                ));
            }
        }
        if self.actuator_max_m <= self.actuator_min_m {
            return Err(format!(
                "arm.actuator_max_m: {} m must exceed actuator_min_m = {} m",
                self.actuator_max_m, self.actuator_min_m
            ));
        }
        let o = Self::MAX_OFFSET_M;
        for (i, v) in self.actuator_offset_m.iter().enumerate() {
            if !(v.is_finite() && (-o..=o).contains(v)) {
                return Err(format!(
                    "arm.actuator_offset_m: actuator {} is {v:?}; each must be in [-{o}, {o}] m",
                    i + 1
                ));
            }
        }
        for (m, v) in self.module_rotation_deg.iter().enumerate() {
            if !(v.is_finite() && (-360.0..=360.0).contains(v)) {
                return Err(format!(
                    "arm.module_rotation_deg: module {} is {v:?}; each must be in [-360, 360] degrees",
                    m + 1
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The geometry's layout is the paper's arm as its description says it.
    #[test]
    fn the_geometry_is_the_papers_layout() {
        let text = include_str!("../../../contract/arm/testdata/paper.toml");
        let paper = Layout::new(&toml::from_str(text).unwrap()).unwrap();
        assert_eq!(ArmGeometry::default().layout(), paper);
    }

    #[test]
    fn bad_geometry_names_the_key() {
        let arm = ArmGeometry {
            actuator_max_m: 0.1,
            ..Default::default()
        };
        assert!(arm.validate().unwrap_err().contains("arm.actuator_max_m"));
        let arm = ArmGeometry {
            actuator_radius_m: f64::NAN,
            ..Default::default()
        };
        assert!(
            arm.validate()
                .unwrap_err()
                .contains("arm.actuator_radius_m")
        );
        assert!(ArmGeometry::default().validate().is_ok());
    }

    #[test]
    fn every_length_and_angle_is_bounded() {
        let check = |arm: ArmGeometry, want: &str| {
            let e = arm.validate().unwrap_err();
            assert!(e.starts_with(want), "{e} (wanted {want:?})");
        };
        let d = ArmGeometry::default();
        check(
            ArmGeometry {
                module_rotation_deg: [0.0, f64::NAN],
                ..d
            },
            "arm.module_rotation_deg: module 2 is NaN; each must be in [-360, 360] degrees",
        );
        check(
            ArmGeometry {
                module_rotation_deg: [1e300, 0.0],
                ..d
            },
            "arm.module_rotation_deg: module 1 is 1e300",
        );
        check(
            ArmGeometry {
                actuator_max_m: 1e300,
                ..d
            },
            "arm.actuator_max_m: must be a length in (0, 10] m",
        );
        check(
            ArmGeometry {
                actuator_radius_m: 2.0,
                ..d
            },
            "arm.actuator_radius_m: must be a length in (0, 1] m",
        );
        check(
            ArmGeometry {
                tool_m: f64::INFINITY,
                ..d
            },
            "arm.tool_m: must be a length in [0, 10] m",
        );
        check(
            ArmGeometry {
                actuator_max_m: 0.1,
                ..d
            },
            "arm.actuator_max_m: 0.1 m must exceed actuator_min_m = 0.19 m",
        );
    }
}
