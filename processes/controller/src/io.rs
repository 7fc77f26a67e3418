//! The io thread: publishes what the tick produced. iceoryx2 0.10 allocates a reference count
//! for every loaned sample, so the tick hands its samples to this thread over a bounded
//! lock-free ring instead of sending them itself; this thread sends them a fraction of a period
//! later, at the tick's rate.

use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

use anyhow::Context;
use rtrb::{Consumer, Producer, PushError, RingBuffer};
use softarm_config::Config;
use softarm_ipc::iceoryx2::port::update_connections::UpdateConnections;
use softarm_ipc::{
    ConditioningSample, ControllerStatus, ExecutionStats, Namespace, Node, Setpoint,
};
use softarm_runtime::clock::Ticker;
use softarm_runtime::now_ns;

use crate::Shared;

/// What the tick publishes, by value: the ring's slots are allocated once, and a box per
/// message would allocate in the tick.
#[allow(clippy::large_enum_variant)]
pub(crate) enum Outgoing {
    Setpoint(Setpoint),
    Sample(ConditioningSample),
    Stats(ExecutionStats),
    Status(ControllerStatus),
}

/// What the outbox could not keep, since the start.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Drops {
    /// Every message dropped, of any kind.
    pub(crate) all: u64,
    /// Conditioning samples among them: the backlog was full too.
    pub(crate) samples: u64,
}

/// The tick's side of the ring to the io thread.
pub(crate) struct Outbox {
    tx: Producer<Outgoing>,
    /// The first tick deadline; the io thread runs at the same rate, `IO_OFFSET_NS` later.
    epoch_ns: u64,
    /// Conditioning samples and stats the ring had no room for, oldest first, offered again
    /// before anything newer of theirs. Preallocated; never grows past `BACKLOG`.
    backlog: VecDeque<Outgoing>,
    drops: Drops,
}

impl Outbox {
    fn new(tx: Producer<Outgoing>, epoch_ns: u64) -> Self {
        Self {
            tx,
            epoch_ns,
            backlog: VecDeque::with_capacity(BACKLOG),
            drops: Drops::default(),
        }
    }

    /// Never blocks. A full ring (io thread stalled) drops a setpoint or a status, which the
    /// next supersedes, and counts it; conditioning samples and stats, which nothing replaces
    /// (the learner needs every sample), wait in the backlog, and are dropped and counted only
    /// once that is full too.
    pub(crate) fn send(&mut self, m: Outgoing) {
        match m {
            Outgoing::Sample(_) | Outgoing::Stats(_) => self.keep(m),
            Outgoing::Setpoint(_) | Outgoing::Status(_) => {
                if self.tx.push(m).is_err() {
                    self.drops.all += 1;
                }
            }
        }
    }

    fn keep(&mut self, m: Outgoing) {
        self.flush();
        let m = if self.backlog.is_empty() {
            match self.tx.push(m) {
                Ok(()) => return,
                Err(PushError::Full(m)) => m,
            }
        } else {
            m
        };
        if self.backlog.len() < BACKLOG {
            self.backlog.push_back(m);
        } else {
            self.drops.all += 1;
            if let Outgoing::Sample(_) = m {
                self.drops.samples += 1;
            }
        }
    }

    /// Offers the backlog to the ring again, oldest first; once per tick, before anything new.
    pub(crate) fn flush(&mut self) {
        while let Some(m) = self.backlog.pop_front() {
            if let Err(PushError::Full(m)) = self.tx.push(m) {
                // Back where it was: the slot it left is free, so this never allocates.
                self.backlog.push_front(m);
                return;
            }
        }
    }

    pub(crate) fn drops(&self) -> Drops {
        self.drops
    }

    /// Messages waiting in the backlog.
    pub(crate) fn backlog(&self) -> usize {
        self.backlog.len()
    }

    pub(crate) fn epoch_ns(&self) -> u64 {
        self.epoch_ns
    }
}

/// Room for a few periods of everything the tick publishes.
const OUTBOX_CAPACITY: usize = 256;

/// Conditioning samples and stats kept while the ring is full: four executions of 16 points,
/// the `cp_sample` subscriber's buffer.
const BACKLOG: usize = 64;

/// How long after each tick deadline the io thread sends (ns): past the tick's wake-up and
/// evaluation, well inside the period.
const IO_OFFSET_NS: u64 = 250_000;

