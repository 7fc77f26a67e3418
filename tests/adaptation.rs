//! End to end: the running stack adapts to an arm that is not the one its model was trained on.
//! The real `softarm up --scenario tool-change` (the sim's tool 20 mm longer than the model
//! knows), the default `softarm` learner, errors as the tracker measures them.

use std::path::Path;
use std::time::Duration;

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use softarm_config::Config;
use softarm_config::scenario::Scenario;
use softarm_config::waypoints::WaypointFile;
use softarm_learner::{Learner, online_learner};
use softarm_model::bundle::Model;
use softarm_rehearsal::Rehearsal;
use softarm_test_support::config::{config_text, with_overrides};
use softarm_test_support::{DEMO_WAYPOINTS, Guard, TestStack, eventually, set_id};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");

#[test]
fn a_stack_on_a_changed_arm_lowers_its_error_and_reports_its_reconditionings() {
    let mut s = TestStack::new(BIN, "adapt", true);
    s.up_with(&["--scenario", "tool-change"]);
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 6);
    assert_eq!(code, 0, "{out}{err}");
    let stats = s.wait_stats(set_id(&out), 6, Duration::from_secs(180));
    let m: Vec<f64> = stats.iter().map(mean_m).collect();
    eprintln!("mean error per execution (m): {m:?}");
    // The longer tool is felt at the first point; from there on the learner is at work, the
    // rest of the first execution too: each point that ran corrected within it (an estimate
    // late on a loaded machine runs an execution later) missed by well under the first.
    let first = &stats[0];
    let errors: Vec<f64> = (first["errors_mm"].as_array().unwrap().iter())
        .map(|e| e.as_f64().unwrap_or(f64::NAN) * 1e-3)
        .collect();
    let within: Vec<bool> = (first["within"].as_array().unwrap().iter())
        .map(|b| b.as_bool().unwrap())
        .collect();
    let felt = errors[0];
    assert!(felt > 0.01, "the longer tool is felt at first: {first}");
    assert!(!within[0] && within[1..].iter().any(|w| *w), "{first}");
    for (e, _) in errors.iter().zip(&within).skip(1).filter(|(_, w)| **w) {
        assert!(*e < 0.6 * felt, "{first}");
    }
    assert!(m[5] < 0.5 * felt, "no adaptation: {m:?}, {first}");
    assert!(
        m.iter().all(|e| *e <= 1.5 * felt),
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
    // The actuators' lag (the sim's first-order 20 ms, and the way a setpoint takes to it)
    // was measured while the arm moved, and the next set is led by it in whole ticks (2 ms),
    // within the 0.75 tick the lead waits for before it moves, up to the 0.1 s cap.
    let c = &st["controller"];
    let lag = c["lag_ns"]
        .as_u64()
        .unwrap_or_else(|| panic!("no lag measured: {st}"));
    assert!(lag >= 10_000_000, "a lag of {lag} ns: {st}");
    let lead = c["lead_ns"].as_u64().unwrap();
    assert_eq!(lead % 2_000_000, 0, "{st}");
    assert!(lead.abs_diff(lag.min(100_000_000)) <= 1_500_000, "{st}");
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
    let m: Vec<f64> = stats.iter().map(mean_m).collect();
    eprintln!("mean error per execution (m): {m:?}");
    assert!(m[0] > 0.01, "the longer tool is felt at first: {m:?}");
    assert!(m[4] < 0.5 * m[0], "a one-point set did not improve: {m:?}");
}

/// Issue 48: a way-point beyond the arm's reach, in the running stack. The demo set with its
/// second point 80 mm below where it was, which the sim's arm comes within 21.8 mm of (a brute
/// force over the sim's own arm, `rig/rehearsal/src/tests.rs::nearest_reach`): the learner
/// brings it there and holds it, `stats` says it of that point in every execution, and the
/// other points are not thrown by what it misses by.
#[test]
fn a_way_point_beyond_reach_is_held_where_the_arm_comes_nearest_and_said() {
    const NEAREST_M: f64 = 0.0218;
    let mut s = TestStack::new(BIN, "beyond", true);
    s.up();
    let demo = std::fs::read_to_string(DEMO_WAYPOINTS).unwrap();
    let beyond = demo.replace("[0.031, 0.000, -0.501]", "[0.031, 0.000, -0.580]");
    assert_ne!(beyond, demo);
    let file = s.dir.join("beyond.toml");
    std::fs::write(&file, beyond).unwrap();
    let (code, out, err) = s.submit(&file, 6);
    assert_eq!(code, 0, "{out}{err}");
    let stats = s.wait_stats(set_id(&out), 6, Duration::from_secs(180));
    let said = serde_json::json!([false, true, false, false, false]);
    for v in &stats {
        assert_eq!(v["beyond_reach"], said, "{v}");
    }
    let error = |v: &serde_json::Value, n: usize| v["errors_mm"][n].as_f64().unwrap() * 1e-3;
    // Held, it scatters by what the sim's own disturbance moves it (a millimetre); before,
    // the learner stepped toward the target and stopped 14 mm further than the arm comes.
    for v in &stats[3..] {
        assert!((error(v, 1) - NEAREST_M).abs() < 0.003, "{v}");
    }
    for n in [0, 2, 3, 4] {
        assert!(error(&stats[5], n) < 0.005, "point {n}: {}", stats[5]);
    }
}

