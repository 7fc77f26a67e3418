//! The files in /dev/shm of a stack with an iceoryx2 root folder of its own (an installed stack).
//!
//! iceoryx2 keeps the shared memory of every service, and a counter of the nodes it made, in
//! /dev/shm, never under its root folder, each file named from `global.prefix`. It makes every
//! segment its creator's alone (0600) except that counter, which iceoryx2 0.10 creates
//! world-writable (0666) so that every iceoryx2 program of the computer may share it. Whoever
//! writes into it decides the fate of every node made after: a version that is not 0.10's and
//! each fails (`VersionMismatch`), a file cut to nothing and each hangs. A running process does
//! not read it again, but no process of the stack could restart and no command (`softarm
//! status`, `softarm estop`) could join it.
//!
//! So a stack of its own root has a prefix of its own ([`prefix`]), and makes that counter
//! itself, its user's alone (0600), before iceoryx2 would ([`make_counter`]). [`Leftovers`] is
//! what such a stack leaves on the host once it stopped, for `softarm uninstall`.

use std::io::Write;
use std::os::unix::fs::{MetadataExt, OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};

use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;
use iceoryx2_bb_elementary::package_version::PackageVersion;
use iceoryx2_cal::hash::Hash;
use iceoryx2_cal::hash::sha1::Sha1;

use crate::Error;

/// Where glibc's `shm_open`, and so iceoryx2, puts shared memory on Linux.
pub const SHM_DIR: &str = "/dev/shm";

/// The prefix of every file of the stack whose iceoryx2 root is `root` (as
/// [`crate::Namespace::under`] writes it, ending with `/`): `softarm_` and a hash of the root,
/// so two stacks of their own roots share no file in /dev/shm, nor with any other iceoryx2
/// program (those use `iox2_`).
pub fn prefix(root: &str) -> String {
    // FNV-1a: stable across builds and platforms, unlike std's hasher.
    let hash = root.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    });
    format!("softarm_{hash:016x}_")
}

/// iceoryx2's node counter for `prefix`, named as iceoryx2 0.10 names it
/// (`iceoryx2::node::global_management_segment`): the prefix, the hash of the counter's type
/// name, `node`, the package version and the suffix.
pub fn counter_path(prefix: &str) -> PathBuf {
    const TYPE: &str = "iceoryx2::node::global_management_segment::State";
    let type_hash = String::from(Sha1::new(TYPE.as_bytes()).value());
    let v = PackageVersion::get();
    let suffix = Config::default().global.node.global_mgmt_suffix;
    let name = format!(
        "{prefix}{type_hash}_node.{}_{}_{}{suffix}",
        v.major(),
        v.minor(),
        v.patch()
    );
    Path::new(SHM_DIR).join(name)
}

/// The counter as iceoryx2 initialises it: its version (u64), the count (u32) and padding.
fn counter_bytes() -> [u8; 16] {
    let mut bytes = [0; 16];
    bytes[..8].copy_from_slice(&PackageVersion::get().to_u64().to_ne_bytes());
    bytes
}

/// What the counter at `path` is now.
enum Found {
    Missing,
    /// This user's, 0600, a file: what [`make_counter`] makes.
    Ready,
    /// This user's but not as made here (iceoryx2's own 0666, a tool's): replaced.
    Replace,
    /// Another user's: refused.
    Taken(u32),
}

fn found(path: &Path) -> Result<Found, Error> {
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.uid() != nix::unistd::geteuid().as_raw() => Ok(Found::Taken(m.uid())),
        Ok(m) if m.is_file() && m.mode() & 0o7777 == 0o600 && m.len() >= 16 => Ok(Found::Ready),
        Ok(_) => Ok(Found::Replace),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Found::Missing),
        Err(e) => Err(Error(format!("reading {}: {e}", path.display()))),
    }
}

fn taken(path: &Path, uid: u32) -> Error {
    Error(format!(
        "{} belongs to uid {uid}, not to uid {} this process runs as: someone else made it \
         first, and could write into it to stop the stack's processes from starting. With the \
         stack stopped, remove it as root (`rm {}`) and start the stack again",
        path.display(),
        nix::unistd::geteuid(),
        path.display()
    ))
}

/// Makes iceoryx2's node counter for `prefix` this user's alone (0600) unless it is already:
/// written whole beside it, then linked in (or renamed over this user's own), so it never
/// appears half-made or open to others. Refuses one another user made first, naming it.
pub fn make_counter(prefix: &str) -> Result<(), Error> {
    let path = counter_path(prefix);
    let mut tmp = None;
    let placed = place(&path, &mut tmp);
    remove_tmp(tmp.as_deref());
    placed
}

