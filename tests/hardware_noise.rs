//! The motor bus as a real RS-485 bus is every day: noisy. The emulated bus
//! (`softarm_emulate::dynamixel`, in the test process) corrupts reply bytes or loses replies at
//! a seeded rate, and the real `tendon` driver, with the whole hardware stack or alone, must
//! keep the goals going, keep its motor data fresh, report the bus honestly and count each
//! lost reply once.
//!
//! Everything asserted is a count, a ratio or an invariant in the driver's own cycles (goal
//! writes per cycle, the share of `motor_state` samples younger than the controller's input
//! time-out in the driver's cycles; a HOLD counts against the bus only when the motor data was
//! stale in those cycles), so the tests hold with both cores busy. The wall-clock
//! figures (writes per second, the longest gap, freshness in milliseconds) are measured by the
//! ignored `noisy_bus_figures`.

use std::path::Path;
use std::time::{Duration, Instant};

use softarm_config::Config;
use softarm_emulate::canary::Canary;
use softarm_emulate::dynamixel::{BusCounters, BusFaults};
use softarm_emulate::rig::Rig;
use softarm_ipc::{ControllerState, DriverState, MotorState, Namespace, Node, Pub, Setpoint, Sub};
use softarm_runtime::now_ns;
use softarm_test_support::{DEMO_WAYPOINTS, Devices, TestStack, eventually, set_id};
use softarm_watch::{Limits, Watch};

use crate::hardware::send;

const BIN: &str = env!("CARGO_BIN_EXE_softarm");
const LIMIT: Duration = Duration::from_secs(60);

/// A hardware stack (quick model) on an emulated bus in this process.
fn stack(name: &str, up: bool) -> (TestStack, Config, Rig) {
    let (mut s, c, rig) = TestStack::with_devices(BIN, name, Devices::Alone, |c| {
        let rig = Rig::start(c, 0.5).unwrap();
        let (tendon, tracker) = (rig.tendon_path().into(), rig.tracker_path().into());
        (rig, tendon, tracker)
    });
    if up {
        s.add_quick_model();
        s.up();
    }
    (s, c, rig)
}

fn node(s: &TestStack) -> Node {
    Node::open(Namespace::new(&s.namespace).unwrap(), "test").unwrap()
}

fn noise(rig: &Rig, faults: BusFaults, seed: u64) {
    let mut bus = rig.bus.lock().unwrap();
    bus.set_fault_seed(seed);
    bus.set_faults(faults);
}

fn counters(rig: &Rig) -> BusCounters {
    rig.bus.lock().unwrap().counters()
}

/// What the driver published over a while, in its own cycles.
#[derive(Debug, Default, Clone)]
struct Seen {
    samples: u64,
    /// Driver cycles covered (the sequence numbers' span; samples missed count too).
    cycles: u64,
    /// Samples whose data was younger than the controller's input time-out.
    fresh: u64,
    /// Stale samples whose data aged while the kernel held the pty path (the [`Canary`] saw
    /// it): the machine's doing, not the bus's nor the driver's.
    excused: u64,
    /// The first stale samples not excused: (stamp, received, age in cycles).
    unexcused: Vec<(u64, u64, u16)>,
    max_age_cycles: u16,
    states: std::collections::BTreeMap<&'static str, u64>,
    max_loss_permille: u32,
    loss_permille_sum: u64,
    first: Option<MotorState>,
    last: Option<MotorState>,
    following_seqs: Vec<u64>,
}

impl Seen {
    fn take(&mut self, m: &MotorState, fresh_cycles: u16, excused: bool) {
        if let Some(l) = &self.last {
            self.cycles += m.seq.saturating_sub(l.seq);
        }
        self.first.get_or_insert(*m);
        self.last = Some(*m);
        self.samples += 1;
        self.fresh += u64::from(m.age_cycles < fresh_cycles);
        self.excused += u64::from(excused);
        self.max_age_cycles = self.max_age_cycles.max(m.age_cycles);
        let state = m.driver_state().map_or("?", |s| s.name());
        *self.states.entry(state).or_default() += 1;
        if m.driver_state() == Some(DriverState::Following) {
            self.following_seqs.push(m.seq);
        }
        self.max_loss_permille = self.max_loss_permille.max(m.loss_permille);
        self.loss_permille_sum += u64::from(m.loss_permille);
    }

    fn following_after(&self, seq: u64) -> u64 {
        self.following_seqs.iter().filter(|&&s| s > seq).count() as u64
    }

    /// Of the samples the machine did not hold up.
    fn fresh_share(&self) -> f64 {
        self.fresh as f64 / self.clean().max(1) as f64
    }

