//! Who a process joins its stack as. iceoryx2 makes every shared memory segment its creator's
//! alone (0600), so all the processes on a stack's services must be one user: a segment made by
//! anyone else is one the others cannot map (root's e-stop reached nobody; root's folders kept
//! the service from starting). An installed stack names that user and its operators' group
//! (`[host]`); [`join`] makes the calling process that user before it touches any shared
//! memory or state file:
//!
//! - the stack's user: nothing to do;
//! - root: drops to the user for good (groups, gid, uid);
//! - a member of the operators' group: runs the same command again through the operator gate,
//!   a copy of softarm set-user-ID the stack's user (and set-group-ID the group) that only the
//!   group may execute;
//! - anyone else: refused, with what to do.

use std::ffi::CString;
use std::path::{Path, PathBuf};

use nix::unistd::{Gid, Group, Uid, User};

/// Set in the environment of a command run again through the gate: the gate must have made
/// it the stack's user, and must not be entered twice.
pub const THROUGH_GATE: &str = "SOFTARM_THROUGH_GATE";

/// The stack's identity, as its config names it.
#[derive(Debug, Clone)]
pub struct StackUser {
    pub user: String,
    pub group: String,
    /// The operator gate (`host.gate`); `None`: only root and the user may join.
    pub gate: Option<PathBuf>,
    /// The config that names them, for messages.
    pub config: String,
}

/// Why this process may not join the stack, said so that the person can act on it.
#[derive(Debug, thiserror::Error)]
pub enum JoinError {
    #[error(
        "the stack's user `{user}` (host.user in {config}) does not exist on this computer: \
         `softarm install` creates it"
    )]
    NoUser { user: String, config: String },
    #[error(
        "the operators' group `{group}` (host.group in {config}) does not exist on this \
         computer: `softarm install` creates it"
    )]
    NoGroup { group: String, config: String },
    #[error(
        "you ({me}) may not operate this stack: it runs as `{user}`, and only root and the \
         members of the group `{group}` may join it ({config}). Ask its administrator for \
         `usermod -aG {group} {me}` (then log in again), or use sudo"
    )]
    NotOperator {
        me: String,
        user: String,
        group: String,
        config: String,
    },
    #[error(
        "you ({me}) are in the operators' group `{group}`, but {config} names no operator gate \
         (host.gate): run this as root or as `{user}`, or install softarm again to get one"
    )]
    NoGate {
        me: String,
        user: String,
        group: String,
        config: String,
    },
    #[error(
        "the operator gate {gate} could not be run ({reason}): `softarm install` puts it there, \
         owned by `{user}`, mode 6750"
    )]
    Gate {
        gate: PathBuf,
        user: String,
        reason: String,
    },
    #[error(
        "the operator gate {gate} did not make this command `{user}`: it must be owned by \
         `{user}` with the set-user-ID bit (mode 6750), on a file system mounted without \
         nosuid; `softarm install` puts it so"
    )]
    GateNotSetuid { gate: PathBuf, user: String },
    #[error(
        "you ({me}) may not read the stack's config {config}: only root and the members of the \
         group `{group}` may. Ask its administrator for `usermod -aG {group} {me}` (then log in \
         again), or use sudo"
    )]
    ConfigUnreadable {
        me: String,
        group: String,
        config: String,
    },
    #[error("could not become `{user}`: {source}")]
    Drop { user: String, source: nix::Error },
}

fn name_of(uid: Uid) -> String {
    match User::from_uid(uid) {
        Ok(Some(u)) => u.name,
        _ => format!("uid {uid}"),
    }
}

/// Why `config` cannot be read, when the reason is who this process is: an installed
/// stack's config is for root and its operators' group only (mode 640). `None`: it can be
/// opened, or fails for another reason (the config loader says that one).
pub fn config_unreadable(config: &Path) -> Option<JoinError> {
    use std::os::unix::fs::MetadataExt;
    match std::fs::File::open(config) {
        Err(e) if e.kind() == std::io::ErrorKind::PermissionDenied => {}
        _ => return None,
    }
    let group = std::fs::metadata(config)
        .ok()
        .and_then(|m| Group::from_gid(Gid::from_raw(m.gid())).ok().flatten())
        .map_or("softarm".to_string(), |g| g.name);
    Some(JoinError::ConfigUnreadable {
        me: name_of(Uid::current()),
        group,
        config: config.display().to_string(),
    })
}

fn member_of(gid: Gid) -> bool {
    Gid::effective() == gid
        || Gid::current() == gid
        || nix::unistd::getgroups().is_ok_and(|g| g.contains(&gid))
}

