//! What every softarm process needs at run time, beneath the contract and the method:
//!
//! - [`clock`]: CLOCK_MONOTONIC ([`now_ns`], the stamp of every sample), [`clock::Ticker`]
//!   (fixed-rate loops on absolute deadlines), [`clock::Backoff`] (retries at doubling intervals).
//! - [`latch`]: the e-stop latch on disk ([`EstopLatch`]).
//! - [`file`]: [`file::write_atomic`], for every file written for others to read.
//! - [`identity`]: who a process joins an installed stack as ([`identity::join_with`]).
//! - [`stop_flag`]: SIGINT and SIGTERM as a flag every loop checks.
//! - [`lock_memory`]: a process that must keep its pace locks its pages in RAM.

pub mod clock;
pub mod file;
pub mod identity;
pub mod latch;

use std::sync::Arc;
use std::sync::atomic::AtomicBool;

pub use clock::now_ns;
pub use latch::EstopLatch;

/// Locks every page of this process in RAM, now and to come (`mlockall`), for a process that
/// must keep its pace: a page the kernel reclaims (memory pressure, or a proactive reclaimer
/// such as DAMON's `pageout`, on by default on the 2-core VM, which paged the stack's binaries
/// out between their uses) stalls the process on a disk read the next time it is touched, for
/// seconds on a busy machine. Needs `CAP_IPC_LOCK` or a large enough `LimitMEMLOCK`; the
/// error says so.
pub fn lock_memory() -> Result<(), String> {
    use nix::sys::mman::{MlockAllFlags, mlockall};
    mlockall(MlockAllFlags::MCL_CURRENT | MlockAllFlags::MCL_FUTURE).map_err(|e| {
        format!(
            "memory not locked ({e}; needs CAP_IPC_LOCK or LimitMEMLOCK=infinity): a page the \
             kernel reclaims stalls this process when next touched"
        )
    })
}

/// SIGINT and SIGTERM set the returned flag; processes finish their loop and clean up.
pub fn stop_flag() -> std::io::Result<Arc<AtomicBool>> {
    let flag = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, flag.clone())?;
    }
    Ok(flag)
}
