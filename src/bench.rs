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
