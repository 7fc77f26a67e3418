//! End to end: samples with out-of-range fields on the iceoryx2 services, as a broken peer
//! could send them, reach the real processes and change nothing but a counter and a log line.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use softarm_config::Config;
use softarm_config::hardware::Mapping;
use softarm_config::waypoints::WaypointFile;
use softarm_emulate::rig::Rig;
use softarm_ipc::iceoryx2::prelude::ZeroCopySend;
use softarm_ipc::{
    ActuationEstimate, Actuators, ConditioningSample, ControllerState, ControllerStatus,
    DriverState, EstimateRequest, MAX_WAYPOINTS, MotorState, Namespace, Node, Position, Setpoint,
    Sub, TrackerSample, WaypointReply, WaypointSet,
};
use softarm_kinematics::forward::ForwardModel;
use softarm_kinematics::pcc;
use softarm_runtime::now_ns;
use softarm_test_support::{DEMO_WAYPOINTS, Devices, TestStack, alive, eventually, with_overrides};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");

#[test]
fn a_setpoint_that_is_not_a_number_is_refused_by_the_driver() {
    let s = TestStack::new(BIN, "nan-setpoint", false);
    // The sim alone, and this test as its controller.
    let mut sim = s.spawn(&["sim"]);
    let node = Node::open(Namespace::new(&s.namespace).unwrap(), "test").unwrap();
    let setpoints = node.publisher(&node.setpoint().unwrap()).unwrap();
    let motors = node.subscriber(&node.motor_state().unwrap()).unwrap();
    let send = |actuation: Actuators| {
        setpoints
            .send_copy(Setpoint {
                seq: 1,
                stamp_ns: now_ns(),
                actuation,
                ..Default::default()
            })
            .unwrap()
    };
    // Wait for the sim, then a good setpoint, then broken ones.
    let start = Instant::now();
    while send([0.6; 6].into()) == 0 {
        assert!(start.elapsed() < Duration::from_secs(20), "no sim");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(300));
    // Not numbers, and another arm's five or nine actuators.
    for bad in [
        [f64::NAN; 6].into(),
        [0.6, 0.6, f64::INFINITY, 0.6, 0.6, 0.6].into(),
        [0.6, f64::NEG_INFINITY, 0.6, 0.6, 0.6, f64::NAN].into(),
        Actuators::filled(5, 0.9),
        Actuators::filled(9, 0.9),
    ] {
        send(bad);
        std::thread::sleep(Duration::from_millis(50));
    }
    // Motor states from after the broken setpoints, however slow the machine: the last good
    // setpoint still rules.
    let after = now_ns();
    let mut seen = 0;
    let start = Instant::now();
    while seen < 20 {
        while let Ok(Some(m)) = motors.receive() {
            if m.stamp_ns > after {
                seen += 1;
                assert!(
                    m.actuation
                        .iter()
                        .all(|v| v.is_finite() && (0.5..0.7).contains(v)),
                    "the sim followed a broken setpoint: {:?}",
                    m.actuation
                );
            }
        }
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "no motor state after the broken setpoints"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(alive(sim.id() as i32), "the sim died: {}", s.logs());
    let _ = nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(sim.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    );
    sim.wait().unwrap();
    let log = std::fs::read_to_string(s.dir.join("sim.log")).unwrap();
    assert!(log.contains("setpoint refused"), "{log}");
    assert!(log.contains("refused=5"), "five refused, counted: {log}");
}

/// Three of the demo set's way-points: a set the quick model can plan.
const TARGETS: [Position; 3] = [
    [0.165, 0.000, -0.471],
    [0.031, 0.000, -0.501],
    [-0.105, 0.000, -0.487],
];
const LIMIT: Duration = Duration::from_secs(30);

fn node(s: &TestStack) -> Node {
    Node::open(Namespace::new(&s.namespace).unwrap(), "test").unwrap()
}

fn log_of(s: &TestStack, role: &str) -> String {
    std::fs::read_to_string(s.dir.join(format!("{role}.log"))).unwrap_or_default()
}

/// Every file under `dir` with its bytes (none if `dir` is not there).
fn files(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        if e.path().is_dir() {
            out.extend(files(&e.path()));
        } else {
            out.insert(e.path(), std::fs::read(e.path()).unwrap_or_default());
        }
    }
    out
}

