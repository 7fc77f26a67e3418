//! An Ascension Bird tracker (trakSTAR / Flock of Birds class) on a pseudo-terminal: the device
//! side of the RS-232 protocol in [`softarm_tracker::bird`].
//!
//! [`BirdDevice`] is the pure device model: it parses the bytes the host writes and produces the
//! bytes the unit would answer. [`serve`] runs it on a [`Pty`], streams on absolute deadlines,
//! and injects faults ([`BirdFaults`]) for tests.
//!
//! Commands understood: POSITION and POSITION/ANGLES (switch the record format), POINT (one
//! record now; also ends STREAM mode, as on the real unit), STREAM, STREAM STOP, RUN and SLEEP
//! (no output while asleep; a STREAM mode set before or during SLEEP resumes on RUN).
//! Multi-byte commands a host commonly sends while setting up are consumed whole, so their data
//! bytes are never taken for commands:
//! - EXAMINE VALUE (`O` + parameter): answers BIRD STATUS (2 bytes: master, initialized,
//!   running/sleeping, format and streaming bits) and POSITION SCALING (2 bytes); other
//!   parameters get no answer (logged at debug).
//! - CHANGE VALUE (`P` + parameter + data, the data length from
//!   [`softarm_tracker::bird::change_value_len`]): POSITION SCALING 0/1 switches the position
//!   full scale to 36/72 in; other parameters are accepted and ignored. An unknown parameter
//!   (length unknown) consumes no data.
//! - HEMISPHERE (`L` + axis + sign): selects the hemisphere positions are reported in (below);
//!   EXAMINE VALUE and CHANGE VALUE of parameter 22 read and set it (two bytes, axis and sign).
//!   Axis `0x00` is X, `0x06` Y, `0x0C` Z; sign 0 the positive half, 1 the negative; other bytes
//!   leave the selection as it was (logged at debug).
//! - ANGLE ALIGN / REFERENCE FRAME (`J`/`H` + 12, `q`/`r` + 6),
//!   BUTTON MODE (`M` + 1), NEXT TRANSMITTER (`0` + 1), SYNC (`A` + 1), super-expanded RS232 TO
//!   FBB (`0xA0` + address): data consumed, otherwise ignored.
//! - RS232 TO FBB prefixes (`0xE0..=0xFF`), which hosts of a flock put before every command, are
//!   accepted silently: this unit answers whatever address is named.
//!
//! Hemisphere folding, as a real unit does it: the transmitter's field is the same at p and -p,
//! so a sensor on the far side of the selected hemisphere's boundary plane (p · h < 0, with h
//! the hemisphere's direction: +X forward, -X aft, -Z upper, +Z lower, -Y left, +Y right) is
//! reported at -p: X, Y and Z all negated. Its angles are reported as they are (the field
//! vectors the sensor sees, and so the orientation worked out from them, are the same at both
//! points). A sensor on the plane is reported as it is. The unit starts in the forward
//! hemisphere.
//!
//! Two switches of [`BirdFaults`] make it an older unit: one that ignores STREAM STOP (only
//! POINT ends its stream) and one that does not answer EXAMINE VALUE of the hemisphere.
//!
//! Any other byte is ignored (logged at debug). Only the POSITION and POSITION/ANGLES formats are
//! modelled; the other format commands (ANGLES, MATRIX, QUATERNION, ...) are ignored, and GROUP
//! MODE (an address byte after each record) is not modelled.

use std::fs::{File, OpenOptions};
use std::io;
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::thread;
use std::time::{Duration, Instant};

use nix::fcntl::OFlag;
use nix::sys::termios::{FlushArg, tcflush};
use softarm_tracker::bird::{
    CHANGE_VALUE, EXAMINE_VALUE, FULL_SCALE_EXTENDED_IN, FULL_SCALE_STANDARD_IN, HEMISPHERE,
    MAX_RECORD_BYTES, POINT, POSITION, POSITION_ANGLES, RUN, Record, RecordFormat, SLEEP, STREAM,
    STREAM_STOP, change_value_len, encode, param, status,
};
use tracing::{debug, info, warn};

use crate::pty::Pty;

/// ANGLE ALIGN (6 words of sines and cosines).
const ANGLE_ALIGN1: u8 = b'J';
/// REFERENCE FRAME (6 words).
const REFERENCE_FRAME1: u8 = b'H';
/// ANGLE ALIGN, angles form (3 words).
const ANGLE_ALIGN2: u8 = b'q';
/// REFERENCE FRAME, angles form (3 words).
const REFERENCE_FRAME2: u8 = b'r';
/// BUTTON MODE (1 byte).
const BUTTON_MODE: u8 = b'M';
/// NEXT TRANSMITTER (1 byte: address and transmitter number).
const NEXT_TRANSMITTER: u8 = b'0';
/// SYNC (1 byte: sync type).
const SYNC: u8 = b'A';
/// RS232 TO FBB in super-expanded addressing: followed by the address byte.
const RS232_TO_FBB_SUPER_EXPANDED: u8 = 0xA0;

/// Fault injection for tests, shared with the serving thread.
#[derive(Debug, Default)]
pub struct BirdFaults {
    /// Stop answering and streaming: what the host writes is read and discarded, nothing is
    /// sent, the device keeps its state (as with the cable pulled). Clearing it resumes.
    pub silent: AtomicBool,
    /// 0 = never; else, about once per this many records sent, replace a byte with a garbage
    /// byte, insert a garbage byte, or drop a byte (one of the three at random).
    pub corrupt_one_in: AtomicU32,
    /// An older Flock of Birds: STREAM STOP (`?`) is not a command it knows.
    pub ignore_stream_stop: AtomicBool,
    /// An older unit (software revision before 3.66): EXAMINE VALUE of the hemisphere gets no
    /// answer.
    pub no_hemisphere_readback: AtomicBool,
    /// Stalls the line for this many ms from when the serving thread takes it (and clears it):
    /// nothing is read or written meanwhile, as when a loaded host's pty worker waits for a
    /// CPU. The unit goes on making its records; they wait and come at once when the stall
    /// ends, and the commands the host wrote meanwhile are read then.
    pub stall_ms: AtomicU64,
}

/// What the unit has done, shared with the serving thread.
#[derive(Debug, Default)]
pub struct BirdCounts {
    /// Records sent (POINT answers and streamed records), counted when made, before any
    /// corruption (a stalled line holds them back after).
    pub records: AtomicU64,
    /// EXAMINE VALUE of the hemisphere heard: a driver asks it once each time it opens the
    /// port and sets the unit up, so this counts the opens.
    pub hemisphere_reads: AtomicU64,
}

impl BirdFaults {
    /// No faults.
    pub fn new() -> Self {
        Self::default()
    }
}

/// A command whose data bytes are still to come.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Pending {
    /// The next byte is a command.
    Command,
    /// The next byte is the parameter of EXAMINE VALUE.
    ExamineParameter,
    /// The next byte is the parameter of CHANGE VALUE.
    ChangeParameter,
    /// Data of CHANGE VALUE `parameter`: `have` of `need` bytes are in `data`.
    ChangeData {
        parameter: u8,
        have: usize,
        need: usize,
    },
    /// `left` data bytes of a command to consume and ignore.
    Skip { left: usize },
    /// The data of HEMISPHERE: the axis byte, once it has come.
    HemisphereData { axis: Option<u8> },
}

