//! Executing a way-point set: per execution a rest that slews to v(0), then Eq. 11 tick by tick;
//! at each conditioning point a sample for the learner, at the end of each execution its stats.
//! The tick plays it on the arm, `softarm-rehearsal` on a simulated plant: this is the one
//! place that decides when a point is sampled and which estimate the learner sends next.

use softarm_config::Controller;
use softarm_ipc::{ConditioningSample, ExecutionStats, MAX_WAYPOINTS, Position};
use softarm_method::blend::{Blend, ConditionedOn, ConditioningPoint};
use softarm_method::distance;

/// Tracker samples kept for the reach estimate: 320 ms at 200 Hz.
pub const TRACK_LEN: usize = 64;
/// The end effector's position at a conditioning point is estimated from the tracker samples
/// within this of T_cond (ns) — 11 at 200 Hz — not from one: a line through them averages the
/// tracker's noise down (0.5 mm per axis and sample to about 0.15 mm) while following the arm
/// through the point.
pub const REACH_WINDOW_NS: u64 = 25_000_000;
/// How long a point's sample waits for the tracker to cover the window after T_cond (ns); a
/// late or silent tracker gives what there is by then.
pub const REACH_WAIT_NS: u64 = 100_000_000;

/// The newest tracker samples, (stamp, position), oldest overwritten: what the reach at a
/// conditioning point is estimated from. Fixed size: the tick allocates nothing.
#[derive(Debug, Clone)]
pub struct Track {
    samples: [(u64, Position); TRACK_LEN],
    len: usize,
    /// Where the next sample goes.
    next: usize,
}

impl Default for Track {
    fn default() -> Self {
        Self {
            samples: [(0, [f64::NAN; 3]); TRACK_LEN],
            len: 0,
            next: 0,
        }
    }
}

impl Track {
    /// Takes in a tracker sample; one not newer than the newest (the same sample read again, or
    /// a driver whose clock went back) is left out.
    pub fn push(&mut self, stamp_ns: u64, position: Position) {
        if self.newest().is_some_and(|(t, _)| stamp_ns <= t) {
            return;
        }
        self.samples[self.next] = (stamp_ns, position);
        self.next = (self.next + 1) % TRACK_LEN;
        self.len = (self.len + 1).min(TRACK_LEN);
    }

    pub fn newest(&self) -> Option<(u64, Position)> {
        (self.len > 0).then(|| self.samples[(self.next + TRACK_LEN - 1) % TRACK_LEN])
    }

    /// The position at `t_ns`: per axis, a least-squares line through the samples within
    /// `half_width_ns` of it, evaluated there; the mean of samples that cannot make a line;
    /// `None` without any.
    pub fn position_at(&self, t_ns: u64, half_width_ns: u64) -> Option<Position> {
        let near = || {
            self.samples[..self.len]
                .iter()
                .filter(move |(s, _)| s.abs_diff(t_ns) <= half_width_ns)
                .map(move |(s, p)| ((*s as i128 - t_ns as i128) as f64 * 1e-9, p))
        };
        let n = near().count();
        if n == 0 {
            return None;
        }
        let mean_t = near().map(|(t, _)| t).sum::<f64>() / n as f64;
        let mean_p: Position =
            std::array::from_fn(|d| near().map(|(_, p)| p[d]).sum::<f64>() / n as f64);
        let spread = near().map(|(t, _)| (t - mean_t).powi(2)).sum::<f64>();
        if n < 3 || spread <= 0.0 {
            return Some(mean_p);
        }
        Some(std::array::from_fn(|d| {
            let slope = near()
                .map(|(t, p)| (t - mean_t) * (p[d] - mean_p[d]))
                .sum::<f64>()
                / spread;
            mean_p[d] - slope * mean_t
        }))
    }
}

/// The rest before each execution, in ticks.
pub fn rest_ticks(c: &Controller) -> i64 {
    (c.rest_s * c.rate_hz).round() as i64
}

