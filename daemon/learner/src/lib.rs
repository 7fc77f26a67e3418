//! The learner process: CACLA-MTL at the conditioning points, under `learner.algorithm`
//! ([`softarm_method::online`]). An `EstimateRequest` (a set was accepted) is answered with the
//! first, exploration-free estimate of every point; each `ConditioningSample` is one visit and is
//! answered with the `ActuationEstimate` the controller asked for next.
//! The state is checkpointed atomically after every execution and at exit, and resumed at start
//! when it descends from the current model bundle.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use softarm_config::Config;
use softarm_ipc::{
    Actuation, ActuationEstimate, ConditioningSample, EstimateRequest, MAX_WAYPOINTS, Namespace,
    Node,
};
use softarm_method::cacla::{CaclaMtl, LearnerConfig};
use softarm_method::online::OnlineLearner;
use softarm_method::space::Workspace;
use softarm_model::bundle::{BundleError, BundleWatch, Model, read_checkpoint, write_checkpoint};
use softarm_runtime::now_ns;

struct Loaded {
    learner: OnlineLearner,
    model_id: String,
}

/// Counts and logs a refused sample, naming what was wrong.
fn refuse(refused: &mut u64, s: &ConditioningSample, why: &dyn std::fmt::Display) {
    *refused += 1;
    tracing::warn!(
        set_id = s.set_id,
        point = s.point,
        refused = *refused,
        "sample refused: {why}"
    );
}