/// A selected hemisphere: the axis (0 = X, 1 = Y, 2 = Z) and whether it is the negative half.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Selected {
    pub axis: usize,
    pub negative: bool,
}

impl Selected {
    /// The unit's default: forward, +X.
    pub const FORWARD: Self = Self {
        axis: 0,
        negative: false,
    };

    /// From the two bytes of HEMISPHERE (axis, sign), written from the command's description:
    /// the axis byte is 0, 6 or 12 for X, Y, Z and the sign byte 0 or 1.
    pub fn from_bytes(axis: u8, sign: u8) -> Option<Self> {
        let axis = match axis {
            0x00 => 0,
            0x06 => 1,
            0x0C => 2,
            _ => return None,
        };
        let negative = match sign {
            0 => false,
            1 => true,
            _ => return None,
        };
        Some(Self { axis, negative })
    }

    /// The two bytes (axis, sign) EXAMINE VALUE answers.
    pub fn bytes(self) -> [u8; 2] {
        [6 * self.axis as u8, u8::from(self.negative)]
    }

    /// Where a sensor truly at `p` is reported: mirrored through the origin when it is on the
    /// other side of the boundary plane.
    pub fn fold(self, p: [f64; 3]) -> [f64; 3] {
        let outside = if self.negative {
            p[self.axis] > 0.0
        } else {
            p[self.axis] < 0.0
        };
        if outside { p.map(|v| -v) } else { p }
    }
}

/// The longest CHANGE VALUE data (14 bytes) the device keeps.
const MAX_CHANGE_DATA: usize = 16;

/// The device: answers the single-byte commands as the real unit does.
#[derive(Clone, Debug)]
pub struct BirdDevice {
    full_scale_in: f64,
    format: RecordFormat,
    streaming: bool,
    asleep: bool,
    pending: Pending,
    change_data: [u8; MAX_CHANGE_DATA],
    records: u64,
    hemisphere: Selected,
    hemisphere_reads: u64,
    knows_stream_stop: bool,
    answers_hemisphere: bool,
}

impl BirdDevice {
    /// A unit awake, in POSITION format, not streaming (point mode), whose positions have a full
    /// scale of `full_scale_in` inches.
    ///
    /// # Panics
    ///
    /// If `full_scale_in` is not a finite positive number.
    pub fn new(full_scale_in: f64) -> Self {
        assert!(
            full_scale_in.is_finite() && full_scale_in > 0.0,
            "full scale must be a finite positive number of inches, got {full_scale_in}"
        );
        Self {
            full_scale_in,
            format: RecordFormat::Position,
            streaming: false,
            asleep: false,
            pending: Pending::Command,
            change_data: [0; MAX_CHANGE_DATA],
            records: 0,
            hemisphere: Selected::FORWARD,
            hemisphere_reads: 0,
            knows_stream_stop: true,
            answers_hemisphere: true,
        }
    }

    /// Makes this an older unit: without STREAM STOP (`knows_stream_stop` false), without the
    /// hemisphere parameter of EXAMINE VALUE (`answers_hemisphere` false).
    pub fn set_model(&mut self, knows_stream_stop: bool, answers_hemisphere: bool) {
        self.knows_stream_stop = knows_stream_stop;
        self.answers_hemisphere = answers_hemisphere;
    }

    /// The selected hemisphere.
    pub fn hemisphere(&self) -> Selected {
        self.hemisphere
    }

    /// Feeds bytes the host wrote; returns what the device answers right away (a POINT gets one
    /// record of the current position) into `out`.
    pub fn receive(
        &mut self,
        bytes: &[u8],
        position_in: [f64; 3],
        angles_deg: [f64; 3],
        out: &mut Vec<u8>,
    ) {
        for &b in bytes {
            self.pending = match self.pending {
                Pending::Command => self.command(b, position_in, angles_deg, out),
                Pending::ExamineParameter => {
                    self.examine(b, out);
                    Pending::Command
                }
                Pending::ChangeParameter => match change_value_len(b) {
                    Some(0) => Pending::Command,
                    Some(need) => Pending::ChangeData {
                        parameter: b,
                        have: 0,
                        need,
                    },
                    None => {
                        debug!(parameter = b, "bird: CHANGE VALUE of an unknown parameter");
                        Pending::Command
                    }
                },
                Pending::ChangeData {
                    parameter,
                    have,
                    need,
                } => {
                    if have < MAX_CHANGE_DATA {
                        self.change_data[have] = b;
                    }
                    if have + 1 == need {
                        self.change(parameter, need);
                        Pending::Command
                    } else {
                        Pending::ChangeData {
                            parameter,
                            have: have + 1,
                            need,
                        }
                    }
                }
                Pending::HemisphereData { axis: None } => Pending::HemisphereData { axis: Some(b) },
                Pending::HemisphereData { axis: Some(axis) } => {
                    self.select(axis, b);
                    Pending::Command
                }
                Pending::Skip { left } => {
                    if left <= 1 {
                        Pending::Command
                    } else {
                        Pending::Skip { left: left - 1 }
                    }
                }
            };
        }
    }

    /// Handles a command byte; returns what the following bytes are.
    fn command(
        &mut self,
        b: u8,
        position_in: [f64; 3],
        angles_deg: [f64; 3],
        out: &mut Vec<u8>,
    ) -> Pending {
        let skip = |left| Pending::Skip { left };
        match b {
            POSITION | POSITION_ANGLES => {
                if let Some(format) = RecordFormat::from_command(b) {
                    self.format = format;
                }
            }
            POINT => {
                self.streaming = false;
                if !self.asleep {
                    self.record(position_in, angles_deg, out);
                }
            }
            STREAM => self.streaming = true,
            STREAM_STOP if self.knows_stream_stop => self.streaming = false,
            RUN => self.asleep = false,
            SLEEP => self.asleep = true,
            EXAMINE_VALUE => return Pending::ExamineParameter,
            CHANGE_VALUE => return Pending::ChangeParameter,
            HEMISPHERE => return Pending::HemisphereData { axis: None },
            ANGLE_ALIGN1 | REFERENCE_FRAME1 => return skip(12),
            ANGLE_ALIGN2 | REFERENCE_FRAME2 => return skip(6),
            BUTTON_MODE | NEXT_TRANSMITTER | SYNC | RS232_TO_FBB_SUPER_EXPANDED => return skip(1),
            0xE0..=0xFF => {} // RS232 TO FBB prefix: this unit answers any address
            _ => debug!(byte = b, "bird: ignored command byte"),
        }
        Pending::Command
    }

    /// Selects the hemisphere HEMISPHERE or CHANGE VALUE names (bytes that name none: ignored).
    fn select(&mut self, axis: u8, sign: u8) {
        match Selected::from_bytes(axis, sign) {
            Some(h) => self.hemisphere = h,
            None => debug!(axis, sign, "bird: no such hemisphere; selection unchanged"),
        }
    }