const SECOND_WAYPOINTS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/config/waypoints/second.toml");

/// The sim as another arm: the running one stopped as a restarting driver would be, and the
/// scenario's started where the controller holds the arm.
/// The test's own sim driver is a guard: a failed assert leaves none running.
fn sim_as(s: &TestStack, sim: Option<Guard>, scenario: &str) -> Guard {
    if let Some(mut old) = sim {
        kill(Pid::from_raw(old.id() as i32), Signal::SIGTERM).unwrap();
        old.wait().unwrap();
    }
    s.spawn(&["sim", "--scenario", scenario])
}

/// SIGKILL to the learner, and back (a new process) with its model loaded.
fn restart_learner(s: &TestStack) {
    let learner = |s: &TestStack| {
        s.children()
            .into_iter()
            .find(|c| c.0 == "learner")
            .map(|c| c.1)
    };
    let old = learner(s).expect("a learner runs");
    kill(Pid::from_raw(old), Signal::SIGKILL).unwrap();
    eventually("a new learner", Duration::from_secs(60), || {
        learner(s).filter(|p| *p != old)
    });
    eventually("the new learner's model", Duration::from_secs(60), || {
        (s.logs().matches("learner ready").count() >= 2).then_some(())
    });
}

/// An execution's mean error (m) from its stats; NaN (JSON null) when the tracker saw none
/// of the samples around one of its points (a sim starved of its CPU on a loaded machine).
fn mean_m(v: &serde_json::Value) -> f64 {
    v["mean_mm"].as_f64().map_or(f64::NAN, |mm| mm * 1e-3)
}

/// One execution as `softarm stats` reports it: its mean error (m) and the points that ran on
/// an older estimate than the learner's for it (`late_estimates`).
#[derive(Debug, Clone, Copy)]
struct Run {
    mean_m: f64,
    late: u64,
}

/// Each execution of `set` run `executions` times on the stack.
fn run_set(s: &TestStack, set: &str, executions: u32) -> Vec<Run> {
    let (code, out, err) = s.submit(Path::new(set), executions);
    assert_eq!(code, 0, "{out}{err}");
    let stats = s.wait_stats(set_id(&out), executions as usize, Duration::from_secs(180));
    // Each point's error and the estimates not in force, so that a failure on a loaded
    // machine says which point and whether its estimate was late.
    for v in &stats {
        eprintln!(
            "  {set} execution {}: {} mm, {} late",
            v["execution"], v["errors_mm"], v["late_estimates"]
        );
    }
    stats
        .iter()
        .map(|v| Run {
            mean_m: mean_m(v),
            late: v["late_estimates"].as_u64().unwrap(),
        })
        .collect()
}

/// The mean errors judged by "from the third execution on": a point whose estimate came late
/// (the learner's answer after the point's window had begun, on a loaded machine) ran on the
/// one before and took no step in that execution, so each execution with a late estimate puts
/// the third off by one. `softarm stats` counts them; the learning is judged, not the machine.
fn from_the_third(runs: &[Run]) -> Vec<f64> {
    let mut late = 0;
    runs.iter()
        .enumerate()
        .filter_map(|(i, r)| {
            late += usize::from(r.late > 0);
            (i >= 2 + late).then_some(r.mean_m)
        })
        .collect()
}

/// A freshly started learner's first execution of `set` on `scenario`'s arm, with the stack's
/// model and config: Alg. 2 rehearsed in process (it runs the stack's own code, see
/// `softarm-rehearsal`), whose controller measures the actuators' lag in the set's first rest
/// and leads by it, as the stack's has measured it.
fn fresh_first(model: &Model<6>, config: &Config, scenario: &str, set: &str) -> f64 {
    let on = Scenario::resolve(scenario)
        .unwrap()
        .apply_to(&config.arm, &config.sim)
        .unwrap();
    let online = online_learner(
        model.learner.clone(),
        model.kinematics.clone(),
        config.learner,
        softarm_kinematics::pcc::Arm::of_config(&config.arm).unwrap(),
    )
    .unwrap();
    let learner = Learner::new(online, config);
    let set = WaypointFile::load(Path::new(set)).unwrap();
    let body = softarm_sim::plant::Body::of_arm(&on.arm, &on.steps).unwrap();
    let mut r = Rehearsal::new(model, config, learner, body, &on.sim).unwrap();
    r.rehearse(&set, 1).unwrap()[0].mean_m
}

