//! The service thread: admits and plans way-point sets, asks the learner for their first
//! estimates, re-conditions the running set as estimates come, starts demonstrations, reloads
//! the model, and frees what the tick is done with. Not real-time.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread;
use std::time::{Duration, Instant};

use anyhow::Context;
use rtrb::{Consumer, Producer, PushError};
use softarm_config::Config;
use softarm_ipc::{
    ActuationEstimate, ControllerState, DemonstrateReply, DemonstrateRequest, EstimateRequest,
    Namespace, Node, Pub, Server, Sub, WaypointReply, WaypointSet,
};
use softarm_method::blend::{BlendError, ConditionedOn, Replanner};
use softarm_model::bundle::{BundleWatch, Model};
use softarm_runtime::{EstopLatch, now_ns};

use crate::admission::{Admitted, admit, conditioned_on};
use crate::control::{Plan, Retired};
use crate::demonstration::DemoSequences;
use crate::{Shared, rt};

/// How often the service thread looks for work: quick enough for users and the learner, and
/// light on the CPU.
const POLL: Duration = Duration::from_millis(2);

/// How often the e-stop latch file is read (as the drivers do): an `estop` sample can be
/// missed, the file cannot.
const LATCH_EVERY: Duration = Duration::from_millis(50);

/// How long to wait before offering the tick a set again when its ring is full.
const TO_TICK_RETRY: Duration = Duration::from_micros(200);

/// A set admitted and planned, waiting for the learner's first estimates.
struct PendingSet<const N: usize> {
    set_id: u64,
    /// `None`: wait for every estimate, however long.
    deadline: Option<Instant>,
    admitted: Admitted<N>,
    estimates: Vec<Option<ConditionedOn<N>>>,
}

impl<const N: usize> PendingSet<N> {
    fn ready(&self, now: Instant) -> bool {
        self.estimates.iter().all(Option::is_some) || self.deadline.is_some_and(|d| now >= d)
    }
}

/// The replanner of every set handed to the tick (running, queued, or still in the ring), until
/// the tick hands the set back. Each set keeps its own to its end: a set queued behind a running
/// one never takes the running set's estimates, and its replanner is used only once it runs
/// (estimates for it come only from its own conditioning samples).
#[derive(Default)]
struct Replanners<const N: usize> {
    sets: Vec<(u64, Replanner<N>)>,
}

impl<const N: usize> Replanners<N> {
    fn add(&mut self, set_id: u64, replanner: Replanner<N>) {
        self.sets.push((set_id, replanner));
    }

    /// Re-conditions `point` of set `set_id` on `on`; `None` if that set is not with the tick.
    fn recondition(
        &mut self,
        set_id: u64,
        point: usize,
        on: &ConditionedOn<N>,
    ) -> Option<Result<(), BlendError>> {
        let (_, r) = self.sets.iter_mut().find(|(id, _)| *id == set_id)?;
        Some(r.recondition_on(point, on))
    }

    /// The tick is done with the set: its replanner goes (here, off the tick thread).
    fn remove(&mut self, set_id: u64) {
        self.sets.retain(|(id, _)| *id != set_id);
    }

    fn is_empty(&self) -> bool {
        self.sets.is_empty()
    }
}

/// Why a set is refused while the e-stop is engaged: nothing is queued, so the user knows the
/// set will not start by itself once the e-stop is released.
const STOPPED_REASON: &str = "the e-stop is engaged (STOPPED): nothing was queued; release it with `softarm estop --reset`, then submit again";

/// The model the controller plans with, reloaded when `softarm train` writes a new bundle.
struct ModelSlot<const N: usize> {
    watch: BundleWatch,
    model: Option<Model<N>>,
    /// The arm the config describes: a bundle made for another is not used.
    arm: String,
}

impl<const N: usize> ModelSlot<N> {
    /// Loads the bundle when it appears or changes; a bad bundle is reported and not used.
    fn refresh(&mut self, shared: &Shared) {
        if !self.watch.changed() {
            return;
        }
        match Model::read_for_arm(self.watch.dir(), &self.arm) {
            Ok(m) => {
                tracing::info!(id = %m.id, primitives = m.actuation.len(), "model bundle loaded");
                self.model = Some(m);
                shared.model_loaded.store(true, Ordering::Relaxed);
            }
            Err(e) => tracing::error!("{e}; keeping the model I had"),
        }
    }
}

