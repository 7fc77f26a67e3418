//! The controller's tick allocates nothing once running: the controller runs in this process
//! (its tick loop on a thread of this test) under a counting allocator, against the real `sim`
//! and `learner` processes, through whole executions of a way-point set: conditioning samples,
//! re-conditioned groups swapped in, stats and status published.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use softarm_clients::{stats, submit};
use softarm_config::Config;
use softarm_ipc::Namespace;
use softarm_test_alloc as alloc;
use softarm_test_support::{DEMO_WAYPOINTS, TestStack};

#[test]
fn the_controller_tick_allocates_nothing_once_running() {
    let s = TestStack::new(env!("CARGO_BIN_EXE_softarm"), "alloc", true);
    let config = Config::load(&s.config).unwrap();
    let mut sim = s.spawn(&["sim"]);
    let mut learner = s.spawn(&["learner"]);

    let stop = Arc::new(AtomicBool::new(false));
    let controller = {
        let stop = stop.clone();
        let config = config.clone();
        // `controller::run` runs its tick loop on the calling thread: this one is counted. Its
        // service thread, and everything else in this test, is not.
        std::thread::spawn(move || {
            let _counted = alloc::count_this_thread();
            softarm_controller::run(&config, &stop)
        })
    };

    let ns = Namespace::new(&s.namespace).unwrap();
    let follower = stats::Stats::open(&ns).unwrap();
    let set = submit::prepare(&config, std::path::Path::new(DEMO_WAYPOINTS), 3).unwrap();
    // The controller may still be loading its model: retry until it takes the set.
    let mut outcome = submit::submit(&ns, set, Duration::from_secs(10));
    for _ in 0..20 {
        if matches!(outcome, submit::Outcome::Accepted { .. }) {
            break;
        }
        std::thread::sleep(Duration::from_millis(500));
        outcome = submit::submit(&ns, set, Duration::from_secs(10));
    }
    let submit::Outcome::Accepted { set_id } = outcome else {
        panic!("{outcome:?}");
    };
    let next = || loop {
        let st = follower
            .next(Duration::from_secs(60))
            .expect("stats within a minute");
        if st.set_id == set_id {
            return st;
        }
    };
    // Warm: the first execution ran every path of the tick once.
    assert_eq!(next().execution, 1);
    let before = alloc::all_threads();
    assert_eq!(next().execution, 2);
    assert_eq!(next().execution, 3);
    let during = alloc::all_threads() - before;

    stop.store(true, Ordering::Relaxed);
    controller.join().unwrap().unwrap();
    let _ = sim.kill();
    let _ = learner.kill();
    let _ = sim.wait();
    let _ = learner.wait();
    assert!(
        before > 0,
        "the counter sees the tick thread's set-up allocations"
    );
    assert_eq!(
        during, 0,
        "{during} allocations or frees on the tick thread in two executions"
    );
}
