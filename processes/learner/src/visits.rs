//! The learner's side of Alg. 2, without I/O: a set's request answered with the first estimate
//! of every point, each conditioning point's visit learnt from and answered with the estimate
//! the controller asked for next. The learner process runs it between its subscribers and its
//! publisher, `softarm-rehearsal` in one process with the controller's execution.

use softarm_config::Config;
use softarm_ipc::{
    ActuationEstimate, ConditioningSample, EstimateRequest, MAX_WAYPOINTS, Position,
};
use softarm_learning::arm::Seen;
use softarm_learning::online::{OnlineLearner, Reach};
use softarm_learning::within::Within;
use softarm_space::Workspace;

/// How far outside the way-point workspace an arm's position is still believed (m). Farther, a
/// `reached` is a tracker glitch or a broken peer's: learning from it would wreck the learner
/// (its Jacobians, corrections and critic scale with the error), and the checkpoint with it.
const REACH_MARGIN_M: f64 = 0.25;

/// An arm judged this long or longer after its actuators stopped (s) is said to be so, once.
const SETTLING_SAID_S: f64 = 0.1;

/// An [`OnlineLearner<N>`] at the conditioning points of the sets the controller runs. What does
/// not fit is refused, counted and logged, naming what was wrong; nothing else changes then.
pub struct Learner<const N: usize> {
    online: OnlineLearner<N>,
    /// Where a reached position may be: the way-point workspace grown by [`REACH_MARGIN_M`].
    reach: Workspace,
    /// The set learnt on; 0 for none.
    set_id: u64,
    /// The set, execution and point last learnt from.
    last_visit: Option<(u64, u32, u32)>,
    refused: u64,
    /// Arm changes seen since the start.
    arm_changes: u64,
    /// The calibrated arm last logged: the samples its fit was tried on.
    calibrated_logged: usize,
    /// `controller.rest_s`, and how long the arm must stand still to be judged as last logged.
    rest_s: f64,
    judged_after_logged: f64,
}

impl<const N: usize> Learner<N> {
    /// `online` at the points of sets checked against `config`'s way-point workspace.
    pub fn new(online: OnlineLearner<N>, config: &Config) -> Self {
        let w = config.waypoints.workspace();
        Self {
            online,
            reach: Workspace {
                min_m: w.min_m.map(|v| v - REACH_MARGIN_M),
                max_m: w.max_m.map(|v| v + REACH_MARGIN_M),
            },
            set_id: 0,
            last_visit: None,
            refused: 0,
            calibrated_logged: 0,
            arm_changes: 0,
            rest_s: config.controller.rest_s,
            judged_after_logged: 0.0,
        }
    }

    /// Arm changes seen since the start.
    pub fn arm_changes(&self) -> u64 {
        self.arm_changes
    }

    /// One sample of the arm (the actuators' measured state and the tracked position, at
    /// `stamp_ns`). When it shows that the arm has changed, what was learnt of the old one is
    /// forgotten, and the running set's points get new first estimates, which go back.
    pub fn observe_arm(
        &mut self,
        stamp_ns: u64,
        measured: &[f64; N],
        position: &Position,
    ) -> Vec<ActuationEstimate> {
        let seen = self.online.observe_arm(stamp_ns, measured, position);
        self.say_settling();
        let off = match seen {
            Seen::Changed(off) => off,
            Seen::Different(off) => {
                tracing::debug!(off_mm = off * 1e3, "the arm is not where it was");
                return Vec::new();
            }
            _ => return Vec::new(),
        };
        self.arm_changes += 1;
        let estimates = self.online.first_estimates();
        tracing::info!(
            off_mm = off * 1e3,
            arm_changes = self.arm_changes,
            set_id = self.set_id,
            estimates = estimates.len(),
            "the arm has changed: what was learnt of it is forgotten, the set starts over"
        );
        estimates
            .into_iter()
            .map(|(point, a)| {
                let point = point as u32;
                estimate(self.set_id, point, self.next_execution(point), a, false)
            })
            .collect()
    }

