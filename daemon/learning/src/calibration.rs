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

use nalgebra::{DMatrix, DVector, Matrix3, SVector, Vector3};

use softarm_kinematics::forward::{ForwardModel, Jacobian};
use softarm_kinematics::pcc::Kinematics;
use softarm_sections::arm::ArmGeometry;
use softarm_space::{ACTUATORS, Actuation, Position};

/// Parameters fitted: the tool's offset in the tip frame (x, y, z; m), each actuator's length
/// offset (m), each module's bend per length difference (a fraction: what its actuators'
/// radius sets), each module's rotation (degrees), the connector's length (m).
pub const PARAMETERS: usize = 3 + ACTUATORS + 2 + 2 + 1;

/// How far each parameter plausibly is from the configured arm: the prior's standard deviation
/// (same units as the parameter). A tool swapped or bent by centimetres, tendons crept by
/// millimetres, a module remounted by some degrees.
const PRIOR: [f64; PARAMETERS] = [
    0.02, 0.02, 0.03, 0.005, 0.005, 0.005, 0.005, 0.005, 0.005, 0.2, 0.2, 10.0, 10.0, 0.01,
];

/// How well a sample tells where the arm is (m): tracker noise, the actuation's disturbance
/// between motor and tracker stamps, and what no PCC arm fits.
const SAMPLE_SIGMA_M: f64 = 0.001;

/// Levenberg-Marquardt iterations at most.
const ITERATIONS: usize = 15;

/// The configured arm with fitted parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibratedArm {
    configured: ArmGeometry,
    /// Departures from the configured arm, in the order of [`PARAMETERS`].
    pub theta: [f64; PARAMETERS],
    /// Root mean square of the fitted arm's miss over the samples (m).
    pub rms_m: f64,
    /// Samples it was fitted to.
    pub samples: usize,
}

impl ForwardModel for CalibratedArm {
    fn position(&self, a: &Actuation) -> Position {
        position(&self.configured, &self.theta, a)
    }
}

/// Where the arm of `configured` with departures `theta` puts the tracked point at `a`.
fn position(configured: &ArmGeometry, theta: &[f64; PARAMETERS], a: &Actuation) -> Position {
    let mut arm = *configured;
    arm.tool_m += theta[2];
    arm.connector_m += theta[7 + ACTUATORS];
    for (o, t) in arm
        .actuator_offset_m
        .iter_mut()
        .zip(&theta[3..3 + ACTUATORS])
    {
        *o += t;
    }
    arm.module_rotation_deg[0] += theta[5 + ACTUATORS];
    arm.module_rotation_deg[1] += theta[6 + ACTUATORS];
    // A module's bend is its actuators' length differences over their radius: scaling the
    // differences about their mean is a module whose actuators sit nearer or further out.
    let mut lengths = arm.lengths(a);
    for (m, module) in lengths.chunks_mut(3).enumerate() {
        let mean = module.iter().sum::<f64>() / 3.0;
        let scale = 1.0 + theta[3 + ACTUATORS + m];
        for l in module {
            *l = mean + (*l - mean) * scale;
        }
    }
    let pose = arm.pose_of_lengths(&lengths);
    let p = pose.position + pose.rotation * Vector3::new(theta[0], theta[1], 0.0);
    [p.x, p.y, p.z]
}

impl CalibratedArm {
    /// The configured arm itself: nothing fitted.
    pub fn configured(arm: ArmGeometry) -> Self {
        Self {
            configured: arm,
            theta: [0.0; PARAMETERS],
            rms_m: 0.0,
            samples: 0,
        }
    }

