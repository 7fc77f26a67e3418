//! The `tracker` driver process: an electromagnetic tracker speaking the Ascension Bird RS-232
//! protocol (trakSTAR class). Configures the record format, streams (or polls) records, finds
//! their boundaries by the phasing bit ([`bird::Decoder`]), converts them to metres in the base
//! frame and publishes `tracker` samples stamped on arrival. At open it stops a stream left
//! running and selects the configured hemisphere, read back where the unit allows (module
//! `setup`). A silent device is reported and asked again on the same port with back-off:
//! silence is no evidence that the port is gone (a loaded host delivers a pseudo-terminal's
//! bytes late). The port is reopened only when it is gone: an I/O error, end of file (a
//! hang-up), or its name leading to no device or to another one. The loop never blocks longer
//! than a read time-out (an open, with its drain and read-back, about 1.4 s at most), so it
//! always hears its stop signal.

use std::io::{ErrorKind, Read, Write};
use std::os::fd::AsFd;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::Context;
use serial2::SerialPort;

use softarm_config::Config;
use softarm_config::hardware::{Frame, TrackerConfig, TrackerMode, TrackerRecord};
use softarm_ipc::{Namespace, Node, Position, TrackerSample};
use softarm_runtime::clock::Backoff;
use softarm_runtime::now_ns;

pub mod bird;
mod setup;

use bird::{Decoder, RecordFormat};
pub use setup::{READBACK_TIMEOUT, ReadBack, StopBy};

/// How long one read waits: the loop's longest pause (opening the port, with its drain and
/// read-back, takes longer: at most about 1.4 s).
const READ_TIMEOUT: Duration = Duration::from_millis(10);

fn format_of(t: &TrackerConfig) -> RecordFormat {
    match t.record {
        TrackerRecord::Position => RecordFormat::Position,
        TrackerRecord::PositionAngles => RecordFormat::PositionAngles,
    }
}

/// Bird records carry no checksum: a garbled data byte decodes to a wrong position. A record
/// farther from the last accepted one than the arm can move in the time between (plus a margin
/// for noise) is held back; the next record decides: close to the held one, the arm did move
/// and it is accepted; close to the last, the held one was garbage.
#[derive(Debug)]
struct Plausibility {
    max_speed_m_per_s: f64,
    last: Option<(Position, u64)>,
    held: Option<(Position, u64)>,
    rejected: u64,
}

impl Plausibility {
    /// Noise and quantisation the bound allows beyond the speed (m).
    const MARGIN_M: f64 = 0.005;

    fn new(max_speed_m_per_s: f64) -> Self {
        Self {
            max_speed_m_per_s,
            last: None,
            held: None,
            rejected: 0,
        }
    }

