//! The configured arm (`[arm]`) with a few of its physical parameters fitted to what the tracker
//! saw of the real one: a calibrated arm. What one set taught is carried to targets never
//! visited as the difference between what the calibrated and the configured arm need there.
//!
//! Why physical parameters, not a residual over task space: a longer or bent tool moves the
//! tracked point along the tip's own axes, so what the arm gets wrong depends on the tip's
//! orientation, not on where the target is; a residual over task space learnt at one set's
//! points is wrong at another's. Measured in the rehearsal on `tool-change`, the unvisited
//! second set's first execution after the demo set: 9.8–11.5 mm with a task-space residual of
//! the configured arm, 7.7–8.1 mm with the visited points' corrections carried over task
//! space, 3.3–4.0 mm with this (its static miss 0.3–0.9 mm; the rest is the actuators' lag
//! into the point). Fitted to the footprint, not to the visits: its samples are many,
//! averaged, and taken where the arm stood still or moved slowly.
//! Pure: no I/O.

use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, SVector, Vector3};

use softarm_kinematics::forward::{ForwardModel, Jacobian};
use softarm_kinematics::pcc;
use softarm_space::{MAX_ACTUATORS, Position};

/// Most modules a calibrated arm has.
const MAX_MODULES: usize = 8;

/// Most parameters of any arm: the tool's offset in the tip frame (x, y, z; m), each
/// actuator's length offset (m), each module's bend per length difference (a fraction: what
/// its actuators' radius sets), each module's rotation (degrees), the connector's length (m).
pub const MAX_PARAMETERS: usize = 3 + MAX_ACTUATORS + 2 * MAX_MODULES + 1;

/// How far each kind of parameter plausibly is from the configured arm: the prior's standard
/// deviation (same units as the parameter). A tool swapped or bent by centimetres, tendons
/// crept by millimetres, a module remounted by some degrees.
const PRIOR_TOOL_XY_M: f64 = 0.02;
const PRIOR_TOOL_Z_M: f64 = 0.03;
const PRIOR_OFFSET_M: f64 = 0.005;
const PRIOR_BEND: f64 = 0.2;
const PRIOR_ROTATION_DEG: f64 = 10.0;
const PRIOR_CONNECTOR_M: f64 = 0.01;

/// How well a sample tells where the arm is (m): tracker noise, the actuation's disturbance
/// between motor and tracker stamps, and what no PCC arm fits.
const SAMPLE_SIGMA_M: f64 = 0.001;

/// A sample missed by more than this many times the median miss of a first fit is left out
/// of the second ([`CalibratedArm::fit`]).
const OUTLIER_FACTOR: f64 = 4.0;
/// ...and by more than this (m): tracker noise and the lag of a moving arm are not outliers.
const OUTLIER_FLOOR_M: f64 = 0.003;

/// Levenberg-Marquardt iterations at most.
const ITERATIONS: usize = 15;

/// How far a fitted parameter may depart from where its fit started, in its prior's standard
/// deviations: beyond it the parameter soaks up what the arm's model cannot represent (a
/// MuJoCo arm's dynamics, tendons turned from where `[arm]` has them), which is no tool nor
/// tendon of a real arm (measured: 65–174 mm tool offsets on a three-segment arm whose tool
/// is where `[arm]` has it). Rotations are not bounded: they are angles, searched whole.
const BOUND_PRIORS: f64 = 2.5;

/// The configured arm missing the samples by more than this (RMS, m) has its modules'
/// rotations searched whole first ([`ROTATION_STEP_DEG`]): a lab's drawing with its tendons
/// turned, or a tracker frame turned about the base's axis, is no small departure that
/// Levenberg-Marquardt finds from the drawing's (measured on the paper's arm turned 180°: it
/// bent both modules the other way instead, 17 mm of tool, −15 mm of connector).
const ROTATION_SEARCH_RMS_M: f64 = 0.005;
/// ...with at least this many samples.
const ROTATION_SEARCH_SAMPLES: usize = 30;
/// The step of that search (degrees).
const ROTATION_STEP_DEG: f64 = 30.0;

/// A fit that explains less than this of the configured arm's miss (its RMS over the
/// configured arm's) is not taken: the arm's model cannot represent the arm, and a fitted arm
/// that pretends it does sends the learner further off than the trained model alone.
const EXPLAINED: f64 = 0.5;
/// ...unless it misses by less than this anyway (m): the tracker's noise and a moving arm's
/// lag, which no parameter explains.
const EXPLAINED_FLOOR_M: f64 = 0.0015;

