//! Dynamixel Protocol 2.0, the master's side, as far as the driver needs it: instruction
//! packets out, status packets in. Written from the ROBOTIS e-Manual ("DYNAMIXEL Protocol
//! 2.0": packet layout, byte stuffing, CRC-16), independently of the emulator's device side
//! (`softarm_emulate::dynamixel`), which stays a check written from the same page by other
//! hands.
//!
//! Why not `dynamixel2` (0.9.1, used before): it panics on a status packet whose length field
//! is below 4, misses the stuffing of `FF FF FF FD FD`, and its sync read expects the
//! replies in request order with 34 ms each: one lost reply made the next motor's reply "the
//! wrong id" and the one after a 34 ms time-out. It also flushes the input before every
//! instruction, so a reply that the kernel delivers late (a loaded machine) is thrown away,
//! and every exchange blocks the caller until its reply or its time-out. Here a thread reads
//! the line all the time ([`Wire`]), [`Decoder`] finds every status packet whatever came
//! before it, and the caller matches replies to requests by id, never by order.

use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use serial2::SerialPort;
use softarm_runtime::now_ns;

pub const HEADER: [u8; 4] = [0xFF, 0xFF, 0xFD, 0x00];
pub const BROADCAST_ID: u8 = 0xFE;

/// Instruction codes (e-Manual, "Instruction").
pub mod instruction {
    pub const PING: u8 = 0x01;
    pub const READ: u8 = 0x02;
    pub const WRITE: u8 = 0x03;
    pub const STATUS: u8 = 0x55;
    pub const SYNC_READ: u8 = 0x82;
    pub const SYNC_WRITE: u8 = 0x83;
}

/// The longest status packet the driver asks for has 54 parameters (the settings read at
/// start, Operating Mode .. Torque Enable), 72 stuffed at worst; a length field above this is
/// not a reply of ours. Once running, the longest has 10 (14 stuffed):
/// [`LineCounts::running`] narrows the limit, so a garbled length field is refused at once
/// instead of swallowing the replies behind it until enough bytes came.
pub const START_MAX_LENGTH: usize = 4 + 72;
pub const RUNNING_MAX_LENGTH: usize = 4 + 14;

/// CRC-16 (polynomial 0x8005, initial value 0, not reflected), as the e-Manual's table code.
const CRC_TABLE: [u16; 256] = {
    let mut table = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = (i as u16) << 8;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x8005
            } else {
                crc << 1
            };
            bit += 1;
        }
        table[i] = crc;
        i += 1;
    }
    table
};

pub fn crc16(bytes: &[u8]) -> u16 {
    bytes.iter().fold(0u16, |crc, &b| {
        (crc << 8) ^ CRC_TABLE[usize::from((crc >> 8) as u8 ^ b)]
    })
}

/// An instruction packet: header, id, length, then instruction and parameters with a 0xFD
/// added after every `FF FF FD` (byte stuffing), then the CRC of all that.
pub fn encode(id: u8, inst: u8, params: &[u8]) -> Vec<u8> {
    let mut p = Vec::with_capacity(10 + params.len() + params.len() / 3);
    p.extend_from_slice(&HEADER);
    p.extend_from_slice(&[id, 0, 0]);
    let body = p.len();
    for &b in std::iter::once(&inst).chain(params) {
        p.push(b);
        if p.len() - body >= 3 && p[p.len() - 3..] == [0xFF, 0xFF, 0xFD] {
            p.push(0xFD);
        }
    }
    let length = (p.len() - body + 2) as u16;
    p[5..7].copy_from_slice(&length.to_le_bytes());
    let crc = crc16(&p);
    p.extend_from_slice(&crc.to_le_bytes());
    p
}

/// Undoes byte stuffing: the 0xFD that follows `FF FF FD` is dropped.
pub fn unstuff(stuffed: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(stuffed.len());
    for (i, &b) in stuffed.iter().enumerate() {
        if b == 0xFD && i >= 3 && stuffed[i - 3..i] == [0xFF, 0xFF, 0xFD] {
            continue;
        }
        out.push(b);
    }
    out
}

/// A status packet as it arrived.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Status {
    pub id: u8,
    /// The error field: bit 7 the alert bit, bits 0..6 the error number.
    pub error: u8,
    pub params: Vec<u8>,
}

