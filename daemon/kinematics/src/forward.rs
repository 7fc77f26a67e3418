//! Forward models: what predicts where the end effector goes for an actuation. The learner
//! pre-trains against one offline and steers its corrections by one's Jacobian; the PCC
//! kinematics, the fitted RBF network and the fitted polynomial are three.

use softarm_sections::arm::ArmGeometry;
use softarm_space::{ACTUATORS, Actuation, Position};

use crate::pcc::Kinematics;

/// ∂p/∂a: metres per unit of normalised actuation, one row per axis.
pub type Jacobian = nalgebra::SMatrix<f64, 3, ACTUATORS>;

/// Something that predicts where the end effector goes for a normalised actuation.
pub trait ForwardModel {
    fn position(&self, actuation: &Actuation) -> Position;

    /// ∂p/∂a at `actuation`; central differences unless the model knows better.
    fn jacobian(&self, actuation: &Actuation) -> Jacobian {
        finite_difference(self, actuation)
    }
}

/// ∂p/∂a by central differences of `model`.
pub fn finite_difference<M: ForwardModel + ?Sized>(model: &M, a: &Actuation) -> Jacobian {
    const H: f64 = 1e-5;
    let mut j = Jacobian::zeros();
    for i in 0..ACTUATORS {
        let (mut up, mut down) = (*a, *a);
        up[i] += H;
        down[i] -= H;
        let (p, m) = (model.position(&up), model.position(&down));
        for d in 0..3 {
            j[(d, i)] = (p[d] - m[d]) / (2.0 * H);
        }
    }
    j
}

/// The PCC kinematics ([`Kinematics`]) as a forward model.
impl ForwardModel for ArmGeometry {
    /// End-effector position (m) for a normalised actuation: the forward model of the plant.
    fn position(&self, actuation: &Actuation) -> Position {
        let p = self.pose(actuation).position;
        [p.x, p.y, p.z]
    }
}
