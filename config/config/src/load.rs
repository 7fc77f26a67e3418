//! How a command finds its stack's config and joins the stack: the file `--config` names
//! (else [`crate::CONFIG_ENV`]'s, the installed one, the embedded one), `--namespace` over the
//! config's, and this process made the stack's user when the config names one.

use std::path::{Path, PathBuf};

use anyhow::Context;
use softarm_ipc::Namespace;
use softarm_runtime::identity::{self, StackUser};

use crate::{Config, ConfigError};

/// The stack a command is for, as its `--config` and `--namespace` name it (`None`: not
/// given).
#[derive(Debug, Clone, Default)]
pub struct Loader {
    pub config: Option<PathBuf>,
    pub namespace: Option<String>,
}

impl Loader {
    /// The config file this command uses; `None`: the embedded one.
    pub fn path(&self) -> Option<PathBuf> {
        crate::locate(
            self.config.as_deref(),
            std::env::var_os(crate::CONFIG_ENV),
            Path::new(crate::INSTALLED),
        )
    }

    /// The config, and this process made the stack's user when the config names one (root and
    /// its operators become it; anyone else is refused): so it joins the stack's services as
    /// the stack itself, before it opens any.
    pub fn load(&self) -> anyhow::Result<Config> {
        Ok(self.load_reading(|| ())?.0)
    }

    /// The config as read, without joining the stack: for what only looks at it.
    pub fn read(&self) -> anyhow::Result<Config> {
        let mut c = match &self.path() {
            Some(p) => {
                if let Some(refused) = identity::config_unreadable(p) {
                    return Err(refused.into());
                }
                Config::load(p)?
            }
            None => {
                let mut c = Config::default_sim(PathBuf::from("."));
                // The latch is never relative to wherever the command happens to run.
                c.state.dir = crate::user_state_dir();
                c
            }
        };
        if let Some(ns) = &self.namespace {
            Namespace::new(ns).context("--namespace")?;
            c.robot.namespace = Some(ns.clone());
        }
        Ok(c)
    }

    /// [`Loader::load`], running `as_caller` with the rights of the person who ran the command,
    /// before this process becomes the stack's user: for the files they name.
    pub fn load_reading<R>(&self, as_caller: impl FnOnce() -> R) -> anyhow::Result<(Config, R)> {
        let path = self.path();
        let c = self.read()?;
        let (Some(user), Some(group)) = (&c.host.user, &c.host.group) else {
            return Ok((c, as_caller()));
        };
        let r = identity::join_with(
            &StackUser {
                user: user.clone(),
                group: group.clone(),
                gate: c.host.gate.clone(),
                config: path.map_or("the embedded config".into(), |p| p.display().to_string()),
            },
            as_caller,
        )?;
        Ok((c, r))
    }

    /// [`Loader::load`] for a process that needs config section `[section]`: without it the
    /// config is refused (exit 78, not restarted).
    pub fn load_with(
        &self,
        section: &str,
        has: impl Fn(&Config) -> bool,
    ) -> anyhow::Result<Config> {
        let c = self.load()?;
        if has(&c) {
            return Ok(c);
        }
        Err(ConfigError {
            origin: self
                .config
                .as_ref()
                .map_or("the embedded config".into(), |p| p.display().to_string()),
            line: None,
            message: format!(
                "no [{section}] section: the {section} driver needs one (config/hardware.toml \
                 has an example)"
            ),
        }
        .into())
    }

    /// The stack's namespace, once joined.
    pub fn namespace(&self) -> anyhow::Result<Namespace> {
        Ok(self.load()?.bus()?)
    }

    /// `loaded` with `arm`'s arm in it (a shipped arm's name or an arm file), as
    /// [`crate::arms::into_config`] puts it; as loaded without one.
    pub fn with_arm(&self, loaded: Config, arm: Option<&str>) -> anyhow::Result<Config> {
        match arm {
            Some(arm) => crate::arms::into_config(loaded, arm, self.path().as_deref()),
            None => Ok(loaded),
        }
    }

    /// The arguments that start a child on the same stack.
    pub fn args(&self) -> Vec<String> {
        let mut v = Vec::new();
        if let Some(c) = self.path() {
            v.extend(["--config".into(), c.display().to_string()]);
        }
        if let Some(n) = &self.namespace {
            v.extend(["--namespace".into(), n.clone()]);
        }
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default config in a file of its own, for a loader to name with `--config`.
    fn default_file(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("softarm-load-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("softarm.toml");
        std::fs::write(&file, crate::DEFAULT).unwrap();
        file
    }

    #[test]
    fn a_child_is_started_on_the_same_file_and_namespace() {
        let loader = Loader {
            config: Some("/some/softarm.toml".into()),
            namespace: Some("softarm/other".into()),
        };
        assert_eq!(
            loader.args(),
            [
                "--config",
                "/some/softarm.toml",
                "--namespace",
                "softarm/other"
            ]
        );
    }

    #[test]
    fn namespace_replaces_the_configs_and_is_checked() {
        let file = default_file("namespace");
        let mut loader = Loader {
            config: Some(file.clone()),
            namespace: Some("softarm/other".into()),
        };
        assert_eq!(loader.read().unwrap().namespace(), "softarm/other");
        loader.namespace = Some("no spaces here".into());
        let e = format!("{:#}", loader.read().unwrap_err());
        assert!(e.starts_with("--namespace: "), "{e}");
        std::fs::remove_dir_all(file.parent().unwrap()).unwrap();
    }

    /// `--arm` changes the arm and keeps what the loader changed: the namespace, the state.
    #[test]
    fn another_arm_keeps_the_namespace_and_the_state() {
        let file = default_file("arm");
        let loader = Loader {
            config: Some(file.clone()),
            namespace: Some("softarm/other".into()),
        };
        let mut read = loader.read().unwrap();
        read.state.dir = "/somewhere/else".into();
        let paper = read.arm_identity();
        let tdcr = loader.with_arm(read.clone(), Some("tdcr")).unwrap();
        assert_ne!(tdcr.arm_identity(), paper);
        assert_eq!(tdcr.namespace(), "softarm/other");
        assert_eq!(tdcr.state.dir, PathBuf::from("/somewhere/else"));
        let same = loader.with_arm(read, None).unwrap();
        assert_eq!(same.arm_identity(), paper);
        let e = loader.with_arm(same, Some("no-such-arm")).unwrap_err();
        assert!(e.chain().any(|c| c.is::<ConfigError>()), "{e:#}");
        std::fs::remove_dir_all(file.parent().unwrap()).unwrap();
    }
}
