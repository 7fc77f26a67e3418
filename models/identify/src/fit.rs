//! The physical model ([`crate::tendon`]) calibrated to a recording: damped Gauss-Newton
//! (Levenberg-Marquardt) on the tip's miss, within a prior around the configured arm whose
//! strength is chosen by cross-validation over held-out motions.
//!
//! Why a prior, and why chosen so: a recording of a few motion families leaves some
//! parameters barely told apart (a longer first module or a base further down; a radius or a
//! stiffness), and a free fit trades them off to fit what it saw, which carries badly to
//! motions it did not see. How strongly to hold the arm to its configuration is what the
//! held-out motions of the training recording decide, never another recording. Pure math.

use nalgebra::{DMatrix, DVector};
use softarm_kinematics::linalg::on_every_core;

use crate::residual::{RIDGES, Residual, WIDTHS};
use crate::tendon::{Model, Shape, Slots, Structure};

/// One sample: the actuators' pulls (m) and the tracked tip (m).
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    pub pull_m: Vec<f64>,
    pub tip_m: [f64; 3],
    /// Which cross-validation group (motion) it belongs to.
    pub group: usize,
}

/// Which terms beyond the configured arm's geometry and stiffnesses a fit calibrates; a term
/// off stays at 0 (its slots are not fitted).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Terms {
    /// Each module's weight and the payload at the marker ([`Slots::gravity`]).
    pub gravity: bool,
}

/// How far each kind of parameter plausibly is from the configured arm (the prior's standard
/// deviations at strength 1): a backbone within 10 %, a radius within 30 %, a tendon's angle
/// within 10°, a module turned within 60°, slack within 3 mm, stiffnesses within e³, the marker
/// within 2 cm of the axis, the base tilted within 5° and placed within 2 cm. A term `terms`
/// leaves off has 0: it is not fitted.
pub fn prior_sd(slots: Slots, nominal: &[f64], terms: Terms) -> Vec<f64> {
    let mut sd = vec![0.0; slots.count()];
    for m in 0..slots.modules {
        sd[slots.length(m)] = 0.1 * nominal[slots.length(m)].abs() + 0.002;
        sd[slots.bend_stiffness(m)] = 3.0;
        sd[slots.rotation(m)] = 60f64.to_radians();
    }
    sd[slots.axial_stiffness()] = 3.0;
    sd[slots.tendon_stiffness()] = 3.0;
    for i in 0..slots.tendons {
        sd[slots.radius(i)] = 0.3 * nominal[slots.radius(i)].abs() + 0.0005;
        sd[slots.angle(i)] = 10f64.to_radians();
        sd[slots.offset(i)] = 0.003;
    }
    for k in 0..3 {
        sd[slots.marker(k)] = 0.02;
        sd[slots.base_rotation(k)] = 5f64.to_radians();
        sd[slots.base_position(k)] = 0.02;
    }
    if terms.gravity {
        // A module of a few tens of grams on a backbone a few hundredths of a newton-metre
        // stiff: module 0's weight some units per metre, its direction anything; the others'
        // masses near their share of the length, a payload of a fraction of a module.
        for k in 0..3 {
            sd[slots.gravity_vector(k)] = 5.0;
        }
        for m in 1..slots.modules {
            sd[slots.weight(m)] = 0.5;
        }
        sd[slots.payload()] = 0.3;
    }
    sd
}

/// Whether slot `k`'s prior holds it to the configured arm (and so grows with the strength):
/// the configuration says nothing of weight, so gravity's prior is only its plausible range.
fn held_to_configuration(slots: Slots, k: usize) -> bool {
    !slots.gravity().contains(&k)
}

/// The fitted parameters and how well they fit.
#[derive(Debug, Clone, PartialEq)]
pub struct Fitted {
    pub theta: Vec<f64>,
    /// RMS of the tip's miss over the samples fitted (m).
    pub rms_m: f64,
}

/// Levenberg-Marquardt iterations at most.
const ITERATIONS: usize = 40;

/// The residual scale (m): a millimetre.
const SIGMA_M: f64 = 0.001;

/// A calibration problem: the arm, the prior's centre and spread, its strength.
pub struct Problem<'a> {
    pub structure: &'a Structure,
    pub center: &'a [f64],
    pub sd: &'a [f64],
    /// Multiplies the prior's weight: 0 fits freely, large keeps the configured arm.
    pub strength: f64,
}

