//! `softarm train --from`: a model bundle from a lab's recording instead of demonstrations
//! through the stack. The arm's physical model is calibrated to it ([`softarm_identify`]);
//! the RBF forward model and the polynomial kinematics are fitted to it, each at the size and
//! ridge cross-validation over held-out motions chooses; the learner is pre-trained against
//! the calibrated arm; a ProMP per class of motions (the label's first word: `seg2_dir90` is
//! a `seg`). `softarm model check`: every one of those models against a recording.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use softarm_arm::Layout;
use softarm_config::Config;
use softarm_config::activation::MAX_PRIMITIVES;
use softarm_config::forward_model::NetworkConfig;
use softarm_config::kinematics::PolynomialConfig;
use softarm_identify::check::{self, Check};
use softarm_identify::file::Identified;
use softarm_identify::fit::FOLDS;
use softarm_identify::recording::Recording as Rows;
use softarm_identify::run::{self as identify, Identification};
use softarm_identify::tendon::Structure;
use softarm_kinematics::forward::ForwardModel;
use softarm_kinematics::poly::Polynomial;
use softarm_kinematics::rbf::RbfNetwork;
use softarm_method::skill::Recording;
use softarm_method::space::Position;
use softarm_model::bundle::Model;
use softarm_model::pipeline;

use softarm_identify::run::bar;

use crate::{budget, training};

/// A motion becomes a demonstration of its class when it has at least this many rows.
const MIN_ROWS: usize = 4;

/// The ridges cross-validation tries for the RBF network and the polynomial: from none to
/// one that holds a model near its mean.
const MODEL_RIDGES: [f64; 5] = [1e-8, 1e-5, 1e-3, 1e-1, 10.0];

/// What a model size and ridge measured on held-out motions.
#[derive(Debug, Clone, PartialEq)]
pub struct Tried {
    pub what: String,
    pub held_out_rms_mm: f64,
}

/// What `train --from` made.
#[derive(Debug, Clone)]
pub struct FromRecording {
    pub identification: Identification,
    pub model_path: PathBuf,
    pub twin_path: PathBuf,
    pub bundle_dir: PathBuf,
    pub model_id: String,
    pub classes: Vec<String>,
    pub demonstrations: usize,
    pub forward: (String, Vec<Tried>),
    pub kinematics: (String, Vec<Tried>),
    pub pretrain_updates: u64,
}

impl FromRecording {
    pub fn summary(&self) -> String {
        let tried = |what: &str, t: &[Tried]| {
            let t: Vec<(String, f64)> = (t.iter())
                .map(|t| (t.what.clone(), t.held_out_rms_mm))
                .collect();
            softarm_identify::run::tried_table(what, &t)
        };
        format!(
            "{}the RBF forward model: {}\n{}the polynomial kinematics: {}\n{}primitives: {} \
             classes ({}) from {} motions; the learner pre-trained against the calibrated arm, \
             {} updates\nmodel: {}\ntwin arm: {}\nbundle {} in {}",
            self.identification.summary(),
            self.forward.0,
            tried("centres/width/ridge", &self.forward.1),
            self.kinematics.0,
            tried("degree/ridge", &self.kinematics.1),
            self.classes.len(),
            self.classes.join(", "),
            self.demonstrations,
            self.pretrain_updates,
            self.model_path.display(),
            self.twin_path.display(),
            self.model_id,
            self.bundle_dir.display()
        )
    }
}

/// The whole of `train --from` for the config's arm, on `recording` (read by the caller:
/// a CSV through its column map, `softarm_identify::run::read_recording`, or softarm's own);
/// writes into `out` only once everything was fitted.
pub fn train_from(config: &Config, recording: Rows, out: &Path) -> Result<FromRecording> {
    let arm = config.layout();
    let identification = identify::identify(recording, &arm)?;
    let n = arm.actuators().len();
    let (built, model_id, (model_path, twin_path)) = softarm_method::space::with_actuators!(
        n,
        N => {
            let (mut model, built) = bundle::<N>(config, &arm, &identification)?;
            // Everything fitted: now written, each file atomically.
            let paths = identification.write(out)?;
            model.arm = arm.identity();
            let id = model
                .write(out)
                .with_context(|| format!("writing the model bundle into {}", out.display()))?;
            (built, id, paths)
        },
        n => bail!("{n} actuators: an arm has 3 to 16")
    );
    Ok(FromRecording {
        identification,
        model_path,
        twin_path,
        bundle_dir: out.into(),
        model_id,
        classes: built.classes,
        demonstrations: built.demonstrations,
        forward: built.forward,
        kinematics: built.kinematics,
        pretrain_updates: built.pretrain_updates,
    })
}

