//! End to end on the real arm's code path, without the arm: the `tendon` and `tracker` driver
//! processes against emulators of their devices on pseudo-terminals (Dynamixel Protocol 2.0
//! motors, an Ascension Bird tracker), and the whole hardware stack (`softarm-rig emulate` +
//! `softarm up` with the hardware config) closing the loop through them.

use std::path::Path;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use softarm_config::Config;
use softarm_config::hardware::Mapping;
use softarm_emulate::canary::Watch;
use softarm_emulate::dynamixel::{BusFaults, short_status_packet};
use softarm_emulate::rig::Rig;
use softarm_ipc::iceoryx2::prelude::ZeroCopySend;
use softarm_ipc::{DriverState, MotorState, Namespace, Node, Pub, Setpoint, Sub, TrackerSample};
use softarm_kinematics::forward::ForwardModel;
use softarm_kinematics::pcc;
use softarm_runtime::now_ns;
use softarm_test_support::{DEMO_WAYPOINTS, Devices, Guard, TestStack, alive, set_id};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");
/// The test rig's binary: `emulate`.
const RIG: &str = env!("CARGO_BIN_EXE_softarm-rig");
const LIMIT: Duration = Duration::from_secs(20);

/// Waits on the emulated devices never end before this much wall clock, whatever the kernel
/// held: a driver that does not recover is found, if slowly.
const HANG: Duration = Duration::from_secs(240);

thread_local! {
    /// The pty canary of the emulators this test thread started last.
    static LINE: std::cell::RefCell<Option<Watch>> = const { std::cell::RefCell::new(None) };
}

/// The waits of this test thread discount what `rig`'s canary sees the kernel hold.
pub(crate) fn watch(rig: &Rig) {
    LINE.with(|l| *l.borrow_mut() = Some(rig.canary.watch()));
}

/// A test's folder and namespace with the hardware config, quick time-outs, and the
/// emulators running for it.
fn rig(name: &str) -> (TestStack, Config, Rig) {
    let (s, c, rig) = TestStack::with_devices(BIN, name, Devices::Shared, |c| {
        let rig = Rig::start(c, 0.5).unwrap();
        let (tendon, tracker) = (rig.tendon_path().into(), rig.tracker_path().into());
        (rig, tendon, tracker)
    });
    watch(&rig);
    (s, c, rig)
}

/// Points `link` at `target`, as udev points /dev/softarm-tendon at the adapter plugged in.
fn relink(link: &Path, target: &Path) {
    let _ = std::fs::remove_file(link);
    std::os::unix::fs::symlink(target, link).unwrap();
}

pub(crate) fn node(s: &TestStack) -> Node {
    Node::open(Namespace::new(&s.namespace).unwrap(), "test").unwrap()
}

