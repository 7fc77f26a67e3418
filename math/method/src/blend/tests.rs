//! Eq. 11 against direct computation, the hand-over of re-conditioned tables, failures held.

use super::*;
use crate::promp::{Basis, Demonstration, TrainConfig};

const D: usize = 6;
const RATE: f64 = 50.0;

fn primitive(offset: f64) -> Primitive {
    let demos: Vec<Demonstration> = (0..8)
        .map(|i| {
            let times: Vec<f64> = (0..50).map(|s| 4.0 * s as f64 / 49.0).collect();
            let values = DMatrix::from_fn(50, D, |r, d| {
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

/// Two points (1 s and 3 s) over 4 s at 50 Hz, on two primitives.
fn start() -> (Blend<D>, Replanner<D>) {
    Planner::<D>::new(
        vec![primitive(0.4), primitive(0.6)],
        &[1.0, 3.0],
        &[0, 1],
        Timeline::new(4.0, RATE).unwrap(),
        ActivationConfig::default(),
        1e-6,
    )
    .unwrap()
    .start(&[[0.5; D], [0.55; D]])
    .unwrap()
}

/// Makes group `group`'s solve fail from tick `from` on: its own primitive's precision turns
/// negative definite, as a covariance degenerate enough to break the Cholesky would.
fn break_group(blend: &mut Blend<D>, group: usize, from: usize) {
    for e in &mut blend.conditioned[group].entries[from..] {
        for (d, row) in e.precision.iter_mut().enumerate() {
            *row = [0.0; D];
            row[d] = -1e9;
        }
    }
}

fn close(a: &[f64; D], b: &[f64; D], tol: f64) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
}

#[test]
fn a_group_whose_solve_fails_holds_its_last_good_value_and_is_counted() {
    let (mut blend, _r) = start();
    let (mut intact, _ri) = start();
    let k1 = blend.timeline.tick_of(1.0);
    for k in 0..=k1 {
        assert_eq!(blend.tick(k), intact.tick(k));
    }
    let held = blend.held[0];
    break_group(&mut blend, 0, k1 + 1);
    assert_eq!(blend.held_solves(), 0);

    // Inside group 0's window (b_0 = 1): v holds group 0's last good value, exactly.
    let window_end = blend.timeline.tick_of(1.0 + 0.1);
    for (n, k) in (k1 + 1..=window_end).enumerate() {
        assert_eq!(blend.tick(k), held, "tick {k}");
        assert_eq!(blend.held_solves(), n as u64 + 1);
        intact.tick(k);
    }
    let before = blend.held_solves();

    // Handing over to group 1: group 0 keeps its b_0 share at the held value, so v stays
    // near the intact blend's (dropping the share would pull v up to b_0 · 0.5 toward 0;
    // the held value is only as stale as the trajectory's drift).
    let k3 = blend.timeline.tick_of(3.0 - 0.1);
    let mut handing_over = 0;
    for k in window_end + 1..k3 {
        let b0 = blend.schedule.b(0, blend.timeline.time_of(k));
        let (v, want) = (blend.tick(k), intact.tick(k));
        assert!(close(&v, &want, 0.1), "tick {k}: {v:?} vs {want:?}");
        if b0 > 0.0 {
            handing_over += 1;
            let one = intact.group_mean(1, k, &intact.activations(k).1).unwrap();
            let expect: [f64; D] = std::array::from_fn(|d| b0 * held[d] + (1.0 - b0) * one[d]);
            assert!(close(&v, &expect, 1e-12), "tick {k}");
        }
    }
    assert!(handing_over > 10);
    assert_eq!(blend.held_solves() - before, handing_over);
    // Group 1's own solves are fine: nothing more is counted once group 0 is inactive.
    let count = blend.held_solves();
    blend.tick(blend.timeline.tick_of(3.0));
    assert_eq!(blend.held_solves(), count);
}

#[test]
fn the_tick_frees_nothing_when_the_retired_ring_is_full() {
    let (mut blend, mut replanner) = start();
    replanner.recondition(1, &[0.7; D], 2).unwrap();
    replanner.recondition(0, &[0.3; D], 2).unwrap();
    // Fill the retired ring, as if the replanner had not drained it.
    let capacity = blend.retired.buffer().capacity();
    let fill = |blend: &mut Blend<D>| {
        while !blend.retired.is_full() {
            blend.retire(Table::zeroed(1));
        }
    };
    fill(&mut blend);
    let before = blend.evaluate(blend.timeline.tick_of(3.0));
    // Group 1 is inactive at tick 1, but its old table has nowhere to go: nothing is
    // swapped (nor freed); the updates wait.
    blend.tick(1);
    blend.rest();
    assert_eq!(blend.applied(), 0);
    assert_eq!(blend.evaluate(blend.timeline.tick_of(3.0)), before);
    // A newer estimate for a waiting group waits in its ring too.
    replanner.recondition(1, &[0.8; D], 2).unwrap();
    fill(&mut blend);
    blend.tick(1);
    assert_eq!(blend.pending_count, 2);
    assert_eq!(blend.updates.slots(), 1);

    // Room again: the rest takes in all of them, each old table goes back.
    for _ in 0..capacity {
        replanner.retired.pop().unwrap();
    }
    blend.rest();
    assert_eq!(blend.applied(), 2);
    assert!(!blend.has_pending() && blend.updates.is_empty());
    // 1 superseded + 2 replaced.
    assert_eq!(replanner.retired.slots(), 3);
    let v = blend.evaluate(blend.timeline.tick_of(3.0));
    assert!(close(&v, &[0.8; D], 1e-3), "{v:?}");
}
