//! Executing a way-point set: per execution a rest that slews to v(0), then Eq. 11 tick by tick;
//! at each conditioning point a sample for the learner, at the end of each execution its stats.
//! The tick plays it on the arm, `softarm-rehearsal` on a simulated plant: this is the one
//! place that decides when a point is sampled and which estimate the learner sends next.

use softarm_config::Controller;
use softarm_ipc::{
    ACTUATORS, Actuation, ConditioningSample, ExecutionStats, MAX_WAYPOINTS, Position,
};
use softarm_method::blend::{Blend, ConditioningPoint};
use softarm_method::distance;

/// The rest before each execution, in ticks.
pub fn rest_ticks(c: &Controller) -> i64 {
    (c.rest_s * c.rate_hz).round() as i64
}

/// A conditioning sample as the learner gets it: with the `setpoint` published at the point
/// (the action it credits) and the actuators' newest measured state (NaN if none yet).
pub fn complete_sample(
    mut s: ConditioningSample,
    setpoint: Actuation,
    measured: Option<Actuation>,
) -> ConditioningSample {
    s.actuation = setpoint;
    s.measured = measured.unwrap_or([f64::NAN; ACTUATORS]);
    s
}

/// A way-point set ready to run: its blend and what the tick needs to know. Made by
/// [`Admitted::start`](crate::Admitted::start).
pub struct ReadySet {
    pub(crate) set_id: u64,
    pub(crate) executions: u32,
    /// How many of `points` the set has.
    pub(crate) count: usize,
    pub(crate) points: [ConditioningPoint; MAX_WAYPOINTS],
    pub(crate) blend: Blend<ACTUATORS>,
}

/// Executing a way-point set, `executions` times over.
pub struct Execution {
    set: Box<ReadySet>,
    /// 1-based.
    execution: u32,
    /// Ticks into the execution, the next to play; negative while resting before it.
    k: i64,
    next_point: usize,
    errors: [f64; MAX_WAYPOINTS],
    /// The blend's count of tables swapped in when the current execution's rest began.
    applied_before: u64,
}

/// What one tick of an execution produced.
pub struct ExecutionTick {
    /// Before the limiter.
    pub target: Actuation,
    /// At a conditioning point: the sample for the learner (the caller completes it with the
    /// setpoint it published, [`complete_sample`], and numbers it).
    pub point: Option<ConditioningSample>,
    /// At the end of an execution: its stats (sequence number by the caller).
    pub finished: Option<ExecutionStats>,
}

