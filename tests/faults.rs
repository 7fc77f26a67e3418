//! Fault injection, end to end: the sim, the learner and the controller SIGKILLed at seeded
//! random moments of running executions, `softarm up` restarting them. An independent
//! subscriber (`softarm_watch`, the one `softarm-rig soak` uses) checks what a person
//! beside the arm relies on: no setpoint outside the actuator limits, no step faster than the
//! slew limit (within each controller's stream, and across a restart no jump), HOLD within
//! twice the stale age once the sim is gone, no execution's statistics twice or lost; the test
//! checks that executions go on after each restart. With the e-stop engaged, the same kills
//! (each process once, seeded order and moments) leave only STOPPED setpoints until the reset,
//! every restarted controller STOPPED, and the reset moves nothing by a jump.
//! A failure names the seed; SOFTARM_FAULT_SEED=N reruns that sequence.

use std::path::Path;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use rand::seq::SliceRandom;
use rand::{RngExt, SeedableRng};
use softarm_config::Config;
use softarm_ipc::Namespace;
use softarm_test_support::{DEMO_WAYPOINTS, FaultSeed, TestStack, set_id};
use softarm_watch::{Limits, Report, Watch};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");

/// The independent observer, subscribed before anything is killed, checking the test config's
/// limits.
fn watch(s: &TestStack) -> Watch {
    let config = Config::load(&s.config).unwrap();
    Watch::start(
        &Namespace::new(&s.namespace).unwrap(),
        Limits::from_config(&config),
    )
    .unwrap()
}

/// Setpoints the invariants must have been checked over to mean something.
const ENOUGH_SETPOINTS: u64 = 5000;

/// Watches on until the watch has seen enough setpoints: a controller starved on a loaded
/// machine skips ticks (overruns), so a run of fixed events can carry fewer than on an idle
/// one (4887 seen, with a quarter of the ticks skipped).
fn watch_enough(w: &Watch) {
    softarm_test_support::eventually("enough setpoints watched", Duration::from_secs(60), || {
        (w.report().setpoints > ENOUGH_SETPOINTS).then_some(())
    });
}

/// Every invariant held, over enough setpoints to mean something.
fn check(r: &Report, run: &str) {
    assert!(
        r.setpoints > ENOUGH_SETPOINTS,
        "{run}: {} setpoints",
        r.setpoints
    );
    assert_eq!(
        r.violations, 0,
        "{run}: {} invariants broken: {:#?}",
        r.violations, r.messages
    );
}

#[test]
fn random_kills_break_no_safety_invariant() {
    let said = FaultSeed::from_env(7);
    let seed = said.0;
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut s = TestStack::new(BIN, "faults", true);
    s.up();

    let watch = watch(&s);

    let pid_of =
        |s: &TestStack, role: &str| s.children().into_iter().find(|c| c.0 == role).map(|c| c.1);
    let mut sim_kills = 0;
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
        if victim == "sim" {
            // `up` restarts it after a second at the earliest.
            let killed = softarm_runtime::now_ns();
            watch.outage(killed, killed + 900_000_000);
            sim_kills += 1;
        }
        kill(Pid::from_raw(old), Signal::SIGKILL).unwrap();
        eprintln!("round {round} (seed {seed}): killed {victim}");
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
            let before = watch.executions_of(set);
            let start = Instant::now();
            while watch.executions_of(set) == before
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
    watch_enough(&watch);
    let r = watch.finish();
    s.stop();
    check(&r, &format!("seed {seed}"));
    eprintln!(
        "seed {seed}: {} setpoints from {} controller runs, {} executions, {sim_kills} sim kills",
        r.setpoints, r.streams, r.executions
    );
}

#[test]
fn stalled_processes_and_a_cpu_hog_break_no_safety_invariant() {
    let mut s = TestStack::new(BIN, "stalls", true);
    s.up();
    let watch = watch(&s);
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 20);
    assert_eq!(code, 0, "{out}{err}");
    let set = set_id(&out);
    s.wait_status("EXECUTE", Duration::from_secs(60), |st| {
        st["controller"]["state"] == "EXECUTE"
    });
    let children = s.children();
    let pid = |role: &str| children.iter().find(|c| c.0 == role).unwrap().1;
    let overruns = |s: &TestStack| s.status()["controller"]["overruns"].as_u64().unwrap();
    let finished = || watch.executions_of(set);
    let executing_again = |s: &TestStack, what: &str| {
        s.wait_status(what, Duration::from_secs(60), |st| {
            st["controller"]["state"] == "EXECUTE"
        });
    };

    // Each process stalled for 0.6 s (SIGSTOP, SIGCONT) in the middle of an execution.
    let mut stalled_overruns = (0, 0);
    for role in ["sim", "learner", "controller"] {
        std::thread::sleep(Duration::from_millis(1000));
        let before = overruns(&s);
        let stopped = softarm_runtime::now_ns();
        if role == "sim" {
            watch.outage(stopped, stopped + 600_000_000);
        }
        kill(Pid::from_raw(pid(role)), Signal::SIGSTOP).unwrap();
        std::thread::sleep(Duration::from_millis(600));
        kill(Pid::from_raw(pid(role)), Signal::SIGCONT).unwrap();
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
    watch_enough(&watch);
    let r = watch.finish();
    s.stop();
    check(&r, "stalls");
    eprintln!(
        "stalls: {} setpoints, {} executions; controller overruns {} -> {} over its own 0.6 s stop",
        r.setpoints, r.executions, stalled_overruns.0, stalled_overruns.1
    );
}

