//! End to end: `softarm ros2` (started by `softarm up` with `[ros2] enabled = true`, or beside
//! a stack) against an independent ROS 2 peer without ROS: Eclipse Cyclone DDS from Python
//! (`clients/python/examples/ros2_peer.py`, `pip install cyclonedds`), on loopback with
//! unicast discovery as ROS 2 does for a localhost-only setup. The peer sees the bridge's
//! topics under their ROS 2 DDS names and types, decodes setpoints equal to those the stack's
//! own `setpoint` service carried, gets a way-point set executed only when the config accepts
//! them (and refused, with nothing submitted, when not), and stops the stack with an e-stop.
//! The bridge killed, the stack runs on; the stack gone, the bridge says so.
//!
//! Each test has its namespace (so its own ROS 2 topic names) and its own DDS domain, derived
//! from the namespace ([`domain`]), so tests running side by side do not even discover each
//! other. Without `python3` with `cyclonedds`, a test says "not run" and passes, unless
//! `SOFTARM_REQUIRE_PYTHON=1` (CI).

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use serde_json::Value;
use softarm_ipc::{Namespace, Node};
use softarm_test_support::{
    DEMO_WAYPOINTS, TestStack, alive, config_text, eventually, with_overrides,
};

use crate::python::{python, run_python};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");
const PEER: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/clients/python/examples/ros2_peer.py"
);

/// A DDS domain of the test's own, from its namespace: 1 to 100 (0 is left to a developer's
/// ROS 2 on this machine; up to 101 keeps RTPS's ports below Linux's ephemeral range). Two
/// tests that drew the same domain would still not mix: their topics' names differ.
pub(crate) fn domain(namespace: &str) -> u16 {
    // FNV-1a: the same namespace gives the same domain in the bridge's config and the peer.
    let h = namespace.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    });
    1 + (h % 100) as u16
}

/// A stack with the bridge enabled (`up` starts it) or not, diagnostics 5 times a second, and
/// `overrides` on top; not started.
fn stack(name: &str, bridge: bool, overrides: &[(&str, toml::Value)]) -> TestStack {
    TestStack::with_config(BIN, name, true, |dir, ns| {
        let mut all = vec![
            ("ros2.enabled", bridge.into()),
            ("ros2.domain_id", (domain(ns) as i64).into()),
            ("ros2.status_hz", 5.0.into()),
        ];
        all.extend(overrides.iter().cloned());
        with_overrides(&config_text(dir, ns), &all)
    })
}

/// `ros2_peer.py` for the stack's bridge with `args`; its JSON.
pub(crate) fn peer(py: &str, s: &TestStack, args: &[&str]) -> Value {
    let ns = softarm_ros2::convert::ros_namespace(&s.namespace);
    let domain = domain(&s.namespace).to_string();
    let mut all = vec![PEER, "--namespace", &ns, "--domain", &domain];
    all.extend_from_slice(args);
    let out = run_python(py, &all);
    serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("not JSON ({e}): {}", String::from_utf8_lossy(&out.stdout)))
}

/// The bridge's log line that says it runs.
fn bridging(s: &TestStack) {
    eventually("the bridge running", Duration::from_secs(60), || {
        s.logs()
            .contains("bridging the stack to ROS 2")
            .then_some(())
    });
}

/// Every setpoint the stack's own `setpoint` service carries while it runs: (stamp_ns, the
/// bits of each actuation), read on a thread of its own until stopped.
struct Recorder {
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<Vec<(u64, Vec<u64>)>>,
}

impl Recorder {
    fn start(namespace: &str) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let ns = Namespace::new(namespace).unwrap();
        let flag = stop.clone();
        let thread = std::thread::spawn(move || {
            let node = Node::open(ns, "test").unwrap();
            let sub = node.subscriber(&node.setpoint().unwrap()).unwrap();
            let mut seen = Vec::new();
            while !flag.load(Ordering::Relaxed) {
                while let Ok(Some(s)) = sub.receive() {
                    let bits = s.actuation.iter().map(|v| v.to_bits()).collect();
                    seen.push((s.stamp_ns, bits));
                }
                std::thread::sleep(Duration::from_micros(500));
            }
            seen
        });
        Self { stop, thread }
    }

    fn finish(self) -> Vec<(u64, Vec<u64>)> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.join().unwrap()
    }
}