impl Execution {
    /// The set's first execution, from the start of its rest.
    pub fn new(set: Box<ReadySet>, rest_ticks: i64) -> Self {
        Self {
            execution: 1,
            k: -rest_ticks,
            next_point: 0,
            errors: [0.0; MAX_WAYPOINTS],
            applied_before: set.blend.applied(),
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

    /// Re-conditioned tables swapped in during the current execution (its rest included: what
    /// is swapped in there is in force for it).
    pub fn reconditions(&self) -> u32 {
        u32::try_from(self.set.blend.applied() - self.applied_before).unwrap_or(u32::MAX)
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
    pub(crate) fn into_set(self) -> Box<ReadySet> {
        self.set
    }

    /// One tick. `skipped`: the periods the clock skipped before this tick (overruns). The
    /// execution follows the clock, so it jumps that many ticks ahead (the limiter smooths the
    /// jump) and T_cond stays on wall time; a point whose tick was jumped over is sampled at the
    /// first tick played at or after it, one point per tick, and the execution ends only once
    /// every point was sampled. `reached`: the newest tracker position (`None`: none yet).
    pub fn step(
        &mut self,
        reached: Option<Position>,
        rest_ticks: i64,
        now: u64,
        skipped: u64,
    ) -> ExecutionTick {
        let set = &mut self.set;
        let last = set.blend.timeline().ticks() as i64 - 1;
        self.k = self
            .k
            .saturating_add(i64::try_from(skipped).unwrap_or(i64::MAX))
            .min(last);
        if self.k < 0 {
            self.k += 1;
            return ExecutionTick {
                target: set.blend.rest(),
                point: None,
                finished: None,
            };
        }
        let tick = self.k as usize;
        let target = set.blend.tick(tick);
        let mut point = None;
        if self.next_point < set.count && set.points[self.next_point].tick <= tick {
            let n = self.next_point;
            let reached = reached.unwrap_or([f64::NAN; 3]);
            let desired = set.points[n].position;
            self.errors[n] = distance(&desired, &reached);
            // The estimate wanted next: the following point, or the first of the next execution.
            let (next, next_execution) = if n + 1 < set.count {
                (n + 1, self.execution)
            } else {
                (0, self.execution + 1)
            };
            point = Some(ConditioningSample {
                seq: 0,
                stamp_ns: now,
                set_id: set.set_id,
                execution: self.execution,
                point: n as u32,
                points: set.count as u32,
                _pad: 0,
                actuation: [0.0; ACTUATORS],
                desired,
                reached,
                next_point: next as u32,
                next_execution,
                next_desired: set.points[next].position,
                measured: [f64::NAN; ACTUATORS],
            });
            self.next_point += 1;
        }
        self.k += 1;
        let mut finished = None;
        if self.k > last && self.next_point == set.count {
            let reconditions = self.reconditions();
            let set = &self.set;
            let errs = &self.errors[..set.count];
            finished = Some(ExecutionStats {
                seq: 0,
                stamp_ns: now,
                set_id: set.set_id,
                execution: self.execution,
                executions: set.executions,
                count: set.count as u32,
                reconditions,
                errors_m: self.errors,
                mean_m: errs.iter().sum::<f64>() / errs.len() as f64,
                max_m: errs.iter().cloned().fold(0.0, f64::max),
            });
            self.execution += 1;
            self.k = -rest_ticks;
            self.next_point = 0;
            self.applied_before = set.blend.applied();
        }
        ExecutionTick {
            target,
            point,
            finished,
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use nalgebra::DMatrix;
    use softarm_method::activation::ActivationConfig;
    use softarm_method::blend::{Planner, Replanner, Timeline};
    use softarm_method::promp::{Basis, Demonstration, Primitive, TrainConfig};

    const REST: i64 = 5;
    const REACHED: Position = [0.0, 0.0, -0.3];

    fn primitive(offset: f64) -> Primitive {
        let demos: Vec<Demonstration> = (0..8)
            .map(|i| {
                let times: Vec<f64> = (0..50).map(|s| 4.0 * s as f64 / 49.0).collect();
                let values = DMatrix::from_fn(50, ACTUATORS, |r, d| {
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
    pub(crate) fn planner() -> Planner<ACTUATORS> {
        Planner::<ACTUATORS>::new(
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
    fn ready_set() -> Box<ReadySet> {
        ready_set_and_replanner().0
    }

    fn ready_set_and_replanner() -> (Box<ReadySet>, Replanner<ACTUATORS>) {
        let planner = planner();
        let mut points = [ConditioningPoint::default(); MAX_WAYPOINTS];
        let positions = [[0.1, 0.0, -0.3], [0.0, 0.2, -0.3]];
        for (n, &tick) in planner.conditioning_ticks().iter().enumerate() {
            points[n] = ConditioningPoint {
                position: positions[n],
                tick,
            };
        }
        let (blend, replanner) = planner.start(&[[0.5; ACTUATORS]; 2]).unwrap();
        let set = Box::new(ReadySet {
            set_id: 7,
            executions: 2,
            count: 2,
            points,
            blend,
        });
        (set, replanner)
    }

    #[test]
    fn reconditionings_are_counted_per_execution() {
        let (set, mut replanner) = ready_set_and_replanner();
        let ticks = set.blend.timeline().ticks() as i64;
        let mut x = Execution::new(set, REST);
        let step = |x: &mut Execution| x.step(Some(REACHED), REST, 0, 0).finished;
        for _ in 0..REST + 10 {
            assert!(step(&mut x).is_none());
        }
        // Group 1 is inactive at tick 10: swapped in on the next tick.
        replanner.recondition(1, &[0.6; ACTUATORS]).unwrap();
        step(&mut x);
        assert_eq!(x.reconditions(), 1);
        for _ in 11..ticks - 1 {
            assert!(step(&mut x).is_none());
        }
        let first = step(&mut x).expect("execution 1 ends");
        assert_eq!((first.execution, first.reconditions), (1, 1));
        assert_eq!(x.reconditions(), 0, "execution 2 has applied nothing yet");

        // Group 0's estimate after the end: the rest of execution 2 takes it in, for execution 2.
        replanner.recondition(0, &[0.4; ACTUATORS]).unwrap();
        step(&mut x);
        assert_eq!(x.reconditions(), 1);
        replanner.recondition(1, &[0.7; ACTUATORS]).unwrap();
        let second = (0..10 * ticks).find_map(|_| step(&mut x)).unwrap();
        assert_eq!((second.execution, second.reconditions), (2, 2));
    }

    #[test]
    fn executions_rest_sample_each_point_and_end_with_stats() {
        let set = ready_set();
        let (cond, ticks) = (
            set.points.map(|p| p.tick),
            set.blend.timeline().ticks() as u64,
        );
        let mut x = Execution::new(set, REST);
        assert!(x.at_boundary(REST) && !x.through());
        let (mut samples, mut stats) = (Vec::new(), Vec::new());
        let mut n = 0u64;
        while stats.len() < 2 {
            let t = x.step(Some(REACHED), REST, n, 0);
            assert!(t.target.iter().all(|v| v.is_finite()));
            samples.extend(t.point.map(|s| (n, s)));
            stats.extend(t.finished.map(|s| (n, s)));
            n += 1;
            assert!(n < 10_000, "the executions never end");
        }
        assert!(x.at_boundary(REST) && x.through());

        // Each execution: REST ticks of rest, then the timeline; points at their ticks.
        let per_execution = REST as u64 + ticks;
        let at = |execution: u64, tick: u64| execution * per_execution + REST as u64 + tick;
        let got: Vec<_> = samples
            .iter()
            .map(|(n, s)| (*n, s.execution, s.point, s.next_point, s.next_execution))
            .collect();
        assert_eq!(
            got,
            [
                (at(0, cond[0] as u64), 1, 0, 1, 1),
                (at(0, cond[1] as u64), 1, 1, 0, 2),
                (at(1, cond[0] as u64), 2, 0, 1, 2),
                (at(1, cond[1] as u64), 2, 1, 0, 3),
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
        let mut x = Execution::new(set, REST);
        let jumps = [
            (1, 2),     // in the rest
            (53, 4),    // tick 48 -> 53, over point 0 (tick 50)
            (145, 70),  // tick 140 -> 211, past point 1 (tick 150) and the end (tick 200)
            (262, 119), // execution 2, tick 40 -> 160, over both points
        ];
        let (mut samples, mut stats) = (Vec::new(), Vec::new());
        let (mut clock, mut skipped) = (0u64, 0u64);
        while stats.len() < 2 {
            let t = x.step(Some(REACHED), REST, clock, skipped);
            samples.extend(t.point.map(|s| (clock, s.execution, s.point)));
            stats.extend(t.finished.map(|s| (clock, s.execution)));
            skipped = jumps.iter().find(|j| j.0 == clock).map_or(0, |j| j.1);
            clock += 1 + skipped;
            assert!(clock < 10_000, "the executions never end");
        }
        // The tick played at clock c is c - REST within an execution that began at clock 0,
        // and c - 217 - REST in the second, which began right after the first ended (216).
        assert_eq!(
            samples,
            [(58, 1, 0), (216, 1, 1), (382, 2, 0), (383, 2, 1)],
            "each point at the first tick played at or after its own"
        );
        assert_eq!(stats, [(216, 1), (217 + REST as u64 + 200, 2)]);
    }
}
