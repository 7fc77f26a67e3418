//! Many motors on one bus at their factory settings: the emulated motors
//! (`softarm_emulate::dynamixel`) answer after their Return Delay Time (factory 500 µs) one after
//! another, at the line's baud rate, as real ones do. The `tendon` driver sets the delay at
//! start, sizes its wait for the replies to the bus, and so keeps every reply of a nine- and a
//! sixteen-motor bus at the shipped baud and rate; a motor that refuses the delay is named.
//!
//! What is asserted is counts in the driver's own cycles (read time-outs, DEGRADED
//! transitions, collisions the emulated line saw), never how fast.

use std::time::{Duration, Instant};

use softarm_config::Config;
use softarm_emulate::dynamixel::{BusFaults, RETURN_DELAY_TIME};
use softarm_emulate::rig::Rig;
use softarm_ipc::{DriverState, MotorState, Pub, Setpoint, Sub};
use softarm_test_support::{Devices, TestStack};

use crate::hardware::{eventually, newest, node, send_each, watch};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");

/// An arm of `n` tendons (3 or 4 to a segment, coupled routing as the shipped TDCR), a motor
/// per tendon with ids 1 to `n` on one bus, 20 mm of stroke on a 5 mm spool.
fn tendons(n: usize, text: String) -> String {
    let per = if n.is_multiple_of(4) { 4 } else { 3 };
    let mut arm = String::from("routing = \"coupled\"\nmount = \"standing\"\nconnector_m = 0.0\n");
    arm.push_str("tool_m = 0.01\n");
    for k in 0..n / per {
        let from = 0.05 + 0.06 * k as f64;
        arm.push_str(&format!(
            "[[modules]]\nbackbone_m = 0.06\nrotation_deg = {}\ntendons = {{ count = {per}, \
             radius_m = 0.0045, length_m = [{from:.2}, {:.2}] }}\n",
            20 * k,
            from + 0.02
        ));
    }
    let text = softarm_config::arms::with_arm(&text, &arm, "bus").unwrap();
    let list = |v: Vec<toml::Value>| toml::Value::Array(v);
    let each = |f: &dyn Fn(usize) -> toml::Value| list((0..n).map(f).collect());
    softarm_test_support::with_overrides(
        &text,
        &[
            ("tendon.ids", each(&|i| (i as i64 + 1).into())),
            ("tendon.spool_radius_m", each(&|_| 0.005.into())),
            (
                "tendon.zero_ticks",
                each(&|i| if i % 2 == 0 { 1000 } else { 3500 }.into()),
            ),
            (
                "tendon.direction",
                each(&|i| if i % 2 == 0 { 1 } else { -1 }.into()),
            ),
            ("tendon.min_ticks", each(&|_| 800.into())),
            ("tendon.max_ticks", each(&|_| 3700.into())),
        ],
    )
}

/// The hardware stack's folder for an `n`-motor bus, its emulators started at the motors'
/// factory settings, with `faults` on the bus from the start; the driver not yet.
fn bus_of(name: &str, n: usize, faults: BusFaults) -> (TestStack, Config, Rig) {
    let (s, c, rig) = TestStack::with_devices_for(
        BIN,
        name,
        Devices::Alone,
        |text| tendons(n, text),
        |c| {
            let rig = Rig::start(c, 0.5).unwrap();
            rig.bus.lock().unwrap().set_faults(faults);
            let (tendon, tracker) = (rig.tendon_path().into(), rig.tracker_path().into());
            (rig, tendon, tracker)
        },
    );
    watch(&rig);
    let t = c.tendon.as_ref().unwrap();
    assert_eq!((t.ids.len(), t.baud, t.rate_hz), (n, 1_000_000, 100.0));
    let bus = rig.bus.lock().unwrap();
    assert!(
        (bus.motors().iter()).all(|m| m.u8_at(RETURN_DELAY_TIME) == 250),
        "the motors start at the factory's 500 µs"
    );
    drop(bus);
    (s, c, rig)
}

fn delays(rig: &Rig) -> Vec<u8> {
    let bus = rig.bus.lock().unwrap();
    bus.motors()
        .iter()
        .map(|m| m.u8_at(RETURN_DELAY_TIME))
        .collect()
}

/// What the driver published while following for a while.
#[derive(Debug, Default)]
struct Run {
    /// Driver cycles covered (the sequence numbers' span), and samples seen of them.
    cycles: u64,
    samples: u64,
    /// Read time-outs counted meanwhile, and samples one cycle after the last whose count
    /// rose (cycles with a read time-out).
    timeouts: u64,
    timed_out_cycles: u64,
    /// Samples saying DEGRADED, and changes between FOLLOWING and DEGRADED either way.
    degraded: u64,
    flips: u64,
    /// Instructions that came while replies were due, on the emulated line.
    collisions: u64,
    /// SYNC READs of the positions the bus executed meanwhile.
    reads: u64,
}