    /// Answers EXAMINE VALUE of `parameter`.
    fn examine(&mut self, parameter: u8, out: &mut Vec<u8>) {
        if parameter == param::HEMISPHERE {
            self.hemisphere_reads += 1;
        }
        let word: u16 = match parameter {
            param::HEMISPHERE if self.answers_hemisphere => {
                u16::from_le_bytes(self.hemisphere.bytes())
            }
            param::BIRD_STATUS => {
                let format = u16::from(self.format.command() - POSITION + 1) << 1;
                let mut s = status::MASTER | status::INITIALIZED | format;
                s |= if self.asleep {
                    status::SLEEPING
                } else {
                    status::RUNNING
                };
                if self.streaming {
                    s |= status::STREAMING;
                }
                s
            }
            param::POSITION_SCALING => u16::from(self.full_scale_in > FULL_SCALE_STANDARD_IN),
            _ => {
                debug!(parameter, "bird: EXAMINE VALUE not answered");
                return;
            }
        };
        out.extend_from_slice(&word.to_le_bytes());
    }

    /// Applies CHANGE VALUE of `parameter` once its `len` data bytes are in.
    fn change(&mut self, parameter: u8, len: usize) {
        match parameter {
            param::HEMISPHERE => self.select(self.change_data[0], self.change_data[1]),
            param::POSITION_SCALING => {
                match u16::from_le_bytes([self.change_data[0], self.change_data[1]]) {
                    0 => self.full_scale_in = FULL_SCALE_STANDARD_IN,
                    1 => self.full_scale_in = FULL_SCALE_EXTENDED_IN,
                    v => debug!(value = v, "bird: unsupported POSITION SCALING ignored"),
                }
            }
            _ => debug!(
                parameter,
                data = ?&self.change_data[..len.min(MAX_CHANGE_DATA)],
                "bird: CHANGE VALUE accepted and ignored"
            ),
        }
    }

    /// Appends one record of the pose in the current format.
    fn record(&mut self, position_in: [f64; 3], angles_deg: [f64; 3], out: &mut Vec<u8>) {
        let record = Record {
            position_in: self.hemisphere.fold(position_in),
            angles_deg: Some(angles_deg),
        };
        let mut buf = [0u8; MAX_RECORD_BYTES];
        let n = encode(self.format, self.full_scale_in, &record, &mut buf);
        out.extend_from_slice(&buf[..n]);
        self.records += 1;
    }

    /// Whether the unit is in STREAM mode (it sends only while also awake).
    pub fn streaming(&self) -> bool {
        self.streaming
    }

    /// Whether the unit is asleep (SLEEP; no output until RUN).
    pub fn asleep(&self) -> bool {
        self.asleep
    }

    /// The current record format.
    pub fn format(&self) -> RecordFormat {
        self.format
    }

    /// The current position full scale, inches.
    pub fn full_scale_in(&self) -> f64 {
        self.full_scale_in
    }

    /// Records produced so far (POINT answers and streamed records).
    pub fn records_sent(&self) -> u64 {
        self.records
    }

    /// EXAMINE VALUE of the hemisphere heard so far, answered or not.
    pub fn hemisphere_reads(&self) -> u64 {
        self.hemisphere_reads
    }

    /// One streamed record of the given pose into `out` when streaming (nothing otherwise, or
    /// while asleep).
    pub fn stream(&mut self, position_in: [f64; 3], angles_deg: [f64; 3], out: &mut Vec<u8>) {
        if self.streaming && !self.asleep {
            self.record(position_in, angles_deg, out);
        }
    }
}

/// A small deterministic generator for fault injection.
struct XorShift(u64);

impl XorShift {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// Uniform-enough in `0..n` (`n > 0`).
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

/// Replaces a byte of `out` with garbage, inserts a garbage byte or drops a byte.
fn corrupt(out: &mut Vec<u8>, rng: &mut XorShift) {
    if out.is_empty() {
        return;
    }
    let at = rng.below(out.len() as u64) as usize;
    let garbage = rng.next() as u8;
    match rng.below(3) {
        0 => out[at] = garbage,
        1 => out.insert(at, garbage),
        _ => {
            out.remove(at);
        }
    }
}

/// How long a write may block (the host not reading) before the unread input of the host is
/// dropped, as a serial port does when its receive buffer overruns.
const OVERRUN_AFTER: Duration = Duration::from_millis(100);
/// The longest the loop waits without looking at `stop`.
const MAX_WAIT: Duration = Duration::from_millis(50);

/// Drops the host's unread input when a write has blocked for longer than [`OVERRUN_AFTER`], so
/// a host that stops reading cannot stall the device (or its `stop`).
fn overrun_guard(slave: File, writing_since_ms: &AtomicU64, done: &AtomicBool, epoch: Instant) {
    while !done.load(Ordering::Acquire) {
        thread::sleep(Duration::from_millis(20));
        let since = writing_since_ms.load(Ordering::Acquire);
        if since == 0 {
            continue;
        }
        let now = epoch.elapsed().as_millis() as u64 + 1;
        if now.saturating_sub(since) > OVERRUN_AFTER.as_millis() as u64 {
            match tcflush(&slave, FlushArg::TCIFLUSH) {
                Ok(()) => debug!("bird: host not reading; its unread input dropped"),
                Err(e) => warn!(error = %e, "bird: could not drop the host's unread input"),
            }
        }
    }
}

/// Opens the slave side once more, for [`overrun_guard`].
fn open_slave(path: &Path) -> io::Result<File> {
    OpenOptions::new()
        .read(true)
        .custom_flags((OFlag::O_NOCTTY | OFlag::O_NONBLOCK | OFlag::O_CLOEXEC).bits())
        .open(path)
}

/// Serves a device on `pty` until `stop`: reads commands, streams at `rate_hz` on absolute
/// deadlines, asks `pose()` for the sensor pose in the tracker frame (inches; degrees as
/// azimuth, elevation, roll) at each record, applies `faults`, and counts in `counts` what it
/// did (records as they are handed to the pty, before any corruption).
///
/// A host that stops reading cannot stall the loop: once a write has blocked for 100 ms the
/// host's unread input is dropped, as an overrun serial port would.
///
/// # Errors
///
/// `InvalidInput` for a rate or full scale that is not a finite positive number; otherwise the
/// first error reading or writing the pty.
pub fn serve(
    mut pty: Pty,
    rate_hz: f64,
    full_scale_in: f64,
    mut pose: impl FnMut() -> ([f64; 3], [f64; 3]),
    faults: Arc<BirdFaults>,
    stop: Arc<AtomicBool>,
    counts: Arc<BirdCounts>,
) -> io::Result<()> {
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("stream rate must be a positive number of Hz, got {rate_hz}"),
        ));
    }
    if !(full_scale_in.is_finite() && full_scale_in > 0.0) {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("full scale must be a positive number of inches, got {full_scale_in}"),
        ));
    }
    let period = Duration::try_from_secs_f64(1.0 / rate_hz).map_err(|_| {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("stream rate {rate_hz} Hz is too low"),
        )
    })?;
    crate::run_as_device("tracker");
    let shared = Shared {
        faults: &faults,
        stop: &stop,
        counts: &counts,
        writing_since_ms: AtomicU64::new(0),
        epoch: Instant::now(),
    };
    let done = AtomicBool::new(false);
    let guard = match open_slave(pty.path()) {
        Ok(f) => Some(f),
        Err(e) => {
            warn!(error = %e, "bird: no overrun guard; a host that stops reading can stall the emulator");
            None
        }
    };
    info!(path = %pty.path().display(), rate_hz, full_scale_in, "bird emulator serving");

    thread::scope(|s| {
        if let Some(slave) = guard {
            let (w, d, epoch) = (&shared.writing_since_ms, &done, shared.epoch);
            s.spawn(move || overrun_guard(slave, w, d, epoch));
        }
        let result = serve_loop(&mut pty, period, full_scale_in, &mut pose, &shared);
        done.store(true, Ordering::Release);
        result
    })
}

