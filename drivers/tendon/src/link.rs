//! The motor bus as the driver uses it: opening it (one sync read finds every motor and its
//! settings), the writes (sync writes, no reply), and reads that never make anything wait:
//! a read is sent, its replies are taken at the start of the next cycle, matched to the read by
//! motor id, and what has not come by then is counted as dropped, once.

use std::time::Duration;

use anyhow::{Context, bail};
use softarm_config::hardware::TendonConfig;
use softarm_driver::Action;
use softarm_ipc::MAX_ACTUATORS;
use softarm_runtime::now_ns;

use crate::table;
use crate::timing::{Lateness, Line, RETURN_DELAY};
use crate::wire::{Arrival, BROADCAST_ID, Status, Wire, instruction, is_timeout};

/// A failed exchange on the bus.
#[derive(Debug)]
pub(crate) enum Fault {
    /// A write could not go out in time: try again next cycle.
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

fn write_fault(e: std::io::Error) -> Fault {
    if is_timeout(&e) {
        Fault::Bus(format!("a write did not go out in time ({e})"))
    } else {
        Fault::Port(e.to_string())
    }
}

/// What the motors last reported: one entry per motor, room for every arm.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Reading {
    /// The motors on the bus (the arm's actuators); the entries past them stay empty.
    pub motors: usize,
    pub ticks: [i32; MAX_ACTUATORS],
    pub current_a: [f64; MAX_ACTUATORS],
    pub hardware_error: [u8; MAX_ACTUATORS],
    /// Per motor, when the read its newest position answered was sent (ns), and in which
    /// driver cycle.
    pub asked_ns: [Option<u64>; MAX_ACTUATORS],
    pub asked_cycle: [u64; MAX_ACTUATORS],
    /// Per motor, when the newest status read it answered was sent (ns) and whether that read
    /// found its torque on.
    pub torque_seen: [Option<(u64, bool)>; MAX_ACTUATORS],
}

impl Reading {
    /// Nothing heard yet from `motors` motors.
    pub fn new(motors: usize) -> Self {
        Self {
            motors,
            ..Self::default()
        }
    }

    pub fn faulted(&self, i: usize) -> bool {
        self.hardware_error[i] != 0
    }

    /// Motor `i` was found with its torque off by a status read sent after `since_ns`.
    pub fn found_off_since(&self, i: usize, since_ns: u64) -> bool {
        self.torque_seen[i].is_some_and(|(sent_ns, on)| !on && sent_ns > since_ns)
    }

    /// The oldest motor's newest answer: the data is at least this fresh. `None` until every
    /// motor answered once.
    pub fn stamp_ns(&self) -> Option<u64> {
        if self.motors == 0 {
            return None;
        }
        self.asked_ns[..self.motors]
            .iter()
            .try_fold(u64::MAX, |oldest, a| a.map(|a| oldest.min(a)))
    }

    /// Driver cycles since the oldest motor's newest data was asked for.
    pub fn age_cycles(&self, cycle: u64) -> u64 {
        let oldest = self.asked_cycle[..self.motors].iter().copied().min();
        cycle.saturating_sub(oldest.unwrap_or(0))
    }
}

/// The bus's events since the driver started, each counted once.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct Counts {
    /// Replies asked for, in reads closed.
    pub asked: u64,
    /// Replies that came whole (late ones included).
    pub answered: u64,
    /// Replies with an error number (the motor refused the read).
    pub refused: u64,
    /// Replies that came after their read closed (a loaded machine delivers late).
    pub late: u64,
    /// Reads that ended with a reply missing.
    pub timeouts: u64,
    /// Replies no read asked for.
    pub stray: u64,
}

impl Counts {
    /// Replies asked for that never came whole: neither answered (late or not) nor refused
    /// nor seen with a bad CRC (`crc_errors`, counted by the line). A reply the machine
    /// delivers after its read closed moves from here to `late` when it comes.
    pub fn dropped(&self, crc_errors: u64) -> u64 {
        self.asked
            .saturating_sub(self.answered + self.refused + crc_errors)
    }
}

/// Closed reads are kept this long for their late replies: a loaded machine was seen to hold
/// a pseudo-terminal's bytes for seconds (the kernel's flip-buffer work waiting for a CPU).
const KEEP_CLOSED_NS: u64 = 3_000_000_000;

/// Which read is out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Ask {
    /// Present Position (132..136): most cycles. The shortest reply (15 bytes) survives a
    /// noisy line best.
    Position,
    /// Present Current, Velocity and Position (126..136): every few cycles.
    Data,
    /// Torque Enable .. Hardware Error Status (64..71), at 5 Hz and after an alert bit.
    Status,
}

impl Ask {
    fn address_len(self) -> (u16, u16) {
        match self {
            Ask::Position => (table::PRESENT_POSITION, 4),
            Ask::Data => (table::PRESENT_CURRENT, 10),
            Ask::Status => (table::TORQUE_ENABLE, 7),
        }
    }
}