/// Polls `f` every 20 ms until it gives `Some`: for at most [`LIMIT`] of the time the kernel
/// let the pty path work, as the test's canary measured it, and at most [`HANG`] in all. A
/// loaded machine holds every pty for seconds (the kernel's flip-buffer work left without a
/// CPU, `softarm_emulate::canary`), and no driver or device can answer meanwhile; what a test
/// bounds is how long the driver takes on a line that works.
pub(crate) fn eventually<T>(what: &str, mut f: impl FnMut() -> Option<T>) -> T {
    let (start, from) = (Instant::now(), now_ns());
    loop {
        if let Some(v) = f() {
            return v;
        }
        let held = LINE.with(|l| {
            l.borrow()
                .as_ref()
                .map_or(0, |w| w.stalled_ns(from, now_ns()))
        });
        let working = start.elapsed().saturating_sub(Duration::from_nanos(held));
        assert!(
            working < LIMIT && start.elapsed() < HANG,
            "waited {:.1} s for {what}, {:.1} s of it with the kernel holding the pty path",
            start.elapsed().as_secs_f64(),
            held as f64 / 1e9
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The newest motor state that arrived, if any.
pub(crate) fn newest<T: Copy + std::fmt::Debug + ZeroCopySend>(sub: &Sub<T>) -> Option<T> {
    let mut last = None;
    while let Ok(Some(m)) = sub.receive() {
        last = Some(*m);
    }
    last
}

/// A setpoint of `a` on every actuator, stamped now (also used by `hardware_noise`).
pub(crate) fn send(setpoints: &Pub<Setpoint>, a: f64) {
    setpoints
        .send_copy(Setpoint {
            stamp_ns: now_ns(),
            actuation: [a; 6].into(),
            ..Setpoint::default()
        })
        .unwrap();
}

/// Sends `a` at about 100 Hz for `d`.
fn follow(setpoints: &Pub<Setpoint>, a: f64, d: Duration) {
    let start = Instant::now();
    while start.elapsed() < d {
        send(setpoints, a);
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn spawn(s: &TestStack, role: &str) -> Guard {
    s.spawn(&[role])
}

fn stop(child: Guard) -> std::process::ExitStatus {
    child.stop(LIMIT)
}

fn torque(rig: &Rig, ids: &[u8]) -> Vec<bool> {
    let bus = rig.bus.lock().unwrap();
    ids.iter()
        .map(|&id| bus.motor(id).unwrap().torque_enabled())
        .collect()
}

fn goals(rig: &Rig, ids: &[u8]) -> Vec<i32> {
    let bus = rig.bus.lock().unwrap();
    ids.iter()
        .map(|&id| bus.motor(id).unwrap().goal_position())
        .collect()
}

#[test]
fn tendon_follows_then_holds_then_turns_the_torque_off_and_obeys_the_estop() {
    let (s, c, rig) = rig("hw-tendon");
    let t = c.tendon.clone().unwrap();
    let mapping = Mapping::new(&t, &c.layout());
    let n = node(&s);
    let setpoints = n.publisher(&n.setpoint().unwrap()).unwrap();
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    let driver = spawn(&s, "tendon");

    // Torque off until the first setpoint.
    let m: MotorState = eventually("motor state", || newest(&motors));
    assert_eq!(m.driver_state(), Some(DriverState::Off));
    assert_eq!(torque(&rig, &t.ids), [false; 6]);
    for i in 0..6 {
        assert!((m.actuation[i] - 0.5).abs() < 1e-3, "{:?}", m.actuation);
    }

    // A first setpoint far from where the motors stand does not turn the torque on...
    follow(&setpoints, 0.3, Duration::from_millis(300));
    assert_eq!(torque(&rig, &t.ids), [false; 6], "engaged 0.2 away");
    // ...one where they stand does; then they follow, goals the mapping's ticks.
    eventually("torque on at 0.5", || {
        send(&setpoints, 0.5);
        (torque(&rig, &t.ids) == [true; 6]).then_some(())
    });
    let want: Vec<i32> = (0..6).map(|i| mapping.ticks(i, 0.3)).collect();
    eventually("the goals of 0.3", || {
        send(&setpoints, 0.3);
        (goals(&rig, &t.ids) == want).then_some(())
    });
    // FOLLOWING on the clean bus: a loaded machine may deliver a reply late, which the driver
    // honestly says (DEGRADED) until its data is fresh again.
    let m = eventually("the motors at 0.3, FOLLOWING", || {
        send(&setpoints, 0.3);
        newest(&motors).filter(|m| {
            m.actuation.iter().all(|a| (a - 0.3).abs() < 2e-3)
                && m.driver_state() == Some(DriverState::Following)
        })
    });
    assert!(
        m.current_a.iter().all(|a| a.is_finite()),
        "{:?}",
        m.current_a
    );
    // Beyond the limits: clamped to the controller's actuator limits.
    follow(&setpoints, 7.0, Duration::from_millis(200));
    let want_max: Vec<i32> = (0..6).map(|i| mapping.ticks(i, 1.0)).collect();
    eventually("goals clamped", || {
        send(&setpoints, 7.0);
        (goals(&rig, &t.ids) == want_max).then_some(())
    });
    eventually("back at 0.3", || {
        send(&setpoints, 0.3);
        newest(&motors).filter(|m| m.actuation.iter().all(|a| (a - 0.3).abs() < 2e-3))
    });
    // A motor that browns out restarts with its torque off and says nothing: the status read
    // finds it, and the driver turns it on again where it stands (the goal is there).
    rig.bus.lock().unwrap().brown_out(t.ids[2]);
    assert!(!torque(&rig, &t.ids)[2]);
    eventually("the browned-out motor's torque on again", || {
        send(&setpoints, 0.3);
        (torque(&rig, &t.ids) == [true; 6]).then_some(())
    });

    // Silence: hold (torque on), then torque off. Timed from before the last setpoint.
    let silent_from = now_ns();
    send(&setpoints, 0.3);
    eventually("HOLDING", || {
        newest(&motors).filter(|m| m.driver_state() == Some(DriverState::Holding))
    });
    assert_eq!(torque(&rig, &t.ids), [true; 6], "holding keeps the torque");
    eventually("OFF", || {
        newest(&motors).filter(|m| m.driver_state() == Some(DriverState::Off))
    });
    assert!(
        now_ns() - silent_from >= 2_000_000_000,
        "off before its time-out"
    );
    // The driver says OFF as it writes the torque off; the write reaches the motors after
    // (on a loaded machine, the kernel was seen to hold it in the pty).
    eventually("the torque off", || {
        (torque(&rig, &t.ids) == [false; 6]).then_some(())
    });

    // A controller that comes back (from where the motors stand) is followed again.
    eventually("torque on again", || {
        send(&setpoints, 0.3);
        (torque(&rig, &t.ids) == [true; 6]).then_some(())
    });

    // E-stop: torque off at once, setpoints ignored until the reset.
    let out = s.run(&["estop"]);
    assert!(out.status.success(), "{out:?}");
    eventually("torque off on e-stop", || {
        send(&setpoints, 0.3);
        (torque(&rig, &t.ids) == [false; 6]).then_some(())
    });
    follow(&setpoints, 0.3, Duration::from_millis(300));
    assert_eq!(
        torque(&rig, &t.ids),
        [false; 6],
        "setpoints obeyed under e-stop"
    );
    let m = newest(&motors).unwrap();
    assert_eq!(m.driver_state(), Some(DriverState::Stopped));
    let out = s.run(&["estop", "--reset"]);
    assert!(out.status.success(), "{out:?}");
    eventually("torque on after the reset", || {
        send(&setpoints, 0.3);
        (torque(&rig, &t.ids) == [true; 6]).then_some(())
    });

    // Leaving, the driver turns the torque off: nothing stays driven by a process that is gone.
    // (Its last write may still be in the pty when it has exited: a loaded machine's kernel
    // was seen to hold it.)
    assert!(stop(driver).success());
    eventually("the torque off after the driver left", || {
        (torque(&rig, &t.ids) == [false; 6]).then_some(())
    });
}

#[test]
fn an_estop_reaches_the_motors_while_their_replies_are_lost() {
    // The return line broken: the motors obey but answer nothing, so every read times out
    // and the driver's loop is slow; the e-stop's sample may come and go while it is blocked.
    let (s, c, rig) = rig("hw-estop-deaf");
    let t = c.tendon.clone().unwrap();
    let n = node(&s);
    let setpoints = n.publisher(&n.setpoint().unwrap()).unwrap();
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    let driver = spawn(&s, "tendon");
    eventually("torque on", || {
        send(&setpoints, 0.5);
        (torque(&rig, &t.ids) == [true; 6]).then_some(())
    });
    rig.bus.lock().unwrap().set_faults(BusFaults {
        silent: true,
        ..BusFaults::default()
    });
    follow(&setpoints, 0.5, Duration::from_millis(300));
    // The motors obey, but the driver cannot read them back: it cannot confirm, and the e-stop
    // says so (and latches all the same).
    let out = s.run(&["estop", "--timeout", "1"]);
    let said = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    assert!(
        said.contains("not confirmed in 1 s by: tendon: alive, but has published nothing"),
        "{said}"
    );
    assert!(c.estop_latch().engaged().unwrap());
    eventually("torque off on e-stop without replies", || {
        send(&setpoints, 0.5);
        (torque(&rig, &t.ids) == [false; 6]).then_some(())
    });
    // Replies back: still stopped, still off, whatever is sent.
    rig.bus.lock().unwrap().set_faults(BusFaults::default());
    follow(&setpoints, 0.5, Duration::from_millis(1500));
    assert_eq!(torque(&rig, &t.ids), [false; 6], "driven after an e-stop");
    let m = eventually("fresh motor state", || {
        newest(&motors).filter(|m| now_ns() - m.stamp_ns < 100_000_000)
    });
    assert_eq!(m.driver_state(), Some(DriverState::Stopped));
    assert!(stop(driver).success());
}

#[test]
fn an_estop_whose_sample_was_missed_still_reaches_the_motors_through_the_latch() {
    // As when `softarm estop` published while the driver was blocked on the bus and left
    // before it looked: only the latch file says so.
    let (s, c, rig) = rig("hw-estop-latch");
    let t = c.tendon.clone().unwrap();
    let n = node(&s);
    let setpoints = n.publisher(&n.setpoint().unwrap()).unwrap();
    let driver = spawn(&s, "tendon");
    eventually("torque on", || {
        send(&setpoints, 0.5);
        (torque(&rig, &t.ids) == [true; 6]).then_some(())
    });
    let latch = c.estop_latch();
    latch.set(true).unwrap();
    eventually("torque off from the latch", || {
        send(&setpoints, 0.5);
        (torque(&rig, &t.ids) == [false; 6]).then_some(())
    });
    follow(&setpoints, 0.5, Duration::from_millis(300));
    assert_eq!(torque(&rig, &t.ids), [false; 6]);
    latch.set(false).unwrap();
    eventually("torque on after the latch's reset", || {
        send(&setpoints, 0.5);
        (torque(&rig, &t.ids) == [true; 6]).then_some(())
    });
    assert!(stop(driver).success());
}

#[test]
fn tendon_survives_a_noisy_and_a_silent_bus_and_stops_commanding_a_faulted_motor() {
    let (s, c, rig) = rig("hw-tendon-faults");
    let t = c.tendon.clone().unwrap();
    let n = node(&s);
    let setpoints = n.publisher(&n.setpoint().unwrap()).unwrap();
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    let driver = spawn(&s, "tendon");
    let pid = driver.id() as i32;
    eventually("following", || {
        send(&setpoints, 0.5);
        newest(&motors).filter(|m| m.driver_state() == Some(DriverState::Following))
    });

    // Bad checksums and garbage: counted, and the motors are still read and driven.
    rig.bus.lock().unwrap().set_faults(BusFaults {
        corrupt_crc_one_in: 4,
        garbage_one_in: 3,
        ..BusFaults::default()
    });
    follow(&setpoints, 0.5, Duration::from_millis(1000));
    rig.bus.lock().unwrap().set_faults(BusFaults::default());
    let m = eventually("fresh motor state after the noise", || {
        send(&setpoints, 0.55);
        newest(&motors).filter(|m| now_ns() - m.stamp_ns < 100_000_000 && m.faults > 0)
    });
    // The replies lost in the last second say DEGRADED, with the rate; then FOLLOWING again.
    assert_eq!(m.driver_state(), Some(DriverState::Degraded));
    assert!(
        m.loss_permille > 0 && m.crc_errors > 0 && m.garbage_bytes > 0,
        "{m:?}"
    );
    eventually("FOLLOWING once the lost replies are a second old", || {
        send(&setpoints, 0.55);
        newest(&motors).filter(|m| m.driver_state() == Some(DriverState::Following))
    });
    assert!(alive(pid));

    // Bytes dynamixel2 0.9.1 (the packet layer before) panicked on (a status packet too short
    // to be one): garbage to the driver's own, counted, skipped.
    for length in [1, 2, 3] {
        let before = newest(&motors).map_or(0, |m| m.garbage_bytes);
        rig.bus
            .lock()
            .unwrap()
            .inject_raw(&short_status_packet(t.ids[0], length));
        eventually("the short packet counted", || {
            send(&setpoints, 0.55);
            newest(&motors).filter(|m| m.garbage_bytes > before)
        });
    }
    assert!(alive(pid), "a reply from the wire killed the driver");
    eventually("fresh motor state after the short packets", || {
        send(&setpoints, 0.55);
        newest(&motors).filter(|m| {
            now_ns() - m.stamp_ns < 100_000_000 && m.driver_state() == Some(DriverState::Following)
        })
    });

    // A bus that stops answering: the state goes stale (the controller would hold), the faults
    // count, the process lives, and it picks up again.
    let before = newest(&motors).map_or(m.faults, |m| m.faults);
    rig.bus.lock().unwrap().set_faults(BusFaults {
        silent: true,
        ..BusFaults::default()
    });
    follow(&setpoints, 0.55, Duration::from_millis(800));
    let m = newest(&motors).expect("motor state keeps coming, stamped when last read");
    assert!(
        now_ns() - m.stamp_ns > 300_000_000,
        "stale data looks fresh"
    );
    assert!(m.faults > before, "{} -> {}", before, m.faults);
    assert!(alive(pid));
    rig.bus.lock().unwrap().set_faults(BusFaults::default());
    eventually("fresh motor state after the silence", || {
        send(&setpoints, 0.55);
        newest(&motors).filter(|m| now_ns() - m.stamp_ns < 100_000_000)
    });

    // A motor with a hardware error its Shutdown setting does not act on (input voltage): the
    // motor itself stays on; the driver turns it off, reports it, and moves nothing after it.
    {
        let mut bus = rig.bus.lock().unwrap();
        bus.set_hardware_error(t.ids[2], 0x01);
        assert!(
            bus.motor(t.ids[2]).unwrap().torque_enabled(),
            "the emulated motor turned itself off"
        );
    }
    let m = eventually("the fault reported", || {
        send(&setpoints, 0.55);
        newest(&motors).filter(|m| m.driver_state() == Some(DriverState::Fault))
    });
    assert_eq!(m.hardware_error[2], 0x01, "{:?}", m.hardware_error);
    assert_eq!(m.hardware_error.iter().filter(|&&e| e != 0).count(), 1);
    let held = goals(&rig, &t.ids);
    follow(&setpoints, 0.6, Duration::from_millis(500));
    assert_eq!(
        goals(&rig, &t.ids),
        held,
        "goals written after a motor fault"
    );
    let on = torque(&rig, &t.ids);
    assert!(!on[2], "the faulted motor is off");
    assert_eq!(
        on.iter().filter(|&&v| v).count(),
        5,
        "the others hold: {on:?}"
    );
    // The faulted motor raises the alert bit on every reply: once its status is read, the
    // positions are read again (a driver reading the status on every alert read nothing else,
    // and every motor's state went stale). Counted on the bus, so it holds on a slow machine:
    // about one status read in twenty cycles.
    let reads = || {
        let c = rig.bus.lock().unwrap().counters();
        (c.position_reads, c.hardware_error_reads)
    };
    let start = reads();
    let (positions, statuses) = eventually("fifty reads after the fault", || {
        follow(&setpoints, 0.6, Duration::from_millis(100));
        let (p, s) = reads();
        let (p, s) = (p - start.0, s - start.1);
        (p + s >= 50).then_some((p, s))
    });
    assert!(
        positions > 4 * statuses,
        "{positions} position reads beside {statuses} status reads after the fault"
    );
    eventually("fresh motor state beside the faulted motor", || {
        send(&setpoints, 0.6);
        newest(&motors).filter(|m| {
            now_ns() - m.stamp_ns < 100_000_000 && m.driver_state() == Some(DriverState::Fault)
        })
    });
    assert!(stop(driver).success());
}

/// Issue 20: a tendon driver started while the bus stalls for 3 s (a loaded host's pty worker
/// holding every byte) keeps asking the motors instead of giving up after its 2 s: it drives
/// nothing meanwhile, and follows, torque on where the motors stand, once the bus answers.
#[test]
fn a_tendon_start_on_a_stalled_bus_follows_once_the_bus_answers() {
    let (s, c, rig) = rig("hw-start-stall");
    let t = c.tendon.clone().unwrap();
    rig.bus.lock().unwrap().stall(3.0);
    let stall_ends = Instant::now() + Duration::from_secs(3);
    let n = node(&s);
    let setpoints = n.publisher(&n.setpoint().unwrap()).unwrap();
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    let driver = spawn(&s, "tendon");
    let pid = driver.id() as i32;
    while rig.bus.lock().unwrap().stalled() {
        send(&setpoints, 0.5);
        assert_eq!(torque(&rig, &t.ids), [false; 6], "engaged during the stall");
        assert!(
            newest(&motors).is_none(),
            "motor state before any motor answered"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    eventually("following after the stall", || {
        send(&setpoints, 0.5);
        newest(&motors).filter(|m| m.driver_state() == Some(DriverState::Following))
    });
    // A figure, not asserted (it depends on the machine's load).
    eprintln!(
        "FOLLOWING {} ms after the bus's 3 s stall ended",
        stall_ends.elapsed().as_millis()
    );
    eventually("torque on", || {
        send(&setpoints, 0.5);
        (torque(&rig, &t.ids) == [true; 6]).then_some(())
    });
    assert!(alive(pid));
    assert!(stop(driver).success());
}

/// A motor that never answers (its return line broken: it hears every write) is never
/// engaged, nor is any other, however long the driver asks; it is named in the log. Once it
/// answers, the driver follows.
#[test]
fn a_motor_that_never_answers_the_survey_is_never_engaged() {
    let (s, c, rig) = rig("hw-start-mute");
    let t = c.tendon.clone().unwrap();
    {
        let mut bus = rig.bus.lock().unwrap();
        bus.stall(1.0);
        bus.set_faults(BusFaults {
            mute_id: Some(t.ids[3]),
            ..BusFaults::default()
        });
    }
    let n = node(&s);
    let setpoints = n.publisher(&n.setpoint().unwrap()).unwrap();
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    let driver = spawn(&s, "tendon");
    let log = || std::fs::read_to_string(s.dir.join("tendon.log")).unwrap_or_default();
    // Until the driver has asked the muted motor ten times after the stall and named it.
    let silenced = |rig: &Rig| rig.bus.lock().unwrap().counters().silenced;
    let mut after_stall = None;
    let named = "no answer on";
    let limit = Instant::now() + LIMIT;
    while after_stall.is_none_or(|n| silenced(&rig) < n + 10) || !log().contains(named) {
        assert!(Instant::now() < limit, "waited {LIMIT:?}: {}", log());
        send(&setpoints, 0.5);
        assert_eq!(torque(&rig, &t.ids), [false; 6], "a motor engaged");
        assert!(newest(&motors).is_none(), "motor state without motor 4");
        if after_stall.is_none() && !rig.bus.lock().unwrap().stalled() {
            after_stall = Some(silenced(&rig));
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(log().contains("from motor id 4 (actuator 4)"), "{}", log());
    rig.bus.lock().unwrap().set_faults(BusFaults::default());
    eventually("following once motor 4 answers", || {
        send(&setpoints, 0.5);
        newest(&motors).filter(|m| m.driver_state() == Some(DriverState::Following))
    });
    assert!(stop(driver).success());
}

#[test]
fn tracker_publishes_the_arm_in_the_base_frame_resyncs_and_survives_silence() {
    let (s, c, rig) = rig("hw-tracker");
    let n = node(&s);
    let samples = n.subscriber(&n.tracker().unwrap()).unwrap();
    let driver = spawn(&s, "tracker");
    let pid = driver.id() as i32;

    let want = ForwardModel::<6>::position(&pcc::Arm::of_config(&c.arm).unwrap(), &[0.5; 6]);
    let close = |p: &TrackerSample| (0..3).all(|i| (p.position[i] - want[i]).abs() < 1e-4);
    let p = eventually("tracker samples", || newest(&samples));
    assert!(close(&p), "{:?} vs {want:?}", p.position);

    // Garbled and lost bytes: records keep coming between them, and none of the garbled ones
    // that decode to a jump gets out (a garbled low byte moves a record by 14 mm at most; the
    // check lets through what the arm could do in a record's time, 25 mm).
    newest(&samples);
    rig.tracker_faults
        .corrupt_one_in
        .store(3, Ordering::Relaxed);
    let start = Instant::now();
    let mut during = 0;
    while start.elapsed() < Duration::from_millis(800) {
        while let Ok(Some(p)) = samples.receive() {
            during += 1;
            let d = (0..3)
                .map(|i| (p.position[i] - want[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!(d < 0.03, "a garbled record got out: {:?}", p.position);
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    rig.tracker_faults
        .corrupt_one_in
        .store(0, Ordering::Relaxed);
    assert!(during > 10, "{during} samples through the noise");
    let p = eventually("good samples after the noise", || {
        newest(&samples).filter(|p| now_ns() - p.stamp_ns < 50_000_000 && close(p))
    });
    assert!(p.seq > 20, "{}", p.seq);

    // A silent device: no samples (so the controller holds), the process lives and asks again.
    // Records the device sent before it fell silent may still be in the kernel's pty path on
    // a loaded machine: what is checked is that the samples stop.
    rig.tracker_faults.silent.store(true, Ordering::Relaxed);
    eventually("no samples from a silent device for 600 ms", || {
        newest(&samples);
        std::thread::sleep(Duration::from_millis(600));
        newest(&samples).is_none().then_some(())
    });
    assert!(alive(pid));
    rig.tracker_faults.silent.store(false, Ordering::Relaxed);
    eventually("samples after the silence", || {
        newest(&samples).filter(|p| now_ns() - p.stamp_ns < 50_000_000 && close(p))
    });
    assert!(stop(driver).success());
    let log = std::fs::read_to_string(s.dir.join("tracker.log")).unwrap();
    assert!(log.contains("the tracker sends nothing"), "{log}");
    assert!(log.contains("the tracker answers again"), "{log}");
}

/// The opens the emulated tracker has heard (each open reads the hemisphere back once).
fn tracker_opens(rig: &Rig) -> u64 {
    rig.tracker_counts.hemisphere_reads.load(Ordering::Acquire)
}

/// Points the stack's `tracker.port` at a stable name in its folder, as a udev rule gives the
/// adapter, leading to `device`; returns the name.
fn tracker_on_link(s: &TestStack, device: &Path) -> std::path::PathBuf {
    let link = s.dir.join("tracker");
    relink(&link, device);
    let text = std::fs::read_to_string(&s.config).unwrap();
    let text = softarm_test_support::with_overrides(
        &text,
        &[("tracker.port", link.display().to_string().into())],
    );
    std::fs::write(&s.config, text).unwrap();
    link
}

/// Waits until the driver has published every record the unit has made so far (taken before
/// looking), and checks it never published more than the unit made: none lost, none twice.
fn every_record_published(rig: &Rig, samples: &Sub<TrackerSample>, what: &str) -> TrackerSample {
    let made = rig.tracker_counts.records.load(Ordering::Acquire);
    let p = eventually(what, || newest(samples).filter(|p| p.seq >= made));
    let now_made = rig.tracker_counts.records.load(Ordering::Acquire);
    assert!(p.seq <= now_made, "{} samples of {now_made} records", p.seq);
    p
}

/// Issue 20: a line that stalls longer than `tracker.silent_after_ms` with the port alive (a
/// loaded host's pty worker waiting for a CPU, bytes delivered late) is slow, not gone. The
/// silence is reported and the unit asked again on the same port; the records flow again with
/// no reopen (the unit heard one open), every record published once.
#[test]
fn a_stalled_tracker_line_is_asked_again_on_the_same_port_not_reopened() {
    let (s, _c, rig) = rig("hw-tracker-stall");
    let n = node(&s);
    let samples = n.subscriber(&n.tracker().unwrap()).unwrap();
    let driver = spawn(&s, "tracker");
    every_record_published(&rig, &samples, "tracker samples");
    assert_eq!(tracker_opens(&rig), 1);
    for stall_ms in [1500, 600] {
        rig.tracker_faults
            .stall_ms
            .store(stall_ms, Ordering::Release);
        let stalled_at = now_ns();
        let ends = stalled_at + stall_ms * 1_000_000;
        eventually("the stall to end", || {
            newest(&samples).filter(|p| p.stamp_ns > ends)
        });
        // A figure, not asserted (it depends on the machine's load).
        eprintln!(
            "tracker samples again {} ms after a {stall_ms} ms stall ended",
            now_ns().saturating_sub(ends) / 1_000_000
        );
        every_record_published(&rig, &samples, "every record after the stall");
    }
    assert!(stop(driver).success());
    assert_eq!(tracker_opens(&rig), 1, "the port was reopened on a stall");
    let log = std::fs::read_to_string(s.dir.join("tracker.log")).unwrap();
    assert!(log.contains("the tracker sends nothing"), "{log}");
    assert!(log.contains("the tracker answers again"), "{log}");
}

/// The tracker's emulator restarted (its pty closed and a new one made): the driver reads the
/// hang-up at once and says so, reopens the port once the name leads to the new device, sets
/// the new unit up and streams again.
#[test]
fn a_restarted_tracker_emulator_is_reopened_on_the_hang_up_and_streams_again() {
    let (s, _c, mut rig) = rig("hw-tracker-restart");
    let link = tracker_on_link(&s, rig.tracker_path());
    let n = node(&s);
    let samples = n.subscriber(&n.tracker().unwrap()).unwrap();
    let driver = spawn(&s, "tracker");
    every_record_published(&rig, &samples, "tracker samples");
    let log = || std::fs::read_to_string(s.dir.join("tracker.log")).unwrap_or_default();
    // What the driver said before the restart (an emulator starved on a loaded machine may
    // have been silent for a while then) is not about the restart.
    let before = log().len();
    rig.restart_tracker().unwrap();
    eventually("the hang-up noticed", || {
        log()[before..].contains("the line hung up").then_some(())
    });
    relink(&link, rig.tracker_path());
    eventually("the new unit opened", || {
        (tracker_opens(&rig) > 1).then_some(())
    });
    let opened = now_ns();
    eventually("samples from the new unit", || {
        newest(&samples).filter(|p| p.stamp_ns > opened)
    });
    assert!(stop(driver).success());
    assert_eq!(tracker_opens(&rig), 2, "one open before, one after");
    // The hang-up is read at once, not found by waiting for a silent line: the old line is
    // closed by the kernel, whatever the emulator's thread gets of the CPU.
    let after = &log()[before..];
    let hung_up = after.find("the line hung up").unwrap();
    assert!(
        after
            .find("the tracker sends nothing")
            .is_none_or(|t| t > hung_up),
        "{after}"
    );
}

/// An adapter replaced behind the name while the old line stays open and silent (no hang-up):
/// the device behind `tracker.port` is another one, checked while silent, and the port is
/// reopened on it; a silent line alone is never reopened.
#[test]
fn a_tracker_replaced_behind_its_name_is_reopened_while_silent() {
    let (s, c, old) = rig("hw-tracker-replaced");
    let link = tracker_on_link(&s, old.tracker_path());
    let n = node(&s);
    let samples = n.subscriber(&n.tracker().unwrap()).unwrap();
    let driver = spawn(&s, "tracker");
    every_record_published(&old, &samples, "tracker samples");
    old.tracker_faults.silent.store(true, Ordering::Release);
    let new = Rig::start(&c, 0.5).unwrap();
    watch(&new);
    relink(&link, new.tracker_path());
    eventually("the new unit opened", || {
        (tracker_opens(&new) > 0).then_some(())
    });
    let opened = now_ns();
    eventually("samples from the new unit", || {
        newest(&samples).filter(|p| p.stamp_ns > opened)
    });
    assert!(stop(driver).success());
    assert_eq!((tracker_opens(&old), tracker_opens(&new)), (1, 1));
}

#[test]
fn both_drivers_survive_an_unplugged_adapter_and_pick_up_when_it_is_back() {
    let (s, c, rig) = rig("hw-unplug");
    let t = c.tendon.clone().unwrap();
    // The drivers open stable names, as a udev rule gives them.
    let (tendon_link, tracker_link) = (s.dir.join("tendon"), s.dir.join("tracker"));
    relink(&tendon_link, rig.tendon_path());
    relink(&tracker_link, rig.tracker_path());
    let text = std::fs::read_to_string(&s.config).unwrap();
    let text = softarm_test_support::with_overrides(
        &text,
        &[
            ("tendon.port", tendon_link.display().to_string().into()),
            ("tracker.port", tracker_link.display().to_string().into()),
        ],
    );
    std::fs::write(&s.config, text).unwrap();
    let n = node(&s);
    let setpoints = n.publisher(&n.setpoint().unwrap()).unwrap();
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    let samples = n.subscriber(&n.tracker().unwrap()).unwrap();
    let tendon = spawn(&s, "tendon");
    let tracker = spawn(&s, "tracker");
    eventually("following", || {
        send(&setpoints, 0.5);
        newest(&motors).filter(|m| m.driver_state() == Some(DriverState::Following))
    });
    eventually("tracker samples", || newest(&samples));

    // Unplugged: the devices and their names are gone.
    rig.stop().unwrap();
    std::fs::remove_file(&tendon_link).unwrap();
    std::fs::remove_file(&tracker_link).unwrap();
    follow(&setpoints, 0.5, Duration::from_millis(1500));
    newest(&samples);
    std::thread::sleep(Duration::from_millis(300));
    assert!(
        newest(&samples).is_none(),
        "samples from an unplugged tracker"
    );
    let m = newest(&motors).unwrap();
    assert!(
        now_ns() - m.stamp_ns > 500_000_000,
        "stale motor state looks fresh"
    );
    assert!(alive(tendon.id() as i32) && alive(tracker.id() as i32));

    // Plugged in again (new devices, the same names): both pick up, the motors are driven.
    let rig = Rig::start(&c, 0.5).unwrap();
    watch(&rig);
    relink(&tendon_link, rig.tendon_path());
    relink(&tracker_link, rig.tracker_path());
    eventually("fresh motor state, following", || {
        send(&setpoints, 0.5);
        newest(&motors).filter(|m| {
            now_ns() - m.stamp_ns < 100_000_000 && m.driver_state() == Some(DriverState::Following)
        })
    });
    eventually("torque on the new bus", || {
        send(&setpoints, 0.5);
        (torque(&rig, &t.ids) == [true; 6]).then_some(())
    });
    eventually("tracker samples again", || {
        newest(&samples).filter(|p| now_ns() - p.stamp_ns < 50_000_000)
    });
    assert!(stop(tendon).success());
    assert!(stop(tracker).success());
}

#[test]
fn tracker_polls_in_point_mode_with_angles() {
    let (s, c, _rig) = rig("hw-point");
    let text = std::fs::read_to_string(&s.config).unwrap();
    let text = softarm_test_support::with_overrides(
        &text,
        &[
            ("tracker.mode", "point".into()),
            ("tracker.record", "position_angles".into()),
        ],
    );
    std::fs::write(&s.config, text).unwrap();
    let n = node(&s);
    let samples = n.subscriber(&n.tracker().unwrap()).unwrap();
    let driver = spawn(&s, "tracker");
    let want = ForwardModel::<6>::position(&pcc::Arm::of_config(&c.arm).unwrap(), &[0.5; 6]);
    let p = eventually("20 polled samples", || {
        newest(&samples).filter(|p| p.seq >= 20)
    });
    assert!(
        (0..3).all(|i| (p.position[i] - want[i]).abs() < 1e-4),
        "{:?} vs {want:?}",
        p.position
    );
    assert!(stop(driver).success());
}

#[test]
fn a_motor_fault_holds_the_controller_and_shows_in_status() {
    let (s, c, rig) = rig("hw-fault-stack");
    softarm_test_support::quick_model(&s.dir.join("model"));
    let mut s = s;
    s.up();
    s.wait_status("the driver following", LIMIT, |st| {
        st["driver"]["state"] == "FOLLOWING"
    });
    let id = c.tendon.unwrap().ids[4];
    rig.bus.lock().unwrap().set_hardware_error(id, 0x04);
    let st = s.wait_status("HOLD on the fault", LIMIT, |st| {
        st["controller"]["state"] == "HOLD" && st["driver"]["state"] == "FAULT"
    });
    assert_eq!(st["driver"]["hardware_error"][4], 0x04, "{st}");
    // A set is not executed on a faulted arm.
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 1);
    assert_eq!(code, 0, "{out}{err}");
    std::thread::sleep(Duration::from_secs(1));
    assert_eq!(s.status()["controller"]["state"], "HOLD");
}

#[test]
fn the_hardware_stack_executes_a_set_through_softarm_emulate() {
    // The emulators as a user runs them, from the hardware config; the stack from the config
    // `softarm-rig emulate` writes.
    let (mut s, mut emulate) = TestStack::emulated(BIN, RIG, "hw-stack", Devices::Shared);
    let c = Config::load(&s.config).unwrap();
    assert!(c.tendon.unwrap().port.starts_with("/dev/pts"));
    s.up();
    let alive_roles = s.status()["alive"].clone();
    for role in ["controller", "learner", "tendon", "tracker"] {
        assert!(
            alive_roles.as_array().unwrap().iter().any(|r| r == role),
            "{role} not alive: {alive_roles}"
        );
    }
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 2);
    assert_eq!(code, 0, "{out}{err}");
    let stats = s.wait_stats(set_id(&out), 2, Duration::from_secs(90));
    // The learning round trip runs through the emulated devices: the conditioning samples
    // (the emulated tracker's positions) reach the learner and its estimates re-condition the
    // set. Whether the second execution is lower says nothing here: the emulated arm is the
    // model's, and led by its measured lag the first already reaches the points within a
    // millimetre or so (0.44 then 0.50 mm in one run).
    assert!(
        stats[1]["reconditions"].as_u64().unwrap() >= 1,
        "no estimates through the emulators: {stats:?}"
    );
    // A loaded machine can keep the emulated tracker's sample from a point's window: that
    // point is unseen (its error null, counted), and the mean and the worst are of the others.
    let mut judged = 0;
    for e in &stats {
        eprintln!("execution through the emulators: {e}");
        let errors = e["errors_mm"].as_array().unwrap();
        let unseen = errors.iter().filter(|x| x.is_null()).count();
        assert_eq!(e["unseen"].as_u64(), Some(unseen as u64), "{e}");
        if unseen == errors.len() {
            assert!(e["mean_mm"].is_null(), "{e}");
            continue;
        }
        judged += 1;
        // The emulated arm is the model's arm: the way-points are reached.
        let mean_mm = e["mean_mm"].as_f64().unwrap();
        assert!(mean_mm < 20.0, "{e}");
    }
    assert!(
        judged > 0,
        "the tracker saw no point of any execution: {stats:?}"
    );
    // `status` counts them too.
    let unseen: u64 = stats.iter().map(|e| e["unseen"].as_u64().unwrap()).sum();
    s.wait_status("status counting the unseen points", LIMIT, |st| {
        st["controller"]["points_unseen"] == unseen
    });
    s.stop();
    kill(Pid::from_raw(emulate.id() as i32), Signal::SIGTERM).unwrap();
    let out = eventually("softarm-rig emulate to stop", || {
        emulate.try_wait().unwrap()
    });
    assert!(out.success());
    let mut text = String::new();
    std::io::Read::read_to_string(&mut emulate.stdout.take().unwrap(), &mut text).unwrap();
    assert!(
        text.contains("tendon motors (Dynamixel 2.0): /dev/pts/"),
        "{text}"
    );
}

/// The hardware config on the shipped nine-tendon TDCR (`config/arms/tdcr.toml`): a motor per
/// tendon, ids 11 to 19, each with its own direction; 20 mm of stroke on a 5 mm spool.
fn tdcr(text: String) -> String {
    let arm = softarm_config::arms::resolve("tdcr").unwrap();
    nine_motors(&softarm_config::arms::with_arm(&text, &arm, "tdcr").unwrap())
}

/// `text`'s `[tendon]` with nine motors, ids 11 to 19, each with its own direction; 20 mm of
/// stroke on a 5 mm spool.
pub(crate) fn nine_motors(text: &str) -> String {
    let list = |v: Vec<toml::Value>| toml::Value::Array(v);
    softarm_test_support::with_overrides(
        text,
        &[
            (
                "tendon.ids",
                list((11..20).map(toml::Value::from).collect()),
            ),
            ("tendon.spool_radius_m", list(vec![0.005.into(); 9])),
            (
                "tendon.zero_ticks",
                list(
                    (0..9)
                        .map(|i| if i % 2 == 0 { 1000 } else { 3500 }.into())
                        .collect(),
                ),
            ),
            (
                "tendon.direction",
                list(
                    (0..9)
                        .map(|i| if i % 2 == 0 { 1 } else { -1 }.into())
                        .collect(),
                ),
            ),
            ("tendon.min_ticks", list(vec![800.into(); 9])),
            ("tendon.max_ticks", list(vec![3700.into(); 9])),
        ],
    )
}

/// A setpoint of `values`, stamped now.
pub(crate) fn send_each(setpoints: &Pub<Setpoint>, values: &[f64]) {
    setpoints
        .send_copy(Setpoint {
            stamp_ns: now_ns(),
            actuation: softarm_ipc::Actuators::new(values),
            ..Setpoint::default()
        })
        .unwrap();
}

/// Any arm's tendons on the bus: the driver of a nine-tendon arm engages its nine motors where
/// they stand, drives each to its own goal through its own mapping, reports nine actuators, and
/// refuses a setpoint of the paper's six.
#[test]
fn a_nine_tendon_arm_is_driven_motor_by_motor() {
    let (s, c, rig) = TestStack::with_devices_for(BIN, "hw-nine", Devices::Shared, tdcr, |c| {
        let rig = Rig::start(c, 0.5).unwrap();
        let (tendon, tracker) = (rig.tendon_path().into(), rig.tracker_path().into());
        (rig, tendon, tracker)
    });
    watch(&rig);
    let t = c.tendon.clone().unwrap();
    assert_eq!(t.ids.len(), 9);
    let mapping = Mapping::new(&t, &c.layout());
    let n = node(&s);
    let setpoints = n.publisher(&n.setpoint().unwrap()).unwrap();
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    let _driver = spawn(&s, "tendon");

    let m: MotorState = eventually("motor state", || newest(&motors));
    assert_eq!(m.actuation.len(), 9, "{:?}", m.actuation);
    assert!(
        m.actuation.iter().all(|a| (a - 0.5).abs() < 1e-3),
        "{:?}",
        m.actuation
    );
    eventually("nine motors' torque on at 0.5", || {
        send_each(&setpoints, &[0.5; 9]);
        (torque(&rig, &t.ids) == [true; 9]).then_some(())
    });
    // Each motor to its own goal (every tendon a different length), within the engage step.
    let want: Vec<f64> = (0..9).map(|i| 0.47 + 0.0075 * i as f64).collect();
    let goals_of: Vec<i32> = (0..9).map(|i| mapping.ticks(i, want[i])).collect();
    eventually("each motor's goal", || {
        send_each(&setpoints, &want);
        (goals(&rig, &t.ids) == goals_of).then_some(())
    });
    let m = eventually("nine actuators where they were sent, FOLLOWING", || {
        send_each(&setpoints, &want);
        newest(&motors).filter(|m| {
            m.driver_state() == Some(DriverState::Following)
                && m.actuation
                    .iter()
                    .zip(&want)
                    .all(|(a, w)| (a - w).abs() < 2e-3)
        })
    });
    assert_eq!(m.current_a.len(), 9);
    // The paper's six on this arm: refused whole, the goals stay.
    follow(&setpoints, 0.3, Duration::from_millis(300));
    assert_eq!(
        goals(&rig, &t.ids),
        goals_of,
        "a six-actuator setpoint was followed"
    );
}

/// The nine-tendon TDCR with its top segment's three motors on a second bus (ids 11 to 13
/// again: ids are a bus's own).
fn tdcr_on_two_buses(text: String, second: &std::cell::OnceCell<std::path::PathBuf>) -> String {
    // Until the rig has made it: any path but tendon.port's.
    let port = (second.get()).map_or("/dev/softarm-second-bus".into(), |p| {
        p.display().to_string()
    });
    let text = format!(
        "{}\n[[tendon.extra_bus]]\nport = {port:?}\nactuators = [7, 8, 9]\n",
        tdcr(text)
    );
    let ids = (11..17).chain(11..14).map(toml::Value::from).collect();
    softarm_test_support::with_overrides(&text, &[("tendon.ids", toml::Value::Array(ids))])
}

/// Motors on more than one bus: the driver engages the nine where they stand, drives each bus's
/// motors to their own goals, reports the nine in the arm's order, FOLLOWING; a hardware error
/// on the second bus holds the first too (the arm is one body), and both buses' positions are
/// still read.
#[test]
fn a_nine_tendon_arm_on_two_buses_is_driven_as_one() {
    let second = std::cell::OnceCell::new();
    let (s, c, rig) = TestStack::with_devices_for(
        BIN,
        "hw-two-buses",
        Devices::Shared,
        |text| tdcr_on_two_buses(text, &second),
        |c| {
            let rig = Rig::start(c, 0.5).unwrap();
            second.set(rig.tendon_paths()[1].clone()).unwrap();
            let (tendon, tracker) = (rig.tendon_path().into(), rig.tracker_path().into());
            (rig, tendon, tracker)
        },
    );
    watch(&rig);
    let t = c.tendon.clone().unwrap();
    assert_eq!(t.extra_bus[0].port, rig.tendon_paths()[1]);
    let mapping = Mapping::new(&t, &c.layout());
    let on_bus = |k: usize, f: &dyn Fn(&softarm_emulate::dynamixel::Motor) -> i32| -> Vec<i32> {
        let bus = rig.buses[k].lock().unwrap();
        let ids: &[u8] = if k == 0 { &t.ids[..6] } else { &t.ids[6..] };
        ids.iter().map(|&id| f(bus.motor(id).unwrap())).collect()
    };
    let all = |f: &dyn Fn(&softarm_emulate::dynamixel::Motor) -> i32| {
        [on_bus(0, f), on_bus(1, f)].concat()
    };
    let n = node(&s);
    let setpoints = n.publisher(&n.setpoint().unwrap()).unwrap();
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    let driver = spawn(&s, "tendon");

    let m: MotorState = eventually("motor state", || newest(&motors));
    assert_eq!(m.actuation.len(), 9, "{:?}", m.actuation);
    eventually("nine motors' torque on at 0.5, on both buses", || {
        send_each(&setpoints, &[0.5; 9]);
        (all(&|m| i32::from(m.torque_enabled())) == [1; 9]).then_some(())
    });
    let want: Vec<f64> = (0..9).map(|i| 0.47 + 0.0075 * i as f64).collect();
    let goals_of: Vec<i32> = (0..9).map(|i| mapping.ticks(i, want[i])).collect();
    eventually("each motor's goal, on its own bus", || {
        send_each(&setpoints, &want);
        (all(&|m| m.goal_position()) == goals_of).then_some(())
    });
    eventually("nine actuators where they were sent, FOLLOWING", || {
        send_each(&setpoints, &want);
        newest(&motors).filter(|m| {
            m.driver_state() == Some(DriverState::Following)
                && m.actuation
                    .iter()
                    .zip(&want)
                    .all(|(a, w)| (a - w).abs() < 2e-3)
        })
    });
    // A hardware error on the second bus's first motor (actuator 7).
    rig.buses[1]
        .lock()
        .unwrap()
        .set_hardware_error(t.ids[6], 0x01);
    let m = eventually("the fault reported as actuator 7's", || {
        send_each(&setpoints, &want);
        newest(&motors).filter(|m| m.driver_state() == Some(DriverState::Fault))
    });
    assert_eq!(m.hardware_error[6], 0x01, "{:?}", m.hardware_error);
    assert_eq!(m.hardware_error.iter().filter(|&&e| e != 0).count(), 1);
    let held = all(&|m| m.goal_position());
    let moved: Vec<f64> = want.iter().map(|w| w + 0.01).collect();
    for _ in 0..25 {
        send_each(&setpoints, &moved);
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(
        all(&|m| m.goal_position()),
        held,
        "goals written on a bus after a motor fault on the other"
    );
    let on = all(&|m| i32::from(m.torque_enabled()));
    assert_eq!(on[6], 0, "the faulted motor is off: {on:?}");
    assert_eq!(on.iter().sum::<i32>(), 8, "the others hold: {on:?}");
    // Both buses still read: positions asked of each after the fault.
    let reads = |k: usize| rig.buses[k].lock().unwrap().counters().position_reads;
    let start = (reads(0), reads(1));
    eventually("positions read on both buses after the fault", || {
        send_each(&setpoints, &moved);
        (reads(0) > start.0 + 20 && reads(1) > start.1 + 20).then_some(())
    });
    eventually("fresh motor state beside the faulted motor", || {
        send_each(&setpoints, &moved);
        newest(&motors).filter(|m| {
            now_ns() - m.stamp_ns < 100_000_000 && m.driver_state() == Some(DriverState::Fault)
        })
    });
    assert!(stop(driver).success());
}
