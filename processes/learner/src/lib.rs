//! The learner process: CACLA-MTL at the conditioning points, under `learner.algorithm`
//! ([`softarm_learning::online`]). An `EstimateRequest` (a set was accepted) is answered with the
//! first, exploration-free estimate of every point; each `ConditioningSample` is one visit and is
//! answered with the `ActuationEstimate` the controller asked for next.
//! The state is checkpointed atomically after every execution (on a thread of its own, so a
//! slow disk never delays an answer) and at exit, and resumed at start when it descends from
//! the current model bundle.
//!
//! What it does with requests and samples is [`Learner`]'s (module `visits`), without I/O,
//! so that `softarm-rehearsal` runs the same code in one process; this is the process around it.

mod visits;

pub use visits::Learner;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use softarm_config::Config;
use softarm_config::learner::LearnerConfig;
use softarm_ipc::{
    ActuationEstimate, ConditioningSample, EstimateRequest, MotorState, Node, Position, Pub, Sub,
    TrackerSample,
};
use softarm_kinematics::pcc;
use softarm_kinematics::poly::Polynomial;
use softarm_learning::cacla::{CaclaMtl, LearnerState};
use softarm_learning::online::{ArmState, OnlineLearner};
use softarm_model::bundle::{BundleError, BundleWatch, Model, read_checkpoint, write_checkpoint};
use softarm_runtime::now_ns;

struct Loaded<const N: usize> {
    learner: Learner<N>,
    model_id: String,
}

/// The online learner of a trained `state` (a bundle's or a checkpoint's) with the runtime
/// settings of `configured` (`runtime_config`), steering its corrections by the configured
/// `arm`, as the learner process runs it.
pub fn online_learner<const N: usize>(
    mut state: LearnerState<N>,
    kinematics: Polynomial<N>,
    configured: LearnerConfig,
    arm: pcc::Arm,
) -> Result<OnlineLearner<N>, String> {
    state.config = runtime_config(state.config, configured);
    let cacla = CaclaMtl::restore(&state)?;
    tracing::info!(algorithm = state.config.algorithm.name(), "online learner");
    Ok(OnlineLearner::new(cacla, kinematics, arm))
}

/// The checkpoint if it descends from the bundle in `model_dir`, else the bundle's learner.
fn load<const N: usize>(config: &Config, configured: pcc::Arm) -> Result<Loaded<N>, BundleError> {
    let model_dir = config.model_dir();
    let model = Model::<N>::read_for_arm(&model_dir, &config.arm_identity())?;
    let (state, arm) = match read_checkpoint::<N>(&config.state_dir()) {
        Ok(c) if c.model == model.id => {
            tracing::info!(
                dir = %config.state_dir().display(),
                corrections = c.arm.corrections.len(),
                footprint = c.arm.footprint.len(),
                "resuming from the learner checkpoint"
            );
            (c.state, c.arm)
        }
        Ok(_) => {
            tracing::info!(
                "the checkpoint belongs to an older model: starting from the new bundle"
            );
            (model.learner.clone(), ArmState::default())
        }
        Err(BundleError::Missing { .. }) => (model.learner.clone(), ArmState::default()),
        Err(e) => {
            tracing::error!("{e}; starting from the model bundle instead");
            (model.learner.clone(), ArmState::default())
        }
    };
    let mut online =
        online_learner(state, model.kinematics, config.learner, configured).map_err(|why| {
            BundleError::Invalid {
                path: model_dir.clone(),
                why,
            }
        })?;
    online.restore_arm(&arm);
    Ok(Loaded {
        learner: Learner::new(online, config),
        model_id: model.id,
    })
}

/// Rates, discount and exploration come from the config, so they can be tuned without
/// retraining; the lattices (spacing, span, width, box) are the trained model's own.
fn runtime_config(trained: LearnerConfig, configured: LearnerConfig) -> LearnerConfig {
    let runtime = LearnerConfig {
        alpha_critic: configured.alpha_critic,
        alpha_actor: configured.alpha_actor,
        gamma: configured.gamma,
        sigma_max: configured.sigma_max,
        sigma_mid_m: configured.sigma_mid_m,
        sigma_slope_per_m: configured.sigma_slope_per_m,
        seed: configured.seed,
        algorithm: configured.algorithm,
        gauss_newton: configured.gauss_newton,
        actor_max_centres: configured.actor_max_centres,
        critic_max_centres: configured.critic_max_centres,
        ..trained
    };
    if runtime != configured {
        tracing::warn!(
            "the [learner] lattice settings differ from the trained model's; the model's are used \
             (run `softarm train` to apply the new ones)"
        );
    }
    runtime
}

