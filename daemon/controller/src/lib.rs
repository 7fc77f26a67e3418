//! The controller process (DESIGN §3): a fixed-rate tick thread that evaluates Eq. 11 and
//! enforces the limits, and a service thread that talks to users and the learner and plans.
//!
//! The tick thread allocates nothing, locks nothing and sleeps only on absolute deadlines once
//! it runs: plans arrive over a bounded lock-free channel as boxes and leave the same way, to be
//! freed by the service thread; re-conditioned groups reach the engine through its own channel.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, sync_channel};
use std::time::{Duration, Instant};

use softarm_ipc::clock::Ticker;
use softarm_ipc::iceoryx2::port::update_connections::UpdateConnections;
use softarm_ipc::{
    ConditioningSample, ControllerState, ControllerStatus, DemonstrateReply, EstimateRequest,
    ExecutionStats, Latency, MAX_WAYPOINTS, Namespace, Node, Setpoint, WaypointReply, now_ns,
};

use softarm_method::classify::classify;
use softarm_method::engine::{Planner, Replanner, TickEngine, Timeline};
use softarm_model::bundle::{BundleWatch, Model};
use softarm_model::config::Config;
use softarm_model::waypoints::validate;

const NO_DEMO: u32 = u32::MAX;

/// Clamps to the actuator limits and limits the change per tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limiter {
    min: [f64; 6],
    max: [f64; 6],
    step: f64,
    last: [f64; 6],
}

impl Limiter {
    pub fn new(
        min: [f64; 6],
        max: [f64; 6],
        slew_per_s: f64,
        rate_hz: f64,
        start: [f64; 6],
    ) -> Self {
        let mut l = Self {
            min,
            max,
            step: slew_per_s / rate_hz,
            last: start,
        };
        l.reset(start);
        l
    }

    /// Starts again from a measured state (after HOLD or e-stop), so resuming never jumps.
    pub fn reset(&mut self, measured: [f64; 6]) {
        self.last = std::array::from_fn(|i| measured[i].clamp(self.min[i], self.max[i]));
    }

    pub fn last(&self) -> [f64; 6] {
        self.last
    }

    /// The setpoint for a target: at most `step` from the last, inside the limits. A non-finite
    /// target holds the last setpoint.
    pub fn apply(&mut self, target: &[f64; 6]) -> [f64; 6] {
        if target.iter().all(|v| v.is_finite()) {
            for i in 0..6 {
                let t = target[i].clamp(self.min[i], self.max[i]);
                self.last[i] += (t - self.last[i]).clamp(-self.step, self.step);
            }
        }
        self.last
    }
}

/// Tick wake-up latency in fixed 1 µs buckets up to 10 ms; preallocated, allocation-free.
pub struct LatencyHistogram {
    buckets: Box<[u32]>,
    overflow: u64,
    count: u64,
    min: u64,
    max: u64,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        Self {
            buckets: vec![0; 10_000].into_boxed_slice(),
            overflow: 0,
            count: 0,
            min: u64::MAX,
            max: 0,
        }
    }
}

impl LatencyHistogram {
    pub fn record(&mut self, ns: u64) {
        let us = (ns / 1000) as usize;
        match self.buckets.get_mut(us) {
            Some(b) => *b = b.saturating_add(1),
            None => self.overflow += 1,
        }
        self.count += 1;
        self.min = self.min.min(ns);
        self.max = self.max.max(ns);
    }

    /// The bucket (as ns, its upper edge) below which a fraction q of the samples lie.
    fn quantile(&self, q: f64) -> u64 {
        let want = (q * self.count as f64).ceil() as u64;
        let mut seen = 0u64;
        for (us, &c) in self.buckets.iter().enumerate() {
            seen += c as u64;
            if seen >= want {
                return ((us as u64 + 1) * 1000).min(self.max);
            }
        }
        self.max
    }

    pub fn summary(&self) -> Latency {
        if self.count == 0 {
            return Latency::default();
        }
        Latency {
            min_ns: self.min,
            p50_ns: self.quantile(0.5),
            p99_ns: self.quantile(0.99),
            p999_ns: self.quantile(0.999),
            max_ns: self.max,
            samples: self.count,
        }
    }
}

/// A way-point set ready to run: its engine and what the tick needs to know.
pub struct Plan {
    set_id: u64,
    executions: u32,
    points: usize,
    desired: [[f64; 3]; MAX_WAYPOINTS],
    cond_ticks: [usize; MAX_WAYPOINTS],
    engine: TickEngine<6>,
}