fn diagnostic<'a>(got: &'a Value, part: &str) -> &'a Value {
    &got["diagnostics"][part]
}

#[test]
fn a_ros2_peer_sees_the_topics_and_the_setpoints_the_stack_sent() {
    let Some(py) = python(&["cyclonedds"]) else {
        return;
    };
    let mut s = stack("ros2-topics", true, &[]);
    s.up();
    bridging(&s);
    // A set under way, so that setpoints change every tick: each one then says which it is.
    // Long enough to outlast the peer's start and discovery, however slow a loaded machine
    // makes them: a set that ended leaves the setpoint still, and no value says which it is.
    s.executing(Path::new(DEMO_WAYPOINTS), 50);
    let recorder = Recorder::start(&s.namespace);
    let got = peer(&py, &s, &["--seconds", "6"]);
    let recorded = recorder.finish();

    // The topics, under the ROS 2 names and DDS type names a ROS 2 node uses.
    let ns = format!("rt{}", softarm_ros2::convert::ros_namespace(&s.namespace));
    let published = got["topics"]["published"].as_object().unwrap();
    let want = [
        ("setpoint", "sensor_msgs::msg::dds_::JointState_"),
        ("joint_states", "sensor_msgs::msg::dds_::JointState_"),
        ("tracker", "geometry_msgs::msg::dds_::PointStamped_"),
        (
            "diagnostics",
            "diagnostic_msgs::msg::dds_::DiagnosticArray_",
        ),
    ];
    for (topic, kind) in want {
        assert_eq!(published[&format!("{ns}/{topic}")], kind, "{published:?}");
    }
    assert_eq!(published.len(), want.len(), "{published:?}");
    let subscribed = got["topics"]["subscribed"].as_object().unwrap();
    assert_eq!(
        subscribed[&format!("{ns}/waypoints")],
        "trajectory_msgs::msg::dds_::MultiDOFJointTrajectory_"
    );
    assert_eq!(
        subscribed[&format!("{ns}/estop")],
        "std_msgs::msg::dds_::Empty_"
    );
    assert_eq!(
        got["joint_names"],
        serde_json::json!(["a1", "a2", "a3", "a4", "a5", "a6"])
    );
    for topic in ["setpoint", "joint_states", "tracker", "diagnostics"] {
        assert!(got["counts"][topic].as_u64().unwrap() > 0, "{topic}: {got}");
    }
    assert_eq!(got["tracker"]["frame_id"], "base");
    assert_eq!(diagnostic(&got, "controller")["level"], 0, "{got}");

    // Setpoints: each the peer decoded is, bit for bit, the one the service carried with the
    // same stamp. ROS time is the stamp moved by one fixed offset: found from the setpoints
    // whose values appear once in the recording, then every one is checked with it.
    let by_stamp: BTreeMap<u64, &Vec<u64>> = recorded.iter().map(|(t, b)| (*t, b)).collect();
    let mut by_value: BTreeMap<&Vec<u64>, Vec<u64>> = BTreeMap::new();
    for (t, b) in &recorded {
        by_value.entry(b).or_default().push(*t);
    }
    let decoded: Vec<(i128, Vec<u64>)> = got["setpoints"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| {
            let bits = v[1].as_array().unwrap().iter().map(|b| b.as_u64().unwrap());
            (v[0].as_u64().unwrap() as i128, bits.collect())
        })
        .collect();
    let offsets: Vec<i128> = decoded
        .iter()
        .filter_map(|(ros, bits)| match by_value.get(bits).map(Vec::as_slice) {
            Some([t]) => Some(ros - *t as i128),
            _ => None,
        })
        .collect();
    assert!(
        offsets.len() >= 20,
        "{} of {} decoded setpoints found once among {} recorded",
        offsets.len(),
        decoded.len(),
        recorded.len()
    );
    assert!(offsets.iter().all(|o| *o == offsets[0]), "{offsets:?}");
    let mut compared = 0;
    for (ros, bits) in &decoded {
        if let Some(r) = by_stamp.get(&((ros - offsets[0]) as u64)) {
            assert_eq!(
                *r, bits,
                "the setpoint stamped {ros} differs from the service's"
            );
            compared += 1;
        }
    }
    eprintln!(
        "{} setpoints decoded, {compared} compared with the {} the service carried",
        decoded.len(),
        recorded.len()
    );
    assert!(compared >= 20, "{compared} compared");
}