/// What [`serve_loop`] shares with its caller and the overrun guard.
struct Shared<'a> {
    faults: &'a BirdFaults,
    stop: &'a AtomicBool,
    counts: &'a BirdCounts,
    writing_since_ms: AtomicU64,
    epoch: Instant,
}

/// A stalled line ([`BirdFaults::stall_ms`]): until when, and the bytes that wait for it.
#[derive(Default)]
struct Stall {
    until: Option<Instant>,
    held: Vec<u8>,
}

impl Stall {
    /// Takes a stall asked for; whether the line is stalled now.
    fn on(&mut self, faults: &BirdFaults, now: Instant) -> bool {
        let ms = faults.stall_ms.swap(0, Ordering::AcqRel);
        if ms > 0 {
            self.until = Some(now + Duration::from_millis(ms));
        }
        self.until.is_some_and(|u| now < u)
    }

    /// The bytes to write now: none while stalled (they are held), else what was held and `out`.
    fn pass(&mut self, stalled: bool, out: &mut Vec<u8>) {
        if stalled {
            self.held.append(out);
        } else if !self.held.is_empty() {
            self.held.append(out);
            std::mem::swap(&mut self.held, out);
        }
    }
}

/// The body of [`serve`].
fn serve_loop(
    pty: &mut Pty,
    period: Duration,
    full_scale_in: f64,
    pose: &mut impl FnMut() -> ([f64; 3], [f64; 3]),
    sh: &Shared,
) -> io::Result<()> {
    let mut dev = BirdDevice::new(full_scale_in);
    let mut rng = XorShift(0x9e37_79b9_7f4a_7c15);
    let mut buf = [0u8; 256];
    let mut out = Vec::with_capacity(64);
    let mut next = Instant::now() + period;
    let mut last_pose = ([0.0; 3], [0.0; 3]);
    let mut stall = Stall::default();
    while !sh.stop.load(Ordering::Acquire) {
        out.clear();
        let before = dev.records_sent();
        let silent = sh.faults.silent.load(Ordering::Acquire);
        let stalled = stall.on(sh.faults, Instant::now());
        dev.set_model(
            !sh.faults.ignore_stream_stop.load(Ordering::Relaxed),
            !sh.faults.no_hemisphere_readback.load(Ordering::Relaxed),
        );

        // Commands, until the next deadline (whole milliseconds; 0 just polls); none read
        // while the line is stalled.
        let wait = next.saturating_duration_since(Instant::now()).min(MAX_WAIT);
        let n = if stalled {
            thread::sleep(wait);
            0
        } else {
            pty.read_timeout(&mut buf, wait)?
        };
        if n > 0 {
            if !silent {
                if buf[..n].contains(&POINT) {
                    last_pose = pose();
                }
                let reads = dev.hemisphere_reads();
                dev.receive(&buf[..n], last_pose.0, last_pose.1, &mut out);
                // Added, not stored: the counts go on across a restarted emulator.
                let heard = dev.hemisphere_reads() - reads;
                sh.counts
                    .hemisphere_reads
                    .fetch_add(heard, Ordering::Release);
            }
        } else {
            let rest = next.saturating_duration_since(Instant::now());
            if rest < Duration::from_millis(1) {
                thread::sleep(rest);
            }
        }

        let now = Instant::now();
        if now >= next {
            next += period;
            if next <= now {
                // Fell behind (a stalled host, a loaded machine): skip, do not burst.
                next = now + period;
            }
            if !silent && dev.streaming() && !dev.asleep() {
                last_pose = pose();
                dev.stream(last_pose.0, last_pose.1, &mut out);
            }
        }
        let records = dev.records_sent() - before;
        corrupt_records(sh.faults, records, &mut out, &mut rng);
        // Counted when made, so a host that has read a record finds it counted.
        sh.counts.records.fetch_add(records, Ordering::Release);
        stall.pass(stalled, &mut out);
        if !out.is_empty() {
            write(pty, &out, sh)?;
        }
    }
    Ok(())
}

/// Corrupts about one of `faults.corrupt_one_in` of the `records` just made in `out`.
fn corrupt_records(faults: &BirdFaults, records: u64, out: &mut Vec<u8>, rng: &mut XorShift) {
    let one_in = u64::from(faults.corrupt_one_in.load(Ordering::Relaxed));
    if one_in > 0 {
        for _ in 0..records {
            if rng.below(one_in) == 0 {
                corrupt(out, rng);
            }
        }
    }
}

/// Writes `out` to the host, telling the overrun guard how long the write has blocked.
fn write(pty: &mut Pty, out: &[u8], sh: &Shared) -> io::Result<()> {
    let since = sh.epoch.elapsed().as_millis() as u64 + 1;
    sh.writing_since_ms.store(since, Ordering::Release);
    let written = pty.write_all(out);
    sh.writing_since_ms.store(0, Ordering::Release);
    written
}

#[cfg(test)]
mod tests {
    use super::*;
    use softarm_tracker::bird::{Decoder, DecoderStats};

    const FS: f64 = 36.0;
    const ANG_LSB: f64 = 180.0 / 8192.0;
    const P: [f64; 3] = [10.5, -7.25, 3.0];
    const A: [f64; 3] = [30.0, -20.0, 135.5];

    fn close(r: &Record, p: [f64; 3], a: Option<[f64; 3]>, fs: f64) -> bool {
        let pos_ok = (0..3).all(|i| (r.position_in[i] - p[i]).abs() <= fs / 8192.0);
        let ang_ok = match (r.angles_deg, a) {
            (Some(x), Some(y)) => (0..3).all(|i| (x[i] - y[i]).abs() <= ANG_LSB),
            (None, None) => true,
            _ => false,
        };
        pos_ok && ang_ok
    }

    fn decode_all(format: RecordFormat, fs: f64, bytes: &[u8]) -> (Vec<Record>, DecoderStats) {
        let mut d = Decoder::new(format, fs);
        let got = bytes.iter().filter_map(|&b| d.push(b)).collect();
        (got, d.stats())
    }

    #[test]
    fn starts_in_point_mode_position_format() {
        let dev = BirdDevice::new(FS);
        assert_eq!(dev.format(), RecordFormat::Position);
        assert!(!dev.streaming());
        assert!(!dev.asleep());
        assert_eq!(dev.full_scale_in(), FS);
    }

    #[test]
    fn point_answers_one_record_of_the_pose() {
        let mut dev = BirdDevice::new(FS);
        let mut out = Vec::new();
        dev.receive(&[POINT], P, A, &mut out);
        assert_eq!(out.len(), 6);
        let (got, stats) = decode_all(RecordFormat::Position, FS, &out);
        assert_eq!(got.len(), 1);
        assert!(close(&got[0], P, None, FS), "{got:?}");
        assert_eq!(stats.malformed + stats.dropped_bytes, 0);
        assert!(!dev.streaming());
        assert_eq!(dev.records_sent(), 1);

        // Switch format: POSITION/ANGLES then POINT in one write.
        out.clear();
        dev.receive(&[POSITION_ANGLES, POINT], P, A, &mut out);
        assert_eq!(dev.format(), RecordFormat::PositionAngles);
        assert_eq!(out.len(), 12);
        let (got, _) = decode_all(RecordFormat::PositionAngles, FS, &out);
        assert_eq!(got.len(), 1);
        assert!(close(&got[0], P, Some(A), FS), "{got:?}");

        // And back.
        out.clear();
        dev.receive(&[POSITION], P, A, &mut out);
        assert!(out.is_empty());
        assert_eq!(dev.format(), RecordFormat::Position);
    }

