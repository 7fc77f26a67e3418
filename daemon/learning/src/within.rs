//! Learning within the execution (the paper's III-D re-planning): what the points seen so far
//! in the running execution show of the arm as it is now, shared with the points still to come.
//!
//! Each visited point predicts where its try lands from its own history (its error filter and
//! Jacobian, or its target on a first visit). What it misses that prediction by, beyond its
//! usual scatter, is the arm: a tool swapped, a tendon crept, a load. That part is a departure
//! δθ of the calibrated arm's parameters ([`CalibratedArm`]: tool in the tip frame, actuator
//! offsets, bends, rotations, connector), estimated by a Kalman filter over the execution's
//! points from a prior of the plausible departures, and carried to a later point `m` as the
//! shift `G_m δθ` its sensitivity gives there. Not a shift of task space: a longer tool moves
//! every point along its own tip axis, which turns from point to point.
//!
//! Only what stands out of the scatter counts: a miss within what a point's prediction usually
//! misses by (learnt per kind of visit, first or repeated) is shrunk to nothing, one beyond it
//! by the scatter's share, so that on an arm that has not changed nothing is added.
//! Pure: no I/O.

use nalgebra::{DMatrix, DVector, Vector3};

use crate::calibration::CalibratedArm;
use softarm_kinematics::forward::ForwardModel;

/// A miss counts as evidence only beyond this many times its kind's scatter (RMS of the miss).
const EVIDENCE: f64 = 1.5;

/// How fast the scatter of a kind of visit follows what it sees: the weight of one visit.
const SCATTER_WEIGHT: f64 = 0.1;
/// A visit pulls its kind's scatter up by at most this many times its variance: a change of
/// the arm is no scatter.
const SCATTER_CLIP: f64 = 4.0;

/// What a first visit's prediction (its target) misses by before anything is learnt (RMS, m):
/// a trained model's miss at a target it never ran, on an arm that is as trained.
pub const FIRST_MISS_M: f64 = 0.005;

/// A shift smaller than this at a point is not sent as a correction (m).
pub const LEAST_SHIFT_M: f64 = 1e-4;

/// The kind of a visit's prediction, each with its own scatter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// The point's first try: predicted to land on its target.
    First,
    /// A later one: predicted from the point's own tries.
    Repeated,
}

/// How a point's estimate was corrected within its execution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Within {
    /// Not asked: the point comes first in its execution, or the algorithm does not learn
    /// within the execution (`paper`).
    NotAsked,
    /// What the execution's points so far missed by is within their scatter.
    NoEvidence,
    /// The arm as they show it would move the point by `shift_m` (m), which no actuation
    /// within the trust region makes up for by half.
    Unhelpful { shift_m: f64 },
    /// Moved by what the departure seen so far predicts at the point: `shift_m` (m) there,
    /// shortened to the trust region if `capped`.
    Corrected { shift_m: f64, capped: bool },
}

impl Within {
    pub fn corrected(&self) -> bool {
        matches!(self, Within::Corrected { .. })
    }
}

/// The departure the running execution's points show, and what each kind of visit scatters by.
#[derive(Debug, Clone)]
pub struct Departure {
    /// δθ: the calibrated arm's parameters as the execution shows them, less as calibrated.
    theta: DVector<f64>,
    /// Its covariance.
    cov: DMatrix<f64>,
    /// The last point seen in this execution: a point at or before it begins the next.
    last_point: Option<usize>,
    /// Whether any point of this execution counted as evidence.
    evidence: bool,
    /// Per axis (m²): what a first and a repeated visit's prediction misses by, the departure
    /// taken away.
    first_var: f64,
    repeated_var: f64,
}

impl Departure {
    /// Nothing seen; a repeated visit scatters by `noise_m` (RMS) until it is learnt.
    pub fn new(noise_m: f64) -> Self {
        Self {
            theta: DVector::zeros(0),
            cov: DMatrix::zeros(0, 0),
            last_point: None,
            evidence: false,
            first_var: FIRST_MISS_M * FIRST_MISS_M / 3.0,
            repeated_var: noise_m * noise_m / 3.0,
        }
    }

