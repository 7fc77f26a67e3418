//! The tick's steps as one function, without I/O: from the clock, the newest samples and a
//! plan, the state, the setpoint and what to publish. The controller's tick thread calls it
//! between its reads and its outbox; `softarm-rehearsal` calls it on a simulated clock, so
//! what is rehearsed is this very sequence. Allocation-free once running.

use softarm_config::Controller;
use softarm_ipc::{ConditioningSample, ControllerState, ExecutionStats, Position, Setpoint};

use crate::demonstration::{self, DemoPlayback, DemoSequences, NO_DEMO};
use crate::execution::{self, Execution, ReadySet, Track};
use crate::lag::ActuatorLag;
use crate::limiter::Limiter;

/// What the service side hands the tick: a set to execute, or demonstrations to play.
pub enum Plan<const N: usize> {
    Execute(Box<ReadySet<N>>),
    Demonstrate(Box<DemoSequences<N>>),
}

/// What the tick is done with, handed back to be freed off the tick thread.
pub enum Retired<const N: usize> {
    Set(Box<ReadySet<N>>),
    Demo(Box<DemoSequences<N>>),
}

/// Where the tick's results go: the controller's outbox and rings, or a rehearsal.
pub trait Outputs<const N: usize> {
    fn setpoint(&mut self, s: Setpoint);
    fn sample(&mut self, s: ConditioningSample);
    fn stats(&mut self, s: ExecutionStats);
    /// Must not block or free on the tick thread.
    fn retire(&mut self, r: Retired<N>);
}

/// The newest of what the drivers and the e-stop said, as the tick reads it.
pub struct Latest<const N: usize> {
    /// The end-effector position and its stamp.
    pub position: Option<(Position, u64)>,
    /// The newest positions, for the reach at a conditioning point.
    pub track: Track,
    /// The measured actuation and its stamp.
    pub measured: Option<([f64; N], u64)>,
    /// The e-stop is engaged.
    pub engaged: bool,
    /// The driver reports a motor with a hardware error, or its torque off (it has not engaged
    /// the setpoint, e.g. one too far from where a sagged motor stands): the arm may not move
    /// until it is fixed; the setpoint stays where it is, so a driver that engages takes it.
    pub driver_fault: bool,
}

impl<const N: usize> Latest<N> {
    /// Nothing heard yet; `engaged`: the e-stop as the process found it.
    pub fn new(engaged: bool) -> Self {
        Self {
            position: None,
            track: Track::default(),
            measured: None,
            engaged,
            driver_fault: false,
        }
    }

    /// A tracker sample stamped `stamp_ns`, already checked to be numbers.
    pub fn take_tracker(&mut self, stamp_ns: u64, position: Position) {
        self.position = Some((position, stamp_ns));
        self.track.push(stamp_ns, position);
    }

    /// A measured actuation stamped `stamp_ns`, already checked to be numbers.
    pub fn take_motors(&mut self, stamp_ns: u64, actuation: [f64; N]) {
        self.measured = Some((actuation, stamp_ns));
    }
}

/// How fresh the data is at this tick, and so whether the arm may move.
#[derive(Debug, Clone, Copy)]
pub struct Health {
    pub tracker_age_ns: u64,
    pub motor_age_ns: u64,
    pub safe: bool,
}

/// What a tick decided.
#[derive(Debug, Clone, Copy)]
pub struct Decided {
    pub state: ControllerState,
    pub health: Health,
}

/// What [`Control::report`] tells `status`.
#[derive(Debug, Clone, Copy)]
pub struct Report {
    pub set_id: u64,
    /// The execution under way, 0 if none.
    pub execution: u32,
    pub reconditions_current: u32,
    pub reconditions_last: u32,
    pub held_solves: u64,
    /// Points of finished executions the tracker did not see at their time.
    pub points_unseen: u64,
    /// The measured lag, `u64::MAX` while not measured.
    pub lag_ns: u64,
    pub lead_ns: u64,
}

/// What a playing tick does. One lives in place: boxing the execution would allocate on the
/// tick thread when a set starts.
#[allow(clippy::large_enum_variant)]
enum Mode<const N: usize> {
    Idle,
    Demonstrate(DemoPlayback<N>),
    Execute(Execution<N>),
}