    fn near(&self, from: (Position, u64), p: Position, t: u64) -> bool {
        let dt = t.saturating_sub(from.1) as f64 * 1e-9;
        let d = (0..3)
            .map(|i| (p[i] - from.0[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        d <= self.max_speed_m_per_s * dt + Self::MARGIN_M
    }

    /// Whether to publish `p`, arrived at `t`.
    fn accept(&mut self, p: Position, t: u64) -> bool {
        let ok = match self.last {
            None => true,
            Some(last) if self.near(last, p, t) => true,
            // Two records that agree with each other: the arm did move (a knock, a jump
            // after a silence).
            _ => self.held.is_some_and(|h| self.near(h, p, t)),
        };
        if ok {
            self.last = Some((p, t));
            self.held = None;
        } else {
            self.held = Some((p, t));
            self.rejected += 1;
        }
        ok
    }
}

/// One read: at most [`READ_TIMEOUT`]; 0 bytes when nothing came. End of file is an error: the
/// line hung up (the port's other side closed, an adapter unplugged), and the port is gone.
fn read(port: &mut SerialPort, buf: &mut [u8]) -> std::io::Result<usize> {
    match port.read(buf) {
        // The port is non-blocking: a live line with nothing to read times out or would block.
        Ok(0) => Err(std::io::Error::new(
            ErrorKind::UnexpectedEof,
            "end of file: the line hung up",
        )),
        Ok(n) => Ok(n),
        Err(e) if is_timeout(&e) => Ok(0),
        Err(e) => Err(e),
    }
}

fn is_timeout(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted
    )
}

/// Which device a port is: `st_dev`, `st_ino` and `st_rdev` of its node. An adapter plugged in
/// again is a new node behind the same name (another inode, or another device number).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Device(u64, u64, u64);

impl Device {
    fn of(m: &std::fs::Metadata) -> Self {
        use std::os::unix::fs::MetadataExt;
        Self(m.dev(), m.ino(), m.rdev())
    }

    /// The device `path` leads to now (symbolic links followed, as udev names are).
    fn at(path: &Path) -> Option<Self> {
        std::fs::metadata(path).ok().map(|m| Self::of(&m))
    }

    /// The device an open port is.
    fn opened(port: &SerialPort) -> Option<Self> {
        let fd = port.as_fd().try_clone_to_owned().ok()?;
        std::fs::File::from(fd)
            .metadata()
            .ok()
            .map(|m| Self::of(&m))
    }
}

/// Evidence that a port is gone though no read failed: its name leads to no device now, or to
/// another than the one `opened`.
fn replaced(opened: Option<Device>, now: Option<Device>) -> bool {
    match (opened, now) {
        (_, None) => true,
        (Some(o), Some(n)) => o != n,
        (None, Some(_)) => false,
    }
}

/// A unit that sends nothing: reported after `silent_after_ms`, and asked again on the same
/// port at once, then at doubling intervals up to 2 s, until a record comes. Silence is no
/// evidence that the port is gone: a loaded host delivers a pseudo-terminal's bytes hundreds
/// of milliseconds late, and reopening then loses more records than it saves.
#[derive(Debug)]
struct Silence {
    silent_ns: u64,
    last_record: u64,
    silent: bool,
    episodes: u64,
    /// The unit asked again, in all.
    asked: u64,
    ask: Backoff,
}

impl Silence {
    fn new(silent_ns: u64, now: u64) -> Self {
        Self {
            silent_ns,
            last_record: now,
            silent: false,
            episodes: 0,
            asked: 0,
            ask: Backoff::new(silent_ns, 2_000_000_000),
        }
    }

    /// A record that arrived at `at`; whether it ended a silence.
    fn record(&mut self, at: u64) -> bool {
        self.last_record = self.last_record.max(at);
        std::mem::take(&mut self.silent)
    }

    /// A port (re)opened at `now`: the unit's silence counts from here.
    fn restart(&mut self, now: u64) {
        self.last_record = now;
        self.silent = false;
    }

    fn silent_ms(&self, now: u64) -> u64 {
        now.saturating_sub(self.last_record) / 1_000_000
    }

    /// Whether the unit is to be asked again at `now`.
    fn ask_due(&mut self, now: u64) -> bool {
        if now.saturating_sub(self.last_record) < self.silent_ns {
            return false;
        }
        if !self.silent {
            self.silent = true;
            self.episodes += 1;
            self.ask.succeeded();
        }
        if !self.ask.ready(now) {
            return false;
        }
        self.ask.failed(now);
        self.asked += 1;
        true
    }
}

/// Runs the tracker driver until `stop` is set.
pub fn run(config: &Config, namespace: Namespace, stop: &AtomicBool) -> anyhow::Result<()> {
    let t = config
        .tracker
        .as_ref()
        .context("the config has no [tracker] section")?;
    let node = Node::open(namespace, "tracker")?;
    let publisher = node.publisher(&node.tracker()?)?;
    let mut reader = Reader::open(t)?;
    while !stop.load(Ordering::Relaxed) {
        reader.step(|sample| {
            let _ = publisher.send_copy(sample);
        });
    }
    reader.leave();
    Ok(())
}

/// While the unit is silent, the device behind `tracker.port` is checked this often.
const CHECK_DEVICE_EVERY_NS: u64 = 100_000_000;

/// The tracker's line and what was learnt from it between reads: the driver without its
/// iceoryx2 publisher (so tests can drive it against an emulated unit).
pub struct Reader<'a> {
    t: &'a TrackerConfig,
    frame: Frame,
    /// `None` while the port is closed (being reopened).
    port: Option<SerialPort>,
    /// The device the port was opened on.
    device: Option<Device>,
    format: RecordFormat,
    decoder: Decoder,
    plausible: Plausibility,
    period_ns: u64,
    seq: u64,
    reported: bird::DecoderStats,
    next_poll: u64,
    silence: Silence,
    /// When the device behind the port was last checked (only while the unit is silent).
    device_checked: u64,
    /// Ports closed because they were gone (to be reopened), and failed opens.
    reopens: u64,
    port_faults: u64,
    /// Writes that did not go out within the write time-out: skipped, not a reopen.
    write_timeouts: u64,
    reopen: Backoff,
    /// How this unit stops a stream, learnt at the first open.
    stop_by: StopBy,
    /// The last open's hemisphere read-back, and whether an unverified one was reported (once:
    /// a unit that lacks the parameter lacks it at every reopen).
    readback: ReadBack,
    unverified_reported: bool,
}

impl<'a> Reader<'a> {
    /// Opens `t.port` and sets the unit up: the stream a previous session left stopped, the
    /// hemisphere selected and read back, the scaling, the format, and the stream (or polling).
    pub fn open(t: &'a TrackerConfig) -> anyhow::Result<Self> {
        let format = format_of(t);
        let mut decoder = Decoder::new(format, t.full_scale_in);
        let opened = setup::open(t, &mut decoder, StopBy::StreamStop)?;
        tracing::info!(
            port = %t.port.display(),
            baud = t.baud,
            record = ?t.record,
            mode = ?t.mode,
            hemisphere = t.hemisphere.name(),
            stop_by = ?opened.stop_by,
            "tracker open"
        );
        let now = now_ns();
        let mut reader = Self {
            t,
            frame: Frame::new(t),
            device: Device::opened(&opened.port),
            port: Some(opened.port),
            format,
            reported: decoder.stats(),
            decoder,
            plausible: Plausibility::new(t.max_speed_m_per_s),
            period_ns: (1e9 / t.rate_hz) as u64,
            seq: 0,
            next_poll: now,
            silence: Silence::new((t.silent_after_ms * 1e6) as u64, now),
            device_checked: now,
            reopens: 0,
            port_faults: 0,
            write_timeouts: 0,
            reopen: Backoff::new(10_000_000, 2_000_000_000),
            stop_by: opened.stop_by,
            readback: opened.readback,
            unverified_reported: false,
        };
        reader.report_readback();
        Ok(reader)
    }

