//! `[arm]`: the arm's geometry, as plain data with its validation. The kinematics on it are
//! `softarm_kinematics::pcc::Kinematics`.

use serde::{Deserialize, Serialize};

pub use softarm_arm::Mount;
use softarm_arm::{Description, Group, Layout, ModuleDescription, Routing};
pub use softarm_space::ACTUATORS;

/// Actuators per module and modules per arm.
pub const ACTUATORS_PER_MODULE: usize = 3;
pub const MODULES: usize = 2;
const _: () = assert!(ACTUATORS == ACTUATORS_PER_MODULE * MODULES);

/// The arm's geometry; the `[arm]` section of the config. Defaults: two modules,
/// actuator radius 25 mm, actuator length 0.19–0.25 m, second module rotated 60°, hanging base.
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
        let d = Description {
            mount: self.mount,
            routing: Routing::Independent,
            connector_m: self.connector_m,
            tool_m: self.tool_m,
            modules: self.module_rotation_deg.map(module).to_vec(),
        };
        Layout::new(&d).expect("a valid geometry is two modules that bend every way")
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
        let text = include_str!("../../../../ipc/arm/testdata/paper.toml");
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
