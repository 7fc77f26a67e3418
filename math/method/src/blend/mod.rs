//! Eq. 11 of the paper: the conditioned primitives blended, evaluated once per controller
//! tick,
//!
//!   v(t) = Σ_i b_i(t) μ*_i(t),  μ*_i = (Σ_j a_j Λ_ij)⁻¹ Σ_j a_j Λ_ij μ_ij,  Λ_ij = (S_ij + floor·I)⁻¹.
//!
//! Words used here: a *group* is conditioning point i's copy of the M primitives, in which its
//! primitive Q[i] is conditioned on the actuation estimate for point i (the paper's u_ij for
//! that i); b_i(t) weighs the groups, a_j(t) the primitives within one
//! ([`crate::activation`]).
//!
//! - [`table`]: every marginal N(μ_ij, S_ij) precomputed on the controller's tick grid in
//!   information form (Λ, Λμ), so a tick is a few weighted sums and one D×D Cholesky solve per
//!   active group (at most two are active).
//! - [`condition`]: the [`Planner`] prepares a set; the [`Replanner`] conditions a group again
//!   (UpdatePrim) off the tick thread, into a spare table sent over a bounded lock-free
//!   single-producer single-consumer ring ([`rtrb`]).
//! - [`tick`]: the [`Blend`] evaluates v at a tick on the tick thread. It swaps a re-conditioned
//!   table in while b_i = 0 or between executions (the rest, and tick 0), so conditioning again
//!   never moves a setpoint already played, and sends the old table back over another ring for
//!   reuse, so the tick never frees memory either. A tick allocates nothing and locks nothing.

use rtrb::{Consumer, Producer, PushError, RingBuffer};

use nalgebra::{DMatrix, DVector};

use crate::activation::{MAX_PRIMITIVES, Schedule, ScheduleError};
use softarm_kinematics::linalg::solve_spd;
use softarm_sections::activation::ActivationConfig;

use crate::promp::{Primitive, PrimitiveError};

pub mod condition;
pub mod table;
pub mod tick;

pub use condition::{Planner, Replanner};
pub use table::{ConditionedOn, Table, Update};
pub use tick::Blend;

/// A conditioning point as the tick executes it: where the end effector should be (P_cond,
/// m, base frame) and the tick of its time T_cond on the tick grid, where it is sampled.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ConditioningPoint {
    pub position: crate::space::Position,
    pub tick: usize,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BlendError {
    #[error(transparent)]
    Primitive(#[from] PrimitiveError),
    #[error(transparent)]
    Schedule(#[from] ScheduleError),
    #[error("tick rate must be finite and > 0, got {0} Hz")]
    Rate(f64),
    #[error("primitive {index}: {why}")]
    PrimitiveMismatch { index: usize, why: String },
    #[error("{what}: expected {expected}, got {got}")]
    Count {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("no group {group}: the plan has {groups}")]
    NoSuchGroup { group: usize, groups: usize },
    #[error("{what} must be finite (got {value} at index {index})")]
    NonFinite {
        what: &'static str,
        index: usize,
        value: f64,
    },
    #[error("the blend is gone (the controller stopped)")]
    Disconnected,
    #[error("{0} re-conditioned groups already wait for the tick; try again once it runs")]
    Busy(usize),
}

/// The controller's tick grid over one execution: tick k at t = k / rate, phase k / (ticks − 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Timeline {
    pub(super) rate_hz: f64,
    pub(super) ticks: usize,
}

impl Timeline {
    /// The duration is snapped to whole ticks.
    pub fn new(duration_s: f64, rate_hz: f64) -> Result<Self, BlendError> {
        if !(rate_hz.is_finite() && rate_hz > 0.0) {
            return Err(BlendError::Rate(rate_hz));
        }
        if !(duration_s.is_finite() && duration_s > 0.0) {
            return Err(ScheduleError::Duration(duration_s).into());
        }
        let ticks = (duration_s * rate_hz).round().max(1.0) as usize + 1;
        Ok(Self { rate_hz, ticks })
    }

    pub fn ticks(&self) -> usize {
        self.ticks
    }

    pub fn rate_hz(&self) -> f64 {
        self.rate_hz
    }

    pub fn duration(&self) -> f64 {
        (self.ticks - 1) as f64 / self.rate_hz
    }

    pub fn time_of(&self, tick: usize) -> f64 {
        tick as f64 / self.rate_hz
    }

    pub fn phase_of(&self, tick: usize) -> f64 {
        tick as f64 / (self.ticks - 1) as f64
    }

    /// The tick nearest to t, inside the execution.
    pub fn tick_of(&self, t: f64) -> usize {
        ((t * self.rate_hz).round().max(0.0) as usize).min(self.ticks - 1)
    }
}

#[cfg(test)]
mod tests;