    /// One turn of the loop as named steps: the port kept (reopened only when it is gone), a
    /// poll when due and one read (at most [`READ_TIMEOUT`]), every plausible record handed to
    /// `publish` as a sample in the base frame, a silent unit asked again.
    pub fn step(&mut self, publish: impl FnMut(TrackerSample)) {
        let now = now_ns();
        if !self.keep_port(now) {
            return;
        }
        let mut buf = [0u8; 256];
        let Some(n) = self.exchange(now, &mut buf) else {
            return;
        };
        let arrived = now_ns();
        self.decode(&buf[..n], arrived, publish);
        self.report_line();
        self.ask_if_silent(arrived);
    }

    /// Counts of the records read so far.
    pub fn stats(&self) -> bird::DecoderStats {
        self.decoder.stats()
    }

    /// Ports closed because they were gone (each reopened once it could be).
    pub fn reopens(&self) -> u64 {
        self.reopens
    }

    /// Times the silent unit was asked again on its port.
    pub fn asked_again(&self) -> u64 {
        self.silence.asked
    }

    /// What the last open's hemisphere read-back said.
    pub fn readback(&self) -> ReadBack {
        self.readback
    }

    /// How this unit's stream is stopped.
    pub fn stop_by(&self) -> StopBy {
        self.stop_by
    }

