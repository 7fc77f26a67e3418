//! Forward models: what predicts where the end effector goes for an actuation. The learner
//! pre-trains against one offline; the PCC kinematics and the fitted RBF network are two.

use crate::pcc::ArmGeometry;
use crate::space::{Actuation, Position};

/// Something that predicts where the end effector goes for a normalised actuation.
pub trait ForwardModel {
    fn position(&self, actuation: &Actuation) -> Position;
}

impl ForwardModel for ArmGeometry {
    fn position(&self, actuation: &Actuation) -> Position {
        ArmGeometry::position(self, actuation)
    }
}
