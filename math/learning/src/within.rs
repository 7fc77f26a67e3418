//! Learning within the execution (the paper's III-D re-planning): what the points seen so far
//! in the running execution show of the arm as it is now, shared with the points still to come.
//!
//! Each visited point predicts where its try lands from its own history (its error filter and
//! slope, or on a first visit where the model of its first estimate says that lands). What it
//! misses that prediction by, beyond its usual scatter, is the arm: a tool swapped, a tendon
//! crept, a load. That part is a departure δθ of the calibrated arm's parameters
//! ([`CalibratedArm`]: tool in the tip frame, actuator offsets, bends, rotations, connector),
//! estimated by a Kalman filter over the execution's points from a prior of what changes while
//! an arm runs ([`CalibratedArm::change_variances`]); a later point is corrected by the
//! departed arm ([`Departure::arm_now`]; the learner takes its inverse). Not a shift of task
//! space: a longer tool moves every point along its own tip axis, which turns from point to
//! point.
//!
//! Only what stands out of the scatter counts: a miss within 2.5 times what a point's prediction
//! usually misses by (learnt per kind of visit, first or repeated) teaches nothing, so that on
//! an arm that has not changed nothing is added.
//! Pure: no I/O.

use nalgebra::{DMatrix, DVector, Vector3};

use crate::calibration::CalibratedArm;
use softarm_kinematics::forward::ForwardModel;

/// A miss counts as evidence only beyond this many times its kind's scatter (RMS of the miss):
/// a miss of pure scatter goes beyond it at about one visit in 3,000 (χ² of three degrees of
/// freedom); at 1.5 it was one in 12, and the learner corrected the rest of a nominal
/// execution by that scatter.
const EVIDENCE: f64 = 2.5;
/// A miss beyond this many times its kind's scatter is evidence enough alone; one between
/// [`EVIDENCE`] and this needs a second point of the execution beside it. One point tells a
/// departure of a dozen parameters only by the prior's choice of explanation, which a small
/// miss does not pin (measured: a 0.25 mm tendon step seen at one point as 3.9 mm, carried to
/// another as 11 mm).
const ALONE: f64 = 3.5;
/// A departure's shift at a point still to come is taken up to this many times the largest
/// miss that showed it: a departure that would move another point much further than any point
/// moved is its prior's extrapolation, not the arm.
const AMPLIFY: f64 = 1.5;

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
    /// The point's first try: predicted to land where the model of its first estimate says.
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
    /// The calibrated arm misses its own samples by `rms_m` (m), more than the tracker's
    /// noise (`noise_m`): no model of the arm to share a departure by.
    Unfit { rms_m: f64 },
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
    /// Points of this execution that counted as evidence, whether one did alone, and the
    /// largest miss among them (m).
    evidence: u32,
    alone: bool,
    largest_m: f64,
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
            evidence: 0,
            alone: false,
            largest_m: 0.0,
            first_var: FIRST_MISS_M * FIRST_MISS_M / 3.0,
            repeated_var: noise_m * noise_m / 3.0,
        }
    }

    /// A new execution (or set, or arm): nothing of the departure is known; the scatter stays.
    pub fn restart(&mut self) {
        self.theta = DVector::zeros(0);
        self.cov = DMatrix::zeros(0, 0);
        self.last_point = None;
        self.evidence = 0;
        self.alone = false;
        self.largest_m = 0.0;
    }

    /// A changed arm: nothing of it is known, its scatter neither, as a fresh learner's
    /// (measured in the running stack: a learner that had seen two changes started a third's
    /// set at 12.2 mm where a fresh one started at 9.0).
    pub fn forget(&mut self, noise_m: f64) {
        *self = Self::new(noise_m);
    }

    /// The last point seen in the running execution.
    pub fn last_point(&self) -> Option<usize> {
        self.last_point
    }

    /// Point `point`'s try, at actuation `a`, landed `missed` (m) from where its own history
    /// predicted, a prediction doubtful by `doubt` (m²: a long step's). Learns the departure
    /// from it unless that doubt is beyond the kind's scatter; a point at or before the last
    /// seen begins a new execution.
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
        let scatter2 = 3.0 * *var;
        // A long step's own prediction is doubtful: what it misses by may be the step's, not
        // the arm's (measured: the TDCR's calibrated steps after a tool change missing by 49
        // mm, which shared threw two other points 66 and 121 mm off). It tells nothing here.
        if doubt > scatter2 {
            return;
        }
        let miss2 = innovation.norm_squared();
        // Evidence is a miss of the point's own prediction beyond the scatter, whatever the
        // departure already said of it: a second point that agrees confirms. What is not
        // evidence is the scatter: a changed arm's misses are not (a learner that had seen two
        // changes corrected a third's first execution less than a fresh one: 8.9 against 6.8 mm).
        let raw2 = missed.norm_squared();
        if raw2 <= EVIDENCE * EVIDENCE * scatter2 {
            *var += SCATTER_WEIGHT * ((miss2 / 3.0).min(SCATTER_CLIP * *var) - *var);
        } else {
            self.evidence += 1;
            self.alone |= raw2 > ALONE * ALONE * scatter2;
            self.largest_m = self.largest_m.max(raw2.sqrt());
        }
        // Nothing is learnt before a point showed a departure; after, every point's miss of
        // the departure's prediction refines it, one that contradicts it too.
        if self.evidence == 0 {
            return;
        }
        let r = DMatrix::<f64>::identity(3, 3) * var.max(f64::MIN_POSITIVE);
        let pgt = &self.cov * g.transpose();
        let s = &g * &pgt + r;
        let Some(s_inv) = s.try_inverse() else {
            return;
        };
        let k = &pgt * s_inv;
        self.theta += &k * DVector::from_column_slice(innovation.as_slice());
        self.cov = &self.cov - &k * &g * &self.cov;
    }

    /// Point `point` came and told nothing of the arm (its target is beyond reach); a point at
    /// or before the last seen begins a new execution.
    pub fn pass<const N: usize>(&mut self, arm: &CalibratedArm<N>, point: usize) {
        if self.last_point.is_some_and(|last| point <= last) || self.theta.is_empty() {
            self.restart();
            self.theta = DVector::zeros(arm.parameters());
            self.cov = DMatrix::from_diagonal(&arm.change_variances());
        }
        self.last_point = Some(point);
    }

    /// `arm` as the execution's points so far show it at actuation `a`: departed by what they
    /// showed, scaled down where that would move the tracked point further than [`AMPLIFY`]
    /// times the largest miss that showed it; none without evidence enough in this execution.
    pub fn arm_now<const N: usize>(
        &self,
        arm: &CalibratedArm<N>,
        a: &[f64; N],
    ) -> Option<CalibratedArm<N>> {
        let enough = self.alone || self.evidence >= 2;
        if !enough || self.theta.len() != arm.parameters() {
            return None;
        }
        let now = arm.departed(&self.theta);
        let (at, was) = (now.position(a), arm.position(a));
        let shift = (0..3).map(|d| (at[d] - was[d]).powi(2)).sum::<f64>().sqrt();
        let most = AMPLIFY * self.largest_m;
        Some(if shift > most {
            arm.departed(&(&self.theta * (most / shift)))
        } else {
            now
        })
    }
}
