//! Alg. 2 in one process, faster than real time and without iceoryx2, for tests that must fail
//! when adaptation stops working and for tuning
//! (`cargo run --release -p softarm-rehearsal --example online`).
//!
//! It is the running stack's own code with the processes and the wall clock taken out: the
//! controller's admission ([`admit`], [`Admitted::start`]) and its tick's steps ([`Control`])
//! on a simulated tick clock, the learner's [`Learner`] answering each request and visit, and
//! the sim driver's [`SimArm`] stepped on the sim's own deadlines. Only the transport and the
//! clock are simulated ([`Rehearsal`] says where they differ from the stack); what is tuned
//! here is what runs.
//!
//! [`Admitted::start`]: softarm_controller::Admitted::start

use anyhow::{Context, bail};
use softarm_config::Config;
use softarm_config::sim::SimConfig;
use softarm_config::waypoints::WaypointFile;
use softarm_controller::{
    ActuatorLag, Control, Latest, Outputs, Plan, Retired, admit, conditioned_on, rest_ticks,
};
use softarm_ipc::{
    ActuationEstimate, ConditioningSample, ControllerState, ExecutionStats, Setpoint, WaypointSet,
};
use softarm_learner::Learner;
use softarm_method::blend::Replanner;
use softarm_model::bundle::Model;
use softarm_sim::SimArm;
use softarm_sim::plant::{Body, Measurement};

const NS_PER_S: f64 = 1e9;

/// How long the arm holds after a set's end before a sim driver restarted as another arm
/// stops (measured in `softarm-rig soak`: 51 ms from the set's end to the old sim stopping).
pub const END_HOLD_NS: u64 = 50_000_000;

/// How long no sample comes while the sim driver restarts as another arm (measured in `softarm
/// soak`: 57 ms from the old sim stopping to the new one starting where the controller holds
/// the arm).
pub const SIM_AWAY_NS: u64 = 60_000_000;

/// How long the restarted sim publishes the held arm before the next set moves it (measured in
/// `softarm-rig soak`: the set accepted 85 ms after the new sim said it was running).
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
    /// time that passed on the newest setpoint, as drivers/sim does.
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
/// setpoint, steps its [`SimArm`] and publishes the measurement, which is the newest tracker
/// and motor sample the controller's tick reads until the next.
struct SimDriver<const N: usize> {
    arm: SimArm,
    period_ns: u64,
    /// Its next deadline (ns of simulated time).
    due_ns: u64,
    /// The newest setpoint the controller published for it to follow, not yet taken.
    setpoint: Option<[f64; N]>,
    newest: Measurement,
    /// Its own stalls, if the machine has them.
    stalls: Option<StallClock>,
    /// Periods slept through in the stall under way, stepped at its next deadline.
    missed: u64,
}

impl<const N: usize> SimDriver<N> {
    /// The sim driver's arm on `body`, as it starts when no controller runs: at
    /// `sim.initial_actuation`, its first measurement published at time 0.
    fn new(body: Body, sim: &SimConfig) -> anyhow::Result<Self> {
        if body.start().actuators() != N {
            bail!(
                "the sim's arm has {} actuators; the rehearsal runs {N}",
                body.start().actuators()
            );
        }
        let mut arm = SimArm::of_body(body, sim, &sim.initial_actuation.fixed::<N>())?;
        let newest = arm.step(None, false, 1);
        let period_ns = (arm.dt() * NS_PER_S).round() as u64;
        Ok(Self {
            arm,
            period_ns,
            due_ns: period_ns,
            setpoint: None,
            newest,
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
            let periods = std::mem::take(&mut self.missed) + 1;
            let setpoint = self.setpoint.take();
            self.newest = self
                .arm
                .step(setpoint.as_ref().map(|a| &a[..]), false, periods);
            published(self.due_ns, &self.newest);
            self.due_ns += self.period_ns;
        }
    }
}

/// What one tick of the [`Control`] published.
#[derive(Default)]
struct Published {
    setpoint: Option<Setpoint>,
    sample: Option<ConditioningSample>,
    stats: Option<ExecutionStats>,
}

impl<const N: usize> Outputs<N> for Published {
    fn setpoint(&mut self, s: Setpoint) {
        self.setpoint = Some(s);
    }

    fn sample(&mut self, s: ConditioningSample) {
        self.sample = Some(s);
    }

    fn stats(&mut self, s: ExecutionStats) {
        self.stats = Some(s);
    }