/// The service thread's ports.
struct Ports {
    waypoints: Server<WaypointSet, WaypointReply>,
    demonstrate: Server<DemonstrateRequest, DemonstrateReply>,
    requests: Pub<EstimateRequest>,
    estimates: Sub<ActuationEstimate>,
    /// Last, so the ports go before it.
    _node: Node,
}

impl Ports {
    fn open(namespace: Namespace) -> Result<Self, softarm_ipc::Error> {
        let node = Node::open(namespace, "controller.service")?;
        Ok(Self {
            waypoints: node.server(&node.waypoints()?)?,
            demonstrate: node.server(&node.demonstrate()?)?,
            requests: node.publisher(&node.estimate_request()?)?,
            estimates: node.subscriber(&node.estimate()?)?,
            _node: node,
        })
    }
}

pub(crate) struct Service<const N: usize> {
    config: Config,
    shared: Arc<Shared>,
    ports: Ports,
    to_tick: Producer<Plan<N>>,
    retired: Consumer<Retired<N>>,
    slot: ModelSlot<N>,
    pending: Option<PendingSet<N>>,
    /// The sets the tick runs, has queued or has yet to take, each with its replanner.
    handed: Replanners<N>,
    next_set_id: u64,
    request_seq: u64,
    latch: EstopLatch,
    latch_read: Instant,
}

impl<const N: usize> Service<N> {
    pub(crate) fn open(
        config: Config,
        namespace: Namespace,
        shared: Arc<Shared>,
        to_tick: Producer<Plan<N>>,
        retired: Consumer<Retired<N>>,
    ) -> anyhow::Result<Self> {
        let ports = Ports::open(namespace).context("opening the service thread's ports")?;
        let mut slot = ModelSlot {
            watch: BundleWatch::new(config.model_dir(), Duration::from_millis(200)),
            model: None,
            arm: config.arm_identity(),
        };
        slot.refresh(&shared);
        if slot.model.is_none() {
            tracing::warn!(
                "no model bundle in {} yet: way-point sets are refused until `softarm train` writes one",
                slot.watch.dir().display()
            );
        }
        Ok(Self {
            shared,
            ports,
            to_tick,
            retired,
            slot,
            pending: None,
            handed: Replanners::default(),
            next_set_id: (now_ns() & 0xffff_ffff) << 16,
            request_seq: 0,
            latch: config.estop_latch(),
            latch_read: Instant::now(),
            config,
        })
    }

    /// Serves until `stop` is set.
    pub(crate) fn run(mut self, stop: &AtomicBool) -> anyhow::Result<()> {
        let mut ready = false;
        while !stop.load(Ordering::Relaxed) {
            thread::sleep(POLL);
            // READY=1 from here, not the tick thread: once the tick has run and every port is
            // open (this thread's were opened before the loop).
            if !ready && self.shared.heartbeat.load(Ordering::Relaxed) > 0 {
                ready = true;
                rt::notify_ready();
            }
            self.slot.refresh(&self.shared);
            self.read_latch();
            self.admit_sets();
            self.answer_demonstration_requests();
            self.take_estimates();
            self.start_when_ready();
            self.free_retired();
        }
        Ok(())
    }

    /// Answers way-point sets: admitted ones wait for their first estimates (replacing any set
    /// still waiting), the others are rejected with the reason.
    fn admit_sets(&mut self) {
        while let Ok(Some(req)) = self.ports.waypoints.receive() {
            let set = *req.payload();
            let admission = if self.stopped() {
                Err(anyhow::anyhow!(STOPPED_REASON))
            } else {
                admit(&self.config, self.slot.model.as_ref(), &set)
            };
            let reply = match admission {
                Ok(admitted) => {
                    let set_id = self.request_estimates(&set, admitted);
                    WaypointReply::accepted(set.seq, now_ns(), set_id)
                }
                Err(reason) => {
                    tracing::warn!("way-point set rejected: {reason}");
                    WaypointReply::rejected(set.seq, now_ns(), &reason.to_string())
                }
            };
            let _ = req.send_copy(reply);
        }
    }

    /// Names an admitted set, asks the learner for its first estimates, and keeps it pending.
    fn request_estimates(&mut self, set: &WaypointSet, admitted: Admitted<N>) -> u64 {
        self.next_set_id += 1;
        let set_id = self.next_set_id;
        let n = admitted.points();
        tracing::info!(
            set_id,
            points = n,
            executions = set.executions,
            q = ?admitted.classes(),
            "way-point set accepted"
        );
        self.request_seq += 1;
        let _ = self.ports.requests.send_copy(admitted.estimate_request(
            set_id,
            self.request_seq,
            now_ns(),
        ));
        self.pending = Some(PendingSet {
            set_id,
            deadline: estimate_deadline(Instant::now(), self.config.controller.estimate_timeout_s),
            admitted,
            estimates: vec![None; n],
        });
        set_id
    }