/// A request for [`TARGETS`] as set `set_id`.
fn request(set_id: u64) -> EstimateRequest {
    let mut desired = [[0.0; 3]; MAX_WAYPOINTS];
    desired[..3].copy_from_slice(&TARGETS);
    EstimateRequest {
        seq: set_id,
        stamp_ns: now_ns(),
        set_id,
        count: 3,
        _pad: 0,
        desired,
    }
}

/// A well-formed visit of `point` in `execution` of set `set_id` (of [`TARGETS`]) with the
/// actuation `actuation`, where the arm reached `reached`.
fn visit(
    set_id: u64,
    execution: u32,
    point: u32,
    actuation: Actuators,
    reached: Position,
) -> ConditioningSample {
    let next = (point + 1) % 3;
    ConditioningSample {
        seq: 0,
        stamp_ns: now_ns(),
        set_id,
        execution,
        point,
        points: 3,
        _pad: 0,
        actuation,
        desired: TARGETS[point as usize],
        reached,
        next_point: next,
        next_execution: if next == 0 { execution + 1 } else { execution },
        next_desired: TARGETS[next as usize],
        measured: Actuators::filled(6, f64::NAN),
        conditioned: actuation,
    }
}

/// The estimates that arrive within [`LIMIT`] until `n` of set `set_id` did: (those, any of
/// other sets that came meanwhile).
fn estimates(
    sub: &Sub<ActuationEstimate>,
    set_id: u64,
    n: usize,
) -> (Vec<ActuationEstimate>, Vec<ActuationEstimate>) {
    let (mut mine, mut others) = (Vec::new(), Vec::new());
    let start = Instant::now();
    while mine.len() < n {
        while let Ok(Some(e)) = sub.receive() {
            if e.set_id == set_id {
                mine.push(*e);
            } else {
                others.push(*e);
            }
        }
        assert!(
            start.elapsed() < LIMIT,
            "{} of {n} estimates of set {set_id} in {LIMIT:?}",
            mine.len()
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    mine.sort_by_key(|e| e.point);
    (mine, others)
}

fn actuations(e: &[ActuationEstimate]) -> Vec<(u32, Actuators)> {
    e.iter().map(|e| (e.point, e.actuation)).collect()
}

#[test]
fn malformed_conditioning_samples_and_requests_are_refused_by_the_learner_and_change_nothing() {
    let s = TestStack::new(BIN, "bad-learner", true);
    let learner = s.spawn(&["learner"]);
    let n = node(&s);
    let requests = n.publisher(&n.estimate_request().unwrap()).unwrap();
    let samples = n.publisher(&n.cp_sample().unwrap()).unwrap();
    let answers = n.subscriber(&n.estimate().unwrap()).unwrap();
    // The learner's ports open before it loads the model, so its subscribers exist once it is
    // ready; nothing sent before is lost either way (the requests wait in its buffer).
    eventually("the learner ready", LIMIT, || {
        log_of(&s, "learner")
            .contains("learner ready")
            .then_some(())
    });
    // Slow enough that no buffer (8 requests, 64 samples) overflows however late the learner
    // polls.
    let pace = || std::thread::sleep(Duration::from_millis(20));

    // A set, one visit of it learnt (its second point: no checkpoint yet), and what the learner
    // then answers for the same targets as a new set.
    requests.send_copy(request(1000)).unwrap();
    let (first, _) = estimates(&answers, 1000, 3);
    samples
        .send_copy(visit(1000, 1, 1, first[1].actuation, [0.03, 0.001, -0.5]))
        .unwrap();
    estimates(&answers, 1000, 1);
    requests.send_copy(request(2000)).unwrap();
    let (before, _) = estimates(&answers, 2000, 3);
    let state = s.dir.join("state");
    let checkpoints = files(&state);

    // Requests a broken peer could send: refused whole, before the running set's memory goes.
    let mut bad_requests = Vec::new();
    bad_requests.push((
        EstimateRequest {
            set_id: 0,
            ..request(3)
        },
        "request refused: set_id 0 is no set",
    ));
    bad_requests.push((
        EstimateRequest {
            count: 0,
            ..request(4)
        },
        "request refused: count 0 is out of range (1 to 16)",
    ));
    bad_requests.push((
        EstimateRequest {
            count: 17,
            ..request(5)
        },
        "request refused: count 17 is out of range (1 to 16)",
    ));
    let mut nan = request(6);
    nan.desired[1][2] = f64::NAN;
    bad_requests.push((
        nan,
        "request refused: desired[1] [0.031, 0.0, NaN] is not finite",
    ));
    for (r, _) in &bad_requests {
        requests.send_copy(*r).unwrap();
        pace();
    }

    // Samples: of the running set (2000) with out-of-range, non-finite or inconsistent fields,
    // and of the set visited before (1000), going back over its last visit.
    let a = before[2].actuation;
    let good = visit(2000, 1, 2, a, TARGETS[2]);
    let mut far = good;
    far.desired = [0.1, 0.1, -0.4];
    let bad_samples: Vec<(ConditioningSample, &str)> = vec![
        (
            ConditioningSample { point: 3, ..good },
            "sample refused: point 3 is out of range (the set has 3 points)",
        ),
        (
            ConditioningSample {
                next_point: 99,
                ..good
            },
            "sample refused: next_point 99 is out of range (the set has 3 points)",
        ),
        (
            ConditioningSample {
                points: 0,
                point: 0,
                next_point: 0,
                ..good
            },
            "sample refused: points 0 is out of range (1 to 16)",
        ),
        (
            ConditioningSample { points: 17, ..good },
            "sample refused: points 17 is out of range (1 to 16)",
        ),
        (
            ConditioningSample {
                actuation: Actuators::filled(9, 0.5),
                ..good
            },
            "sample refused: actuation has 9 actuators; the arm has 6",
        ),
        (
            ConditioningSample {
                desired: [f64::NAN, -0.1, -0.48],
                ..good
            },
            "sample refused: desired [NaN, -0.1, -0.48] is not finite",
        ),
        (
            ConditioningSample {
                next_desired: [0.1, f64::INFINITY, -0.4],
                ..good
            },
            "sample refused: next_desired [0.1, inf, -0.4] is not finite",
        ),
        (
            ConditioningSample {
                actuation: [0.5, 0.5, f64::NEG_INFINITY, 0.5, 0.5, 0.5].into(),
                ..good
            },
            "sample refused: actuation [0.5, 0.5, -inf, 0.5, 0.5, 0.5] is not finite",
        ),
        (
            ConditioningSample { set_id: 0, ..good },
            "sample refused: set_id 0 is no set",
        ),
        (
            ConditioningSample {
                execution: 0,
                ..good
            },
            "sample refused: execution 0: executions count from 1",
        ),
        (
            ConditioningSample {
                execution: 3,
                next_execution: 1,
                ..good
            },
            "sample refused: next_execution 1 is before execution 3",
        ),
        (
            ConditioningSample {
                points: 2,
                point: 1,
                next_point: 0,
                ..good
            },
            "sample refused: the set has 3 points, the sample says 2",
        ),
        (
            far,
            "sample refused: point 2 is [0.1, 0.1, -0.4], but the set has it at [-0.105, 0.0, -0.487]",
        ),
        (
            visit(1000, 1, 1, a, TARGETS[1]),
            "sample refused: execution 1 point 1 does not follow the last visit of the set (execution 1 point 1)",
        ),
        (
            visit(1000, 1, 0, a, TARGETS[0]),
            "sample refused: execution 1 point 0 does not follow the last visit of the set (execution 1 point 1)",
        ),
    ];
    for (sample, _) in &bad_samples {
        samples
            .send_copy(ConditioningSample {
                stamp_ns: now_ns(),
                ..*sample
            })
            .unwrap();
        pace();
    }
    // Not learnt from, but answered: the estimate asked for is due. A position the arm cannot
    // be at (a tracker glitch), and none at all; the second's answer, sent last, also says
    // every sample before it was handled.
    let glitch = "sample refused: reached [1e300, 0.0, -0.5] is outside where the arm can be";
    samples
        .send_copy(visit(2000, 1, 0, before[0].actuation, [1e300, 0.0, -0.5]))
        .unwrap();
    pace();
    samples
        .send_copy(visit(2000, 1, 1, before[1].actuation, [f64::NAN; 3]))
        .unwrap();
    let (answered, others) = estimates(&answers, 2000, 2);
    assert_eq!(answered.iter().map(|e| e.point).collect::<Vec<_>>(), [1, 2]);
    assert!(others.is_empty(), "refused input was answered: {others:?}");

    // Nothing changed: the same targets get the same first estimates, bit for bit, and no
    // checkpoint was written (the refused samples were last points of their sets).
    requests.send_copy(request(3000)).unwrap();
    let (after, others) = estimates(&answers, 3000, 3);
    assert!(others.is_empty(), "refused input was answered: {others:?}");
    assert_eq!(
        actuations(&after),
        actuations(&before),
        "the learner's state changed"
    );
    assert!(files(&state) == checkpoints, "a checkpoint was written");
    assert!(
        alive(learner.id() as i32),
        "the learner died:\n{}",
        log_of(&s, "learner")
    );

    // The checkpoint check can see one: a good last point is learnt and checkpointed.
    samples
        .send_copy(visit(3000, 1, 2, after[2].actuation, [-0.1, 0.002, -0.49]))
        .unwrap();
    estimates(&answers, 3000, 1);
    eventually("a checkpoint", LIMIT, || {
        (files(&state) != checkpoints).then_some(())
    });

    assert!(learner.stop(LIMIT).success());
    let log = log_of(&s, "learner");
    for (_, want) in &bad_requests {
        assert!(log.contains(want), "the log lacks {want:?}:\n{log}");
    }
    for (_, want) in &bad_samples {
        assert!(log.contains(want), "the log lacks {want:?}:\n{log}");
    }
    assert!(log.contains(glitch), "the log lacks {glitch:?}:\n{log}");
    let refused = bad_requests.len() + bad_samples.len() + 1;
    assert!(
        log.contains(&format!("learner stopped refused={refused}")),
        "{refused} refused, counted:\n{log}"
    );
}

fn goals(rig: &Rig, ids: &[u8]) -> Vec<i32> {
    let bus = rig.bus.lock().unwrap();
    ids.iter()
        .map(|&id| bus.motor(id).unwrap().goal_position())
        .collect()
}

fn torque(rig: &Rig, ids: &[u8]) -> Vec<bool> {
    let bus = rig.bus.lock().unwrap();
    ids.iter()
        .map(|&id| bus.motor(id).unwrap().torque_enabled())
        .collect()
}

/// The newest sample that arrived, if any.
fn newest<T: Copy + std::fmt::Debug + ZeroCopySend>(sub: &Sub<T>) -> Option<T> {
    let mut last = None;
    while let Ok(Some(m)) = sub.receive() {
        last = Some(*m);
    }
    last
}

/// The number after ` key=` in `log`'s last line that has it.
fn counted(log: &str, key: &str) -> Option<u64> {
    log.lines().rev().find_map(|l| {
        l.split_whitespace()
            .find_map(|w| w.strip_prefix(&format!("{key}=")))
            .and_then(|v| v.parse().ok())
    })
}

/// Returns once the driver has polled its commands since the call: the driver polls, works and
/// publishes its motor state, in that order, so the second state published after the call is
/// from a cycle that began after it.
fn polled_since(motors: &Sub<MotorState>) {
    while let Ok(Some(_)) = motors.receive() {}
    let mut published = 0;
    eventually("two driver cycles", LIMIT, || {
        std::thread::sleep(Duration::from_millis(2));
        while let Ok(Some(_)) = motors.receive() {
            published += 1;
        }
        (published >= 2).then_some(())
    });
}

#[test]
fn setpoints_with_nan_inf_or_out_of_range_values_never_reach_the_tendon_motors() {
    let (s, c, rig) = TestStack::with_devices(BIN, "bad-tendon", Devices::Shared, |c| {
        let rig = Rig::start(c, 0.5).unwrap();
        let (tendon, tracker) = (rig.tendon_path().into(), rig.tracker_path().into());
        (rig, tendon, tracker)
    });
    let t = c.tendon.clone().unwrap();
    let mapping = Mapping::new(&t, &c.layout());
    // What the driver writes for a setpoint: the controller's limits, then the motors'.
    let (lo, hi) = (
        c.controller.actuator_min.fixed::<6>(),
        c.controller.actuator_max.fixed::<6>(),
    );
    let ticks = |a: [f64; 6]| -> Vec<i32> {
        (0..6)
            .map(|i| {
                let v = a[i].clamp(lo[i], hi[i]);
                mapping.ticks(i, v).clamp(t.min_ticks[i], t.max_ticks[i])
            })
            .collect()
    };
    // Not about the torque going off for want of a setpoint (2 s here): the refusals below
    // are paced by the driver's cycles, which a loaded machine slows.
    let text = std::fs::read_to_string(&s.config).unwrap();
    let text = with_overrides(&text, &[("tendon.torque_off_after_ms", 60_000.0.into())]);
    std::fs::write(&s.config, text).unwrap();
    let n = node(&s);
    let setpoints = n.publisher(&n.setpoint().unwrap()).unwrap();
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    let driver = s.spawn(&["tendon"]);
    let pid = driver.id() as i32;
    let send = |actuation: [f64; 6]| {
        setpoints
            .send_copy(Setpoint {
                stamp_ns: now_ns(),
                actuation: actuation.into(),
                ..Setpoint::default()
            })
            .unwrap();
    };
    let follow = |actuation: [f64; 6], what: &str| {
        let want = ticks(actuation);
        eventually(what, LIMIT, || {
            send(actuation);
            std::thread::sleep(Duration::from_millis(10));
            (goals(&rig, &t.ids) == want).then_some(())
        });
    };
    eventually("the torque on where the motors stand", LIMIT, || {
        send([0.5; 6]);
        std::thread::sleep(Duration::from_millis(10));
        (torque(&rig, &t.ids) == [true; 6]).then_some(())
    });
    follow([0.4; 6], "the goals of 0.4");
    let good = goals(&rig, &t.ids);

    // Not numbers: refused whole, whichever value it is; the goals stay those of the last good
    // setpoint, the torque stays on, the driver holds.
    let bad = [
        [f64::NAN; 6],
        [0.4, 0.4, f64::INFINITY, 0.4, 0.4, 0.4],
        [0.9, f64::NEG_INFINITY, 0.4, 0.4, 0.4, f64::NAN],
        [0.4, 0.4, 0.4, 0.4, 0.4, f64::NAN],
    ];
    let mut sent = 0;
    for _ in 0..8 {
        for b in bad {
            send(b);
            sent += 1;
            // One at a time, each polled before the next (the service keeps 4): each counted.
            polled_since(&motors);
            assert_eq!(goals(&rig, &t.ids), good, "a goal moved after {b:?}");
        }
    }
    assert_eq!(torque(&rig, &t.ids), [true; 6], "the torque went off");
    // Holding where the last good setpoint put them: the motors, on their way from 0.5 when
    // the goals of 0.4 were written, get there (a loaded machine slows the emulated motors:
    // seen at 0.413 on the first HOLDING sample), and none of the bad values moves them.
    let mut last = None;
    eventually("HOLDING at 0.4 on non-numbers", LIMIT, || {
        let m = newest(&motors).filter(|m| m.driver_state() == Some(DriverState::Holding))?;
        last = Some(m.actuation);
        m.actuation
            .iter()
            .all(|a| (a - 0.4).abs() < 0.01)
            .then_some(())
    });
    assert_eq!(goals(&rig, &t.ids), good, "a goal moved: {last:?}");
    assert!(alive(pid), "the driver died");

    // Out of range: clamped to the controller's actuator limits, motor by motor.
    follow([7.0; 6], "the goals clamped to 1");
    follow([-3.0; 6], "the goals clamped to 0");
    follow([0.4, 7.0, -3.0, 0.4, 1e300, -1e300], "each goal clamped");
    // And good setpoints are followed again.
    follow([0.45; 6], "the goals of 0.45");

    assert!(driver.stop(LIMIT).success());
    let log = log_of(&s, "tendon");
    assert!(log.contains("setpoint refused: not a number"), "{log}");
    let refused = counted(&log, "refused").unwrap_or_else(|| panic!("no count: {log}"));
    assert_eq!(refused, sent, "refused setpoints counted:\n{log}");
    assert!(counted(&log, "clamped").unwrap_or(0) > 0, "{log}");
}

/// The controller's newest status within 10 s that `ok` accepts.
fn wait_state(
    status: &Sub<ControllerStatus>,
    what: &str,
    ok: impl Fn(&ControllerStatus) -> bool,
) -> ControllerStatus {
    eventually(what, Duration::from_secs(10), || {
        newest(status).filter(|s| ok(s))
    })
}

fn state_of(s: &ControllerStatus) -> ControllerState {
    ControllerState::from_u32(s.state).expect("a known state")
}

#[test]
fn tracker_samples_that_are_not_numbers_hold_the_controller() {
    let s = TestStack::new(BIN, "bad-tracker", true);
    let arm = pcc::Arm::of_config(&Config::load(&s.config).unwrap().arm).unwrap();
    let controller = s.spawn(&["controller"]);
    let n = node(&s);
    let status = n.subscriber(&n.status().unwrap()).unwrap();
    let samples = n.subscriber(&n.cp_sample().unwrap()).unwrap();
    // This test is the drivers: fresh motor states, and tracker samples of where the arm is,
    // or with `bad` in them.
    let bad: Mutex<Option<Position>> = Mutex::new(None);
    let done = AtomicBool::new(false);
    std::thread::scope(|scope| {
        scope.spawn(|| {
            let n = node(&s);
            let motors = n.publisher(&n.motor_state().unwrap()).unwrap();
            let tracker = n.publisher(&n.tracker().unwrap()).unwrap();
            let at = ForwardModel::<6>::position(&arm, &[0.5; 6]);
            while !done.load(Ordering::Relaxed) {
                let stamp_ns = now_ns();
                motors
                    .send_copy(MotorState {
                        stamp_ns,
                        actuation: [0.5; 6].into(),
                        ..MotorState::default()
                    })
                    .unwrap();
                let position = bad.lock().unwrap().unwrap_or(at);
                tracker
                    .send_copy(TrackerSample {
                        stamp_ns,
                        position,
                        ..TrackerSample::default()
                    })
                    .unwrap();
                std::thread::sleep(Duration::from_millis(5));
            }
        });
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            wait_state(&status, "IDLE with the model", |st| {
                state_of(st) == ControllerState::Idle && st.model_loaded == 1
            });
            // Fresh samples whose position is not a number: as good as none, the controller
            // holds...
            for position in [
                [f64::NAN; 3],
                [0.1, f64::INFINITY, -0.4],
                [f64::NEG_INFINITY, 0.0, f64::NAN],
            ] {
                *bad.lock().unwrap() = Some(position);
                wait_state(
                    &status,
                    &format!("HOLD on tracker samples {position:?}"),
                    |st| state_of(st) == ControllerState::Hold,
                );
            }
            // ... and a set submitted meanwhile is not executed: no state but HOLD, no
            // conditioning sample, for longer than the learner's estimates are waited for.
            let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 1);
            assert_eq!(code, 0, "{out}{err}");
            let start = Instant::now();
            while start.elapsed() < Duration::from_secs(4) {
                if let Some(st) = newest(&status) {
                    assert_eq!(state_of(&st), ControllerState::Hold, "{st:?}");
                }
                assert!(
                    newest(&samples).is_none(),
                    "executed on tracker samples that are not numbers"
                );
                std::thread::sleep(Duration::from_millis(20));
            }
            // Good samples again: the set runs, and its conditioning points see the arm.
            *bad.lock().unwrap() = None;
            wait_state(&status, "EXECUTE with good tracker samples", |st| {
                state_of(st) == ControllerState::Execute
            });
            let cp = eventually("a conditioning sample", LIMIT, || newest(&samples));
            assert!(cp.reached.iter().all(|v| v.is_finite()), "{cp:?}");
        }));
        done.store(true, Ordering::Relaxed);
        if let Err(e) = result {
            std::panic::resume_unwind(e);
        }
    });
    assert!(
        alive(controller.id() as i32),
        "the controller died:\n{}",
        log_of(&s, "controller")
    );
    assert!(controller.stop(LIMIT).success());
}

