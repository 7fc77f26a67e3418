//! The paper's simulation pipeline, measured on the default `[arm]` (the paper's arm): III-B
//! demonstrations from its PCC model, the RBF forward model fitted on them, CACLA-MTL
//! warm-started by imitation and pre-trained against the forward model (the steps of
//! `softarm_model::pipeline`, as `softarm train` runs them), then evaluated against the PCC
//! model on 200 held-out targets without exploration.
//!
//! `cargo run --release -p softarm-model --example convergence [-- SECONDS [SEED]]`

use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use hdrhistogram::Histogram;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use softarm_kinematics::forward::ForwardModel;
use softarm_kinematics::pcc;
use softarm_learning::cacla::evaluate;
use softarm_method::space::distance;
use softarm_model::pipeline::{
    IMITATION_PASSES, Training, TrainingData, forward_model, imitation, learner,
};
use softarm_sections::arm::ArmConfig;
use softarm_sections::demonstrations::DemoRecipe;
use softarm_sections::forward_model::NetworkConfig;
use softarm_sections::learner::LearnerConfig;
use softarm_sections::learner::PretrainConfig;

/// The default `[arm]`'s actuators.
const N: usize = 6;

/// Values on a 3-significant-digit histogram.
fn histogram(values: impl IntoIterator<Item = u64>) -> Histogram<u64> {
    let mut h = Histogram::new(3).expect("3 significant digits");
    for v in values {
        h.record(v).expect("an auto-resizing histogram");
    }
    h
}

/// Errors (m) → mean ± sd, median, p90 and max in mm.
fn stats(name: &str, errors: Vec<f64>) {
    let nm = histogram(errors.iter().map(|e| (e * 1e9).round() as u64));
    let mm = |v: f64| v / 1e6;
    println!(
        "{name:<34} mean {:6.2} ± {:5.2} mm  median {:6.2}  p90 {:6.2}  max {:6.2}",
        mm(nm.mean()),
        mm(nm.stdev()),
        mm(nm.value_at_quantile(0.5) as f64),
        mm(nm.value_at_quantile(0.9) as f64),
        mm(nm.max() as f64)
    );
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let budget_s: f64 = match args.get(1) {
        Some(s) => s.parse().context("SECONDS must be a number")?,
        None => 60.0,
    };
    let budget = Duration::try_from_secs_f64(budget_s)
        .with_context(|| format!("SECONDS must be a duration >= 0, got {budget_s}"))?;
    let seed: u64 = match args.get(2) {
        Some(s) => s.parse().context("SEED must be a whole number >= 0")?,
        None => 1,
    };
    let config = ArmConfig::default();
    let arm = pcc::Arm::of_config(&config).map_err(anyhow::Error::msg)?;
    let recipe = DemoRecipe::default();

    let data = TrainingData::<N>::from_plant(&config, &recipe, seed)?;
    let (acts, positions) = (&data.actuations, &data.positions);
    let held_out = TrainingData::<N>::from_plant(&config, &recipe, seed.wrapping_add(1000))?;

    let t = Instant::now();
    let (net, fifth, _) = forward_model(acts, positions, &data.demo, &NetworkConfig::default())?;
    println!(
        "forward model: {} centres, fitted on {} samples in {:.2?} (with the held-out fit); every 5th demonstration held out: mean {:.2} mm, max {:.2} mm",
        net.centres(),
        acts.len(),
        t.elapsed(),
        fifth.mean_m * 1e3,
        fifth.max_m * 1e3
    );
    let fwd_err: Vec<f64> = held_out
        .actuations
        .iter()
        .zip(&held_out.positions)
        .map(|(a, p)| distance(&net.position(a), p))
        .collect();
    stats("forward model, held-out", fwd_err);

    let mut rng = StdRng::seed_from_u64(seed.wrapping_add(7));
    // Held-out targets inside the demonstrated subspace: positions of held-out demonstrations
    // within 10 mm of a training demonstration.
    let near = |p: &[f64; 3]| positions.iter().any(|q| distance(p, q) < 0.01);
    let h_pos = &held_out.positions;
    let (mut targets, mut outside) = (Vec::new(), 0);
    while targets.len() < 200 {
        if outside > 1_000_000 {
            bail!("fewer than 200 held-out positions lie within 10 mm of a demonstration");
        }
        let p = h_pos[rng.random_range(0..h_pos.len())];
        if near(&p) {
            targets.push(p)
        } else {
            outside += 1
        }
    }
    println!(
        "held-out targets: 200 inside the demonstrated subspace ({outside} drawn outside it and skipped)"
    );

    // Overrides for experiments, as TOML: LEARNER='alpha_actor = 0.1', PRETRAIN='...'.
    let env = |k: &str| std::env::var(k).unwrap_or_default().replace(';', "\n");
    let mut config: LearnerConfig =
        toml::from_str(&env("LEARNER")).context("LEARNER: not [learner] keys")?;
    config.seed = seed;
    let pre: PretrainConfig =
        toml::from_str(&env("PRETRAIN")).context("PRETRAIN: not [pretrain] keys")?;
    let warm = std::env::var("WARM").map(|v| v != "0").unwrap_or(true);
    let training = Training {
        basis_functions: 15,
        forward: NetworkConfig::default(),
        kinematics: Default::default(),
        learner: config,
        pretrain: pre,
        imitation_passes: if warm { IMITATION_PASSES } else { 0 },
    };
    let mut untrained = imitation(config, acts, positions, 0)?;
    stats(
        "untrained actor on PCC",
        evaluate(&mut untrained, &arm, &targets),
    );
    if warm {
        let mut imitated = imitation(config, acts, positions, training.imitation_passes)?;
        stats(
            "after imitation on PCC",
            evaluate(&mut imitated, &arm, &targets),
        );
    }
    let t = Instant::now();
    let mut next_report = Duration::from_secs(10);
    let (mut learner, report) = learner(&training, &net, acts, positions, |r| {
        let e = t.elapsed();
        if e >= next_report {
            next_report += Duration::from_secs(10);
            eprintln!(
                "  {:>4.0} s: {} epochs, {} updates",
                e.as_secs_f64(),
                r.epochs,
                r.updates
            );
        }
        e < budget
    })?;
    println!(
        "pre-training: {:.1} s, {} epochs ({} converged), {} updates, centres stored {:?}",
        t.elapsed().as_secs_f64(),
        report.epochs,
        report.converged_epochs,
        report.updates,
        learner.stored_centres()
    );
    stats(
        "trained actor on PCC",
        evaluate(&mut learner, &arm, &targets),
    );
    stats(
        "trained actor on forward model",
        evaluate(&mut learner, &net, &targets),
    );

    // Update latency: one visit (act + observe) at a conditioning point.
    let mut ns = Vec::with_capacity(20_000);
    let mut memory = [None; 5];
    for i in 0..20_000 {
        // Five points visited in turn, a new set every 20 visits each.
        let target = targets[(i / 100 * 5 + i % 5) % targets.len()];
        let memory = &mut memory[i % 5];
        let a = learner.act(memory.as_ref(), &target, true);
        let reached = arm.position(&a);
        let t = Instant::now();
        std::hint::black_box(learner.observe(memory, &target, &a, &reached));
        ns.push(t.elapsed().as_nanos() as u64);
    }
    let ns = histogram(ns);
    let us = |v: u64| v as f64 / 1e3;
    println!(
        "learner update (observe): p50 {:.1} µs  p99 {:.1} µs  max {:.1} µs",
        us(ns.value_at_quantile(0.5)),
        us(ns.value_at_quantile(0.99)),
        us(ns.max())
    );
    Ok(())
}