impl Problem<'_> {
    fn theta(&self, z: &DVector<f64>) -> Vec<f64> {
        (0..z.len())
            .map(|k| self.center[k] + z[k] * self.sd[k])
            .collect()
    }

    /// Residuals (scaled misses, then the prior's) at `theta`, the shapes warm-started from
    /// and written back to `shapes` (when `keep`), settled on gravity's `curvatures` there.
    fn residuals(
        &self,
        z: &DVector<f64>,
        samples: &[&Sample],
        shapes: &mut [Shape],
        curvatures: &[Option<DMatrix<f64>>],
        keep: bool,
    ) -> DVector<f64> {
        let theta = self.theta(z);
        let model = Model::new(self.structure, &theta);
        let mut r = DVector::zeros(3 * samples.len() + z.len());
        for (j, s) in samples.iter().enumerate() {
            let shape = match curvatures.get(j) {
                Some(c) => model.settle_on(&s.pull_m, &shapes[j], c.as_ref()),
                None => model.settle(&s.pull_m, &shapes[j]),
            };
            let p = model.marker(&shape);
            for k in 0..3 {
                r[3 * j + k] = (p[k] - s.tip_m[k]) / SIGMA_M;
            }
            if keep {
                shapes[j] = shape;
            }
        }
        let slots = self.structure.slots;
        let w = self.strength.sqrt();
        for k in 0..z.len() {
            let weight = if held_to_configuration(slots, k) {
                w
            } else {
                1.0
            };
            r[3 * samples.len() + k] = weight * z[k];
        }
        r
    }

    /// Gravity's curvature at each of `shapes` for the arm at `z`: what the Jacobian's small
    /// steps settle on (none without gravity).
    fn curvatures(&self, z: &DVector<f64>, shapes: &[Shape]) -> Vec<Option<DMatrix<f64>>> {
        let theta = self.theta(z);
        let model = Model::new(self.structure, &theta);
        (shapes.iter())
            .map(|s| model.is_heavy().then(|| model.gravity_curvature(s)))
            .collect()
    }

    /// `z` with no mass below zero (a projected step): a negative mass is no arm, and a fit
    /// left free gave the short third module -1.2 times the first's.
    fn feasible(&self, mut z: DVector<f64>) -> DVector<f64> {
        for k in self.structure.slots.masses() {
            if k < z.len() && self.sd[k] > 0.0 {
                z[k] = z[k].max(-self.center[k] / self.sd[k]);
            }
        }
        z
    }

    /// Fits from `start` (parameters).
    pub fn fit(&self, start: &[f64], samples: &[&Sample]) -> Fitted {
        let p = start.len();
        let vars = 3 * self.structure.slots.modules;
        let mut z = DVector::from_fn(p, |k, _| {
            if self.sd[k] == 0.0 {
                0.0
            } else {
                (start[k] - self.center[k]) / self.sd[k]
            }
        });
        let mut shapes = vec![DVector::zeros(vars); samples.len()];
        let mut r = self.residuals(&z, samples, &mut shapes, &[], true);
        let mut cost = r.norm_squared();
        let mut damping = 1.0;
        for _ in 0..ITERATIONS {
            let h = 1e-6;
            let curvatures = self.curvatures(&z, &shapes);
            let mut jac = DMatrix::zeros(r.len(), p);
            for k in 0..p {
                // A parameter not fitted (a term off) has no column.
                if self.sd[k] == 0.0 {
                    continue;
                }
                let mut zk = z.clone();
                zk[k] += h;
                let rk = self.residuals(&zk, samples, &mut shapes, &curvatures, false);
                jac.set_column(k, &((rk - &r) / h));
            }
            let jtj = jac.tr_mul(&jac);
            let jtr = jac.tr_mul(&r);
            let mut improved = false;
            for _ in 0..16 {
                let mut a = jtj.clone();
                for k in 0..p {
                    a[(k, k)] += damping * (jtj[(k, k)] + 1e-9);
                }
                let Some(step) = a.cholesky().map(|c| c.solve(&-&jtr)) else {
                    damping *= 10.0;
                    continue;
                };
                let trial = self.feasible(&z + &step);
                let mut trial_shapes = shapes.clone();
                let rt = self.residuals(&trial, samples, &mut trial_shapes, &curvatures, true);
                let ct = rt.norm_squared();
                if ct.is_finite() && ct < cost {
                    let gain = (cost - ct) / cost;
                    z = trial;
                    r = rt;
                    cost = ct;
                    shapes = trial_shapes;
                    damping = (damping / 3.0).max(1e-9);
                    improved = gain > 1e-7;
                    break;
                }
                damping *= 4.0;
            }
            if !improved {
                break;
            }
        }
        let misses = r.rows(0, 3 * samples.len()).norm_squared() * SIGMA_M * SIGMA_M;
        Fitted {
            theta: self.theta(&z),
            rms_m: (misses / samples.len().max(1) as f64).sqrt(),
        }
    }
}

