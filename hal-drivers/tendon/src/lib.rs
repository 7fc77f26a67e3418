//! The `tendon` driver process: the arm's six tendon motors on a Dynamixel Protocol 2.0 bus
//! (X-series), through the `dynamixel2` crate. Consumes `setpoint` and `estop`, publishes
//! `motor_state`, and is safe on its own: torque comes on only with a valid setpoint close to
//! where the motors stand, an e-stop turns it off at once, setpoints that stop arriving lead to
//! hold and then torque off ([`softarm_driver::Supervisor`]), a motor reporting a hardware
//! error is turned off and gets no other command. Torque-off is written every cycle while it
//! is wanted (a sync write has no reply, so a lost one is simply sent again). Serial faults
//! are counted, reported and retried with back-off; a panic of the protocol code on bytes from
//! the wire is caught and counted like any other fault.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, bail};
use dynamixel2::instructions::SyncWriteData;
use dynamixel2::serial2::SerialPort;
use dynamixel2::{Bus, ReadError, TransferError, WriteError};

use softarm_config::Config;
use softarm_config::hardware::{Mapping, TendonConfig};
use softarm_driver::{Action, Commands, Supervisor, Timeouts};
use softarm_ipc::{ACTUATORS, Actuation, DriverState, MotorState, Namespace, Node};
use softarm_runtime::clock::{Backoff, Ticker};
use softarm_runtime::now_ns;

pub mod table;

/// A failed exchange on the bus.
#[derive(Debug)]
enum Fault {
    /// The motors did not answer in time, or answered garbage: retry.
    Bus(String),
    /// The port itself failed (unplugged adapter): reopen it.
    Port(String),
}

impl std::fmt::Display for Fault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Fault::Bus(m) => write!(f, "bus: {m}"),
            Fault::Port(m) => write!(f, "port: {m}"),
        }
    }
}

fn io_fault(e: &std::io::Error) -> Fault {
    use std::io::ErrorKind::*;
    match e.kind() {
        TimedOut | WouldBlock | Interrupted => Fault::Bus(format!("no answer ({e})")),
        _ => Fault::Port(e.to_string()),
    }
}

impl From<ReadError> for Fault {
    fn from(e: ReadError) -> Self {
        match &e {
            ReadError::Io(io) => io_fault(io),
            _ => Fault::Bus(e.to_string()),
        }
    }
}

impl From<WriteError> for Fault {
    fn from(e: WriteError) -> Self {
        match &e {
            WriteError::Write(io) | WriteError::DiscardBuffer(io) => Fault::Port(io.to_string()),
            _ => Fault::Bus(e.to_string()),
        }
    }
}

impl From<TransferError> for Fault {
    fn from(e: TransferError) -> Self {
        match e {
            TransferError::WriteError(w) => w.into(),
            TransferError::ReadError(r) => r.into(),
        }
    }
}

/// Runs `f` on the bus; a panic inside the protocol code (bytes from the wire it did not
/// expect) is a fault of the exchange, not of the process.
fn guarded<T>(f: impl FnOnce() -> Result<T, Fault>) -> Result<T, Fault> {
    catch_unwind(AssertUnwindSafe(f))
        .unwrap_or_else(|_| Err(Fault::Bus("the protocol code panicked on a reply".into())))
}

/// What the motors last reported.
#[derive(Debug, Clone, Copy, Default)]
struct Reading {
    ticks: [i32; ACTUATORS],
    current_a: [f64; ACTUATORS],
    hardware_error: [u8; ACTUATORS],
    /// When every motor last answered (ns); `None` before the first full reading.
    stamp_ns: Option<u64>,
}

impl Reading {
    fn faulted(&self, i: usize) -> bool {
        self.hardware_error[i] != 0
    }
}

