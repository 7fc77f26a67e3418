//! The `tracker` driver process: an electromagnetic tracker speaking the Ascension Bird RS-232
//! protocol (trakSTAR class). Configures the record format, streams (or polls) records, finds
//! their boundaries by the phasing bit ([`bird::Decoder`]), converts them to metres in the base
//! frame and publishes `tracker` samples stamped on arrival. A silent device is reported and
//! asked again with back-off; a lost port is reopened; the process never blocks longer than a
//! read time-out, so it always hears its stop signal.

use std::io::{ErrorKind, Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::Context;
use serial2::SerialPort;

use softarm_ipc::{Namespace, Node, TrackerSample, now_ns};
use softarm_model::config::Config;
use softarm_model::hardware::{Frame, TrackerConfig, TrackerMode, TrackerRecord};

pub mod bird;

use bird::{Decoder, RecordFormat};

/// How long one read waits: the loop's longest pause.
const READ_TIMEOUT: Duration = Duration::from_millis(10);

fn format_of(t: &TrackerConfig) -> RecordFormat {
    match t.record {
        TrackerRecord::Position => RecordFormat::Position,
        TrackerRecord::PositionAngles => RecordFormat::PositionAngles,
    }
}

fn open(t: &TrackerConfig) -> anyhow::Result<SerialPort> {
    let mut port = SerialPort::open(&t.port, t.baud).with_context(|| {
        format!(
            "cannot open the tracker {} (tracker.port); is it plugged in and are you in the \
             `dialout` group?",
            t.port.display()
        )
    })?;
    port.set_read_timeout(READ_TIMEOUT)?;
    port.set_write_timeout(Duration::from_millis(100))?;
    // Whatever the device sent before is from another session.
    let _ = port.discard_buffers();
    start(&mut port, t)?;
    Ok(port)
}

/// Asks for the configured record format and, in stream mode, starts the stream.
fn start(port: &mut SerialPort, t: &TrackerConfig) -> std::io::Result<()> {
    port.write_all(&[format_of(t).command()])?;
    if t.mode == TrackerMode::Stream {
        port.write_all(&[bird::STREAM])?;
    }
    Ok(())
}

/// One read: at most [`READ_TIMEOUT`]; 0 bytes when nothing came.
fn read(port: &mut SerialPort, buf: &mut [u8]) -> std::io::Result<usize> {
    match port.read(buf) {
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
    let frame = Frame::new(t);
    let node = Node::open(namespace, "tracker")?;
    let publisher = node.publisher(&node.tracker()?)?;
    let mut port = Some(open(t)?);
    tracing::info!(
        port = %t.port.display(),
        baud = t.baud,
        record = ?t.record,
        mode = ?t.mode,
        "tracker open"
    );

    let format = format_of(t);
    let mut decoder = Decoder::new(format, t.full_scale_in);
    let period_ns = (1e9 / t.rate_hz) as u64;
    let silent_ns = (t.silent_after_ms * 1e6) as u64;
    let mut buf = [0u8; 256];
    let mut seq = 0u64;
    let mut reported = decoder.stats();
    let mut next_poll = now_ns();
    let mut last_record = now_ns();
    // Silence: reported after silent_after_ms, the device asked again at doubling intervals.
    let mut silent = false;
    let mut silent_episodes = 0u64;
    let mut next_ask = 0u64;
    let mut ask_every = silent_ns;
    // A lost port: reopened at doubling intervals.
    let mut port_faults = 0u64;
    let mut reopen_at = 0u64;
    let mut reopen_every = 10_000_000u64;
    while !stop.load(Ordering::Relaxed) {
        let now = now_ns();
        let Some(p) = port.as_mut() else {
            if now < reopen_at {
                std::thread::sleep(READ_TIMEOUT);
                continue;
            }
            match open(t) {
                Ok(p) => {
                    tracing::warn!("tracker port back");
                    decoder.reset();
                    port = Some(p);
                    reopen_every = 10_000_000;
                }
                Err(e) => {
                    port_faults += 1;
                    reopen_at = now + reopen_every;
                    reopen_every = (reopen_every * 2).min(2_000_000_000);
                    tracing::error!(port_faults, "{e:#}");
                }
            }
            continue;
        };
        let io = if t.mode == TrackerMode::Point && now >= next_poll {
            next_poll = next_poll.saturating_add(period_ns).max(now);
            p.write_all(&[bird::POINT]).and_then(|()| read(p, &mut buf))
        } else {
            read(p, &mut buf)
        };
        let n = match io {
            Ok(n) => n,
            Err(e) => {
                port_faults += 1;
                tracing::error!(port_faults, "tracker port lost: {e}; reopening");
                port = None;
                reopen_at = now + reopen_every;
                continue;
            }
        };
        let arrived = now_ns();
        for &byte in &buf[..n] {
            if let Some(record) = decoder.push(byte) {
                seq += 1;
                last_record = arrived;
                let _ = publisher.send_copy(TrackerSample {
                    seq,
                    stamp_ns: arrived,
                    position: frame.to_base(record.position_in),
                });
            }
        }
        let stats = decoder.stats();
        if stats != reported {
            // At powers of two: a noisy line must not flood the journal.
            let bad = stats.malformed + stats.dropped_bytes;
            if bad != reported.malformed + reported.dropped_bytes && bad.is_power_of_two() {
                tracing::warn!(
                    records = stats.records,
                    malformed = stats.malformed,
                    dropped_bytes = stats.dropped_bytes,
                    "tracker records lost or garbled; resynchronised on the phasing bit"
                );
            }
            reported = stats;
        }
        if last_record == arrived && silent {
            tracing::warn!("the tracker answers again");
            silent = false;
            ask_every = silent_ns;
        }
        if arrived.saturating_sub(last_record) >= silent_ns {
            if !silent {
                silent = true;
                silent_episodes += 1;
                next_ask = arrived;
            }
            if arrived >= next_ask {
                tracing::error!(
                    silent_ms = arrived.saturating_sub(last_record) / 1_000_000,
                    silent_episodes,
                    "the tracker sends nothing; asking again"
                );
                decoder.reset();
                if let Err(e) = start(p, t) {
                    tracing::error!("tracker port lost: {e}; reopening");
                    port = None;
                }
                next_ask = arrived + ask_every;
                ask_every = (ask_every * 2).min(2_000_000_000);
            }
        }
    }
    if let Some(p) = port.as_mut() {
        // Leave the device quiet for the next one to open it.
        let _ = p.write_all(&[bird::POINT]);
    }
    let s = decoder.stats();
    tracing::info!(
        records = s.records,
        malformed = s.malformed,
        dropped_bytes = s.dropped_bytes,
        silent_episodes,
        port_faults,
        "tracker driver stopped"
    );
    Ok(())
}