/// Names the motors that have not answered the survey in `waited_s` seconds, and says it goes on.
fn name_missing(t: &TendonConfig, ids: &[u8], waited_s: u64) {
    let named: Vec<String> = ids
        .iter()
        .map(|&id| {
            let actuator = t.ids.iter().position(|&x| x == id).map_or(0, |i| i + 1);
            format!("id {id} (actuator {actuator})")
        })
        .collect();
    tracing::error!(
        "no answer on {} at {} baud from motor {} for {waited_s} s: check the motors' power and \
         wiring, and tendon.ids and tendon.baud against the motors' settings; still asking, and \
         no torque comes on until every motor has answered",
        t.port.display(),
        t.baud,
        named.join(", ")
    );
}

/// Says that motor `id` (the bus's `i`th) keeps Return Delay Time `delay` (unit 2 µs) although
/// the driver wrote [`RETURN_DELAY`] (`refused`: the write's error, if it failed), and what to
/// do.
fn say_delay_kept(t: &TendonConfig, id: u8, i: usize, delay: u8, refused: Option<anyhow::Error>) {
    let refused = refused.map_or(String::new(), |e| format!(" ({e:#})"));
    tracing::error!(
        "motor id {id} (actuator {}) on {} kept its Return Delay Time of {} µs where the driver \
         wrote {} µs{refused}: every read of the bus waits that long for its reply. Set its \
         Return Delay Time (control table address 9) to {RETURN_DELAY} with DYNAMIXEL Wizard, \
         torque off, or replace the motor; the driver goes on, its reads sized to the delay",
        i + 1,
        t.port.display(),
        u32::from(delay) * 2,
        u32::from(RETURN_DELAY) * 2,
    );
}

/// Says that motor `id` (the bus's `i`th), found holding with its torque on, keeps Return Delay
/// Time `delay` (unit 2 µs) until a start that finds its torque off.
fn say_delay_left(t: &TendonConfig, id: u8, i: usize, delay: u8) {
    tracing::warn!(
        "motor id {id} (actuator {}) on {} holds with its torque on and a Return Delay Time of \
         {} µs: left so, the torque is not turned off under a holding arm; it is set to {} µs \
         at a start that finds the torque off (a driver that stops turns it off), and every \
         read of the bus waits that long meanwhile",
        i + 1,
        t.port.display(),
        u32::from(delay) * 2,
        u32::from(RETURN_DELAY) * 2,
    );
}

/// The alert bit (0x80 in a status packet's error field), which a motor raises on every reply
/// from a hardware error until it is rebooted. A motor's alert is news once: the status read
/// it triggers reports the error, and after that the motor's replies are read as usual, so one
/// faulted motor does not turn every read into a status read and leave the others unread.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Alert {
    /// A motor raised the alert bit its status has not been read with: the next read is the
    /// status.
    pub due: bool,
    /// Motors whose status was read while they raised the bit.
    known: [bool; MAX_ACTUATORS],
}

impl Alert {
    /// Motor `i` replied to read `ask` with the alert bit `raised` or not.
    fn heard(&mut self, i: usize, raised: bool, ask: Ask) {
        if !raised {
            self.known[i] = false;
        } else if ask == Ask::Status {
            self.known[i] = true;
        } else if !self.known[i] {
            self.due = true;
        }
    }
}

/// A read that was sent and whose replies are being collected.
#[derive(Debug, Clone, Copy)]
struct Pending {
    ask: Ask,
    /// The motors this read asked (all, or those a first read of the cycle missed).
    asked: [bool; MAX_ACTUATORS],
    sent_ns: u64,
    /// When its last reply is due on the line, after what went out before it (ns).
    due_ns: u64,
    sent_cycle: u64,
    answered: [bool; MAX_ACTUATORS],
    refused: [bool; MAX_ACTUATORS],
}

/// An open bus and what the driver knows of its motors.
pub(crate) struct Link {
    pub wire: Wire,
    /// The motors' ids, in the arm's order; `n` of them.
    ids: [u8; MAX_ACTUATORS],
    n: usize,
    /// The torque may be on somewhere: the driver turned it on, or found it on, or could not
    /// ask a motor. While set, an `Off` writes torque-off.
    pub torque: bool,
    /// Per motor, when Torque Enable was last written on (ns): a status read sent after it
    /// that finds the torque off means the motor lost it (a brown-out restarts a motor with
    /// its torque off, and a SYNC WRITE has no reply to say it was lost).
    enabled_ns: [u64; MAX_ACTUATORS],
    pending: Option<Pending>,
    /// Reads closed in the last 3 s with replies missing, for their late replies.
    closed: std::collections::VecDeque<Pending>,
    /// Which motors raise the alert bit, and whether the next read is the status.
    pub alert: Alert,
    /// When a reply last came (ns).
    pub last_reply_ns: u64,
    /// The motors' settings while they are being asked (`None` once every motor answered and
    /// is configured).
    survey: Option<Survey>,
    configure_faults: u64,
    /// Per motor, its Return Delay Time (unit 2 µs) as read back once configured.
    delays: [u8; MAX_ACTUATORS],
    /// Per motor, the Return Delay Time it was said to keep ([`say_delay_kept`]): said once,
    /// not again at each configuration a lost reply elsewhere on the bus starts over.
    delays_said: [Option<u8>; MAX_ACTUATORS],
    line: Line,
    /// When the line is done with what the driver sent, and the replies it asked for (ns).
    busy_until_ns: u64,
    /// How late after their time on the line the replies have come lately.
    pub lateness: Lateness,
}

