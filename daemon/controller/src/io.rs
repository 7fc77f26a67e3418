//! The io thread: publishes what the tick produced. iceoryx2 0.10 allocates a reference count
//! for every loaned sample, so the tick hands its samples to this thread over a bounded
//! lock-free ring instead of sending them itself; this thread sends them a fraction of a period
//! later, at the tick's rate.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

use anyhow::Context;
use rtrb::{Consumer, Producer, RingBuffer};
use softarm_ipc::clock::Ticker;
use softarm_ipc::iceoryx2::port::update_connections::UpdateConnections;
use softarm_ipc::{
    ConditioningSample, ControllerStatus, ExecutionStats, Namespace, Node, Setpoint, now_ns,
};
use softarm_model::config::Config;

/// What the tick publishes.
pub(crate) enum Outgoing {
    Setpoint(Setpoint),
    Sample(ConditioningSample),
    Stats(ExecutionStats),
    Status(ControllerStatus),
}

/// The tick's side of the ring to the io thread.
pub(crate) struct Outbox {
    tx: Producer<Outgoing>,
    /// The first tick deadline; the io thread runs at the same rate, `IO_OFFSET_NS` later.
    epoch_ns: u64,
}

impl Outbox {
    /// Never blocks; a full outbox (io thread stalled) drops the sample.
    pub(crate) fn send(&mut self, m: Outgoing) {
        let _ = self.tx.push(m);
    }

    pub(crate) fn epoch_ns(&self) -> u64 {
        self.epoch_ns
    }
}

/// Room for a few periods of everything the tick publishes.
const OUTBOX_CAPACITY: usize = 256;

/// How long after each tick deadline the io thread sends (ns): past the tick's wake-up and
/// evaluation, well inside the period.
const IO_OFFSET_NS: u64 = 250_000;

/// Starts the io thread; it runs until `stop` is set.
pub(crate) fn start(
    config: &Config,
    namespace: Namespace,
    stop: Arc<AtomicBool>,
) -> anyhow::Result<(Outbox, JoinHandle<anyhow::Result<()>>)> {
    let (tx, rx) = RingBuffer::<Outgoing>::new(OUTBOX_CAPACITY);
    let rate = config.controller.rate_hz;
    let epoch_ns = now_ns() + 20_000_000;
    let io_start = epoch_ns + IO_OFFSET_NS.min((5e8 / rate) as u64);
    let handle = std::thread::Builder::new()
        .name("controller-io".into())
        .spawn(move || run(namespace, rx, rate, io_start, &stop))
        .context("starting the io thread")?;
    Ok((Outbox { tx, epoch_ns }, handle))
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
