//! `[arm]`: the arm the config describes ([`ArmConfig`]: any arm, as modules from the base, or
//! the paper's arm by its shorthand keys, which are read as its two modules), as plain data
//! with its validation. The kinematics on it are `softarm_kinematics::pcc::Arm`.

use serde::{Deserialize, Serialize};

use softarm_arm::{Description, Group, Layout, MAX_LENGTH_M, MAX_RADIUS_M, ModuleDescription};
pub use softarm_arm::{Mount, Routing};

/// Largest actuator length offset (m), either way: `actuator_offset_m`, and what a drift's
/// creep adds to it.
pub const MAX_OFFSET_M: f64 = 0.05;

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
    pub module_rotation_deg: Option<[f64; SHORTHAND_MODULES]>,
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
/// The modules the shorthand keys make: the paper's two, of three tendons each.
pub const SHORTHAND_MODULES: usize = 2;
const SHORTHAND_TENDONS: usize = 3;
/// What an absent key is: the paper's arm.
const DEFAULT_RADIUS_M: f64 = 0.025;
const DEFAULT_STROKE_M: [f64; 2] = [0.19, 0.25];
const DEFAULT_ROTATION_DEG: [f64; SHORTHAND_MODULES] = [0.0, 60.0];
const DEFAULT_CONNECTOR_M: f64 = 0.03;
const DEFAULT_TOOL_M: f64 = 0.03;

impl ArmConfig {
    /// The arm as a description: `modules` as written, or the shorthand's two modules of
    /// three evenly spaced tendons, ending in their module, named `a1`..`a6`.
    pub fn description(&self) -> Description {
        let modules = match &self.modules {
            Some(modules) => modules.clone(),
            None => {
                let tendons = Group {
                    count: SHORTHAND_TENDONS,
                    radius_m: self.actuator_radius_m.unwrap_or(DEFAULT_RADIUS_M),
                    angles_deg: None,
                    length_m: self.stroke_m(),
                    names: None,
                };
                let rotation = self.module_rotation_deg.unwrap_or(DEFAULT_ROTATION_DEG);
                rotation
                    .map(|rotation_deg| ModuleDescription {
                        rotation_deg,
                        backbone_m: None,
                        tendons: Some(tendons.clone()),
                        chambers: None,
                    })
                    .to_vec()
            }
        };
        Description {
            mount: self.mount.unwrap_or(Mount::Hanging),
            routing: self.routing.unwrap_or_default(),
            connector_m: self.connector_m.unwrap_or(DEFAULT_CONNECTOR_M),
            tool_m: self.tool_m.unwrap_or(DEFAULT_TOOL_M),
            modules,
        }
    }

    /// The shorthand's stroke: each tendon's length at actuation 0 and 1 (m).
    fn stroke_m(&self) -> [f64; 2] {
        [
            self.actuator_min_m.unwrap_or(DEFAULT_STROKE_M[0]),
            self.actuator_max_m.unwrap_or(DEFAULT_STROKE_M[1]),
        ]
    }

    /// This arm written by the shorthand keys, every one of them set, if they can write it:
    /// the paper's kind of arm (two soft modules of three tendons at 0°, 120° and 240° from the
    /// module's rotation, of one radius and stroke, named by place, ending in their module).
    /// What a scenario's shorthand keys are set on. `None` for any other arm.
    pub fn shorthand(&self) -> Option<ArmConfig> {
        let d = self.description();
        let (radius_m, stroke_m) = match &self.modules {
            None => (
                self.actuator_radius_m.unwrap_or(DEFAULT_RADIUS_M),
                self.stroke_m(),
            ),
            Some(modules) => {
                let first = modules.first()?.tendons.as_ref()?;
                let paper_kind = |m: &ModuleDescription| {
                    m.backbone_m.is_none()
                        && m.chambers.is_none()
                        && m.tendons.as_ref().is_some_and(|t| {
                            t.count == SHORTHAND_TENDONS
                                && t.names.is_none()
                                && t.radius_m == first.radius_m
                                && t.length_m == first.length_m
                                && t.angles_deg
                                    .as_ref()
                                    .is_none_or(|a| a.as_slice() == [0.0, 120.0, 240.0])
                        })
                };
                let independent = d.routing == Routing::Independent;
                if modules.len() != SHORTHAND_MODULES
                    || !independent
                    || !modules.iter().all(paper_kind)
                {
                    return None;
                }
                (first.radius_m, first.length_m)
            }
        };
        Some(ArmConfig {
            modules: None,
            routing: None,
            actuator_radius_m: Some(radius_m),
            actuator_min_m: Some(stroke_m[0]),
            actuator_max_m: Some(stroke_m[1]),
            module_rotation_deg: Some([d.modules[0].rotation_deg, d.modules[1].rotation_deg]),
            connector_m: Some(d.connector_m),
            tool_m: Some(d.tool_m),
            mount: Some(d.mount),
            actuator_offset_m: Some(
                (self.actuator_offset_m.clone())
                    .unwrap_or_else(|| vec![0.0; SHORTHAND_MODULES * SHORTHAND_TENDONS]),
            ),
        })
    }