impl Run {
    fn take(&mut self, last: &MotorState, m: &MotorState) {
        let state = |m: &MotorState| m.driver_state();
        let (following, degraded) = (Some(DriverState::Following), Some(DriverState::Degraded));
        self.samples += 1;
        self.degraded += u64::from(state(m) == degraded);
        self.flips += u64::from(
            (state(last), state(m)) == (following, degraded)
                || (state(last), state(m)) == (degraded, following),
        );
        self.timed_out_cycles += u64::from(m.seq == last.seq + 1 && m.timeouts > last.timeouts);
    }
}

/// Follows `n` actuators at 0.5 until the driver has run `cycles` cycles from its first
/// FOLLOWING or DEGRADED sample, counting.
fn follow_for(
    rig: &Rig,
    setpoints: &Pub<Setpoint>,
    motors: &Sub<MotorState>,
    n: usize,
    cycles: u64,
) -> Run {
    let bus = || rig.bus.lock().unwrap().counters();
    let driving = [Some(DriverState::Following), Some(DriverState::Degraded)];
    let first = eventually("FOLLOWING or DEGRADED", || {
        send_each(setpoints, &vec![0.5; n]);
        newest(motors).filter(|m| driving.contains(&m.driver_state()))
    });
    let before = bus();
    let (mut last, mut run) = (first, Run::default());
    let start = Instant::now();
    while last.seq - first.seq < cycles {
        send_each(setpoints, &vec![0.5; n]);
        std::thread::sleep(Duration::from_millis(10));
        while let Ok(Some(m)) = motors.receive() {
            run.take(&last, &m);
            last = *m;
        }
        assert!(start.elapsed() < Duration::from_secs(600), "{run:?}");
    }
    let after = bus();
    run.cycles = last.seq - first.seq;
    run.timeouts = last.timeouts - first.timeouts;
    run.collisions = after.collisions - before.collisions;
    run.reads = after.position_reads - before.position_reads;
    run
}

/// The driver on a bus of `n` motors at their factory settings, following for `cycles`; its
/// log, the motors' Return Delay Times after, and the stack (its folder kept if the test
/// fails).
fn factory_bus_run(name: &str, n: usize, cycles: u64) -> (Run, String, Vec<u8>, TestStack) {
    let (s, _c, rig) = bus_of(name, n, BusFaults::default());
    let node = node(&s);
    let setpoints = node.publisher(&node.setpoint().unwrap()).unwrap();
    let motors = node.subscriber(&node.motor_state().unwrap()).unwrap();
    let driver = s.spawn(&["tendon"]);
    let run = follow_for(&rig, &setpoints, &motors, n, cycles);
    eprintln!("{n} motors at factory settings: {run:?}");
    assert!(driver.stop(Duration::from_secs(20)).success());
    let log = std::fs::read_to_string(s.dir.join("tendon.log")).unwrap();
    (run, log, delays(&rig), s)
}

/// The driver on a bus of `n` motors at their factory settings: it sets their Return Delay
/// Time to 0 at start, says what the bus can do per cycle, and follows. How often a read times
/// out or DEGRADES depends on how late the loaded machine delivers the pty's bytes (at a load
/// of 9 to 12, 0.7 % of the cycles on nine motors; with the suite's stacks beside it, more):
/// `factory_bus_figures` measures it, and nothing here asserts a rate of it. Unfixed, the
/// delays stayed at 250, and nine motors timed out in 62 % of the cycles, sixteen in all.
fn factory_bus_follows(name: &str, n: usize) {
    let (run, log, delays, _stack) = factory_bus_run(name, n, 400);
    assert_eq!(delays, vec![0; n], "the Return Delay Times as set");
    assert!(run.degraded < run.samples, "never FOLLOWING: {run:?}");
    assert!(run.reads > 0, "no position read: {run:?}");
    assert!(
        log.contains(&format!("a cycle of {n} motors at 1000000 baud takes")),
        "what the bus can do per cycle, logged: {log}"
    );
}

#[test]
fn nine_motors_at_factory_settings_are_set_and_read_every_cycle() {
    factory_bus_follows("hw-bus-nine", 9);
}

#[test]
fn sixteen_motors_at_factory_settings_are_set_and_read_every_cycle() {
    factory_bus_follows("hw-bus-sixteen", 16);
}

