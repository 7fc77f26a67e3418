//! Real-time set-up of the tick thread (a pinned CPU, SCHED_FIFO; the process's memory is
//! locked where it starts, `src/lib.rs::keep_pace`), each refused
//! one a warning, and systemd's notifications: READY once the tick runs (sent by the service
//! thread), WATCHDOG while it does, STATUS with its state.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use softarm_ipc::ControllerState;

use softarm_config::Controller;

use crate::Shared;

/// Applies the configured real-time settings to the calling thread (the tick's).
pub(crate) fn setup(c: &Controller) {
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

/// READY=1 has been sent: the watchdog says nothing before it.
static READY: AtomicBool = AtomicBool::new(false);

/// READY=1 to systemd (once, when the tick first ran).
pub(crate) fn notify_ready() {
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Ready]);
    READY.store(true, Ordering::Release);
}

/// How often STATUS= is refreshed when the watchdog does not ask for more.
const STATUS_EVERY: Duration = Duration::from_secs(1);

/// Under systemd (NOTIFY_SOCKET set), a low-priority thread that sends WATCHDOG=1 only while
/// the tick's heartbeat advances (a frozen loop gets the controller killed and restarted), and
/// STATUS= with the state and tick count.
pub(crate) fn start_watchdog(shared: Arc<Shared>) -> Option<JoinHandle<()>> {
    std::env::var_os("NOTIFY_SOCKET")?;
    let watchdog = sd_notify::watchdog_enabled();
    let period = watchdog.map_or(STATUS_EVERY, |w| (w / 2).min(STATUS_EVERY));
    std::thread::Builder::new()
        .name("controller-watchdog".into())
        .spawn(move || {
            let mut last = 0;
            loop {
                std::thread::sleep(period);
                let beat = shared.heartbeat.load(Ordering::Relaxed);
                let state = ControllerState::from_u32(shared.state.load(Ordering::Relaxed))
                    .map_or("?", |s| s.name());
                // Before its first tick the loop has not stalled: it has not started (a
                // loaded machine can take longer than a watchdog period to get there).
                let status = if beat == 0 {
                    format!("{state}, starting")
                } else if beat == last {
                    format!("{state}, tick stalled at {beat}")
                } else {
                    format!("{state}, {beat} ticks")
                };
                let _ = sd_notify::notify(&[sd_notify::NotifyState::Status(&status)]);
                // The service thread says READY=1 once the tick has run; a heartbeat seen
                // first here (the service thread waiting for a CPU) must not make the watchdog
                // speak before it.
                if beat != last && watchdog.is_some() && READY.load(Ordering::Acquire) {
                    let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
                }
                last = beat;
            }
        })
        .ok()
}
