//! The Foxglove layout for the configured arm: the shipped one (`config/foxglove/softarm.json`:
//! the scene, the error at each point, the actuation, the states, the status) with the
//! actuation plot drawing the arm's own actuators by their names. The error plot follows any
//! set as it is: `stats.errors_m` carries the set's points alone, so a point past them draws
//! nothing. Pure; `softarm view --layout FILE` writes it.

use serde_json::{Value, json};
use softarm_arm::{Layout, Mount};

/// The shipped layout, the template.
const SHIPPED: &str = include_str!("../../../config/foxglove/softarm.json");
/// The panel the arm's actuators are drawn in, and the scene's.
const ACTUATION: &str = "Plot!softarm-actuation";
const SCENE: &str = "3D!softarm-scene";

/// The layout for `arm`: the setpoint and the measured actuation of each of its actuators, by
/// name; the scene's camera and grid on a standing arm below and around it, not above (the
/// shipped framing is the hanging paper arm's).
pub fn for_arm(arm: &Layout) -> Value {
    let names: Vec<&str> = arm.names().collect();
    let mut layout = for_names(&names);
    if arm.mount == Mount::Standing {
        let length: f64 = arm
            .modules()
            .iter()
            .map(|m| {
                m.backbone_m.unwrap_or_else(|| {
                    arm.actuators()[m.actuators.clone()]
                        .iter()
                        .map(|a| a.max_m)
                        .fold(0.0, f64::max)
                })
            })
            .sum::<f64>()
            + arm.connector_m * (arm.modules().len() - 1) as f64
            + arm.tool_m;
        let scene = &mut layout["configById"][SCENE];
        scene["cameraState"]["targetOffset"] = json!([0, 0, round(0.5 * length)]);
        scene["cameraState"]["distance"] = json!(round((2.5 * length).max(0.2)));
        scene["layers"]["grid"]["position"] = json!([0, 0, 0]);
        scene["layers"]["grid"]["size"] = json!(round((2.0 * length).max(0.1)));
    }
    layout
}

fn round(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

/// The shipped layout with the actuation plot of actuators `names`, in the arm's order.
fn for_names(names: &[&str]) -> Value {
    let mut layout: Value = serde_json::from_str(SHIPPED).expect("the shipped layout is JSON");
    let series = |service: &str, what: &str| {
        names
            .iter()
            .enumerate()
            .map(|(i, name)| {
                json!({
                    "value": format!("{service}.actuation[{i}]"),
                    "enabled": true,
                    "timestampMethod": "receiveTime",
                    "label": format!("{what} {name}"),
                })
            })
            .collect::<Vec<_>>()
    };
    let mut paths = series("setpoint", "setpoint");
    paths.extend(series("motor_state", "measured"));
    layout["configById"][ACTUATION]["paths"] = Value::Array(paths);
    layout
}

#[cfg(test)]
mod tests {
    use super::*;

    fn labels(layout: &Value) -> Vec<String> {
        layout["configById"][ACTUATION]["paths"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| {
                format!(
                    "{} = {}",
                    p["label"].as_str().unwrap(),
                    p["value"].as_str().unwrap()
                )
            })
            .collect()
    }

    fn arm(file: &str) -> Layout {
        let text = softarm_config::arms::resolve(file).unwrap();
        let c: softarm_config::arm::ArmConfig = toml::from_str(&text).unwrap();
        c.layout().unwrap()
    }

    /// The shipped file is the layout of the paper's arm (`softarm view --layout` writes it),
    /// so the two stay one.
    #[test]
    fn the_shipped_layout_is_the_papers_arms() {
        let shipped: Value = serde_json::from_str(SHIPPED).unwrap();
        assert_eq!(
            for_arm(&arm("paper")),
            shipped,
            "regenerate config/foxglove/softarm.json with softarm view --layout"
        );
    }

    #[test]
    fn every_actuator_of_the_arm_is_drawn_by_its_name() {
        let got = labels(&for_arm(&arm("hybrid")));
        assert_eq!(got.len(), 16);
        assert_eq!(got[3], "setpoint p1 = setpoint.actuation[3]");
        assert_eq!(got[15], "measured p2 = motor_state.actuation[7]");
        let tdcr = for_arm(&arm("tdcr"));
        assert_eq!(labels(&tdcr).len(), 18);
        // Standing, 0.19 m tall: the grid at its base, the camera on its middle.
        let scene = &tdcr["configById"][SCENE];
        assert_eq!(scene["layers"]["grid"]["position"], json!([0, 0, 0]));
        assert_eq!(scene["cameraState"]["targetOffset"], json!([0, 0, 0.095]));
    }
}