/// Where each parameter sits in θ for an arm of `n` actuators and `m` modules.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Slots {
    n: usize,
    m: usize,
}

impl Slots {
    fn of(arm: &pcc::Arm) -> Self {
        Self {
            n: arm.actuators(),
            m: arm.modules(),
        }
    }
    fn count(&self) -> usize {
        3 + self.n + 2 * self.m + 1
    }
    fn offset(&self, i: usize) -> usize {
        3 + i
    }
    fn bend(&self, module: usize) -> usize {
        3 + self.n + module
    }
    fn rotation(&self, module: usize) -> usize {
        3 + self.n + self.m + module
    }
    fn connector(&self) -> usize {
        3 + self.n + 2 * self.m
    }
    fn is_rotation(&self, k: usize) -> bool {
        (self.rotation(0)..self.connector()).contains(&k)
    }
    /// The prior's standard deviation of parameter `k`.
    fn prior(&self, k: usize) -> f64 {
        match k {
            0 | 1 => PRIOR_TOOL_XY_M,
            2 => PRIOR_TOOL_Z_M,
            k if k < self.bend(0) => PRIOR_OFFSET_M,
            k if k < self.rotation(0) => PRIOR_BEND,
            k if k < self.connector() => PRIOR_ROTATION_DEG,
            _ => PRIOR_CONNECTOR_M,
        }
    }
}

/// The configured arm with fitted parameters, for an arm of `N` actuators.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibratedArm<const N: usize> {
    configured: pcc::Arm,
    /// Departures from the configured arm, in the order of [`MAX_PARAMETERS`]'s doc; as many
    /// as the arm has ([`CalibratedArm::parameters`]), the rest 0.
    pub theta: [f64; MAX_PARAMETERS],
    /// Root mean square of the fitted arm's miss over the samples (m).
    pub rms_m: f64,
    /// Samples it was fitted to; 0 when it is the configured arm (nothing fitted, or a fit
    /// not taken: see [`EXPLAINED`]).
    pub samples: usize,
    /// Samples the last fit was tried on, whether taken or not.
    pub tried: usize,
}

impl<const N: usize> ForwardModel<N> for CalibratedArm<N> {
    fn position(&self, a: &[f64; N]) -> Position {
        position(&self.configured, &self.theta, a)
    }
}

/// Where the arm `configured` with departures `theta` puts the tracked point at `a`.
fn position(configured: &pcc::Arm, theta: &[f64; MAX_PARAMETERS], a: &[f64]) -> Position {
    let slots = Slots::of(configured);
    let mut offsets = [0.0; MAX_ACTUATORS];
    offsets[..slots.n].copy_from_slice(&theta[slots.offset(0)..slots.offset(slots.n)]);
    let mut turns = [0.0; MAX_MODULES];
    for (m, t) in turns.iter_mut().enumerate().take(slots.m) {
        *t = theta[slots.rotation(m)].to_radians();
    }
    let arm = configured.changed(theta[2], theta[slots.connector()], &offsets, &turns);
    // A module's bend is its actuators' length differences over their radius: scaling the
    // differences about their mean is a module whose actuators sit nearer or further out.
    let mut lengths = arm.lengths(a);
    let (mut sum, mut count) = ([0.0; MAX_MODULES], [0usize; MAX_MODULES]);
    for (i, l) in lengths[..slots.n].iter().enumerate() {
        sum[arm.owner(i)] += l;
        count[arm.owner(i)] += 1;
    }
    for (i, l) in lengths[..slots.n].iter_mut().enumerate() {
        let m = arm.owner(i);
        let mean = sum[m] / count[m] as f64;
        *l = mean + (*l - mean) * (1.0 + theta[slots.bend(m)]);
    }
    match arm.pose_of_lengths(&lengths[..slots.n], 0.0) {
        Ok(pose) => {
            let p = pose.position + pose.rotation * Vector3::new(theta[0], theta[1], 0.0);
            [p.x, p.y, p.z]
        }
        Err(_) => [f64::NAN; 3],
    }
}

