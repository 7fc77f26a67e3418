//! The Blend against a direct evaluation of Eq. 11, and the properties the controller
//! relies on: conditioned points are reproduced, replanning never touches the past or the
//! present, updates wait for their group to be inactive or for the rest before its next
//! execution.

mod common;

use common::{D, primitives};
use nalgebra::{DMatrix, DVector};
use softarm_method::activation::MAX_PRIMITIVES;
use softarm_method::blend::{Blend, BlendError, ConditionedOn, Planner, Timeline};
use softarm_method::classify::classify;
use softarm_method::promp::{Basis, Demonstration, Primitive, TrainConfig, ViaPoint};
use softarm_sections::activation::ActivationConfig;

const FLOOR: f64 = 1e-6;
const T_COND: [f64; 5] = [1.0, 3.0, 5.0, 7.0, 9.0];
const Q: [usize; 5] = [0, 1, 2, 1, 0];

fn initial() -> Vec<[f64; D]> {
    (0..5)
        .map(|n| std::array::from_fn(|d| 0.3 + 0.08 * n as f64 + 0.05 * d as f64))
        .collect()
}

fn planner(rate: f64) -> Planner<D> {
    Planner::new(
        primitives(3, 15),
        &T_COND,
        &Q,
        Timeline::new(10.0, rate).unwrap(),
        ActivationConfig::default(),
        FLOOR,
    )
    .unwrap()
}

/// Eq. 11 straight from its definition, with nalgebra inverses: the slow path to check against.
fn direct(
    planner: &Planner<D>,
    prims: &[Primitive],
    estimates: &[[f64; D]],
    tick: usize,
) -> [f64; D] {
    let tl = planner.timeline();
    let s = planner.schedule();
    let t = tl.time_of(tick);
    let z = tl.phase_of(tick);
    let mut a = [0.0; MAX_PRIMITIVES];
    s.a(t, &mut a);
    let mut v = DVector::zeros(D);
    for (i, b) in s.groups(t).iter() {
        let mut lam = DMatrix::zeros(D, D);
        let mut eta = DVector::zeros(D);
        for (j, p) in prims.iter().enumerate() {
            let mut p = p.clone();
            if j == s.assignment()[i] {
                let z_star = tl.phase_of(planner.conditioning_ticks()[i]);
                p.condition(&ViaPoint::exact(z_star, &estimates[i]))
                    .unwrap();
            }
            let m = p.marginal(z);
            let cov = m.cov + DMatrix::identity(D, D) * FLOOR;
            let prec = cov.try_inverse().unwrap();
            eta += &prec * &m.mean * a[j];
            lam += prec * a[j];
        }
        v += lam.try_inverse().unwrap() * eta * b;
    }
    std::array::from_fn(|d| v[d])
}

/// v at tick `k` as the controller plays it (`Blend::tick`), used here as a read: it must take
/// no re-conditioned table in and hold no group, so it is v of the tables in force.
fn read(blend: &mut Blend<D>, k: usize) -> [f64; D] {
    let (applied, held) = (blend.applied(), blend.held_solves());
    let v = blend.tick(k);
    assert_eq!(
        blend.applied(),
        applied,
        "reading tick {k} swapped a table in"
    );
    assert_eq!(blend.held_solves(), held, "reading tick {k} held a group");
    v
}

#[test]
fn engine_agrees_with_a_direct_evaluation() {
    let prims = primitives(3, 15);
    let p = planner(100.0);
    let init = initial();
    let (mut blend, _r) = Planner::new(
        prims.clone(),
        &T_COND,
        &Q,
        Timeline::new(10.0, 100.0).unwrap(),
        ActivationConfig::default(),
        FLOOR,
    )
    .unwrap()
    .start(&init)
    .unwrap();
    let mut worst = 0.0f64;
    for tick in (0..blend.timeline().ticks()).step_by(7) {
        let want = direct(&p, &prims, &init, tick);
        let got = read(&mut blend, tick);
        for d in 0..D {
            worst = worst.max((got[d] - want[d]).abs());
        }
    }
    assert!(worst < 1e-7, "blend vs direct Eq. 11: {worst:e}");
}

#[test]
fn conditioned_actuation_is_reproduced_at_each_point() {
    let p = planner(500.0);
    let ticks = p.conditioning_ticks().to_vec();
    let init = initial();
    let (mut blend, _r) = p.start(&init).unwrap();
    for (n, &k) in ticks.iter().enumerate() {
        let v = read(&mut blend, k);
        for d in 0..D {
            assert!(
                (v[d] - init[n][d]).abs() < 1e-3,
                "point {n}, actuator {d}: {} vs {}",
                v[d],
                init[n][d]
            );
        }
    }
}