/// At start every motor gets this long to answer a write, three times: a loaded machine may
/// deliver a reply tens of milliseconds late. The survey's sync read is sent again this often
/// for the motors that have not answered whole.
const START_REPLY_TIMEOUT: Duration = Duration::from_millis(100);
const START_ATTEMPTS: usize = 3;
/// A survey this old with motors missing names them in the log, and again every
/// [`NAME_EVERY_NS`] while it lasts. Its replies are the longest the driver asks for (67 bytes):
/// with 2 % of the bytes garbled only about a quarter arrive whole, and 2 s of tries (about
/// twenty) miss one of six 1 time in 300, so a noisy bus is not said to miss a motor.
const SURVEY_BUDGET_NS: u64 = 2_000_000_000;
const NAME_EVERY_NS: u64 = 10_000_000_000;

/// The settings read at start: Return Delay Time (9) .. Torque Enable (64).
const SURVEY_FROM: u16 = table::RETURN_DELAY_TIME;
const SURVEY_LEN: u16 = table::TORQUE_ENABLE - SURVEY_FROM + 1;

/// What the survey, or a read back, found of a motor's settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Found {
    /// Return Delay Time (unit 2 µs).
    delay: u8,
    mode: u8,
    /// Max and Min Position Limit.
    limits: [u32; 2],
    torque: bool,
}

impl Found {
    /// The settings in `s`, the bytes from [`SURVEY_FROM`] on.
    fn of(s: &[u8]) -> Self {
        use table::*;
        let at = |address: u16| usize::from(address - SURVEY_FROM);
        let u32_at = |address: u16| {
            let a = at(address);
            u32::from_le_bytes([s[a], s[a + 1], s[a + 2], s[a + 3]])
        };
        Self {
            delay: s[at(RETURN_DELAY_TIME)],
            mode: s[at(OPERATING_MODE)],
            limits: [u32_at(MAX_POSITION_LIMIT), u32_at(MIN_POSITION_LIMIT)],
            torque: s[at(TORQUE_ENABLE)] != 0,
        }
    }
}

/// What a status packet was to the survey.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Heard {
    /// A motor's settings, the first time.
    New,
    /// A motor already heard (a reply to an earlier ask, delivered late).
    Again,
    /// No answer to the survey.
    Other,
}

/// Every motor's settings, asked at start until each has answered whole. A slow bus (a
/// loaded machine's pty holding the replies for seconds) only makes it longer: nobody gives up
/// on a motor that answers late, and none is engaged before all have answered.
#[derive(Debug)]
struct Survey {
    /// Per motor (`n` of them), its settings once it answered whole.
    settings: [Option<Vec<u8>>; MAX_ACTUATORS],
    n: usize,
    began_ns: u64,
    /// When the last sync read went out; `None` before the first.
    asked_ns: Option<u64>,
    /// When the missing motors are next named in the log.
    name_ns: u64,
}

impl Survey {
    fn new(now: u64, n: usize) -> Self {
        Self {
            settings: Default::default(),
            n,
            began_ns: now,
            asked_ns: None,
            name_ns: now.saturating_add(SURVEY_BUDGET_NS),
        }
    }

    fn complete(&self) -> bool {
        self.settings[..self.n].iter().all(Option::is_some)
    }

    /// The ids of the motors that have not answered.
    fn missing(&self, ids: &[u8]) -> Vec<u8> {
        (0..self.n)
            .filter(|&i| self.settings[i].is_none())
            .map(|i| ids[i])
            .collect()
    }

    /// Whether the sync read is due at `now`: at once, then every [`START_REPLY_TIMEOUT`]
    /// while a motor is missing.
    fn ask_due(&self, now: u64) -> bool {
        let every = START_REPLY_TIMEOUT.as_nanos() as u64;
        !self.complete() && self.asked_ns.is_none_or(|a| now.saturating_sub(a) >= every)
    }

    /// Takes status packet `s`.
    fn take(&mut self, ids: &[u8], s: &Status) -> Heard {
        let Some(i) = ids.iter().position(|&id| id == s.id) else {
            return Heard::Other;
        };
        if s.params.len() != usize::from(SURVEY_LEN) {
            return Heard::Other;
        }
        if self.settings[i].is_some() {
            return Heard::Again;
        }
        self.settings[i] = Some(s.params.clone());
        Heard::New
    }

    /// Whether to name the missing motors at `now`: after [`SURVEY_BUDGET_NS`], then every
    /// [`NAME_EVERY_NS`].
    fn name_due(&mut self, now: u64) -> bool {
        if self.complete() || now < self.name_ns {
            return false;
        }
        self.name_ns = now.saturating_add(NAME_EVERY_NS);
        true
    }
}

