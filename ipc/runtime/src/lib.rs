//! What every softarm process needs at run time, beneath the contract and the method:
//!
//! - [`clock`]: CLOCK_MONOTONIC ([`now_ns`], the stamp of every sample), [`clock::Ticker`]
//!   (fixed-rate loops on absolute deadlines), [`clock::Backoff`] (retries at doubling intervals).
//! - [`latch`]: the e-stop latch on disk ([`EstopLatch`]).
//! - [`file`]: [`file::write_atomic`], for every file written for others to read.
//! - [`identity`]: who a process joins an installed stack as ([`identity::join_with`]).
//! - [`stop_flag`]: SIGINT and SIGTERM as a flag every loop checks.

pub mod clock;
pub mod file;
pub mod identity;
pub mod latch;

use std::sync::Arc;
use std::sync::atomic::AtomicBool;

pub use clock::now_ns;
pub use latch::EstopLatch;

/// SIGINT and SIGTERM set the returned flag; processes finish their loop and clean up.
pub fn stop_flag() -> std::io::Result<Arc<AtomicBool>> {
    let flag = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, flag.clone())?;
    }
    Ok(flag)
}