#[test]
fn a_waypoint_set_from_ros2_is_checked_and_executed_when_accepted() {
    let Some(py) = python(&["cyclonedds"]) else {
        return;
    };
    let mut s = stack(
        "ros2-accept",
        true,
        &[("ros2.accept_waypoints", true.into())],
    );
    s.up();
    bridging(&s);

    // Out of the workspace: refused by the bridge, nothing submitted.
    let text = std::fs::read_to_string(DEMO_WAYPOINTS).unwrap();
    let far = s.dir.join("far.toml");
    std::fs::write(&far, text.replace("-0.471]", "2.0]")).unwrap();
    let far = far.to_str().unwrap();
    let got = peer(
        &py,
        &s,
        &["--waypoints", far, "--until", "refused", "--seconds", "60"],
    );
    let bridge = diagnostic(&got, "ros2 bridge");
    let why = bridge["values"]["last_refusal"].as_str().unwrap();
    assert!(
        why.contains("point 1") && why.contains("outside the workspace"),
        "{got}"
    );
    // Refused by the bridge's own check, not by the controller after a submit.
    assert!(!why.starts_with("the controller"), "{got}");
    assert_eq!(bridge["level"], 1, "{got}");
    assert_eq!(bridge["values"]["sets_accepted"], "0");
    assert!(
        s.logs().contains("refused, nothing submitted"),
        "{}",
        s.logs()
    );

    // The demo set: accepted by the controller, executed.
    let got = peer(
        &py,
        &s,
        &[
            "--waypoints",
            DEMO_WAYPOINTS,
            "--until",
            "accepted",
            "--seconds",
            "60",
        ],
    );
    let bridge = diagnostic(&got, "ros2 bridge");
    assert_eq!(got["sent"]["waypoints"], true, "{got}");
    assert_eq!(bridge["values"]["sets_accepted"], "1", "{got}");
    assert_ne!(bridge["values"]["sets_refused"], "0", "{got}");
    assert_eq!(bridge["values"]["last_refusal"], "", "{got}");
    let set: u64 = bridge["values"]["last_set_id"]
        .as_str()
        .unwrap()
        .parse()
        .unwrap();
    let stats = s.wait_stats(set, 1, Duration::from_secs(120));
    assert_eq!(stats[0]["executions"], 1, "{stats:?}");
    assert_eq!(
        stats[0]["errors_mm"].as_array().unwrap().len(),
        5,
        "{stats:?}"
    );
}

#[test]
fn a_waypoint_set_from_ros2_is_refused_when_read_only() {
    let Some(py) = python(&["cyclonedds"]) else {
        return;
    };
    let mut s = stack("ros2-refuse", true, &[]);
    s.up();
    bridging(&s);
    let got = peer(
        &py,
        &s,
        &[
            "--waypoints",
            DEMO_WAYPOINTS,
            "--until",
            "refused",
            "--seconds",
            "60",
        ],
    );
    assert_eq!(got["sent"]["waypoints"], true, "{got}");
    let bridge = diagnostic(&got, "ros2 bridge");
    assert_eq!(bridge["level"], 1, "{got}");
    assert!(
        bridge["message"]
            .as_str()
            .unwrap()
            .contains("ros2.accept_waypoints is false"),
        "{got}"
    );
    assert_eq!(bridge["values"]["sets_accepted"], "0");
    assert!(
        s.logs()
            .contains("refused, nothing submitted: ros2.accept_waypoints is false"),
        "{}",
        s.logs()
    );
    // Nothing reached the controller: it never had a set, and stays idle.
    std::thread::sleep(Duration::from_secs(2));
    let st = s.status();
    assert_eq!(st["controller"]["state"], "IDLE", "{st}");
    assert_eq!(st["controller"]["set_id"], 0, "{st}");
}

