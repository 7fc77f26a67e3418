//! Fault injection, end to end: the sim, the learner and the controller SIGKILLed at seeded
//! random moments of running executions, `softarm up` restarting them. An independent
//! subscriber of `setpoint` and `stats` checks what a person beside the arm relies on: no
//! setpoint outside the actuator limits, no step faster than the slew limit (within each
//! controller's stream, and across a restart no jump), HOLD within twice the stale age once
//! the sim is gone, executions going on after a restart, no execution's statistics twice.
//! A failure names the seed; SOFTARM_FAULT_SEED=N reruns that sequence.

use std::collections::BTreeSet;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use rand::{RngExt, SeedableRng};
use softarm_ipc::{ControllerState, Namespace, Node};
use softarm_test_support::{DEMO_WAYPOINTS, TestStack, set_id};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");
/// The test config's (the default's) `controller.slew_per_s` and `tracker_timeout_ms`.
const SLEW_PER_S: f64 = 1.5;
const STALE_NS: u64 = 100_000_000;

#[derive(Debug, Clone, Copy)]
struct Seen {
    stamp_ns: u64,
    seq: u64,
    actuation: [f64; 6],
    state: u32,
}

/// The independent observer: every setpoint and execution's stats, on a thread of its own.
struct Observer {
    done: Arc<AtomicBool>,
    seen: Arc<Mutex<Vec<Seen>>>,
    stats: Arc<Mutex<Vec<(u64, u32)>>>,
    thread: std::thread::JoinHandle<()>,
}

impl Observer {
    fn start(namespace: &str) -> Self {
        let done = Arc::new(AtomicBool::new(false));
        let seen: Arc<Mutex<Vec<Seen>>> = Arc::default();
        let stats: Arc<Mutex<Vec<(u64, u32)>>> = Arc::default();
        let thread = {
            let (done, seen, stats) = (done.clone(), seen.clone(), stats.clone());
            let ns = Namespace::new(namespace).unwrap();
            std::thread::spawn(move || {
                let node = Node::open(ns, "observer").unwrap();
                let setpoints = node.subscriber(&node.setpoint().unwrap()).unwrap();
                let stat = node.subscriber(&node.stats().unwrap()).unwrap();
                while !done.load(Ordering::Relaxed) {
                    while let Ok(Some(p)) = setpoints.receive() {
                        seen.lock().unwrap().push(Seen {
                            stamp_ns: p.stamp_ns,
                            seq: p.seq,
                            actuation: p.actuation,
                            state: p.state,
                        });
                    }
                    while let Ok(Some(x)) = stat.receive() {
                        stats.lock().unwrap().push((x.set_id, x.execution));
                    }
                    std::thread::sleep(Duration::from_micros(500));
                }
            })
        };
        Self {
            done,
            seen,
            stats,
            thread,
        }
    }

    fn finish(self) -> (Vec<Seen>, Vec<(u64, u32)>) {
        self.done.store(true, Ordering::Relaxed);
        self.thread.join().unwrap();
        let seen = self.seen.lock().unwrap().clone();
        let stats = self.stats.lock().unwrap().clone();
        (seen, stats)
    }
}