    /// Freed here: the rehearsal has no tick thread to keep from freeing.
    fn retire(&mut self, _: Retired<N>) {}
}

/// The running set's side on the service thread: its id and its replanner.
struct Running<const N: usize> {
    set_id: u64,
    replanner: Replanner<N>,
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
pub struct Rehearsal<'a, const N: usize> {
    model: &'a Model<N>,
    config: &'a Config,
    learner: Learner<N>,
    sim_driver: SimDriver<N>,
    /// The controller's tick, as the tick thread runs it.
    control: Control<N>,
    /// What the tick has read of the sim, as the controller's inputs keep it.
    latest: Latest<N>,
    /// A set admitted and not yet handed to the tick.
    plan: Option<Plan<N>>,
    running: Option<Running<N>>,
    rest_ticks: i64,
    period_ns: u64,
    /// The simulated clock: the time of the next tick (ns).
    now_ns: u64,
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

impl<'a, const N: usize> Rehearsal<'a, N> {
    /// The stack of `config` with `model`, `learner`, and the sim driver on `body` (an arm of
    /// `N` actuators, with its steps) under `sim` (its drift included).
    pub fn new(
        model: &'a Model<N>,
        config: &'a Config,
        learner: Learner<N>,
        body: Body,
        sim: &SimConfig,
    ) -> anyhow::Result<Self> {
        let c = &config.controller;
        let sim_driver = SimDriver::new(body, sim)?;
        // The sim's first measurement, published at time 0, is what the first tick reads.
        let mut latest = Latest::new(false);
        latest.take_tracker(0, sim_driver.newest.position);
        latest.take_motors(0, sim_driver.newest.actuation_of());
        Ok(Self {
            model,
            config,
            learner,
            sim_driver,
            control: Control::new(c),
            latest,
            plan: None,
            running: None,
            rest_ticks: rest_ticks(c),
            period_ns: (NS_PER_S / c.rate_hz).round() as u64,
            now_ns: 0,
            next_set_id: 0,
            gap_due: false,
            sim: sim.clone(),
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
            Stalled::Sim => self.sim_driver.stalls = Some(StallClock::new(stalls)),
            Stalled::Learner => self.learner_stalls = Some(StallClock::new(stalls)),
        }
        self
    }

    pub fn learner(&self) -> &Learner<N> {
        &self.learner
    }

    /// The actuators' lag as its controller has measured it.
    pub fn lag(&self) -> &ActuatorLag<N> {
        self.control.lag()
    }

    /// Its controller has measured `lag` already: a freshly started learner beside a
    /// controller that has been running, which is what "a fresh learner" is compared as (a
    /// fresh controller would lead by nothing in its first set).
    pub fn with_lag(mut self, lag: &ActuatorLag<N>) -> Self {
        self.control.set_lag(lag.clone());
        self
    }

    /// Another learner takes over (a restarted learner process); the one that ran.
    pub fn replace_learner(&mut self, learner: Learner<N>) -> Learner<N> {
        std::mem::replace(&mut self.learner, learner)
    }

    /// The sim's arm changes between sets, as when `softarm-rig soak` restarts the sim with another
    /// scenario: the arm held for [`END_HOLD_NS`] after the last set, no sample for
    /// [`SIM_AWAY_NS`], then the arm held where it was for [`CHANGE_HOLD_NS`] before the next
    /// set, as the stack's; the learner watches it, and the controller ticks on, holding. The
    /// restarted sim runs `body` without the first one's drift.
    pub fn change_arm(&mut self, body: Body) -> anyhow::Result<()> {
        if self.gap_due {
            self.hold_for(END_HOLD_NS);
            self.gap_due = false;
        }
        // As the sim driver restarts: a new plant, its realism from its seed, started at the
        // setpoint the controller holds (not where the actuators were: they lag it, with
        // backlash and the disturbance).
        let sim = SimConfig {
            drift: Default::default(),
            ..self.sim.clone()
        };
        let held = self
            .sim_driver
            .setpoint
            .unwrap_or_else(|| std::array::from_fn(|i| self.sim_driver.arm.command()[i]));
        self.sim_driver.arm =
            SimArm::of_body(body, &sim, &held).context("the restarted sim's plant")?;
        self.sim_driver.away_until(self.now_ns + SIM_AWAY_NS);
        self.hold_for(SIM_AWAY_NS + CHANGE_HOLD_NS);
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
            self.hold_for(SET_GAP_NS);
            self.gap_due = false;
        }
        self.start(&set)?;
        // Far more than the set takes at the arm's pace, held now and then: a set that never
        // ends (the arm held for good) fails rather than hangs.
        let limit_ns = self.now_ns + 10 * set_length_ns(&set, self.rest_ticks, self.period_ns);
        let mut stats = Vec::with_capacity(executions as usize);
        // The tick retires a set between executions once every one has run.
        while self.plan.is_some() || !self.control.is_idle() {
            if self.now_ns > limit_ns {
                bail!(
                    "the set did not end: {} of {executions} executions in {:.1} s",
                    stats.len(),
                    self.now_ns as f64 / NS_PER_S
                );
            }
            stats.extend(self.tick());
        }
        self.running = None;
        self.gap_due = true;
        Ok(stats)
    }

