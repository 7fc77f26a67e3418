//! The tick loop: on every absolute deadline, read the inputs, decide the state, step the mode,
//! limit, publish, and now and then the status. It allocates nothing, locks nothing and frees
//! nothing once running: sets and demonstrations come and go as boxes over lock-free rings, and
//! what it publishes goes to the io thread.

use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;
use rtrb::{Consumer, Producer};
use softarm_config::{Config, Controller};
use softarm_ipc::{
    Actuation, ConditioningSample, ControllerState, ControllerStatus, DriverState, EstopState,
    ExecutionStats, MotorState, Namespace, Node, Position, Setpoint, Sub, TrackerSample,
};
use softarm_runtime::clock::Ticker;
use softarm_runtime::now_ns;

use crate::demonstration::{self, DemoPlayback, DemoSequences, NO_DEMO};
use crate::execution::{self, Execution, ReadySet, Track};
use crate::io::{Outbox, Outgoing};
use crate::lag::ActuatorLag;
use crate::latency::TickLatency;
use crate::limiter::Limiter;
use crate::{Retired, Shared, ToTick, rt};

/// The tick's ends of the rings to the other threads.
pub(crate) struct Links {
    /// Sets and demonstrations from the service thread.
    pub(crate) plans: Consumer<ToTick>,
    /// What the tick is done with, back to the service thread.
    pub(crate) retired: Producer<Retired>,
    pub(crate) outbox: Outbox,
}

