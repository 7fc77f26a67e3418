//! `softarm bench`: single-call timings of the controller's hot paths, as percentiles.

use std::time::Instant;

use softarm_method::activation::ActivationConfig;
use softarm_method::cacla::{CaclaMtl, LearnerConfig, PretrainConfig, pretrain};
use softarm_method::engine::{Planner, Timeline};
use softarm_method::pcc::ArmGeometry;
use softarm_method::skill::{self, DemoRecipe};

#[derive(clap::Args)]
pub struct Args {
    /// Ticks to time.
    #[arg(long, default_value_t = 200_000)]
    ticks: usize,
    /// Re-conditionings to time.
    #[arg(long, default_value_t = 50)]
    reconditions: usize,
}

/// Sorted durations in ns → a min / p50 / p99 / p99.9 / max line.
fn summary(name: &str, mut ns: Vec<u64>) {
    ns.sort_unstable();
    let at = |q: f64| ns[((ns.len() - 1) as f64 * q).round() as usize];
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
        fmt(ns[0]),
        fmt(at(0.5)),
        fmt(at(0.99)),
        fmt(at(0.999)),
        fmt(ns[ns.len() - 1])
    );
}

pub fn run(args: &Args) -> Result<(), String> {
    if args.ticks == 0 || args.reconditions == 0 {
        return Err("--ticks and --reconditions must be > 0".into());
    }
    let arm = ArmGeometry::default();
    let recipe = DemoRecipe::default();
    let demos = skill::demonstrations(&arm, &recipe, 1);
    let (actuation, _task) = skill::train_primitives(&demos, 15).map_err(|e| e.to_string())?;
    let t_cond = [1.0, 3.0, 5.0, 7.0, 9.0];
    let planner = Planner::<6>::new(
        actuation,
        &t_cond,
        &[0, 1, 2, 1, 0],
        Timeline::new(10.0, 500.0).map_err(|e| e.to_string())?,
        ActivationConfig::default(),
        1e-6,
    )
    .map_err(|e| e.to_string())?;
    let (mut engine, mut replanner) = planner.start(&[[0.5; 6]; 5]).map_err(|e| e.to_string())?;
    let ticks = engine.timeline().ticks();
    println!(
        "softarm bench: N=5 conditioning points, M=3 primitives, D=6, K=15, 10 s at 500 Hz ({} cores)",
        std::thread::available_parallelism().map_or(0, |n| n.get())
    );

    let mut ns = Vec::with_capacity(args.ticks);
    let mut sink = 0.0;
    for i in 0..args.ticks {
        let start = Instant::now();
        let v = engine.tick(std::hint::black_box(i % ticks));
        ns.push(start.elapsed().as_nanos() as u64);
        sink += v[0];
    }
    summary("Eq. 11 tick", ns);

    let k3 = engine.timeline().tick_of(t_cond[3]);
    let mut ns = Vec::with_capacity(args.reconditions);
    for i in 0..args.reconditions {
        let a = [0.4 + 0.002 * i as f64; 6];
        let start = Instant::now();
        replanner.recondition(1, &a).map_err(|e| e.to_string())?;
        sink += engine.tick(k3)[0];
        ns.push(start.elapsed().as_nanos() as u64);
    }
    summary("re-condition one group + ready", ns);

    // A CACLA-MTL update at a conditioning point, five points visited in turn as in an
    // execution, on a learner warmed up by a short pre-training.
    let (acts, positions) = skill::forward_data(&demos);
    let mut learner = CaclaMtl::new(LearnerConfig::default())?;
    learner.imitate(&positions, &acts, 1);
    let warm = PretrainConfig {
        max_epochs: 2_000,
        ..Default::default()
    };
    pretrain(&mut learner, &arm, &positions, &warm, |_| true);
    let updates = args.ticks.min(100_000);
    let mut ns = Vec::with_capacity(updates);
    for i in 0..updates {
        let point = i % 5;
        let target = positions[(i / 100 * 5 + point) * 37 % positions.len()];
        let a = learner.act(point, &target, true);
        let reached = arm.position(&a);
        let start = Instant::now();
        let visit = learner.observe(point, &target, &a, &reached);
        ns.push(start.elapsed().as_nanos() as u64);
        sink += visit.error;
    }
    summary("CACLA-MTL update at a conditioning point", ns);
    std::hint::black_box(sink);
    Ok(())
}
