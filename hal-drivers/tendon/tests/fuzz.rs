//! Property-based fuzzing of the tendon driver's status handling: mangled, forged and
//! arbitrary bytes arriving where the driver expects the motors' status packets.
//!
//! The bytes reach the driver's reading only through `dynamixel2`, which reads from a serial
//! port, and the driver's own `Link::read` (reached through `softarm_tendon::fuzz::Probe`).
//! So each case runs the real thing on a pseudo-terminal: the emulated X-series bus
//! (`softarm_emulate::dynamixel`, written independently of `dynamixel2`) answers, and a layer
//! between it and the line changes its answers as the case says. Whatever arrives, no panic
//! escapes, a fault is a bus fault (never a port fault, which would reopen the port), and every
//! value the driver keeps is one that some status packet with a right CRC, the right ID and
//! length and no error number carried: garbage never becomes a position. A reply with an
//! error number is a missing answer, never a position; a reply with the alert bit makes the
//! driver read the hardware-error status. The link works again at the next exchange.
//!
//! Each case takes milliseconds, or about 35 ms per answer a mangled reply costs (the
//! `dynamixel2` time-out), so the counts are smaller than for the pure codecs.
//! `cargo test -p softarm-tendon --test fuzz` runs a bounded number of cases, CI more (see
//! docs/FUZZING.md); `PROPTEST_CASES=20000 cargo test --release -p softarm-tendon --test fuzz`
//! runs longer.

use std::io;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use proptest::prelude::*;
use softarm_config::Config;
use softarm_config::hardware::TendonConfig;
use softarm_emulate::dynamixel::{self as dxl, Bus};
use softarm_emulate::pty::Pty;
use softarm_tendon::fuzz::Probe;
use softarm_tendon::table::CURRENT_UNIT_A;

/// `n` cases, or `PROPTEST_CASES` when set (longer runs by hand, more cases in CI).
fn cases(n: u32) -> ProptestConfig {
    let n = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(n);
    ProptestConfig::with_cases(n)
}

/// The motor ids of `config/hardware.toml`.
const IDS: [u8; 6] = [1, 2, 3, 4, 5, 6];
const HEADER: [u8; 4] = [0xFF, 0xFF, 0xFD, 0x00];
/// The third answer set of a read (torque enable .. hardware error status) has 7 bytes.
const STATUS_LEN: usize = 7;

/// The hardware config with the port on the pseudo-terminal.
fn config(port: &Path) -> TendonConfig {
    let text = include_str!("../../../config/hardware.toml");
    let c = Config::parse(text, "hardware.toml", ".".into()).unwrap();
    let mut t = c.tendon.unwrap();
    assert_eq!(t.ids, IDS);
    t.port = port.to_owned();
    t
}

/// One change to the bytes of one answer set (all the status packets that answer one
/// instruction). Positions are fractions of the current length.
#[derive(Clone, Debug)]
enum Edit {
    /// One byte xor'ed with a non-zero mask.
    Flip(f64, u8),
    /// Bytes inserted.
    Insert(f64, Vec<u8>),
    /// Bytes lost.
    Lose(f64, usize),
    /// Everything from here on lost.
    Cut(f64),
    /// The whole answer set replaced.
    Replace(Vec<u8>),
    /// A status packet with a right CRC inserted: (at, id, error field, parameters).
    Forge(f64, u8, u8, Vec<u8>),
    /// `short_status_packet(id, length)` inserted (length 0 to 3: dynamixel2 0.9.1 panics).
    Short(f64, u8, u16),
    /// The k-th packet sent again with this error field (and its CRC made right).
    Error(usize, u8),
    /// The k-th packet sent again with these parameters (and its CRC made right): a motor
    /// answering nonsense, or a corruption the CRC misses.
    Data(usize, Vec<u8>),
}

/// The status packets of an answer set as the emulator sent them: (id, error, parameters).
fn split(bytes: &[u8]) -> Vec<(u8, u8, Vec<u8>)> {
    let mut packets = Vec::new();
    let mut at = 0;
    while at < bytes.len() {
        assert_eq!(bytes[at..at + 4], HEADER, "the emulator sent {bytes:02x?}");
        let length = usize::from(u16::from_le_bytes([bytes[at + 5], bytes[at + 6]]));
        let body = dxl::unstuff(&bytes[at + 7..at + 5 + length]);
        packets.push((bytes[at + 4], body[1], body[2..].to_vec()));
        at += 7 + length;
    }
    packets
}