/// Sync-write data for the motors `value` gives a value for, on the stack: the first `n`.
fn for_motors<T: Copy + Default>(
    ids: &[u8; ACTUATORS],
    value: impl Fn(usize) -> Option<T>,
) -> ([SyncWriteData<T>; ACTUATORS], usize) {
    let mut data = std::array::from_fn(|_| SyncWriteData {
        motor_id: 0,
        data: T::default(),
    });
    let mut n = 0;
    for i in 0..ACTUATORS {
        if let Some(v) = value(i) {
            data[n] = SyncWriteData {
                motor_id: ids[i],
                data: v,
            };
            n += 1;
        }
    }
    (data, n)
}

/// An open bus and what the driver knows of its motors.
struct Link {
    bus: Bus<Vec<u8>, Vec<u8>>,
    ids: [u8; ACTUATORS],
    /// The torque may be on somewhere: the driver turned it on, or found it on, or could not
    /// ask a motor. While set, an `Off` writes torque-off.
    torque: bool,
}

impl Link {
    /// Opens the port, pings every motor and writes mode and limits where they differ. At start
    /// (`strict`) a motor that does not answer is an error naming it; on a reopen the link is
    /// kept with what answers, so torque-off can always go out.
    fn open(t: &TendonConfig, strict: bool) -> anyhow::Result<Self> {
        let port = t.port.display();
        let mut serial = SerialPort::open(&t.port, t.baud).with_context(|| {
            format!(
                "cannot open the motor bus {port} (tendon.port); is the adapter plugged in and \
                 are you in the `dialout` group?"
            )
        })?;
        // A write that cannot go out must not stall the loop (serial2's default is 3 s).
        serial.set_write_timeout(std::time::Duration::from_millis(50))?;
        let bus = Bus::new(serial).map_err(|e| anyhow::anyhow!("{e}"))?;
        let mut link = Self {
            bus,
            ids: t.ids,
            torque: false,
        };
        let mut missing = Vec::new();
        for i in 0..ACTUATORS {
            let id = t.ids[i];
            // Twice: one lost reply is not a missing motor.
            let answered = (0..2).any(|_| guarded(|| Ok(link.bus.ping(id)?)).is_ok());
            if !answered {
                missing.push(format!("id {id} (actuator {})", i + 1));
                // Unknown: assume it is driven, so that an `Off` reaches it.
                link.torque = true;
                continue;
            }
            let on = link.configure(t, i).with_context(|| {
                format!("configuring motor id {id} (actuator {}) on {port}", i + 1)
            });
            match on {
                Ok(on) => link.torque |= on,
                Err(e) if strict => return Err(e),
                Err(e) => {
                    tracing::error!("{e:#}");
                    link.torque = true;
                }
            }
        }
        if !missing.is_empty() {
            let message = format!(
                "no answer on {port} at {} baud from motor {}: check the motors' power and \
                 wiring, and tendon.ids and tendon.baud against the motors' settings",
                t.baud,
                missing.join(", ")
            );
            if strict {
                bail!(message);
            }
            tracing::error!("{message}");
        }
        Ok(link)
    }

    /// Writes position control and the limits where they differ from the config (they live in
    /// EEPROM, which wears, and can be written only with the torque off), and the profile
    /// velocity (RAM). Returns whether the motor's torque is on: a driver restarted beside a
    /// running controller leaves a holding motor holding, so the arm does not drop.
    fn configure(&mut self, t: &TendonConfig, i: usize) -> anyhow::Result<bool> {
        use table::*;
        let id = self.ids[i];
        let b = &mut self.bus;
        let fail = anyhow::Error::msg;
        let limits = [
            (MAX_POSITION_LIMIT, t.max_ticks[i] as u32),
            (MIN_POSITION_LIMIT, t.min_ticks[i] as u32),
        ];
        let mode_ok =
            guarded(|| Ok(b.read_u8(id, OPERATING_MODE)?.data)).map_err(fail)? == POSITION_CONTROL;
        let mut limits_ok = [true; 2];
        for (ok, (address, value)) in limits_ok.iter_mut().zip(limits) {
            *ok = guarded(|| Ok(b.read_u32(id, address)?.data)).map_err(fail)? == value;
        }
        let on = if mode_ok && limits_ok == [true; 2] {
            guarded(|| Ok(b.read_u8(id, TORQUE_ENABLE)?.data)).map_err(fail)? != 0
        } else {
            tracing::info!(id, "writing operating mode and limits (torque off)");
            guarded(|| Ok(b.write_u8(id, TORQUE_ENABLE, 0)?)).map_err(fail)?;
            if !mode_ok {
                guarded(|| Ok(b.write_u8(id, OPERATING_MODE, POSITION_CONTROL)?)).map_err(fail)?;
            }
            for (ok, (address, value)) in limits_ok.into_iter().zip(limits) {
                if !ok {
                    guarded(|| Ok(b.write_u32(id, address, value)?)).map_err(fail)?;
                }
            }
            false
        };
        guarded(|| Ok(b.write_u32(id, PROFILE_VELOCITY, t.profile_velocity)?)).map_err(fail)?;
        Ok(on)
    }

