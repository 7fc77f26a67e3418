//! End to end: systemd's notify protocol against a fake NOTIFY_SOCKET, as `Type=notify` units
//! with `WatchdogSec=` see it. The controller says READY=1 once it ticks and WATCHDOG=1 only
//! while the tick's heartbeat advances: a frozen loop (the tick thread alone stopped from
//! outside, by ptrace, the rest of the process running on) stops the watchdog, so systemd
//! would kill and restart it. The learner says READY=1 once its
//! ports are open, and what it waits for.

use std::os::unix::net::UnixDatagram;
use std::process::Stdio;
use std::time::{Duration, Instant};

use nix::sys::ptrace;
use nix::unistd::Pid;
use softarm_test_support::{Guard, TestStack};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");

struct FakeSystemd {
    socket: UnixDatagram,
    path: std::path::PathBuf,
}

impl FakeSystemd {
    fn new(s: &TestStack) -> Self {
        let path = s.dir.join("notify.sock");
        let socket = UnixDatagram::bind(&path).unwrap();
        socket
            .set_read_timeout(Some(Duration::from_millis(100)))
            .unwrap();
        Self { socket, path }
    }

    fn spawn(&self, s: &TestStack, role: &str, env: &[(&str, &str)]) -> Guard {
        let mut c = s.command();
        c.arg(role)
            .arg("--config")
            .arg(&s.config)
            .env("NOTIFY_SOCKET", &self.path)
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        for (k, v) in env {
            c.env(k, v);
        }
        Guard::spawn(&mut c)
    }

    /// Every message until `done` says so or `limit` passes.
    fn until(&self, limit: Duration, done: impl Fn(&[String]) -> bool) -> Vec<String> {
        let start = Instant::now();
        let mut got = Vec::new();
        let mut buf = [0u8; 4096];
        while start.elapsed() < limit && !done(&got) {
            if let Ok(n) = self.socket.recv(&mut buf) {
                // One datagram may carry several lines.
                for line in String::from_utf8_lossy(&buf[..n]).lines() {
                    got.push(line.to_string());
                }
            }
        }
        got
    }
}

#[test]
fn the_controller_is_ready_once_it_ticks_and_its_watchdog_stops_with_the_loop() {
    let s = TestStack::new(BIN, "notify-controller", false);
    let systemd = FakeSystemd::new(&s);
    // A watchdog of 200 ms asks every 100 ms.
    let child = systemd.spawn(&s, "controller", &[("WATCHDOG_USEC", "200000")]);
    let mut got = systemd.until(Duration::from_secs(60), |m| {
        m.iter().filter(|l| *l == "WATCHDOG=1").count() >= 3
    });
    // The tick runs on the process's main thread: stopped alone (PTRACE_INTERRUPT stops the
    // thread it is given, not its process), as a deadlocked or starved loop would stand.
    let tick = Pid::from_raw(child.id() as i32);
    ptrace::seize(tick, ptrace::Options::empty()).expect("ptrace the controller's tick thread");
    ptrace::interrupt(tick).unwrap();
    got.extend(systemd.until(Duration::from_secs(60), |m| {
        m.iter().any(|l| l.contains("tick stalled"))
    }));
    let stalled = got
        .iter()
        .position(|l| l.contains("tick stalled"))
        .unwrap_or_else(|| panic!("the stall was never reported: {got:?}"));
    let ready = got
        .iter()
        .position(|l| l == "READY=1")
        .unwrap_or_else(|| panic!("no READY=1: {got:?}"));
    let beats = got[ready..stalled]
        .iter()
        .filter(|l| *l == "WATCHDOG=1")
        .count();
    assert!(beats >= 2, "the watchdog ran while the loop did: {got:?}");
    assert!(
        got[..ready].iter().all(|l| l != "WATCHDOG=1"),
        "a watchdog before READY: {got:?}"
    );
    assert!(
        got[ready..]
            .iter()
            .any(|l| l.starts_with("STATUS=IDLE") || l.starts_with("STATUS=HOLD")),
        "STATUS says the state: {got:?}"
    );
    // Frozen: a second of silence from the watchdog while the process lives on.
    let after = systemd.until(Duration::from_secs(1), |_| false);
    assert!(
        after.iter().all(|l| l != "WATCHDOG=1"),
        "the watchdog went on with the loop frozen: {after:?}"
    );
    assert!(
        after.iter().any(|l| l.contains("tick stalled")),
        "{after:?}"
    );
    // Let go, it ticks again and the watchdog comes back.
    ptrace::detach(tick, None).unwrap();
    let again = systemd.until(Duration::from_secs(60), |m| {
        m.iter().any(|l| l == "WATCHDOG=1")
    });
    assert!(again.iter().any(|l| l == "WATCHDOG=1"), "{again:?}");
    child.stop(Duration::from_secs(20));
}

#[test]
fn the_learner_is_ready_once_its_ports_are_open_and_says_what_it_waits_for() {
    let s = TestStack::new(BIN, "notify-learner", false);
    let systemd = FakeSystemd::new(&s);
    let child = systemd.spawn(&s, "learner", &[("WATCHDOG_USEC", "200000")]);
    let got = systemd.until(Duration::from_secs(30), |m| {
        m.iter().filter(|l| *l == "WATCHDOG=1").count() >= 2
    });
    let ready = got.iter().position(|l| l == "READY=1");
    assert!(ready.is_some(), "no READY=1: {got:?}");
    assert!(
        got.iter()
            .any(|l| l == "STATUS=waiting for a model bundle (softarm train)"),
        "{got:?}"
    );
    assert!(
        got.iter().filter(|l| *l == "WATCHDOG=1").count() >= 2,
        "{got:?}"
    );
    child.stop(Duration::from_secs(20));
}