fn checkpoint<const N: usize>(
    dir: &Path,
    state: &LearnerState<N>,
    arm: &ArmState<N>,
    model_id: &str,
) {
    let started = Instant::now();
    match write_checkpoint(dir, state, arm, model_id) {
        // Slow writes are worth knowing of: they are why checkpoints are off the answering loop.
        Ok(()) if started.elapsed() > Duration::from_millis(500) => {
            tracing::warn!(
                ms = started.elapsed().as_millis() as u64,
                "slow checkpoint write"
            )
        }
        Ok(()) => {}
        Err(e) => tracing::error!("checkpoint not written: {e}"),
    }
}

/// Writes checkpoints on a thread of its own: a write syncs three files and a folder, which on
/// a busy disk takes seconds, and the controller wants each next estimate within about 100 ms.
/// The newest state waiting replaces an older one not yet written; [`Checkpoints::finish`]
/// writes what is waiting and stops.
struct Checkpoints<const N: usize> {
    shared: Arc<(Mutex<Pending<N>>, Condvar)>,
    writer: Option<std::thread::JoinHandle<()>>,
}

struct Pending<const N: usize> {
    next: Option<(LearnerState<N>, ArmState<N>, String)>,
    done: bool,
}

impl<const N: usize> Checkpoints<N> {
    fn start(dir: PathBuf) -> Self {
        let shared = Arc::new((
            Mutex::new(Pending {
                next: None,
                done: false,
            }),
            Condvar::new(),
        ));
        let writer = {
            let shared = shared.clone();
            std::thread::spawn(move || {
                let (lock, wake) = &*shared;
                loop {
                    let job = {
                        let mut p = lock.lock().unwrap_or_else(|e| e.into_inner());
                        while p.next.is_none() && !p.done {
                            p = wake.wait(p).unwrap_or_else(|e| e.into_inner());
                        }
                        match p.next.take() {
                            Some(job) => job,
                            None => return,
                        }
                    };
                    checkpoint(&dir, &job.0, &job.1, &job.2);
                }
            })
        };
        Self {
            shared,
            writer: Some(writer),
        }
    }

    /// Queues `l`'s state, replacing one not yet written.
    fn save(&self, l: &Loaded<N>) {
        let online = l.learner.online();
        let job = (
            online.cacla().state(),
            online.arm_state(),
            l.model_id.clone(),
        );
        let (lock, wake) = &*self.shared;
        lock.lock().unwrap_or_else(|e| e.into_inner()).next = Some(job);
        wake.notify_one();
    }

    /// Writes what is waiting, then stops the writer.
    fn finish(&mut self) {
        let (lock, wake) = &*self.shared;
        lock.lock().unwrap_or_else(|e| e.into_inner()).done = true;
        wake.notify_one();
        if let Some(w) = self.writer.take() {
            let _ = w.join();
        }
    }
}

/// What the controller sent, merged from the two services.
// A few at a time in a reused buffer: boxing the large variant would only add allocations.
/// Motor samples kept for pairing: as many as the service buffers, so that every tracker sample
/// of a backlog finds its motor sample.
const MOTOR_SAMPLES: usize = softarm_ipc::ARM_BUFFER;
/// A tracker and a motor sample this close (ns) are of the same moment of the arm.
const PAIRED_NS: u64 = 10_000_000;

#[allow(clippy::large_enum_variant)]
enum Incoming {
    Request(EstimateRequest),
    Sample(ConditioningSample),
}

impl Incoming {
    fn stamp_ns(&self) -> u64 {
        match self {
            Incoming::Request(r) => r.stamp_ns,
            Incoming::Sample(s) => s.stamp_ns,
        }
    }
}

/// The learner's ports: requests and samples from the controller, estimates back.
struct Ports<const N: usize> {
    requests: Sub<EstimateRequest>,
    samples: Sub<ConditioningSample>,
    /// The arm itself, as the controller reads it: for the footprint that tells when it changed.
    tracker: Sub<TrackerSample>,
    motors: Sub<MotorState>,
    /// The newest motor samples, (stamp, actuation), for pairing with tracker samples.
    motor_samples: [(u64, [f64; N]); MOTOR_SAMPLES],
    next_motor: usize,
    estimates: Pub<ActuationEstimate>,
    /// Estimates sent.
    seq: u64,
    /// Last, so the ports go before it.
    _node: Node,
}

