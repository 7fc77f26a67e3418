//! Demonstrations by the paper's III-B recipe and what is trained from them: per primitive
//! class, random start and end actuations around the class extremes, random intermediate
//! points, linear interpolation; each class trains one actuation-space and one task-space ProMP,
//! and all samples together form D_fwd for the forward model. For an arm of any `N` actuators:
//! a recipe without classes takes them from the arm ([`classes`]). Pure math.

use nalgebra::DMatrix;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use softarm_arm::{Kind, Layout};
use softarm_kinematics::forward::ForwardModel;
use softarm_sections::activation::MAX_PRIMITIVES;
use softarm_sections::demonstrations::{ClassExtremes, DemoRecipe, derived_classes};

use crate::promp::{Basis, Demonstration, Primitive, PrimitiveError, TrainConfig};
use crate::space::Position;

/// How far a derived class bends a module from the middle of its strokes (normalised).
const SWEEP: f64 = 0.3;

/// The recipe's classes on `arm`: those it gives, else the paper's three on the paper's kind of
/// arm (two soft modules of three evenly spaced tendons ending in their module), else derived:
/// for each module a sweep from bending one way to bending the opposite way, then all modules
/// bent the same way and, with more than one, an S (each bent opposite to the one before);
/// at most [`MAX_PRIMITIVES`].
pub fn classes(recipe: &DemoRecipe, arm: &Layout) -> Vec<ClassExtremes> {
    if let Some(given) = &recipe.classes {
        return given.clone();
    }
    if arm.is_papers_kind() {
        return DemoRecipe::paper_classes();
    }
    let modules = arm.modules().len();
    // (direction each module bends at the start: None for straight), per class.
    let mut plans: Vec<Vec<Option<f64>>> = (0..modules)
        .map(|m| (0..modules).map(|k| (k == m).then_some(0.0)).collect())
        .collect();
    plans.push(vec![Some(0.0); modules]);
    if modules > 1 {
        plans.push(
            (0..modules)
                .map(|k| Some(std::f64::consts::PI * (k % 2) as f64))
                .collect(),
        );
    }
    plans.truncate(MAX_PRIMITIVES);
    debug_assert_eq!(plans.len(), derived_classes(arm));
    plans
        .into_iter()
        .enumerate()
        .map(|(c, plan)| {
            // Each class in a plane of its own, so the classes cover the workspace around.
            let phi = std::f64::consts::TAU * c as f64 / (modules + 2) as f64;
            let at = |sign: f64| bent(arm, &plan, phi, sign);
            ClassExtremes {
                start: at(1.0),
                end: at(-1.0),
            }
        })
        .collect()
}

/// The normalised actuation that bends each module of `plan` towards `phi` + its own
/// direction (away from it for `sign` = −1), the others left at the middle of their strokes: a
/// tendon shortens on the side it bends towards, a chamber off the axis lengthens opposite it,
/// one on the axis stays.
fn bent(arm: &Layout, plan: &[Option<f64>], phi: f64, sign: f64) -> Vec<f64> {
    arm.actuators()
        .iter()
        .map(|a| {
            let Some(offset) = plan[a.module] else {
                return 0.5;
            };
            let toward = (a.angle_rad - (phi + offset)).cos();
            let pull = match a.kind {
                _ if a.radius_m == 0.0 => 0.0,
                Kind::Tendon => -toward,
                Kind::Chamber => toward,
            };
            (0.5 + sign * SWEEP * pull).clamp(0.0, 1.0)
        })
        .collect()
}