/// What the line delivered besides status packets, each counted once.
#[derive(Debug, Default)]
pub struct LineCounts {
    /// Packets that came whole with a wrong CRC.
    pub crc_errors: AtomicU64,
    /// Bytes that belonged to no packet.
    pub garbage_bytes: AtomicU64,
    /// The longest length field taken for a reply of ours (0: [`START_MAX_LENGTH`]).
    pub max_length: std::sync::atomic::AtomicUsize,
}

impl LineCounts {
    fn add(counter: &AtomicU64, n: u64) {
        counter.fetch_add(n, Ordering::Relaxed);
    }

    /// From now on only the replies of a running driver are expected.
    pub fn running(&self) {
        self.max_length.store(RUNNING_MAX_LENGTH, Ordering::Relaxed);
    }

    fn max_length(&self) -> usize {
        match self.max_length.load(Ordering::Relaxed) {
            0 => START_MAX_LENGTH,
            n => n,
        }
    }
}

/// Finds status packets in a byte stream split anywhere, with anything between them.
#[derive(Debug, Default)]
pub struct Decoder {
    buf: Vec<u8>,
}

impl Decoder {
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// The next whole status packet, if one is there; what it skips is counted.
    pub fn next(&mut self, counts: &LineCounts) -> Option<Status> {
        loop {
            let start = self.buf.windows(4).position(|w| w == HEADER);
            let skip = start.unwrap_or_else(|| {
                // A tail that may be the start of a header waits for more bytes.
                let keep = (1..4)
                    .rev()
                    .find(|&k| self.buf.ends_with(&HEADER[..k]))
                    .unwrap_or(0);
                self.buf.len() - keep
            });
            if skip > 0 {
                LineCounts::add(&counts.garbage_bytes, skip as u64);
                self.buf.drain(..skip);
            }
            if start.is_none() || self.buf.len() < 7 {
                return None;
            }
            let length = usize::from(u16::from_le_bytes([self.buf[5], self.buf[6]]));
            if !(4..=counts.max_length()).contains(&length) {
                // Not a reply of ours (a garbled length): its first byte is garbage, and a
                // real packet may start inside.
                LineCounts::add(&counts.garbage_bytes, 1);
                self.buf.drain(..1);
                continue;
            }
            let total = 7 + length;
            if self.buf.len() < total {
                return None;
            }
            let crc = u16::from_le_bytes([self.buf[total - 2], self.buf[total - 1]]);
            if crc != crc16(&self.buf[..total - 2]) {
                LineCounts::add(&counts.crc_errors, 1);
                // One bad packet: its bytes go, unless a header inside it starts another.
                let inner = self.buf[1..total]
                    .windows(4)
                    .position(|w| w == HEADER)
                    .map_or(total, |p| p + 1);
                self.buf.drain(..inner);
                continue;
            }
            let id = self.buf[4];
            let body = unstuff(&self.buf[7..total - 2]);
            self.buf.drain(..total);
            // An instruction (an adapter that echoes what it sends) is not a reply.
            if body.len() >= 2 && body[0] == instruction::STATUS {
                return Some(Status {
                    id,
                    error: body[1],
                    params: body[2..].to_vec(),
                });
            }
        }
    }
}

/// What the reading thread delivers.
#[derive(Debug)]
pub enum Arrival {
    /// A status packet, and when it was decoded (ns).
    Status(Status, u64),
    /// The port failed (not a time-out): the thread has ended.
    PortError(String),
}

/// An open port: instructions written by the caller, the line read all the time by a thread
/// of its own, so a late or missing reply never holds back a write.
pub struct Wire {
    port: SerialPort,
    path: PathBuf,
    arrivals: Receiver<Arrival>,
    pub counts: Arc<LineCounts>,
    stop: Arc<AtomicBool>,
    reader: Option<JoinHandle<()>>,
    /// The device the port was opened on (st_rdev), to tell a new adapter behind the same
    /// name.
    device: Option<u64>,
    /// Tests: bytes as they were written, when asked for.
    pub sent: Option<Arc<Mutex<Vec<u8>>>>,
}

