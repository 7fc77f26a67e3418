//! The e-stop latch on disk. An e-stop must outlive the processes that saw it: a controller or
//! driver restarted after an e-stop (by `softarm up`, by systemd, by hand) comes back stopped
//! until `softarm estop --reset`. The `estop` service tells the running processes; this file
//! tells the ones that start later. `softarm estop` writes it (atomically), and every process
//! that honours the e-stop reads it when it starts.
//!
//! The file holds one word, `engaged` or `released`. No file: released (nothing was ever
//! e-stopped here). A file that cannot be read or says anything else counts as engaged: a
//! process that cannot tell must not move the arm.

use std::path::{Path, PathBuf};

const ENGAGED: &str = "engaged";
const RELEASED: &str = "released";

/// The latch file of one stack (`<state.dir>/estop`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EstopLatch {
    path: PathBuf,
}

/// Why the latch reads as engaged although nobody engaged it.
#[derive(Debug, thiserror::Error)]
pub enum LatchError {
    #[error("cannot read the e-stop latch {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("the e-stop latch {path} says {got:?}, neither `engaged` nor `released`")]
    Garbled { path: PathBuf, got: String },
    #[error("cannot write the e-stop latch {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
}

impl EstopLatch {
    pub fn new(path: impl Into<PathBuf>) -> Self {
        Self { path: path.into() }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Whether the e-stop is latched. An error means it must be taken as engaged.
    pub fn engaged(&self) -> Result<bool, LatchError> {
        match std::fs::read_to_string(&self.path) {
            Ok(text) => match text.trim() {
                ENGAGED => Ok(true),
                RELEASED => Ok(false),
                other => Err(LatchError::Garbled {
                    path: self.path.clone(),
                    got: other.chars().take(40).collect(),
                }),
            },
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(false),
            Err(source) => Err(LatchError::Read {
                path: self.path.clone(),
                source,
            }),
        }
    }

    /// Whether the e-stop is latched; when the file cannot tell, engaged, with the reason
    /// logged through `warn`.
    pub fn engaged_or_safe(&self, warn: impl FnOnce(&LatchError)) -> bool {
        self.engaged().unwrap_or_else(|e| {
            warn(&e);
            true
        })
    }

    /// Latches (`true`) or releases the e-stop. Atomic ([`crate::file::write_atomic`]): a
    /// reader sees the old word or the new one, never a part, also across a power cut.
    pub fn set(&self, engaged: bool) -> Result<(), LatchError> {
        let word = if engaged { ENGAGED } else { RELEASED };
        crate::file::write_atomic(&self.path, format!("{word}\n").as_bytes(), None).map_err(
            |source| LatchError::Write {
                path: self.path.clone(),
                source,
            },
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("softarm-latch-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn a_latch_is_released_until_engaged_and_stays_engaged_until_released() {
        let d = dir("cycle");
        let latch = EstopLatch::new(d.join("state/estop"));
        assert!(!latch.engaged().unwrap(), "no file: released");
        latch.set(true).unwrap();
        assert!(latch.engaged().unwrap());
        // Another reader (a restarted process) sees the same.
        assert!(EstopLatch::new(latch.path()).engaged().unwrap());
        latch.set(false).unwrap();
        assert!(!latch.engaged().unwrap());
        // Nothing left over beside it.
        let names: Vec<_> = std::fs::read_dir(d.join("state"))
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["estop"]);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_latch_that_cannot_tell_counts_as_engaged() {
        let d = dir("garbled");
        std::fs::create_dir_all(&d).unwrap();
        let latch = EstopLatch::new(d.join("estop"));
        std::fs::write(latch.path(), "enga").unwrap();
        let e = latch.engaged().unwrap_err();
        assert!(e.to_string().contains("\"enga\""), "{e}");
        let mut warned = false;
        assert!(latch.engaged_or_safe(|_| warned = true));
        assert!(warned);
        // A folder where the file should be cannot be read as a word either.
        let folder = EstopLatch::new(&d);
        assert!(folder.engaged_or_safe(|_| {}));
        std::fs::remove_dir_all(&d).unwrap();
    }
}
