//! A tick of the engine allocates nothing, even while it takes in re-conditioned groups and
//! hands the old tables back. Proven with a counting global allocator that counts only the
//! calling thread, so the other tests of this binary can run beside it.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use common::{D, primitives};
use softarm_method::activation::ActivationConfig;
use softarm_method::engine::{Planner, Timeline};

struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new: usize) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(ptr, layout, new) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn count() -> u64 {
    ALLOCATIONS.with(|c| c.get())
}

#[test]
fn ticks_allocate_and_free_nothing() {
    let t_cond = [1.0, 3.0, 5.0, 7.0, 9.0];
    let planner = Planner::<D>::new(
        primitives(3, 15),
        &t_cond,
        &[0, 1, 2, 1, 0],
        Timeline::new(10.0, 500.0).unwrap(),
        ActivationConfig::default(),
        1e-6,
    )
    .unwrap();
    let (mut engine, mut replanner) = planner.start(&[[0.5; D]; 5]).unwrap();
    let tl = *engine.timeline();

    // The replanner runs on its own thread, as in the controller; its allocations don't count.
    let worker = std::thread::spawn(move || {
        for n in 1..5 {
            replanner
                .recondition(n, &[0.4 + 0.05 * n as f64; D])
                .unwrap();
        }
        replanner
    });
    let replanner = worker.join().unwrap();

    let before = count();
    let mut sink = 0.0;
    for k in 0..tl.ticks() {
        let v = engine.tick(k);
        sink += v[0];
    }
    let during = count() - before;
    assert!(sink.is_finite());
    assert!(!engine.has_pending(), "every update was taken in");
    assert_eq!(
        during,
        0,
        "{during} allocations or frees in {} ticks",
        tl.ticks()
    );
    drop(replanner);
}

#[test]
fn the_counter_sees_allocations() {
    let before = count();
    let v: Vec<u8> = Vec::with_capacity(std::hint::black_box(16));
    drop(std::hint::black_box(v));
    assert_eq!(count() - before, 2);
}
