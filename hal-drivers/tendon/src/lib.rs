//! The `tendon` driver process: the arm's six tendon motors on a Dynamixel Protocol 2.0 bus
//! (X-series), through the `dynamixel2` crate. Consumes `setpoint` and `estop`, publishes
//! `motor_state`, and is safe on its own: torque comes on only with a valid setpoint, an e-stop
//! turns it off at once, setpoints that stop arriving lead to hold and then torque off
//! ([`softarm_driver::Supervisor`]), a motor reporting a hardware error gets no more commands.
//! Serial faults are counted, reported and retried with back-off; a panic of the protocol code
//! on bytes from the wire is caught and counted like any other fault.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, bail};
use dynamixel2::instructions::SyncWriteData;
use dynamixel2::{Bus, ReadError, TransferError, WriteError};

use softarm_driver::{Action, Commands, Supervisor, Timeouts};
use softarm_ipc::clock::Ticker;
use softarm_ipc::{ACTUATORS, DriverState, MotorState, Namespace, Node, now_ns};
use softarm_model::config::Config;
use softarm_model::hardware::{Mapping, TendonConfig};

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

/// Retries with back-off: 10 ms, doubling per failure, at most 1 s apart.
#[derive(Debug, Default)]
struct Backoff {
    failures: u32,
    next_ns: u64,
}

impl Backoff {
    fn ready(&self, now_ns: u64) -> bool {
        now_ns >= self.next_ns
    }

    fn failed(&mut self, now_ns: u64) {
        let wait_ns = (10_000_000u64 << self.failures.min(7)).min(1_000_000_000);
        self.failures += 1;
        self.next_ns = now_ns + wait_ns;
    }

