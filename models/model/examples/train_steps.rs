//! Where training's time goes, step by step, on an arm's demonstrations from its kinematic
//! model at the stack's sample count (the demo's recipe: 8 demonstrations a class, 2.5 s each,
//! at the simulated tracker's 200 Hz): the primitives, the RBF forward model, the polynomial
//! kinematics, the imitation warm start (pre-training runs for its budget, `pretrain.budget_s`,
//! whatever the arm: not timed here), each with its seconds, the process's peak resident
//! memory after it, and the models' errors on held-out demonstrations.
//!
//! `cargo run --release -p softarm-model --example train_steps [-- ARM [SEED]]`, ARM `paper`
//! (the default `[arm]`; the default) or an `[arm]` file such as
//! `models/model/examples/sixteen-tendons.toml`.

use std::time::Instant;

use softarm_arm::Layout;
use softarm_kinematics::pcc::Arm;
use softarm_model::pipeline::{
    IMITATION_PASSES, TrainingData, forward_model, imitation, kinematics, primitives,
};
use softarm_sections::arm::ArmConfig;
use softarm_sections::demonstrations::DemoRecipe;
use softarm_sections::forward_model::NetworkConfig;
use softarm_sections::kinematics::PolynomialConfig;
use softarm_sections::learner::LearnerConfig;

/// The process's peak resident memory so far (MB), from /proc.
fn peak_mb() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    (status.lines())
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn timed<T>(what: &str, f: impl FnOnce() -> T) -> T {
    let start = Instant::now();
    let out = f();
    println!(
        "{what:>14}: {:7.2} s   (peak resident {:6.0} MB)",
        start.elapsed().as_secs_f64(),
        peak_mb()
    );
    out
}

fn run<const N: usize>(layout: &Layout, recipe: &DemoRecipe, seed: u64) -> anyhow::Result<()> {
    let arm = Arm::new(layout, &[]);
    let data = TrainingData::<N>::of_arm(layout, &arm, recipe, seed)?;
    let (a, p, d) = (&data.actuations, &data.positions, &data.demo);
    println!(
        "{N} actuators: {} demonstrations, {} samples",
        data.recordings.len(),
        a.len()
    );
    let all = Instant::now();
    timed("primitives", || primitives(&data.recordings, 15))?;
    let (_, forward, width) = timed("forward model", || {
        forward_model(a, p, d, &NetworkConfig::default())
    })?;
    let (poly, poly_error) = timed("kinematics", || {
        kinematics(a, p, d, &PolynomialConfig::default())
    })?;
    // The learner's box around the hanging arms measured here.
    let learner = LearnerConfig {
        workspace_min_m: [-0.65, -0.65, -0.7],
        workspace_max_m: [0.65, 0.65, 0.05],
        ..LearnerConfig::default()
    };
    timed("imitation", || imitation(learner, a, p, IMITATION_PASSES))?;
    println!(
        "{:>14}: {:7.2} s\nforward model (width {width}): held out {:.2} mm mean, {:.2} max; \
         kinematics (degree {}): held out {:.2} mm mean, {:.2} max",
        "all",
        all.elapsed().as_secs_f64(),
        forward.mean_m * 1e3,
        forward.max_m * 1e3,
        poly.degree(),
        poly_error.mean_m * 1e3,
        poly_error.max_m * 1e3
    );
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let arm = args.next().unwrap_or_else(|| "paper".into());
    let seed = args.next().map_or(Ok(1), |s| s.parse())?;
    let layout = if arm == "paper" {
        ArmConfig::default().layout().map_err(anyhow::Error::msg)?
    } else {
        Layout::new(&toml::from_str(&std::fs::read_to_string(&arm)?)?)
            .map_err(anyhow::Error::msg)?
    };
    let recipe = DemoRecipe {
        demos_per_class: 8,
        duration_s: 2.5,
        sample_rate_hz: 200.0,
        ..DemoRecipe::default()
    };
    match layout.actuators().len() {
        6 => run::<6>(&layout, &recipe, seed),
        9 => run::<9>(&layout, &recipe, seed),
        16 => run::<16>(&layout, &recipe, seed),
        n => anyhow::bail!("an arm of {n} actuators: this example runs 6, 9 or 16"),
    }
}