    /// The checked arm. Call after [`ArmConfig::validate`]; an arm it refused gives the error.
    pub fn layout(&self) -> Result<Layout, String> {
        Layout::new(&self.description()).map_err(|e| e.to_string())
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
            self.validate_shorthand()?;
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
            let o = MAX_OFFSET_M;
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

    /// The shorthand keys' values, and the lengths both forms share, over the paper's
    /// defaults; the error is `arm.KEY: message`.
    fn validate_shorthand(&self) -> Result<(), String> {
        let [min_m, max_m] = self.stroke_m();
        let positive = [
            (
                "actuator_radius_m",
                self.actuator_radius_m.unwrap_or(DEFAULT_RADIUS_M),
                MAX_RADIUS_M,
            ),
            ("actuator_min_m", min_m, MAX_LENGTH_M),
            ("actuator_max_m", max_m, MAX_LENGTH_M),
        ];
        for (key, v, max) in positive {
            if !(v.is_finite() && v > 0.0 && v <= max) {
                return Err(format!(
                    "arm.{key}: must be a length in (0, {max}] m, got {v:?}"
                ));
            }
        }
        let fixed = [
            (
                "connector_m",
                self.connector_m.unwrap_or(DEFAULT_CONNECTOR_M),
            ),
            ("tool_m", self.tool_m.unwrap_or(DEFAULT_TOOL_M)),
        ];
        for (key, v) in fixed {
            if !(v.is_finite() && (0.0..=MAX_LENGTH_M).contains(&v)) {
                return Err(format!(
                    "arm.{key}: must be a length in [0, {MAX_LENGTH_M}] m, got {v:?}"
                ));
            }
        }
        if max_m <= min_m {
            return Err(format!(
                "arm.actuator_max_m: {max_m} m must exceed actuator_min_m = {min_m} m"
            ));
        }
        let rotation = self.module_rotation_deg.unwrap_or(DEFAULT_ROTATION_DEG);
        for (m, v) in rotation.iter().enumerate() {
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

    /// The shorthand's arm is the paper's arm as its description says it.
    #[test]
    fn the_shorthand_is_the_papers_layout() {
        let text = include_str!("../../../contract/arm/testdata/paper.toml");
        let paper = Layout::new(&toml::from_str(text).unwrap()).unwrap();
        assert_eq!(ArmConfig::default().layout().unwrap(), paper);
    }

    /// The paper's arm written by its modules is the shorthand's arm; any other arm has no
    /// shorthand.
    #[test]
    fn the_shorthand_writes_the_papers_kind_of_arm_alone() {
        let modules = |text: &str| ArmConfig {
            modules: Some(toml::from_str::<Description>(text).unwrap().modules),
            ..ArmConfig::default()
        };
        let paper = modules(include_str!("../../../contract/arm/testdata/paper.toml"));
        let shorthand = paper.shorthand().unwrap();
        assert_eq!(shorthand, ArmConfig::default().shorthand().unwrap());
        assert_eq!(shorthand.layout(), paper.layout());
        assert_eq!(shorthand.shorthand().unwrap(), shorthand);
        let tdcr = modules(include_str!("../../../contract/arm/testdata/tdcr.toml"));
        assert_eq!(tdcr.shorthand(), None);
        // Two modules of three tendons at other angles: not the paper's kind.
        let mut turned = paper.clone();
        let tendons = turned.modules.as_mut().unwrap()[1]
            .tendons
            .as_mut()
            .unwrap();
        tendons.angles_deg = Some(vec![0.0, 90.0, 240.0]);
        assert_eq!(turned.shorthand(), None);
    }

    #[test]
    fn bad_shorthand_names_the_key() {
        let arm = ArmConfig {
            actuator_max_m: Some(0.1),
            ..Default::default()
        };
        assert!(arm.validate().unwrap_err().contains("arm.actuator_max_m"));
        let arm = ArmConfig {
            actuator_radius_m: Some(f64::NAN),
            ..Default::default()
        };
        assert!(
            arm.validate()
                .unwrap_err()
                .contains("arm.actuator_radius_m")
        );
        assert!(ArmConfig::default().validate().is_ok());
    }

    #[test]
    fn every_length_and_angle_is_bounded() {
        let check = |arm: ArmConfig, want: &str| {
            let e = arm.validate().unwrap_err();
            assert!(e.starts_with(want), "{e} (wanted {want:?})");
        };
        let d = ArmConfig::default;
        check(
            ArmConfig {
                module_rotation_deg: Some([0.0, f64::NAN]),
                ..d()
            },
            "arm.module_rotation_deg: module 2 is NaN; each must be in [-360, 360] degrees",
        );
        check(
            ArmConfig {
                module_rotation_deg: Some([1e300, 0.0]),
                ..d()
            },
            "arm.module_rotation_deg: module 1 is 1e300",
        );
        check(
            ArmConfig {
                actuator_max_m: Some(1e300),
                ..d()
            },
            "arm.actuator_max_m: must be a length in (0, 10] m",
        );
        check(
            ArmConfig {
                actuator_radius_m: Some(2.0),
                ..d()
            },
            "arm.actuator_radius_m: must be a length in (0, 1] m",
        );
        check(
            ArmConfig {
                tool_m: Some(f64::INFINITY),
                ..d()
            },
            "arm.tool_m: must be a length in [0, 10] m",
        );
        check(
            ArmConfig {
                actuator_max_m: Some(0.1),
                ..d()
            },
            "arm.actuator_max_m: 0.1 m must exceed actuator_min_m = 0.19 m",
        );
        check(
            ArmConfig {
                actuator_offset_m: Some(vec![0.0, 0.0, 0.0, 0.0, 0.06, 0.0]),
                ..d()
            },
            "arm.actuator_offset_m: actuator 5 is 0.06; each must be in [-0.05, 0.05] m",
        );
    }
}