#[test]
fn reconditioning_the_next_group_never_changes_the_past_or_present() {
    let rate = 500.0;
    let half_window = ActivationConfig::default().window_s / 2.0;
    for n in 0..4 {
        let next = n + 1;
        let (mut blend, mut replanner) = planner(rate).start(&initial()).unwrap();
        let tl = *blend.timeline();
        let before: Vec<_> = (0..tl.ticks()).map(|k| read(&mut blend, k)).collect();

        let estimate: [f64; D] = std::array::from_fn(|d| 0.6 - 0.04 * d as f64);
        replanner.recondition(next, &estimate, 2).unwrap();
        // The controller ticks on: at T_cond[n] group n+ is inactive, so the swap happens now.
        let k_n = tl.tick_of(T_COND[n]);
        blend.tick(k_n);
        assert!(!blend.has_pending());

        let end_of_window = tl.tick_of(T_COND[n] + half_window);
        for k in 0..=end_of_window {
            let now = read(&mut blend, k);
            for d in 0..D {
                assert!((now[d] - before[k][d]).abs() <= 1e-12, "n = {n}, tick {k}");
            }
        }
        let k_next = tl.tick_of(T_COND[next]);
        let now = read(&mut blend, k_next);
        for d in 0..D {
            assert!(
                (now[d] - estimate[d]).abs() < 1e-3,
                "n+ = {next} reproduces its new estimate"
            );
            assert!((now[d] - before[k_next][d]).abs() > 1e-2, "and it moved");
        }
    }
}

#[test]
fn an_update_waits_while_its_group_is_active() {
    let (mut blend, mut replanner) = planner(500.0).start(&initial()).unwrap();
    let tl = *blend.timeline();
    let k2 = tl.tick_of(T_COND[2]);
    let old = read(&mut blend, k2);
    let estimate = [0.9; D];
    replanner.recondition(2, &estimate, 2).unwrap();
    // Inside group 2's window: held back, v unchanged.
    assert_eq!(blend.tick(k2), old);
    assert!(blend.has_pending());
    // Group 2's window and hand-over are over at T_cond[3]: taken in.
    blend.tick(tl.tick_of(T_COND[3]));
    assert!(!blend.has_pending());
    let v = read(&mut blend, k2);
    assert!(v.iter().all(|x| (x - 0.9).abs() < 1e-3), "{v:?}");
}

/// One execution as the controller plays it: `rest` ticks of rest, then the timeline, calling
/// `at(k, v)` after each tick k with the v it played.
fn play(blend: &mut Blend<D>, rest: usize, mut at: impl FnMut(usize, [f64; D])) {
    for _ in 0..rest {
        blend.rest();
    }
    for k in 0..blend.timeline().ticks() {
        let v = blend.tick(k);
        at(k, v);
    }
}

fn near(v: &[f64; D], want: &[f64; D], tol: f64) -> bool {
    v.iter().zip(want).all(|(x, y)| (x - y).abs() < tol)
}

#[test]
fn a_one_point_set_applies_each_estimate_in_its_next_execution() {
    // b_0 = 1 all along: there is no inactive stretch, only the rest between executions.
    let planner = Planner::<D>::new(
        primitives(3, 15),
        &[2.0],
        &[1],
        Timeline::new(4.0, 100.0).unwrap(),
        ActivationConfig::default(),
        FLOOR,
    )
    .unwrap();
    let k0 = planner.conditioning_ticks()[0];
    let first = [0.45; D];
    let (mut blend, mut replanner) = planner.start(&[first]).unwrap();
    let rest = 40;

    // Execution 1: the learner's answer to the point's sample arrives a few ticks later; the
    // group is active, so it waits, and execution 1 plays on unchanged.
    let second = [0.6; D];
    let mut played = Vec::new();
    play(&mut blend, rest, |k, v| {
        played.push(v);
        if k == k0 + 3 {
            replanner.recondition(0, &second, 2).unwrap();
        }
    });
    assert!(near(&played[k0], &first, 1e-3), "{:?}", played[k0]);
    assert!(blend.has_pending() && blend.applied() == 0);
    assert_eq!(
        read(&mut blend, k0),
        played[k0],
        "nothing moved during execution 1"
    );
    // What ran in execution 1, as its point's sample says: the first estimate, for it.
    assert_eq!(
        blend.conditioned_on(0),
        ConditionedOn {
            actuation: first,
            execution: 1,
            within: false,
            beyond_reach: false,
        }
    );

    // Execution 2 uses it; an estimate arriving after execution 2 ended is used in execution 3.
    let third = [0.35; D];
    let mut at_point = None;
    play(&mut blend, rest, |k, v| {
        if k == k0 {
            at_point = Some(v);
        }
    });
    assert!(near(&at_point.unwrap(), &second, 1e-3), "{at_point:?}");
    assert_eq!(blend.applied(), 1);
    assert_eq!(
        blend.conditioned_on(0),
        ConditionedOn {
            actuation: second,
            execution: 2,
            within: false,
            beyond_reach: false,
        }
    );
    replanner.recondition(0, &third, 3).unwrap();
    play(&mut blend, rest, |k, v| {
        if k == k0 {
            at_point = Some(v);
        }
    });
    assert!(near(&at_point.unwrap(), &third, 1e-3), "{at_point:?}");
    assert_eq!(blend.applied(), 2);
    assert_eq!(blend.conditioned_on(0).execution, 3);

    // Without a rest (controller.rest_s = 0), the execution's first tick takes it in.
    replanner.recondition(0, &first, 4).unwrap();
    play(&mut blend, 0, |_, _| {});
    assert!(near(&read(&mut blend, k0), &first, 1e-3));
    assert_eq!(blend.applied(), 3);
}