/// Runs the tick loop on the calling thread until `stop` is set.
pub(crate) fn run(
    config: &Config,
    namespace: Namespace,
    shared: &Shared,
    links: Links,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    let engaged = shared.latched.load(Ordering::Relaxed);
    let ports = Inputs::open(namespace, engaged).context("opening the tick's subscribers")?;
    rt::setup(&config.controller);
    let mut tick = Tick::new(&config.controller, ports, shared, links);
    tracing::info!(rate_hz = tick.timing.rate_hz, "controller running");
    while !stop.load(Ordering::Relaxed) {
        tick.tick();
    }
    let refused = tick.inputs.refused;
    let overruns = tick.ticker.overruns();
    let ticks = tick.count.ticks;
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

/// What a playing tick does. One lives in the tick, in place: boxing the execution would
/// allocate on the tick thread when a set starts.
#[allow(clippy::large_enum_variant)]
enum Mode {
    Idle,
    Demonstrate(DemoPlayback),
    Execute(Execution),
}

/// The configured timing, in ticks where the loop counts ticks.
struct Timing {
    rate_hz: f64,
    /// Tracker or motor data older than this holds the arm (ns).
    timeout_ns: u64,
    rest_ticks: i64,
    demo_rest_ticks: i64,
    /// Ticks per status (10 Hz).
    status_every: u64,
}

impl Timing {
    fn new(c: &Controller) -> Self {
        Self {
            rate_hz: c.rate_hz,
            timeout_ns: (c.tracker_timeout_ms * 1e6) as u64,
            rest_ticks: execution::rest_ticks(c),
            demo_rest_ticks: (demonstration::rest_s(c) * c.rate_hz).round() as i64,
            status_every: (c.rate_hz / 10.0).round().max(1.0) as u64,
        }
    }
}

/// The subscriptions, and the newest of each.
struct Inputs {
    tracker: Sub<TrackerSample>,
    motors: Sub<MotorState>,
    estop: Sub<EstopState>,
    /// The end-effector position and its stamp.
    position: Option<(Position, u64)>,
    /// The newest positions, for the reach at a conditioning point.
    track: Track,
    /// The measured actuation and its stamp.
    measured: Option<(Actuation, u64)>,
    engaged: bool,
    /// The latch file said engaged when last looked at ([`Shared::latched`]).
    latched: bool,
    /// The driver reports a motor with a hardware error, or its torque off (it has not engaged
    /// the setpoint, e.g. one too far from where a sagged motor stands): the arm may not move
    /// until it is fixed; the setpoint stays where it is, so a driver that engages takes it.
    driver_fault: bool,
    /// Samples whose position or actuation is not a number: never taken as fresh data (the
    /// controller holds on stale data rather than execute on, or start its limiter from, NaN).
    refused: u64,
    /// Last, so the ports go before it.
    _node: Node,
}

impl Inputs {
    /// `engaged`: the e-stop latch as the process found it on disk.
    fn open(namespace: Namespace, engaged: bool) -> Result<Self, softarm_ipc::Error> {
        let node = Node::open(namespace, "controller")?;
        Ok(Self {
            tracker: node.subscriber(&node.tracker()?)?,
            motors: node.subscriber(&node.motor_state()?)?,
            estop: node.subscriber(&node.estop()?)?,
            position: None,
            track: Track::default(),
            measured: None,
            engaged,
            latched: engaged,
            driver_fault: false,
            refused: 0,
            _node: node,
        })
    }

    /// Takes in everything that arrived since the last tick, and the latch file as the service
    /// thread last read it.
    fn read(&mut self, latched: bool) {
        // The file engages (newly engaged: an e-stop whose sample was missed); only the reset's
        // sample releases. A reset writes the file before it publishes, so releasing on the
        // file would set the controller going before the reset is on the `estop` service, and
        // a reader of both (a safety watch) would see motion after an e-stop it saw no reset
        // of. A reset sample missed leaves it STOPPED, and `softarm estop --reset` says so.
        if latched && !self.latched {
            self.engaged = true;
        }
        self.latched = latched;
        while let Ok(Some(s)) = self.tracker.receive() {
            if s.position.iter().all(|v| v.is_finite()) {
                self.position = Some((s.position, s.stamp_ns));
                self.track.push(s.stamp_ns, s.position);
            } else {
                self.refused += 1;
            }
        }
        while let Ok(Some(s)) = self.motors.receive() {
            if s.actuation.iter().all(|v| v.is_finite()) {
                self.measured = Some((s.actuation, s.stamp_ns));
            } else {
                self.refused += 1;
            }
            // What the driver says of itself holds whatever its readings.
            self.driver_fault =
                s.state == DriverState::Fault as u32 || s.state == DriverState::Off as u32;
        }
        while let Ok(Some(s)) = self.estop.receive() {
            self.engaged = s.engaged != 0;
        }
    }
}

/// How fresh the data is at this tick, and so whether the arm may move.
struct Health {
    tracker_age_ns: u64,
    motor_age_ns: u64,
    safe: bool,
}

/// What the mode produced this tick.
struct Step {
    /// `None` holds the last setpoint.
    target: Option<Actuation>,
    /// (demonstration, class) while one is recorded.
    demo: (u32, u32),
    /// The execution under way, 0 if none.
    execution: u32,
    sample: Option<ConditioningSample>,
    finished: Option<ExecutionStats>,
}

impl Step {
    const HOLD: Self = Self {
        target: None,
        demo: (NO_DEMO, NO_DEMO),
        execution: 0,
        sample: None,
        finished: None,
    };
}

/// Sequence numbers of what the tick publishes, and what `status` reports of past sets.
#[derive(Default)]
struct Counts {
    ticks: u64,
    setpoints: u64,
    samples: u64,
    stats: u64,
    /// Re-conditionings applied during the last completed execution, whichever set it was.
    last_reconditions: u32,
    /// Held group solves of the sets already done.
    held_solves: u64,
}

/// Everything the tick loop keeps between ticks.
struct Tick<'a> {
    config: &'a Controller,
    timing: Timing,
    inputs: Inputs,
    shared: &'a Shared,
    links: Links,
    ticker: Ticker,
    latency: TickLatency,
    /// `None` until the arm's state is known: the first setpoint starts there.
    limiter: Option<Limiter>,
    /// The actuators' lag behind the setpoints, which executions lead by.
    lag: ActuatorLag,
    mode: Mode,
    /// The next set, waiting for the running one's execution to end.
    queued: Option<Box<ReadySet>>,
    was_safe: bool,
    /// The e-stop was engaged since the arm was last safe: the drivers held their own
    /// positions (or dropped the torque), not the setpoint.
    stopped_since_safe: bool,
    /// Periods the clock skipped before this tick (overruns): a playing execution follows.
    skipped: u64,
    count: Counts,
}