/// Demonstration sequences to play.
pub struct DemoPlan {
    sequences: Vec<(usize, Vec<[f64; 6]>)>,
    /// Ticks per sequence sample.
    ticks_per_sample: usize,
}

enum ToTick {
    Execute(Box<Plan>),
    Demonstrate(Box<DemoPlan>),
}

enum Retired {
    Plan(Box<Plan>),
    Demo(Box<DemoPlan>),
}

enum Mode {
    Idle,
    Demonstrate(Demonstration),
    Execute(Execution),
}

/// Playing the demonstration sequences, each after a rest that slews to its start.
struct Demonstration {
    plan: Box<DemoPlan>,
    demo: usize,
    /// Ticks into this demo; negative while resting before it.
    k: i64,
}

impl Demonstration {
    /// The target of this tick, and (demo, class) while a demonstration is being recorded.
    fn step(&mut self, rest_ticks: i64) -> ([f64; 6], Option<(u32, u32)>) {
        let (class, seq) = &self.plan.sequences[self.demo];
        let ticks_per_sample = self.plan.ticks_per_sample;
        let out = if self.k < 0 {
            (seq[0], None)
        } else {
            let target = sample_at(seq, self.k as usize, ticks_per_sample);
            (target, Some((self.demo as u32, *class as u32)))
        };
        self.k += 1;
        if self.k >= 0 && self.k as usize > (seq.len() - 1) * ticks_per_sample {
            self.demo += 1;
            self.k = -rest_ticks;
        }
        out
    }

    fn done(&self) -> bool {
        self.demo >= self.plan.sequences.len()
    }
}

/// Executing a way-point set: per execution a rest that slews to v(0), then Eq. 11 tick by tick.
struct Execution {
    plan: Box<Plan>,
    /// 1-based.
    execution: u32,
    /// Ticks into the execution; negative while resting before it.
    k: i64,
    next_point: usize,
    errors: [f64; MAX_WAYPOINTS],
}

/// What one tick of an execution produced.
struct ExecutionTick {
    target: [f64; 6],
    /// At a conditioning point: the sample for the learner (the caller fills in the setpoint it
    /// published, and the sequence number).
    point: Option<ConditioningSample>,
    /// At the end of an execution: its stats (sequence number by the caller).
    finished: Option<ExecutionStats>,
}

impl Execution {
    fn new(plan: Box<Plan>, rest_ticks: i64) -> Self {
        Self {
            plan,
            execution: 1,
            k: -rest_ticks,
            next_point: 0,
            errors: [0.0; MAX_WAYPOINTS],
        }
    }

    /// Starts the current execution over (after an e-stop).
    fn restart(&mut self, rest_ticks: i64) {
        if self.k >= 0 {
            self.k = -rest_ticks;
            self.next_point = 0;
        }
    }

    /// Whether the set is through (or another waits) at an execution boundary.
    fn at_boundary(&self, rest_ticks: i64) -> bool {
        self.k == -rest_ticks
    }

    fn step(&mut self, reached: Option<[f64; 3]>, rest_ticks: i64, now: u64) -> ExecutionTick {
        let plan = &mut self.plan;
        if self.k < 0 {
            self.k += 1;
            return ExecutionTick {
                target: plan.engine.evaluate(0),
                point: None,
                finished: None,
            };
        }
        let tick = self.k as usize;
        let target = plan.engine.tick(tick);
        let mut point = None;
        if self.next_point < plan.points && tick == plan.cond_ticks[self.next_point] {
            let n = self.next_point;
            let reached = reached.unwrap_or([f64::NAN; 3]);
            let desired = plan.desired[n];
            self.errors[n] = distance(&desired, &reached);
            // The estimate wanted next: the following point, or the first of the next execution.
            let (next, next_execution) = if n + 1 < plan.points {
                (n + 1, self.execution)
            } else {
                (0, self.execution + 1)
            };
            point = Some(ConditioningSample {
                seq: 0,
                stamp_ns: now,
                set_id: plan.set_id,
                execution: self.execution,
                point: n as u32,
                points: plan.points as u32,
                _pad: 0,
                actuation: [0.0; 6],
                desired,
                reached,
                next_point: next as u32,
                next_execution,
                next_desired: plan.desired[next],
            });
            self.next_point += 1;
        }
        self.k += 1;
        let mut finished = None;
        if self.k as usize >= plan.engine.timeline().ticks() {
            let errs = &self.errors[..plan.points];
            finished = Some(ExecutionStats {
                seq: 0,
                stamp_ns: now,
                set_id: plan.set_id,
                execution: self.execution,
                executions: plan.executions,
                count: plan.points as u32,
                _pad: 0,
                errors_m: self.errors,
                mean_m: errs.iter().sum::<f64>() / errs.len() as f64,
                max_m: errs.iter().cloned().fold(0.0, f64::max),
            });
            self.execution += 1;
            self.k = -rest_ticks;
            self.next_point = 0;
        }
        ExecutionTick {
            target,
            point,
            finished,
        }
    }
}