impl<const N: usize> CalibratedArm<N> {
    /// The configured arm itself: nothing fitted.
    pub fn configured(arm: pcc::Arm) -> Self {
        debug_assert_eq!(arm.actuators(), N);
        Self {
            configured: arm,
            theta: [0.0; MAX_PARAMETERS],
            rms_m: 0.0,
            samples: 0,
            tried: 0,
        }
    }

    /// Each module's fitted rotation (degrees, in (−180, 180]).
    pub fn rotations_deg(&self) -> Vec<f64> {
        let slots = Slots::of(&self.configured);
        (0..slots.m)
            .map(|m| self.theta[slots.rotation(m)])
            .collect()
    }

    /// How many parameters its arm has: 3 + N + 2 × modules + 1.
    pub fn parameters(&self) -> usize {
        Slots::of(&self.configured).count()
    }

    /// This arm departed by `delta` (one per parameter, in [`CalibratedArm::sensitivity`]'s
    /// order and units).
    pub fn departed(&self, delta: &DVector<f64>) -> Self {
        let mut arm = *self;
        for (t, d) in arm.theta.iter_mut().zip(delta.iter()) {
            *t += d;
        }
        arm
    }

    /// Each parameter's variance of a change while the arm runs: a tool swapped or loaded as
    /// the calibration's prior has it, tendons creeping by a third of it, modules turning,
    /// bending and their connector stretching by a tenth (they change when a lab rebuilds the
    /// arm, not while it runs). Measured within an execution after a 40 mm longer tool on the
    /// TDCR: the next points 23 and 7 mm off with the calibration's prior, 2.8 and 1.5 with
    /// this; on the paper's arm after 20 mm, 1.9–2.1 against 0.3–0.6 mm.
    pub fn change_variances(&self) -> DVector<f64> {
        let slots = Slots::of(&self.configured);
        let scale = |k: usize| match k {
            0..=2 => 1.0,
            k if k < slots.bend(0) => 1.0 / 3.0,
            _ => 0.1,
        };
        DVector::from_fn(slots.count(), |k, _| (scale(k) * slots.prior(k)).powi(2))
    }

    /// How the tracked point moves at `a` per unit of each parameter (3 × parameters): what a
    /// departure of the arm's parameters does there.
    pub fn sensitivity(&self, a: &[f64; N]) -> DMatrix<f64> {
        let slots = Slots::of(&self.configured);
        let mut g = DMatrix::zeros(3, slots.count());
        for q in 0..slots.count() {
            let col = sensitivity(&self.configured, &self.theta, a, q);
            g.set_column(q, &col);
        }
        g
    }

    /// The parameters that explain `samples` (measured actuation, tracked position) best
    /// within the prior: damped Gauss-Newton (Levenberg-Marquardt) on
    /// Σ ‖p − f(a; θ)‖² / σ² + Σ (θ_k / prior_k)². With few samples or ones that do not tell
    /// a parameter, the prior keeps it at the configured arm's.
    ///
    /// Then once more without the samples the first fit misses by more than
    /// [`OUTLIER_FACTOR`] times its median miss (and [`OUTLIER_FLOOR_M`]): a sample that paired
    /// a tracker position with an actuation of another moment (a loaded machine) is not the
    /// arm, and one such pulled the fit 10 mm off.
    ///
    /// Every parameter but the rotations stays within [`BOUND_PRIORS`] of where it started;
    /// a fit that explains too little ([`EXPLAINED`]) is not taken: the configured arm, with
    /// `samples` 0, as if nothing had been fitted.
    pub fn fit(configured: pcc::Arm, samples: &[([f64; N], Position)]) -> Self {
        let fitted = Self::fit_without_outliers(configured, samples);
        let as_configured = rms(&configured, &[0.0; MAX_PARAMETERS], samples);
        if fitted.rms_m > EXPLAINED_FLOOR_M && fitted.rms_m > EXPLAINED * as_configured {
            return Self {
                tried: samples.len(),
                rms_m: as_configured,
                ..Self::configured(configured)
            };
        }
        fitted
    }

    fn fit_without_outliers(configured: pcc::Arm, samples: &[([f64; N], Position)]) -> Self {
        let first = Self::fit_all(configured, samples);
        let mut misses: Vec<f64> = (samples.iter())
            .map(|(a, p)| dist2(&first.position(a), p).sqrt())
            .collect();
        let limit = {
            misses.sort_by(f64::total_cmp);
            let median = misses.get(misses.len() / 2).copied().unwrap_or(0.0);
            (OUTLIER_FACTOR * median).max(OUTLIER_FLOOR_M)
        };
        let kept: Vec<([f64; N], Position)> = (samples.iter())
            .filter(|(a, p)| dist2(&first.position(a), p).sqrt() <= limit)
            .copied()
            .collect();
        if kept.len() == samples.len() || kept.len() < samples.len() / 2 {
            return first;
        }
        Self::fit_all(configured, &kept)
    }