    /// Says how long a physical arm goes on moving after its actuators stop, when first seen
    /// and when it grew by half: an operator whose arm never rests that long between
    /// executions learns why the learner neither checks it for changes nor calibrates it.
    fn say_settling(&mut self) {
        let Some(after) = self.online.judged_after_s() else {
            return;
        };
        if after < SETTLING_SAID_S || after <= 1.5 * self.judged_after_logged {
            return;
        }
        self.judged_after_logged = after;
        if after < self.rest_s {
            tracing::info!(
                judged_after_s = after,
                "the arm goes on moving after its actuators stop: it is judged only once they \
                 stood still this long"
            );
        } else {
            tracing::warn!(
                judged_after_s = after,
                rest_s = self.rest_s,
                "the arm goes on moving after its actuators stop for longer than it rests \
                 between executions (controller.rest_s): between them it is neither checked \
                 for changes nor calibrated on where it stands; a longer rest_s lets it settle"
            );
        }
    }

    pub fn online(&self) -> &OnlineLearner<N> {
        &self.online
    }

    /// The set learnt on; 0 before the first.
    pub fn set_id(&self) -> u64 {
        self.set_id
    }

    /// Requests and samples refused.
    pub fn refused(&self) -> u64 {
        self.refused
    }

    /// A set was accepted: its points' histories start over, and the first estimate of every
    /// point (its first execution runs without exploration) goes back. None if refused. The
    /// estimates' `seq` and `stamp_ns` are the sender's.
    pub fn request(&mut self, r: &EstimateRequest) -> Vec<ActuationEstimate> {
        // Checked before the running set's memory is given up for it.
        let first = check_request(r)
            .and_then(|()| self.online.start_set(r.points()).map_err(|e| e.to_string()));
        let first = match first {
            Ok(first) => first,
            Err(why) => {
                self.refused += 1;
                tracing::warn!(
                    set_id = r.set_id,
                    refused = self.refused,
                    "request refused: {why}"
                );
                return Vec::new();
            }
        };
        self.set_id = r.set_id;
        for point in (0..first.len()).filter(|n| self.online.reach(*n).beyond()) {
            tracing::warn!(
                set_id = r.set_id,
                point,
                "the point's target is beyond the arm's reach as calibrated (its nearest place \
                 is more than 5 mm away): the learner brings it to the nearest place the arm \
                 reaches and holds it there, and what it misses by is not taken for a change \
                 of the arm"
            );
        }
        let (actor, critic) = self.online.cacla().stored_centres();
        let (actor_evicted, critic_evicted) = self.online.cacla().evicted_centres();
        tracing::info!(
            set_id = r.set_id,
            points = first.len(),
            actor,
            critic,
            actor_evicted,
            critic_evicted,
            "first estimates sent (lattice weights stored and evicted)"
        );
        first
            .into_iter()
            .enumerate()
            .map(|(point, a)| estimate(r.set_id, point as u32, 1, a, false))
            .collect()
    }

    /// One visit of a conditioning point: learnt from, and answered with the estimate the
    /// sample asks for next (`next_point` of `next_execution`, as the controller's execution
    /// decided). `None` if the sample is refused. The estimate's `seq` and `stamp_ns` are the
    /// sender's.
    pub fn visit(&mut self, s: &ConditioningSample) -> Option<ActuationEstimate> {
        let mut s = *s;
        if let Err(why) = check::<N>(&s).and_then(|()| check_order(&s, self.last_visit)) {
            self.refuse(&s, &why);
            return None;
        }
        if s.reached.iter().all(|v| v.is_finite()) && !self.reach.contains(&s.reached) {
            // Not learnt from; the estimate asked for is still due.
            let why = format!(
                "reached {:?} is outside where the arm can be (the way-point workspace and \
                 {REACH_MARGIN_M} m around it): not learnt from",
                s.reached
            );
            self.refuse(&s, &why);
            s.reached = [f64::NAN; 3];
        }
        // A set whose request this learner did not see (it restarted): its targets are learnt
        // from the samples.
        if s.set_id != self.set_id && self.online.begin(s.points as usize).is_ok() {
            self.set_id = s.set_id;
        }
        let reach = self.online.reach(s.point as usize);
        let result = observe_and_estimate(&mut self.online, &s);
        self.say_calibrated();
        say_reach(&s, reach, self.online.reach(s.point as usize));
        match result {
            Ok(next) => {
                tracing::debug!(point = s.next_point, estimate = ?next, "estimate");
                self.last_visit = Some((s.set_id, s.execution, s.point));
                let within = self.online.within(s.next_point as usize);
                say_within(&s, within);
                let mut e = estimate(
                    s.set_id,
                    s.next_point,
                    s.next_execution,
                    next,
                    within.corrected(),
                );
                e.beyond_reach = self.online.reach(s.next_point as usize).beyond().into();
                e.answers_ns = s.stamp_ns;
                Some(e)
            }
            Err(why) => {
                self.refuse(&s, &why);
                None
            }
        }
    }

