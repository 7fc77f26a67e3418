//! The tick loop: on every absolute deadline, read the inputs, take the [`Control`]'s steps
//! (decide the state, step the mode, limit, publish), and now and then the status. It
//! allocates nothing, locks nothing and frees nothing once running: sets and demonstrations
//! come and go as boxes over lock-free rings, and what it publishes goes to the io thread.

use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;
use rtrb::{Consumer, Producer};
use softarm_config::{Config, Controller};
use softarm_ipc::{
    ConditioningSample, ControllerStatus, DriverState, EstopState, ExecutionStats, MotorState,
    Namespace, Node, Setpoint, Sub, TrackerSample,
};
use softarm_runtime::clock::Ticker;
use softarm_runtime::now_ns;

use crate::control::{Control, Decided, Latest, Outputs, Plan, Retired};
use crate::io::{Outbox, Outgoing};
use crate::latency::TickLatency;
use crate::{Shared, rt};

/// The tick's ends of the rings to the other threads.
pub(crate) struct Links<const N: usize> {
    /// Sets and demonstrations from the service thread.
    pub(crate) plans: Consumer<Plan<N>>,
    /// What the tick is done with, back to the service thread.
    pub(crate) retired: Producer<Retired<N>>,
    pub(crate) outbox: Outbox,
}

/// Runs the tick loop on the calling thread until `stop` is set.
pub(crate) fn run<const N: usize>(
    config: &Config,
    namespace: Namespace,
    shared: &Shared,
    links: Links<N>,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    let engaged = shared.latched.load(Ordering::Relaxed);
    let ports = Inputs::open(namespace, engaged).context("opening the tick's subscribers")?;
    rt::setup(&config.controller);
    let mut tick = Tick::new(&config.controller, ports, shared, links);
    tracing::info!(rate_hz = tick.timing.rate_hz, "controller running");
    while !stop.load(Ordering::Relaxed) && !shared.thread_failed.load(Ordering::Relaxed) {
        tick.tick();
    }
    let refused = tick.inputs.refused;
    let overruns = tick.ticker.overruns();
    let ticks = tick.ticks;
    if refused == 0 {
        tracing::info!(ticks, overruns, "controller stopped");
    } else {
        tracing::warn!(
            ticks,
            overruns,
            "controller stopped; it refused {refused} tracker or motor samples that were not numbers"
        );
    }
    Ok(())
}

/// The configured timing of the loop itself.
struct Timing {
    rate_hz: f64,
    /// Ticks per status (10 Hz).
    status_every: u64,
}

impl Timing {
    fn new(c: &Controller) -> Self {
        Self {
            rate_hz: c.rate_hz,
            status_every: (c.rate_hz / 10.0).round().max(1.0) as u64,
        }
    }
}

/// The subscriptions, and the newest of each.
struct Inputs<const N: usize> {
    tracker: Sub<TrackerSample>,
    motors: Sub<MotorState>,
    estop: Sub<EstopState>,
    latest: Latest<N>,
    /// The latch file said engaged when last looked at ([`Shared::latched`]).
    latched: bool,
    /// Samples whose position or actuation is not a number: never taken as fresh data (the
    /// controller holds on stale data rather than execute on, or start its limiter from, NaN).
    refused: u64,
    /// Last, so the ports go before it.
    _node: Node,
}

impl<const N: usize> Inputs<N> {
    /// `engaged`: the e-stop latch as the process found it on disk.
    fn open(namespace: Namespace, engaged: bool) -> Result<Self, softarm_ipc::Error> {
        let node = Node::open(namespace, "controller")?;
        Ok(Self {
            tracker: node.subscriber(&node.tracker()?)?,
            motors: node.subscriber(&node.motor_state()?)?,
            estop: node.subscriber(&node.estop()?)?,
            latest: Latest::new(engaged),
            latched: engaged,
            refused: 0,
            _node: node,
        })
    }

    /// Takes in everything that arrived since the last tick, and the latch file as the service
    /// thread last read it.
    fn read(&mut self, latched: bool) {
        let latest = &mut self.latest;
        // The file engages (newly engaged: an e-stop whose sample was missed); only the reset's
        // sample releases. A reset writes the file before it publishes, so releasing on the
        // file would set the controller going before the reset is on the `estop` service, and
        // a reader of both (a safety watch) would see motion after an e-stop it saw no reset
        // of. A reset sample missed leaves it STOPPED, and `softarm estop --reset` says so.
        if latched && !self.latched {
            latest.engaged = true;
        }
        self.latched = latched;
        while let Ok(Some(s)) = self.tracker.receive() {
            if s.position.iter().all(|v| v.is_finite()) {
                latest.take_tracker(s.stamp_ns, s.position);
            } else {
                self.refused += 1;
            }
        }
        while let Ok(Some(s)) = self.motors.receive() {
            // A reading of another arm's actuators is no reading of this one.
            match s.actuation.fixed() {
                Some(a) if a.iter().all(|v| v.is_finite()) => latest.take_motors(s.stamp_ns, a),
                _ => self.refused += 1,
            }
            // What the driver says of itself holds whatever its readings.
            latest.driver_fault =
                s.state == DriverState::Fault as u32 || s.state == DriverState::Off as u32;
        }
        while let Ok(Some(s)) = self.estop.receive() {
            latest.engaged = s.engaged != 0;
        }
    }
}