impl Link {
    /// Opens the port; the link then surveys the motors ([`Link::survey`]) and is
    /// [`Link::ready`] once every one has answered and is configured. Until then the torque may
    /// be on anywhere (a restarted driver's motors hold), so an `Off` reaches every motor.
    pub fn open(t: &TendonConfig) -> anyhow::Result<Self> {
        // A write finds room in the kernel's buffer at once unless the line is stuck: waiting
        // longer than half a period for one would only stall the next cycle's writes.
        let write_timeout = Duration::from_secs_f64((0.5 / t.rate_hz).clamp(0.002, 0.05));
        let wire = Wire::open(&t.port, t.baud, write_timeout).with_context(|| {
            format!(
                "cannot open the motor bus {} (tendon.port); is the adapter plugged in and \
                 are you in the `dialout` group?",
                t.port.display()
            )
        })?;
        let now = now_ns();
        let n = t.ids.len();
        let mut ids = [0; MAX_ACTUATORS];
        ids[..n].copy_from_slice(&t.ids);
        Ok(Self {
            wire,
            ids,
            n,
            torque: true,
            enabled_ns: [0; MAX_ACTUATORS],
            pending: None,
            closed: std::collections::VecDeque::new(),
            alert: Alert::default(),
            last_reply_ns: now,
            survey: Some(Survey::new(now, n)),
            configure_faults: 0,
            delays: [0; MAX_ACTUATORS],
            delays_said: [None; MAX_ACTUATORS],
            line: Line::new(t.baud),
            busy_until_ns: now,
            lateness: Lateness::default(),
        })
    }

    /// The motors' Return Delay Times as read back once configured (unit 2 µs).
    pub fn delays(&self) -> &[u8] {
        &self.delays[..self.n]
    }

    /// When the open read's last reply is due on the line (ns), if a read is open.
    pub fn read_due_ns(&self) -> Option<u64> {
        self.pending.map(|p| p.due_ns)
    }

    /// `ns` more on the line from now or from when it is free, whichever is later: returns
    /// when the line is free again.
    fn on_line(&mut self, ns: u64) -> u64 {
        self.busy_until_ns = self.busy_until_ns.max(now_ns()) + ns;
        self.busy_until_ns
    }

    /// Every motor has answered the survey and is configured: the link reads and drives.
    pub fn ready(&self) -> bool {
        self.survey.is_none()
    }

    /// One step of the survey: the sync read of Return Delay Time .. Torque Enable sent to the
    /// motors that have not answered whole, when due, and their answers taken, waiting at most
    /// `wait`. Once every motor has answered: position control, the limits and the Return
    /// Delay Time written where they differ and read back ([`Link::configure`]), the profile
    /// velocity, and the link is ready (true: it just became ready). On a clean bus of motors
    /// set before, that is one exchange, not five per motor.
    pub fn survey(
        &mut self,
        t: &TendonConfig,
        counts: &mut Counts,
        wait: Duration,
    ) -> Result<bool, Fault> {
        let Some(s) = self.survey.as_mut() else {
            return Ok(false);
        };
        let now = now_ns();
        if s.ask_due(now) {
            let ask = s.missing(&self.ids[..self.n]);
            // The read before ended with some motor's answer missing.
            counts.timeouts += u64::from(s.asked_ns.is_some());
            s.asked_ns = Some(now);
            let mut params = SURVEY_FROM.to_le_bytes().to_vec();
            params.extend(SURVEY_LEN.to_le_bytes());
            params.extend(&ask);
            counts.asked += ask.len() as u64;
            self.wire
                .send(BROADCAST_ID, instruction::SYNC_READ, &params)
                .map_err(write_fault)?;
        }
        self.take_survey(counts, wait)?;
        let Some(s) = self.survey.as_mut() else {
            return Ok(false);
        };
        if !s.complete() {
            if s.name_due(now) {
                let waited_s = now.saturating_sub(s.began_ns) / 1_000_000_000;
                let missing = s.missing(&self.ids[..self.n]);
                name_missing(t, &missing, waited_s);
            }
            return Ok(false);
        }
        self.finish(t, counts)
    }

    /// Takes the survey's answers that have come, waiting at most `wait` for them all.
    fn take_survey(&mut self, counts: &mut Counts, wait: Duration) -> Result<(), Fault> {
        let deadline = std::time::Instant::now() + wait;
        while let Some(s) = self.survey.as_mut()
            && !s.complete()
        {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            match self.wire.receive(left) {
                None => break,
                Some(Arrival::PortError(e)) => return Err(Fault::Port(e)),
                Some(Arrival::Status(st, _)) => {
                    self.last_reply_ns = now_ns();
                    match s.take(&self.ids[..self.n], &st) {
                        // A late answer to an earlier ask is an answer, not a lost reply.
                        Heard::New | Heard::Again => counts.answered += 1,
                        Heard::Other => counts.stray += 1,
                    }
                }
            }
        }
        Ok(())
    }

    /// Every motor answered: configures each, writes the profile velocity, and the link is
    /// ready. A motor whose configuration fails is asked again (and stays unengaged).
    fn finish(&mut self, t: &TendonConfig, counts: &mut Counts) -> Result<bool, Fault> {
        let Some(s) = self.survey.as_mut() else {
            return Ok(false);
        };
        let settings = std::mem::take(&mut s.settings);
        let mut torque = false;
        let mut failed = false;
        for (i, found) in settings.into_iter().enumerate().take(self.n) {
            let found = found.expect("every motor answered");
            let now = match self.configure(t, i, &found, counts) {
                Ok((on, now)) => {
                    torque |= on;
                    now
                }
                Err(e) => {
                    failed = true;
                    self.configure_faults += 1;
                    if self.configure_faults.is_power_of_two() {
                        tracing::error!(
                            configure_faults = self.configure_faults,
                            "configuring motor id {} (actuator {}) on {}: {e:#}; asking it again",
                            t.ids[i],
                            i + 1,
                            t.port.display()
                        );
                    }
                    continue;
                }
            };
            // What the motor holds now: asked again (another motor failed), it is not written
            // again (EEPROM wears).
            if let Some(s) = self.survey.as_mut() {
                s.settings[i] = Some(now);
            }
        }
        if failed {
            return Ok(false);
        }
        // RAM, lost at a power cycle: written every open, to every motor (no reply).
        let velocity = self.for_motors(|_| Some(t.profile_velocity.to_le_bytes()));
        self.sync_write(table::PROFILE_VELOCITY, &velocity)?;
        self.wire.counts.running();
        self.survey = None;
        self.torque = torque;
        Ok(true)
    }

