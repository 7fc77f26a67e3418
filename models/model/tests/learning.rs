//! CACLA-MTL learns: pre-trained against the RBF forward model (fitted on PCC demonstrations),
//! the actor puts the real (PCC) end effector on held-out targets far better than untrained,
//! and better than the demonstrations alone. Fixed seeds and a fixed number of epochs, so the
//! result is the same on every machine; small enough for a debug build. Full figures:
//! `cargo run --release -p softarm-model --example convergence`.

use softarm_kinematics::pcc;
use softarm_learning::cacla::{evaluate, pretrain};
use softarm_model::pipeline::{TrainingData, forward_model, imitation};
use softarm_sections::arm::ArmConfig;
use softarm_sections::demonstrations::DemoRecipe;
use softarm_sections::forward_model::NetworkConfig;
use softarm_sections::learner::LearnerConfig;
use softarm_sections::learner::PretrainConfig;

/// The default `[arm]`'s actuators.
const N: usize = 6;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

#[test]
fn pretraining_on_the_forward_model_reaches_held_out_targets_on_the_plant() {
    let config = ArmConfig::default();
    let arm = pcc::Arm::of_config(&config).unwrap();
    let recipe = DemoRecipe::default();
    let data = TrainingData::<N>::from_plant(&config, &recipe, 1).unwrap();
    let (acts, positions) = (&data.actuations, &data.positions);
    let (net, fit, _) = forward_model(
        acts,
        positions,
        &data.demo,
        &NetworkConfig {
            centres: 200,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(fit.mean_m < 0.002, "forward model held-out error {fit:?}");
    // Held-out targets: every 97th sample of demonstrations made with another seed, kept where
    // they lie inside the demonstrated subspace (within 10 mm of a training sample).
    let held_out = TrainingData::<N>::from_plant(&config, &recipe, 99)
        .unwrap()
        .positions;
    let targets: Vec<[f64; 3]> = held_out
        .iter()
        .step_by(97)
        .filter(|p| {
            positions
                .iter()
                .any(|q| (0..3).map(|d| (p[d] - q[d]).powi(2)).sum::<f64>() < 1e-4)
        })
        .copied()
        .collect();
    assert!(targets.len() > 100, "{}", targets.len());

    let mut untrained = imitation(LearnerConfig::default(), acts, positions, 0).unwrap();
    let untrained = evaluate(&mut untrained, &arm, &targets);
    let mut learner = imitation(LearnerConfig::default(), acts, positions, 3).unwrap();
    let imitated = evaluate(&mut learner, &arm, &targets);
    let config = PretrainConfig {
        max_epochs: 20_000,
        ..Default::default()
    };
    let report = pretrain(&mut learner, &net, positions, &config, |_| true);
    let trained = evaluate(&mut learner, &arm, &targets);
    let mm = |v: &[f64]| (mean(v) * 1e3, median(v.to_vec()) * 1e3);
    eprintln!(
        "untrained {:.1?} mm, imitated {:.1?} mm, trained {:.1?} mm (mean, median); {report:?}; forward model {fit:?}",
        mm(&untrained),
        mm(&imitated),
        mm(&trained)
    );
    assert!(mean(&trained) < 0.5 * mean(&untrained));
    assert!(
        median(trained.clone()) < 0.8 * median(imitated.clone()),
        "CACLA improves on the demonstrations"
    );
    assert!(mean(&trained) < 0.015, "mean {} mm", mean(&trained) * 1e3);
}
