//! `softarm bench`: single-call timings of the controller's hot paths, as percentiles.

use std::time::Instant;

use hdrhistogram::Histogram;
use softarm_method::activation::ActivationConfig;
use softarm_method::cacla::{LearnerConfig, PretrainConfig};
use softarm_method::engine::{Planner, Timeline};
use softarm_method::pcc::ArmGeometry;
use softarm_method::rbf::NetworkConfig;
use softarm_method::skill::DemoRecipe;
use softarm_model::pipeline::{self, Training, TrainingData};

#[derive(clap::Args)]
pub struct Args {
    /// Ticks to time.
    #[arg(long, default_value_t = 200_000)]
    ticks: usize,
    /// Re-conditionings to time.
    #[arg(long, default_value_t = 50)]
    reconditions: usize,
    /// Instead of the hot paths: a bare loop on absolute deadlines (clock_nanosleep, as the
    /// controller's tick) for this many seconds, and its wake-up latency. Run it beside a
    /// running stack to see what the controller's own latency (`softarm status`) adds.
    #[arg(long, value_name = "SECONDS")]
    wakeup: Option<f64>,
    /// The bare loop's rate.
    #[arg(long, default_value_t = 500.0)]
    rate_hz: f64,
    /// Runs the bare loop with SCHED_FIFO at this priority (needs CAP_SYS_NICE).
    #[arg(long, value_name = "PRIORITY")]
    fifo: Option<i32>,
}

/// A bare absolute-deadline loop: the wake-up latency of each period, as the tick records it.
fn wakeup(seconds: f64, rate_hz: f64, fifo: Option<i32>) -> anyhow::Result<()> {
    if !(seconds > 0.0 && seconds <= 3600.0 && (1.0..=10_000.0).contains(&rate_hz)) {
        anyhow::bail!("--wakeup must be in (0, 3600] s and --rate-hz in [1, 10000]");
    }
    if let Some(priority) = fifo {
        let param = nix::libc::sched_param {
            sched_priority: priority,
        };
        // SAFETY: plain syscall on this thread with a valid parameter struct.
        if unsafe { nix::libc::sched_setscheduler(0, nix::libc::SCHED_FIFO, &param) } != 0 {
            anyhow::bail!(
                "SCHED_FIFO priority {priority} refused: {}",
                std::io::Error::last_os_error()
            );
        }
    }
    let periods = (seconds * rate_hz).round() as u64;
    let mut ticker = softarm_ipc::clock::Ticker::new(rate_hz);
    let mut ns = histogram();
    for _ in 0..periods {
        ns.saturating_record(ticker.wait().latency_ns.max(1));
    }
    summary(
        &format!(
            "bare loop wake-up, {rate_hz} Hz, {}",
            fifo.map_or("normal scheduling".to_string(), |p| format!(
                "SCHED_FIFO {p}"
            ))
        ),
        &ns,
    );
    println!("overruns (periods skipped): {}", ticker.overruns());
    Ok(())
}

/// Durations in ns → a min / p50 / p99 / p99.9 / max line (3 significant digits).
fn summary(name: &str, ns: &Histogram<u64>) {
    let fmt = |v: u64| {
        if v >= 1_000_000 {
            format!("{:.2} ms", v as f64 / 1e6)
        } else if v >= 1_000 {
            format!("{:.2} µs", v as f64 / 1e3)
        } else {
            format!("{v} ns")
        }
    };
    println!(
        "{name:<44} n={:<7} min {:>9}  p50 {:>9}  p99 {:>9}  p99.9 {:>9}  max {:>9}",
        ns.len(),
        fmt(ns.min()),
        fmt(ns.value_at_quantile(0.5)),
        fmt(ns.value_at_quantile(0.99)),
        fmt(ns.value_at_quantile(0.999)),
        fmt(ns.max())
    );
}

/// An empty histogram of durations from 1 ns to an hour, in ns.
fn histogram() -> Histogram<u64> {
    Histogram::new_with_bounds(1, 3_600_000_000_000, 3).expect("valid bounds")
}

/// Records `start.elapsed()` (beyond the bounds: clamped to them).
fn record(ns: &mut Histogram<u64>, start: Instant) {
    let v = u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX);
    ns.saturating_record(v);
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    if let Some(seconds) = args.wakeup {
        return wakeup(seconds, args.rate_hz, args.fifo);
    }
    if args.ticks == 0 || args.reconditions == 0 {
        anyhow::bail!("--ticks and --reconditions must be > 0");
    }
    let arm = ArmGeometry::default();
    let recipe = DemoRecipe::default();
    let demos = TrainingData::from_plant(&arm, &recipe, 1)?;
    let (actuation, _task) = pipeline::primitives(&demos.recordings, 15)?;
    let t_cond = [1.0, 3.0, 5.0, 7.0, 9.0];
    let planner = Planner::<6>::new(
        actuation,
        &t_cond,
        &[0, 1, 2, 1, 0],
        Timeline::new(10.0, 500.0)?,
        ActivationConfig::default(),
        1e-6,
    )?;
    let (mut engine, mut replanner) = planner.start(&[[0.5; 6]; 5])?;
    let ticks = engine.timeline().ticks();
    println!(
        "softarm bench: N=5 conditioning points, M=3 primitives, D=6, K=15, 10 s at 500 Hz ({} cores)",
        std::thread::available_parallelism().map_or(0, |n| n.get())
    );

    let mut ns = histogram();
    let mut sink = 0.0;
    for i in 0..args.ticks {
        let start = Instant::now();
        let v = engine.tick(std::hint::black_box(i % ticks));
        record(&mut ns, start);
        sink += v[0];
    }
    summary("Eq. 11 tick", &ns);

    let k3 = engine.timeline().tick_of(t_cond[3]);
    let mut ns = histogram();
    for i in 0..args.reconditions {
        let a = [0.4 + 0.002 * i as f64; 6];
        let start = Instant::now();
        replanner.recondition(1, &a)?;
        sink += engine.tick(k3)[0];
        record(&mut ns, start);
    }
    summary("re-condition one group + ready", &ns);

    // A CACLA-MTL update at a conditioning point, five points visited in turn as in an
    // execution, on a learner warmed up by one imitation pass and a short pre-training on the
    // kinematic model.
    let warm = Training {
        basis_functions: 15,
        forward: NetworkConfig::default(),
        kinematics: Default::default(),
        learner: LearnerConfig::default(),
        pretrain: PretrainConfig {
            max_epochs: 2_000,
            ..Default::default()
        },
        imitation_passes: 1,
    };
    let positions = &demos.positions;
    let (mut learner, _) = pipeline::learner(&warm, &arm, &demos.actuations, positions, |_| true)?;
    let updates = args.ticks.min(100_000);
    let mut ns = histogram();
    for i in 0..updates {
        let point = i % 5;
        let target = positions[(i / 100 * 5 + point) * 37 % positions.len()];
        let a = learner.act(point, &target, true);
        let reached = arm.position(&a);
        let start = Instant::now();
        let visit = learner.observe(point, &target, &a, &reached);
        record(&mut ns, start);
        sink += visit.error;
    }
    summary("CACLA-MTL update at a conditioning point", &ns);
    std::hint::black_box(sink);
    Ok(())
}