    /// Writes position control, the limits and the Return Delay Time where they differ from
    /// what the driver needs (they live in EEPROM, which wears, and can be written only with the
    /// torque off), then reads them back. Returns whether the motor's torque is on: a driver
    /// restarted beside a running controller leaves a holding motor holding, so the arm does not
    /// drop. A delay the motor does not keep is said ([`say_delay_kept`]), and the reads are
    /// sized to it; wrong mode or limits read back are an error (the motor is asked again).
    /// Also the settings the motor holds now, as the survey reads them.
    fn configure(
        &mut self,
        t: &TendonConfig,
        i: usize,
        s: &[u8],
        counts: &mut Counts,
    ) -> anyhow::Result<(bool, Vec<u8>)> {
        use table::*;
        let found = Found::of(s);
        self.delays[i] = found.delay;
        let limits = [t.max_ticks[i] as u32, t.min_ticks[i] as u32];
        let eeprom_ok = found.mode == POSITION_CONTROL && found.limits == limits;
        let delay_ok = found.delay == RETURN_DELAY;
        let id = self.ids[i];
        if eeprom_ok && !delay_ok && found.torque {
            say_delay_left(t, id, i, found.delay);
        }
        if eeprom_ok && (delay_ok || found.torque) {
            return Ok((found.torque, s.to_vec()));
        }
        tracing::info!(
            id,
            "writing operating mode, limits and return delay time (torque off)"
        );
        // EEPROM needs the torque off. This is the start, before this driver turned any torque
        // on: a motor found holding the arm (a driver restarted beside a running controller)
        // is turned off only for a wrong mode or limits, which must not be driven, never for
        // the delay alone (above).
        self.write(id, TORQUE_ENABLE, &[0], counts)?;
        if found.mode != POSITION_CONTROL {
            self.write(id, OPERATING_MODE, &[POSITION_CONTROL], counts)?;
        }
        for (k, address) in [MAX_POSITION_LIMIT, MIN_POSITION_LIMIT]
            .into_iter()
            .enumerate()
        {
            if found.limits[k] != limits[k] {
                self.write(id, address, &limits[k].to_le_bytes(), counts)?;
            }
        }
        let refused = match delay_ok {
            true => None,
            false => self
                .write(id, RETURN_DELAY_TIME, &[RETURN_DELAY], counts)
                .err(),
        };
        let now = self.read(id, SURVEY_FROM, SURVEY_LEN, counts)?;
        let back = Found::of(&now);
        if back.mode != POSITION_CONTROL || back.limits != limits {
            bail!(
                "it reads back operating mode {} and position limits {:?} (max, min) after they \
                 were written as {POSITION_CONTROL} and {limits:?}",
                back.mode,
                back.limits
            );
        }
        self.delays[i] = back.delay;
        if back.delay != RETURN_DELAY && self.delays_said[i] != Some(back.delay) {
            say_delay_kept(t, id, i, back.delay, refused);
            self.delays_said[i] = Some(back.delay);
        }
        Ok((false, now))
    }

    /// A WRITE with its reply awaited (start only), tried [`START_ATTEMPTS`] times.
    fn write(
        &mut self,
        id: u8,
        address: u16,
        data: &[u8],
        counts: &mut Counts,
    ) -> anyhow::Result<()> {
        let mut params = address.to_le_bytes().to_vec();
        params.extend_from_slice(data);
        let what = format!("a write at address {address}");
        self.exchange(id, instruction::WRITE, &params, 0, &what, counts)
            .map(drop)
    }

    /// A READ of `len` bytes from `address`, its reply awaited (start only), tried
    /// [`START_ATTEMPTS`] times.
    fn read(
        &mut self,
        id: u8,
        address: u16,
        len: u16,
        counts: &mut Counts,
    ) -> anyhow::Result<Vec<u8>> {
        let mut params = address.to_le_bytes().to_vec();
        params.extend(len.to_le_bytes());
        let what = format!("a read of {len} bytes from address {address}");
        self.exchange(
            id,
            instruction::READ,
            &params,
            usize::from(len),
            &what,
            counts,
        )
    }

