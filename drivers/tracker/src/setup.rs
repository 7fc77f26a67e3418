//! Opening the tracker's line and setting the unit up: stop whatever stream a previous session
//! left running (without letting its last record pass for a fresh one), select the configured
//! hemisphere and read it back, then the position scaling, the record format and the stream.
//!
//! # Stopping a stream
//!
//! STREAM STOP (`?`, trakSTAR) ends a stream and sends nothing; POINT (`B`, every Bird) ends it
//! too but answers with one more record. The driver sends STREAM STOP and listens: a unit that
//! accepts it (or was not streaming) goes quiet within a few record periods. One that keeps
//! streaming (an older Flock of Birds, which does not know `?`) is stopped with POINT, and the
//! one record that answers it is swallowed by the decoder ([`Decoder::discard_next`]) if it had
//! not come yet, so it never comes out as a fresh sample; the driver remembers the unit's way
//! and uses POINT from then on (reopens, leaving).
//!
//! # Reading the hemisphere back
//!
//! HEMISPHERE has no answer, so the driver asks EXAMINE VALUE of parameter 22 on a quiet line
//! and compares the two bytes (axis, sign) with what it sent. Another valid hemisphere is an
//! error (the unit did not take the command: positions would come out mirrored); no answer is
//! not (units before software revision 3.66 lack the parameter): the driver says so once and
//! goes on with the hemisphere sent but unverified. Bytes that name no hemisphere (a noisy line)
//! are reported and the driver goes on.

use std::io::Write;
use std::time::{Duration, Instant};

use anyhow::Context;
use serial2::SerialPort;
use softarm_config::hardware::{TrackerConfig, TrackerMode};

use crate::bird::{self, Decoder, Hemisphere, HemisphereBytes};
use crate::{READ_TIMEOUT, format_of, read};

/// How a stream is stopped on this unit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StopBy {
    /// STREAM STOP: nothing follows.
    StreamStop,
    /// POINT: one record follows, to be discarded.
    Point,
}

/// What the hemisphere read-back said.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReadBack {
    /// The unit reads back the hemisphere sent.
    Confirmed,
    /// No answer within [`READBACK_TIMEOUT`] (an older unit, or a silent one).
    NotAnswered,
    /// Bytes that name no hemisphere.
    Garbled([u8; 2]),
}

/// A line opened and the unit set up.
pub(crate) struct Opened {
    pub port: SerialPort,
    pub readback: ReadBack,
    /// How this unit stops a stream (learnt here when STREAM STOP was ignored).
    pub stop_by: StopBy,
}

/// The longest the read-back answer may take.
pub const READBACK_TIMEOUT: Duration = Duration::from_millis(150);
/// The longest a drain waits for the line to go quiet before deciding the unit still streams.
const DRAIN_LIMIT: Duration = Duration::from_millis(600);

/// Opens `t.port` and sets the unit up (see the module docs). `decoder` is the one the driver
/// reads records with: a POINT answer still owed when this returns is left for it to discard.
pub(crate) fn open(
    t: &TrackerConfig,
    decoder: &mut Decoder,
    stop_by: StopBy,
) -> anyhow::Result<Opened> {
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
    let on = |what: &str| format!("tracker {}: {what}", t.port.display());
    let stop_by = quiesce(&mut port, t, decoder, stop_by).with_context(|| on("stopping"))?;
    let readback = select_hemisphere(&mut port, t.hemisphere)
        .with_context(|| on("selecting the hemisphere (tracker.hemisphere)"))?;
    start(&mut port, t).with_context(|| on("starting"))?;
    Ok(Opened {
        port,
        readback,
        stop_by,
    })
}

/// Stops a stream left running, so the line is quiet for the read-back; how it was stopped.
fn quiesce(
    port: &mut SerialPort,
    t: &TrackerConfig,
    decoder: &mut Decoder,
    stop_by: StopBy,
) -> anyhow::Result<StopBy> {
    let quiet = quiet_window(t);
    if stop_by == StopBy::StreamStop {
        port.write_all(&[bird::STREAM_STOP])?;
        if drain(port, decoder, quiet)?.quiet {
            return Ok(StopBy::StreamStop);
        }
        tracing::warn!(
            "the tracker kept streaming after STREAM STOP ('?'); stopping it with POINT from now \
             on (the record that answers POINT is discarded)"
        );
    }
    port.write_all(&[bird::POINT])?;
    decoder.discard_next(1);
    let drained = drain(port, decoder, quiet)?;
    if drained.quiet && drained.records > 0 {
        // The answer came during the drain (the unit sends nothing after it), and went with it.
        decoder.discard_next(0);
    }
    Ok(StopBy::Point)
}

