//! What every softarm process needs at run time, beneath the contract and the method:
//!
//! - [`clock`]: CLOCK_MONOTONIC ([`now_ns`], the stamp of every sample), [`clock::Ticker`]
//!   (fixed-rate loops on absolute deadlines), [`clock::Backoff`] (retries at doubling intervals).
//! - [`latch`]: the e-stop latch on disk ([`EstopLatch`]).
//! - [`file`]: [`file::write_atomic`], for every file written for others to read.

pub mod clock;
pub mod file;
pub mod latch;

pub use clock::now_ns;
pub use latch::EstopLatch;
