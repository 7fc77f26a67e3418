//! How long the bus takes: when a read's replies are all in, and whether a cycle's writes and
//! reads fit in a period of `tendon.rate_hz`. A byte is 10 bits on the line (start, 8 data,
//! stop); each motor answers its Return Delay Time after the packet before its answer ends (the
//! instruction's, or the previous motor's in a SYNC READ), one after another.

use std::time::Duration;

use softarm_config::hardware::TendonConfig;

/// The Return Delay Time the driver writes at start: the motors answer at once, one after
/// another. The factory's 250 (500 µs) makes a SYNC READ of nine motors wait 4.5 ms for the
/// delays alone; the ROBOTIS e-Manual advises lowering it when many motors share a bus.
pub const RETURN_DELAY: u8 = 0;

/// A Return Delay Time's unit.
const RETURN_DELAY_UNIT_NS: u64 = 2_000;

/// The host's and the adapter's share of an exchange, beyond the line's: twice the USB
/// adapter's latency timer and 2 ms, as the ROBOTIS DYNAMIXEL SDK sizes its packet time-out,
/// with the FTDI's timer at 1 ms as `config/udev/99-softarm.rules` sets it (at its default of
/// 16 ms every reply waits that long in the adapter).
pub const LATENCY_MARGIN: Duration = Duration::from_millis(4);

/// How late after their time on the line the replies have come, over the last
/// [`LATENESS_KEPT_S`] seconds: the host's and the adapter's share of an exchange as this
/// computer has it now. A loaded computer wakes the driver's threads milliseconds late, again
/// and again while the load lasts; a read asked again before its replies could arrive is a
/// time-out counted for nothing, and on a real bus a collision.
#[derive(Debug, Clone, Copy, Default)]
pub struct Lateness {
    /// The latest of each of the last seconds, this one's last (ns).
    latest: [u64; LATENESS_KEPT_S],
    /// When this second began.
    began_ns: u64,
}

/// Seconds a late reply widens the wait for.
pub const LATENESS_KEPT_S: usize = 5;

impl Lateness {
    /// A reply that was due on the line at `due_ns` arrived at `at_ns`.
    pub fn heard(&mut self, at_ns: u64, due_ns: u64) {
        let seconds = at_ns.saturating_sub(self.began_ns) / 1_000_000_000;
        if seconds > 0 {
            let shift = (seconds as usize).min(LATENESS_KEPT_S);
            self.latest.rotate_left(shift);
            self.latest[LATENESS_KEPT_S - shift..].fill(0);
            self.began_ns = at_ns;
        }
        let late = at_ns.saturating_sub(due_ns);
        self.latest[LATENESS_KEPT_S - 1] = self.latest[LATENESS_KEPT_S - 1].max(late);
    }

    /// The wait for replies beyond their time on the line: [`LATENCY_MARGIN`], or half as much
    /// again as the latest lateness seen lately, whichever is longer (ns).
    pub fn margin_ns(&self) -> u64 {
        let seen = self.latest.iter().copied().max().unwrap_or(0);
        (LATENCY_MARGIN.as_nanos() as u64).max(seen + seen / 2)
    }
}

/// Bytes of a packet besides its parameters: header 4, id, length 2, instruction, CRC 2.
const PACKET_BYTES: usize = 10;
/// Bytes of a status packet besides its data: the above and the error byte.
const STATUS_BYTES: usize = PACKET_BYTES + 1;
/// A SYNC READ's or SYNC WRITE's parameters before the motors': address 2, length 2.
const SYNC_BYTES: usize = 4;

/// The bytes the longest cycle reads from each motor: Present Current, Velocity and Position.
pub const LONGEST_READ: usize = 10;
/// The bytes of a goal (Goal Position).
const GOAL: usize = 4;

/// Time on a line of `baud` bits per second.
#[derive(Debug, Clone, Copy)]
pub struct Line {
    baud: u32,
}

impl Line {
    pub fn new(baud: u32) -> Self {
        Self { baud: baud.max(1) }
    }

    /// `n` bytes on the line (ns).
    pub fn bytes_ns(&self, n: usize) -> u64 {
        n as u64 * 10_000_000_000 / u64::from(self.baud)
    }

    /// A SYNC READ of `data` bytes from the motors whose Return Delay Times are `delays`: its
    /// instruction, then each reply after its motor's delay (ns).
    pub fn sync_read_ns(&self, data: usize, delays: impl IntoIterator<Item = u8>) -> u64 {
        let (mut motors, mut replies) = (0, 0);
        for d in delays {
            motors += 1;
            replies += u64::from(d) * RETURN_DELAY_UNIT_NS + self.bytes_ns(STATUS_BYTES + data);
        }
        self.bytes_ns(PACKET_BYTES + SYNC_BYTES + motors) + replies
    }

    /// A SYNC WRITE of `data` bytes to each of `motors` motors (ns): no reply.
    pub fn sync_write_ns(&self, data: usize, motors: usize) -> u64 {
        self.bytes_ns(PACKET_BYTES + SYNC_BYTES + motors * (1 + data))
    }
}

/// A cycle of one bus at its longest: every goal written, every motor's current, velocity and
/// position read, and the host's and the adapter's share, against the period.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cycle {
    pub motors: usize,
    pub baud: u32,
    /// The longest Return Delay Time of the motors (µs).
    pub delay_us: u64,
    pub write_ns: u64,
    pub read_ns: u64,
    pub margin_ns: u64,
    pub period_ns: u64,
}