    /// Instruction `inst` to motor `id` and its reply of `reply_len` bytes awaited, tried
    /// [`START_ATTEMPTS`] times: the reply's parameters. `what` names it in errors.
    fn exchange(
        &mut self,
        id: u8,
        inst: u8,
        params: &[u8],
        reply_len: usize,
        what: &str,
        counts: &mut Counts,
    ) -> anyhow::Result<Vec<u8>> {
        for _ in 0..START_ATTEMPTS {
            self.wire
                .send(id, inst, params)
                .with_context(|| format!("sending {what}"))?;
            counts.asked += 1;
            let deadline = std::time::Instant::now() + START_REPLY_TIMEOUT;
            loop {
                let left = deadline.saturating_duration_since(std::time::Instant::now());
                match self.wire.receive(left) {
                    Some(Arrival::Status(s, _))
                        if s.id == id
                            && (s.params.len() == reply_len
                                || (s.params.is_empty() && s.error & 0x7F != 0)) =>
                    {
                        counts.answered += 1;
                        if s.error & 0x7F != 0 {
                            bail!("the motor refused {what}: error {:#04x}", s.error);
                        }
                        return Ok(s.params);
                    }
                    Some(Arrival::Status(..)) => counts.stray += 1,
                    Some(Arrival::PortError(e)) => bail!("reading the motor bus: {e}"),
                    None => break,
                }
            }
            counts.timeouts += 1;
        }
        bail!("no answer to {what}")
    }

    /// Sync-write parameters for the motors `value` gives a value for.
    pub fn for_motors<const N: usize>(
        &self,
        value: impl Fn(usize) -> Option<[u8; N]>,
    ) -> Vec<(u8, [u8; N])> {
        (0..self.n)
            .filter_map(|i| value(i).map(|v| (self.ids[i], v)))
            .collect()
    }

    /// One SYNC WRITE (no reply): the same item to several motors.
    pub fn sync_write<const N: usize>(
        &mut self,
        address: u16,
        data: &[(u8, [u8; N])],
    ) -> Result<(), Fault> {
        if data.is_empty() {
            return Ok(());
        }
        let mut params = address.to_le_bytes().to_vec();
        params.extend((N as u16).to_le_bytes());
        for (id, v) in data {
            params.push(*id);
            params.extend_from_slice(v);
        }
        self.wire
            .send(BROADCAST_ID, instruction::SYNC_WRITE, &params)
            .map_err(write_fault)?;
        self.on_line(self.line.sync_write_ns(N, data.len()));
        Ok(())
    }

    /// Motor `i` (without a hardware error) was found with its torque off after the driver
    /// last turned it on.
    pub fn lost_torque(&self, i: usize, reading: &Reading) -> bool {
        self.torque && !reading.faulted(i) && reading.found_off_since(i, self.enabled_ns[i])
    }

    /// Torque off for every motor (no reply: sent again each cycle while it is wanted).
    pub fn torque_off(&mut self) -> Result<(), Fault> {
        let data = self.for_motors(|_| Some([0u8]));
        self.sync_write(table::TORQUE_ENABLE, &data)?;
        self.torque = false;
        Ok(())
    }

    /// What the safety logic decided, on the bus, at once: writes need no reply, so nothing
    /// on the read side holds them back. A motor with a hardware error gets torque-off every
    /// cycle and nothing else (its Shutdown setting may not have turned it off). `near` says
    /// which motors stand within the engage step of their goal: the torque comes on only if
    /// all do, and comes on again only for those. Returns the motors found off while following
    /// and turned on again.
    pub fn apply(
        &mut self,
        action: Action,
        goals: &[i32; MAX_ACTUATORS],
        near: &[bool; MAX_ACTUATORS],
        reading: &Reading,
        profile_velocity: u32,
    ) -> Result<usize, Fault> {
        if reading.hardware_error.iter().any(|&e| e != 0) {
            let data = self.for_motors(|i| reading.faulted(i).then_some([0u8]));
            self.sync_write(table::TORQUE_ENABLE, &data)?;
        }
        let engage = near[..self.n].iter().all(|&n| n);
        match action {
            Action::Off => self.torque_off().map(|()| 0),
            Action::Hold => Ok(0),
            Action::Follow(_) if !self.torque && !engage => Ok(0),
            Action::Follow(_) => {
                // The goal first: the torque then holds where the controller wants, not
                // wherever the goal register was left.
                let data =
                    self.for_motors(|i| (!reading.faulted(i)).then_some(goals[i].to_le_bytes()));
                self.sync_write(table::GOAL_POSITION, &data)?;
                let n = self.n;
                let on: [bool; MAX_ACTUATORS] = if self.torque {
                    std::array::from_fn(|i| i < n && near[i] && self.lost_torque(i, reading))
                } else {
                    std::array::from_fn(|i| i < n && !reading.faulted(i))
                };
                let lost = if self.torque {
                    on.iter().filter(|&&o| o).count()
                } else {
                    0
                };
                if lost > 0 {
                    // Profile Velocity is RAM: a motor that restarted has lost it.
                    let data = self.for_motors(|i| on[i].then_some(profile_velocity.to_le_bytes()));
                    self.sync_write(table::PROFILE_VELOCITY, &data)?;
                }
                if on.contains(&true) {
                    let data = self.for_motors(|i| on[i].then_some([1u8]));
                    self.sync_write(table::TORQUE_ENABLE, &data)?;
                    let now = now_ns();
                    for i in (0..self.n).filter(|&i| on[i]) {
                        self.enabled_ns[i] = now;
                    }
                    self.torque = true;
                }
                Ok(lost)
            }
        }
    }

    /// The time read `ask` of the motors `asked` takes on the line: its instruction and every
    /// reply, each after its motor's Return Delay Time (ns).
    pub fn read_ns(&self, ask: Ask, asked: &[bool; MAX_ACTUATORS]) -> u64 {
        let delays = (0..self.n).filter(|&i| asked[i]).map(|i| self.delays[i]);
        self.line
            .sync_read_ns(usize::from(ask.address_len().1), delays)
    }