    fn clean(&self) -> u64 {
        self.samples - self.excused
    }
}

fn first_seq(seen: &Seen) -> u64 {
    seen.first.map_or(0, |m| m.seq)
}

/// Cycles of the driver that fit in the controller's input time-out.
fn fresh_cycles(c: &Config) -> u16 {
    let t = c.tendon.as_ref().unwrap();
    (c.controller.tracker_timeout_ms / 1000.0 * t.rate_hz).floor() as u16
}

/// HOLD setpoints by their cause, as the driver's own cycles tell it.
#[derive(Debug, Default, Clone, Copy)]
struct Holds {
    /// With motor data older than the controller's time-out in the driver's cycles within the
    /// last [`HOLD_CAUSE_CYCLES`]: the bus.
    bus: u64,
    /// With the motor data fresh in the driver's cycles all that while: the controller's
    /// wall-clock time-out passed because a process waited for a CPU (a loaded machine), or
    /// the tracker's data was late; no bus does that.
    machine: u64,
    /// With motor data older than the time-out within the last [`HOLD_CAUSE_CYCLES`], whether
    /// or not a stall of the machine's explains that (`bus` and those of `machine`): on a bus
    /// that is failing, the data is stale whatever else holds the machine up.
    after_stale: u64,
    /// Setpoints seen, HOLD or not.
    setpoints: u64,
}

/// How far back a stale motor state explains a HOLD: the controller's input time-out and the
/// delivery of both samples, in the driver's cycles.
const HOLD_CAUSE_CYCLES: u64 = 20;

/// How long after the kernel lets a held pty path go its backlog still delays replies: the
/// driver's requests queued meanwhile are answered in order, and the newest request's reply
/// waits behind the stale ones' (measured: data 100–250 ms old 100–250 ms after a stall).
const LINE_RECOVERY_NS: u64 = 500_000_000;