fn place(at: f64, len: usize) -> usize {
    ((at * (len + 1) as f64) as usize).min(len)
}

fn apply(original: &[u8], edits: &[Edit]) -> Vec<u8> {
    if edits.is_empty() {
        return original.to_vec();
    }
    let mut packets = split(original);
    let n = packets.len();
    for e in edits {
        match e {
            Edit::Error(k, error) if n > 0 => packets[k % n].1 = *error,
            Edit::Data(k, params) if n > 0 => packets[k % n].2 = params.clone(),
            _ => {}
        }
    }
    let mut bytes: Vec<u8> = packets
        .iter()
        .flat_map(|(id, error, params)| dxl::status_packet(*id, *error, params))
        .collect();
    if !edits
        .iter()
        .any(|e| matches!(e, Edit::Error(..) | Edit::Data(..)))
    {
        assert_eq!(bytes, original, "split and status_packet round-trip");
    }
    for e in edits {
        match e {
            Edit::Flip(at, mask) => {
                if !bytes.is_empty() {
                    let i = place(*at, bytes.len() - 1);
                    bytes[i] ^= mask;
                }
            }
            Edit::Insert(at, b) => {
                let i = place(*at, bytes.len());
                bytes.splice(i..i, b.iter().copied());
            }
            Edit::Lose(at, n) => {
                let i = place(*at, bytes.len());
                bytes.drain(i..(i + n).min(bytes.len()));
            }
            Edit::Cut(at) => bytes.truncate(place(*at, bytes.len())),
            Edit::Replace(b) => bytes = b.clone(),
            Edit::Forge(at, id, error, params) => {
                let i = place(*at, bytes.len());
                bytes.splice(i..i, dxl::status_packet(*id, *error, params));
            }
            Edit::Short(at, id, length) => {
                let i = place(*at, bytes.len());
                bytes.splice(i..i, dxl::short_status_packet(*id, *length));
            }
            Edit::Error(..) | Edit::Data(..) => {}
        }
    }
    bytes
}

/// dynamixel2 0.9.1's unstuffing (its private `bytestuff::unstuff_inplace`, transcribed): its
/// state machine forgets a run of three or more 0xFF, so `FF FF FF FD FD` keeps both FD.
fn unstuff_as_dynamixel2(data: &[u8]) -> Vec<u8> {
    const PATTERN: [u8; 4] = [0xFF, 0xFF, 0xFD, 0xFD];
    let mut out = Vec::with_capacity(data.len());
    let mut state = 0;
    for &b in data {
        if b == PATTERN[state] {
            state += 1;
        } else {
            state = 0;
        }
        if state == 4 {
            state = 0;
        } else {
            out.push(b);
        }
    }
    out
}

/// The parameters of every status packet anywhere in `bytes` that a master could take for
/// motor `id`'s answer of `count` bytes: a header, a length of at least 4, a right CRC,
/// instruction 0x55, no error number (the alert bit allowed), `count` parameters once
/// unstuffed as the e-Manual says or as dynamixel2 does.
fn acceptable(bytes: &[u8], id: u8, count: usize) -> Vec<Vec<u8>> {
    let mut found = Vec::new();
    for p in 0..bytes.len() {
        if !bytes[p..].starts_with(&HEADER) || bytes.len() < p + 7 || bytes[p + 4] != id {
            continue;
        }
        let length = usize::from(u16::from_le_bytes([bytes[p + 5], bytes[p + 6]]));
        let end = p + 7 + length;
        if length < 4 || end > bytes.len() {
            continue;
        }
        let crc = u16::from_le_bytes([bytes[end - 2], bytes[end - 1]]);
        if crc != dynamixel2::checksum::calculate_checksum(0, &bytes[p..end - 2]) {
            continue;
        }
        if bytes[p + 7] != 0x55 || bytes[p + 8] & 0x7f != 0 {
            continue;
        }
        let stuffed = &bytes[p + 9..end - 2];
        for params in [dxl::unstuff(stuffed), unstuff_as_dynamixel2(stuffed)] {
            if params.len() == count {
                found.push(params);
            }
        }
    }
    found
}

