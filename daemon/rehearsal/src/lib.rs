//! Alg. 2 in one process, faster than real time and without iceoryx2, for tests that must fail
//! when adaptation stops working and for tuning
//! (`cargo run --release -p softarm-rehearsal --example online`).
//!
//! It is the running stack's own code with the processes and the wall clock taken out: the
//! controller's admission ([`admit`], [`Admitted::start`]), its [`Execution`] and [`Limiter`]
//! on a simulated tick clock, the learner's [`Learner`] answering each request and visit, and
//! a [`Plant`] stepped as the sim driver steps it (hal-drivers/sim). Only the transport and the
//! clock are simulated ([`Rehearsal`] says where they differ from the stack); what is tuned
//! here is what runs.
//!
//! [`Admitted::start`]: softarm_controller::Admitted::start

use anyhow::{Context, bail};
use softarm_config::Config;
use softarm_config::waypoints::WaypointFile;
use softarm_controller::{ActuatorLag, Execution, Limiter, Track, admit, rest_ticks};
use softarm_ipc::{ACTUATORS, Actuation, ActuationEstimate, ExecutionStats, WaypointSet};
use softarm_learner::Learner;
use softarm_method::blend::Replanner;
use softarm_method::pcc::ArmGeometry;
use softarm_method::plant::{Measurement, Plant, SimConfig};
use softarm_model::bundle::Model;

const NS_PER_S: f64 = 1e9;

/// How long the arm holds after a set's end before a sim driver restarted as another arm
/// stops (measured in `softarm soak`: 51 ms from the set's end to the old sim stopping).
pub const END_HOLD_NS: u64 = 50_000_000;

/// How long no sample comes while the sim driver restarts as another arm (measured in `softarm
/// soak`: 57 ms from the old sim stopping to the new one starting where the controller holds
/// the arm).
pub const SIM_AWAY_NS: u64 = 60_000_000;

/// How long the restarted sim publishes the held arm before the next set moves it (measured in
/// `softarm soak`: the set accepted 85 ms after the new sim said it was running).
pub const CHANGE_HOLD_NS: u64 = 80_000_000;

/// How long the arm holds between two sets: `softarm submit --wait` returning on the set's
/// last stats, the next `submit` starting and the controller planning its set take longer.
pub const SET_GAP_NS: u64 = 200_000_000;

/// A loaded machine, as the stack meets one: a process kept from its CPU for `for_ns` every
/// `every_ns` of simulated time, the first at `every_ns`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stalls {
    pub of: Stalled,
    pub every_ns: u64,
    pub for_ns: u64,
}

/// The process a [`Stalls`] keeps from its CPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stalled {
    /// The controller's tick: no setpoint is published meanwhile (the sim holds the last),
    /// then the tick plays with the periods it missed as `skipped`, as the stack's does.
    Controller,
    /// The sim driver: no sample is published meanwhile, then it steps its plant by all the
    /// time that passed on the newest setpoint, as hal-drivers/sim does.
    Sim,
    /// The learner: what it answers meanwhile reaches the controller when the stall ends,
    /// which may be after the point it is for has started.
    Learner,
}

/// When the stalls of [`Stalls`] come.
#[derive(Debug, Clone, Copy)]
struct StallClock {
    stalls: Stalls,
    next_ns: u64,
    /// When the latest stall started.
    last_ns: Option<u64>,
}

impl StallClock {
    fn new(stalls: Stalls) -> Self {
        Self {
            stalls,
            next_ns: stalls.every_ns,
            last_ns: None,
        }
    }

    /// The stall's length if one is due at or before `now_ns` and was not taken yet.
    fn due(&mut self, now_ns: u64) -> Option<u64> {
        if now_ns < self.next_ns {
            return None;
        }
        while self.next_ns <= now_ns {
            self.last_ns = Some(self.next_ns);
            self.next_ns += self.stalls.every_ns.max(1);
        }
        Some(self.stalls.for_ns)
    }

    /// When the stall under way at `now_ns` ends, if one is.
    fn busy_until(&mut self, now_ns: u64) -> Option<u64> {
        self.due(now_ns);
        let end = self.last_ns? + self.stalls.for_ns;
        (now_ns < end).then_some(end)
    }
}

