//! A tick of the blend (rest or execution) allocates nothing, even while it takes in
//! re-conditioned groups and hands the old tables back. Proven with a counting global allocator
//! that counts only the threads that ask, so the other tests of this binary can run beside it.

mod common;

use common::primitives_of;
use softarm_method::blend::{Planner, Timeline};
use softarm_sections::activation::ActivationConfig;
use softarm_test_alloc::{self as alloc, Counting};

#[global_allocator]
static GLOBAL: Counting = Counting;

/// The default `[arm]`'s six actuators, a three-segment TDCR's nine, the most an arm may have.
#[test]
fn ticks_allocate_and_free_nothing() {
    ticks_allocate_and_free_nothing_at::<6>();
    ticks_allocate_and_free_nothing_at::<9>();
    ticks_allocate_and_free_nothing_at::<16>();
}

fn ticks_allocate_and_free_nothing_at<const D: usize>() {
    let t_cond = [1.0, 3.0, 5.0, 7.0, 9.0];
    let planner = Planner::<D>::new(
        primitives_of(3, 15, D),
        &t_cond,
        &[0, 1, 2, 1, 0],
        Timeline::new(10.0, 500.0).unwrap(),
        ActivationConfig::default(),
        1e-6,
    )
    .unwrap();
    let (mut blend, mut replanner) = planner.start(&[[0.5; D]; 5]).unwrap();
    let tl = *blend.timeline();

    // The replanner runs on its own thread, as in the controller; its allocations don't count.
    let worker = std::thread::spawn(move || {
        for n in 0..5 {
            replanner
                .recondition(n, &[0.4 + 0.05 * n as f64; D], 2)
                .unwrap();
        }
        replanner
    });
    let replanner = worker.join().unwrap();

    let _counted = alloc::count_this_thread();
    let before = alloc::this_thread();
    let mut sink = 0.0;
    // The rest before the execution takes in group 0 (active from t = 0), the ticks the others.
    for _ in 0..10 {
        sink += blend.rest()[0];
    }
    for k in 0..tl.ticks() {
        let v = blend.tick(k);
        sink += v[0];
    }
    let during = alloc::this_thread() - before;
    assert!(sink.is_finite());
    assert!(!blend.has_pending(), "every update was taken in");
    assert_eq!(
        during,
        0,
        "{during} allocations or frees in {} ticks at D = {D}",
        tl.ticks()
    );
    drop(replanner);
}

#[test]
fn the_counter_sees_allocations() {
    let before = alloc::this_thread();
    let v: Vec<u8> = Vec::with_capacity(std::hint::black_box(16));
    drop(std::hint::black_box(v));
    assert_eq!(alloc::this_thread(), before, "not counted before asking");
    let counted = alloc::count_this_thread();
    let all = alloc::all_threads();
    let v: Vec<u8> = Vec::with_capacity(std::hint::black_box(16));
    drop(std::hint::black_box(v));
    assert_eq!(alloc::this_thread() - before, 2);
    assert!(alloc::all_threads() - all >= 2);
    drop(counted);
    let v: Vec<u8> = Vec::with_capacity(std::hint::black_box(16));
    drop(std::hint::black_box(v));
    assert_eq!(
        alloc::this_thread() - before,
        2,
        "not counted after the guard"
    );
}