/// What the service thread and the watchdog see of the tick thread.
#[derive(Default)]
struct Shared {
    state: AtomicU32,
    heartbeat: AtomicU64,
    model_loaded: AtomicBool,
}

/// Runs the controller until `stop` is set.
pub fn run(config: &Config, stop: &AtomicBool) -> Result<(), String> {
    let namespace = Namespace::new(&config.namespace()).map_err(|e| e.to_string())?;
    let shared = Arc::new(Shared::default());
    let (to_tick_tx, to_tick_rx) = sync_channel::<ToTick>(4);
    let (retired_tx, retired_rx) = sync_channel::<Retired>(8);

    let service = {
        let config = config.clone();
        let shared = shared.clone();
        let namespace = namespace.clone();
        let stop_flag = Arc::new(AtomicBool::new(false));
        let thread_stop = stop_flag.clone();
        let handle = std::thread::Builder::new()
            .name("controller-service".into())
            .spawn(move || {
                service_thread(
                    &config,
                    namespace,
                    &shared,
                    to_tick_tx,
                    retired_rx,
                    &thread_stop,
                )
            })
            .map_err(|e| format!("starting the service thread: {e}"))?;
        (handle, stop_flag)
    };
    let watchdog = start_watchdog(shared.clone());
    let (outbox, io) = start_io(config, namespace.clone(), service.1.clone())?;

    let result = tick_thread(
        config, namespace, &shared, to_tick_rx, retired_tx, outbox, stop,
    );
    service.1.store(true, Ordering::Relaxed);
    let service_result = service
        .0
        .join()
        .unwrap_or_else(|_| Err("the service thread panicked".into()));
    let io_result = io
        .join()
        .unwrap_or_else(|_| Err("the io thread panicked".into()));
    drop(watchdog);
    result.and(service_result).and(io_result)
}

/// What the tick publishes. iceoryx2 0.10 allocates a reference count for every loaned sample,
/// so the tick hands its samples to the io thread over a bounded lock-free channel instead of
/// sending them itself; the io thread sends them a fraction of a period later.
enum Outgoing {
    Setpoint(Setpoint),
    Sample(ConditioningSample),
    Stats(ExecutionStats),
    Status(ControllerStatus),
}

struct Outbox {
    tx: SyncSender<Outgoing>,
    /// The first tick deadline; the io thread runs at the same rate, `IO_OFFSET_NS` later.
    epoch_ns: u64,
}

impl Outbox {
    /// Never blocks; a full outbox (io thread stalled) drops the sample.
    fn send(&self, m: Outgoing) {
        let _ = self.tx.try_send(m);
    }
}

/// How long after each tick deadline the io thread sends (ns): past the tick's wake-up and
/// evaluation, well inside the period.
const IO_OFFSET_NS: u64 = 250_000;

