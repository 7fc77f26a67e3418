//! The `tendon` driver process: the arm's tendon motors, one per actuator, on one or more
//! Dynamixel Protocol 2.0 buses (X-series), through the driver's own packet layer ([`wire`]).
//! Each bus is a [`Driver`] of its own (its port, survey, reads, health), all run in one cycle
//! and published as one `motor_state` in the arm's order; a motor's hardware error anywhere
//! holds every bus. Consumes `setpoint` and `estop`, publishes `motor_state`, and is safe on
//! its own: torque comes on only with a valid setpoint close to where the motors stand, an e-stop turns it off at once, setpoints that
//! stop arriving lead to hold and then torque off ([`softarm_driver::Supervisor`]), a motor
//! reporting a hardware error is turned off and gets no other command.
//!
//! A noisy bus never holds back a write: goals (and torque-off) go out every cycle, with no
//! reply to wait for; a read is sent each cycle and its replies are taken at the start of the
//! next, whatever came. Lost replies are counted once each and reported with the loss rate
//! (DEGRADED); the port is reopened only when it is gone (an I/O error, its device node
//! vanished or replaced), never because replies are garbled or missing.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::Context;

use softarm_config::Config;
use softarm_config::hardware::{Bus as BusConfig, Mapping, TendonConfig};
use softarm_config::per_actuator::PerActuator;
use softarm_driver::{Action, Commands, Poll, Supervisor, Timeouts};
use softarm_ipc::{Actuators, DriverState, MAX_ACTUATORS, MotorState, Namespace, Node};
use softarm_runtime::clock::{Backoff, Ticker};
use softarm_runtime::now_ns;

#[cfg(test)]
mod fuzz;
mod health;
mod link;
pub mod table;
mod timing;
pub mod wire;

use health::{Bus, Health};
use link::{Ask, Counts, Fault, Link, Reading};
use timing::{Cycle, RETURN_DELAY};