    fn succeeded(&mut self) {
        self.failures = 0;
        self.next_ns = 0;
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

/// An open bus whose motors answered and are configured.
struct Link {
    bus: Bus<Vec<u8>, Vec<u8>>,
    ids: [u8; ACTUATORS],
    /// Whether the driver has turned the torque on (as far as it knows).
    torque: bool,
}

impl Link {
    /// Opens the port, pings every motor (a missing one is named), and writes the operating
    /// mode and limits where they differ.
    fn open(t: &TendonConfig) -> anyhow::Result<Self> {
        let port = t.port.display();
        let mut bus = Bus::open(&t.port, t.baud).with_context(|| {
            format!(
                "cannot open the motor bus {port} (tendon.port); is the adapter plugged in and \
                 are you in the `dialout` group?"
            )
        })?;
        let mut missing = Vec::new();
        for (i, &id) in t.ids.iter().enumerate() {
            // Twice: one lost reply is not a missing motor.
            let answered = (0..2).any(|_| guarded(|| Ok(bus.ping(id)?)).is_ok());
            if !answered {
                missing.push(format!("id {id} (actuator {})", i + 1));
            }
        }
        if !missing.is_empty() {
            bail!(
                "no answer on {port} at {} baud from motor {}: check the motors' power and \
                 wiring, and tendon.ids and tendon.baud against the motors' settings",
                t.baud,
                missing.join(", ")
            );
        }
        let mut link = Self {
            bus,
            ids: t.ids,
            torque: false,
        };
        let mut torque = [false; ACTUATORS];
        for i in 0..ACTUATORS {
            torque[i] = link.configure(t, i).with_context(|| {
                format!(
                    "configuring motor id {} (actuator {}) on {port}",
                    t.ids[i],
                    i + 1
                )
            })?;
        }
        // Any motor on counts as on: the first `Off` then turns them all off.
        link.torque = torque.iter().any(|&on| on);
        Ok(link)
    }

    /// Writes the operating mode and limits where they differ from the config (they live in
    /// EEPROM, which wears, and can be written only with the torque off). Returns whether the
    /// motor's torque is on: a driver restarted beside a running controller leaves a holding
    /// motor holding, so the arm does not drop.
    fn configure(&mut self, t: &TendonConfig, i: usize) -> anyhow::Result<bool> {
        use table::*;
        let id = self.ids[i];
        let b = &mut self.bus;
        let fail = anyhow::Error::msg;
        let mode = t.operating_mode.register_value();
        let limits = [
            (MAX_POSITION_LIMIT, t.max_ticks[i] as u32),
            (MIN_POSITION_LIMIT, t.min_ticks[i] as u32),
        ];
        let mode_ok = guarded(|| Ok(b.read_u8(id, OPERATING_MODE)?.data)).map_err(fail)? == mode;
        let mut limits_ok = [true; 2];
        for (ok, (address, value)) in limits_ok.iter_mut().zip(limits) {
            *ok = guarded(|| Ok(b.read_u32(id, address)?.data)).map_err(fail)? == value;
        }
        let current_ok =
            guarded(|| Ok(b.read_u16(id, CURRENT_LIMIT)?.data)).map_err(fail)? == t.current_limit;
        if mode_ok && limits_ok == [true; 2] && current_ok {
            return Ok(guarded(|| Ok(b.read_u8(id, TORQUE_ENABLE)?.data)).map_err(fail)? != 0);
        }
        tracing::info!(id, "writing operating mode and limits (torque off)");
        guarded(|| Ok(b.write_u8(id, TORQUE_ENABLE, 0)?)).map_err(fail)?;
        if !mode_ok {
            guarded(|| Ok(b.write_u8(id, OPERATING_MODE, mode)?)).map_err(fail)?;
        }
        for (ok, (address, value)) in limits_ok.into_iter().zip(limits) {
            if !ok {
                guarded(|| Ok(b.write_u32(id, address, value)?)).map_err(fail)?;
            }
        }
        if !current_ok {
            guarded(|| Ok(b.write_u16(id, CURRENT_LIMIT, t.current_limit)?)).map_err(fail)?;
        }
        Ok(false)
    }

    /// Writes torque enable to every motor that may be commanded.
    fn set_torque(&mut self, on: bool, reading: &Reading) -> Result<(), Fault> {
        let ids = self.ids;
        let bus = &mut self.bus;
        let (data, n) = for_motors(&ids, |i| (!on || !reading.faulted(i)).then_some(on as u8));
        guarded(|| Ok(bus.sync_write_u8(table::TORQUE_ENABLE, &data[..n])?))?;
        self.torque = on;
        Ok(())
    }

    /// Goal positions for every motor that may be commanded.
    fn write_goals(&mut self, goals: &[i32; ACTUATORS], reading: &Reading) -> Result<(), Fault> {
        let ids = self.ids;
        let bus = &mut self.bus;
        let (data, n) = for_motors(&ids, |i| (!reading.faulted(i)).then_some(goals[i] as u32));
        guarded(|| Ok(bus.sync_write_u32(table::GOAL_POSITION, &data[..n])?))
    }

    /// What the safety logic decided, on the bus. An e-stop's torque-off goes out even to
    /// motors with a hardware error (turning a motor off is never a command to move).
    fn apply(&mut self, action: Action, mapping: &Mapping, reading: &Reading) -> Result<(), Fault> {
        match action {
            Action::Off if self.torque => self.set_torque(false, reading),
            Action::Off | Action::Hold => Ok(()),
            Action::Follow(a) => {
                // The goal first: the torque then holds where the controller wants, not
                // wherever the goal register was left.
                self.write_goals(&mapping.all_ticks(&a), reading)?;
                if !self.torque {
                    self.set_torque(true, reading)?;
                }
                Ok(())
            }
        }
    }

    /// Present current and position of every motor in one sync read (126..136), and the
    /// hardware-error status when a motor raises its alert bit or `errors` asks for it.
    /// Returns the number of motors that did not answer.
    fn read(&mut self, reading: &mut Reading, errors: bool) -> Result<usize, Fault> {
        let ids = self.ids;
        let bus = &mut self.bus;
        let mut alert = errors;
        let mut missing = 0;
        let mut first_fault = None;
        guarded(|| {
            bus.sync_read_cb(&ids, table::PRESENT_CURRENT, 10, |r| match r {
                Ok(r) => {
                    let Some(i) = ids.iter().position(|&id| id == r.motor_id) else {
                        missing += 1;
                        return;
                    };
                    let d = r.data;
                    let current = i16::from_le_bytes([d[0], d[1]]);
                    reading.current_a[i] = f64::from(current) * table::CURRENT_UNIT_A;
                    reading.ticks[i] = i32::from_le_bytes([d[6], d[7], d[8], d[9]]);
                    alert |= r.alert;
                }
                Err(e) => {
                    missing += 1;
                    first_fault.get_or_insert(Fault::from(e));
                }
            })?;
            Ok(())
        })?;
        if alert {
            guarded(|| {
                bus.sync_read_u8_cb(&ids, table::HARDWARE_ERROR_STATUS, |r| match r {
                    Ok(r) => {
                        if let Some(i) = ids.iter().position(|&id| id == r.motor_id) {
                            reading.hardware_error[i] |= r.data;
                        }
                    }
                    Err(_) => missing += 1,
                })?;
                Ok(())
            })?;
        }
        match first_fault {
            Some(Fault::Port(m)) => Err(Fault::Port(m)),
            _ => Ok(missing),
        }
    }
}

/// Runs the tendon driver until `stop` is set.
pub fn run(config: &Config, namespace: Namespace, stop: &AtomicBool) -> anyhow::Result<()> {
    let t = config
        .tendon
        .as_ref()
        .context("the config has no [tendon] section")?;
    let mapping = Mapping::new(t, &config.arm);
    let node = Node::open(namespace, "tendon")?;
    let mut commands = Commands::open(&node, &config.estop_latch())?;
    let publisher = node.publisher(&node.motor_state()?)?;
    let ms = |v: f64| (v * 1e6) as u64;
    let mut supervisor = Supervisor::new(Timeouts {
        hold_after_ns: ms(t.hold_after_ms),
        off_after_ns: ms(t.torque_off_after_ms),
    });

    // At start a missing motor is an error the user must fix; later the driver keeps trying.
    let mut link = Some(Link::open(t)?);
    tracing::info!(
        port = %t.port.display(),
        baud = t.baud,
        ids = ?t.ids,
        "motors answered; the torque comes on with the first setpoint"
    );

    let mut reading = Reading::default();
    // A bus silent this long is reopened: an adapter unplugged and plugged in again is a new
    // device behind the same name, and the old descriptor never hears from it.
    const REOPEN_AFTER_NS: u64 = 1_000_000_000;
    let mut last_answer = now_ns();
    let mut backoff = Backoff::default();
    let mut faults = 0u64;
    let mut seq = 0u64;
    let mut cycle = 0u64;
    let mut last_state = DriverState::Off;
    // The hardware-error status is read at about 5 Hz besides whenever a motor raises its alert.
    let errors_every = ((t.rate_hz / 5.0).round() as u64).max(1);
    let mut ticker = Ticker::new(t.rate_hz);
    while !stop.load(Ordering::Relaxed) {
        ticker.wait();
        cycle += 1;
        let now = now_ns();
        let poll = commands.poll();
        let fault = reading.hardware_error.iter().any(|&e| e != 0);
        let action = supervisor.update(now, &poll, fault);
        let state = supervisor.state();
        if state != last_state {
            tracing::warn!(from = last_state.name(), to = state.name(), "driver state");
            last_state = state;
        }

        if link.is_none() && backoff.ready(now) {
            match Link::open(t) {
                Ok(l) => {
                    tracing::warn!("motor bus back");
                    link = Some(l);
                    backoff.succeeded();
                    last_answer = now;
                }
                Err(e) => {
                    faults += 1;
                    backoff.failed(now);
                    tracing::error!(faults, "{e:#}");
                }
            }
        }
        // An e-stop's torque-off goes out at once, back-off or not.
        let urgent = matches!(action, Action::Off) && poll.stopped;
        if let Some(l) = link.as_mut()
            && (backoff.ready(now) || urgent)
        {
            let result = l
                .apply(action, &mapping, &reading)
                .and_then(|()| l.read(&mut reading, cycle.is_multiple_of(errors_every)));
            match result {
                Ok(0) => {
                    reading.stamp_ns = Some(now_ns());
                    backoff.succeeded();
                    last_answer = now;
                }
                Ok(missing) => {
                    faults += missing as u64;
                    backoff.failed(now);
                    if faults.is_power_of_two() {
                        tracing::error!(faults, missing, "motors did not answer; retrying");
                    }
                }
                Err(f) => {
                    faults += 1;
                    backoff.failed(now);
                    if faults.is_power_of_two() || matches!(f, Fault::Port(_)) {
                        tracing::error!(faults, "{f}; retrying");
                    }
                    if matches!(f, Fault::Port(_)) {
                        link = None;
                    }
                }
            }
            if link.is_some() && now.saturating_sub(last_answer) > REOPEN_AFTER_NS {
                tracing::error!(
                    faults,
                    "no answer from the motors for 1 s: reopening the port"
                );
                link = None;
                // At once: it has waited long enough.
                backoff.succeeded();
            }
            for (i, &e) in reading.hardware_error.iter().enumerate() {
                if e != 0 && !fault {
                    tracing::error!(
                        id = t.ids[i],
                        actuator = i + 1,
                        hardware_error = format!("{e:#04x}"),
                        "motor reports a hardware error: no more commands to it, the others \
                         hold; restart the driver once the cause is fixed"
                    );
                }
            }
        }

        // Stamped when the motors last answered: data that is old looks old to the controller.
        let Some(stamp_ns) = reading.stamp_ns else {
            continue;
        };
        seq += 1;
        let _ = publisher.send_copy(MotorState {
            seq,
            stamp_ns,
            actuation: std::array::from_fn(|i| mapping.actuation(i, reading.ticks[i])),
            current_a: reading.current_a,
            faults,
            state: state as u32,
            hardware_error: reading.hardware_error,
            ..MotorState::default()
        });
    }
    // Leaving: the arm must not stay driven by a process that is gone.
    if let Some(l) = link.as_mut()
        && l.torque
        && let Err(e) = l.set_torque(false, &reading)
    {
        tracing::error!("could not turn the torque off on the way out: {e}");
    }
    tracing::info!(
        faults,
        refused = commands.refused(),
        overruns = ticker.overruns(),
        "tendon driver stopped"
    );
    Ok(())
}