/// Starts the io thread; it runs until `stop` is set. If it fails, `shared` says so.
pub(crate) fn start(
    config: &Config,
    namespace: Namespace,
    stop: Arc<AtomicBool>,
    shared: Arc<Shared>,
) -> anyhow::Result<(Outbox, JoinHandle<anyhow::Result<()>>)> {
    let (tx, rx) = RingBuffer::<Outgoing>::new(OUTBOX_CAPACITY);
    let rate = config.controller.rate_hz;
    let epoch_ns = now_ns() + 20_000_000;
    let io_start = epoch_ns + IO_OFFSET_NS.min((5e8 / rate) as u64);
    let handle = std::thread::Builder::new()
        .name("controller-io".into())
        .spawn(move || shared.thread_ended(run(namespace, rx, rate, io_start, &stop)))
        .context("starting the io thread")?;
    Ok((Outbox::new(tx, epoch_ns), handle))
}

fn run(
    namespace: Namespace,
    mut rx: Consumer<Outgoing>,
    rate: f64,
    start_ns: u64,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    let ipc = Node::open(namespace, "controller.io").context("opening the io thread's node")?;
    let open = || -> Result<_, softarm_ipc::Error> {
        Ok((
            ipc.publisher(&ipc.setpoint()?)?,
            ipc.publisher(&ipc.cp_sample()?)?,
            ipc.publisher(&ipc.stats()?)?,
            ipc.publisher(&ipc.status()?)?,
        ))
    };
    let (setpoints, samples, stats, status) =
        open().context("opening the controller's publishers")?;
    let mut ticker = Ticker::starting_at(rate, start_ns);
    while !stop.load(Ordering::Relaxed) {
        ticker.wait();
        while let Ok(m) = rx.pop() {
            match m {
                Outgoing::Setpoint(s) => {
                    let _ = setpoints.send_copy(s);
                }
                Outgoing::Sample(s) => {
                    let _ = samples.send_copy(s);
                }
                Outgoing::Stats(s) => {
                    let _ = stats.send_copy(s);
                }
                Outgoing::Status(s) => {
                    let _ = status.send_copy(s);
                    // Late subscribers (`softarm stats`) get the history on an update.
                    let _ = stats.update_connections();
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(seq: u64) -> Outgoing {
        Outgoing::Sample(ConditioningSample {
            seq,
            ..Default::default()
        })
    }

    fn setpoint() -> Outgoing {
        Outgoing::Setpoint(Setpoint::default())
    }

    /// What the io thread would send: the samples' sequence numbers, and how many others.
    fn drain(rx: &mut Consumer<Outgoing>) -> (Vec<u64>, usize) {
        let (mut samples, mut others) = (Vec::new(), 0);
        while let Ok(m) = rx.pop() {
            match m {
                Outgoing::Sample(s) => samples.push(s.seq),
                _ => others += 1,
            }
        }
        (samples, others)
    }

    #[test]
    fn a_full_ring_counts_its_drops_and_loses_no_sample_the_backlog_can_keep() {
        let (tx, mut rx) = RingBuffer::new(4);
        let mut out = Outbox::new(tx, 0);
        for _ in 0..4 {
            out.send(setpoint());
        }
        // The io thread stalls: setpoints and statuses are dropped and counted, samples wait.
        out.send(setpoint());
        out.send(Outgoing::Status(ControllerStatus::default()));
        for seq in 1..=3 {
            out.send(sample(seq));
        }
        assert_eq!(out.drops(), Drops { all: 2, samples: 0 });
        assert_eq!(out.backlog(), 3);

        // Two slots free: the oldest two go first; the third waits, and a newer sample after it.
        rx.pop().unwrap();
        rx.pop().unwrap();
        out.flush();
        out.send(sample(4));
        assert_eq!(drain(&mut rx), (vec![1, 2], 2));
        out.flush();
        out.send(setpoint());
        assert_eq!(drain(&mut rx), (vec![3, 4], 1));
        assert_eq!(out.backlog(), 0);

        // Only once the backlog is full is a sample lost, and counted as such.
        for _ in 0..4 {
            out.send(setpoint());
        }
        for seq in 0..BACKLOG as u64 + 2 {
            out.send(sample(100 + seq));
        }
        assert_eq!(out.backlog(), BACKLOG);
        assert_eq!(out.drops(), Drops { all: 4, samples: 2 });
        // The kept ones all arrive, in order.
        let mut sent = Vec::new();
        while out.backlog() > 0 {
            sent.extend(drain(&mut rx).0);
            out.flush();
        }
        sent.extend(drain(&mut rx).0);
        assert_eq!(sent, (100..100 + BACKLOG as u64).collect::<Vec<_>>());
    }
}