/// What building the bundle chose and did.
struct Built {
    classes: Vec<String>,
    demonstrations: usize,
    forward: (String, Vec<Tried>),
    kinematics: (String, Vec<Tried>),
    pretrain_updates: u64,
}

/// The normalised actuation of pulls `pull_m` (m, from the recording's zero lengths
/// `zero_length_m`): each tendon's length on its stroke. [`Calibrated`] goes the other way.
fn actuation_of<const N: usize>(arm: &Layout, zero_length_m: &[f64], pull_m: &[f64]) -> [f64; N] {
    std::array::from_fn(|i| arm.actuators()[i].actuation_of(zero_length_m[i] - pull_m[i]))
}

/// Each row's normalised actuation.
fn actuations<const N: usize>(arm: &Layout, rows: &Rows) -> Vec<[f64; N]> {
    (rows.rows.iter())
        .map(|r| actuation_of(arm, &rows.zero_length_m, &r.pull_m))
        .collect()
}

/// The calibrated arm as a forward model over normalised actuation.
struct Calibrated<'a, F: Fn(&[f64]) -> [f64; 3]> {
    predict: F,
    arm: &'a Layout,
    zero_length_m: &'a [f64],
}

impl<const N: usize, F: Fn(&[f64]) -> [f64; 3]> ForwardModel<N> for Calibrated<'_, F> {
    fn position(&self, a: &[f64; N]) -> Position {
        let pulls: [f64; N] = std::array::from_fn(|i| {
            self.zero_length_m[i] - self.arm.actuators()[i].length_of(a[i])
        });
        (self.predict)(&pulls)
    }
}