/// It found that a sim restarted while the e-stop was latched started its arm at
/// `initial_actuation` (it took its start only from a setpoint it may follow): after the reset,
/// or in a controller restarted meanwhile, the limiter started from the teleported arm, a
/// setpoint step of up to 0.3 in one tick. The sim now starts where a STOPPED controller holds
/// the arm too.
#[test]
fn an_estop_stays_latched_through_random_kills_and_a_reset_resumes_smoothly() {
    let said = FaultSeed::from_env(7);
    let seed = said.0;
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut s = TestStack::new(BIN, "estop-kills", true);
    s.up();
    // Watching from before the e-stop: from twice the stale age after it, only STOPPED
    // setpoints, whichever controller sends them, until the reset.
    let watch = watch(&s);
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 20);
    assert_eq!(code, 0, "seed {seed}: {out}{err}");
    let first = set_id(&out);
    s.wait_status("EXECUTE", Duration::from_secs(60), |st| {
        st["controller"]["state"] == "EXECUTE"
    });
    std::thread::sleep(Duration::from_millis(rng.random_range(300..2000)));
    let out = s.run(&["estop"]);
    assert!(out.status.success(), "seed {seed}: {out:?}");
    s.wait_status("STOPPED", Duration::from_secs(10), |st| {
        st["controller"]["state"] == "STOPPED"
    });

    // Each process SIGKILLed once, in a seeded order, at a seeded moment; `up` restarts it.
    // No outage is declared for the sim: a stopped controller says STOPPED, not HOLD.
    let pid_of =
        |s: &TestStack, role: &str| s.children().into_iter().find(|c| c.0 == role).map(|c| c.1);
    let mut victims = ["controller", "sim", "learner"];
    victims.shuffle(&mut rng);
    for victim in victims {
        std::thread::sleep(Duration::from_millis(rng.random_range(100..1500)));
        let ticks = s.status()["controller"]["ticks"].as_u64().unwrap_or(0);
        let old = pid_of(&s, victim).unwrap_or_else(|| panic!("no {victim}: {}", s.logs()));
        kill(Pid::from_raw(old), Signal::SIGKILL).unwrap();
        eprintln!("e-stop (seed {seed}): killed {victim}");
        let start = Instant::now();
        while pid_of(&s, victim).is_none_or(|p| p == old) {
            assert!(
                start.elapsed() < Duration::from_secs(30),
                "seed {seed}: no new {victim}: {}",
                s.logs()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        // Every process back; a new controller (its tick count starts again) says STOPPED.
        let st = s.wait_status(
            &format!("the stack back after the {victim}"),
            Duration::from_secs(30),
            |st| {
                let alive = st["alive"].as_array().cloned().unwrap_or_default();
                let fresh = victim != "controller"
                    || st["controller"]["ticks"]
                        .as_u64()
                        .is_some_and(|t| t < ticks);
                ["controller", "learner", "sim"]
                    .iter()
                    .all(|r| alive.iter().any(|a| a == r))
                    && fresh
            },
        );
        assert_eq!(
            st["controller"]["state"], "STOPPED",
            "seed {seed}: after the {victim} restarted: {st}"
        );
    }
    // Still stopped a while later, whoever restarted.
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(s.status()["controller"]["state"], "STOPPED", "seed {seed}");
    assert_eq!(
        watch.executions_of(first),
        watch.report().executions as usize
    );

    // Released: the controller leaves STOPPED (the watch checks the step), and a new set runs.
    let out = s.run(&["estop", "--reset"]);
    assert!(out.status.success(), "seed {seed}: {out:?}");
    s.wait_status("IDLE after the reset", Duration::from_secs(10), |st| {
        st["controller"]["state"] == "IDLE"
    });
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 1);
    assert_eq!(code, 0, "seed {seed}: {out}{err}");
    let second = set_id(&out);
    let start = Instant::now();
    while watch.executions_of(second) == 0 {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "seed {seed}: the new set did not execute after the reset: {}",
            s.logs()
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    watch_enough(&watch);
    let r = watch.finish();
    s.stop();
    check(&r, &format!("e-stop, seed {seed}"));
    assert!(r.estops >= 1, "seed {seed}: the watch saw no e-stop");
    assert_eq!(r.streams, 2, "seed {seed}: one controller restart");
    eprintln!(
        "e-stop (seed {seed}): {} setpoints from {} controller runs, {} executions",
        r.setpoints, r.streams, r.executions
    );
}

/// A controller whose io thread cannot open its publishers (here `setpoint` is held by another
/// program with another payload type; under load it was iceoryx2's `HangsInCreation`) exits
/// with that error, for `up` or systemd to restart it, rather than tick on, alive and
/// publishing nothing.
#[test]
fn a_controller_that_cannot_publish_exits_saying_why() {
    use softarm_ipc::iceoryx2::prelude::{NodeBuilder, ServiceName, ipc};
    let s = TestStack::new(BIN, "cannot-publish", false);
    let name = ServiceName::new(&format!("{}/setpoint", s.namespace)).unwrap();
    let node = NodeBuilder::new().create::<ipc::Service>().unwrap();
    let _other = node
        .service_builder(&name)
        .publish_subscribe::<u64>()
        .create()
        .unwrap();
    let mut controller = s.spawn(&["controller"]);
    let status =
        softarm_test_support::eventually("the controller to exit", Duration::from_secs(60), || {
            controller.try_wait().unwrap()
        });
    assert!(!status.success(), "{status:?}");
    let log = std::fs::read_to_string(s.dir.join("controller.log")).unwrap();
    assert!(log.contains("opening the controller's publishers"), "{log}");
}
