//! The learner's side of Alg. 2: the estimates sent for a way-point set's conditioning points
//! and what each visit teaches, under either algorithm (`learner.algorithm`):
//!
//! - [`Algorithm::Paper`] — Alg. 1 exactly: a ~ N(Ac(p_d), σ(g)² I), the critic judges, the
//!   actor moves toward the executed action when δ > 0.
//! - [`Algorithm::Softarm`] (default) — the same actor-critic, but exploration is *directed*:
//!   the errors of a changed arm are systematic and repeat every execution, so the next action
//!   of a point is a damped Gauss-Newton step from its best executed action,
//!   a = a_base + J⁺ (p_d − p_reached), with J the Jacobian of the forward model refitted online,
//!   inside a per-point trust region that shrinks when a step makes things worse. A set's first
//!   estimates are the actor's means refined against that same refitted model, so what was
//!   learnt on one set carries over to points never visited.
//!
//! The refit: p_arm(a) ≈ k(a) + c + B (a − ā), where k is the trained polynomial
//! ([`crate::poly`]) and c, B a ridge fit of the residuals of the last visits.
//! Pure: no I/O, no clock; allocation only when a set starts.

use std::collections::VecDeque;

use nalgebra::{Matrix3, SVector, Vector3};
use serde::{Deserialize, Serialize};

use crate::cacla::{CaclaMtl, Visit};
use crate::forward::{ForwardModel, Jacobian};
use crate::poly::Polynomial;
use crate::space::{ACTUATORS, Actuation, MAX_WAYPOINTS, Position, distance};

/// Which online learner runs: `learner.algorithm`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Algorithm {
    /// The paper's Alg. 1, as printed (with its three corrections), for comparison.
    Paper,
    /// Directed exploration with the refitted forward model's Jacobian (this module).
    #[default]
    Softarm,
}

impl Algorithm {
    pub fn name(self) -> &'static str {
        match self {
            Algorithm::Paper => "paper",
            Algorithm::Softarm => "softarm",
        }
    }
}

/// `[learner.correction]`: the directed corrections of [`Algorithm::Softarm`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CorrectionConfig {
    /// Fraction of the Gauss-Newton step taken for errors well above `noise_m`. Near the noise
    /// it falls as g e² / (e² + noise²), so the corrections average the tracker noise out
    /// instead of chasing it.
    pub gain: f64,
    /// μ of the damped pseudo-inverse Jᵀ(JJᵀ + μ²I)⁻¹ (m): directions that move the end
    /// effector less than this per unit actuation are not pushed along.
    pub damping_m: f64,
    /// Largest step ‖Δa‖ of a point's first correction (normalised units).
    pub trust_initial: f64,
    /// The trust region grows ×1.5 per improving step up to this, and halves per failed one
    /// down to `trust_min`.
    pub trust_max: f64,
    pub trust_min: f64,
    /// What one measurement of the error at a point scatters by (m): tracker noise, timing
    /// jitter, backlash. A rise smaller than this is noise, not a failed step.
    pub noise_m: f64,
    /// Gauss-Newton iterations of a set's first estimates against the refitted model.
    pub refine_steps: usize,
    /// The refit uses the residuals of this many last visits.
    pub refit_visits: usize,
    /// A point's Jacobian learns from a step only if the step was meant to move the end
    /// effector more than this (m, ‖J Δa‖): the noise of smaller moves would dominate.
    pub broyden_min_m: f64,
}

impl Default for CorrectionConfig {
    fn default() -> Self {
        Self {
            gain: 0.8,
            damping_m: 0.005,
            trust_initial: 0.2,
            trust_max: 0.3,
            trust_min: 0.01,
            noise_m: 0.002,
            refine_steps: 10,
            refit_visits: 64,
            broyden_min_m: 0.005,
        }
    }
}

