//! Admitting a way-point set (Alg. 2's set-up): validated against the config, each way-point
//! classified to a primitive, planned on the tick grid, then started from the learner's first
//! estimates. The service thread admits the running stack's sets with it, and
//! `softarm-rehearsal` the sets it rehearses, so both plan a set the same way.

use anyhow::bail;
use softarm_config::Config;
use softarm_config::waypoints::validate;
use softarm_ipc::{ActuationEstimate, EstimateRequest, MAX_WAYPOINTS, Position, WaypointSet};
use softarm_method::blend::{
    BlendError, ConditionedOn, ConditioningPoint, Planner, Replanner, Timeline,
};
use softarm_method::classify::classify;
use softarm_model::bundle::Model;

use crate::execution::ReadySet;

/// What the learner's estimate `e` conditions its point on, with the learner's words about it;
/// `None` if it is not for an arm of `N` actuators. As the service thread and the rehearsal
/// both take it.
pub fn conditioned_on<const N: usize>(e: &ActuationEstimate) -> Option<ConditionedOn<N>> {
    Some(ConditionedOn {
        actuation: e.actuation.fixed()?,
        execution: e.execution,
        within: e.within != 0,
        beyond_reach: e.beyond_reach != 0,
    })
}

/// A set that passed admission: planned, with each way-point's primitive and its mean there,
/// waiting for the learner's first estimates.
pub struct Admitted<const N: usize> {
    planner: Planner<N>,
    classes: Vec<usize>,
    /// Without the learner's estimate, each point's primitive's own mean at its phase (no
    /// conditioning change), from the model this set was planned with.
    fallback: Vec<[f64; N]>,
    executions: u32,
    desired: [Position; MAX_WAYPOINTS],
}

/// Validates `set` and plans it with `model`: ClassifyToPrimitives, then the primitives'
/// marginals on the tick grid. Any error is the rejection reason, worded for the user.
pub fn admit<const N: usize>(
    config: &Config,
    model: Option<&Model<N>>,
    set: &WaypointSet,
) -> anyhow::Result<Admitted<N>> {
    validate(set, &config.waypoints, &config.activation).map_err(anyhow::Error::msg)?;
    let Some(model) = model else {
        bail!(
            "no trained model in {}: run `softarm train` first",
            config.model_dir().display()
        );
    };
    let n = set.count as usize;
    let points = &set.positions_m[..n];
    let z: Vec<f64> = set.times_s[..n]
        .iter()
        .map(|t| t / set.duration_s)
        .collect();
    let classes = classify(&model.task, points, &z, config.controller.variance_floor)?;
    let timeline = Timeline::new(set.duration_s, config.controller.rate_hz)?;
    let planner = Planner::new(
        model.actuation.clone(),
        &set.times_s[..n],
        &classes,
        timeline,
        config.activation,
        config.controller.variance_floor,
    )?;
    let fallback = classes
        .iter()
        .zip(&z)
        .map(|(&j, &z)| {
            let m = model.actuation[j].marginal(z).mean;
            std::array::from_fn(|d| m[d])
        })
        .collect();
    let mut desired = [[0.0; 3]; MAX_WAYPOINTS];
    desired[..n].copy_from_slice(points);
    Ok(Admitted {
        planner,
        classes,
        fallback,
        executions: set.executions,
        desired,
    })
}

impl<const N: usize> Admitted<N> {
    /// The set's way-points (conditioning points).
    pub fn points(&self) -> usize {
        self.classes.len()
    }

    /// The primitive each way-point was classified to.
    pub fn classes(&self) -> &[usize] {
        &self.classes
    }

    pub fn executions(&self) -> u32 {
        self.executions
    }

    /// What the learner is asked for this set's first estimates, the set named `set_id`
    /// (`seq` and `stamp_ns` are the sender's).
    pub fn estimate_request(&self, set_id: u64, seq: u64, stamp_ns: u64) -> EstimateRequest {
        EstimateRequest {
            seq,
            stamp_ns,
            set_id,
            count: self.points() as u32,
            _pad: 0,
            desired: self.desired,
        }
    }

    /// The set ready for the tick, started from the learner's first `estimates` (one per point;
    /// a point without one starts from its primitive's mean), and the [`Replanner`] that
    /// re-conditions it with the estimates that come while it runs.
    pub fn start(
        self,
        set_id: u64,
        estimates: &[Option<ConditionedOn<N>>],
    ) -> Result<(ReadySet<N>, Replanner<N>), BlendError> {
        let initial: Vec<ConditionedOn<N>> = self
            .fallback
            .iter()
            .enumerate()
            .map(|(i, fallback)| {
                estimates
                    .get(i)
                    .copied()
                    .flatten()
                    .unwrap_or(ConditionedOn {
                        actuation: *fallback,
                        execution: 1,
                        ..ConditionedOn::NONE
                    })
            })
            .collect();
        let points = initial.len();
        let mut cond = [ConditioningPoint::default(); MAX_WAYPOINTS];
        for ((c, &position), &tick) in cond
            .iter_mut()
            .zip(&self.desired)
            .zip(self.planner.conditioning_ticks())
        {
            *c = ConditioningPoint { position, tick };
        }
        let (blend, replanner) = self.planner.start_on(&initial)?;
        let set = ReadySet {
            set_id,
            executions: self.executions,
            count: points,
            points: cond,
            blend,
        };
        Ok((set, replanner))
    }
}