/// The sim driver in simulated time: on its own deadlines (`sim.rate_hz`) it takes the newest
/// setpoint, steps the plant by one period and publishes the measurement, which is the newest
/// tracker and motor sample the controller's tick reads until the next.
struct SimArm {
    plant: Plant,
    period_ns: u64,
    dt: f64,
    /// Its next deadline (ns of simulated time).
    due_ns: u64,
    /// The newest setpoint (before the first, where the arm starts, as the sim holds it).
    command: Actuation,
    newest: Measurement,
    /// When `newest` was published (ns).
    newest_ns: u64,
    /// Its own stalls, if the machine has them.
    stalls: Option<StallClock>,
    /// Periods slept through in the stall under way, stepped at its next deadline.
    missed: u64,
}

impl SimArm {
    /// The sim driver's plant, as it starts when no controller runs: at
    /// `sim.initial_actuation`, its first measurement published at time 0.
    fn new(arm: ArmGeometry, sim: &SimConfig) -> anyhow::Result<Self> {
        let mut plant = Plant::of_sim(arm, sim, sim.initial_actuation)
            .map_err(anyhow::Error::msg)
            .context("the simulated plant")?;
        let dt = 1.0 / sim.rate_hz;
        let command = sim.initial_actuation;
        let newest = plant.step(&command, dt);
        Ok(Self {
            plant,
            period_ns: (dt * NS_PER_S).round() as u64,
            dt,
            due_ns: (dt * NS_PER_S).round() as u64,
            command,
            newest,
            newest_ns: 0,
            stalls: None,
            missed: 0,
        })
    }

    /// No step and no sample up to `now_ns`: the sim driver is away (the arm holds).
    fn away_until(&mut self, now_ns: u64) {
        while self.due_ns <= now_ns {
            self.due_ns += self.period_ns;
        }
    }

    /// Every step whose deadline is at or before `now_ns`: a sample published at the instant
    /// of a tick is read by that tick. `published` sees each measurement with its time.
    /// A stall moves the next deadline by its length; the step there covers the periods
    /// slept through too, on the setpoint newest then.
    fn run_until(&mut self, now_ns: u64, mut published: impl FnMut(u64, &Measurement)) {
        while self.due_ns <= now_ns {
            if self.missed == 0
                && let Some(for_ns) = self.stalls.as_mut().and_then(|s| s.due(self.due_ns))
            {
                self.missed = for_ns / self.period_ns;
                self.due_ns += self.missed * self.period_ns;
                continue;
            }
            let dt = self.dt * (std::mem::take(&mut self.missed) + 1) as f64;
            self.newest = self.plant.step(&self.command, dt);
            self.newest_ns = self.due_ns;
            published(self.due_ns, &self.newest);
            self.due_ns += self.period_ns;
        }
    }
}

/// The controller's tick, the learner and the sim on one simulated clock: way-point sets run
/// one after another on the same arm and learner, as `softarm submit` runs them on a stack.
///
/// Where it differs from the running stack, knowingly, unless [`Rehearsal::with_stalls`] makes
/// it a loaded machine: the tick never overruns (`skipped` is 0, so every point is sampled at
/// its own tick; the stack under load samples at the first tick played after it); the
/// learner's estimate re-conditions the set at once, where the stack's goes through two
/// processes polling every 2 ms (a few ticks; the blend swaps a group in only while it is
/// inactive, at least `window_s / 2` after its point, so this changes no table); a set starts
/// as soon as it is admitted (the stack idles a few ms waiting for the first estimates, the
/// sim stepping on); the sim's deadlines fall on the tick grid's (phase
/// 0) and the arm starts at `sim.initial_actuation` with the plant's noise drawn from its seed
/// on, where the stack's sim has run for a while before the set (other noise, same statistics).
pub struct Rehearsal<'a> {
    model: &'a Model,
    config: &'a Config,
    learner: Learner,
    arm: SimArm,
    /// Started, as the tick starts it, from the first measured state.
    limiter: Limiter,
    /// The actuators' lag, as the tick measures it and leads by.
    lag: ActuatorLag,
    rest_ticks: i64,
    period_ns: u64,
    /// The simulated clock: the time of the next tick (ns).
    now_ns: u64,
    /// The tracker samples the tick has read, as the controller's inputs keep them.
    track: Track,
    next_set_id: u64,
    /// The sim's config, for a sim restarted as another arm.
    sim: SimConfig,
    /// A set ended and the arm has not held since: [`SET_GAP_NS`] before the next set, or
    /// [`END_HOLD_NS`] before a change of the arm.
    gap_due: bool,
    /// The tick's own stalls, if the machine has them.
    tick_stalls: Option<StallClock>,
    /// The learner's stalls, and its answers held back by them (when they arrive).
    learner_stalls: Option<StallClock>,
    late: Vec<(u64, ActuationEstimate)>,
}

