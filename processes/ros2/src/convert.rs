//! The stack's samples as ROS 2 messages and ROS 2 way-point sets as the stack's, pure: no I/O,
//! no clock (times come in as arguments), so every rule here is unit-tested.

use softarm_config::Config;
use softarm_config::waypoints::validate;
use softarm_ipc::{
    ControllerState, ControllerStatus, DriverState, ExecutionStats, MAX_WAYPOINTS, MotorState,
    Setpoint, TrackerSample, WaypointSet,
};

use crate::msg::{
    DiagnosticArray, DiagnosticStatus, Header, JointState, KeyValue, Level,
    MultiDofJointTrajectory, Point, PointStamped, Time,
};

/// The frame of positions: the tracker's base frame, in metres.
pub const FRAME: &str = "base";
/// A set from ROS 2 lasts until this long after its last way-point (s): a trajectory has no
/// duration of its own, and the demo set's file ends 0.5 s after its last point.
pub const END_AFTER_LAST_S: f64 = 0.5;
/// A sample older than this is stale (s): the controller's status comes 10 times a second,
/// the motor state 100 or 200.
pub const STALE_AFTER_S: f64 = 1.0;

/// The ROS 2 namespace of a stack's namespace: `softarm/arm-1` → `/softarm/arm_1`. ROS names
/// allow letters, digits and `_`, a token must not start with a digit, and `__` is reserved.
pub fn ros_namespace(namespace: &str) -> String {
    let mut out = String::new();
    for token in namespace.split('/').filter(|t| !t.is_empty()) {
        out.push('/');
        if token.starts_with(|c: char| c.is_ascii_digit()) {
            out.push('_');
        }
        for c in token.chars() {
            let c = if c.is_ascii_alphanumeric() { c } else { '_' };
            if !(c == '_' && out.ends_with('_')) {
                out.push(c);
            }
        }
    }
    if out.is_empty() { "/".into() } else { out }
}

/// ROS time of a stack sample: its `stamp_ns` (CLOCK_MONOTONIC) moved onto the system clock
/// by `offset_ns` (system minus monotonic, taken once when the bridge starts, so one sample's
/// stamp is always the same ROS time).
pub fn ros_time(stamp_ns: u64, offset_ns: i128) -> Time {
    let ns = (stamp_ns as i128 + offset_ns).max(0);
    let sec = (ns / 1_000_000_000).min(i32::MAX as i128) as i32;
    Time {
        sec,
        nanosec: (ns % 1_000_000_000) as u32,
    }
}

fn header(stamp_ns: u64, offset_ns: i128) -> Header {
    Header {
        stamp: ros_time(stamp_ns, offset_ns),
        frame_id: String::new(),
    }
}

/// A setpoint: the normalised actuation (0 to 1 of each actuator's stroke) as positions of
/// the arm's actuators, named `joints` (`[arm]`'s names). `None` for a setpoint of another
/// count, which no joint list describes.
pub fn setpoint_state(s: &Setpoint, joints: &[String], offset_ns: i128) -> Option<JointState> {
    (s.actuation.len() == joints.len()).then(|| JointState {
        header: header(s.stamp_ns, offset_ns),
        name: joints.to_vec(),
        position: s.actuation.to_vec(),
        velocity: Vec::new(),
        effort: Vec::new(),
    })
}

/// The measured actuation, and the motor currents (A) as efforts where every motor has one
/// (the sim measures none); `None` as for [`setpoint_state`].
pub fn measured_state(m: &MotorState, joints: &[String], offset_ns: i128) -> Option<JointState> {
    let currents = m.current_a.iter().all(|c| c.is_finite());
    (m.actuation.len() == joints.len()).then(|| JointState {
        header: header(m.stamp_ns, offset_ns),
        name: joints.to_vec(),
        position: m.actuation.to_vec(),
        velocity: Vec::new(),
        effort: if currents {
            m.current_a.to_vec()
        } else {
            Vec::new()
        },
    })
}