fn bundle<const N: usize>(
    config: &Config,
    arm: &Layout,
    identification: &Identification,
) -> Result<(Model<N>, Built)> {
    let rows = &identification.recording;
    let acts = actuations::<N>(arm, rows);
    let positions: Vec<Position> = rows.rows.iter().map(|r| r.tip_m).collect();
    let motions = rows.motions();
    let motion: Vec<usize> = (rows.rows.iter())
        .map(|r| motions.binary_search(&r.motion).unwrap_or(0))
        .collect();

    // The primitives: a demonstration per motion of enough rows, its class its first word;
    // past the most softarm blends, the classes of fewest motions become one, `other`.
    let long: Vec<(usize, Vec<usize>)> = (0..motions.len())
        .map(|m| {
            (
                m,
                (0..rows.len())
                    .filter(|j| motion[*j] == m)
                    .collect::<Vec<_>>(),
            )
        })
        .filter(|(_, mine)| mine.len() >= MIN_ROWS)
        .collect();
    if long.is_empty() {
        bail!(
            "{}: no motion has {MIN_ROWS} rows or more: a primitive needs motions, not single \
             poses",
            rows.path.display()
        );
    }
    let classes = classes_of(long.iter().map(|(m, _)| rows.class_of(&motions[*m])));
    let demonstrations: Vec<Recording<N>> = (long.iter().zip(&classes.of))
        .map(|((_, mine), class)| {
            let t0 = rows.rows[mine[0]].time_s;
            let span = (rows.rows[mine[mine.len() - 1]].time_s - t0).max(1e-9);
            Recording {
                class: *class,
                // Each motion on the config's demonstration duration: a primitive is a shape
                // in phase, the set's times place it.
                times: (mine.iter())
                    .map(|j| (rows.rows[*j].time_s - t0) / span * config.demonstrations.duration_s)
                    .collect(),
                actuation: mine.iter().map(|j| acts[*j]).collect(),
                position: mine.iter().map(|j| positions[*j]).collect(),
            }
        })
        .collect();
    let classes = classes.names;
    let mut train = training(config);
    let (actuation, task) = pipeline::primitives(&demonstrations, train.basis_functions)
        .context("the primitives from the recording's motions")?;

    // The data-driven models, each at the size cross-validation chooses.
    let rbf_candidates: Vec<NetworkConfig> = [25, 50, 100, 200, 400]
        .into_iter()
        .filter(|c| c + N + 1 < rows.len() * (FOLDS - 1) / FOLDS)
        .flat_map(|centres| {
            [1.5, 3.0].into_iter().flat_map(move |width_factor| {
                MODEL_RIDGES.map(|ridge| NetworkConfig {
                    centres,
                    width_factor,
                    ridge,
                    widths: 1,
                })
            })
        })
        .collect();
    let data = Data {
        acts: &acts,
        positions: &positions,
        motion: &motion,
    };
    let progress = bar((rbf_candidates.len() * FOLDS) as u64, "RBF network");
    let (forward_config, forward_tried) = choose(
        &rbf_candidates,
        describe_rbf,
        |a, p, c| RbfNetwork::fit(a, p, c).map_err(|e| e.to_string()),
        &data,
        &mut || progress.inc(1),
    )?;
    progress.finish_and_clear();
    let terms = |degree: usize| (1..=degree).fold(1usize, |t, d| t * (N + d) / d);
    let poly_candidates: Vec<PolynomialConfig> = (1..=4)
        .filter(|d| terms(*d) < rows.len() / 2)
        .flat_map(|degree| MODEL_RIDGES.map(|ridge| PolynomialConfig { degree, ridge }))
        .collect();
    let progress = bar((poly_candidates.len() * FOLDS) as u64, "polynomial");
    let (kinematics_config, kinematics_tried) = choose(
        &poly_candidates,
        |c| format!("{}/{:e}", c.degree, c.ridge),
        Polynomial::fit,
        &data,
        &mut || progress.inc(1),
    )?;
    progress.finish_and_clear();
    train.forward = forward_config;
    train.kinematics = kinematics_config;
    let forward = RbfNetwork::fit(&acts, &positions, &train.forward)
        .map_err(|e| anyhow::anyhow!("the RBF forward model on every row: {e}"))?;
    let kinematics = Polynomial::fit(&acts, &positions, &train.kinematics)
        .map_err(|e| anyhow::anyhow!("the polynomial kinematics on every row: {e}"))?;

    // The learner, pre-trained against the calibrated arm on the recording's own poses.
    let structure = Structure::of(arm);
    let calibrated = Calibrated {
        predict: identification.model.predictor(&structure, false),
        arm,
        zero_length_m: &rows.zero_length_m,
    };
    let limit = budget(config.pretrain.budget_s)?;
    let mut started: Option<(Instant, softarm_identify::run::Bar)> = None;
    let (learner, report) = pipeline::learner(&train, &calibrated, &acts, &positions, |_| {
        let (start, progress) =
            started.get_or_insert_with(|| (Instant::now(), bar(limit.as_secs(), "pre-training s")));
        progress.set_position(start.elapsed().as_secs());
        start.elapsed() < limit
    })
    .context("pre-training the learner against the calibrated arm")?;
    if let Some((_, progress)) = started {
        progress.finish_and_clear();
    }
    let model = Model {
        actuation,
        task,
        forward,
        kinematics,
        learner: learner.state(),
        demo_duration_s: config.demonstrations.duration_s,
        arm: String::new(),
        id: String::new(),
    };
    Ok((
        model,
        Built {
            classes,
            demonstrations: demonstrations.len(),
            forward: (
                format!(
                    "{} centres, width {}, ridge {:e}",
                    train.forward.centres, train.forward.width_factor, train.forward.ridge
                ),
                forward_tried,
            ),
            kinematics: (
                format!(
                    "degree {}, ridge {:e}",
                    train.kinematics.degree, train.kinematics.ridge
                ),
                kinematics_tried,
            ),
            pretrain_updates: report.updates,
        },
    ))
}