    #[test]
    fn stream_and_stream_stop() {
        let mut dev = BirdDevice::new(FS);
        let mut out = Vec::new();
        dev.stream(P, A, &mut out);
        assert!(out.is_empty(), "point mode: nothing streamed");

        dev.receive(&[POSITION_ANGLES, STREAM], P, A, &mut out);
        assert!(out.is_empty(), "STREAM itself answers nothing");
        assert!(dev.streaming());
        for _ in 0..3 {
            dev.stream(P, A, &mut out);
        }
        let (got, stats) = decode_all(RecordFormat::PositionAngles, FS, &out);
        assert_eq!(got.len(), 3);
        assert!(got.iter().all(|r| close(r, P, Some(A), FS)));
        assert_eq!(stats.malformed + stats.dropped_bytes, 0);

        out.clear();
        dev.receive(&[STREAM_STOP], P, A, &mut out);
        assert!(!dev.streaming());
        dev.stream(P, A, &mut out);
        assert!(out.is_empty());

        // POINT ends streaming too, and answers one record.
        dev.receive(&[STREAM], P, A, &mut out);
        assert!(dev.streaming());
        dev.receive(&[POINT], P, A, &mut out);
        assert!(!dev.streaming());
        assert_eq!(out.len(), 12);
        out.clear();
        dev.stream(P, A, &mut out);
        assert!(out.is_empty());
    }

    #[test]
    fn sleep_silences_until_run() {
        let mut dev = BirdDevice::new(FS);
        let mut out = Vec::new();
        dev.receive(&[STREAM, SLEEP], P, A, &mut out);
        assert!(dev.asleep() && dev.streaming());
        dev.stream(P, A, &mut out);
        dev.receive(&[POINT], P, A, &mut out);
        assert!(out.is_empty(), "asleep: no records");
        dev.receive(&[RUN, STREAM], P, A, &mut out);
        assert!(!dev.asleep());
        dev.stream(P, A, &mut out);
        assert_eq!(out.len(), 6);
    }

    #[test]
    fn multi_byte_commands_are_consumed_whole() {
        let mut dev = BirdDevice::new(FS);
        let mut out = Vec::new();
        // RS232 TO FBB prefix, HEMISPHERE with data, CHANGE VALUE MEASUREMENT RATE whose data
        // bytes are POINT and STREAM, CHANGE VALUE GROUP MODE, an ANGLE ALIGN full of POINTs.
        let mut host = vec![0xF1, HEMISPHERE, 0x0C, 0x01];
        host.extend_from_slice(&[CHANGE_VALUE, param::MEASUREMENT_RATE, POINT, STREAM]);
        host.extend_from_slice(&[CHANGE_VALUE, param::GROUP_MODE, 0]);
        host.push(ANGLE_ALIGN1);
        host.extend_from_slice(&[POINT; 12]);
        host.extend_from_slice(&[b'?' + 0x80, 0x13]); // junk: ignored
        dev.receive(&host, P, A, &mut out);
        assert!(out.is_empty(), "no data byte taken for POINT: {out:?}");
        assert!(!dev.streaming(), "no data byte taken for STREAM");

        // The byte after them is a command again.
        dev.receive(&[0xF1, POINT], P, A, &mut out);
        assert_eq!(out.len(), 6);

        // Split across writes.
        out.clear();
        dev.receive(&[CHANGE_VALUE], P, A, &mut out);
        dev.receive(&[param::MEASUREMENT_RATE, POINT], P, A, &mut out);
        dev.receive(&[POINT], P, A, &mut out);
        assert!(out.is_empty());
        dev.receive(&[POINT], P, A, &mut out);
        assert_eq!(out.len(), 6);
    }

    #[test]
    fn position_scaling_is_examined_and_changed() {
        let mut dev = BirdDevice::new(FS);
        let mut out = Vec::new();
        dev.receive(&[EXAMINE_VALUE, param::POSITION_SCALING], P, A, &mut out);
        assert_eq!(out, [0, 0]);

        out.clear();
        dev.receive(
            &[CHANGE_VALUE, param::POSITION_SCALING, 1, 0],
            P,
            A,
            &mut out,
        );
        assert!(out.is_empty());
        assert_eq!(dev.full_scale_in(), 72.0);
        dev.receive(&[EXAMINE_VALUE, param::POSITION_SCALING], P, A, &mut out);
        assert_eq!(out, [1, 0]);

        // 40 in is beyond 36 in full scale but within 72.
        out.clear();
        let far = [40.0, -50.0, 60.0];
        dev.receive(&[POINT], far, A, &mut out);
        let (got, _) = decode_all(RecordFormat::Position, 72.0, &out);
        assert!(close(&got[0], far, None, 72.0), "{got:?}");

        dev.receive(
            &[CHANGE_VALUE, param::POSITION_SCALING, 0, 0],
            P,
            A,
            &mut out,
        );
        assert_eq!(dev.full_scale_in(), 36.0);
    }

    #[test]
    fn bird_status_reflects_the_state() {
        let mut dev = BirdDevice::new(FS);
        let mut out = Vec::new();
        let mut status_word = |dev: &mut BirdDevice| {
            out.clear();
            dev.receive(&[EXAMINE_VALUE, param::BIRD_STATUS], P, A, &mut out);
            assert_eq!(out.len(), 2);
            u16::from_le_bytes([out[0], out[1]])
        };
        let s = status_word(&mut dev);
        assert_eq!(s & status::MASTER, status::MASTER);
        assert_eq!(s & status::RUNNING, status::RUNNING);
        assert_eq!(s & status::STREAMING, 0);
        assert_eq!((s & status::FORMAT_MASK) >> 1, 1, "POSITION");

        dev.receive(&[POSITION_ANGLES, STREAM, SLEEP], P, A, &mut Vec::new());
        let s = status_word(&mut dev);
        assert_eq!(s & status::STREAMING, status::STREAMING);
        assert_eq!(s & status::SLEEPING, status::SLEEPING);
        assert_eq!(s & status::RUNNING, 0);
        assert_eq!((s & status::FORMAT_MASK) >> 1, 4, "POSITION/ANGLES");

        // Unanswered parameter: nothing comes, and the next byte is a command.
        out.clear();
        dev.receive(
            &[EXAMINE_VALUE, param::SOFTWARE_REVISION, RUN, POINT],
            P,
            A,
            &mut out,
        );
        assert_eq!(out.len(), 12);
    }

    #[test]
    fn corrupt_changes_the_bytes() {
        let mut rng = XorShift(7);
        let mut lens = [0usize; 3];
        for _ in 0..300 {
            let mut out = vec![0x80u8, 1, 2, 3, 4, 5];
            corrupt(&mut out, &mut rng);
            lens[out.len() - 5] += 1;
        }
        assert!(
            lens.iter().all(|&n| n > 50),
            "drop, replace and insert all happen: {lens:?}"
        );
        let mut empty = Vec::new();
        corrupt(&mut empty, &mut rng);
        assert!(empty.is_empty());
    }