impl CorrectionConfig {
    /// Checks every field; the error is `learner.correction.KEY: message`.
    pub fn validate(&self) -> Result<(), String> {
        let bad = |key: &str, m: String| Err(format!("learner.correction.{key}: {m}"));
        // (key, value, smallest (exclusive), largest)
        let ranges = [
            ("gain", self.gain, 0.0, 1.0),
            ("damping_m", self.damping_m, 0.0, 1.0),
            ("trust_initial", self.trust_initial, 0.0, 2.5),
            ("trust_max", self.trust_max, 0.0, 2.5),
            ("trust_min", self.trust_min, 0.0, 2.5),
            ("noise_m", self.noise_m, 0.0, 1.0),
            ("broyden_min_m", self.broyden_min_m, 0.0, 1.0),
        ];
        for (k, v, lo, hi) in ranges {
            if !(v.is_finite() && v > lo && v <= hi) {
                return bad(k, format!("must be in ({lo}, {hi}], got {v:?}"));
            }
        }
        if !(self.trust_min <= self.trust_initial && self.trust_initial <= self.trust_max) {
            return bad(
                "trust_initial",
                format!(
                    "must lie between trust_min ({}) and trust_max ({}), got {}",
                    self.trust_min, self.trust_max, self.trust_initial
                ),
            );
        }
        if self.refine_steps > 1000 {
            return bad(
                "refine_steps",
                format!("must be 0 to 1000, got {}", self.refine_steps),
            );
        }
        if !(1..=100_000).contains(&self.refit_visits) {
            return bad(
                "refit_visits",
                format!("must be 1 to 100000, got {}", self.refit_visits),
            );
        }
        Ok(())
    }
}

/// A visit or estimate that does not fit the running set.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OnlineError {
    #[error("point {point} is not in the set ({points} points)")]
    PointOutOfRange { point: usize, points: usize },
    #[error("a set has 1 to {MAX_WAYPOINTS} points, got {0}")]
    SetSize(usize),
    #[error("point {point} is {got:?}, but the set has it at {want:?}")]
    TargetMismatch {
        point: usize,
        got: Position,
        want: Position,
    },
    #[error("a position or the actuation is not finite")]
    NotFinite,
}

/// One executed try at a point.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Try {
    action: Actuation,
    reached: Position,
    error: f64,
}

/// What the learner knows of one conditioning point of the running set.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Point {
    /// Unknown when the learner joined a set already running (after a restart) until a sample
    /// names it.
    target: Option<Position>,
    /// The exploration-free estimate of its first execution.
    first: Option<Actuation>,
    last: Option<Try>,
    best: Option<Try>,
    /// The trust region's radius (‖Δa‖).
    radius: f64,
    /// The point's own Jacobian: the model's at its first correction, then Broyden-updated
    /// from what each step really did.
    jacobian: Option<Jacobian>,
    /// The systematic error p_d − p at the last try and its variance (m²): a Kalman filter
    /// over the executions, so a correction follows the arm, not one noisy tracker sample.
    bias: Option<(Vector3<f64>, f64)>,
    /// The pending estimate went back to the best try after a worse one.
    retry: bool,
}

/// The online refit: what the trained polynomial k gets wrong about the arm as it is now, as
/// the mean c of the residuals p_reached − k(a_measured) of the last visits. Only the offset: a
/// slope fitted to a handful of clustered points extrapolates wildly (measured: a second set
/// started 60 % worse with one), while a changed tool, creep or twist shifts the end effector
/// alike over a region.
struct Refit {
    residuals: VecDeque<Vector3<f64>>,
    offset: Vector3<f64>,
}

impl Refit {
    fn new() -> Self {
        Self {
            residuals: VecDeque::new(),
            offset: Vector3::zeros(),
        }
    }

    fn push(&mut self, residual: Vector3<f64>, keep: usize) {
        while self.residuals.len() >= keep {
            self.residuals.pop_front();
        }
        self.residuals.push_back(residual);
        self.offset = self.residuals.iter().sum::<Vector3<f64>>() / self.residuals.len() as f64;
    }
}

/// The trained polynomial shifted by the refit: the model the corrections are steered by.
struct Refitted<'a> {
    kinematics: &'a Polynomial,
    offset: Vector3<f64>,
}

impl ForwardModel for Refitted<'_> {
    fn position(&self, a: &Actuation) -> Position {
        let p = self.kinematics.position(a);
        std::array::from_fn(|d| p[d] + self.offset[d])
    }

    fn jacobian(&self, a: &Actuation) -> Jacobian {
        self.kinematics.jacobian(a)
    }
}

/// How far a step's effect may differ from J Δa (a fraction of it): the filter's process noise.
const STEP_UNCERTAINTY: f64 = 0.3;
/// What the arm may drift between two executions, as a fraction of the measurement variance: the
/// filter never stops listening.
const DRIFT: f64 = 0.1;