#[test]
fn an_estimate_for_group_0_arriving_after_the_execution_is_used_in_the_next() {
    let (mut blend, mut replanner) = planner(100.0).start(&initial()).unwrap();
    let tl = *blend.timeline();
    let k0 = tl.tick_of(T_COND[0]);
    play(&mut blend, 20, |_, _| {});
    // The answer to the last point's sample comes once the execution is over.
    let estimate = [0.7; D];
    replanner.recondition(0, &estimate, 2).unwrap();
    let mut at_point = None;
    play(&mut blend, 20, |k, v| {
        if k == k0 {
            at_point = Some(v);
        }
    });
    assert!(near(&at_point.unwrap(), &estimate, 1e-3), "{at_point:?}");
    assert_eq!(blend.applied(), 1);
}

#[test]
fn bad_estimates_are_refused_and_change_nothing() {
    let (mut blend, mut replanner) = planner(100.0).start(&initial()).unwrap();
    let before: Vec<_> = (0..blend.timeline().ticks())
        .map(|k| read(&mut blend, k))
        .collect();
    let mut bad = [0.5; D];
    bad[3] = f64::NAN;
    let e = replanner.recondition(1, &bad, 2).unwrap_err();
    assert!(e.to_string().contains("actuation estimate"), "{e}");
    assert!(replanner.recondition(7, &[0.5; D], 2).is_err());
    for (k, b) in before.iter().enumerate() {
        assert_eq!(&blend.tick(k), b);
    }
}

#[test]
fn a_replanner_never_blocks_on_a_tick_that_does_not_run() {
    let (mut blend, mut replanner) = planner(100.0).start(&initial()).unwrap();
    let groups = T_COND.len();
    // The tick takes nothing in: after one update per group waiting, the next is refused.
    for _ in 0..groups {
        replanner.recondition(1, &[0.6; D], 2).unwrap();
    }
    let e = replanner.recondition(1, &[0.6; D], 2).unwrap_err();
    assert!(matches!(e, BlendError::Busy(n) if n == groups), "{e}");
    // Once the tick runs it takes them in, and there is room again.
    blend.tick(blend.timeline().tick_of(T_COND[3]));
    replanner.recondition(1, &[0.7; D], 2).unwrap();
    drop(blend);
    assert!(matches!(
        replanner.recondition(1, &[0.7; D], 2),
        Err(BlendError::Disconnected)
    ));
}

#[test]
fn plans_that_do_not_fit_are_refused() {
    let tl = Timeline::new(10.0, 500.0).unwrap();
    let c = ActivationConfig::default();
    let e = Planner::<D>::new(primitives(3, 15), &[1.0, 12.0], &[0, 1], tl, c, FLOOR)
        .err()
        .unwrap();
    assert!(e.to_string().contains("outside the execution"), "{e}");
    let e = Planner::<4>::new(primitives(1, 15), &[1.0], &[0], tl, c, FLOOR)
        .err()
        .unwrap();
    assert!(e.to_string().contains("has 6 DoF"), "{e}");
    let mut mixed = primitives(2, 15);
    mixed.push(primitives(1, 10).remove(0));
    let e = Planner::<D>::new(mixed, &[1.0], &[0], tl, c, FLOOR)
        .err()
        .unwrap();
    assert!(e.to_string().contains("another basis"), "{e}");
}

#[test]
fn classify_picks_the_nearest_task_space_primitive() {
    // Three straight-line task-space motions far apart; points near each at mid-phase.
    let task: Vec<Primitive> = (0..3)
        .map(|j| {
            let demos: Vec<Demonstration> = (0..8)
                .map(|i| {
                    let times: Vec<f64> = (0..50).map(|s| s as f64 / 49.0).collect();
                    let values = DMatrix::from_fn(50, 3, |r, d| {
                        0.1 * j as f64 * (d as f64 + 1.0)
                            + 0.05 * times[r]
                            + 0.002 * (i as f64 + d as f64).sin()
                    });
                    Demonstration::new(times, values)
                })
                .collect();
            Primitive::train(
                Basis::new(8, None).unwrap(),
                &demos,
                &TrainConfig::default(),
            )
            .unwrap()
        })
        .collect();
    let points = [[0.2, 0.4, 0.6], [0.0, 0.0, 0.0], [0.1, 0.2, 0.3]];
    let q = classify(&task, &points, &[0.5, 0.1, 0.9], FLOOR).unwrap();
    assert_eq!(q, vec![2, 0, 1]);
    assert!(classify(&task, &points, &[0.5], FLOOR).is_err());
}
