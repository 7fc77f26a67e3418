//! The `tracker` driver process: an electromagnetic tracker speaking the Ascension Bird RS-232
//! protocol (trakSTAR class). Configures the record format, streams (or polls) records, finds
//! their boundaries by the phasing bit ([`bird::Decoder`]), converts them to metres in the base
//! frame and publishes `tracker` samples stamped on arrival. At open it stops a stream left
//! running and selects the configured hemisphere, read back where the unit allows
//! (module `setup`). A silent device is reported and asked again with back-off; a lost
//! port is reopened; the loop never blocks longer than a read time-out (an open, with its drain
//! and read-back, about 1.4 s at most), so it always hears its stop signal.

use std::io::{ErrorKind, Read, Write};
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

/// One read: at most [`READ_TIMEOUT`]; 0 bytes when nothing came.
fn read(port: &mut SerialPort, buf: &mut [u8]) -> std::io::Result<usize> {
    match port.read(buf) {
        Ok(0) => {
            // End of file: a hung-up line answers at once; wait as a time-out would.
            std::thread::sleep(READ_TIMEOUT);
            Ok(0)
        }
        Ok(n) => Ok(n),
        Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock) => Ok(0),
        Err(e) if e.kind() == ErrorKind::Interrupted => Ok(0),
        Err(e) => Err(e),
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

/// The tracker's line and what was learnt from it between reads: the driver without its
/// iceoryx2 publisher (so tests can drive it against an emulated unit).
pub struct Reader<'a> {
    t: &'a TrackerConfig,
    frame: Frame,
    /// `None` while the port is closed (being reopened).
    port: Option<SerialPort>,
    format: RecordFormat,
    decoder: Decoder,
    plausible: Plausibility,
    period_ns: u64,
    silent_ns: u64,
    seq: u64,
    reported: bird::DecoderStats,
    next_poll: u64,
    last_record: u64,
    /// Silence: reported after silent_after_ms, the device asked again at doubling intervals.
    silent: bool,
    silent_episodes: u64,
    ask: Backoff,
    /// A lost port: reopened at doubling intervals.
    port_faults: u64,
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
        let silent_ns = (t.silent_after_ms * 1e6) as u64;
        let mut reader = Self {
            t,
            frame: Frame::new(t),
            port: Some(opened.port),
            format,
            reported: decoder.stats(),
            decoder,
            plausible: Plausibility::new(t.max_speed_m_per_s),
            period_ns: (1e9 / t.rate_hz) as u64,
            silent_ns,
            seq: 0,
            next_poll: now_ns(),
            last_record: now_ns(),
            silent: false,
            silent_episodes: 0,
            ask: Backoff::new(silent_ns, 2_000_000_000),
            port_faults: 0,
            reopen: Backoff::new(10_000_000, 2_000_000_000),
            stop_by: opened.stop_by,
            readback: opened.readback,
            unverified_reported: false,
        };
        reader.report_readback();
        Ok(reader)
    }

    /// One turn of the loop: reopen a lost port when due, poll, read (at most [`READ_TIMEOUT`]),
    /// and hand every plausible record to `publish` as a sample in the base frame.
    pub fn step(&mut self, publish: impl FnMut(TrackerSample)) {
        let now = now_ns();
        if !self.reopen(now) {
            return;
        }
        let mut buf = [0u8; 256];
        let Some(n) = self.exchange(now, &mut buf) else {
            return;
        };
        let arrived = now_ns();
        let got_record = self.decode(&buf[..n], arrived, publish);
        self.report_line();
        self.watch_silence(got_record, arrived);
    }

    /// Counts of the records read so far.
    pub fn stats(&self) -> bird::DecoderStats {
        self.decoder.stats()
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

    /// Whether the port is open; a closed one is opened again once the back-off allows (and
    /// the loop waits a read time-out while it may not).
    fn reopen(&mut self, now: u64) -> bool {
        if self.port.is_some() {
            return true;
        }
        if !self.reopen.ready(now) {
            std::thread::sleep(READ_TIMEOUT);
            return false;
        }
        self.decoder.reset();
        match setup::open(self.t, &mut self.decoder, self.stop_by) {
            Ok(opened) => {
                tracing::info!("tracker port opened");
                self.port = Some(opened.port);
                self.stop_by = opened.stop_by;
                self.readback = opened.readback;
                self.report_readback();
                self.reopen.succeeded();
            }
            Err(e) => {
                self.port_faults += 1;
                self.reopen.failed(now);
                tracing::error!(port_faults = self.port_faults, "{e:#}");
            }
        }
        false
    }

    /// Polls (in POINT mode, when due) and reads: the bytes read, `None` when the port was
    /// lost (closed, to be reopened).
    fn exchange(&mut self, now: u64, buf: &mut [u8]) -> Option<usize> {
        let p = self.port.as_mut()?;
        let io = if self.t.mode == TrackerMode::Point && now >= self.next_poll {
            self.next_poll = self.next_poll.saturating_add(self.period_ns).max(now);
            p.write_all(&[bird::POINT]).and_then(|()| read(p, buf))
        } else {
            read(p, buf)
        };
        match io {
            Ok(n) => Some(n),
            Err(e) => {
                self.port_faults += 1;
                tracing::error!(
                    port_faults = self.port_faults,
                    "tracker port lost: {e}; reopening"
                );
                self.port = None;
                self.reopen.failed(now);
                None
            }
        }
    }

    /// Decodes `bytes`, read at `arrived`, and hands every plausible record to `publish` as a
    /// sample in the base frame; whether any record came.
    fn decode(
        &mut self,
        bytes: &[u8],
        arrived: u64,
        mut publish: impl FnMut(TrackerSample),
    ) -> bool {
        // Several records in one read waited in the line: the k-th of the last m arrived
        // (m - 1 - k) record periods earlier, as far as anyone can tell.
        let mut got_record = false;
        let mut behind = (self.decoder.pending() + bytes.len()) / self.format.bytes();
        for &byte in bytes {
            let Some(record) = self.decoder.push(byte) else {
                continue;
            };
            behind = behind.saturating_sub(1);
            let arrived = arrived.saturating_sub(behind as u64 * self.period_ns);
            self.last_record = arrived;
            got_record = true;
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
        got_record
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

    /// A device silent for `silent_after_ms` is reported, and asked again through a freshly
    /// opened port at doubling intervals.
    fn watch_silence(&mut self, got_record: bool, now: u64) {
        if got_record && self.silent {
            tracing::warn!("the tracker answers again");
            self.silent = false;
        }
        if now.saturating_sub(self.last_record) < self.silent_ns {
            return;
        }
        if !self.silent {
            self.silent = true;
            self.silent_episodes += 1;
            self.ask.succeeded();
        }
        if self.ask.ready(now) {
            tracing::error!(
                silent_ms = now.saturating_sub(self.last_record) / 1_000_000,
                silent_episodes = self.silent_episodes,
                "the tracker sends nothing; reopening the port and asking again"
            );
            // Asked again through a freshly opened port: an adapter unplugged and plugged in
            // again is a new device behind the same name, which the old descriptor never
            // hears from.
            self.port = None;
            self.reopen.succeeded();
            self.ask.failed(now);
        }
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
            silent_episodes = self.silent_episodes,
            port_faults = self.port_faults,
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
}
