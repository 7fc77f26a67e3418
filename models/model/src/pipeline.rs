//! The offline pipeline that makes a [`Model`], written once: demonstrations → actuation- and
//! task-space ProMPs → RBF forward model and polynomial kinematics (each with its error on
//! held-out demonstrations) → imitation warm start of CACLA-MTL → pre-training against the
//! forward model.
//!
//! `softarm train` records its demonstrations through the running stack and hands them to
//! [`train`]; the tests, the benches and the examples make them straight from the kinematic
//! model with [`from_plant`]. Pure: no iceoryx2, no files, no clock — pre-training runs until
//! its epoch cap or until the caller's `keep_going` says stop, as [`cacla::pretrain`] does.
//!
//! [`cacla::pretrain`]: softarm_learning::cacla::pretrain

use softarm_arm::Layout;
use softarm_kinematics::forward::ForwardModel;
use softarm_kinematics::linalg::{BLOCK_ROWS, Normal};
use softarm_kinematics::pcc;
use softarm_kinematics::poly::{Polynomial, terms};
use softarm_kinematics::rbf::{RbfError, RbfNetwork};
use softarm_learning::cacla::{self, CaclaMtl, PretrainReport};
use softarm_method::activation::MAX_PRIMITIVES;
use softarm_method::promp::{Primitive, PrimitiveError};
use softarm_method::skill::{self, Recording};
use softarm_method::space::{Position, distance};
use softarm_sections::arm::ArmConfig;
use softarm_sections::demonstrations::DemoRecipe;
use softarm_sections::forward_model::NetworkConfig;
use softarm_sections::kinematics::PolynomialConfig;
use softarm_sections::learner::LearnerConfig;
use softarm_sections::learner::PretrainConfig;

use crate::bundle::Model;

/// Supervised passes over D_fwd that warm-start the actor before pre-training (`softarm train`).
pub const IMITATION_PASSES: usize = 3;

/// Every this-many-th demonstration (from the first on) is held out of the forward models'
/// first fits to measure their error. Whole demonstrations: a held-out sample between two
/// fitted neighbours 5 ms apart would measure interpolation, not the model.
pub const HOLD_OUT_EVERY: usize = 5;

/// The steps of [`train`] that take a while on a large arm, in order, for progress; the
/// pre-training after them is the caller's to show (its `keep_going` sees every epoch).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Step {
    /// The ProMPs, a class at a time.
    Primitives,
    /// The RBF forward model: each width tried, the held-out fit, the final fit.
    ForwardModel,
    /// The polynomial kinematics: each degree tried, the held-out fit, the final fit, in rows
    /// summed × terms² (what a fit costs), the total shrinking when fewer degrees are tried.
    Kinematics,
    /// The imitation warm start, a pass at a time.
    Imitation,
}

impl Step {
    pub const ALL: [Step; 4] = [
        Step::Primitives,
        Step::ForwardModel,
        Step::Kinematics,
        Step::Imitation,
    ];

    /// What the step does, for the user.
    pub fn name(self) -> &'static str {
        match self {
            Step::Primitives => "primitives",
            Step::ForwardModel => "forward model",
            Step::Kinematics => "kinematics",
            Step::Imitation => "imitation",
        }
    }
}

/// Told how far a step is: (step, done, total), `done` never past `total` and never back.
pub type Progress<'a> = &'a mut dyn FnMut(Step, u64, u64);

/// What can go wrong in the pipeline: bad input, never a panic.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PipelineError {
    #[error("no demonstrations were recorded")]
    NoRecordings,
    #[error("recording {index}: {why}")]
    Recording { index: usize, why: String },
    #[error("no recording of class {class}, though there are {classes} classes (numbered from 0)")]
    MissingClass { class: usize, classes: usize },
    #[error("the demonstration recipe: {0}")]
    Recipe(String),
    #[error("the arm: {0}")]
    Arm(String),
    #[error("training the primitives: {0}")]
    Primitives(PrimitiveError),
    #[error("D_fwd has {actuations} actuations but {positions} positions")]
    Mismatch { actuations: usize, positions: usize },
    #[error("D_fwd is empty: no samples to fit the forward model on")]
    NoSamples,
    #[error("fitting the forward model {stage}: {error}")]
    Forward {
        stage: &'static str,
        error: RbfError,
    },
    #[error("fitting the polynomial kinematics {stage}: {error}")]
    Kinematics { stage: &'static str, error: String },
    #[error("D_fwd has {samples} samples but {demos} demonstration indices")]
    DemoIndex { samples: usize, demos: usize },
    #[error("the learner: {0}")]
    Learner(String),
}

/// How the pipeline trains; `softarm_train::training` gives `softarm train`'s settings
/// from a config.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Training {
    /// K of every ProMP, per DoF.
    pub basis_functions: usize,
    pub forward: NetworkConfig,
    pub kinematics: PolynomialConfig,
    pub learner: LearnerConfig,
    /// Pre-training; its `budget_s` is for the caller's `keep_going`, not read here.
    pub pretrain: PretrainConfig,
    pub imitation_passes: usize,
}

/// What the pipeline learns from.
#[derive(Debug, Clone, PartialEq)]
pub struct TrainingData<const N: usize> {
    /// The demonstrations the ProMPs learn from (commanded actuation, end-effector position).
    pub recordings: Vec<Recording<N>>,
    /// Their nominal duration (s): the bundle's `demo_duration_s`.
    pub duration_s: f64,
    /// D_fwd, which the forward model and the imitation learn from: on the stack what the
    /// actuators really did, from the kinematic model the commanded actuations.
    pub actuations: Vec<[f64; N]>,
    pub positions: Vec<Position>,
    /// The demonstration (index into `recordings`) each D_fwd sample belongs to.
    pub demo: Vec<usize>,
}