impl Wire {
    /// Opens the port; a write that cannot go out within `write_timeout` fails with a
    /// time-out (serial2's default of 3 s would stall the loop).
    pub fn open(path: &Path, baud: u32, write_timeout: Duration) -> io::Result<Self> {
        let mut port = SerialPort::open(path, baud)?;
        port.set_write_timeout(write_timeout)?;
        let mut reading = port.try_clone()?;
        // Short, so the thread hears its stop signal.
        reading.set_read_timeout(Duration::from_millis(20))?;
        let counts = Arc::new(LineCounts::default());
        let stop = Arc::new(AtomicBool::new(false));
        let (tx, arrivals) = channel();
        let reader = {
            let (counts, stop) = (counts.clone(), stop.clone());
            std::thread::Builder::new()
                .name("tendon bus reader".into())
                .spawn(move || read_line(reading, tx, &counts, &stop))?
        };
        Ok(Self {
            device: device_of(path),
            path: path.to_owned(),
            port,
            arrivals,
            counts,
            stop,
            reader: Some(reader),
            sent: None,
        })
    }

    /// Writes one instruction packet. A time-out is returned as such (the caller decides);
    /// any other error means the port is gone.
    pub fn send(&mut self, id: u8, inst: u8, params: &[u8]) -> io::Result<()> {
        let packet = encode(id, inst, params);
        if let Some(sent) = &self.sent
            && let Ok(mut s) = sent.lock()
        {
            s.extend_from_slice(&packet);
        }
        self.port.write_all(&packet)
    }

    /// The next arrival, waiting at most `timeout` (zero: only what is there).
    pub fn receive(&self, timeout: Duration) -> Option<Arrival> {
        if timeout.is_zero() {
            self.arrivals.try_recv().ok()
        } else {
            self.arrivals.recv_timeout(timeout).ok()
        }
    }

    /// Evidence that the port is gone although nothing failed yet: its name names no device
    /// now, or another one (an adapter plugged in again behind the same udev name).
    pub fn device_changed(&self) -> bool {
        match (device_of(&self.path), self.device) {
            (None, _) => true,
            (Some(now), Some(then)) => now != then,
            (Some(_), None) => false,
        }
    }
}

impl Drop for Wire {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(r) = self.reader.take() {
            let _ = r.join();
        }
    }
}

fn device_of(path: &Path) -> Option<u64> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(path).ok().map(|m| m.rdev())
}

/// The reading thread: bytes to packets to the channel until stopped or the port fails.
fn read_line(port: SerialPort, tx: Sender<Arrival>, counts: &LineCounts, stop: &AtomicBool) {
    let mut decoder = Decoder::default();
    let mut buf = [0u8; 512];
    while !stop.load(Ordering::Relaxed) {
        let n = match port.read(&mut buf) {
            // End of file: the line hung up (its other side closed, the adapter unplugged). A
            // live port with nothing to read times out instead; reading on spun a core.
            Ok(0) => {
                let _ = tx.send(Arrival::PortError("end of file: the line hung up".into()));
                return;
            }
            Ok(n) => n,
            Err(e) if is_timeout(&e) => continue,
            Err(e) => {
                let _ = tx.send(Arrival::PortError(e.to_string()));
                return;
            }
        };
        decoder.push(&buf[..n]);
        let at = now_ns();
        while let Some(s) = decoder.next(counts) {
            if tx.send(Arrival::Status(s, at)).is_err() {
                return;
            }
        }
    }
}