    /// Reads from `port` into `decoder` until `enough` says so or `limit` passes; returns the
    /// records and the number of bytes read.
    fn read_until(
        port: &serial2::SerialPort,
        decoder: &mut Decoder,
        limit: Duration,
        mut enough: impl FnMut(&[Record], &Decoder) -> bool,
    ) -> (Vec<Record>, usize) {
        let deadline = Instant::now() + limit;
        let mut got = Vec::new();
        let mut bytes = 0;
        let mut buf = [0u8; 256];
        while Instant::now() < deadline && !enough(&got, decoder) {
            match port.read(&mut buf) {
                Ok(n) => {
                    bytes += n;
                    got.extend(buf[..n].iter().filter_map(|&b| decoder.push(b)));
                }
                Err(e) if e.kind() == io::ErrorKind::TimedOut => {}
                Err(e) => panic!("read: {e}"),
            }
        }
        (got, bytes)
    }

    /// The emulated unit at `rate_hz` on `pty`, on a thread of its own, with its faults and
    /// counts shared with the test.
    struct Served {
        faults: Arc<BirdFaults>,
        counts: Arc<BirdCounts>,
        stop: Arc<AtomicBool>,
        server: thread::JoinHandle<io::Result<()>>,
    }

    impl Served {
        fn start(pty: Pty, rate_hz: f64) -> Self {
            let faults = Arc::new(BirdFaults::new());
            let stop = Arc::new(AtomicBool::new(false));
            let counts = Arc::new(BirdCounts::default());
            let server = {
                let (faults, stop, counts) = (faults.clone(), stop.clone(), counts.clone());
                thread::spawn(move || serve(pty, rate_hz, FS, || (P, A), faults, stop, counts))
            };
            Self {
                faults,
                counts,
                stop,
                server,
            }
        }

        /// Stops the unit; its thread must end without an error.
        fn finish(self) {
            self.stop.store(true, Ordering::Release);
            self.server.join().unwrap().unwrap();
        }
    }

    #[test]
    fn serves_a_stream_over_a_pty_with_faults() {
        let pty = Pty::open().unwrap();
        let path = pty.path().to_owned();
        let unit = Served::start(pty, 250.0);
        let (faults, sent) = (unit.faults.clone(), unit.counts.clone());

        let mut port = serial2::SerialPort::open(&path, 115_200).unwrap();
        port.set_read_timeout(Duration::from_millis(50)).unwrap();
        port.write_all(&[POSITION_ANGLES, STREAM]).unwrap();

        // Clean stream: at least ~0.3 s and a few records, every one the scripted pose.
        let mut d = Decoder::new(RecordFormat::PositionAngles, FS);
        let start = Instant::now();
        let (got, _) = read_until(&port, &mut d, Duration::from_secs(10), |got, _| {
            start.elapsed() >= Duration::from_millis(300) && got.len() >= 10
        });
        assert!(!got.is_empty(), "records arrive");
        assert!(got.iter().all(|r| close(r, P, Some(A), FS)), "{got:?}");
        assert_eq!(d.stats().malformed, 0);
        assert_eq!(d.stats().dropped_bytes, 0);
        assert!(sent.records.load(Ordering::Relaxed) >= got.len() as u64);

        // Corrupted stream: the decoder resyncs, most records are still right, and the damage
        // shows in its counts.
        faults.corrupt_one_in.store(3, Ordering::Relaxed);
        let mut d = Decoder::new(RecordFormat::PositionAngles, FS);
        let (got, _) = read_until(&port, &mut d, Duration::from_secs(20), |got, d| {
            let s = d.stats();
            got.len() >= 60 && s.malformed + s.dropped_bytes > 0
        });
        let good = got.iter().filter(|r| close(r, P, Some(A), FS)).count();
        let s = d.stats();
        assert!(s.malformed + s.dropped_bytes > 0, "{s:?}");
        assert!(good * 2 > got.len(), "{good} good of {}: {s:?}", got.len());
        faults.corrupt_one_in.store(0, Ordering::Relaxed);

        // Silent: once the record in flight (if any) is out, nothing more comes.
        faults.silent.store(true, Ordering::Release);
        let settle = Instant::now() + Duration::from_secs(10);
        loop {
            let before = sent.records.load(Ordering::Relaxed);
            thread::sleep(Duration::from_millis(100));
            if sent.records.load(Ordering::Relaxed) == before || Instant::now() > settle {
                break;
            }
        }
        port.discard_input_buffer().unwrap();
        let quiet_from = sent.records.load(Ordering::Relaxed);
        port.write_all(&[POINT, STREAM]).unwrap(); // unheard
        let mut d = Decoder::new(RecordFormat::PositionAngles, FS);
        let (got, bytes) = read_until(&port, &mut d, Duration::from_millis(300), |_, _| false);
        assert_eq!((got.len(), bytes), (0, 0), "silent");
        assert_eq!(sent.records.load(Ordering::Relaxed), quiet_from);

        // Loud again: the stream resumes.
        faults.silent.store(false, Ordering::Release);
        let (got, _) = read_until(&port, &mut d, Duration::from_secs(10), |got, _| {
            !got.is_empty()
        });
        assert!(!got.is_empty(), "stream resumes");

        unit.finish();
    }

    #[test]
    fn a_stalled_line_holds_records_and_commands_and_delivers_them_after() {
        let pty = Pty::open().unwrap();
        let path = pty.path().to_owned();
        let unit = Served::start(pty, 100.0);
        let (faults, counts) = (unit.faults.clone(), unit.counts.clone());
        let mut port = serial2::SerialPort::open(&path, 115_200).unwrap();
        port.set_read_timeout(Duration::from_millis(20)).unwrap();
        port.write_all(&[POSITION_ANGLES, STREAM]).unwrap();
        let mut d = Decoder::new(RecordFormat::PositionAngles, FS);
        let (mut got, _) = read_until(&port, &mut d, Duration::from_secs(10), |got, _| {
            got.len() >= 3
        });

        const STALL: Duration = Duration::from_millis(1500);
        faults
            .stall_ms
            .store(STALL.as_millis() as u64, Ordering::Release);
        while faults.stall_ms.load(Ordering::Acquire) != 0 {
            thread::sleep(Duration::from_millis(1));
        }
        let taken = Instant::now();
        let made = counts.records.load(Ordering::Acquire);
        port.write_all(&[EXAMINE_VALUE, param::HEMISPHERE]).unwrap();
        thread::sleep(Duration::from_millis(300));
        if taken.elapsed() < STALL {
            // Asserted only while the stall surely lasts (a loaded machine may sleep past it).
            assert_eq!(
                counts.hemisphere_reads.load(Ordering::Acquire),
                0,
                "read while stalled"
            );
            assert!(
                counts.records.load(Ordering::Acquire) > made,
                "no records made"
            );
        }
        // After it: every record made came, none lost, and the command was read.
        let deadline = Instant::now() + Duration::from_secs(20);
        let mut all = false;
        while !all && Instant::now() < deadline {
            let made = counts.records.load(Ordering::Acquire);
            all = counts.hemisphere_reads.load(Ordering::Acquire) > 0 && got.len() as u64 >= made;
            let (more, _) = read_until(&port, &mut d, Duration::from_millis(50), |_, _| false);
            got.extend(more);
        }
        assert!(all, "{} records of {counts:?}", got.len());
        assert_eq!(counts.hemisphere_reads.load(Ordering::Acquire), 1);
        assert!(got.len() as u64 <= counts.records.load(Ordering::Acquire));
        assert!(got.iter().all(|r| close(r, P, Some(A), FS)));
        unit.finish();
    }