/// An answer set as the bus sent it and as the driver got it.
type Exchange = (Vec<u8>, Vec<u8>);

/// A read as long as this may have lost answers to the scheduler rather than to the bytes:
/// `dynamixel2` waits 34 ms (plus the transfer time) for an answer and looks at the clock
/// before it looks at the bytes that came meanwhile, so a test or bus thread kept off the CPU
/// that long on a loaded machine costs answers. Expectations that a lost answer would break
/// are checked on reads shorter than this only (a read that loses nothing takes a few ms);
/// everything else is checked on every read.
const LATE: Duration = Duration::from_millis(30);

/// One driver read: its result, the answer sets, whether it took [`LATE`] or longer.
struct Read {
    result: Result<usize, String>,
    log: Vec<Exchange>,
    late: bool,
}

/// Runs `scenario` again while one of its reads was late (at most five times), for the plain
/// tests' exact expectations.
fn on_time<T>(mut scenario: impl FnMut() -> (T, bool)) -> T {
    for _ in 0..4 {
        let (out, late) = scenario();
        if !late {
            return out;
        }
    }
    scenario().0
}

/// What the layer between the emulated bus and the line does and has seen.
#[derive(Default)]
struct Line {
    /// Changes applied (else answers pass untouched).
    armed: bool,
    /// The edits of the k-th answer set since armed.
    plan: Vec<Vec<Edit>>,
    /// Every answer set since armed.
    log: Vec<Exchange>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// dynamixel2's panics on bad replies are expected here and caught by the driver: not printed
/// (with `RUST_BACKTRACE` set, printing each one's backtrace would take most of the time).
/// Every other panic is printed as usual.
fn quiet_dynamixel2_panics() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let default = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let theirs = info
                .location()
                .is_some_and(|l| l.file().contains("/dynamixel2-"));
            if !theirs {
                default(info);
            }
        }));
    });
}

/// The emulated bus on a pseudo-terminal behind the changing layer, and the driver's link to
/// it. Stopped on drop.
struct Rig {
    bus: Arc<Mutex<Bus>>,
    line: Arc<Mutex<Line>>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<io::Result<()>>>,
    probe: Option<Probe>,
}

impl Rig {
    /// Motors at `positions`, the driver's link open (as at start: every motor answered).
    fn start(positions: [i32; 6]) -> Self {
        quiet_dynamixel2_panics();
        let mut pty = Pty::open().unwrap();
        let path = pty.path().to_owned();
        let mut bus = Bus::new(&IDS, 0);
        for (id, p) in IDS.iter().zip(positions) {
            bus.motor_mut(*id).unwrap().set_present_position(p);
        }
        let bus = Arc::new(Mutex::new(bus));
        let line = Arc::new(Mutex::new(Line::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (bus, line, stop) = (bus.clone(), line.clone(), stop.clone());
            std::thread::spawn(move || {
                let mut buf = [0u8; 1024];
                while !stop.load(Ordering::Relaxed) {
                    let n = pty.read_timeout(&mut buf, Duration::from_millis(1))?;
                    let mut out = Vec::new();
                    lock(&bus).receive(&buf[..n], &mut out);
                    if out.is_empty() {
                        continue;
                    }
                    let mut l = lock(&line);
                    if l.armed {
                        let k = l.log.len();
                        let delivered = apply(&out, l.plan.get(k).map_or(&[], |p| p));
                        l.log.push((out, delivered.clone()));
                        out = delivered;
                    }
                    drop(l);
                    pty.write_all(&out)?;
                }
                Ok(())
            })
        };
        let mut rig = Self {
            bus,
            line,
            stop,
            thread: Some(thread),
            probe: None,
        };
        // Opening is not under test, and on a loaded machine it can lose an answer (see
        // `LATE`): tried again then.
        let t = config(&path);
        let mut attempts = 0;
        rig.probe = Some(loop {
            match Probe::open(&t) {
                Ok(p) => break p,
                Err(e) if attempts >= 4 => panic!("{e:#}"),
                Err(_) => attempts += 1,
            }
        });
        rig
    }

    fn probe(&mut self) -> &mut Probe {
        self.probe.as_mut().unwrap()
    }

    /// One driver read with the answers changed by `plan`.
    fn read(&mut self, plan: Vec<Vec<Edit>>, status: bool) -> Read {
        *lock(&self.line) = Line {
            armed: true,
            plan,
            log: Vec::new(),
        };
        let start = Instant::now();
        let result = self.probe().read(status);
        let late = start.elapsed() >= LATE;
        let mut l = lock(&self.line);
        l.armed = false;
        Read {
            result,
            log: std::mem::take(&mut l.log),
            late,
        }
    }

    fn set_hardware_error(&self, id: u8, bits: u8) {
        lock(&self.bus).set_hardware_error(id, bits);
    }
}

impl Drop for Rig {
    fn drop(&mut self) {
        self.probe = None;
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let result = t.join();
            if !std::thread::panicking() {
                result
                    .expect("the bus thread panicked")
                    .expect("the bus thread failed");
            }
        }
    }
}