    /// Demonstrations start only while the controller is idle with no set on its way.
    fn answer_demonstration_requests(&mut self) {
        while let Ok(Some(req)) = self.ports.demonstrate.receive() {
            let r = *req.payload();
            let idle = self.shared.state.load(Ordering::Relaxed) == ControllerState::Idle as u32;
            let refused = DemonstrateReply {
                seq: r.seq,
                ..Default::default()
            };
            let reply = if idle && self.pending.is_none() && self.handed.is_empty() {
                let sequences = DemoSequences::new(&self.config, r.seed);
                let (demos, duration_s) = (
                    sequences.sequences.len(),
                    sequences.duration_s(&self.config),
                );
                // Refused if the tick's ring is full, or the tick is gone (stopping).
                let sent = !self.to_tick.is_abandoned()
                    && self
                        .to_tick
                        .push(Plan::Demonstrate(Box::new(sequences)))
                        .is_ok();
                if sent {
                    DemonstrateReply {
                        seq: r.seq,
                        stamp_ns: now_ns(),
                        accepted: 1,
                        demos: demos as u32,
                        duration_s,
                    }
                } else {
                    refused
                }
            } else {
                tracing::warn!("demonstrations refused: the controller is busy");
                refused
            };
            let _ = req.send_copy(reply);
        }
    }

    /// Estimates for the pending set are kept for its start; those for the running set
    /// re-condition it.
    fn take_estimates(&mut self) {
        while let Ok(Some(s)) = self.ports.estimates.receive() {
            let s = *s;
            let point = s.point as usize;
            let Some(on) = conditioned_on(&s) else {
                tracing::warn!(
                    set_id = s.set_id,
                    point,
                    "estimate not used: {} actuators, the arm has {N}",
                    s.actuation.len()
                );
                continue;
            };
            if let Some(p) = self.pending.as_mut().filter(|p| p.set_id == s.set_id) {
                if point < p.estimates.len() {
                    p.estimates[point] = Some(on);
                }
            } else {
                match self.handed.recondition(s.set_id, point, &on) {
                    Some(Err(err)) => {
                        tracing::warn!(set_id = s.set_id, point, "estimate not used: {err}")
                    }
                    // From the sample it answers to the table on its way to the tick, which
                    // swaps it in at its next tick if the point's group is not active yet.
                    Some(Ok(())) if s.answers_ns > 0 => tracing::debug!(
                        set_id = s.set_id,
                        point,
                        execution = s.execution,
                        within = on.within,
                        since_sample_ms = now_ns().saturating_sub(s.answers_ns) as f64 * 1e-6,
                        "re-conditioned"
                    ),
                    _ => {}
                }
            }
        }
    }

    /// Once the pending set has its estimates (or waited long enough for them), builds its tick
    /// blend and hands it to the tick.
    fn start_when_ready(&mut self) {
        if !self
            .pending
            .as_ref()
            .is_some_and(|p| p.ready(Instant::now()))
        {
            return;
        }
        let p = self.pending.take().expect("checked above");
        if self.stopped() {
            // The e-stop came while the set waited for its estimates: the tick would drop it.
            tracing::warn!(
                set_id = p.set_id,
                "e-stop engaged before the set started: dropped; `softarm estop --reset`, then submit again"
            );
            return;
        }
        if p.estimates.iter().any(Option::is_none) {
            tracing::warn!(
                set_id = p.set_id,
                "no estimates from the learner in time: starting from the primitives' means"
            );
        }
        match p.admitted.start(p.set_id, &p.estimates) {
            Ok((set, replanner)) => {
                if self.send_to_tick(Plan::Execute(Box::new(set))) {
                    self.handed.add(p.set_id, replanner);
                }
            }
            Err(err) => tracing::error!(set_id = p.set_id, "planning failed: {err}"),
        }
    }