    /// Fitted from the configured arm, and, if it misses by much, from its modules turned as
    /// a whole search says ([`turned`]): whichever misses less. Both, since a longer tool too
    /// makes the configured arm miss by much, and turning modules makes up for some of it.
    fn fit_all(configured: pcc::Arm, samples: &[([f64; N], Position)]) -> Self {
        let plain = Self::fit_from(configured, samples, [0.0; MAX_PARAMETERS]);
        // Not from a few samples: ten at a handful of postures are met by many a turn of
        // each module, with the tool soaking up the rest (measured in the running stack: a
        // 180° turn fitted as 172° and −148° with a 36 mm tool, every point after 10–24 mm off).
        if samples.len() < ROTATION_SEARCH_SAMPLES {
            return plain;
        }
        let centre = turned(&configured, samples);
        if centre == [0.0; MAX_PARAMETERS] {
            return plain;
        }
        let turned = Self::fit_from(configured, samples, centre);
        if turned.rms_m < plain.rms_m {
            turned
        } else {
            plain
        }
    }

    /// Levenberg-Marquardt from `centre`, where the prior is centred too.
    fn fit_from(
        configured: pcc::Arm,
        samples: &[([f64; N], Position)],
        centre: [f64; MAX_PARAMETERS],
    ) -> Self {
        let slots = Slots::of(&configured);
        let k = slots.count();
        let mut theta = centre;
        let mut cost = cost_of(&configured, &centre, &theta, samples);
        let mut lambda = 1e-3;
        for _ in 0..ITERATIONS {
            let (jtj, jtr) = normal_equations(&configured, &centre, &theta, samples);
            let mut improved = false;
            while lambda < 1e6 {
                let damped = &jtj + DMatrix::from_diagonal(&jtj.diagonal().map(|v| v * lambda));
                let Some(step) = damped.cholesky().map(|c| c.solve(&jtr)) else {
                    lambda *= 10.0;
                    continue;
                };
                // The solve is in units of the prior; back to the parameters' own.
                let mut next = theta;
                for p in 0..k {
                    next[p] += step[p] * slots.prior(p);
                    if !slots.is_rotation(p) {
                        let bound = BOUND_PRIORS * slots.prior(p);
                        next[p] = next[p].clamp(centre[p] - bound, centre[p] + bound);
                    }
                }
                let next_cost = cost_of(&configured, &centre, &next, samples);
                if next_cost < cost {
                    improved = (cost - next_cost) > 1e-9 * cost;
                    theta = next;
                    cost = next_cost;
                    lambda = (lambda * 0.3).max(1e-7);
                    break;
                }
                lambda *= 10.0;
            }
            if !improved {
                break;
            }
        }
        for m in 0..slots.m {
            let r = &mut theta[slots.rotation(m)];
            *r -= 360.0 * ((*r + 180.0) / 360.0).ceil() - 360.0;
        }
        Self {
            configured,
            theta,
            rms_m: rms(&configured, &theta, samples),
            samples: samples.len(),
            tried: samples.len(),
        }
    }

    /// The actuation that puts this arm's tracked point at `target`, from `start`: damped
    /// Gauss-Newton with its steps' null-space part pulled back to `start`, so that two arms
    /// inverted from the same start differ by what differs between them, not by where the
    /// free directions wandered.
    pub fn invert(model: &impl ForwardModel<N>, target: &Position, start: &[f64; N]) -> [f64; N] {
        let mut a = *start;
        for _ in 0..ITERATIONS {
            let p = model.position(&a);
            let e = Vector3::from_fn(|d, _| target[d] - p[d]);
            if e.norm() < 1e-6 {
                break;
            }
            let j: Jacobian<N> = model.jacobian(&a);
            let Some(pinv) = damped_pseudo_inverse(&j, 1e-3) else {
                break;
            };
            let back = SVector::<f64, N>::from_fn(|i, _| start[i] - a[i]);
            let step = pinv * e + (back - pinv * (j * back));
            a = std::array::from_fn(|i| (a[i] + step[i]).clamp(0.0, 1.0));
        }
        a
    }
}

