//! Turns on the machine for the end-to-end tests, which run side by side in one binary: at
//! most [`STACKS`] stacks at a time, and stacks with emulated devices by their [`Devices`].
//! A test waiting for its turn holds a test thread and nothing else, so the binary runs more
//! threads than stacks (`.cargo/config.toml`) and the tests behind a waiting one go on.

use std::sync::{Condvar, Mutex, MutexGuard};

/// Stacks running at a time in this test binary. The end-to-end tests spend most of their time
/// waiting on the wall clock (a set executing at the arm's pace, a process restarting): six
/// side by side kept the binary at about 0.6 of a core on the 2-core VM.
pub const STACKS: usize = 6;

/// Stacks with emulated devices running at a time (`Devices::Shared`). Every emulated device
/// is a pseudo-terminal, whose bytes move only when the kernel's flip-buffer worker runs, at
/// nice 0 beside the suite's processes and the machine's own: on the 2-core VM with a busy loop
/// per core, every emulated arm of the suite at once (seven ptys watched by canaries) left that
/// worker runnable and not run for tens of seconds, every pty of the machine held meanwhile.
pub const SHARED_DEVICES: usize = 2;

/// How a stack with emulated devices shares the machine with the other such stacks. The
/// emulators stand in for hardware, which needs no CPU of the computer; no product runs two
/// arms' devices on its own CPUs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Devices {
    /// Beside other emulated arms: what the test asserts (safety invariants, recovery within
    /// its limits) holds on a busy machine too.
    Shared,
    /// No other emulated arm meanwhile: the test counts the bus's events and the freshness of
    /// its data, which two emulated arms beside the busy loops of a loaded machine left stale.
    Alone,
}

#[derive(Debug)]
struct Use {
    stacks: usize,
    shared: usize,
    alone: bool,
}

static USE: Mutex<Use> = Mutex::new(Use {
    stacks: 0,
    shared: 0,
    alone: false,
});
static CHANGED: Condvar = Condvar::new();

fn in_use() -> MutexGuard<'static, Use> {
    // A test that failed while holding it poisons nothing the next one needs.
    USE.lock().unwrap_or_else(|p| p.into_inner())
}

fn wait_until(mut free: impl FnMut(&mut Use) -> bool) {
    let mut u = in_use();
    while !free(&mut u) {
        u = CHANGED.wait(u).unwrap_or_else(|p| p.into_inner());
    }
}

/// A stack's place among the [`STACKS`]; given back on drop.
#[derive(Debug)]
pub(crate) struct StackTurn(());

impl StackTurn {
    pub(crate) fn take() -> Self {
        wait_until(|u| {
            let free = u.stacks < STACKS;
            u.stacks += usize::from(free);
            free
        });
        Self(())
    }
}

impl Drop for StackTurn {
    fn drop(&mut self) {
        in_use().stacks -= 1;
        CHANGED.notify_all();
    }
}

/// A turn for emulated devices; given back on drop. Taken before the stack's own
/// [`StackTurn`], never while holding one, so a test waiting here holds no stack's place.
#[derive(Debug)]
pub(crate) struct DevicesTurn(Devices);

impl DevicesTurn {
    pub(crate) fn take(devices: Devices) -> Self {
        // `Shared` turns do not wait for a waiting `Alone` one: the longest device tests are
        // shared, and run beside each other rather than one after the other around the
        // alone ones. There are few of them, so the alone ones wait at most that long.
        wait_until(|u| {
            let free = !u.alone
                && match devices {
                    Devices::Shared => u.shared < SHARED_DEVICES,
                    Devices::Alone => u.shared == 0,
                };
            if free {
                match devices {
                    Devices::Shared => u.shared += 1,
                    Devices::Alone => u.alone = true,
                }
            }
            free
        });
        Self(devices)
    }
}

impl Drop for DevicesTurn {
    fn drop(&mut self) {
        let mut u = in_use();
        match self.0 {
            Devices::Shared => u.shared -= 1,
            Devices::Alone => u.alone = false,
        }
        drop(u);
        CHANGED.notify_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
    use std::time::Duration;

    /// One test: the turns are the binary's, shared by every test in it.
    #[test]
    fn shared_turns_overlap_and_an_alone_one_overlaps_none() {
        // Two shared at once, without waiting.
        let a = DevicesTurn::take(Devices::Shared);
        let b = DevicesTurn::take(Devices::Shared);
        // An alone one waits for both.
        static GOT: AtomicBool = AtomicBool::new(false);
        let alone = std::thread::spawn(|| {
            let turn = DevicesTurn::take(Devices::Alone);
            GOT.store(true, Ordering::SeqCst);
            turn
        });
        std::thread::sleep(Duration::from_millis(50));
        assert!(!GOT.load(Ordering::SeqCst), "alone beside two shared");
        drop(a);
        assert!(!GOT.load(Ordering::SeqCst), "alone beside a shared one");
        drop(b);
        drop(alone.join().unwrap());

        // Many of both kinds: an alone turn never overlaps another devices turn, and at most
        // SHARED_DEVICES shared ones overlap.
        static SHARED_NOW: AtomicUsize = AtomicUsize::new(0);
        static ALONE_NOW: AtomicUsize = AtomicUsize::new(0);
        let threads: Vec<_> = (0..12)
            .map(|i| {
                std::thread::spawn(move || {
                    let devices = if i % 4 == 0 {
                        Devices::Alone
                    } else {
                        Devices::Shared
                    };
                    let _turn = DevicesTurn::take(devices);
                    let (mine, other) = match devices {
                        Devices::Alone => (&ALONE_NOW, &SHARED_NOW),
                        Devices::Shared => (&SHARED_NOW, &ALONE_NOW),
                    };
                    let now = mine.fetch_add(1, Ordering::SeqCst) + 1;
                    std::thread::sleep(Duration::from_millis(10));
                    assert_eq!(
                        other.load(Ordering::SeqCst),
                        0,
                        "{devices:?} beside the other"
                    );
                    assert!(devices == Devices::Shared || now == 1, "two alone at once");
                    assert!(now <= SHARED_DEVICES, "{now} shared at once");
                    mine.fetch_sub(1, Ordering::SeqCst);
                })
            })
            .collect();
        for t in threads {
            t.join().unwrap();
        }

        // At most STACKS stacks.
        let stacks: Vec<_> = (0..STACKS).map(|_| StackTurn::take()).collect();
        static MORE: AtomicBool = AtomicBool::new(false);
        let more = std::thread::spawn(|| {
            let turn = StackTurn::take();
            MORE.store(true, Ordering::SeqCst);
            turn
        });
        std::thread::sleep(Duration::from_millis(50));
        assert!(!MORE.load(Ordering::SeqCst), "a stack beyond {STACKS}");
        drop(stacks);
        drop(more.join().unwrap());
    }
}