/// The configured timing, in ticks where the loop counts ticks.
struct Timing {
    rate_hz: f64,
    /// Tracker or motor data older than this holds the arm (ns).
    timeout_ns: u64,
    rest_ticks: i64,
    demo_rest_ticks: i64,
}

impl Timing {
    fn new(c: &Controller) -> Self {
        Self {
            rate_hz: c.rate_hz,
            timeout_ns: (c.tracker_timeout_ms * 1e6) as u64,
            rest_ticks: execution::rest_ticks(c),
            demo_rest_ticks: (demonstration::rest_s(c) * c.rate_hz).round() as i64,
        }
    }
}

/// What the mode produced this tick.
struct Step<const N: usize> {
    /// `None` holds the last setpoint.
    target: Option<[f64; N]>,
    /// (demonstration, class) while one is recorded.
    demo: (u32, u32),
    /// The execution under way, 0 if none.
    execution: u32,
    sample: Option<ConditioningSample>,
    finished: Option<ExecutionStats>,
}

impl<const N: usize> Step<N> {
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
    setpoints: u64,
    samples: u64,
    stats: u64,
    /// Re-conditionings applied during the last completed execution, whichever set it was.
    last_reconditions: u32,
    /// Held group solves of the sets already done.
    held_solves: u64,
    /// Points of finished executions with no tracker sample in their window.
    points_unseen: u64,
}

/// Everything the tick keeps between ticks, bar its I/O.
pub struct Control<const N: usize> {
    timing: Timing,
    /// Clamp range and slew limit, for the limiter made at the first measured state.
    actuator_min: [f64; N],
    actuator_max: [f64; N],
    slew_per_s: f64,
    /// `None` until the arm's state is known: the first setpoint starts there.
    limiter: Option<Limiter<N>>,
    /// The actuators' lag behind the setpoints, which executions lead by.
    lag: ActuatorLag<N>,
    mode: Mode<N>,
    /// The next set, waiting for the running one's execution to end.
    queued: Option<Box<ReadySet<N>>>,
    was_safe: bool,
    /// The e-stop was engaged since the arm was last safe: the drivers held their own
    /// positions (or dropped the torque), not the setpoint.
    stopped_since_safe: bool,
    count: Counts,
}

impl<const N: usize> Control<N> {
    pub fn new(c: &Controller) -> Self {
        Self {
            timing: Timing::new(c),
            actuator_min: c.actuator_min.fixed(),
            actuator_max: c.actuator_max.fixed(),
            slew_per_s: c.slew_per_s,
            limiter: None,
            lag: ActuatorLag::new(c.rate_hz, c.max_lead_s),
            mode: Mode::Idle,
            queued: None,
            was_safe: false,
            stopped_since_safe: false,
            count: Counts::default(),
        }
    }

    /// One tick at `now` (ns), `skipped` whole periods after the last: take the plan, decide
    /// the state, step the mode, limit, measure the lag, credit, publish, end at a boundary.
    pub fn tick(
        &mut self,
        now: u64,
        skipped: u64,
        latest: &Latest<N>,
        plan: Option<Plan<N>>,
        out: &mut impl Outputs<N>,
    ) -> Decided {
        match plan {
            Some(Plan::Execute(set)) => self.execute(set, out),
            Some(Plan::Demonstrate(seqs)) => self.demonstrate(seqs, out),
            None => {}
        }
        if latest.engaged {
            self.abandon(out);
            self.stopped_since_safe = true;
        }
        self.start_limiter(latest);
        let health = self.health(now, latest);
        let state = self.decide_state(latest, &health);
        if self.limiter.is_some() {
            if health.safe && !self.was_safe {
                self.resume(latest);
            }
            let step = self.step_mode(health.safe, now, skipped, latest);
            let setpoint = self.limit(step.target);
            self.measure_lag(now, &setpoint, latest, health.safe);
            self.credit(now, &setpoint, latest);
            self.publish(state, now, setpoint, step, out);
        }
        self.was_safe = health.safe;
        self.end_at_boundary(out);
        Decided { state, health }
    }