    /// Says what the read-back said: confirmed at debug; unverified at most once per process.
    fn report_readback(&mut self) {
        let h = self.t.hemisphere.name();
        match self.readback {
            ReadBack::Confirmed => tracing::debug!(hemisphere = h, "tracker hemisphere confirmed"),
            ReadBack::NotAnswered if !self.unverified_reported => {
                self.unverified_reported = true;
                tracing::warn!(
                    hemisphere = h,
                    "the tracker did not answer the hemisphere read-back (EXAMINE VALUE of \
                     parameter 22, which units before software revision 3.66 lack; or the unit \
                     is silent): HEMISPHERE was sent but is not verified (said once)"
                );
            }
            ReadBack::Garbled(bytes) => tracing::warn!(
                hemisphere = h,
                ?bytes,
                "the tracker's hemisphere read-back names no hemisphere (a noisy line?): \
                 HEMISPHERE was sent but is not verified"
            ),
            ReadBack::NotAnswered => {}
        }
    }

    /// Whether the port is open and still the device opened. A closed port is opened again
    /// once the back-off allows (the loop waits a read time-out while it may not); while the
    /// unit is silent, an open one whose name leads to no device now, or to another (an
    /// adapter plugged in again), is closed: the old descriptor would never hear from it.
    fn keep_port(&mut self, now: u64) -> bool {
        if self.port.is_none() {
            self.reopen_port(now);
            return false;
        }
        if self.silence.silent && now.saturating_sub(self.device_checked) >= CHECK_DEVICE_EVERY_NS {
            self.device_checked = now;
            if replaced(self.device, Device::at(&self.t.port)) {
                self.close(now, "the device behind it is gone or was replaced");
                return false;
            }
        }
        true
    }

    /// Opens the port again and sets the unit up, when the back-off allows.
    fn reopen_port(&mut self, now: u64) {
        if !self.reopen.ready(now) {
            std::thread::sleep(READ_TIMEOUT);
            return;
        }
        self.decoder.reset();
        match setup::open(self.t, &mut self.decoder, self.stop_by) {
            Ok(opened) => {
                tracing::warn!(
                    port = %self.t.port.display(),
                    reopens = self.reopens,
                    "tracker port open again"
                );
                self.device = Device::opened(&opened.port);
                self.port = Some(opened.port);
                self.stop_by = opened.stop_by;
                self.readback = opened.readback;
                self.report_readback();
                self.reopen.succeeded();
                self.silence.restart(now_ns());
            }
            Err(e) => {
                self.port_faults += 1;
                self.reopen.failed(now);
                tracing::error!(port_faults = self.port_faults, "{e:#}");
            }
        }
    }

    /// Closes a port that is gone (`why`), to be reopened at once and then with back-off.
    fn close(&mut self, now: u64, why: &str) {
        if self.port.take().is_some() {
            self.reopens += 1;
            self.reopen.succeeded();
            self.reopen.failed(now);
            tracing::error!(
                port = %self.t.port.display(),
                reopens = self.reopens,
                "tracker port lost: {why}; reopening"
            );
        }
    }

    /// Polls (in POINT mode, when due, and not while the unit is silent: then it is asked
    /// again at the back-off's pace, so a stalled line does not pile up polls whose answers
    /// would all come at once) and reads: the bytes read, `None` when the port is gone.
    fn exchange(&mut self, now: u64, buf: &mut [u8]) -> Option<usize> {
        let poll = self.t.mode == TrackerMode::Point && !self.silence.silent;
        if poll && now >= self.next_poll {
            self.next_poll = self.next_poll.saturating_add(self.period_ns).max(now);
            let written = self.port.as_mut()?.write_all(&[bird::POINT]);
            self.wrote(now, written, "polling (POINT)");
        }
        match read(self.port.as_mut()?, buf) {
            Ok(n) => Some(n),
            Err(e) => {
                self.close(now, &format!("reading: {e}"));
                None
            }
        }
    }

