//! Fault injection on the real arm's code path, without the arm: `softarm-rig emulate` (the motor
//! bus and the tracker on pseudo-terminals) and `softarm up` with the hardware config, the
//! `tendon` and `tracker` drivers and the controller SIGKILLed at seeded random moments of
//! running executions while `up` restarts them. An independent subscriber
//! (`softarm_watch`) checks every setpoint: within the actuator limits, no step
//! beyond the slew limit (nor a jump across a controller restart), HOLD and nothing executed
//! from twice the stale age after a driver died until it can be back, no execution's
//! statistics twice or lost. After each kill the driver is back (a new process), the
//! controller executes again and an execution finishes.
//!
//! The tracker gone leaves the controller with stale tracker data, the tendon driver gone with
//! stale motor state; the controller holds on either after `controller.tracker_timeout_ms`
//! (`processes/controller/src/tick.rs`, `Tick::health`), so the config's limits apply to both.
//! A failure names the seed; SOFTARM_FAULT_SEED=N reruns that sequence.
//!
//! Also `softarm-rig soak` on this code path: its own kills, its report read back.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use rand::seq::SliceRandom;
use rand::{RngExt, SeedableRng};
use softarm_config::Config;
use softarm_ipc::Namespace;
use softarm_runtime::now_ns;
use softarm_test_support::{
    DEMO_WAYPOINTS, Devices, FaultSeed, TestStack, eventually, output, set_id,
};
use softarm_watch::{Limits, Watch};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");
/// The test rig's binary: `emulate` and `soak`.
const RIG: &str = env!("CARGO_BIN_EXE_softarm-rig");
const LIMIT: Duration = Duration::from_secs(30);

fn pid_of(s: &TestStack, role: &str) -> Option<i32> {
    s.children().into_iter().find(|c| c.0 == role).map(|c| c.1)
}

fn alive_all(st: &serde_json::Value) -> bool {
    let alive = st["alive"].as_array().cloned().unwrap_or_default();
    ["controller", "learner", "tendon", "tracker"]
        .iter()
        .all(|r| alive.iter().any(|a| a == r))
}

/// Waits for an execution of `set` to finish after `victim` came back. The controller pauses
/// an execution while it holds (data older than its time-out, which a loaded machine's held
/// pseudo-terminals make often), so what bounds the wait is the time it spent executing, as
/// its setpoints say ([`Watch::executing`]): an execution of the demo set is 5 s and a rest;
/// 20 s of EXECUTE without one finishing is a stack that does not execute. (A bound on the
/// wall clock failed on a loaded machine, and so did EXECUTE time counted by polling `softarm
/// status`, which takes seconds there: a HOLD between two polls counted as executing.)
fn an_execution_after(s: &TestStack, watch: &Watch, set: u64, victim: &str) {
    const EXECUTING: Duration = Duration::from_secs(20);
    let before = watch.executions_of(set);
    let (start, executing_before) = (Instant::now(), watch.executing());
    while watch.executions_of(set) <= before {
        let executing = watch.executing() - executing_before;
        assert!(
            executing < EXECUTING && start.elapsed() < Duration::from_secs(300),
            "no execution finished after the {victim} came back: {executing:?} executing in \
             {:?}; status {}\n{}",
            start.elapsed(),
            s.status(),
            s.logs()
        );
        std::thread::sleep(Duration::from_millis(200));
    }
}