/// Δa = g Jᵀ(JJᵀ + μ²I)⁻¹ e, shortened to at most `radius`.
fn correction(
    j: &Jacobian,
    e: &Vector3<f64>,
    gain: f64,
    c: &CorrectionConfig,
    radius: f64,
) -> Actuation {
    let jjt = j * j.transpose() + Matrix3::identity() * c.damping_m * c.damping_m;
    let Some(inv) = jjt.try_inverse() else {
        return [0.0; ACTUATORS];
    };
    let mut step = j.transpose() * inv * e * gain;
    let norm = step.norm();
    if norm > radius {
        step *= radius / norm;
    }
    std::array::from_fn(|i| step[i])
}

fn plus(a: &Actuation, step: &Actuation) -> Actuation {
    std::array::from_fn(|i| (a[i] + step[i]).clamp(0.0, 1.0))
}

fn error_vector(target: &Position, p: &Position) -> Vector3<f64> {
    Vector3::from_fn(|d, _| target[d] - p[d])
}

/// CACLA-MTL at the conditioning points of the running set, with the chosen algorithm.
pub struct OnlineLearner {
    cacla: CaclaMtl,
    kinematics: Polynomial,
    refit: Refit,
    set: Vec<Point>,
}

impl OnlineLearner {
    pub fn new(cacla: CaclaMtl, kinematics: Polynomial) -> Self {
        Self {
            cacla,
            kinematics,
            refit: Refit::new(),
            set: Vec::with_capacity(MAX_WAYPOINTS),
        }
    }

    pub fn algorithm(&self) -> Algorithm {
        self.cacla.config().algorithm
    }

    pub fn cacla(&self) -> &CaclaMtl {
        &self.cacla
    }

    /// Visits the refit holds.
    pub fn refit_visits(&self) -> usize {
        self.refit.residuals.len()
    }

    /// Where the refitted model puts the end effector for `a`.
    pub fn predict(&self, a: &Actuation) -> Position {
        self.model().position(a)
    }