impl<'a> Tick<'a> {
    fn new(config: &'a Controller, inputs: Inputs, shared: &'a Shared, links: Links) -> Self {
        let timing = Timing::new(config);
        Self {
            ticker: Ticker::starting_at(timing.rate_hz, links.outbox.epoch_ns()),
            config,
            timing,
            inputs,
            shared,
            links,
            latency: TickLatency::new(),
            limiter: None,
            lag: ActuatorLag::new(config.rate_hz, config.max_lead_s),
            mode: Mode::Idle,
            queued: None,
            was_safe: false,
            stopped_since_safe: false,
            skipped: 0,
            count: Counts::default(),
        }
    }

    /// One tick: read the inputs, decide the state, step the mode, limit, publish, status.
    fn tick(&mut self) {
        let now = self.wait();
        // What waited for room goes before anything new.
        self.links.outbox.flush();
        self.inputs
            .read(self.shared.latched.load(Ordering::Relaxed));
        self.take_plan();
        if self.inputs.engaged {
            self.abandon();
            self.stopped_since_safe = true;
        }
        self.start_limiter();
        let health = self.health(now);
        let state = self.decide_state(&health);
        self.shared.state.store(state as u32, Ordering::Relaxed);
        if self.limiter.is_some() {
            if health.safe && !self.was_safe {
                self.resume();
            }
            let step = self.step_mode(health.safe, now);
            let setpoint = self.limit(step.target);
            self.measure_lag(now, &setpoint, health.safe);
            self.credit(now, &setpoint);
            self.publish(state, now, setpoint, step);
        }
        self.was_safe = health.safe;
        self.end_at_boundary();
        if self.count.ticks.is_multiple_of(self.timing.status_every) {
            self.publish_status(state, now, &health);
        }
        self.shared
            .heartbeat
            .store(self.count.ticks, Ordering::Relaxed);
    }

    /// Sleeps until the next deadline; the time of this tick.
    fn wait(&mut self) -> u64 {
        let wake = self.ticker.wait();
        self.latency.record(wake.latency_ns);
        self.skipped = wake.missed;
        self.count.ticks += 1;
        now_ns()
    }

    /// A set or demonstration from the service thread, if one came.
    fn take_plan(&mut self) {
        match self.links.plans.pop() {
            Ok(ToTick::Execute(set)) => self.execute(set),
            Ok(ToTick::Demonstrate(seqs)) => self.demonstrate(seqs),
            Err(_) => {}
        }
    }

    /// A new set runs at once, or after the running set's execution (replacing a queued one).
    fn execute(&mut self, set: Box<ReadySet>) {
        if let Mode::Execute(_) = self.mode {
            if let Some(old) = self.queued.replace(set) {
                self.retire(Retired::Set(old));
            }
            return;
        }
        if let Mode::Demonstrate(d) = std::mem::replace(&mut self.mode, Mode::Idle) {
            self.retire(Retired::Demo(d.into_sequences()));
        }
        self.mode = Mode::Execute(self.start(set));
    }

    /// A set's executions, to be led by the actuators' lag.
    fn start(&self, set: Box<ReadySet>) -> Execution {
        Execution::new(set, self.timing.rest_ticks, self.lag.max_lead_ticks())
    }

    /// Demonstrations play only from idle.
    fn demonstrate(&mut self, seqs: Box<DemoSequences>) {
        if let Mode::Idle = self.mode {
            self.mode = Mode::Demonstrate(DemoPlayback::new(seqs, self.timing.demo_rest_ticks));
        } else {
            self.retire(Retired::Demo(seqs));
        }
    }

    /// Back to the service thread to be freed. Never blocks: the ring has room for all that
    /// can be in flight; were it full, the box would be freed here, as with any bounded channel.
    fn retire(&mut self, r: Retired) {
        let _ = self.links.retired.push(r);
    }