    /// Nothing plays and nothing waits.
    pub fn is_idle(&self) -> bool {
        matches!(self.mode, Mode::Idle) && self.queued.is_none()
    }

    /// The actuators' lag as measured so far.
    pub fn lag(&self) -> &ActuatorLag<N> {
        &self.lag
    }

    /// Takes a lag measured elsewhere (a controller that has been running).
    pub fn set_lag(&mut self, lag: ActuatorLag<N>) {
        self.lag = lag;
    }

    /// What `status` says of the mode, the past sets and the lag.
    pub fn report(&self) -> Report {
        let (set_id, execution, reconditions, held) = match &self.mode {
            Mode::Execute(x) => (x.set_id(), x.execution(), x.reconditions(), x.held_solves()),
            _ => (0, 0, 0, 0),
        };
        Report {
            set_id,
            execution,
            reconditions_current: reconditions,
            reconditions_last: self.count.last_reconditions,
            held_solves: self.count.held_solves + held,
            points_unseen: self.count.points_unseen,
            lag_ns: self.lag.lag_s().map_or(u64::MAX, |s| (s * 1e9) as u64),
            lead_ns: self.lag.lead_ns(),
        }
    }

    /// A new set runs at once, or after the running set's execution (replacing a queued one).
    fn execute(&mut self, set: Box<ReadySet<N>>, out: &mut impl Outputs<N>) {
        if let Mode::Execute(_) = self.mode {
            if let Some(old) = self.queued.replace(set) {
                out.retire(Retired::Set(old));
            }
            return;
        }
        if let Mode::Demonstrate(d) = std::mem::replace(&mut self.mode, Mode::Idle) {
            out.retire(Retired::Demo(d.into_sequences()));
        }
        self.mode = Mode::Execute(self.start(set));
    }

    /// A set's executions, to be led by the actuators' lag.
    fn start(&self, set: Box<ReadySet<N>>) -> Execution<N> {
        Execution::new(set, self.timing.rest_ticks, self.lag.max_lead_ticks())
    }

    /// Demonstrations play only from idle.
    fn demonstrate(&mut self, seqs: Box<DemoSequences<N>>, out: &mut impl Outputs<N>) {
        if let Mode::Idle = self.mode {
            self.mode = Mode::Demonstrate(DemoPlayback::new(seqs, self.timing.demo_rest_ticks));
        } else {
            out.retire(Retired::Demo(seqs));
        }
    }

    /// Nothing is published before the arm's state is known: the first setpoint starts there.
    fn start_limiter(&mut self, latest: &Latest<N>) {
        if self.limiter.is_none()
            && let Some((m, _)) = latest.measured
        {
            self.limiter = Some(Limiter::new(
                self.actuator_min,
                self.actuator_max,
                self.slew_per_s,
                self.timing.rate_hz,
                m,
            ));
        }
    }

    fn health(&self, now: u64, latest: &Latest<N>) -> Health {
        let age = |stamp: Option<u64>| stamp.map_or(u64::MAX, |t| now.saturating_sub(t));
        let tracker_age_ns = age(latest.position.map(|p| p.1));
        let motor_age_ns = age(latest.measured.map(|m| m.1));
        let timeout = self.timing.timeout_ns;
        Health {
            tracker_age_ns,
            motor_age_ns,
            safe: !latest.engaged
                && !latest.driver_fault
                && tracker_age_ns <= timeout
                && motor_age_ns <= timeout,
        }
    }

