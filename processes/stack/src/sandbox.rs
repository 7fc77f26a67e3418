//! A sandbox stack: a namespace and a folder of its own, so it never meets a running stack, its
//! config written there, and both gone when it ends (unless kept). The commands that bring a
//! stack up themselves (`demo`, `soak`, `bench`) run in one, and so does each end-to-end test
//! (`tests/support/src/stack.rs::TestStack` is built on it).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use softarm_clients::status;
use softarm_config::{Config, Override};
use softarm_ipc::{ControllerState, Namespace};
use softarm_model::bundle::Model;
use softarm_train as train;

use crate::supervisor::Supervisor;

pub struct Sandbox {
    pub namespace: Namespace,
    /// The config the children read, in the folder.
    pub config_path: PathBuf,
    pub config: Config,
    folder: Folder,
}

impl Sandbox {
    /// Namespace `softarm/<name>`, a fresh folder `<tmp>/softarm-<name>`, and there the config
    /// `text(folder, namespace)` with that namespace, its state in the folder, and `overrides`.
    pub fn new(
        name: &str,
        text: impl FnOnce(&Path, &str) -> String,
        overrides: &[Override],
    ) -> anyhow::Result<Self> {
        Self::create(name, &format!("the config of {name}"), text, overrides)
    }

    /// A command's own sandbox (`<kind>-<pid>`) on the config `text` with `overrides`.
    pub fn for_command(kind: &str, text: &str, overrides: &[Override]) -> anyhow::Result<Self> {
        let name = format!("{kind}-{}", std::process::id());
        let what = format!("the {kind}'s config");
        Self::create(&name, &what, |_, _| text.to_string(), overrides)
    }

    /// [`Sandbox::new`], its config called `what` in errors.
    fn create(
        name: &str,
        what: &str,
        text: impl FnOnce(&Path, &str) -> String,
        overrides: &[Override],
    ) -> anyhow::Result<Self> {
        let namespace = format!("softarm/{name}");
        let dir = std::env::temp_dir().join(format!("softarm-{name}"));
        // A folder of this name an earlier process left (pids are reused) is not this one's.
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        let folder = Folder {
            dir: dir.clone(),
            keep: false,
        };
        let mut all: Vec<Override> = vec![
            ("robot.namespace", namespace.clone().into()),
            ("state.dir", dir.join("state").display().to_string().into()),
        ];
        all.extend_from_slice(overrides);
        let text = softarm_config::with_overrides(&text(&dir, &namespace), &all)
            .map_err(anyhow::Error::msg)
            .context(what.to_string())?;
        let config_path = dir.join("softarm.toml");
        std::fs::write(&config_path, &text)
            .with_context(|| format!("writing {}", config_path.display()))?;
        let config = Config::load(&config_path)?;
        Ok(Self {
            namespace: Namespace::new(&namespace)?,
            config_path,
            config,
            folder,
        })
    }

    /// The sandbox's folder.
    pub fn dir(&self) -> &Path {
        &self.folder.dir
    }

    /// Keeps the folder when the sandbox is dropped, to look into after.
    pub fn keep(&mut self) {
        self.folder.keep = true;
    }

    /// `roles` started as children on this config, logging at `RUST_LOG` or else `level`.
    pub fn supervisor(&self, roles: &[&str], level: &str) -> anyhow::Result<Supervisor> {
        let level = std::env::var("RUST_LOG").unwrap_or_else(|_| level.into());
        let mut sup = Supervisor::new(
            vec!["--config".into(), self.config_path.display().to_string()],
            vec![("RUST_LOG".into(), level)],
        )?;
        for role in roles {
            sup.add(role)?;
        }
        Ok(sup)
    }

    /// Waits until `ok` holds of the stack's status, restarting children meanwhile.
    pub fn wait_for(
        &self,
        what: &str,
        limit: Duration,
        sup: &mut Supervisor,
        stop: &AtomicBool,
        ok: &dyn Fn(&status::Report) -> bool,
    ) -> anyhow::Result<()> {
        let start = Instant::now();
        loop {
            if stop.load(Ordering::Relaxed) {
                bail!("interrupted");
            }
            sup.poll();
            if let Ok(r) = status::status(&self.namespace, Duration::from_millis(200))
                && ok(&r)
            {
                return Ok(());
            }
            if start.elapsed() > limit {
                bail!("{what} did not happen within {} s", limit.as_secs());
            }
        }
    }