    /// A new execution (or set, or arm): nothing of the departure is known; the scatter stays.
    pub fn restart(&mut self) {
        self.theta = DVector::zeros(0);
        self.cov = DMatrix::zeros(0, 0);
        self.last_point = None;
        self.evidence = false;
    }

    /// The last point seen in the running execution.
    pub fn last_point(&self) -> Option<usize> {
        self.last_point
    }

    /// Point `point`'s try, at actuation `a`, landed `missed` (m) from where its own history
    /// predicted, a prediction doubtful by `doubt` (m², beyond the kind's scatter: a long
    /// step's). Learns the departure from it; a point at or before the last seen begins a new
    /// execution.
    pub fn observe<const N: usize>(
        &mut self,
        arm: &CalibratedArm<N>,
        point: usize,
        a: &[f64; N],
        missed: &Vector3<f64>,
        kind: Kind,
        doubt: f64,
    ) {
        self.pass(arm, point);
        if !missed.iter().all(|v| v.is_finite()) {
            return;
        }
        // Linearised where the departure seen so far puts the arm (an extended Kalman filter):
        // the shift it predicts is the departed arm's own, as the corrections take it.
        let now = arm.departed(&self.theta);
        let g = now.sensitivity(a);
        let (at, was) = (now.position(a), arm.position(a));
        let predicted = Vector3::from_fn(|d, _| at[d] - was[d]);
        if !g.iter().chain(predicted.iter()).all(|v| v.is_finite()) {
            return;
        }
        let innovation = missed - predicted;
        let var = match kind {
            Kind::First => &mut self.first_var,
            Kind::Repeated => &mut self.repeated_var,
        };
        let scatter2 = 3.0 * *var + doubt.max(0.0);
        let miss2 = innovation.norm_squared();
        // What a long step misses by is its doubt, not the scatter of the kind.
        if doubt <= 3.0 * *var {
            *var += SCATTER_WEIGHT * ((miss2 / 3.0).min(SCATTER_CLIP * *var) - *var);
        }
        // Until the execution shows a departure, a miss is shrunk by the scatter's share:
        // nothing within it, nearly all of one far beyond. Once it has, the later points
        // refine it, weighed against their scatter.
        let keep = if self.evidence {
            1.0
        } else if miss2 > 0.0 {
            (1.0 - EVIDENCE * EVIDENCE * scatter2 / miss2).max(0.0)
        } else {
            0.0
        };
        self.evidence |= keep > 0.0;
        let r = DMatrix::<f64>::identity(3, 3) * (scatter2 / 3.0);
        let pgt = &self.cov * g.transpose();
        let s = &g * &pgt + r;
        let Some(s_inv) = s.try_inverse() else {
            return;
        };
        let k = &pgt * s_inv;
        let kept = DVector::from_column_slice((innovation * keep).as_slice());
        self.theta += &k * kept;
        self.cov = &self.cov - &k * &g * &self.cov;
    }

    /// Point `point` came and told nothing of the arm (its target is beyond reach); a point at
    /// or before the last seen begins a new execution.
    pub fn pass<const N: usize>(&mut self, arm: &CalibratedArm<N>, point: usize) {
        if self.last_point.is_some_and(|last| point <= last) || self.theta.len() == 0 {
            self.restart();
            self.theta = DVector::zeros(arm.parameters());
            self.cov = DMatrix::from_diagonal(&arm.prior_variances());
        }
        self.last_point = Some(point);
    }

    /// `arm` as the execution's points so far show it: departed by what they showed; none
    /// without evidence in this execution.
    pub fn arm_now<const N: usize>(&self, arm: &CalibratedArm<N>) -> Option<CalibratedArm<N>> {
        (self.evidence && self.theta.len() == arm.parameters()).then(|| arm.departed(&self.theta))
    }

    /// The scatter (RMS, m) of a kind of visit's prediction.
    pub fn scatter_m(&self, kind: Kind) -> f64 {
        let var = match kind {
            Kind::First => self.first_var,
            Kind::Repeated => self.repeated_var,
        };
        (3.0 * var).sqrt()
    }
}