/// Reads `motor_state` (and counts HOLD setpoints by cause) until `done` says so. A stale
/// sample whose data aged while `canary` saw the kernel hold the pty path, or within
/// [`LINE_RECOVERY_NS`] after, is excused, and so are the HOLDs it explains.
fn watch_bus(
    motors: &Sub<MotorState>,
    setpoints: &Sub<Setpoint>,
    fresh: u16,
    canary: &Canary,
    mut done: impl FnMut(&Seen) -> bool,
) -> (Seen, Holds) {
    let mut seen = Seen::default();
    let mut holds = Holds::default();
    let mut stale = None;
    let start = Instant::now();
    let mut checked = Instant::now();
    loop {
        while let Ok(Some(m)) = motors.receive() {
            let is_stale = m.age_cycles >= fresh;
            let excused = is_stale
                && canary.stalled_within(m.stamp_ns.saturating_sub(LINE_RECOVERY_NS), now_ns());
            seen.take(&m, fresh, excused);
            if is_stale && !excused && seen.unexcused.len() < 40 {
                seen.unexcused.push((m.stamp_ns, now_ns(), m.age_cycles));
            }
            if is_stale {
                stale = Some((m.seq, excused));
            }
        }
        let newest = seen.last.map_or(0, |m| m.seq);
        let recent = |s: u64| newest.saturating_sub(s) <= HOLD_CAUSE_CYCLES;
        let bus = stale.is_some_and(|(s, excused)| !excused && recent(s));
        let after_stale = stale.is_some_and(|(s, _)| recent(s));
        while let Ok(Some(p)) = setpoints.receive() {
            holds.setpoints += 1;
            if p.state == ControllerState::Hold as u32 {
                holds.after_stale += u64::from(after_stale);
                *if bus {
                    &mut holds.bus
                } else {
                    &mut holds.machine
                } += 1;
            }
        }
        if checked.elapsed() > Duration::from_millis(500) {
            checked = Instant::now();
            if done(&seen) {
                return (seen, holds);
            }
        }
        assert!(start.elapsed() < LIMIT * 3, "{seen:#?}");
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Goal writes the driver sent since it started that never reached the emulated motors,
/// counted where nothing is in flight: the driver paused (SIGSTOP), the line drained, then the
/// driver resumed. Under load the kernel holds a pty's bytes for a second or more, so
/// emulator counts taken while the driver writes are short by the writes still in the line:
/// late, not lost. Counted over the driver's whole run, this bounds the loss of any window.
fn goal_writes_lost(s: &TestStack, rig: &Rig, motors: &Sub<MotorState>, last: &MotorState) -> u64 {
    use nix::sys::signal::{Signal, kill};
    let pid = nix::unistd::Pid::from_raw(
        s.children()
            .into_iter()
            .find(|c| c.0 == "tendon")
            .expect("a tendon driver")
            .1,
    );
    kill(pid, Signal::SIGSTOP).unwrap();
    // Published before the pause; the pause may fall between a write and its report.
    let mut sent = last.goal_writes;
    while let Ok(Some(m)) = motors.receive() {
        sent = m.goal_writes;
    }
    let (mut arrived, mut moved) = (counters(rig).goal_writes, Instant::now());
    let start = Instant::now();
    // Drained: all arrived, or nothing more for 5 s while the kernel held nothing (the rest
    // was lost).
    while arrived < sent && moved.elapsed() < Duration::from_secs(5) && start.elapsed() < LIMIT {
        std::thread::sleep(Duration::from_millis(20));
        let now = counters(rig).goal_writes;
        let held = rig.canary.stalled_within(now_ns() - 20_000_000, now_ns());
        if now != arrived || held {
            (arrived, moved) = (now, Instant::now());
        }
    }
    kill(pid, Signal::SIGCONT).unwrap();
    assert!(
        arrived <= sent + 1,
        "{arrived} goal writes arrived of {sent} sent: another writer on the bus?"
    );
    sent.saturating_sub(arrived)
}

/// Samples the machine did not hold up that a noise test must have seen: 5 s of the driver's.
const MIN_CLEAN: u64 = 500;

/// One goal write sent per driver cycle with a fresh setpoint, from `first` to `last`; where
/// the kernel held the pty path a write can time out, at most one per cycle it held.
fn assert_writes_sent(
    first: &MotorState,
    last: &MotorState,
    canary: &Canary,
    c: &Config,
    what: &str,
) {
    let wanted = last.setpoint_cycles - first.setpoint_cycles;
    let sent = last.goal_writes - first.goal_writes;
    let rate = c.tendon.as_ref().unwrap().rate_hz;
    let held = canary.stalled_ns(first.stamp_ns, now_ns());
    let held_cycles = (held as f64 * 1e-9 * rate).ceil() as u64;
    assert!(
        sent <= wanted && wanted - sent <= held_cycles,
        "{what}: {sent} goal writes sent in {wanted} cycles with a fresh setpoint; the kernel \
         held the pty path for {held_cycles} cycles of them"
    );
}

/// The demo set, two executions, run through a noisy bus: the goals keep up with the driver's
/// cycles, the motor data stays fresh, the set executes and the controller holds on it at most
/// 1 % of the time.
fn demo_through(name: &str, faults: BusFaults) {
    let (mut s, c, rig) = stack(name, true);
    let n = node(&s);
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    let setpoints = n.subscriber(&n.setpoint().unwrap()).unwrap();
    let watch = Watch::start(
        &Namespace::new(&s.namespace).unwrap(),
        Limits::from_config(&c),
    )
    .unwrap();
    noise(&rig, faults, 20);
    let before = counters(&rig);
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 2);
    assert_eq!(code, 0, "{out}{err}");
    let set = set_id(&out);
    let (seen, holds) = watch_bus(&motors, &setpoints, fresh_cycles(&c), &rig.canary, |seen| {
        watch.executions_of(set) >= 2 && seen.clean() >= MIN_CLEAN
    });
    let after = counters(&rig);
    noise(&rig, BusFaults::default(), 20);
    let report = watch.finish();
    let writes = after.goal_writes - before.goal_writes;
    let last = seen.last.unwrap();
    let first = seen.first.unwrap();
    let wanted = last.setpoint_cycles - first.setpoint_cycles;
    eprintln!(
        "{name}: {writes} goal writes at the motors by then in {} driver cycles with a fresh setpoint \
         ({:.3} per cycle; {} cycles in all), {} motor states, \
         {:.4} fresher than the controller's time-out (oldest {} cycles; {} stale samples \
         excused: the kernel held the pty path {:?}), states {:?}, loss up \
         to {} per mille, HOLD setpoints {:?}; bus {:?}; driver: dropped {} crc {} garbage {} \
         time-outs {} reopens {}",
        wanted,
        writes as f64 / wanted as f64,
        seen.cycles,
        seen.samples,
        seen.fresh_share(),
        seen.max_age_cycles,
        seen.excused,
        rig.canary.stalls(),
        seen.states,
        seen.max_loss_permille,
        holds,
        after,
        last.dropped - first.dropped,
        last.crc_errors - first.crc_errors,
        last.garbage_bytes - first.garbage_bytes,
        last.timeouts - first.timeouts,
        last.reopens,
    );
    let lost = after.dropped_replies + after.corrupted_packets
        - before.dropped_replies
        - before.corrupted_packets;
    assert!(
        lost > 20,
        "{name}: the noise reached too few replies: {lost}"
    );
    // The writes wait for nothing: one per cycle with a setpoint, sent and arrived.
    assert_writes_sent(&first, &last, &rig.canary, &c, name);
    assert!(
        seen.fresh_share() >= 0.99,
        "{name}: motor data fresh in {:.4} of the {} samples the machine did not hold up \
         ({} excused): not excused {:?}; stalls {:?}",
        seen.fresh_share(),
        seen.clean(),
        seen.excused,
        seen.unexcused,
        rig.canary.stalls()
    );
    // The noise must not make the controller hold: HOLD on stale motor data in at most 1 % of
    // its setpoints, the "fresher than the time-out 99 % of the time" as the controller
    // lives it. Not none: a reply the loaded machine's pty delivers 100 ms late makes the data
    // stale in the driver's cycles too (seen: 16 HOLD setpoints of about 6000, the data at most
    // 12 cycles old, where 2 % lost replies alone leave it 10 cycles old about never).
    assert!(
        holds.bus * 100 <= holds.setpoints,
        "{name}: the controller held on the bus's stale data: {holds:?}\n{}",
        s.logs()
    );
    assert_eq!(
        last.reopens, 0,
        "{name}: a noisy bus is no reason to reopen the port"
    );
    assert!(
        seen.states.get("DEGRADED").copied().unwrap_or(0) > 0,
        "{name}: lost replies and never DEGRADED: {:?}",
        seen.states
    );
    assert_eq!(report.violations, 0, "{name}: {:#?}", report.messages);
    assert_eq!(report.executions, 2);
    let never = goal_writes_lost(&s, &rig, &motors, &last);
    assert!(
        (wanted - never.min(wanted)) as f64 >= 0.95 * wanted as f64,
        "{name}: {never} goal writes never reached the motors, {wanted} cycles with a setpoint \
         in the window"
    );
    s.stop();
}

#[test]
fn noisy_bus_corrupted_bytes_keeps_the_arm_going() {
    demo_through(
        "hw-noise-bytes",
        BusFaults {
            corrupt_byte_ppm: 20_000,
            ..Default::default()
        },
    );
}

#[test]
fn noisy_bus_dropped_replies_keeps_the_arm_going() {
    demo_through(
        "hw-noise-drops",
        BusFaults {
            drop_reply_ppm: 20_000,
            ..Default::default()
        },
    );
}

/// A tendon driver restarted while 2 % of the reply bytes are garbled finds all six motors and
/// drives them again: its start-up survey's long replies arrive whole only about a quarter of
/// the time, so it must ask again until each motor has answered, never giving up (the process
/// is not restarted again). A motor not found within 2 s is named while the survey goes on:
/// seen once under a load average of 15, the sixth motor found 40 ms after.
#[test]
fn a_driver_restarted_on_a_noisy_bus_finds_every_motor() {
    let (s, _c, rig) = stack("hw-noise-restart", true);
    let n = node(&s);
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    noise(
        &rig,
        BusFaults {
            corrupt_byte_ppm: 20_000,
            ..BusFaults::default()
        },
        21,
    );
    let tendon = |s: &TestStack| s.children().into_iter().find(|c| c.0 == "tendon");
    let (_, old) = tendon(&s).expect("a tendon driver");
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(old),
        nix::sys::signal::Signal::SIGKILL,
    )
    .unwrap();
    let killed_ns = now_ns();
    eventually("a new tendon driver with motor data", LIMIT, || {
        let mut driving = false;
        while let Ok(Some(m)) = motors.receive() {
            driving |= m.stamp_ns > killed_ns
                && matches!(
                    m.driver_state(),
                    Some(DriverState::Following | DriverState::Degraded)
                );
        }
        (driving && tendon(&s).is_some_and(|(_, pid)| pid != old)).then_some(())
    });
    assert_eq!(
        s.logs().matches("softarm up: tendon exited").count(),
        1,
        "a start-up on the noisy bus gave up: {}",
        s.logs()
    );
}