    #[test]
    fn a_host_that_stops_reading_cannot_stall_stop() {
        let pty = Pty::open().unwrap();
        let path = pty.path().to_owned();
        let unit = Served::start(pty, 5000.0);
        let sent = unit.counts.clone();
        let port = serial2::SerialPort::open(&path, 115_200).unwrap();
        port.write_all(&[POSITION_ANGLES, STREAM]).unwrap();
        // 5 kHz × 12 bytes fills the pty's buffers in well under a second; keep not reading
        // until far more than they hold has been sent.
        let deadline = Instant::now() + Duration::from_secs(20);
        while sent.records.load(Ordering::Relaxed) < 10_000 && Instant::now() < deadline {
            thread::sleep(Duration::from_millis(20));
        }
        assert!(
            sent.records.load(Ordering::Relaxed) >= 10_000,
            "the emulator kept going"
        );
        unit.finish();
        drop(port);
    }

    #[test]
    fn hemisphere_is_selected_read_back_and_folds_positions_not_angles() {
        use softarm_tracker::bird::{Hemisphere, HemisphereBytes};
        let mut dev = BirdDevice::new(FS);
        let mut out = Vec::new();
        let examine = |dev: &mut BirdDevice| {
            let mut out = Vec::new();
            dev.receive(&[EXAMINE_VALUE, param::HEMISPHERE], P, A, &mut out);
            out
        };
        // The unit's default: forward, answered as axis 0, sign 0.
        assert_eq!(dev.hemisphere(), Selected::FORWARD);
        assert_eq!(examine(&mut dev), [0, 0]);

        let behind = [-10.5, 7.25, -3.0];
        let mirrored = [10.5, -7.25, 3.0];
        let point = |dev: &mut BirdDevice, p: [f64; 3]| {
            let mut out = Vec::new();
            dev.receive(&[POSITION_ANGLES, POINT], p, A, &mut out);
            decode_all(RecordFormat::PositionAngles, FS, &out).0[0]
        };
        // Forward: a sensor behind the transmitter comes out in front, all three coordinates
        // negated, its angles as they are.
        let r = point(&mut dev, behind);
        assert!(close(&r, mirrored, Some(A), FS), "{r:?}");
        assert!(close(&point(&mut dev, P), P, Some(A), FS));

        // Every hemisphere the driver can send is taken, read back as sent, and keeps the
        // positions on its side and mirrors the others.
        for h in Hemisphere::ALL {
            out.clear();
            dev.receive(&h.command(), P, A, &mut out);
            assert!(out.is_empty(), "HEMISPHERE has no answer");
            assert_eq!(examine(&mut dev), h.bytes(), "{h:?}");
            let sel = dev.hemisphere();
            let d: [f64; 3] = std::array::from_fn(|i| {
                if i == sel.axis {
                    if sel.negative { -1.0 } else { 1.0 }
                } else {
                    0.0
                }
            });
            for p in [P, behind, [1.0, 2.0, 3.0], [-1.0, -2.0, -3.0]] {
                let inside = (0..3).map(|i| p[i] * d[i]).sum::<f64>() >= 0.0;
                let want = if inside { p } else { p.map(|v| -v) };
                let r = point(&mut dev, p);
                assert!(close(&r, want, Some(A), FS), "{h:?} {p:?}: {r:?}");
            }
        }

        // CHANGE VALUE of parameter 22 sets it too; bytes that name no hemisphere change nothing.
        dev.receive(
            &[CHANGE_VALUE, param::HEMISPHERE, 0x00, 0x01],
            P,
            A,
            &mut out,
        );
        assert_eq!(examine(&mut dev), Hemisphere::Aft.bytes());
        dev.receive(&[HEMISPHERE, 0x03, 0x01, POINT], P, A, &mut out);
        assert_eq!(examine(&mut dev), Hemisphere::Aft.bytes());

        // An older unit: no answer to the read-back, and STREAM STOP is not a command to it.
        dev.set_model(false, false);
        assert!(examine(&mut dev).is_empty());
        dev.receive(&[STREAM, STREAM_STOP], P, A, &mut out);
        assert!(dev.streaming(), "only POINT stops an older unit's stream");
    }

