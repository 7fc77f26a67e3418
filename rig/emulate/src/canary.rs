//! The kernel's pseudo-terminal path, watched. A pty's bytes reach its reader only once the
//! tty layer's flip-buffer work has run on a kernel worker thread (`flush_to_ldisc`), and a
//! reader's `poll` waits for that work. On a loaded machine that worker can be left without a
//! CPU for seconds (measured on the 2-core VM under two busy loops and the suite: the emulated
//! bus's thread blocked in `n_tty_poll` → `__flush_work` for 1–12 s with its 2 ms time-out,
//! the worker runnable and not run, and an unrelated pty echo stalled 11 s at the same time).
//! Every pty is then held, whoever reads it and at whatever priority, and no driver, emulator
//! or real serial adapter (the same tty layer) can do anything about it. [`Canary`] measures
//! those stalls on a pty of its own, so that what a driver did in them can be told from what
//! it did on its own.

use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::AsFd;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use softarm_runtime::now_ns;

use crate::pty::Pty;

/// A round trip longer than this is a stall: a pty echoed at a device's priority answers
/// within a few milliseconds even beside a busy loop per core (max 12 ms in 30 s measured).
pub const STALL_NS: u64 = 20_000_000;
/// One round trip started this often. The pty path's stalls that matter last seconds, and any
/// stall longer than this holds a round trip; each trip is work for the kernel's flip-buffer
/// worker, the very thread a loaded machine leaves waiting (every emulated rig has a canary,
/// and at 5 ms theirs were a third of the suite's pty traffic).
const PERIOD: Duration = Duration::from_millis(50);

/// A time the kernel held the pty path: from a byte's sending to its echo's arrival (ns, the
/// `softarm_runtime::now_ns` clock).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Stall {
    pub from_ns: u64,
    pub to_ns: u64,
}

#[derive(Debug, Default)]
struct Seen {
    stalls: Mutex<Vec<Stall>>,
    /// When the byte in flight was sent; 0 when none is.
    waiting_since_ns: AtomicU64,
    /// Round trips completed.
    trips: AtomicU64,
}

/// A byte sent around a pty of its own every 5 ms, by two threads at the emulators' priority,
/// until dropped.
#[derive(Debug)]
pub struct Canary {
    seen: Arc<Seen>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

impl Canary {
    pub fn start() -> io::Result<Self> {
        let mut pty = Pty::open()?;
        let mut port = pty.slave_file()?;
        let seen = Arc::new(Seen::default());
        let stop = Arc::new(AtomicBool::new(false));
        let echo = {
            let stop = stop.clone();
            std::thread::Builder::new()
                .name("pty canary echo".into())
                .spawn(move || {
                    crate::run_as_device("pty canary");
                    let mut buf = [0u8; 64];
                    while !stop.load(Ordering::Relaxed) {
                        match pty.read_timeout(&mut buf, Duration::from_millis(20)) {
                            Ok(0) => {}
                            Ok(n) if pty.write_all(&buf[..n]).is_ok() => {}
                            _ => return,
                        }
                    }
                })?
        };
        let ping = {
            let (seen, stop) = (seen.clone(), stop.clone());
            std::thread::Builder::new()
                .name("pty canary".into())
                .spawn(move || {
                    crate::run_as_device("pty canary");
                    while !stop.load(Ordering::Relaxed) {
                        if round_trip(&mut port, &seen, &stop).is_err() {
                            return;
                        }
                    }
                })?
        };
        Ok(Self {
            seen,
            stop,
            threads: vec![echo, ping],
        })
    }

    /// The stalls that have ended, oldest first.
    pub fn ended(&self) -> Vec<Stall> {
        self.watch().ended()
    }

    /// The stalls seen so far, the one going on included (up to now).
    pub fn stalls(&self) -> Vec<Stall> {
        self.watch().stalls()
    }

    /// How long the path was stalled within [from_ns, to_ns] (ns).
    pub fn stalled_ns(&self, from_ns: u64, to_ns: u64) -> u64 {
        self.watch().stalled_ns(from_ns, to_ns)
    }

    /// Whether the path was stalled at some time within [from_ns, to_ns].
    pub fn stalled_within(&self, from_ns: u64, to_ns: u64) -> bool {
        self.stalls()
            .iter()
            .any(|s| s.from_ns <= to_ns && s.to_ns >= from_ns)
    }