    /// Torque off for every motor (no reply: sent again each cycle while it is wanted).
    fn torque_off(&mut self) -> Result<(), Fault> {
        let ids = self.ids;
        let (data, n) = for_motors(&ids, |_| Some(0u8));
        let bus = &mut self.bus;
        guarded(|| Ok(bus.sync_write_u8(table::TORQUE_ENABLE, &data[..n])?))?;
        self.torque = false;
        Ok(())
    }

    /// What the safety logic decided, on the bus. A motor with a hardware error gets torque-off
    /// every cycle and nothing else (its Shutdown setting may not have turned it off).
    fn apply(
        &mut self,
        action: Action,
        goals: &[i32; ACTUATORS],
        engage: bool,
        reading: &Reading,
    ) -> Result<(), Fault> {
        let ids = self.ids;
        let bus = &mut self.bus;
        if reading.hardware_error.iter().any(|&e| e != 0) {
            let (data, n) = for_motors(&ids, |i| reading.faulted(i).then_some(0u8));
            guarded(|| Ok(bus.sync_write_u8(table::TORQUE_ENABLE, &data[..n])?))?;
        }
        match action {
            Action::Off => self.torque_off(),
            Action::Hold => Ok(()),
            Action::Follow(_) if !self.torque && !engage => Ok(()),
            Action::Follow(_) => {
                // The goal first: the torque then holds where the controller wants, not
                // wherever the goal register was left.
                let (data, n) =
                    for_motors(&ids, |i| (!reading.faulted(i)).then_some(goals[i] as u32));
                guarded(|| Ok(bus.sync_write_u32(table::GOAL_POSITION, &data[..n])?))?;
                if !self.torque {
                    let (data, n) = for_motors(&ids, |i| (!reading.faulted(i)).then_some(1u8));
                    guarded(|| Ok(bus.sync_write_u8(table::TORQUE_ENABLE, &data[..n])?))?;
                    self.torque = true;
                }
                Ok(())
            }
        }
    }