/// 10 % of the reply bytes corrupted: most replies are lost. The goals still go out, the
/// driver says the bus is failing (DEGRADED, most replies lost; `status` in words), the
/// controller holds on the stale data, and no invariant breaks; clean again, it follows.
#[test]
fn a_failing_bus_is_safe_and_said_so() {
    let (mut s, c, rig) = stack("hw-noise-failing", true);
    let n = node(&s);
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    let setpoints = n.subscriber(&n.setpoint().unwrap()).unwrap();
    let watch = Watch::start(
        &Namespace::new(&s.namespace).unwrap(),
        Limits::from_config(&c),
    )
    .unwrap();
    let (code, out, err) = s.submit(Path::new(DEMO_WAYPOINTS), 50);
    assert_eq!(code, 0, "{out}{err}");
    s.wait_status("EXECUTE", LIMIT, |st| {
        st["controller"]["state"] == "EXECUTE"
    });
    // What the clean bus published meanwhile (up to the services' buffers, 64 samples) is
    // not under test: the watch starts with the noise.
    while let Ok(Some(_)) = motors.receive() {}
    while let Ok(Some(_)) = setpoints.receive() {}
    noise(
        &rig,
        BusFaults {
            corrupt_byte_ppm: 100_000,
            ..Default::default()
        },
        10,
    );
    let before = counters(&rig);
    let start = Instant::now();
    let (seen, holds) = watch_bus(&motors, &setpoints, fresh_cycles(&c), &rig.canary, |_| {
        start.elapsed() > Duration::from_secs(6)
    });
    let after = counters(&rig);
    // The bus still fails: `status` says so once a motor state reaches it within its window
    // (a loaded machine can keep the driver's from it for one call).
    let text = eventually("status saying the bus fails", LIMIT, || {
        let text = String::from_utf8_lossy(&s.run(&["status"]).stdout).to_string();
        text.contains("DEGRADED (bus failing").then_some(text)
    });
    let writes = after.goal_writes - before.goal_writes;
    eprintln!(
        "10 %: {writes} goal writes in {} cycles, fresh {:.3}, states {:?}, loss up to {} \
         per mille, HOLD setpoints {holds:?}\n{text}",
        seen.cycles,
        seen.fresh_share(),
        seen.states,
        seen.max_loss_permille
    );
    let (first, last) = (seen.first.unwrap(), seen.last.unwrap());
    let wanted = last.setpoint_cycles - first.setpoint_cycles;
    assert_writes_sent(&first, &last, &rig.canary, &c, "10 %");
    let never = goal_writes_lost(&s, &rig, &motors, &last);
    assert!(
        (wanted - never.min(wanted)) as f64 >= 0.95 * wanted as f64,
        "{never} goal writes never reached the motors, {wanted} cycles with a setpoint"
    );
    assert!(seen.max_loss_permille >= 500, "{}", seen.max_loss_permille);
    // The loss rate covers the last second: a few cycles pass before it shows.
    assert!(
        seen.following_after(first_seq(&seen) + 20) == 0,
        "FOLLOWING on a failing bus: {:?}",
        seen.states
    );
    // Held on stale motor data; on a loaded machine the canary's stalls may explain the
    // staleness too (seen: 1744 HOLD setpoints, all after stale data the stalls covered).
    assert!(
        holds.after_stale > 0,
        "the controller should hold on stale motor data: {holds:?}"
    );
    // Clean again: following, fresh.
    noise(&rig, BusFaults::default(), 10);
    eventually("FOLLOWING on a clean bus", LIMIT, || {
        motors
            .receive()
            .ok()
            .flatten()
            .filter(|m| m.driver_state() == Some(DriverState::Following) && m.age_cycles < 3)
            .map(|_| ())
    });
    let report = watch.finish();
    assert_eq!(report.violations, 0, "{:#?}", report.messages);
    s.stop();
}