/// The actuation sequences to play of `recipe` with `classes` ([`classes`]), per class:
/// (class, samples at `sample_rate_hz`), `N` actuators each.
pub fn sequences<const N: usize>(
    recipe: &DemoRecipe,
    classes: &[ClassExtremes],
    seed: u64,
) -> Vec<(usize, Vec<[f64; N]>)> {
    let mut rng = StdRng::seed_from_u64(seed);
    let samples = (recipe.duration_s * recipe.sample_rate_hz).round() as usize + 1;
    let mut out = Vec::with_capacity(classes.len() * recipe.demos_per_class);
    let fixed = |v: &[f64]| -> [f64; N] { std::array::from_fn(|d| v[d]) };
    for (class, ex) in classes.iter().enumerate() {
        let (start, end) = (fixed(&ex.start), fixed(&ex.end));
        for _ in 0..recipe.demos_per_class {
            let mut jitter = |nominal: [f64; N]| -> [f64; N] {
                nominal
                    .map(|v| (v + rng.random_range(-recipe.spread..=recipe.spread)).clamp(0.0, 1.0))
            };
            let mut knots = vec![(0.0, jitter(start))];
            for i in 1..=recipe.intermediate_points {
                let f = i as f64 / (recipe.intermediate_points + 1) as f64;
                let nominal: [f64; N] = std::array::from_fn(|d| start[d] + f * (end[d] - start[d]));
                knots.push((f, jitter(nominal)));
            }
            knots.push((1.0, jitter(end)));
            let seq = (0..samples)
                .map(|s| interpolate(&knots, s as f64 / (samples - 1) as f64))
                .collect();
            out.push((class, seq));
        }
    }
    out
}

/// Piecewise-linear interpolation through (phase, actuation) knots.
fn interpolate<const N: usize>(knots: &[(f64, [f64; N])], z: f64) -> [f64; N] {
    let i = knots
        .windows(2)
        .position(|w| z <= w[1].0)
        .unwrap_or(knots.len() - 2);
    let (z0, a0) = knots[i];
    let (z1, a1) = knots[i + 1];
    let f = ((z - z0) / (z1 - z0)).clamp(0.0, 1.0);
    std::array::from_fn(|d| a0[d] + f * (a1[d] - a0[d]))
}

/// Where the demo set's points lie on the demonstrations: three along the first class's path,
/// two along the second's, (class of the two, phase), as the paper's demo set lies on its
/// classes 1 and 2. Never a class's middle: a derived class sweeps through the straight arm
/// there, the edge of the arm's reach, which any change that shortens the arm takes out of
/// reach (seen: a TDCR with a tool 5 mm shorter, its learner chasing a point it could not
/// reach, 7 to 12 mm off for nine executions).
const DEMO_PHASES: [(usize, f64); 5] = [(0, 0.2), (0, 0.35), (0, 0.75), (1, 0.7), (1, 0.85)];

/// A way-point for each of [`DEMO_PHASES`] on the nominal demonstrations of `classes` (start to
/// end, as [`sequences`] plays them without the jitter), through the kinematics `arm`: on the
/// two classes whose paths carry the end effector farthest, the farther first. Every point
/// lies where a primitive was trained, so a set of them is one the arm can pass through; what
/// `softarm demo` runs on an arm without a set of its own.
pub fn demo_points<const N: usize>(
    classes: &[ClassExtremes],
    arm: &impl ForwardModel<N>,
) -> Vec<Position> {
    demo_points_along(classes.len(), |class, f| {
        let c = &classes[class];
        arm.position(&std::array::from_fn(|d| {
            c.start[d] + f * (c.end[d] - c.start[d])
        }))
    })
}

/// [`demo_points`] where the arm went in training: each class's path is the mean of its
/// task-space primitive `task[class]` (where the tracker saw the end effector over the class's
/// demonstrations, phase for phase), not a model's prediction, which on an arm the model fits
/// less well can put a point where the arm never goes.
pub fn demo_points_seen(task: &[Primitive]) -> Vec<Position> {
    demo_points_along(task.len(), |class, f| {
        let mean = task[class].marginal(f).mean;
        [mean[0], mean[1], mean[2]]
    })
}

/// The points of [`DEMO_PHASES`] on `classes` paths, `along(class, phase)` being where a class's
/// path is at a phase in [0, 1].
fn demo_points_along(classes: usize, along: impl Fn(usize, f64) -> Position) -> Vec<Position> {
    let travel = |c: usize| -> f64 {
        (1..=20)
            .map(|i| {
                let (a, b) = (along(c, (i - 1) as f64 / 20.0), along(c, i as f64 / 20.0));
                crate::space::distance(&a, &b)
            })
            .sum()
    };
    let mut order: Vec<(usize, f64)> = (0..classes).map(travel).enumerate().collect();
    order.sort_by(|x, y| y.1.total_cmp(&x.1));
    let pick = [order[0].0, order[order.len().min(2) - 1].0];
    DEMO_PHASES
        .iter()
        .map(|&(k, f)| along(pick[k], f))
        .collect()
}