    /// Logs the calibrated arm once per fit: what the learner now believes of the arm.
    fn say_calibrated(&mut self) {
        let c = self.online.calibrated();
        if c.tried == self.calibrated_logged {
            return;
        }
        self.calibrated_logged = c.tried;
        if c.samples == 0 && c.tried > 0 {
            tracing::info!(
                samples = c.tried,
                configured_rms_mm = c.rms_m * 1e3,
                "the arm not calibrated: no fit explains enough of it, the configured arm stays"
            );
            return;
        }
        tracing::info!(
            samples = c.samples,
            rms_mm = c.rms_m * 1e3,
            tool_mm = ?c.theta[..3].iter().map(|v| v * 1e3).collect::<Vec<_>>(),
            rotations_deg = ?c.rotations_deg(),
            "the arm calibrated (tool offset in the tip frame)"
        );
    }

    /// The execution of the running set whose `point` is visited next: the one last visited if
    /// the point comes after the last visit's, else the one after.
    fn next_execution(&self, point: u32) -> u32 {
        match self.last_visit {
            Some((set_id, execution, last)) if set_id == self.set_id => {
                if point > last {
                    execution
                } else {
                    execution + 1
                }
            }
            _ => 1,
        }
    }

    /// Counts and logs a refused sample, naming what was wrong.
    fn refuse(&mut self, s: &ConditioningSample, why: &dyn std::fmt::Display) {
        self.refused += 1;
        tracing::warn!(
            set_id = s.set_id,
            point = s.point,
            refused = self.refused,
            "sample refused: {why}"
        );
    }
}

/// `point`'s estimate for `execution` of set `set_id`; `within`: corrected within it.
fn estimate<const N: usize>(
    set_id: u64,
    point: u32,
    execution: u32,
    actuation: [f64; N],
    within: bool,
) -> ActuationEstimate {
    ActuationEstimate {
        seq: 0,
        stamp_ns: 0,
        set_id,
        point,
        execution,
        actuation: actuation.into(),
        within: within.into(),
        beyond_reach: 0,
        answers_ns: 0,
    }
}

/// Says how a visit `s` changed where its point stands with its reach (`was`, `now`).
fn say_reach(s: &ConditioningSample, was: Reach, now: Reach) {
    let (set_id, point) = (s.set_id, s.point);
    match (was, now) {
        (Reach::Held { .. }, Reach::Held { .. }) => {}
        (_, Reach::Held { error_m }) => tracing::warn!(
            set_id,
            point,
            error_mm = error_m * 1e3,
            "the point is beyond the arm's reach: held at the nearest place its tries found, \
             as further steps did not bring it closer"
        ),
        (Reach::Held { .. }, _) => tracing::warn!(
            set_id,
            point,
            "the point held beyond reach is missed by more than it was held at: the arm moved \
             there, stepping toward it again"
        ),
        (Reach::Beyond, Reach::Reachable) => tracing::info!(
            set_id,
            point,
            "the point is within the arm's reach after all: its tries came within 5 mm"
        ),
        _ => {}
    }
}