    /// Present position (132..136) and present current (126..128) of every motor, in two
    /// sync reads, and, when `status` asks or a reply raises its alert bit, torque enable and
    /// hardware-error status in a third (64..71). Returns the number of answers missing.
    ///
    /// Not one read of 126..136: Present Velocity sits between, and a velocity of -1
    /// (`FF FF FF FF`) before a position byte `FD` is a byte run dynamixel2 0.9.1 does not
    /// unstuff, which cost a reading about every second on a moving arm.
    fn read(&mut self, reading: &mut Reading, status: bool) -> Result<usize, Fault> {
        let ids = self.ids;
        let bus = &mut self.bus;
        let mut alert = status;
        let mut missing = 0;
        let mut first_fault = None;
        for (address, len) in [(table::PRESENT_POSITION, 4u16), (table::PRESENT_CURRENT, 2)] {
            guarded(|| {
                bus.sync_read_cb(&ids, address, len, |r| match r {
                    Ok(r) => {
                        let Some(i) = ids.iter().position(|&id| id == r.motor_id) else {
                            missing += 1;
                            return;
                        };
                        let d = r.data;
                        if address == table::PRESENT_POSITION {
                            reading.ticks[i] = i32::from_le_bytes([d[0], d[1], d[2], d[3]]);
                        } else {
                            let current = i16::from_le_bytes([d[0], d[1]]);
                            reading.current_a[i] = f64::from(current) * table::CURRENT_UNIT_A;
                        }
                        alert |= r.alert;
                    }
                    Err(e) => {
                        // An answer with an error number still carries the motor's alert
                        // bit (tests/fuzz.rs found it dropped with the answer).
                        if let ReadError::MotorError(m) = &e {
                            alert |= m.alert();
                        }
                        missing += 1;
                        first_fault.get_or_insert(Fault::from(e));
                    }
                })?;
                Ok(())
            })?;
        }
        if alert {
            let mut on = false;
            guarded(|| {
                bus.sync_read_cb(&ids, table::TORQUE_ENABLE, 7, |r| match r {
                    Ok(r) => {
                        if let Some(i) = ids.iter().position(|&id| id == r.motor_id) {
                            on |= r.data[0] != 0;
                            // Sticky: cleared only by restarting the driver, once the cause
                            // is fixed.
                            reading.hardware_error[i] |= r.data[6];
                        }
                    }
                    Err(_) => missing += 1,
                })?;
                Ok(())
            })?;
            // A motor found on while the driver thinks all are off: the next `Off` resends.
            self.torque |= on;
        }
        match first_fault {
            Some(Fault::Port(m)) => Err(Fault::Port(m)),
            _ => Ok(missing),
        }
    }
}

/// The driver's bus exchange on a port of the caller's choosing, for the fuzz tests
/// (`tests/fuzz.rs`). Bytes from the wire become a `Reading` only through `dynamixel2`, which
/// reads from a serial port, and `Link::read`: this is the narrowest path there is. Not an API.
#[doc(hidden)]
pub mod fuzz {
    use super::*;

    /// What the motors last reported, as the driver holds it.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub struct Snapshot {
        pub ticks: [i32; ACTUATORS],
        pub current_a: [f64; ACTUATORS],
        pub hardware_error: [u8; ACTUATORS],
    }

    /// An open `Link` and the `Reading` its reads update.
    pub struct Probe {
        link: Link,
        reading: Reading,
    }

    impl Probe {
        /// Opens the bus as the driver does at start (every motor must answer).
        pub fn open(t: &TendonConfig) -> anyhow::Result<Self> {
            Ok(Self {
                link: Link::open(t, true)?,
                reading: Reading::default(),
            })
        }

        /// One `Link::read`: the number of answers missing, or the fault as the driver
        /// reports it.
        pub fn read(&mut self, status: bool) -> Result<usize, String> {
            self.link
                .read(&mut self.reading, status)
                .map_err(|f| f.to_string())
        }

        pub fn reading(&self) -> Snapshot {
            Snapshot {
                ticks: self.reading.ticks,
                current_a: self.reading.current_a,
                hardware_error: self.reading.hardware_error,
            }
        }
    }
}

/// A bus silent this long is reopened: an adapter unplugged and plugged in again is a new
/// device behind the same name, and the old descriptor never hears from it.
const REOPEN_AFTER_NS: u64 = 1_000_000_000;

/// Runs the tendon driver until `stop` is set.
pub fn run(config: &Config, namespace: Namespace, stop: &AtomicBool) -> anyhow::Result<()> {
    let t = config
        .tendon
        .as_ref()
        .context("the config has no [tendon] section")?;
    let node = Node::open(namespace, "tendon")?;
    let mut commands = Commands::open(&node, &config.estop_latch())?;
    let publisher = node.publisher(&node.motor_state()?)?;
    let mut driver = Driver::open(config, t)?;
    let mut ticker = Ticker::new(t.rate_hz);
    while !stop.load(Ordering::Relaxed) {
        ticker.wait();
        let now = now_ns();
        let poll = commands.poll(now, driver.timeouts.hold_after_ns);
        driver.cycle(now, &poll);
        if let Some(state) = driver.motor_state() {
            let _ = publisher.send_copy(state);
        }
    }
    driver.leave();
    tracing::info!(
        faults = driver.faults,
        clamped = driver.clamped,
        refused_engage = driver.refused_engage,
        refused = commands.refused(),
        overruns = ticker.overruns(),
        "tendon driver stopped"
    );
    Ok(())
}