/// One recorded demonstration: what was commanded and where the end effector went.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording<const N: usize> {
    pub class: usize,
    pub times: Vec<f64>,
    pub actuation: Vec<[f64; N]>,
    pub position: Vec<Position>,
}

/// Plays the recipe's sequences with `classes` through a forward model (the kinematic plant)
/// and records.
pub fn demonstrations<const N: usize>(
    model: &impl ForwardModel<N>,
    recipe: &DemoRecipe,
    classes: &[ClassExtremes],
    seed: u64,
) -> Vec<Recording<N>> {
    let dt = 1.0 / recipe.sample_rate_hz;
    sequences(recipe, classes, seed)
        .into_iter()
        .map(|(class, actuation)| Recording {
            class,
            times: (0..actuation.len()).map(|i| i as f64 * dt).collect(),
            position: actuation.iter().map(|a| model.position(a)).collect(),
            actuation,
        })
        .collect()
}

/// Trains one actuation-space (`N` DoF) and one task-space (3 DoF) primitive per class.
pub fn train_primitives<const N: usize>(
    recordings: &[Recording<N>],
    basis_functions: usize,
) -> Result<(Vec<Primitive>, Vec<Primitive>), PrimitiveError> {
    let classes = recordings.iter().map(|r| r.class + 1).max().unwrap_or(0);
    let basis = Basis::new(basis_functions, None)?;
    let config = TrainConfig::default();
    let mut actuation = Vec::with_capacity(classes);
    let mut task = Vec::with_capacity(classes);
    for class in 0..classes {
        let mine: Vec<&Recording<N>> = recordings.iter().filter(|r| r.class == class).collect();
        let demo =
            |values: DMatrix<f64>, r: &Recording<N>| Demonstration::new(r.times.clone(), values);
        let a: Vec<Demonstration> = mine
            .iter()
            .map(|r| {
                demo(
                    DMatrix::from_fn(r.times.len(), N, |i, d| r.actuation[i][d]),
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
pub fn forward_data<const N: usize>(recordings: &[Recording<N>]) -> (Vec<[f64; N]>, Vec<Position>) {
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
    use softarm_kinematics::pcc;
    use softarm_sections::arm::ArmConfig;

    /// The default `[arm]`'s actuators.
    const N: usize = 6;

    /// The default `[arm]`.
    fn default_arm() -> ArmConfig {
        ArmConfig::default()
    }

    #[test]
    fn recipe_makes_seeded_demos_around_the_class_extremes() {
        let recipe = DemoRecipe::default();
        let layout = default_arm().layout().unwrap();
        recipe.validate(&layout).unwrap();
        let classes = classes(&recipe, &layout);
        assert_eq!(classes, DemoRecipe::paper_classes());
        let a = sequences::<N>(&recipe, &classes, 7);
        assert_eq!(a, sequences(&recipe, &classes, 7));
        assert_ne!(a, sequences(&recipe, &classes, 8));
        assert_eq!(a.len(), 60);
        for (class, seq) in &a {
            let ex = &classes[*class];
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
        let arm = pcc::Arm::of_config(&default_arm()).unwrap();
        let classes = DemoRecipe::paper_classes();
        let recs = demonstrations::<N>(&arm, &DemoRecipe::default(), &classes, 1);
        let (act, task) = train_primitives(&recs, 15).unwrap();
        assert_eq!((act.len(), task.len()), (3, 3));
        assert_eq!((act[0].dofs(), task[0].dofs()), (6, 3));
        // The task-space mean at the end of class 0 is where its nominal end actuation goes.
        let end = task[0].marginal(1.0).mean;
        let nominal =
            ForwardModel::<N>::position(&arm, &std::array::from_fn(|d| classes[0].end[d]));
        let err = (0..3)
            .map(|d| (end[d] - nominal[d]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(err < 0.03, "{err}");
        let bad = DemoRecipe {
            spread: 0.9,
            ..Default::default()
        };
        let layout = default_arm().layout().unwrap();
        assert!(bad.validate(&layout).unwrap_err().contains("spread"));
    }

    fn shipped(name: &str) -> Layout {
        let text = match name {
            "tdcr" => include_str!("../../../config/arms/tdcr.toml"),
            "hybrid" => include_str!("../../../config/arms/hybrid.toml"),
            _ => unreachable!(),
        };
        Layout::new(&toml::from_str(text).unwrap()).unwrap()
    }

    /// A new arm needs no hand-written classes: each module swept, then all together and an S,
    /// and the demonstrations of each class move the tip apart from the others'.
    #[test]
    fn an_arm_without_classes_gets_them_from_its_modules() {
        let tdcr = shipped("tdcr");
        let c = classes(&DemoRecipe::default(), &tdcr);
        assert_eq!(c.len(), 5);
        for ex in &c {
            assert_eq!((ex.start.len(), ex.end.len()), (9, 9));
            assert!(
                ex.start
                    .iter()
                    .chain(&ex.end)
                    .all(|v| (0.2..=0.8).contains(v))
            );
        }
        // Class 0 sweeps the first segment alone.
        assert!(c[0].start[3..].iter().all(|v| *v == 0.5));
        assert!(c[0].start[..3].iter().any(|v| *v < 0.45));
        let arm = softarm_kinematics::pcc::Arm::new(&tdcr, &[]);
        let recs = demonstrations::<9>(&arm, &DemoRecipe::default(), &c, 3);
        assert_eq!(recs.len(), 5 * 20);
        let (act, task) = train_primitives(&recs, 15).unwrap();
        assert_eq!((act.len(), act[0].dofs(), task[0].dofs()), (5, 9, 3));
        assert!(
            recs.iter()
                .flat_map(|r| r.position.iter().flatten())
                .all(|v| v.is_finite())
        );
        // The hybrid's chambers on the axis stay at the middle; its tendons sweep.
        let hybrid = shipped("hybrid");
        let c = classes(&DemoRecipe::default(), &hybrid);
        assert_eq!(c.len(), 4);
        assert_eq!((c[0].start[3], c[0].end[3]), (0.5, 0.5));
        assert_ne!(c[0].start[0], c[0].end[0]);
    }

    /// On an arm that is not where its drawing has it (here its first module's tendons turned
    /// 120°), the demo's points through the drawing's kinematics lie where the arm never went;
    /// on the task-space primitives they lie on its demonstrations.
    #[test]
    fn the_demo_points_seen_lie_where_the_arm_went() {
        let text = include_str!("../../../config/arms/tdcr.toml");
        let drawn = shipped("tdcr");
        let turned = text.replacen(
            "backbone_m = 0.06\ntendons",
            "backbone_m = 0.06\nrotation_deg = 120\ntendons",
            1,
        );
        assert_ne!(turned, text);
        let turned = Layout::new(&toml::from_str(&turned).unwrap()).unwrap();
        let classes = classes(&DemoRecipe::default(), &drawn);
        let arm = pcc::Arm::new(&turned, &[]);
        let recs = demonstrations::<9>(&arm, &DemoRecipe::default(), &classes, 3);
        let (_, task) = train_primitives(&recs, 15).unwrap();
        let went: Vec<Position> = recs.iter().flat_map(|r| r.position.clone()).collect();
        let nearest = |p: &Position| {
            went.iter()
                .map(|q| crate::space::distance(p, q))
                .fold(f64::INFINITY, f64::min)
        };
        let seen: Vec<f64> = demo_points_seen(&task).iter().map(nearest).collect();
        assert_eq!(seen.len(), 5);
        assert!(seen.iter().all(|d| *d < 0.003), "{seen:?}");
        let drawn_arm = pcc::Arm::new(&drawn, &[]);
        let through: Vec<f64> = demo_points::<9>(&classes, &drawn_arm)
            .iter()
            .map(nearest)
            .collect();
        assert!(through.iter().any(|d| *d > 0.02), "{through:?}");
    }
}
