//! softarm's user-facing clients of a running stack: `submit`, `stats`, `status`, `estop` and
//! `train`. Each is a short-lived iceoryx2 node in the stack's namespace. Beside them what
//! `record` and the live view (`softarm-view`) share: the services as channels
//! ([`channels`]) and the 3-D scene ([`scene`]).

pub mod channels;
pub mod estop;
pub mod plot;
pub mod record;
pub mod scene;
pub mod stats;
pub mod status;
pub mod submit;
pub mod train;
pub mod watch;

use std::time::{Duration, Instant};

/// Polls `f` every millisecond until it yields or `timeout` passes.
pub(crate) fn poll<T>(timeout: Duration, mut f: impl FnMut() -> Option<T>) -> Option<T> {
    let start = Instant::now();
    loop {
        if let Some(v) = f() {
            return Some(v);
        }
        if start.elapsed() >= timeout {
            return None;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// Refuses an output path no file can be written at, before the work that would produce it:
/// `out` a directory, or its folder missing or not a folder. The error names `what` and `out`.
pub(crate) fn check_output_path(out: &std::path::Path, what: &str) -> anyhow::Result<()> {
    if out.is_dir() {
        anyhow::bail!(
            "cannot write {what} to {}: it is a directory",
            out.display()
        );
    }
    let dir = match out.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => std::path::Path::new("."),
    };
    if !dir.exists() {
        anyhow::bail!(
            "cannot write {what} to {}: there is no folder {}",
            out.display(),
            dir.display()
        );
    }
    if !dir.is_dir() {
        anyhow::bail!(
            "cannot write {what} to {}: {} is not a folder",
            out.display(),
            dir.display()
        );
    }
    if nix::unistd::access(dir, nix::unistd::AccessFlags::W_OK).is_err() {
        // On an installed stack this process runs as the stack's user, whoever started it.
        let uid = nix::unistd::Uid::effective();
        let me = nix::unistd::User::from_uid(uid)
            .ok()
            .flatten()
            .map_or(format!("uid {uid}"), |u| u.name);
        anyhow::bail!(
            "cannot write {what} to {}: {me}, whom this command runs as, may not write in {} \
             (on an installed stack every command runs as the stack's user): choose a folder \
             {me} may write, such as the stack's state folder",
            out.display(),
            dir.display(),
        );
    }
    Ok(())
}

/// The message for a stack that does not answer.
pub(crate) fn unreachable(namespace: &str, what: &str) -> String {
    format!(
        "no controller answered {what} in namespace {namespace:?}: is `softarm up` running there \
         (same --config or --namespace)?"
    )
}