/// How far `theta` misses `samples`: the RMS (m).
pub fn rms_m(structure: &Structure, theta: &[f64], samples: &[&Sample]) -> f64 {
    let model = Model::new(structure, theta);
    let sum: f64 = (samples.iter())
        .map(|s| {
            let p = model.predict(&s.pull_m);
            (0..3).map(|k| (p[k] - s.tip_m[k]).powi(2)).sum::<f64>()
        })
        .sum();
    (sum / samples.len().max(1) as f64).sqrt()
}

/// The configured arm's angles turned by one of twelve angles and read either way round
/// (the recording's frame turned about the axis, the tendons numbered the other way): the
/// start that fits `samples` best, its base moved by the mean miss (the recording's origin
/// off the base). A local fit from the wrong one of these does not find its way out.
pub fn orient(structure: &Structure, nominal: &[f64], samples: &[&Sample]) -> Vec<f64> {
    let s = structure.slots;
    let mut best = (f64::INFINITY, nominal.to_vec());
    for mirror in [1.0, -1.0] {
        for k in 0..12 {
            let turn = (k as f64 * 30.0).to_radians();
            let mut theta = nominal.to_vec();
            for i in 0..s.tendons {
                theta[s.angle(i)] = mirror * nominal[s.angle(i)];
            }
            for m in 0..s.modules {
                theta[s.rotation(m)] = turn;
            }
            let rms = rms_m(structure, &theta, samples);
            if rms < best.0 {
                best = (rms, theta);
            }
        }
    }
    // The base where the recording's frame puts it: the mean miss taken up by its position.
    let mut theta = best.1;
    let model = Model::new(structure, &theta);
    let mut mean = [0.0; 3];
    for sample in samples {
        let p = model.predict(&sample.pull_m);
        for k in 0..3 {
            mean[k] += (sample.tip_m[k] - p[k]) / samples.len().max(1) as f64;
        }
    }
    for k in 0..3 {
        if mean[k].is_finite() {
            theta[s.base_position(k)] += mean[k];
        }
    }
    theta
}

/// The prior strengths cross-validation chooses from.
pub const STRENGTHS: [f64; 6] = [1.0, 10.0, 100.0, 1e3, 1e4, 1e5];

/// Folds of cross-validation: whole motions held out.
pub const FOLDS: usize = 5;

/// One choice cross-validation judges: the prior's strength and the terms fitted.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Candidate {
    strength: f64,
    terms: Terms,
}

/// What cross-validation found for one candidate: the RMS over held-out motions (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Validated {
    pub strength: f64,
    pub terms: Terms,
    pub held_out_rms_m: f64,
}

/// What [`calibrate`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// Fitted to every sample (at most [`MAX_FIT_ROWS`] of them) at the chosen strength; its
    /// RMS over every sample.
    pub fitted: Fitted,
    pub strength: f64,
    pub terms: Terms,
    pub validated: Vec<Validated>,
    /// For the chosen candidate, each fold's fit (without its held-out motions): what the
    /// residual's cross-validation builds on.
    pub folds: Vec<Vec<f64>>,
}

/// Whether `sample` is held out in `fold`.
pub fn held_out(sample: &Sample, fold: usize) -> bool {
    sample.group % FOLDS == fold
}

/// Most rows a physical fit is given: a longer recording is fitted on every k-th row (each
/// fit's cost grows with its rows; a few thousand tell the model's few dozen parameters).
pub const MAX_FIT_ROWS: usize = 2000;