    /// The controller ticks on for `ns` with no set running.
    fn hold_for(&mut self, ns: u64) {
        let until = self.now_ns + ns;
        while self.now_ns < until {
            self.tick();
        }
    }

    /// The sim up to the clock, the tick's inputs and the learner reading each measurement (as
    /// the controller and the learner process read `tracker` and `motor_state`): the estimates
    /// the learner sends back (on a change of the arm).
    fn sim_until_now(&mut self) -> Vec<ActuationEstimate> {
        let (learner, latest) = (&mut self.learner, &mut self.latest);
        let mut estimates = Vec::new();
        self.sim_driver.run_until(self.now_ns, |t, m| {
            latest.take_tracker(t, m.position);
            let actuation = m.actuation_of();
            latest.take_motors(t, actuation);
            estimates.extend(learner.observe_arm(t, &actuation, &m.position));
        });
        estimates
    }

    /// As the service thread starts a set: admission, the learner's first estimates, the
    /// blend handed to the tick and the replanner kept.
    fn start(&mut self, set: &WaypointSet) -> anyhow::Result<()> {
        let admitted = admit(self.config, Some(self.model), set).context("set rejected")?;
        self.next_set_id += 1;
        let set_id = self.next_set_id;
        let request = admitted.estimate_request(set_id, set_id, self.now_ns);
        let mut estimates = vec![None; admitted.points()];
        for e in self.learner.request(&request) {
            estimates[e.point as usize] = conditioned_on(&e);
        }
        if estimates.iter().any(Option::is_none) {
            // The stack would start from the primitives' means after a time-out: nothing to
            // rehearse then.
            bail!("the learner refused the set");
        }
        let (ready, replanner) = admitted.start(set_id, &estimates)?;
        self.plan = Some(Plan::Execute(Box::new(ready)));
        self.running = Some(Running { set_id, replanner });
        Ok(())
    }

    /// One tick, as the controller's: the sim's newest samples read, the [`Control`]'s steps,
    /// the setpoint to the sim; a conditioning sample goes to the learner and its estimate
    /// re-conditions the set. The execution's stats when one ends.
    fn tick(&mut self) -> Option<ExecutionStats> {
        // A stalled tick publishes nothing meanwhile and then plays with what it missed.
        let skipped = self
            .tick_stalls
            .as_mut()
            .and_then(|s| s.due(self.now_ns))
            .map_or(0, |for_ns| for_ns / self.period_ns);
        self.now_ns += skipped * self.period_ns;
        for e in self.sim_until_now() {
            self.answer(e);
        }
        self.deliver_late();
        let mut out = Published::default();
        self.control.tick(
            self.now_ns,
            skipped,
            &self.latest,
            self.plan.take(),
            &mut out,
        );
        // The sim follows a fresh setpoint, not a stopped controller's (drivers/driver).
        if let Some(s) = out.setpoint
            && s.state != ControllerState::Stopped as u32
        {
            self.sim_driver.setpoint = s.actuation.fixed();
        }
        if let Some(sample) = out.sample
            && let Some(e) = self.learner.visit(&sample)
        {
            self.answer(e);
        }
        self.now_ns += self.period_ns;
        out.stats
    }

    /// The learner's answer re-conditions the set now, or when the learner's stall under way
    /// ends.
    fn answer(&mut self, e: ActuationEstimate) {
        let now = self.now_ns;
        match self.learner_stalls.as_mut().and_then(|s| s.busy_until(now)) {
            Some(at) => self.late.push((at, e)),
            None => self.recondition(&e),
        }
    }

    /// The answers held back by a learner's stall that has ended, in the order sent.
    fn deliver_late(&mut self) {
        let now = self.now_ns;
        let (due, waiting): (Vec<_>, Vec<_>) = std::mem::take(&mut self.late)
            .into_iter()
            .partition(|(at, _)| *at <= now);
        self.late = waiting;
        for (_, e) in due {
            self.recondition(&e);
        }
    }

    /// An estimate re-conditions its point of the running set, as the service thread does; one
    /// for a set that is gone goes nowhere, and one that does not fit is not used.
    fn recondition(&mut self, e: &ActuationEstimate) {
        let Some(r) = self.running.as_mut().filter(|r| r.set_id == e.set_id) else {
            return;
        };
        let Some(on) = conditioned_on(e) else {
            return;
        };
        if let Err(err) = r.replanner.recondition_on(e.point as usize, &on) {
            tracing::warn!(
                set_id = e.set_id,
                point = e.point,
                "estimate not used: {err}"
            );
        }
    }
}

/// A set's executions with their rests, at the arm's pace (ns).
fn set_length_ns(set: &WaypointSet, rest_ticks: i64, period_ns: u64) -> u64 {
    let execution_ns = (set.duration_s * NS_PER_S) as u64 + rest_ticks.max(0) as u64 * period_ns;
    (u64::from(set.executions) + 1) * execution_ns
}

#[cfg(test)]
mod tests;