/// Bytes as a broken line delivers them: random, the bytes of the protocol's structure, and
/// headers with an id and a length.
fn wire_bytes() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(
        prop_oneof![
            4 => any::<u8>().prop_map(|b| vec![b]),
            2 => prop::sample::select(vec![0xFFu8, 0xFD, 0x00, 0x55, 0x80]).prop_map(|b| vec![b]),
            1 => (id(), 0u16..40).prop_map(|(id, len)| {
                let mut v = HEADER.to_vec();
                v.push(id);
                v.extend(len.to_le_bytes());
                v
            }),
        ],
        0..24,
    )
    .prop_map(|c| c.concat())
}

/// One of the motors' ids mostly, any id sometimes.
fn id() -> impl Strategy<Value = u8> {
    prop_oneof![4 => prop::sample::select(IDS.to_vec()), 1 => any::<u8>()]
}

/// An error field: none, the alert bit, an error number, both.
fn error_field() -> impl Strategy<Value = u8> {
    prop_oneof![Just(0u8), Just(0x80u8), 1u8..0x80, 0x81u8..=0xff]
}

/// Parameters of a forged packet: the lengths the driver reads and others, with the bytes of
/// stuffing often.
fn forged_params() -> impl Strategy<Value = Vec<u8>> {
    let byte = prop_oneof![3 => any::<u8>(), 1 => Just(0xFFu8), 1 => Just(0xFDu8)];
    prop_oneof![Just(4usize), Just(2), Just(STATUS_LEN), 0usize..12]
        .prop_flat_map(move |n| prop::collection::vec(byte.clone(), n))
}

fn edit() -> impl Strategy<Value = Edit> {
    let at = 0.0f64..1.0;
    prop_oneof![
        3 => (at.clone(), 1u8..=0xff).prop_map(|(a, m)| Edit::Flip(a, m)),
        2 => (at.clone(), wire_bytes()).prop_map(|(a, b)| Edit::Insert(a, b)),
        2 => (at.clone(), 1usize..20).prop_map(|(a, n)| Edit::Lose(a, n)),
        1 => at.clone().prop_map(Edit::Cut),
        1 => wire_bytes().prop_map(Edit::Replace),
        3 => (at.clone(), id(), error_field(), forged_params())
            .prop_map(|(a, id, e, p)| Edit::Forge(a, id, e, p)),
        1 => (at, id(), 0u16..4).prop_map(|(a, id, l)| Edit::Short(a, id, l)),
        2 => (0usize..6, error_field()).prop_map(|(k, e)| Edit::Error(k, e)),
        2 => (0usize..6, forged_params()).prop_map(|(k, p)| Edit::Data(k, p)),
    ]
}

/// Edits for each of the (at most three) answer sets of a read: a third of them untouched.
fn plan() -> impl Strategy<Value = Vec<Vec<Edit>>> {
    prop::collection::vec(
        prop_oneof![1 => Just(Vec::new()), 2 => prop::collection::vec(edit(), 1..4)],
        3,
    )
}

fn positions() -> impl Strategy<Value = [i32; 6]> {
    prop::array::uniform6(0i32..4096)
}