/// `samples`, or [`MAX_FIT_ROWS`] of them evenly spread over all of it: the folds' fits and
/// the final one of a long recording then see as many rows each, so that the prior's
/// strength, which does not grow with the rows, weighs the same in both.
fn thinned<'a>(samples: &[&'a Sample]) -> Vec<&'a Sample> {
    let n = samples.len();
    if n <= MAX_FIT_ROWS {
        return samples.to_vec();
    }
    (0..MAX_FIT_ROWS)
        .map(|k| samples[(k * n + n / 2) / MAX_FIT_ROWS])
        .collect()
}

/// Where every fit starts and what its prior is centred on: the configured arm oriented to
/// the recording ([`orient`]).
struct Start<'a> {
    structure: &'a Structure,
    nominal: &'a [f64],
    center: Vec<f64>,
}

impl<'a> Start<'a> {
    fn of(structure: &'a Structure, nominal: &'a [f64], samples: &[Sample]) -> Self {
        let all: Vec<&Sample> = samples.iter().collect();
        Self {
            structure,
            nominal,
            center: orient(structure, nominal, &thinned(&all)),
        }
    }

    fn problem(&self, sd: &'a [f64], strength: f64) -> Problem<'_> {
        Problem {
            structure: self.structure,
            center: &self.center,
            sd,
            strength,
        }
    }
}

/// Each of `candidates` fitted [`FOLDS`] times with a fifth of the motions held out (each fit
/// on at most [`MAX_FIT_ROWS`] rows, on every core), each fold's fit from `from[fold]` (fits
/// of the same fold, so nothing held out is seen) or else the prior's centre: what each
/// measured, and each fold's fit.
fn validate(
    start: &Start,
    samples: &[Sample],
    candidates: &[Candidate],
    from: Option<&[Vec<f64>]>,
    tick: &mut dyn FnMut(),
) -> Vec<(Validated, Vec<Vec<f64>>)> {
    let all: Vec<&Sample> = samples.iter().collect();
    let sds: Vec<Vec<f64>> = (candidates.iter())
        .map(|c| prior_sd(start.structure.slots, start.nominal, c.terms))
        .collect();
    // Job j: candidate j / FOLDS without fold j % FOLDS; its fit and its held-out squared miss.
    let fits = on_every_core(
        candidates.len() * FOLDS,
        |job| {
            let (c, fold) = (job / FOLDS, job % FOLDS);
            let (held, train): (Vec<&Sample>, Vec<&Sample>) =
                all.iter().partition(|s| held_out(s, fold));
            let fitted = if train.is_empty() {
                start.center.clone()
            } else {
                let problem = start.problem(&sds[c], candidates[c].strength);
                let first = from.map_or(start.center.as_slice(), |f| f[fold].as_slice());
                problem.fit(first, &thinned(&train)).theta
            };
            let missed = rms_m(start.structure, &fitted, &held).powi(2) * held.len() as f64;
            (
                fitted,
                if held.is_empty() { 0.0 } else { missed },
                held.len(),
            )
        },
        tick,
    );
    let mut fits = fits.into_iter();
    (candidates.iter())
        .map(|c| {
            let mine: Vec<_> = fits.by_ref().take(FOLDS).collect();
            let sum: f64 = mine.iter().map(|f| f.1).sum();
            let count: usize = mine.iter().map(|f| f.2).sum();
            let v = Validated {
                strength: c.strength,
                terms: c.terms,
                held_out_rms_m: (sum / count.max(1) as f64).sqrt(),
            };
            (v, mine.into_iter().map(|f| f.0).collect())
        })
        .collect()
}

/// How many fits [`calibrate`] makes: what its `tick` counts to.
pub fn calibration_fits() -> usize {
    (STRENGTHS.len() + 1) * FOLDS + 1
}

/// The calibration of `structure` to `samples`: oriented, then each of [`STRENGTHS`] without
/// gravity cross-validated ([`validate`]), then gravity at the strength chosen (the prior
/// holds the geometry as it did; gravity's own prior is its plausible range, the same at
/// every strength); the candidate whose held-out RMS is least, fitted to all. Gravity at one
/// strength only: a fit with it costs about five without. `tick` is called after each fit:
/// [`calibration_fits`] in all.
pub fn calibrate(
    structure: &Structure,
    nominal: &[f64],
    samples: &[Sample],
    tick: &mut dyn FnMut(),
) -> Calibration {
    let start = Start::of(structure, nominal, samples);
    let plain: Vec<Candidate> = (STRENGTHS.iter())
        .map(|s| Candidate {
            strength: *s,
            terms: Terms::default(),
        })
        .collect();
    let mut tried = validate(&start, samples, &plain, None, tick);
    let best = least(&tried);
    let heavy = Candidate {
        strength: tried[best].0.strength,
        terms: Terms { gravity: true },
    };
    // From each fold's fit without gravity: fewer steps to where gravity takes it.
    let from = tried[best].1.clone();
    tried.extend(validate(&start, samples, &[heavy], Some(&from), tick));
    chosen(&start, samples, tried, tick)
}

/// The index of the least held-out RMS in `tried`.
fn least(tried: &[(Validated, Vec<Vec<f64>>)]) -> usize {
    (0..tried.len())
        .min_by(|a, b| {
            tried[*a]
                .0
                .held_out_rms_m
                .total_cmp(&tried[*b].0.held_out_rms_m)
        })
        .unwrap_or(0)
}

/// The candidate of `tried` whose held-out RMS is least, fitted to every sample.
fn chosen(
    start: &Start,
    samples: &[Sample],
    mut tried: Vec<(Validated, Vec<Vec<f64>>)>,
    tick: &mut dyn FnMut(),
) -> Calibration {
    let all: Vec<&Sample> = samples.iter().collect();
    let best = least(&tried);
    let v = tried[best].0;
    let sd = prior_sd(start.structure.slots, start.nominal, v.terms);
    let mut fitted = start
        .problem(&sd, v.strength)
        .fit(&start.center, &thinned(&all));
    fitted.rms_m = rms_m(start.structure, &fitted.theta, &all);
    tick();
    Calibration {
        fitted,
        strength: v.strength,
        terms: v.terms,
        validated: tried.iter().map(|t| t.0).collect(),
        folds: tried.swap_remove(best).1,
    }
}

/// What cross-validation found for one residual (`None`: the physical model alone).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResidualValidated {
    pub width_ridge: Option<(f64, f64)>,
    pub held_out_rms_m: f64,
}

