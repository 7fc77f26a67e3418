//! Arms other than the paper's, described in `[arm]` alone: the sim drives the shipped
//! nine-tendon TDCR and the hybrid with its chambers from setpoints of their own counts, the
//! Python mirror reads a nine-actuator stack, the ROS 2 bridge names the hybrid's joints as its
//! `[arm]` does, and the whole stack executes a set on the TDCR.

use std::time::Duration;

use softarm_config::Config;
use softarm_config::arms;
use softarm_ipc::{Actuators, MotorState, Namespace, Node, Setpoint, TrackerSample};
use softarm_kinematics::pcc;
use softarm_runtime::now_ns;
use softarm_test_support::{Guard, TestStack, config_text, eventually, with_overrides};

use crate::python::{python, run_python};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");
const PY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/clients/python");

/// A stack folder whose config is the embedded one on shipped arm `arm`, with `overrides`; no
/// model, nothing started. The sim's realism stays as shipped.
fn on_arm(name: &str, arm: &str, overrides: &[(&str, toml::Value)]) -> (TestStack, Config) {
    let s = TestStack::with_config(BIN, name, false, |dir, ns| {
        let text =
            arms::with_arm(&config_text(dir, ns), &arms::resolve(arm).unwrap(), arm).unwrap();
        with_overrides(&text, overrides)
    });
    let c = Config::load(&s.config).unwrap();
    (s, c)
}

