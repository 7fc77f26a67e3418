//! Processes a test starts, and waiting for what they do.

use std::process::Child;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;

/// A process the test started: killed if the test ends without stopping it, so a failed
/// assertion leaves nothing running.
#[derive(Debug)]
pub struct Guard(pub Child);

impl std::ops::Deref for Guard {
    type Target = Child;
    fn deref(&self) -> &Child {
        &self.0
    }
}

impl std::ops::DerefMut for Guard {
    fn deref_mut(&mut self) -> &mut Child {
        &mut self.0
    }
}

impl Drop for Guard {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

impl Guard {
    /// SIGTERM, then its exit status; killed and a panic if it has not exited within `limit`.
    pub fn stop(mut self, limit: Duration) -> std::process::ExitStatus {
        let _ = kill(Pid::from_raw(self.0.id() as i32), Signal::SIGTERM);
        let start = Instant::now();
        loop {
            if let Some(status) = self.0.try_wait().unwrap() {
                return status;
            }
            if start.elapsed() > limit {
                let _ = self.0.kill();
                panic!("the process did not stop on SIGTERM within {limit:?}");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// The seed of a seeded fault test: `SOFTARM_FAULT_SEED` if set, else the test's own. If the
/// test fails, whichever assertion failed, it says how to rerun the same sequence.
#[derive(Debug)]
pub struct FaultSeed(pub u64);

impl FaultSeed {
    pub fn from_env(default: u64) -> Self {
        Self(
            std::env::var("SOFTARM_FAULT_SEED")
                .ok()
                .and_then(|s| s.parse().ok())
                .unwrap_or(default),
        )
    }
}

impl Drop for FaultSeed {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!(
                "failed with seed {0}: rerun with SOFTARM_FAULT_SEED={0}",
                self.0
            );
        }
    }
}

/// Polls `f` every 20 ms until it gives `Some`; a panic naming `what` after `limit`.
pub fn eventually<T>(what: &str, limit: Duration, mut f: impl FnMut() -> Option<T>) -> T {
    let start = Instant::now();
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(start.elapsed() < limit, "waited {limit:?} for {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::process::Command;

    #[test]
    fn a_guard_kills_what_it_holds_and_stop_asks_first() {
        let pid = {
            let g = Guard(Command::new("sleep").arg("30").spawn().unwrap());
            g.id() as i32
        };
        // Reaped by the guard: gone, not a zombie.
        assert!(!crate::alive(pid));
        let g = Guard(Command::new("sleep").arg("30").spawn().unwrap());
        let status = g.stop(Duration::from_secs(5));
        assert_eq!(
            std::os::unix::process::ExitStatusExt::signal(&status),
            Some(15)
        );
        assert_eq!(eventually("3", Duration::from_secs(1), || Some(3)), 3);
    }
}
