//! `[host]`: an installed stack's place on its computer. Who its processes run as, who may
//! operate it, where its iceoryx2 services live. `softarm install` writes it; a config without
//! it (a stack in a work tree) runs as whoever starts it, on iceoryx2's default root folder.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::{Invalid, invalid};

/// The `[host]` section; every key is optional and the section may be absent.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct HostConfig {
    /// The user the stack's processes run as. iceoryx2 makes every shared memory segment its
    /// creator's alone (0600), so a process joins the stack as this user or not at all: root
    /// becomes it, the members of `group` become it through `gate`, anyone else is refused.
    pub user: Option<String>,
    /// The stack's operators: its members may run every command on the stack (status, submit,
    /// the e-stop and its reset...). Required with `user`.
    pub group: Option<String>,
    /// iceoryx2's root folder for this stack (absolute), in place of the global
    /// `/tmp/iceoryx2/` that the first user of iceoryx2 on the computer would own.
    pub ipc_root: Option<PathBuf>,
    /// The operator gate: a copy of `softarm` owned by `user` and `group`, set-user-ID and
    /// set-group-ID, executable by the group alone (mode 6750). A member of `group` runs a
    /// command on the stack through it. Absent: only root and `user` itself may.
    pub gate: Option<PathBuf>,
}

/// A user or group name as `useradd` takes it (the portable set, at most 32 characters).
fn is_name(s: &str) -> bool {
    let mut chars = s.chars();
    matches!(chars.next(), Some(c) if c.is_ascii_lowercase() || c == '_')
        && chars.all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || "_-".contains(c))
        && s.len() <= 32
}

impl HostConfig {
    /// Checks the names, that user and group go together, and the paths.
    pub(crate) fn validate(&self) -> Result<(), Invalid> {
        for (key, name) in [("host.user", &self.user), ("host.group", &self.group)] {
            if let Some(n) = name
                && !is_name(n)
            {
                return invalid(
                    key,
                    format!(
                        "{n:?} is not a user or group name: up to 32 of a-z 0-9 _ -, starting \
                         with a letter or _"
                    ),
                );
            }
        }
        if self.user.is_some() != self.group.is_some() {
            let (key, other) = if self.user.is_some() {
                ("host.group", "host.user")
            } else {
                ("host.user", "host.group")
            };
            return invalid(
                key,
                format!(
                    "needed with {other}: the stack's user and its operators' group go together"
                ),
            );
        }
        if let Some(root) = &self.ipc_root
            && !root.is_absolute()
        {
            return invalid(
                "host.ipc_root",
                format!("{} must be an absolute path", root.display()),
            );
        }
        if let Some(gate) = &self.gate {
            if self.user.is_none() {
                return invalid(
                    "host.gate",
                    "needs host.user: the gate makes its members that user".into(),
                );
            }
            if !gate.is_absolute() {
                return invalid(
                    "host.gate",
                    format!("{} must be an absolute path", gate.display()),
                );
            }
        }
        Ok(())
    }

    /// As [`HostConfig::validate`], and `bus`, the stack's namespace under `ipc_root`
    /// ([`crate::Config::bus`]), made: its error is `ipc_root`'s.
    pub(crate) fn validate_for(
        &self,
        bus: Result<softarm_ipc::Namespace, softarm_ipc::Error>,
    ) -> Result<(), Invalid> {
        self.validate()?;
        match bus {
            Ok(_) => Ok(()),
            Err(m) => invalid("host.ipc_root", m.to_string()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn host(user: Option<&str>, group: Option<&str>) -> HostConfig {
        HostConfig {
            user: user.map(Into::into),
            group: group.map(Into::into),
            ..HostConfig::default()
        }
    }

    #[test]
    fn names_and_paths_are_checked() {
        assert!(HostConfig::default().validate().is_ok());
        assert!(host(Some("softarm"), Some("softarm")).validate().is_ok());
        let (key, m) = host(Some("Soft Arm"), Some("x")).validate().unwrap_err();
        assert_eq!(key, "host.user");
        assert!(m.contains("not a user or group name"), "{m}");
        assert_eq!(
            host(Some("a"), None).validate().unwrap_err().0,
            "host.group"
        );
        assert_eq!(host(None, Some("a")).validate().unwrap_err().0, "host.user");
        let relative = HostConfig {
            ipc_root: Some("run/ipc".into()),
            ..HostConfig::default()
        };
        assert_eq!(relative.validate().unwrap_err().0, "host.ipc_root");
        let gate_alone = HostConfig {
            gate: Some("/usr/local/libexec/softarm/softarm".into()),
            ..HostConfig::default()
        };
        assert_eq!(gate_alone.validate().unwrap_err().0, "host.gate");
    }

    #[test]
    fn a_root_the_namespace_cannot_go_under_is_the_root_s_error() {
        let root = HostConfig {
            ipc_root: Some("/run/softarm/iceoryx2".into()),
            ..HostConfig::default()
        };
        let ns = softarm_ipc::Namespace::new("softarm/sim").unwrap();
        root.validate_for(Ok(ns)).unwrap();
        let refused = softarm_ipc::Error("not a path iceoryx2 takes".into());
        assert_eq!(
            root.validate_for(Err(refused)).unwrap_err(),
            ("host.ipc_root".into(), "not a path iceoryx2 takes".into())
        );
        // The section's own checks come first.
        let relative = HostConfig {
            ipc_root: Some("run/ipc".into()),
            ..HostConfig::default()
        };
        let refused = softarm_ipc::Error("x".into());
        let (key, m) = relative.validate_for(Err(refused)).unwrap_err();
        assert_eq!(key, "host.ipc_root");
        assert!(m.ends_with("must be an absolute path"), "{m}");
    }
}