/// The newest motor state after a few more cycles, every read of the noise closed.
fn settled(motors: &Sub<MotorState>, setpoints: &Pub<Setpoint>, cycles: u64) -> MotorState {
    let mut first = None;
    eventually("a few more cycles", LIMIT, || {
        send(setpoints, 0.5);
        std::thread::sleep(Duration::from_millis(5));
        let mut last = None;
        while let Ok(Some(m)) = motors.receive() {
            last = Some(*m);
        }
        let m = last?;
        let f = *first.get_or_insert(m.seq);
        (m.seq >= f + cycles).then_some(m)
    })
}

/// Each lost reply counted once, each bad CRC once, each garbage byte once: the driver's counts
/// equal the emulator's, exactly, phase by phase. (The driver at 20 Hz, so a reply the loaded
/// machine delivers late is still inside its read. A phase in which the kernel held the pty
/// path long enough to split an instruction is run again, at most twice.)
#[test]
fn lost_replies_bad_crcs_and_garbage_are_counted_once_each() {
    const RATE_HZ: f64 = 20.0;
    let (s, c, rig) = stack("hw-noise-count", false);
    let text = std::fs::read_to_string(&s.config).unwrap();
    let text = softarm_test_support::with_overrides(&text, &[("tendon.rate_hz", RATE_HZ.into())]);
    std::fs::write(&s.config, text).unwrap();
    let n = node(&s);
    let setpoints = n.publisher(&n.setpoint().unwrap()).unwrap();
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    let driver = s.spawn(&["tendon"]);
    // Samples before FOLLOWING that no driver could have followed in: data older than the
    // controller's time-out (a loaded machine holds a pty's bytes), no fresh setpoint that
    // cycle (a loaded machine holds this test's sends too), or DEGRADED for replies lost (on
    // this clean bus, only replies a loaded machine delivered after the read gave up). The
    // driver must say FOLLOWING as soon as it may.
    let fresh = (c.controller.tracker_timeout_ms / 1000.0 * RATE_HZ).floor() as u16;
    let (mut stale, mut unsent, mut lossy, mut followed) = (0, 0, 0, 0);
    let first = eventually("following", LIMIT, || {
        send(&setpoints, 0.5);
        std::thread::sleep(Duration::from_millis(10));
        while let Ok(Some(m)) = motors.receive() {
            if m.driver_state() == Some(DriverState::Following) {
                return Some(*m);
            }
            stale += u64::from(m.age_cycles >= fresh);
            unsent += u64::from(m.setpoint_cycles == followed);
            lossy += u64::from(m.driver_state() == Some(DriverState::Degraded));
            followed = m.setpoint_cycles;
        }
        None
    });
    // Up and following at once: one exchange at start, then the first cycles' reads.
    assert!(
        first.seq <= 3 + stale + unsent + lossy,
        "FOLLOWING at the driver's {}th cycle; before it {stale} samples with stale data, \
         {unsent} without a fresh setpoint, {lossy} with replies lost",
        first.seq
    );
    let phases = [
        (
            "dropped",
            BusFaults {
                drop_reply_ppm: 50_000,
                ..Default::default()
            },
        ),
        (
            "bad CRCs",
            BusFaults {
                corrupt_crc_one_in: 20,
                ..Default::default()
            },
        ),
        (
            "garbage",
            BusFaults {
                garbage_one_in: 10,
                ..Default::default()
            },
        ),
    ];
    let mut base = (settled(&motors, &setpoints, 3), counters(&rig));
    // Replies late before any noise count as dropped until they come (and take the drop back):
    // a count taken meanwhile would make the first phase's drops look fewer than the emulator's
    // (measured: 6 such, then 17 counted for 23 dropped).
    let waited = Instant::now();
    while base.0.dropped != base.1.dropped_replies && waited.elapsed() < LATE_REPLIES {
        base = (settled(&motors, &setpoints, 1), counters(&rig));
    }
    for (seed, (what, faults)) in phases.into_iter().enumerate() {
        for attempt in 1.. {
            // The driver widens its wait for replies for a while after replies came late (a
            // stall): a phase begun then closes its reads on another schedule than the
            // emulator's drops; let that pass first.
            let last_stall = rig.canary.stalls().iter().map(|s| s.to_ns).max();
            if let Some(end) = last_stall {
                let since = Duration::from_nanos(now_ns().saturating_sub(end));
                std::thread::sleep(AFTER_STALL.saturating_sub(since));
            }
            let from = now_ns();
            noise(&rig, faults, seed as u64 + 1);
            let start = Instant::now();
            while start.elapsed() < Duration::from_secs(4) {
                send(&setpoints, 0.5);
                std::thread::sleep(Duration::from_millis(10));
            }
            noise(&rig, BusFaults::default(), 0);
            let (m0, e0) = base;
            base = (settled(&motors, &setpoints, 3), counters(&rig));
            // A reply the machine delivers after its read closed counts as dropped until it
            // comes, if within the driver's 3 s for late replies: wait that out before counting.
            let waited = Instant::now();
            // Signed: a late reply that comes takes back the drop counted for it, so the
            // driver's count can go down between two reads.
            let diff = |a: u64, b: u64| a as i64 - b as i64;
            while diff(base.0.dropped, m0.dropped)
                != diff(base.1.dropped_replies, e0.dropped_replies)
                && waited.elapsed() < LATE_REPLIES
            {
                base = (settled(&motors, &setpoints, 1), counters(&rig));
            }
            let (m, e) = base;
            // Where the kernel held the line, the counts cannot be exact: a reply held past the
            // driver's wait for late ones is lost to the driver and sent by the emulator, and
            // the devices (a real one too) drop an instruction that stops coming for 100 ms.
            let held = rig
                .canary
                .stalls()
                .iter()
                .filter(|s| s.to_ns >= from)
                .map(|s| s.to_ns - s.from_ns)
                .max()
                .unwrap_or(0);
            if held > HELD_TOO_LONG_NS && attempt < ATTEMPTS {
                eprintln!(
                    "{what}: the kernel held the pty path {} ms; again",
                    held / 1_000_000
                );
                // What the hold delayed can still come and take back a drop counted for it: the
                // next attempt counts from after that (measured: counted from before, the next
                // attempt's drops came to -2 against the emulator's 0).
                base = after_late_replies(&rig, &motors, &setpoints);
                continue;
            }
            eprintln!(
                "after {what}: driver dropped {} crc {} garbage {} time-outs {} reopens {} \
                 faults {}; emulator {e:?}",
                m.dropped, m.crc_errors, m.garbage_bytes, m.timeouts, m.reopens, m.faults
            );
            let dropped = diff(m.dropped, m0.dropped);
            let crc_errors = diff(m.crc_errors, m0.crc_errors);
            // Each event counted once, whatever the kernel did.
            assert_eq!(m.reopens, 0, "{what}");
            assert_eq!(
                diff(m.faults, m0.faults),
                dropped + crc_errors,
                "{what}: faults, each once"
            );
            if held > HELD_TOO_LONG_NS {
                // Held in every attempt: a reply held past the driver's wait, or an instruction
                // the hold split, is lost to the driver and not dropped by the emulator, and a
                // driver held in the kernel publishes its counts late (a phase was seen with no
                // drop counted beside the emulator's 53), so the phase's counts say nothing
                // exact. What holds whatever the kernel did is checked above (each event once,
                // no reopen) and here (no CRC error the emulator did not make).
                eprintln!(
                    "{what}: the kernel held the pty path in all {ATTEMPTS} attempts; counts \
                     bounded, not exact"
                );
                assert!(
                    crc_errors <= diff(e.corrupted_crcs, e0.corrupted_crcs),
                    "{what}: more CRC errors than the emulator made"
                );
                // What the hold delayed can still come and take back a drop counted for it, in
                // the next phase: it counts from after that (seen: the next phase's drops came
                // to -6 against the emulator's 0).
                base = after_late_replies(&rig, &motors, &setpoints);
                break;
            }
            assert_eq!(
                dropped,
                diff(e.dropped_replies, e0.dropped_replies),
                "{what}: dropped replies"
            );
            assert_eq!(
                crc_errors,
                diff(e.corrupted_crcs, e0.corrupted_crcs),
                "{what}: CRC errors"
            );
            assert_eq!(
                m.garbage_bytes - m0.garbage_bytes,
                e.garbage_sent - e0.garbage_sent,
                "{what}: garbage bytes"
            );
            assert!(
                dropped + crc_errors == 0 || m.timeouts > m0.timeouts,
                "{what}: reads with a reply missing"
            );
            break;
        }
    }
    assert!(counters(&rig).dropped_replies > 10);
    assert!(counters(&rig).corrupted_crcs > 10);
    assert!(driver.stop(LIMIT).success());
}