/// A tracker position, in metres in the base frame.
pub fn tracker_point(t: &TrackerSample, offset_ns: i128) -> PointStamped {
    let [x, y, z] = t.position;
    PointStamped {
        header: Header {
            frame_id: FRAME.into(),
            ..header(t.stamp_ns, offset_ns)
        },
        point: Point { x, y, z },
    }
}

/// A way-point set from ROS 2 as the stack's, checked as `softarm submit` checks a file: one
/// execution, way-point i at `points[i].transforms[0].translation` (m, base frame) at
/// `points[i].time_from_start`, the set ending [`END_AFTER_LAST_S`] after the last. The error
/// says what is wrong and where.
pub fn waypoint_set(t: &MultiDofJointTrajectory, config: &Config) -> Result<WaypointSet, String> {
    let n = t.points.len();
    if n == 0 || n > MAX_WAYPOINTS {
        return Err(format!("{n} points; a set has 1 to {MAX_WAYPOINTS}"));
    }
    let frame = t.header.frame_id.as_str();
    if !(frame.is_empty() || frame == FRAME) {
        return Err(format!(
            "header.frame_id {frame:?}: positions must be in the base frame \"{FRAME}\" (or \
             leave it empty); the bridge does no frame transforms"
        ));
    }
    let mut set = WaypointSet {
        executions: 1,
        count: n as u32,
        ..Default::default()
    };
    for (i, p) in t.points.iter().enumerate() {
        let Some(transform) = p.transforms.first() else {
            return Err(format!(
                "points[{i}].transforms is empty: transforms[0].translation is the way-point"
            ));
        };
        let d = p.time_from_start;
        if d.sec < 0 || d.nanosec >= 1_000_000_000 {
            return Err(format!(
                "points[{i}].time_from_start = {} s {} ns is not a time after the start",
                d.sec, d.nanosec
            ));
        }
        set.times_s[i] = d.sec as f64 + d.nanosec as f64 * 1e-9;
        let v = transform.translation;
        set.positions_m[i] = [v.x, v.y, v.z];
    }
    set.duration_s = set.times_s[n - 1] + END_AFTER_LAST_S;
    validate(&set, &config.waypoints, &config.activation)?;
    Ok(set)
}

/// What the bridge itself did with the input from ROS 2, for the diagnostics.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BridgeReport {
    pub accept_waypoints: bool,
    pub sets_accepted: u64,
    pub sets_refused: u64,
    /// The id the controller gave the last set accepted, 0 if none.
    pub last_set_id: u64,
    /// Why the last set refused was, if the last set was refused.
    pub last_refusal: Option<String>,
    pub estops: u64,
    /// What the stack said of the last e-stop from ROS 2 (`confirmed: ...`, `not confirmed
    /// by: ...`), if one came.
    pub estop_confirmation: Option<String>,
}

/// What the diagnostics are made from: the newest samples with their ages (s) when the
/// diagnostics are made, and the e-stop latch (`None`: unreadable, which counts as engaged).
#[derive(Debug, Clone, Default)]
pub struct Snapshot {
    pub status: Option<(ControllerStatus, f64)>,
    pub motor: Option<(MotorState, f64)>,
    pub stats: Option<ExecutionStats>,
    pub estop_latched: Option<bool>,
    pub bridge: BridgeReport,
}

fn status(
    level: Level,
    name: String,
    message: String,
    values: Vec<(&str, String)>,
) -> DiagnosticStatus {
    DiagnosticStatus {
        level: level as u8,
        name,
        message,
        hardware_id: String::new(),
        values: values
            .into_iter()
            .map(|(k, v)| KeyValue {
                key: k.into(),
                value: v,
            })
            .collect(),
    }
}

