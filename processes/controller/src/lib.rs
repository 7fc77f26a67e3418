//! The controller process: a fixed-rate tick thread that evaluates Eq. 11 and
//! enforces the limits, a service thread that talks to users and the learner and plans, and an
//! io thread that publishes what the tick produced.
//!
//! The tick thread allocates nothing, locks nothing and sleeps only on absolute deadlines once
//! it runs: way-point sets and demonstrations arrive over a bounded lock-free ring as boxes and
//! leave the same way, to be freed by the service thread; re-conditioned groups reach the blend
//! through its own rings; what it publishes leaves over a ring to the io thread.
//!
//! The modules: the tick loop ([`tick`]), what its modes play ([`execution`] of way-point sets,
//! [`demonstration`]s), the actuators' [`lag`] it leads by, its [`limiter`] and its wake-up
//! [`latency`]; the [`service`] thread
//! (estimates, re-conditioning, demonstrations) and the [`admission`] of sets it uses; the
//! [`io`] thread and the tick's outbox; real-time set-up and the watchdog ([`rt`]).
//!
//! Admission, [`Execution`], [`ActuatorLag`] and the [`Limiter`] are public so that `softarm-rehearsal` runs
//! Alg. 2 with this very code on a simulated plant, in one process.

mod admission;
mod control;
mod demonstration;
mod execution;
mod io;
mod lag;
mod latency;
mod limiter;
mod rt;
mod service;
mod tick;

pub use admission::{Admitted, admit, conditioned_on};
pub use control::{Control, Decided, Health, Latest, Outputs, Plan, Report, Retired};
pub use demonstration::DemoSequences;
pub use execution::{
    Execution, ExecutionTick, REACH_WAIT_NS, REACH_WINDOW_NS, ReadySet, Track, rest_ticks,
};
pub use lag::ActuatorLag;
pub use limiter::Limiter;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::thread::JoinHandle;

use anyhow::{Context, anyhow};
use rtrb::RingBuffer;
use softarm_config::Config;

/// Room for sets and demonstrations on their way to the tick, and back.
const TO_TICK_CAPACITY: usize = 4;
const RETIRED_CAPACITY: usize = 8;

/// What the service thread and the watchdog see of the tick thread.
#[derive(Default)]
struct Shared {
    state: AtomicU32,
    heartbeat: AtomicU64,
    model_loaded: AtomicBool,
    /// The e-stop latch file says engaged (or cannot be read), as the service thread last read
    /// it: the tick takes it beside the `estop` service, so an e-stop whose sample this process
    /// missed still stops it, without file I/O in the tick (`tick::Inputs::read`).
    latched: AtomicBool,
    /// The service or the io thread ended with an error: the tick stops too, and the process
    /// exits with that error to be restarted. A tick without its io thread publishes nothing
    /// and looks alive (seen: a controller ticking for minutes whose io thread could not open
    /// `setpoint`).
    thread_failed: AtomicBool,
}

impl Shared {
    /// `result` of a thread beside the tick; an error stops the tick.
    fn thread_ended(&self, result: anyhow::Result<()>) -> anyhow::Result<()> {
        if result.is_err() {
            self.thread_failed.store(true, Ordering::Relaxed);
        }
        result
    }
}

/// Runs the controller until `stop` is set. The tick loop runs on the calling thread.
pub fn run(config: &Config, stop: &AtomicBool) -> anyhow::Result<()> {
    let n = config.layout().actuators().len();
    softarm_ipc::with_actuators!(n, N => run_for::<N>(config, stop), n => {
        unreachable!("a loaded config's arm has 3 to 16 actuators, not {n}")
    })
}

/// [`run`] for an arm of `N` actuators.
fn run_for<const N: usize>(config: &Config, stop: &AtomicBool) -> anyhow::Result<()> {
    let namespace = config.bus()?;
    let shared = Arc::new(Shared::default());
    let latch = config.estop_latch();
    let latched = latch.engaged_or_safe(|e| tracing::error!("{e}; starting STOPPED"));
    if latched {
        tracing::warn!(
            "the e-stop is latched ({}): STOPPED until `softarm estop --reset`",
            latch.path().display()
        );
    }
    shared.latched.store(latched, Ordering::Relaxed);
    let (to_tick, plans) = RingBuffer::<Plan<N>>::new(TO_TICK_CAPACITY);
    let (retired, retired_rx) = RingBuffer::<Retired<N>>::new(RETIRED_CAPACITY);
    // Tells the service and io threads to finish once the tick has.
    let threads_stop = Arc::new(AtomicBool::new(false));

    let service = {
        let config = config.clone();
        let shared = shared.clone();
        let namespace = namespace.clone();
        let stop = threads_stop.clone();
        std::thread::Builder::new()
            .name("controller-service".into())
            .spawn(move || {
                let r =
                    service::Service::open(config, namespace, shared.clone(), to_tick, retired_rx)
                        .and_then(|service| service.run(&stop));
                shared.thread_ended(r)
            })
            .context("starting the service thread")?
    };
    let watchdog = rt::start_watchdog(shared.clone());
    let (outbox, io) = io::start(
        config,
        namespace.clone(),
        threads_stop.clone(),
        shared.clone(),
    )?;

    let result = tick::run(
        config,
        namespace,
        &shared,
        tick::Links {
            plans,
            retired,
            outbox,
        },
        stop,
    );
    threads_stop.store(true, Ordering::Relaxed);
    let service_result = join(service, "service");
    let io_result = join(io, "io");
    drop(watchdog);
    result.and(service_result).and(io_result)
}

fn join(handle: JoinHandle<anyhow::Result<()>>, name: &str) -> anyhow::Result<()> {
    handle
        .join()
        .unwrap_or_else(|_| Err(anyhow!("the {name} thread panicked")))
}