/// Publishes `a` as the setpoint every 10 ms while the returned guard lives.
struct Commanding {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Commanding {
    fn start(namespace: &str, a: Vec<f64>) -> Self {
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let (flag, ns) = (stop.clone(), namespace.to_string());
        let thread = std::thread::spawn(move || {
            let n = Node::open(Namespace::new(&ns).unwrap(), "test.commands").unwrap();
            let p = n.publisher(&n.setpoint().unwrap()).unwrap();
            while !flag.load(std::sync::atomic::Ordering::Relaxed) {
                let _ = p.send_copy(Setpoint {
                    stamp_ns: now_ns(),
                    actuation: Actuators::new(&a),
                    ..Setpoint::default()
                });
                std::thread::sleep(Duration::from_millis(10));
            }
        });
        Self {
            stop,
            thread: Some(thread),
        }
    }
}

impl Drop for Commanding {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn sim(s: &TestStack) -> Guard {
    s.spawn(&["sim"])
}

/// The nine-tendon TDCR in the sim: it follows setpoints of nine (each actuator its own
/// value), reports nine, and the tracker sees the tip where the TDCR's kinematics put it for
/// the actuation the sim measured; Python reads the nine from the live service.
#[test]
fn the_sim_drives_a_nine_tendon_arm_and_python_reads_it() {
    let (s, c) = on_arm("arm-tdcr", "tdcr", &[]);
    assert_eq!(c.layout().actuators().len(), 9);
    let _sim = sim(&s);
    let want: Vec<f64> = (0..9).map(|i| 0.3 + 0.05 * i as f64).collect();
    let _commanding = Commanding::start(&s.namespace, want.clone());
    let n = Node::open(Namespace::new(&s.namespace).unwrap(), "test").unwrap();
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    let tracker = n.subscriber(&n.tracker().unwrap()).unwrap();
    // The sim's lag and rate limit take it there; its noise keeps it within a few thousandths.
    let m: MotorState = eventually(
        "nine actuators where they were sent",
        Duration::from_secs(60),
        || {
            let mut last = None;
            while let Ok(Some(m)) = motors.receive() {
                last = Some(*m);
            }
            last.filter(|m| {
                m.actuation.len() == 9
                    && m.actuation
                        .iter()
                        .zip(&want)
                        .all(|(a, w)| (a - w).abs() < 0.02)
            })
        },
    );
    let arm = pcc::Arm::new(&c.layout(), &[]);
    let model = arm.pose(&m.actuation).unwrap().position;
    let seen: TrackerSample = eventually("a tracker sample", Duration::from_secs(20), || {
        let mut last = None;
        while let Ok(Some(t)) = tracker.receive() {
            last = Some(*t);
        }
        last
    });
    let miss = (0..3)
        .map(|d| (seen.position[d] - model[d]).powi(2))
        .sum::<f64>()
        .sqrt();
    // Tracker noise, drift and the time between the two samples: millimetres, on an arm
    // whose tip moves 100 mm and more across its strokes.
    assert!(
        miss < 0.005,
        "the tracker {:?} is {miss} m from the model's {model}",
        seen.position
    );
    assert!(
        seen.position[2] > 0.1,
        "standing: the tip is above its base, {:?}",
        seen.position
    );

    let Some(py) = python(&["iceoryx2"]) else {
        return;
    };
    let read = format!(
        "import sys, time; sys.path.insert(0, {PY:?}); import softarm_ipc as sa\n\
         node = sa.open_node({ns:?}, 'python.arm')\n\
         sub = sa.subscribe(node, {ns:?}, 'motor_state')\n\
         end = time.monotonic() + 60\n\
         while time.monotonic() < end:\n\
         \x20   got = list(sub.receive_all())\n\
         \x20   if got:\n\
         \x20       print(' '.join(f'{{a:.3f}}' for a in got[-1].actuation.to_list())); break\n\
         \x20   time.sleep(0.01)\n",
        ns = s.namespace
    );
    let out = run_python(&py, &["-c", &read]);
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    let values: Vec<f64> = text
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    assert_eq!(values.len(), 9, "{text}");
    for (v, w) in values.iter().zip(&want) {
        assert!((v - w).abs() < 0.02, "{text}");
    }
}

/// The hybrid arm (tendons and a chamber in each module): the sim follows eight actuators, and
/// a setpoint of the paper's six is refused whole.
#[test]
fn the_sim_drives_the_hybrid_arm_and_refuses_six() {
    let (s, c) = on_arm("arm-hybrid", "hybrid", &[]);
    let names: Vec<String> = c.layout().names().map(String::from).collect();
    assert_eq!(names, ["t1", "t2", "t3", "p1", "t4", "t5", "t6", "p2"]);
    let _sim = sim(&s);
    let n = Node::open(Namespace::new(&s.namespace).unwrap(), "test").unwrap();
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    let newest = || {
        let mut last = None;
        while let Ok(Some(m)) = motors.receive() {
            last = Some(*m);
        }
        last
    };
    // Six is refused: the arm stays at its initial actuation.
    {
        let _six = Commanding::start(&s.namespace, vec![0.8; 6]);
        std::thread::sleep(Duration::from_millis(500));
        let m: MotorState = eventually("motor state", Duration::from_secs(20), &newest);
        assert_eq!(m.actuation.len(), 8);
        assert!(
            m.actuation.iter().all(|a| (a - 0.5).abs() < 0.02),
            "{:?}",
            m.actuation
        );
    }
    let want = [0.4, 0.45, 0.5, 0.7, 0.55, 0.6, 0.65, 0.3];
    let _eight = Commanding::start(&s.namespace, want.to_vec());
    eventually(
        "eight actuators where they were sent",
        Duration::from_secs(60),
        || {
            newest().filter(|m| {
                m.actuation
                    .iter()
                    .zip(&want)
                    .all(|(a, w)| (a - w).abs() < 0.02)
            })
        },
    );
}

/// The whole stack on the nine-tendon TDCR: the sim, the controller and the learner run its
/// nine actuators from a model made for it, and a set on its own demonstrations is executed:
/// every point seen, each execution re-conditioned by the learner's estimates. A scenario of
/// the paper's arm's per-actuator values on the TDCR is a config error (78, which neither `up`
/// nor systemd restarts), naming the arm and the key.
#[test]
fn the_stack_executes_a_set_on_the_nine_tendon_arm() {
    let (mut s, c) = on_arm("arm-tdcr-stack", "tdcr", &[]);
    // The paper's creep names six actuators: a config error on this arm, naming both.
    let out = s.run(&["sim", "--scenario", "creep"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(78), "{err}");
    assert!(err.contains("9 actuators (a1 .. a9) in 3 modules"), "{err}");
    assert!(
        err.contains("arm.actuator_offset_m: a key of the paper's arm"),
        "{err}"
    );

    softarm_test_support::quick_model_of(&s.dir.join("model"), &c);
    s.up();
    let file = softarm_stack::demo::demo_set(&c).unwrap();
    let mut text = format!("duration_s = {}\n", file.duration_s);
    for p in &file.point {
        text += &format!(
            "[[point]]\nt_s = {}\nposition_m = {:?}\n",
            p.t_s, p.position_m
        );
    }
    let path = s.dir.join("tdcr-set.toml");
    std::fs::write(&path, text).unwrap();
    let id = s.executing(&path, 3);
    let stats = s.wait_stats(id, 3, Duration::from_secs(120));
    for st in &stats {
        assert_eq!(st["errors_mm"].as_array().unwrap().len(), 5, "{st}");
        assert_eq!(st["unseen"], 0, "{st}");
        assert!(st["mean_mm"].as_f64().unwrap().is_finite(), "{st}");
    }
    // From the second execution on, the learner's estimates re-condition it as it runs.
    assert!(
        stats[1..]
            .iter()
            .all(|st| st["reconditions"].as_u64().unwrap() > 0),
        "{stats:?}"
    );
    // Every sample a visit, every estimate used: no count was another arm's.
    let logs = s.logs();
    for refusal in ["sample refused", "estimate not used"] {
        assert!(!logs.contains(refusal), "{refusal}: {logs}");
    }
}

/// The arm's joints reach ROS 2 by the names `[arm]` gives them: the hybrid arm in the sim
/// (tendons t1..t6, chambers p1 and p2), bridged, its setpoints and `joint_states` with eight.
#[test]
fn a_ros2_peer_sees_the_joints_named_as_the_arm_names_them() {
    let Some(py) = python(&["cyclonedds"]) else {
        return;
    };
    let (s, _) = on_arm("arm-ros2", "hybrid", &[("ros2.status_hz", 5.0.into())]);
    let s = {
        // The domain is the namespace's, which the folder gives: set once it is known.
        let text = std::fs::read_to_string(&s.config).unwrap();
        let domain = (crate::ros2::domain(&s.namespace) as i64).into();
        std::fs::write(
            &s.config,
            with_overrides(
                &text,
                &[("ros2.enabled", true.into()), ("ros2.domain_id", domain)],
            ),
        )
        .unwrap();
        s
    };
    let _sim = sim(&s);
    let _bridge = s.spawn(&["ros2"]);
    let _commanding = Commanding::start(&s.namespace, vec![0.5; 8]);
    eventually("the bridge running", Duration::from_secs(60), || {
        std::fs::read_to_string(s.dir.join("ros2.log"))
            .unwrap_or_default()
            .contains("bridging the stack to ROS 2")
            .then_some(())
    });
    let got = crate::ros2::peer(&py, &s, &["--seconds", "4"]);
    assert_eq!(
        got["joint_names"],
        serde_json::json!(["t1", "t2", "t3", "p1", "t4", "t5", "t6", "p2"]),
        "{got}"
    );
    assert!(got["counts"]["joint_states"].as_u64().unwrap() > 0, "{got}");
    assert!(got["counts"]["setpoint"].as_u64().unwrap() > 0, "{got}");
}