impl Cycle {
    /// The cycle of `t`'s bus whose motors have Return Delay Times `delays`.
    pub fn of(t: &TendonConfig, delays: &[u8]) -> Self {
        let line = Line::new(t.baud);
        Self {
            motors: delays.len(),
            baud: t.baud,
            delay_us: delays.iter().map(|&d| u64::from(d) * 2).max().unwrap_or(0),
            write_ns: line.sync_write_ns(GOAL, delays.len()),
            read_ns: line.sync_read_ns(LONGEST_READ, delays.iter().copied()),
            margin_ns: LATENCY_MARGIN.as_nanos() as u64,
            period_ns: (1e9 / t.rate_hz) as u64,
        }
    }

    pub fn total_ns(&self) -> u64 {
        self.write_ns + self.read_ns + self.margin_ns
    }

    /// Every motor is read within a period, after the goals.
    pub fn fits(&self) -> bool {
        self.total_ns() <= self.period_ns
    }

    /// The highest `tendon.rate_hz` at which it fits.
    pub fn max_rate_hz(&self) -> f64 {
        1e9 / self.total_ns() as f64
    }

    /// The line alone (the goals' write and the replies, without the host's and the adapter's
    /// margin, an estimate) carries every motor within a period.
    pub fn line_fits(&self) -> bool {
        self.write_ns + self.read_ns <= self.period_ns
    }

    /// The highest `tendon.rate_hz` the line alone carries.
    pub fn line_max_rate_hz(&self) -> f64 {
        1e9 / (self.write_ns + self.read_ns) as f64
    }

    /// The figures, for the log and for errors.
    pub fn describe(&self) -> String {
        let ms = |ns: u64| ns as f64 / 1e6;
        format!(
            "a cycle of {} motors at {} baud takes {:.1} ms of the {:.1} ms period ({:.0} Hz): \
             the goals' write {:.2} ms, a SYNC READ of every motor {:.2} ms (replies after a \
             Return Delay Time of up to {} µs), {:.1} ms for the host and the adapter; at most \
             {:.0} Hz",
            self.motors,
            self.baud,
            ms(self.total_ns()),
            ms(self.period_ns),
            1e9 / self.period_ns as f64,
            ms(self.write_ns),
            ms(self.read_ns),
            self.delay_us,
            ms(self.margin_ns),
            self.max_rate_hz().floor(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sync_read_is_its_instruction_then_each_reply_after_its_delay() {
        let line = Line::new(1_000_000);
        assert_eq!(line.bytes_ns(1), 10_000);
        // Nine positions: 23 bytes out, nine replies of 15 bytes.
        assert_eq!(line.sync_read_ns(4, [0; 9]), 230_000 + 9 * 150_000);
        // At the factory's 500 µs each, 4.5 ms more.
        assert_eq!(line.sync_read_ns(4, [250; 9]), 230_000 + 9 * 650_000);
        // Nine goals: 14 + 9 × 5 bytes.
        assert_eq!(line.sync_write_ns(4, 9), 590_000);
    }

    #[test]
    fn the_margin_follows_the_latest_lateness_of_the_last_seconds() {
        const MS: u64 = 1_000_000;
        let mut l = Lateness::default();
        assert_eq!(l.margin_ns(), 4 * MS, "at least the adapter's");
        l.heard(1000 * MS, 999 * MS);
        assert_eq!(l.margin_ns(), 4 * MS);
        l.heard(1100 * MS, 1092 * MS);
        assert_eq!(l.margin_ns(), 12 * MS, "8 ms late and a half");
        // An early reply (the line model long) is not late.
        l.heard(1200 * MS, 1300 * MS);
        l.heard(5050 * MS, 5049 * MS);
        assert_eq!(l.margin_ns(), 12 * MS, "kept for 5 s");
        l.heard(6100 * MS, 6099 * MS);
        assert_eq!(l.margin_ns(), 4 * MS, "forgotten after them");
        l.heard(6200 * MS, 6194 * MS);
        l.heard(60_000 * MS, 59_999 * MS);
        assert_eq!(l.margin_ns(), 4 * MS, "a long silence forgets too");
    }

    #[test]
    fn a_cycle_fits_a_period_or_says_by_how_much_it_does_not() {
        let text = include_str!("../../../config/hardware.toml");
        let c = softarm_config::Config::parse(text, "hardware.toml", ".".into()).unwrap();
        let mut t = c.tendon.unwrap();
        assert_eq!((t.rate_hz, t.baud), (100.0, 1_000_000), "the shipped bus");
        let nine = Cycle::of(&t, &[RETURN_DELAY; 9]);
        // 0.59 ms of goals, 0.23 + 9 × 0.21 ms of reads, 4 ms of margin.
        assert_eq!(nine.total_ns(), 590_000 + 2_120_000 + 4_000_000);
        assert!(nine.fits());
        // Sixteen at the factory's delay: 16 × 0.71 ms of replies alone.
        let factory = Cycle::of(&t, &[250; 16]);
        assert!(!factory.fits(), "{}", factory.describe());
        assert!(factory.describe().contains("500 µs"));
        // At 57600 baud nine motors' 271 bytes take 47 ms: 19 Hz, not 100.
        t.baud = 57_600;
        let slow = Cycle::of(&t, &[RETURN_DELAY; 9]);
        assert!(!slow.fits() && (19.0..20.0).contains(&slow.max_rate_hz()));
    }
}
