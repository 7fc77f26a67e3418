//! Fixed-rate loops on absolute deadlines: `next += period; clock_nanosleep(TIMER_ABSTIME)`.
//! Relative sleeps drift by the loop's own run time; these do not. Overruns are counted and the
//! missed cycles skipped, never caught up in a burst.

use nix::sys::time::TimeSpec;
use nix::time::{ClockId, ClockNanosleepFlags, clock_nanosleep};

/// Nanoseconds on CLOCK_MONOTONIC: the stamp of every sample.
pub fn now_ns() -> u64 {
    let ts = nix::time::clock_gettime(ClockId::CLOCK_MONOTONIC).expect("CLOCK_MONOTONIC exists");
    ts.tv_sec() as u64 * 1_000_000_000 + ts.tv_nsec() as u64
}

/// What one wait observed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Wake {
    /// How late the thread woke after its deadline (ns).
    pub latency_ns: u64,
    /// Whole cycles that were skipped because the deadline had long passed: this wake stands for
    /// the latest deadline passed, `missed + 1` periods after the previous wake's. A loop that
    /// keeps time in ticks advances by that much to follow the clock.
    pub missed: u64,
}

pub struct Ticker {
    period_ns: u64,
    next_ns: u64,
    overruns: u64,
}

impl Ticker {
    /// A ticker whose first deadline is one period from now.
    pub fn new(rate_hz: f64) -> Self {
        let period_ns = (1e9 / rate_hz).round().max(1.0) as u64;
        Self {
            period_ns,
            next_ns: now_ns(),
            overruns: 0,
        }
    }

    /// A ticker whose first deadline is `first_ns` (CLOCK_MONOTONIC), so two loops can run at
    /// the same rate with a fixed phase between them.
    pub fn starting_at(rate_hz: f64, first_ns: u64) -> Self {
        let period_ns = (1e9 / rate_hz).round().max(1.0) as u64;
        Self {
            period_ns,
            next_ns: first_ns.saturating_sub(period_ns),
            overruns: 0,
        }
    }

    /// A ticker on the grid `epoch_ns + k · period` whose first deadline is the first of the
    /// grid at or after `now_ns`: a loop that joins another's phase late (its start took a
    /// while) begins on time rather than with every period it was not yet running counted
    /// as an overrun.
    pub fn joining(rate_hz: f64, epoch_ns: u64, now_ns: u64) -> Self {
        let period_ns = (1e9 / rate_hz).round().max(1.0) as u64;
        let behind = now_ns.saturating_sub(epoch_ns);
        let first = epoch_ns + behind.div_ceil(period_ns) * period_ns;
        Self::starting_at(rate_hz, first)
    }

    /// Cycles skipped so far.
    pub fn overruns(&self) -> u64 {
        self.overruns
    }

    /// Sleeps until the next deadline. Allocates nothing; the only syscalls are the sleep and
    /// the clock read.
    pub fn wait(&mut self) -> Wake {
        let next = self.next_deadline();
        let ts = TimeSpec::new((next / 1_000_000_000) as _, (next % 1_000_000_000) as _);
        // EINTR: a signal arrived; the deadline is absolute, so just sleep again.
        while let Err(nix::errno::Errno::EINTR) = clock_nanosleep(
            ClockId::CLOCK_MONOTONIC,
            ClockNanosleepFlags::TIMER_ABSTIME,
            &ts,
        ) {}
        self.woke_at(now_ns())
    }

    fn next_deadline(&mut self) -> u64 {
        self.next_ns += self.period_ns;
        self.next_ns
    }

    /// The accounting of a wake-up at `now` for the deadline just waited for: missed deadlines
    /// are counted and skipped.
    fn woke_at(&mut self, now: u64) -> Wake {
        let latency_ns = now.saturating_sub(self.next_ns);
        let missed = latency_ns / self.period_ns;
        if missed > 0 {
            self.next_ns += missed * self.period_ns;
            self.overruns += missed;
        }
        Wake { latency_ns, missed }
    }
}

/// When to try again after failures: at first `first_ns` after one, doubling per failure up to
/// `max_ns`; a success starts over. For reopening a port, asking a silent device again.
#[derive(Debug, Clone, Copy)]
pub struct Backoff {
    first_ns: u64,
    max_ns: u64,
    wait_ns: u64,
    next_ns: u64,
}

impl Backoff {
    pub fn new(first_ns: u64, max_ns: u64) -> Self {
        Self {
            first_ns,
            max_ns,
            wait_ns: first_ns,
            next_ns: 0,
        }
    }

    /// Whether it is time to try.
    pub fn ready(&self, now_ns: u64) -> bool {
        now_ns >= self.next_ns
    }

    /// A try failed at `now_ns`: the next waits, longer each time.
    pub fn failed(&mut self, now_ns: u64) {
        self.next_ns = now_ns.saturating_add(self.wait_ns);
        self.wait_ns = self.wait_ns.saturating_mul(2).min(self.max_ns);
    }