/// Random actuations [`nearest_place`] starts its search from, beside the one it is given.
const NEAREST_SAMPLES: usize = 512;
/// Of those, how many it descends from (the nearest few).
const NEAREST_STARTS: usize = 4;
/// Descent steps from each start.
const NEAREST_ITERATIONS: usize = 60;

/// The actuation inside [0, 1] that brings `model`'s tracked point nearest to `target`: a
/// target beyond the arm's reach has no inverse, and Gauss-Newton clipped to the range stops
/// wherever the clipping turns it (measured: 34 mm off a target the arm comes within 22 mm of).
/// Bounded descent (damped Gauss-Newton on the actuators not held at a limit by the error,
/// each step halved until it brings the point nearer) from `start` and from the nearest of
/// [`NEAREST_SAMPLES`] spread actuations (a fixed sequence: the same answer every time).
pub fn nearest_place<const N: usize>(
    model: &impl ForwardModel<N>,
    target: &Position,
    start: &[f64; N],
) -> [f64; N] {
    let off = |a: &[f64; N]| {
        let p = model.position(a);
        Vector3::from_fn(|d, _| target[d] - p[d]).norm()
    };
    // Kronecker's sequence (k √p_i mod 1, p_i the i-th prime): spread over the cube, no RNG.
    const PRIMES: [f64; 16] = [
        2., 3., 5., 7., 11., 13., 17., 19., 23., 29., 31., 37., 41., 43., 47., 53.,
    ];
    let spread = (1..=NEAREST_SAMPLES)
        .map(|k| std::array::from_fn(|i| (k as f64 * PRIMES[i % 16].sqrt()).fract()));
    let mut starts: Vec<([f64; N], f64)> = spread.map(|a: [f64; N]| (a, off(&a))).collect();
    starts.sort_by(|a, b| a.1.total_cmp(&b.1));
    starts.truncate(NEAREST_STARTS);
    starts.push((*start, off(start)));
    starts
        .into_iter()
        .map(|(a, _)| nearest_place_from(model, target, a))
        .min_by(|a, b| off(a).total_cmp(&off(b)))
        .unwrap_or(*start)
}

/// [`nearest_place`]'s descent from `a` alone: the nearest place around it.
pub fn nearest_place_from<const N: usize>(
    model: &impl ForwardModel<N>,
    target: &Position,
    mut a: [f64; N],
) -> [f64; N] {
    let error = |a: &[f64; N]| {
        let p = model.position(a);
        Vector3::from_fn(|d, _| target[d] - p[d])
    };
    let mut e = error(&a);
    for _ in 0..NEAREST_ITERATIONS {
        let mut j: Jacobian<N> = model.jacobian(&a);
        let push = j.transpose() * e;
        for i in 0..N {
            if (a[i] <= 0.0 && push[i] < 0.0) || (a[i] >= 1.0 && push[i] > 0.0) {
                j.set_column(i, &Vector3::zeros());
            }
        }
        let Some(pinv) = damped_pseudo_inverse(&j, 1e-3) else {
            break;
        };
        let mut step = pinv * e;
        let mut moved = false;
        for _ in 0..12 {
            let b: [f64; N] = std::array::from_fn(|i| (a[i] + step[i]).clamp(0.0, 1.0));
            let f = error(&b);
            if f.norm() < e.norm() - 1e-7 {
                (a, e, moved) = (b, f, true);
                break;
            }
            step *= 0.5;
        }
        if !moved {
            break;
        }
    }
    a
}

/// Jᵀ (J Jᵀ + λ² I)⁻¹: the damped minimum-norm inverse of a Jacobian; none if singular. Here
/// rather than in `online`, which uses it too, so that `online` depends on this module and not
/// the other way round.
pub(crate) fn damped_pseudo_inverse<const N: usize>(
    j: &Jacobian<N>,
    damping: f64,
) -> Option<SMatrix<f64, N, 3>> {
    let jjt = j * j.transpose() + Matrix3::identity() * damping * damping;
    Some(j.transpose() * jjt.try_inverse()?)
}