/// A way-point set ready to run: its blend and what the tick needs to know. Made by
/// [`Admitted::start`](crate::Admitted::start).
pub struct ReadySet<const N: usize> {
    pub(crate) set_id: u64,
    pub(crate) executions: u32,
    /// How many of `points` the set has.
    pub(crate) count: usize,
    pub(crate) points: [ConditioningPoint; MAX_WAYPOINTS],
    pub(crate) blend: Blend<N>,
}

/// Executing a way-point set, `executions` times over.
pub struct Execution<const N: usize> {
    set: Box<ReadySet<N>>,
    /// 1-based.
    execution: u32,
    /// Ticks into the execution, the next to play; negative while resting before it.
    k: i64,
    /// How far ahead of the clock Eq. 11 is evaluated (ticks): the actuators' lag as measured
    /// ([`ActuatorLag`](crate::ActuatorLag)) `max_lead` ticks before the first execution
    /// starts, so the first rest's slew has told it. Fixed for the set: the learner's
    /// per-point state is the set's, and a lead that changed between two executions would
    /// move every point by the lag it had corrected for (measured: the nominal arm's second
    /// execution 2.8 mm against 1.5 with the lead switched on after the first).
    lead: Option<i64>,
    /// The largest lead (ticks): where in the first rest the lead is taken.
    max_lead: i64,
    next_point: usize,
    /// A point whose time has come, waiting for the tracker samples after it.
    pending: Option<Pending<N>>,
    errors: [f64; MAX_WAYPOINTS],
    /// Points of the current execution so far that ran on their estimate for it.
    in_force: u32,
    /// Bit n: point n ran on an estimate corrected within the execution.
    within: u32,
    /// Bit n: point n ran on an estimate for a target beyond the arm's reach.
    beyond_reach: u32,
    /// What each point's group ran on in the current execution, for the first `evaluated`.
    ran_on: [ConditionedOn<N>; MAX_WAYPOINTS],
    evaluated: usize,
}

/// A conditioning point whose time has come.
#[derive(Debug, Clone, Copy)]
struct Pending<const N: usize> {
    point: usize,
    /// T_cond (ns): the time of the tick it came at.
    t_cond: u64,
    /// The setpoint published at that tick (the action the learner credits) and the actuators'
    /// newest measured state then (NaN if none), once [`Execution::published`] said them.
    setpoint: [f64; N],
    measured: [f64; N],
    /// The estimate its group ran on.
    conditioned: [f64; N],
}

/// What one tick of an execution produced.
pub struct ExecutionTick<const N: usize> {
    /// Before the limiter.
    pub target: [f64; N],
    /// A conditioning point's sample for the learner, complete but for its number.
    pub point: Option<ConditioningSample>,
    /// At the end of an execution: its stats (sequence number by the caller).
    pub finished: Option<ExecutionStats>,
}

impl<const N: usize> Execution<N> {
    /// The set's first execution, from the start of its rest; leads of up to `max_lead`
    /// ticks (see [`Execution::step`]).
    pub fn new(set: Box<ReadySet<N>>, rest_ticks: i64, max_lead: i64) -> Self {
        Self {
            execution: 1,
            k: -rest_ticks,
            lead: None,
            max_lead: max_lead.max(0),
            next_point: 0,
            pending: None,
            errors: [0.0; MAX_WAYPOINTS],
            in_force: 0,
            within: 0,
            beyond_reach: 0,
            ran_on: [ConditionedOn::NONE; MAX_WAYPOINTS],
            evaluated: 0,
            set,
        }
    }

    pub fn set_id(&self) -> u64 {
        self.set.set_id
    }

    /// The execution under way (1-based); past the last once the set is through.
    pub fn execution(&self) -> u32 {
        self.execution
    }

    /// Points of the current execution so far whose group ran on the estimate meant for this
    /// execution: it reached the tick before the group's window (the rest included). The
    /// others ran on an older one, the learner's answer too late (a loaded machine).
    pub fn reconditions(&self) -> u32 {
        self.in_force
    }