    /// What a write's result says about the port: a time-out is a line backed up (counted,
    /// said at powers of two; the write is skipped), any other error a port that is gone.
    fn wrote(&mut self, now: u64, r: std::io::Result<()>, what: &str) {
        match r {
            Ok(()) => {}
            Err(e) if is_timeout(&e) => {
                self.write_timeouts += 1;
                if self.write_timeouts.is_power_of_two() {
                    tracing::warn!(
                        port = %self.t.port.display(),
                        write_timeouts = self.write_timeouts,
                        "tracker: {what}: the write did not go out in time (the line is backed \
                         up); skipped"
                    );
                }
            }
            Err(e) => self.close(now, &format!("{what}: {e}")),
        }
    }

    /// Decodes `bytes`, read at `arrived`, and hands every plausible record to `publish` as a
    /// sample in the base frame; a record ends a silence.
    fn decode(&mut self, bytes: &[u8], arrived: u64, mut publish: impl FnMut(TrackerSample)) {
        // Several records in one read waited in the line: the k-th of the last m arrived
        // (m - 1 - k) record periods earlier, as far as anyone can tell.
        let mut behind = (self.decoder.pending() + bytes.len()) / self.format.bytes();
        for &byte in bytes {
            let Some(record) = self.decoder.push(byte) else {
                continue;
            };
            behind = behind.saturating_sub(1);
            let arrived = arrived.saturating_sub(behind as u64 * self.period_ns);
            if self.silence.record(arrived) {
                tracing::warn!(
                    asked_again = self.silence.asked,
                    "the tracker answers again"
                );
            }
            let position = self.frame.to_base(record.position_in);
            if !self.plausible.accept(position, arrived) {
                if self.plausible.rejected.is_power_of_two() {
                    tracing::warn!(
                        rejected = self.plausible.rejected,
                        ?position,
                        "tracker record too far from the last: held back until the next \
                         confirms it"
                    );
                }
                continue;
            }
            self.seq += 1;
            publish(TrackerSample {
                seq: self.seq,
                stamp_ns: arrived,
                position,
            });
        }
    }

    /// Reports lost or garbled records, at powers of two: a noisy line must not flood the
    /// journal.
    fn report_line(&mut self) {
        let stats = self.decoder.stats();
        if stats == self.reported {
            return;
        }
        let bad = stats.malformed + stats.dropped_bytes;
        if bad != self.reported.malformed + self.reported.dropped_bytes && bad.is_power_of_two() {
            tracing::warn!(
                records = stats.records,
                malformed = stats.malformed,
                dropped_bytes = stats.dropped_bytes,
                "tracker records lost or garbled; resynchronised on the phasing bit"
            );
        }
        self.reported = stats;
    }

    /// A unit silent for `silent_after_ms` is reported and asked again on the same port, at
    /// doubling intervals ([`Silence`]); the port is reopened only when it is gone.
    fn ask_if_silent(&mut self, now: u64) {
        if !self.silence.ask_due(now) {
            return;
        }
        tracing::error!(
            port = %self.t.port.display(),
            silent_ms = self.silence.silent_ms(now),
            silent_episodes = self.silence.episodes,
            asked_again = self.silence.asked,
            "the tracker sends nothing; asking it again on the same port"
        );
        let Some(p) = self.port.as_mut() else {
            return;
        };
        let written = setup::ask_again(p, self.t);
        self.wrote(now, written, "asking the silent unit again");
    }

