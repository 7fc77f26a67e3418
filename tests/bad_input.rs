//! End to end: samples with out-of-range fields on the iceoryx2 services, as a broken peer
//! could send them, reach the real processes and change nothing but a counter and a log line.

use std::time::{Duration, Instant};

use softarm_ipc::{Namespace, Node, Setpoint, now_ns};
use softarm_test_support::{TestStack, alive};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");

#[test]
fn a_setpoint_that_is_not_a_number_is_refused_by_the_driver() {
    let s = TestStack::new(BIN, "nan-setpoint", false);
    // The sim alone, and this test as its controller.
    let mut sim = s.spawn(&["sim"]);
    let node = Node::open(Namespace::new(&s.namespace).unwrap(), "test").unwrap();
    let setpoints = node.publisher(&node.setpoint().unwrap()).unwrap();
    let motors = node.subscriber(&node.motor_state().unwrap()).unwrap();
    let send = |actuation: [f64; 6]| {
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
    while send([0.6; 6]) == 0 {
        assert!(start.elapsed() < Duration::from_secs(20), "no sim");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(300));
    for bad in [
        [f64::NAN; 6],
        [0.6, 0.6, f64::INFINITY, 0.6, 0.6, 0.6],
        [0.6, f64::NEG_INFINITY, 0.6, 0.6, 0.6, f64::NAN],
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
    assert!(log.contains("refused=3"), "three refused, counted: {log}");
}