#[test]
fn killed_hardware_drivers_and_controller_break_no_safety_invariant() {
    let said = FaultSeed::from_env(11);
    let seed = said.0;
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let started = Instant::now();

    // The emulators as a user runs them; the stack from the config `softarm-rig emulate` writes.
    let (mut s, mut emulate) = TestStack::emulated(BIN, RIG, "hw-faults", Devices::Shared);
    let config = Config::load(&s.config).unwrap();
    s.up();
    s.wait_status("every process of the hardware stack", LIMIT, alive_all);

    // The motor-state time-out is the tracker's (one `timeout_ns` in the controller), so the
    // config's limits are the ones to check.
    let watch = Watch::start(
        &Namespace::new(&s.namespace).unwrap(),
        Limits::from_config(&config),
    )
    .unwrap();

    let submit = |s: &TestStack| {
        let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 200);
        assert_eq!(code, 0, "{out}{err}");
        let set = set_id(&out);
        s.wait_status("EXECUTE", LIMIT, |st| {
            st["controller"]["state"] == "EXECUTE"
        });
        set
    };
    let mut set = submit(&s);

    // Each driver at least twice, the controller once, in a seeded order; `up`'s back-off
    // doubles per restart of the same process (1 s, 2 s), which bounds the count.
    let mut victims = vec!["tendon", "tendon", "tracker", "tracker", "controller"];
    victims.shuffle(&mut rng);
    let mut driver_kills = 0;
    for (round, victim) in victims.into_iter().enumerate() {
        std::thread::sleep(Duration::from_millis(rng.random_range(300..2500)));
        let old = pid_of(&s, victim).unwrap_or_else(|| panic!("no {victim}: {}", s.logs()));
        if victim != "controller" {
            // `up` restarts it after a second at the earliest.
            let killed = now_ns();
            watch.outage(killed, killed + 900_000_000);
            driver_kills += 1;
        }
        kill(Pid::from_raw(old), Signal::SIGKILL).unwrap();
        eprintln!(
            "round {round} (seed {seed}): killed {victim} at {:.1} s",
            started.elapsed().as_secs_f64()
        );
        // Restarted by `up`: a new process of that role.
        eventually(&format!("a new {victim}"), LIMIT, || {
            pid_of(&s, victim).filter(|&p| p != old)
        });
        // The stack whole again and executing; a new controller forgot its set.
        if victim == "controller" {
            s.wait_status("a new controller, IDLE", LIMIT, |st| {
                alive_all(st) && st["controller"]["state"] == "IDLE"
            });
            set = submit(&s);
        } else {
            s.wait_status(
                &format!("EXECUTE after the {victim} came back"),
                LIMIT,
                |st| alive_all(st) && st["controller"]["state"] == "EXECUTE",
            );
        }
        // Going on: an execution of the set finishes after the restart.
        an_execution_after(&s, &watch, set, victim);
    }
    let r = watch.finish();
    s.stop();
    kill(Pid::from_raw(emulate.id() as i32), Signal::SIGTERM).unwrap();
    let status = eventually("softarm-rig emulate to stop", LIMIT, || {
        emulate.try_wait().unwrap()
    });
    assert!(status.success(), "softarm-rig emulate: {status}");
    eprintln!(
        "seed {seed}: {} setpoints from {} controller runs, {} executions of {} sets, \
         {driver_kills} driver kills, {:.1} s",
        r.setpoints,
        r.streams,
        r.executions,
        r.sets,
        started.elapsed().as_secs_f64()
    );
    assert_eq!(
        r.violations, 0,
        "seed {seed}: {} invariants broken: {:#?}",
        r.violations, r.messages
    );
    assert_eq!(r.outages, driver_kills, "seed {seed}");
    assert!(r.setpoints > 5000, "seed {seed}: {} setpoints", r.setpoints);
    assert_eq!(r.streams, 2, "seed {seed}: one controller restart");
}

/// `softarm-rig soak` on the real arm's code path: the tendon and tracker drivers against
/// `softarm-rig emulate`, killed at random; no sim, so no arm changes.
#[test]
fn a_soak_of_the_hardware_stack_kills_its_drivers_and_changes_no_arm() {
    let (s, _emulator) = TestStack::emulated(BIN, RIG, "soak-hw", Devices::Shared);
    let out = output(
        Command::new(RIG)
            .args(["soak", "--minutes", "0.75", "--kill-every-s", "8"])
            // Two executions to count, however slow the machine (a loaded one got through one in
            // the 45 s).
            .args(["--at-least-executions", "2"])
            .args(["--seed", "5", "--json", "--config"])
            .arg(&s.config)
            .env("TMPDIR", &s.dir),
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    let r: serde_json::Value = serde_json::from_str(stdout.trim())
        .unwrap_or_else(|e| panic!("{e}: stdout {stdout:?}\nstderr {stderr}"));
    let ctx = format!("{r:#}\nstderr:\n{stderr}");
    assert!(out.status.success(), "{ctx}");
    assert_eq!(r["invariants"]["violations"], 0, "{ctx}");
    assert!(r["executions"].as_u64().unwrap() >= 2, "{ctx}");
    // The drivers the config names run (and may be killed); no sim, so no scenario changes.
    let roles: Vec<&str> = r["rss"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x[0].as_str().unwrap())
        .collect();
    assert_eq!(
        roles,
        ["tendon", "tracker", "controller", "learner"],
        "{ctx}"
    );
    assert_eq!(r["scenario_changes"], 0, "{ctx}");
    assert!(!r["kills"].as_array().unwrap().is_empty(), "{ctx}");
    assert!(r["kills_survived"].as_u64().unwrap() >= 1, "{ctx}");
    assert_eq!(
        r["kills_not_survived"].as_array().unwrap().len(),
        0,
        "{ctx}"
    );
}
