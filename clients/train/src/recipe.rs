//! What makes a model: the settings [`crate::train`] trained it with, kept beside its bundle, so
//! that a cached model trained by other settings or an older softarm is trained again rather
//! than run as if it were the one asked for.

use std::path::Path;

use softarm_config::Config;

/// The file beside a model's bundle that holds its recipe.
pub const FILE: &str = "recipe.toml";

/// What makes a model: one table per config section that the demonstrations or the fits
/// read, and one for softarm itself (its version, the bundle's format, the seed).
#[derive(Debug, Clone, PartialEq)]
pub struct Recipe(toml::Table);

/// The recipe of a model trained on `config`'s stack with `seed`. `learner.algorithm` is left
/// out: it chooses only the online update, and both algorithms run on the same model, side by
/// side.
pub fn of(config: &Config, seed: u64) -> Recipe {
    let mut recipe = toml::Table::new();
    let mut section = |name: &str, value: Result<toml::Table, toml::ser::Error>| {
        // Every section is plain data of numbers, strings and lists: it always serialises.
        recipe.insert(
            name.into(),
            toml::Value::Table(value.expect("a config section serialises to TOML")),
        );
    };
    section("arm", toml::Table::try_from(&config.arm));
    section("sim", toml::Table::try_from(&config.sim));
    section("controller", toml::Table::try_from(&config.controller));
    section("activation", toml::Table::try_from(config.activation));
    section(
        "demonstrations",
        toml::Table::try_from(&config.demonstrations),
    );
    section("forward_model", toml::Table::try_from(config.forward_model));
    section("kinematics", toml::Table::try_from(config.kinematics));
    section("pretrain", toml::Table::try_from(config.pretrain));
    section(
        "learner",
        toml::Table::try_from(config.learner).map(|mut t| {
            t.remove("algorithm");
            t
        }),
    );
    let mut softarm = toml::Table::new();
    softarm.insert("version".into(), env!("CARGO_PKG_VERSION").into());
    softarm.insert(
        "bundle_format".into(),
        i64::from(softarm_model::bundle::FORMAT).into(),
    );
    softarm.insert(
        "basis_functions".into(),
        i64::try_from(config.model.basis_functions)
            .unwrap_or(i64::MAX)
            .into(),
    );
    softarm.insert(
        "seed".into(),
        toml::Value::String(seed.to_string()), // u64: beyond TOML's integers
    );
    recipe.insert("softarm".into(), toml::Value::Table(softarm));
    Recipe(recipe)
}

/// Writes `recipe` beside the bundle in `dir` (atomically: a half-written one would read as
/// another recipe, and the model would only be trained again).
pub fn write(dir: &Path, recipe: &Recipe) -> std::io::Result<()> {
    let text = format!(
        "# What made the model in this folder (softarm train); a cached model whose recipe\n\
         # differs from the one asked for is trained again.\n{}",
        toml::to_string(&recipe.0).map_err(std::io::Error::other)?
    );
    softarm_runtime::file::write_atomic(&dir.join(FILE), text.as_bytes(), None)
}

/// Why the model in `dir` is not what `recipe` would train, naming what differs; `None` when
/// it is.
pub fn differs(dir: &Path, recipe: &Recipe) -> Option<String> {
    let recipe = &recipe.0;
    let path = dir.join(FILE);
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Some(format!(
            "{} says nothing of what trained it (no {FILE}: an older softarm, or `--model-dir` \
             of another command)",
            dir.display()
        ));
    };
    let Ok(kept) = text.parse::<toml::Table>() else {
        return Some(format!("{} does not read as TOML", path.display()));
    };
    let mut changed: Vec<String> = recipe
        .iter()
        .filter(|(k, v)| kept.get(*k) != Some(*v))
        .map(|(k, _)| format!("[{k}]"))
        .collect();
    changed.extend(
        (kept.keys())
            .filter(|k| !recipe.contains_key(*k))
            .map(|k| format!("[{k}]")),
    );
    (!changed.is_empty()).then(|| {
        format!(
            "the model in {} was trained with other settings ({} differ)",
            dir.display(),
            changed.join(", ")
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> Config {
        Config::default_sim(std::path::PathBuf::from("."))
    }

    #[test]
    fn a_model_trained_by_other_settings_is_named_by_what_differs() {
        let dir = std::env::temp_dir().join(format!("softarm-recipe-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let c = config();
        let why = differs(&dir, &of(&c, 1)).unwrap();
        assert!(why.contains("no recipe.toml"), "{why}");

        write(&dir, &of(&c, 1)).unwrap();
        assert_eq!(differs(&dir, &of(&c, 1)), None, "the same settings");
        let mut other = c.clone();
        other.learner.algorithm = softarm_config::learner::Algorithm::Paper;
        assert_eq!(
            differs(&dir, &of(&other, 1)),
            None,
            "the online algorithm alone"
        );

        let mut other = c.clone();
        other.forward_model.width_factor *= 2.0;
        other.kinematics.degree -= 1;
        let why = differs(&dir, &of(&other, 1)).unwrap();
        assert!(
            why.contains("([forward_model], [kinematics] differ)"),
            "{why}"
        );
        let why = differs(&dir, &of(&c, 2)).unwrap();
        assert!(why.contains("[softarm]"), "another seed: {why}");

        std::fs::write(dir.join(FILE), "not = [toml").unwrap();
        assert!(
            differs(&dir, &of(&c, 1))
                .unwrap()
                .contains("does not read as TOML")
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
