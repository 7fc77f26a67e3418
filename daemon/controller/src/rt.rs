//! Real-time set-up of the tick thread (locked memory, a pinned CPU, SCHED_FIFO), each refused
//! one a warning, and systemd's notifications: READY once the tick runs (sent by the service
//! thread), WATCHDOG while it does.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::thread::JoinHandle;

use softarm_model::config::Controller;

use crate::Shared;

/// Applies the configured real-time settings to the calling thread (the tick's).
pub(crate) fn setup(c: &Controller) {
    if c.mlockall {
        use nix::sys::mman::{MlockAllFlags, mlockall};
        if let Err(e) = mlockall(MlockAllFlags::MCL_CURRENT | MlockAllFlags::MCL_FUTURE) {
            tracing::warn!("mlockall refused ({e}); going on without locked memory");
        }
    }
    if let Some(cpu) = c.cpu {
        let mut set = nix::sched::CpuSet::new();
        if set.set(cpu).is_err()
            || nix::sched::sched_setaffinity(nix::unistd::Pid::from_raw(0), &set).is_err()
        {
            tracing::warn!("cannot pin the tick thread to CPU {cpu}; going on unpinned");
        }
    }
    if c.realtime_priority > 0 {
        let param = nix::libc::sched_param {
            sched_priority: c.realtime_priority,
        };
        // SAFETY: plain syscall on this thread with a valid parameter struct.
        let r = unsafe { nix::libc::sched_setscheduler(0, nix::libc::SCHED_FIFO, &param) };
        if r != 0 {
            tracing::warn!(
                "SCHED_FIFO priority {} refused (needs CAP_SYS_NICE or an rtprio limit); going on \
                 with normal scheduling",
                c.realtime_priority
            );
        }
    }
}

/// READY=1 to systemd (once, when the tick first ran).
pub(crate) fn notify_ready() {
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Ready]);
}

/// WATCHDOG=1 to systemd only while the tick's heartbeat advances.
pub(crate) fn start_watchdog(shared: Arc<Shared>) -> Option<JoinHandle<()>> {
    let period = sd_notify::watchdog_enabled()? / 2;
    std::thread::Builder::new()
        .name("controller-watchdog".into())
        .spawn(move || {
            let mut last = 0;
            loop {
                std::thread::sleep(period);
                let beat = shared.heartbeat.load(Ordering::Relaxed);
                if beat != last {
                    let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
                }
                last = beat;
            }
        })
        .ok()
}