impl<'a> Rehearsal<'a> {
    /// The stack of `config` with `model`, `learner`, and the sim driver on `arm` under `sim`.
    pub fn new(
        model: &'a Model,
        config: &'a Config,
        learner: Learner,
        arm: ArmGeometry,
        sim: &SimConfig,
    ) -> anyhow::Result<Self> {
        let c = &config.controller;
        let arm = SimArm::new(arm, sim)?;
        let limiter = Limiter::new(
            c.actuator_min,
            c.actuator_max,
            c.slew_per_s,
            c.rate_hz,
            arm.newest.actuation,
        );
        Ok(Self {
            model,
            config,
            learner,
            arm,
            limiter,
            lag: ActuatorLag::new(c.rate_hz, c.max_lead_s),
            rest_ticks: rest_ticks(c),
            period_ns: (NS_PER_S / c.rate_hz).round() as u64,
            now_ns: 0,
            track: Track::default(),
            next_set_id: 0,
            gap_due: false,
            sim: *sim,
            tick_stalls: None,
            learner_stalls: None,
            late: Vec::new(),
        })
    }

    /// On a loaded machine: `stalls` keep the controller's tick, the sim or the learner from
    /// the CPU (one kind per call).
    pub fn with_stalls(mut self, stalls: Stalls) -> Self {
        match stalls.of {
            Stalled::Controller => self.tick_stalls = Some(StallClock::new(stalls)),
            Stalled::Sim => self.arm.stalls = Some(StallClock::new(stalls)),
            Stalled::Learner => self.learner_stalls = Some(StallClock::new(stalls)),
        }
        self
    }

    pub fn learner(&self) -> &Learner {
        &self.learner
    }

    /// The actuators' lag as its controller has measured it.
    pub fn lag(&self) -> &ActuatorLag {
        &self.lag
    }

    /// Its controller has measured `lag` already: a freshly started learner beside a
    /// controller that has been running, which is what "a fresh learner" is compared as (a
    /// fresh controller would lead by nothing in its first set).
    pub fn with_lag(mut self, lag: &ActuatorLag) -> Self {
        self.lag = lag.clone();
        self
    }

    /// Another learner takes over (a restarted learner process); the one that ran.
    pub fn replace_learner(&mut self, learner: Learner) -> Learner {
        std::mem::replace(&mut self.learner, learner)
    }

    /// The sim's arm changes between sets, as when `softarm soak` restarts the sim with another
    /// scenario: the arm held for [`END_HOLD_NS`] after the last set, no sample for
    /// [`SIM_AWAY_NS`], then the arm held where it was for [`CHANGE_HOLD_NS`] before the next
    /// set, as the stack's; the learner watches it (no set runs, so what it would send goes
    /// nowhere).
    pub fn change_arm(&mut self, arm: ArmGeometry) -> anyhow::Result<()> {
        if self.gap_due {
            self.now_ns += END_HOLD_NS;
            self.hold();
            self.gap_due = false;
        }
        // As the sim driver restarts: a new plant, its realism from its seed, started at the
        // setpoint the controller holds (not where the actuators were: they lag it, with
        // backlash and the disturbance).
        let sim = SimConfig {
            changes: Default::default(),
            ..self.sim
        };
        self.arm.plant = Plant::of_sim(arm, &sim, self.arm.command)
            .map_err(anyhow::Error::msg)
            .context("the restarted sim's plant")?;
        self.now_ns += SIM_AWAY_NS;
        self.arm.away_until(self.now_ns);
        self.now_ns += CHANGE_HOLD_NS;
        self.hold();
        Ok(())
    }

    /// Runs `set` `executions` times from where the arm is; each execution's stats, as the
    /// controller publishes them on `stats`.
    pub fn rehearse(
        &mut self,
        set: &WaypointFile,
        executions: u32,
    ) -> anyhow::Result<Vec<ExecutionStats>> {
        let set = set.to_set(executions).map_err(anyhow::Error::msg)?;
        if self.gap_due {
            // The arm holds where the last set left it until this one is admitted.
            self.now_ns += SET_GAP_NS;
            self.hold();
            self.gap_due = false;
        }
        let (mut execution, mut replanner) = self.start(&set)?;
        let mut stats = Vec::with_capacity(executions as usize);
        // The tick ends a set between executions once every one has run.
        while !(execution.at_boundary(self.rest_ticks) && execution.through()) {
            stats.extend(self.tick(&mut execution, &mut replanner));
        }
        self.gap_due = true;
        Ok(stats)
    }