/// The diagnostics of the stack in `namespace` (its ROS 2 namespace names each entry):
/// controller, driver, e-stop, the last execution's errors, and the bridge.
pub fn diagnostics(s: &Snapshot, namespace: &str, stamp: Time) -> DiagnosticArray {
    let name = |part: &str| format!("{namespace}: {part}");
    DiagnosticArray {
        header: Header {
            stamp,
            frame_id: String::new(),
        },
        status: vec![
            controller(s, name("controller")),
            driver(s, name("driver")),
            estop(s, name("estop")),
            stats(s, name("stats")),
            bridge(s, name("ros2 bridge")),
        ],
    }
}

fn stale(name: String, what: &str, age: Option<f64>) -> DiagnosticStatus {
    let message = match age {
        Some(a) => format!("no {what} for {a:.1} s: the stack is gone or not in this namespace"),
        None => format!("no {what} yet: the stack is not running or not in this namespace"),
    };
    status(Level::Stale, name, message, Vec::new())
}

fn controller(s: &Snapshot, name: String) -> DiagnosticStatus {
    let Some((c, age)) = s.status.filter(|(_, age)| *age <= STALE_AFTER_S) else {
        return stale(name, "status from the controller", s.status.map(|(_, a)| a));
    };
    let state = ControllerState::from_u32(c.state);
    let (level, message) = match state {
        Some(ControllerState::Hold) => (Level::Warn, "HOLD: tracker or motor data too old".into()),
        Some(ControllerState::Stopped) => (Level::Warn, "STOPPED: the e-stop is engaged".into()),
        Some(st) => (Level::Ok, st.name().to_string()),
        None => (Level::Error, format!("unknown state {}", c.state)),
    };
    let ms = |ns: u64| format!("{:.3}", ns as f64 / 1e6);
    let values = vec![
        ("state", state.map_or("?".into(), |s| s.name().to_string())),
        ("set_id", c.set_id.to_string()),
        ("execution", c.execution.to_string()),
        ("ticks", c.ticks.to_string()),
        ("overruns", c.overruns.to_string()),
        ("tick_latency_p50_ms", ms(c.latency.p50_ns)),
        ("tick_latency_p99_ms", ms(c.latency.p99_ns)),
        ("tracker_age_ms", ms(c.tracker_age_ns)),
        ("motor_age_ms", ms(c.motor_age_ns)),
        ("model_loaded", (c.model_loaded == 1).to_string()),
        ("status_age_s", format!("{age:.3}")),
    ];
    status(level, name, message, values)
}

fn driver(s: &Snapshot, name: String) -> DiagnosticStatus {
    let Some((m, _)) = s.motor.filter(|(_, age)| *age <= STALE_AFTER_S) else {
        return stale(name, "motor state from the driver", s.motor.map(|(_, a)| a));
    };
    let state = m.driver_state();
    let level = match state {
        Some(DriverState::Following) => Level::Ok,
        Some(DriverState::Fault) | None => Level::Error,
        Some(_) => Level::Warn,
    };
    let message = state.map_or(format!("unknown state {}", m.state), |d| {
        d.name().to_string()
    });
    let values = vec![
        ("loss_permille", m.loss_permille.to_string()),
        ("faults", m.faults.to_string()),
        ("reopens", m.reopens.to_string()),
    ];
    status(level, name, message, values)
}

fn estop(s: &Snapshot, name: String) -> DiagnosticStatus {
    let (level, message) = match s.estop_latched {
        Some(false) => (Level::Ok, "released".to_string()),
        Some(true) => (
            Level::Error,
            "engaged: reset with `softarm estop --reset` on the arm's host (never from ROS 2)"
                .to_string(),
        ),
        None => (
            Level::Error,
            "the latch cannot be read, which counts as engaged".to_string(),
        ),
    };
    let engaged = s.estop_latched != Some(false);
    let confirmation = s.bridge.estop_confirmation.clone().unwrap_or_default();
    // An e-stop from ROS 2 that the stack did not confirm is a fault whatever the latch says.
    let level = if confirmation.starts_with("not ") {
        Level::Error
    } else {
        level
    };
    status(
        level,
        name,
        message,
        vec![
            ("engaged", engaged.to_string()),
            ("confirmation", confirmation),
        ],
    )
}