    /// Group solves of this set that failed and were held at their last good value.
    pub(crate) fn held_solves(&self) -> u64 {
        self.set.blend.held_solves()
    }

    /// Whether it is between executions, where the set may end or give way to the next.
    pub fn at_boundary(&self, rest_ticks: i64) -> bool {
        self.k == -rest_ticks
    }

    /// Whether every execution has run.
    pub fn through(&self) -> bool {
        self.execution > self.set.executions
    }

    /// The set back, to be freed off the tick thread.
    pub(crate) fn into_set(self) -> Box<ReadySet<N>> {
        self.set
    }

    /// One tick. `skipped`: the periods the clock skipped before this tick (overruns). The
    /// execution follows the clock, so it jumps that many ticks ahead (the limiter smooths the
    /// jump) and T_cond stays on wall time; a point's time comes at the first tick played at or
    /// after its own, one point per tick, and its sample goes out once `track` covers
    /// [`REACH_WINDOW_NS`] after that (or [`REACH_WAIT_NS`] passed), with the position
    /// estimated from the samples around it. The execution ends only once every point's
    /// sample went out.
    ///
    /// `lead`: what the actuators' lag asks for now (ticks). The set takes it once, `max_lead`
    /// ticks before its first execution starts, and evaluates Eq. 11 that far ahead of the
    /// clock from then on (its first tick played from the rest's last `lead` ticks, its last
    /// held at the end), so the actuators, following late, are where it says when it says;
    /// the points' times stay on the clock.
    pub fn step(
        &mut self,
        track: &Track,
        rest_ticks: i64,
        lead: i64,
        now: u64,
        skipped: u64,
    ) -> ExecutionTick<N> {
        let last = self.set.blend.timeline().ticks() as i64 - 1;
        self.k = self
            .k
            .saturating_add(i64::try_from(skipped).unwrap_or(i64::MAX))
            .min(last);
        if self.lead.is_none() && self.k >= -self.max_lead {
            self.lead = Some(lead.clamp(0, self.max_lead.min(last)));
        }
        let ahead = (self.k + self.lead.unwrap_or(0)).min(last);
        let target = self.evaluate(ahead);
        if self.k < 0 {
            self.k += 1;
            return ExecutionTick {
                target,
                point: None,
                finished: None,
            };
        }
        let tick = self.k as usize;
        let point = self.sample(track, now);
        let set = &self.set;
        if self.pending.is_none()
            && self.next_point < set.count
            && set.points[self.next_point].tick <= tick
        {
            let on = self.ran_on[self.next_point];
            if on.execution == self.execution {
                self.in_force += 1;
                if on.within {
                    self.within |= 1 << self.next_point;
                }
            }
            // Whichever execution's estimate it ran on: its target is beyond reach all the same.
            if on.beyond_reach {
                self.beyond_reach |= 1 << self.next_point;
            }
            self.pending = Some(Pending {
                point: self.next_point,
                t_cond: now,
                setpoint: [f64::NAN; N],
                measured: [f64::NAN; N],
                conditioned: on.actuation,
            });
            self.next_point += 1;
        }
        self.k += 1;
        let mut finished = None;
        if self.k > last && self.next_point == set.count && self.pending.is_none() {
            finished = Some(self.finish(now, rest_ticks));
        }
        ExecutionTick {
            target,
            point,
            finished,
        }
    }

    /// Eq. 11 at tick `ahead` of the execution (the rest's target before it), noting what the
    /// groups whose points' times it reaches run on.
    fn evaluate(&mut self, ahead: i64) -> [f64; N] {
        let Ok(ahead) = usize::try_from(ahead) else {
            return self.set.blend.rest();
        };
        let target = self.set.blend.tick(ahead);
        // A group's table is swapped only while the group is inactive, and it is active at its
        // own point's time: what is in force then is what its whole window ran on (taken here,
        // where Eq. 11 plays it, since a lead plays it before the point's time on the clock).
        let set = &self.set;
        while self.evaluated < set.count && set.points[self.evaluated].tick <= ahead {
            self.ran_on[self.evaluated] = set.blend.conditioned_on(self.evaluated);
            self.evaluated += 1;
        }
        target
    }