    /// The sim up to the clock, the tick's track and the learner reading each measurement (as
    /// the controller and the learner process read `tracker` and `motor_state`): the estimates
    /// the learner sends back (on a change of the arm).
    fn sim_until_now(&mut self) -> Vec<ActuationEstimate> {
        let (learner, track) = (&mut self.learner, &mut self.track);
        let mut estimates = Vec::new();
        self.arm.run_until(self.now_ns, |t, m| {
            track.push(t, m.position);
            estimates.extend(learner.observe_arm(t, &m.actuation, &m.position));
        });
        estimates
    }

    /// The arm held up to the clock with no set running: what the learner would send goes
    /// nowhere.
    fn hold(&mut self) {
        self.sim_until_now();
    }

    /// As the service thread starts a set: admission, the learner's first estimates, the
    /// blend handed to the tick and the replanner kept.
    fn start(&mut self, set: &WaypointSet) -> anyhow::Result<(Execution, Replanner<ACTUATORS>)> {
        let admitted = admit(self.config, Some(self.model), set).context("set rejected")?;
        self.next_set_id += 1;
        let set_id = self.next_set_id;
        let request = admitted.estimate_request(set_id, set_id, self.now_ns);
        let mut estimates = vec![None; admitted.points()];
        for e in self.learner.request(&request) {
            estimates[e.point as usize] = Some(e.actuation);
        }
        if estimates.iter().any(Option::is_none) {
            // The stack would start from the primitives' means after a time-out: nothing to
            // rehearse then.
            bail!("the learner refused the set");
        }
        let (ready, replanner) = admitted.start(set_id, &estimates)?;
        let max_lead = self.lag.max_lead_ticks();
        Ok((
            Execution::new(Box::new(ready), self.rest_ticks, max_lead),
            replanner,
        ))
    }

    /// One tick, as the controller's: read the newest tracker and motor samples, step the
    /// execution, limit, publish the setpoint; a conditioning sample goes to the learner and
    /// its estimate re-conditions the set. The execution's stats when one ends.
    fn tick(
        &mut self,
        execution: &mut Execution,
        replanner: &mut Replanner<ACTUATORS>,
    ) -> Option<ExecutionStats> {
        // A stalled tick publishes nothing meanwhile and then plays with what it missed.
        let skipped = self
            .tick_stalls
            .as_mut()
            .and_then(|s| s.due(self.now_ns))
            .map_or(0, |for_ns| for_ns / self.period_ns);
        self.now_ns += skipped * self.period_ns;
        for e in self.sim_until_now() {
            self.answer(replanner, e);
        }
        self.deliver_late(replanner);
        let lead = self.lag.lead_ticks();
        let t = execution.step(&self.track, self.rest_ticks, lead, self.now_ns, skipped);
        let setpoint = self.limiter.apply(&t.target);
        let measured = (self.arm.newest_ns, &self.arm.newest.actuation);
        self.lag.published(self.now_ns, &setpoint, Some(measured));
        let followed = self.lag.followed(self.now_ns, execution.lead());
        execution.published(
            &followed.unwrap_or(setpoint),
            Some(&self.arm.newest.actuation),
        );
        self.arm.command = setpoint;
        if let Some(sample) = t.point
            && let Some(e) = self.learner.visit(&sample)
        {
            self.answer(replanner, e);
        }
        self.now_ns += self.period_ns;
        t.finished
    }

    /// The learner's answer re-conditions the set now, or when the learner's stall under way
    /// ends.
    fn answer(&mut self, replanner: &mut Replanner<ACTUATORS>, e: ActuationEstimate) {
        let now = self.now_ns;
        match self.learner_stalls.as_mut().and_then(|s| s.busy_until(now)) {
            Some(at) => self.late.push((at, e)),
            None => recondition(replanner, &e),
        }
    }

    /// The answers held back by a learner's stall that has ended, in the order sent.
    fn deliver_late(&mut self, replanner: &mut Replanner<ACTUATORS>) {
        let now = self.now_ns;
        self.late.retain(|(at, e)| {
            let due = *at <= now;
            if due {
                recondition(replanner, e);
            }
            !due
        });
    }
}

/// An estimate re-conditions its point, as the service thread does; one that does not fit is
/// not used, and the set runs on.
fn recondition(replanner: &mut Replanner<ACTUATORS>, e: &ActuationEstimate) {
    if let Err(err) = replanner.recondition(e.point as usize, &e.actuation, e.execution) {
        tracing::warn!(
            set_id = e.set_id,
            point = e.point,
            "estimate not used: {err}"
        );
    }
}

#[cfg(test)]
mod tests;
