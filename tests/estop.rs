//! End to end: the e-stop outlives the processes that saw it. An e-stop, then the controller and
//! the sim killed with SIGKILL and restarted by `softarm up`: both come back stopped; a reset
//! releases them all, and never sets the arm moving by itself. A set submitted while STOPPED is
//! refused with what to do, and nothing is queued.

use std::path::Path;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use softarm_ipc::{DriverState, MotorState, Namespace, Node, Sub};
use softarm_test_support::{DEMO_WAYPOINTS, TestStack, set_id};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");

fn pid_of(s: &TestStack, role: &str) -> i32 {
    s.children()
        .into_iter()
        .find(|c| c.0 == role)
        .unwrap_or_else(|| panic!("no {role} running: {}", s.logs()))
        .1
}

/// SIGKILL `role`, then waits until `up` has started another.
fn kill_and_wait_for_restart(s: &TestStack, role: &str) {
    let old = pid_of(s, role);
    kill(Pid::from_raw(old), Signal::SIGKILL).unwrap();
    let start = Instant::now();
    loop {
        if let Some((_, pid)) = s.children().into_iter().find(|c| c.0 == role)
            && pid != old
        {
            return;
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "no new {role}: {}",
            s.logs()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Waits for a `motor_state` sample stamped after `since_ns` and returns its `stopped` flag.
fn driver_stopped(motors: &Sub<MotorState>, since_ns: u64) -> bool {
    let start = Instant::now();
    loop {
        while let Ok(Some(m)) = motors.receive() {
            if m.stamp_ns > since_ns {
                return m.driver_state() == Some(DriverState::Stopped);
            }
        }
        assert!(start.elapsed() < Duration::from_secs(20), "no motor state");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn an_estop_survives_restarts_until_reset_and_a_reset_moves_nothing() {
    let mut s = TestStack::new(BIN, "estop-latch", true);
    s.up();
    let node = Node::open(Namespace::new(&s.namespace).unwrap(), "test").unwrap();
    let motors = node.subscriber(&node.motor_state().unwrap()).unwrap();

    // A set under way when the e-stop comes.
    let set = s.executing(Path::new(DEMO_WAYPOINTS), 3);
    let out = s.run(&["estop"]);
    assert!(out.status.success(), "{out:?}");
    s.wait_status("STOPPED", Duration::from_secs(10), |st| {
        st["controller"]["state"] == "STOPPED"
    });
    assert!(driver_stopped(&motors, softarm_runtime::now_ns()));
    let finished = s.stats(set).len();

    // Restarted after the e-stop, each comes back stopped: it read the latch.
    kill_and_wait_for_restart(&s, "controller");
    s.wait_status("a new controller, STOPPED", Duration::from_secs(30), |st| {
        st["controller"]["state"] == "STOPPED"
            && st["alive"]
                .as_array()
                .is_some_and(|a| a.iter().any(|n| n == "controller"))
    });
    kill_and_wait_for_restart(&s, "sim");
    let after = softarm_runtime::now_ns();
    assert!(driver_stopped(&motors, after), "the new sim moves");
    assert!(s.logs().contains("the e-stop is latched"), "{}", s.logs());
    assert_eq!(s.status()["controller"]["state"], "STOPPED");

    // A set submitted while STOPPED is refused, saying what to do, and nothing is queued.
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 1);
    assert_ne!(code, 0, "accepted while STOPPED: {out}{err}");
    let said = format!("{out}{err}");
    assert!(
        said.contains("e-stop is engaged") && said.contains("softarm estop --reset"),
        "{said}"
    );

    // Released everywhere; neither the dropped set nor the refused one starts by itself.
    let out = s.run(&["estop", "--reset"]);
    assert!(out.status.success(), "{out:?}");
    s.wait_status("IDLE after reset", Duration::from_secs(10), |st| {
        st["controller"]["state"] == "IDLE"
    });
    assert!(!driver_stopped(&motors, softarm_runtime::now_ns()));
    std::thread::sleep(Duration::from_secs(2));
    let st = s.status();
    assert_eq!(st["controller"]["state"], "IDLE", "{st}");

    assert_eq!(
        s.stats(set).len(),
        finished,
        "the set went on after the e-stop"
    );
    // A new submit runs.
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 1);
    assert_eq!(code, 0, "{out}{err}");
    s.wait_stats(set_id(&out), 1, Duration::from_secs(60));
}