    /// A sensor crossing the forward/aft plane, seen through the tracker driver's own open
    /// sequence and decoder (`Reader`) against this emulator on a pseudo-terminal, with
    /// `tracker.hemisphere` as given: for each scripted position (inches, tracker frame) the
    /// samples that follow it (m, base frame = tracker frame here).
    fn through_the_driver(
        hemisphere: softarm_config::hardware::TrackerHemisphere,
        faults: BirdFaults,
        path_in: &[[f64; 3]],
    ) -> (Vec<[f64; 3]>, softarm_tracker::Reader<'static>) {
        use softarm_config::hardware::{TrackerConfig, TrackerMode, TrackerRecord};
        use std::sync::Mutex;
        let pty = Pty::open().unwrap();
        let t: &'static TrackerConfig = Box::leak(Box::new(TrackerConfig {
            port: pty.path().to_owned(),
            baud: 115_200,
            record: TrackerRecord::Position,
            mode: TrackerMode::Stream,
            rate_hz: 100.0,
            full_scale_in: FS,
            silent_after_ms: 2000.0,
            max_speed_m_per_s: 2.0,
            translation_m: [0.0; 3],
            rotation_deg: [0.0; 3],
            hemisphere,
        }));
        let pose = Arc::new(Mutex::new(path_in[0]));
        let faults = Arc::new(faults);
        let stop = Arc::new(AtomicBool::new(false));
        let sent = Arc::new(BirdCounts::default());
        let server = {
            let (pose, faults, stop, sent) =
                (pose.clone(), faults.clone(), stop.clone(), sent.clone());
            thread::spawn(move || {
                let pose = move || (*pose.lock().unwrap(), A);
                serve(pty, 100.0, FS, pose, faults, stop, sent)
            })
        };
        if faults.ignore_stream_stop.load(Ordering::Relaxed) {
            // A session before this one left the unit streaming.
            let port = serial2::SerialPort::open(&t.port, 115_200).unwrap();
            port.write_all(&[STREAM]).unwrap();
            let start = sent.records.load(Ordering::Relaxed);
            while sent.records.load(Ordering::Relaxed) < start + 3 {
                thread::sleep(Duration::from_millis(5));
            }
        }
        let mut reader = softarm_tracker::Reader::open(t).unwrap();
        let mut seen = Vec::new();
        for &p in path_in {
            *pose.lock().unwrap() = p;
            // Records made from here on carry the new pose (one may be in the making): wait
            // until the driver has read past them, by count, then take three fresh samples.
            let after = sent.records.load(Ordering::Acquire) + 2;
            let deadline = Instant::now() + Duration::from_secs(30);
            while reader.stats().records < after && Instant::now() < deadline {
                reader.step(|_| {});
            }
            let mut fresh = Vec::new();
            while fresh.len() < 3 && Instant::now() < deadline {
                reader.step(|s| fresh.push(s.position));
            }
            // One step may bring several records (a loaded machine delivers them together).
            assert!(fresh.len() >= 3, "samples at {p:?} in 30 s: {fresh:?}");
            assert!(
                fresh.windows(2).all(|w| w[0] == w[1]),
                "{p:?}: a still sensor gives one position: {fresh:?}"
            );
            seen.push(fresh[fresh.len() - 1]);
        }
        stop.store(true, Ordering::Release);
        server.join().unwrap().unwrap();
        (seen, reader)
    }

    #[test]
    fn a_sensor_crossing_the_plane_is_right_in_its_hemisphere_and_mirrored_outside() {
        use softarm_config::hardware::TrackerHemisphere;
        use softarm_tracker::ReadBack;
        // The sensor works behind the transmitter (x < 0) and crosses to x > 0.
        let path = [
            [-8.0, 3.0, 10.0],
            [-4.0, -2.0, 10.0],
            [-0.5, 3.0, -6.0],
            [0.5, 3.0, -6.0],
            [4.0, -2.0, 10.0],
        ];
        let m = |p: [f64; 3]| p.map(|v| v * 0.0254);
        let near = |a: [f64; 3], b: [f64; 3]| (0..3).all(|i| (a[i] - b[i]).abs() < 2e-4);
        for (hemisphere, behind_right) in [
            (TrackerHemisphere::Aft, true),
            (TrackerHemisphere::Forward, false),
        ] {
            let (seen, reader) = through_the_driver(hemisphere, BirdFaults::new(), &path);
            assert_eq!(reader.readback(), ReadBack::Confirmed, "{hemisphere:?}");
            for (p, got) in path.iter().zip(&seen) {
                let on_its_side = (p[0] < 0.0) == behind_right;
                let want = if on_its_side { m(*p) } else { m(p.map(|v| -v)) };
                assert!(
                    near(*got, want),
                    "{hemisphere:?}: sensor at {p:?} in reported at {got:?} m, want {want:?} \
                     ({})",
                    if on_its_side { "true" } else { "mirrored" }
                );
            }
        }
    }

    #[test]
    fn an_older_unit_is_stopped_with_point_and_its_answer_is_not_a_sample() {
        use softarm_config::hardware::TrackerHemisphere;
        use softarm_tracker::{ReadBack, StopBy};
        let faults = BirdFaults::new();
        faults.ignore_stream_stop.store(true, Ordering::Relaxed);
        faults.no_hemisphere_readback.store(true, Ordering::Relaxed);
        let path = [[-6.0, 1.0, 2.0], [-2.0, -1.0, 4.0]];
        let (seen, reader) = through_the_driver(TrackerHemisphere::Aft, faults, &path);
        assert_eq!(reader.stop_by(), StopBy::Point);
        assert_eq!(reader.readback(), ReadBack::NotAnswered);
        for (p, got) in path.iter().zip(&seen) {
            let want = p.map(|v| v * 0.0254);
            assert!(
                (0..3).all(|i| (got[i] - want[i]).abs() < 2e-4),
                "{p:?}: {got:?}"
            );
        }
        // The answer to POINT went with the drain, or the decoder swallowed it: at most one.
        assert!(reader.stats().discarded <= 1, "{:?}", reader.stats());
    }

    /// The tracker driver's `Reader` (silent after 200 ms) against this emulator in `mode`, the
    /// line stalled for longer than that twice: the unit is asked again on the same port, never
    /// reopened, and what comes after is whole records, each published once.
    fn stalled_through_the_driver(mode: softarm_config::hardware::TrackerMode) {
        use softarm_config::hardware::{TrackerConfig, TrackerHemisphere, TrackerRecord};
        let pty = Pty::open().unwrap();
        let t = TrackerConfig {
            port: pty.path().to_owned(),
            baud: 115_200,
            record: TrackerRecord::PositionAngles,
            mode,
            rate_hz: 100.0,
            full_scale_in: FS,
            silent_after_ms: 200.0,
            max_speed_m_per_s: 2.0,
            translation_m: [0.0; 3],
            rotation_deg: [0.0; 3],
            hemisphere: TrackerHemisphere::Forward,
        };
        let unit = Served::start(pty, 100.0);
        let (faults, counts) = (unit.faults.clone(), unit.counts.clone());
        let mut reader = softarm_tracker::Reader::open(&t).unwrap();
        let mut seqs = Vec::new();
        type Done<'d> = &'d dyn Fn(&softarm_tracker::Reader) -> bool;
        let mut run_until = |reader: &mut softarm_tracker::Reader, done: Done| {
            let deadline = Instant::now() + Duration::from_secs(30);
            while !done(reader) && Instant::now() < deadline {
                reader.step(|s| seqs.push(s.seq));
            }
            assert!(done(reader), "{mode:?}: waited 30 s");
        };
        run_until(&mut reader, &|r| r.stats().records >= 5);
        for stall_ms in [1200, 500] {
            let asked = reader.asked_again();
            faults.stall_ms.store(stall_ms, Ordering::Release);
            // Through the silence (the unit asked again), then until every record made has
            // been read.
            run_until(&mut reader, &|r| r.asked_again() > asked);
            let made = counts.records.load(Ordering::Acquire);
            run_until(&mut reader, &|r| r.stats().records >= made);
        }
        unit.finish();
        let s = reader.stats();
        assert_eq!(reader.reopens(), 0, "{mode:?}: reopened on a stall");
        assert!(
            reader.asked_again() >= 2,
            "{mode:?}: {}",
            reader.asked_again()
        );
        assert_eq!(
            (s.malformed, s.dropped_bytes, s.discarded),
            (0, 0, 0),
            "{mode:?}: the decoder lost its phase"
        );
        assert!(s.records <= counts.records.load(Ordering::Acquire));
        assert_eq!(
            seqs.len() as u64,
            s.records,
            "{mode:?}: a record published twice or held"
        );
        assert!(seqs.windows(2).all(|w| w[1] == w[0] + 1));
        assert!(
            counts.hemisphere_reads.load(Ordering::Acquire) == 1,
            "{mode:?}: opened again"
        );
    }

    #[test]
    fn a_stalled_stream_is_asked_again_not_reopened_and_stays_in_phase() {
        stalled_through_the_driver(softarm_config::hardware::TrackerMode::Stream);
    }

    #[test]
    fn a_stalled_poll_is_asked_again_not_reopened_and_stays_in_phase() {
        stalled_through_the_driver(softarm_config::hardware::TrackerMode::Point);
    }

    #[test]
    fn serve_rejects_a_bad_rate_or_scale() {
        for (rate, scale) in [(0.0, FS), (f64::NAN, FS), (1e-300, FS), (100.0, 0.0)] {
            let r = serve(
                Pty::open().unwrap(),
                rate,
                scale,
                || (P, A),
                Arc::new(BirdFaults::new()),
                Arc::new(AtomicBool::new(false)),
                Arc::new(BirdCounts::default()),
            );
            assert_eq!(
                r.unwrap_err().kind(),
                io::ErrorKind::InvalidInput,
                "{rate} Hz, {scale} in"
            );
        }
    }
}
