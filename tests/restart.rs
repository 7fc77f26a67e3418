//! End to end: a controller killed during an execution and restarted by `up`, while the sim
//! drives on, resumes without a setpoint jump. Checked from an independent subscriber of
//! `setpoint`: between any two setpoints it receives, across the restart too, no actuator moves
//! more than the slew limit allows for the time between them.

use std::path::Path;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use softarm_ipc::{Namespace, Node};
use softarm_test_support::{DEMO_WAYPOINTS, TestStack, set_id};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");
/// `controller.slew_per_s` of the test config (the default).
const SLEW_PER_S: f64 = 1.5;

#[test]
fn a_restarted_controller_resumes_without_a_setpoint_jump() {
    let mut s = TestStack::new(BIN, "restart-jump", true);
    s.up();
    let node = Node::open(Namespace::new(&s.namespace).unwrap(), "test").unwrap();
    let setpoints = node.subscriber(&node.setpoint().unwrap()).unwrap();
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 5);
    assert_eq!(code, 0, "{out}{err}");
    let set = set_id(&out);
    s.wait_stats(set, 1, Duration::from_secs(60));

    // (stamp, actuation) of every setpoint received, the old controller's and the new one's.
    let mut seen: Vec<(u64, [f64; 6])> = Vec::new();
    let record = |seen: &mut Vec<(u64, [f64; 6])>, until: Instant| {
        while Instant::now() < until {
            while let Ok(Some(p)) = setpoints.receive() {
                seen.push((p.stamp_ns, p.actuation.fixed().expect("the arm's six")));
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    };
    // Mid-execution: moving.
    record(&mut seen, Instant::now() + Duration::from_millis(1500));
    let (_, pid) = s
        .children()
        .into_iter()
        .find(|c| c.0 == "controller")
        .unwrap();
    kill(Pid::from_raw(pid), Signal::SIGKILL).unwrap();
    let killed = softarm_runtime::now_ns();
    // Until the new controller has published for a second or so.
    let start = Instant::now();
    while seen.iter().filter(|p| p.0 > killed).count() < 500 {
        record(&mut seen, Instant::now() + Duration::from_millis(100));
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no new controller publishing: {}",
            s.logs()
        );
    }
    let first_new = seen.iter().position(|p| p.0 > killed).unwrap();
    assert!(
        first_new > 100,
        "the old controller was seen moving: {first_new}"
    );

    // Within each controller's stream: never faster than the slew limit.
    let mut worst = 0.0f64;
    for (i, w) in seen.windows(2).enumerate() {
        if i + 1 == first_new {
            continue;
        }
        let dt = (w[1].0.saturating_sub(w[0].0)) as f64 * 1e-9;
        // One tick of slack for the limiter's own period and rounding.
        let allowed = SLEW_PER_S * (dt + 0.002) + 1e-9;
        for a in 0..6 {
            let step = (w[1].1[a] - w[0].1[a]).abs();
            worst = worst.max(step / allowed);
            assert!(
                step <= allowed,
                "actuator {a} moved {step} in {dt} s (allowed {allowed}), setpoint {}",
                i + 1
            );
        }
    }
    // Across the restart: the new controller starts where the arm is, which is where the old
    // one left it (the sim held it there); backlash, noise and lag leave millimetres at most.
    let (last_old, first) = (seen[first_new - 1].1, seen[first_new].1);
    for a in 0..6 {
        assert!(
            (first[a] - last_old[a]).abs() < 0.02,
            "actuator {a}: the old controller left {} and the new one started at {}",
            last_old[a],
            first[a]
        );
    }
    eprintln!(
        "{} setpoints, {} after the restart; worst step {:.0} % of the slew limit",
        seen.len(),
        seen.len() - first_new,
        worst * 100.0
    );
}