    /// The set's lead (ticks; 0 until taken).
    pub fn lead(&self) -> i64 {
        self.lead.unwrap_or(0)
    }

    /// The setpoint the actuators were following at this tick (after the limiter: the one
    /// published the set's lead before, see [`ActuatorLag::followed`](crate::ActuatorLag)) and
    /// their newest measured state: what a point whose time came at this tick credits.
    pub fn published(&mut self, setpoint: &[f64; N], measured: Option<&[f64; N]>) {
        if let Some(p) = self.pending.as_mut()
            && p.setpoint[0].is_nan()
        {
            p.setpoint = *setpoint;
            p.measured = measured.copied().unwrap_or([f64::NAN; N]);
        }
    }

    /// The pending point's sample, once the tracker has covered the window after it.
    fn sample(&mut self, track: &Track, now: u64) -> Option<ConditioningSample> {
        let Pending {
            point: n,
            t_cond,
            setpoint,
            measured,
            conditioned,
        } = self.pending?;
        let covered = track
            .newest()
            .is_some_and(|(t, _)| t >= t_cond + REACH_WINDOW_NS);
        if !covered && now < t_cond + REACH_WAIT_NS {
            return None;
        }
        self.pending = None;
        let set = &self.set;
        let reached = track
            .position_at(t_cond, REACH_WINDOW_NS)
            .unwrap_or([f64::NAN; 3]);
        let desired = set.points[n].position;
        self.errors[n] = distance(&desired, &reached);
        // The estimate wanted next: the following point, or the first of the next execution.
        let (next, next_execution) = if n + 1 < set.count {
            (n + 1, self.execution)
        } else {
            (0, self.execution + 1)
        };
        Some(ConditioningSample {
            seq: 0,
            stamp_ns: t_cond,
            set_id: set.set_id,
            execution: self.execution,
            point: n as u32,
            points: set.count as u32,
            _pad: 0,
            actuation: setpoint.into(),
            desired,
            reached,
            next_point: next as u32,
            next_execution,
            next_desired: set.points[next].position,
            measured: measured.into(),
            conditioned: conditioned.into(),
        })
    }