/// Says how the estimate `s` asks for was corrected within its execution, and why not: a
/// correction shortened to the trust region is worth an operator's eye, the rest a debug line.
/// (One that comes too late for its point's group runs an execution later: `stats`' `late`.)
fn say_within(s: &ConditioningSample, within: Within) {
    let (set_id, point, execution) = (s.set_id, s.next_point, s.next_execution);
    match within {
        Within::NotAsked => {}
        Within::NoEvidence => tracing::debug!(
            set_id,
            point,
            execution,
            "not corrected within the execution: the points before it missed by no more than \
             they scatter"
        ),
        Within::Unfit { rms_m } => tracing::debug!(
            set_id,
            point,
            execution,
            calibrated_rms_mm = rms_m * 1e3,
            "not corrected within the execution: the calibrated arm misses where the arm went by \
             more than the tracker's noise (learner.gauss_newton.noise_m), no model to share by"
        ),
        Within::Unhelpful { shift_m } => tracing::debug!(
            set_id,
            point,
            execution,
            shift_mm = shift_m * 1e3,
            "not corrected within the execution: the arm as the points before it showed it \
             cannot make up for its shift here within the trust region"
        ),
        Within::Corrected {
            shift_m,
            capped: false,
        } => tracing::debug!(
            set_id,
            point,
            execution,
            shift_mm = shift_m * 1e3,
            "corrected within the execution by what the points before it showed"
        ),
        Within::Corrected {
            shift_m,
            capped: true,
        } => tracing::info!(
            set_id,
            point,
            execution,
            shift_mm = shift_m * 1e3,
            "corrected within the execution, shortened to the trust region \
             (learner.gauss_newton.trust_max): the arm moved further than one step makes up for"
        ),
    }
}

/// A sample the learner can use: a set (ids start at 1), points in range (the memory grows to
/// the point's index), executions counted from 1 and not going back, and finite positions and
/// actuation. The reason names the field.
fn check<const N: usize>(s: &ConditioningSample) -> Result<(), String> {
    if s.set_id == 0 {
        return Err("set_id 0 is no set".into());
    }
    let points = s.points as usize;
    if points == 0 || points > MAX_WAYPOINTS {
        return Err(format!(
            "points {} is out of range (1 to {MAX_WAYPOINTS})",
            s.points
        ));
    }
    for (name, index) in [("point", s.point), ("next_point", s.next_point)] {
        if index >= s.points {
            return Err(format!(
                "{name} {index} is out of range (the set has {} points)",
                s.points
            ));
        }
    }
    if s.execution == 0 {
        return Err("execution 0: executions count from 1".into());
    }
    if s.next_execution < s.execution {
        return Err(format!(
            "next_execution {} is before execution {}",
            s.next_execution, s.execution
        ));
    }
    for (name, v) in [
        ("actuation", &s.actuation),
        ("measured", &s.measured),
        ("conditioned", &s.conditioned),
    ] {
        if v.len() != N {
            return Err(format!("{name} has {} actuators; the arm has {N}", v.len()));
        }
    }
    for (name, v) in [
        ("desired", &s.desired[..]),
        ("next_desired", &s.next_desired[..]),
        ("actuation", &s.actuation[..]),
    ] {
        if !v.iter().all(|x| x.is_finite()) {
            return Err(format!("{name} {v:?} is not finite"));
        }
    }
    // All NaN is "not known"; a part of it is a broken peer.
    let known = s.conditioned.iter().filter(|x| x.is_finite()).count();
    if known != 0 && known != s.conditioned.len() {
        return Err(format!(
            "conditioned {:?} is neither finite nor unknown (all NaN)",
            s.conditioned
        ));
    }
    Ok(())
}

/// A sample of the set last visited must come after that visit: the controller plays each set's
/// executions and points in order, so one that does not (a repeat, or counters gone back) is
/// stale or a confused peer's, and is not learnt from.
fn check_order(s: &ConditioningSample, last: Option<(u64, u32, u32)>) -> Result<(), String> {
    match last {
        Some((set_id, execution, point))
            if set_id == s.set_id && (s.execution, s.point) <= (execution, point) =>
        {
            Err(format!(
                "execution {} point {} does not follow the last visit of the set (execution \
                 {execution} point {point}): repeated or out of order",
                s.execution, s.point
            ))
        }
        _ => Ok(()),
    }
}