/// Classes numbered by first appearance, and each motion's.
struct Classes {
    names: Vec<String>,
    of: Vec<usize>,
}

/// The class of each motion by its name; past [`MAX_PRIMITIVES`], the classes of fewest
/// motions are one, `other`.
fn classes_of(names: impl Iterator<Item = String>) -> Classes {
    let names: Vec<String> = names.collect();
    let mut count: Vec<(String, usize)> = Vec::new();
    for n in &names {
        match count.iter_mut().find(|(c, _)| c == n) {
            Some((_, k)) => *k += 1,
            None => count.push((n.clone(), 1)),
        }
    }
    let keep: Vec<String> = if count.len() <= MAX_PRIMITIVES {
        count.into_iter().map(|(c, _)| c).collect()
    } else {
        let mut by_size = count.clone();
        by_size.sort_by_key(|c| std::cmp::Reverse(c.1));
        let kept: Vec<&String> = by_size[..MAX_PRIMITIVES - 1]
            .iter()
            .map(|(c, _)| c)
            .collect();
        (count.iter())
            .filter(|(c, _)| kept.contains(&c))
            .map(|(c, _)| c.clone())
            .collect()
    };
    let mut classes = Classes {
        names: keep,
        of: Vec::with_capacity(names.len()),
    };
    for n in &names {
        let class = match classes.names.iter().position(|c| c == n) {
            Some(c) => c,
            None => match classes.names.iter().position(|c| c == "other") {
                Some(c) => c,
                None => {
                    classes.names.push("other".into());
                    classes.names.len() - 1
                }
            },
        };
        classes.of.push(class);
    }
    classes
}

fn describe_rbf(c: &NetworkConfig) -> String {
    format!("{}/{}/{:e}", c.centres, c.width_factor, c.ridge)
}

/// The rows the data-driven models are fitted to: actuation, tip, and each row's motion.
struct Data<'a, const N: usize> {
    acts: &'a [[f64; N]],
    positions: &'a [Position],
    motion: &'a [usize],
}

/// The candidate whose fits on four fifths of the motions miss the fifth least (RMS over
/// every held-out row), and what each measured.
fn choose<const N: usize, C: Copy, M: ForwardModel<N>>(
    candidates: &[C],
    name: impl Fn(&C) -> String,
    fit: impl Fn(&[[f64; N]], &[Position], &C) -> std::result::Result<M, String>,
    data: &Data<N>,
    tick: &mut dyn FnMut(),
) -> Result<(C, Vec<Tried>)> {
    let Data {
        acts,
        positions,
        motion,
    } = *data;
    let mut tried = Vec::new();
    let mut best: Option<(f64, C)> = None;
    for c in candidates {
        let (mut sum, mut count) = (0.0, 0usize);
        for fold in 0..FOLDS {
            tick();
            let seen: Vec<usize> = (0..acts.len())
                .filter(|j| motion[*j] % FOLDS != fold)
                .collect();
            let a: Vec<[f64; N]> = seen.iter().map(|j| acts[*j]).collect();
            let p: Vec<Position> = seen.iter().map(|j| positions[*j]).collect();
            let Ok(model) = fit(&a, &p, c) else {
                sum = f64::INFINITY;
                continue;
            };
            for j in (0..acts.len()).filter(|j| motion[*j] % FOLDS == fold) {
                let q = model.position(&acts[j]);
                sum += (0..3)
                    .map(|k| (q[k] - positions[j][k]).powi(2))
                    .sum::<f64>();
                count += 1;
            }
        }
        let rms = (sum / count.max(1) as f64).sqrt();
        tried.push(Tried {
            what: name(c),
            held_out_rms_mm: rms * 1e3,
        });
        if rms.is_finite() && best.is_none_or(|(b, _)| rms < b) {
            best = Some((rms, *c));
        }
    }
    match best {
        Some((_, c)) => Ok((c, tried)),
        None => {
            let motions = motion
                .iter()
                .collect::<std::collections::BTreeSet<_>>()
                .len();
            bail!(
                "no candidate model could be fitted without each fifth of the motions: the \
                 recording's {} rows of {motions} motions are too few (record more motions); \
                 nothing was written",
                acts.len()
            )
        }
    }
}

