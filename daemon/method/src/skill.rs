//! Demonstrations by the paper's III-B recipe and what is trained from them: per primitive
//! class, random start and end actuations around the class extremes, random intermediate
//! points, linear interpolation; each class trains one actuation-space and one task-space ProMP,
//! and all samples together form D_fwd for the forward model. Pure math.

use nalgebra::DMatrix;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use serde::{Deserialize, Serialize};

use crate::forward::ForwardModel;
use crate::promp::{Basis, Demonstration, Primitive, PrimitiveError, TrainConfig};
use crate::space::{Actuation, Position};

/// The extremes of one primitive class: where its motions start and end.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ClassExtremes {
    pub start: Actuation,
    pub end: Actuation,
}

/// How demonstrations are made.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct DemoRecipe {
    /// Demonstrations recorded per class (primitive).
    pub demos_per_class: usize,
    /// Length of each demonstration (s).
    pub duration_s: f64,
    /// Recorded samples per second.
    pub sample_rate_hz: f64,
    /// Start, end and intermediate points are drawn uniformly within ± this of their nominal.
    pub spread: f64,
    /// Random points between start and end.
    pub intermediate_points: usize,
    /// One primitive each: its nominal start and end actuations.
    pub classes: Vec<ClassExtremes>,
}

impl Default for DemoRecipe {
    fn default() -> Self {
        // Three motion classes of the two-module arm: a sweep of module 1 across the x–z
        // plane, a sweep that bends both modules the same way, and an S-shape.
        Self {
            demos_per_class: 20,
            duration_s: 4.0,
            sample_rate_hz: 50.0,
            spread: 0.1,
            intermediate_points: 2,
            classes: vec![
                ClassExtremes {
                    start: [0.2, 0.8, 0.8, 0.5, 0.5, 0.5],
                    end: [0.8, 0.3, 0.3, 0.5, 0.5, 0.5],
                },
                ClassExtremes {
                    start: [0.8, 0.2, 0.7, 0.7, 0.2, 0.6],
                    end: [0.6, 0.8, 0.2, 0.5, 0.8, 0.2],
                },
                ClassExtremes {
                    start: [0.3, 0.6, 0.8, 0.8, 0.5, 0.3],
                    end: [0.8, 0.5, 0.3, 0.3, 0.6, 0.8],
                },
            ],
        }
    }
}

impl DemoRecipe {
    /// Checks every field; the error is `demonstrations.KEY: message`. The bounds keep the
    /// demonstrations under an hour and their samples in memory.
    pub fn validate(&self) -> Result<(), String> {
        let bad = |key: &str, m: String| Err(format!("demonstrations.{key}: {m}"));
        let max_classes = crate::activation::MAX_PRIMITIVES;
        if self.classes.is_empty() || self.classes.len() > max_classes {
            return bad(
                "classes",
                format!(
                    "need 1 to {max_classes} classes, got {}",
                    self.classes.len()
                ),
            );
        }
        if !(2..=1000).contains(&self.demos_per_class) {
            return bad(
                "demos_per_class",
                format!("must be 2 to 1000, got {}", self.demos_per_class),
            );
        }
        if !(self.duration_s.is_finite() && self.duration_s > 0.0 && self.duration_s <= 600.0) {
            return bad(
                "duration_s",
                format!("must be in (0, 600] s, got {:?}", self.duration_s),
            );
        }
        if !(self.sample_rate_hz.is_finite()
            && self.sample_rate_hz > 0.0
            && self.sample_rate_hz <= 1000.0)
        {
            return bad(
                "sample_rate_hz",
                format!("must be in (0, 1000] Hz, got {:?}", self.sample_rate_hz),
            );
        }
        let per_demo = self.sample_rate_hz * self.duration_s;
        if !(10.0..=10_000.0).contains(&per_demo) {
            return bad(
                "sample_rate_hz",
                format!(
                    "{} Hz over duration_s = {} s makes {per_demo:.0} samples per \
                     demonstration; need 10 to 10000",
                    self.sample_rate_hz, self.duration_s
                ),
            );
        }
        let demos = self.classes.len() * self.demos_per_class;
        let total_s = demos as f64 * self.duration_s;
        if total_s > 3600.0 {
            return bad(
                "demos_per_class",
                format!(
                    "{demos} demonstrations of {} s take {total_s:.0} s; at most 3600 s in all",
                    self.duration_s
                ),
            );
        }
        if !(0.0..=0.5).contains(&self.spread) {
            return bad(
                "spread",
                format!("must be in [0, 0.5], got {:?}", self.spread),
            );
        }
        if self.intermediate_points > 100 {
            return bad(
                "intermediate_points",
                format!("must be 0 to 100, got {}", self.intermediate_points),
            );
        }
        for (i, c) in self.classes.iter().enumerate() {
            for (field, values) in [("start", &c.start), ("end", &c.end)] {
                if let Some(d) = values.iter().position(|v| !(0.0..=1.0).contains(v)) {
                    return bad(
                        &format!("classes[{i}].{field}"),
                        format!(
                            "actuator {} is {:?}; each must be in [0, 1]",
                            d + 1,
                            values[d]
                        ),
                    );
                }
            }
        }
        Ok(())
    }

