//! The kinematics and forward models of softarm, pure math: no I/O, no clock, no iceoryx2
//! (Cargo enforces it: this crate depends on neither). The settings they are made from
//! (`[arm]`, `[kinematics]`, `[forward_model]`) are plain data in `softarm-sections`; the math
//! on them is here.
//!
//! - [`arc`] — one constant-curvature module: its arc, its transform, its centroid.
//! - [`arcs`] — actuator lengths to module arcs for any arm (least squares).
//! - [`pcc`] — piecewise-constant-curvature kinematics of any arm, [`pcc::Arm`].
//! - [`forward`] — the [`forward::ForwardModel`] trait (the PCC kinematics are one).
//! - [`poly`] — the polynomial forward model (the learner's kinematics).
//! - [`rbf`] — RBF lattices (the learner's actor and critic) and the RBF forward-model network.
//! - [`linalg`] — the symmetric solve and the normal equations the fits share, summed in blocks
//!   on every core.

pub mod arc;
pub mod arcs;
pub mod forward;
pub mod linalg;
pub mod pcc;
pub mod poly;
pub mod rbf;