/// The departures a fit starts from: none, or, where the configured arm misses `samples` by
/// more than [`ROTATION_SEARCH_RMS_M`], each module's rotation searched whole in steps of
/// [`ROTATION_STEP_DEG`], one module at a time, twice round.
fn turned<const N: usize>(
    configured: &pcc::Arm,
    samples: &[([f64; N], Position)],
) -> [f64; MAX_PARAMETERS] {
    let mut theta = [0.0; MAX_PARAMETERS];
    let mut best = rms(configured, &theta, samples);
    if best <= ROTATION_SEARCH_RMS_M {
        return theta;
    }
    let slots = Slots::of(configured);
    let steps = (360.0 / ROTATION_STEP_DEG).round() as usize;
    for _ in 0..2 {
        for m in 0..slots.m {
            let k = slots.rotation(m);
            let mut tried = theta;
            for s in 0..steps {
                tried[k] = s as f64 * ROTATION_STEP_DEG - 180.0 + ROTATION_STEP_DEG;
                let miss = rms(configured, &tried, samples);
                if miss < best {
                    best = miss;
                    theta[k] = tried[k];
                }
            }
        }
    }
    theta
}

/// The root mean square of the miss of the arm `configured` with `theta` over `samples` (m).
fn rms<const N: usize>(
    configured: &pcc::Arm,
    theta: &[f64; MAX_PARAMETERS],
    samples: &[([f64; N], Position)],
) -> f64 {
    let miss: f64 = samples
        .iter()
        .map(|(a, p)| dist2(&position(configured, theta, a), p))
        .sum();
    let miss = (miss / samples.len().max(1) as f64).sqrt();
    // An arm that cannot be posed at some sample misses it without end.
    if miss.is_nan() { f64::INFINITY } else { miss }
}

fn dist2(a: &Position, b: &Position) -> f64 {
    (0..3).map(|d| (a[d] - b[d]).powi(2)).sum()
}

/// The objective, in units of σ and the prior.
fn cost_of<const N: usize>(
    configured: &pcc::Arm,
    centre: &[f64; MAX_PARAMETERS],
    theta: &[f64; MAX_PARAMETERS],
    s: &[([f64; N], Position)],
) -> f64 {
    let slots = Slots::of(configured);
    let data: f64 = s
        .iter()
        .map(|(a, p)| dist2(&position(configured, theta, a), p))
        .sum::<f64>()
        / (SAMPLE_SIGMA_M * SAMPLE_SIGMA_M);
    let prior: f64 = (0..slots.count())
        .map(|k| ((theta[k] - centre[k]) / slots.prior(k)).powi(2))
        .sum();
    let all = data + prior;
    if all.is_nan() { f64::INFINITY } else { all }
}

/// JᵀJ and Jᵀr of the whitened residuals (data and prior) in units of the prior, by central
/// differences over the parameters.
fn normal_equations<const N: usize>(
    configured: &pcc::Arm,
    centre: &[f64; MAX_PARAMETERS],
    theta: &[f64; MAX_PARAMETERS],
    samples: &[([f64; N], Position)],
) -> (DMatrix<f64>, DVector<f64>) {
    let slots = Slots::of(configured);
    let k = slots.count();
    let mut jtj = DMatrix::<f64>::identity(k, k);
    let mut jtr = DVector::<f64>::from_fn(k, |p, _| -(theta[p] - centre[p]) / slots.prior(p));
    for (a, p) in samples {
        let f = position(configured, theta, a);
        let r = Vector3::from_fn(|d, _| (p[d] - f[d]) / SAMPLE_SIGMA_M);
        let cols: Vec<Vector3<f64>> = (0..k)
            .map(|q| sensitivity(configured, theta, a, q) * (slots.prior(q) / SAMPLE_SIGMA_M))
            .collect();
        for q in 0..k {
            jtr[q] += cols[q].dot(&r);
            for l in 0..k {
                jtj[(q, l)] += cols[q].dot(&cols[l]);
            }
        }
    }
    (jtj, jtr)
}