impl<const N: usize> Ports<N> {
    fn open(config: &Config) -> anyhow::Result<Self> {
        let namespace = config.bus()?;
        let node = Node::open(namespace, "learner")?;
        Ok(Self {
            requests: node.subscriber(&node.estimate_request()?)?,
            samples: node.subscriber(&node.cp_sample()?)?,
            tracker: node.subscriber(&node.tracker()?)?,
            motors: node.subscriber(&node.motor_state()?)?,
            motor_samples: [(0, [f64::NAN; N]); MOTOR_SAMPLES],
            next_motor: 0,
            estimates: node.publisher(&node.estimate()?)?,
            seq: 0,
            _node: node,
        })
    }

    /// (stamp, measured actuation, position) of each tracker sample since the last call that a
    /// motor sample was taken within [`PAIRED_NS`] of (drivers stamp on their own: the sim both
    /// at once, a tendon bus and a tracker each when it read).
    fn arm_samples(&mut self) -> Vec<(u64, [f64; N], Position)> {
        while let Ok(Some(m)) = self.motors.receive() {
            let Some(a) = m.actuation.fixed() else {
                continue;
            };
            self.motor_samples[self.next_motor] = (m.stamp_ns, a);
            self.next_motor = (self.next_motor + 1) % MOTOR_SAMPLES;
        }
        let mut out = Vec::new();
        while let Ok(Some(t)) = self.tracker.receive() {
            let nearest = self
                .motor_samples
                .iter()
                .filter(|(stamp, a)| {
                    stamp.abs_diff(t.stamp_ns) <= PAIRED_NS && a.iter().all(|v| v.is_finite())
                })
                .min_by_key(|(stamp, _)| stamp.abs_diff(t.stamp_ns));
            if let Some((_, a)) = nearest {
                out.push((t.stamp_ns, *a, t.position));
            }
        }
        out
    }

    fn send(&mut self, e: ActuationEstimate) {
        self.seq += 1;
        let _ = self.estimates.send_copy(ActuationEstimate {
            seq: self.seq,
            stamp_ns: now_ns(),
            ..e
        });
    }
}

/// Everything the learner's loop keeps between turns.
struct Process<'a, const N: usize> {
    config: &'a Config,
    /// The arm the learner's corrections are steered by (the configured `[arm]`).
    arm: pcc::Arm,
    ports: Ports<N>,
    watch: BundleWatch,
    loaded: Option<Loaded<N>>,
    /// Said once that no bundle is there yet.
    warned: bool,
    inbox: Vec<Incoming>,
    /// Requests and samples refused by the learners of models since replaced.
    refused_before: u64,
    /// Under systemd: how often to say WATCHDOG=1, and when it was last said.
    watchdog: Option<(Duration, Instant)>,
    /// The state last told in STATUS= (model loaded, set).
    told: Option<(bool, u64)>,
    checkpoints: Checkpoints<N>,
}

/// Runs the learner until `stop` is set.
pub fn run(config: &Config, stop: &AtomicBool) -> anyhow::Result<()> {
    let n = config.layout().actuators().len();
    softarm_ipc::with_actuators!(n, N => run_for::<N>(config, stop), n => {
        unreachable!("a loaded config's arm has 3 to 16 actuators, not {n}")
    })
}

/// [`run`] for an arm of `N` actuators.
fn run_for<const N: usize>(config: &Config, stop: &AtomicBool) -> anyhow::Result<()> {
    let mut p = Process::<N> {
        config,
        arm: pcc::Arm::of_config(&config.arm).map_err(anyhow::Error::msg)?,
        ports: Ports::open(config)?,
        watch: BundleWatch::new(config.model_dir(), Duration::from_millis(200)),
        loaded: None,
        warned: false,
        inbox: Vec::new(),
        refused_before: 0,
        watchdog: None,
        told: None,
        checkpoints: Checkpoints::start(config.state_dir()),
    };
    // Under systemd: READY=1 now that every port is open (a model may still be missing: then
    // the learner waits for one, and says so in STATUS=); WATCHDOG=1 while this loop turns.
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Ready]);
    p.watchdog = sd_notify::watchdog_enabled().map(|w| (w / 2, Instant::now()));
    while !stop.load(Ordering::Relaxed) {
        // An estimate is needed before the next group fades in (at least window_s / 2 after the
        // point): 2 ms is plenty.
        std::thread::sleep(Duration::from_millis(2));
        p.turn();
    }
    // The last state is written after everything queued, so it is the one that stays.
    p.checkpoints.finish();
    if let Some(l) = &p.loaded {
        let online = l.learner.online();
        checkpoint(
            &config.state_dir(),
            &online.cacla().state(),
            &online.arm_state(),
            &l.model_id,
        );
    }
    tracing::info!(refused = p.refused(), "learner stopped");
    Ok(())
}