/// Hardware Error Status bits of one motor: mostly none.
fn hardware_error() -> impl Strategy<Value = u8> {
    prop_oneof![
        4 => Just(0u8),
        1 => prop::sample::select(vec![
            dxl::hardware_error::INPUT_VOLTAGE,
            dxl::hardware_error::OVERHEATING,
            dxl::hardware_error::MOTOR_ENCODER,
            dxl::hardware_error::ELECTRICAL_SHOCK,
            dxl::hardware_error::OVERLOAD,
        ]),
    ]
}

fn ticks_of(p: &[u8]) -> i32 {
    i32::from_le_bytes([p[0], p[1], p[2], p[3]])
}

fn current_of(p: &[u8]) -> f64 {
    f64::from(i16::from_le_bytes([p[0], p[1]])) * CURRENT_UNIT_A
}

/// A clean read after whatever happened: every answer, the motors' real positions. (A late
/// read that lost answers is tried again, at most five times.)
fn recovers(rig: &mut Rig, positions: [i32; 6]) -> Result<(), TestCaseError> {
    for _ in 0..5 {
        let r = rig.read(Vec::new(), false);
        if r.late && r.result != Ok(0) {
            continue;
        }
        prop_assert_eq!(r.result, Ok(0), "the link did not recover");
        prop_assert_eq!(rig.probe().reading().ticks, positions);
        return Ok(());
    }
    Err(TestCaseError::fail(
        "five clean reads in a row lost answers",
    ))
}

proptest! {
    #![proptest_config(cases(64))]

    /// Mangled, forged, cut and arbitrary answers: no panic escapes the driver, a fault is a
    /// bus fault, and every position, current and hardware-error bit the driver keeps was
    /// carried by a packet a master may accept as that motor's answer (what the motor sent,
    /// or a forgery with a right CRC: the protocol cannot tell). A read that reports every
    /// answer present took every value from such a packet.
    #[test]
    fn mangled_answers_never_become_readings(
        positions in positions(),
        errors in prop::array::uniform6(hardware_error()),
        plan in plan(),
        status in any::<bool>(),
    ) {
        let mut rig = Rig::start(positions);
        for (id, bits) in IDS.iter().zip(errors) {
            if bits != 0 {
                rig.set_hardware_error(*id, bits);
            }
        }
        let before = rig.probe().reading();
        let untouched = plan.iter().all(Vec::is_empty);
        let Read { result, log, late } = rig.read(plan, status);
        let after = rig.probe().reading();
        prop_assert!(!log.is_empty(), "no instruction went out");
        match &result {
            Ok(missing) => prop_assert!(*missing <= 3 * IDS.len()),
            Err(e) => prop_assert!(e.starts_with("bus: "), "{e}"),
        }
        if result.is_ok() && status {
            prop_assert_eq!(log.len(), 3, "status asked for but not read");
        }
        let delivered = |k: usize| log.get(k).map(|(_, d)| d.as_slice());
        for (i, &id) in IDS.iter().enumerate() {
            let c = after.current_a[i];
            prop_assert!(c.is_finite() && c.abs() <= 32768.0 * CURRENT_UNIT_A);
            let ticks: Vec<i32> = delivered(0)
                .map(|d| acceptable(d, id, 4).iter().map(|p| ticks_of(p)).collect())
                .unwrap_or_default();
            let currents: Vec<f64> = delivered(1)
                .map(|d| acceptable(d, id, 2).iter().map(|p| current_of(p)).collect())
                .unwrap_or_default();
            let status_bits = delivered(2)
                .map(|d| acceptable(d, id, STATUS_LEN).iter().fold(0, |a, p| a | p[6]))
                .unwrap_or(0);
            let t = after.ticks[i];
            prop_assert!(
                t == before.ticks[i] || ticks.contains(&t),
                "motor {id}: {t} ticks, carried by no acceptable packet ({ticks:?})"
            );
            prop_assert!(c == before.current_a[i] || currents.contains(&c), "motor {id}: {c} A");
            let new_bits = after.hardware_error[i] & !before.hardware_error[i];
            prop_assert_eq!(new_bits & !status_bits, 0, "motor {}: error bits from nowhere", id);
            if result == Ok(0) {
                prop_assert!(ticks.contains(&t), "motor {id}: all answered, {t} from nowhere");
                prop_assert!(currents.contains(&c), "motor {id}: all answered, {c} A from nowhere");
            }
        }
        if untouched && !late {
            prop_assert_eq!(result, Ok(0));
            prop_assert_eq!(after.ticks, positions);
            for (i, &bits) in errors.iter().enumerate() {
                if log.len() == 3 {
                    prop_assert_eq!(after.hardware_error[i], bits);
                }
            }
        }
        recovers(&mut rig, positions)?;
    }
}

