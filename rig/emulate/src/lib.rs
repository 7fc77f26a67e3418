//! Emulators of softarm's hardware on pseudo-terminals, speaking the real protocols: a bus of
//! Dynamixel Protocol 2.0 motors and an Ascension Bird tracker. Tests and `softarm-rig emulate`
//! run the real drivers against them. [`command`] is `softarm-rig emulate`.

pub mod bird;
pub mod canary;
pub mod command;
pub mod dynamixel;
pub mod pty;
pub mod rig;

/// The nice value of the emulators' device threads.
const DEVICE_NICE: i32 = -10;

/// Puts the calling thread, a device's, ahead of ordinary work where allowed (root or
/// CAP_SYS_NICE; else it stays at the default, said once): the devices it stands in for answer
/// in time whatever the computer is doing, and an emulator left waiting for a CPU on a loaded
/// machine looks to a driver like a bus that stopped answering.
pub(crate) fn run_as_device(what: &str) {
    // SAFETY: gettid and setpriority read their arguments only.
    let r = unsafe {
        let tid = nix::libc::gettid();
        nix::libc::setpriority(nix::libc::PRIO_PROCESS, tid as nix::libc::id_t, DEVICE_NICE)
    };
    static SAID: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    if r != 0 && !SAID.swap(true, std::sync::atomic::Ordering::Relaxed) {
        tracing::info!(
            "nice {DEVICE_NICE} for the emulated {what} refused (needs CAP_SYS_NICE): the \
             devices run at the default priority"
        );
    }
}