    /// What the canary measures, readable from anywhere (a test's waits) for as long as it
    /// runs; after it stopped, what it measured until then.
    pub fn watch(&self) -> Watch {
        Watch {
            seen: self.seen.clone(),
            stop: self.stop.clone(),
        }
    }
}

/// A [`Canary`]'s record, shared.
#[derive(Debug, Clone)]
pub struct Watch {
    seen: Arc<Seen>,
    stop: Arc<AtomicBool>,
}

impl Watch {
    /// The stalls that have ended, oldest first.
    pub fn ended(&self) -> Vec<Stall> {
        self.seen
            .stalls
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// The stalls seen so far, the one going on included (up to now) while the canary runs.
    pub fn stalls(&self) -> Vec<Stall> {
        let mut out = self.ended();
        let since = self.seen.waiting_since_ns.load(Ordering::Acquire);
        let now = now_ns();
        let running = !self.stop.load(Ordering::Relaxed);
        if running && since != 0 && now.saturating_sub(since) > STALL_NS {
            out.push(Stall {
                from_ns: since,
                to_ns: now,
            });
        }
        out
    }

    /// How long the path was stalled within [from_ns, to_ns] (ns).
    pub fn stalled_ns(&self, from_ns: u64, to_ns: u64) -> u64 {
        self.stalls()
            .iter()
            .map(|s| s.to_ns.min(to_ns).saturating_sub(s.from_ns.max(from_ns)))
            .sum()
    }
}

/// One byte there and back, a stall recorded if it took too long; then the rest of the period.
fn round_trip(port: &mut File, seen: &Seen, stop: &AtomicBool) -> io::Result<()> {
    let sent = now_ns();
    seen.waiting_since_ns.store(sent, Ordering::Release);
    port.write_all(b"c")?;
    let mut byte = [0u8; 1];
    loop {
        let mut fds = [PollFd::new(port.as_fd(), PollFlags::POLLIN)];
        match poll(&mut fds, PollTimeout::from(100u16)) {
            Ok(0) | Err(nix::errno::Errno::EINTR) if !stop.load(Ordering::Relaxed) => continue,
            Ok(0) | Err(nix::errno::Errno::EINTR) => return Ok(()),
            Ok(_) => {
                port.read_exact(&mut byte)?;
                break;
            }
            Err(e) => return Err(e.into()),
        }
    }
    let back = now_ns();
    seen.waiting_since_ns.store(0, Ordering::Release);
    seen.trips.fetch_add(1, Ordering::Relaxed);
    if back - sent > STALL_NS {
        seen.stalls
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push(Stall {
                from_ns: sent,
                to_ns: back,
            });
    }
    let next = Duration::from_nanos((sent + PERIOD.as_nanos() as u64).saturating_sub(back));
    std::thread::sleep(next);
    Ok(())
}

impl Drop for Canary {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stall_is_found_where_it_was_and_one_going_on_counts_up_to_now() {
        let c = Canary {
            seen: Arc::default(),
            stop: Arc::default(),
            threads: Vec::new(),
        };
        let t0 = now_ns();
        let seen = &c.seen;
        seen.stalls.lock().unwrap().push(Stall {
            from_ns: t0 + 1_000,
            to_ns: t0 + 2_000,
        });
        assert!(c.stalled_within(t0, t0 + 1_500));
        assert!(c.stalled_within(t0 + 1_500, t0 + 5_000));
        assert!(!c.stalled_within(t0 + 2_001, t0 + 5_000));
        assert_eq!(c.stalled_ns(t0 + 1_500, t0 + 10_000), 500);
        // A byte in flight for longer than a stall counts up to now.
        seen.waiting_since_ns
            .store(t0 - 2 * STALL_NS, Ordering::Release);
        assert!(c.stalled_within(t0 - STALL_NS, t0 - STALL_NS));
    }

    #[test]
    fn a_byte_goes_around() {
        let c = Canary::start().unwrap();
        // A liveness check, not a timing one: a loaded machine holds ptys for seconds.
        let start = std::time::Instant::now();
        while c.seen.trips.load(Ordering::Relaxed) < 3 && start.elapsed() < Duration::from_secs(120)
        {
            std::thread::sleep(Duration::from_millis(1));
        }
        assert!(
            c.seen.trips.load(Ordering::Relaxed) >= 3,
            "three echoes did not come in 120 s"
        );
    }
}