    /// Leaves the device quiet for the next one to open it, and says what happened. A unit
    /// that needs POINT to stop answers with a record nobody reads: the next open drains it.
    pub fn leave(&mut self) {
        if let Some(p) = self.port.as_mut() {
            let stop = match self.stop_by {
                StopBy::StreamStop => bird::STREAM_STOP,
                StopBy::Point => bird::POINT,
            };
            let _ = p.write_all(&[stop]);
        }
        let s = self.decoder.stats();
        tracing::info!(
            records = s.records,
            malformed = s.malformed,
            dropped_bytes = s.dropped_bytes,
            discarded = s.discarded,
            implausible = self.plausible.rejected,
            silent_episodes = self.silence.episodes,
            asked_again = self.silence.asked,
            reopens = self.reopens,
            port_faults = self.port_faults,
            write_timeouts = self.write_timeouts,
            "tracker driver stopped"
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn a_garbled_record_is_held_back_and_a_real_move_is_not() {
        let mut p = Plausibility::new(2.0);
        assert!(p.accept([0.0, 0.0, -0.4], 0));
        // 10 ms later: 2 m/s allows 20 mm + 5 mm.
        assert!(p.accept([0.02, 0.0, -0.4], 10 * MS));
        // A garbled word: 0.3 m off for one record.
        assert!(!p.accept([0.32, 0.0, -0.4], 20 * MS));
        assert!(p.accept([0.03, 0.0, -0.4], 30 * MS));
        assert_eq!(p.rejected, 1);
        // The arm knocked 0.1 m away: held once, confirmed by the next.
        assert!(!p.accept([0.13, 0.0, -0.4], 40 * MS));
        assert!(p.accept([0.131, 0.0, -0.4], 50 * MS));
        assert!(p.accept([0.132, 0.0, -0.4], 60 * MS));
        // After a long silence the arm may be anywhere within reach of the speed.
        assert!(p.accept([0.3, 0.0, -0.4], 2000 * MS));
    }

    /// The times (ms) at which a unit silent since 0 is asked again, stepping 1 ms up to `end`.
    fn asks(s: &mut Silence, from: u64, end: u64) -> Vec<u64> {
        (from..=end).filter(|&t| s.ask_due(t * MS)).collect()
    }

    #[test]
    fn a_silent_unit_is_asked_again_at_doubling_intervals_until_a_record_comes() {
        let mut s = Silence::new(200 * MS, 0);
        // Reported and asked at once after 200 ms, then at doubling intervals up to 2 s.
        assert_eq!(asks(&mut s, 0, 6000), [200, 400, 800, 1600, 3200, 5200]);
        assert_eq!((s.episodes, s.asked), (1, 6));
        assert!(s.silent);
        // A record ends it; the next silence starts over from 200 ms.
        assert!(s.record(6000 * MS));
        assert!(!s.record(6010 * MS), "not silent any more");
        assert_eq!(asks(&mut s, 6011, 7000), [6210, 6410, 6810]);
        assert_eq!(s.episodes, 2);
        // Records back-dated behind the newest do not move the silence back.
        s.record(7000 * MS);
        s.record(6900 * MS);
        assert_eq!(asks(&mut s, 7001, 7200), [7200]);
        // A port opened again: its silence counts from the open.
        s.restart(9000 * MS);
        assert!(!s.silent);
        assert_eq!(asks(&mut s, 9001, 9200), [9200]);
    }

    #[test]
    fn only_a_name_that_leads_elsewhere_or_nowhere_is_a_replaced_device() {
        let (a, b) = (Device(1, 2, 3), Device(1, 5, 3));
        assert!(!replaced(Some(a), Some(a)));
        assert!(
            replaced(Some(a), Some(b)),
            "another inode: plugged in again"
        );
        assert!(
            replaced(Some(a), Some(Device(1, 2, 4))),
            "another device number"
        );
        assert!(replaced(Some(a), None), "the name leads nowhere");
        assert!(!replaced(None, Some(a)), "unknown at open: no evidence");
    }

    #[test]
    fn a_name_pointed_at_another_node_is_another_device() {
        let dir = std::env::temp_dir().join(format!("softarm-tracker-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (a, b, link) = (dir.join("a"), dir.join("b"), dir.join("link"));
        std::fs::write(&a, b"").unwrap();
        std::fs::write(&b, b"").unwrap();
        let _ = std::fs::remove_file(&link);
        std::os::unix::fs::symlink(&a, &link).unwrap();
        let opened = Device::at(&link);
        assert_eq!(opened, Device::at(&a));
        assert!(!replaced(opened, Device::at(&link)));
        std::fs::remove_file(&link).unwrap();
        assert!(
            replaced(opened, Device::at(&link)),
            "unplugged: the name is gone"
        );
        std::os::unix::fs::symlink(&b, &link).unwrap();
        assert!(
            replaced(opened, Device::at(&link)),
            "the name leads to another node"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