/// The demo set as a request, for `executions` executions.
fn demo_set(executions: u32) -> WaypointSet {
    WaypointFile::load(Path::new(DEMO_WAYPOINTS))
        .unwrap()
        .to_set(executions)
        .unwrap()
}

#[test]
fn waypoint_requests_with_nonsense_are_rejected_by_the_controller_naming_it() {
    // What `softarm submit` checks before sending, sent anyway, as a peer of another make
    // (the Python mirrors) could: the controller's own checks.
    let s = TestStack::new(BIN, "bad-waypoints", true);
    let controller = s.spawn(&["controller"]);
    let n = node(&s);
    let status = n.subscriber(&n.status().unwrap()).unwrap();
    let asked = n.subscriber(&n.estimate_request().unwrap()).unwrap();
    let client = n.client(&n.waypoints().unwrap()).unwrap();
    wait_state(&status, "the model loaded", |st| st.model_loaded == 1);
    let submit = |set: WaypointSet| -> WaypointReply {
        let pending = client.send_copy(set).unwrap();
        eventually("an answer", LIMIT, || {
            pending.receive().ok().flatten().map(|r| *r)
        })
    };

    let good = demo_set(1);
    let with = |f: &dyn Fn(&mut WaypointSet)| {
        let mut set = good;
        f(&mut set);
        set
    };
    #[rustfmt::skip]
    let cases: Vec<(&str, WaypointSet, &str)> = vec![
        ("no point", with(&|s| s.count = 0), "0 points; a set has 1 to 16"),
        ("too many points", with(&|s| s.count = 17), "17 points; a set has 1 to 16"),
        ("count u32::MAX", with(&|s| s.count = u32::MAX), "4294967295 points"),
        ("duration 0", with(&|s| s.duration_s = 0.0), "duration 0 s is outside [1, 120] s"),
        ("duration NaN", with(&|s| s.duration_s = f64::NAN), "duration NaN s is outside"),
        ("duration inf", with(&|s| s.duration_s = f64::INFINITY), "duration inf s is outside"),
        ("duration negative", with(&|s| s.duration_s = -5.0), "duration -5 s is outside"),
        ("0 executions", with(&|s| s.executions = 0), "0 executions; 1 to 10000 are allowed"),
        ("u32::MAX executions", with(&|s| s.executions = u32::MAX), "4294967295 executions"),
        ("a time NaN", with(&|s| s.times_s[1] = f64::NAN), "point 2: t_s = NaN is not a finite number"),
        ("a time negative", with(&|s| s.times_s[0] = -0.8), "point 1: time -0.8 s is outside (0, 5] s"),
        ("a time after the duration", with(&|s| s.times_s[4] = 6.0), "point 5: time 6 s is outside (0, 5] s"),
        ("times out of order", with(&|s| s.times_s.swap(1, 2)), "point 3: times must increase strictly (1.8 s follows 2.8 s)"),
        ("two times too close", with(&|s| s.times_s[1] = 1.0), "points 1 and 2 are 0.200 s apart"),
        ("a position NaN", with(&|s| s.positions_m[2][2] = f64::NAN), "point 3: position_m 3 (z) = NaN is not a finite number"),
        ("a position inf", with(&|s| s.positions_m[0][0] = f64::INFINITY), "point 1: position_m 1 (x) = inf is not a finite number"),
        ("a position outside the workspace", with(&|s| s.positions_m[3] = [0.0, 0.0, 0.3]), "point 4: position [0.0, 0.0, 0.3] m is outside the workspace box"),
        ("a position in the box but beyond the arm", with(&|s| s.positions_m[1] = [0.44, -0.44, 0.04]), "point 2: position [0.44, -0.44, 0.04] m is 0.624 m from the base, beyond the arm's reach"),
    ];
    for (what, set, want) in &cases {
        let r = submit(*set);
        assert_eq!(r.accepted, 0, "{what}: accepted as set {}", r.set_id);
        assert!(
            r.reason().contains(want),
            "{what}: the reason is {:?}, not {want:?}",
            r.reason()
        );
    }
    // Nothing changed: no set was taken on (the learner was asked for nothing, none runs), the
    // controller lives; and it takes a good set.
    assert!(
        newest(&asked).is_none(),
        "a rejected set went to the learner"
    );
    let st = newest(&status).unwrap();
    assert_eq!(st.set_id, 0, "{st:?}");
    assert!(
        alive(controller.id() as i32),
        "the controller died:\n{}",
        log_of(&s, "controller")
    );
    let r = submit(good);
    assert_eq!(r.accepted, 1, "the good set: {}", r.reason());
    let request = eventually("the good set's estimate request", LIMIT, || newest(&asked));
    assert_eq!(request.set_id, r.set_id);
    assert!(controller.stop(LIMIT).success());
    let log = log_of(&s, "controller");
    assert_eq!(
        log.matches("way-point set rejected").count(),
        cases.len(),
        "each rejection logged:\n{log}"
    );
}