/// The driver's and the emulator's counts once the driver's count of dropped replies has stood
/// still for [`LATE_REPLIES`] (at most [`LATE_REPLIES_AT_MOST`]): after the kernel held the pty
/// path, late replies keep coming and taking back drops for as long as the hold delayed them, not
/// only within the driver's own wait (seen: after a hold of 20.9 s and 3.1 s of waiting, the
/// next attempt's drops came to -48 against the emulator's 0).
fn after_late_replies(
    rig: &Rig,
    motors: &Sub<MotorState>,
    setpoints: &Pub<Setpoint>,
) -> (MotorState, BusCounters) {
    let start = Instant::now();
    let mut base = (settled(motors, setpoints, 1), counters(rig));
    let mut still_since = Instant::now();
    while still_since.elapsed() < LATE_REPLIES && start.elapsed() < LATE_REPLIES_AT_MOST {
        std::thread::sleep(Duration::from_millis(200));
        let now = (settled(motors, setpoints, 1), counters(rig));
        if now.0.dropped != base.0.dropped {
            still_since = Instant::now();
        }
        base = now;
    }
    base
}

/// How long [`after_late_replies`] waits at most.
const LATE_REPLIES_AT_MOST: Duration = Duration::from_secs(30);

/// How long the driver waits for a late reply (3 s, `KEEP_CLOSED_NS` in its `link.rs`), and
/// a cycle more.
const LATE_REPLIES: Duration = Duration::from_millis(3_100);
/// How long after a stall the driver's wait for replies stays widened (its lateness is kept
/// 5 s), and a little more.
const AFTER_STALL: Duration = Duration::from_millis(5_500);