/// The residual over the physical model, or none, as cross-validation over the same held-out
/// motions chooses: each fold's residual learnt on what its fold's physical fit misses of the
/// motions it saw, judged on those it did not. Then fitted to every sample's miss of
/// `calibration.fitted`. `tick` is called once per fold of each candidate.
pub fn residual(
    structure: &Structure,
    calibration: &Calibration,
    samples: &[Sample],
    scale_m: &[f64],
    tick: &mut dyn FnMut(),
) -> (Option<Residual>, Vec<ResidualValidated>) {
    // Each fold's physical prediction of every sample, once.
    let predicted: Vec<Vec<[f64; 3]>> = (calibration.folds.iter())
        .map(|theta| {
            let model = Model::new(structure, theta);
            samples.iter().map(|s| model.predict(&s.pull_m)).collect()
        })
        .collect();
    let miss = |p: &[f64; 3], s: &Sample| -> [f64; 3] {
        [s.tip_m[0] - p[0], s.tip_m[1] - p[1], s.tip_m[2] - p[2]]
    };
    let mut tried = vec![ResidualValidated {
        width_ridge: None,
        held_out_rms_m: (calibration.validated.iter())
            .find(|v| v.strength == calibration.strength && v.terms == calibration.terms)
            .map_or(f64::INFINITY, |v| v.held_out_rms_m),
    }];
    let candidates: Vec<(f64, f64)> = (WIDTHS.iter())
        .flat_map(|w| RIDGES.iter().map(move |r| (*w, *r)))
        .collect();
    // Job j: candidate j / FOLDS learnt without fold j % FOLDS; its held-out squared miss.
    let held_out_misses = on_every_core(
        candidates.len() * FOLDS,
        |job| {
            let ((width, ridge), fold) = (candidates[job / FOLDS], job % FOLDS);
            let predicted = &predicted[fold];
            let seen: Vec<usize> = (0..samples.len())
                .filter(|j| !held_out(&samples[*j], fold))
                .collect();
            let pulls: Vec<&[f64]> = seen.iter().map(|j| samples[*j].pull_m.as_slice()).collect();
            let misses: Vec<[f64; 3]> = (seen.iter())
                .map(|j| miss(&predicted[*j], &samples[*j]))
                .collect();
            let Some(r) = Residual::fit(&pulls, &misses, scale_m, width, ridge) else {
                return (f64::INFINITY, 0);
            };
            let held = (samples.iter().enumerate()).filter(|(_, s)| held_out(s, fold));
            let (mut sum, mut count) = (0.0, 0usize);
            for (j, s) in held {
                let c = r.correction(&s.pull_m);
                let m = miss(&predicted[j], s);
                sum += (0..3).map(|k| (m[k] - c[k]).powi(2)).sum::<f64>();
                count += 1;
            }
            (sum, count)
        },
        tick,
    );
    for (candidate, folds) in candidates.iter().zip(held_out_misses.chunks(FOLDS)) {
        let sum: f64 = folds.iter().map(|f| f.0).sum();
        let count: usize = folds.iter().map(|f| f.1).sum();
        tried.push(ResidualValidated {
            width_ridge: Some(*candidate),
            held_out_rms_m: (sum / count.max(1) as f64).sqrt(),
        });
    }
    let best = (tried.iter())
        .min_by(|a, b| a.held_out_rms_m.total_cmp(&b.held_out_rms_m))
        .and_then(|v| v.width_ridge);
    let fitted = best.and_then(|(width, ridge)| {
        let model = Model::new(structure, &calibration.fitted.theta);
        let pulls: Vec<&[f64]> = samples.iter().map(|s| s.pull_m.as_slice()).collect();
        let misses: Vec<[f64; 3]> = (samples.iter())
            .map(|s| miss(&model.predict(&s.pull_m), s))
            .collect();
        Residual::fit(&pulls, &misses, scale_m, width, ridge)
    });
    (fitted, tried)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn arm() -> softarm_arm::Layout {
        crate::test_arm()
    }

    /// Pulls of one tendon at a time and pairs, as a lab's babbling: deterministic.
    fn pulls(n: usize) -> Vec<Vec<f64>> {
        let mut out = Vec::new();
        for i in 0..n {
            for step in 1..=6 {
                let mut p = vec![-0.004; n];
                p[i] = 0.0015 * step as f64;
                out.push(p);
                let mut q = vec![0.0; n];
                q[i] = 0.001 * step as f64;
                q[(i + 4) % n] = 0.0008 * step as f64;
                out.push(q);
            }
        }
        out
    }

    /// A recording of [`pulls`] on `model`, four rows a motion.
    fn recorded(model: &Model) -> Vec<Sample> {
        (pulls(6).into_iter().enumerate())
            .map(|(j, pull_m)| Sample {
                tip_m: model.predict(&pull_m),
                pull_m,
                group: j / 4,
            })
            .collect()
    }

    #[test]
    fn a_long_recording_is_thinned_evenly_to_its_cap() {
        let samples: Vec<Sample> = (0..5 * MAX_FIT_ROWS / 2)
            .map(|j| Sample {
                pull_m: vec![j as f64],
                tip_m: [0.0; 3],
                group: 0,
            })
            .collect();
        let refs: Vec<&Sample> = samples.iter().collect();
        let kept = thinned(&refs);
        assert_eq!(kept.len(), MAX_FIT_ROWS);
        let at: Vec<f64> = kept.iter().map(|s| s.pull_m[0]).collect();
        // 2.5 rows a kept one: every gap 2 or 3.
        assert!(
            at.windows(2)
                .all(|w| w[1] - w[0] >= 2.0 && w[1] - w[0] <= 3.0)
        );
        assert!(at[0] <= 2.0 && *at.last().unwrap() >= samples.len() as f64 - 3.0);
        assert_eq!(thinned(&refs[..10]).len(), 10);
    }

    #[test]
    fn a_calibration_finds_an_arm_it_was_not_told() {
        let arm = arm();
        let structure = Structure::of(&arm);
        let nominal = structure.nominal(&arm);
        let s = structure.slots;
        let mut truth = nominal.clone();
        truth[s.length(0)] = 0.108;
        truth[s.rotation(1)] = 0.3;
        truth[s.offset(2)] = 0.001;
        truth[s.marker(2)] = 0.016;
        truth[s.base_position(0)] = -0.01;
        let model = Model::new(&structure, &truth);
        let samples = recorded(&model);
        let refs: Vec<&Sample> = samples.iter().collect();
        let before = rms_m(&structure, &nominal, &refs);
        let sd = prior_sd(s, &nominal, Terms::default());
        let problem = Problem {
            structure: &structure,
            center: &nominal,
            sd: &sd,
            strength: 1e-3,
        };
        let fitted = problem.fit(&nominal, &refs);
        assert!(before > 0.01, "{before}");
        assert!(fitted.rms_m < 2e-4, "{} after {}", fitted.rms_m, before);
        assert!((fitted.theta[s.length(0)] - 0.108).abs() < 2e-3);
        // Module 2's tendons turned by 0.3 rad: its rotation and their own angles together.
        for i in 3..6 {
            let turned = fitted.theta[s.rotation(1)] + fitted.theta[s.angle(i)];
            assert!(
                (turned - nominal[s.angle(i)] - 0.3).abs() < 0.06,
                "{turned}"
            );
        }
    }

    /// A step that would make a mass negative stops at zero: a negative mass is no arm.
    #[test]
    fn no_mass_is_fitted_below_zero() {
        let arm = arm();
        let structure = Structure::of(&arm);
        let nominal = structure.nominal(&arm);
        let s = structure.slots;
        let sd = prior_sd(s, &nominal, Terms { gravity: true });
        let problem = Problem {
            structure: &structure,
            center: &nominal,
            sd: &sd,
            strength: 1.0,
        };
        let z = problem.feasible(DVector::from_element(nominal.len(), -1e3));
        let theta = problem.theta(&z);
        for k in s.masses() {
            assert!(theta[k].abs() < 1e-12, "slot {k}: {}", theta[k]);
        }
        // Gravity's direction is no mass: free either way.
        assert!(theta[s.gravity_vector(2)] < -1.0);
    }

    /// An arm with weight (hanging, as the shared recording's), sampled: the fit with gravity
    /// gives back module 1's weight, within a tenth, and misses far less than one without.
    #[test]
    fn a_calibration_with_gravity_gives_back_the_arms_weight() {
        let arm = arm();
        let structure = Structure::of(&arm);
        let nominal = structure.nominal(&arm);
        let s = structure.slots;
        let mut truth = nominal.clone();
        let weight = [0.0, 0.0, -4.0];
        for k in 0..3 {
            truth[s.gravity_vector(k)] = weight[k];
        }
        truth[s.weight(1)] = 0.7;
        truth[s.payload()] = 0.4;
        truth[s.length(0)] = 0.104;
        let model = Model::new(&structure, &truth);
        let samples = recorded(&model);
        let refs: Vec<&Sample> = samples.iter().collect();
        let fit = |gravity| {
            let sd = prior_sd(s, &nominal, Terms { gravity });
            let problem = Problem {
                structure: &structure,
                center: &nominal,
                sd: &sd,
                strength: 1e-3,
            };
            problem.fit(&nominal, &refs)
        };
        let light = fit(false);
        let heavy = fit(true);
        let found: Vec<f64> = (0..3).map(|k| heavy.theta[s.gravity_vector(k)]).collect();
        let (m1, payload) = (heavy.theta[s.weight(1)], heavy.theta[s.payload()]);
        println!(
            "RMS {:.3} mm with gravity, {:.3} without; weight {found:.3?} (truth {weight:?}), \
             module 2's mass {m1:.3} (0.7), payload {payload:.3} (0.4)",
            heavy.rms_m * 1e3,
            light.rms_m * 1e3
        );
        assert!(heavy.rms_m < 0.5 * light.rms_m);
        let off: f64 = (0..3).map(|k| (found[k] - weight[k]).powi(2)).sum::<f64>();
        assert!(off.sqrt() < 0.1 * 4.0, "{found:?}");
        // How the weight splits between module 2 and the payload is told less well (both
        // pull on module 1 from beyond its end): not asserted.
    }
}