proptest! {
    #![proptest_config(cases(128))]

    /// Well-formed answers with any error field: an answer with an error number is a missing
    /// answer (a fault), and that motor's position and current stay what they were; an answer
    /// with the alert bit (alone or with an error number), from a motor with a hardware error
    /// or forged, makes the driver read every motor's hardware-error status, which it then
    /// holds; without one and unasked, it does not.
    #[test]
    fn error_fields_are_faults_and_alerts_read_the_status(
        positions in positions(),
        errors in prop::array::uniform6(hardware_error()),
        forged in prop::array::uniform2(prop::array::uniform6(prop::option::of(error_field()))),
        status in any::<bool>(),
    ) {
        let mut rig = Rig::start(positions);
        for (id, bits) in IDS.iter().zip(errors) {
            if bits != 0 {
                rig.set_hardware_error(*id, bits);
            }
        }
        let plan: Vec<Vec<Edit>> = forged
            .iter()
            .map(|set| {
                set.iter()
                    .enumerate()
                    .filter_map(|(k, e)| e.map(|e| Edit::Error(k, e)))
                    .collect()
            })
            .collect();
        // What each answer's error field is on the line.
        let field = |set: usize, i: usize| {
            forged[set][i].unwrap_or(if errors[i] != 0 { 0x80 } else { 0 })
        };
        let before = rig.probe().reading();
        let Read { result, log, late } = rig.read(plan, status);
        prop_assume!(!late, "a late read may have lost answers to the scheduler");
        let after = rig.probe().reading();
        let mut missing = 0;
        let mut alert = status;
        for set in 0..2 {
            for i in 0..IDS.len() {
                let e = field(set, i);
                missing += usize::from(e & 0x7f != 0);
                alert |= e & 0x80 != 0;
            }
        }
        prop_assert_eq!(result, Ok(missing));
        for i in 0..IDS.len() {
            let refused = field(0, i) & 0x7f != 0;
            let want = if refused { before.ticks[i] } else { positions[i] };
            prop_assert_eq!(after.ticks[i], want, "motor {} (field {:#04x})", IDS[i], field(0, i));
            if field(1, i) & 0x7f != 0 {
                prop_assert_eq!(after.current_a[i], before.current_a[i]);
            }
        }
        prop_assert_eq!(log.len(), 2 + usize::from(alert), "status read iff asked or alerted");
        let want = if alert { errors } else { [0; 6] };
        prop_assert_eq!(after.hardware_error, want);
        recovers(&mut rig, positions)?;
    }
}

/// Found by `error_fields_are_faults_and_alerts_read_the_status`: an answer with an error number
/// and the alert bit (0x81) was counted missing and its alert bit dropped with it, so a motor
/// with a hardware error whose only alert came that way was not looked at until the next
/// periodic status read. Motor 5 has one; its position answer is forged without the alert bit,
/// its current answer with Result Fail and the alert bit.
#[test]
fn an_alert_on_a_refused_answer_still_reads_the_status() {
    let (result, sets, errors) = on_time(|| {
        let mut rig = Rig::start([1000, 1100, 1200, 2800, 2900, 3000]);
        rig.set_hardware_error(IDS[4], dxl::hardware_error::OVERLOAD);
        let plan = vec![vec![Edit::Error(4, 0)], vec![Edit::Error(4, 0x81)]];
        let r = rig.read(plan, false);
        let errors = rig.probe().reading().hardware_error;
        ((r.result, r.log.len(), errors), r.late)
    });
    assert_eq!(result, Ok(1));
    assert_eq!(sets, 3, "the status was not read");
    let mut want = [0; 6];
    want[4] = dxl::hardware_error::OVERLOAD;
    assert_eq!(errors, want);
}