/// Every model `train --from` made, against one recording.
#[derive(Debug, Clone)]
pub struct Compared {
    /// The calibrated physical model with its residual: the identified model.
    pub identified: Check,
    pub physical: Check,
    /// The bundle's, if the model's folder has one for this arm.
    pub rbf_network: Option<Check>,
    pub polynomial: Option<Check>,
}

/// `softarm model check`: the identified model at `model_file` and the bundle beside it,
/// against the recording `rows`.
pub fn check(arm: &Layout, rows: &Rows, model_file: &Path) -> Result<Compared> {
    let model = Identified::read(model_file, arm)?;
    let identified = identify::check_model(&model, arm, rows, false);
    let physical = identify::check_model(&model, arm, rows, true);
    let dir = model_file.parent().unwrap_or(Path::new("."));
    let n = arm.actuators().len();
    let (rbf_network, polynomial) = softarm_method::space::with_actuators!(n, N => bundle_checks::<N>(arm, rows, dir), _n => (None, None));
    Ok(Compared {
        identified,
        physical,
        rbf_network,
        polynomial,
    })
}

fn bundle_checks<const N: usize>(
    arm: &Layout,
    rows: &Rows,
    dir: &Path,
) -> (Option<Check>, Option<Check>) {
    let Ok(model) = Model::<N>::read_for_arm(dir, &arm.identity()) else {
        return (None, None);
    };
    let on = |m: &dyn Fn(&[f64; N]) -> Position| {
        check::check(
            rows,
            |pulls| m(&actuation_of(arm, &rows.zero_length_m, pulls)),
            &mut || {},
        )
    };
    (
        Some(on(&|a| model.forward.position(a))),
        Some(on(&|a| model.kinematics.position(a))),
    )
}

impl Compared {
    fn each(&self) -> Vec<(&'static str, &Check)> {
        let mut out = vec![
            ("identified (physical + residual)", &self.identified),
            ("physical model alone", &self.physical),
        ];
        if let Some(c) = &self.rbf_network {
            out.push(("RBF network", c));
        }
        if let Some(c) = &self.polynomial {
            out.push(("polynomial", c));
        }
        out
    }

    pub fn table(&self) -> String {
        (self.each().into_iter())
            .map(|(name, c)| format!("{name}\n{}", c.table()))
            .collect::<Vec<_>>()
            .join("\n")
    }

    /// One JSON object: the identified model's `all` and `families` first, then each model's.
    pub fn json(&self) -> String {
        let identified = self.identified.json();
        let rest: Vec<String> = (self.each().into_iter().skip(1))
            .map(|(name, c)| {
                let key = match name {
                    "physical model alone" => "physical",
                    "RBF network" => "rbf_network",
                    _ => "polynomial",
                };
                format!("\"{key}\":{}", c.json())
            })
            .collect();
        format!(
            "{},{}}}",
            &identified[..identified.len() - 1],
            rest.join(",")
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classes_past_the_most_blended_become_other() {
        let few = classes_of(["seg", "pair", "seg"].map(String::from).into_iter());
        assert_eq!(few.names, ["seg", "pair"]);
        assert_eq!(few.of, [0, 1, 0]);
        // Ten kinds, the first of three motions, the rest of one each.
        let names = ["a", "a", "a", "b", "c", "d", "e", "f", "g", "h", "i", "j"];
        let many = classes_of(names.map(String::from).into_iter());
        assert_eq!(many.names.len(), MAX_PRIMITIVES);
        assert_eq!(many.names[0], "a");
        assert_eq!(many.names.last().unwrap(), "other");
        let other = MAX_PRIMITIVES - 1;
        assert_eq!(many.of.iter().filter(|c| **c == other).count(), 3);
        assert!(many.of.iter().all(|c| *c < MAX_PRIMITIVES));
    }
}