    /// Nothing is published before the arm's state is known: the first setpoint starts there.
    fn start_limiter(&mut self) {
        if self.limiter.is_none()
            && let Some((m, _)) = self.inputs.measured
        {
            let c = self.config;
            self.limiter = Some(Limiter::new(
                c.actuator_min,
                c.actuator_max,
                c.slew_per_s,
                self.timing.rate_hz,
                m,
            ));
        }
    }

    fn health(&self, now: u64) -> Health {
        let age = |stamp: Option<u64>| stamp.map_or(u64::MAX, |t| now.saturating_sub(t));
        let tracker_age_ns = age(self.inputs.position.map(|p| p.1));
        let motor_age_ns = age(self.inputs.measured.map(|m| m.1));
        let timeout = self.timing.timeout_ns;
        Health {
            tracker_age_ns,
            motor_age_ns,
            safe: !self.inputs.engaged
                && !self.inputs.driver_fault
                && tracker_age_ns <= timeout
                && motor_age_ns <= timeout,
        }
    }

    /// STOPPED on e-stop, HOLD on stale data (or before the arm's state is known), else the
    /// mode's.
    fn decide_state(&self, health: &Health) -> ControllerState {
        if self.inputs.engaged {
            ControllerState::Stopped
        } else if !health.safe || self.limiter.is_none() {
            ControllerState::Hold
        } else {
            match self.mode {
                Mode::Idle => ControllerState::Idle,
                Mode::Demonstrate(_) => ControllerState::Demonstrate,
                Mode::Execute(_) => ControllerState::Execute,
            }
        }
    }

    /// Safe again. After STOPPED the limiter starts from the measured state: the drivers held
    /// their own positions or dropped the torque, so the last setpoint may be anywhere. After
    /// HOLD it goes on from the held setpoint, which the drivers kept applying: restarting from
    /// the measured state would step the setpoint by the arm's tracking error at that moment,
    /// faster than the slew limit. After HOLD the execution resumes where it paused; after an
    /// e-stop there is none ([`abandon`]).
    ///
    /// [`abandon`]: Self::abandon
    fn resume(&mut self) {
        if std::mem::take(&mut self.stopped_since_safe)
            && let (Some(lim), Some((m, _))) = (self.limiter.as_mut(), self.inputs.measured)
        {
            lim.reset(m);
        }
    }

    /// E-stop: the running and the queued set, or the demonstrations, are dropped, so a reset
    /// never sets the arm moving by itself: the next motion needs a new submit. The execution
    /// under way publishes no statistics (it did not finish).
    fn abandon(&mut self) {
        match std::mem::replace(&mut self.mode, Mode::Idle) {
            Mode::Execute(x) => {
                self.count.held_solves += x.held_solves();
                self.retire(Retired::Set(x.into_set()));
            }
            Mode::Demonstrate(d) => self.retire(Retired::Demo(d.into_sequences())),
            Mode::Idle => {}
        }
        if let Some(set) = self.queued.take() {
            self.retire(Retired::Set(set));
        }
    }

    /// The mode's target for this tick; unsafe, the mode pauses and the setpoint holds.
    fn step_mode(&mut self, safe: bool, now: u64) -> Step {
        if !safe {
            return Step::HOLD;
        }
        match &mut self.mode {
            Mode::Idle => Step::HOLD,
            Mode::Demonstrate(d) => {
                let (target, tag) = d.step(self.timing.demo_rest_ticks);
                Step {
                    target: Some(target),
                    demo: tag.unwrap_or((NO_DEMO, NO_DEMO)),
                    ..Step::HOLD
                }
            }
            Mode::Execute(x) => {
                let execution = x.execution();
                let t = x.step(
                    &self.inputs.track,
                    self.timing.rest_ticks,
                    self.lag.lead_ticks(),
                    now,
                    self.skipped,
                );
                Step {
                    target: Some(t.target),
                    execution,
                    sample: t.point,
                    finished: t.finished,
                    ..Step::HOLD
                }
            }
        }
    }

    /// The setpoint published and the actuators' newest state, for their lag; only while the
    /// arm is safe (held, or stopped, the actuators do not follow the setpoint).
    fn measure_lag(&mut self, now: u64, setpoint: &Actuation, safe: bool) {
        let measured = self.inputs.measured.as_ref().filter(|_| safe);
        self.lag
            .published(now, setpoint, measured.map(|(m, t)| (*t, m)));
    }