/// A motor that refuses the write of its Return Delay Time is named with what to do; the
/// others are set, and the driver follows (with its reads sized to the delay kept).
#[test]
fn a_motor_that_refuses_its_return_delay_is_named_and_the_bus_still_follows() {
    let faults = BusFaults {
        refuse_write: Some((5, RETURN_DELAY_TIME)),
        ..BusFaults::default()
    };
    let (s, _c, rig) = bus_of("hw-bus-refused", 9, faults);
    let node = node(&s);
    let setpoints = node.publisher(&node.setpoint().unwrap()).unwrap();
    let motors = node.subscriber(&node.motor_state().unwrap()).unwrap();
    let driver = s.spawn(&["tendon"]);
    let run = follow_for(&rig, &setpoints, &motors, 9, 200);
    let mut want = vec![0; 9];
    want[4] = 250;
    assert_eq!(delays(&rig), want, "motor 5 kept the factory's delay");
    assert!(run.degraded < run.samples, "never FOLLOWING: {run:?}");
    let log = std::fs::read_to_string(s.dir.join("tendon.log")).unwrap();
    let said: Vec<&str> = (log.lines())
        .filter(|l| l.contains("Return Delay Time of 500 µs"))
        .collect();
    assert_eq!(said.len(), 1, "said once: {log}");
    assert!(
        said[0].contains("ERROR")
            && said[0].contains("motor id 5 (actuator 5)")
            && said[0].contains("DYNAMIXEL Wizard"),
        "{}",
        said[0]
    );
    assert!(driver.stop(Duration::from_secs(20)).success());
}

/// A bus that cannot read its motors within a period even when they answer at once is
/// refused at start as a config error, with the numbers and what to change; nothing is sent to
/// the motors.
#[test]
fn a_bus_too_slow_for_the_rate_is_refused_with_its_numbers() {
    let (s, c, rig) = TestStack::with_devices_for(
        BIN,
        "hw-bus-slow",
        Devices::Shared,
        |text| {
            let text = tendons(16, text);
            softarm_test_support::with_overrides(&text, &[("tendon.baud", 57_600.into())])
        },
        |c| {
            let rig = Rig::start(c, 0.5).unwrap();
            let (tendon, tracker) = (rig.tendon_path().into(), rig.tracker_path().into());
            (rig, tendon, tracker)
        },
    );
    watch(&rig);
    assert_eq!(c.tendon.as_ref().unwrap().baud, 57_600);
    let mut driver = s.spawn(&["tendon"]);
    let status = eventually("the driver to refuse the bus", || {
        driver.try_wait().unwrap()
    });
    assert_eq!(status.code(), Some(78), "a config error: not started again");
    let log = std::fs::read_to_string(s.dir.join("tendon.log")).unwrap();
    assert!(
        log.contains("cannot carry tendon.rate_hz: a cycle of 16 motors at 57600 baud takes")
            && log.contains("Lower tendon.rate_hz to"),
        "{log}"
    );
    assert_eq!(
        rig.bus.lock().unwrap().counters().instructions,
        0,
        "nothing sent"
    );
}

/// The figures of the guide's measurement: nine motors at their factory settings followed for
/// a minute (6000 cycles at 100 Hz): the share of cycles with a read time-out, the flips
/// between FOLLOWING and DEGRADED, the bus's warnings. `SOFTARM_BUS_MOTORS` changes the count.
#[test]
#[ignore = "a measurement: a minute of counts, printed"]
fn factory_bus_figures() {
    let n = std::env::var("SOFTARM_BUS_MOTORS").map_or(9, |v| v.parse().unwrap());
    let (run, log, delays, _stack) = factory_bus_run("hw-bus-figures", n, 6000);
    println!("Return Delay Times after the run: {delays:?}");
    let warned = |what: &str| log.lines().filter(|l| l.contains(what)).count();
    println!(
        "{n} motors, {} cycles ({} samples): cycles with a read time-out {:.1} %, read \
         time-outs {}, DEGRADED samples {:.1} %, FOLLOWING/DEGRADED flips {}, collisions {} in \
         {} reads; log: {} \"replies are being lost\", {} \"motor bus failing\"",
        run.cycles,
        run.samples,
        100.0 * run.timed_out_cycles as f64 / run.samples.max(1) as f64,
        run.timeouts,
        100.0 * run.degraded as f64 / run.samples.max(1) as f64,
        run.flips,
        run.collisions,
        run.reads,
        warned("replies are being lost"),
        warned("motor bus failing"),
    );
    for l in log.lines().filter(|l| l.contains("motor bus failing")) {
        println!("{l}");
    }
}