fn stats(s: &Snapshot, name: String) -> DiagnosticStatus {
    let Some(e) = &s.stats else {
        return status(Level::Ok, name, "no execution yet".into(), Vec::new());
    };
    let mm = |m: f64| format!("{:.2}", m * 1e3);
    let message = format!(
        "set {} execution {}/{}: mean {} mm, max {} mm",
        e.set_id,
        e.execution,
        e.executions,
        mm(e.mean_m),
        mm(e.max_m)
    );
    let values = vec![
        ("set_id", e.set_id.to_string()),
        ("execution", e.execution.to_string()),
        ("mean_mm", mm(e.mean_m)),
        ("max_mm", mm(e.max_m)),
    ];
    status(Level::Ok, name, message, values)
}

fn bridge(s: &Snapshot, name: String) -> DiagnosticStatus {
    let b = &s.bridge;
    let (level, message) = match &b.last_refusal {
        Some(why) => (Level::Warn, format!("way-point set refused: {why}")),
        None if b.accept_waypoints => (Level::Ok, "accepting way-point sets".into()),
        None => (Level::Ok, "read-only: way-point sets are refused".into()),
    };
    let values = vec![
        ("accept_waypoints", b.accept_waypoints.to_string()),
        ("sets_accepted", b.sets_accepted.to_string()),
        ("sets_refused", b.sets_refused.to_string()),
        ("last_set_id", b.last_set_id.to_string()),
        ("last_refusal", b.last_refusal.clone().unwrap_or_default()),
        ("estops", b.estops.to_string()),
    ];
    status(level, name, message, values)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msg::{Duration, MultiDofJointTrajectoryPoint, Transform, Vector3};
    use softarm_ipc::Latency;

    fn config() -> Config {
        Config::default_sim("/".into())
    }

    /// The demo set (`config/waypoints/demo.toml`) as a ROS 2 user sends it.
    fn demo() -> MultiDofJointTrajectory {
        let points = [
            (0.8, [0.165, 0.000, -0.471]),
            (1.8, [0.031, 0.000, -0.501]),
            (2.8, [-0.105, 0.000, -0.487]),
            (3.7, [-0.136, 0.065, -0.473]),
            (4.5, [-0.063, 0.183, -0.450]),
        ];
        MultiDofJointTrajectory {
            header: Header {
                frame_id: "base".into(),
                ..Default::default()
            },
            joint_names: vec!["tip".into()],
            points: points
                .iter()
                .map(|&(t, [x, y, z])| MultiDofJointTrajectoryPoint {
                    transforms: vec![Transform {
                        translation: Vector3 { x, y, z },
                        ..Default::default()
                    }],
                    time_from_start: Duration {
                        sec: t as i32,
                        nanosec: ((t - (t as i32) as f64) * 1e9).round() as u32,
                    },
                    ..Default::default()
                })
                .collect(),
        }
    }

    #[test]
    fn a_stack_namespace_becomes_a_valid_ros_namespace() {
        assert_eq!(ros_namespace("softarm/arm1"), "/softarm/arm1");
        assert_eq!(
            ros_namespace("softarm/test-ros2-x.y-123"),
            "/softarm/test_ros2_x_y_123"
        );
        assert_eq!(ros_namespace("softarm/7th--arm"), "/softarm/_7th_arm");
        for ns in ["softarm/a-b", "x/1", "a/b/c", "softarm/arm__1"] {
            let r = ros_namespace(ns);
            assert!(
                ros2_client::Name::new(&r, "setpoint").is_ok(),
                "{ns} -> {r}"
            );
        }
    }

    #[test]
    fn ros_time_is_the_stamp_moved_by_a_fixed_offset() {
        let t = ros_time(1_500_000_000, 1_700_000_000_000_000_000);
        assert_eq!(
            t,
            Time {
                sec: 1_700_000_001,
                nanosec: 500_000_000
            }
        );
        // Before the epoch cannot be said: 0.
        assert_eq!(ros_time(5, -10), Time::default());
    }

    #[test]
    fn samples_become_joint_states_and_points_value_for_value() {
        let s = Setpoint {
            stamp_ns: 2_000_000_001,
            actuation: [0.1, 0.2, 0.3, 0.4, 0.5, 0.6].into(),
            ..Default::default()
        };
        let joints: Vec<String> = config().layout().names().map(String::from).collect();
        assert_eq!(
            joints,
            ["a1", "a2", "a3", "a4", "a5", "a6"],
            "the paper's arm"
        );
        let j = setpoint_state(&s, &joints, 0).unwrap();
        assert_eq!(j.name, joints);
        assert_eq!(j.position, s.actuation.as_slice());
        assert_eq!(j.header.stamp, Time { sec: 2, nanosec: 1 });
        assert!(j.velocity.is_empty() && j.effort.is_empty());

        let mut m = MotorState {
            actuation: [0.5; 6].into(),
            current_a: [f64::NAN; 6].into(),
            ..Default::default()
        };
        assert!(
            measured_state(&m, &joints, 0).unwrap().effort.is_empty(),
            "the sim measures no current"
        );
        m.current_a = [0.25; 6].into();
        let j = measured_state(&m, &joints, 0).unwrap();
        assert_eq!((j.position, j.effort), (vec![0.5; 6], vec![0.25; 6]));
        // Another arm's count: no joint state names it.
        m.actuation = [0.5; 9].into();
        assert!(measured_state(&m, &joints, 0).is_none());

        let t = TrackerSample {
            position: [0.1, -0.2, -0.45],
            ..Default::default()
        };
        let p = tracker_point(&t, 0);
        assert_eq!(p.header.frame_id, "base");
        assert_eq!((p.point.x, p.point.y, p.point.z), (0.1, -0.2, -0.45));
    }

    #[test]
    fn a_trajectory_becomes_the_set_a_file_would() {
        let c = config();
        let set = waypoint_set(&demo(), &c).unwrap();
        let file = softarm_config::waypoints::WaypointFile::load(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../config/waypoints/demo.toml"),
        )
        .unwrap()
        .to_set(1)
        .unwrap();
        assert_eq!(set.count, file.count);
        assert_eq!(set.executions, 1);
        assert_eq!(set.duration_s, file.duration_s);
        assert_eq!(set.positions_m, file.positions_m);
        for (a, b) in set.times_s.iter().zip(file.times_s) {
            assert!((a - b).abs() < 1e-9, "{a} {b}");
        }
        // An empty frame is the base frame too.
        let mut t = demo();
        t.header.frame_id.clear();
        assert!(waypoint_set(&t, &c).is_ok());
    }

    #[test]
    fn a_bad_trajectory_is_refused_saying_why() {
        let c = config();
        let refused = |f: &dyn Fn(&mut MultiDofJointTrajectory)| {
            let mut t = demo();
            f(&mut t);
            waypoint_set(&t, &c).unwrap_err()
        };
        let nan = refused(&|t| t.points[2].transforms[0].translation.y = f64::NAN);
        assert!(
            nan.contains("point 3") && nan.contains("not a finite number"),
            "{nan}"
        );
        let many = refused(&|t| {
            let p = t.points[0].clone();
            t.points = vec![p; MAX_WAYPOINTS + 1];
        });
        assert_eq!(many, format!("17 points; a set has 1 to {MAX_WAYPOINTS}"));
        assert!(refused(&|t| t.points.clear()).starts_with("0 points"));
        let order = refused(&|t| t.points.swap(1, 2));
        assert!(order.contains("times must increase strictly"), "{order}");
        let out = refused(&|t| t.points[0].transforms[0].translation.z = 2.0);
        assert!(
            out.contains("point 1") && out.contains("outside the workspace"),
            "{out}"
        );
        let frame = refused(&|t| t.header.frame_id = "world".into());
        assert!(frame.contains("header.frame_id \"world\""), "{frame}");
        let none = refused(&|t| t.points[1].transforms.clear());
        assert!(none.contains("points[1].transforms is empty"), "{none}");
        let negative = refused(&|t| t.points[0].time_from_start.sec = -1);
        assert!(negative.contains("points[0].time_from_start"), "{negative}");
        let nanos = refused(&|t| t.points[0].time_from_start.nanosec = 1_000_000_000);
        assert!(nanos.contains("points[0].time_from_start"), "{nanos}");
    }

    fn levels(s: &Snapshot) -> Vec<(String, u8)> {
        diagnostics(s, "/softarm/a", Time::default())
            .status
            .into_iter()
            .map(|d| {
                (
                    d.name.trim_start_matches("/softarm/a: ").to_string(),
                    d.level,
                )
            })
            .collect()
    }

    fn level(s: &Snapshot, part: &str) -> u8 {
        levels(s).into_iter().find(|(n, _)| n == part).unwrap().1
    }

    #[test]
    fn diagnostics_say_what_runs_and_what_is_gone() {
        let running = ControllerStatus {
            state: ControllerState::Execute as u32,
            latency: Latency {
                p99_ns: 250_000,
                ..Default::default()
            },
            ..Default::default()
        };
        let motor = MotorState::default();
        let mut s = Snapshot {
            status: Some((running, 0.05)),
            motor: Some((motor, 0.01)),
            estop_latched: Some(false),
            ..Default::default()
        };
        let names: Vec<String> = levels(&s).into_iter().map(|(n, _)| n).collect();
        assert_eq!(
            names,
            ["controller", "driver", "estop", "stats", "ros2 bridge"]
        );
        assert!(
            levels(&s).iter().all(|(_, l)| *l == Level::Ok as u8),
            "{:?}",
            levels(&s)
        );
        let d = diagnostics(&s, "/softarm/a", Time::default());
        let c = &d.status[0];
        assert_eq!(c.message, "EXECUTE");
        assert!(
            c.values
                .iter()
                .any(|kv| kv.key == "tick_latency_p99_ms" && kv.value == "0.250")
        );

        // The controller gone: stale, and saying so; never a state it no longer has.
        s.status = Some((running, STALE_AFTER_S + 0.5));
        assert_eq!(level(&s, "controller"), Level::Stale as u8);
        let d = diagnostics(&s, "/softarm/a", Time::default());
        assert!(
            d.status[0]
                .message
                .contains("no status from the controller for 1.5 s")
        );
        s.status = None;
        assert_eq!(level(&s, "controller"), Level::Stale as u8);
        s.motor = Some((motor, 5.0));
        assert_eq!(level(&s, "driver"), Level::Stale as u8);

        // The e-stop: engaged, or a latch that cannot be read, is an error.
        s.estop_latched = Some(true);
        assert_eq!(level(&s, "estop"), Level::Error as u8);
        s.estop_latched = None;
        assert_eq!(level(&s, "estop"), Level::Error as u8);

        // A refusal is visible until a set is accepted.
        s.bridge.last_refusal = Some("ros2.accept_waypoints is false".into());
        s.bridge.sets_refused = 1;
        assert_eq!(level(&s, "ros2 bridge"), Level::Warn as u8);
        let d = diagnostics(&s, "/softarm/a", Time::default());
        assert!(
            d.status[4]
                .message
                .contains("refused: ros2.accept_waypoints is false")
        );
    }
}