/// The driver's state between cycles: the bus, what the motors last said, the safety state
/// machine and the counts it reports.
struct Driver<'a> {
    t: &'a TendonConfig,
    mapping: Mapping,
    timeouts: Timeouts,
    supervisor: Supervisor,
    /// Setpoints are clamped to what the controller may send, then to the motors' limits.
    limits: (Actuation, Actuation),
    /// `None` while the port is closed (being reopened).
    link: Option<Link>,
    reading: Reading,
    /// Retries: 10 ms after a failure, doubling per failure, at most 1 s apart.
    backoff: Backoff,
    last_answer: u64,
    faults: u64,
    clamped: u64,
    refused_engage: u64,
    seq: u64,
    cycle: u64,
    last_state: DriverState,
    reported_errors: [u8; ACTUATORS],
    /// Torque and hardware-error status are read every this many cycles (about 5 Hz), and
    /// whenever a reply raises its alert bit.
    status_every: u64,
}

impl<'a> Driver<'a> {
    fn open(config: &Config, t: &'a TendonConfig) -> anyhow::Result<Self> {
        let ms = |v: f64| (v * 1e6) as u64;
        let timeouts = Timeouts {
            hold_after_ns: ms(t.hold_after_ms),
            off_after_ns: ms(t.torque_off_after_ms),
        };
        // At start a missing motor is an error the user must fix; later the driver keeps trying.
        let link = Link::open(t, true)?;
        tracing::info!(
            port = %t.port.display(),
            baud = t.baud,
            ids = ?t.ids,
            "motors answered; the torque comes on with the first setpoint"
        );
        Ok(Self {
            t,
            mapping: Mapping::new(t, &config.arm),
            timeouts,
            supervisor: Supervisor::new(timeouts),
            limits: (
                config.controller.actuator_min,
                config.controller.actuator_max,
            ),
            link: Some(link),
            reading: Reading::default(),
            backoff: Backoff::new(10_000_000, 1_000_000_000),
            last_answer: now_ns(),
            faults: 0,
            clamped: 0,
            refused_engage: 0,
            seq: 0,
            cycle: 0,
            last_state: DriverState::Off,
            reported_errors: [0; ACTUATORS],
            status_every: ((t.rate_hz / 5.0).round() as u64).max(1),
        })
    }

    /// One cycle: the safety decision, the port reopened if due, the action and a reading on
    /// the bus, hardware errors reported.
    fn cycle(&mut self, now: u64, poll: &softarm_driver::Poll) {
        self.cycle += 1;
        let fault = self.reading.hardware_error.iter().any(|&e| e != 0);
        let action = self.supervisor.update(now, poll, fault);
        self.log_state();
        self.reopen(now);
        let (goals, engage) = match action {
            Action::Follow(a) => self.goals(&a),
            _ => ([0; ACTUATORS], false),
        };
        // Torque-off goes out at once, back-off or not.
        let urgent = matches!(action, Action::Off) || fault;
        self.exchange(now, action, &goals, engage, urgent);
        self.report_hardware_errors();
    }

    fn log_state(&mut self) {
        let state = self.supervisor.state();
        if state != self.last_state {
            if state == DriverState::Following {
                tracing::info!(
                    from = self.last_state.name(),
                    to = state.name(),
                    "driver state"
                );
            } else {
                tracing::warn!(
                    from = self.last_state.name(),
                    to = state.name(),
                    "driver state"
                );
            }
            self.last_state = state;
        }
    }

    /// Opens the port again once the back-off allows, if it is closed.
    fn reopen(&mut self, now: u64) {
        if self.link.is_some() || !self.backoff.ready(now) {
            return;
        }
        match Link::open(self.t, false) {
            Ok(l) => {
                tracing::warn!("motor bus open again");
                self.link = Some(l);
                self.backoff.succeeded();
                self.last_answer = now;
            }
            Err(e) => {
                self.faults += 1;
                self.backoff.failed(now);
                tracing::error!(faults = self.faults, "{e:#}");
            }
        }
    }