/// The checkpoint if it descends from the bundle in `model_dir`, else the bundle's learner.
fn load(config: &Config) -> Result<Loaded, BundleError> {
    let model_dir = config.model_dir();
    let model = Model::read(&model_dir)?;
    let state = match read_checkpoint(&config.state_dir()) {
        Ok((state, from)) if from == model.id => {
            tracing::info!(dir = %config.state_dir().display(), "resuming from the learner checkpoint");
            state
        }
        Ok(_) => {
            tracing::info!(
                "the checkpoint belongs to an older model: starting from the new bundle"
            );
            model.learner.clone()
        }
        Err(BundleError::Missing { .. }) => model.learner.clone(),
        Err(e) => {
            tracing::error!("{e}; starting from the model bundle instead");
            model.learner.clone()
        }
    };
    let mut state = state;
    state.config = runtime_config(state.config, config.learner);
    let cacla = CaclaMtl::restore(&state).map_err(|why| BundleError::Invalid {
        path: model_dir.clone(),
        why,
    })?;
    tracing::info!(algorithm = state.config.algorithm.name(), "online learner");
    Ok(Loaded {
        learner: OnlineLearner::new(cacla, model.kinematics),
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
        correction: configured.correction,
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

fn checkpoint(config: &Config, l: &Loaded) {
    if let Err(e) = write_checkpoint(&config.state_dir(), &l.learner.cacla().state(), &l.model_id) {
        tracing::error!("checkpoint not written: {e}");
    }
}

/// What the controller sent, merged from the two services.
// A few at a time in a reused buffer: boxing the large variant would only add allocations.
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

/// A sample the learner can use: a set (ids start at 1), points in range (the memory grows to
/// the point's index), executions counted from 1 and not going back, and finite positions and
/// actuation. The reason names the field.
fn check(s: &ConditioningSample) -> Result<(), String> {
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
        ("desired", &s.desired[..]),
        ("next_desired", &s.next_desired[..]),
        ("actuation", &s.actuation[..]),
    ] {
        if !v.iter().all(|x| x.is_finite()) {
            return Err(format!("{name} {v:?} is not finite"));
        }
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

/// How far outside the way-point workspace an arm's position is still believed (m). Farther, a
/// `reached` is a tracker glitch or a broken peer's: learning from it would wreck the learner
/// (its Jacobians, corrections and critic scale with the error), and the checkpoint with it.
const REACH_MARGIN_M: f64 = 0.25;

/// Where a reached position may be: the way-point workspace grown by [`REACH_MARGIN_M`].
fn reachable(config: &Config) -> Workspace {
    let w = config.waypoints.workspace();
    Workspace {
        min_m: w.min_m.map(|v| v - REACH_MARGIN_M),
        max_m: w.max_m.map(|v| v + REACH_MARGIN_M),
    }
}

/// A request the learner can plan with: a set, 1 to `MAX_WAYPOINTS` points, finite targets.
/// Checked before the running set's memory is given up for it. The reason names the field.
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
fn visit(learner: &mut OnlineLearner, s: &ConditioningSample) -> Result<Actuation, String> {
    if learner.points() != s.points as usize {
        return Err(format!(
            "the set has {} points, the sample says {}",
            learner.points(),
            s.points
        ));
    }
    if s.reached.iter().all(|v| v.is_finite()) {
        let v = learner
            .observe(
                s.point as usize,
                &s.desired,
                &s.actuation,
                &s.reached,
                Some(&s.measured),
            )
            .map_err(|e| e.to_string())?;
        tracing::debug!(
            point = s.point,
            execution = s.execution,
            error_mm = v.error * 1e3,
            td = ?v.td_error,
            action = ?s.actuation,
            measured = ?s.measured,
            "visit"
        );
    } else {
        tracing::warn!(
            point = s.point,
            "no tracker position at the point: visit skipped"
        );
    }
    // The set's first execution runs without exploration.
    let explore = s.next_execution >= 2;
    learner
        .estimate(s.next_point as usize, &s.next_desired, explore)
        .map_err(|e| e.to_string())
}

/// Runs the learner until `stop` is set.
pub fn run(config: &Config, stop: &AtomicBool) -> anyhow::Result<()> {
    let namespace = Namespace::new(&config.namespace())?;
    let ipc = Node::open(namespace, "learner")?;
    let requests = ipc.subscriber(&ipc.estimate_request()?)?;
    let samples = ipc.subscriber(&ipc.cp_sample()?)?;
    let estimates = ipc.publisher(&ipc.estimate()?)?;
    let mut seq = 0u64;
    let mut send = |set_id: u64, point: u32, actuation: Actuation| {
        seq += 1;
        let _ = estimates.send_copy(ActuationEstimate {
            seq,
            stamp_ns: now_ns(),
            set_id,
            point,
            _pad: 0,
            actuation,
        });
    };

    let mut watch = BundleWatch::new(config.model_dir(), Duration::from_millis(200));
    let mut loaded: Option<Loaded> = None;
    let mut warned = false;
    let mut set_id = 0u64;
    let mut inbox: Vec<Incoming> = Vec::new();
    // Requests and samples refused since the start; the set and visit last learnt from.
    let mut refused = 0u64;
    let mut last_visit: Option<(u64, u32, u32)> = None;
    let reach = reachable(config);
    // Under systemd: READY=1 now that every port is open (a model may still be missing: then
    // the learner waits for one, and says so in STATUS=); WATCHDOG=1 while this loop turns.
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Ready]);
    let mut watchdog = sd_notify::watchdog_enabled().map(|w| (w / 2, std::time::Instant::now()));
    let mut told = None;
    while !stop.load(Ordering::Relaxed) {
        // An estimate is needed before the next group fades in (at least window_s / 2 after the
        // point): 2 ms is plenty.
        std::thread::sleep(Duration::from_millis(2));
        if let Some((every, last)) = watchdog.as_mut()
            && last.elapsed() >= *every
        {
            *last = std::time::Instant::now();
            let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
        }
        let state = (loaded.is_some(), set_id);
        if told != Some(state) {
            told = Some(state);
            let status = match state {
                (false, _) => "waiting for a model bundle (softarm train)".to_string(),
                (true, 0) => "model loaded, no way-point set".to_string(),
                (true, id) => format!("learning on set {id}"),
            };
            let _ = sd_notify::notify(&[sd_notify::NotifyState::Status(&status)]);
        }
        // A new bundle (after `softarm train`) replaces what the learner had.
        if watch.changed() {
            match load(config) {
                Ok(l) => {
                    tracing::info!(model = %l.model_id, "learner ready");
                    loaded = Some(l);
                    set_id = 0;
                    last_visit = None;
                }
                Err(e) => tracing::error!("{e}"),
            }
        } else if !watch.exists() && !warned {
            warned = true;
            tracing::warn!(
                "no model bundle in {} yet: waiting for `softarm train`",
                watch.dir().display()
            );
        }
        // Without a model, requests and samples wait in the subscribers' buffers.
        let Some(l) = loaded.as_mut() else {
            continue;
        };
        // Both queues, in the order the controller sent them: a sample of the running set
        // sent before a new set's request is still a visit of that set.
        while let Ok(Some(r)) = requests.receive() {
            inbox.push(Incoming::Request(*r));
        }
        while let Ok(Some(s)) = samples.receive() {
            inbox.push(Incoming::Sample(*s));
        }
        inbox.sort_by_key(Incoming::stamp_ns);
        for m in inbox.drain(..) {
            match m {
                Incoming::Request(r) => {
                    if let Err(why) = check_request(&r) {
                        refused += 1;
                        tracing::warn!(set_id = r.set_id, refused, "request refused: {why}");
                        continue;
                    }
                    // A new set: its points' histories start over, and its first execution
                    // runs without exploration.
                    match l.learner.start_set(r.points()) {
                        Ok(first) => {
                            set_id = r.set_id;
                            for (point, a) in first.into_iter().enumerate() {
                                send(r.set_id, point as u32, a);
                            }
                            let (actor, critic) = l.learner.cacla().stored_centres();
                            let (actor_evicted, critic_evicted) =
                                l.learner.cacla().evicted_centres();
                            tracing::info!(
                                set_id,
                                points = r.points().len(),
                                actor,
                                critic,
                                actor_evicted,
                                critic_evicted,
                                "first estimates sent (lattice weights stored and evicted)"
                            );
                        }
                        Err(e) => {
                            refused += 1;
                            tracing::warn!(set_id = r.set_id, refused, "request refused: {e}");
                        }
                    }
                }
                Incoming::Sample(mut s) => {
                    if let Err(why) = check(&s).and_then(|()| check_order(&s, last_visit)) {
                        refuse(&mut refused, &s, &why);
                        continue;
                    }
                    if s.reached.iter().all(|v| v.is_finite()) && !reach.contains(&s.reached) {
                        // Not learnt from; the estimate asked for is still due.
                        let why = format!(
                            "reached {:?} is outside where the arm can be (the way-point \
                             workspace and {REACH_MARGIN_M} m around it): not learnt from",
                            s.reached
                        );
                        refuse(&mut refused, &s, &why);
                        s.reached = [f64::NAN; 3];
                    }
                    if s.set_id != set_id {
                        // A set whose request this learner did not see (it restarted): its
                        // targets are learnt from the samples.
                        if l.learner.begin(s.points as usize).is_ok() {
                            set_id = s.set_id;
                        }
                    }
                    match visit(&mut l.learner, &s) {
                        Ok(next) => {
                            tracing::debug!(point = s.next_point, estimate = ?next, "estimate");
                            send(s.set_id, s.next_point, next)
                        }
                        Err(why) => {
                            refuse(&mut refused, &s, &why);
                            continue;
                        }
                    }
                    last_visit = Some((s.set_id, s.execution, s.point));
                    if s.point + 1 == s.points {
                        checkpoint(config, l);
                    }
                }
            }
        }
    }
    if let Some(l) = &loaded {
        checkpoint(config, l);
    }
    tracing::info!(refused, "learner stopped");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> ConditioningSample {
        ConditioningSample {
            set_id: 1,
            points: 3,
            point: 2,
            next_point: 0,
            execution: 1,
            next_execution: 2,
            ..Default::default()
        }
    }

    #[test]
    fn malformed_samples_are_refused_with_a_reason() {
        assert_eq!(check(&sample()), Ok(()));
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
                actuation: [f64::INFINITY; 6],
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
        ];
        for s in bad {
            assert!(check(&s).is_err(), "{s:?}");
        }
        // The field is named.
        let why = |s| check(&s).unwrap_err();
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

    mod fuzz {
        //! Arbitrary samples on `cp_sample`, as a broken or hostile peer could send them: the
        //! learner refuses what does not fit with a reason and never panics, and what it
        //! answers is a finite actuation in [0, 1].
        use super::*;
        use proptest::prelude::*;
        use softarm_method::cacla::{CaclaMtl, LearnerConfig};
        use softarm_method::pcc::ArmGeometry;
        use softarm_method::poly::{Polynomial, PolynomialConfig};

        fn learner() -> OnlineLearner {
            let arm = ArmGeometry::default();
            let a: Vec<Actuation> = (0..400)
                .map(|i| {
                    std::array::from_fn(|j| 0.2 + 0.6 * (((i * 7 + j * 13) % 37) as f64 / 36.0))
                })
                .collect();
            let p: Vec<_> = a.iter().map(|a| arm.position(a)).collect();
            let poly = Polynomial::fit(&a, &p, &PolynomialConfig::default()).unwrap();
            OnlineLearner::new(CaclaMtl::new(LearnerConfig::default()).unwrap(), poly)
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
                0u64..3,
            )
                .prop_map(|((points, point, next_point, exec), a, d, r, m, set_id)| {
                    ConditioningSample {
                        set_id,
                        points,
                        point,
                        next_point,
                        execution: exec,
                        next_execution: exec + 1,
                        actuation: a,
                        desired: d,
                        reached: r,
                        next_desired: d,
                        measured: m,
                        ..Default::default()
                    }
                })
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
                    if check(&s).is_err() {
                        continue;
                    }
                    if l.points() != s.points as usize {
                        l.begin(s.points as usize).unwrap();
                    }
                    if let Ok(a) = visit(&mut l, &s) {
                        prop_assert!(
                            a.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v)),
                            "{a:?} for {s:?}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn the_inbox_keeps_the_order_things_were_sent_in() {
        let mut inbox = [
            Incoming::Request(EstimateRequest {
                stamp_ns: 20,
                ..Default::default()
            }),
            Incoming::Sample(ConditioningSample {
                stamp_ns: 10,
                ..sample()
            }),
        ];
        inbox.sort_by_key(Incoming::stamp_ns);
        assert!(matches!(inbox[0], Incoming::Sample(_)));
    }
}