    /// The e-stop holds the arm (the tick's state, at most a tick old).
    /// Reads the e-stop latch file every [`LATCH_EVERY`] for the tick ([`Shared::latched`]).
    fn read_latch(&mut self) {
        if self.latch_read.elapsed() < LATCH_EVERY {
            return;
        }
        self.latch_read = Instant::now();
        let latched = self
            .latch
            .engaged_or_safe(|e| tracing::error!("{e}; STOPPED"));
        let was = self.shared.latched.swap(latched, Ordering::Relaxed);
        if latched && !was {
            tracing::warn!("the e-stop latch is engaged: STOPPED");
        } else if was && !latched {
            tracing::warn!("the e-stop latch is released: IDLE until a set is submitted");
        }
    }

    fn stopped(&self) -> bool {
        self.shared.state.load(Ordering::Relaxed) == ControllerState::Stopped as u32
    }

    /// Hands the tick a message, waiting (this thread only) while its ring is full; false if
    /// the tick is gone.
    fn send_to_tick(&mut self, mut m: Plan<N>) -> bool {
        loop {
            if self.to_tick.is_abandoned() {
                return false;
            }
            match self.to_tick.push(m) {
                Ok(()) => return true,
                Err(PushError::Full(back)) => {
                    m = back;
                    thread::sleep(TO_TICK_RETRY);
                }
            }
        }
    }

    /// Sets and demonstrations the tick is done with are freed here, never on the tick thread.
    fn free_retired(&mut self) {
        while let Ok(r) = self.retired.pop() {
            match r {
                Retired::Set(set) => {
                    self.handed.remove(set.set_id);
                    tracing::info!(set_id = set.set_id, "way-point set finished");
                }
                Retired::Demo(d) => {
                    tracing::info!(demos = d.sequences.len(), "demonstrations finished");
                }
            }
        }
    }
}

/// When to stop waiting for a set's first estimates: `timeout_s` from `now`. Never panics,
/// whatever the configuration says: a timeout too long for a `Duration` or an `Instant` waits
/// for the estimates however long they take, one that is not > 0 (or NaN) does not wait.
fn estimate_deadline(now: Instant, timeout_s: f64) -> Option<Instant> {
    let wait = Duration::try_from_secs_f64(timeout_s).unwrap_or(if timeout_s > 0.0 {
        Duration::MAX
    } else {
        Duration::ZERO
    });
    now.checked_add(wait)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::execution::tests::planner;

    /// The default `[arm]`'s actuators.
    const N: usize = 6;

    /// An estimate of `a` for every actuator, for execution 2.
    fn on(a: f64) -> ConditionedOn<N> {
        ConditionedOn {
            actuation: [a; N],
            execution: 2,
            ..ConditionedOn::NONE
        }
    }

    #[test]
    fn a_queued_set_leaves_the_running_set_its_replanner() {
        let (mut running, r) = planner().start(&[[0.5; N]; 2]).unwrap();
        let (mut queued, q) = planner().start(&[[0.5; N]; 2]).unwrap();
        let mut handed = Replanners::default();
        handed.add(1, r);
        handed.add(2, q);

        // The running set's estimates still re-condition it, and only it.
        assert!(matches!(handed.recondition(1, 1, &on(0.6)), Some(Ok(()))));
        running.rest();
        queued.rest();
        assert_eq!((running.applied(), queued.applied()), (1, 0));
        // Once the queued set runs, its own.
        assert!(matches!(handed.recondition(2, 0, &on(0.4)), Some(Ok(()))));
        queued.rest();
        assert_eq!((running.applied(), queued.applied()), (1, 1));

        // A queued set replaced by a newer one goes back; the running set keeps its replanner.
        handed.remove(2);
        assert!(handed.recondition(2, 0, &on(0.4)).is_none());
        assert!(matches!(handed.recondition(1, 0, &on(0.6)), Some(Ok(()))));
        running.rest();
        assert_eq!(running.applied(), 2);
        handed.remove(1);
        assert!(handed.is_empty());
    }

    #[test]
    fn any_estimate_timeout_gives_a_deadline_without_panicking() {
        let now = Instant::now();
        assert_eq!(
            estimate_deadline(now, 0.5),
            Some(now + Duration::from_millis(500))
        );
        assert_eq!(estimate_deadline(now, 1e30), None);
        assert_eq!(estimate_deadline(now, f64::INFINITY), None);
        assert_eq!(estimate_deadline(now, f64::NAN), Some(now));
        assert_eq!(estimate_deadline(now, -1.0), Some(now));
        assert_eq!(estimate_deadline(now, 0.0), Some(now));
        // Fits a Duration but not an Instant from now.
        assert_eq!(estimate_deadline(now, 1e19), None);
    }
}