    /// The goal ticks of setpoint `a`, clamped, and whether the torque may come on for them.
    fn goals(&mut self, a: &Actuation) -> ([i32; ACTUATORS], bool) {
        let (t, mapping, (lo, hi)) = (self.t, &self.mapping, self.limits);
        let mut goals = [0i32; ACTUATORS];
        let mut wild = false;
        for i in 0..ACTUATORS {
            let v = a[i].clamp(lo[i], hi[i]);
            let g = mapping.ticks(i, v).clamp(t.min_ticks[i], t.max_ticks[i]);
            wild |= v != a[i] || mapping.ticks(i, v) != g;
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
        let known = reading.stamp_ns.is_some();
        let engage = known
            && (0..ACTUATORS).all(|i| {
                (mapping.actuation(i, goals[i]) - mapping.actuation(i, reading.ticks[i])).abs()
                    <= t.max_engage_step
            });
        let off = self.link.as_ref().is_some_and(|l| !l.torque);
        if off && known && !engage {
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
        (goals, engage)
    }

    /// The action and a reading on the bus, when the back-off allows or it is `urgent`; faults
    /// counted, the port closed on a port fault or a bus silent for [`REOPEN_AFTER_NS`].
    fn exchange(
        &mut self,
        now: u64,
        action: Action,
        goals: &[i32; ACTUATORS],
        engage: bool,
        urgent: bool,
    ) {
        let status = self.cycle.is_multiple_of(self.status_every);
        let Some(l) = self.link.as_mut() else {
            return;
        };
        if !(self.backoff.ready(now) || urgent) {
            return;
        }
        let reading = &mut self.reading;
        let result = l
            .apply(action, goals, engage, reading)
            .and_then(|()| l.read(reading, status));
        match result {
            Ok(0) => {
                reading.stamp_ns = Some(now_ns());
                self.backoff.succeeded();
                self.last_answer = now;
            }
            Ok(missing) => {
                self.faults += missing as u64;
                self.backoff.failed(now);
                if self.faults.is_power_of_two() {
                    tracing::error!(
                        faults = self.faults,
                        missing,
                        "motors did not answer; retrying"
                    );
                }
            }
            Err(f) => {
                self.faults += 1;
                self.backoff.failed(now);
                if self.faults.is_power_of_two() || matches!(f, Fault::Port(_)) {
                    tracing::error!(faults = self.faults, "{f}; retrying");
                }
                if matches!(f, Fault::Port(_)) {
                    self.link = None;
                }
            }
        }
        if self.link.is_some() && now.saturating_sub(self.last_answer) > REOPEN_AFTER_NS {
            tracing::error!(
                faults = self.faults,
                "no answer from the motors for 1 s: reopening the port"
            );
            self.link = None;
            self.backoff.succeeded();
            self.last_answer = now;
        }
    }

    fn report_hardware_errors(&mut self) {
        for (i, &e) in self.reading.hardware_error.iter().enumerate() {
            if e != self.reported_errors[i] {
                self.reported_errors[i] = e;
                tracing::error!(
                    id = self.t.ids[i],
                    actuator = i + 1,
                    hardware_error = format!("{e:#04x}"),
                    "motor reports a hardware error: turned off, the others hold; restart the \
                     driver once the cause is fixed"
                );
            }
        }
    }

    /// What to publish, stamped when the motors last answered: data that is old looks old to
    /// the controller. `None` before the first full reading.
    fn motor_state(&mut self) -> Option<MotorState> {
        let stamp_ns = self.reading.stamp_ns?;
        self.seq += 1;
        Some(MotorState {
            seq: self.seq,
            stamp_ns,
            actuation: std::array::from_fn(|i| self.mapping.actuation(i, self.reading.ticks[i])),
            current_a: self.reading.current_a,
            faults: self.faults,
            state: self.supervisor.state() as u32,
            hardware_error: self.reading.hardware_error,
            ..MotorState::default()
        })
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