/// The invariants over what the observer saw; `outages` are (from, to) when the sim surely
/// published nothing (killed, or stopped). Returns how many controller runs the setpoints came
/// from.
fn check(seen: &[Seen], stats: &[(u64, u32)], outages: &[(u64, u64)], run: &str) -> usize {
    assert!(seen.len() > 5000, "{run}: {} setpoints", seen.len());
    // Limits, and the slew within each controller's stream (a restarted controller starts its
    // sequence again); across a restart, no jump.
    let mut streams = 1;
    for w in seen.windows(2) {
        for a in 0..6 {
            let v = w[1].actuation[a];
            assert!(
                (0.0..=1.0).contains(&v),
                "{run}: setpoint {v} outside [0, 1]"
            );
        }
        let restarted = w[1].seq <= w[0].seq;
        streams += usize::from(restarted);
        let dt = w[1].stamp_ns.saturating_sub(w[0].stamp_ns) as f64 * 1e-9;
        // One tick of slack for the limiter's own period; across a restart the new controller
        // starts from the measured state, which backlash and lag leave within 0.02.
        let allowed = if restarted {
            0.02
        } else {
            SLEW_PER_S * (dt + 0.002) + 1e-9
        };
        for a in 0..6 {
            let step = (w[1].actuation[a] - w[0].actuation[a]).abs();
            assert!(
                step <= allowed,
                "{run}: actuator {a} stepped {step} in {dt} s (allowed {allowed}, restart \
                 {restarted}) at {:?}",
                w[1]
            );
        }
    }
    // The sim gone: from twice the stale age on, for as long as it surely stays gone, nothing
    // is executed on stale data, and the controller says HOLD.
    for &(k, end) in outages {
        let executing = seen
            .iter()
            .filter(|p| (k + 2 * STALE_NS..end).contains(&p.stamp_ns))
            .filter(|p| p.state == ControllerState::Execute as u32)
            .count();
        assert_eq!(
            executing, 0,
            "{run}: executed on stale data after the sim went"
        );
        assert!(
            seen.iter()
                .any(|p| p.stamp_ns > k && p.state == ControllerState::Hold as u32),
            "{run}: no HOLD after the sim went"
        );
    }
    // No execution's statistics twice.
    let unique: BTreeSet<_> = stats.iter().collect();
    assert_eq!(
        unique.len(),
        stats.len(),
        "{run}: duplicate stats {stats:?}"
    );
    streams
}