/// ∂p/∂θ_q at `a` (per unit of θ_q), by central differences of a ten-thousandth of its prior.
fn sensitivity(
    configured: &pcc::Arm,
    theta: &[f64; MAX_PARAMETERS],
    a: &[f64],
    q: usize,
) -> Vector3<f64> {
    const H: f64 = 1e-4;
    let h = H * Slots::of(configured).prior(q);
    let (mut up, mut down) = (*theta, *theta);
    up[q] += h;
    down[q] -= h;
    let (u, d) = (position(configured, &up, a), position(configured, &down, a));
    Vector3::from_fn(|i, _| (u[i] - d[i]) / (2.0 * h))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::default_arm::{N, arm};
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    fn actuations(n: usize, seed: u64) -> Vec<[f64; N]> {
        let mut rng = StdRng::seed_from_u64(seed);
        (0..n)
            .map(|_| std::array::from_fn(|_| rng.random_range(0.3..0.7)))
            .collect()
    }

    fn miss(model: &impl ForwardModel<N>, real: &pcc::Arm, a: &[[f64; N]]) -> f64 {
        a.iter()
            .map(|a| dist2(&model.position(a), &real.position(a)).sqrt())
            .fold(0.0, f64::max)
    }

    #[test]
    fn a_calibrated_arm_finds_a_longer_tool_and_crept_tendons() {
        let configured = arm();
        let real = configured.changed(0.02, 0.0, &[0.0, 0.003, 0.0, 0.0, 0.0, 0.004], &[0.0; 2]);
        let samples: Vec<([f64; N], Position)> = actuations(40, 1)
            .into_iter()
            .map(|a| (a, real.position(&a)))
            .collect();
        let fitted = CalibratedArm::fit(configured, &samples);
        let elsewhere = actuations(50, 2);
        assert!(miss(&configured, &real, &elsewhere) > 0.015);
        let m = miss(&fitted, &real, &elsewhere);
        assert!(m < 0.0005, "the fitted arm misses by up to {m} m");
        assert!(fitted.rms_m < 0.0005, "{fitted:?}");
        // What it needs at a target is what the real arm needs.
        let target = real.position(&[0.4, 0.6, 0.5, 0.55, 0.45, 0.5]);
        let a = CalibratedArm::invert(&fitted, &target, &[0.5; N]);
        assert!(dist2(&real.position(&a), &target).sqrt() < 0.0005);
    }

    #[test]
    fn without_samples_the_calibrated_arm_is_the_configured_one() {
        let configured = arm();
        let fitted = CalibratedArm::<N>::fit(configured, &[]);
        // 3 + N + 2 × modules + 1: the default [arm]'s 14.
        assert_eq!(fitted.parameters(), 3 + N + 2 * 2 + 1);
        assert_eq!(fitted.theta, [0.0; MAX_PARAMETERS]);
        assert_eq!(fitted, CalibratedArm::configured(configured));
        let a = [0.4, 0.6, 0.5, 0.55, 0.45, 0.5];
        assert_eq!(fitted.position(&a), configured.position(&a));
    }

    /// Any arm: the nine-tendon TDCR with a longer tool and two crept tendons, found from
    /// samples of its tip (its 3 + 9 + 6 + 1 parameters).
    #[test]
    fn a_calibrated_nine_tendon_arm_finds_its_tool_and_tendons() {
        let text = include_str!("../../../config/arms/tdcr.toml");
        let layout = softarm_arm::Layout::new(&toml::from_str(text).unwrap()).unwrap();
        let configured = pcc::Arm::new(&layout, &[]);
        let mut offsets = [0.0; 9];
        offsets[1] = 0.0006;
        offsets[7] = -0.0004;
        let real = configured.changed(0.008, 0.0, &offsets, &[0.0; 3]);
        let mut rng = StdRng::seed_from_u64(4);
        let mut draw = |n: usize| -> Vec<[f64; 9]> {
            (0..n)
                .map(|_| std::array::from_fn(|_| rng.random_range(0.4..0.6)))
                .collect()
        };
        let samples: Vec<([f64; 9], Position)> = draw(60)
            .into_iter()
            .map(|a| (a, real.position(&a)))
            .collect();
        let fitted = CalibratedArm::<9>::fit(configured, &samples);
        assert_eq!(fitted.parameters(), 19);
        let elsewhere = draw(50);
        let worst = |m: &dyn Fn(&[f64; 9]) -> Position| {
            elsewhere
                .iter()
                .map(|a| dist2(&m(a), &real.position(a)).sqrt())
                .fold(0.0, f64::max)
        };
        assert!(worst(&|a| configured.position(a)) > 0.005);
        let m = worst(&|a| fitted.position(a));
        assert!(m < 0.0005, "the fitted arm misses by up to {m} m");
        // Five samples that paired a position with the actuation of another moment: left out.
        let mut wild = samples.clone();
        for (k, (_, p)) in wild.iter_mut().take(5).enumerate() {
            p[k % 3] += 0.08;
        }
        let fitted = CalibratedArm::<9>::fit(configured, &wild);
        let m = worst(&|a| fitted.position(a));
        assert!(
            m < 0.0005,
            "with five wild samples, the fitted arm misses by up to {m} m"
        );
    }
}

