//! The paper's simulation pipeline, measured: III-B demonstrations from the PCC model, the RBF
//! forward model fitted on them, CACLA-MTL pre-trained against the forward model, then
//! evaluated against the PCC model on 200 held-out targets without exploration.
//!
//! `cargo run --release -p softarm-daemon --example convergence [-- SECONDS [SEED]]`

use std::time::{Duration, Instant};

use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use softarm_method::cacla::{CaclaMtl, LearnerConfig, PretrainConfig, evaluate, pretrain};
use softarm_method::forward::ForwardModel;
use softarm_method::pcc::ArmGeometry;
use softarm_method::rbf::{NetworkConfig, RbfNetwork};
use softarm_method::skill::{DemoRecipe, demonstrations, forward_data};

fn stats(name: &str, mut v: Vec<f64>) {
    v.sort_by(f64::total_cmp);
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt();
    let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
    println!(
        "{name:<34} mean {:6.2} ± {:5.2} mm  median {:6.2}  p90 {:6.2}  max {:6.2}",
        mean * 1e3,
        sd * 1e3,
        q(0.5) * 1e3,
        q(0.9) * 1e3,
        q(1.0) * 1e3
    );
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let budget = Duration::from_secs_f64(args.get(1).and_then(|s| s.parse().ok()).unwrap_or(60.0));
    let seed: u64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1);
    let arm = ArmGeometry::default();
    let recipe = DemoRecipe::default();

    let demos = demonstrations(&arm, &recipe, seed);
    let (acts, positions) = forward_data(&demos);
    let held_out = demonstrations(&arm, &recipe, seed + 1000);
    let (h_acts, h_pos) = forward_data(&held_out);

    let t = Instant::now();
    let net = RbfNetwork::fit(&acts, &positions, &NetworkConfig::default()).unwrap();
    println!(
        "forward model: {} centres, fitted on {} samples in {:.2?}",
        net.centres(),
        acts.len(),
        t.elapsed()
    );
    let fwd_err: Vec<f64> = h_acts
        .iter()
        .zip(&h_pos)
        .map(|(a, p)| {
            let y = net.position(a);
            (0..3).map(|d| (y[d] - p[d]).powi(2)).sum::<f64>().sqrt()
        })
        .collect();
    stats("forward model, held-out", fwd_err);

    let mut rng = StdRng::seed_from_u64(seed + 7);
    // Held-out targets inside the demonstrated subspace: positions of held-out demonstrations
    // within 10 mm of a training demonstration.
    let near = |p: &[f64; 3]| {
        positions
            .iter()
            .any(|q| (0..3).map(|d| (p[d] - q[d]).powi(2)).sum::<f64>() < 1e-4)
    };
    let (mut targets, mut outside) = (Vec::new(), 0);
    while targets.len() < 200 {
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
    let mut config: LearnerConfig = toml::from_str(&env("LEARNER")).expect("LEARNER");
    config.seed = seed;
    let pre: PretrainConfig = toml::from_str(&env("PRETRAIN")).expect("PRETRAIN");
    let mut learner = CaclaMtl::new(config).unwrap();
    stats(
        "untrained actor on PCC",
        evaluate(&mut learner, &arm, &targets),
    );
    let warm = std::env::var("WARM").map(|v| v != "0").unwrap_or(true);
    let t = Instant::now();
    if warm {
        learner.imitate(&positions, &acts, 3);
        stats(
            "after imitation on PCC",
            evaluate(&mut learner, &arm, &targets),
        );
    }
    let start = Instant::now();
    let mut next_report = Duration::from_secs(10);
    let report = pretrain(&mut learner, &net, &positions, &pre, |r| {
        let e = start.elapsed();
        if e >= next_report {
            next_report += Duration::from_secs(10);
            eprintln!(
                "  {:>4.0} s: {} epochs, {} updates",
                e.as_secs_f64(),
                r.epochs,
                r.updates
            );
        }
        t.elapsed() < budget
    });
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
    for i in 0..20_000 {
        // Five points visited in turn, a new set every 20 visits each.
        let target = targets[(i / 100 * 5 + i % 5) % targets.len()];
        let a = learner.act(i % 5, &target, true);
        let reached = arm.position(&a);
        let t = Instant::now();
        std::hint::black_box(learner.observe(i % 5, &target, &a, &reached));
        ns.push(t.elapsed().as_nanos() as f64);
    }
    ns.sort_by(f64::total_cmp);
    let q = |p: f64| ns[((ns.len() - 1) as f64 * p).round() as usize] / 1e3;
    println!(
        "learner update (observe): p50 {:.1} µs  p99 {:.1} µs  max {:.1} µs",
        q(0.5),
        q(0.99),
        q(1.0)
    );
}