/// Runs the tendon driver until `stop` is set.
pub fn run(config: &Config, namespace: Namespace, stop: &AtomicBool) -> anyhow::Result<()> {
    let t = config
        .tendon
        .as_ref()
        .context("the config has no [tendon] section")?;
    let node = Node::open(namespace, "tendon")?;
    let mut commands = Commands::open(&node, &config.estop_latch(), t.ids.len())?;
    let publisher = node.publisher(&node.motor_state()?)?;
    let buses = t.buses();
    let mapping = Mapping::new(t, &config.layout());
    let mut drivers = (buses.iter())
        .map(|b| Driver::open(config, b, mapping.select(&b.actuators)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let hold_after_ns = drivers[0].timeouts.hold_after_ns;
    let mut ticker = Ticker::new(t.rate_hz);
    let mut seq = 0;
    while !stop.load(Ordering::Relaxed) {
        ticker.wait();
        let now = now_ns();
        let poll = commands.poll(now, hold_after_ns);
        // A fault on one bus holds them all: the arm is one body.
        let fault = drivers.iter().any(Driver::fault);
        for d in &mut drivers {
            d.cycle(now, &poll, fault);
        }
        if let Some(state) = motor_state(&mut drivers, t.ids.len(), &mut seq) {
            let _ = publisher.send_copy(state);
        }
    }
    for d in &mut drivers {
        d.leave();
        let c = d.totals();
        tracing::info!(
            port = %d.t.port.display(),
            dropped = c.dropped,
            crc_errors = c.crc_errors,
            garbage_bytes = c.garbage_bytes,
            timeouts = c.timeouts,
            reopens = c.reopens,
            goal_writes = d.goal_writes,
            clamped = d.clamped,
            refused_engage = d.refused_engage,
            reengaged = d.reengaged,
            stranded = d.stranded,
            "tendon bus stopped"
        );
    }
    tracing::info!(
        refused = commands.refused(),
        overruns = ticker.overruns(),
        "tendon driver stopped"
    );
    Ok(())
}

/// The state every bus's motors are in, as one `motor_state` in the arm's order (`n`
/// actuators): stamped by the oldest bus's data, the counts summed, the state the least
/// able of the buses'. `None` before every bus has heard every motor once.
fn motor_state(drivers: &mut [Driver], n: usize, seq: &mut u64) -> Option<MotorState> {
    let mut all = MotorState {
        actuation: Actuators::filled(n, 0.0),
        current_a: Actuators::filled(n, 0.0),
        state: DriverState::Following as u32,
        goal_writes: u64::MAX,
        stamp_ns: u64::MAX,
        ..MotorState::default()
    };
    for d in drivers.iter_mut() {
        let s = d.motor_state()?;
        for (k, &i) in d.actuators.iter().enumerate() {
            all.actuation[i] = s.actuation[k];
            all.current_a[i] = s.current_a[k];
            all.hardware_error[i] = s.hardware_error[k];
        }
        all.stamp_ns = all.stamp_ns.min(s.stamp_ns);
        all.faults += s.faults;
        all.dropped += s.dropped;
        all.crc_errors += s.crc_errors;
        all.garbage_bytes += s.garbage_bytes;
        all.timeouts += s.timeouts;
        all.reopens += s.reopens;
        all.setpoint_cycles = s.setpoint_cycles;
        all.goal_writes = all.goal_writes.min(s.goal_writes);
        all.loss_permille = all.loss_permille.max(s.loss_permille);
        all.age_cycles = all.age_cycles.max(s.age_cycles);
        all.state = least_able(all.state, s.state);
    }
    *seq += 1;
    all.seq = *seq;
    Some(all)
}

/// Of two buses' states, the one that can do less: a fault, stopped, off, holding, degraded,
/// following.
fn least_able(a: u32, b: u32) -> u32 {
    let rank = |s: u32| match DriverState::from_u32(s) {
        Some(DriverState::Fault) | None => 0,
        Some(DriverState::Stopped) => 1,
        Some(DriverState::Off) => 2,
        Some(DriverState::Holding) => 3,
        Some(DriverState::Degraded) => 4,
        Some(DriverState::Following) => 5,
    };
    if rank(b) < rank(a) { b } else { a }
}

/// The bus counts as `motor_state` reports them.
#[derive(Debug, Clone, Copy, Default)]
struct Totals {
    dropped: u64,
    crc_errors: u64,
    garbage_bytes: u64,
    timeouts: u64,
    reopens: u64,
}

/// The driver's state between cycles: the bus, what the motors last said, the safety state
/// machine and the counts it reports.
struct Driver<'a> {
    /// This bus's section: its port, and its motors' ids and lists alone.
    t: &'a TendonConfig,
    /// The arm's actuators on this bus, one per motor (0-based, in the arm's order).
    actuators: &'a [usize],
    /// Its motors.
    n: usize,
    mapping: Mapping,
    timeouts: Timeouts,
    supervisor: Supervisor,
    /// Setpoints are clamped to what the controller may send, then to the motors' limits.
    limits: ([f64; MAX_ACTUATORS], [f64; MAX_ACTUATORS]),
    /// `None` while the port is closed (being reopened).
    link: Option<Link>,
    reading: Reading,
    /// Reopening a port that is gone: 10 ms after a failure, doubling, at most 1 s apart.
    reopen_backoff: Backoff,
    /// A read that got no reply at all: the next waits, 10 ms doubling to 200 ms (the writes
    /// do not).
    read_backoff: Backoff,
    /// `counts.late` when the read back-off was last decided: replies heard late since then
    /// say the bus answers.
    late_heard: u64,
    counts: Counts,
    /// CRC errors and garbage of the ports closed so far (each port counts its own).
    closed_line: (u64, u64),
    reopens: u64,
    health: Health,
    /// Motor data older than this holds the controller (`controller.tracker_timeout_ms`):
    /// the driver says FOLLOWING only while its data is fresher.
    stale_after_ns: u64,
    clamped: u64,
    refused_engage: u64,
    /// Motors found with the torque off while following, and turned on again.
    reengaged: u64,
    /// Cycles with a motor found off while following that was too far from its goal to engage.
    stranded: u64,
    write_faults: u64,
    goal_writes: u64,
    setpoint_cycles: u64,
    seq: u64,
    cycle: u64,
    reported: DriverState,
    reported_errors: [u8; MAX_ACTUATORS],
    /// Torque and hardware-error status are read every this many cycles (about 5 Hz), and
    /// after a reply raises its alert bit, in place of that cycle's data read.
    status_every: u64,
    /// When the port's device was last checked while the bus is silent.
    device_checked_ns: u64,
}

/// Whether closed read `c` found the bus silent, so the next read backs off: every motor was
/// asked and none answered, and no reply came late meanwhile. A bus that answers late is slow,
/// not silent (a loaded machine delivers a pty's bytes tens of ms late): backing its reads off
/// to 200 ms left the data older than the controller's time-out for as long as that lasted.
/// One motor asked again whose reply was garbled again is not silence either.
fn silent(c: &link::Closed, motors: usize, heard_late: bool) -> bool {
    c.asked == motors && c.answered + c.refused == 0 && !heard_late
}

/// Present current (with velocity and position) is read every this many cycles; the
/// position alone in the others.
const DATA_EVERY: u64 = 4;

/// The share of a period a cycle of the survey waits for the motors' answers (those that come
/// later are taken in the next cycles).
const SURVEY_WAIT: f64 = 0.4;

/// A bus silent this long has its device checked (gone, or another one behind the name).
const CHECK_DEVICE_AFTER_NS: u64 = 500_000_000;

/// How long the survey's first exchange, before the loop, waits for the motors' answers.
const START_SURVEY_WAIT: Duration = Duration::from_millis(100);

/// Says that every motor answered the survey and is configured, and what the bus can do per
/// cycle with the motors' Return Delay Times as read back: a warning when every motor cannot
/// be read within a period.
fn said_ready(t: &TendonConfig, link: &Link) {
    tracing::info!(
        port = %t.port.display(),
        baud = t.baud,
        ids = ?t.ids,
        "every motor answered; the torque comes on with the first setpoint where they stand"
    );
    let cycle = Cycle::of(t, link.delays());
    if cycle.fits() {
        tracing::info!(port = %t.port.display(), "motor bus: {}", cycle.describe());
    } else {
        tracing::warn!(
            port = %t.port.display(),
            "motor bus: {}: the motors' replies do not all fit in a period, so their data is a \
             period late or more and, on a real bus, the next cycle's goals collide with them; \
             set the motors' Return Delay Time to {RETURN_DELAY} or lower tendon.rate_hz",
            cycle.describe()
        );
    }
}

/// Refuses a bus whose line cannot carry the goals and every motor's reply within a period
/// of `tendon.rate_hz` even when they answer at once (Return Delay Time [`RETURN_DELAY`]): the
/// config asks for more than the line carries. A config error (exit 78): starting the driver
/// again cannot help. The host's and the adapter's share is an estimate: a cycle that fits
/// the line but not with it is warned of once the motors answered ([`said_ready`]).
fn check_rate(t: &TendonConfig) -> anyhow::Result<()> {
    let cycle = Cycle::of(t, &vec![RETURN_DELAY; t.ids.len()]);
    if cycle.line_fits() {
        return Ok(());
    }
    Err(softarm_config::ConfigError {
        origin: "[tendon]".into(),
        line: None,
        message: format!(
            "rate_hz: the motor bus {} cannot carry tendon.rate_hz: {}. Lower tendon.rate_hz to \
             {:.0} Hz or less, raise tendon.baud (and the motors' Baud Rate), or move some \
             motors to a [[tendon.extra_bus]]",
            t.port.display(),
            cycle.describe(),
            cycle.line_max_rate_hz().floor()
        ),
    }
    .into())
}

impl<'a> Driver<'a> {
    /// The driver of bus `bus`, whose motors map by `mapping` (this bus's, [`Mapping::select`]).
    fn open(config: &Config, bus: &'a BusConfig, mapping: Mapping) -> anyhow::Result<Self> {
        let t = &bus.tendon;
        let ms = |v: f64| (v * 1e6) as u64;
        let timeouts = Timeouts {
            hold_after_ns: ms(t.hold_after_ms),
            off_after_ns: ms(t.torque_off_after_ms),
        };
        check_rate(t)?;
        let mut counts = Counts::default();
        let mut link = Link::open(t)?;
        // The first exchange of the survey before the loop, as long as a motor gets to answer:
        // on a clean bus every motor has answered when it ends. A bus that has not (a stall,
        // noise, a motor missing) is asked again in the loop, which hears the e-stop meanwhile.
        match link.survey(t, &mut counts, START_SURVEY_WAIT) {
            Ok(true) => said_ready(t, &link),
            Ok(false) | Err(Fault::Bus(_)) => {}
            Err(Fault::Port(m)) => anyhow::bail!(
                "asking the motors on {} for their settings: {m}",
                t.port.display()
            ),
        }
        let n = t.ids.len();
        let on = &bus.actuators;
        let limit = |p: &PerActuator| std::array::from_fn(|i| on.get(i).map_or(0.0, |&a| p.get(a)));
        Ok(Self {
            t,
            actuators: on,
            n,
            mapping,
            timeouts,
            supervisor: Supervisor::new(timeouts),
            limits: (
                limit(&config.controller.actuator_min),
                limit(&config.controller.actuator_max),
            ),
            link: Some(link),
            reading: Reading::new(n),
            reopen_backoff: Backoff::new(10_000_000, 1_000_000_000),
            read_backoff: Backoff::new(10_000_000, 200_000_000),
            late_heard: 0,
            counts,
            closed_line: (0, 0),
            reopens: 0,
            health: Health::new(t.rate_hz),
            stale_after_ns: ms(config.controller.tracker_timeout_ms),
            clamped: 0,
            refused_engage: 0,
            reengaged: 0,
            stranded: 0,
            write_faults: 0,
            goal_writes: 0,
            setpoint_cycles: 0,
            seq: 0,
            cycle: 0,
            reported: DriverState::Off,
            reported_errors: [0; MAX_ACTUATORS],
            status_every: ((t.rate_hz / 5.0).round() as u64).max(1),
            device_checked_ns: now_ns(),
        })
    }

    /// One cycle as named steps: the safety decision, the port kept (reopened only when it is
    /// gone), the motors surveyed until every one has answered, the last read's replies
    /// taken, the action written, the next read sent, the state reported.
    /// `fault`: a motor reports a hardware error, on this bus or another.
    fn cycle(&mut self, now: u64, poll: &Poll, fault: bool) {
        self.cycle += 1;
        self.setpoint_cycles += u64::from(poll.setpoint.is_some());
        let action = self.supervisor.update(now, poll, fault);
        self.keep_port(now);
        self.survey();
        self.collect(now);
        self.act(action);
        self.ask(now);
        self.report(now);
    }

    /// A motor of this bus reports a hardware error.
    fn fault(&self) -> bool {
        self.reading.hardware_error.iter().any(|&e| e != 0)
    }

    /// Reopens a closed port once the back-off allows; closes one whose device is gone or
    /// replaced (the old descriptor would never hear from the new adapter).
    fn keep_port(&mut self, now: u64) {
        match &self.link {
            None if self.reopen_backoff.ready(now) => match Link::open(self.t) {
                Ok(l) => {
                    tracing::warn!(reopens = self.reopens, "motor bus open again");
                    self.link = Some(l);
                    self.reopen_backoff.succeeded();
                }
                Err(e) => {
                    self.reopen_backoff.failed(now);
                    tracing::error!(reopens = self.reopens, "{e:#}");
                }
            },
            Some(l)
                if now.saturating_sub(l.last_reply_ns) > CHECK_DEVICE_AFTER_NS
                    && now.saturating_sub(self.device_checked_ns) > CHECK_DEVICE_AFTER_NS =>
            {
                self.device_checked_ns = now;
                if l.wire.device_changed() {
                    self.close("the device behind tendon.port is gone or was replaced");
                }
            }
            _ => {}
        }
    }

    /// A link still surveying asks the motors that have not answered and takes their
    /// settings, waiting up to [`SURVEY_WAIT`] of a period; it is ready once every motor has
    /// answered and is configured. However long the bus stalls, the motors that answer late
    /// are taken, and none is engaged before then.
    fn survey(&mut self) {
        let Some(l) = self.link.as_mut().filter(|l| !l.ready()) else {
            return;
        };
        let wait = Duration::from_secs_f64(SURVEY_WAIT / self.t.rate_hz);
        match l.survey(self.t, &mut self.counts, wait) {
            Ok(true) => said_ready(self.t, l),
            Ok(false) => {}
            Err(Fault::Port(m)) => self.close(&format!("surveying: {m}")),
            Err(f @ Fault::Bus(_)) => {
                self.write_faults += 1;
                if self.write_faults.is_power_of_two() {
                    tracing::error!(write_faults = self.write_faults, "surveying: {f}");
                }
            }
        }
    }

    /// Closes the port, to be reopened; its counts are kept.
    fn close(&mut self, why: &str) {
        if let Some(l) = self.link.take() {
            use std::sync::atomic::Ordering::Relaxed;
            self.closed_line.0 += l.wire.counts.crc_errors.load(Relaxed);
            self.closed_line.1 += l.wire.counts.garbage_bytes.load(Relaxed);
            self.reopens += 1;
            tracing::error!(
                reopens = self.reopens,
                "motor bus: {why}; reopening the port"
            );
        }
    }

    /// The replies to the read sent last cycle, into the reading; the read closed (what has
    /// not come is lost) and the loss rate updated.
    fn collect(&mut self, now: u64) {
        let Some(l) = self.link.as_mut().filter(|l| l.ready()) else {
            return;
        };
        let late = self.counts.late;
        if let Err(f) = l.take_replies(&mut self.reading, &mut self.counts, Duration::ZERO) {
            self.close(&f.to_string());
            return;
        }
        self.health.found(self.counts.late - late);
        let closed = l.close_read(&mut self.counts);
        if let Some(c) = closed {
            self.health.add(c.missing, c.asked);
        }
        let heard_late = self.counts.late > self.late_heard;
        self.late_heard = self.counts.late;
        match closed {
            Some(c) if silent(&c, self.n, heard_late) => self.read_backoff.failed(now),
            Some(_) => self.read_backoff.succeeded(),
            None if heard_late => self.read_backoff.succeeded(),
            None => {}
        }
    }

    /// The action on the bus, every cycle: nothing on the read side holds it back. While the
    /// motors are being surveyed only torque-off goes out: nothing is driven before every
    /// motor has answered.
    fn act(&mut self, action: Action) {
        let surveying = self.link.as_ref().is_some_and(|l| !l.ready());
        let action = match action {
            Action::Follow(_) if surveying => Action::Hold,
            a => a,
        };
        let (goals, near) = match action {
            Action::Follow(a) => self.goals(&a),
            _ => ([0; MAX_ACTUATORS], [false; MAX_ACTUATORS]),
        };
        let Some(l) = self.link.as_mut() else {
            return;
        };
        let torque = l.torque;
        let engage = near[..self.n].iter().all(|&n| n);
        match l.apply(
            action,
            &goals,
            &near,
            &self.reading,
            self.t.profile_velocity,
        ) {
            Ok(lost) => {
                if matches!(action, Action::Follow(_)) && (torque || engage) {
                    self.goal_writes += 1;
                }
                if matches!(action, Action::Follow(_)) {
                    self.say_lost_torque(lost, &near);
                }
            }
            Err(Fault::Port(m)) => self.close(&format!("writing: {m}")),
            Err(f @ Fault::Bus(_)) => {
                // The line is backed up: this cycle's read would only add to it.
                self.read_backoff.failed(now_ns());
                self.write_faults += 1;
                if self.write_faults.is_power_of_two() {
                    tracing::error!(write_faults = self.write_faults, "{f}");
                }
            }
        }
    }

    /// Says what following found of the torque: `lost` motors turned on again, and those
    /// found off too far from their goal to be (`near` says which are close enough).
    fn say_lost_torque(&mut self, lost: usize, near: &[bool; MAX_ACTUATORS]) {
        let Some(l) = self.link.as_ref() else {
            return;
        };
        let stranded = (0..self.n)
            .filter(|&i| !near[i] && l.lost_torque(i, &self.reading))
            .count();
        if stranded > 0 {
            self.stranded += 1;
            if self.stranded.is_power_of_two() {
                tracing::error!(
                    stranded = self.stranded,
                    "{stranded} motor(s) found with the torque off while following, farther \
                     than tendon.max_engage_step from their goal: they stay off until the \
                     setpoint comes to where they stand"
                );
            }
        }
        if lost > 0 {
            self.reengaged += lost as u64;
            tracing::error!(
                reengaged = self.reengaged,
                "{lost} motor(s) found with the torque off while following (a brown-out \
                 restarts a motor so, or the torque-on write was lost): torque on again where \
                 they stand"
            );
        }
    }

    /// Sends this cycle's read, when the read back-off allows: the status when due or after
    /// an alert bit, present current and position every [`DATA_EVERY`] cycles, else the
    /// position alone. The goals are out already, so the rest of the cycle is the reads': the
    /// motors whose position did not come in the time the bus needs for the replies are asked
    /// once more ([`Driver::ask_again`]), so a noisy line costs a motor's data a cycle only when
    /// both replies are lost.
    fn ask(&mut self, now: u64) {
        let Some(l) = self.link.as_mut().filter(|l| l.ready()) else {
            return;
        };
        if !self.read_backoff.ready(now) {
            return;
        }
        let ask = if l.alert.due || self.cycle.is_multiple_of(self.status_every) {
            l.alert.due = false;
            Ask::Status
        } else if self.cycle.is_multiple_of(DATA_EVERY) {
            Ask::Data
        } else {
            Ask::Position
        };
        let mut sent = l.ask(ask, self.cycle, None);
        if sent.is_ok() && ask != Ask::Status {
            sent = self.ask_again(now);
        }
        if let Err(f) = sent {
            match f {
                Fault::Port(m) => self.close(&format!("writing: {m}")),
                Fault::Bus(_) => self.write_faults += 1,
            }
        }
    }

    /// Waits for the replies of the read just sent until the bus has had the time for them
    /// (the line's, after what went out before the read, and the host's and the adapter's:
    /// [`timing::LATENCY_MARGIN`], or more while replies come later, [`timing::Lateness`]), then asks the
    /// motors that did not answer once more, if their replies are on the line before the next
    /// cycle's start (`now` is this cycle's): taken then. Asking sooner would be answered by the
    /// replies still coming, and on a half-duplex bus collide with them; asking when the
    /// replies cannot be in by the next cycle would collide with its goals.
    fn ask_again(&mut self, now: u64) -> Result<(), Fault> {
        let Some(l) = self.link.as_mut() else {
            return Ok(());
        };
        let margin = l.lateness.margin_ns();
        let next_cycle = now + (1e9 / self.t.rate_hz) as u64;
        let Some(due) = l.read_due_ns().map(|d| d + margin) else {
            return Ok(());
        };
        if due >= next_cycle {
            return Ok(());
        }
        let deadline =
            std::time::Instant::now() + Duration::from_nanos(due.saturating_sub(now_ns()));
        loop {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            let late = self.counts.late;
            let done = l.take_replies(&mut self.reading, &mut self.counts, left)?;
            self.health.found(self.counts.late - late);
            if done {
                return Ok(());
            }
            if left.is_zero() {
                break;
            }
        }
        let Some(c) = l.close_read(&mut self.counts) else {
            return Ok(());
        };
        self.health.add(c.missing, c.asked);
        match c.missing_motors {
            // On the line before the next goals go out; the host takes them at the next collect.
            Some(missing) if now_ns() + l.read_ns(Ask::Position, &missing) < next_cycle => {
                l.ask(Ask::Position, self.cycle, Some(missing))
            }
            _ => Ok(()),
        }
    }

    /// The state as reported: FOLLOWING only while the motor data is fresh and the bus keeps
    /// its replies, else DEGRADED; transitions and hardware errors logged.
    fn report(&mut self, now: u64) {
        let mut state = self.supervisor.state();
        let age = self.reading.stamp_ns().map(|s| now.saturating_sub(s));
        let bus = self.health.bus(age, self.stale_after_ns);
        let surveying = self.link.as_ref().is_some_and(|l| !l.ready());
        if state == DriverState::Following && surveying {
            // What `act` does then: nothing driven until every motor has answered.
            state = DriverState::Holding;
        } else if state == DriverState::Following && bus != Bus::Good {
            state = DriverState::Degraded;
        }
        // A survey names the motors it misses itself.
        if !surveying {
            self.health.log(now, bus, age, &self.totals());
        }
        // FOLLOWING <-> DEGRADED is the bus's to say (`Health::log`, rate-limited).
        let bus_only = [self.reported, state]
            .iter()
            .all(|s| matches!(s, DriverState::Following | DriverState::Degraded));
        if state != self.reported && bus_only {
            self.reported = state;
        }
        if state != self.reported {
            if state == DriverState::Following {
                tracing::info!(
                    from = self.reported.name(),
                    to = state.name(),
                    "driver state"
                );
            } else {
                tracing::warn!(
                    from = self.reported.name(),
                    to = state.name(),
                    "driver state"
                );
            }
            self.reported = state;
        }
        self.report_hardware_errors();
    }

    /// The goal ticks of setpoint `a`, clamped, and per motor whether its torque may come on
    /// for them: its position is known and within `tendon.max_engage_step` of its goal.
    /// `a` has one value per actuator of the arm ([`Commands`] refused every other count);
    /// this bus's motors take theirs.
    fn goals(&mut self, a: &Actuators) -> ([i32; MAX_ACTUATORS], [bool; MAX_ACTUATORS]) {
        let (t, mapping, (lo, hi), n) = (self.t, &self.mapping, self.limits, self.n);
        let mut goals = [0i32; MAX_ACTUATORS];
        let mut wild = false;
        for i in 0..n {
            let want = a[self.actuators[i]];
            let v = want.clamp(lo[i], hi[i]);
            let g = mapping.ticks(i, v).clamp(t.min_ticks[i], t.max_ticks[i]);
            wild |= v != want || mapping.ticks(i, v) != g;
            goals[i] = g;
        }
        if wild {
            self.clamped += 1;
            if self.clamped.is_power_of_two() {
                tracing::warn!(clamped = self.clamped, setpoint = ?a, "setpoint beyond the limits, clamped");
            }
        }
        // Torque comes on only for a setpoint where the motors already are.
        let reading = &self.reading;
        let near: [bool; MAX_ACTUATORS] = std::array::from_fn(|i| {
            i < n
                && reading.asked_ns[i].is_some()
                && (mapping.actuation(i, goals[i]) - mapping.actuation(i, reading.ticks[i])).abs()
                    <= t.max_engage_step
        });
        let known = reading.stamp_ns().is_some();
        let off = self.link.as_ref().is_some_and(|l| !l.torque);
        if off && known && near[..n].contains(&false) {
            self.refused_engage += 1;
            if self.refused_engage.is_power_of_two() {
                tracing::error!(
                    refused_engage = self.refused_engage,
                    setpoint = ?a,
                    "first setpoint is farther than tendon.max_engage_step from where \
                     the motors stand: the torque stays off"
                );
            }
        }
        (goals, near)
    }

    fn report_hardware_errors(&mut self) {
        for (i, &e) in self.reading.hardware_error[..self.n].iter().enumerate() {
            if e != self.reported_errors[i] {
                self.reported_errors[i] = e;
                tracing::error!(
                    id = self.t.ids[i],
                    actuator = self.actuators[i] + 1,
                    hardware_error = format!("{e:#04x}"),
                    "motor reports a hardware error: turned off, the others hold; restart the \
                     driver once the cause is fixed"
                );
            }
        }
    }

    /// The bus counts since the start, over every port opened.
    fn totals(&self) -> Totals {
        use std::sync::atomic::Ordering::Relaxed;
        let (mut crc, mut garbage) = self.closed_line;
        if let Some(l) = &self.link {
            crc += l.wire.counts.crc_errors.load(Relaxed);
            garbage += l.wire.counts.garbage_bytes.load(Relaxed);
        }
        Totals {
            dropped: self.counts.dropped(crc),
            crc_errors: crc,
            garbage_bytes: garbage,
            timeouts: self.counts.timeouts,
            reopens: self.reopens,
        }
    }

    /// What to publish, stamped when the oldest motor's newest data was asked for: data that
    /// is old looks old to the controller. `None` before every motor answered once.
    fn motor_state(&mut self) -> Option<MotorState> {
        let stamp_ns = self.reading.stamp_ns()?;
        self.seq += 1;
        let c = self.totals();
        Some(MotorState {
            seq: self.seq,
            stamp_ns,
            actuation: self.actuation(),
            current_a: Actuators::new(&self.reading.current_a[..self.n]),
            faults: c.dropped + c.crc_errors + c.reopens,
            dropped: c.dropped,
            crc_errors: c.crc_errors,
            garbage_bytes: c.garbage_bytes,
            timeouts: c.timeouts,
            reopens: c.reopens,
            setpoint_cycles: self.setpoint_cycles,
            goal_writes: self.goal_writes,
            state: self.reported as u32,
            loss_permille: self.health.loss_permille(),
            hardware_error: std::array::from_fn(|i| {
                self.reading.hardware_error.get(i).copied().unwrap_or(0)
            }),
            age_cycles: self.reading.age_cycles(self.cycle).min(u64::from(u16::MAX)) as u16,
        })
    }

    /// The actuation the motors stand at, one per motor.
    fn actuation(&self) -> Actuators {
        let mut a = Actuators::filled(self.n, 0.0);
        for (i, v) in a.iter_mut().enumerate() {
            *v = self.mapping.actuation(i, self.reading.ticks[i]);
        }
        a
    }

    /// Leaving: the arm must not stay driven by a process that is gone.
    fn leave(&mut self) {
        if let Some(l) = self.link.as_mut()
            && let Err(e) = l.torque_off()
        {
            tracing::error!("could not turn the torque off on the way out: {e}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn closed(asked: usize, answered: usize) -> link::Closed {
        link::Closed {
            asked,
            missing_motors: None,
            answered,
            refused: 0,
            missing: asked - answered,
        }
    }

    #[test]
    fn only_a_bus_that_answers_nothing_at_all_backs_the_reads_off() {
        assert!(silent(&closed(6, 0), 6, false));
        // Late replies: the bus is slow (a loaded machine), its reads must go on.
        assert!(!silent(&closed(6, 0), 6, true));
        assert!(!silent(&closed(6, 1), 6, false));
        // One motor asked again.
        assert!(!silent(&closed(1, 0), 6, false));
    }
}