/// Makes this process the stack's user, or says why it may not be. Returns only as that user;
/// a group member's command is replaced by the same command through the gate (this function
/// does not return then, unless the gate cannot be run). `as_caller` runs first with the rights
/// of the person who ran the command (root, the operator through the gate, or the stack's
/// user): files they name on the command line are theirs to read, not the stack's.
pub fn join_with<R>(stack: &StackUser, as_caller: impl FnOnce() -> R) -> Result<R, JoinError> {
    let user = User::from_name(&stack.user)
        .ok()
        .flatten()
        .ok_or_else(|| JoinError::NoUser {
            user: stack.user.clone(),
            config: stack.config.clone(),
        })?;
    let group = Group::from_name(&stack.group)
        .ok()
        .flatten()
        .ok_or_else(|| JoinError::NoGroup {
            group: stack.group.clone(),
            config: stack.config.clone(),
        })?;
    let euid = Uid::effective();
    let drop = |source| JoinError::Drop {
        user: stack.user.clone(),
        source,
    };
    if euid == user.uid {
        let caller = Uid::current();
        if caller == user.uid {
            return Ok(as_caller());
        }
        // Through the gate the real ids are still the operator's: read as them, then take the
        // gate's wholly (the user, and the operators' group from the set-group-ID bit), so
        // nothing this process creates is the operator's.
        let (gate_gid, caller_gid) = (Gid::effective(), Gid::current());
        nix::unistd::setegid(caller_gid).map_err(drop)?;
        nix::unistd::seteuid(caller).map_err(drop)?;
        let r = as_caller();
        nix::unistd::seteuid(user.uid).map_err(drop)?;
        nix::unistd::setegid(gate_gid).map_err(drop)?;
        nix::unistd::setresgid(gate_gid, gate_gid, gate_gid).map_err(drop)?;
        nix::unistd::setresuid(user.uid, user.uid, user.uid).map_err(drop)?;
        stack_umask();
        return Ok(r);
    }
    if euid.is_root() {
        let r = as_caller();
        let groups = [user.gid, group.gid];
        nix::unistd::setgroups(&groups).map_err(drop)?;
        nix::unistd::setresgid(user.gid, user.gid, user.gid).map_err(drop)?;
        nix::unistd::setresuid(user.uid, user.uid, user.uid).map_err(drop)?;
        stack_umask();
        return Ok(r);
    }
    let me = name_of(Uid::current());
    if !member_of(group.gid) {
        return Err(JoinError::NotOperator {
            me,
            user: stack.user.clone(),
            group: stack.group.clone(),
            config: stack.config.clone(),
        });
    }
    let Some(gate) = &stack.gate else {
        return Err(JoinError::NoGate {
            me,
            user: stack.user.clone(),
            group: stack.group.clone(),
            config: stack.config.clone(),
        });
    };
    if std::env::var_os(THROUGH_GATE).is_some() {
        return Err(JoinError::GateNotSetuid {
            gate: gate.clone(),
            user: stack.user.clone(),
        });
    }
    let reason = enter_gate(gate);
    Err(JoinError::Gate {
        gate: gate.clone(),
        user: stack.user.clone(),
        reason,
    })
}

/// What the services' units set (`UMask=0007`): files the stack writes are for its group.
fn stack_umask() {
    nix::sys::stat::umask(nix::sys::stat::Mode::from_bits_truncate(0o007));
}

/// Replaces this process by its own command line run through `gate`; returns only the reason
/// it could not.
fn enter_gate(gate: &Path) -> String {
    use std::os::unix::ffi::OsStrExt;
    let cstring = |bytes: &[u8]| CString::new(bytes).map_err(|e| e.to_string());
    let argv: Result<Vec<CString>, String> =
        std::env::args_os().map(|a| cstring(a.as_bytes())).collect();
    let path = cstring(gate.as_os_str().as_bytes());
    let mut env: Vec<Vec<u8>> = std::env::vars_os()
        .filter(|(k, _)| k != THROUGH_GATE)
        .map(|(k, v)| [k.as_bytes(), b"=", v.as_bytes()].concat())
        .collect();
    env.push(format!("{THROUGH_GATE}=1").into_bytes());
    let env: Result<Vec<CString>, String> = env.iter().map(|e| cstring(e)).collect();
    let (Ok(argv), Ok(path), Ok(env)) = (argv, path, env) else {
        return "an argument or the environment holds a NUL byte".into();
    };
    match nix::unistd::execve(&path, &argv, &env) {
        Err(e) => e.desc().to_string(),
        Ok(never) => match never {},
    }
}