#[cfg(test)]
mod turned {
    use super::*;
    use crate::default_arm::{N, arm};
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};
    use softarm_sections::arm::ArmConfig;

    fn draw(n: usize, rng: &mut StdRng) -> Vec<[f64; N]> {
        (0..n)
            .map(|_| std::array::from_fn(|_| rng.random_range(0.35..0.65)))
            .collect()
    }

    /// `[arm]` with the tendons turned from where they are: the fit finds the turn, and no
    /// tool, tendon or bend soaks it up (before, turned 180°: both modules bent the other way
    /// (bend −2), a 17 mm tool and a −15 mm connector; turned 120°: a module turned 600°).
    #[test]
    fn a_calibrated_arm_of_an_arm_configured_turned_finds_the_turn_and_nothing_else() {
        let real = arm();
        let mut rng = StdRng::seed_from_u64(5);
        let samples: Vec<([f64; N], Position)> = draw(60, &mut rng)
            .into_iter()
            .map(|a| (a, real.position(&a)))
            .collect();
        let elsewhere = draw(50, &mut rng);
        for turn in [60.0, 120.0, 180.0] {
            let configured = pcc::Arm::of_config(&ArmConfig {
                module_rotation_deg: Some([turn, 60.0 + turn]),
                ..Default::default()
            })
            .unwrap();
            let fitted = CalibratedArm::<N>::fit(configured, &samples);
            let theta = fitted.theta;
            for (m, r) in fitted.rotations_deg().iter().enumerate() {
                let off = (r + turn).rem_euclid(360.0);
                assert!(
                    off.min(360.0 - off) < 1.0,
                    "turned {turn}°, module {m}: {r}°"
                );
            }
            let tool = (theta[0].powi(2) + theta[1].powi(2) + theta[2].powi(2)).sqrt();
            assert!(
                tool < 0.001,
                "turned {turn}°: a tool of {tool} m: {theta:?}"
            );
            assert!(theta[3..11].iter().all(|v| v.abs() < 0.01), "{theta:?}");
            assert!(theta[13].abs() < 0.001, "{theta:?}");
            let worst = elsewhere
                .iter()
                .map(|a| dist2(&fitted.position(a), &real.position(a)).sqrt())
                .fold(0.0, f64::max);
            assert!(worst < 0.0005, "turned {turn}°: misses by up to {worst} m");
        }
    }

    /// An arm the configured arm's model cannot represent (three modules where `[arm]` has
    /// two): what is fitted stays within its bounds, and a fit that explains little is not
    /// taken.
    #[test]
    fn an_arm_no_fit_represents_gives_no_implausible_parameters() {
        let text = include_str!("../../../config/arms/tdcr.toml");
        let layout = softarm_arm::Layout::new(&toml::from_str(text).unwrap()).unwrap();
        let tdcr = pcc::Arm::new(&layout, &[]);
        let configured = arm();
        let mut rng = StdRng::seed_from_u64(6);
        // The default [arm]'s six actuations drive the TDCR's nine tendons (three of them slack).
        let samples: Vec<([f64; N], Position)> = draw(80, &mut rng)
            .into_iter()
            .map(|a| {
                let nine: [f64; 9] = std::array::from_fn(|i| a.get(i).copied().unwrap_or(0.5));
                (a, tdcr.position(&nine))
            })
            .collect();
        let fitted = CalibratedArm::<N>::fit(configured, &samples);
        let slots = Slots::of(&configured);
        for k in (0..slots.count()).filter(|k| !slots.is_rotation(*k)) {
            assert!(
                fitted.theta[k].abs() <= BOUND_PRIORS * slots.prior(k) + 1e-12,
                "parameter {k}: {:?}",
                fitted.theta
            );
        }
        let configured_rms = rms(&configured, &[0.0; MAX_PARAMETERS], &samples);
        assert!(
            fitted.samples == 0 || fitted.rms_m <= EXPLAINED * configured_rms,
            "{fitted:?} against {configured_rms} m"
        );
    }
}