/// dynamixel2 0.9.1 panics on a status packet whose length field is below 4 and whose CRC
/// fits (pinned in `softarm_emulate::dynamixel`'s tests). Injected before each answer set of
/// a read with the emulator's own raw-bytes injection: the driver catches it, reports a bus
/// fault, and the next read is whole.
#[test]
fn a_short_status_packet_is_a_bus_fault_not_a_panic() {
    let positions = [1000, 1100, 1200, 2800, 2900, 3000];
    let panicked = Err("bus: the protocol code panicked on a reply".to_string());
    for length in 0..4u16 {
        for set in 0..3 {
            let (result, sets, ticks, again) = on_time(|| {
                let mut rig = Rig::start(positions);
                let mut plan = vec![Vec::new(); 3];
                plan[set] = vec![Edit::Short(0.0, IDS[0], length)];
                let r = rig.read(plan, true);
                let ticks = rig.probe().reading().ticks;
                let clean = rig.read(Vec::new(), false);
                let again = (clean.result, rig.probe().reading().ticks);
                ((r.result, r.log.len(), ticks, again), r.late || clean.late)
            });
            let case = format!("length {length} before answer set {set}");
            if length >= 2 || cfg!(debug_assertions) {
                assert_eq!(result, panicked, "{case}");
                assert_eq!(sets, set + 1, "{case}");
            } else {
                // Release builds wrap the length; the CRC then does not fit.
                assert!(!matches!(result, Ok(0)), "{case}: {result:?}");
            }
            // Answer sets read before the bad one are whole.
            if set > 0 {
                assert_eq!(ticks, positions, "{case}");
            }
            assert_eq!(again, (Ok(0), positions), "{case}: the next read");
        }
    }
    // Through the emulator's raw-bytes injection too (before the next status packet).
    let (result, again) = on_time(|| {
        let mut rig = Rig::start(positions);
        lock(&rig.bus).inject_raw(&dxl::short_status_packet(IDS[2], 3));
        let r = rig.read(Vec::new(), false);
        let clean = rig.read(Vec::new(), false);
        let again = (clean.result, rig.probe().reading().ticks);
        ((r.result, again), r.late || clean.late)
    });
    assert_eq!(result, panicked);
    assert_eq!(again, (Ok(0), positions), "the next read");
}

/// dynamixel2 0.9.1 does not unstuff `FF FF FF FD FD` (pinned in `softarm_emulate::dynamixel`'s
/// tests). A Present Position of `FF FF FF FD` (little-endian) goes out as that; the driver
/// counts that motor's answer missing and keeps its last position rather than a misread one.
/// `FF FF FD` after an ordinary byte is unstuffed right, and read right.
#[test]
fn a_misread_stuffing_is_a_missing_answer_not_a_position() {
    let fffffffd = i32::from_le_bytes([0xFF, 0xFF, 0xFF, 0xFD]);
    let fffffd01 = i32::from_le_bytes([0xFF, 0xFF, 0xFD, 0x01]);
    let mut positions = [1000, 1100, 1200, 2800, 2900, 3000];
    let (first, result, sent, got) = on_time(|| {
        let mut rig = Rig::start(positions);
        let first = rig.read(Vec::new(), false);
        {
            let mut bus = lock(&rig.bus);
            let motor = bus.motor_mut(IDS[2]).unwrap();
            motor.set_present_position(fffffffd);
            let motor = bus.motor_mut(IDS[4]).unwrap();
            motor.set_present_position(fffffd01);
        }
        let r = rig.read(Vec::new(), false);
        let got = rig.probe().reading().ticks;
        let sent = r.log[0].1.clone();
        ((first.result, r.result, sent, got), first.late || r.late)
    });
    assert_eq!(first, Ok(0));
    let stuffed = [0xFF, 0xFF, 0xFF, 0xFD, 0xFD];
    assert!(sent.windows(5).any(|w| w == stuffed), "{sent:02x?}");
    assert_eq!(result, Ok(1));
    // Motor 3 kept its last position; motor 5's was read right.
    positions[4] = fffffd01;
    assert_eq!(got, positions);
}