#[test]
fn random_kills_break_no_safety_invariant() {
    let seed: u64 = std::env::var("SOFTARM_FAULT_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(7);
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut s = TestStack::new(BIN, "faults", true);
    s.up();

    let observer = Observer::start(&s.namespace);
    let stats = observer.stats.clone();

    let pid_of =
        |s: &TestStack, role: &str| s.children().into_iter().find(|c| c.0 == role).map(|c| c.1);
    let mut sim_kills = Vec::new();
    let mut sets = Vec::new();
    for round in 0..4 {
        // A set under way (a killed controller forgets its set: submit again).
        let st = s.status();
        if st["controller"]["state"] != "EXECUTE" {
            let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 20);
            assert_eq!(code, 0, "round {round} (seed {seed}): {out}{err}");
            sets.push(set_id(&out));
            s.wait_status("EXECUTE", Duration::from_secs(60), |st| {
                st["controller"]["state"] == "EXECUTE"
            });
        }
        std::thread::sleep(Duration::from_millis(rng.random_range(300..3000)));
        let victim = ["sim", "learner", "controller"][rng.random_range(0..3usize)];
        let old = pid_of(&s, victim).unwrap_or_else(|| panic!("no {victim}: {}", s.logs()));
        kill(Pid::from_raw(old), Signal::SIGKILL).unwrap();
        let killed = softarm_ipc::now_ns();
        eprintln!("round {round} (seed {seed}): killed {victim}");
        if victim == "sim" {
            // `up` restarts it after a second at the earliest.
            sim_kills.push((killed, killed + 900_000_000));
        }
        // Restarted by `up`, and the controller executing again.
        let start = Instant::now();
        while pid_of(&s, victim).is_none_or(|p| p == old) {
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "round {round} (seed {seed}): no new {victim}: {}",
                s.logs()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        let st = s.wait_status("the stack back", Duration::from_secs(60), |st| {
            let alive = st["alive"].as_array().map_or(0, |a| a.len());
            alive >= 3 && matches!(st["controller"]["state"].as_str(), Some("EXECUTE" | "IDLE"))
        });
        if st["controller"]["state"] == "EXECUTE" || victim != "controller" {
            // Going on: a new execution finishes after the restart.
            let set = *sets.last().unwrap();
            let before = stats.lock().unwrap().iter().filter(|x| x.0 == set).count();
            let start = Instant::now();
            while stats.lock().unwrap().iter().filter(|x| x.0 == set).count() == before
                && s.status()["controller"]["state"] == "EXECUTE"
            {
                assert!(
                    start.elapsed() < Duration::from_secs(60),
                    "round {round} (seed {seed}): no execution finished after the {victim} came back"
                );
                std::thread::sleep(Duration::from_millis(200));
            }
        }
    }
    let (seen, stats) = observer.finish();
    s.stop();
    let streams = check(&seen, &stats, &sim_kills, &format!("seed {seed}"));
    eprintln!(
        "seed {seed}: {} setpoints from {streams} controller runs, {} executions, {} sim kills",
        seen.len(),
        stats.len(),
        sim_kills.len()
    );
}

#[test]
fn stalled_processes_and_a_cpu_hog_break_no_safety_invariant() {
    let mut s = TestStack::new(BIN, "stalls", true);
    s.up();
    let observer = Observer::start(&s.namespace);
    let stats = observer.stats.clone();
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 20);
    assert_eq!(code, 0, "{out}{err}");
    let set = set_id(&out);
    s.wait_status("EXECUTE", Duration::from_secs(60), |st| {
        st["controller"]["state"] == "EXECUTE"
    });
    let children = s.children();
    let pid = |role: &str| children.iter().find(|c| c.0 == role).unwrap().1;
    let overruns = |s: &TestStack| s.status()["controller"]["overruns"].as_u64().unwrap();
    let finished = || stats.lock().unwrap().iter().filter(|x| x.0 == set).count();
    let executing_again = |s: &TestStack, what: &str| {
        s.wait_status(what, Duration::from_secs(60), |st| {
            st["controller"]["state"] == "EXECUTE"
        });
    };

    // Each process stalled for 0.6 s (SIGSTOP, SIGCONT) in the middle of an execution.
    let mut outages = Vec::new();
    let mut stalled_overruns = (0, 0);
    for role in ["sim", "learner", "controller"] {
        std::thread::sleep(Duration::from_millis(1000));
        let before = overruns(&s);
        kill(Pid::from_raw(pid(role)), Signal::SIGSTOP).unwrap();
        let stopped = softarm_ipc::now_ns();
        std::thread::sleep(Duration::from_millis(600));
        let resumed = softarm_ipc::now_ns();
        kill(Pid::from_raw(pid(role)), Signal::SIGCONT).unwrap();
        if role == "sim" {
            outages.push((stopped, resumed));
        }
        executing_again(&s, &format!("EXECUTE after the {role} resumed"));
        if role == "controller" {
            stalled_overruns = (before, overruns(&s));
        }
    }
    // The controller's own stall shows in its overrun counter (periods skipped, not bursts).
    assert!(
        stalled_overruns.1 > stalled_overruns.0,
        "a controller stopped for 0.6 s counted no overrun: {stalled_overruns:?}"
    );

    // A busy thread on every core for three seconds.
    let hogs: Vec<_> = (0..std::thread::available_parallelism().map_or(2, |n| n.get()))
        .map(|_| {
            std::thread::spawn(|| {
                let start = Instant::now();
                let mut x = 0u64;
                while start.elapsed() < Duration::from_secs(3) {
                    x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                }
            })
        })
        .collect();
    for h in hogs {
        h.join().unwrap();
    }
    // Going on: another execution finishes.
    let after_hog = finished();
    let start = Instant::now();
    while finished() == after_hog {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no execution finished after the CPU hog: {}",
            s.logs()
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    // Nothing crashed: the same processes as at the start.
    assert_eq!(s.children(), children, "a process died: {}", s.logs());
    let (seen, stats) = observer.finish();
    s.stop();
    check(&seen, &stats, &outages, "stalls");
    eprintln!(
        "stalls: {} setpoints, {} executions; controller overruns {} -> {} over its own 0.6 s stop",
        seen.len(),
        stats.len(),
        stalled_overruns.0,
        stalled_overruns.1
    );
}
