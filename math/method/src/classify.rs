//! ClassifyToPrimitives (the paper's Alg. 2): which primitive each conditioning point belongs
//! to, by Mahalanobis distance to the task-space ProMPs at the point's phase.

use nalgebra::{DMatrix, DVector};

use crate::activation::ScheduleError;
use crate::blend::BlendError;
use softarm_kinematics::linalg::solve_spd;

use crate::promp::{Primitive, PrimitiveError};
use crate::space::Position;

/// ClassifyToPrimitives: for each conditioning point, the primitive whose task-space ProMP is
/// nearest to the point at its phase in Mahalanobis distance.
pub fn classify(
    task_primitives: &[Primitive],
    points: &[Position],
    phases: &[f64],
    variance_floor: f64,
) -> Result<Vec<usize>, BlendError> {
    if points.len() != phases.len() {
        return Err(BlendError::Count {
            what: "conditioning phases",
            expected: points.len(),
            got: phases.len(),
        });
    }
    if task_primitives.is_empty() {
        return Err(ScheduleError::PrimitiveCount(0).into());
    }
    for (index, p) in task_primitives.iter().enumerate() {
        if p.dofs() != 3 {
            return Err(BlendError::PrimitiveMismatch {
                index,
                why: format!("a task-space primitive has 3 DoF, this one {}", p.dofs()),
            });
        }
    }
    points
        .iter()
        .zip(phases)
        .map(|(point, &z)| {
            let mut best = (usize::MAX, f64::INFINITY);
            for (j, p) in task_primitives.iter().enumerate() {
                let m = p.marginal(z.clamp(0.0, 1.0));
                let mut cov = m.cov;
                for d in 0..3 {
                    cov[(d, d)] += variance_floor;
                }
                let r = DVector::from_fn(3, |d, _| point[d] - m.mean[d]);
                let x = solve_spd(cov, DMatrix::from_column_slice(3, 1, r.as_slice()))
                    .ok_or(PrimitiveError::Singular)?;
                let d2 = r.dot(&x.column(0));
                if d2 < best.1 {
                    best = (j, d2);
                }
            }
            Ok(best.0)
        })
        .collect()
}