/// The controller's outputs: the outbox to the io thread, the ring back to the service thread.
impl<const N: usize> Outputs<N> for Links<N> {
    fn setpoint(&mut self, s: Setpoint) {
        self.outbox.send(Outgoing::Setpoint(s));
    }

    fn sample(&mut self, s: ConditioningSample) {
        self.outbox.send(Outgoing::Sample(s));
    }

    fn stats(&mut self, s: ExecutionStats) {
        self.outbox.send(Outgoing::Stats(s));
    }

    /// Never blocks: the ring has room for all that can be in flight; were it full, the box
    /// would be freed here, as with any bounded channel.
    fn retire(&mut self, r: Retired<N>) {
        let _ = self.retired.push(r);
    }
}

/// Everything the tick loop keeps between ticks: its I/O around the [`Control`].
struct Tick<'a, const N: usize> {
    timing: Timing,
    inputs: Inputs<N>,
    shared: &'a Shared,
    links: Links<N>,
    ticker: Ticker,
    latency: TickLatency,
    control: Control<N>,
    /// Periods the clock skipped before this tick (overruns): a playing execution follows.
    skipped: u64,
    ticks: u64,
}

impl<'a, const N: usize> Tick<'a, N> {
    fn new(config: &Controller, inputs: Inputs<N>, shared: &'a Shared, links: Links<N>) -> Self {
        let timing = Timing::new(config);
        Self {
            // On the io thread's phase, from the first deadline still ahead: opening the
            // inputs can take seconds on a loaded machine (a killed controller's iceoryx2
            // resources cleaned up), which is not the loop running late (seen: 5000 overruns
            // and a 10 s "latency" in the status of a controller that never stalled).
            ticker: Ticker::joining(timing.rate_hz, links.outbox.epoch_ns(), now_ns()),
            timing,
            inputs,
            shared,
            links,
            latency: TickLatency::new(),
            control: Control::new(config),
            skipped: 0,
            ticks: 0,
        }
    }

    /// One tick: wait, read the inputs, the [`Control`]'s steps, status, heartbeat.
    fn tick(&mut self) {
        let now = self.wait();
        // What waited for room goes before anything new.
        self.links.outbox.flush();
        self.inputs
            .read(self.shared.latched.load(Ordering::Relaxed));
        let plan = self.links.plans.pop().ok();
        let decided = self.control.tick(
            now,
            self.skipped,
            &self.inputs.latest,
            plan,
            &mut self.links,
        );
        self.shared
            .state
            .store(decided.state as u32, Ordering::Relaxed);
        if self.ticks.is_multiple_of(self.timing.status_every) {
            self.publish_status(now, &decided);
        }
        self.shared.heartbeat.store(self.ticks, Ordering::Relaxed);
    }

    /// Sleeps until the next deadline; the time of this tick.
    fn wait(&mut self) -> u64 {
        let wake = self.ticker.wait();
        self.latency.record(wake.latency_ns);
        self.skipped = wake.missed;
        self.ticks += 1;
        now_ns()
    }

    fn publish_status(&mut self, now: u64, decided: &Decided) {
        let drops = self.links.outbox.drops();
        let r = self.control.report();
        let status = ControllerStatus {
            seq: self.ticks,
            stamp_ns: now,
            state: decided.state as u32,
            execution: r.execution,
            set_id: r.set_id,
            rate_hz: self.timing.rate_hz,
            ticks: self.ticks,
            overruns: self.ticker.overruns(),
            latency: self.latency.summary(),
            tracker_age_ns: decided.health.tracker_age_ns,
            motor_age_ns: decided.health.motor_age_ns,
            model_loaded: self.shared.model_loaded.load(Ordering::Relaxed) as u32,
            reconditions_current: r.reconditions_current,
            reconditions_last: r.reconditions_last,
            outbox_backlog: self.links.outbox.backlog() as u32,
            outbox_dropped: drops.all,
            samples_dropped: drops.samples,
            held_solves: r.held_solves,
            points_unseen: r.points_unseen,
            lag_ns: r.lag_ns,
            lead_ns: r.lead_ns,
        };
        self.links.outbox.send(Outgoing::Status(status));
    }
}
