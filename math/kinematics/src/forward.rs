//! Forward models: what predicts where the end effector goes for an actuation. The learner
//! pre-trains against one offline and steers its corrections by one's Jacobian; the PCC
//! kinematics, the fitted RBF network and the fitted polynomial are three.

use softarm_space::Position;

use crate::pcc;

/// ∂p/∂a: metres per unit of normalised actuation, one row per axis, one column per actuator
/// (`N` of them).
pub type Jacobian<const N: usize> = nalgebra::SMatrix<f64, 3, N>;

/// Something that predicts where the end effector goes for a normalised actuation of `N`
/// actuators.
pub trait ForwardModel<const N: usize> {
    fn position(&self, actuation: &[f64; N]) -> Position;

    /// ∂p/∂a at `actuation`; central differences unless the model knows better.
    fn jacobian(&self, actuation: &[f64; N]) -> Jacobian<N> {
        finite_difference(self, actuation)
    }
}

/// ∂p/∂a by central differences of `model`.
pub fn finite_difference<const N: usize, M: ForwardModel<N> + ?Sized>(
    model: &M,
    a: &[f64; N],
) -> Jacobian<N> {
    const H: f64 = 1e-5;
    let mut j = Jacobian::<N>::zeros();
    for i in 0..N {
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

/// Any arm's PCC kinematics ([`pcc::Arm`] of `N` actuators) as a forward model; an actuation
/// whose arcs the model cannot tell (outside every valid arm's strokes) gives NaN.
impl<const N: usize> ForwardModel<N> for pcc::Arm {
    fn position(&self, actuation: &[f64; N]) -> Position {
        debug_assert_eq!(self.actuators(), N);
        match self.pose(actuation) {
            Ok(p) => [p.position.x, p.position.y, p.position.z],
            Err(_) => [f64::NAN; 3],
        }
    }
}
