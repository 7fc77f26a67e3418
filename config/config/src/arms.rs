//! The shipped arms (`config/arms/`), each an `[arm]` section on its own, and putting an arm
//! file into a config: what `--arm NAME|FILE` reads.

use std::path::Path;

use crate::arm::ArmConfig;
use crate::{Config, ConfigError};

/// The shipped arms by name, each an `[arm]` section's text.
pub const SHIPPED: [(&str, &str); 3] = [
    ("paper", include_str!("../../../config/arms/paper.toml")),
    ("hybrid", include_str!("../../../config/arms/hybrid.toml")),
    ("tdcr", include_str!("../../../config/arms/tdcr.toml")),
];

/// An arm file's text: `name_or_path` a file, else a shipped arm's name.
pub fn resolve(name_or_path: &str) -> Result<String, ConfigError> {
    let path = Path::new(name_or_path);
    if path.is_file() {
        return std::fs::read_to_string(path).map_err(|e| ConfigError {
            origin: name_or_path.into(),
            line: None,
            message: format!("cannot read the arm file: {e}"),
        });
    }
    match SHIPPED.iter().find(|(name, _)| *name == name_or_path) {
        Some((_, text)) => Ok(text.to_string()),
        None => Err(ConfigError {
            origin: name_or_path.into(),
            line: None,
            message: format!(
                "no such arm file, nor a shipped arm; the shipped ones are {}",
                SHIPPED.map(|(n, _)| n).join(", ")
            ),
        }),
    }
}

/// Checks an arm file on its own: the error names its line and key (`arm.KEY`, as in a config).
pub fn check(arm: &str, origin: &str) -> Result<ArmConfig, ConfigError> {
    let a: ArmConfig = toml::from_str(arm).map_err(|e| ConfigError {
        origin: origin.into(),
        line: e.span().map(|s| crate::line_at(arm, s.start)),
        message: format!("arm: {}", e.message()),
    })?;
    a.validate().map_err(|m| {
        let key = m.split_once(": ").map_or("", |(k, _)| k);
        ConfigError {
            origin: origin.into(),
            line: crate::key_line(arm, key.strip_prefix("arm.").unwrap_or(key)),
            message: m.clone(),
        }
    })?;
    Ok(a)
}

/// `config` (a config file's text) with its `[arm]` section replaced by `arm` (an arm file's
/// text, checked by [`check`], `origin` naming it). Comments and layout of the rest survive.
/// Another arm than the config's brings its own boxes: where way-points may lie
/// (`waypoints.workspace_*`, `waypoints.reach_m`) and what the learner's lattices span
/// (`learner.workspace_*`) become the cube around the mount the arm's reach bounds
/// ([`reach_box`]); the same arm keeps the config's. The result is checked when it is
/// parsed: an arm that does not fit the rest (a list of another length) is refused there,
/// naming the key.
pub fn with_arm(config: &str, arm: &str, origin: &str) -> Result<String, ConfigError> {
    let new = check(arm, origin)?;
    let table: toml_edit::DocumentMut =
        arm.parse().map_err(|e: toml_edit::TomlError| ConfigError {
            origin: origin.into(),
            line: e.span().map(|s| crate::line_at(arm, s.start)),
            message: e.message().to_string(),
        })?;
    let mut doc: toml_edit::DocumentMut =
        config
            .parse()
            .map_err(|e: toml_edit::TomlError| ConfigError {
                origin: "the config".into(),
                line: e.span().map(|s| crate::line_at(config, s.start)),
                message: e.message().to_string(),
            })?;
    let old: Option<ArmConfig> = doc
        .get("arm")
        .and_then(|a| toml::from_str(&a.to_string()).ok());
    let same = old
        .and_then(|o| o.layout().ok())
        .is_some_and(|o| Ok(o) == new.layout());
    if !same {
        let reach = reach_box(&new.layout().expect("checked"));
        for (section, keys) in [
            (
                "waypoints",
                &["workspace_min_m", "workspace_max_m", "reach_m"][..],
            ),
            ("learner", &["workspace_min_m", "workspace_max_m"][..]),
        ] {
            if doc.get(section).is_none() {
                doc.insert(section, toml_edit::table());
            }
            for key in keys {
                let v = match *key {
                    "workspace_min_m" => toml_edit::value(toml_edit::Array::from_iter([-reach; 3])),
                    "workspace_max_m" => toml_edit::value(toml_edit::Array::from_iter([reach; 3])),
                    _ => toml_edit::value(reach),
                };
                doc[section][key] = v;
            }
        }
    }
    let mut table = table.as_table().clone();
    table.set_implicit(false);
    doc.insert("arm", toml_edit::Item::Table(table));
    Ok(doc.to_string())
}

/// `loaded` (the config read from `path`, `None`: the embedded one) with `arm`'s arm in it (a
/// shipped arm's name or an arm file) and the boxes its reach bounds, as [`with_arm`] puts it;
/// the config's text read again and parsed, its state folder and namespace kept as loaded.
pub fn into_config(loaded: Config, arm: &str, path: Option<&Path>) -> anyhow::Result<Config> {
    let (text, origin) = match path {
        Some(p) => (std::fs::read_to_string(p)?, p.display().to_string()),
        None => (crate::DEFAULT.to_string(), "embedded default config".into()),
    };
    let text = with_arm(&text, &resolve(arm)?, arm)?;
    let mut c = Config::parse(&text, &origin, loaded.base_dir.clone())?;
    c.state.dir = loaded.state.dir;
    c.robot.namespace = loaded.robot.namespace;
    Ok(c)
}

