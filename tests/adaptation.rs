//! End to end: the running stack adapts to an arm that is not the one its model was trained on.
//! The real `softarm up --scenario tool-change` (the sim's tool 20 mm longer than the model
//! knows), the default `softarm` learner, errors as the tracker measures them.

use std::path::Path;
use std::time::Duration;

use softarm_test_support::{DEMO_WAYPOINTS, TestStack, set_id};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");

#[test]
fn a_stack_on_a_changed_arm_lowers_its_error_and_reports_its_reconditionings() {
    let mut s = TestStack::new(BIN, "adapt", true);
    s.up_with(&["--scenario", "tool-change"]);
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 6);
    assert_eq!(code, 0, "{out}{err}");
    let stats = s.wait_stats(set_id(&out), 6, Duration::from_secs(180));
    let m: Vec<f64> = stats
        .iter()
        .map(|v| v["mean_mm"].as_f64().unwrap() * 1e-3)
        .collect();
    eprintln!("mean error per execution (m): {m:?}");
    assert!(m[0] > 0.01, "the longer tool is felt at first: {m:?}");
    assert!(m[5] < 0.5 * m[0], "no adaptation: {m:?}");
    assert!(
        m.iter().all(|e| *e <= 1.5 * m[0]),
        "the arm wandered: {m:?}"
    );
    // Every execution after the first ran on re-conditioned estimates, and status says so.
    for v in &stats[1..] {
        assert!(v["reconditions"].as_u64().unwrap() >= 1, "{v}");
    }
    let st = s.status();
    assert!(
        st["controller"]["reconditions"]["last"].as_u64().unwrap() >= 1,
        "{st}"
    );
}

#[test]
fn a_one_point_set_improves_across_executions() {
    let mut s = TestStack::new(BIN, "onepoint", true);
    s.up_with(&["--scenario", "tool-change"]);
    // On the nominal path of the first demonstrated class, half-way.
    let file = s.dir.join("one-point.toml");
    std::fs::write(
        &file,
        "duration_s = 3.0\n[[point]]\nt_s = 1.5\nposition_m = [0.031, 0.0, -0.501]\n",
    )
    .unwrap();
    let (code, out, err) = s.submit(&file, 5);
    assert_eq!(code, 0, "{out}{err}");
    let stats = s.wait_stats(set_id(&out), 5, Duration::from_secs(120));
    let m: Vec<f64> = stats
        .iter()
        .map(|v| v["mean_mm"].as_f64().unwrap() * 1e-3)
        .collect();
    eprintln!("mean error per execution (m): {m:?}");
    assert!(m[0] > 0.01, "the longer tool is felt at first: {m:?}");
    assert!(m[4] < 0.5 * m[0], "a one-point set did not improve: {m:?}");
}