pub fn is_timeout(e: &io::Error) -> bool {
    use io::ErrorKind::*;
    matches!(e.kind(), TimedOut | WouldBlock | Interrupted)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(s: &str) -> Vec<u8> {
        s.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    /// The e-Manual's examples, byte for byte.
    #[test]
    fn manual_packets() {
        // Ping to id 1.
        assert_eq!(
            encode(1, instruction::PING, &[]),
            hex("FF FF FD 00 01 03 00 01 19 4E")
        );
        // Read of 4 bytes at 132 from id 1.
        assert_eq!(
            encode(1, instruction::READ, &[0x84, 0, 4, 0]),
            hex("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15")
        );
        // Its status packet: Present Position 166 (0xA6).
        let counts = LineCounts::default();
        let mut d = Decoder::default();
        d.push(&hex("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0"));
        assert_eq!(
            d.next(&counts),
            Some(Status {
                id: 1,
                error: 0,
                params: vec![0xA6, 0, 0, 0]
            })
        );
    }

    #[test]
    fn stuffing_round_trips() {
        let params = [0xFF, 0xFF, 0xFD, 0xFD, 0xFF, 0xFF, 0xFF, 0xFD, 0x01];
        let p = encode(7, instruction::WRITE, &params);
        let length = usize::from(u16::from_le_bytes([p[5], p[6]]));
        assert_eq!(length, 1 + params.len() + 2 + 2, "two 0xFD added");
        let body = unstuff(&p[7..p.len() - 2]);
        assert_eq!(body[0], instruction::WRITE);
        assert_eq!(&body[1..], &params);
    }

    fn status_bytes(id: u8, error: u8, params: &[u8]) -> Vec<u8> {
        let mut p = encode(id, instruction::STATUS, &[]);
        // Rebuilt with the error field and parameters (encode knows instructions only).
        p.truncate(7);
        let mut body = vec![instruction::STATUS, error];
        body.extend_from_slice(params);
        let stuffed = encode(0, 0, &body);
        p.extend_from_slice(&stuffed[8..stuffed.len() - 2]);
        let length = (p.len() - 7 + 2) as u16;
        p[5..7].copy_from_slice(&length.to_le_bytes());
        let crc = crc16(&p);
        p.extend_from_slice(&crc.to_le_bytes());
        p
    }

    #[test]
    fn garbage_bad_crcs_and_short_lengths_are_counted_once_and_skipped() {
        let counts = LineCounts::default();
        let mut d = Decoder::default();
        let good = status_bytes(3, 0x80, &[1, 2, 3, 4]);
        let mut bad = status_bytes(4, 0, &[5, 6, 7, 8]);
        let last = bad.len() - 1;
        bad[last] ^= 0x5A;
        // dynamixel2 0.9.1 panicked on this one: a length field of 1.
        let short = [0xFF, 0xFF, 0xFD, 0x00, 0x02, 0x01, 0x00, 0x55];
        let mut line = vec![0x11, 0x22, 0x33];
        line.extend_from_slice(&short);
        line.extend_from_slice(&bad);
        line.extend_from_slice(&good);
        // Split anywhere.
        for chunk in line.chunks(5) {
            d.push(chunk);
        }
        let s = d.next(&counts).unwrap();
        assert_eq!((s.id, s.error, s.params), (3, 0x80, vec![1, 2, 3, 4]));
        assert_eq!(d.next(&counts), None);
        assert_eq!(counts.crc_errors.load(Ordering::Relaxed), 1);
        assert_eq!(
            counts.garbage_bytes.load(Ordering::Relaxed),
            3 + short.len() as u64
        );
    }

    #[test]
    fn a_reply_inside_a_garbled_one_is_found() {
        // A corrupted length swallows the next packet; the CRC fails and the decoder finds
        // the packet inside.
        let counts = LineCounts::default();
        let mut d = Decoder::default();
        let mut first = status_bytes(1, 0, &[1, 1, 1, 1]);
        first[5] = 0x10; // length 16 instead of 8
        let second = status_bytes(2, 0, &[2, 2, 2, 2]);
        d.push(&first);
        d.push(&second);
        let s = d.next(&counts).unwrap();
        assert_eq!(s.id, 2);
        assert_eq!(counts.crc_errors.load(Ordering::Relaxed), 1);
    }

    #[test]
    fn stuffed_status_with_three_ff_is_unstuffed() {
        // Present Velocity -1 then a position byte 0xFD: `FF FF FF FF FD` is stuffed to
        // `FF FF FF FF FD FD`; dynamixel2 0.9.1 kept the second 0xFD.
        let counts = LineCounts::default();
        let mut d = Decoder::default();
        let params = [0, 0, 0xFF, 0xFF, 0xFF, 0xFF, 0xFD, 0x07, 0, 0];
        d.push(&status_bytes(5, 0, &params));
        assert_eq!(d.next(&counts).unwrap().params, params);
    }

    #[test]
    fn random_bytes_never_panic() {
        let counts = LineCounts::default();
        let mut d = Decoder::default();
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        for _ in 0..50_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            // Headers often, so that lengths and CRCs are exercised.
            let b = if x.is_multiple_of(7) {
                0xFF
            } else {
                (x >> 8) as u8
            };
            d.push(&[b]);
            while d.next(&counts).is_some() {}
        }
    }
}