impl<const N: usize> TrainingData<N> {
    /// The recipe's demonstrations on the arm `arm` describes (of `N` actuators) played
    /// through its PCC kinematics ([`pcc::Arm::of_config`]), D_fwd all of their samples.
    pub fn from_plant(
        arm: &ArmConfig,
        recipe: &DemoRecipe,
        seed: u64,
    ) -> Result<Self, PipelineError> {
        let layout = arm.layout().map_err(PipelineError::Arm)?;
        let actuators = layout.actuators().len();
        if actuators != N {
            return Err(PipelineError::Arm(format!(
                "{actuators} actuators, where {N} were asked for"
            )));
        }
        let plant = pcc::Arm::of_config(arm).map_err(PipelineError::Arm)?;
        Self::of_arm(&layout, &plant, recipe, seed)
    }

    /// The recipe's demonstrations on the arm of `layout` played through `plant` (its
    /// kinematic model), D_fwd all of their samples.
    pub fn of_arm(
        layout: &Layout,
        plant: &impl ForwardModel<N>,
        recipe: &DemoRecipe,
        seed: u64,
    ) -> Result<Self, PipelineError> {
        recipe.validate(layout).map_err(PipelineError::Recipe)?;
        let classes = skill::classes(recipe, layout);
        let recordings = skill::demonstrations(plant, recipe, &classes, seed);
        let (actuations, positions) = skill::forward_data(&recordings);
        let demo = recordings
            .iter()
            .enumerate()
            .flat_map(|(i, r)| std::iter::repeat_n(i, r.actuation.len()))
            .collect();
        Ok(Self {
            recordings,
            duration_s: recipe.duration_s,
            actuations,
            positions,
            demo,
        })
    }
}

/// A forward model's error (m) on the samples held out of its first fit, and the final model's
/// on the samples it was fitted to (the kind of figure the paper reports: 3.7 ± 1.6 mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeldOut {
    pub samples: usize,
    pub mean_m: f64,
    pub max_m: f64,
    /// Mean and standard deviation on its own training samples.
    pub fitted_mean_m: f64,
    pub fitted_sd_m: f64,
}

/// What training measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrainReport {
    pub recordings: usize,
    /// Samples of D_fwd.
    pub samples: usize,
    pub forward_error: HeldOut,
    /// The forward model's width, as [`forward_model`] chose it.
    pub forward_width_factor: f64,
    pub kinematics_error: HeldOut,
    /// The polynomial's degree, as [`kinematics`] chose it.
    pub kinematics_degree: usize,
    pub pretrain: PretrainReport,
}

/// One actuation-space (`N` DoF) and one task-space (3 DoF) ProMP per class, K =
/// `basis_functions`. Classes are numbered from 0 and each needs a recording.
pub fn primitives<const N: usize>(
    recordings: &[Recording<N>],
    basis_functions: usize,
) -> Result<(Vec<Primitive>, Vec<Primitive>), PipelineError> {
    if recordings.is_empty() {
        return Err(PipelineError::NoRecordings);
    }
    for (index, r) in recordings.iter().enumerate() {
        let (t, a, p) = (r.times.len(), r.actuation.len(), r.position.len());
        if t != a || t != p {
            return Err(PipelineError::Recording {
                index,
                why: format!("{t} times, {a} actuations and {p} positions"),
            });
        }
        if r.class >= MAX_PRIMITIVES {
            return Err(PipelineError::Recording {
                index,
                why: format!("class {} (at most {MAX_PRIMITIVES} classes)", r.class),
            });
        }
    }
    let classes = recordings.iter().map(|r| r.class + 1).max().unwrap_or(0);
    if let Some(class) = (0..classes).find(|c| recordings.iter().all(|r| r.class != *c)) {
        return Err(PipelineError::MissingClass { class, classes });
    }
    skill::train_primitives(recordings, basis_functions).map_err(PipelineError::Primitives)
}

fn same_length<const N: usize>(
    actuations: &[[f64; N]],
    positions: &[Position],
) -> Result<(), PipelineError> {
    if actuations.len() != positions.len() {
        return Err(PipelineError::Mismatch {
            actuations: actuations.len(),
            positions: positions.len(),
        });
    }
    if actuations.is_empty() {
        return Err(PipelineError::NoSamples);
    }
    Ok(())
}

fn same_demos<const N: usize>(
    actuations: &[[f64; N]],
    demo: &[usize],
) -> Result<(), PipelineError> {
    if demo.len() != actuations.len() {
        return Err(PipelineError::DemoIndex {
            samples: actuations.len(),
            demos: demo.len(),
        });
    }
    Ok(())
}