/// A request the learner can plan with: a set, 1 to `MAX_WAYPOINTS` points, finite targets.
/// The reason names the field.
fn check_request(r: &EstimateRequest) -> Result<(), String> {
    if r.set_id == 0 {
        return Err("set_id 0 is no set".into());
    }
    if r.count == 0 || r.count as usize > MAX_WAYPOINTS {
        return Err(format!(
            "count {} is out of range (1 to {MAX_WAYPOINTS})",
            r.count
        ));
    }
    if let Some(i) = r
        .points()
        .iter()
        .position(|p| !p.iter().all(|v| v.is_finite()))
    {
        return Err(format!("desired[{i}] {:?} is not finite", r.desired[i]));
    }
    Ok(())
}

/// One visit and the estimate asked for next; without a tracker position at the point there is
/// nothing to learn, but the estimate is still due. A sample that does not fit the running set
/// (point, target) changes nothing.
fn observe_and_estimate<const N: usize>(
    learner: &mut OnlineLearner<N>,
    s: &ConditioningSample,
) -> Result<[f64; N], String> {
    if learner.points() != s.points as usize {
        return Err(format!(
            "the set has {} points, the sample says {}",
            learner.points(),
            s.points
        ));
    }
    // `check` counted them: this arm's actuators.
    let arm = |a: &softarm_ipc::Actuators| a.fixed::<N>().expect("checked");
    let (actuation, conditioned) = (arm(&s.actuation), arm(&s.conditioned));
    // NaN: the controller did not say (`check` refuses a half-known one).
    let conditioned = conditioned[0].is_finite().then_some(&conditioned);
    if s.reached.iter().all(|v| v.is_finite()) {
        let v = learner
            .observe(
                s.point as usize,
                &s.desired,
                &actuation,
                conditioned,
                &s.reached,
            )
            .map_err(|e| e.to_string())?;
        tracing::debug!(
            point = s.point,
            execution = s.execution,
            error_mm = v.error * 1e3,
            td = ?v.td_error,
            action = ?s.actuation,
            conditioned = ?s.conditioned,
            measured = ?s.measured,
            "visit"
        );
    } else {
        tracing::warn!(
            point = s.point,
            "no tracker position at the point: visit skipped"
        );
    }
    // The set's first execution runs without exploration (its estimates are `request`'s); the
    // controller's execution says which execution the estimate is for.
    let explore = s.next_execution >= 2;
    learner
        .estimate(s.next_point as usize, &s.next_desired, explore)
        .map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default `[arm]`'s actuators.
    const N: usize = 6;

    fn sample() -> ConditioningSample {
        ConditioningSample {
            set_id: 1,
            points: 3,
            point: 2,
            next_point: 0,
            execution: 1,
            next_execution: 2,
            actuation: [0.5; N].into(),
            measured: [f64::NAN; N].into(),
            conditioned: [0.5; N].into(),
            ..Default::default()
        }
    }

    #[test]
    fn malformed_samples_are_refused_with_a_reason() {
        assert_eq!(check::<N>(&sample()), Ok(()));
        let bad = [
            ConditioningSample {
                points: 0,
                ..sample()
            },
            ConditioningSample {
                points: MAX_WAYPOINTS as u32 + 1,
                ..sample()
            },
            ConditioningSample {
                point: 3,
                ..sample()
            },
            ConditioningSample {
                next_point: u32::MAX,
                ..sample()
            },
            ConditioningSample {
                desired: [f64::NAN, 0.0, 0.0],
                ..sample()
            },
            ConditioningSample {
                actuation: [f64::INFINITY; 6].into(),
                ..sample()
            },
            ConditioningSample {
                set_id: 0,
                ..sample()
            },
            ConditioningSample {
                execution: 0,
                ..sample()
            },
            ConditioningSample {
                next_execution: 0,
                ..sample()
            },
            ConditioningSample {
                conditioned: [0.5, f64::NAN, 0.5, 0.5, 0.5, 0.5].into(),
                ..sample()
            },
            // Another arm's actuators, or none.
            ConditioningSample {
                measured: [f64::NAN; 9].into(),
                ..sample()
            },
            ConditioningSample {
                actuation: Default::default(),
                ..sample()
            },
        ];
        // Not known (all NaN) is fine.
        assert_eq!(
            check::<N>(&ConditioningSample {
                conditioned: [f64::NAN; 6].into(),
                ..sample()
            }),
            Ok(())
        );
        for s in bad {
            assert!(check::<N>(&s).is_err(), "{s:?}");
        }
        // The field is named.
        let why = |s| check::<N>(&s).unwrap_err();
        assert!(
            why(ConditioningSample {
                point: 7,
                ..sample()
            })
            .starts_with("point 7 ")
        );
        assert!(
            why(ConditioningSample {
                next_point: 9,
                ..sample()
            })
            .starts_with("next_point 9")
        );
        assert!(
            why(ConditioningSample {
                next_desired: [f64::NAN; 3],
                ..sample()
            })
            .starts_with("next_desired")
        );
    }

    #[test]
    fn a_visit_that_does_not_follow_the_last_of_its_set_is_refused() {
        let s = sample();
        assert_eq!(check_order(&s, None), Ok(()));
        // The same visit again, and an earlier one: refused.
        assert!(check_order(&s, Some((1, 1, 2))).is_err());
        assert!(check_order(&s, Some((1, 2, 0))).is_err());
        // A later one, or one of another set: fine.
        assert_eq!(check_order(&s, Some((1, 1, 1))), Ok(()));
        assert_eq!(check_order(&s, Some((2, 5, 2))), Ok(()));
    }

    #[test]
    fn malformed_requests_are_refused_naming_the_field() {
        let good = EstimateRequest {
            set_id: 4,
            count: 2,
            ..Default::default()
        };
        assert_eq!(check_request(&good), Ok(()));
        let mut nan = good;
        nan.desired[1][2] = f64::NAN;
        for (r, want) in [
            (EstimateRequest { set_id: 0, ..good }, "set_id 0"),
            (EstimateRequest { count: 0, ..good }, "count 0"),
            (EstimateRequest { count: 17, ..good }, "count 17"),
            (nan, "desired[1]"),
        ] {
            let why = check_request(&r).unwrap_err();
            assert!(why.starts_with(want), "{why}");
        }
    }

    #[test]
    fn a_set_is_answered_with_its_first_estimates_and_each_visit_with_the_next_asked_for() {
        let config = Config::default_sim(".".into());
        let mut l = Learner::new(fuzz::learner(), &config);
        let (p0, p1) = ([0.165, 0.0, -0.471], [0.031, 0.0, -0.501]);
        let mut desired = [[0.0; 3]; MAX_WAYPOINTS];
        desired[..2].copy_from_slice(&[p0, p1]);
        let request = EstimateRequest {
            set_id: 5,
            count: 2,
            desired,
            ..Default::default()
        };
        let first = l.request(&request);
        let named: Vec<_> = first
            .iter()
            .map(|e| (e.set_id, e.point, e.execution))
            .collect();
        assert_eq!(named, [(5, 0, 1), (5, 1, 1)], "(set, point, execution)");
        assert_eq!(l.set_id(), 5);

        // The last point of execution 1: the answer is what the sample asks for next.
        let visit = ConditioningSample {
            set_id: 5,
            points: 2,
            point: 1,
            next_point: 0,
            execution: 1,
            next_execution: 2,
            actuation: first[1].actuation,
            desired: p1,
            reached: [p1[0] + 0.01, p1[1], p1[2]],
            next_desired: p0,
            measured: first[1].actuation,
            conditioned: first[1].actuation,
            ..Default::default()
        };
        let next = l.visit(&visit).expect("a good visit is answered");
        assert_eq!((next.set_id, next.point, next.execution), (5, 0, 2));
        // New first estimates (a changed arm) are for each point's next visit: execution 2.
        assert_eq!((l.next_execution(0), l.next_execution(1)), (2, 2));
        assert!(next.actuation.iter().all(|a| (0.0..=1.0).contains(a)));

        // The same visit again, and a request that is no set: refused, counted, nothing changes.
        assert!(l.visit(&visit).is_none());
        assert!(l.request(&EstimateRequest::default()).is_empty());
        assert_eq!((l.refused(), l.set_id()), (2, 5));
    }

    mod fuzz {
        //! Arbitrary samples on `cp_sample`, as a broken or hostile peer could send them: the
        //! learner refuses what does not fit with a reason and never panics, and what it
        //! answers is a finite actuation in [0, 1].
        use super::*;
        use proptest::prelude::*;
        use softarm_config::arm::ArmConfig;
        use softarm_config::kinematics::PolynomialConfig;
        use softarm_config::learner::LearnerConfig;
        use softarm_kinematics::forward::ForwardModel;
        use softarm_kinematics::pcc;
        use softarm_kinematics::poly::Polynomial;
        use softarm_learning::cacla::CaclaMtl;

        pub(super) fn learner() -> OnlineLearner<N> {
            let arm = pcc::Arm::of_config(&ArmConfig::default()).unwrap();
            let a: Vec<[f64; N]> = (0..400)
                .map(|i| {
                    std::array::from_fn(|j| 0.2 + 0.6 * (((i * 7 + j * 13) % 37) as f64 / 36.0))
                })
                .collect();
            let p: Vec<_> = a.iter().map(|a| arm.position(a)).collect();
            let poly = Polynomial::fit(&a, &p, &PolynomialConfig::default()).unwrap();
            OnlineLearner::new(CaclaMtl::new(LearnerConfig::default()).unwrap(), poly, arm)
        }

        fn value() -> impl Strategy<Value = f64> {
            prop_oneof![
                -1.0f64..1.0,
                Just(f64::NAN),
                Just(f64::INFINITY),
                Just(f64::NEG_INFINITY),
                Just(1e300),
                Just(-0.0),
            ]
        }

        fn sample() -> impl Strategy<Value = ConditioningSample> {
            (
                (0u32..20, 0u32..20, 0u32..20, 0u32..4),
                prop::array::uniform6(value()),
                prop::array::uniform3(value()),
                prop::array::uniform3(value()),
                prop::array::uniform6(value()),
                prop::array::uniform6(value()),
                0u64..3,
            )
                .prop_map(
                    |((points, point, next_point, exec), a, d, r, m, c, set_id)| {
                        ConditioningSample {
                            set_id,
                            points,
                            point,
                            next_point,
                            execution: exec,
                            next_execution: exec + 1,
                            actuation: a.into(),
                            desired: d,
                            reached: r,
                            next_desired: d,
                            measured: m.into(),
                            conditioned: c.into(),
                            ..Default::default()
                        }
                    },
                )
        }

        proptest! {
            // Each case fits a polynomial and replays up to 40 samples: a failure shrinks in
            // a bounded number of steps, so it is reported within CI's time bound, not killed.
            #![proptest_config(ProptestConfig {
                max_shrink_iters: 400,
                ..ProptestConfig::with_cases(
                    std::env::var("PROPTEST_CASES")
                        .ok()
                        .and_then(|v| v.parse().ok())
                        .unwrap_or(256),
                )
            })]

            #[test]
            fn arbitrary_samples_never_panic_and_answers_are_actuations(
                samples in prop::collection::vec(sample(), 1..40),
            ) {
                let mut l = learner();
                for s in samples {
                    if check::<N>(&s).is_err() {
                        continue;
                    }
                    if l.points() != s.points as usize {
                        l.begin(s.points as usize).unwrap();
                    }
                    if let Ok(a) = observe_and_estimate(&mut l, &s) {
                        prop_assert!(
                            a.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v)),
                            "{a:?} for {s:?}"
                        );
                    }
                }
            }
        }
    }
}