/// Issue 19, end to end: one controller and one learner running all along while the sim's arm
/// changes between sets (the sim restarted with another scenario), a return to nominal among
/// them, the learner killed and restarted mid-sequence. Each change is caught by the third
/// execution, and no set starts worse than a freshly started learner would start it on that
/// arm.
#[test]
fn a_running_stack_keeps_up_with_an_arm_that_changes() {
    // No sim of `up`'s: the test runs it, so that it can come back as another arm.
    let mut s = TestStack::with_config(BIN, "arm-changes", true, |dir, ns| {
        with_overrides(
            &config_text(dir, ns),
            &[("robot.drivers", toml::Value::Array(Vec::new()))],
        )
    });
    let mut sim = Some(sim_as(&s, None, "nominal"));
    s.up();
    let config = Config::load(&s.config).unwrap();
    let model = Model::<6>::read(&config.model_dir()).unwrap();
    // Three executions to learn, and room for late estimates: each puts "from the third" off
    // by one, and two in four executions (seen on a busy machine) left nothing to judge.
    let phases = [
        ("nominal", DEMO_WAYPOINTS, 6),
        ("tool-change", DEMO_WAYPOINTS, 6),
        ("twist", SECOND_WAYPOINTS, 6),
        ("nominal", DEMO_WAYPOINTS, 6),
    ];
    for (n, (scenario, set, executions)) in phases.into_iter().enumerate() {
        if n > 0 {
            let seen = s.logs().matches("the arm has changed").count();
            sim = Some(sim_as(&s, sim.take(), scenario));
            s.wait_status(
                "the new arm's sim to be followed",
                Duration::from_secs(60),
                |v| v["controller"]["state"] == "IDLE",
            );
            // The learner sees the change where the sim comes back, before the next set: a
            // person changing an arm does not submit within the few hundred ms a busy machine
            // (the whole suite beside it) can take the learner to read the first samples.
            eventually(
                "the learner to see the arm change",
                Duration::from_secs(30),
                || (s.logs().matches("the arm has changed").count() > seen).then_some(()),
            );
        }
        let runs = run_set(&s, set, executions);
        let m: Vec<f64> = runs.iter().map(|r| r.mean_m).collect();
        let fresh = fresh_first(&model, &config, scenario, set);
        eprintln!(
            "{scenario}: {:?} mm; a fresh learner's first {:.1} mm; arm changes seen so far {}",
            m.iter()
                .map(|e| format!("{:.1}", e * 1e3))
                .collect::<Vec<_>>(),
            fresh * 1e3,
            s.logs().matches("the arm has changed").count()
        );
        // The stack's sim has run before (other noise, another start) where the rehearsal's
        // starts new: 0.5 mm for that.
        assert!(
            m[0] <= 1.1 * fresh + 0.0005,
            "{scenario}: first execution {:.1} mm, a fresh learner's {:.1} mm",
            m[0] * 1e3,
            fresh * 1e3
        );
        // Executions with a point the tracker did not see (NaN) tell nothing of the learning.
        // Back from the third execution: on average within 2 mm, none over 3 mm. One
        // execution's mean scatters by a few tenths of a millimetre (the tracker's noise and
        // the sim's disturbance at five points), so a bound on each alone at 2 mm failed now and
        // then with the learning as converged as ever (2.01 mm beside 1.28).
        let judged: Vec<f64> = from_the_third(&runs)
            .into_iter()
            .filter(|e| e.is_finite())
            .collect();
        assert!(
            !judged.is_empty(),
            "{scenario}: nothing to judge from the third execution {runs:?}: an execution with \
             a late estimate puts the third off by one, and that many came late"
        );
        let mean = judged.iter().sum::<f64>() / judged.len() as f64;
        assert!(
            mean <= 0.002 && judged.iter().all(|e| *e <= 0.003),
            "{scenario}: from the third execution {runs:?}: mean {:.2} mm, more than 2 mm (or \
             one over 3 mm)",
            mean * 1e3
        );
        // The nominal arm's 1.2 mm target on average is the rehearsal's (many more
        // executions): here one or two, each with about a millimetre of the sim's disturbance.
        if n == 1 {
            // The learner killed mid-sequence: `up` restarts it from its checkpoint, which
            // keeps what it knew of the arm: the adapted arm's next set starts adapted (a
            // learner that forgot starts it at the fresh learner's ~20 mm), and the next change
            // is still seen.
            restart_learner(&s);
            let again = run_set(&s, set, 1)[0].mean_m;
            eprintln!(
                "{scenario} after the learner's restart: {:.1} mm",
                again * 1e3
            );
            assert!(again <= 0.002, "after the restart {again} m");
        }
    }
    let changes = s.logs().matches("the arm has changed").count();
    assert_eq!(changes, 3, "one change seen per change made: {}", s.logs());
    drop(sim);
}