/// The half-width (m) of the cube around the mount that holds everything `arm` can reach: its
/// reach ([`softarm_arm::Layout::reach_m`]), rounded up to the millimetre.
pub fn reach_box(arm: &softarm_arm::Layout) -> f64 {
    (arm.reach_m() * 1e3).ceil() / 1e3
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each shipped arm in the embedded config: valid, its counts and kinds as it says, and
    /// only the paper's written by the shorthand keys.
    #[test]
    fn every_shipped_arm_loads_into_the_default_config() {
        let want = [
            ("paper", 6, 2, true),
            ("hybrid", 8, 2, false),
            ("tdcr", 9, 3, false),
        ];
        for ((name, text), (n, actuators, modules, paper)) in SHIPPED.iter().zip(want) {
            assert_eq!(*name, n);
            let merged = with_arm(crate::DEFAULT, text, name).unwrap();
            let c = Config::parse(&merged, name, ".".into()).unwrap();
            let layout = c.layout();
            assert_eq!(layout.actuators().len(), actuators, "{name}");
            assert_eq!(layout.modules().len(), modules, "{name}");
            assert_eq!(c.arm.shorthand().is_some(), paper, "{name}");
            assert_eq!(layout.is_papers_kind(), paper, "{name}");
            assert_eq!(resolve(name).unwrap(), *text);
        }
        // The paper's arm as modules is the shorthand's arm: the same identity and layout, and
        // the same shorthand.
        let d = Config::default_sim(".".into());
        let merged = with_arm(crate::DEFAULT, SHIPPED[0].1, "paper").unwrap();
        let p = Config::parse(&merged, "paper", ".".into()).unwrap();
        assert_eq!(p.arm_identity(), d.arm_identity());
        assert_eq!(p.layout(), d.layout());
        assert_eq!(p.arm.shorthand(), d.arm.shorthand());
        assert!(
            resolve("no-such-arm")
                .unwrap_err()
                .message
                .contains("paper, hybrid, tdcr")
        );
    }

    /// Another arm brings the boxes its reach bounds; the config's own arm keeps the config's.
    #[test]
    fn another_arm_brings_its_boxes_and_the_same_arm_keeps_the_configs() {
        let d = Config::default_sim(".".into());
        let paper = with_arm(crate::DEFAULT, SHIPPED[0].1, "paper").unwrap();
        let p = Config::parse(&paper, "paper", ".".into()).unwrap();
        assert_eq!(p.waypoints, d.waypoints);
        assert_eq!(p.learner, d.learner);
        let tdcr = with_arm(crate::DEFAULT, SHIPPED[2].1, "tdcr").unwrap();
        let t = Config::parse(&tdcr, "tdcr", ".".into()).unwrap();
        // Three 60 mm backbones and a 10 mm tool.
        assert_eq!(reach_box(&t.layout()), 0.19);
        assert_eq!(t.waypoints.reach_m, 0.19);
        assert_eq!(t.waypoints.workspace_min_m, [-0.19; 3]);
        assert_eq!(t.waypoints.workspace_max_m, [0.19; 3]);
        assert_eq!(t.learner.workspace_min_m, [-0.19; 3]);
        assert_eq!(t.learner.workspace_max_m, [0.19; 3]);
        // The rest of the sections as they were.
        assert_eq!(t.learner.actor_spacing_m, d.learner.actor_spacing_m);
        assert_eq!(t.waypoints.max_executions, d.waypoints.max_executions);
    }

    /// A bad arm file is refused naming its own line and key, whatever the config.
    #[test]
    fn a_bad_arm_names_its_line_and_key() {
        let two = "mount = \"standing\"\n[[modules]]\ntendons = { count = 2, radius_m = 0.01, length_m = [0.1, 0.2] }\n";
        let e = with_arm(crate::DEFAULT, two, "two.toml").unwrap_err();
        assert_eq!(e.origin, "two.toml");
        assert_eq!(e.line, Some(2), "{e}");
        assert!(
            e.message
                .starts_with("arm.modules[0]: cannot bend in every direction"),
            "{e}"
        );
        let lopsided = "[[modules]]\ntendons = { count = 3, radius_m = 0.01, length_m = [0.1, 0.2], angles_deg = [0, 30, 60] }\n";
        let e = check(lopsided, "l.toml").unwrap_err();
        assert!(e.message.contains("leaves a gap of 300°"), "{e}");
        let shorthand = "actuator_radius_m = 0.02\n[[modules]]\ntendons = { count = 3, radius_m = 0.01, length_m = [0.1, 0.2] }\n";
        let e = check(shorthand, "s.toml").unwrap_err();
        assert_eq!(e.line, Some(1), "{e}");
        assert!(
            e.message
                .starts_with("arm.actuator_radius_m: a shorthand key"),
            "{e}"
        );
        let unknown = "[[modules]]\ntendon = { count = 3 }\n";
        let e = check(unknown, "u.toml").unwrap_err();
        assert_eq!(e.line, Some(2), "{e}");
        // Nine actuators into a config whose lists have six: refused when the config is read.
        let six = crate::DEFAULT.replace(
            "actuator_min = 0.0 ",
            "actuator_min = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0] ",
        );
        let merged = with_arm(&six, SHIPPED[2].1, "tdcr").unwrap();
        let e = Config::parse(&merged, "c.toml", ".".into()).unwrap_err();
        assert!(
            e.message
                .starts_with("controller.actuator_min: 6 values for an arm of 9"),
            "{e}"
        );
    }
}