    /// What a conditioning point whose time came at this tick credits: the setpoint the
    /// actuators were following (published the set's lead before) and where they were.
    fn credit(&mut self, now: u64, setpoint: &Actuation) {
        if let Mode::Execute(x) = &mut self.mode {
            let followed = self.lag.followed(now, x.lead()).unwrap_or(*setpoint);
            x.published(&followed, self.inputs.measured.as_ref().map(|(m, _)| m));
        }
    }

    /// Clamp and slew; `None` holds the last setpoint.
    fn limit(&mut self, target: Option<Actuation>) -> Actuation {
        let lim = self.limiter.as_mut().expect("only called with a limiter");
        match target {
            Some(t) => lim.apply(&t),
            None => lim.last(),
        }
    }

    /// The setpoint, and the conditioning sample and stats the step produced.
    fn publish(&mut self, state: ControllerState, now: u64, setpoint: Actuation, step: Step) {
        self.count.setpoints += 1;
        self.links.outbox.send(Outgoing::Setpoint(Setpoint {
            seq: self.count.setpoints,
            stamp_ns: now,
            actuation: setpoint,
            state: state as u32,
            demo: step.demo.0,
            demo_class: step.demo.1,
            execution: step.execution,
        }));
        if let Some(mut s) = step.sample {
            self.count.samples += 1;
            s.seq = self.count.samples;
            self.links.outbox.send(Outgoing::Sample(s));
        }
        if let Some(mut s) = step.finished {
            self.count.last_reconditions = s.reconditions;
            self.count.stats += 1;
            s.seq = self.count.stats;
            self.links.outbox.send(Outgoing::Stats(s));
        }
    }

    /// Mode changes at boundaries: a finished demonstration run, or a way-point set through (or
    /// giving way to the queued one) between executions.
    fn end_at_boundary(&mut self) {
        let done = match &self.mode {
            Mode::Demonstrate(d) => d.done(),
            Mode::Execute(x) => {
                x.at_boundary(self.timing.rest_ticks) && (x.through() || self.queued.is_some())
            }
            Mode::Idle => false,
        };
        if !done {
            return;
        }
        match std::mem::replace(&mut self.mode, Mode::Idle) {
            Mode::Demonstrate(d) => self.retire(Retired::Demo(d.into_sequences())),
            Mode::Execute(x) => {
                self.count.held_solves += x.held_solves();
                self.retire(Retired::Set(x.into_set()))
            }
            Mode::Idle => {}
        }
        if let Some(set) = self.queued.take() {
            self.mode = Mode::Execute(self.start(set));
        }
    }

    fn publish_status(&mut self, state: ControllerState, now: u64, health: &Health) {
        let (set_id, execution, reconditions, held) = match &self.mode {
            Mode::Execute(x) => (x.set_id(), x.execution(), x.reconditions(), x.held_solves()),
            _ => (0, 0, 0, 0),
        };
        let drops = self.links.outbox.drops();
        let status = ControllerStatus {
            seq: self.count.ticks,
            stamp_ns: now,
            state: state as u32,
            execution,
            set_id,
            rate_hz: self.timing.rate_hz,
            ticks: self.count.ticks,
            overruns: self.ticker.overruns(),
            latency: self.latency.summary(),
            tracker_age_ns: health.tracker_age_ns,
            motor_age_ns: health.motor_age_ns,
            model_loaded: self.shared.model_loaded.load(Ordering::Relaxed) as u32,
            reconditions_current: reconditions,
            reconditions_last: self.count.last_reconditions,
            outbox_backlog: self.links.outbox.backlog() as u32,
            outbox_dropped: drops.all,
            samples_dropped: drops.samples,
            held_solves: self.count.held_solves + held,
            lag_ns: self.lag.lag_s().map_or(u64::MAX, |s| (s * 1e9) as u64),
            lead_ns: self.lag.lead_ns(),
        };
        self.links.outbox.send(Outgoing::Status(status));
    }
}
