//! Demonstrations by the paper's III-B recipe and what is trained from them: per primitive
//! class, random start and end actuations around the class extremes, random intermediate
//! points, linear interpolation; each class trains one actuation-space and one task-space ProMP,
//! and all samples together form D_fwd for the forward model. Pure math.

use nalgebra::DMatrix;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use softarm_kinematics::forward::ForwardModel;
use softarm_sections::demonstrations::DemoRecipe;

use crate::promp::{Basis, Demonstration, Primitive, PrimitiveError, TrainConfig};
use crate::space::{Actuation, Position};

/// The actuation sequences to play of `recipe`, per class: (class, samples at
/// `sample_rate_hz`).
pub fn sequences(recipe: &DemoRecipe, seed: u64) -> Vec<(usize, Vec<Actuation>)> {
    let mut rng = StdRng::seed_from_u64(seed);
    let samples = (recipe.duration_s * recipe.sample_rate_hz).round() as usize + 1;
    let mut out = Vec::with_capacity(recipe.classes.len() * recipe.demos_per_class);
    for (class, ex) in recipe.classes.iter().enumerate() {
        for _ in 0..recipe.demos_per_class {
            let mut jitter = |nominal: Actuation| -> Actuation {
                nominal
                    .map(|v| (v + rng.random_range(-recipe.spread..=recipe.spread)).clamp(0.0, 1.0))
            };
            let mut knots = vec![(0.0, jitter(ex.start))];
            for i in 1..=recipe.intermediate_points {
                let f = i as f64 / (recipe.intermediate_points + 1) as f64;
                let nominal: Actuation =
                    std::array::from_fn(|d| ex.start[d] + f * (ex.end[d] - ex.start[d]));
                knots.push((f, jitter(nominal)));
            }
            knots.push((1.0, jitter(ex.end)));
            let seq = (0..samples)
                .map(|s| interpolate(&knots, s as f64 / (samples - 1) as f64))
                .collect();
            out.push((class, seq));
        }
    }
    out
}

/// Piecewise-linear interpolation through (phase, actuation) knots.
fn interpolate(knots: &[(f64, Actuation)], z: f64) -> Actuation {
    let i = knots
        .windows(2)
        .position(|w| z <= w[1].0)
        .unwrap_or(knots.len() - 2);
    let (z0, a0) = knots[i];
    let (z1, a1) = knots[i + 1];
    let f = ((z - z0) / (z1 - z0)).clamp(0.0, 1.0);
    std::array::from_fn(|d| a0[d] + f * (a1[d] - a0[d]))
}

/// One recorded demonstration: what was commanded and where the end effector went.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    pub class: usize,
    pub times: Vec<f64>,
    pub actuation: Vec<Actuation>,
    pub position: Vec<Position>,
}

/// Plays the recipe's sequences through a forward model (the kinematic plant) and records.
pub fn demonstrations(model: &impl ForwardModel, recipe: &DemoRecipe, seed: u64) -> Vec<Recording> {
    let dt = 1.0 / recipe.sample_rate_hz;
    sequences(recipe, seed)
        .into_iter()
        .map(|(class, actuation)| Recording {
            class,
            times: (0..actuation.len()).map(|i| i as f64 * dt).collect(),
            position: actuation.iter().map(|a| model.position(a)).collect(),
            actuation,
        })
        .collect()
}

/// Trains one actuation-space (6 DoF) and one task-space (3 DoF) primitive per class.
pub fn train_primitives(
    recordings: &[Recording],
    basis_functions: usize,
) -> Result<(Vec<Primitive>, Vec<Primitive>), PrimitiveError> {
    let classes = recordings.iter().map(|r| r.class + 1).max().unwrap_or(0);
    let basis = Basis::new(basis_functions, None)?;
    let config = TrainConfig::default();
    let mut actuation = Vec::with_capacity(classes);
    let mut task = Vec::with_capacity(classes);
    for class in 0..classes {
        let mine: Vec<&Recording> = recordings.iter().filter(|r| r.class == class).collect();
        let demo =
            |values: DMatrix<f64>, r: &Recording| Demonstration::new(r.times.clone(), values);
        let a: Vec<Demonstration> = mine
            .iter()
            .map(|r| {
                demo(
                    DMatrix::from_fn(r.times.len(), 6, |i, d| r.actuation[i][d]),
                    r,
                )
            })
            .collect();
        let p: Vec<Demonstration> = mine
            .iter()
            .map(|r| {
                demo(
                    DMatrix::from_fn(r.times.len(), 3, |i, d| r.position[i][d]),
                    r,
                )
            })
            .collect();
        actuation.push(Primitive::train(basis.clone(), &a, &config)?);
        task.push(Primitive::train(basis.clone(), &p, &config)?);
    }
    Ok((actuation, task))
}

/// All (actuation, position) samples: D_fwd.
pub fn forward_data(recordings: &[Recording]) -> (Vec<Actuation>, Vec<Position>) {
    let a = recordings
        .iter()
        .flat_map(|r| r.actuation.iter().copied())
        .collect();
    let p = recordings
        .iter()
        .flat_map(|r| r.position.iter().copied())
        .collect();
    (a, p)
}

#[cfg(test)]
mod tests {
    use super::*;
    use softarm_sections::arm::ArmGeometry;

    #[test]
    fn recipe_makes_seeded_demos_around_the_class_extremes() {
        let recipe = DemoRecipe::default();
        recipe.validate().unwrap();
        let a = sequences(&recipe, 7);
        assert_eq!(a, sequences(&recipe, 7));
        assert_ne!(a, sequences(&recipe, 8));
        assert_eq!(a.len(), 60);
        for (class, seq) in &a {
            let ex = recipe.classes[*class];
            assert_eq!(seq.len(), 201);
            for d in 0..6 {
                assert!((seq[0][d] - ex.start[d]).abs() <= 0.1 + 1e-12);
                assert!((seq[200][d] - ex.end[d]).abs() <= 0.1 + 1e-12);
            }
            assert!(seq.iter().flatten().all(|v| (0.0..=1.0).contains(v)));
        }
    }

    #[test]
    fn trains_a_primitive_pair_per_class() {
        let arm = ArmGeometry::default();
        let recs = demonstrations(&arm, &DemoRecipe::default(), 1);
        let (act, task) = train_primitives(&recs, 15).unwrap();
        assert_eq!((act.len(), task.len()), (3, 3));
        assert_eq!((act[0].dofs(), task[0].dofs()), (6, 3));
        // The task-space mean at the end of class 0 is where its nominal end actuation goes.
        let end = task[0].marginal(1.0).mean;
        let nominal = arm.position(&DemoRecipe::default().classes[0].end);
        let err = (0..3)
            .map(|d| (end[d] - nominal[d]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(err < 0.03, "{err}");
        let bad = DemoRecipe {
            spread: 0.9,
            ..Default::default()
        };
        assert!(bad.validate().unwrap_err().contains("spread"));
    }
}