#[test]
fn an_estop_from_ros2_stops_the_stack_and_latches() {
    let Some(py) = python(&["cyclonedds"]) else {
        return;
    };
    let mut s = stack("ros2-estop", true, &[]);
    s.up();
    bridging(&s);
    let set = s.executing(Path::new(DEMO_WAYPOINTS), 10);
    // Best-effort, as a sensor-data QoS publisher sends: a reliable reader alone would never
    // match it (the way-point tests' reliable writer shows the reliable side).
    let got = peer(
        &py,
        &s,
        &[
            "--estop",
            "--best-effort",
            "--until",
            "engaged",
            "--seconds",
            "60",
        ],
    );
    assert_eq!(got["sent"]["estop"], true, "{got}");
    assert_eq!(diagnostic(&got, "estop")["level"], 2, "{got}");
    let estops = &diagnostic(&got, "ros2 bridge")["values"]["estops"];
    let estops: u64 = estops.as_str().unwrap().parse().unwrap();
    assert!(estops >= 1, "{got}");
    s.wait_status("STOPPED", Duration::from_secs(10), |st| {
        st["controller"]["state"] == "STOPPED"
    });
    // Confirmed as `softarm estop` confirms it: by what the controller and the sim say after.
    eventually(
        "the bridge to confirm the e-stop",
        Duration::from_secs(30),
        || {
            s.logs()
                .contains("e-stop from ROS 2 confirmed: controller STOPPED, sim STOPPED")
                .then_some(())
        },
    );
    // Latched as `softarm estop` latches it, and the set is gone: no more executions.
    let latch = std::fs::read_to_string(s.dir.join("state/estop")).unwrap();
    assert_eq!(latch.trim(), "engaged");
    let done = s.stats(set).len();
    std::thread::sleep(Duration::from_secs(8));
    assert_eq!(s.stats(set).len(), done, "executions after the e-stop");
    assert_eq!(s.status()["controller"]["state"], "STOPPED");
}

#[test]
fn killing_the_bridge_leaves_the_stack_running() {
    let Some(_py) = python(&["cyclonedds"]) else {
        return;
    };
    let mut s = stack("ros2-kill-bridge", true, &[]);
    s.up();
    bridging(&s);
    let set = s.executing(Path::new(DEMO_WAYPOINTS), 3);
    let bridge = eventually("the bridge", Duration::from_secs(10), || {
        s.children().into_iter().find(|(role, _)| role == "ros2")
    })
    .1;
    let ticks = s.status()["controller"]["ticks"].as_u64().unwrap();
    kill(Pid::from_raw(bridge), Signal::SIGKILL).unwrap();
    // The set runs to its end, and the controller ticks on.
    let stats = s.wait_stats(set, 3, Duration::from_secs(120));
    assert_eq!(stats.len(), 3);
    let after = s.status();
    assert!(
        after["controller"]["ticks"].as_u64().unwrap() > ticks,
        "{after}"
    );
    assert!(!alive(bridge));
}

#[test]
fn killing_the_stack_leaves_the_bridge_reporting_it() {
    let Some(py) = python(&["cyclonedds"]) else {
        return;
    };
    let mut s = stack("ros2-kill-stack", false, &[]);
    s.up();
    // The bridge beside the stack, as another unit would run it.
    let mut bridge = s.spawn(&["ros2"]);
    let got = peer(&py, &s, &["--until", "running", "--seconds", "60"]);
    assert_eq!(diagnostic(&got, "controller")["level"], 0, "{got}");

    let start = Instant::now();
    assert!(s.stop().is_some());
    let got = peer(&py, &s, &["--until", "stale", "--seconds", "60"]);
    let controller = diagnostic(&got, "controller");
    assert_eq!(controller["level"], 3, "{got}");
    assert!(
        controller["message"]
            .as_str()
            .unwrap()
            .contains("no status from the controller for"),
        "{got}"
    );
    assert_eq!(diagnostic(&got, "driver")["level"], 3, "{got}");
    assert!(
        bridge.try_wait().unwrap().is_none(),
        "the bridge went with the stack"
    );
    eprintln!(
        "the bridge reported the stack gone {:.1} s after it was stopped",
        start.elapsed().as_secs_f64()
    );
}
