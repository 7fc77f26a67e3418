//! `softarm record`, `softarm replay` and `softarm plot`: every pub/sub service of a running
//! stack into an MCAP file ([`record`]), and the file back into the per-execution statistics
//! ([`record::replay`]) and the paper's Fig. 4 ([`plot`]). The channels and the scene the file
//! holds are `softarm-channels`'; the statistics' formats `softarm stats`'.
//!
//! [`plot`] takes from [`record`] (the file's messages), never the other way; so does
//! [`poses`], the still poses of a recording, which `softarm train --from` identifies the arm
//! from.

pub mod plot;
pub mod poses;
pub mod record;

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