/// Tries of a phase before its counts are only bounded: each try is about 7 s, and on a
/// loaded machine the kernel holds the pty path in most (two and three in a row were seen).
const ATTEMPTS: usize = 6;

/// A stall this long can split an instruction (the emulated motors drop one that stops coming
/// for 100 ms, as the real ones do).
const HELD_TOO_LONG_NS: u64 = 100_000_000;

/// Setpoints at the controller's rate (500 Hz) until `stop`, as a running controller sends.
fn controller_like(
    namespace: String,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let n = Node::open(Namespace::new(&namespace).unwrap(), "setpoints").unwrap();
        let setpoints = n.publisher(&n.setpoint().unwrap()).unwrap();
        while !stop.load(std::sync::atomic::Ordering::Relaxed) {
            send(&setpoints, 0.5);
            std::thread::sleep(Duration::from_millis(2));
        }
    })
}

/// The wall-clock figures of issue 20, measured (not asserted): the driver alone at
/// `tendon.rate_hz` (100 Hz) with setpoints at 500 Hz, 10 s per noise: goal writes per second
/// against the configured rate, the longest gap between two goal writes at the emulated
/// motors, and the share of `motor_state` samples fresher than the controller's input time-out
/// (in the driver's cycles, and in milliseconds when this thread received them). Also how
/// long a driver takes from its start to FOLLOWING. Run on a quiet machine:
/// `cargo test --test e2e noisy_bus_figures -- --ignored --nocapture`.
#[test]
#[ignore = "a measurement: wall-clock figures, printed"]
fn noisy_bus_figures() {
    use std::sync::Arc;
    use std::sync::atomic::AtomicBool;
    let (s, c, rig) = stack("hw-noise-figures", false);
    let t = c.tendon.clone().unwrap();
    let timeout_ns = (c.controller.tracker_timeout_ms * 1e6) as u64;
    let n = node(&s);
    let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let feeder = controller_like(s.namespace.clone(), stop.clone());
    let started = Instant::now();
    let driver = s.spawn(&["tendon"]);
    let first = eventually("following", LIMIT, || {
        motors
            .receive()
            .ok()
            .flatten()
            .filter(|m| m.driver_state() == Some(DriverState::Following))
            .map(|m| *m)
    });
    println!(
        "start: FOLLOWING {:.0} ms after the process was started, at its {}th motor_state",
        started.elapsed().as_secs_f64() * 1e3,
        first.seq
    );
    let phases = [
        ("clean", BusFaults::default()),
        (
            "2 % bytes corrupted",
            BusFaults {
                corrupt_byte_ppm: 20_000,
                ..Default::default()
            },
        ),
        (
            "2 % replies dropped",
            BusFaults {
                drop_reply_ppm: 20_000,
                ..Default::default()
            },
        ),
        (
            "10 % bytes corrupted",
            BusFaults {
                corrupt_byte_ppm: 100_000,
                ..Default::default()
            },
        ),
    ];
    println!(
        "| bus | goal writes/s (of {:.0}) | longest gap ms (periods) | fresh, driver cycles | \
         fresh, ms at receipt | oldest ms at receipt | replies lost (mean of the driver's \
         last-second rate) | states |",
        t.rate_hz
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (what, faults) in phases {
        noise(&rig, faults, 7);
        rig.bus.lock().unwrap().record_goal_writes(true);
        let (mut seen, mut fresh_ms, mut oldest_ms) = (Seen::default(), 0u64, 0.0f64);
        let start = Instant::now();
        let before = counters(&rig);
        while start.elapsed() < Duration::from_secs(10) {
            while let Ok(Some(m)) = motors.receive() {
                seen.take(&m, fresh_cycles(&c), false);
                let age = now_ns().saturating_sub(m.stamp_ns);
                fresh_ms += u64::from(age < timeout_ns);
                oldest_ms = oldest_ms.max(age as f64 / 1e6);
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        let elapsed = start.elapsed().as_secs_f64();
        let after = counters(&rig);
        let times = rig.bus.lock().unwrap().goal_write_times().to_vec();
        rig.bus.lock().unwrap().record_goal_writes(false);
        let gap = times.windows(2).map(|w| w[1] - w[0]).fold(0.0, f64::max);
        let rate = (after.goal_writes - before.goal_writes) as f64 / elapsed;
        let loss = seen.loss_permille_sum as f64 / seen.samples.max(1) as f64 / 10.0;
        println!(
            "| {what} | {rate:.1} ({:.1} %) | {:.1} ({:.2}) | {:.4} | {:.4} | {oldest_ms:.0} | \
             {loss:.1} % | {:?} |",
            100.0 * rate / t.rate_hz,
            gap * 1e3,
            gap * t.rate_hz,
            seen.fresh_share(),
            fresh_ms as f64 / seen.samples.max(1) as f64,
            seen.states,
        );
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    feeder.join().unwrap();
    assert!(driver.stop(LIMIT).success());
}
