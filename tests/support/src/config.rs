//! Test configs: the embedded default, edited by dotted key (`"pretrain.budget_s"`).

use std::path::Path;

use softarm_config::DEFAULT;

/// [`softarm_config::with_overrides`], for tests: a bad override is a test bug.
pub fn with_overrides(text: &str, overrides: &[(&str, toml::Value)]) -> String {
    softarm_config::with_overrides(text, overrides).unwrap_or_else(|e| panic!("{e}"))
}

/// The shipped hardware config (`config/hardware.toml`).
pub const HARDWARE: &str = include_str!(concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../config/hardware.toml"
));

/// [`config_text`] for the real arm: the hardware config with the devices at `tendon` and
/// `tracker` (emulators' pseudo-terminals).
pub fn hardware_config_text(dir: &Path, namespace: &str, tendon: &Path, tracker: &Path) -> String {
    let path = |p: &Path| toml::Value::from(p.display().to_string());
    with_overrides(
        &quick(HARDWARE, dir, namespace),
        &[
            ("tendon.port", path(tendon)),
            ("tracker.port", path(tracker)),
        ],
    )
}

/// `base` with namespace `namespace`, model and state folders under `dir`, and quick training.
fn quick(base: &str, dir: &Path, namespace: &str) -> String {
    let path = |sub: &str| toml::Value::from(dir.join(sub).display().to_string());
    with_overrides(
        base,
        &[
            ("robot.namespace", namespace.into()),
            ("model.dir", path("model")),
            ("state.dir", path("state")),
            ("demonstrations.demos_per_class", 3.into()),
            ("demonstrations.duration_s", 1.5.into()),
            ("pretrain.budget_s", 2.0.into()),
        ],
    )
}

/// The embedded default with namespace `namespace`, model and state folders under `dir`, and
/// quick training settings (3 demonstrations per class of 1.5 s, 2 s of pre-training).
pub fn config_text(dir: &Path, namespace: &str) -> String {
    quick(DEFAULT, dir, namespace)
}

#[cfg(test)]
mod tests {
    use super::*;
    use softarm_config::Config;

    #[test]
    fn a_test_config_is_valid_and_has_its_overrides() {
        let text = config_text(Path::new("/tmp/t"), "softarm/test-x");
        let c = Config::parse(&text, "t.toml", "/".into()).unwrap();
        assert_eq!(c.namespace(), "softarm/test-x");
        assert_eq!(c.model_dir(), Path::new("/tmp/t/model"));
        assert_eq!(c.state_dir(), Path::new("/tmp/t/state"));
        assert_eq!(c.demonstrations.demos_per_class, 3);
        assert_eq!(c.demonstrations.duration_s, 1.5);
        assert_eq!(c.pretrain.budget_s, 2.0);
        // Untouched keys keep the default's values.
        let default = Config::parse(DEFAULT, "d.toml", "/".into()).unwrap();
        assert_eq!(c.learner, default.learner);
        assert_eq!(c.controller, default.controller);

        let nested = with_overrides(&text, &[("sim.realism.seed", 9.into())]);
        let c = Config::parse(&nested, "t.toml", "/".into()).unwrap();
        assert_eq!(c.sim.realism.seed, 9);
    }

    #[test]
    #[should_panic(expected = "no section [nowhere]")]
    fn an_override_of_a_missing_section_says_so() {
        with_overrides(DEFAULT, &[("nowhere.key", 1.into())]);
    }
}