/// Fits `fit` without every [`HOLD_OUT_EVERY`]-th demonstration, measures the error there,
/// then fits again on every sample; `tick` after each fit.
fn held_out_fit<const N: usize, M: ForwardModel<N>, E>(
    actuations: &[[f64; N]],
    positions: &[Position],
    demo: &[usize],
    fit: impl Fn(&[[f64; N]], &[Position]) -> Result<M, E>,
    wrap: impl Fn(&'static str, E) -> PipelineError,
    tick: &mut dyn FnMut(),
) -> Result<(M, HeldOut), PipelineError> {
    same_length(actuations, positions)?;
    same_demos(actuations, demo)?;
    let held = |i: usize| demo[i].is_multiple_of(HOLD_OUT_EVERY);
    let (fit_a, fit_p) = picked(actuations, positions, |i| !held(i));
    let partial =
        fit(&fit_a, &fit_p).map_err(|e| wrap("without the held-out demonstrations", e))?;
    tick();
    let model = fit(actuations, positions).map_err(|e| wrap("on every sample", e))?;
    tick();
    let held_out = held_out(&partial, &model, actuations, positions, held);
    Ok((model, held_out))
}

/// The samples whose index `keep` keeps.
fn picked<const N: usize>(
    actuations: &[[f64; N]],
    positions: &[Position],
    keep: impl Fn(usize) -> bool,
) -> (Vec<[f64; N]>, Vec<Position>) {
    (0..actuations.len())
        .filter(|i| keep(*i))
        .map(|i| (actuations[i], positions[i]))
        .unzip()
}

/// `partial`'s error on the samples `held` picks, `model`'s on every sample.
fn held_out<const N: usize>(
    partial: &impl ForwardModel<N>,
    model: &impl ForwardModel<N>,
    actuations: &[[f64; N]],
    positions: &[Position],
    held: impl Fn(usize) -> bool,
) -> HeldOut {
    let errors: Vec<f64> = (0..actuations.len())
        .filter(|i| held(*i))
        .map(|i| distance(&partial.position(&actuations[i]), &positions[i]))
        .collect();
    let fitted: Vec<f64> = (actuations.iter().zip(positions))
        .map(|(a, p)| distance(&model.position(a), p))
        .collect();
    let fitted_mean_m = fitted.iter().sum::<f64>() / fitted.len().max(1) as f64;
    let fitted_sd_m = (fitted
        .iter()
        .map(|e| (e - fitted_mean_m).powi(2))
        .sum::<f64>()
        / fitted.len().max(1) as f64)
        .sqrt();
    HeldOut {
        samples: errors.len(),
        mean_m: errors.iter().sum::<f64>() / errors.len().max(1) as f64,
        max_m: errors.iter().copied().fold(0.0, f64::max),
        fitted_mean_m,
        fitted_sd_m,
    }
}

/// The RBF forward model on D_fwd at the width [`chosen_width`] gives, with its error on
/// held-out demonstrations and that width.
pub fn forward_model<const N: usize>(
    actuations: &[[f64; N]],
    positions: &[Position],
    demo: &[usize],
    config: &NetworkConfig,
) -> Result<(RbfNetwork<N>, HeldOut, f64), PipelineError> {
    fit_forward(actuations, positions, demo, config, &mut |_, _| {})
}

/// [`forward_model`], `progress(done, total)` in fits.
fn fit_forward<const N: usize>(
    actuations: &[[f64; N]],
    positions: &[Position],
    demo: &[usize],
    config: &NetworkConfig,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<(RbfNetwork<N>, HeldOut, f64), PipelineError> {
    same_length(actuations, positions)?;
    same_demos(actuations, demo)?;
    let total = config.widths.max(1) as u64 + 2;
    let mut done = 0;
    progress(done, total);
    let width_factor = chosen_width(actuations, positions, demo, config, &mut || {
        done += 1;
        progress(done, total)
    });
    let config = NetworkConfig {
        width_factor,
        widths: 1,
        ..*config
    };
    // Widths not tried (one width, too few demonstrations) are done too.
    let mut done = total - 2;
    progress(done, total);
    let (model, held_out) = held_out_fit(
        actuations,
        positions,
        demo,
        |a, p| RbfNetwork::fit(a, p, &config),
        |stage, error| PipelineError::Forward { stage, error },
        &mut || {
            done += 1;
            progress(done, total)
        },
    )?;
    Ok((model, held_out, width_factor))
}

/// Which of `config.widths` widths (`width_factor` × 1, 2, 4, …) the forward model fits with:
/// the one least wrong on the demonstrations just after each held-out one, fitted without
/// them and without the held-out ones, so that the choice never sees the demonstrations its
/// error is reported on. Too few demonstrations to judge, or no width that fits: the first.
fn chosen_width<const N: usize>(
    actuations: &[[f64; N]],
    positions: &[Position],
    demo: &[usize],
    config: &NetworkConfig,
    tick: &mut dyn FnMut(),
) -> f64 {
    let role = |i: usize| demo[i] % HOLD_OUT_EVERY;
    let fitted: Vec<usize> = (0..actuations.len()).filter(|i| role(*i) > 1).collect();
    let judged: Vec<usize> = (0..actuations.len()).filter(|i| role(*i) == 1).collect();
    let widths = (0..config.widths).map(|k| config.width_factor * f64::from(1u32 << k));
    if config.widths <= 1 || fitted.is_empty() || judged.is_empty() {
        return config.width_factor;
    }
    let a: Vec<[f64; N]> = fitted.iter().map(|i| actuations[*i]).collect();
    let p: Vec<Position> = fitted.iter().map(|i| positions[*i]).collect();
    let error = |width_factor: f64| {
        let config = NetworkConfig {
            width_factor,
            widths: 1,
            ..*config
        };
        RbfNetwork::fit(&a, &p, &config).map_or(f64::INFINITY, |net| {
            (judged.iter())
                .map(|i| distance(&net.position(&actuations[*i]), &positions[*i]))
                .sum::<f64>()
        })
    };
    widths
        .map(|w| {
            let e = error(w);
            tick();
            (e, w)
        })
        .filter(|(e, _)| e.is_finite())
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map_or(config.width_factor, |(_, w)| w)
}

/// The polynomial kinematics on D_fwd (whose Jacobian steers the online corrections), at the
/// degree [`chosen_degree`] gives, with its error on held-out demonstrations.
pub fn kinematics<const N: usize>(
    actuations: &[[f64; N]],
    positions: &[Position],
    demo: &[usize],
    config: &PolynomialConfig,
) -> Result<(Polynomial<N>, HeldOut), PipelineError> {
    fit_kinematics(actuations, positions, demo, config, &mut |_, _| {})
}

/// [`kinematics`], `progress(done, total)` in rows summed × terms².
///
/// Every fit here is one of normal equations, and those of two sets of samples add up to those
/// of both: the rows the choice fitted are summed once, the held-out fit adds the judged rows to
/// them, the final fit the held-out ones.
fn fit_kinematics<const N: usize>(
    actuations: &[[f64; N]],
    positions: &[Position],
    demo: &[usize],
    config: &PolynomialConfig,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<(Polynomial<N>, HeldOut), PipelineError> {
    same_length(actuations, positions)?;
    same_demos(actuations, demo)?;
    let wrap = |stage, error| PipelineError::Kinematics { stage, error };
    Polynomial::check(actuations, positions, config).map_err(|e| wrap("of the samples", e))?;
    let role = |i: usize| demo[i] % HOLD_OUT_EVERY;
    let (held_a, held_p) = picked(actuations, positions, |i| role(i) == 0);
    let (judged_a, judged_p) = picked(actuations, positions, |i| role(i) == 1);
    let (fit_a, fit_p) = picked(actuations, positions, |i| role(i) > 1);
    let rows = [fit_a.len(), judged_a.len(), held_a.len()];
    let mut meter = Meter::new(progress, N, rows, config.degree);
    let (degree, fitted) = chosen_degree(&fit_a, &fit_p, &judged_a, &judged_p, config, &mut meter);
    meter.chosen(degree, fitted.is_some());
    // Without the held-out demonstrations: the choice's rows and the judged ones.
    let judged =
        Polynomial::normal_equations(&judged_a, &judged_p, degree, &mut meter.tick(degree));
    let partial_normal = match fitted {
        Some(fitted) => fitted + judged,
        None => {
            Polynomial::normal_equations(&fit_a, &fit_p, degree, &mut meter.tick(degree)) + judged
        }
    };
    let partial = Polynomial::solve(&partial_normal, degree, config.ridge)
        .map_err(|e| wrap("without the held-out demonstrations", e))?;
    let held = Polynomial::normal_equations(&held_a, &held_p, degree, &mut meter.tick(degree));
    let model = Polynomial::solve(&(partial_normal + held), degree, config.ridge)
        .map_err(|e| wrap("on every sample", e))?;
    let held_out = held_out(&partial, &model, actuations, positions, |i| role(i) == 0);
    Ok((model, held_out))
}

/// Which degree of 1 to `config.degree` the polynomial kinematics fit with: the one least wrong
/// on the `judged` samples (the demonstrations just after each held-out one) when fitted to the
/// `fitted` ones (neither those nor the held-out ones), as the forward model's width
/// ([`chosen_width`]): the choice never sees the demonstrations its error is reported on.
/// Every degree is tried: the error need not rise and fall once (on a sixteen-tendon arm's
/// demonstrations degree 2 was more wrong than 1). Too few samples to judge: `config.degree`.
/// With the degree, the fitted samples' equations at it, when it was chosen.
fn chosen_degree<const N: usize>(
    fit_a: &[[f64; N]],
    fit_p: &[Position],
    judged_a: &[[f64; N]],
    judged_p: &[Position],
    config: &PolynomialConfig,
    meter: &mut Meter,
) -> (usize, Option<Normal>) {
    if fit_a.is_empty() || judged_a.is_empty() {
        return (config.degree, None);
    }
    let mut best: Option<(f64, usize, Normal)> = None;
    for degree in 1..=config.degree {
        let normal = Polynomial::normal_equations(fit_a, fit_p, degree, &mut meter.tick(degree));
        let error =
            Polynomial::<N>::solve(&normal, degree, config.ridge).map_or(f64::INFINITY, |poly| {
                (judged_a.iter().zip(judged_p))
                    .map(|(a, p)| distance(&poly.position(a), p))
                    .sum::<f64>()
            });
        // Not finite: more terms than samples, as every higher degree would have.
        if !error.is_finite() {
            break;
        }
        if best.as_ref().is_none_or(|(e, _, _)| error < *e) {
            best = Some((error, degree, normal));
        }
    }
    match best {
        Some((_, degree, normal)) => (degree, Some(normal)),
        None => (config.degree, None),
    }
}

/// The kinematics' progress in rows summed × terms², a block of rows at a time: planned for
/// every degree up to the highest, then shrunk to the degree chosen.
struct Meter<'a> {
    progress: &'a mut dyn FnMut(u64, u64),
    /// Blocks of the choice's fitted, the judged and the held-out samples.
    blocks: [u64; 3],
    inputs: usize,
    done: u64,
    total: u64,
}

impl<'a> Meter<'a> {
    fn new(
        progress: &'a mut dyn FnMut(u64, u64),
        inputs: usize,
        rows: [usize; 3],
        max_degree: usize,
    ) -> Self {
        let mut meter = Self {
            progress,
            blocks: rows.map(|r| r.div_ceil(BLOCK_ROWS) as u64),
            inputs,
            done: 0,
            total: 0,
        };
        let [fitted, judged, held] = meter.blocks;
        meter.total = (1..=max_degree)
            .map(|d| fitted * meter.cost(d))
            .sum::<u64>()
            + (judged + held) * meter.cost(max_degree);
        (meter.progress)(0, meter.total);
        meter
    }

    /// What summing a block of rows costs at `degree`: terms².
    fn cost(&self, degree: usize) -> u64 {
        (terms(self.inputs, degree) as u64).pow(2)
    }

    /// Counts a block summed at `degree`.
    fn tick(&mut self, degree: usize) -> impl FnMut() + '_ {
        let cost = self.cost(degree);
        move || {
            self.done = (self.done + cost).min(self.total);
            (self.progress)(self.done, self.total)
        }
    }

    /// `degree` chosen: what is left is the judged and the held-out samples at it, and the
    /// choice's fitted ones unless it summed them at that degree.
    fn chosen(&mut self, degree: usize, fitted_summed: bool) {
        let [fitted, judged, held] = self.blocks;
        let left = judged + held + if fitted_summed { 0 } else { fitted };
        self.total = self.done + left * self.cost(degree);
        (self.progress)(self.done, self.total)
    }
}

/// The imitation warm start: a new learner whose actor took `passes` supervised passes over
/// D_fwd (the demonstrations say which actuation reaches which position).
pub fn imitation<const N: usize>(
    config: LearnerConfig,
    actuations: &[[f64; N]],
    positions: &[Position],
    passes: usize,
) -> Result<CaclaMtl<N>, PipelineError> {
    same_length(actuations, positions)?;
    let mut learner = CaclaMtl::new(config).map_err(PipelineError::Learner)?;
    learner.imitate(positions, actuations, passes);
    Ok(learner)
}

/// The imitation warm start, then CACLA-MTL pre-training against `model` on targets drawn from
/// D_fwd's positions, until `training.pretrain.max_epochs` or until `keep_going` says stop.
pub fn learner<const N: usize>(
    training: &Training,
    model: &impl ForwardModel<N>,
    actuations: &[[f64; N]],
    positions: &[Position],
    keep_going: impl FnMut(&PretrainReport) -> bool,
) -> Result<(CaclaMtl<N>, PretrainReport), PipelineError> {
    learner_showing(
        training,
        model,
        actuations,
        positions,
        &mut |_, _| {},
        keep_going,
    )
}

/// [`learner`], `imitated(done, total)` in imitation passes.
fn learner_showing<const N: usize>(
    training: &Training,
    model: &impl ForwardModel<N>,
    actuations: &[[f64; N]],
    positions: &[Position],
    imitated: &mut dyn FnMut(u64, u64),
    keep_going: impl FnMut(&PretrainReport) -> bool,
) -> Result<(CaclaMtl<N>, PretrainReport), PipelineError> {
    let passes = training.imitation_passes;
    let mut learner = imitation(training.learner, actuations, positions, 0)?;
    imitated(0, passes as u64);
    for pass in 0..passes {
        learner.imitate(positions, actuations, 1);
        imitated(pass as u64 + 1, passes as u64);
    }
    let report = cacla::pretrain(
        &mut learner,
        model,
        positions,
        &training.pretrain,
        keep_going,
    );
    Ok((learner, report))
}

/// The whole pipeline: primitives, forward model, pre-trained learner, as a [`Model`] (its `id`
/// empty until written, its `arm` for the caller, who knows which arm the data came from).
pub fn train<const N: usize>(
    data: &TrainingData<N>,
    training: &Training,
    keep_going: impl FnMut(&PretrainReport) -> bool,
) -> Result<(Model<N>, TrainReport), PipelineError> {
    train_showing(data, training, &mut |_, _, _| {}, keep_going)
}

/// [`train`], telling `progress` how far each [`Step`] is as it goes.
pub fn train_showing<const N: usize>(
    data: &TrainingData<N>,
    training: &Training,
    progress: Progress,
    keep_going: impl FnMut(&PretrainReport) -> bool,
) -> Result<(Model<N>, TrainReport), PipelineError> {
    progress(Step::Primitives, 0, 1);
    let (actuation, task) = primitives(&data.recordings, training.basis_functions)?;
    progress(Step::Primitives, 1, 1);
    let (forward, forward_error, forward_width_factor) = fit_forward(
        &data.actuations,
        &data.positions,
        &data.demo,
        &training.forward,
        &mut |done, total| progress(Step::ForwardModel, done, total),
    )?;
    let (kinematics, kinematics_error) = fit_kinematics(
        &data.actuations,
        &data.positions,
        &data.demo,
        &training.kinematics,
        &mut |done, total| progress(Step::Kinematics, done, total),
    )?;
    let (learner, pretrain) = learner_showing(
        training,
        &forward,
        &data.actuations,
        &data.positions,
        &mut |done, total| progress(Step::Imitation, done, total),
        keep_going,
    )?;
    let kinematics_degree = kinematics.degree();
    let model = Model {
        actuation,
        task,
        forward,
        kinematics,
        learner: learner.state(),
        demo_duration_s: data.duration_s,
        arm: String::new(),
        id: String::new(),
    };
    Ok((
        model,
        TrainReport {
            recordings: data.recordings.len(),
            samples: data.actuations.len(),
            forward_error,
            forward_width_factor,
            kinematics_error,
            kinematics_degree,
            pretrain,
        },
    ))
}

/// The simulated path: the recipe's demonstrations straight from the PCC kinematics of the arm
/// `arm` describes (of `N` actuators: [`TrainingData::from_plant`]), then [`train`].
pub fn from_plant<const N: usize>(
    arm: &ArmConfig,
    recipe: &DemoRecipe,
    seed: u64,
    training: &Training,
    keep_going: impl FnMut(&PretrainReport) -> bool,
) -> Result<(Model<N>, TrainReport), PipelineError> {
    train(
        &TrainingData::from_plant(arm, recipe, seed)?,
        training,
        keep_going,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use softarm_learning::cacla::evaluate;

    /// The default `[arm]`'s actuators.
    const N: usize = 6;

    /// The default `[arm]`.
    fn paper() -> ArmConfig {
        ArmConfig::default()
    }

    fn quick() -> Training {
        Training {
            basis_functions: 8,
            forward: NetworkConfig {
                centres: 60,
                ..Default::default()
            },
            kinematics: Default::default(),
            learner: LearnerConfig::default(),
            pretrain: PretrainConfig {
                max_epochs: 100,
                ..Default::default()
            },
            imitation_passes: 2,
        }
    }

    fn recipe() -> DemoRecipe {
        DemoRecipe {
            demos_per_class: 4,
            ..Default::default()
        }
    }

    fn mean(v: &[f64]) -> f64 {
        v.iter().sum::<f64>() / v.len() as f64
    }

    #[test]
    fn a_quick_model_from_the_plant_is_whole_and_the_same_for_the_same_inputs() {
        let arm = paper();
        let (m, r) = from_plant::<N>(&arm, &recipe(), 3, &quick(), |_| true).unwrap();
        assert_eq!((m.actuation.len(), m.task.len()), (3, 3));
        assert_eq!((m.actuation[0].dofs(), m.task[0].dofs()), (6, 3));
        assert_eq!(m.actuation[0].basis().len(), 8);
        assert_eq!(m.forward.centres(), 60);
        assert_eq!(m.demo_duration_s, recipe().duration_s);
        assert!(m.id.is_empty());
        assert_eq!(r.recordings, 12);
        assert_eq!(r.samples, 12 * 201);
        // Demonstrations 0, 5 and 10 of 12 held out, whole.
        assert_eq!(r.forward_error.samples, 3 * 201);
        assert_eq!(r.kinematics_error.samples, 3 * 201);
        assert_eq!(m.kinematics.degree(), 4);
        // On whole held-out demonstrations, few as they are here: millimetres.
        assert!(
            r.kinematics_error.mean_m < 0.005,
            "{:?}",
            r.kinematics_error
        );
        assert_eq!(r.pretrain.epochs, 100);
        assert!(r.pretrain.updates > 0);
        assert!(!m.learner.actor.is_empty() && !m.learner.critic.is_empty());
        // On demonstrations it never saw, the RBF network is off by millimetres (60 centres
        // here), the smooth polynomial by less.
        assert!(r.forward_error.mean_m < 0.015, "{:?}", r.forward_error);
        assert!(
            r.kinematics_error.mean_m < r.forward_error.mean_m,
            "{:?} vs {:?}",
            r.kinematics_error,
            r.forward_error
        );
        // Nothing but the inputs decides the model.
        let (again, _) = from_plant::<N>(&arm, &recipe(), 3, &quick(), |_| true).unwrap();
        assert_eq!(again.actuation, m.actuation);
        assert_eq!(again.task, m.task);
        assert_eq!(again.forward, m.forward);
        assert_eq!(again.kinematics, m.kinematics);
        assert_eq!(again.learner, m.learner);
        let (other, _) = from_plant::<N>(&arm, &recipe(), 4, &quick(), |_| true).unwrap();
        assert_ne!(other.forward, m.forward);
    }

    #[test]
    fn the_forward_model_is_refitted_on_every_sample_after_the_held_out_check() {
        let data = TrainingData::<N>::from_plant(&paper(), &recipe(), 5).unwrap();
        let config = quick().forward;
        let (net, held, width_factor) =
            forward_model(&data.actuations, &data.positions, &data.demo, &config).unwrap();
        let chosen = NetworkConfig {
            width_factor,
            widths: 1,
            ..config
        };
        assert_eq!(
            net,
            RbfNetwork::fit(&data.actuations, &data.positions, &chosen).unwrap()
        );
        let held_out: Vec<usize> = (0..data.actuations.len())
            .filter(|i| data.demo[*i].is_multiple_of(HOLD_OUT_EVERY))
            .collect();
        assert_eq!(held.samples, held_out.len());
        assert!(held.mean_m > 0.0 && held.mean_m <= held.max_m, "{held:?}");
        // The held-out error is the partial fit's: larger than the full fit's on those samples.
        let on_all: f64 = held_out
            .iter()
            .map(|&i| distance(&net.position(&data.actuations[i]), &data.positions[i]))
            .sum::<f64>()
            / held.samples as f64;
        assert!(on_all < held.mean_m, "{on_all} vs {held:?}");
    }

    #[test]
    fn the_width_is_chosen_without_the_demonstrations_its_error_is_reported_on() {
        let data = TrainingData::<N>::from_plant(&paper(), &recipe(), 5).unwrap();
        let config = quick().forward;
        let width = |positions: &[Position], config: &NetworkConfig| {
            forward_model(&data.actuations, positions, &data.demo, config)
                .unwrap()
                .2
        };
        let chosen = width(&data.positions, &config);
        let tried = [config.width_factor, 2.0 * config.width_factor];
        assert!(tried.contains(&chosen), "{chosen}");
        // The held-out demonstrations 10 cm off: the choice is the same.
        let mut off = data.positions.clone();
        for (i, p) in off.iter_mut().enumerate() {
            if data.demo[i].is_multiple_of(HOLD_OUT_EVERY) {
                p[2] += 0.1;
            }
        }
        assert_eq!(width(&off, &config), chosen);
        // One width: the configured one.
        let one = NetworkConfig {
            widths: 1,
            ..config
        };
        assert_eq!(width(&data.positions, &one), config.width_factor);
    }

    /// Noisy samples of a linear map, ten demonstrations of 60: a polynomial of degree 4 (210
    /// terms) fits the noise of the few it is fitted to.
    fn linear_and_noisy() -> (Vec<[f64; N]>, Vec<Position>, Vec<usize>) {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        let (mut a, mut p, mut demo) = (Vec::new(), Vec::new(), Vec::new());
        for d in 0..10 {
            for _ in 0..60 {
                let x: [f64; N] = std::array::from_fn(|_| rng.random_range(0.2..0.8));
                let noise = |rng: &mut rand::rngs::StdRng| rng.random_range(-0.005..0.005);
                a.push(x);
                p.push([
                    0.1 * x[0] - 0.05 * x[3] + noise(&mut rng),
                    0.08 * x[1] + 0.02 * x[4] + noise(&mut rng),
                    -0.4 + 0.05 * x[2] + 0.05 * x[5] + noise(&mut rng),
                ]);
                demo.push(d);
            }
        }
        (a, p, demo)
    }

    #[test]
    fn the_degree_is_chosen_without_the_demonstrations_its_error_is_reported_on() {
        let (a, p, demo) = linear_and_noisy();
        let config = PolynomialConfig::default();
        assert_eq!(config.degree, 4);
        let (poly, held) = kinematics(&a, &p, &demo, &config).unwrap();
        assert!(poly.degree() < 4, "degree {}", poly.degree());
        // The reported error is of the chosen degree fitted without the held-out demonstrations.
        let fitted: Vec<usize> = (0..a.len())
            .filter(|i| demo[*i] % HOLD_OUT_EVERY != 0)
            .collect();
        let (fa, fp): (Vec<_>, Vec<_>) = fitted.iter().map(|i| (a[*i], p[*i])).unzip();
        let chosen = PolynomialConfig {
            degree: poly.degree(),
            ..config
        };
        let partial = Polynomial::fit(&fa, &fp, &chosen).unwrap();
        let on_held: Vec<f64> = (0..a.len())
            .filter(|i| demo[*i] % HOLD_OUT_EVERY == 0)
            .map(|i| distance(&partial.position(&a[i]), &p[i]))
            .collect();
        assert_eq!(held.samples, on_held.len());
        assert!((held.mean_m - mean(&on_held)).abs() < 1e-9, "{held:?}");
        // The held-out demonstrations 10 cm off: the same degree, a larger error.
        let mut off = p.clone();
        for (i, q) in off.iter_mut().enumerate() {
            if demo[i].is_multiple_of(HOLD_OUT_EVERY) {
                q[2] += 0.1;
            }
        }
        let (moved, held_off) = kinematics(&a, &off, &demo, &config).unwrap();
        assert_eq!(moved.degree(), poly.degree());
        assert!(held_off.mean_m > 0.05, "{held_off:?}");
        // The final fit is on every sample, at the chosen degree (its sums in another order).
        let all = Polynomial::fit(&a, &p, &chosen).unwrap();
        for x in &a {
            assert!(distance(&poly.position(x), &all.position(x)) < 1e-9);
        }
        // Too few demonstrations to judge (only the held-out one and the one after): the
        // configured degree.
        let two: Vec<usize> = (0..a.len()).filter(|i| demo[*i] < 2).collect();
        let pick = |v: &[[f64; N]]| two.iter().map(|i| v[*i]).collect::<Vec<_>>();
        let pick_p = |v: &[Position]| two.iter().map(|i| v[*i]).collect::<Vec<_>>();
        let d2: Vec<usize> = two.iter().map(|i| demo[*i]).collect();
        let lower = PolynomialConfig {
            degree: 2,
            ..config
        };
        let (configured, _) = kinematics(&pick(&a), &pick_p(&p), &d2, &lower).unwrap();
        assert_eq!(configured.degree(), 2);
    }

    #[test]
    fn pretraining_lowers_the_error_of_imitation_alone() {
        let arm = pcc::Arm::of_config(&paper()).unwrap();
        let data = TrainingData::<N>::from_plant(&paper(), &recipe(), 7).unwrap();
        let (net, _, _) = forward_model(
            &data.actuations,
            &data.positions,
            &data.demo,
            &quick().forward,
        )
        .unwrap();
        let targets: Vec<Position> = data.positions.iter().step_by(41).copied().collect();
        let training = Training {
            pretrain: PretrainConfig {
                max_epochs: 1500,
                ..Default::default()
            },
            ..quick()
        };
        let mut imitated = imitation(
            training.learner,
            &data.actuations,
            &data.positions,
            training.imitation_passes,
        )
        .unwrap();
        let before = mean(&evaluate(&mut imitated, &arm, &targets));
        let mut untrained =
            imitation(training.learner, &data.actuations, &data.positions, 0).unwrap();
        let untrained = mean(&evaluate(&mut untrained, &arm, &targets));
        let (mut trained, report) =
            learner(&training, &net, &data.actuations, &data.positions, |_| true).unwrap();
        let after = mean(&evaluate(&mut trained, &arm, &targets));
        assert_eq!(report.epochs, 1500);
        assert!(
            before < untrained,
            "imitation {before} vs untrained {untrained}"
        );
        assert!(
            after < 0.8 * before,
            "pre-trained {} mm vs imitation only {} mm",
            after * 1e3,
            before * 1e3
        );
    }

    #[test]
    fn keep_going_stops_pre_training() {
        let mut asked = 0;
        let (_, r) = from_plant::<N>(&paper(), &recipe(), 3, &quick(), |p| {
            asked += 1;
            p.epochs < 3
        })
        .unwrap();
        assert_eq!(r.pretrain.epochs, 3);
        assert_eq!(asked, 4);
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        let arm = paper();
        let data = TrainingData::<N>::from_plant(&arm, &recipe(), 1).unwrap();
        let t = quick();
        assert_eq!(
            primitives::<N>(&[], 8).unwrap_err(),
            PipelineError::NoRecordings
        );

        let mut short = data.recordings.clone();
        short[5].position.pop();
        let e = primitives(&short, 8).unwrap_err();
        assert!(
            matches!(e, PipelineError::Recording { index: 5, .. }),
            "{e}"
        );
        assert!(
            e.to_string()
                .contains("201 times, 201 actuations and 200 positions")
        );

        let gap: Vec<Recording<N>> = data
            .recordings
            .iter()
            .filter(|r| r.class != 1)
            .cloned()
            .collect();
        assert_eq!(
            primitives(&gap, 8).unwrap_err(),
            PipelineError::MissingClass {
                class: 1,
                classes: 3
            }
        );
        let mut many = data.recordings.clone();
        many[0].class = MAX_PRIMITIVES;
        assert!(primitives(&many, 8).is_err());

        let mut backwards = data.recordings.clone();
        backwards[2].times[3] = backwards[2].times[2];
        let e = primitives(&backwards, 8).unwrap_err();
        assert!(matches!(e, PipelineError::Primitives(_)), "{e}");
        assert!(matches!(
            primitives(&data.recordings, 1).unwrap_err(),
            PipelineError::Primitives(PrimitiveError::TooFewBasisFunctions(1))
        ));

        let (a, p, d) = (&data.actuations, &data.positions, &data.demo);
        assert!(matches!(
            forward_model(a, &p[1..], d, &t.forward).unwrap_err(),
            PipelineError::Mismatch { .. }
        ));
        assert_eq!(
            forward_model(a, p, &d[1..], &t.forward).unwrap_err(),
            PipelineError::DemoIndex {
                samples: a.len(),
                demos: a.len() - 1
            }
        );
        assert_eq!(
            forward_model::<N>(&[], &[], &[], &t.forward).unwrap_err(),
            PipelineError::NoSamples
        );
        // Only demonstration 0, which is held out: nothing to fit without it.
        for e in [
            forward_model(&a[..201], &p[..201], &d[..201], &t.forward).unwrap_err(),
            kinematics(&a[..201], &p[..201], &d[..201], &t.kinematics).unwrap_err(),
        ] {
            assert!(
                e.to_string()
                    .contains("without the held-out demonstrations"),
                "{e}"
            );
        }
        let mut nan = a.clone();
        nan[17][2] = f64::NAN;
        assert!(forward_model(&nan, p, d, &t.forward).is_err());
        assert!(kinematics(&nan, p, d, &t.kinematics).is_err());

        assert!(imitation(t.learner, a, &p[..10], 1).is_err());
        let bad = LearnerConfig {
            gamma: 2.0,
            ..Default::default()
        };
        let e = imitation(bad, a, p, 1).err().unwrap().to_string();
        assert!(e.contains("learner.gamma"), "{e}");

        let mut mismatched = data.clone();
        mismatched.positions.pop();
        assert!(train(&mismatched, &t, |_| true).is_err());
        let e = from_plant::<N>(
            &arm,
            &DemoRecipe {
                demos_per_class: 0,
                ..Default::default()
            },
            1,
            &t,
            |_| true,
        )
        .unwrap_err();
        assert!(matches!(e, PipelineError::Recipe(_)), "{e}");
    }

    /// Any arm: a quick model of the nine-tendon TDCR from its kinematics, its classes taken
    /// from the arm; the bundle of nine reads back for that arm alone.
    #[test]
    fn a_quick_model_of_a_nine_tendon_arm() {
        let text = include_str!("../../../config/arms/tdcr.toml");
        let layout = Layout::new(&toml::from_str(text).unwrap()).unwrap();
        let arm = softarm_kinematics::pcc::Arm::new(&layout, &[]);
        let data = TrainingData::<9>::of_arm(&layout, &arm, &recipe(), 3).unwrap();
        assert_eq!(data.recordings.len(), 5 * 4);
        let training = Training {
            learner: LearnerConfig {
                workspace_min_m: [-0.2, -0.2, 0.0],
                workspace_max_m: [0.2, 0.2, 0.25],
                ..LearnerConfig::default()
            },
            ..quick()
        };
        let (mut m, r) = train(&data, &training, |_| true).unwrap();
        assert_eq!((m.actuation.len(), m.actuation[0].dofs()), (5, 9));
        assert!(r.kinematics_error.mean_m < 0.005, "{r:?}");
        let dir = std::env::temp_dir().join(format!("softarm-nine-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        m.arm = layout.identity();
        m.write(&dir).unwrap();
        let back = Model::<9>::read_for_arm(&dir, &layout.identity()).unwrap();
        assert_eq!(back.learner, m.learner);
        let paper = paper().layout().unwrap().identity();
        let e = Model::<N>::read_for_arm(&dir, &paper)
            .unwrap_err()
            .to_string();
        assert!(e.contains("9 actuators (a1 .. a9) in 3 modules"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
