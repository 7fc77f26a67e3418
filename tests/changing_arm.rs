//! End to end: the sim driver runs a scenario that changes the arm while it runs. The real
//! `softarm sim --scenario FILE` with a step 2 s into its clock (the tool 30 mm longer) and no
//! controller: the actuation holds where the sim starts it, and the tracked tip drops by the
//! tool's 30 mm at the step. Times are the sim's own (sample number over its rate), never the
//! wall clock, so a busy machine changes nothing.

use std::time::Duration;

use softarm_ipc::{Namespace, Node};
use softarm_test_support::{TestStack, eventually};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");
/// `sim.rate_hz` of the test config (the default).
const RATE_HZ: f64 = 200.0;

#[test]
fn the_sim_changes_its_arm_at_the_scenarios_time() {
    let s = TestStack::new(BIN, "changing-arm", false);
    let scenario = s.dir.join("swap.toml");
    std::fs::write(
        &scenario,
        "# A tool 30 mm longer 2 s in.\n[[step]]\nat_s = 2.0\n[step.arm]\ntool_m = 0.06\n",
    )
    .unwrap();
    let node = Node::open(Namespace::new(&s.namespace).unwrap(), "test").unwrap();
    let tracker = node.subscriber(&node.tracker().unwrap()).unwrap();
    let motors = node.subscriber(&node.motor_state().unwrap()).unwrap();
    let _sim = s.spawn(&["sim", "--scenario", scenario.to_str().unwrap()]);

    // (sim time, tip z) and (sim time, actuation) until the sim's clock is 1 s past the step.
    let (mut tips, mut actuations) = (Vec::new(), Vec::new());
    eventually("the sim's clock at 3 s", Duration::from_secs(60), || {
        while let Ok(Some(t)) = tracker.receive() {
            tips.push((t.seq as f64 / RATE_HZ, t.position[2]));
        }
        while let Ok(Some(m)) = motors.receive() {
            actuations.push((m.seq as f64 / RATE_HZ, m.actuation));
        }
        tips.last().is_some_and(|t| t.0 >= 3.0).then_some(())
    });
    let mean_z = |from: f64, to: f64| {
        let z: Vec<f64> = (tips.iter().filter(|t| t.0 > from && t.0 < to))
            .map(|t| t.1)
            .collect();
        assert!(
            z.len() >= 10,
            "samples between {from} and {to} s: {}",
            z.len()
        );
        z.iter().sum::<f64>() / z.len() as f64
    };
    let drop_m = mean_z(1.0, 1.95) - mean_z(2.05, 3.0);
    assert!(
        (drop_m - 0.03).abs() < 0.003,
        "the tip dropped {drop_m} m at the step, not the tool's 0.03 m\n{}",
        std::fs::read_to_string(s.dir.join("sim.log")).unwrap_or_default()
    );
    // The arm changed, not the actuation: it held at the start's 0.5 throughout (its
    // disturbance is a thousandth).
    assert!(actuations.len() >= 10);
    for (t, a) in &actuations {
        assert!(a.iter().all(|v| (v - 0.5).abs() < 0.01), "{a:?} at {t} s");
    }
    let log = std::fs::read_to_string(s.dir.join("sim.log")).unwrap();
    assert!(log.contains("the scenario's arm changes"), "{log}");
}