/// [`make_counter`]'s work; the file beside `path` it wrote, if any, is left in `tmp`.
fn place(path: &Path, tmp: &mut Option<PathBuf>) -> Result<(), Error> {
    let io = |what: &str, e: std::io::Error| Error(format!("{what} {}: {e}", path.display()));
    // A link that finds the counter made meanwhile (another process of the stack) looks again.
    for _ in 0..3 {
        let replace = match found(path)? {
            Found::Ready => return Ok(()),
            Found::Taken(uid) => return Err(taken(path, uid)),
            Found::Missing => false,
            Found::Replace => true,
        };
        let t = match tmp {
            Some(t) => t,
            None => tmp.insert(write_tmp(path).map_err(|e| io("making a counter beside", e))?),
        };
        let done = if replace {
            std::fs::rename(t.as_path(), path)
        } else {
            std::fs::hard_link(t.as_path(), path)
        };
        match done {
            Ok(()) => return Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(io("putting in place", e)),
        }
    }
    Err(Error(format!(
        "{} kept appearing and going while it was made: stop whatever removes it, and start \
         again",
        path.display()
    )))
}

fn remove_tmp(tmp: Option<&Path>) {
    if let Some(t) = tmp {
        let _ = std::fs::remove_file(t);
    }
}

/// A new file beside `path` holding a fresh counter, mode 0600 whatever the umask.
fn write_tmp(path: &Path) -> std::io::Result<PathBuf> {
    let name = path
        .file_name()
        .map_or("counter".into(), |n| n.to_string_lossy());
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    let tmp = path.with_file_name(format!(".{name}.{}.{nanos}.tmp", std::process::id()));
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(&tmp)?;
    let written = f
        .set_permissions(std::fs::Permissions::from_mode(0o600))
        .and_then(|()| f.write_all(&counter_bytes()));
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    Ok(tmp)
}

/// What a stack of its own iceoryx2 root leaves on the host: the root folder and its files in
/// /dev/shm, and which of its processes still run.
#[derive(Debug)]
pub struct Leftovers {
    pub root: PathBuf,
    pub prefix: String,
    /// The names of the live nodes under the root (and of those this user may not tell alive
    /// or dead).
    pub alive: Vec<String>,
    /// Every file in /dev/shm with the stack's prefix.
    pub shm: Vec<PathBuf>,
}

impl Leftovers {
    /// What is left of the stack whose iceoryx2 root is `root`; it creates nothing.
    pub fn of(root: &Path) -> Result<Self, Error> {
        let ns = crate::Namespace::new("softarm")?.under(root)?;
        let prefix = ns.prefix().expect("set by under").to_string();
        let root = ns.root().expect("set by under").to_path_buf();
        let mut alive = Vec::new();
        if root.join("nodes").is_dir() {
            crate::IoxNode::list(&ns.iceoryx2_config(), |state| {
                match &state {
                    NodeState::Alive(view) => alive.push(
                        view.details()
                            .as_ref()
                            .map_or(format!("{:?}", view.id()), |d| d.name().to_string()),
                    ),
                    NodeState::Inaccessible(id) => alive.push(format!("{id:?} (inaccessible)")),
                    _ => {}
                }
                CallbackProgression::Continue
            })
            .map_err(|e| Error(format!("listing the nodes under {}: {e:?}", root.display())))?;
        }
        let mut shm: Vec<PathBuf> = std::fs::read_dir(SHM_DIR)
            .map_err(|e| Error(format!("reading {SHM_DIR}: {e}")))?
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with(&prefix))
            .map(|e| e.path())
            .collect();
        shm.sort();
        Ok(Self {
            root,
            prefix,
            alive,
            shm,
        })
    }

    /// Removes the root folder and the files in /dev/shm; refused while a node is alive.
    /// Returns how many files in /dev/shm went.
    pub fn remove(&self) -> Result<usize, Error> {
        if !self.alive.is_empty() {
            return Err(Error(format!(
                "the stack still runs ({}): stop it first",
                self.alive.join(", ")
            )));
        }
        for f in &self.shm {
            match std::fs::remove_file(f) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => return Err(Error(format!("removing {}: {e}", f.display()))),
            }
        }
        match std::fs::remove_dir_all(&self.root) {
            Ok(()) => Ok(self.shm.len()),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(self.shm.len()),
            Err(e) => Err(Error(format!("removing {}: {e}", self.root.display()))),
        }
    }
}