    /// Sends a sync read to the motors `only` names (all when `None`) in driver cycle `cycle`;
    /// its replies are taken by [`Link::take_replies`].
    pub fn ask(
        &mut self,
        ask: Ask,
        cycle: u64,
        only: Option<[bool; MAX_ACTUATORS]>,
    ) -> Result<(), Fault> {
        let asked = only.unwrap_or(std::array::from_fn(|i| i < self.n));
        let (address, len) = ask.address_len();
        let mut params = address.to_le_bytes().to_vec();
        params.extend(len.to_le_bytes());
        params.extend((0..self.n).filter(|&i| asked[i]).map(|i| self.ids[i]));
        self.wire
            .send(BROADCAST_ID, instruction::SYNC_READ, &params)
            .map_err(write_fault)?;
        let read_ns = self.read_ns(ask, &asked);
        self.pending = Some(Pending {
            ask,
            asked,
            due_ns: self.on_line(read_ns),
            sent_ns: now_ns(),
            sent_cycle: cycle,
            answered: [false; MAX_ACTUATORS],
            refused: [false; MAX_ACTUATORS],
        });
        Ok(())
    }

    /// Takes every reply that has arrived (waiting at most `wait` for the first) into
    /// `reading`. Returns whether the open read is complete. A port error ends the link.
    pub fn take_replies(
        &mut self,
        reading: &mut Reading,
        counts: &mut Counts,
        wait: Duration,
    ) -> Result<bool, Fault> {
        let mut wait = wait;
        loop {
            if self.pending.is_some_and(|p| p.missing().is_none()) {
                return Ok(true);
            }
            let arrival = self.wire.receive(wait);
            wait = Duration::ZERO;
            match arrival {
                None => return Ok(false),
                Some(Arrival::PortError(e)) => return Err(Fault::Port(e)),
                Some(Arrival::Status(s, at)) => {
                    self.last_reply_ns = now_ns();
                    let ids = &self.ids[..self.n];
                    let (torque, alert) = (&mut self.torque, &mut self.alert);
                    if let Some(p) = self.pending.as_mut()
                        && take(p, ids, &s, reading, torque, alert)
                    {
                        self.lateness.heard(at, p.due_ns);
                        continue;
                    }
                    // Late: for the oldest closed read still missing this motor's answer.
                    let late = (self.closed.iter_mut())
                        .find_map(|p| take(p, ids, &s, reading, torque, alert).then_some(p.due_ns));
                    if let Some(due_ns) = late {
                        self.lateness.heard(at, due_ns);
                        counts.late += 1;
                        counts.answered += 1;
                    } else {
                        counts.stray += 1;
                    }
                }
            }
        }
    }

    /// Closes the open read: a reply that has not come is lost (dropped, or a CRC error the
    /// line counted), unless it comes late, within 3 s.
    pub fn close_read(&mut self, counts: &mut Counts) -> Option<Closed> {
        let p = self.pending.take()?;
        let answered = p.answered.iter().filter(|&&a| a).count();
        let refused = p.refused.iter().filter(|&&r| r).count();
        let asked = p.asked.iter().filter(|&&a| a).count();
        let missing = asked - answered - refused;
        counts.asked += asked as u64;
        counts.answered += answered as u64;
        counts.refused += refused as u64;
        let now = now_ns();
        while self
            .closed
            .front()
            .is_some_and(|c| now.saturating_sub(c.sent_ns) > KEEP_CLOSED_NS)
        {
            self.closed.pop_front();
        }
        if missing > 0 {
            counts.timeouts += 1;
            self.closed.push_back(p);
        }
        Some(Closed {
            asked,
            missing_motors: p.missing(),
            answered,
            refused,
            missing,
        })
    }
}

impl Pending {
    /// The motors asked that have not answered, if any.
    fn missing(&self) -> Option<[bool; MAX_ACTUATORS]> {
        let m: [bool; MAX_ACTUATORS] =
            std::array::from_fn(|i| self.asked[i] && !self.answered[i] && !self.refused[i]);
        m.iter().any(|&m| m).then_some(m)
    }
}

/// A read closed.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Closed {
    pub asked: usize,
    /// The motors that did not answer, if any.
    pub missing_motors: Option<[bool; MAX_ACTUATORS]>,
    /// Replies with data.
    pub answered: usize,
    /// Replies with an error number.
    pub refused: usize,
    /// Replies that did not come (dropped or with a bad CRC).
    pub missing: usize,
}