impl<const N: usize> Process<'_, N> {
    /// One turn: systemd, the model, then what the controller sent, answered in order.
    fn turn(&mut self) {
        self.keep_watchdog();
        self.tell_status();
        self.reload();
        // Without a model, requests and samples wait in the subscribers' buffers.
        if self.loaded.is_some() {
            self.take_inbox();
            self.answer();
            self.watch_arm();
        }
    }

    fn keep_watchdog(&mut self) {
        if let Some((every, last)) = self.watchdog.as_mut()
            && last.elapsed() >= *every
        {
            *last = Instant::now();
            let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
        }
    }

    fn tell_status(&mut self) {
        let state = (
            self.loaded.is_some(),
            self.loaded.as_ref().map_or(0, |l| l.learner.set_id()),
        );
        if self.told == Some(state) {
            return;
        }
        self.told = Some(state);
        let status = match state {
            (false, _) => "waiting for a model bundle (softarm train)".to_string(),
            (true, 0) => "model loaded, no way-point set".to_string(),
            (true, id) => format!("learning on set {id}"),
        };
        let _ = sd_notify::notify(&[sd_notify::NotifyState::Status(&status)]);
    }

    /// A new bundle (after `softarm train`) replaces what the learner had.
    fn reload(&mut self) {
        if self.watch.changed() {
            match load(self.config, self.arm) {
                Ok(l) => {
                    tracing::info!(model = %l.model_id, "learner ready");
                    let old = self.loaded.replace(l);
                    self.refused_before += old.map_or(0, |o| o.learner.refused());
                }
                Err(e) => tracing::error!("{e}"),
            }
        } else if !self.watch.exists() && !self.warned {
            self.warned = true;
            tracing::warn!(
                "no model bundle in {} yet: waiting for `softarm train`",
                self.watch.dir().display()
            );
        }
    }

    /// Both queues, in the order the controller sent them: a sample of the running set sent
    /// before a new set's request is still a visit of that set.
    fn take_inbox(&mut self) {
        while let Ok(Some(r)) = self.ports.requests.receive() {
            self.inbox.push(Incoming::Request(*r));
        }
        while let Ok(Some(s)) = self.ports.samples.receive() {
            self.inbox.push(Incoming::Sample(*s));
        }
        self.inbox.sort_by_key(Incoming::stamp_ns);
    }

    /// Each request with the first estimates, each visit with the next; a checkpoint after
    /// each execution's last point.
    fn answer(&mut self) {
        let Some(l) = self.loaded.as_mut() else {
            return;
        };
        for m in self.inbox.drain(..) {
            match m {
                Incoming::Request(r) => {
                    for e in l.learner.request(&r) {
                        self.ports.send(e);
                    }
                }
                Incoming::Sample(s) => {
                    if let Some(e) = l.learner.visit(&s) {
                        self.ports.send(e);
                        if s.point + 1 == s.points {
                            self.checkpoints.save(l);
                        }
                    }
                }
            }
        }
    }

    /// The arm's samples through its footprint; after a change of the arm, the running set's
    /// new first estimates, and a checkpoint (what was learnt of the old arm is gone).
    fn watch_arm(&mut self) {
        let Some(l) = self.loaded.as_mut() else {
            return;
        };
        let changes = l.learner.arm_changes();
        for (stamp_ns, measured, position) in self.ports.arm_samples() {
            for e in l.learner.observe_arm(stamp_ns, &measured, &position) {
                self.ports.send(e);
            }
        }
        if l.learner.arm_changes() != changes {
            self.checkpoints.save(l);
        }
    }

    fn refused(&self) -> u64 {
        self.refused_before + self.loaded.as_ref().map_or(0, |l| l.learner.refused())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_inbox_keeps_the_order_things_were_sent_in() {
        let mut inbox = [
            Incoming::Request(EstimateRequest {
                stamp_ns: 20,
                ..Default::default()
            }),
            Incoming::Sample(ConditioningSample {
                stamp_ns: 10,
                ..Default::default()
            }),
        ];
        inbox.sort_by_key(Incoming::stamp_ns);
        assert!(matches!(inbox[0], Incoming::Sample(_)));
    }
}