    /// Waits for the controller; trains a model into the config's model folder if none there
    /// is usable (through this stack, as `softarm train` does), or, in softarm's own cache, if
    /// the one there was trained by other settings or another softarm (its recipe,
    /// `softarm_train::recipe`), and waits until it is loaded. `say` tells the user what
    /// happens and why.
    pub fn ready_with_model(
        &self,
        sup: &mut Supervisor,
        stop: &AtomicBool,
        seed: u64,
        folder: ModelFolder,
        say: &dyn Fn(&str),
    ) -> anyhow::Result<()> {
        self.wait_for(
            "the controller coming up",
            Duration::from_secs(20),
            sup,
            stop,
            &|r| {
                r.controller
                    .is_some_and(|s| s.state == ControllerState::Idle as u32)
            },
        )?;
        let model_dir = self.config.model_dir();
        // A cached model an older softarm wrote is not readable any more: trained again.
        let arm = self.config.arm_identity();
        let readable = softarm_ipc::with_actuators!(self.config.layout().actuators().len(),
            N => Model::<N>::read_for_arm(&model_dir, &arm).map(drop),
            n => unreachable!("a loaded config's arm has 3 to 16 actuators, not {n}"));
        let recipe = train::recipe::of(&self.config, seed);
        let train_because = why_train(
            readable.map_err(|e| e.to_string()),
            &model_dir,
            &recipe,
            folder,
            say,
        );
        if let Some(why) = train_because {
            say(&format!(
                "{why}: training (demonstrations, ProMPs, forward models, CACLA-MTL pre-training)"
            ));
            let t = Instant::now();
            // Each step's progress: a bar on a terminal, else lines as `say`'s.
            let out = train::Output {
                terminal: std::io::IsTerminal::is_terminal(&std::io::stderr()),
                lines: say,
            };
            let r = train::train(&self.config, &self.namespace, seed, out, stop)?;
            say(&format!(
                "trained in {:.1} s: {}",
                t.elapsed().as_secs_f64(),
                r.summary()
            ));
        }
        self.wait_for(
            "loading the model",
            Duration::from_secs(20),
            sup,
            stop,
            &|r| {
                r.controller.is_some_and(|s| s.model_loaded == 1)
                    && r.alive.iter().any(|n| n == "learner")
            },
        )
    }
}

/// Why the model in `dir` is to be trained before a run, `None` when it runs as it is:
/// `readable` says whether a bundle for the arm reads there; one in softarm's cache is
/// trained again when its recipe is not `recipe`, one the user gave is only said to differ.
fn why_train(
    readable: Result<(), String>,
    dir: &Path,
    recipe: &train::recipe::Recipe,
    folder: ModelFolder,
    say: &dyn Fn(&str),
) -> Option<String> {
    match readable {
        Ok(()) => {
            let differs = train::recipe::differs(dir, recipe);
            match (folder, differs) {
                (ModelFolder::Cache, differs) => differs,
                (ModelFolder::Given, Some(why)) => {
                    // The user's own folder is theirs: said, never trained over.
                    say(&format!("{why}; used as it is (train it again to match)"));
                    None
                }
                (ModelFolder::Given, None) => None,
            }
        }
        Err(_) if !dir.join("model.toml").exists() => {
            Some(format!("no model in {}", dir.display()))
        }
        Err(e) => Some(format!("the model is not usable ({e})")),
    }
}

/// Whose model folder a sandbox runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelFolder {
    /// softarm's own cache: a model trained by other settings is trained again.
    Cache,
    /// One the user named: used as it is, whatever trained it (a difference is said).
    Given,
}

/// A sandbox's folder, removed when dropped unless kept.
struct Folder {
    dir: PathBuf,
    keep: bool,
}

impl Drop for Folder {
    fn drop(&mut self) {
        if !self.keep {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

/// Removes a folder when dropped.
pub struct RemoveOnDrop(pub PathBuf);

impl Drop for RemoveOnDrop {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The demo's way-point set (`config/waypoints/demo.toml`), built in.
pub const DEMO_WAYPOINTS: &str = include_str!("../../../config/waypoints/demo.toml");

/// Where trained models are cached between runs of `demo`, `soak` and `bench`:
/// `$XDG_CACHE_HOME/softarm`, else `~/.cache/softarm`.
pub fn cache_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("XDG_CACHE_HOME") {
        return PathBuf::from(d).join("softarm");
    }
    if let Some(h) = std::env::var_os("HOME") {
        return PathBuf::from(h).join(".cache/softarm");
    }
    std::env::temp_dir().join("softarm-cache")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cached_model_of_another_recipe_is_trained_again_and_a_given_one_is_not() {
        let dir = std::env::temp_dir().join(format!("softarm-why-train-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let config = Config::default_sim(PathBuf::from("."));
        let recipe = train::recipe::of(&config, 1);
        train::recipe::write(&dir, &recipe).unwrap();
        let said = std::cell::RefCell::new(Vec::new());
        let say = |l: &str| said.borrow_mut().push(l.to_string());
        let why = |readable, recipe, folder| why_train(readable, &dir, recipe, folder, &say);

        assert_eq!(
            why(Ok(()), &recipe, ModelFolder::Cache),
            None,
            "the same recipe"
        );
        assert_eq!(why(Ok(()), &recipe, ModelFolder::Given), None);
        let mut other = config.clone();
        other.forward_model.centres += 1;
        let other = train::recipe::of(&other, 1);
        let again = why(Ok(()), &other, ModelFolder::Cache).unwrap();
        assert!(again.contains("[forward_model] differ"), "{again}");
        assert!(said.borrow().is_empty());
        assert_eq!(
            why(Ok(()), &other, ModelFolder::Given),
            None,
            "never over the user's"
        );
        assert!(
            said.borrow()[0].contains("used as it is"),
            "{:?}",
            said.borrow()
        );

        let unreadable = why(Err("format 1".into()), &recipe, ModelFolder::Given).unwrap();
        assert!(unreadable.starts_with("no model in"), "{unreadable}");
        std::fs::write(dir.join("model.toml"), "").unwrap();
        let unreadable = why(Err("format 1".into()), &recipe, ModelFolder::Given).unwrap();
        assert!(unreadable.contains("not usable (format 1)"), "{unreadable}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