    /// The actuation sequences to play, per class: (class, samples at `sample_rate_hz`).
    pub fn sequences(&self, seed: u64) -> Vec<(usize, Vec<Actuation>)> {
        let mut rng = StdRng::seed_from_u64(seed);
        let samples = (self.duration_s * self.sample_rate_hz).round() as usize + 1;
        let mut out = Vec::with_capacity(self.classes.len() * self.demos_per_class);
        for (class, ex) in self.classes.iter().enumerate() {
            for _ in 0..self.demos_per_class {
                let mut jitter = |nominal: Actuation| -> Actuation {
                    nominal
                        .map(|v| (v + rng.random_range(-self.spread..=self.spread)).clamp(0.0, 1.0))
                };
                let mut knots = vec![(0.0, jitter(ex.start))];
                for i in 1..=self.intermediate_points {
                    let f = i as f64 / (self.intermediate_points + 1) as f64;
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
    recipe
        .sequences(seed)
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
    use crate::pcc::ArmGeometry;

    #[test]
    fn recipe_makes_seeded_demos_around_the_class_extremes() {
        let recipe = DemoRecipe::default();
        recipe.validate().unwrap();
        let a = recipe.sequences(7);
        assert_eq!(a, recipe.sequences(7));
        assert_ne!(a, recipe.sequences(8));
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

    #[test]
    fn every_field_is_bounded_and_named() {
        let check = |edit: &dyn Fn(&mut DemoRecipe), want: &str| {
            let mut r = DemoRecipe::default();
            edit(&mut r);
            let e = r.validate().unwrap_err();
            assert!(e.starts_with(want), "{e} (wanted {want:?})");
        };
        check(
            &|r| r.demos_per_class = 1 << 40,
            "demonstrations.demos_per_class: must be 2 to 1000",
        );
        check(
            &|r| r.duration_s = 1e300,
            "demonstrations.duration_s: must be in (0, 600] s, got 1e300",
        );
        check(
            &|r| r.sample_rate_hz = f64::INFINITY,
            "demonstrations.sample_rate_hz: must be in (0, 1000] Hz",
        );
        check(
            &|r| r.sample_rate_hz = 1.0,
            "demonstrations.sample_rate_hz: 1 Hz over duration_s = 4 s makes 4 samples",
        );
        check(
            &|r| r.intermediate_points = usize::MAX,
            "demonstrations.intermediate_points: must be 0 to 100",
        );
        check(
            &|r| r.spread = f64::NAN,
            "demonstrations.spread: must be in [0, 0.5]",
        );
        check(
            &|r| r.classes.clear(),
            "demonstrations.classes: need 1 to 8 classes, got 0",
        );
        check(
            &|r| {
                r.demos_per_class = 1000;
                r.duration_s = 600.0;
                r.sample_rate_hz = 10.0;
            },
            "demonstrations.demos_per_class: 3000 demonstrations of 600 s take 1800000 s",
        );
        check(
            &|r| r.classes[1].end[3] = 1.5,
            "demonstrations.classes[1].end: actuator 4 is 1.5",
        );
        check(
            &|r| r.classes[2].start[0] = f64::NAN,
            "demonstrations.classes[2].start: actuator 1 is NaN",
        );
    }
}