/// One reply for read `p`: true when `p` asked for it and had not had it. An answer with an
/// error number is the motor refusing (it still carries the alert bit); a late answer's data
/// is kept only where it is newer than what the reading has.
fn take(
    p: &mut Pending,
    ids: &[u8],
    s: &Status,
    reading: &mut Reading,
    torque: &mut bool,
    alert: &mut Alert,
) -> bool {
    let Some(i) = ids.iter().position(|&id| id == s.id) else {
        return false;
    };
    if !p.asked[i] {
        return false;
    }
    let d = &s.params;
    let fits = match p.ask {
        Ask::Position => d.len() == 4,
        Ask::Data => d.len() == 10,
        Ask::Status => d.len() == 7,
    };
    let refused = s.error & 0x7F != 0;
    if p.answered[i] || p.refused[i] || !(fits || refused) {
        return false;
    }
    alert.heard(i, s.error & 0x80 != 0, p.ask);
    if refused {
        p.refused[i] = true;
        return true;
    }
    match p.ask {
        Ask::Data if reading.asked_ns[i].is_none_or(|a| a < p.sent_ns) => {
            reading.current_a[i] =
                f64::from(i16::from_le_bytes([d[0], d[1]])) * table::CURRENT_UNIT_A;
            reading.ticks[i] = i32::from_le_bytes([d[6], d[7], d[8], d[9]]);
            reading.asked_ns[i] = Some(p.sent_ns);
            reading.asked_cycle[i] = p.sent_cycle;
        }
        Ask::Position if reading.asked_ns[i].is_none_or(|a| a < p.sent_ns) => {
            reading.ticks[i] = i32::from_le_bytes([d[0], d[1], d[2], d[3]]);
            reading.asked_ns[i] = Some(p.sent_ns);
            reading.asked_cycle[i] = p.sent_cycle;
        }
        Ask::Data | Ask::Position => {}
        Ask::Status => {
            // A motor found on while the driver thinks all are off: the next `Off` resends.
            *torque |= d[0] != 0;
            if reading.torque_seen[i].is_none_or(|(sent_ns, _)| sent_ns < p.sent_ns) {
                reading.torque_seen[i] = Some((p.sent_ns, d[0] != 0));
            }
            // Sticky: cleared only by restarting the driver, once the cause is fixed.
            reading.hardware_error[i] |= d[6];
        }
    }
    p.answered[i] = true;
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;
    const IDS: [u8; 6] = [1, 2, 3, 4, 5, 6];

    fn settings(id: u8) -> Status {
        Status {
            id,
            error: 0,
            params: vec![3; usize::from(SURVEY_LEN)],
        }
    }

    #[test]
    fn only_a_status_read_sent_after_the_torque_went_on_can_find_it_lost() {
        let mut p = Pending {
            ask: Ask::Status,
            asked: std::array::from_fn(|i| i < 6),
            sent_ns: 50,
            due_ns: 50,
            sent_cycle: 1,
            answered: [false; MAX_ACTUATORS],
            refused: [false; MAX_ACTUATORS],
        };
        let off = |id| Status {
            id,
            error: 0,
            params: vec![0; 7],
        };
        let (mut reading, mut torque, mut alert) = (Reading::new(6), false, Alert::default());
        assert!(take(
            &mut p,
            &IDS,
            &off(3),
            &mut reading,
            &mut torque,
            &mut alert
        ));
        // Sent at 50: says nothing of a torque turned on at 60, everything of one at 40.
        assert!(!reading.found_off_since(2, 60) && reading.found_off_since(2, 40));
        // A late answer of an older read does not overwrite the newer one.
        let mut older = Pending {
            sent_ns: 10,
            answered: [false; MAX_ACTUATORS],
            ..p
        };
        let on = Status {
            params: vec![1, 0, 0, 0, 0, 0, 0],
            ..off(3)
        };
        assert!(take(
            &mut older,
            &IDS,
            &on,
            &mut reading,
            &mut torque,
            &mut alert
        ));
        assert!(reading.found_off_since(2, 40));
        assert!(!reading.found_off_since(0, 0), "not asked: not found off");
    }

    #[test]
    fn a_survey_asks_the_missing_motors_every_100_ms_until_each_has_answered() {
        let mut s = Survey::new(0, 6);
        assert!(s.ask_due(0), "at once");
        s.asked_ns = Some(0);
        assert!(!s.ask_due(99 * MS) && s.ask_due(100 * MS));
        for id in [2, 5] {
            assert_eq!(s.take(&IDS, &settings(id)), Heard::New);
        }
        assert_eq!(s.missing(&IDS), [1, 3, 4, 6]);
        // A late answer to an earlier ask, a refusal (no data), another length, a stranger.
        assert_eq!(s.take(&IDS, &settings(2)), Heard::Again);
        let refused = Status {
            id: 1,
            error: 0x02,
            params: vec![],
        };
        assert_eq!(s.take(&IDS, &refused), Heard::Other);
        let position = Status {
            params: vec![0; 4],
            ..settings(1)
        };
        assert_eq!(s.take(&IDS, &position), Heard::Other);
        assert_eq!(s.take(&IDS, &settings(9)), Heard::Other);
        // However long it takes: no budget ends it.
        assert!(s.ask_due(3_600_000 * MS));
        for id in [1, 3, 4, 6] {
            s.take(&IDS, &settings(id));
        }
        assert!(s.complete() && s.missing(&IDS).is_empty());
        assert!(!s.ask_due(3_600_000 * MS), "nothing left to ask");
    }

    #[test]
    fn the_missing_motors_are_named_after_2_s_then_every_10_s() {
        let mut s = Survey::new(1000 * MS, 6);
        let named: Vec<u64> = (0..=25_000)
            .step_by(100)
            .filter(|&t| s.name_due((1000 + t) * MS))
            .collect();
        assert_eq!(named, [2000, 12_000, 22_000]);
        for id in IDS {
            s.take(&IDS, &settings(id));
        }
        assert!(!s.name_due(100_000 * MS), "all answered: nothing to name");
    }
}