    /// A try succeeded: the next may come at once, and a failure waits `first_ns` again.
    pub fn succeeded(&mut self) {
        self.wait_ns = self.first_ns;
        self.next_ns = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Joining late keeps the phase and counts no overrun for the time it was not running;
    /// joining early starts at the epoch.
    #[test]
    fn a_ticker_joining_late_starts_on_the_grid_without_overruns() {
        const MS: u64 = 1_000_000;
        let epoch = 1_000 * MS;
        let mut t = Ticker::joining(500.0, epoch, epoch + 10_001 * MS);
        let first = t.next_deadline();
        assert_eq!(first, epoch + 10_002 * MS);
        let wake = t.woke_at(first + MS / 2);
        assert_eq!((wake.missed, t.overruns()), (0, 0));
        let mut early = Ticker::joining(500.0, epoch, epoch - 5 * MS);
        assert_eq!(early.next_deadline(), epoch);
        let mut exact = Ticker::joining(500.0, epoch, epoch + 4 * MS);
        assert_eq!(exact.next_deadline(), epoch + 4 * MS);
        // Started at the epoch instead, the same late start is 5000 overruns.
        let mut at_epoch = Ticker::starting_at(500.0, epoch);
        at_epoch.next_deadline();
        at_epoch.woke_at(first + MS / 2);
        assert_eq!(at_epoch.overruns(), 5001);
    }

    #[test]
    fn a_backoff_doubles_up_to_its_cap_and_starts_over_on_success() {
        const MS: u64 = 1_000_000;
        let mut b = Backoff::new(10 * MS, 45 * MS);
        assert!(b.ready(0));
        let mut waits = Vec::new();
        let mut t = 1000 * MS;
        for _ in 0..5 {
            b.failed(t);
            let mut next = t;
            while !b.ready(next) {
                next += MS;
            }
            waits.push((next - t) / MS);
            t = next;
        }
        assert_eq!(waits, [10, 20, 40, 45, 45]);
        b.succeeded();
        assert!(b.ready(t));
        b.failed(t);
        assert!(!b.ready(t + 9 * MS) && b.ready(t + 10 * MS));
    }

    /// A controlled sequence of wake-ups: late ones skip exactly the deadlines that passed, and
    /// the next deadline stays on the grid.
    #[test]
    fn late_wakes_skip_the_deadlines_that_passed() {
        const MS: u64 = 1_000_000;
        let mut t = Ticker::starting_at(1000.0, 10 * MS);
        let wake = |t: &mut Ticker, now: u64| {
            t.next_deadline();
            let w = t.woke_at(now);
            (w, t.next_ns)
        };
        // On time, and late by less than a period: nothing skipped.
        assert_eq!(wake(&mut t, 10 * MS).0.missed, 0);
        assert_eq!(
            wake(&mut t, 11 * MS + MS / 2),
            (
                Wake {
                    latency_ns: MS / 2,
                    missed: 0
                },
                11 * MS
            )
        );
        // Deadline 12 ms, woken at 15.3 ms: 13, 14 and 15 ms have passed too. This wake stands
        // for 15 ms; the next deadline is 16 ms.
        let (w, deadline) = wake(&mut t, 15 * MS + MS * 3 / 10);
        assert_eq!((w.missed, deadline), (3, 15 * MS));
        assert_eq!(
            wake(&mut t, 16 * MS),
            (
                Wake {
                    latency_ns: 0,
                    missed: 0
                },
                16 * MS
            )
        );
        // Exactly one period late skips one.
        assert_eq!(wake(&mut t, 18 * MS).0.missed, 1);
        assert_eq!(t.overruns(), 4);
        // A clock read before the deadline (not possible after an absolute sleep) skips nothing.
        assert_eq!(
            wake(&mut t, 18 * MS).0,
            Wake {
                latency_ns: 0,
                missed: 0
            }
        );
    }

    // Only what holds on a loaded machine: a deadline never passes early, and the overrun
    // counter is exactly the sum of the cycles each wait reports as missed, however many that is.
    #[test]
    fn deadlines_are_absolute_and_overruns_skip() {
        let mut t = Ticker::new(1000.0);
        let start = now_ns();
        let mut missed = 0;
        for _ in 0..50 {
            missed += t.wait().missed;
        }
        let elapsed = now_ns() - start;
        // 50 periods of 1 ms at least (absolute deadlines cannot run early).
        assert!(elapsed >= 49_000_000, "{elapsed}");
        assert_eq!(t.overruns(), missed);
        std::thread::sleep(std::time::Duration::from_millis(10));
        let before = t.overruns();
        let w = t.wait();
        assert!(w.missed >= 8, "{w:?}");
        assert_eq!(t.overruns() - before, w.missed);
    }
}