    /// The parameters that explain `samples` (measured actuation, tracked position) best
    /// within the prior: damped Gauss-Newton (Levenberg-Marquardt) on
    /// Σ ‖p − f(a; θ)‖² / σ² + Σ (θ_k / prior_k)². With few samples or ones that do not tell
    /// a parameter, the prior keeps it at the configured arm's.
    pub fn fit(configured: ArmGeometry, samples: &[(Actuation, Position)]) -> Self {
        let mut theta = [0.0; PARAMETERS];
        let mut cost = cost_of(&configured, &theta, samples);
        let mut lambda = 1e-3;
        for _ in 0..ITERATIONS {
            let (jtj, jtr) = normal_equations(&configured, &theta, samples);
            let mut improved = false;
            while lambda < 1e6 {
                let damped = &jtj + DMatrix::from_diagonal(&jtj.diagonal().map(|v| v * lambda));
                let Some(step) = damped.cholesky().map(|c| c.solve(&jtr)) else {
                    lambda *= 10.0;
                    continue;
                };
                // The solve is in units of the prior; back to the parameters' own.
                let next: [f64; PARAMETERS] =
                    std::array::from_fn(|k| theta[k] + step[k] * PRIOR[k]);
                let next_cost = cost_of(&configured, &next, samples);
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
        let miss: f64 = samples
            .iter()
            .map(|(a, p)| dist2(&position(&configured, &theta, a), p))
            .sum();
        Self {
            configured,
            theta,
            rms_m: (miss / samples.len().max(1) as f64).sqrt(),
            samples: samples.len(),
        }
    }

    /// The actuation that puts this arm's tracked point at `target`, from `start`: damped
    /// Gauss-Newton with its steps' null-space part pulled back to `start`, so that two arms
    /// inverted from the same start differ by what differs between them, not by where the
    /// free directions wandered.
    pub fn invert(model: &impl ForwardModel, target: &Position, start: &Actuation) -> Actuation {
        let mut a = *start;
        for _ in 0..ITERATIONS {
            let p = model.position(&a);
            let e = Vector3::from_fn(|d, _| target[d] - p[d]);
            if e.norm() < 1e-6 {
                break;
            }
            let j: Jacobian = model.jacobian(&a);
            let Some(pinv) = damped_pseudo_inverse(&j, 1e-3) else {
                break;
            };
            let back = SVector::<f64, ACTUATORS>::from_fn(|i, _| start[i] - a[i]);
            let step = pinv * e + (back - pinv * (j * back));
            a = std::array::from_fn(|i| (a[i] + step[i]).clamp(0.0, 1.0));
        }
        a
    }
}

/// Jᵀ (J Jᵀ + λ² I)⁻¹: the damped minimum-norm inverse of a Jacobian; none if singular. Here
/// rather than in `online`, which uses it too, so that `online` depends on this module and not
/// the other way round.
pub(crate) fn damped_pseudo_inverse(
    j: &Jacobian,
    damping: f64,
) -> Option<nalgebra::SMatrix<f64, ACTUATORS, 3>> {
    let jjt = j * j.transpose() + Matrix3::identity() * damping * damping;
    Some(j.transpose() * jjt.try_inverse()?)
}

fn dist2(a: &Position, b: &Position) -> f64 {
    (0..3).map(|d| (a[d] - b[d]).powi(2)).sum()
}

/// The objective, in units of σ and the prior.
fn cost_of(
    configured: &ArmGeometry,
    theta: &[f64; PARAMETERS],
    s: &[(Actuation, Position)],
) -> f64 {
    let data: f64 = s
        .iter()
        .map(|(a, p)| dist2(&position(configured, theta, a), p))
        .sum::<f64>()
        / (SAMPLE_SIGMA_M * SAMPLE_SIGMA_M);
    let prior: f64 = (0..PARAMETERS).map(|k| (theta[k] / PRIOR[k]).powi(2)).sum();
    data + prior
}

/// JᵀJ and Jᵀr of the whitened residuals (data and prior) in units of the prior, by central
/// differences over the parameters.
fn normal_equations(
    configured: &ArmGeometry,
    theta: &[f64; PARAMETERS],
    samples: &[(Actuation, Position)],
) -> (DMatrix<f64>, DVector<f64>) {
    let mut jtj = DMatrix::<f64>::identity(PARAMETERS, PARAMETERS);
    let mut jtr = DVector::<f64>::from_fn(PARAMETERS, |k, _| -theta[k] / PRIOR[k]);
    const H: f64 = 1e-4;
    for (a, p) in samples {
        let f = position(configured, theta, a);
        let r = Vector3::from_fn(|d, _| (p[d] - f[d]) / SAMPLE_SIGMA_M);
        let cols: Vec<Vector3<f64>> = (0..PARAMETERS)
            .map(|k| {
                let (mut up, mut down) = (*theta, *theta);
                up[k] += H * PRIOR[k];
                down[k] -= H * PRIOR[k];
                let (u, d) = (position(configured, &up, a), position(configured, &down, a));
                Vector3::from_fn(|i, _| (u[i] - d[i]) / (2.0 * H) / SAMPLE_SIGMA_M)
            })
            .collect();
        for k in 0..PARAMETERS {
            jtr[k] += cols[k].dot(&r);
            for l in 0..PARAMETERS {
                jtj[(k, l)] += cols[k].dot(&cols[l]);
            }
        }
    }
    (jtj, jtr)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    fn actuations(n: usize, seed: u64) -> Vec<Actuation> {
        let mut rng = StdRng::seed_from_u64(seed);
        (0..n)
            .map(|_| std::array::from_fn(|_| rng.random_range(0.3..0.7)))
            .collect()
    }

    fn miss(model: &impl ForwardModel, real: &ArmGeometry, a: &[Actuation]) -> f64 {
        a.iter()
            .map(|a| dist2(&model.position(a), &real.position(a)).sqrt())
            .fold(0.0, f64::max)
    }

    #[test]
    fn a_calibrated_arm_finds_a_longer_tool_and_crept_tendons() {
        let configured = ArmGeometry::default();
        let mut real = configured;
        real.tool_m += 0.02;
        real.actuator_offset_m = [0.0, 0.003, 0.0, 0.0, 0.0, 0.004];
        let samples: Vec<(Actuation, Position)> = actuations(40, 1)
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
        let a = CalibratedArm::invert(&fitted, &target, &[0.5; ACTUATORS]);
        assert!(dist2(&real.position(&a), &target).sqrt() < 0.0005);
    }

    #[test]
    fn without_samples_the_calibrated_arm_is_the_configured_one() {
        let configured = ArmGeometry::default();
        let fitted = CalibratedArm::fit(configured, &[]);
        assert_eq!(fitted.theta, [0.0; PARAMETERS]);
        assert_eq!(fitted, CalibratedArm::configured(configured));
        let a = [0.4, 0.6, 0.5, 0.55, 0.45, 0.5];
        assert_eq!(fitted.position(&a), configured.position(&a));
    }
}