    /// STOPPED on e-stop, HOLD on stale data (or before the arm's state is known), else the
    /// mode's.
    fn decide_state(&self, latest: &Latest<N>, health: &Health) -> ControllerState {
        if latest.engaged {
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
    fn resume(&mut self, latest: &Latest<N>) {
        if std::mem::take(&mut self.stopped_since_safe)
            && let (Some(lim), Some((m, _))) = (self.limiter.as_mut(), latest.measured)
        {
            lim.reset(m);
        }
    }

    /// E-stop: the running and the queued set, or the demonstrations, are dropped, so a reset
    /// never sets the arm moving by itself: the next motion needs a new submit. The execution
    /// under way publishes no statistics (it did not finish).
    fn abandon(&mut self, out: &mut impl Outputs<N>) {
        match std::mem::replace(&mut self.mode, Mode::Idle) {
            Mode::Execute(x) => {
                self.count.held_solves += x.held_solves();
                out.retire(Retired::Set(x.into_set()));
            }
            Mode::Demonstrate(d) => out.retire(Retired::Demo(d.into_sequences())),
            Mode::Idle => {}
        }
        if let Some(set) = self.queued.take() {
            out.retire(Retired::Set(set));
        }
    }

    /// The mode's target for this tick; unsafe, the mode pauses and the setpoint holds.
    fn step_mode(&mut self, safe: bool, now: u64, skipped: u64, latest: &Latest<N>) -> Step<N> {
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
                    &latest.track,
                    self.timing.rest_ticks,
                    self.lag.lead_ticks(),
                    now,
                    skipped,
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

    /// Clamp and slew; `None` holds the last setpoint.
    fn limit(&mut self, target: Option<[f64; N]>) -> [f64; N] {
        let lim = self.limiter.as_mut().expect("only called with a limiter");
        match target {
            Some(t) => lim.apply(&t),
            None => lim.last(),
        }
    }

    /// The setpoint published and the actuators' newest state, for their lag; only while the
    /// arm is safe (held, or stopped, the actuators do not follow the setpoint).
    fn measure_lag(&mut self, now: u64, setpoint: &[f64; N], latest: &Latest<N>, safe: bool) {
        let measured = latest.measured.as_ref().filter(|_| safe);
        self.lag
            .published(now, setpoint, measured.map(|(m, t)| (*t, m)));
    }

    /// What a conditioning point whose time came at this tick credits: the setpoint the
    /// actuators were following (published the set's lead before) and where they were.
    fn credit(&mut self, now: u64, setpoint: &[f64; N], latest: &Latest<N>) {
        if let Mode::Execute(x) = &mut self.mode {
            let followed = self.lag.followed(now, x.lead()).unwrap_or(*setpoint);
            x.published(&followed, latest.measured.as_ref().map(|(m, _)| m));
        }
    }

    /// The setpoint, and the conditioning sample and stats the step produced.
    fn publish(
        &mut self,
        state: ControllerState,
        now: u64,
        setpoint: [f64; N],
        step: Step<N>,
        out: &mut impl Outputs<N>,
    ) {
        self.count.setpoints += 1;
        out.setpoint(Setpoint {
            seq: self.count.setpoints,
            stamp_ns: now,
            actuation: setpoint.into(),
            state: state as u32,
            demo: step.demo.0,
            demo_class: step.demo.1,
            execution: step.execution,
        });
        if let Some(mut s) = step.sample {
            self.count.samples += 1;
            s.seq = self.count.samples;
            out.sample(s);
        }
        if let Some(mut s) = step.finished {
            self.count.last_reconditions = s.reconditions;
            self.count.points_unseen += s.unseen() as u64;
            self.count.stats += 1;
            s.seq = self.count.stats;
            out.stats(s);
        }
    }

    /// Mode changes at boundaries: a finished demonstration run, or a way-point set through (or
    /// giving way to the queued one) between executions.
    fn end_at_boundary(&mut self, out: &mut impl Outputs<N>) {
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
            Mode::Demonstrate(d) => out.retire(Retired::Demo(d.into_sequences())),
            Mode::Execute(x) => {
                self.count.held_solves += x.held_solves();
                out.retire(Retired::Set(x.into_set()))
            }
            Mode::Idle => {}
        }
        if let Some(set) = self.queued.take() {
            self.mode = Mode::Execute(self.start(set));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::execution::tests::ready_set;
    use softarm_config::Config;

    /// The default `[arm]`'s actuators.
    const N: usize = 6;

    /// What the tick sent, as a rehearsal or the outbox would take it.
    #[derive(Default)]
    struct Sent {
        setpoints: Vec<Setpoint>,
        stats: usize,
        retired: usize,
    }

    impl Outputs<N> for Sent {
        fn setpoint(&mut self, s: Setpoint) {
            self.setpoints.push(s);
        }
        fn sample(&mut self, _: ConditioningSample) {}
        fn stats(&mut self, _: ExecutionStats) {
            self.stats += 1;
        }
        fn retire(&mut self, _: Retired<N>) {
            self.retired += 1;
        }
    }

    const PERIOD_NS: u64 = 20_000_000;

    /// A tick `PERIOD_NS` after the last, the drivers' data stamped now if `fresh`.
    fn tick(
        c: &mut Control<N>,
        latest: &mut Latest<N>,
        now: &mut u64,
        fresh: bool,
        out: &mut Sent,
    ) {
        *now += PERIOD_NS;
        if fresh {
            latest.take_motors(*now, [0.5; N]);
            latest.take_tracker(*now, [0.0, 0.0, -0.3]);
        }
        let d = c.tick(*now, 0, latest, None, out);
        assert_eq!(
            d.state as u32,
            out.setpoints.last().map_or(d.state as u32, |s| s.state)
        );
    }

    /// The safety of one tick, without a process: nothing is published before the arm's state
    /// is known; stale data holds the setpoint and pauses the set; the e-stop drops the set,
    /// publishes the frozen setpoint as STOPPED, and a new set waits for a new plan.
    #[test]
    fn stale_data_holds_and_an_estop_drops_the_set_with_the_setpoint_frozen() {
        let config = Controller {
            rate_hz: 50.0,
            ..Config::default_sim(".".into()).controller
        };
        let mut c = Control::new(&config);
        let (mut latest, mut out, mut now) = (Latest::new(false), Sent::default(), 0);
        let d = c.tick(
            PERIOD_NS,
            0,
            &latest,
            Some(Plan::Execute(ready_set())),
            &mut out,
        );
        assert_eq!(d.state, ControllerState::Hold);
        assert!(out.setpoints.is_empty(), "published before a motor_state");

        for _ in 0..60 {
            tick(&mut c, &mut latest, &mut now, true, &mut out);
        }
        let playing = out.setpoints.last().unwrap();
        assert_eq!(playing.state, ControllerState::Execute as u32);
        assert_eq!(playing.execution, 1);

        // No data for longer than the time-out: HOLD, the setpoint where it was, the set paused.
        let stale_ticks = (config.tracker_timeout_ms * 1e6) as u64 / PERIOD_NS + 2;
        for _ in 0..stale_ticks {
            tick(&mut c, &mut latest, &mut now, false, &mut out);
        }
        let s = out.setpoints.last().unwrap();
        assert_eq!(s.state, ControllerState::Hold as u32);
        let hold = |s: &&Setpoint| s.state == ControllerState::Hold as u32;
        let holding = out.setpoints.iter().rev().take_while(hold).count();
        assert!(holding >= 2);
        let held = out.setpoints[out.setpoints.len() - holding - 1].actuation;
        assert!(
            out.setpoints
                .iter()
                .rev()
                .take_while(hold)
                .all(|s| s.actuation == held)
        );
        assert_eq!(c.report().execution, 1, "the set waits, paused");

        // Fresh again, then the e-stop: STOPPED at once, the setpoint frozen, the set dropped.
        tick(&mut c, &mut latest, &mut now, true, &mut out);
        let before = out.setpoints.last().unwrap().actuation;
        latest.engaged = true;
        tick(&mut c, &mut latest, &mut now, true, &mut out);
        let s = out.setpoints.last().unwrap();
        assert_eq!(s.state, ControllerState::Stopped as u32);
        assert_eq!(s.actuation, before, "a jump on the e-stop");
        assert_eq!(out.retired, 1, "the set is handed back to be freed");
        assert!(c.is_idle());
        assert_eq!(out.stats, 0, "an abandoned execution has no statistics");

        // Released: IDLE, holding; nothing runs until a new plan comes.
        latest.engaged = false;
        for _ in 0..10 {
            tick(&mut c, &mut latest, &mut now, true, &mut out);
        }
        assert_eq!(
            out.setpoints.last().unwrap().state,
            ControllerState::Idle as u32
        );
        assert_eq!(c.report().set_id, 0);
    }
}
