//! A throwaway stack for the commands that bring one up themselves (`demo`, `soak`, `bench`): a
//! namespace and a folder of the command's own, so it never meets a running stack, and both
//! gone when it ends.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use softarm_clients::{status, train};
use softarm_config::{Config, Override};
use softarm_ipc::{ControllerState, Namespace};
use softarm_model::bundle::Model;

use crate::supervisor::Supervisor;

pub struct Scratch {
    pub namespace: Namespace,
    /// The config the children read, in `dir`.
    pub config_path: PathBuf,
    pub config: Config,
    _remove: RemoveOnDrop,
}

impl Scratch {
    /// Namespace `softarm/<kind>-<pid>`, folder `<tmp>/softarm-<kind>-<pid>`, and there the
    /// config `text` with that namespace, its state in the folder, and `overrides`.
    pub fn new(kind: &str, text: &str, overrides: &[Override]) -> anyhow::Result<Self> {
        let pid = std::process::id();
        let namespace = format!("softarm/{kind}-{pid}");
        let dir = std::env::temp_dir().join(format!("softarm-{kind}-{pid}"));
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        let remove = RemoveOnDrop(dir.clone());
        let mut all: Vec<Override> = vec![
            ("robot.namespace", namespace.clone().into()),
            ("state.dir", dir.join("state").display().to_string().into()),
        ];
        all.extend_from_slice(overrides);
        let text = softarm_config::with_overrides(text, &all)
            .map_err(anyhow::Error::msg)
            .with_context(|| format!("the {kind}'s config"))?;
        let config_path = dir.join("softarm.toml");
        std::fs::write(&config_path, &text)
            .with_context(|| format!("writing {}", config_path.display()))?;
        let config = Config::load(&config_path)?;
        Ok(Self {
            namespace: Namespace::new(&namespace)?,
            config_path,
            config,
            _remove: remove,
        })
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
}

impl Scratch {
    /// Waits for the controller; trains a model into the config's model folder if none there
    /// is usable (through this stack, as `softarm train` does), and waits until it is loaded.
    /// `say` tells the user what happens.
    pub fn ready_with_model(
        &self,
        sup: &mut Supervisor,
        stop: &AtomicBool,
        seed: u64,
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
        let train_because = match Model::read(&model_dir) {
            Ok(_) => None,
            Err(_) if !model_dir.join("model.toml").exists() => {
                Some(format!("no model in {}", model_dir.display()))
            }
            Err(e) => Some(format!("the model is not usable ({e})")),
        };
        if let Some(why) = train_because {
            say(&format!(
                "{why}: training (demonstrations, ProMPs, forward models, CACLA-MTL pre-training)"
            ));
            let t = Instant::now();
            let r = train::train(&self.config, &self.namespace, seed)?;
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