#[test]
fn motor_states_that_are_not_numbers_hold_the_controller_and_never_reach_its_setpoints() {
    let s = TestStack::new(BIN, "bad-motors", true);
    let arm = pcc::Arm::of_config(&Config::load(&s.config).unwrap().arm).unwrap();
    let controller = s.spawn(&["controller"]);
    let n = node(&s);
    let status = n.subscriber(&n.status().unwrap()).unwrap();
    let setpoints = n.subscriber(&n.setpoint().unwrap()).unwrap();
    // This test is the drivers: good tracker samples, and motor states that report `bad` (the
    // first the controller ever sees among them: where its limiter starts) until it is `None`.
    let bad: Mutex<Option<[f64; 6]>> = Mutex::new(Some([f64::NAN; 6]));
    let done = AtomicBool::new(false);
    std::thread::scope(|scope| {
        scope.spawn(|| {
            let n = node(&s);
            let motors = n.publisher(&n.motor_state().unwrap()).unwrap();
            let tracker = n.publisher(&n.tracker().unwrap()).unwrap();
            let at = ForwardModel::<6>::position(&arm, &[0.5; 6]);
            while !done.load(Ordering::Relaxed) {
                let stamp_ns = now_ns();
                let actuation = bad.lock().unwrap().unwrap_or([0.5; 6]);
                motors
                    .send_copy(MotorState {
                        stamp_ns,
                        actuation: actuation.into(),
                        ..MotorState::default()
                    })
                    .unwrap();
                tracker
                    .send_copy(TrackerSample {
                        stamp_ns,
                        position: at,
                        ..TrackerSample::default()
                    })
                    .unwrap();
                std::thread::sleep(Duration::from_millis(5));
            }
        });
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let numbers = |what: &str| {
                let start = Instant::now();
                while start.elapsed() < Duration::from_secs(1) {
                    while let Ok(Some(p)) = setpoints.receive() {
                        assert!(
                            p.actuation.iter().all(|v| v.is_finite()),
                            "{what}: a setpoint that is not a number: {:?}",
                            p.actuation
                        );
                    }
                    std::thread::sleep(Duration::from_millis(5));
                }
            };
            for actuation in [[f64::NAN; 6], [0.5, 0.5, f64::INFINITY, 0.5, 0.5, 0.5]] {
                *bad.lock().unwrap() = Some(actuation);
                wait_state(
                    &status,
                    &format!("HOLD on motor states {actuation:?}"),
                    |st| state_of(st) == ControllerState::Hold,
                );
                numbers(&format!("motor states {actuation:?}"));
            }
            *bad.lock().unwrap() = None;
            wait_state(&status, "IDLE with good motor states", |st| {
                state_of(st) == ControllerState::Idle
            });
            numbers("good motor states");
            let p = eventually("a setpoint", LIMIT, || newest(&setpoints));
            assert!(
                p.actuation.iter().all(|a| (a - 0.5).abs() < 1e-6),
                "the setpoint is not where the motors stand: {:?}",
                p.actuation
            );
        }));
        done.store(true, Ordering::Relaxed);
        if let Err(e) = result {
            std::panic::resume_unwind(e);
        }
    });
    assert!(
        alive(controller.id() as i32),
        "the controller died:\n{}",
        log_of(&s, "controller")
    );
    assert!(controller.stop(LIMIT).success());
}