    fn model(&self) -> Refitted<'_> {
        Refitted {
            kinematics: &self.kinematics,
            offset: self.refit.offset,
        }
    }

    /// A new set: every point's history starts over; returns the estimates of its first
    /// execution (no exploration).
    pub fn start_set(&mut self, targets: &[Position]) -> Result<Vec<Actuation>, OnlineError> {
        self.begin(targets.len())?;
        if targets.iter().flatten().any(|v| !v.is_finite()) {
            return Err(OnlineError::NotFinite);
        }
        targets
            .iter()
            .enumerate()
            .map(|(n, t)| self.estimate(n, t, false))
            .collect()
    }

    /// Joins a set of `points` points whose targets are not known yet (the learner restarted
    /// while it ran): each point's target is taken from the first sample that names it.
    pub fn begin(&mut self, points: usize) -> Result<(), OnlineError> {
        if !(1..=MAX_WAYPOINTS).contains(&points) {
            return Err(OnlineError::SetSize(points));
        }
        self.cacla.forget_points();
        self.set.clear();
        self.set.resize(
            points,
            Point {
                target: None,
                first: None,
                last: None,
                best: None,
                radius: self.cacla.config().correction.trust_initial,
                jacobian: None,
                bias: None,
                retry: false,
            },
        );
        Ok(())
    }

    /// Points of the running set (0 before the first).
    pub fn points(&self) -> usize {
        self.set.len()
    }

    /// Checks `point` and `target` against the set and fills in an unknown target.
    fn point(&mut self, point: usize, target: &Position) -> Result<&mut Point, OnlineError> {
        let points = self.set.len();
        let p = self
            .set
            .get_mut(point)
            .ok_or(OnlineError::PointOutOfRange { point, points })?;
        if !target.iter().all(|v| v.is_finite()) {
            return Err(OnlineError::NotFinite);
        }
        match p.target {
            Some(want) if want != *target => {
                return Err(OnlineError::TargetMismatch {
                    point,
                    got: *target,
                    want,
                });
            }
            _ => p.target = Some(*target),
        }
        Ok(p)
    }

    /// One visit: `action` was executed for `point` and the end effector reached `reached`,
    /// the actuators having reported `measured` there (if known). Alg. 1's update under both
    /// algorithms; under `softarm` also the refit and the point's trust region.
    pub fn observe(
        &mut self,
        point: usize,
        target: &Position,
        action: &Actuation,
        reached: &Position,
        measured: Option<&Actuation>,
    ) -> Result<Visit, OnlineError> {
        if !action.iter().chain(reached).all(|v| v.is_finite()) {
            return Err(OnlineError::NotFinite);
        }
        let c = self.cacla.config().correction;
        let softarm = self.algorithm() == Algorithm::Softarm;
        let p = self.point(point, target)?;
        let error = distance(target, reached);
        let now = Try {
            action: *action,
            reached: *reached,
            error,
        };
        if softarm {
            // Broyden: J += (Δp − J Δa) Δaᵀ / ‖Δa‖², from a step large enough to stand out of
            // the noise. It learns what the model gets wrong about this arm at this point.
            if let (Some(last), Some(j)) = (p.last, p.jacobian.as_mut()) {
                let da = SVector::<f64, ACTUATORS>::from_fn(|i, _| action[i] - last.action[i]);
                let dp = Vector3::from_fn(|d, _| reached[d] - last.reached[d]);
                // Judged by what the step was meant to do: a tiny step whose Δp is mostly
                // noise would teach J a huge slope.
                if (*j * da).norm() > c.broyden_min_m {
                    *j += (dp - *j * da) * da.transpose() / da.norm_squared();
                }
            }
            // Predict the error from the last try and the step since (J Δa), then weigh in the
            // measurement: a large step is trusted to the measurement, small ones average.
            let observed = error_vector(target, reached);
            let r = c.noise_m * c.noise_m;
            p.bias = Some(match (p.bias, p.last, p.jacobian) {
                (Some((bias, var)), Some(last), Some(j)) => {
                    let da = SVector::<f64, ACTUATORS>::from_fn(|i, _| action[i] - last.action[i]);
                    let moved = j * da;
                    let predicted = bias - moved;
                    let var = var + (STEP_UNCERTAINTY * moved.norm()).powi(2) + DRIFT * r;
                    let k = var / (var + r);
                    (predicted + (observed - predicted) * k, (1.0 - k) * var)
                }
                _ => (observed, r),
            });
            match p.best {
                Some(best) if error < best.error => {
                    p.radius = (p.radius * 1.5).min(c.trust_max);
                    p.best = Some(now);
                }
                Some(best) if error > best.error + c.noise_m => {
                    p.radius = (p.radius * 0.5).max(c.trust_min);
                    // The next step starts from the best try, whose error is measured, not
                    // filtered.
                    p.bias = None;
                    // Worse again after going back to the best: that best was a lucky tracker
                    // sample, or the arm has changed since. This try is where things stand.
                    if p.retry {
                        p.best = Some(now);
                    }
                }
                Some(_) => {}
                None => p.best = Some(now),
            }
            p.last = Some(now);
            // The refit learns the arm, not the lag: from what the actuators did where they
            // are known, else from the setpoint.
            let at = match measured {
                Some(m) if m.iter().all(|v| v.is_finite()) => *m,
                _ => *action,
            };
            let predicted = self.kinematics.position(&at);
            let residual = Vector3::from_fn(|d, _| reached[d] - predicted[d]);
            self.refit.push(residual, c.refit_visits);
        }
        Ok(self.cacla.observe(point, target, action, reached))
    }

    /// The actuation to send for `point`'s next visit; with `explore` false (a set's first
    /// execution) the exploration-free estimate.
    pub fn estimate(
        &mut self,
        point: usize,
        target: &Position,
        explore: bool,
    ) -> Result<Actuation, OnlineError> {
        self.point(point, target)?;
        if self.algorithm() == Algorithm::Paper {
            return Ok(self.cacla.act(point, target, explore));
        }
        let c = self.cacla.config().correction;
        let p = self.set[point];
        if explore && let (Some(last), Some(best)) = (p.last, p.best) {
            // A step that made things worse is not built on: back to the best try.
            let base = if last.error <= best.error + c.noise_m {
                last
            } else {
                best
            };
            let j = match p.jacobian {
                Some(j) => j,
                None => {
                    let j = self.model().jacobian(&base.action);
                    self.set[point].jacobian = Some(j);
                    j
                }
            };
            self.set[point].retry = base != last;
            let e = match p.bias {
                Some((bias, _)) if base == last => bias,
                _ => error_vector(target, &base.reached),
            };
            let step = correction(&j, &e, c.gain, &c, p.radius);
            return Ok(plus(&base.action, &step));
        }
        if let Some(first) = p.first {
            return Ok(first);
        }
        let first = self.refine(target);
        self.set[point].first = Some(first);
        Ok(first)
    }

    /// The actor's mean, refined by Gauss-Newton against the refitted model, never further
    /// than `trust_max` from the mean (the model is trusted near the demonstrations only).
    fn refine(&mut self, target: &Position) -> Actuation {
        let c = self.cacla.config().correction;
        let mean = self.cacla.actor(target);
        let model = self.model();
        let mut a = mean;
        let mut err = error_vector(target, &model.position(&a));
        for _ in 0..c.refine_steps {
            let mut step = correction(&model.jacobian(&a), &err, 1.0, &c, c.trust_max);
            // Backtracking: a step the model says is worse is halved, up to four times.
            let mut improved = false;
            for _ in 0..4 {
                let mut next = plus(&a, &step);
                let off: f64 = (0..ACTUATORS)
                    .map(|i| (next[i] - mean[i]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                if off > c.trust_max {
                    let s = c.trust_max / off;
                    next = std::array::from_fn(|i| mean[i] + s * (next[i] - mean[i]));
                }
                let next_err = error_vector(target, &model.position(&next));
                if next_err.norm() < err.norm() {
                    a = next;
                    err = next_err;
                    improved = true;
                    break;
                }
                step = step.map(|v| v * 0.5);
            }
            if !improved {
                break;
            }
        }
        a
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cacla::LearnerConfig;
    use crate::pcc::ArmGeometry;
    use crate::poly::PolynomialConfig;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    /// A polynomial of the nominal arm and an actor that imitated it.
    fn learner(algorithm: Algorithm) -> OnlineLearner {
        let arm = ArmGeometry::default();
        let mut rng = StdRng::seed_from_u64(3);
        let a: Vec<Actuation> = (0..1500)
            .map(|_| std::array::from_fn(|_| rng.random_range(0.2..0.8)))
            .collect();
        let p: Vec<Position> = a.iter().map(|a| arm.position(a)).collect();
        let poly = Polynomial::fit(&a, &p, &PolynomialConfig::default()).unwrap();
        let config = LearnerConfig {
            algorithm,
            ..Default::default()
        };
        let mut cacla = CaclaMtl::new(config).unwrap();
        cacla.imitate(&p, &a, 3);
        OnlineLearner::new(cacla, poly)
    }

    fn targets() -> Vec<Position> {
        let arm = ArmGeometry::default();
        [
            [0.3, 0.6, 0.7, 0.5, 0.4, 0.5],
            [0.6, 0.4, 0.5, 0.6, 0.5, 0.3],
            [0.5, 0.5, 0.3, 0.4, 0.6, 0.6],
        ]
        .iter()
        .map(|a| arm.position(a))
        .collect()
    }

    /// Mean error per execution of `executions` quasi-static executions on `arm`.
    fn run(l: &mut OnlineLearner, arm: &ArmGeometry, executions: usize) -> Vec<f64> {
        let t = targets();
        let mut a = l.start_set(&t).unwrap();
        let mut means = Vec::new();
        for _ in 0..executions {
            let mut sum = 0.0;
            for n in 0..t.len() {
                let reached = arm.position(&a[n]);
                sum += l.observe(n, &t[n], &a[n], &reached, None).unwrap().error;
                a[n] = l.estimate(n, &t[n], true).unwrap();
            }
            means.push(sum / t.len() as f64);
        }
        means
    }

    #[test]
    fn first_estimates_are_refined_against_the_model() {
        let mut l = learner(Algorithm::Softarm);
        let arm = ArmGeometry::default();
        let t = targets();
        let first = l.start_set(&t).unwrap();
        for (a, t) in first.iter().zip(&t) {
            // The imitated actor is millimetres off; refined, the polynomial's error.
            assert!(distance(&arm.position(a), t) < 0.002);
        }
        // Asked again without exploration: the same estimate.
        assert_eq!(l.estimate(1, &t[1], false).unwrap(), first[1]);
    }

    #[test]
    fn directed_corrections_adapt_to_a_longer_tool_where_the_paper_does_not() {
        let tool = ArmGeometry {
            tool_m: 0.05,
            ..Default::default()
        };
        let ours = run(&mut learner(Algorithm::Softarm), &tool, 6);
        let paper = run(&mut learner(Algorithm::Paper), &tool, 6);
        assert!(ours[0] > 0.01, "the longer tool is felt: {ours:?}");
        assert!(ours[4] < 0.002, "softarm: {ours:?}");
        assert!(paper[4] > 0.01, "paper: {paper:?}");
        assert!(ours.iter().all(|e| *e <= 1.5 * ours[0]), "{ours:?}");
    }

    #[test]
    fn the_refit_carries_over_to_points_never_visited() {
        let tool = ArmGeometry {
            tool_m: 0.05,
            ..Default::default()
        };
        // Between two of the visited points: where the refit interpolates.
        let other: Position = ArmGeometry::default().position(&[0.45, 0.5, 0.6, 0.55, 0.45, 0.4]);
        let mut fresh = learner(Algorithm::Softarm);
        let before = fresh.start_set(&[other]).unwrap()[0];
        let mut l = learner(Algorithm::Softarm);
        run(&mut l, &tool, 10);
        assert!(l.refit_visits() > 0);
        let after = l.start_set(&[other]).unwrap()[0];
        let (e0, e1) = (
            distance(&tool.position(&before), &other),
            distance(&tool.position(&after), &other),
        );
        // The offset alone: a third of the longer tool's error goes (the rest turns with the tip).
        assert!(e1 < 0.7 * e0, "unadapted {e0} m, adapted {e1} m");
    }

    #[test]
    fn a_failed_step_shrinks_the_trust_region_and_backtracks() {
        let mut l = learner(Algorithm::Softarm);
        let t = targets();
        l.start_set(&t).unwrap();
        let good = [0.5; 6];
        l.observe(0, &t[0], &good, &[t[0][0] + 0.004, t[0][1], t[0][2]], None)
            .unwrap();
        let r0 = l.set[0].radius;
        // Much worse than the best: the radius halves and the next step starts from the best.
        l.observe(
            0,
            &t[0],
            &[0.9; 6],
            &[t[0][0] + 0.05, t[0][1], t[0][2]],
            None,
        )
        .unwrap();
        assert_eq!(l.set[0].radius, r0 * 0.5);
        let next = l.estimate(0, &t[0], true).unwrap();
        let from_good: f64 = next.iter().map(|v| (v - 0.5).powi(2)).sum::<f64>().sqrt();
        assert!(from_good <= r0 * 0.5 + 1e-12, "{next:?}");
        // Worse than the best again from there: the best was luck, so this try becomes the
        // base and a point is never stuck on one lucky sample.
        let stale = [t[0][0] + 0.012, t[0][1], t[0][2]];
        l.observe(0, &t[0], &next, &stale, None).unwrap();
        assert_eq!(l.set[0].best.unwrap().reached, stale);
        let after = l.estimate(0, &t[0], true).unwrap();
        let from_stale: f64 = (0..6)
            .map(|i| (after[i] - next[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(
            from_stale > 0.0 && from_stale <= r0 * 0.25 + 1e-12,
            "{after:?}"
        );
    }

    #[test]
    fn visits_that_do_not_fit_the_set_are_refused_and_change_nothing() {
        let mut l = learner(Algorithm::Softarm);
        let t = targets();
        l.start_set(&t).unwrap();
        let a = [0.5; 6];
        assert_eq!(
            l.observe(3, &t[0], &a, &t[0], None).unwrap_err(),
            OnlineError::PointOutOfRange {
                point: 3,
                points: 3
            }
        );
        assert!(matches!(
            l.observe(0, &t[1], &a, &t[0], None).unwrap_err(),
            OnlineError::TargetMismatch { point: 0, .. }
        ));
        assert_eq!(
            l.observe(0, &t[0], &a, &[f64::NAN; 3], None).unwrap_err(),
            OnlineError::NotFinite
        );
        assert_eq!(l.refit_visits(), 0);
        assert_eq!(l.cacla().memory(0), None);
        assert_eq!(l.start_set(&[]).unwrap_err(), OnlineError::SetSize(0));
        // A learner that joined a running set learns the targets from the samples.
        l.begin(2).unwrap();
        l.observe(1, &t[2], &a, &t[2], None).unwrap();
        assert!(l.observe(1, &t[0], &a, &t[0], None).is_err());
    }
}