    /// The execution's stats; the next begins with its rest.
    fn finish(&mut self, now: u64, rest_ticks: i64) -> ExecutionStats {
        let reconditions = self.reconditions();
        let set = &self.set;
        // A point the tracker did not see (NaN: no sample in its window, a missed window on a
        // loaded machine or a tracker that dropped out) says nothing of the error: the mean and
        // the worst are of the points seen, NaN if none was.
        let seen = self.errors[..set.count].iter().filter(|e| e.is_finite());
        let (sum, n, max) = seen.fold((0.0, 0usize, f64::NAN), |(s, n, m), e| {
            (s + e, n + 1, m.max(*e))
        });
        let stats = ExecutionStats {
            seq: 0,
            stamp_ns: now,
            set_id: set.set_id,
            execution: self.execution,
            executions: set.executions,
            count: set.count as u32,
            reconditions,
            within: self.within,
            beyond_reach: self.beyond_reach,
            errors_m: self.errors,
            mean_m: if n > 0 { sum / n as f64 } else { f64::NAN },
            max_m: max,
        };
        self.execution += 1;
        self.k = -rest_ticks;
        self.next_point = 0;
        self.in_force = 0;
        self.within = 0;
        self.beyond_reach = 0;
        self.evaluated = 0;
        stats
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use nalgebra::DMatrix;
    use softarm_config::activation::ActivationConfig;

    /// The default `[arm]`'s actuators.
    const N: usize = 6;
    use softarm_method::blend::{Planner, Replanner, Timeline};
    use softarm_method::promp::{Basis, Demonstration, Primitive, TrainConfig};

    const REST: i64 = 5;
    const REACHED: Position = [0.0, 0.0, -0.3];
    /// The tick period of [`planner`]'s 50 Hz timeline (ns).
    const PERIOD: u64 = 20_000_000;

    /// One tick played at `clock` (in periods), the tracker at `REACHED` with a sample at the
    /// tick's time, the actuators' lag asking for no lead.
    fn play(x: &mut Execution<N>, track: &mut Track, clock: u64, skipped: u64) -> ExecutionTick<N> {
        let now = clock * PERIOD;
        track.push(now, REACHED);
        let t = x.step(track, REST, 0, now, skipped);
        x.published(&t.target, None);
        t
    }

    fn primitive(offset: f64) -> Primitive {
        let demos: Vec<Demonstration> = (0..8)
            .map(|i| {
                let times: Vec<f64> = (0..50).map(|s| 4.0 * s as f64 / 49.0).collect();
                let values = DMatrix::from_fn(50, N, |r, d| {
                    offset + 0.1 * (times[r] + 0.3 * d as f64 + 0.05 * i as f64).sin()
                });
                Demonstration::new(times, values)
            })
            .collect();
        Primitive::train(
            Basis::new(5, None).unwrap(),
            &demos,
            &TrainConfig::default(),
        )
        .unwrap()
    }

    /// A 4 s plan at 50 Hz through two way-points (at 1 s and 3 s).
    pub(crate) fn planner() -> Planner<N> {
        Planner::<N>::new(
            vec![primitive(0.4), primitive(0.6)],
            &[1.0, 3.0],
            &[0, 1],
            Timeline::new(4.0, 50.0).unwrap(),
            ActivationConfig::default(),
            1e-6,
        )
        .unwrap()
    }

    /// [`planner`]'s set, executed twice.
    pub(crate) fn ready_set() -> Box<ReadySet<N>> {
        ready_set_and_replanner().0
    }

    fn ready_set_and_replanner() -> (Box<ReadySet<N>>, Replanner<N>) {
        let planner = planner();
        let mut points = [ConditioningPoint::default(); MAX_WAYPOINTS];
        let positions = [[0.1, 0.0, -0.3], [0.0, 0.2, -0.3]];
        for (n, &tick) in planner.conditioning_ticks().iter().enumerate() {
            points[n] = ConditioningPoint {
                position: positions[n],
                tick,
            };
        }
        let (blend, replanner) = planner.start(&[[0.5; N]; 2]).unwrap();
        let set = Box::new(ReadySet {
            set_id: 7,
            executions: 2,
            count: 2,
            points,
            blend,
        });
        (set, replanner)
    }

    /// Each point's sample says which estimate its group ran on, and the stats count the
    /// points that ran on the one meant for their execution: an estimate that reaches the tick
    /// once its group is active runs an execution late.
    #[test]
    fn estimates_in_force_are_counted_and_each_sample_says_what_ran() {
        let (set, mut replanner) = ready_set_and_replanner();
        let mut x = Execution::new(set, REST, 0);
        let (mut track, mut clock) = (Track::default(), 0);
        let mut samples = Vec::new();
        let mut step = |x: &mut Execution<N>| {
            clock += 1;
            let t = play(x, &mut track, clock, 0);
            samples.extend(t.point.map(|s| (s.execution, s.point, s.conditioned[0])));
            t.finished
        };
        for _ in 0..REST + 10 {
            assert!(step(&mut x).is_none());
        }
        // Execution 1 runs on the first estimates (for it); group 1 is inactive at tick 10, so
        // an estimate for it then is in time.
        // It was corrected within the execution, and its target is beyond reach, which the
        // stats say of point 1.
        let within = ConditionedOn {
            actuation: [0.6; N],
            execution: 1,
            within: true,
            beyond_reach: true,
        };
        replanner.recondition_on(1, &within).unwrap();
        let first = (0..1000).find_map(|_| step(&mut x)).unwrap();
        assert_eq!((first.execution, first.reconditions), (1, 2));
        assert_eq!((first.within, first.beyond_reach), (0b10, 0b10));
        assert_eq!(x.reconditions(), 0, "nothing of execution 2 has run yet");

        // Execution 2: group 0's estimate comes in the rest, in time; group 1's once group 1
        // is active (tick 100 of 200, between the points), so point 1 runs on execution 1's.
        replanner.recondition(0, &[0.4; N], 2).unwrap();
        for _ in 0..REST + 100 {
            assert!(step(&mut x).is_none());
        }
        replanner.recondition(1, &[0.7; N], 2).unwrap();
        let second = (0..1000).find_map(|_| step(&mut x)).unwrap();
        assert_eq!((second.execution, second.reconditions), (2, 1));
        // Point 1 ran on execution 1's estimate: corrected within that execution, not this;
        // its target beyond reach all the same.
        assert_eq!((second.within, second.beyond_reach), (0, 0b10));
        assert_eq!(
            samples,
            [(1, 0, 0.5), (1, 1, 0.6), (2, 0, 0.4), (2, 1, 0.6)],
            "(execution, point, what its group ran on)"
        );
    }

    #[test]
    fn executions_rest_sample_each_point_and_end_with_stats() {
        let set = ready_set();
        let (cond, ticks) = (
            set.points.map(|p| p.tick),
            set.blend.timeline().ticks() as u64,
        );
        let mut x = Execution::new(set, REST, 0);
        assert!(x.at_boundary(REST) && !x.through());
        let (mut samples, mut stats) = (Vec::new(), Vec::new());
        let (mut n, mut track) = (0u64, Track::default());
        while stats.len() < 2 {
            let t = play(&mut x, &mut track, n, 0);
            assert!(t.target.iter().all(|v| v.is_finite()));
            samples.extend(t.point.map(|s| (n, s)));
            stats.extend(t.finished.map(|s| (n, s)));
            n += 1;
            assert!(n < 10_000, "the executions never end");
        }
        assert!(x.at_boundary(REST) && x.through());

        // Each execution: REST ticks of rest, then the timeline; each point's sample two ticks
        // after its tick, once the tracker covered the 25 ms after it.
        let per_execution = REST as u64 + ticks;
        let at = |execution: u64, tick: u64| execution * per_execution + REST as u64 + tick;
        let sampled = |execution: u64, tick: u64| at(execution, tick) + 2;
        let got: Vec<_> = samples
            .iter()
            .map(|(n, s)| (*n, s.execution, s.point, s.next_point, s.next_execution))
            .collect();
        assert_eq!(
            got,
            [
                (sampled(0, cond[0] as u64), 1, 0, 1, 1),
                (sampled(0, cond[1] as u64), 1, 1, 0, 2),
                (sampled(1, cond[0] as u64), 2, 0, 1, 2),
                (sampled(1, cond[1] as u64), 2, 1, 0, 3),
            ]
        );
        assert!(samples.iter().all(|(_, s)| s.set_id == 7 && s.points == 2));
        assert_eq!(samples[1].1.next_desired, [0.1, 0.0, -0.3]);

        assert_eq!(stats[0].0, at(0, ticks - 1));
        assert_eq!(stats[1].0, at(1, ticks - 1));
        let s = stats[1].1;
        assert_eq!((s.execution, s.executions, s.count), (2, 2, 2));
        assert!((s.errors_m[0] - 0.1).abs() < 1e-12 && (s.errors_m[1] - 0.2).abs() < 1e-12);
        assert!((s.mean_m - 0.15).abs() < 1e-12 && (s.max_m - 0.2).abs() < 1e-12);
    }

    /// The clock skips periods (overruns): the execution follows it. `jumps` are (clock of a
    /// wake, periods skipped before the next wake).
    #[test]
    fn skipped_periods_advance_the_execution_and_no_point_is_lost() {
        let set = ready_set();
        let (cond, ticks) = (
            set.points.map(|p| p.tick),
            set.blend.timeline().ticks() as u64,
        );
        assert_eq!((cond[0], cond[1], ticks), (50, 150, 201));
        let mut x = Execution::new(set, REST, 0);
        let jumps = [
            (1, 2),     // in the rest
            (53, 4),    // tick 48 -> 53, over point 0 (tick 50)
            (145, 70),  // tick 140 -> 211, past point 1 (tick 150) and the end (tick 200)
            (262, 119), // execution 2, tick 38 -> 158, over both points
        ];
        let (mut samples, mut stats) = (Vec::new(), Vec::new());
        let (mut clock, mut skipped, mut track) = (0u64, 0u64, Track::default());
        while stats.len() < 2 {
            let t = play(&mut x, &mut track, clock, skipped);
            samples.extend(t.point.map(|s| (clock, s.execution, s.point)));
            stats.extend(t.finished.map(|s| (clock, s.execution)));
            skipped = jumps.iter().find(|j| j.0 == clock).map_or(0, |j| j.1);
            clock += 1 + skipped;
            assert!(clock < 10_000, "the executions never end");
        }
        // The tick played at clock c is c - REST within an execution that began at clock 0,
        // and c - 219 - REST in the second, which began right after the first ended (218).
        assert_eq!(
            samples,
            [(60, 1, 0), (218, 1, 1), (384, 2, 0), (386, 2, 1)],
            "each point's time at the first tick played at or after its own, one at a time, its \
             sample two ticks later"
        );
        // The first ends once point 1's sample is out (218), at its last tick held meanwhile.
        assert_eq!(stats, [(218, 1), (219 + REST as u64 + 200, 2)]);
    }

    /// A lead plays Eq. 11 that many ticks ahead of the clock, from the rest's last ticks to
    /// the end, and leaves the points' times and samples where they were. The set keeps the
    /// lead it took before its first execution, whatever the lag asks for later.
    #[test]
    fn a_lead_plays_eq_11_ahead_and_leaves_the_points_on_the_clock() {
        const LEAD: i64 = 3;
        let rest = 10;
        let (set, mut reference) = (ready_set(), ready_set());
        let ticks = set.blend.timeline().ticks() as i64;
        let mut led = Execution::new(set, rest, 4);
        let mut plain = Execution::new(ready_set(), rest, 0);
        let (mut track, mut track_plain) = (Track::default(), Track::default());
        let (mut samples, mut samples_plain) = (Vec::new(), Vec::new());
        for clock in 0..rest + ticks {
            // Taken at the rest's fourth tick from its end: what was asked for before and
            // after does not count.
            let asked = match clock - rest {
                ..-4 => 1,
                -4 => LEAD,
                _ => 2,
            };
            let t = x_step(&mut led, &mut track, clock as u64, rest, asked);
            let p = x_step(&mut plain, &mut track_plain, clock as u64, rest, 0);
            let k = clock - rest;
            let want = match k + LEAD {
                ahead if ahead < 0 => reference.blend.rest(),
                ahead => reference.blend.tick(ahead.min(ticks - 1) as usize),
            };
            assert_eq!(t.target, want, "clock {clock}: Eq. 11 at tick {}", k + LEAD);
            samples.extend(t.point.map(|s| (clock, s.point, s.stamp_ns)));
            samples_plain.extend(p.point.map(|s| (clock, s.point, s.stamp_ns)));
        }
        assert_eq!(samples.len(), 2);
        assert_eq!(samples, samples_plain, "the points sampled when they were");
    }

    fn x_step(
        x: &mut Execution<N>,
        track: &mut Track,
        clock: u64,
        rest: i64,
        lead: i64,
    ) -> ExecutionTick<N> {
        let now = clock * PERIOD;
        track.push(now, REACHED);
        let t = x.step(track, rest, lead, now, 0);
        x.published(&t.target, None);
        t
    }

    #[test]
    fn the_reach_at_a_point_is_a_line_through_the_samples_around_it() {
        let mut track = Track::default();
        assert_eq!(track.position_at(0, REACH_WINDOW_NS), None);
        // Moving at 0.2 m/s along x through [0.1, 0, -0.4] at t = 1 s, each sample 0.5 mm off
        // in turn either way, every 5 ms.
        let t0 = 1_000_000_000u64;
        for k in 0..40u64 {
            let t = t0 - 100_000_000 + k * 5_000_000;
            let dt = (t as f64 - t0 as f64) * 1e-9;
            let noise = if k % 2 == 0 { 0.0005 } else { -0.0005 };
            track.push(t, [0.1 + 0.2 * dt, noise, -0.4 - noise]);
        }
        // An old stamp again is not taken.
        track.push(t0, [9.0; 3]);
        let p = track.position_at(t0, REACH_WINDOW_NS).unwrap();
        let err = distance(&p, &[0.1, 0.0, -0.4]);
        assert!(err < 0.0001, "{p:?}: {err} m off, one sample is 0.7 mm off");
        // Only one sample in reach: that one.
        let mut one = Track::default();
        one.push(t0, [0.1, 0.0, -0.4]);
        assert_eq!(
            one.position_at(t0 + 1, REACH_WINDOW_NS),
            Some([0.1, 0.0, -0.4])
        );
    }

    #[test]
    fn a_silent_tracker_leaves_no_point_waiting() {
        let set = ready_set();
        let cond = set.points[0].tick as u64;
        let mut x = Execution::new(set, REST, 0);
        let mut track = Track::default();
        // The tracker's last sample comes before point 0; then it falls silent.
        let mut got = None;
        for clock in 0..REST as u64 + cond + 20 {
            if clock < REST as u64 + cond - 10 {
                track.push(clock * PERIOD, REACHED);
            }
            let t = x.step(&track, REST, 0, clock * PERIOD, 0);
            x.published(&t.target, None);
            got = got.or(t.point.map(|s| (clock, s)));
        }
        let (clock, s) = got.expect("the point's sample went out");
        // After REACH_WAIT_NS (5 ticks), with no position to learn from.
        assert_eq!(clock, REST as u64 + cond + 5);
        assert!(s.reached.iter().all(|v| v.is_nan()));
        assert!(
            s.actuation.iter().all(|v| v.is_finite()),
            "the setpoint it credits"
        );
    }

    #[test]
    fn a_point_the_tracker_did_not_see_is_left_out_of_the_mean_and_the_worst() {
        let set = ready_set();
        let (cond, desired) = (set.points[0].tick as u64, set.points[1].position);
        let ticks = set.blend.timeline().ticks() as u64;
        let mut x = Execution::new(set, REST, 0);
        let mut track = Track::default();
        let mut stats = None;
        // Silent from before point 0 to after its wait; back for point 1.
        let silent = REST as u64 + cond - 10..REST as u64 + cond + 6;
        for clock in 0..2 * (REST as u64 + ticks) {
            if !silent.contains(&clock) {
                track.push(clock * PERIOD, REACHED);
            }
            let t = x.step(&track, REST, 0, clock * PERIOD, 0);
            x.published(&t.target, None);
            stats = stats.or(t.finished);
        }
        let s = stats.expect("the execution finished");
        assert!(s.errors_m[0].is_nan(), "{:?}", s.errors_m);
        let seen = distance(&desired, &REACHED);
        assert!((s.errors_m[1] - seen).abs() < 1e-12);
        assert!(
            (s.mean_m - seen).abs() < 1e-12 && (s.max_m - seen).abs() < 1e-12,
            "{s:?}"
        );
    }
}