fn start_io(
    config: &Config,
    namespace: Namespace,
    stop: Arc<AtomicBool>,
) -> Result<(Outbox, std::thread::JoinHandle<Result<(), String>>), String> {
    let (tx, rx) = sync_channel::<Outgoing>(256);
    let rate = config.controller.rate_hz;
    let epoch_ns = now_ns() + 20_000_000;
    let io_start = epoch_ns + IO_OFFSET_NS.min((5e8 / rate) as u64);
    let handle = std::thread::Builder::new()
        .name("controller-io".into())
        .spawn(move || -> Result<(), String> {
            let e = |e: softarm_ipc::Error| e.to_string();
            let ipc = Node::open(namespace, "controller.io").map_err(e)?;
            let setpoints = ipc.publisher(&ipc.setpoint().map_err(e)?).map_err(e)?;
            let samples = ipc.publisher(&ipc.cp_sample().map_err(e)?).map_err(e)?;
            let stats = ipc.publisher(&ipc.stats().map_err(e)?).map_err(e)?;
            let status = ipc.publisher(&ipc.status().map_err(e)?).map_err(e)?;
            let mut ticker = Ticker::starting_at(rate, io_start);
            while !stop.load(Ordering::Relaxed) {
                ticker.wait();
                while let Ok(m) = rx.try_recv() {
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
        })
        .map_err(|e| format!("starting the io thread: {e}"))?;
    Ok((Outbox { tx, epoch_ns }, handle))
}

fn setup_realtime(config: &Config) {
    let c = &config.controller;
    if c.mlockall {
        use nix::sys::mman::{MlockAllFlags, mlockall};
        if let Err(e) = mlockall(MlockAllFlags::MCL_CURRENT | MlockAllFlags::MCL_FUTURE) {
            tracing::warn!("mlockall refused ({e}); going on without locked memory");
        }
    }
    if let Some(cpu) = c.cpu {
        let mut set = nix::sched::CpuSet::new();
        if set.set(cpu).is_err()
            || nix::sched::sched_setaffinity(nix::unistd::Pid::from_raw(0), &set).is_err()
        {
            tracing::warn!("cannot pin the tick thread to CPU {cpu}; going on unpinned");
        }
    }
    if c.realtime_priority > 0 {
        let param = nix::libc::sched_param {
            sched_priority: c.realtime_priority,
        };
        // SAFETY: plain syscall on this thread with a valid parameter struct.
        let r = unsafe { nix::libc::sched_setscheduler(0, nix::libc::SCHED_FIFO, &param) };
        if r != 0 {
            tracing::warn!(
                "SCHED_FIFO priority {} refused (needs CAP_SYS_NICE or an rtprio limit); going on \
                 with normal scheduling",
                c.realtime_priority
            );
        }
    }
}

fn tick_thread(
    config: &Config,
    namespace: Namespace,
    shared: &Shared,
    plans: Receiver<ToTick>,
    retired: SyncSender<Retired>,
    outbox: Outbox,
    stop: &AtomicBool,
) -> Result<(), String> {
    let e = |e: softarm_ipc::Error| e.to_string();
    let ipc = Node::open(namespace, "controller").map_err(e)?;
    let tracker = ipc.subscriber(&ipc.tracker().map_err(e)?).map_err(e)?;
    let motors = ipc.subscriber(&ipc.motor_state().map_err(e)?).map_err(e)?;
    let estop = ipc.subscriber(&ipc.estop().map_err(e)?).map_err(e)?;
    setup_realtime(config);

    let c = &config.controller;
    let rate = c.rate_hz;
    let timeout_ns = (c.tracker_timeout_ms * 1e6) as u64;
    let rest_ticks = (c.rest_s * rate).round() as i64;
    let demo_rest_ticks = (c.rest_s.max(0.5) * rate).round() as i64;
    let status_every = (rate / 10.0).round().max(1.0) as u64;

    let mut hist = LatencyHistogram::default();
    let mut limiter: Option<Limiter> = None;
    let mut mode = Mode::Idle;
    let mut queued: Option<Box<Plan>> = None;
    let mut position: Option<([f64; 3], u64)> = None;
    let mut measured: Option<([f64; 6], u64)> = None;
    let mut engaged = false;
    let mut was_safe = false;
    // Whether the unsafe spell now ending included an e-stop (restart) or only stale data
    // (resume where the execution paused).
    let mut stopped_while_unsafe = false;
    let (mut seq, mut cp_seq, mut stats_seq, mut tick_count) = (0u64, 0u64, 0u64, 0u64);
    let mut ticker = Ticker::starting_at(rate, outbox.epoch_ns);
    let mut notified = false;
    tracing::info!(rate_hz = rate, "controller running");

    while !stop.load(Ordering::Relaxed) {
        let wake = ticker.wait();
        hist.record(wake.latency_ns);
        tick_count += 1;
        let now = now_ns();

        while let Ok(Some(s)) = tracker.receive() {
            position = Some((s.position, s.stamp_ns));
        }
        while let Ok(Some(s)) = motors.receive() {
            measured = Some((s.actuation, s.stamp_ns));
        }
        while let Ok(Some(s)) = estop.receive() {
            engaged = s.engaged != 0;
        }
        match plans.try_recv() {
            Ok(ToTick::Execute(p)) => match mode {
                Mode::Execute(_) => {
                    if let Some(old) = queued.replace(p) {
                        let _ = retired.try_send(Retired::Plan(old));
                    }
                }
                _ => {
                    if let Mode::Demonstrate(d) = std::mem::replace(&mut mode, Mode::Idle) {
                        let _ = retired.try_send(Retired::Demo(d.plan));
                    }
                    mode = Mode::Execute(Execution::new(p, rest_ticks));
                }
            },
            Ok(ToTick::Demonstrate(d)) => {
                if matches!(mode, Mode::Idle) {
                    mode = Mode::Demonstrate(Demonstration {
                        plan: d,
                        demo: 0,
                        k: -demo_rest_ticks,
                    });
                } else {
                    let _ = retired.try_send(Retired::Demo(d));
                }
            }
            Err(TryRecvError::Empty | TryRecvError::Disconnected) => {}
        }

        let tracker_age = position.map_or(u64::MAX, |(_, t)| now.saturating_sub(t));
        let motor_age = measured.map_or(u64::MAX, |(_, t)| now.saturating_sub(t));
        // Nothing is published before the arm's state is known: the first setpoint starts there.
        if limiter.is_none()
            && let Some((m, _)) = measured
        {
            limiter = Some(Limiter::new(
                c.actuator_min,
                c.actuator_max,
                c.slew_per_s,
                rate,
                m,
            ));
        }
        let safe = !engaged && tracker_age <= timeout_ns && motor_age <= timeout_ns;
        let state = if engaged {
            ControllerState::Stopped
        } else if !safe || limiter.is_none() {
            ControllerState::Hold
        } else {
            match mode {
                Mode::Idle => ControllerState::Idle,
                Mode::Demonstrate(_) => ControllerState::Demonstrate,
                Mode::Execute(_) => ControllerState::Execute,
            }
        };
        shared.state.store(state as u32, Ordering::Relaxed);

        if let Some(lim) = limiter.as_mut() {
            if safe && !was_safe {
                if let Some((m, _)) = measured {
                    lim.reset(m);
                }
                // After an e-stop the execution starts over from its rest phase.
                if let Mode::Execute(x) = &mut mode
                    && stopped_while_unsafe
                {
                    x.restart(rest_ticks);
                }
                stopped_while_unsafe = false;
            }
            let mut demo_tag = (NO_DEMO, NO_DEMO);
            let mut execution_no = 0;
            let mut sample: Option<ConditioningSample> = None;
            let mut finished: Option<ExecutionStats> = None;
            let target = match &mut mode {
                _ if !safe => lim.last(),
                Mode::Idle => lim.last(),
                Mode::Demonstrate(d) => {
                    let (target, tag) = d.step(demo_rest_ticks);
                    demo_tag = tag.unwrap_or((NO_DEMO, NO_DEMO));
                    target
                }
                Mode::Execute(x) => {
                    execution_no = x.execution;
                    let t = x.step(position.map(|p| p.0), rest_ticks, now);
                    sample = t.point;
                    finished = t.finished;
                    t.target
                }
            };
            let out = lim.apply(&target);
            seq += 1;
            outbox.send(Outgoing::Setpoint(Setpoint {
                seq,
                stamp_ns: now,
                actuation: out,
                state: state as u32,
                demo: demo_tag.0,
                demo_class: demo_tag.1,
                execution: execution_no,
            }));
            if let Some(mut s) = sample {
                cp_seq += 1;
                s.seq = cp_seq;
                s.actuation = out;
                outbox.send(Outgoing::Sample(s));
            }
            if let Some(mut s) = finished {
                stats_seq += 1;
                s.seq = stats_seq;
                outbox.send(Outgoing::Stats(s));
            }
        }
        was_safe = safe;
        stopped_while_unsafe |= engaged;

        // Mode changes at boundaries: a finished demonstration run or way-point set.
        let done = match &mode {
            Mode::Demonstrate(d) => d.done(),
            Mode::Execute(x) => {
                x.at_boundary(rest_ticks) && (x.execution > x.plan.executions || queued.is_some())
            }
            Mode::Idle => false,
        };
        if done {
            match std::mem::replace(&mut mode, Mode::Idle) {
                Mode::Demonstrate(d) => {
                    let _ = retired.try_send(Retired::Demo(d.plan));
                }
                Mode::Execute(x) => {
                    let _ = retired.try_send(Retired::Plan(x.plan));
                }
                Mode::Idle => {}
            }
            if let Some(p) = queued.take() {
                mode = Mode::Execute(Execution::new(p, rest_ticks));
            }
        }

        if tick_count % status_every == 0 {
            let (set_id, execution) = match &mode {
                Mode::Execute(x) => (x.plan.set_id, x.execution),
                _ => (0, 0),
            };
            outbox.send(Outgoing::Status(ControllerStatus {
                seq: tick_count,
                stamp_ns: now,
                state: state as u32,
                execution,
                set_id,
                rate_hz: rate,
                ticks: tick_count,
                overruns: ticker.overruns(),
                latency: hist.summary(),
                tracker_age_ns: tracker_age,
                motor_age_ns: motor_age,
                model_loaded: shared.model_loaded.load(Ordering::Relaxed) as u32,
                _pad: 0,
            }));
        }
        shared.heartbeat.store(tick_count, Ordering::Relaxed);
        if !notified {
            notified = true;
            let _ = sd_notify::notify(&[sd_notify::NotifyState::Ready]);
        }
    }
    tracing::info!(
        overruns = ticker.overruns(),
        ticks = tick_count,
        "controller stopped"
    );
    Ok(())
}

/// The demonstration sequence at tick k, linearly interpolated between its samples.
fn sample_at(seq: &[[f64; 6]], k: usize, ticks_per_sample: usize) -> [f64; 6] {
    let i = (k / ticks_per_sample).min(seq.len() - 1);
    let j = (i + 1).min(seq.len() - 1);
    let f = (k % ticks_per_sample) as f64 / ticks_per_sample as f64;
    std::array::from_fn(|d| seq[i][d] + f * (seq[j][d] - seq[i][d]))
}

fn distance(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// WATCHDOG=1 to systemd only while the tick's heartbeat advances.
fn start_watchdog(shared: Arc<Shared>) -> Option<std::thread::JoinHandle<()>> {
    let period = sd_notify::watchdog_enabled()? / 2;
    std::thread::Builder::new()
        .name("controller-watchdog".into())
        .spawn(move || {
            let mut last = 0;
            loop {
                std::thread::sleep(period);
                let beat = shared.heartbeat.load(Ordering::Relaxed);
                if beat != last {
                    let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
                }
                last = beat;
            }
        })
        .ok()
}

/// What the service thread does with a set while it waits for the learner's first estimates.
struct Planning {
    set_id: u64,
    deadline: Instant,
    planner: Planner<6>,
    executions: u32,
    desired: [[f64; 3]; MAX_WAYPOINTS],
    z: Vec<f64>,
    estimates: Vec<Option<[f64; 6]>>,
}

/// The model the controller plans with, reloaded when `softarm train` writes a new bundle.
struct ModelSlot {
    watch: BundleWatch,
    model: Option<Model>,
}

impl ModelSlot {
    /// Loads the bundle when it appears or changes; a bad bundle is reported and not used.
    fn refresh(&mut self, shared: &Shared) {
        if !self.watch.changed() {
            return;
        }
        match Model::read(self.watch.dir()) {
            Ok(m) => {
                tracing::info!(id = %m.id, primitives = m.actuation.len(), "model bundle loaded");
                self.model = Some(m);
                shared.model_loaded.store(true, Ordering::Relaxed);
            }
            Err(e) => tracing::error!("{e}; keeping the model I had"),
        }
    }
}

fn service_thread(
    config: &Config,
    namespace: Namespace,
    shared: &Shared,
    to_tick: SyncSender<ToTick>,
    retired: Receiver<Retired>,
    stop: &AtomicBool,
) -> Result<(), String> {
    let e = |e: softarm_ipc::Error| e.to_string();
    let ipc = Node::open(namespace, "controller.service").map_err(e)?;
    let waypoints = ipc.server(&ipc.waypoints().map_err(e)?).map_err(e)?;
    let demonstrate = ipc.server(&ipc.demonstrate().map_err(e)?).map_err(e)?;
    let requests = ipc
        .publisher(&ipc.estimate_request().map_err(e)?)
        .map_err(e)?;
    let estimates = ipc.subscriber(&ipc.estimate().map_err(e)?).map_err(e)?;

    let mut slot = ModelSlot {
        watch: BundleWatch::new(config.model_dir(), Duration::from_millis(200)),
        model: None,
    };
    slot.refresh(shared);
    if slot.model.is_none() {
        tracing::warn!(
            "no model bundle in {} yet: way-point sets are refused until `softarm train` writes one",
            slot.watch.dir().display()
        );
    }
    let mut planning: Option<Planning> = None;
    let mut active: Option<(u64, Replanner<6>)> = None;
    let mut next_set_id = (now_ns() & 0xffff_ffff) << 16;
    let mut request_seq = 0u64;

    while !stop.load(Ordering::Relaxed) {
        // Not real-time: 2 ms is quick enough for users and the learner, and light on the CPU.
        std::thread::sleep(Duration::from_millis(2));
        slot.refresh(shared);

        while let Ok(Some(req)) = waypoints.receive() {
            let set = *req.payload();
            let reply = match admit(config, &slot, &set) {
                Ok((planner, q, z)) => {
                    next_set_id += 1;
                    let set_id = next_set_id;
                    let n = set.count as usize;
                    let mut desired = [[0.0; 3]; MAX_WAYPOINTS];
                    desired[..n].copy_from_slice(&set.positions_m[..n]);
                    tracing::info!(
                        set_id,
                        points = n,
                        executions = set.executions,
                        ?q,
                        "way-point set accepted"
                    );
                    request_seq += 1;
                    let _ = requests.send_copy(EstimateRequest {
                        seq: request_seq,
                        stamp_ns: now_ns(),
                        set_id,
                        count: n as u32,
                        _pad: 0,
                        desired,
                    });
                    planning = Some(Planning {
                        set_id,
                        deadline: Instant::now()
                            + Duration::from_secs_f64(config.controller.estimate_timeout_s),
                        planner,
                        executions: set.executions,
                        desired,
                        z,
                        estimates: vec![None; n],
                    });
                    WaypointReply::accepted(set.seq, set_id)
                }
                Err(reason) => {
                    tracing::warn!("way-point set rejected: {reason}");
                    WaypointReply::rejected(set.seq, &reason)
                }
            };
            let _ = req.send_copy(reply);
        }

        while let Ok(Some(req)) = demonstrate.receive() {
            let r = *req.payload();
            let idle = shared.state.load(Ordering::Relaxed) == ControllerState::Idle as u32;
            let recipe = &config.demonstrations;
            let reply = if idle && planning.is_none() && active.is_none() {
                let sequences = recipe.sequences(r.seed);
                let ticks_per_sample = (config.controller.rate_hz / recipe.sample_rate_hz)
                    .round()
                    .max(1.0) as usize;
                let rest = config.controller.rest_s.max(0.5);
                let n = sequences.len();
                let plan = DemoPlan {
                    sequences,
                    ticks_per_sample,
                };
                match to_tick.try_send(ToTick::Demonstrate(Box::new(plan))) {
                    Ok(()) => DemonstrateReply {
                        seq: r.seq,
                        stamp_ns: now_ns(),
                        accepted: 1,
                        demos: n as u32,
                        duration_s: n as f64 * (recipe.duration_s + rest),
                    },
                    Err(_) => DemonstrateReply {
                        seq: r.seq,
                        ..Default::default()
                    },
                }
            } else {
                tracing::warn!("demonstrations refused: the controller is busy");
                DemonstrateReply {
                    seq: r.seq,
                    ..Default::default()
                }
            };
            let _ = req.send_copy(reply);
        }

        while let Ok(Some(s)) = estimates.receive() {
            let s = *s;
            let point = s.point as usize;
            if let Some(p) = planning.as_mut().filter(|p| p.set_id == s.set_id) {
                if point < p.estimates.len() {
                    p.estimates[point] = Some(s.actuation);
                }
            } else if let Some((set_id, replanner)) = active.as_mut().filter(|a| a.0 == s.set_id)
                && let Err(err) = replanner.recondition(point, &s.actuation)
            {
                tracing::warn!(set_id = *set_id, point, "estimate not used: {err}");
            }
        }

        let ready = planning.as_ref().is_some_and(|p| {
            p.estimates.iter().all(Option::is_some) || Instant::now() >= p.deadline
        });
        if ready {
            let p = planning.take().expect("checked above");
            let model = slot
                .model
                .as_ref()
                .expect("a set is only admitted with a model");
            let q = p.planner.schedule().assignment().to_vec();
            let initial: Vec<[f64; 6]> = p
                .estimates
                .iter()
                .enumerate()
                .map(|(n, e)| {
                    e.unwrap_or_else(|| {
                        // No learner: the primitive's own mean there, i.e. no conditioning change.
                        let m = model.actuation[q[n]].marginal(p.z[n]).mean;
                        std::array::from_fn(|d| m[d])
                    })
                })
                .collect();
            if p.estimates.iter().any(Option::is_none) {
                tracing::warn!(
                    set_id = p.set_id,
                    "no estimates from the learner in time: starting from the primitives' means"
                );
            }
            let points = initial.len();
            let mut cond_ticks = [0usize; MAX_WAYPOINTS];
            cond_ticks[..points].copy_from_slice(p.planner.conditioning_ticks());
            match p.planner.start(&initial) {
                Ok((engine, replanner)) => {
                    let plan = Plan {
                        set_id: p.set_id,
                        executions: p.executions,
                        points,
                        desired: p.desired,
                        cond_ticks,
                        engine,
                    };
                    if to_tick.send(ToTick::Execute(Box::new(plan))).is_ok() {
                        active = Some((p.set_id, replanner));
                    }
                }
                Err(err) => tracing::error!(set_id = p.set_id, "planning failed: {err}"),
            }
        }

        // Plans the tick is done with are freed here, never on the tick thread.
        while let Ok(r) = retired.try_recv() {
            match r {
                Retired::Plan(p) => {
                    if active.as_ref().is_some_and(|a| a.0 == p.set_id) {
                        active = None;
                    }
                    tracing::info!(set_id = p.set_id, "way-point set finished");
                }
                Retired::Demo(d) => {
                    tracing::info!(demos = d.sequences.len(), "demonstrations finished");
                }
            }
        }
    }
    Ok(())
}

/// Validates a set and plans it: ClassifyToPrimitives, then the primitives' marginals on the
/// tick grid. Any error is the rejection reason; nothing changes.
fn admit(
    config: &Config,
    slot: &ModelSlot,
    set: &softarm_ipc::WaypointSet,
) -> Result<(Planner<6>, Vec<usize>, Vec<f64>), String> {
    validate(set, &config.waypoints, &config.activation)?;
    let model = slot.model.as_ref().ok_or_else(|| {
        format!(
            "no trained model in {}: run `softarm train` first",
            slot.watch.dir().display()
        )
    })?;
    let n = set.count as usize;
    let points = &set.positions_m[..n];
    let z: Vec<f64> = set.times_s[..n]
        .iter()
        .map(|t| t / set.duration_s)
        .collect();
    let q = classify(&model.task, points, &z, config.controller.variance_floor)
        .map_err(|e| e.to_string())?;
    let timeline =
        Timeline::new(set.duration_s, config.controller.rate_hz).map_err(|e| e.to_string())?;
    let planner = Planner::new(
        model.actuation.clone(),
        &set.times_s[..n],
        &q,
        timeline,
        config.activation,
        config.controller.variance_floor,
    )
    .map_err(|e| e.to_string())?;
    Ok((planner, q, z))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_limiter_clamps_and_slews() {
        let mut l = Limiter::new([0.1; 6], [0.9; 6], 1.0, 100.0, [0.5; 6]);
        let out = l.apply(&[1.0; 6]);
        assert!((out[0] - 0.51).abs() < 1e-12);
        for _ in 0..100 {
            l.apply(&[1.0; 6]);
        }
        assert_eq!(l.last(), [0.9; 6]);
        let held = l.apply(&[f64::NAN; 6]);
        assert_eq!(held, [0.9; 6]);
        l.reset([0.0; 6]);
        assert_eq!(l.last(), [0.1; 6]);
    }

    #[test]
    fn latency_percentiles_come_from_the_buckets() {
        let mut h = LatencyHistogram::default();
        for i in 0..1000u64 {
            h.record(i * 1000 + 500);
        }
        h.record(50_000_000);
        let s = h.summary();
        assert_eq!(s.min_ns, 500);
        assert_eq!(s.max_ns, 50_000_000);
        assert!((499_000..=502_000).contains(&s.p50_ns), "{s:?}");
        assert!((989_000..=992_000).contains(&s.p99_ns), "{s:?}");
        assert_eq!(s.samples, 1001);
    }

    #[test]
    fn demonstrations_interpolate_between_samples() {
        let seq = vec![[0.0; 6], [1.0; 6]];
        assert_eq!(sample_at(&seq, 0, 4), [0.0; 6]);
        assert_eq!(sample_at(&seq, 2, 4), [0.5; 6]);
        assert_eq!(sample_at(&seq, 4, 4), [1.0; 6]);
        assert_eq!(sample_at(&seq, 9, 4), [1.0; 6]);
    }
}