/// No byte for this long: the unit is not streaming. Five record periods, within 100–300 ms:
/// long enough that a stream stalled by a busy host is not taken for a stopped one.
fn quiet_window(t: &TrackerConfig) -> Duration {
    Duration::from_secs_f64((5.0 / t.rate_hz).clamp(0.1, 0.3))
}

struct Drained {
    /// The line was quiet for the whole window before [`DRAIN_LIMIT`].
    quiet: bool,
    /// Complete records that went by (stale: from before the stop).
    records: u64,
}

/// Reads and drops what comes until nothing has come for `quiet` (or [`DRAIN_LIMIT`] passes).
/// The bytes go through `decoder` (its records dropped) so a record split across the end of
/// the drain is not misread after it.
fn drain(
    port: &mut SerialPort,
    decoder: &mut Decoder,
    quiet: Duration,
) -> std::io::Result<Drained> {
    let start = Instant::now();
    let before = decoder.stats().records;
    let mut last_byte = start;
    let mut buf = [0u8; 256];
    loop {
        let now = Instant::now();
        if now.duration_since(last_byte) >= quiet {
            let records = decoder.stats().records - before;
            return Ok(Drained {
                quiet: true,
                records,
            });
        }
        if now.duration_since(start) >= DRAIN_LIMIT {
            let records = decoder.stats().records - before;
            return Ok(Drained {
                quiet: false,
                records,
            });
        }
        let n = read(port, &mut buf)?;
        if n > 0 {
            last_byte = Instant::now();
            for &b in &buf[..n] {
                let _stale = decoder.push(b);
            }
        }
    }
}

/// Sends HEMISPHERE and reads it back (EXAMINE VALUE of parameter 22).
fn select_hemisphere(port: &mut SerialPort, want: Hemisphere) -> anyhow::Result<ReadBack> {
    port.write_all(&want.command())?;
    port.write_all(&[bird::EXAMINE_VALUE, bird::param::HEMISPHERE])?;
    let start = Instant::now();
    let mut got = [0u8; 2];
    let mut have = 0;
    let mut buf = [0u8; 2];
    while have < 2 && start.elapsed() < READBACK_TIMEOUT {
        let n = read(port, &mut buf[..2 - have])?;
        got[have..have + n].copy_from_slice(&buf[..n]);
        have += n;
    }
    if have < 2 {
        return Ok(ReadBack::NotAnswered);
    }
    match Hemisphere::from_bytes(got) {
        Some(h) if h == want => Ok(ReadBack::Confirmed),
        Some(h) => anyhow::bail!(
            "sent HEMISPHERE {want:?} ({:#04x} {:#04x}) but the unit reads back {h:?} \
             ({:#04x} {:#04x}): it did not take the command, and positions on the other side \
             of the transmitter would come out mirrored",
            want.bytes()[0],
            want.bytes()[1],
            got[0],
            got[1]
        ),
        None => Ok(ReadBack::Garbled(got)),
    }
}

/// Asks a silent unit again on the open line: the settings that have no answer (the
/// hemisphere, the scaling, the record format: a unit power-cycled behind a live line starts
/// in its defaults, which would mirror or scale its positions) and the stream, or one POINT.
/// Only POINT is answered, with one record, so the records in the line stay whole and the
/// decoder in phase; the read-back, which answers with bytes that are no record, needs a quiet
/// line and is left to an open.
pub(crate) fn ask_again(port: &mut SerialPort, t: &TrackerConfig) -> std::io::Result<()> {
    port.write_all(&t.hemisphere.command())?;
    start(port, t)?;
    if t.mode == TrackerMode::Point {
        port.write_all(&[bird::POINT])?;
    }
    Ok(())
}

/// Sets the position scaling the config expects (a device left at the other one would
/// report every position off by a factor of two), asks for the configured record format and,
/// in stream mode, starts the stream.
fn start(port: &mut SerialPort, t: &TrackerConfig) -> std::io::Result<()> {
    // POSITION SCALING: 0 = 36 in, 1 = 72 in, a little-endian word.
    let scaling = u8::from(t.full_scale_in == bird::FULL_SCALE_EXTENDED_IN);
    port.write_all(&[
        bird::CHANGE_VALUE,
        bird::param::POSITION_SCALING,
        scaling,
        0,
    ])?;
    port.write_all(&[format_of(t).command()])?;
    if t.mode == TrackerMode::Stream {
        port.write_all(&[bird::STREAM])?;
    }
    Ok(())
}
